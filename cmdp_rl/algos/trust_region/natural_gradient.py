"""What the trust-region algorithms (CPO, TRPO-Lagrangian, PCPO) share: the options, the importance-weighted
surrogates around the policy that collected the batch, the Fisher-vector product, conjugate gradient, the
backtracking line search, and the iteration around the policy step (GAE, J_c, critic regression,
checkpointing). Each algorithm is a :class:`NaturalGradient` that writes ``policy_step``. Natural gradient:
Kakade 2001; the trust-region step: Schulman et al. 2015, "Trust Region Policy Optimization", Appendix C.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Annotated, Any, Callable, ClassVar

import torch
from tensordict import TensorDictBase
from torch import nn
from torch.distributions import kl_divergence

from cmdp_rl.algos.base import AlgoConfig, check_finite, check_parameters_finite, require_minibatches
from cmdp_rl.algos.learner import Learner, SingleLearner
from cmdp_rl.algos.minibatch import Tally
from cmdp_rl.algos.multiplier import EpisodeCost, EpisodeCostEstimate, logged_multiplier
from cmdp_rl.algos.ppo import CriticRegression
from cmdp_rl.config.validation import Field, NonNegativeFloat, PositiveInt, options
from cmdp_rl.policies.agent import Agent
from cmdp_rl.rollout import keys
from cmdp_rl.rollout.advantages import TwinGAE, standardized

if TYPE_CHECKING:
    from cmdp_rl.config.run_config import RunConfig


@options
class NaturalGradientConfig(AlgoConfig):
    """The trust region, the conjugate gradient, and the critics' regression."""

    tiny: ClassVar[dict] = {"critic_epochs": 2, "critic_minibatches": 2}  # AlgoConfig.tiny

    target_kl: Annotated[
        float, Field(gt=0, allow_inf_nan=False, description="a positive number (the KL radius delta)")
    ] = 0.01
    cg_iters: PositiveInt = 10
    cg_damping: NonNegativeFloat = 0.1
    critic_epochs: PositiveInt = 10
    critic_minibatches: PositiveInt = 8

    def check(self, run: RunConfig) -> None:
        require_minibatches(run, "critic_minibatches", self.critic_minibatches)
        if hasattr(self, "multiplier"):  # trpo_lag's algo.multiplier node
            self.multiplier.check()


def fisher_vector_product(
    kl: torch.Tensor, params: list[nn.Parameter], damping: float
) -> Callable[[torch.Tensor], torch.Tensor]:
    """``v -> (H + damping I) v``, ``H`` the Hessian of the mean KL ``kl`` (the Fisher matrix), never formed."""
    flat_grad = flat(torch.autograd.grad(kl, params, create_graph=True))

    def fvp(v: torch.Tensor) -> torch.Tensor:
        return flat(torch.autograd.grad(flat_grad @ v, params, retain_graph=True)) + damping * v

    return fvp


def flat(tensors: tuple[torch.Tensor, ...]) -> torch.Tensor:
    return torch.cat([t.reshape(-1) for t in tensors])


def conjugate_gradient(
    matvec: Callable[[torch.Tensor], torch.Tensor], b: torch.Tensor, iters: int, residual_tol: float = 1e-10
) -> torch.Tensor:
    """``A^-1 b`` in at most ``iters`` steps of conjugate gradient, ``A`` symmetric positive definite given
    as a product (Nocedal & Wright, "Numerical Optimization", 2nd ed., Algorithm 5.2): torch's solvers
    need ``A`` as a matrix, and the Fisher matrix is never formed. Stops once ``|r|^2 < residual_tol``."""
    x = torch.zeros_like(b)
    r = b.clone()  # residual b - A x at x = 0
    p = r.clone()
    rr = r.dot(r)
    for _ in range(iters):
        if rr < residual_tol:
            break
        ap = matvec(p)
        alpha = rr / p.dot(ap)
        x += alpha * p
        r -= alpha * ap
        rr_new = r.dot(r)
        p = r + (rr_new / rr) * p
        rr = rr_new
    return x


@torch.no_grad()
def assign(params: list[nn.Parameter], vector: torch.Tensor) -> None:
    """Copy a flat vector into the parameters, in place: ``nn.utils.vector_to_parameters`` rebinds them to
    views of it, whose alignment changes BLAS rounding, so a resumed run would drift in the last bits."""
    offset = 0
    for p in params:
        p.copy_(vector[offset : offset + p.numel()].view_as(p))
        offset += p.numel()


def per_step_constraint(episode_cost: float, cost_limit: float, episode_length: float) -> float:
    """The constraint value ``c = (J_c - d) / T`` in the surrogate's per-step units: over an episode of T
    steps the per-step surrogate's change predicts J_c's (the performance-difference identity, episodic),
    so ``J_c + T dL_c <= d`` reads ``dL_c <= -c``; the papers' discounted form has ``1 / (1 - gamma)``."""
    return (episode_cost - cost_limit) / max(episode_length, 1.0)


class Surrogates:
    """Called: the importance-weighted policy and cost surrogates and the mean KL from ``pi_k``."""

    def __init__(self, agent: Agent, units: dict[str, torch.Tensor], adv: torch.Tensor, cost_adv: torch.Tensor) -> None:
        self.agent, self.units, self.adv, self.cost_adv = agent, units, adv, cost_adv
        head = agent.actor.head
        self.old_dist = head.dist({k: units[k] for k in head.param_keys})

    def __call__(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        units = self.units
        dist = self.agent.dist(units)
        ratio = torch.exp(dist.log_prob(units[keys.ACTION]) - units[keys.LOG_PROB]).reshape(self.adv.shape)
        return (ratio * self.adv).mean(), (ratio * self.cost_adv).mean(), kl_divergence(self.old_dist, dist).mean()


STATS = ("loss_v", "loss_vc", "entropy", "kl")  # every trust-region algorithm's, first
NO_STEP = {"step_fraction": 0.0, "kl": 0.0, "surr_reward_change": 0.0, "surr_cost_change": 0.0}


@torch.no_grad()
def line_search(
    params: list[nn.Parameter],
    step: torch.Tensor,
    surrogates: Surrogates,
    old: tuple[float, float],
    target_kl: float,
    steps: int,
    coef: float,
    accept: Callable[[float, float], bool],
) -> dict[str, float]:
    """Backtracking line search (Schulman et al. 2015, Appendix C): the first of the fractions 1, coef,
    coef^2, ... of ``step`` whose sampled KL is finite and within ``target_kl`` and whose surrogates'
    changes ``accept(d_reward, d_cost)`` takes, else no step. Returns the fraction (0: none), its KL
    and the surrogates' changes."""
    theta0 = nn.utils.parameters_to_vector(params).detach()
    old_reward, old_cost = old
    for j in range(steps):
        fraction = coef**j
        assign(params, theta0 + fraction * step)
        new_reward, new_cost, new_kl = (t.item() for t in surrogates())
        d_reward, d_cost = new_reward - old_reward, new_cost - old_cost
        if math.isfinite(new_kl) and new_kl <= target_kl and accept(d_reward, d_cost):
            return {"step_fraction": fraction, "kl": new_kl, "surr_reward_change": d_reward, "surr_cost_change": d_cost}
    assign(params, theta0)  # no acceptable step: stay at pi_k
    return dict(NO_STEP)


class NaturalGradient:
    """A trust-region iteration: GAE, J_c, the policy step the subclass writes, the critics' regression."""

    name = "natural_gradient"
    stats: tuple[str, ...] = ()
    multiplier: Any = None  # trpo_lag's lambda (multiplier.py), logged and checkpointed

    def __init__(self, cfg: NaturalGradientConfig, agent: Agent) -> None:
        self.cfg, self.agent = cfg, agent
        self.gae = TwinGAE(cfg.gamma, cfg.cost_gamma, cfg.gae_lambda)
        self.policy_params = list(agent.actor.parameters())
        self.critic_params = list(agent.critics.parameters())
        self.critic_opt = torch.optim.Adam(self.critic_params, lr=cfg.critic_lr)
        self.critics = CriticRegression(agent)
        self.episode_cost = EpisodeCostEstimate()

    @property
    def lagrange_multiplier(self) -> float | list[float]:
        return 0.0 if self.multiplier is None else logged_multiplier(self.multiplier.values)

    def policy_step(
        self,
        units: dict[str, torch.Tensor],
        episode_cost: float,
        episode_length: float,
        estimate: EpisodeCost | None = None,
    ) -> dict[str, float]:
        """Move the policy on training units carrying GAE advantages (``estimate``: the J_c measurement the costs come
        from, whose window a per-episode multiplier reads); returns its statistics."""
        raise NotImplementedError

    def update(self, batch: TensorDictBase) -> dict[str, float]:
        """One iteration on a ``[N, T]`` batch from the collector; returns scalars to log."""
        self.gae(batch, self.agent)
        units, stats = self.policy_update(batch)
        losses = self.fit_critics(
            units, SingleLearner(self.agent, self.cfg.max_grad_norm), [(self.critic_opt, self.critic_params)]
        )
        stats.update({k: v.item() for k, v in losses.items()})
        check_parameters_finite(self.agent)
        stats["lagrange_multiplier"] = self.lagrange_multiplier
        return stats

    def policy_update(self, batch: TensorDictBase) -> tuple[dict[str, torch.Tensor], dict[str, float]]:
        """After GAE: J_c, the training units and the policy step; returns the units and the step's statistics."""
        estimate = self.episode_cost.update(batch)
        needed = [*self.agent.in_keys, keys.ACTION, keys.LOG_PROB, *self.agent.actor.head.param_keys]
        needed += [keys.ADVANTAGE, keys.COST_ADVANTAGE, *self.critics.target_keys()]
        present = batch.keys(True)
        units = self.agent.training_units({k: batch.get(k) for k in dict.fromkeys(needed) if k in present})
        # J_c, or K numbers with K constraints (only trpo_lag takes K > 1; the others refuse it when built).
        episode_cost = estimate.costs[0] if len(estimate.costs) == 1 else estimate.costs
        return units, self.policy_step(units, episode_cost, estimate.length, estimate=estimate)

    def linearise(
        self, units: dict[str, torch.Tensor], adv: torch.Tensor, cost_gradient: bool = True
    ) -> tuple[
        Surrogates, tuple[float, float], torch.Tensor, torch.Tensor | None, Callable[[torch.Tensor], torch.Tensor]
    ]:
        """The subproblem at the current policy for the policy advantage ``adv`` (standardised if
        ``normalize_advantage``): the surrogates (for the line search), their values, the gradients ``g``
        (policy) and ``b`` (cost; None without ``cost_gradient``, a backward pass trpo_lag does not need)
        and the Fisher-vector product ``v -> H v``."""
        params = self.policy_params
        cost_adv = units[keys.COST_ADVANTAGE]
        if self.cfg.normalize_advantage:
            adv = standardized(adv)
        # The cost advantage only centred: it stays in cost's units, to compare with the budget.
        surrogates = Surrogates(self.agent, units, adv, cost_adv - cost_adv.mean())
        reward_surr, cost_surr, kl = surrogates()
        g = flat(torch.autograd.grad(reward_surr, params, retain_graph=True))
        b = flat(torch.autograd.grad(cost_surr, params, retain_graph=True)) if cost_gradient else None
        fvp = fisher_vector_product(kl, params, self.cfg.cg_damping)
        return surrogates, (reward_surr.item(), cost_surr.item()), g, b, fvp

    @torch.no_grad()
    def entropy(self, units: dict[str, torch.Tensor]) -> float:
        return self.agent.dist(units).entropy().mean().item()

    def fit_critics(
        self, units: dict[str, torch.Tensor], learner: Learner, optimisers: list
    ) -> dict[str, torch.Tensor]:
        """Critic regression, ``critic_epochs`` x ``critic_minibatches`` Adam steps: each loss's mean (per agent)."""
        cfg, tally = self.cfg, Tally()
        for _ in range(cfg.critic_epochs):
            for mb in learner.minibatches(units, cfg.critic_minibatches):
                losses = {k: learner.mean(t) for k, t in self.critics.terms(mb, learner.values(mb)).items()}
                check_finite(**losses)
                first, *rest = losses.values()
                learner.step(sum(rest, first), optimisers)
                tally.add({k: v.double() for k, v in losses.items()})  # summed in float64, as Python floats would be
        return tally.means()

    def state_dict(self) -> dict:
        state = {
            "networks": self.agent.state_dict(),
            "critic_opt": self.critic_opt.state_dict(),
            "episode_cost": self.episode_cost.state_dict(),
        }
        return state if self.multiplier is None else {**state, "multiplier": self.multiplier.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        self.agent.load_state_dict(state["networks"])
        self.critic_opt.load_state_dict(state["critic_opt"])
        self.episode_cost.load_state_dict(state["episode_cost"])
        if self.multiplier is not None:
            self.multiplier.load_state_dict(state["multiplier"])
