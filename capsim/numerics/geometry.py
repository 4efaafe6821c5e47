"""Geometry of 6-node quadratic triangles (seed 3.3): shape functions, quadrature
points, normals, Jacobians, and the integral properties V, S, centroid, inertia.

Everything here is vectorised numpy over elements; the hot loops over pairs of
nodes and elements live in ``kernels.py``.
"""

from __future__ import annotations

from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from capsim.numerics.quadrature import triangle_rule


def interpolate(phi: np.ndarray, nodal: np.ndarray) -> np.ndarray:
    """Values at rule points from element-nodal values: (q, 6) × (N_e, 6, d) →
    (N_e, q, d), as one matrix product (much faster than einsum here)."""
    ne, _, d = nodal.shape
    flat = nodal.transpose(0, 2, 1).reshape(ne * d, 6) @ phi.T  # (N_e·d, q)
    return flat.reshape(ne, d, -1).transpose(0, 2, 1)


def shape_functions(xi: np.ndarray, eta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Quadratic Lagrange basis φ_k and its derivatives at (ξ, η); each (m, 6).

    Nodes: 0 (0,0), 1 (1,0), 2 (0,1), 3 (½,0), 4 (½,½), 5 (0,½).
    """
    xi = np.atleast_1d(np.asarray(xi, float))
    eta = np.atleast_1d(np.asarray(eta, float))
    z = 1.0 - xi - eta
    phi = np.stack(
        [z * (2 * z - 1), xi * (2 * xi - 1), eta * (2 * eta - 1), 4 * xi * z, 4 * xi * eta, 4 * eta * z],
        axis=1,
    )
    dxi = np.stack(
        [-(4 * z - 1), 4 * xi - 1, 0 * xi, 4 * (z - xi), 4 * eta, -4 * eta],
        axis=1,
    )
    deta = np.stack(
        [-(4 * z - 1), 0 * xi, 4 * eta - 1, -4 * xi, 4 * xi, 4 * (z - eta)],
        axis=1,
    )
    return phi, dxi, deta


@dataclass(frozen=True)
class ElementGeometry:
    """Quadrature-point data of every element.

    points (N_e, m, 3), normals (N_e, m, 3) outward unit normals, weights (N_e, m)
    = Gauss weight × surface Jacobian, so Σ weights = area.
    """

    points: np.ndarray
    normals: np.ndarray
    weights: np.ndarray

    @property
    def element_areas(self) -> np.ndarray:
        return self.weights.sum(axis=1)


#: element_geometry in plain numpy, not the numba kernel: a case's start checks (a wall's
#: clearance, capsules apart) measure rest meshes, and `capsim validate` should not import numba
#: (~0.3 s) for that. The kernel (fastmath) and numpy differ in round-off, so a run's own meshes
#: keep the kernel: their numbers stay the same to the bit.
_NUMPY_QUADRATURE: ContextVar[bool] = ContextVar("numpy_quadrature", default=False)


@contextmanager
def numpy_quadrature():
    """Within it, :func:`element_geometry` uses numpy (the same values to round-off)."""
    token = _NUMPY_QUADRATURE.set(True)
    try:
        yield
    finally:
        _NUMPY_QUADRATURE.reset(token)


def element_geometry(x: np.ndarray, elements: np.ndarray, n_points: int = 6) -> ElementGeometry:
    """Positions, unit normals and area weights at the regular Gauss points."""
    phi, dxi, deta, w = _rule_tables(n_points)
    if _NUMPY_QUADRATURE.get():
        nodal = np.asarray(x, dtype=np.float64)[elements]  # (N_e, 6, 3)
        points, a, b = (interpolate(table, nodal) for table in (phi, dxi, deta))
        normals = np.cross(a, b)
        jac = np.linalg.norm(normals, axis=-1)
        return ElementGeometry(points, normals / jac[..., None], w * jac)
    from capsim.numerics.kernels import element_quadrature

    return ElementGeometry(*element_quadrature(np.ascontiguousarray(x), elements, phi, dxi, deta, w))


@lru_cache(maxsize=None)
def _rule_tables(n_points: int):
    xi, eta, w = triangle_rule(n_points)
    phi, dxi, deta = shape_functions(xi, eta)
    return phi, dxi, deta, w


def reference_point(geo: ElementGeometry) -> np.ndarray:
    """The surface's mean point rounded to whole units of a: what the integrals below measure
    from. ⅓ ∫ x·n dS and ½ ∫ |x|² n dS are the same about any point (∫ n dS = 0 on a closed
    surface), but about the origin their terms grow with the distance while their sums do
    not: at 1e6 a the centroid from |x|² ~ 1e12 lost every digit, and D_xy read 0.57 ± 0.39
    where the shape had 0.26. A whole number keeps x − p exact and a capsule at the origin
    measured as before, to the bit."""
    return np.round(geo.points.reshape(-1, 3).mean(axis=0))


def volume_area(geo: ElementGeometry) -> tuple[float, float]:
    """V = ⅓ ∫ (x − p)·n dS (p: ``reference_point``) and S = ∫ dS."""
    y = geo.points - reference_point(geo)
    volume = np.einsum("eqd,eqd,eq->", y, geo.normals, geo.weights) / 3.0
    return float(volume), float(geo.weights.sum())


def centroid(geo: ElementGeometry, volume: float) -> np.ndarray:
    """Volume centroid, p + ∫_V (x − p) dV / V = p + ½ ∫_S |x − p|² n dS / V."""
    p = reference_point(geo)
    y = geo.points - p
    r2 = np.einsum("eqd,eqd->eq", y, y)
    return p + 0.5 * np.einsum("eq,eqd,eq->d", r2, geo.normals, geo.weights) / volume


def second_moment(geo: ElementGeometry, center: np.ndarray) -> np.ndarray:
    """M = ∫_V y y dV about ``center``, from ⅕ ∫_S y y (y·n) dS (seed 3.9)."""
    y = geo.points - center
    yn = np.einsum("eqd,eqd->eq", y, geo.normals)
    return np.einsum("eqi,eqj,eq->ij", y, y, yn * geo.weights) / 5.0


def surface_moments(geo: ElementGeometry) -> tuple[float, float, np.ndarray, np.ndarray]:
    """(V, S, the centroid, M about it): volume_area, centroid and second_moment in one numba
    pass over the points (issue 57: the three took 0.45 ms a step in numpy at level 3, the kernel
    ~0.02), the same integrals to round-off (tests/numerics/test_step_kernels.py); numpy within
    :func:`numpy_quadrature` (a check before a run need not import numba)."""
    if _NUMPY_QUADRATURE.get():
        volume, area = volume_area(geo)
        center = centroid(geo, volume)
        return volume, area, center, second_moment(geo, center)
    from capsim.numerics.kernels import rounded_mean_point, surface_moments as kernel

    out = kernel(geo.points, geo.normals, geo.weights, rounded_mean_point(geo.points))
    return float(out[0]), float(out[1]), out[2:5].copy(), out[5:].reshape(3, 3).copy()


def min_quality(x: np.ndarray, elements: np.ndarray) -> float:
    """The smallest vertex-triangle quality (``vertex_triangle_quality(x, elements).min()``, one numba
    loop: the guard reads it every step)."""
    from capsim.numerics.kernels import min_vertex_triangle_quality

    return float(min_vertex_triangle_quality(np.ascontiguousarray(x), elements))


def vertex_triangle_quality(x: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """Shape quality of each element's vertex triangle: 4√3·area / Σ edge²

    (1 for an equilateral triangle, → 0 as it degenerates).
    """
    a, b, c = x[elements[:, 0]], x[elements[:, 1]], x[elements[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    s = ((b - a) ** 2).sum(1) + ((c - b) ** 2).sum(1) + ((a - c) ** 2).sum(1)
    return 4.0 * np.sqrt(3.0) * area / s


def best_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation R (3×3) minimising Σ |R (a_i − ā) − (b_i − b̄)|² over the nodes
    (Kabsch 1976: from the SVD of the cross-covariance, reflections excluded). The
    preconditioners of capsim.numerics.linearization and capsim.numerics.viscosity are applied in the frame
    of the rotation from the nodes where they were built."""
    u, _, vt = np.linalg.svd((a - a.mean(axis=0)).T @ (b - b.mean(axis=0)))
    d = np.sign(np.linalg.det(u @ vt))
    return (u @ np.diag([1.0, 1.0, d]) @ vt).T
