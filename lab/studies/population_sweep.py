"""A Hydra sweep as populations: the jobs of ``python train.py -m +experiment=<name>`` grouped into
one population per algorithm, each job an agent (``experiments/studies/penalty_vs_constraint.py
--population``).

The experiment's ``hydra.sweeper.params`` are read with Hydra's own override parser; the ``algo``
entry (a list of config choices such as ``sweep/ppo_lag``) splits the jobs by algorithm, ``seed``
becomes ``population.grid.seed`` and every other swept key must be a per-agent field
(``cmdp_rl.population.spec.PER_AGENT_FIELDS``). A part whose algorithm the batched program does not
cover (an off-policy one, say) is a population whose agents train one after another (``batched``
False).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import yaml
from hydra.core.override_parser.overrides_parser import OverridesParser

from cmdp_rl.config.run_config import CONFIG_DIR
from cmdp_rl.config.validation import ConfigError
from cmdp_rl.population.spec import PER_AGENT_FIELDS, batched


@dataclass
class SweepPart:
    """The jobs of one algorithm choice as one population (``overrides`` compose its config)."""

    name: str  # the algorithm's name, e.g. ppo_lag
    choice: str | None  # the sweep's algo choice, e.g. sweep/ppo_lag (None: the experiment's default)
    grid: dict[str, list] = field(default_factory=dict)
    batched: bool = True

    def overrides(self, experiment: str, extra: Sequence[str] = ()) -> list[str]:
        """The overrides that compose this part's population config (``population.grid.*``)."""
        out = [f"+experiment={experiment}", *([f"algo={self.choice}"] if self.choice else []), *extra]
        for key, values in self.grid.items():
            out.append(f"population.grid.{key}={_hydra_list(values)}")
        return out


def _hydra_value(v: Any) -> str:
    if isinstance(v, list):
        return "[" + ",".join(_hydra_value(x) for x in v) + "]"
    return repr(v) if isinstance(v, str) else str(v)


def _hydra_list(values: list) -> str:
    return "[" + ",".join(_hydra_value(v) for v in values) + "]"


def sweep_parts(experiment: str) -> list[SweepPart]:
    """The parts of ``configs/experiment/<experiment>.yaml``'s sweep, one per algorithm choice."""
    doc = yaml.safe_load((CONFIG_DIR / "experiment" / f"{experiment}.yaml").read_text())
    params = (((doc or {}).get("hydra") or {}).get("sweeper") or {}).get("params") or {}
    parser = OverridesParser.create()
    grid: dict[str, list] = {}
    choices: list[str | None] = [None]
    for key, value in params.items():
        (override,) = parser.parse_overrides([f"{key}={value}"])
        values = list(override.sweep_iterator()) if override.is_sweep_override() else [override.value()]
        if key == "algo":
            choices = [str(v) for v in values]
            continue
        if key not in PER_AGENT_FIELDS:
            raise ConfigError(
                f"population: the sweep of {experiment} varies {key}, which is not a per-agent field "
                f"(allowed: {list(PER_AGENT_FIELDS)})"
            )
        grid[key] = [_plain(v) for v in values]
    parts = []
    for choice in choices:  # no algo entry: the experiment's own algorithm (checked when composed)
        name = (choice or "default").rsplit("/", 1)[-1]
        parts.append(SweepPart(name, choice, dict(grid), batched=choice is None or batched(name)))
    return parts


def _plain(v: Any) -> Any:
    """Hydra's parsed value as plain Python (lists of numbers, numbers, strings)."""
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    return v


__all__ = ["SweepPart", "sweep_parts"]
