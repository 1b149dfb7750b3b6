"""Constrained Update Projection (Yang, Ji, Dai, Zhang, Zhou, Li, Yang, Pan, 2022, NeurIPS; Algorithm 1,
cited by name: docs/references.md). Two stages per iteration:

1. ``pi_{k+1/2}`` by PPO's clipped surrogate on ``A_r`` (the paper's practical version; critics included).
2. Projection: ``pi_{k+1}`` minimises, from ``pi_{k+1/2}``::

       E_s[ KL(pi_theta || pi_{k+1/2})[s] ]
         + nu * (1 - gamma_c gae_lambda) / (1 - gamma_c) * E[ pi_theta(a|s) / pi_k(a|s) A_c(s, a) ]

   With ``nu = 0`` the minimiser is ``pi_{k+1/2}`` itself, so the stage runs its own Adam, fresh every
   iteration: earlier momentum would move the policy with a zero gradient (tests/test_cup.py).

``nu`` by ``algo.multiplier``; ``A_c`` standardized when ``normalize_advantage`` is. One cost signal.
"""

from __future__ import annotations

from dataclasses import field
from typing import TYPE_CHECKING, ClassVar, Sequence

import torch
from tensordict import TensorDictBase
from torch.distributions import Distribution, kl_divergence

from cmdp_rl.algos.base import single_constraint
from cmdp_rl.algos.learner import Learner
from cmdp_rl.algos.minibatch import Tally, joined, stopped
from cmdp_rl.algos.multiplier import EpisodeCost, EpisodeCostEstimate, logged_multiplier, step
from cmdp_rl.algos.multiplier_options import DualOptions, MultiplierConfig
from cmdp_rl.algos.ppo import PPO, STATS, PPOConfig
from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import AUTO, AutoInt, options
from cmdp_rl.policies.agent import Agent
from cmdp_rl.rollout import keys
from cmdp_rl.rollout.advantages import standardized

if TYPE_CHECKING:
    from cmdp_rl.config.run_config import RunConfig

HALF = "cup_half"  # key prefix of pi_{k+1/2}'s distribution parameters in the projection's units


@options
class CUPConfig(PPOConfig):
    """CUP (Yang et al. 2022): PPO on A_r, then a projection that trades KL for cost."""

    name: str = "cup"
    deploys: ClassVar[str] = "mixture"  # deploy.policy=auto (AlgoConfig.deploys)
    constraints: ClassVar[int] = 1  # one constraint (single_constraint)
    multiplier: MultiplierConfig = field(default_factory=DualOptions)  # nu

    projection_epochs: AutoInt = AUTO  # auto: update_epochs

    def resolve_auto(self, run: RunConfig) -> None:
        super().resolve_auto(run)
        if self.projection_epochs == AUTO:
            self.projection_epochs = self.update_epochs


class CUP(PPO):
    name = "cup"
    # loss_projection: the stage-2 loss; kl_projection: KL(pi_theta || pi_{k+1/2}) during it.
    stats = (*STATS, "loss_projection", "kl_projection")

    def __init__(self, cfg: CUPConfig, agent: Agent) -> None:
        cost_limit = single_constraint(cfg.cost_limit, agent, "cup", "cup has one cost multiplier nu")
        super().__init__(cfg, agent)
        self.multiplier = cfg.multiplier.build(cost_limit)
        self.episode_cost = EpisodeCostEstimate()  # J_c, measured on each batch before the policy advantage
        self.cost_coef = (1 - cfg.cost_gamma * cfg.gae_lambda) / (1 - cfg.cost_gamma)

    def update_multiplier(self, estimate: EpisodeCost) -> None:
        step(self.multiplier, estimate)

    def before_advantage(self, batch: TensorDictBase) -> None:
        self.update_multiplier(self.episode_cost.update(batch))

    @property
    def lagrange_multiplier(self) -> float | list[float]:
        return logged_multiplier(self.multiplier.values)

    def state_dict(self) -> dict:
        own = {"episode_cost": self.episode_cost.state_dict(), "multiplier": self.multiplier.state_dict()}
        return {**super().state_dict(), **own}

    def load_state_dict(self, state: dict) -> None:
        super().load_state_dict(state)
        self.episode_cost.load_state_dict(state["episode_cost"])
        self.multiplier.load_state_dict(state["multiplier"])

    def second_stage(self, algos: Sequence[CUP], rows: Sequence[TensorDictBase], learner: Learner) -> dict:
        """Stage 2 of every member in minibatch epochs as PPO's, KL early stopping included: mean loss and KL."""
        cfg = self.cfg
        units = learner.agent.training_units(joined([a.projection_inputs(r) for a, r in zip(algos, rows)]))
        with torch.no_grad():  # pi_{k+1/2}: the actor as stage 1 left it
            units.update({(HALF, k): v for k, v in learner.actor_params(units).items()})
        # The cost surrogate's weight: nu (1 - gamma_c gae_lambda) / (1 - gamma_c), one per member.
        nu_coef = learner.per_member([a.multiplier.value * a.cost_coef for a in algos])
        kl_limit = None if self.kl_limit is None else learner.per_member([a.kl_limit for a in algos])
        optimiser = learner.fresh_actor_optimiser(algos)  # fresh: see the module's docstring
        tally, active = Tally(), True
        for _ in range(cfg.projection_epochs):
            for mb in learner.minibatches(units, cfg.num_minibatches, active):
                terms, kl_terms = self.projection_terms(learner.dist(mb), mb, nu_coef)
                loss, kl = learner.mean(terms), learner.mean(kl_terms)
                evaluated = active
                if kl_limit is not None:
                    active = active & ~(kl.detach() > kl_limit)
                learner.step(loss, optimiser, active)
                tally.add({"loss_projection": loss, "kl_projection": kl}, evaluated)
                if stopped(active):
                    break
            if stopped(active):
                break
        return tally.means()

    def projection_inputs(self, batch: TensorDictBase) -> dict:
        """Stage 2's inputs from one agent's batch, the cost advantage standardised if ``normalize_advantage``."""
        present, cost_adv = batch.keys(True), batch.get(keys.COST_ADVANTAGE)
        inputs = {k: batch.get(k) for k in (keys.ACTION, keys.LOG_PROB, *self.agent.in_keys) if k in present}
        return {**inputs, keys.COST_ADVANTAGE: standardized(cost_adv) if self.cfg.normalize_advantage else cost_adv}

    def projection_terms(
        self, dist: Distribution, mb: dict[str, torch.Tensor], nu_coef: float | torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Stage 2's loss per sample, ``KL(pi_theta || pi_{k+1/2}) + nu_coef r A_c``, and its KL term."""
        head = self.agent.actor.head
        half = head.dist({k: mb[(HALF, k)] for k in head.param_keys})
        adv = mb[keys.COST_ADVANTAGE]
        kl = kl_divergence(dist, half).reshape(adv.shape)
        ratio = (dist.log_prob(mb[keys.ACTION]) - mb[keys.LOG_PROB]).reshape(adv.shape).exp()
        if isinstance(nu_coef, torch.Tensor):  # a population's, one per agent: over its [P, B, 1] samples
            nu_coef = nu_coef.view(-1, *(1,) * (adv.dim() - 1))
        return kl + nu_coef * ratio * adv, kl


register("algo", "cup", CUPConfig, CUP)
