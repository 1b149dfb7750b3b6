"""The PPO-family update of every agent at once (ppo, penalty, ppo_lag, pid_lag).

The arithmetic is ``algos/ppo.py``'s, per agent, on ``[P, rows, ...]`` tensors: torchrl's GAE
(``advantages.TwinGAE``) on the whole ``[P N, T]`` batch (its recursion runs along time, row by
row), each agent's J_c estimate and multiplier from its own single-run algorithm object
(``EpisodeCostEstimate``, ``lagrange.DualAscent`` / ``PIDLagrangian``: a few Python numbers per
agent and iteration), the clipped surrogate (Schulman et al., 2017, eq. 7) and the critics' MSE per
agent. Everything that is not elementwise is per agent: advantage normalisation (moments over
each agent's rows), the minibatch permutations (each agent's generator, in its single run's order),
gradient-norm clipping (``StackedParams.clip_grad_norm_``). The per-agent losses are summed before
one backward pass: agents share no parameter, so each agent's gradient is its own loss's.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import torch
from tensordict import TensorDictBase

from cmdp_rl import keys
from cmdp_rl.advantages import TwinGAE
from cmdp_rl.algos.base import TrainingDiverged
from cmdp_rl.algos.ppo import STATS, clipped_gain, logged_multiplier
from cmdp_rl.config import RunConfig
from cmdp_rl.population.agent import PopulationAgent
from cmdp_rl.population.params import StackedAdam

UNIT_KEYS = (keys.OBS, keys.ACTION, keys.LOG_PROB, keys.POLICY_ADVANTAGE, keys.VALUE_TARGET, keys.COST_VALUE_TARGET)


class PopulationPPO:
    """``algos`` are the agents' single-run algorithm objects: they keep each agent's J_c window
    and multiplier (and give the single-run checkpoint its layout); the networks' arithmetic is here."""

    def __init__(
        self, cfgs: Sequence[RunConfig], algos: Sequence[Any], agent: PopulationAgent, envs_per_agent: int
    ) -> None:
        first = cfgs[0].algo
        self.name = first.name
        self.cfg = first  # shared options: discounts, epochs, minibatches, clip, max_grad_norm
        self.algos = list(algos)
        self.agent = agent
        self.n = envs_per_agent
        self.gae = TwinGAE(first.gamma, first.cost_gamma, first.gae_lambda)
        self.log_clip = (math.log1p(-first.clip_epsilon), math.log1p(first.clip_epsilon))
        self.entropy_coef = torch.tensor(
            [c.algo.entropy_coef for c in cfgs], dtype=torch.float32, device=agent.actor.flat.device
        )
        self.actor_opt = StackedAdam(agent.actor.flat, [c.algo.lr for c in cfgs])
        self.critic_opt = StackedAdam(agent.critics.flat, [c.algo.critic_lr for c in cfgs])

    def multipliers(self) -> list[list[float]]:
        """Each agent's lambda in force, one per constraint (0 for PPO)."""
        if self.name == "penalty":
            return [a.penalties for a in self.algos]
        if self.name in ("ppo_lag", "pid_lag"):
            return [a.multiplier.values for a in self.algos]
        return [[0.0] for _ in self.algos]

    def _policy_advantage(self, batch: TensorDictBase) -> torch.Tensor:
        """``PPO.policy_advantage`` of each agent's rows (K = 1: the env has one cost)."""
        adv = batch.get(keys.ADVANTAGE)
        if self.name == "ppo":
            return adv
        lams = [m[0] for m in self.multipliers()]
        per_row = torch.tensor(lams, dtype=torch.float32, device=adv.device).repeat_interleave(self.n).view(-1, 1, 1)
        adv = adv - per_row * batch.get(keys.COST_ADVANTAGE)
        if self.name == "penalty":
            return adv
        # (A_r - lambda A_c) / (1 + lambda), the sum taken in float64 as the single run's Python float.
        scale = torch.tensor([1.0 + lam for lam in lams], dtype=torch.float64).to(torch.float32)
        return adv / scale.to(adv.device).repeat_interleave(self.n).view(-1, 1, 1)

    def update(self, batch: TensorDictBase) -> list[dict[str, Any]]:
        """One iteration for every agent on the ``[P N, T]`` batch; each agent's logged statistics."""
        cfg, P, agent = self.cfg, self.agent.num_agents, self.agent
        self.gae(batch, agent)
        for i, algo in enumerate(self.algos):  # J_c and the multiplier, before the policy update
            algo.update_multiplier(algo.episode_cost.update(batch[i * self.n : (i + 1) * self.n]))
        adv = self._policy_advantage(batch)
        if cfg.normalize_advantage:
            a = adv.reshape(P, -1)
            adv = ((a - a.mean(1, keepdim=True)) / (a.std(1, keepdim=True) + 1e-8)).reshape(adv.shape)
        batch.set(keys.POLICY_ADVANTAGE, adv)
        # Training units per agent: [P, N T, ...].
        data = {k: batch.get(k).reshape(P, -1, *batch.get(k).shape[2:]) for k in UNIT_KEYS}
        total = next(iter(data.values())).shape[1]
        size = total // cfg.num_minibatches
        rows = torch.arange(P, device=adv.device).unsqueeze(1)
        sums: dict[str, torch.Tensor] = {}
        steps = 0
        for _ in range(cfg.update_epochs):
            # One permutation per agent per epoch, from its own generator (algos/minibatch.py's order).
            perm = torch.stack([torch.randperm(total, generator=g, device=g.device) for g in agent.generators])
            shuffled = {k: v[rows, perm] for k, v in data.items()}
            for j in range(cfg.num_minibatches):
                mb = {k: v[:, j * size : (j + 1) * size] for k, v in shuffled.items()}
                stats = self._step(mb)
                sums = {k: sums[k] + v if k in sums else v for k, v in stats.items()}
                steps += 1
        means = (torch.stack([sums[k] for k in STATS]) / steps).tolist()  # [stats, P]: one host sync
        lams = self.multipliers()
        out = []
        for i in range(P):
            stats = {k: means[s][i] for s, k in enumerate(STATS)}
            for k, v in stats.items():
                if not math.isfinite(v):
                    raise TrainingDiverged(f"agent {i}: {k} is {v}: training diverged")
            stats["lagrange_multiplier"] = logged_multiplier(lams[i])
            out.append(stats)
        for name, stacked in (("actor", agent.actor), ("critics", agent.critics)):
            bad = (~torch.isfinite(stacked.flat).all(1)).nonzero().flatten().tolist()
            if bad:
                raise TrainingDiverged(f"agent {bad[0]}: a parameter of the {name} is not finite after the update")
        return out

    def _step(self, mb: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """One minibatch step of every agent: ``PPO.policy_loss`` and the critics' regression per
        agent, one backward, per-agent clipping, Adam. Returns each statistic as ``[P]``, detached."""
        agent = self.agent
        dist, value, cost_value = agent.training_pass(mb[keys.OBS])
        log_prob = dist.log_prob(mb[keys.ACTION])
        old_log_prob = mb[keys.LOG_PROB]
        adv = mb[keys.POLICY_ADVANTAGE]
        gain, log_ratio, log_ratio_clip = clipped_gain(log_prob, old_log_prob, adv, self.log_clip)
        entropy = dist.entropy().mean(1)
        loss_pi = -gain.mean((1, 2)) - self.entropy_coef * entropy
        loss_v = (value - mb[keys.VALUE_TARGET]).pow(2).mean((1, 2))
        loss_vc = (cost_value - mb[keys.COST_VALUE_TARGET]).pow(2).mean((1, 2))
        with torch.no_grad():
            kl = (old_log_prob - log_prob).mean(1)
            clip_fraction = (log_ratio_clip != log_ratio).float().mean((1, 2))
        self.actor_opt.zero_grad()
        self.critic_opt.zero_grad()
        (loss_pi.sum() + loss_v.sum() + loss_vc.sum()).backward()
        agent.actor.clip_grad_norm_(self.cfg.max_grad_norm)
        agent.critics.clip_grad_norm_(self.cfg.max_grad_norm)
        self.actor_opt.step()
        self.critic_opt.step()
        return {
            "loss_pi": loss_pi.detach(),
            "loss_v": loss_v.detach(),
            "loss_vc": loss_vc.detach(),
            "entropy": entropy.detach(),
            "kl": kl,
            "clip_fraction": clip_fraction,
        }

    def state_dict(self) -> dict:
        return {
            "actor_opt": self.actor_opt.state_dict(),
            "critic_opt": self.critic_opt.state_dict(),
            "algos": [
                {
                    "episode_cost": a.episode_cost.state_dict(),
                    **({"multiplier": a.multiplier.state_dict()} if hasattr(a, "multiplier") else {}),
                }
                for a in self.algos
            ],
        }

    def load_state_dict(self, state: dict) -> None:
        self.actor_opt.load_state_dict(state["actor_opt"])
        self.critic_opt.load_state_dict(state["critic_opt"])
        for a, s in zip(self.algos, state["algos"]):
            a.episode_cost.load_state_dict(s["episode_cost"])
            if "multiplier" in s:
                a.multiplier.load_state_dict(s["multiplier"])


__all__ = ["PopulationPPO"]
