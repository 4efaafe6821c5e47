"""Quadrature rules on the parametric triangle {ξ ≥ 0, η ≥ 0, ξ + η ≤ 1}.

* Regular rules: symmetric Gauss rules (Cowper 1973 / Dunavant 1985) selected by
  their number of points; weights sum to 1/2, the area of the parametric triangle.
* Singular rules: the Duffy (collapsed-square) map with its origin at the singular
  node. The Jacobian of the map vanishes linearly at the origin and cancels the
  1/r singularity of the Stokeslet (the seed's "polar" treatment, §3). A mid-edge
  node splits the triangle into two sub-triangles that each have it as a vertex.
* Gauss–Legendre rules on [0, 1] for the element contour integrals (seed 3.6).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

# Barycentric orbits (a, b, c) with weight (weights normalised to sum to 1).
# Each entry: (kind, weight, a, b) with kind 1 = centroid, 3 = (a, b, b) orbit,
# 6 = (a, b, 1-a-b) orbit.
_SYMMETRIC_RULES: dict[int, tuple[int, list[tuple[int, float, float, float]]]] = {
    # n_points: (polynomial degree, orbits)
    1: (1, [(1, 1.0, 1 / 3, 1 / 3)]),
    3: (2, [(3, 1 / 3, 2 / 3, 1 / 6)]),
    4: (3, [(1, -27 / 48, 1 / 3, 1 / 3), (3, 25 / 48, 0.6, 0.2)]),
    6: (
        4,
        [
            (3, 0.223381589678011, 0.108103018168070, 0.445948490915965),
            (3, 0.109951743655322, 0.816847572980459, 0.091576213509771),
        ],
    ),
    7: (
        5,
        [
            (1, 0.225, 1 / 3, 1 / 3),
            (3, 0.132394152788506, 0.059715871789770, 0.470142064105115),
            (3, 0.125939180544827, 0.797426985353087, 0.101286507323456),
        ],
    ),
    12: (
        6,
        [
            (3, 0.116786275726379, 0.501426509658179, 0.249286745170910),
            (3, 0.050844906370207, 0.873821971016996, 0.063089014491502),
            (6, 0.082851075618374, 0.053145049844817, 0.310352451033784),
        ],
    ),
}

REGULAR_ORDERS = tuple(sorted(_SYMMETRIC_RULES))


def triangle_rule_degree(n_points: int) -> int:
    """Polynomial degree integrated exactly by the symmetric rule with n_points."""
    return _SYMMETRIC_RULES[n_points][0]


@lru_cache(maxsize=None)
def triangle_rule(n_points: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Symmetric Gauss rule with ``n_points`` nodes: (xi, eta, weights), Σw = 1/2."""
    if n_points not in _SYMMETRIC_RULES:
        raise ValueError(f"no triangle rule with {n_points} points (allowed: {REGULAR_ORDERS})")
    _, orbits = _SYMMETRIC_RULES[n_points]
    bary, weights = [], []
    for kind, w, a, b in orbits:
        if kind == 1:
            pts = [(a, b, 1 - a - b)]
        elif kind == 3:
            pts = [(a, b, b), (b, a, b), (b, b, a)]
        else:
            c = 1 - a - b
            pts = [(a, b, c), (a, c, b), (b, a, c), (b, c, a), (c, a, b), (c, b, a)]
        bary.extend(pts)
        weights.extend([w] * len(pts))
    bary_arr = np.array(bary)
    w_arr = 0.5 * np.array(weights)
    return bary_arr[:, 1].copy(), bary_arr[:, 2].copy(), w_arr


@lru_cache(maxsize=None)
def gauss_legendre_01(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss–Legendre nodes and weights on [0, 1]."""
    t, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (t + 1.0), 0.5 * w


# Parametric positions of the six element nodes (vertices 0-2, then mid-edges
# 01, 12, 20); see mesh.py for the node ordering.
NODE_XI = np.array([0.0, 1.0, 0.0, 0.5, 0.5, 0.0])
NODE_ETA = np.array([0.0, 0.0, 1.0, 0.0, 0.5, 0.5])


def _duffy_on_subtriangle(p0, p1, p2, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Duffy rule on the parametric sub-triangle (p0, p1, p2), singular at p0.

    (u, v) ∈ [0,1]² ↦ p0 + u[(1−v)(p1−p0) + v(p2−p0)], Jacobian u·|det|.
    After the map a 1/r integrand is smooth and nearly constant along u (the
    radial direction) but varies along v (the angle): n points in u, 2n in v.
    """
    s, ws = gauss_legendre_01(n)
    t, wt = gauss_legendre_01(2 * n)
    u, v = np.meshgrid(s, t, indexing="ij")
    wu, wv = np.meshgrid(ws, wt, indexing="ij")
    p0, p1, p2 = (np.asarray(p, dtype=float) for p in (p0, p1, p2))
    e1, e2 = p1 - p0, p2 - p0
    det = abs(e1[0] * e2[1] - e1[1] * e2[0])
    pts = p0[None, :] + (u.ravel()[:, None]) * ((1 - v.ravel())[:, None] * e1 + v.ravel()[:, None] * e2)
    w = (wu * wv * u).ravel() * det
    return pts[:, 0], pts[:, 1], w


@lru_cache(maxsize=None)
def singular_rules(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Duffy rules for a singularity at each of the six element nodes.

    Every node's triangle is split into two sub-triangles that have the node as
    a vertex; returns arrays of shape (6, m), m = 4 n²: xi, eta, weights.
    """
    corners = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)]
    m = 4 * n * n
    xi = np.zeros((6, m))
    eta = np.zeros((6, m))
    w = np.zeros((6, m))
    for k in range(3):
        p0 = corners[k]
        p1, p2 = corners[(k + 1) % 3], corners[(k + 2) % 3]
        # a vertex: split at the midpoint of the opposite edge as well, so that
        # both halves carry n² points (better angular resolution, same count).
        mid = (0.5 * (p1[0] + p2[0]), 0.5 * (p1[1] + p2[1]))
        a = _duffy_on_subtriangle(p0, p1, mid, n)
        b = _duffy_on_subtriangle(p0, mid, p2, n)
        xi[k] = np.concatenate([a[0], b[0]])
        eta[k] = np.concatenate([a[1], b[1]])
        w[k] = np.concatenate([a[2], b[2]])
    # mid-edge nodes: node 3 on edge 0-1, node 4 on edge 1-2, node 5 on edge 2-0
    for k, (i, j) in zip((3, 4, 5), ((0, 1), (1, 2), (2, 0))):
        p0 = (NODE_XI[k], NODE_ETA[k])
        opposite = 3 - i - j
        a = _duffy_on_subtriangle(p0, corners[j], corners[opposite], n)
        b = _duffy_on_subtriangle(p0, corners[opposite], corners[i], n)
        xi[k] = np.concatenate([a[0], b[0]])
        eta[k] = np.concatenate([a[1], b[1]])
        w[k] = np.concatenate([a[2], b[2]])
    return xi, eta, w


@lru_cache(maxsize=None)
def subdivided_rule(n_points: int, levels: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The symmetric rule with ``n_points`` on each of the 4^levels triangles of the
    reference triangle split ``levels`` times at its edge midpoints: (xi, eta, w),
    Σw = 1/2. For integrands that vary on a scale smaller than the element (the
    near field of a source element close to the target)."""
    xi0, eta0, w0 = triangle_rule(n_points)
    triangles = [np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])]
    for _ in range(levels):
        split = []
        for a, b, c in triangles:
            ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
            split += [np.array([a, ab, ca]), np.array([ab, b, bc]), np.array([ca, bc, c]), np.array([ab, bc, ca])]
        triangles = split
    xs, es, ws = [], [], []
    for a, b, c in triangles:
        p = a[None, :] + xi0[:, None] * (b - a)[None, :] + eta0[:, None] * (c - a)[None, :]
        xs.append(p[:, 0])
        es.append(p[:, 1])
        ws.append(w0 / 4**levels)
    return np.concatenate(xs), np.concatenate(es), np.concatenate(ws)
