"""The normalised metrics' reference (``reference:``, ``RunConfig.reference``): an unconstrained PPO run trained on
the same env for as many steps, named by its finished run directory or by its numbers (J_r^PPO, J_c^PPO,
rho_c^PPO); :func:`load_reference` reads it for ``report/safety_metrics.normalized_scores``."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Optional

import yaml

from cmdp_rl.config.validation import finite, options, require

RunConfig = Any  # cmdp_rl.config.run_config.RunConfig, which imports this module


@dataclass
class Reference:
    """J_r^PPO, J_c^PPO, rho_c^PPO; any of them may be unknown (None), leaving its metric blank."""

    episode_return: Optional[float] = None
    episode_cost: Optional[float | list[float]] = None  # a list: one per constraint
    cost_rate: Optional[float | list[float]] = None
    source: str = "config"


FiniteOrNull = Optional[Annotated[float, finite()]]
Divisor = Annotated[float, finite(gt=0, description="a positive number (it divides the cost rate)")]


@options
class ReferenceConfig:
    """``reference:``: the normalized metrics' PPO reference, a finished run's directory or its numbers."""

    run: Optional[str] = None
    episode_return: FiniteOrNull = None
    episode_cost: FiniteOrNull = None
    cost_rate: Optional[Divisor] = None

    def check(self, run: RunConfig) -> None:
        numbers = {k: getattr(self, k) for k in ("episode_return", "episode_cost", "cost_rate")}
        if self.run is not None:
            require(
                all(v is None for v in numbers.values()),
                "reference",
                "either reference.run or the reference numbers, not both",
                {"run": self.run, **numbers},
            )
            require(
                (Path(self.run) / "eval.json").is_file() and (Path(self.run) / "config.yaml").is_file(),
                "reference.run",
                "a finished run's directory (holding eval.json and config.yaml)",
                self.run,
            )
            problem = reference_run_problem(self.run, run)
            require(problem is None, "reference.run", f"a usable reference run, but {problem}", self.run)
        require(
            self.episode_return is None or self.episode_return != 0,
            "reference.episode_return",
            "null or a nonzero number (it divides the return)",
            self.episode_return,
        )


def _per_constraint_result(result: dict[str, Any], name: str) -> Any:
    """``name`` from an eval.json: its one value, or the list of its ``name/<cost>`` values (with K > 1 costs, each
    constraint's key carries ``/<cost>``: ``report.metrics.constraint_name``)."""
    return result[name] if name in result else [v for k, v in result.items() if k.startswith(name + "/")] or None


def _reference_run(run: str) -> tuple[dict[str, Any], dict[str, Any]]:
    path = Path(run)
    return json.loads((path / "eval.json").read_text()), yaml.safe_load((path / "config.yaml").read_text())


def reference_run_problem(run: str, cfg: RunConfig) -> str | None:
    """Why ``run`` cannot be this run's reference (a finished run of this version on the same env), or None."""
    try:
        result, ref_cfg = _reference_run(run)
    except (OSError, ValueError, yaml.YAMLError) as exc:
        return f"cannot read its eval.json and config.yaml ({exc})"
    missing = [k for k in ("episode_return", "episode_cost", "cost_rate") if _per_constraint_result(result, k) is None]
    if missing:
        return f"its eval.json has no {missing} (a run from an older version? give the numbers instead)"
    ours = {k: v for k, v in dataclasses.asdict(cfg.env).items() if k != "num_envs"}
    theirs = {k: v for k, v in (ref_cfg.get("env") or {}).items() if k != "num_envs"}
    if ours != theirs:
        return f"it ran another env ({theirs}) than this run ({ours})"
    return None


def load_reference(cfg: RunConfig) -> tuple[Reference | None, list[str]]:
    """The reference ``cfg.reference`` names, and warnings about it worth printing."""
    r = cfg.reference
    if r.run is None:
        if r.episode_return is None and r.episode_cost is None and r.cost_rate is None:
            return None, []
        return Reference(r.episode_return, r.episode_cost, r.cost_rate, "config"), []
    result, ref_cfg = _reference_run(r.run)
    warnings = []
    ref_algo = (ref_cfg.get("algo") or {}).get("name")
    if ref_algo != "ppo":
        warnings.append(f"reference run {r.run} is algo={ref_algo}, not the unconstrained ppo Safety Gym normalizes by")
    if ref_cfg.get("total_steps") != cfg.total_steps:
        warnings.append(
            f"reference run {r.run} trained for {ref_cfg.get('total_steps')} steps, this run for "
            f"{cfg.total_steps}: Safety Gym compares at the same step budget"
        )
    ref = Reference(
        result["episode_return"],
        _per_constraint_result(result, "episode_cost"),
        _per_constraint_result(result, "cost_rate"),
        str(r.run),
    )
    return ref, warnings
