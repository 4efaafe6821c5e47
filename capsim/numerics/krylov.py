"""Krylov solvers for the matrix-free systems of the velocity and stage solves.

The products are layer applications, the costly unit of this code, so the solver
counts them and spends none it does not need.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np


class LinearSolveFailed(RuntimeError):
    """A stage solver missed its tolerance within its iterations (the step is retried smaller)."""


class SolverDivergence(RuntimeError):
    """The λ ≠ 1 (or viscous-membrane) velocity solve missed its tolerance. At a trial state the
    integrator rejects the step and retries it smaller (capsim.solve.timestepping.Integrator.attempt);
    at the run's first state the run ends unstable, saying so."""

__all__ = ["gmres"]


def gmres(matvec: Callable[[np.ndarray], np.ndarray], b: np.ndarray, tol: float, *,
          precondition: Callable[[np.ndarray], np.ndarray] | None = None, max_iter: int, restart: int,
          callback: Callable[[], None] | None = None) -> tuple[np.ndarray, int, float]:
    """x with |b − A x|₂ ≤ tol by restarted GMRES on A M⁻¹ y = b, x = M⁻¹ y (Saad &
    Schultz 1986; modified Gram–Schmidt, Givens rotations). With right
    preconditioning the Arnoldi residual is the true one (in exact arithmetic), so
    a solve that converges in its first cycle costs one product per iteration and
    nothing more (SciPy's gmres adds a product for the final residual: a layer
    application per solve). Returns (x, iterations, residual) from x0 = 0;
    iterations counts every product, a restart's true residual included; the
    caller decides what a residual above ``tol`` means."""
    # here, not at the top: capsim.config imports this module (through the scheme registry),
    # and `capsim validate`/`plot`/`summarize` need none of scipy.linalg's ~0.15 s of imports
    from scipy.linalg import solve_triangular

    n = b.size
    apply_m = precondition if precondition is not None else (lambda v: v)
    x = np.zeros(n)
    r = b.copy()
    beta = float(np.linalg.norm(r))
    iterations = 0
    while beta > tol and iterations < max_iter:
        m = min(restart, max_iter - iterations)
        basis = np.empty((m + 1, n))
        hess = np.zeros((m + 1, m))
        cs, sn = np.zeros(m), np.zeros(m)
        g = np.zeros(m + 1)
        g[0] = beta
        basis[0] = r / beta
        j = -1
        for j in range(m):
            w = matvec(apply_m(basis[j]))
            iterations += 1
            for i in range(j + 1):
                hess[i, j] = float(basis[i] @ w)
                w -= hess[i, j] * basis[i]
            h_next = float(np.linalg.norm(w))
            hess[j + 1, j] = h_next
            for i in range(j):  # earlier rotations on the new column
                hess[i, j], hess[i + 1, j] = (cs[i] * hess[i, j] + sn[i] * hess[i + 1, j],
                                              -sn[i] * hess[i, j] + cs[i] * hess[i + 1, j])
            rho = math.hypot(hess[j, j], hess[j + 1, j])
            cs[j], sn[j] = (hess[j, j] / rho, hess[j + 1, j] / rho) if rho > 0.0 else (1.0, 0.0)
            hess[j, j], hess[j + 1, j] = rho, 0.0
            g[j], g[j + 1] = cs[j] * g[j], -sn[j] * g[j]
            if callback is not None:
                callback()
            if not np.isfinite(g[j + 1]):
                return x, iterations, math.inf
            if abs(g[j + 1]) <= tol or not h_next > 0.0:  # converged, or the Krylov space is exhausted
                break
            basis[j + 1] = w / h_next
        k = j + 1
        coef = solve_triangular(hess[:k, :k], g[:k], check_finite=False)
        x += apply_m(coef @ basis[:k])
        if abs(g[k]) <= tol or iterations >= max_iter:
            return x, iterations, abs(g[k])
        r = b - matvec(x)  # a restart: the true residual (one product)
        iterations += 1
        beta = float(np.linalg.norm(r))
    return x, iterations, beta
