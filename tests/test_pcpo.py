"""PCPO (Yang et al. 2020): the projected step on hand-chosen g, b, c, H, and a short learning run."""

import csv
import math

import pytest
import torch
from helpers.runs import RANDOM_RETURN

from cmdp_rl.algos.trust_region.pcpo import projected_step
from cmdp_rl.config.run_config import compose_config
from cmdp_rl.run.trainer import train

H = torch.tensor([[2.0, 0.5], [0.5, 1.0]], dtype=torch.float64)
G = torch.tensor([1.0, 0.0], dtype=torch.float64)
B = torch.tensor([1.0, 1.0], dtype=torch.float64)
DELTA = 0.02


def _solve(v):
    return torch.linalg.solve(H, v)


def _reward_step():
    """The TRPO step by hand: H^-1 g = (1, -0.5) / 1.75, g^T H^-1 g = 1 / 1.75,
    x_r = sqrt(2 delta * 1.75) (1, -0.5) / 1.75."""
    return math.sqrt(2 * DELTA * 1.75) * torch.tensor([1.0, -0.5], dtype=torch.float64) / 1.75


@pytest.mark.parametrize("projection", ["kl", "l2"])
def test_projected_step_satisfies_the_linearised_constraint(projection):
    x_r = _reward_step()
    assert 0.5 * x_r @ H @ x_r == pytest.approx(DELTA)  # the reward step is on the trust region's boundary
    # b^T x_r = 0.5 * sqrt(0.07) / 1.75 ~ 0.0756: with c = 0.05 the reward step breaks c + b^T x <= 0.
    c = 0.05
    assert c + B @ x_r > 0.1
    x, coef = projected_step(G, B, c, DELTA, _solve, projection)
    assert coef > 0
    assert c + B @ x == pytest.approx(0.0, abs=1e-12)  # on the constraint's boundary
    # The correction is along L^-1 b: H^-1 b = (0.5, 1.5) / 1.75 for kl, b for l2.
    direction = torch.tensor([0.5, 1.5], dtype=torch.float64) / 1.75 if projection == "kl" else B
    correction = x_r - x
    assert abs(correction[0] * direction[1] - correction[1] * direction[0]) < 1e-12
    # It is the closest feasible point in the metric L: any other point on the boundary is farther.
    metric = H if projection == "kl" else torch.eye(2, dtype=torch.float64)
    along = torch.tensor([1.0, -1.0], dtype=torch.float64)  # b^T along = 0: stays on the boundary
    for t in (-0.1, -0.01, 0.01, 0.1):
        y = x + t * along
        assert (y - x_r) @ metric @ (y - x_r) > (x - x_r) @ metric @ (x - x_r)


@pytest.mark.parametrize("projection", ["kl", "l2"])
def test_projected_step_from_an_infeasible_iterate_lands_on_the_constraint(projection):
    c = 0.5  # far over budget: the projection must also undo part of the reward step and more
    x, coef = projected_step(G, B, c, DELTA, _solve, projection)
    assert c + B @ x == pytest.approx(0.0, abs=1e-12) and B @ x < 0


@pytest.mark.parametrize("projection", ["kl", "l2"])
def test_projection_leaves_a_feasible_reward_step_alone(projection):
    x_r = _reward_step()
    for c in (-0.2, -(B @ x_r).item()):  # well inside, and exactly on the boundary
        x, coef = projected_step(G, B, c, DELTA, _solve, projection)
        assert coef == 0.0 and torch.allclose(x, x_r, rtol=0, atol=1e-15)


@pytest.mark.slow  # a learning run (pyproject: markers)
def test_pcpo_learns_reach1d_then_returns_within_budget(tmp_path):
    """Reach1D with the passable wall, budget 0.5 (helpers.runs.RANDOM_RETURN: a random policy's return)."""
    cfg = compose_config(
        [
            "algo=pcpo",
            "env=reach1d_torch",
            "env.wall=pass",
            "algo.cost_limit=0.5",
            "total_steps=262144",
            "seed=0",
            "eval_episodes=2",
        ]
    )
    train(cfg, out_dir=tmp_path, echo=lambda s: None)
    with open(tmp_path / "metrics.csv") as f:
        rows = list(csv.DictReader(f))
    returns = [float(r["episode_return"]) for r in rows]
    costs = [float(r["episode_cost"]) for r in rows]
    projected = [float(r["projection_coef"]) > 0 for r in rows]
    assert len(rows) == 8
    assert max(returns) > 2 * RANDOM_RETURN  # it learned to reach the goal (measured: 1.40)
    # The projection acts exactly while over budget or about to be (measured: iterations 3-6) ...
    assert any(projected) and not projected[0]
    assert costs[-1] <= 0.5  # ... and brings the cost back within budget (measured: 0.016)
