"""Constrained Policy Optimization (Achiam, Held, Tamar, Abbeel, 2017, "Constrained Policy
Optimization", ICML; Section 6 and Algorithm 1).

Each iteration solves the approximate CPO update around the policy ``pi_k`` that collected the
batch (Section 6), with ``x = theta - theta_k``::

    max_x  g^T x    s.t.   c + b^T x <= 0,    1/2 x^T H x <= delta

``g`` and ``b`` are the gradients of the reward and cost surrogates (importance-weighted GAE
advantages), ``H`` is the Fisher information of the policy (the Hessian of the mean KL, used only
through products ``H v``) and ``delta`` is ``algo.target_kl``. With ``q = g^T H^-1 g``,
``r = g^T H^-1 b``, ``s = b^T H^-1 b`` the problem has the two-variable dual of Theorem 2,
solved in closed form by :func:`solve_dual`; it has three cases:

- ``TRPO`` (case 0): the whole trust region satisfies the linearised constraint (or the cost has
  no gradient): the constraint is inactive and the step is the natural gradient step of TRPO.
- ``CONSTRAINED`` (case 1): feasible, and the constraint may bind: ``x* = H^-1 (g - nu* b) / lambda*``.
- ``RECOVERY`` (case 2): no point of the trust region satisfies the linearised constraint: the
  step purely reduces cost, ``x = -sqrt(2 delta / s) H^-1 b`` (the paper's recovery rule for
  infeasible iterates, Section 6).

A backtracking line search then shrinks the step until the sampled KL is within ``delta`` and the
cost surrogate stays within what the case allows (Algorithm 1). Both critics regress on their GAE
value targets, as in the paper's experiments.

Signs: ``g`` and ``b`` are gradients of quantities that increase (reward, cost), so maximising the
dual over nu gives ``nu* = max(0, (lambda c + r) / s)`` (derived in :func:`solve_dual`; the tests
check the step against a brute-force solution of the subproblem).

One constraint only: an env with K > 1 costs is refused with a config error. With K linearised
constraints the dual is a QP in K + 1 variables (lambda and nu_1..nu_K, Achiam et al. 2017, eq. 10
with B a matrix) with no closed form like Theorem 2's, and the recovery step must choose which
constraints to restore; solving it (and testing it against a brute-force solution as the K = 1
case is) is future work, not a guess to ship.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, ClassVar, Callable

import torch
from tensordict import TensorDictBase
from torch import nn
from torch.distributions import kl_divergence

from cmdp_rl import keys
from cmdp_rl.advantages import TwinGAE
from cmdp_rl.algos.base import AlgoConfig, check_finite, check_parameters_finite, per_constraint
from cmdp_rl.algos.conjugate_gradient import conjugate_gradient
from cmdp_rl.algos.critics import CriticRegression
from cmdp_rl.algos.episode_cost import EpisodeCostEstimate
from cmdp_rl.algos.minibatch import minibatches
from cmdp_rl.policies.agent import Agent
from cmdp_rl.registry import register
from cmdp_rl.validation import Field, NonNegativeFloat, PositiveInt, UnitOpen, options, require

if TYPE_CHECKING:
    from cmdp_rl.config import RunConfig


@options
class CPOConfig(AlgoConfig):
    """Constrained Policy Optimization (Achiam, Held, Tamar, Abbeel 2017)."""

    name: str = "cpo"
    target_kl: Annotated[float, Field(gt=0, allow_inf_nan=False,
                                      description="a positive number (the KL radius delta)")] = 0.01
    cg_iters: PositiveInt = 10
    cg_damping: NonNegativeFloat = 0.1
    line_search_steps: PositiveInt = 10
    backtrack_coef: UnitOpen = 0.8
    critic_epochs: PositiveInt = 10
    critic_minibatches: PositiveInt = 8
    # The constraint step compares the cost surrogate with J_c - d in raw units: no cost scaling.
    reads_raw_cost: ClassVar[bool] = True

    def check(self, run: RunConfig) -> None:
        batch = run.rollout_steps * run.env.num_envs
        require(batch >= self.critic_minibatches, "algo.critic_minibatches",
                f"at most rollout_steps * env.num_envs = {batch}", self.critic_minibatches)


TRPO, CONSTRAINED, RECOVERY = 0, 1, 2
CASE_NAMES = {TRPO: "trpo", CONSTRAINED: "constrained", RECOVERY: "recovery"}
_EPS = 1e-8


@dataclass
class DualSolution:
    """The case and the optimal dual variables of the CPO subproblem."""

    case: int
    lam: float  # trust-region multiplier; 0 in RECOVERY (the reward is ignored there)
    nu: float  # cost multiplier; in RECOVERY the coefficient of the pure cost step -nu H^-1 b


def solve_dual(q: float, r: float, s: float, c: float, delta: float) -> DualSolution:
    """Solve the dual of the CPO subproblem in closed form.

    The dual (Theorem 2) is ``max_{lambda >= 0, nu >= 0}  -(q - 2 r nu + s nu^2) / (2 lambda) + nu c
    - lambda delta``. For fixed lambda its maximiser is ``nu = max(0, (lambda c + r) / s)``.
    Where that is positive, substituting gives ``f_a(lambda) = -(A / lambda + B lambda) / 2 + r c / s``
    with ``A = q - r^2 / s``, ``B = 2 delta - c^2 / s``; where it is 0, ``f_b(lambda) =
    -(q / lambda + 2 delta lambda) / 2``. Both are concave, so their maximisers ``sqrt(A / B)`` and
    ``sqrt(q / (2 delta))`` projected onto their intervals of lambda give the best point of each
    piece; the dual optimum is the better of the two.
    """
    if s <= _EPS:  # the cost surrogate has no gradient: nothing to trade against; plain TRPO
        return DualSolution(TRPO, math.sqrt(q / (2 * delta)) + _EPS, 0.0)
    B = 2 * delta - c * c / s
    if c < 0 and B < 0:  # |c| > sqrt(2 delta s): even the costliest point of the trust region is feasible
        return DualSolution(TRPO, math.sqrt(q / (2 * delta)) + _EPS, 0.0)
    if B < 0:  # c > sqrt(2 delta s): the cheapest point of the trust region is still infeasible
        return DualSolution(RECOVERY, 0.0, math.sqrt(2 * delta / s))
    A = max(q - r * r / s, 0.0)  # >= 0 by Cauchy-Schwarz in the H^-1 inner product
    # Intervals of lambda > 0 on which nu* > 0 (piece a) and nu* = 0 (piece b): lambda c + r > 0.
    inf = math.inf
    if abs(c) <= _EPS:
        piece_a, piece_b = ((0.0, inf), None) if r > 0 else (None, (0.0, inf))
    else:
        lam_mid = -r / c
        if c > 0:
            piece_a, piece_b = ((max(lam_mid, 0.0), inf), (0.0, lam_mid) if lam_mid > 0 else None)
        else:
            piece_a, piece_b = ((0.0, lam_mid) if lam_mid > 0 else None, (max(lam_mid, 0.0), inf))

    def f_a(lam: float) -> float:
        return -0.5 * (A / lam + B * lam) + r * c / s

    def f_b(lam: float) -> float:
        return -0.5 * (q / lam + 2 * delta * lam)

    candidates = []
    if piece_a is not None:
        lam_a = math.sqrt(A / B) if B > _EPS else inf  # B = 0: f_a increases in lambda
        lam_a = min(max(lam_a, piece_a[0], _EPS), piece_a[1])
        if math.isfinite(lam_a):
            candidates.append((f_a(lam_a), lam_a))
    if piece_b is not None:
        lam_b = min(max(math.sqrt(q / (2 * delta)), piece_b[0], _EPS), piece_b[1])
        candidates.append((f_b(lam_b), lam_b))
    _, lam = max(candidates)
    nu = max(0.0, (lam * c + r) / s)
    return DualSolution(CONSTRAINED, lam, nu)


def fisher_vector_product(
    kl: torch.Tensor, params: list[nn.Parameter], damping: float
) -> Callable[[torch.Tensor], torch.Tensor]:
    """``v -> (H + damping I) v`` with ``H`` the Hessian of ``kl`` (the mean KL from the old policy,
    whose value and gradient are 0 at the old parameters, so its Hessian there is the Fisher
    matrix). Double backprop: one graph for ``grad kl``, then one backward of ``grad kl . v`` per
    product; the matrix is never formed."""
    grads = torch.autograd.grad(kl, params, create_graph=True)
    flat_grad = torch.cat([g.reshape(-1) for g in grads])

    def fvp(v: torch.Tensor) -> torch.Tensor:
        hv = torch.autograd.grad(flat_grad @ v, params, retain_graph=True)
        return torch.cat([h.reshape(-1) for h in hv]) + damping * v

    return fvp


class CPO:
    name = "cpo"
    # What update() returns besides lagrange_multiplier (metrics.csv's columns): the subproblem's
    # case (0 trpo, 1 constrained, 2 recovery), the accepted fraction of the full step (0: none
    # accepted), the dual's trust-region and cost multipliers, the accepted step's change of the
    # reward and cost surrogates, and the critics' losses.
    stats = ("loss_v", "loss_vc", "entropy", "kl", "cpo_case", "step_fraction", "dual_lambda", "dual_nu",
             "surr_reward_change", "surr_cost_change")

    def __init__(self, cfg: CPOConfig, agent: Agent) -> None:
        k = agent.num_costs
        require(k == 1, "algo", f"ppo, penalty, ppo_lag or pid_lag for an env with {k} costs "
                                f"({', '.join(agent.cost_names)}): cpo's closed-form dual handles one constraint", "cpo")
        (self.cost_limit,) = per_constraint(cfg.cost_limit, "algo.cost_limit", agent.cost_names)
        self.cfg = cfg
        self.agent = agent
        self.gae = TwinGAE(cfg.gamma, cfg.cost_gamma, cfg.gae_lambda)
        self.policy_params = list(agent.actor.parameters())
        self.critic_params = list(agent.critics.parameters())
        self.critic_opt = torch.optim.Adam(self.critic_params, lr=cfg.critic_lr)
        self.critics = CriticRegression(agent)
        self.nu = 0.0
        # J_c and the mean episode length the constraint is measured with (algos/episode_cost.py):
        # an unfinished episode's cost so far is only a lower bound of its cost, so batches in
        # which no episode ended (1000-step episodes, 256-step rollouts) use the last episodes
        # that did end.
        self.episode_cost = EpisodeCostEstimate()

    @property
    def lagrange_multiplier(self) -> float:
        """The dual's cost multiplier nu of the last step."""
        return self.nu

    def update(self, batch: TensorDictBase) -> dict[str, float]:
        """One CPO iteration on a ``[N, T]`` batch from the collector; returns scalars to log."""
        self.gae(batch, self.agent)
        estimate = self.episode_cost.update(batch)
        # Training units: steps, or segments [U, L] for a recurrent policy (run in recurrent mode).
        needed = [*self.agent.in_keys, keys.ACTION, keys.LOG_PROB, *self.agent.actor.head.param_keys,
                  keys.ADVANTAGE, keys.COST_ADVANTAGE, *self.critics.target_keys()]
        present = batch.keys(True)
        units = self.agent.training_units({k: batch.get(k) for k in dict.fromkeys(needed) if k in present})
        stats = self.policy_step(units, estimate.cost, estimate.length)
        stats.update(self.fit_critics(units))
        check_parameters_finite(self.agent)
        stats["lagrange_multiplier"] = self.nu
        return stats

    def policy_step(self, units: dict[str, torch.Tensor], episode_cost: float, episode_length: float) -> dict[str, float]:
        """Solve the CPO subproblem on training units (steps, or segments for a recurrent policy)
        carrying GAE advantages and take the step the line search accepts (or none)."""
        cfg, agent, params = self.cfg, self.agent, self.policy_params
        adv = units[keys.ADVANTAGE]
        if cfg.normalize_advantage:
            adv = (adv - adv.mean()) / (adv.std() + 1e-8)
        # The cost advantage is only centred: its scale must stay that of cost, to compare with c.
        cost_adv = units[keys.COST_ADVANTAGE] - units[keys.COST_ADVANTAGE].mean()
        action, old_log_prob = units[keys.ACTION], units[keys.LOG_PROB]
        # pi_k is the policy that collected the batch: its loc/scale are in the batch.
        head = agent.actor.head
        old_dist = head.dist({k: units[k] for k in head.param_keys})

        def surrogates() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
            dist = agent.dist(units)
            ratio = torch.exp(dist.log_prob(action) - old_log_prob).reshape(adv.shape)
            return (ratio * adv).mean(), (ratio * cost_adv).mean(), kl_divergence(old_dist, dist).mean()

        reward_surr, cost_surr, kl = surrogates()
        g = _flat(torch.autograd.grad(reward_surr, params, retain_graph=True))
        b = _flat(torch.autograd.grad(cost_surr, params, retain_graph=True))
        fvp = fisher_vector_product(kl, params, cfg.cg_damping)
        h_inv_g = conjugate_gradient(fvp, g, cfg.cg_iters)
        h_inv_b = conjugate_gradient(fvp, b, cfg.cg_iters)
        q, r, s = g.dot(h_inv_g).item(), g.dot(h_inv_b).item(), b.dot(h_inv_b).item()
        # The budget is on the expected undiscounted episode cost J_c; the surrogate is a per-step
        # mean. Summed over an episode (T steps on average, sampled on-policy), the surrogate's
        # change predicts the change of J_c (the performance-difference identity in its
        # undiscounted episodic form), so J_c + T * dL_c <= d reads dL_c <= -(J_c - d) / T:
        # c = (J_c - d) / T in the surrogate's per-step units. (The paper's discounted form has
        # 1 / (1 - gamma) where an episodic budget has the mean episode length T.)
        c = (episode_cost - self.cost_limit) / max(episode_length, 1.0)
        check_finite(reward_gradient=g.norm(), cost_gradient=b.norm(), q=q, r=r, s=s, c=c)

        sol = solve_dual(q, r, s, c, cfg.target_kl)
        if sol.case == RECOVERY:
            step = -sol.nu * h_inv_b
        else:
            step = (h_inv_g - sol.nu * h_inv_b) / sol.lam
        self.nu = sol.nu

        # Backtracking line search (Section 6.3): accept the first fraction whose sampled KL is
        # within delta and whose cost surrogate change is what the case allows: in RECOVERY it
        # must fall; otherwise it may rise by the slack -c if there is one, and must not rise when
        # the current policy is over budget. Where the current policy is feasible (c < 0) the
        # optimum improves the reward surrogate, so the step must do that too.
        theta0 = nn.utils.parameters_to_vector(params).detach()
        old_reward, old_cost = reward_surr.item(), cost_surr.item()
        accepted = {"step_fraction": 0.0, "kl": 0.0, "surr_reward_change": 0.0, "surr_cost_change": 0.0}
        with torch.no_grad():
            for j in range(cfg.line_search_steps):
                fraction = cfg.backtrack_coef**j
                _assign(params, theta0 + fraction * step)
                new_reward, new_cost, new_kl = (t.item() for t in surrogates())
                d_reward, d_cost = new_reward - old_reward, new_cost - old_cost
                if sol.case == RECOVERY:
                    cost_ok = d_cost < 0
                else:
                    cost_ok = d_cost <= max(-c, 0.0)
                reward_ok = sol.case == RECOVERY or c >= 0 or d_reward > 0
                if math.isfinite(new_kl) and new_kl <= cfg.target_kl and cost_ok and reward_ok:
                    accepted = {"step_fraction": fraction, "kl": new_kl,
                                "surr_reward_change": d_reward, "surr_cost_change": d_cost}
                    break
            else:
                _assign(params, theta0)  # no acceptable step: stay at pi_k
            entropy = agent.dist(units).entropy().mean().item()
        return {"cpo_case": sol.case, "dual_lambda": sol.lam, "dual_nu": sol.nu, "entropy": entropy, **accepted}

    def fit_critics(self, units: dict[str, torch.Tensor]) -> dict[str, float]:
        """Regress the critics on their GAE value targets (minibatch Adam)."""
        cfg = self.cfg
        sums: dict[str, float] = {}
        n = 0
        for _, mb in minibatches(units, cfg.critic_minibatches, cfg.critic_epochs):
            losses = self.critics.losses(mb)
            check_finite(**losses)
            self.critic_opt.zero_grad(set_to_none=True)
            total = None
            for loss in losses.values():
                total = loss if total is None else total + loss
            total.backward()
            nn.utils.clip_grad_norm_(self.critic_params, cfg.max_grad_norm)
            self.critic_opt.step()
            for k, v in losses.items():
                sums[k] = sums.get(k, 0.0) + v.item()
            n += 1
        return {k: v / n for k, v in sums.items()}

    def state_dict(self) -> dict:
        return {"networks": self.agent.state_dict(), "critic_opt": self.critic_opt.state_dict(), "nu": self.nu,
                "episode_cost": self.episode_cost.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        self.agent.load_state_dict(state["networks"])
        self.critic_opt.load_state_dict(state["critic_opt"])
        self.nu = float(state["nu"])
        if "episode_cost" in state:
            self.episode_cost.load_state_dict(state["episode_cost"])
        elif state.get("episode_estimate") is not None:  # a checkpoint from before the shared estimate:
            self.episode_cost.load_state_dict({"recent": [tuple(state["episode_estimate"])]})  # its last J_c


def _flat(tensors: tuple[torch.Tensor, ...]) -> torch.Tensor:
    return torch.cat([t.reshape(-1) for t in tensors])


@torch.no_grad()
def _assign(params: list[nn.Parameter], flat: torch.Tensor) -> None:
    """Copy a flat vector into the parameters, in place. (``nn.utils.vector_to_parameters``
    rebinds each parameter to a view of the vector: a different memory alignment, which changes the
    rounding of the BLAS kernels, so a resumed run, whose parameters are fresh tensors, would drift
    from an uninterrupted one in the last bits.)"""
    offset = 0
    for p in params:
        p.copy_(flat[offset:offset + p.numel()].view_as(p))
        offset += p.numel()


register("algo", "cpo", CPOConfig, CPO)
