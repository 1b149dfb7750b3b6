"""The exact reference of a penalty-versus-constraint study on Reach1D, and the seed exercise's
answers derived from it.

The penalty-optimal plans come from dynamic programming on the env's true-state dynamics
(``lab.studies.reach1d_thresholds``), for the env and discounts the runs used; nothing is learned. This
module is a :class:`lab.studies.penalty_constraint.Reference` and writes ``answers.md``: (a)
a penalty under which the optimal policy still collides, (b) why no single λ enforces a budget.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cmdp_rl.envs.reach1d.task import Reach1DConfig
from cmdp_rl.report.sweeps import RunRecord
from lab.studies.penalty_constraint import budget_markdown, penalty_markdown, start_label
from lab.studies.reach1d_thresholds import CrossingThresholds, closed_form_threshold, crossing_thresholds

SEED_START = 0.1  # the seed exercise's start state


@dataclass
class Reach1DReference:
    env: Reach1DConfig
    gamma: float
    cost_gamma: float
    thresholds: CrossingThresholds
    starts: dict[str, Any] = field(default_factory=dict)  # label -> env.start value
    mixed_envs: list[str] = field(default_factory=list)  # runs whose env differs beyond the start

    def predicted_cost(self, start_lbl: str, penalty: float) -> float:
        return float(self.thresholds.expected_cost(self.starts[start_lbl], penalty)[0])

    def cost_curve(self, start_lbl: str, penalties: np.ndarray) -> np.ndarray:
        return self.thresholds.expected_cost(self.starts[start_lbl], penalties)

    def unconstrained_cost(self, start_lbl: str) -> float:
        """Expected crossings of the reward-optimal plan (lambda = 0), the most a budget can bind."""
        return self.predicted_cost(start_lbl, 0.0)

    def penalty_marker(self) -> tuple[float, str] | None:
        """λ* from the seed's start, below which the penalty-optimal plan crosses (wall=pass)."""
        if self.env.wall != "pass":
            return None
        lam_star = self.thresholds.at(SEED_START)
        return lam_star, f"λ* = {lam_star:.3f}"


def reach1d_reference(records: list[RunRecord]) -> Reach1DReference | None:
    """The DP reference for the env the runs used (the first finished run's env; a sweep over env
    parameters other than the start would need one reference per env and is reported as such)."""
    configs = [r for r in records if isinstance(r.config.get("env"), dict)]
    if not configs:
        return None
    first = configs[0]
    env_fields = {f.name for f in dataclasses.fields(Reach1DConfig)}
    env = Reach1DConfig(**{k: v for k, v in first.config["env"].items() if k in env_fields})
    gamma = float(first.get("algo.gamma", 0.99))
    cost_gamma = float(first.get("algo.cost_gamma", gamma))
    reference = Reach1DReference(env, gamma, cost_gamma, crossing_thresholds(env, gamma, cost_gamma))
    for r in configs:
        start = r.config["env"].get("start")
        reference.starts.setdefault(start_label(start), start)
        if {k: v for k, v in r.config["env"].items() if k != "start"} != {
            k: v for k, v in first.config["env"].items() if k != "start"
        }:
            reference.mixed_envs.append(str(r.path))
    return reference


def answers_markdown(reference: Reach1DReference | None, rows: list[dict[str, Any]]) -> str:
    """The exercise's answers from the env's parameters, checked against the table's ``rows``."""
    if reference is None:
        return "No run has a readable config: nothing to analyse.\n"
    e, g = reference.env, reference.gamma
    th = reference.thresholds
    out = ["# Penalty versus constraint: answers from the env's parameters\n"]
    out.append(
        f"Env: wall={e.wall}, wall_x={e.wall_x}, goal={e.goal}, max_steps={e.max_steps}; "
        f"gamma={g}, cost_gamma={reference.cost_gamma}. Exact plans on the true state "
        "(no sensor noise), positions on a 0.001 grid (`lab/studies/reach1d_thresholds.py`).\n"
    )
    if reference.mixed_envs:
        out.append(
            f"Warning: {len(reference.mixed_envs)} runs used other env parameters than the first "
            f"(e.g. {reference.mixed_envs[0]}); the analysis below is for the first run's env.\n"
        )
    if e.wall != "pass":
        out.append(
            "With wall=block a crossing move is cancelled: crossing never pays, for any "
            "lambda >= 0, so there is no threshold to find.\n"
        )
    out.append("## (a) A penalty under which the optimal policy still collides\n")
    text = (
        f"From the seed's start x0 = {SEED_START} the penalty-optimal policy crosses the wall for every "
        f"lambda < lambda* = {th.at(SEED_START):.4f} (DP)"
    )
    if e.wall == "pass" and reference.cost_gamma == g:
        text += (
            f"; by hand, lambda* = 0.1 (1 + γ + γ² + γ³) + γ³ = {closed_form_threshold(e, g):.4f} for γ = {g}: "
            "walking to the wall is worth the same whether or not it then crosses, so the choice is made at the "
            "wall: cross (4 moves of 0.1 reach the goal band, 0.4 of shaped progress with the +1 "
            "bonus on the 4th, and the crossing cost 1 is paid on the first of them, undiscounted) "
            "or stop (worth 0). Undiscounted (γ → 1) lambda* = 0.4 + 1 = 1.4: the whole "
            "trajectory earns 0.8 + 1 = 1.8 − λ against 0.4 for stopping at the wall"
        )
    text += (
        ". So for example lambda = 1 leaves the optimal policy colliding once per episode: "
        "the goal bonus and the progress beyond the wall outweigh the penalty. Assumptions: the "
        "true state is known (the agent only sees it with noise sigma = 0.02, which costs a "
        "margin near the wall), the cost is discounted as the reward (cost_gamma = gamma), "
        "and the strict crossing test's float edge (landing exactly on the wall) is closed."
    )
    out += [text, ""]
    out += penalty_markdown(rows)
    out.append("## (b) Why no single lambda enforces 'at most d collisions in expectation'\n")
    for lbl, start in reference.starts.items():
        jumps = th.jumps(start)
        desc = ", ".join(f"a drop of {p:.3f} at λ = {lam:.4f}" for lam, p in jumps) or "no jump (never crosses)"
        out.append(
            f"- {lbl}: expected crossings of the penalty-optimal policy = "
            f"{reference.unconstrained_cost(lbl):.3f} for small λ; {desc}; 0 beyond."
        )
    out.append("")
    left = th.threshold[th.x < e.wall_x]
    if left.size and e.wall == "pass":
        out.append(
            f"Per-start thresholds: every start left of the wall has the same λ*(x0) = "
            f"{left.min():.4f}"
            + (f" to {left.max():.4f}" if left.max() - left.min() > 1e-9 else "")
            + "; starts at or beyond the wall never cross (λ* = 0). "
            "For a fixed λ the penalized problem is an ordinary MDP whose optimal policy is "
            "deterministic: from each start it crosses or it does not. Its expected cost is "
            "therefore a step function of λ, jumping by the probability mass of the starts whose "
            "threshold λ passes. A budget d strictly between two levels of that step function "
            "(here 0 < d < P(x0 < wall)) is met with equality by no λ: a λ below the threshold "
            "gives too many crossings, one above gives none and throws away the reward a budget "
            "d would allow. The constrained optimum crosses with probability d / P(x0 < wall) "
            "(a stochastic policy, optimal for the Lagrangian only at λ = λ* exactly, where "
            "crossing and stopping tie), and which mixture is right depends on the budget and on "
            "ρ0. That λ and mixture are found by adapting λ: dual ascent raises λ while J_c > d "
            "and lowers it while J_c < d, so it settles at the tie, where the policy's mixing "
            "makes J_c = d on average. A hand-set λ would have to hit the tie exactly, and a "
            "different ρ0 (or budget) moves the required mixture."
        )
    out += budget_markdown(rows)
    return "\n".join(out) + "\n"
