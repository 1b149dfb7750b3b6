"""Constrained Update Projection (Yang, Ji, Dai, Zhang, Zhou, Li, Yang, Pan, 2022, "Constrained
Update Projection Approach to Safe Policy Optimization", NeurIPS; its Algorithm 1). Its stages are
cited by name, without equation or section numbers (docs/references.md).

Two stages per iteration:

1. Policy improvement: ``pi_{k+1/2}`` maximises the reward surrogate near ``pi_k``; as in the
   paper's practical version, PPO's clipped surrogate on ``A_r`` (the whole PPO update of
   ``ppo.py``, critics included).
2. Projection: ``pi_{k+1}`` minimises, from ``pi_{k+1/2}``::

       E_s[ KL(pi_theta || pi_{k+1/2})[s] ]
         + nu * (1 - gamma_c gae_lambda) / (1 - gamma_c) * E[ pi_theta(a|s) / pi_k(a|s) A_c(s, a) ]

   the distance to the improved policy plus the multiplier times the cost surrogate around the
   behaviour policy ``pi_k`` (the factor is the paper's, from its GAE-based bound). With ``nu = 0``
   the minimiser is ``pi_{k+1/2}`` itself, and the stage leaves it unchanged: it runs its own Adam,
   fresh every iteration, since momentum from stage 1 or from earlier projections would move the
   policy with a zero gradient (``tests/test_cup.py``).

``nu`` by projected dual ascent once per iteration, ``nu <- max(0, nu + nu_lr (J_c - d))``
(:class:`~cmdp_rl.algos.lagrange.DualAscent`). ``A_c`` is standardized when
``algo.normalize_advantage`` is, as PPO's advantage is. One cost signal.
"""

from __future__ import annotations

from functools import partial
from typing import TYPE_CHECKING, Any, ClassVar, Sequence

import torch
from tensordict import TensorDictBase
from torch.distributions import Distribution, kl_divergence

from cmdp_rl.algos.base import single_constraint
from cmdp_rl.algos.lagrange import DualAscent
from cmdp_rl.algos.multiplier_options import Scale, violation_scale
from cmdp_rl.algos.ppo import PPO, STATS, PPOConfig, Reduce
from cmdp_rl.algos.update_backend import Backend, joined, run_epochs
from cmdp_rl.config.registry import register
from cmdp_rl.config.validation import AUTO, AutoInt, NonNegativeFloat, PositiveFloat, options
from cmdp_rl.policies.agent import Agent
from cmdp_rl.rollout import keys
from cmdp_rl.rollout.advantages import standardized
from cmdp_rl.rollout.episode_cost import EpisodeCost

if TYPE_CHECKING:
    from cmdp_rl.config.run_config import RunConfig

HALF = "cup_half"  # key prefix of pi_{k+1/2}'s distribution parameters in the projection's units


@options
class CUPConfig(PPOConfig):
    """CUP (Yang et al. 2022): PPO on A_r, then a projection that trades KL for cost."""

    name: str = "cup"
    deploys: ClassVar[str] = "mixture"  # final_policy=auto (AlgoConfig.deploys)
    constraints: ClassVar[int] = 1  # one constraint (single_constraint)
    nu_init: NonNegativeFloat = 0.0
    nu_lr: PositiveFloat = 0.05
    nu_scale: Scale = "budget"  # the violation's units: none: J_c - d; budget: (J_c - d) / d
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
        self.multiplier = DualAscent(cost_limit, cfg.nu_lr, cfg.nu_init, violation_scale(cost_limit, cfg.nu_scale))
        self.cost_coef = (1 - cfg.cost_gamma * cfg.gae_lambda) / (1 - cfg.cost_gamma)

    @property
    def lagrange_multiplier(self) -> float:
        return self.multiplier.value

    def update_multiplier(self, estimate: EpisodeCost) -> None:
        self.multiplier.update(estimate.cost)

    def second_stage(self, backend: Backend, algos: Sequence[CUP], rows: Sequence[TensorDictBase]) -> dict:
        """Stage 2 of every member (``algos``, each on its ``rows``, stage 1 done): each member's
        mean loss and KL."""
        cfg = self.cfg
        units = backend.training_units(joined([a.projection_inputs(r) for a, r in zip(algos, rows)]))
        with torch.no_grad():  # pi_{k+1/2}: the actor as stage 1 left it
            units.update({(HALF, k): v for k, v in backend.actor_params(units).items()})
        # fresh: see the docstring; at stage 1's rate (lr, or its annealed value with anneal_lr)
        nu_coef = backend.per_member([a.projection_coef() for a in algos])
        step = partial(self.projection_step, backend, backend.fresh_actor_groups(algos), nu_coef)
        sums, counts = run_epochs(backend, units, cfg.num_minibatches, cfg.projection_epochs, step)
        return {k: v / counts for k, v in sums.items()}

    def projection_step(
        self, backend: Backend, groups: list, nu_coef: float | torch.Tensor, mb: dict, active: Any
    ) -> tuple[dict[str, torch.Tensor], Any]:
        """One minibatch of stage 2 (``nu_coef``: one, or one per agent), stopped as PPO's stage is."""
        loss, kl = self.projection_loss(backend.dist(mb), mb, nu_coef, backend.mean)
        evaluated = active
        active, stepping = backend.stop(kl.detach(), active)
        backend.step(loss, groups, stepping)
        return backend.kept({"loss_projection": loss, "kl_projection": kl}, evaluated), active

    def projection_inputs(self, batch: TensorDictBase) -> dict:
        """What stage 2 reads of one agent's batch: the actions, their behaviour log-probs, the cost
        advantage (standardised if ``normalize_advantage``) and the networks' inputs."""
        cost_adv = batch.get(keys.COST_ADVANTAGE)
        if self.cfg.normalize_advantage:
            cost_adv = standardized(cost_adv)
        present = batch.keys(True)
        inputs = [k for k in self.agent.in_keys if k in present and k not in (keys.ACTION, keys.LOG_PROB)]
        return {
            keys.ACTION: batch.get(keys.ACTION),
            keys.LOG_PROB: batch.get(keys.LOG_PROB),
            keys.COST_ADVANTAGE: cost_adv,
            **{k: batch.get(k) for k in inputs},
        }

    def projection_coef(self) -> float:
        """The cost surrogate's weight in stage 2: ``nu (1 - gamma_c gae_lambda) / (1 - gamma_c)``."""
        return self.multiplier.value * self.cost_coef

    def projection_loss(
        self, dist: Distribution, mb: dict[str, torch.Tensor], nu_coef: float | torch.Tensor, mean: Reduce
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Stage 2's loss and ``KL(pi_theta || pi_{k+1/2})``, each reduced by ``mean`` (over the
        minibatch, or per agent in a population, ``nu_coef`` then one per agent)."""
        head = self.agent.actor.head
        half = head.dist({k: mb[(HALF, k)] for k in head.param_keys})
        adv = mb[keys.COST_ADVANTAGE]
        kl = kl_divergence(dist, half).reshape(adv.shape)
        ratio = (dist.log_prob(mb[keys.ACTION]) - mb[keys.LOG_PROB]).reshape(adv.shape).exp()
        return mean(kl + nu_coef * ratio * adv), mean(kl)

    def state_dict(self) -> dict:
        return {**super().state_dict(), "multiplier": self.multiplier.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        super().load_state_dict(state)
        self.multiplier.load_state_dict(state["multiplier"])


register("algo", "cup", CUPConfig, CUP)
