"""Train a constrained-RL agent: ``python train.py algo=ppo_lag env=reach1d [overrides]``.

Options are documented in ``configs/``; outputs go to Hydra's run directory.
``python train.py resume=<run dir> [total_steps=...]`` continues that run from its last checkpoint,
in that directory, with the run's own config (see ``cmdp_rl/resume.py`` for what may change).
"""

from __future__ import annotations

import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.core.override_parser.overrides_parser import OverridesParser
from omegaconf import DictConfig, OmegaConf

from cmdp_rl import ConfigError, TrainingDiverged, load_config, train
from cmdp_rl.checkpoint import CheckpointError
from cmdp_rl.resume import resume_config
from cmdp_rl.rundir import CHECKPOINT



def _if_resumable(resume: str | None, then: str, otherwise: str) -> str:
    """For `hydra.run.dir` and `hydra.output_subdir` in configs/config.yaml: a resumed run writes
    into its own directory, and Hydra's record of the resume command goes beside the original one.
    Only a directory with a checkpoint counts, so a mistyped path is reported, not created."""
    return then if resume and (Path(resume) / CHECKPOINT).is_file() else otherwise


OmegaConf.register_new_resolver("cmdp.if_resumable", _if_resumable)


@hydra.main(config_path="configs", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    raw = OmegaConf.to_container(cfg, resolve=True)
    try:
        if raw.get("resume"):
            overrides = OverridesParser.create().parse_overrides(list(HydraConfig.get().overrides.task))
            run_cfg = resume_config(raw["resume"], raw, [o.key_or_group for o in overrides])
        else:
            run_cfg = load_config(raw)
    except ConfigError as exc:
        print(f"config error: {exc}", file=sys.stderr)
        sys.exit(2)
    except CheckpointError as exc:
        print(f"cannot resume: {exc}", file=sys.stderr)
        sys.exit(2)
    try:
        # A resumed run writes into its own directory, whatever hydra.run.dir says.
        train(run_cfg, None if run_cfg.resume else HydraConfig.get().runtime.output_dir)
    except CheckpointError as exc:
        print(f"cannot resume: {exc}", file=sys.stderr)
        sys.exit(2)
    except TrainingDiverged as exc:
        print(f"training stopped: {exc}", file=sys.stderr)
        sys.exit(3)


if __name__ == "__main__":
    main()
