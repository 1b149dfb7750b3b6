"""Learning on the fork (env=fork, docs/fork.md), whose exact optimum is a randomised policy: each
primal-dual method, on its defaults as `python train.py env=fork algo=<method>` runs it, deploys a
policy that is within budget and within 10% of J* = 6.529 by the exact valuation of what it
deployed (no episode noise: the fork's tables give each member's exact return and cost).

The length of each run is the only option set here (shorter than the preset's 400,000 steps, so
that the whole file stays near a minute)."""

import pytest

from cmdp_rl import train
from cmdp_rl.config.run_config import compose_config
from cmdp_rl.run.rundir import load_trained
from lab.studies.fork_policy import members_of, mixture_gap, weights_of

# (method, total_steps): each method's run length here; see docs/constraint_satisfaction.md for
# the same runs over more seeds.
RUNS = [("ppo_lag", 150_000), ("pid_lag", 150_000), ("trpo_lag", 150_000), ("cup", 150_000)]


@pytest.mark.slow
@pytest.mark.parametrize("algo, steps", RUNS, ids=[r[0] for r in RUNS])
def test_deployed_policy_within_budget_and_near_the_optimum(algo, steps, tmp_path, quiet):
    cfg = compose_config(["env=fork", f"algo={algo}", f"total_steps={steps}", "seed=0"])
    assert cfg.deploy.policy == "mixture"  # what deploy.policy=auto deploys for a primal-dual method here
    result = train(cfg, tmp_path, echo=quiet)
    assert result["mixture_feasible"]
    trained = load_trained(tmp_path)
    trained.env.close()
    actor = trained.agent.actor
    gap = mixture_gap(members_of(actor), cfg.env.model(), cfg.env.solve(cfg.algo.cost_limit), weights_of(actor))
    assert gap.costs[0] <= cfg.algo.cost_limit, f"{algo}: exact cost {gap.costs[0]:.4f} over the budget"
    assert gap.ret >= 0.9 * gap.optimum, f"{algo}: exact return {gap.ret:.3f}, J* {gap.optimum:.3f}"
