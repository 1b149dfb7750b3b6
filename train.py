"""Train a constrained-RL agent: ``python train.py algo=ppo_lag env=reach1d [overrides]``.

Options are documented in ``configs/``; outputs go to Hydra's run directory. Sweeps are Hydra
multiruns (``-m``), e.g. ``python train.py -m +experiment=penalty_sweep``; see
``configs/experiment/``.
"""

from __future__ import annotations

import sys

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

from cmdp_rl import ConfigError, TrainingDiverged, load_config, train
from cmdp_rl.sweeps import clear_outputs, record_failure


@hydra.main(config_path="configs", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    out_dir = HydraConfig.get().runtime.output_dir
    clear_outputs(out_dir)
    try:
        run_cfg = load_config(OmegaConf.to_container(cfg, resolve=True))
        train(run_cfg, out_dir)
    except Exception as exc:
        record_failure(out_dir, exc)
        if HydraConfig.get().mode == RunMode.MULTIRUN:
            # Raise, never sys.exit, inside a sweep: Hydra then marks only this job failed, lets
            # the others finish (each writes its own directory) and raises once all are done.
            # SystemExit would bypass Hydra's per-job handling and stop the whole sweep.
            raise
        if isinstance(exc, ConfigError):
            print(f"config error: {exc}", file=sys.stderr)
            sys.exit(2)
        if isinstance(exc, TrainingDiverged):
            print(f"training stopped: {exc}", file=sys.stderr)
            sys.exit(3)
        raise


if __name__ == "__main__":
    main()
