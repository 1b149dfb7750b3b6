"""The constraint-satisfaction study's cases and methods (docs/constraint_satisfaction.md): each a
list of train.py overrides, as a user would type them. The study itself is
``constraint_satisfaction.py``."""

from __future__ import annotations

# The CMDPs with exact optima, as a user would type them (train.py overrides).
# Reach1D's optimum at d = 0.5 is randomised (cross in half the episodes): evaluate the sampled
# policy, over 200 episodes (the mean action of a Gaussian policy either crosses or does not).
REACH1D_EVAL = ["eval_deterministic=false", "eval_episodes=200"]
CASES: dict[str, list[str]] = {
    "reach1d_pass": ["env=reach1d_torch", "env.wall=pass", "algo.cost_limit=0.5", *REACH1D_EVAL],
    "reach1d_block": ["env=reach1d_torch", "algo.cost_limit=1.0", *REACH1D_EVAL],
    "fork": ["env=fork"],
    "fork_k2": ["env=fork", "env.num_costs=2", "algo.cost_limit=[1.0,1.0]"],
    "grid_k2": ["env=grid"],
    "grid_k1": ["env=grid", "env.costs=[hazard_b]", "algo.cost_limit=0.15"],
    "pointgoal1": ["env=safe_nav"],
}

# The multiplier settings compared (algo overrides; the algorithm first).
METHODS: dict[str, list[str]] = {
    "ppo_lag": ["algo=ppo_lag"],
    "ppo_lag/budget": ["algo=ppo_lag", "algo.multiplier.scale=budget"],
    "ppo_lag/optimistic": ["algo=ppo_lag", "algo.multiplier.scale=budget", "algo/multiplier=optimistic"],
    "ppo_lag/regularized": ["algo=ppo_lag", "algo.multiplier.scale=budget", "algo/multiplier=regularized"],
    "ppo_lag/augmented": ["algo=ppo_lag", "algo.multiplier.scale=budget", "algo/multiplier=augmented"],
    "ppo_lag/average": ["algo=ppo_lag", "algo.multiplier.scale=budget", "deploy.policy=average"],
    # The same with a 4x larger dual step (relative units): multiplier.lr = 0.2.
    "ppo_lag/budget-0.2": ["algo=ppo_lag", "algo.multiplier.scale=budget", "algo.multiplier.lr=0.2"],
    "ppo_lag/optimistic-0.2": [
        "algo=ppo_lag",
        "algo.multiplier.scale=budget",
        "algo/multiplier=optimistic",
        "algo.multiplier.lr=0.2",
    ],
    "ppo_lag/augmented-0.2": [
        "algo=ppo_lag",
        "algo.multiplier.scale=budget",
        "algo/multiplier=augmented",
        "algo.multiplier.lr=0.2",
    ],
    "ppo_lag/average-0.2": [
        "algo=ppo_lag",
        "algo.multiplier.scale=budget",
        "algo.multiplier.lr=0.2",
        "deploy.policy=average",
    ],
    # The average over the last half of the iterations instead of the last quarter.
    "ppo_lag/average-0.2-half": [
        "algo=ppo_lag",
        "algo.multiplier.scale=budget",
        "algo.multiplier.lr=0.2",
        "deploy.policy=average",
        "deploy.window=0.5",
    ],
    # deploy.policy=mixture: the last iterates' actors, one drawn per episode (deploy/mixture.py),
    # on the same training as budget-0.2 and optimistic-0.2 (only the deployed policy differs).
    "ppo_lag/mixture": ["algo=ppo_lag", "deploy.policy=mixture"],
    "ppo_lag/mixture-0.2": [
        "algo=ppo_lag",
        "algo.multiplier.scale=budget",
        "algo.multiplier.lr=0.2",
        "deploy.policy=mixture",
    ],
    "ppo_lag/optimistic-0.2-mixture": [
        "algo=ppo_lag",
        "algo.multiplier.scale=budget",
        "algo/multiplier=optimistic",
        "algo.multiplier.lr=0.2",
        "deploy.policy=mixture",
    ],
    # The mixture over the last half of the iterations, 16 members: a window as long as one orbit
    # of the dual-policy loop on the fork (about 40 iterations at multiplier.lr = 0.2).
    "ppo_lag/mixture-0.2-half": [
        "algo=ppo_lag",
        "algo.multiplier.scale=budget",
        "algo.multiplier.lr=0.2",
        "deploy.policy=mixture",
        "deploy.window=0.5",
        "deploy.snapshots=16",
    ],
    # The best mixture of those snapshots within budget on their measured values (mixture_selection.py).
    "ppo_lag/feasible-0.2-half": [
        "algo=ppo_lag",
        "algo.multiplier.scale=budget",
        "algo.multiplier.lr=0.2",
        "deploy.policy=mixture",
        "deploy.window=0.5",
        "deploy.snapshots=16",
        "deploy.weights=feasible",
    ],
    "ppo_lag/optimistic-0.2-feasible-half": [
        "algo=ppo_lag",
        "algo.multiplier.scale=budget",
        "algo/multiplier=optimistic",
        "algo.multiplier.lr=0.2",
        "deploy.policy=mixture",
        "deploy.window=0.5",
        "deploy.snapshots=16",
        "deploy.weights=feasible",
    ],
    "ppo_lag/feasible-half": [
        "algo=ppo_lag",
        "algo.multiplier.scale=budget",
        "deploy.policy=mixture",
        "deploy.window=0.5",
        "deploy.snapshots=16",
        "deploy.weights=feasible",
    ],
    "pid_lag": ["algo=pid_lag"],
    "trpo_lag": ["algo=trpo_lag"],
    "sac_lag": ["algo=sac_lag"],
    "td3_lag": ["algo=td3_lag"],
    "focops": ["algo=focops"],
    "cup": ["algo=cup"],
    "ppo_lag/0.2": ["algo=ppo_lag", "algo.multiplier.lr=0.2"],
    # The dual step in the cost's own units (the default before multiplier.scale: budget).
    "ppo_lag/raw": ["algo=ppo_lag", "algo.multiplier.scale=none"],
    # lambda weighing the standardised advantages (ppo_lag.lagrangian_advantage), with dual steps
    # of 0.05 (the default) and 0.03.
    "ppo_lag/standardized": ["algo=ppo_lag", "algo.advantage_scale=standardized"],
    "ppo_lag/standardized-0.03": ["algo=ppo_lag", "algo.advantage_scale=standardized", "algo.multiplier.lr=0.03"],
    "pid_lag/standardized": ["algo=pid_lag", "algo.advantage_scale=standardized"],
    "trpo_lag/standardized": ["algo=trpo_lag", "algo.advantage_scale=standardized"],
}
