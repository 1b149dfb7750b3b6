"""Multiplier updates built to converge in the last iterate, not only on average.

Plain projected dual ascent (lagrange.DualAscent) orbits the saddle point of the Lagrangian: the
classical guarantees hold for the average of the iterates, and when the optimum is a randomised
policy the Lagrangian's maximisers at lambda* lie on both sides of the budget, so the last policy
swings over and under it. Each controller here damps that orbit in a different way; all take one
measured ``J_c`` per iteration through :meth:`MultiplierController.update` and read the violation
``g = (J_c - d) / scale`` (lagrange.py). ``Pi`` is the projection onto ``lambda >= 0``.

cooper-optim (PyPI) implements nuPI and the augmented Lagrangian for a differentiable constrained
problem: its ConstrainedOptimizer takes the constraint as a tensor in the autograd graph of the
primal loss and steps a torch optimizer on the multiplier. Here the constraint is one scalar
measured from the batch's episodes once per iteration, and the primal step is PPO's clipped
minibatch epochs, TRPO's line search or the off-policy actor's: no single Lagrangian backward pass
exists for cooper to drive. Only its scalar recursions would fit, and those are the few lines
below, whose state has to go into the run's checkpoint as plain numbers anyway.
"""

from __future__ import annotations

from cmdp_rl.algos.lagrange import MultiplierController


class RegularizedDual(MultiplierController):
    """Regularised primal-dual (Ding, Wei, Zhang, Ribeiro, "Last-Iterate Convergent Policy
    Gradient Primal-Dual Methods for Constrained MDPs", NeurIPS 2023, arXiv 2306.11700, the dual
    step of their RPG-PD)::

        lambda <- Pi[(1 - lr * tau) lambda + lr * g]

    the gradient step on the dual of the tau-regularised Lagrangian ``L + tau/2 lambda^2``, whose
    policy side carries an entropy bonus tau (ppo_lag adds it to entropy_coef). The regulariser
    makes the saddle point unique and the dynamics a contraction, at the price of an O(tau) bias:
    at a fixed point ``g = tau lambda``, a violation of tau * lambda in the scaled units."""

    def __init__(self, cost_limit: float, lr: float, tau: float, init: float = 0.0, scale: float = 1.0) -> None:
        super().__init__(cost_limit, init, scale)
        if not 0.0 <= lr * tau < 1.0:
            raise ValueError(f"lambda_lr * lambda_tau must be in [0, 1), got {lr} * {tau}")
        self.lr, self.tau = lr, tau

    def _next_value(self, episode_cost: float) -> float:
        return max(0.0, (1.0 - self.lr * self.tau) * self.value + self.lr * self.violation(episode_cost))

    def state_dict(self) -> dict:
        return {"value": self.value}

    def load_state_dict(self, state: dict) -> None:
        self.value = float(state["value"])


class OptimisticDual(MultiplierController):
    """nuPI (Sohrabi, Ramirez, Zhang, Lacoste-Julien, Gallego-Posada, "On PI Controllers for
    Updating Lagrange Multipliers in Constrained Optimization", ICML 2024) with
    ``kappa_p = kappa_i = lr``::

        xi     = nu * xi_prev + (1 - nu) * g
        lambda <- Pi[lambda + lr * g + lr * (xi - xi_prev)]

    With ``nu = 0`` it is the optimistic gradient step ``lambda <- Pi[lambda + lr (2 g_t - g_{t-1})]``
    that ReLOAD applies to the multiplier (Moskovitz, O'Donoghue, Veeriah, Flennerhag, Singh,
    Zahavy, "ReLOAD: Reinforcement Learning with Optimistic Ascent-Descent for Last-Iterate
    Convergence in Constrained MDPs", ICML 2023, arXiv 2302.01275): the extra ``lr (g_t -
    g_{t-1})`` is a proportional term that brakes lambda as soon as the violation turns, before the
    policy has crossed the budget. As in cooper's nuPI, the first step has no predecessor: ``xi_prev``
    is taken equal to ``xi``, so the first step is plain dual ascent."""

    def __init__(self, cost_limit: float, lr: float, nu: float = 0.0, init: float = 0.0, scale: float = 1.0) -> None:
        super().__init__(cost_limit, init, scale)
        if not 0.0 <= nu < 1.0:
            raise ValueError(f"lambda_nu must be in [0, 1), got {nu}")
        self.lr, self.nu = lr, nu
        self.xi: float | None = None

    def _next_value(self, episode_cost: float) -> float:
        g = self.violation(episode_cost)
        if self.xi is None:
            xi_prev = xi = g
        else:
            xi_prev = self.xi
            xi = self.nu * xi_prev + (1.0 - self.nu) * g
        self.xi = xi
        return max(0.0, self.value + self.lr * g + self.lr * (self.xi - xi_prev))

    def state_dict(self) -> dict:
        return {"value": self.value, "xi": self.xi}

    def load_state_dict(self, state: dict) -> None:
        self.value = float(state["value"])
        self.xi = None if state.get("xi") is None else float(state["xi"])


class AugmentedLagrangian(MultiplierController):
    """Augmented Lagrangian for an inequality constraint (Nocedal & Wright, "Numerical
    Optimization", 2nd ed., section 17.4 on inequality constraints, maximising ``J_r``): the primal
    objective is ``J_r - psi(g, lambda; rho)`` with ``psi = rho/2 max(0, g + lambda/rho)^2 -
    lambda^2/(2 rho)``, and after each primal step ``lambda <- Pi[lambda + rho g]``.

    One primal iteration stands in for the book's inner minimisation, so each iteration, with g
    measured at the policy the last primal step produced::

        lambda <- Pi[lambda + rho * g]          (the multiplier's update)
        value   = Pi[lambda + rho * g]          (d psi / d g at the current policy)

    ``value`` is what the policy update prices cost with: the penalty's slope, which exceeds the
    multiplier by ``rho g`` while the budget is broken and falls to 0 with slack. Because the
    primal objective is frozen for the iteration, the quadratic acts through that slope alone:
    this is the penalty term's first-order effect, a proportional term on top of dual ascent.
    ``rho`` is ``algo.multiplier.lr``."""

    def __init__(self, cost_limit: float, rho: float, init: float = 0.0, scale: float = 1.0) -> None:
        super().__init__(cost_limit, init, scale)
        self.rho = rho
        self.multiplier = float(init)

    def _next_value(self, episode_cost: float) -> float:
        step = self.rho * self.violation(episode_cost)
        self.multiplier = max(0.0, self.multiplier + step)
        return max(0.0, self.multiplier + step)

    def state_dict(self) -> dict:
        return {"value": self.value, "multiplier": self.multiplier}

    def load_state_dict(self, state: dict) -> None:
        self.value = float(state["value"])
        self.multiplier = float(state["multiplier"])
