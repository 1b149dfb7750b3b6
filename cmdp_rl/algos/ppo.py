"""PPO, reward-penalty PPO and PPO-Lagrangian (dual ascent or PID): one clipped-PPO update, three
policy advantages.

- PPO (Schulman et al., 2017, "Proximal Policy Optimization Algorithms"): ``A = A_r``.
- Penalty: PPO on the reward ``r - lambda c`` with a fixed lambda. GAE is linear in the reward, so
  with ``V = V_r - lambda V_c`` its advantage is exactly ``A_r - lambda A_c``; the two critics stay
  separate and their targets are the same as for every other algorithm.
- PPO-Lagrangian (Ray, Achiam, Amodei, 2019, "Benchmarking Safe Exploration in Deep RL"):
  ``A = (A_r - lambda A_c) / (1 + lambda)``, lambda by projected dual ascent on ``J_c - d``, or by
  a PID controller on it (Stooke, Achiam, Abbeel, 2020): see ``lagrange.py``.

The clipped surrogate is torchrl's ``ClipPPOLoss`` (eq. 7 of Schulman et al.) reading the combined
advantage; both critics regress on their GAE value targets.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.objectives import ClipPPOLoss

from cmdp_rl import keys
from cmdp_rl.advantages import TwinGAE
from cmdp_rl.algos.base import check_finite, check_parameters_finite
from cmdp_rl.algos.critics import critic_losses
from cmdp_rl.algos.lagrange import DualAscent, MultiplierController, PIDLagrangian
from cmdp_rl.collector import finished_episodes
from cmdp_rl.config import PenaltyConfig, PIDLagConfig, PPOConfig, PPOLagConfig
from cmdp_rl.policies import ActorCritic


class PPO:
    name = "ppo"

    def __init__(self, cfg: PPOConfig, ac: ActorCritic) -> None:
        self.cfg = cfg
        self.ac = ac
        self.gae = TwinGAE(cfg.gamma, cfg.cost_gamma, cfg.gae_lambda)
        self.loss = ClipPPOLoss(
            ac.actor, critic_network=None, clip_epsilon=cfg.clip_epsilon,
            entropy_coeff=cfg.entropy_coef, normalize_advantage=False,
        )
        self.loss.set_keys(advantage=keys.POLICY_ADVANTAGE, sample_log_prob=keys.LOG_PROB)
        self.actor_opt = torch.optim.Adam(ac.actor.parameters(), lr=cfg.lr)
        self.critic_params = [*ac.critic.parameters(), *ac.cost_critic.parameters()]
        self.critic_opt = torch.optim.Adam(self.critic_params, lr=cfg.critic_lr)

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

        flat = batch.reshape(-1)
        mb_size = flat.shape[0] // cfg.num_minibatches
        sums = {"loss_pi": 0.0, "loss_v": 0.0, "loss_vc": 0.0, "entropy": 0.0, "kl": 0.0, "clip_fraction": 0.0}
        n = 0
        for _ in range(cfg.update_epochs):
            perm = torch.randperm(flat.shape[0], device=flat.device)
            for i in range(cfg.num_minibatches):
                mb = flat[perm[i * mb_size:(i + 1) * mb_size]]
                # Policy: clipped surrogate on the combined advantage (Schulman et al. eq. 7).
                out = self.loss(mb)
                loss_pi = out["loss_objective"] + out.get("loss_entropy", torch.zeros(()))
                # Critics: regression on the GAE value targets (lambda-returns).
                loss_v, loss_vc = critic_losses(self.ac, mb)
                check_finite(loss_pi=loss_pi, loss_v=loss_v, loss_vc=loss_vc)
                self._step(self.actor_opt, loss_pi, self.ac.actor.parameters())
                self._step(self.critic_opt, loss_v + loss_vc, self.critic_params)
                for k, val in (("loss_pi", loss_pi), ("loss_v", loss_v), ("loss_vc", loss_vc),
                               ("entropy", out["entropy"]), ("kl", out["kl_approx"]),
                               ("clip_fraction", out["clip_fraction"])):
                    sums[k] += val.item()
                n += 1
        check_parameters_finite(self.ac.modules())
        stats = {k: s / n for k, s in sums.items()}
        stats["lagrange_multiplier"] = self.lagrange_multiplier
        return stats

    def _step(self, opt: torch.optim.Optimizer, loss: torch.Tensor, params) -> None:
        opt.zero_grad(set_to_none=True)
        loss.backward()
        nn.utils.clip_grad_norm_(list(params), self.cfg.max_grad_norm)
        opt.step()

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
    """Lambda from a :class:`MultiplierController`: projected dual ascent here, PID in
    :class:`PIDLagrangianPPO`; the policy update is the same."""

    name = "ppo_lag"

    def __init__(self, cfg: PPOLagConfig, ac: ActorCritic) -> None:
        super().__init__(cfg, ac)
        self.multiplier = self.make_multiplier(cfg)

    @staticmethod
    def make_multiplier(cfg: PPOLagConfig) -> MultiplierController:
        return DualAscent(cfg.cost_limit, cfg.lambda_lr, cfg.lambda_init)

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


class PIDLagrangianPPO(PPOLagrangian):
    """PPO-Lagrangian with lambda from a PID controller on ``J_c - d`` (Stooke, Achiam, Abbeel,
    2020, "Responsive Safety in RL by PID Lagrangian Methods"): the proportional and derivative
    terms damp the overshoot and oscillation of the integral-only dual ascent."""

    name = "pid_lag"

    @staticmethod
    def make_multiplier(cfg: PIDLagConfig) -> MultiplierController:
        return PIDLagrangian(
            cfg.cost_limit, kp=cfg.kp, ki=cfg.ki, kd=cfg.kd, init=cfg.lambda_init,
            p_ema_alpha=cfg.p_ema_alpha, d_ema_alpha=cfg.d_ema_alpha, d_delay=cfg.d_delay,
            lambda_max=cfg.lambda_max,
        )
