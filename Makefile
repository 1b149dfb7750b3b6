# Two entry points for a fresh machine: `make train` and `make test`.
# torch is installed first and pinned: a looser requirement resolved before it would pull
# several GB of CUDA packages instead of the local CPU build.
PY := .venv/bin/python
TORCH_VERSION := 2.13.0

.PHONY: setup train test bench sweep clean

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
	$(PY) experiments/penalty_vs_constraint.py $(SWEEP_DIR)

clean:
	rm -rf .venv outputs multirun
