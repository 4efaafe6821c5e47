"""Shared test problems of the time integrators (tests/solve/test_timestepping.py,
tests/solve/test_linearly_implicit.py).

y' = A y + b with A = Q diag(λ) Qᵀ, eigenvalues spread over [−1e4, −1]: exact
solution known. The start lies on the slow manifold (the stiff modes at their
equilibrium), as a smooth solution of a stiff problem does; Q mixes the modes so
that every component sees the stiff ones (an unstable step amplifies their round-off).
"""

from __future__ import annotations

import numpy as np

from capsim.config import apply_overrides, case_from_dict

EIGENVALUES = -np.logspace(0, 4, 40)
Q = np.linalg.qr(np.random.default_rng(1).standard_normal((40, 40)))[0]
A = Q @ np.diag(EIGENVALUES) @ Q.T
FORCING = Q @ np.linspace(1.0, 2.0, 40)
Y_STAR = -np.linalg.solve(A, FORCING)
Y0 = Y_STAR + Q @ np.where(-EIGENVALUES <= 10.0, 1.0, 0.0)
RHO = 1e4
RKF23_LIMIT = 2.5 / RHO  # RKF2(3)'s real stability interval is about [−2.5, 0]


def linear(y: np.ndarray) -> np.ndarray:
    return A @ y + FORCING


def exact(t: float) -> np.ndarray:
    return Y_STAR + Q @ (np.exp(EIGENVALUES * t) * (Q.T @ (Y0 - Y_STAR)))


def capsule_case(tmp_path, name, **dotted):
    """Sphere, level 2, G = 0.05, kt 2, written under tmp_path, with dotted overrides."""
    case = case_from_dict({
        "name": name, "mesh": {"level": 2}, "flow": {"shear_rate_G": 0.05},
        "time": {"t_end": 2.0}, "output": {"path": str(tmp_path / f"{name}.h5")},
    })
    return apply_overrides(case, **dotted)
