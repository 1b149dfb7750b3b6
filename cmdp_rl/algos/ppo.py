"""PPO (Schulman et al., 2017, "Proximal Policy Optimization Algorithms") and the update every PPO-family
algorithm runs, :func:`ppo_update`, on one screen. A variant changes what the loop reads, never the loop:
the multiplier and policy advantage (ppo_lag.py, FOCOPS, CRPO), the per-sample loss (FOCOPS), a stage after
the epochs (CUP). What reduces the per-sample losses and steps the
networks is the :class:`~cmdp_rl.algos.learner.Learner` it is given: a run's ``SingleLearner``, or a population's
``StackedLearner`` (P agents' stacked rows, ``population/learner.py``), so a population runs the same loop. The clipped surrogate is written out, equal to torchrl's
``ClipPPOLoss`` (tests/test_algos.py), which spent most of each minibatch on unused TensorDict work.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, ClassVar, Optional, Sequence

import torch
from tensordict import TensorDictBase
from torch import distributions as D

from cmdp_rl.algos.base import AlgoConfig, TrainingDiverged, check_finite, check_parameters_finite, require_minibatches
from cmdp_rl.algos.learner import Learner, SingleLearner, Units
from cmdp_rl.algos.minibatch import Tally, joined, member_rows, member_stats, stopped
from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import AUTO, AutoInt, AutoSpan, NonNegativeFloat, PositiveFloat, UnitOpen, options
from cmdp_rl.policies.agent import Agent
from cmdp_rl.rollout import keys
from cmdp_rl.rollout.advantages import TwinGAE, standardized

if TYPE_CHECKING:
    from cmdp_rl.config.run_config import RunConfig

# KL early stopping stops at KL_STOP * target_kl: Spinning Up's and Stable-Baselines3's factor.
KL_STOP = 1.5


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
    # KL early stopping: null (off), or stop at the first minibatch whose approximate KL exceeds 1.5 target_kl.
    target_kl: Optional[PositiveFloat] = None
    # Anneal lr and critic_lr linearly to 0 (Huang et al. 2022, "The 37 Implementation Details of PPO", 4) over this
    # many iterations: false, off; "auto" (or true), the run's, ceil(total_steps / batch).
    anneal_lr: AutoSpan = False

    def resolve_auto(self, run: RunConfig) -> None:
        """8 minibatches while the batch is at most 2048 steps, else one per 512 steps, at most 64;
        epochs = 80 / minibatches: about 80 minibatch steps per iteration, the gym default's 10 x 8
        (with 16 or 32 at N = 1024, PPO-Lagrangian's once-per-iteration lambda overshot)."""
        batch = run.rollout_steps * run.env.num_envs
        if self.num_minibatches == AUTO:
            self.num_minibatches = 8 if batch <= 2048 else min(64, batch // 512)
        if self.update_epochs == AUTO:
            self.update_epochs = max(1, round(80 / self.num_minibatches))
        if self.anneal_lr == AUTO:
            self.anneal_lr = max(1, math.ceil(run.total_steps / batch))

    def describe_update(self) -> str:
        return f"{self.update_epochs} x {self.num_minibatches} minibatches"

    def check(self, run: RunConfig) -> None:
        require_minibatches(run, "num_minibatches", self.num_minibatches)
        if hasattr(self, "multiplier"):  # a constrained variant's algo.multiplier node
            self.multiplier.check()


# The statistic each critic's loss is logged as.
LOSS_NAMES = {"reward": "loss_v", "cost": "loss_vc"}


class CriticRegression:
    """Every critic's squared error on its GAE value targets, ``L^VF = (V(s) - V^targ)^2`` (eq. 9)."""

    def __init__(self, agent: Agent) -> None:
        self.agent = agent

    def terms(
        self, mb: dict[str, torch.Tensor], values: dict[str, torch.Tensor] | None = None
    ) -> dict[str, torch.Tensor]:
        """``{"loss_v": ..., "loss_vc": ...}`` per sample; ``values``: the critics' values if the caller has them."""
        out = {}
        for signal in self.agent.critics:
            target = mb[keys.SIGNALS[signal][3]]
            value = self.agent.value(signal, mb) if values is None else values[signal]
            out[LOSS_NAMES[signal]] = (value - target).pow(2)
        return out

    def losses(self, mb: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Each critic's mean squared error on the minibatch."""
        return {name: terms.mean() for name, terms in self.terms(mb).items()}

    def target_keys(self) -> list[str]:
        """The value targets a minibatch must carry."""
        return [keys.SIGNALS[signal][3] for signal in self.agent.critics]


STATS = ("loss_pi", "loss_v", "loss_vc", "entropy", "kl", "clip_fraction")


class PPO:
    name = "ppo"
    stats = STATS  # what update() returns besides lagrange_multiplier: metrics.csv's columns
    # The lambda metrics.csv logs: plain PPO prices no cost. A constrained variant (ppo_lag.py, FOCOPS, CUP, CRPO)
    # measures J_c and keeps its multiplier itself (``before_advantage``, its state_dict).
    lagrange_multiplier: float | list[float] = 0.0

    def __init__(self, cfg: PPOConfig, agent: Agent) -> None:
        self.cfg, self.agent = cfg, agent
        self.gae = TwinGAE(cfg.gamma, cfg.cost_gamma, cfg.gae_lambda)
        self.log_clip = (math.log1p(-cfg.clip_epsilon), math.log1p(cfg.clip_epsilon))
        self.critics = CriticRegression(agent)
        self.kl_limit = None if cfg.target_kl is None else KL_STOP * cfg.target_kl
        self.actor_params = list(agent.actor.parameters())
        self.critic_params = list(agent.critics.parameters())
        self.actor_opt = torch.optim.Adam(self.actor_params, lr=cfg.lr, fused=True)
        self.critic_opt = torch.optim.Adam(self.critic_params, lr=cfg.critic_lr, fused=True)
        self.iteration = 0  # updates done: the learning-rate schedule's clock (anneal_lr)
        self.entropy_coef = cfg.entropy_coef

    def learning_rates(self) -> tuple[float, float]:
        """The actor's and critics' rates at iteration i: ``anneal_lr`` (n iterations) scales them by ``1 - i / n``."""
        frac = max(0.0, 1.0 - self.iteration / self.cfg.anneal_lr) if self.cfg.anneal_lr else 1.0
        return frac * self.cfg.lr, frac * self.cfg.critic_lr

    def update(self, batch: TensorDictBase) -> dict[str, float]:
        if self.cfg.anneal_lr:
            self.actor_opt.param_groups[0]["lr"], self.critic_opt.param_groups[0]["lr"] = self.learning_rates()
        stats = ppo_update([self], batch, SingleLearner(self.agent, self.cfg.max_grad_norm))[0]
        check_parameters_finite(self.agent)
        return stats

    # --- what the variants change -------------------------------------------------------------
    def before_advantage(self, batch: TensorDictBase) -> None:
        """On this member's rows, before its policy advantage: a constrained variant measures J_c and moves its
        multiplier here."""

    def policy_advantage(self, batch: TensorDictBase) -> torch.Tensor:
        return batch.get(keys.ADVANTAGE)

    def policy_terms(self, dist: D.Distribution, mb: Units) -> tuple[torch.Tensor, Units]:
        """The policy loss per sample, ``-min(r A, clip(r, 1 - eps, 1 + eps) A)`` with
        ``r = pi(a|s) / pi_old(a|s)`` (eq. 7, clipped in log-ratio space as ClipPPOLoss), and diagnostics
        without a graph: the KL estimate ``log pi_old - log pi``, the one early stopping reads,
        ``(r - 1) - log r`` (never negative: Schulman 2020, "Approximating KL Divergence"), and clipping."""
        log_prob = dist.log_prob(mb[keys.ACTION])
        old_log_prob, adv = mb[keys.LOG_PROB], mb[keys.POLICY_ADVANTAGE]
        log_ratio = (log_prob - old_log_prob).reshape(adv.shape)
        log_ratio_clip = log_ratio.clamp(*self.log_clip)
        gain = torch.minimum(log_ratio.exp() * adv, log_ratio_clip.exp() * adv)
        with torch.no_grad():
            diagnostics = {
                "kl": old_log_prob - log_prob,
                "clip_fraction": (log_ratio_clip != log_ratio).float(),
                "kl_stop": log_ratio.exp() - 1 - log_ratio,
            }
        return -gain, diagnostics

    def second_stage(self, algos: Sequence[PPO], rows: Sequence[TensorDictBase], learner: Learner) -> Units:
        """A stage after the epochs for every member, on its ``rows``: its statistics' means (CUP's projection)."""
        return {}

    def iteration_stats(self) -> dict[str, float]:
        """A variant's ``stats`` beyond the minibatch loop's (CRPO's ``cost_step``)."""
        return {}

    # --- around the epochs, per member --------------------------------------------------------
    def prepare(self, batch: TensorDictBase) -> torch.Tensor:
        """After GAE, on this member's rows: what a variant measures first, the (standardised) policy advantage."""
        self.before_advantage(batch)
        adv = self.policy_advantage(batch)
        if self.cfg.normalize_advantage:
            adv = standardized(adv)
        return adv

    def finish(self, means: dict[str, float]) -> dict[str, float]:
        """After the minibatches: the logged statistics (checked finite), and the clock advanced."""
        stats = {k: v for k, v in means.items() if k in self.stats}
        check_finite(**stats)
        stats["lagrange_multiplier"] = self.lagrange_multiplier
        stats.update(self.iteration_stats())
        self.iteration += 1
        return stats

    def update_keys(self, batch: TensorDictBase) -> list:
        """The batch entries the minibatch loop reads."""
        fixed = [keys.ACTION, keys.LOG_PROB, keys.POLICY_ADVANTAGE, *self.critics.target_keys()]
        present = batch.keys(True)
        return [*fixed, *(k for k in self.agent.in_keys if k in present and k not in fixed)]

    # --- checkpointing --------------------------------------------------------------------------
    def state_dict(self) -> dict:
        return {
            "networks": self.agent.state_dict(),
            "actor_opt": self.actor_opt.state_dict(),
            "critic_opt": self.critic_opt.state_dict(),
            "iteration": self.iteration,
        }

    def load_state_dict(self, state: dict) -> None:
        self.agent.load_state_dict(state["networks"])
        self.actor_opt.load_state_dict(state["actor_opt"])
        self.critic_opt.load_state_dict(state["critic_opt"])  # an older checkpoint's own J_c window is not read
        self.iteration = int(state["iteration"])


def ppo_update(algos: Sequence[PPO], batch: TensorDictBase, learner: Learner) -> list[dict[str, float]]:
    """One iteration of every member on its rows of the ``[N, T]`` batch; returns each member's statistics."""
    ppo, cfg = algos[0], algos[0].cfg
    ppo.gae(batch, learner.agent)  # A_r, A_c and the critics' targets V^targ = A + V, every member's rows at once
    rows = member_rows(batch, len(algos))
    # Each member's policy advantage A (PPO: A_r; ppo_lag: (A_r - lam A_c) / (1 + lam), after J_c moved lam).
    batch.set(keys.POLICY_ADVANTAGE, joined([a.prepare(r) for a, r in zip(algos, rows)]))
    units = learner.agent.training_units({k: batch.get(k) for k in ppo.update_keys(batch)})
    mean, optimisers = learner.mean, learner.optimisers(algos)  # the reducer: torch.mean for a run
    entropy_coef = learner.per_member([a.entropy_coef for a in algos])
    kl_limit = None if ppo.kl_limit is None else learner.per_member([a.kl_limit for a in algos])
    tally, active = Tally(), True
    for _ in range(cfg.update_epochs):
        for mb in learner.minibatches(units, cfg.num_minibatches, active):  # a fresh order each epoch
            dist, values = learner.forward(mb)  # pi_theta(.|s) and the critics' V_r(s), V_c(s)
            # Clipped surrogate (eq. 7): L^CLIP = E[min(r A, clip(r, 1 - eps, 1 + eps) A)] with
            # r = pi_theta(a|s) / pi_old(a|s); terms: -min(...) per sample (FOCOPS: its own loss).
            terms, diagnostics = ppo.policy_terms(dist, mb)
            entropy = mean(dist.entropy())
            # Minimised (eq. 9): -L^CLIP - c_2 S[pi_theta] + L^VF for each critic, L^VF = E[(V(s) - V^targ)^2].
            loss_pi = mean(terms) - entropy_coef * entropy
            critic_losses = {k: mean(t) for k, t in ppo.critics.terms(mb, values).items()}
            with torch.no_grad():
                stats = {"loss_pi": loss_pi, **critic_losses, "entropy": entropy}
                stats.update({k: mean(t) for k, t in diagnostics.items()})
            # KL early stopping: once E[(r - 1) - log r] > 1.5 target_kl a member takes no step, on
            # this minibatch or after (a run's loop ends); this minibatch still counts in its stats.
            evaluated = active
            if kl_limit is not None:
                active = active & ~(stats["kl_stop"] > kl_limit)
            learner.step(sum(critic_losses.values(), loss_pi), optimisers, active)
            tally.add(stats, evaluated)
            if stopped(active):
                break
        if stopped(active):
            break
    means = tally.means()  # each member's mean over the minibatches it evaluated
    means.update(ppo.second_stage(algos, rows, learner))
    out = []
    for i, (algo, values) in enumerate(zip(algos, member_stats(means, len(algos)))):
        try:
            out.append(algo.finish(values))
        except TrainingDiverged as exc:
            if len(algos) == 1:
                raise
            raise TrainingDiverged(f"agent {i}: {exc}") from exc
    return out


register("algo", "ppo", PPOConfig, PPO)
