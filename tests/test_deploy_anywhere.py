"""A primal-dual run deploys the best mixture of its snapshots within budget on any env: where the env does
not declare its episodes cheap (EnvOptions.values_snapshots), the valuation is held to a stated share of the
run's steps (config.deploy.valuation_plan), spent on fewer snapshots rather than fewer episodes each."""

import json

import pytest

from cmdp_rl import load_config, train
from cmdp_rl.config.deploy import MIN_VALUED_EPISODES, VALUATION_SHARE, valuation_plan


def nav(**top) -> dict:
    return {"env": {"name": "safe_nav", "task": "PointGoal1", **top.pop("env", {})}, "algo": {"name": "ppo_lag"}, **top}


@pytest.mark.parametrize(
    "total_steps, plan",
    [(10_000, None), (200_000, (1, 20)), (1_000_000, (5, 20)), (2_000_000, (10, 20)), (10_000_000, (16, 62))],
)
def test_the_valuation_plan_fits_the_share_of_a_navigation_run(total_steps, plan):
    cfg = load_config(nav(total_steps=total_steps))
    assert valuation_plan(cfg) == plan
    assert cfg.deploy.policy == ("last" if plan is None else "mixture")
    if plan is not None:
        size, episodes = plan
        assert (cfg.deploy.snapshots, cfg.deploy.episodes) == plan
        assert episodes >= MIN_VALUED_EPISODES and size * episodes * 1000 <= VALUATION_SHARE * total_steps


def test_cheap_envs_keep_their_full_valuation_and_unconstrained_runs_their_last_iterate():
    reach = load_config({"env": {"name": "reach1d"}, "algo": {"name": "ppo_lag"}, "total_steps": 10_000})
    assert (reach.deploy.policy, reach.deploy.snapshots, reach.deploy.episodes) == ("mixture", 16, 100)
    assert load_config(nav(algo={"name": "ppo"}, total_steps=10_000_000)).deploy.policy == "last"
    # a given deploy.policy is the user's: no plan caps it
    given = load_config(nav(deploy={"policy": "mixture"}, total_steps=1_000_000))
    assert (given.deploy.snapshots, given.deploy.episodes) == (16, 100)


@pytest.mark.slow
def test_a_navigation_run_values_its_snapshots_within_the_share_and_says_so(tmp_path):
    lines = []
    cfg = nav(env={"max_steps": 25, "num_envs": 4}, total_steps=12_800, rollout_steps=64, eval_episodes=4)
    cfg["algo"].update(update_epochs=1, num_minibatches=2)
    train(load_config(cfg), tmp_path, echo=lines.append)
    result = json.loads((tmp_path / "eval.json").read_text())
    assert result["final_policy"] == "mixture" and result["mixture_weights"] == "feasible"
    members = result["mixture_member_values"]
    assert len(members) == 2  # 10% of 12,800 steps is 51 episodes of 25 steps: two snapshots of 25 each
    assert all(m["episodes"] >= 25 for m in members)
    # what the valuation cost is stated, and it stays near its share (rounded up to whole episodes per env row)
    assert 0 < result["mixture_valuation_steps"] <= 1.5 * VALUATION_SHARE * 12_800
    assert result["mixture_margin"] == 3.0
    said = [line for line in lines if line.startswith("mixture:")]
    assert said and f"({result['mixture_valuation_steps']:,} env steps)" in said[0]
    assert "deployed policy:" in "\n".join(lines)
