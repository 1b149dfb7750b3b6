"""PPO, reward-penalty PPO and PPO-Lagrangian (dual ascent or PID): one clipped-PPO update, three
policy advantages.

- PPO (Schulman et al., 2017, "Proximal Policy Optimization Algorithms"): ``A = A_r``.
- Penalty: PPO on the reward ``r - lambda c`` with a fixed lambda. GAE is linear in the reward, so
  with ``V = V_r - lambda V_c`` its advantage is exactly ``A_r - lambda A_c``; the two critics stay
  separate and their targets are the same as for every other algorithm.
- PPO-Lagrangian (Ray, Achiam, Amodei, 2019, "Benchmarking Safe Exploration in Deep RL"):
  ``A = (A_r - lambda A_c) / (1 + lambda)``, lambda by projected dual ascent on ``J_c - d``, or by
  a PID controller on it (Stooke, Achiam, Abbeel, 2020): see ``lagrange.py``.

K constraints (an env reporting K costs): one multiplier per constraint, each moved by its own
``J_c,k - d_k`` (``lagrange.Multipliers``), and the advantage is
``(A_r - sum_k lambda_k A_c,k) / (1 + sum_k lambda_k)``: the same normalisation as K = 1, which it
is exactly (the penalised advantage's scale stays that of ``A_r`` however many multipliers grow).
Penalty takes one lambda for every cost or a list of K: ``A_r - sum_k lambda_k A_c,k``.

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
from typing import TYPE_CHECKING, Annotated, ClassVar, Optional

import torch
from tensordict import TensorDictBase
from torch import nn

from cmdp_rl import keys
from cmdp_rl.advantages import TwinGAE
from cmdp_rl.algos.base import AlgoConfig, PerConstraint, check_finite, check_parameters_finite, per_constraint
from cmdp_rl.algos.critics import CriticRegression
from cmdp_rl.algos.episode_cost import EpisodeCost, EpisodeCostEstimate
from cmdp_rl.algos.lagrange import DualAscent, MultiplierController, Multipliers, PIDLagrangian
from cmdp_rl.algos.minibatch import minibatches
from cmdp_rl.policies.agent import Agent
from cmdp_rl.registry import register
from cmdp_rl.validation import (
    AUTO,
    AutoInt,
    Bool,
    Field,
    NonNegativeFloat,
    PositiveFloat,
    PositiveInt,
    UnitOpen,
    finite,
    options,
    require,
)

if TYPE_CHECKING:
    from cmdp_rl.config import RunConfig

# KL early stopping (``algo.target_kl``): the update stops at the first minibatch whose approximate
# KL from the behaviour policy, E[(r - 1) - log r] (never negative), exceeds KL_STOP * target_kl,
# before that minibatch's step; the logged statistics average the minibatches evaluated. The
# factor 1.5 is the one Spinning Up's PPO and Stable-Baselines3's PPO use with their target_kl.
KL_STOP = 1.5


@options
class PPOConfig(AlgoConfig):
    """Clipped PPO (Schulman et al., 2017). Shared by every PPO-family algorithm."""

    name: str = "ppo"
    lr: PositiveFloat = 3e-4
    clip_epsilon: UnitOpen = 0.2
    # "auto": about 80 minibatch steps per iteration (resolve_auto), 10 x 8 for a batch of 2048.
    update_epochs: AutoInt = AUTO
    num_minibatches: AutoInt = AUTO
    entropy_coef: NonNegativeFloat = 0.0
    # KL early stopping: null (off), or stop the epoch loop at the first minibatch whose approximate
    # KL exceeds 1.5 * target_kl (KL_STOP).
    target_kl: Optional[PositiveFloat] = None
    # Linear annealing of the actor's and the critics' learning rates from lr (critic_lr) to 0 over
    # the run (Huang et al. 2022, "The 37 Implementation Details of PPO", detail 4); false: constant.
    anneal_lr: Bool = False
    # The iterations the annealing spans; "auto": the run's, ceil(total_steps / batch).
    anneal_iterations: AutoInt = AUTO

    def resolve_auto(self, run: RunConfig) -> None:
        """``num_minibatches`` and ``update_epochs`` from the batch (see ``config.resolve_auto``):
        8 minibatches while the batch is at most 2048 steps, else one per 512 steps, at most 64;
        epochs = 80 / minibatches rounded, at least 1 (about 80 minibatch steps per iteration, the
        gym default's 10 x 8; PPO-Lagrangian moves lambda once per iteration, and with 16 or 32
        steps per iteration at N = 1024, lambda overshot and the policy collapsed)."""
        batch = run.rollout_steps * run.env.num_envs
        if self.num_minibatches == AUTO:
            self.num_minibatches = 8 if batch <= 2048 else min(64, batch // 512)
        if self.update_epochs == AUTO:
            self.update_epochs = max(1, round(80 / self.num_minibatches))
        if self.anneal_iterations == AUTO:
            self.anneal_iterations = max(1, math.ceil(run.total_steps / batch))

    def describe_update(self) -> str:
        return f"{self.update_epochs} x {self.num_minibatches} minibatches"

    def check(self, run: RunConfig) -> None:
        batch = run.rollout_steps * run.env.num_envs
        require(
            batch >= self.num_minibatches,
            "algo.num_minibatches",
            f"at most rollout_steps * env.num_envs = {batch}",
            self.num_minibatches,
        )


@options
class PenaltyConfig(PPOConfig):
    """PPO on r - penalty * c with a fixed exchange rate."""

    name: str = "penalty"
    penalty: PerConstraint = 1.0  # one lambda for every cost, or a list of K
    # Its fixed lambda prices raw cost: cost scaling would change what the number means.
    reads_raw_cost: ClassVar[bool] = True


@options
class PPOLagConfig(PPOConfig):
    """PPO-Lagrangian (Ray, Achiam, Amodei 2019): lambda adapted by projected dual ascent."""

    name: str = "ppo_lag"
    lambda_init: NonNegativeFloat = 0.0
    lambda_lr: PositiveFloat = 0.05
    # With anneal_lr, also anneal lambda's step size linearly to 0 (the same schedule): the dual
    # iterate then settles instead of swinging, as diminishing dual steps do in the convergence
    # results for primal-dual methods; false: lambda_lr throughout.
    anneal_lambda_lr: Bool = False


@options
class PIDLagConfig(PPOConfig):
    """PPO with lambda set by a PID controller (Stooke, Achiam, Abbeel 2020)."""

    name: str = "pid_lag"
    lambda_init: NonNegativeFloat = 0.0
    kp: NonNegativeFloat = 2.0
    ki: NonNegativeFloat = 0.1
    kd: NonNegativeFloat = 0.0
    p_ema_alpha: Annotated[float, finite(ge=0, lt=1)] = 0.0
    d_ema_alpha: Annotated[float, finite(ge=0, lt=1)] = 0.0
    d_delay: PositiveInt = 1
    lambda_max: Annotated[float, Field(gt=0, description="a positive number or .inf")] = math.inf

    def check(self, run: RunConfig) -> None:
        super().check(run)
        gains = self.kp + self.ki + self.kd
        require(gains > 0, "algo.kp + algo.ki + algo.kd", "> 0 (some gain must act)", gains)
        require(
            self.lambda_init <= self.lambda_max,
            "algo.lambda_init",
            "a number in [0, algo.lambda_max]",
            self.lambda_init,
        )


STATS = ("loss_pi", "loss_v", "loss_vc", "entropy", "kl", "clip_fraction")


def clipped_gain(
    log_prob: torch.Tensor, old_log_prob: torch.Tensor, adv: torch.Tensor, log_clip: tuple[float, float]
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The clipped surrogate's per-sample gain ``min(r A, clip(r) A)`` (Schulman et al. 2017,
    eq. 7), clipping the log-ratio to ``log_clip = (log(1 - eps), log(1 + eps))``; also returns the
    log-ratio and its clipped value (for the KL and clip-fraction statistics). Elementwise, so a
    population's update (population/update.py) reduces it per agent."""
    log_ratio = (log_prob - old_log_prob).reshape(adv.shape)
    log_ratio_clip = log_ratio.clamp(*log_clip)
    return torch.minimum(log_ratio.exp() * adv, log_ratio_clip.exp() * adv), log_ratio, log_ratio_clip


class PPO:
    name = "ppo"
    stats = STATS  # what update() returns besides lagrange_multiplier: metrics.csv's columns

    def __init__(self, cfg: PPOConfig, agent: Agent) -> None:
        self.cfg = cfg
        self.agent = agent
        self.gae = TwinGAE(cfg.gamma, cfg.cost_gamma, cfg.gae_lambda)
        self.episode_cost = EpisodeCostEstimate()  # J_c, for the constrained variants
        # Clip bounds on the log-ratio, as ClipPPOLoss: log(1 - eps) <= log r <= log(1 + eps).
        self.log_clip = (math.log1p(-cfg.clip_epsilon), math.log1p(cfg.clip_epsilon))
        self.critics = CriticRegression(agent)
        # The KL past which the epoch loop stops (before that minibatch's step); None: never.
        self.kl_limit = None if cfg.target_kl is None else KL_STOP * cfg.target_kl
        self.actor_params = list(agent.actor.parameters())
        self.critic_params = list(agent.critics.parameters())
        # fused: one kernel per step for all parameters instead of a dozen ops per tensor.
        self.actor_opt = torch.optim.Adam(self.actor_params, lr=cfg.lr, fused=True)
        self.critic_opt = torch.optim.Adam(self.critic_params, lr=cfg.critic_lr, fused=True)
        self.iteration = 0  # updates done: the learning-rate schedule's clock (anneal_lr)

    def anneal_fraction(self) -> float:
        """The annealed rates' fraction of their initial values this iteration (``anneal_lr``,
        ``anneal_lambda_lr``): ``1 - i / anneal_iterations`` for iteration i = 0, 1, ..."""
        return max(0.0, 1.0 - self.iteration / self.cfg.anneal_iterations)

    # --- what the variants change -------------------------------------------------------------
    @property
    def lagrange_multiplier(self) -> float:
        return 0.0

    def update_multiplier(self, estimate: EpisodeCost) -> None:
        """Constrained variants adapt lambda here, before the policy update."""

    def policy_advantage(self, batch: TensorDictBase) -> torch.Tensor:
        return batch.get(keys.ADVANTAGE)

    # --- the shared update ----------------------------------------------------------------------
    def update(self, batch: TensorDictBase) -> dict[str, float]:
        """One PPO iteration on a ``[N, T]`` batch from the collector; returns scalars to log."""
        cfg = self.cfg
        if cfg.anneal_lr:
            frac = self.anneal_fraction()
            self.actor_opt.param_groups[0]["lr"] = frac * cfg.lr
            self.critic_opt.param_groups[0]["lr"] = frac * cfg.critic_lr
        self.gae(batch, self.agent)
        self.update_multiplier(self.episode_cost.update(batch))

        adv = self.policy_advantage(batch)
        if cfg.normalize_advantage:
            adv = (adv - adv.mean()) / (adv.std() + 1e-8)
        batch.set(keys.POLICY_ADVANTAGE, adv)

        # Only what the minibatch loop reads, as training units: steps [N*T, ...], or for a
        # recurrent policy whole segments [U, L, ...] (Agent.training_units).
        data = self.agent.training_units({k: batch.get(k) for k in self._update_keys(batch)})
        sums: dict[str, torch.Tensor] = {}
        steps = 0
        for _, mb in minibatches(data, cfg.num_minibatches, cfg.update_epochs):
            loss_pi, stats = self.policy_loss(mb)
            # Critics: regression on the GAE value targets (lambda-returns).
            critic_losses = self.critics.losses(mb)
            stats = {"loss_pi": loss_pi.detach(), **{k: v.detach() for k, v in critic_losses.items()}, **stats}
            sums = {k: sums[k] + v if k in sums else v for k, v in stats.items()}
            steps += 1
            if self.kl_limit is not None and stats["kl_stop"].item() > self.kl_limit:
                break  # KL early stopping: this minibatch's step would leave the trust region
            self.actor_opt.zero_grad(set_to_none=True)
            self.critic_opt.zero_grad(set_to_none=True)
            # One backward pass: the losses have disjoint parameters, so each network's gradient
            # is that of its own loss.
            total = loss_pi
            for loss in critic_losses.values():
                total = total + loss
            total.backward()
            nn.utils.clip_grad_norm_(self.actor_params, cfg.max_grad_norm)
            nn.utils.clip_grad_norm_(self.critic_params, cfg.max_grad_norm)
            self.actor_opt.step()
            self.critic_opt.step()
        # One host sync per update (not per minibatch): read the statistics, stop on NaN/inf.
        means = (torch.stack(list(sums.values())) / steps).tolist()
        stats = {k: means[i] for i, k in enumerate(sums) if k in self.stats}
        check_finite(**stats)
        check_parameters_finite(self.agent)
        stats["lagrange_multiplier"] = self.lagrange_multiplier
        self.iteration += 1
        return stats

    def policy_loss(self, mb: dict[str, torch.Tensor]) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Clipped surrogate (Schulman et al. 2017, eq. 7) on the policy advantage, minus the
        entropy bonus; returns the loss and its statistics (entropy, the approximate KL
        ``E[log pi_old - log pi]``, the fraction of clipped ratios), detached. The same arithmetic
        as torchrl's ``ClipPPOLoss`` (clip on the log-ratio)."""
        dist = self.agent.dist(mb)
        log_prob = dist.log_prob(mb[keys.ACTION])
        old_log_prob = mb[keys.LOG_PROB]
        adv = mb[keys.POLICY_ADVANTAGE]
        gain, log_ratio, log_ratio_clip = clipped_gain(log_prob, old_log_prob, adv, self.log_clip)
        entropy = dist.entropy().mean()
        loss = -gain.mean() - self.cfg.entropy_coef * entropy
        with torch.no_grad():
            kl = (old_log_prob - log_prob).mean()
            # Non-negative estimate for early stopping: E[(r - 1) - log r] (Schulman, 2020,
            # "Approximating KL Divergence"; the one Stable-Baselines3 stops on).
            kl_stop = (log_ratio.exp() - 1 - log_ratio).mean()
            clip_fraction = (log_ratio_clip != log_ratio).float().mean()
        return loss, {"entropy": entropy.detach(), "kl": kl, "clip_fraction": clip_fraction, "kl_stop": kl_stop}

    def _update_keys(self, batch: TensorDictBase) -> list:
        """The batch entries the minibatch loop reads: the networks' inputs, the action and its
        behaviour log-prob, the policy advantage and the critics' value targets."""
        fixed = [keys.ACTION, keys.LOG_PROB, keys.POLICY_ADVANTAGE, *self.critics.target_keys()]
        present = batch.keys(True)
        return [*fixed, *(k for k in self.agent.in_keys if k in present and k not in fixed)]

    # --- checkpointing --------------------------------------------------------------------------
    def state_dict(self) -> dict:
        return {
            "networks": self.agent.state_dict(),
            "actor_opt": self.actor_opt.state_dict(),
            "critic_opt": self.critic_opt.state_dict(),
            "episode_cost": self.episode_cost.state_dict(),
            "iteration": self.iteration,
        }

    def load_state_dict(self, state: dict) -> None:
        self.agent.load_state_dict(state["networks"])
        self.actor_opt.load_state_dict(state["actor_opt"])
        self.critic_opt.load_state_dict(state["critic_opt"])
        self.episode_cost.load_state_dict(state["episode_cost"])
        self.iteration = int(state["iteration"])


def penalised(batch: TensorDictBase | dict[str, torch.Tensor], lams: list[float]) -> torch.Tensor:
    """``A_r - sum_k lambda_k A_c,k`` (with K = 1 exactly ``A_r - lambda A_c``)."""
    adv, cost_adv = batch.get(keys.ADVANTAGE), batch.get(keys.COST_ADVANTAGE)
    for k, lam in enumerate(lams):
        adv = adv - lam * cost_adv[..., k : k + 1]
    return adv


def logged_multiplier(values: list[float]) -> float | list[float]:
    """A multiplier as metrics.csv takes it: a number for one constraint, else a list of K."""
    return values[0] if len(values) == 1 else list(values)


class PenaltyPPO(PPO):
    name = "penalty"

    def __init__(self, cfg: PenaltyConfig, agent: Agent) -> None:
        super().__init__(cfg, agent)
        self.penalties = per_constraint(cfg.penalty, "algo.penalty", agent.cost_names)

    @property
    def lagrange_multiplier(self) -> float | list[float]:
        return logged_multiplier(self.penalties)

    def policy_advantage(self, batch: TensorDictBase) -> torch.Tensor:
        return penalised(batch, self.penalties)


class PPOLagrangian(PPO):
    """Lambda from a :class:`MultiplierController`: projected dual ascent here, PID in
    :class:`PIDLagrangianPPO`; the policy update is the same."""

    name = "ppo_lag"

    def __init__(self, cfg: PPOLagConfig, agent: Agent) -> None:
        super().__init__(cfg, agent)
        limits = per_constraint(cfg.cost_limit, "algo.cost_limit", agent.cost_names)
        # One multiplier per constraint (lagrange.Multipliers), each with its own budget d_k.
        self.multiplier = Multipliers(lambda d: self.make_multiplier(cfg, d), limits)

    @staticmethod
    def make_multiplier(cfg: PPOLagConfig, cost_limit: float) -> MultiplierController:
        return DualAscent(cost_limit, cfg.lambda_lr, cfg.lambda_init)

    @property
    def lagrange_multiplier(self) -> float | list[float]:
        return logged_multiplier(self.multiplier.values)

    def update_multiplier(self, estimate: EpisodeCost) -> None:
        if getattr(self.cfg, "anneal_lambda_lr", False):
            frac = self.anneal_fraction()
            for c in self.multiplier.controllers:
                c.lr = frac * self.cfg.lambda_lr
        self.multiplier.update(estimate.costs)  # every iteration (algos/episode_cost.py)

    def policy_advantage(self, batch: TensorDictBase) -> torch.Tensor:
        lams = self.multiplier.values
        return penalised(batch, lams) / (1.0 + sum(lams))

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
    def make_multiplier(cfg: PIDLagConfig, cost_limit: float) -> MultiplierController:
        return PIDLagrangian(
            cost_limit,
            kp=cfg.kp,
            ki=cfg.ki,
            kd=cfg.kd,
            init=cfg.lambda_init,
            p_ema_alpha=cfg.p_ema_alpha,
            d_ema_alpha=cfg.d_ema_alpha,
            d_delay=cfg.d_delay,
            lambda_max=cfg.lambda_max,
        )


register("algo", "ppo", PPOConfig, PPO)
register("algo", "penalty", PenaltyConfig, PenaltyPPO)
register("algo", "ppo_lag", PPOLagConfig, PPOLagrangian)
register("algo", "pid_lag", PIDLagConfig, PIDLagrangianPPO)
