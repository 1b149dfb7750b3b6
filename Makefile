# Two entry points for a fresh machine: `make train` and `make test`.
# torch is installed first and pinned: a looser requirement resolved before it would pull
# several GB of CUDA packages instead of the local CPU build.
PY := .venv/bin/python
TORCH_VERSION := 2.13.0

.PHONY: setup train test bench clean

.venv/.installed: pyproject.toml
	test -x $(PY) || python3 -m venv .venv
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q torch==$(TORCH_VERSION)
	$(PY) -m pip install -q -e '.[test,sweep]'
	touch $@

setup: .venv/.installed

train: setup
	$(PY) train.py algo=ppo_lag env=reach1d

test: setup
	$(PY) -m pytest tests

# Throughput table (env, rollout, training steps/s, peak memory); writes outputs/benchmark_throughput.json.
# Takes a few minutes; pass options with BENCH_ARGS, e.g. `make bench BENCH_ARGS="--device cuda"`.
bench: setup
	$(PY) experiments/benchmark_throughput.py $(BENCH_ARGS)

clean:
	rm -rf .venv outputs multirun
