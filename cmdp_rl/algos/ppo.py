"""PPO (Schulman et al., 2017, "Proximal Policy Optimization Algorithms"): one clipped-PPO update
on a policy advantage, ``A = A_r`` here. Reward-penalty PPO and PPO-Lagrangian (Ray, Achiam,
Amodei, 2019, "Benchmarking Safe Exploration in Deep RL") change only that advantage and the
multiplier behind it: ppo_lag.py.

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
from typing import TYPE_CHECKING, Any, Callable, ClassVar, Optional, Sequence

import torch
from tensordict import TensorDictBase
from torch import distributions as D

from cmdp_rl.algos.base import AlgoConfig, check_finite
from cmdp_rl.algos.critics import CriticRegression
from cmdp_rl.algos.update_backend import Backend, OneAgent, iterate
from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import (
    AUTO,
    AutoInt,
    Bool,
    NonNegativeFloat,
    PositiveFloat,
    UnitOpen,
    options,
    require,
)
from cmdp_rl.policies.agent import Agent
from cmdp_rl.rollout import keys
from cmdp_rl.rollout.advantages import TwinGAE, standardized
from cmdp_rl.rollout.episode_cost import EpisodeCost, EpisodeCostEstimate

if TYPE_CHECKING:
    from cmdp_rl.config.run_config import RunConfig

# KL early stopping (``algo.target_kl``): the update stops at the first minibatch whose approximate
# KL from the behaviour policy, E[(r - 1) - log r] (never negative), exceeds KL_STOP * target_kl,
# before that minibatch's step; the logged statistics average the minibatches evaluated. The
# factor 1.5 is the one Spinning Up's PPO and Stable-Baselines3's PPO use with their target_kl.
KL_STOP = 1.5
Units = dict[str, torch.Tensor]
Reduce = Callable[[torch.Tensor], torch.Tensor]  # torch.mean, or a population's mean per agent


@options
class PPOConfig(AlgoConfig):
    """Clipped PPO (Schulman et al., 2017). Shared by every PPO-family algorithm."""

    name: str = "ppo"
    tiny: ClassVar[dict] = {"update_epochs": 2, "num_minibatches": 2}  # AlgoConfig.tiny
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
        self.entropy_coef = cfg.entropy_coef

    def anneal_fraction(self) -> float:
        """The annealed rates' fraction of their initial values this iteration (``anneal_lr``,
        ``anneal_lambda_lr``): ``1 - i / anneal_iterations`` for iteration i = 0, 1, ..."""
        return max(0.0, 1.0 - self.iteration / self.cfg.anneal_iterations)

    def learning_rates(self) -> tuple[float, float]:
        """The actor's and the critics' learning rates this iteration (``anneal_lr``: annealed)."""
        frac = self.anneal_fraction() if self.cfg.anneal_lr else 1.0
        return frac * self.cfg.lr, frac * self.cfg.critic_lr

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
        return iterate([self], batch, OneAgent(self.agent, self.cfg.max_grad_norm, self.kl_limit))[0]

    def prepare(self, batch: TensorDictBase) -> torch.Tensor:
        """After GAE, before the minibatches (one agent's rows): J_c, the multiplier, the policy
        advantage (normalised if ``normalize_advantage``)."""
        self.update_multiplier(self.episode_cost.update(batch))
        adv = self.policy_advantage(batch)
        if self.cfg.normalize_advantage:
            adv = standardized(adv)
        return adv

    def minibatch_step(self, backend: Backend, groups: list, mb: Units, active: Any) -> tuple[Units, Any]:
        """One minibatch: the policy loss and the critics' regression (reduced by the backend's
        mean), KL early stopping, one backward pass and the backend's step. Returns the statistics
        and the agents still active."""
        dist, values = backend.training_pass(mb)
        loss_pi, stats = self.policy_loss(mb, dist, backend.mean, backend.entropy_coef)
        # Critics: regression on the GAE value targets (lambda-returns).
        critic_losses = self.critics.losses(mb, values, backend.mean)
        evaluated = active
        active, stepping = backend.stop(stats["kl_stop"], active)
        total = loss_pi
        for loss in critic_losses.values():
            total = total + loss
        backend.step(total, groups, stepping)
        return backend.kept({"loss_pi": loss_pi, **critic_losses, **stats}, evaluated), active

    def finish(self, means: dict[str, float]) -> dict[str, float]:
        """After the minibatches: the logged statistics (``stats`` of the minibatch means, checked
        finite, the multiplier, the variant's own), and the clock advanced."""
        stats = {k: v for k, v in means.items() if k in self.stats}
        check_finite(**stats)
        stats["lagrange_multiplier"] = self.lagrange_multiplier
        stats.update(self.iteration_stats())
        self.iteration += 1
        return stats

    def policy_loss(
        self,
        mb: Units,
        dist: D.Distribution | None = None,
        mean: Reduce = torch.mean,
        entropy_coef: float | torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, Units]:
        """:meth:`surrogate` minus the entropy bonus, and its statistics, detached. A population
        passes its agents' distribution on ``[P, B, ...]``, its per-agent ``mean`` and coefficients."""
        loss, stats = self.surrogate(self.agent.dist(mb) if dist is None else dist, mb, mean)
        loss = loss - (self.entropy_coef if entropy_coef is None else entropy_coef) * stats["entropy"]
        return loss, {**stats, "entropy": stats["entropy"].detach()}

    def surrogate(self, dist: D.Distribution, mb: Units, mean: Reduce) -> tuple[torch.Tensor, Units]:
        """Clipped surrogate (Schulman et al. 2017, eq. 7; clip on the log-ratio, as ClipPPOLoss) and
        its statistics (entropy with its graph, KL ``E[log pi_old - log pi]``, clip fraction,
        ``kl_stop``), reduced by ``mean``: over the minibatch, or per agent on a population's ``[P, B]``."""
        log_prob = dist.log_prob(mb[keys.ACTION])
        old_log_prob = mb[keys.LOG_PROB]
        adv = mb[keys.POLICY_ADVANTAGE]
        gain, log_ratio, log_ratio_clip = clipped_gain(log_prob, old_log_prob, adv, self.log_clip)
        entropy = mean(dist.entropy())
        with torch.no_grad():
            kl = mean(old_log_prob - log_prob)
            # Non-negative estimate for early stopping: E[(r - 1) - log r] (Schulman, 2020,
            # "Approximating KL Divergence"; the one Stable-Baselines3 stops on).
            kl_stop = mean(log_ratio.exp() - 1 - log_ratio)
            clip_fraction = mean((log_ratio_clip != log_ratio).float())
        return -mean(gain), {"entropy": entropy, "kl": kl, "clip_fraction": clip_fraction, "kl_stop": kl_stop}

    def second_stage(self, backend: Backend, algos: Sequence[PPO], rows: Sequence[TensorDictBase]) -> Units:
        """A stage after the minibatch epochs, for every member (``algos``, each on its ``rows``),
        before ``finish``: its statistics' means per member (none here; CUP's projection)."""
        return {}

    def iteration_stats(self) -> dict[str, float]:
        """A variant's ``stats`` beyond the minibatch loop's (CRPO's ``cost_step``)."""
        return {}

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


def lagrangian_advantage(
    batch: TensorDictBase | dict[str, torch.Tensor], lams: list[float], scale: str = "raw"
) -> torch.Tensor:
    """The Lagrangian's policy advantage ``(A_r - sum_k lambda_k A_c,k) / (1 + sum_k lambda_k)``.

    ``scale``: ``raw`` weighs the advantages in their own units; ``standardized`` first brings
    ``A_r`` and each ``A_c,k`` to mean 0 and standard deviation 1 over the batch, so that lambda = 1
    weighs a cost signal as much as the reward's whatever either is measured in. On PointGoal1 the
    cost advantage's spread is 10-30 times the reward's, so in raw units any lambda above about 0.1
    already hands the policy's update to the cost (docs/constraint_satisfaction.md). OmniSafe
    standardises the reward advantage and centres the cost advantage; both are standardised here so
    that, with the budget-relative dual step, scaling the costs (and the budgets) by any factor
    leaves the whole run unchanged.
    """
    if scale == "standardized":
        adv, cost_adv = batch.get(keys.ADVANTAGE), batch.get(keys.COST_ADVANTAGE)
        rows = tuple(range(cost_adv.dim() - 1))
        batch = {keys.ADVANTAGE: standardized(adv), keys.COST_ADVANTAGE: standardized(cost_adv, rows)}
    return penalised(batch, lams) / (1.0 + sum(lams))


def logged_multiplier(values: list[float]) -> float | list[float]:
    """A multiplier as metrics.csv takes it: a number for one constraint, else a list of K."""
    return values[0] if len(values) == 1 else list(values)


register("algo", "ppo", PPOConfig, PPO)
