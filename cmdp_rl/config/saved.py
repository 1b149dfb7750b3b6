"""What a run directory saves, read back: its files by name, its YAML read safely, and a config saved before some
options became nodes (``deploy``, ``algo.multiplier``) brought to today's layout. A run writes these files
(``cmdp_rl/run/``); the reports, comparisons and plots read them (``cmdp_rl/report/``).

::

    config.yaml     the run's resolved config (cmdp_rl.config.run_config.RunConfig), what a resume continues with
    run_info.json   package version, git commit, library versions, command; one entry per resume
    metrics.csv     one row per iteration (cmdp_rl.report.metrics.COLUMNS)
    checkpoint.pt   the last checkpoint (cmdp_rl.run.checkpoint), written atomically
    eval.json       the final evaluation
    error.txt       why the run failed, if it did (train.py; cmdp_rl.report.sweeps reads it back)
    tb/             TensorBoard events, with ``logger=tensorboard``
    wandb/          Weights & Biases files, with ``logger=wandb`` (wandb_id.txt: its run id, for a resume)
    .hydra/         Hydra's record of the command (train.py only)
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from cmdp_rl.config.validation import ConfigError

CHECKPOINT = "checkpoint.pt"
CONFIG = "config.yaml"
METRICS = "metrics.csv"
EVAL = "eval.json"
ERROR = "error.txt"
RUN_INFO = "run_info.json"
TENSORBOARD = "tb"
# A population's directory (cmdp_rl/population/): its composed config and summary beside its CHECKPOINT.
POPULATION_CONFIG = "population.yaml"
POPULATION_SUMMARY = "population.json"
AGENTS_DIR = "agents"  # a population's agents' run directories
# A population's checkpoint before it took CHECKPOINT's name (same layout): still read by a resume.
POPULATION_CHECKPOINT = "population.pt"
HYDRA_DIR = ".hydra"


def read_yaml(path: Path, what: str = "run") -> Any:
    """A YAML file of a run directory, read with YAML's safe loader (plain values only: a Python
    tag, which the full loader would run, is refused in one line)."""
    try:
        return yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        reason = " ".join(str(exc).split())[:200]
        raise ConfigError(f"{what}: {path} is not valid YAML ({reason})") from None


# The flat run options that became the ``deploy`` node, each by its name there.
_DEPLOY_FIELDS = {
    "final_policy": "policy",
    "average_last": "window",
    "mixture_size": "snapshots",
    "mixture_weights": "weights",
    "mixture_episodes": "episodes",
    "mixture_margin": "margin",
}


def flat_keys(config: dict[str, Any], names: dict[str, Any], node: str) -> list[str]:
    """The keys of ``config`` that are flat options of ``node`` (a mapping under ``node`` is the node itself)."""
    return [k for k in config if k in names and not (k == node and isinstance(config[k], dict))]


def into_node(config: dict[str, Any], names: dict[str, Any], node: str, **fixed: Any) -> dict[str, Any]:
    """``config`` with its :func:`flat_keys` keys moved into the node under their names there (None: dropped), and
    ``fixed``; a value the node already holds wins (a flat default added to a config already moved)."""
    flat = flat_keys(config, names, node)
    own = config.get(node) if isinstance(config.get(node), dict) else {}
    out = {k: v for k, v in config.items() if k not in flat}
    out[node] = {**{names[k]: config[k] for k in flat if names[k]}, **fixed, **own}
    return out


def deploy_node(config: Any) -> Any:
    """A config saved with the flat deployment options (``final_policy``, ``average_last``, ``mixture_*``)
    with them as the ``deploy`` node, the same values under their new names; any other config as it is."""
    if not isinstance(config, dict) or not _DEPLOY_FIELDS.keys() & config.keys():
        return config
    return into_node(config, _DEPLOY_FIELDS, "deploy")
