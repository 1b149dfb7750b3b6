"""PPO, reward-penalty PPO and PPO-Lagrangian: one clipped-PPO update, three policy advantages.

- PPO (Schulman et al., 2017, "Proximal Policy Optimization Algorithms"): ``A = A_r``.
- Penalty: PPO on the reward ``r - lambda c`` with a fixed lambda. GAE is linear in the reward, so
  with ``V = V_r - lambda V_c`` its advantage is exactly ``A_r - lambda A_c``; the two critics stay
  separate and their targets are the same as for every other algorithm.
- PPO-Lagrangian (Ray, Achiam, Amodei, 2019, "Benchmarking Safe Exploration in Deep RL"):
  ``A = (A_r - lambda A_c) / (1 + lambda)``, lambda by projected dual ascent on ``J_c - d``.

The clipped surrogate (eq. 7 of Schulman et al.) reads the combined advantage; both critics regress
on their GAE value targets. The surrogate is written out here rather than torchrl's
``ClipPPOLoss``: with the same formulas (clip in log-ratio space, entropy bonus, ``kl_approx``,
``clip_fraction``; ``tests/test_algos.py`` checks it equals ``ClipPPOLoss`` on a batch),
``ClipPPOLoss`` spent about two thirds of each minibatch on TensorDict work it does for features
we do not use (ESS, ratio statistics, key resolution, a TensorDict clone), the largest cost of the
default gymnasium run's training (measured with cProfile, see ``experiments/``).
"""

from __future__ import annotations

import math

import torch
from tensordict import TensorDict, TensorDictBase
from torch import distributions as D
from torch import nn

from cmdp_rl import keys
from cmdp_rl.advantages import TwinGAE
from cmdp_rl.algos.lagrange import DualAscent
from cmdp_rl.collector import finished_episodes
from cmdp_rl.config import PenaltyConfig, PPOConfig, PPOLagConfig
from cmdp_rl.policies import ActorCritic
from cmdp_rl.policies.tensor_path import TensorActor, TensorModule

STATS = ("loss_pi", "loss_v", "loss_vc", "entropy", "kl", "clip_fraction")


class TrainingDiverged(RuntimeError):
    """A loss or parameter became NaN or infinite."""


class PPO:
    name = "ppo"

    def __init__(self, cfg: PPOConfig, ac: ActorCritic) -> None:
        self.cfg = cfg
        self.ac = ac
        self.gae = TwinGAE(cfg.gamma, cfg.cost_gamma, cfg.gae_lambda)
        # Clip bounds on the log-ratio, as ClipPPOLoss: log(1 - eps) <= log r <= log(1 + eps).
        self.log_clip = (math.log1p(-cfg.clip_epsilon), math.log1p(cfg.clip_epsilon))
        # Tensor paths for the minibatch loop where the modules allow (see policies/tensor_path.py);
        # otherwise the modules are called on TensorDicts.
        self.actor_fast = TensorActor.wrap(ac.actor)
        self.critic_fast = TensorModule.wrap(ac.critic)
        self.cost_critic_fast = TensorModule.wrap(ac.cost_critic)
        self.actor_params = list(ac.actor.parameters())
        self.critic_params = [*ac.critic.parameters(), *ac.cost_critic.parameters()]
        # fused: one kernel per step for all parameters instead of a dozen ops per tensor.
        self.actor_opt = torch.optim.Adam(self.actor_params, lr=cfg.lr, fused=True)
        self.critic_opt = torch.optim.Adam(self.critic_params, lr=cfg.critic_lr, fused=True)

    # --- what the variants change -------------------------------------------------------------
    @property
    def lagrange_multiplier(self) -> float:
        return 0.0

    def update_multiplier(self, episode_cost: float | None) -> None:
        """Constrained variants adapt lambda here, before the policy update."""

    def policy_advantage(self, batch: TensorDictBase) -> torch.Tensor:
        return batch.get(keys.ADVANTAGE)

    # --- the shared update ----------------------------------------------------------------------
    def update(self, batch: TensorDictBase) -> dict[str, float]:
        """One PPO iteration on a ``[N, T]`` batch from the collector; returns scalars to log."""
        cfg = self.cfg
        self.gae(batch, self.ac.critic, self.ac.cost_critic)
        costs = finished_episodes(batch)["cost"]
        self.update_multiplier(costs.mean().item() if costs.numel() else None)

        adv = self.policy_advantage(batch)
        if cfg.normalize_advantage:
            adv = (adv - adv.mean()) / (adv.std() + 1e-8)
        batch.set(keys.POLICY_ADVANTAGE, adv)

        # Only what the minibatch loop reads, flattened to [N*T, ...]; one gather per epoch, then
        # each minibatch is a slice (a view).
        data = {k: batch.get(k).flatten(0, 1) for k in self._update_keys(batch)}
        total = next(iter(data.values())).shape[0]
        mb_size = total // cfg.num_minibatches
        sums = torch.zeros(len(STATS), device=batch.device)
        for _ in range(cfg.update_epochs):
            perm = torch.randperm(total, device=batch.device)
            shuffled = {k: v[perm] for k, v in data.items()}
            for i in range(cfg.num_minibatches):
                mb = {k: v[i * mb_size:(i + 1) * mb_size] for k, v in shuffled.items()}
                loss_pi, entropy, kl, clip_fraction = self.policy_loss(mb)
                # Critics: regression on the GAE value targets (lambda-returns).
                loss_v = (self._values(mb, self.critic_fast, self.ac.critic, keys.VALUE) - mb[keys.VALUE_TARGET]).pow(2).mean()
                loss_vc = (self._values(mb, self.cost_critic_fast, self.ac.cost_critic, keys.COST_VALUE)
                           - mb[keys.COST_VALUE_TARGET]).pow(2).mean()
                self.actor_opt.zero_grad(set_to_none=True)
                self.critic_opt.zero_grad(set_to_none=True)
                # One backward pass: the three losses have disjoint parameters, so each network's
                # gradient is that of its own loss.
                (loss_pi + loss_v + loss_vc).backward()
                nn.utils.clip_grad_norm_(self.actor_params, cfg.max_grad_norm)
                nn.utils.clip_grad_norm_(self.critic_params, cfg.max_grad_norm)
                self.actor_opt.step()
                self.critic_opt.step()
                sums += torch.stack([loss_pi, loss_v, loss_vc, entropy, kl, clip_fraction]).detach()
        # One host sync per update (not per minibatch): read the statistics, stop on NaN/inf.
        means = (sums / (cfg.update_epochs * cfg.num_minibatches)).tolist()
        stats = dict(zip(STATS, means))
        self._check_finite(stats)
        # A last step can leave a parameter infinite with every loss finite: never let such a
        # network reach a checkpoint (one check for all parameters, one host sync).
        params = list(self.ac.modules().named_parameters())
        finite = torch.stack([torch.isfinite(p).all() for _, p in params]).tolist()
        if not all(finite):
            name = next(n for (n, _), ok in zip(params, finite) if not ok)
            raise TrainingDiverged(f"parameter {name} is not finite after the update: training diverged")
        stats["lagrange_multiplier"] = self.lagrange_multiplier
        return stats

    def policy_loss(self, mb: dict[str, torch.Tensor]) -> tuple[torch.Tensor, ...]:
        """Clipped surrogate (Schulman et al. 2017, eq. 7) on the policy advantage, minus the
        entropy bonus; returns (loss, entropy, kl_approx, clip_fraction), the last three detached.
        The same arithmetic as torchrl's ``ClipPPOLoss`` (clip on the log-ratio)."""
        dist = self._dist(mb)
        log_prob = dist.log_prob(mb[keys.ACTION])
        old_log_prob = mb[keys.LOG_PROB]
        adv = mb[keys.POLICY_ADVANTAGE]
        log_ratio = (log_prob - old_log_prob).reshape(adv.shape)
        log_ratio_clip = log_ratio.clamp(*self.log_clip)
        gain = torch.minimum(log_ratio.exp() * adv, log_ratio_clip.exp() * adv)
        entropy = dist.entropy().mean()
        loss = -gain.mean() - self.cfg.entropy_coef * entropy
        with torch.no_grad():
            kl = (old_log_prob - log_prob).mean()
            clip_fraction = (log_ratio_clip != log_ratio).float().mean()
        return loss, entropy.detach(), kl, clip_fraction

    def _dist(self, mb: dict[str, torch.Tensor]) -> D.Distribution:
        if self.actor_fast is not None:
            return self.actor_fast.dist(mb)
        return self.ac.actor.get_dist(TensorDict(mb, batch_size=[len(mb[keys.ACTION])]))

    @staticmethod
    def _values(mb: dict[str, torch.Tensor], fast: TensorModule | None, module, key: str) -> torch.Tensor:
        if fast is not None:
            return fast(mb)
        return module(TensorDict(mb, batch_size=[len(mb[keys.ACTION])])).get(key)

    def _update_keys(self, batch: TensorDictBase) -> list:
        """The batch entries the minibatch loop reads: the networks' inputs, the action and its
        behaviour log-prob, the policy advantage and both value targets."""
        inputs = {*self.ac.actor.in_keys, *self.ac.critic.in_keys, *self.ac.cost_critic.in_keys}
        fixed = [keys.ACTION, keys.LOG_PROB, keys.POLICY_ADVANTAGE, keys.VALUE_TARGET, keys.COST_VALUE_TARGET]
        return [*fixed, *sorted((k for k in inputs if k in batch.keys(True) and k not in fixed), key=str)]

    @staticmethod
    def _check_finite(stats: dict[str, float]) -> None:
        for name, value in stats.items():
            if not math.isfinite(value):
                raise TrainingDiverged(f"{name} is {value}: training diverged")

    # --- checkpointing --------------------------------------------------------------------------
    def state_dict(self) -> dict:
        return {
            "networks": self.ac.modules().state_dict(),
            "actor_opt": self.actor_opt.state_dict(),
            "critic_opt": self.critic_opt.state_dict(),
        }

    def load_state_dict(self, state: dict) -> None:
        self.ac.modules().load_state_dict(state["networks"])
        self.actor_opt.load_state_dict(state["actor_opt"])
        self.critic_opt.load_state_dict(state["critic_opt"])


class PenaltyPPO(PPO):
    name = "penalty"

    def __init__(self, cfg: PenaltyConfig, ac: ActorCritic) -> None:
        super().__init__(cfg, ac)
        self.penalty = cfg.penalty

    @property
    def lagrange_multiplier(self) -> float:
        return self.penalty

    def policy_advantage(self, batch: TensorDictBase) -> torch.Tensor:
        return batch.get(keys.ADVANTAGE) - self.penalty * batch.get(keys.COST_ADVANTAGE)


class PPOLagrangian(PPO):
    name = "ppo_lag"

    def __init__(self, cfg: PPOLagConfig, ac: ActorCritic) -> None:
        super().__init__(cfg, ac)
        self.multiplier = DualAscent(cfg.cost_limit, cfg.lambda_lr, cfg.lambda_init)

    @property
    def lagrange_multiplier(self) -> float:
        return self.multiplier.value

    def update_multiplier(self, episode_cost: float | None) -> None:
        # No episode ended in this batch: no new estimate of J_c, lambda stays.
        if episode_cost is not None:
            self.multiplier.update(episode_cost)

    def policy_advantage(self, batch: TensorDictBase) -> torch.Tensor:
        lam = self.multiplier.value
        return (batch.get(keys.ADVANTAGE) - lam * batch.get(keys.COST_ADVANTAGE)) / (1.0 + lam)

    def state_dict(self) -> dict:
        return {**super().state_dict(), "multiplier": self.multiplier.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        super().load_state_dict(state)
        self.multiplier.load_state_dict(state["multiplier"])
