"""Train a constrained-RL agent: ``python train.py algo=ppo_lag env=reach1d [overrides]``.

Options are documented in ``configs/``; outputs go to Hydra's run directory.
"""

from __future__ import annotations

import sys

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from cmdp_rl import ConfigError, TrainingDiverged, load_config, train


@hydra.main(config_path="configs", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    try:
        run_cfg = load_config(OmegaConf.to_container(cfg, resolve=True))
    except ConfigError as exc:
        print(f"config error: {exc}", file=sys.stderr)
        sys.exit(2)
    try:
        train(run_cfg, HydraConfig.get().runtime.output_dir)
    except TrainingDiverged as exc:
        print(f"training stopped: {exc}", file=sys.stderr)
        sys.exit(3)


if __name__ == "__main__":
    main()
