"""Conjugate gradient for ``A x = b`` with ``A`` symmetric positive definite and given only as a
matrix-vector product (Nocedal & Wright, "Numerical Optimization", 2nd ed., Algorithm 5.2).

Hand-written because torch's solvers (``torch.linalg.solve``, ``cholesky_solve``) need ``A`` as a
matrix; a trust-region method has only Fisher-vector products and never forms the Fisher matrix.
"""

from __future__ import annotations

from typing import Callable

import torch


def conjugate_gradient(
    matvec: Callable[[torch.Tensor], torch.Tensor], b: torch.Tensor, iters: int, residual_tol: float = 1e-10
) -> torch.Tensor:
    """Approximate ``A^-1 b`` in at most ``iters`` steps, stopping early once ``|r|^2 < residual_tol``."""
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
