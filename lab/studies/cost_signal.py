"""What a trained run's cost side knows (issue 50's questions, docs/constraint_satisfaction.md): how well each
critic predicts the discounted return it is trained for, how long a parked episode lasts, and how much the
policy still explores inside a hazard.

    python -m lab.studies.cost_signal RUN_DIR [--episodes-per-env 2] [--envs 16] [--deployed]

On fresh episodes of the run's env with sampled actions of its last iterate (``--deployed``: of the policy
it deployed), at every step t of the first ``HEAD`` steps of each episode:

- each critic's explained variance ``1 - Var(G - V) / Var(G)``, G the realised discounted sum from t to the
  episode's end (its tail past ``HEAD`` weighs at most gamma**(T - HEAD): 0.05 at T = 1000, gamma 0.99);
- the same for the one-step TD error's sign: how often ``c_t + gamma V_c(s') - V_c(s)`` and the realised
  ``G_c(t) - V_c(s_t)`` agree in sign where a cost is incurred within the GAE horizon;
- per episode, the longest run of consecutive costly steps ("parked": over 100), the cost, the return;
- the policy's standard deviation and its mean action's norm on costly steps and elsewhere.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

HEAD = 700  # steps of each episode the critics are judged on


def discounted_to_go(x: torch.Tensor, gamma: float) -> torch.Tensor:
    """``G_t = sum_k gamma^k x_{t+k}`` along the last axis of ``[N, T]`` (one whole episode per row)."""
    out = torch.zeros_like(x)
    running = torch.zeros_like(x[:, 0])
    for t in range(x.shape[1] - 1, -1, -1):
        running = x[:, t] + gamma * running
        out[:, t] = running
    return out


def explained_variance(target: torch.Tensor, value: torch.Tensor) -> float:
    return (1.0 - (target - value).var() / target.var().clamp_min(1e-12)).item()


def longest_run(flags: torch.Tensor) -> torch.Tensor:
    """The longest run of consecutive true entries of each row of ``[N, T]``."""
    best = torch.zeros(flags.shape[0], dtype=torch.long)
    current = torch.zeros_like(best)
    for t in range(flags.shape[1]):
        current = torch.where(flags[:, t], current + 1, torch.zeros_like(current))
        best = torch.maximum(best, current)
    return best


def diagnose(run_dir: Path, envs: int, episodes_per_env: int, deployed: bool) -> dict:
    import cmdp_rl.run.rundir as rundir
    from cmdp_rl.rollout import keys
    from cmdp_rl.rollout.collector import Collector

    if not deployed:  # the last iterate (the checkpoint's networks), whose critics were trained beside it
        rundir.deploy_saved = lambda *a, **k: None
    trained = rundir.load_trained(run_dir, num_envs=envs)
    cfg, env, agent = trained.cfg, trained.env, trained.agent
    steps = cfg.env.episode_steps()
    collector = Collector(env, agent, steps, seed=cfg.seed + 77_777)
    gamma, cost_gamma = cfg.algo.gamma, cfg.algo.cost_gamma
    rows = []
    for _ in range(episodes_per_env):
        batch = collector.collect()
        nxt = batch.get(keys.NEXT)
        reward, cost = nxt.get(keys.REWARD)[..., 0], nxt.get(keys.COST)[..., 0]
        v_r, _ = agent.rollout_values(batch, "reward")
        v_c, next_v_c = agent.rollout_values(batch, "cost")
        with torch.no_grad():
            dist = agent.dist(agent.training_units({k: batch.get(k) for k in agent.in_keys if k in batch.keys()}))
        scale = dist.base_dist.scale if hasattr(dist, "base_dist") else dist.stddev
        rows.append(
            {
                "reward": reward,
                "cost": cost,
                "v_r": v_r[..., 0],
                "v_c": v_c[..., 0],
                "td_c": cost + cost_gamma * next_v_c[..., 0] - v_c[..., 0],
                "std": scale.reshape(envs, steps, -1).mean(-1),
                "action": batch.get(keys.ACTION).norm(dim=-1),
            }
        )
    data = {k: torch.cat([r[k] for r in rows]) for k in rows[0]}
    g_r = discounted_to_go(data["reward"], gamma)[:, :HEAD]
    g_c = discounted_to_go(data["cost"], cost_gamma)[:, :HEAD]
    costly = data["cost"] > 0
    soon = discounted_to_go(costly.float(), 0.95 * cost_gamma)[:, :HEAD] > 0.05  # a cost within GAE's horizon
    residual = g_c - data["v_c"][:, :HEAD]
    agree = (torch.sign(data["td_c"][:, :HEAD]) == torch.sign(residual))[soon].float().mean().item()
    streak = longest_run(costly)
    episode_cost, episode_return = data["cost"].sum(1), data["reward"].sum(1)
    return {
        "run": str(run_dir),
        "iteration": trained.iteration,
        "episodes": int(data["cost"].shape[0]),
        "episode_return": episode_return.mean().item(),
        "episode_cost": episode_cost.mean().item(),
        "explained_variance_reward": explained_variance(g_r, data["v_r"][:, :HEAD]),
        "explained_variance_cost": explained_variance(g_c, data["v_c"][:, :HEAD]),
        "cost_value_mean": data["v_c"].mean().item(),
        "cost_to_go_mean": g_c.mean().item(),
        "td_sign_agrees_near_cost": agree,
        "longest_costly_run_max": int(streak.max()),
        "parked_episodes": int((streak > 100).sum()),
        "episode_cost_max": episode_cost.max().item(),
        "std_costly": data["std"][costly].mean().item() if costly.any() else None,
        "std_elsewhere": data["std"][~costly].mean().item(),
        "action_norm_costly": data["action"][costly].mean().item() if costly.any() else None,
        "action_norm_elsewhere": data["action"][~costly].mean().item(),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", nargs="+", type=Path)
    parser.add_argument("--envs", type=int, default=16)
    parser.add_argument("--episodes-per-env", type=int, default=2)
    parser.add_argument("--deployed", action="store_true", help="the deployed policy instead of the last iterate")
    args = parser.parse_args(argv)
    for run in args.run:
        print(json.dumps(diagnose(run, args.envs, args.episodes_per_env, args.deployed)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
