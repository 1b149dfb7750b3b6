"""The safe-RL field's run metrics (Ray, Achiam, Amodei 2019, sec. 5; Safety Gym's ``bench/bench_utils.py``):
the cost rate ``rho_c`` (all costs incurred in training over the env steps so far), and, against an
unconstrained PPO reference trained on the same env for as many steps,
    normalized return          J_r / J_r^PPO
    normalized violation       max(0, J_c - d) / max(eps, J_c^PPO - d),   eps = 1e-6
    normalized cost rate       rho_c / rho_c^PPO
(``J_r``, ``J_c`` the final policy's mean return and cost, ``d`` the budget; blank without a reference). With
K costs they are per constraint, against a reference run's per-cost numbers."""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Optional

import yaml

from cmdp_rl.config.validation import finite, options, require

RunConfig = Any  # cmdp_rl.config.run_config.RunConfig, which imports this module

EPSILON = 1e-6  # Safety Gym's: keeps the violation finite when PPO itself is within the budget
NORMALIZED = ("normalized_return", "normalized_violation", "normalized_cost_rate")


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


def cost_rate(total_cost: float, total_steps: int) -> float:
    return total_cost / total_steps if total_steps else math.nan


def _listed(x: Any, k: int) -> list:
    return list(x) if isinstance(x, (list, tuple)) else [x] * k


def _reference_values(x: Any, k: int) -> list:
    """A reference's per-constraint numbers: a list of K as it is; a single number only for K = 1."""
    ok = len(x) == k if isinstance(x, (list, tuple)) else k == 1
    return _listed(x, 1) if ok else [None] * k


def normalized_scores(
    episode_return: float,
    episode_cost: float | list[float],
    rate: float | list[float],
    cost_limit: float | list[float],
    ref: Reference | None,
) -> dict[str, Any]:
    """The normalized metrics (lists of K for K costs); None where the reference lacks a number or divides by 0."""
    single = not isinstance(episode_cost, (list, tuple))
    if ref is None:
        return dict.fromkeys(NORMALIZED)
    costs = _listed(episode_cost, 1)
    k = len(costs)
    rates, limits = _listed(rate, k), _listed(cost_limit, k)
    ref_costs, ref_rates = _reference_values(ref.episode_cost, k), _reference_values(ref.cost_rate, k)
    violation = [
        None if rc is None else max(0.0, c - d) / max(EPSILON, rc - d) for c, d, rc in zip(costs, limits, ref_costs)
    ]
    cost_rates = [r / rr if rr else None for r, rr in zip(rates, ref_rates)]
    return {
        "normalized_return": episode_return / ref.episode_return if ref.episode_return else None,
        "normalized_violation": violation[0] if single else violation,
        "normalized_cost_rate": cost_rates[0] if single else cost_rates,
    }


def per_constraint_values(row: dict[str, Any], name: str) -> list:
    """``name``'s values in a metrics row or eval.json: its one entry, or its ``name/<cost>`` entries in order."""
    return [row[name]] if name in row else [v for k, v in row.items() if k.startswith(name + "/")]


def _per_constraint_result(result: dict[str, Any], name: str) -> Any:
    """``name`` from an eval.json: its one value, or the list of its ``name/<cost>`` values."""
    return result[name] if name in result else per_constraint_values(result, name) or None


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
