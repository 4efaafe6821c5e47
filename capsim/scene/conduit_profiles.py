"""Fully developed pressure-driven flow of the empty conduits, u = u(y, z) e_x, along +x.

Units: the mean velocity over the cross-section U = 1 and the viscosity μ = 1; lengths are in
whatever unit the radius or half-widths are given in. Then the pressure gradient −dp/dx = G is
the wall shear's mean times perimeter over area (force balance).

Tube of radius R: u = 2 (1 − r²/R²), G = 8/R², wall shear 4/R.

Rectangular duct |y| ≤ a, |z| ≤ b: ∇²u = −G, u = 0 on the walls (White, Viscous Fluid Flow,
§3-3.3, eq. 3-48; Shah & London 1978). With w = u/G and the cosine series along one side
written as its closed form (the parabola), two exact representations are

    w = (p² − s²)/2 − (16 p²/π³) Σ_{i odd} (−1)^((i−1)/2) cosh(β t)/cosh(β q) cos(β s)/i³,  β = iπ/(2p),

(s, p) = (y, a), (t, q) = (z, b), or the roles swapped. Term i decays like exp(−β (q − |t|)): each
point takes the one that decays faster (the farther wall in units of the series' width), so the
series converges exponentially everywhere but at the corners (where u = 0 and ∇u = 0), and
each point is summed until the tail bound is below 1e-13 relative to U (and to U/p for ∇u). The
hyperbolic ratios are written with exp(−…) only, so nothing overflows.
"""

from __future__ import annotations

import math

import numpy as np

#: ζ(5); Σ_{i odd} 1/i⁵ = (31/32) ζ(5)
ZETA5 = 1.0369277551433699263313655
#: tail bound per point, relative to U = 1 (u) and to U/p (∇u)
SERIES_TOLERANCE = 1e-13
#: the most odd terms a point sums (only points within ~1e-4 of a corner get near it)
MAX_TERMS = 200_000


# ------------------------------------------------------------------ tube

def tube_velocity(y, z, radius: float) -> np.ndarray:
    """u_x = 2 (1 − r²/R²), r² = y² + z² (mean 1)."""
    y, z = np.asarray(y, dtype=float), np.asarray(z, dtype=float)
    return 2.0 * (1.0 - (y * y + z * z) / (radius * radius))


def tube_wall_shear(radius: float) -> float:
    """|du/dn| at the wall, μ = 1: 4/R."""
    return 4.0 / radius


def tube_pressure_gradient(radius: float) -> float:
    """−dp/dx for U = 1, μ = 1: 8/R²."""
    return 8.0 / (radius * radius)


def tube_gradient(points: np.ndarray, radius: float) -> np.ndarray:
    """Velocity gradient L_ij = ∂u_i/∂x_j at points (N, 3): (N, 3, 3)."""
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    out = np.zeros((len(p), 3, 3))
    out[:, 0, 1] = -4.0 * p[:, 1] / radius**2
    out[:, 0, 2] = -4.0 * p[:, 2] / radius**2
    return out


# ------------------------------------------------------------------ duct

def _mean_over_gradient(half_y: float, half_z: float) -> float:
    """U/G = (p²/3) [1 − (192 p/(π⁵ q)) Σ_{i odd} tanh(iπq/(2p))/i⁵], p ≤ q the half-widths.

    Σ tanh/i⁵ = (31/32) ζ(5) − Σ (1 − tanh)/i⁵, and 1 − tanh(x) = 2e^{−2x}/(1 + e^{−2x}) is below
    1e-17 once x > 20: a handful of terms (p ≤ q keeps x ≥ iπ/2)."""
    if not (half_y > 0 and half_z > 0):
        raise ValueError(f"duct half-widths must be positive (got {half_y}, {half_z})")
    p, q = min(half_y, half_z), max(half_y, half_z)
    i = np.arange(1, 2 * math.ceil(20 * p / (math.pi * q)) + 3, 2, dtype=float)
    e = np.exp(-i * math.pi * q / p)
    s = 31.0 / 32.0 * ZETA5 - np.sum(2 * e / (1 + e) / i**5)
    return p * p / 3.0 * (1.0 - 192.0 * p / (math.pi**5 * q) * s)


def duct_pressure_gradient(half_y: float, half_z: float) -> float:
    """G = −dp/dx of the duct for U = 1, μ = 1."""
    return 1.0 / _mean_over_gradient(half_y, half_z)


def _series(s, t, p, q, n_terms):
    """w = u/G and ∂w/∂s, ∂w/∂t from the series along s (half-width p), hyperbolic in t (q)."""
    w = 0.5 * (p * p - s * s)
    ws = -s.copy()
    wt = np.zeros_like(s)
    c = 16.0 * p * p / math.pi**3
    gap = q - np.abs(t)                 # the hyperbolic terms decay like exp(−β gap)
    rate = math.pi * gap / (2.0 * p)    # per unit of i
    sign_t = np.where(t < 0, -1.0, 1.0)
    # the tolerance on w (u/G) and on its gradient, for |u| and |∇u| of order U = 1 and U/p
    g = 1.0 / _mean_over_gradient(p, q)
    tol_w, tol_g = SERIES_TOLERANCE / g, SERIES_TOLERANCE / (g * p)
    active = np.flatnonzero(rate > 0)   # rate 0: the corner (s = ±p there), where w = ∇w = 0
    corner = rate <= 0
    w[corner] = ws[corner] = wt[corner] = 0.0
    first, chunk = 1, 32
    while active.size and first <= 2 * n_terms:
        i = np.arange(first, min(first + 2 * chunk, 2 * n_terms + 1), 2, dtype=float)
        beta = i * math.pi / (2.0 * p)
        sa, ta, ga = s[active, None], np.abs(t[active, None]), gap[active, None]
        e1, e2 = np.exp(-beta * ga), np.exp(-beta * (q + ta))
        den = 1.0 + np.exp(-2.0 * beta * q)
        ch, sh = (e1 + e2) / den, (e1 - e2) / den
        coef = np.where(((i - 1) / 2) % 2 == 0, 1.0, -1.0) / i**3
        cos, sin = np.cos(beta * sa), np.sin(beta * sa)
        w[active] -= c * np.sum(coef * ch * cos, axis=1)
        ws[active] += c * np.sum(coef * beta * ch * sin, axis=1)
        wt[active] -= c * sign_t[active] * np.sum(coef * beta * sh * cos, axis=1)
        last = i[-1]
        # tail after `last`: |ch|, |sh| <= 2 e^{−β gap}, so Σ_{i>last} 2 e^{−rate i}/i³ (× β for ∇w)
        r = rate[active]
        geometric = np.exp(-r * (last + 2)) / (-np.expm1(-2 * r))
        tail_w = 2 * c * geometric / (last + 2) ** 3
        tail_g = 2 * c * math.pi / (2 * p) * geometric / (last + 2) ** 2
        active = active[(tail_w > tol_w) | (tail_g > tol_g)]
        first = int(last) + 2
        chunk = min(2 * chunk, 4096)
    return w, ws, wt


def _duct_fields(y, z, half_y, half_z, n_terms):
    """u, ∂u/∂y, ∂u/∂z (U = 1) at broadcast points of the cross-section."""
    y, z = np.broadcast_arrays(np.asarray(y, dtype=float), np.asarray(z, dtype=float))
    shape = y.shape
    y, z = y.ravel().copy(), z.ravel().copy()
    slack = 1e-12 * max(half_y, half_z)
    if np.any(np.abs(y) > half_y + slack) or np.any(np.abs(z) > half_z + slack):
        raise ValueError(f"points outside the duct |y| <= {half_y}, |z| <= {half_z}")
    y, z = np.clip(y, -half_y, half_y), np.clip(z, -half_z, half_z)
    n_terms = MAX_TERMS if n_terms is None else int(n_terms)
    # per point, the series whose terms decay faster: along y (decay with the z-walls' distance)
    along_y = (half_z - np.abs(z)) / half_y >= (half_y - np.abs(y)) / half_z
    u, uy, uz = (np.empty_like(y) for _ in range(3))
    if along_y.any():
        m = along_y
        u[m], uy[m], uz[m] = _series(y[m], z[m], half_y, half_z, n_terms)
    if (~along_y).any():
        m = ~along_y
        u[m], uz[m], uy[m] = _series(z[m], y[m], half_z, half_y, n_terms)
    g = duct_pressure_gradient(half_y, half_z)
    return (g * u).reshape(shape), (g * uy).reshape(shape), (g * uz).reshape(shape)


def duct_velocity(y, z, half_y: float, half_z: float, n_terms: int | None = None) -> np.ndarray:
    """u_x of the duct |y| ≤ half_y, |z| ≤ half_z (mean 1) at broadcast (y, z).

    ``n_terms``: the most odd terms per point (default :data:`MAX_TERMS`; each point stops once
    its tail is below 1e-13)."""
    return _duct_fields(y, z, half_y, half_z, n_terms)[0]


def duct_gradient(points: np.ndarray, half_y: float, half_z: float, n_terms: int | None = None) -> np.ndarray:
    """Velocity gradient L_ij = ∂u_i/∂x_j at points (N, 3): (N, 3, 3)."""
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    _, uy, uz = _duct_fields(p[:, 1], p[:, 2], half_y, half_z, n_terms)
    out = np.zeros((len(p), 3, 3))
    out[:, 0, 1], out[:, 0, 2] = uy, uz
    return out


def duct_wall_shear(points: np.ndarray, half_y: float, half_z: float) -> np.ndarray:
    """|du/dn| (μ = 1) at points (N, 3) on the duct's walls: there ∇u is normal, so |∇u|."""
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    off = np.minimum(half_y - np.abs(p[:, 1]), half_z - np.abs(p[:, 2]))
    if np.any(np.abs(off) > 1e-9 * max(half_y, half_z)):
        raise ValueError("duct_wall_shear takes points on the walls |y| = half_y or |z| = half_z")
    _, uy, uz = _duct_fields(p[:, 1], p[:, 2], half_y, half_z, None)
    return np.hypot(uy, uz)


def duct_centerline_velocity(half_y: float, half_z: float) -> float:
    """u on the axis (the maximum) for U = 1: 2.0962 for the square duct, → 1.5 as b/a → 0."""
    return float(duct_velocity(0.0, 0.0, half_y, half_z))
