# Two entry points for a fresh machine: `make train` and `make test`.
# torch is installed first and pinned: a looser requirement resolved before it would pull
# several GB of CUDA packages instead of the local CPU build.
PY := .venv/bin/python
TORCH_VERSION := 2.13.0

.PHONY: setup setup-safety-gym setup-mjwarp train test test-cpus bench bench-velocity bench-velocity-smoke bench-safety-gym \
	bench-safety-gym-smoke sweep probe-belief clean

.venv/.installed: pyproject.toml setup.py
	test -x $(PY) || python3 -m venv .venv
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q torch==$(TORCH_VERSION)
	$(PY) -m pip install -q -e '.[test,sweep]'
	touch $@

setup: .venv/.installed

# MuJoCo (the `mujoco` extra) for env=velocity; the test extra has it too, this makes it explicit.
.venv/.mujoco: .venv/.installed
	$(PY) -m pip install -q -e '.[mujoco]'
	touch $@

# The velocity benchmark (experiments/benchmarks/velocity_benchmark.py): ppo, ppo_lag and cpo on HalfCheetah,
# 3 seeds, about an hour on 2 cores; then the table and the PNG. The smoke version runs in minutes.
bench-velocity: .venv/.mujoco
	$(PY) experiments/speed/velocity_speed.py
	$(PY) experiments/benchmarks/velocity_benchmark.py --run $(VELOCITY_ARGS)

bench-velocity-smoke: .venv/.mujoco
	$(PY) experiments/benchmarks/velocity_benchmark.py --run total_steps=8192 rollout_steps=256 env.num_envs=4 \
		eval_episodes=2 env.max_steps=200 hydra.sweep.dir=multirun/velocity_benchmark_smoke

# Safety-Gymnasium (env=safety_gym, docs/safety_gym.md). Its only release, 1.0.0, pins gymnasium 0.28,
# mujoco 2.3 and pygame 2.1, which would downgrade our stack (pygame 2.1 has no wheel for Python
# 3.11): it goes in with --no-deps, after the few packages it really needs (the `safety_gym` extra).
# Our pins are untouched; cmdp_rl/envs/safety_gym/compat.py makes it import on gymnasium 1.x.
SAFETY_GYM_VERSION := 1.0.0
.venv/.safety_gym: .venv/.installed
	$(PY) -m pip install -q -e '.[safety_gym]'
	$(PY) -m pip install -q --no-deps safety-gymnasium==$(SAFETY_GYM_VERSION)
	touch $@

setup-safety-gym: .venv/.safety_gym

# MuJoCo Warp for env=safe_nav env.physics=mjwarp (docs/safe_nav.md): the `mjwarp` extra, 149 MB. make test
# installs it, so that tests/test_safe_nav_warp.py checks that physics on Warp's CPU device (it skips without it).
.venv/.mjwarp: .venv/.safety_gym
	$(PY) -m pip install -q -e '.[mjwarp]'
	touch $@

setup-mjwarp: .venv/.mjwarp

# The Safety-Gymnasium benchmark (experiments/benchmarks/safety_gym_benchmark.py): ppo, ppo_lag, pid_lag and cpo on
# SafetyPointGoal1-v0 and SafetyCarGoal1-v0, 3 seeds, 500k steps each (hours on 2 cores), then the report.
# The smoke version runs the same pipeline on tiny budgets, seed 0 only.
bench-safety-gym: .venv/.safety_gym
	$(PY) experiments/benchmarks/safety_gym_benchmark.py --run $(SAFETY_GYM_ARGS)

bench-safety-gym-smoke: .venv/.safety_gym
	$(PY) experiments/benchmarks/safety_gym_benchmark.py --run total_steps=1024 env.num_envs=2 rollout_steps=256 \
		env.max_steps=256 eval_episodes=1 seed=0 hydra.sweep.dir=multirun/safety_gym_benchmark_smoke

# The first run: the batched Reach1D preset (configs/env/reach1d_torch.yaml, tuned in configs/tuning/)
# for 3M steps, 96 iterations; experiments/benchmarks/first_run.py runs this recipe over seeds
# (the figures in docs/guide/first_run.md).
train: setup
	$(PY) train.py algo=ppo_lag env=reach1d_torch total_steps=3145728

# The tests include Safety-Gymnasium's tasks (tests/test_safety_gym.py) and MuJoCo Warp's physics
# (tests/test_safe_nav_warp.py, on Warp's CPU device: about 105 s of CPU with a fresh kernel cache), so CI installs both.
# One pytest worker per core (pytest-xdist, -n auto: 2 here); worksteal hands a worker that runs dry the
# queued tests of the other, so a few long learning tests do not leave a core idle at the end (docs/testing.md).
# `make test PYTEST_ARGS="-p no:xdist"` runs them in one process.
PYTEST_ARGS := -n auto --dist worksteal
test: setup setup-safety-gym setup-mjwarp
	$(PY) -m pytest tests $(PYTEST_ARGS)

# Other CPUs on this one (docs/testing.md, "Other CPUs on this one"): the tests marked cpu_kernels again under
# each setting of tests/helpers/kernels.py, torch's, numpy's and the BLAS libraries' kernels picked as an AVX2
# CPU, an x86-64-v2 CPU and other BLAS kernels would pick them; then the share of each tolerance they used.
CPU_SETTINGS := avx2 sse4 blas
test-cpus: setup setup-safety-gym
	PYTHONPATH=tests $(PY) -m helpers.kernels $(CPU_SETTINGS) -- $(PYTEST_ARGS)

# Throughput table (env, rollout, training steps/s, peak memory); writes outputs/benchmark_throughput.json.
# Takes a few minutes; pass options with BENCH_ARGS, e.g. `make bench BENCH_ARGS="--device cuda"`.
bench: setup
	$(PY) experiments/speed/benchmark_throughput.py $(BENCH_ARGS)
	$(PY) experiments/speed/population_benchmark.py $(POPULATION_BENCH_ARGS)  # docs/population.md

# The penalty-versus-constraint study (docs/penalty_vs_constraint.md): both Hydra sweeps into one
# directory, then the report from their outputs. `make sweep SWEEP_ARGS="hydra/launcher=..."` scales
# out (see configs/experiment/penalty_vs_constraint.yaml). A sweep with a failed job exits non-zero;
# the `-` keeps going so that the report can list what failed.
ifndef SWEEP_DIR
SWEEP_DIR := multirun/penalty_vs_constraint/$(shell date +%Y-%m-%d_%H-%M-%S)
endif
sweep: setup
	-$(PY) train.py -m +experiment=penalty_sweep hydra.sweep.dir=$(SWEEP_DIR)/penalty $(SWEEP_ARGS)
	-$(PY) train.py -m +experiment=constraint_sweep hydra.sweep.dir=$(SWEEP_DIR)/constraint $(SWEEP_ARGS)
	$(PY) experiments/studies/penalty_vs_constraint.py $(SWEEP_DIR)

# The probe exercise (docs/probe_belief.md): {mlp, lstm, transformer} x {probe, no probe} x 3 seeds,
# about 20 minutes on 2 cores, then the table and the PNG. Overrides: PROBE_ARGS="total_steps=..."
probe-belief: setup
	$(PY) experiments/studies/probe_belief.py --run $(PROBE_ARGS)

clean:
	rm -rf .venv outputs multirun
