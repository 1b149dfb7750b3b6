"""``env.physics=mjwarp`` against ``env.physics=mujoco``: the same task, seed and actions, side by side.

MuJoCo Warp is a different implementation of the same physics (float32, its own solver), so the
two trajectories are close, not equal, and drift apart slowly where contacts and the robot's own
feedback amplify small differences. :func:`compare_physics` steps both over whole episodes with
the same actions (chosen from the ``mujoco`` env's state by ``policy``, so that goals are reached
and hazards entered) and measures how far apart they are, per step and per episode. With
``forced=True`` the ``mujoco`` env's whole state (physics, goals, random streams) is copied into the
``mjwarp`` env before every step, so each step's difference is one step's, not the drift so far:
that is what :data:`TOLERANCE` bounds (tests/test_safe_nav_warp.py asserts it; docs/safe_nav.md).
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import torch

from cmdp_rl.envs.safe_nav.env import SafeNavVecEnv
from cmdp_rl.envs.safe_nav.lidar import LIDAR_BINS

# Per robot: the largest one-step difference (forced=True) of the robot's xy position (m), of a
# reward, of a lidar reading, and of an episode's return; costs and episode ends must be equal. The
# Car's contacts (wheels, chassis) give it rarer, larger one-step differences than the Point's.
TOLERANCE = {"point": (1e-5, 1e-5, 2e-4, 1e-3), "car": (2e-3, 2e-3, 2e-2, 2e-3)}
# Whatever the robot, most steps agree far closer than the largest difference: the median's bound (m).
MEDIAN_POS_TOLERANCE = 1e-6


def compare_physics(
    task: str,
    num_envs: int,
    steps: int,
    policy: Callable[[SafeNavVecEnv, np.random.Generator], np.ndarray],
    seed: int = 11,
    max_steps: int = 0,
    forced: bool = False,
    device: str = "cpu",
) -> dict:
    """Step ``task`` on both physics for ``steps`` steps (``num_envs`` envs each, reset with
    ``seed``); the same actions, ``policy(mujoco_env, rng)``; ``forced``: each step from the
    ``mujoco`` env's state; ``device``: where the ``mjwarp`` env runs (Warp's CPU device, or
    ``cuda``). Returns the largest differences (robot position, lidar, reward per step; episode
    return and cost sums) and what happened."""
    ref = SafeNavVecEnv(task, num_envs, max_steps)
    warp = SafeNavVecEnv(task, num_envs, max_steps, device=device, physics="mjwarp")
    ref.reset(seed=seed)
    warp.reset(seed=seed)
    rng = np.random.default_rng(0)
    lidar_from = ref.obs_dim - LIDAR_BINS * ref.logic.lidar_groups
    out = {"task": task, "num_envs": num_envs, "steps": steps, "forced": forced, "device": device}
    out.update({"pos": [], "lidar": [], "reward": []})
    sums = {k: np.zeros((2, num_envs)) for k in ("return", "cost")}
    episodes = {"return": [[], []], "cost": [[], []]}
    counts = {"cost_mismatch": 0, "end_mismatch": 0, "cost_steps": 0, "goals": 0, "episode_ends": 0}
    for _ in range(steps):
        action = torch.from_numpy(policy(ref, rng))
        action_warp = action.to(warp.device)
        if forced:  # the same integration state, layouts, goals and random streams: one step apart
            state = ref.state_dict()
            warp.load_state_dict({**state, "physics": "mjwarp"})
        a, b = ref.step(action), warp.step(action_warp)
        pos_ref = ref.worlds.gather(range(num_envs))["agent_pos"][:, :2]
        pos_warp = warp.worlds.gather(slice(None))["agent_pos"][:, :2].double().cpu().numpy()
        out["pos"].append(float(np.abs(pos_ref - pos_warp).max()))
        lidar = (a.next_obs[:, lidar_from:] - b.next_obs[:, lidar_from:].cpu()).abs().max()
        out["lidar"].append(float(lidar))
        out["reward"].append(float((a.reward - b.reward.cpu()).abs().max()))
        counts["cost_mismatch"] += int((a.cost != b.cost.cpu()).sum())
        ends = (a.terminated | a.truncated, b.terminated | b.truncated)
        counts["end_mismatch"] += int((ends[0] != ends[1].cpu()).sum())
        counts["cost_steps"] += int(a.cost.sum())
        counts["goals"] += int((a.reward > 0.5).sum())
        for k, s in enumerate((a, b)):
            sums["return"][k] += s.reward[:, 0].double().cpu().numpy()
            sums["cost"][k] += s.cost[:, 0].double().cpu().numpy()
            for i in np.flatnonzero((s.terminated | s.truncated)[:, 0].cpu().numpy()):
                for name in ("return", "cost"):
                    episodes[name][k].append(float(sums[name][k, i]))
                    sums[name][k, i] = 0.0
        counts["episode_ends"] += int(ends[0].sum())
    out.update(counts)
    out["overflow"] = int(np.count_nonzero(warp.worlds.data.overflow.numpy()))
    for name in ("return", "cost"):
        pairs = list(zip(*episodes[name]))
        out[f"episode_{name}s"] = pairs
        out[f"{name}_max_diff"] = max((abs(x - y) for x, y in pairs), default=0.0)
    for key in ("pos", "lidar", "reward"):
        series = np.array(out.pop(key))
        out[f"{key}_max_diff"] = float(series.max())
        out[f"{key}_max_diff_first_100"] = float(series[:100].max())
        out[f"{key}_median_diff"] = float(np.median(series))
    ref.close()
    warp.close()
    return out


def tolerance_breaches(out: dict, robot: str) -> list[str]:
    """What of a ``compare_physics(forced=True)`` result lies outside :data:`TOLERANCE` for
    ``robot`` (``point`` or ``car``), one line each; empty: within every tolerance."""
    pos, reward, lidar, ret = TOLERANCE[robot]
    bounds = [
        ("pos_max_diff", pos),
        ("pos_median_diff", MEDIAN_POS_TOLERANCE),
        ("reward_max_diff", reward),
        ("lidar_max_diff", lidar),
        ("return_max_diff", ret),
    ]
    breaches = [f"{key} {out[key]:.3g} >= {bound:g}" for key, bound in bounds if not out[key] < bound]
    breaches += [
        f"{key} {out[key]} != 0" for key in ("cost_mismatch", "end_mismatch", "cost_max_diff", "overflow") if out[key]
    ]
    return breaches


__all__ = ["MEDIAN_POS_TOLERANCE", "TOLERANCE", "compare_physics", "tolerance_breaches"]
