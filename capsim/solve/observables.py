"""Observables of a capsule configuration, cheap enough for every step.

Deformation and inclination follow the seed (3.9)–(3.10): the second moment
M = ∫_V y y dV about the centroid is matched by the ellipsoid of the same volume
and inertia, whose semi-axes are l_k = (5 μ_k / V)^½ (μ_k the eigenvalues of M).
Of the three principal axes, the one most nearly along z (vorticity) is set
aside; the other two span the shear plane and give L ≥ l and
D_xy = (L − l)/(L + l); θ ∈ (−π/2, π/2] is the angle of the long axis to x.
"""

from __future__ import annotations

import math

import numpy as np

from capsim.numerics.geometry import (
    ElementGeometry,
    centroid,
    interpolate,
    min_quality,
    second_moment,
    surface_moments,
    volume_area,
)
from capsim.scene import smallest_gap
from capsim.numerics import kernels  # numba: already loaded with capsim.numerics.membrane
from capsim.numerics.membrane import row_tension_summary
from capsim.quantities import MOTIONS as _MOTIONS
from capsim.quantities import TURNING_MOTIONS


#: relative gap (μ_L − μ_l)/(μ_L + μ_l) of the in-plane eigenvalues of the second moment below
#: which the long axis, and θ, is undefined (stored as NaN): round-off of a sphere's
#: eigenvalues is ~1e-15 (θ then arbitrary), a capsule after its first step has D_xy ≳ 1e-6
THETA_UNDEFINED_GAP = 1e-10


def unwrap_defined(theta: np.ndarray) -> np.ndarray:
    """θ unwrapped modulo π where it is defined; NaN (no long axis) left NaN and skipped,
    so that an undefined θ at kt = 0 does not turn the whole unwrapped series into NaN."""
    theta = np.array(theta, dtype=float, copy=True)
    ok = np.isfinite(theta)
    if ok.any():
        theta[ok] = np.unwrap(theta[ok], period=np.pi)
    return theta


def capsule_mean(series: np.ndarray, angle: bool = False) -> np.ndarray:
    """A time series as one number per row: a column of several capsules
    (t, capsule) is their mean, the summary's (each capsule's θ unwrapped first when ``angle``:
    capsules at π/2 − ε and −π/2 + ε are at one orientation). The accuracy ladder and capsim study
    compare its last row between levels."""
    s = np.asarray(series, float)
    if angle:
        s = unwrap_defined(s) if s.ndim == 1 else np.stack([unwrap_defined(c) for c in s.T], axis=1)
    return s.mean(axis=1) if s.ndim == 2 else s


#: eigenvalues of the second moment closer than this (relative to the largest) are one
#: eigenvalue split by round-off (a shape of revolution at rest: ~1e-15); their eigenvectors
#: are then arbitrary, and :func:`principal_frame` chooses them by the shear instead
DEGENERATE_GAP = 1e-9
#: the rate of strain of u∞ = (k y, 0, 0) in units of k, and a small weight of the shear plane
#: that orders a pair the strain cannot (a disk with its normal along y or x: of its two equal
#: axes the flow stretches the one in the shear plane, never the one along z)
_STRAIN = np.array([[0.0, 0.5, 0.0], [0.5, 0.0, 0.0], [0.0, 0.0, 0.0]])
_TIE_BREAK = _STRAIN + 1e-3 * np.diag([1.0, 1.0, 0.0])


def principal_frame(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (ascending) and unit eigenvectors (columns) of the symmetric M, with every
    degenerate eigenspace (eigenvalues within DEGENERATE_GAP) spanned by the directions the
    shear stretches most and least (the eigenvectors of the rate of strain restricted to it).

    A shape of revolution at rest has two equal eigenvalues; numpy's eigenvectors in their
    plane are round-off, so every axis-dependent observable (D_xy, θ, the long and the short
    axis) at t = 0 was a tie-break of round-off, unlike the next row, where the flow has split
    the pair along its extensional direction (issue 39: a red cell 45° off the plane gave
    D_xy 0.52 at t = 0, then 4e-4). Choosing the pair as the flow will split it makes the t = 0
    row the limit of the next ones."""
    mu, vec = np.linalg.eigh(M)
    scale = max(float(np.abs(mu).max()), np.finfo(float).tiny)
    groups, start = [], 0
    for k in range(1, 4):
        if k == 3 or mu[k] - mu[k - 1] > DEGENERATE_GAP * scale:
            groups.append(range(start, k))
            start = k
    for group in groups:
        if len(group) < 2:
            continue
        idx = list(group)
        V = vec[:, idx]
        w, R = np.linalg.eigh(V.T @ _TIE_BREAK @ V)
        vec[:, idx] = V @ R[:, ::-1]  # most stretched first
        mu[idx] = mu[idx].mean()
    return mu, vec


def _line(v: np.ndarray) -> np.ndarray:
    """A line has no sign: the first component that is not ~0 is made positive."""
    v = v.copy()
    lead = v[np.flatnonzero(np.abs(v) > 1e-12)[0]]
    return v * np.sign(lead)


def ellipsoid_axes(geo: ElementGeometry) -> dict:
    volume, area, center, moment = surface_moments(geo)
    out = ellipsoid_of_moment(moment, volume)
    out.update(volume=volume, area=area, centroid=center)
    return out


def ellipsoid_of_moment(M: np.ndarray, volume: float) -> dict:
    """The equivalent ellipsoid's axes, D_xy and θ from the second moment M = ∫_V y y dV about
    the centroid and the volume (ellipsoid_axes without the surface integrals)."""
    mu, vec = principal_frame(M)
    axes = np.sqrt(np.maximum(5.0 * mu / volume, 0.0))
    out_of_plane = int(np.argmax(np.abs(vec[2, :])))
    in_plane = [k for k in range(3) if k != out_of_plane]
    # the most stretched of a degenerate pair is listed first, and max keeps the first on a tie
    i_long = max(in_plane, key=lambda k: axes[k])
    i_short = in_plane[1] if i_long == in_plane[0] else in_plane[0]
    L, l = axes[i_long], axes[i_short]
    # the 3-D ellipsoid (issue 26): semi-axes a ≥ b ≥ c, the direction of the longest and
    # (issue 39) of the shortest: a disk's normal, its symmetry axis
    order = np.argsort(-axes, kind="stable")
    long3, short3 = _line(vec[:, order[0]]), _line(vec[:, order[2]])
    a, b, c = axes[order]
    v = vec[:, i_long]
    theta = float(np.arctan2(v[1], v[0]))
    if theta > np.pi / 2:
        theta -= np.pi
    elif theta <= -np.pi / 2:
        theta += np.pi
    # A shape without a long axis in the shear plane (a sphere, a disk seen along its axis)
    # has two equal in-plane eigenvalues: its eigenvector, and θ with it, is then round-off
    # (a level-3 sphere gave 0.5787 rad). The eigenvector's error is about round-off over
    # the relative gap, so below THETA_UNDEFINED_GAP θ is not a property of the shape.
    gap = abs(mu[i_long] - mu[i_short]) / max(abs(mu[i_long]) + abs(mu[i_short]), np.finfo(float).tiny)
    if not gap >= THETA_UNDEFINED_GAP:
        theta = float("nan")
    return {
        "L": float(L),
        "l": float(l),
        "W": float(axes[out_of_plane]),
        "D_xy": float((L - l) / (L + l)),
        "theta": theta,
        "ellipsoid_a": float(a),
        "ellipsoid_b": float(b),
        "ellipsoid_c": float(c),
        "long_axis": long3,
        "short_axis": short3,
    }


#: the columns of kernels.ellipsoid_of_moment's values, in its order
_ELLIPSOID_COLUMNS = ("axis_L", "axis_l", "axis_W", "D_xy", "theta", "ellipsoid_a", "ellipsoid_b", "ellipsoid_c",
                      "long_axis_x", "long_axis_y", "long_axis_z", "short_axis_x", "short_axis_y", "short_axis_z")


def step_observables(x: np.ndarray, elements: np.ndarray, geo: ElementGeometry, max_stretch: float) -> dict:
    """The per-step time series row (everything but t and dt): the shape's moments, its equivalent
    ellipsoid (:func:`ellipsoid_of_moment`, as numba's ``kernels.ellipsoid_of_moment``: between two
    evaluations each numpy call of the row ran 3-5 times slower than alone, issue 57), the worst
    element, the largest stretch."""
    volume, area, c, moment = surface_moments(geo)
    e = dict(zip(_ELLIPSOID_COLUMNS, kernels.ellipsoid_of_moment(moment, volume, _TIE_BREAK, DEGENERATE_GAP,
                                                                 THETA_UNDEFINED_GAP).tolist()))
    cx, cy, cz = c.tolist()
    row = {"D_xy": e.pop("D_xy"), "theta": e.pop("theta"), "volume": volume, "area": area,
           "centroid_x": cx, "centroid_y": cy, "centroid_z": cz}
    row.update(e)
    row.update(min_element_quality=min_quality(x, elements), max_principal_stretch=float(max_stretch))
    return row


# ---------------------------------------------------------------- the material director


class MaterialDirector:
    """The rest shape's symmetry axis a carried by the membrane (issue 26).

    F is the affine map that best carries the rest surface onto the current one in
    the least-squares sense, weighted by rest area: F = argmin ∫ |x − x̄ − F (X − X̄)|² dS₀,
    i.e. F = [∫ (x − x̄)(X − X̄)ᵀ dS₀] M₀⁻¹, M₀ = ∫ (X − X̄)(X − X̄)ᵀ dS₀ (bars: material
    means over dS₀). The director is F a / |F a|: a material quantity (it follows the
    membrane, so it turns with a tumbling body and circles with a tank-treading
    membrane), exactly R a for a rigid rotation R whatever the mesh, and a whole-
    membrane mean of the deformation gradient (not one node's). Integrals at the
    regular Gauss points of the current geometry, weighted by the rest geometry's."""

    def __init__(self, rest_geometry: ElementGeometry, axis) -> None:
        X = rest_geometry.points.reshape(-1, 3)
        w = rest_geometry.weights.ravel()
        self.w = w / w.sum()
        Xc = X - self.w @ X
        M0 = (Xc * self.w[:, None]).T @ Xc
        a = np.asarray(axis, dtype=np.float64)
        # F a = Σ w (x − x̄) [(X − X̄) · M₀⁻¹ a]: one weight per Gauss point
        self.weights = self.w * (Xc @ np.linalg.solve(M0, a / np.linalg.norm(a)))

    def __call__(self, geo: ElementGeometry) -> np.ndarray:
        x = geo.points.reshape(-1, 3)
        d = self.weights @ (x - self.w @ x)
        return d / np.linalg.norm(d)


def director_observables(d: np.ndarray) -> dict:
    """The director, its polar angle from the vorticity axis z, arccos d_z ∈ [0, π], and
    its azimuth in the shear plane from the gradient axis y towards the flow axis x,
    atan2(d_x, d_y) ∈ (−π, π] (Jeffery's angles, docs/known_answers.md)."""
    dx, dy, dz = (float(v) for v in d)  # Python floats: the row's other numbers are (issue 57)
    return {
        "director_x": dx,
        "director_y": dy,
        "director_z": dz,
        "director_polar_angle": math.acos(min(max(dz, -1.0), 1.0)),
        "director_azimuth": math.atan2(dx, dy),
    }


def rest_aspect_ratio(rest_geometry: ElementGeometry, axis) -> float:
    """r = axis / equatorial diameter of the rest shape's equivalent ellipsoid: the square
    root of the ratio of its second moments of volume along a and across it (exact for a
    spheroid; the equivalent-ellipsoid value for the biconcave disk)."""
    volume, _ = volume_area(rest_geometry)
    M = second_moment(rest_geometry, centroid(rest_geometry, volume))
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    along = float(a @ M @ a)
    across = 0.5 * (float(np.trace(M)) - along)
    return float(np.sqrt(along / across))


# ---------------------------------------------------------------- stresslet


class RowSums:
    """The row's surface integrals about the centroid from one kernel pass
    (capsim.numerics.kernels.row_surface_sums): the material director (as :class:`MaterialDirector`),
    the centroid's velocity dc/dt by Reynolds' transport theorem, d/dt ∫_V x dV = ∮ x (u·n) dS, so
    dc/dt = (∮ x (u·n) dS − c ∮ u·n dS)/V, and the stresslet (as :func:`particle_stresslet`;
    tests/numerics/test_step_kernels.py holds them equal to round-off)."""

    def __init__(self, values: np.ndarray) -> None:
        self.values = values

    @property
    def director(self) -> np.ndarray:
        d = self.values[24:27]
        return d / math.sqrt(float(d @ d))

    def centroid_velocity(self, volume: float) -> np.ndarray:
        return self.values[0:3] + self.values[3:6] / volume

    @staticmethod
    def stresslet_of(values: list[float], volume: float, shear_rate_G: float, viscosity_ratio: float) -> np.ndarray:
        """:meth:`stresslet` from the sums as Python floats (``values.tolist()``, which a row holds already),
        element by element: S = sym(elastic)/G − (1 − λ) sym(∫ u n dS), S* = S/(2.5 V) (a row's nine numpy
        calls on 3×3 arrays cost more than the pass that made the sums)."""
        rows = []
        for i in range(3):
            row = []
            for j in range(3):
                s = 0.5 * (values[6 + 3 * i + j] + values[6 + 3 * j + i]) / shear_rate_G
                if viscosity_ratio != 1.0:
                    s = s - (1.0 - viscosity_ratio) * (values[15 + 3 * i + j] + values[15 + 3 * j + i])
                row.append(s / (2.5 * volume))
            rows.append(row)
        return np.array(rows)

    def stresslet(self, volume: float, shear_rate_G: float, viscosity_ratio: float) -> np.ndarray:
        """S* as :func:`particle_stresslet` gives it."""
        return self.stresslet_of(self.values.tolist(), volume, shear_rate_G, viscosity_ratio)


def row_surface_sums(geo: ElementGeometry, density: np.ndarray, weights: np.ndarray, u: np.ndarray,
                     elements: np.ndarray, phi: np.ndarray, center: np.ndarray,
                     director: MaterialDirector) -> RowSums:
    """:class:`RowSums` of a configuration: Δf element-nodal (N_e, 6, 3), or element-constant (N_e, 3: the
    contour method's, repeated at the six nodes: the shape functions sum to one), per the measure ``weights``."""
    if density.ndim == 2:
        density = np.repeat(density[:, None, :], elements.shape[1], axis=1)
    return RowSums(kernels.row_surface_sums(geo.points, geo.normals, geo.weights, np.ascontiguousarray(weights),
                                            density, np.ascontiguousarray(u), elements, phi,
                                            np.asarray(center, dtype=np.float64), director.weights, director.w))


def particle_stresslet(
    geo: ElementGeometry,
    density: np.ndarray,
    velocity: np.ndarray,
    elements: np.ndarray,
    phi: np.ndarray,
    center: np.ndarray,
    volume: float,
    shear_rate_G: float,
    viscosity_ratio: float,
    weights: np.ndarray | None = None,
) -> np.ndarray:
    """Particle stresslet (seed 2.15) over its rigid-sphere value, a (3, 3) array.

    S = ∫ [Δf x − μ(1−λ)(u n + n u)] dS about the centroid; in units of μka³,
    S = (1/G) ∫ Δf x dS − (1−λ) ∫ (u n + n u) dS (Δf in E_s/a, u in ka), and
    S* = S / ((5/2) V) so that a rigid sphere gives S*_xy = 1. The Δf x term is
    symmetrised (its antisymmetric part is the torque, zero up to discretisation).

    density: Δf as the single layer takes it, (N_e, 6, 3) element-nodal values
    interpolated with ``phi`` (q, 6), or (N_e, 3) element-constant, per unit area of the
    surface, or per unit rest area with ``weights`` the rest shape's (``MembraneState.
    weights``: Δf dS = F dS0). velocity: nodal u (N_p, 3), interpolated quadratically to
    the Gauss points.
    """
    weights = geo.weights if weights is None else weights
    if density.ndim == 3:
        df = interpolate(phi, density)
    else:
        df = np.broadcast_to(density[:, None, :], geo.points.shape)
    x = geo.points - center
    elastic = (df * weights[..., None]).reshape(-1, 3).T @ x.reshape(-1, 3)
    S = 0.5 * (elastic + elastic.T) / shear_rate_G
    if viscosity_ratio != 1.0:
        # less the mean velocity (∫ n dS = 0): a capsule carried fast has no round-off of it here
        u = interpolate(phi, velocity[elements] - velocity.mean(axis=0))
        un = (u * geo.weights[..., None]).reshape(-1, 3).T @ geo.normals.reshape(-1, 3)
        S -= (1.0 - viscosity_ratio) * (un + un.T)
    return S / (2.5 * volume)


def stresslet_observables(S_star: np.ndarray) -> dict:
    """S*_xy and the normal stress differences N1* = S*_xx − S*_yy, N2* = S*_yy − S*_zz."""
    return {
        "Sxy_star": float(S_star[0, 1]),
        "N1_star": float(S_star[0, 0] - S_star[1, 1]),
        "N2_star": float(S_star[1, 1] - S_star[2, 2]),
    }


#: row columns that are NaN by definition in some states, not by failure: θ where the shape has
#: no long axis in the plane (a sphere at rest: THETA_UNDEFINED_GAP), dissipation_ratio where the
#: undisturbed flow has no rate of strain at the centroid (the Poiseuille axis, a stopped flow)
MAY_BE_UNDEFINED = ("theta", "dissipation_ratio", "extra_pressure_drop")  # ΔP+: λ ≠ 1 in a constriction


def dissipation_ratio(S_star: np.ndarray, E: np.ndarray) -> float:
    """The particle's extra viscous dissipation S:E (Batchelor 1970: a force-free particle in the
    local rate of strain E of the undisturbed flow, in units of the rate) over a rigid sphere's in
    the same flow, 5μV E:E; with S* = S/((5/2)μkV) that is S*:E / (2 E:E). 1 for a rigid sphere in
    any linear flow; in simple shear it equals S*_xy. NaN where E vanishes (the axis of Poiseuille
    flow, a stopped flow)."""
    EE = float(np.vdot(E, E))
    return float(np.vdot(S_star, E)) / (2.0 * EE) if EE > 1e-20 else float("nan")


# ---------------------------------------------------------------- tank-treading

RIGID_SPHERE_ROTATION_RATE = 0.5  # |ω| of a rigid sphere in shear: k/2, i.e. f_s = k/(4π)


#: the tracker's angles before its first update (kernels.tank_treading_angles: "none yet")
_NO_ANGLES = np.empty(0)


class TankTreadingTracker:
    """Material nodes that start in the plane z = 0 (for a rest shape turned off the shear
    plane, which has no mesh line there: those of the band |z| < band·max|z| away from the
    z-axis), followed about the centroid.

    Each step gives the mean phase-unwrapped angle of these nodes in the
    xy-plane (``tt_angle``, decreasing for the clockwise rotation of shear flow)
    and the instantaneous rate ω = ⟨(r × u)_z / |r|²⟩ over them, reported as
    ``ttf_ratio`` = |ω| / (k/2) over f_s = k/(4π): the nodes' rate in the lab frame, the
    membrane's tank-treading when the body does not turn, its turn (and any tank-treading
    on it) when it does (run_summary tells them apart: rotation_rates).
    """

    def __init__(self, rest_positions: np.ndarray, plane_tol: float = 1e-9, band: float = 0.25) -> None:
        # the plane through the rest shape's own centre (a capsule placed off z = 0: initial_center, capsules)
        rest_positions = rest_positions - rest_positions.mean(axis=0)
        self.nodes = np.flatnonzero(np.abs(rest_positions[:, 2]) < plane_tol)
        if self.nodes.size == 0:
            # a rest shape turned out of the shear plane (issue 26) has no mesh line on
            # z = 0: follow the nodes of a band about it instead, away from the z-axis
            z, rho = np.abs(rest_positions[:, 2]), np.hypot(rest_positions[:, 0], rest_positions[:, 1])
            self.nodes = np.flatnonzero((z < band * z.max()) & (rho > 0.5 * rho.max()))
        if self.nodes.size == 0:
            raise ValueError("no rest-shape nodes lie near the plane z = 0 to track tank-treading")
        self._raw: np.ndarray | None = None
        self._unwrapped: np.ndarray | None = None

    def update(self, x: np.ndarray, u: np.ndarray, center: np.ndarray) -> dict:
        # steps are short: no node turns by π between two accepted steps
        before = (self._raw, self._unwrapped) if self._raw is not None else (_NO_ANGLES, _NO_ANGLES)
        omega, angle, self._raw, self._unwrapped = kernels.tank_treading_angles(
            x, u, self.nodes, np.asarray(center, dtype=float), *before)
        return {"ttf_ratio": abs(omega) / RIGID_SPHERE_ROTATION_RATE, "tt_angle": angle}

    def state(self) -> dict[str, np.ndarray]:
        """The angles of the last update (the unwrapping carries them on)."""
        if self._raw is None:
            return {}
        return {"raw": self._raw.copy(), "unwrapped": self._unwrapped.copy()}

    def restore(self, state: dict[str, np.ndarray]) -> None:
        if "raw" in state:
            self._raw = np.array(state["raw"], dtype=float, copy=True)
            self._unwrapped = np.array(state["unwrapped"], dtype=float, copy=True)


def revolution_rate(t: np.ndarray, angle: np.ndarray, t_from: float) -> float | None:
    """Mean rate |dφ/dt| over the whole revolutions of ``angle`` completed since
    ``t_from`` (counted back from the last sample); None if less than one."""
    t = np.asarray(t, float)
    angle = np.asarray(angle, float)
    sel = t >= t_from
    if np.count_nonzero(sel) < 2:
        return None
    ts, a = t[sel], angle[sel]
    turned = np.abs(a - a[-1])
    n = int(np.floor(turned.max() / (2 * np.pi)))
    if n < 1:
        return None
    target = 2 * np.pi * n
    # last time (going back from the end) at which the angle had turned by n revolutions less
    i = int(np.flatnonzero(turned >= target)[-1])
    if i + 1 < ts.size and turned[i] != turned[i + 1]:
        w = (turned[i] - target) / (turned[i] - turned[i + 1])
        t_start = ts[i] + w * (ts[i + 1] - ts[i])
    else:
        t_start = ts[i]
    return target / (ts[-1] - t_start)


# ---------------------------------------------------------------- motion classifier

#: the classes, their meanings and old names: capsim.quantities (MOTIONS, MOTION_MEANINGS,
#: MOTION_ALIASES); the decision procedure: classify_orbit, and docs/method.md, "Motion classes"
MOTIONS = _MOTIONS
#: the body's symmetry axis counts as along the vorticity axis (rolling) while it stays
#: within this angle of ±z over the classifier's window (rad, ≈ 5.7°) ...
ROLLING_TOL = 0.1
#: ... and as in the shear plane while it stays within this angle of it (≈ 10°); between the
#: two it is off the plane (kayaking, off-plane tank-treading)
OFF_PLANE_TOL = np.deg2rad(10.0)
#: an orbit has settled when its last two whole orbits agree: their periods and their mean
#: orbit constants within this fraction
SETTLED_RTOL = 1e-2
#: an orbit constant that changes by this fraction or more per orbit is a transition in progress
#: (drifting_to_rolling, drifting_to_plane); between SETTLED_RTOL and this the body kayaks but
#: has not settled (a stiff prolate at G = 5e-4 drifts −4 % per orbit towards rolling, the
#: issue-39 red cells 17–63 %)
DRIFT_RTOL = 5e-2
#: whole orbits a settled orbit needs (the last two are compared)
SETTLED_ORBITS = 2
#: swinging has settled when its last two cycles agree: periods and peak-to-peak of θ (or of
#: D_xy, whichever swings) within this fraction
CYCLE_RTOL = 5e-2
#: the body turns (tumbling, kayaking) when its symmetry axis's azimuth advances by at least
#: this over the last half of the run; a swinging body's goes back and forth, no net advance
TURNING_ADVANCE = np.pi / 2
#: below this |sin| of its polar angle the axis is on z to round-off and has no azimuth (a
#: director on z to 1e-17 has an azimuth of round-off that "turns through π": issue 38, 13)
AZIMUTH_FLOOR = 1e-6
#: the rest shape is a sphere (no symmetry axis) when |r − 1| is below this
SPHERE_TOL = 1e-3
#: a turn is nearly rigid when the membrane's rate relative to the body is below this
#: fraction of the body's rate
RIGID_TURN_TOL = 0.1
SUMMARY_QUANTITIES = ("D_xy", "theta", "ttf_ratio", "Sxy_star", "N1_star", "N2_star")


def _window(t_end: float, fraction: float, min_window: float) -> float:
    return max(fraction * t_end, min_window)


def window_stats(t: np.ndarray, s: np.ndarray, t0: float, t1: float | None = None) -> tuple[float, float]:
    """Time-weighted mean and standard deviation of s over [t0, t1] (samples are
    unevenly spaced: adaptive steps)."""
    t = np.asarray(t, float)
    s = np.asarray(s, float)
    t1 = t[-1] if t1 is None else t1
    sel = (t >= t0 - 1e-12) & (t <= t1 + 1e-12)
    ts, ss = t[sel], s[sel]
    if ts.size == 0:
        return float(s[-1]), 0.0
    if ts.size < 2 or ts[-1] <= ts[0]:
        return float(ss.mean()), float(ss.std())
    span = ts[-1] - ts[0]
    mean = np.trapezoid(ss, ts) / span
    var = np.trapezoid((ss - mean) ** 2, ts) / span
    return float(mean), float(np.sqrt(max(var, 0.0)))


def is_steady(
    t: np.ndarray,
    D_xy: np.ndarray,
    theta: np.ndarray,
    rtol: float = 1e-2,
    theta_tol: float = 1e-2,
    window_fraction: float = 0.25,
    min_window: float = 3.0,
) -> bool:
    """D_xy and θ settled: over the last ``max(window_fraction·t, min_window)`` of
    kt (and at least as much time before it), D_xy varies by less than
    ``rtol``·D_xy and θ by less than ``theta_tol`` rad. θ is ignored while the
    shape is a sphere to 1e-3 (its long axis is then undefined)."""
    t = np.asarray(t, float)
    if t.size < 3:
        return False
    w = _window(t[-1], window_fraction, min_window)
    if t[-1] - t[0] < 2 * w:
        return False
    sel = t >= t[-1] - w
    d = np.asarray(D_xy, float)[sel]
    th = unwrap_defined(np.asarray(theta, float)[sel])
    if not np.all(np.isfinite(d)):
        return False
    scale = max(float(np.abs(d).mean()), 1e-3)
    if float(np.ptp(d)) > rtol * scale:
        return False
    # θ undefined (NaN) in the window: only a shape without a long axis, which scale ≤ 1e-3 covers
    return scale <= 1e-3 or (bool(np.all(np.isfinite(th))) and float(np.ptp(th)) <= theta_tol)


def _oscillation(t: np.ndarray, s: np.ndarray, floor: float, min_ratio: float = 0.5) -> dict | None:
    """Sustained periodic oscillation of s(t): at least two whole cycles between
    up-crossings of its linear trend (with hysteresis, so that noise near the
    trend does not count), regular periods and no strong decay."""
    if t.size < 10:
        return None
    ups = _up_crossings(t, s - np.polyval(np.polyfit(t, s, 1), t), floor)
    if len(ups) < 3:
        return None
    # again about the mean over whole cycles: a linear trend fitted to a
    # sinusoid is not flat and would bias the period
    ups = _up_crossings(t, s - window_stats(t, s, ups[0], ups[-1])[0], floor)
    if len(ups) < 3:
        return None
    periods = np.diff(ups)
    if periods.max() > 1.3 * periods.min():
        return None
    cycles = [np.ptp(s[(t >= a) & (t <= b)]) for a, b in zip(ups[:-1], ups[1:])]
    if cycles[-1] < min_ratio * cycles[0]:
        return None
    return {"period": float(periods[-2:].mean()), "t_from": ups[0], "t_to": ups[-1], "last_cycle": (ups[-2], ups[-1]),
            "periods": [float(p) for p in periods], "cycles": [float(c) for c in cycles]}


def _cycles_agree(osc: dict | None, rtol: float = CYCLE_RTOL) -> bool:
    """The last two cycles of an oscillation agree: periods and peak-to-peak within rtol."""
    if osc is None or len(osc["periods"]) < 2:
        return False
    (p0, p1), (c0, c1) = osc["periods"][-2:], osc["cycles"][-2:]
    return abs(p1 - p0) <= rtol * p1 and abs(c1 - c0) <= rtol * max(c1, c0)


def _up_crossings(t: np.ndarray, r: np.ndarray, floor: float) -> list[float]:
    """Times at which r rises through 0, counted only when it goes from below −h
    to above +h (h = 30% of its half-range): noise near 0 does not count."""
    half_range = 0.5 * float(np.ptp(r))
    if half_range <= floor:
        return []
    h = 0.3 * half_range
    ups: list[float] = []
    armed = False
    last_neg = 0
    for i in range(t.size):
        if r[i] < -h:
            armed = True
        if r[i] <= 0.0:
            last_neg = i
        if armed and r[i] > h:
            j = last_neg  # r[j] ≤ 0 < r[j+1]: the zero crossing of this rise
            w = -r[j] / (r[j + 1] - r[j])
            ups.append(float(t[j] + w * (t[j + 1] - t[j])))
            armed = False
    return ups


def _cycle_stats(t: np.ndarray, s: np.ndarray, t_from: float, last_cycle: tuple[float, float]) -> tuple[float, float]:
    mean, _ = window_stats(t, s, t_from, last_cycle[1])
    sel = (t >= last_cycle[0]) & (t <= last_cycle[1])
    return mean, 0.5 * float(np.ptp(s[sel])) if np.any(sel) else 0.0


def classify_motion(
    t: np.ndarray,
    D_xy: np.ndarray,
    theta: np.ndarray,
    rtol: float = 1e-2,
    theta_tol: float = 1e-2,
    window_fraction: float = 0.25,
    min_window: float = 3.0,
) -> dict:
    """What kind of motion the time series (t, D_xy, θ) settled into.

    Returns ``{"motion", "t_from", "t_to", "period", "D_xy_mean",
    "D_xy_amplitude", "theta_mean", "theta_amplitude"}``; [t_from, t_to] is the
    averaging window (whole cycles for oscillating and tumbling, else the last
    ``window_fraction`` of the run), NaN where a field does not apply.

    - unstable: a non-finite value;
    - tumbling: θ ∈ (−π/2, π/2], unwrapped, goes below −π/2 (continuous
      clockwise rotation); period = time for θ to turn by 2π (Jeffery's orbit
      period, seed §5), from successive passages through −π/2 (mod π);
    - steady: :func:`is_steady`;
    - swinging (``oscillating`` before issue 39): at least two sustained regular cycles of θ
      or D_xy over the last two thirds of the run (period from θ when it oscillates), with mean
      and amplitude (half the peak-to-peak of the last cycle) of both;
    - transient: none of these (still evolving, or too short to tell).

    ``settled`` says whether the motion has settled: steady always; swinging when its last
    two cycles agree within CYCLE_RTOL; tumbling when its last two whole turns (θ through
    2π) took the same time within SETTLED_RTOL.
    """
    t = np.asarray(t, float)
    D_xy = np.asarray(D_xy, float)
    theta = np.asarray(theta, float)
    nan = float("nan")
    out = {"motion": "transient", "t_from": nan, "t_to": nan, "period": nan,
           "D_xy_mean": nan, "D_xy_amplitude": nan, "theta_mean": nan, "theta_amplitude": nan, "settled": False}
    if t.size == 0:
        return out
    t_end = float(t[-1])
    out["t_to"] = t_end
    out["t_from"] = max(float(t[0]), (1.0 - window_fraction) * t_end)
    # θ is NaN where the shape has no long axis (a sphere at kt = 0): not a failure; ±∞ is
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(D_xy)) and not np.any(np.isinf(theta))):
        out["motion"] = "unstable"
        return out

    if _tumbling(t, D_xy, theta, out):
        return out
    if is_steady(t, D_xy, theta, rtol, theta_tol, window_fraction, min_window):
        out["motion"] = "steady"
        out["settled"] = True
        for name, s in (("D_xy", D_xy), ("theta", theta)):
            out[f"{name}_mean"] = window_stats(t, s, out["t_from"])[0]
        return out
    _oscillating(t, D_xy, theta, rtol, theta_tol, out)
    return out


def _tumbling(t: np.ndarray, D_xy: np.ndarray, theta: np.ndarray, out: dict) -> bool:
    """classify_motion's tumbling: θ, unwrapped, below −π/2 (a continuous clockwise turn);
    the period from successive passages through −π/2 (mod π), Jeffery's (seed §5). Fills
    `out` and returns True when it tumbles."""
    defined = (D_xy > 1e-3) & np.isfinite(theta)  # θ of a sphere is undefined
    if np.count_nonzero(defined) < 2:
        return False
    td = t[defined]
    th_u = np.unwrap(theta[defined], period=np.pi)
    if not th_u.min() < -np.pi / 2 - 0.05:
        return False
    out["motion"] = "tumbling"
    passes = _passages(td, th_u, -np.pi / 2, falling_only=True)  # through −π/2 − mπ, m = 0, 1, ...
    if len(passes) >= 2:
        out["period"] = 2.0 * float(passes[-1] - passes[-2])
        out["t_from"], out["t_to"] = float(passes[-2]), float(passes[-1])
        # D_xy repeats every half turn (the shape is head-tail symmetric): its mean and half
        # peak-to-peak over the last one, the spread a researcher quotes for a periodic motion
        out["D_xy_mean"], out["D_xy_amplitude"] = _cycle_stats(t, D_xy, out["t_from"], (out["t_from"], out["t_to"]))
    if len(passes) >= 5:  # two whole turns (four half turns): settled when they took the same time
        last, before = passes[-1] - passes[-3], passes[-3] - passes[-5]
        out["settled"] = bool(abs(last - before) < SETTLED_RTOL * last)
    if len(passes) == 1 and td[-1] > passes[0]:
        turned = abs(th_u[-1] - (-np.pi / 2))
        if turned > 0.1:
            out["period"] = 2 * np.pi * float(td[-1] - passes[0]) / turned
    return True


def _oscillating(t: np.ndarray, D_xy: np.ndarray, theta: np.ndarray, rtol: float, theta_tol: float,
                 out: dict) -> None:
    """classify_motion's swinging: two sustained regular cycles of θ or D_xy over the
    last two thirds of the run (the start-up transient of a capsule is a few kt, and two
    whole cycles of kT ≈ 10 must fit in a run of a few tens of kt); fills `out` if so."""
    half = t >= float(t[-1]) / 3.0
    th_half = unwrap_defined(theta[half])
    if not np.all(np.isfinite(th_half)):  # no long axis in this half: D_xy alone can oscillate
        th_half = np.zeros_like(th_half)
    scale = max(float(np.abs(D_xy[half]).mean()), 1e-3)
    osc = _oscillation(t[half], th_half, theta_tol) or _oscillation(t[half], D_xy[half], rtol * scale)
    if osc is None:
        return
    out["motion"] = "swinging"
    out["settled"] = _cycles_agree(osc)
    out["period"] = osc["period"]
    out["t_from"], out["t_to"] = osc["t_from"], osc["t_to"]
    for name, s in (("D_xy", D_xy[half]), ("theta", th_half)):
        out[f"{name}_mean"], out[f"{name}_amplitude"] = _cycle_stats(t[half], s, osc["t_from"], osc["last_cycle"])


def _passages(t: np.ndarray, s: np.ndarray, offset: float, *, shift: float = 0.0,
              falling_only: bool = False) -> list[float]:
    """The times at which s(t), unwrapped, passes through offset + mπ (m any whole number),
    linearly interpolated between samples; only downward passages with `falling_only`;
    `shift` (in units of π) moves the levels so that a start exactly on one counts."""
    level = np.floor((s - offset) / np.pi - shift)
    change = np.diff(level)
    passes = []
    for i in np.flatnonzero(change < 0 if falling_only else change != 0):
        target = max(level[i], level[i + 1]) * np.pi + offset
        w = (target - s[i]) / (s[i + 1] - s[i])
        passes.append(t[i] + w * (t[i + 1] - t[i]))
    return passes


def jeffery_orbit_constant(polar: np.ndarray, azimuth: np.ndarray, r: float) -> np.ndarray:
    """C = |tan θ| (r² cos²φ + sin²φ)^½ / r from Jeffery's orbit tan θ = C r / (r² cos²φ + sin²φ)^½
    (θ the polar angle from z, φ the azimuth from y; docs/known_answers.md): constant
    along a rigid spheroid's orbit; 0 rolling along z, ∞ in the shear plane."""
    polar = np.asarray(polar, float)
    with np.errstate(divide="ignore"):
        # in the plane to round-off (cos θ ~ 1e-17): ∞, not tan's 1e16
        tan = np.where(np.abs(np.cos(polar)) < 1e-12, np.inf, np.abs(np.tan(polar)))
    return tan * np.sqrt(r**2 * np.cos(azimuth) ** 2 + np.sin(azimuth) ** 2) / r


def continuous_line(n: np.ndarray) -> np.ndarray:
    """Unit vectors of a line (n, 3) whose stored sign is a convention (long_axis, short_axis:
    the first component that is not ~0 positive) made continuous from row to row: each row
    keeps the sign that points it along the row before (p and −p are one axis)."""
    n = np.array(n, dtype=float, copy=True)
    if n.shape[0] < 2:
        return n
    dots = np.einsum("ij,ij->i", n[1:], n[:-1])
    n[1:] *= np.cumprod(np.where(dots < 0.0, -1.0, 1.0))[:, None]
    return n


def _stack(series: dict, prefix: str) -> np.ndarray | None:
    if not all(f"{prefix}_{c}" in series for c in "xyz"):
        return None
    return np.stack([np.asarray(series[f"{prefix}_{c}"], float) for c in "xyz"], axis=1)


def body_axis(series: dict, aspect_ratio: float) -> np.ndarray | None:
    """The body's symmetry axis at every row, (n, 3) unit vectors, sign-continuous: the shape's
    own axis from the equivalent ellipsoid (issue 39), its longest axis for a prolate rest shape
    (r > 1) and its shortest, a disk's normal, for an oblate or biconcave one (r < 1). Not the
    material director: a tank-treading membrane carries the director round while the shape
    stays put. Rows without the shape's axes (a run file written before issue 39, or a resumed
    one's earlier rows) take the material director (the same axis for a body turning rigidly).
    None for a sphere (|r − 1| < SPHERE_TOL: no symmetry axis) or without either."""
    if not abs(aspect_ratio - 1.0) >= SPHERE_TOL:
        return None
    axis = _stack(series, "long_axis" if aspect_ratio > 1.0 else "short_axis")
    director = _stack(series, "director")
    if axis is None:
        axis = director
    elif director is not None:
        missing = ~np.all(np.isfinite(axis), axis=1)
        axis[missing] = director[missing]
    if axis is None or axis.shape[0] == 0:
        return None
    return continuous_line(axis)


def _folded_polar(d: np.ndarray) -> np.ndarray:
    """Angle of the line d from the vorticity axis, in [0, π/2]."""
    return np.arccos(np.clip(np.abs(d[:, 2]), 0.0, 1.0))


def _azimuth(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rows where the axis has an azimuth, its azimuth there from y towards x, unwrapped)."""
    ok = np.hypot(d[:, 0], d[:, 1]) > AZIMUTH_FLOOR
    return ok, np.unwrap(np.arctan2(d[ok, 0], d[ok, 1]))


def orbit_summary(t: np.ndarray, director: np.ndarray, aspect_ratio: float = 1.0) -> dict:
    """The orbit of an axis (director: (n, 3) unit vectors at times t, the body's symmetry
    axis or the material director): its period, Jeffery's orbit constant and their changes.

    The azimuth φ = atan2(d_x, d_y), unwrapped over the rows where the axis is off z
    (AZIMUTH_FLOOR), passes through mπ (the axis crossing the yz-plane, where it turns
    fastest) twice per orbit; a whole orbit is φ through 2π, from one passage to the next but
    one (a line: p and −p are the same axis, and the count is the same for either). Whole
    orbits are counted back from the last passage.

    - ``orbit_period``: the last whole orbit's duration, 2π(r + 1/r) for Jeffery's rigid
      spheroid (twice its second half when it begins at the run's start: the first half holds
      the start-up); ``orbit_period_change``: |T_last − T_before| / T_last over the last two;
    - ``orbit_constant_first``, ``orbit_constant``: time means of C over the first and the last
      whole orbit; ``orbit_constant_drift``: (C_last − C_first) / (n C_first), n the orbits
      between them (NaN under two whole orbits);
    - ``orbit_constant_change``: the relative change of C per orbit now: between the means
      over the last two whole orbits, or, with fewer, over the last two half orbits, squared to
      a whole orbit (C repeats every half orbit: the shear flow is the same after a half turn
      about z); NaN in the plane (C = ∞) or under two half orbits;
    - ``orbit_periods``: the whole orbits in the run; ``final_polar_angle``: the axis's angle
      from the vorticity axis at the end, in [0, π/2].
    ``_passages`` (private) lists the passage times for the caller's window."""
    t = np.asarray(t, float)
    d = np.asarray(director, float)
    nan = float("nan")
    out = {"orbit_period": nan, "orbit_period_change": nan, "orbit_constant": nan, "orbit_constant_first": nan,
           "orbit_constant_drift": nan, "orbit_constant_change": nan, "orbit_periods": 0.0,
           "final_polar_angle": float(_folded_polar(d[-1:])[0]) if t.size and np.all(np.isfinite(d[-1])) else nan,
           "jeffery_aspect_ratio": float(aspect_ratio),
           "jeffery_period": float(2.0 * np.pi * (aspect_ratio + 1.0 / aspect_ratio)), "_passages": []}
    if t.size < 3 or not np.all(np.isfinite(d)):
        return out
    ok, phi = _azimuth(d)
    if phi.size < 3:
        return out
    tt = t[ok]
    # the shift counts a start exactly on a passage (an axis started in the yz-plane)
    passes = np.array(_passages(tt, phi, 0.0, shift=1e-9))
    out["_passages"] = [float(p) for p in passes]
    if passes.size < 2:
        return out
    polar = np.arccos(np.clip(d[ok, 2], -1.0, 1.0))
    C = jeffery_orbit_constant(polar, phi, aspect_ratio)

    def mean(a, b):
        sel = (tt >= a) & (tt <= b)
        return float("inf") if np.isinf(C[sel]).any() else window_stats(tt, C, a, b)[0]

    def ratio(new, old):
        return new / old if 0.0 < old < np.inf and np.isfinite(new) else nan

    if passes.size >= 3:
        halves = [mean(a, b) for a, b in zip(passes[-3:-1], passes[-2:])]
        out["orbit_constant_change"] = ratio(halves[1], halves[0]) ** 2 - 1.0
        out["orbit_period"] = float(passes[-1] - passes[-3])
        if passes[-3] <= tt[1]:  # a passage before the second row is the start
            # a whole orbit from the run's start holds the start-up (a body at rest deforming
            # tilts its axis by O(G) at once: a stiff prolate's first half orbit is 4e-4 short):
            # twice its second half, the same by the flow's symmetry under a half turn about z
            out["orbit_period"] = float(2.0 * (passes[-1] - passes[-2]))
        out["orbit_periods"] = float((passes.size - 1) // 2)
        out["orbit_constant_first"] = mean(passes[0], passes[2])
        out["orbit_constant"] = mean(passes[-3], passes[-1])
    if passes.size >= 5:
        out["orbit_constant_change"] = ratio(out["orbit_constant"], mean(passes[-5], passes[-3])) - 1.0
        out["orbit_period_change"] = float(abs((passes[-1] - passes[-3]) - (passes[-3] - passes[-5]))
                                           / (passes[-1] - passes[-3]))
        orbits_between = (passes.size - 3) / 2.0  # from the first whole orbit's start to the last's
        out["orbit_constant_drift"] = (ratio(out["orbit_constant"], out["orbit_constant_first"]) - 1.0) / orbits_between
    return out


def rotation_rates(t: np.ndarray, t_from: float, t_to: float, axis: np.ndarray | None, theta: np.ndarray,
                   tt_angle: np.ndarray | None, D_xy: np.ndarray | None = None, turning: bool | None = None) -> dict:
    """The body's rotation and the membrane's tank-treading over [t_from, t_to], each as a
    rate about the vorticity axis, clockwise (the sense of the shear) positive, over the rigid
    sphere's k/2 (as ttf_ratio):

    - ``body_rotation_ratio``: the turn of the shape's axes: of its symmetry axis's azimuth
      where that axis is off z (the window's median angle from z above ROLLING_TOL), else of
      its in-plane long axis θ; 0 for a round cross-section (D_xy below 1e-3 over the window,
      θ undefined: a body of revolution spinning about z shows no turn of its shape);
    - ``tank_treading_ratio``: the tracked material nodes' mean turn (tt_angle) less the
      body's: the membrane relative to the shape. A spin about the body's own symmetry axis
      counts here (on a shape of revolution it cannot be told from tank-treading);
    - ``rigid_turn``: 1 when the body turns (``turning``, the classifier's verdict; without it
      |body_rotation_ratio| ≥ 0.05) and the membrane's relative rate is below RIGID_TURN_TOL of
      the body's: ttf_ratio is then the body's turn;
    - ``ttf_ratio_kind``: what ttf_ratio (the nodes' rate in the lab frame) is here, a flag
      (0 tank-treading, 1 turn plus tank-treading, 2 a nearly rigid turn: TTF_RATIO_KINDS)."""
    nan = float("nan")
    out = {"body_rotation_ratio": nan, "tank_treading_ratio": nan, "rigid_turn": nan, "ttf_ratio_kind": nan}
    t = np.asarray(t, float)
    if not (np.isfinite(t_from) and np.isfinite(t_to) and t_to > t_from) or t.size < 2:
        return out
    span = t_to - t_from
    body = nan
    if axis is not None:
        sel = (t >= t_from) & (t <= t_to)
        if np.any(sel) and float(np.median(_folded_polar(axis[sel]))) > ROLLING_TOL:
            ok, phi = _azimuth(axis)
            if phi.size >= 2:
                body = float(np.interp(t_to, t[ok], phi) - np.interp(t_from, t[ok], phi)) / span
    if not np.isfinite(body):
        th = unwrap_defined(np.asarray(theta, float))
        fin = np.isfinite(th)
        window = (t >= t_from) & (t <= t_to)
        if np.all(fin[window]) and np.count_nonzero(fin) >= 2 and t[fin][0] <= t_from:
            body = -float(np.interp(t_to, t[fin], th[fin]) - np.interp(t_from, t[fin], th[fin])) / span
        elif D_xy is not None and np.any(window) and float(np.max(np.abs(np.asarray(D_xy)[window]))) < 1e-3:
            body = 0.0
    out["body_rotation_ratio"] = body / RIGID_SPHERE_ROTATION_RATE
    if tt_angle is not None:
        tt = np.asarray(tt_angle, float)
        nodes = -float(np.interp(t_to, t, tt) - np.interp(t_from, t, tt)) / span
        membrane = nodes - body
        out["tank_treading_ratio"] = membrane / RIGID_SPHERE_ROTATION_RATE
        if np.isfinite(body):
            if turning is None:
                turning = abs(out["body_rotation_ratio"]) >= 0.05
            rigid = turning and abs(membrane) < RIGID_TURN_TOL * abs(body)
            out["rigid_turn"] = float(rigid)
            out["ttf_ratio_kind"] = 2.0 if rigid else 1.0 if turning else 0.0  # quantities.TTF_RATIO_KINDS
    return out


def _shape_period(t: np.ndarray, shape: np.ndarray | None, D_xy: np.ndarray, rtol: float) -> float:
    """Period of the shape's oscillation over the last two thirds of the run: of
    (a − c)/(a + c) of the equivalent ellipsoid (any orientation), or of D_xy without it, from
    its last whole cycle (between its last two rises through its mean, with hysteresis:
    _up_crossings); NaN when the shape does not oscillate by more than rtol of its mean (a
    steady state, a rigid turn) or shows no whole cycle."""
    late = t >= float(t[-1]) / 3.0
    if shape is not None and np.all(np.isfinite(shape[late])):
        s = (shape[late, 0] - shape[late, 2]) / (shape[late, 0] + shape[late, 2])
    else:
        s = np.asarray(D_xy, float)[late]
    if s.size < 10 or not np.all(np.isfinite(s)):
        return float("nan")
    ups = _up_crossings(t[late], s - s.mean(), rtol * max(float(np.abs(s).mean()), 1e-3))
    return float(ups[-1] - ups[-2]) if len(ups) >= 2 else float("nan")


def classify_orbit(t: np.ndarray, D_xy: np.ndarray, theta: np.ndarray, director: np.ndarray | None,
                   aspect_ratio: float = 1.0, *, shape: np.ndarray | None = None, **classifier_options) -> dict:
    """The motion in three dimensions, from the shape in the shear plane (classify_motion) and
    the body's symmetry axis (``director``: body_axis's, or for an old run file the material
    director); ``shape`` the equivalent ellipsoid's semi-axes (n, 3), optional.

    In this order (docs/method.md, "Motion classes"; the window is the last
    ``window_fraction`` of the run):

    1. unstable: a non-finite value (classify_motion);
    2. no axis (a sphere, r = 1): classify_motion's class (steady, swinging, tumbling,
       transient), nothing more;
    3. rolling: the axis within ROLLING_TOL of ±z over the window; settled when the shape is
       steady (is_steady);
    4. turning: the axis's azimuth (defined off z, AZIMUTH_FLOOR) advances by TURNING_ADVANCE
       or more over the last half of the run, or in the plane classify_motion says tumbling.
       In the plane (the axis within OFF_PLANE_TOL of it over the window): tumbling; off it:
       kayaking, or drifting_to_rolling / drifting_to_plane while the orbit constant changes by
       DRIFT_RTOL or more per orbit (orbit_summary's orbit_constant_change). Settled when the
       last SETTLED_ORBITS whole orbits agree: period and orbit constant within SETTLED_RTOL;
    5. not turning, in the plane: classify_motion's steady, swinging or transient;
    6. not turning, off the plane: off_plane_tank_treading when the shape (a, b, c) is steady
       and the axis still (its polar angle within theta_tol over the window; settled), or when
       it swings in regular cycles (settled when the last two agree); drifting_to_rolling or
       drifting_to_plane while the axis tilts by more than theta_tol over the window towards z
       or the plane; else transient.

    Returns classify_motion's fields (motion, window, period, means and amplitudes) with the
    motion replaced, ``settled`` (bool), ``motion_in_plane`` (classify_motion's own class) and
    ``turning`` (bool); for a turning body the window is its last whole orbit (the last two
    when settled) and ``period`` the orbit period."""
    opts = {k: v for k, v in classifier_options.items() if k in ("rtol", "theta_tol", "window_fraction", "min_window")}
    t, D_xy, theta = (np.asarray(a, float) for a in (t, D_xy, theta))
    out = classify_motion(t, D_xy, theta, **opts)
    out["motion_in_plane"] = out["motion"]
    out["turning"] = out["motion"] == "tumbling"
    out["orbits_averaged"] = 0.0
    t = np.asarray(t, float)
    if out["motion"] == "unstable" or t.size < 3 or director is None:
        return out
    d = np.asarray(director, float)
    if not np.all(np.isfinite(d)) or not abs(aspect_ratio - 1.0) >= SPHERE_TOL:
        return out
    nan = float("nan")
    rtol = opts.get("rtol", 1e-2)
    theta_tol = opts.get("theta_tol", 1e-2)
    t_last = max(float(t[0]), (1.0 - opts.get("window_fraction", 0.25)) * float(t[-1]))
    last = t >= t_last
    folded = _folded_polar(d)
    # the mean tilt over the window, not its largest: a disk swinging about the plane by ±11° at one
    # level and ±9° at the next is one motion, not two (issue 39's campaign, dextran at 50 1/s)
    in_plane = bool(window_stats(t, folded, t_last)[0] > np.pi / 2 - OFF_PLANE_TOL)
    # 3. rolling first: the body may have turned on its way there
    if folded[last].max() < ROLLING_TOL:
        out.update(motion="rolling", t_from=t_last, t_to=float(t[-1]), period=nan, turning=False,
                   settled=bool(is_steady(t, D_xy, theta, **opts)),
                   D_xy_mean=window_stats(t, D_xy, t_last)[0], D_xy_amplitude=nan, theta_amplitude=nan,
                   theta_mean=(window_stats(t[np.isfinite(theta)], np.asarray(theta)[np.isfinite(theta)], t_last)[0]
                               if np.isfinite(theta[last]).all() else nan))
        return out
    # 4. turning
    ok, phi = _azimuth(d)
    late = (t >= 0.5 * t[-1])[ok]
    advance = abs(float(phi[late][-1] - phi[late][0])) if np.count_nonzero(late) >= 2 else 0.0
    turning = advance >= TURNING_ADVANCE or (in_plane and out["motion_in_plane"] == "tumbling")
    out["turning"] = turning
    if turning:
        orbit = orbit_summary(t, d, aspect_ratio)
        passes = orbit["_passages"]
        change = orbit["orbit_constant_change"]
        if in_plane:
            motion = "tumbling"
        elif np.isfinite(change) and abs(change) >= DRIFT_RTOL:
            motion = "drifting_to_rolling" if change < 0 else "drifting_to_plane"
        else:
            motion = "kayaking"
        settled = (motion in ("tumbling", "kayaking") and orbit["orbit_periods"] >= SETTLED_ORBITS
                   and orbit["orbit_period_change"] < SETTLED_RTOL
                   and (in_plane or abs(change) < SETTLED_RTOL))
        out.update(motion=motion, settled=bool(settled))
        if len(passes) >= 3:
            n = 2 if settled and len(passes) >= 5 else 1
            out["t_from"], out["t_to"] = passes[-1 - 2 * n], passes[-1]
            out["orbits_averaged"] = float(n)
            out["period"] = orbit["orbit_period"]
            out["D_xy_mean"], out["D_xy_amplitude"] = _cycle_stats(t, np.asarray(D_xy, float), out["t_from"],
                                                                   (passes[-3], passes[-1]))
        elif out["motion_in_plane"] != "tumbling":
            out["period"] = nan  # the in-plane projection's period is not the orbit's
        out["theta_mean"] = out["theta_amplitude"] = nan
        return out
    # 5. not turning, in the plane: the shape in the plane says it all, once the axis has stopped
    # tilting (a disk started off the plane reaches it slowly while its in-plane shape already holds:
    # stop_when_settled stopped such runs as 'steady' before the membrane's swing had developed)
    if in_plane:
        if abs(float(folded[last][-1] - folded[last][0])) > theta_tol:
            out["settled"] = False
        return out
    # 6. not turning, off the plane
    out.update(t_from=t_last, t_to=float(t[-1]), period=nan, D_xy_mean=nan, D_xy_amplitude=nan,
               theta_mean=nan, theta_amplitude=nan, settled=False)
    tilt = float(folded[last][-1] - folded[last][0])
    w = _window(float(t[-1]), opts.get("window_fraction", 0.25), opts.get("min_window", 3.0))
    long_enough = float(t[-1] - t[0]) >= 2 * w
    if shape is not None and np.all(np.isfinite(shape[last])):
        s = shape[last]
        shape_steady = bool(np.all(np.ptp(s, axis=0) <= rtol * s.mean(axis=0)))
        tail = t >= t[-1] / 3.0
        d3 = (shape[tail, 0] - shape[tail, 2]) / (shape[tail, 0] + shape[tail, 2])
        swing = _oscillation(t[tail], d3, rtol * max(float(np.abs(d3).mean()), 1e-3)) if np.all(np.isfinite(d3)) else None
    else:
        shape_steady = bool(np.ptp(np.asarray(D_xy, float)[last]) <= rtol * max(float(np.abs(D_xy[last]).mean()), 1e-3))
        swing = None
    swing = swing or _oscillation(t[t >= t[-1] / 3.0], folded[t >= t[-1] / 3.0], theta_tol)
    if swing is not None:
        out.update(motion="off_plane_tank_treading", settled=_cycles_agree(swing), period=swing["period"],
                   t_from=swing["t_from"], t_to=swing["t_to"])
    elif abs(tilt) > theta_tol:
        out["motion"] = "drifting_to_rolling" if tilt < 0 else "drifting_to_plane"
    elif shape_steady and long_enough:
        out.update(motion="off_plane_tank_treading", settled=True)
    else:
        out["motion"] = "transient"
    return out


def orbit_settled(t, D_xy, theta, director, aspect_ratio: float = 1.0, **options) -> bool:
    """time.stop_when_settled: the classifier's own ``settled`` (classify_orbit): a steady
    state, swinging whose last two cycles agree, or an orbit whose last two whole orbits agree
    (period and orbit constant within SETTLED_RTOL); never a transition in progress."""
    return bool(classify_orbit(t, D_xy, theta, director, aspect_ratio, **options)["settled"])


def series_settled(history: dict, aspect_ratio: float = 1.0) -> bool:
    """orbit_settled of a run's history (StepObserver.history): the body's axis and shape as
    run_summary takes them, so that the stop rule and the summary agree."""
    t = np.asarray(history["t"], float)
    shape = _stack_shape(history)
    return orbit_settled(t, np.asarray(history["D_xy"], float), np.asarray(history["theta"], float),
                         body_axis(history, aspect_ratio), aspect_ratio, shape=shape)


def _stack_shape(series: dict) -> np.ndarray | None:
    if not all(f"ellipsoid_{c}" in series for c in "abc"):
        return None
    return np.stack([np.asarray(series[f"ellipsoid_{c}"], float) for c in "abc"], axis=1)


def relaxation_time(t: np.ndarray, D_xy: np.ndarray, t_from: float, floor: float = 1e-6) -> float:
    """kτ of a capsule relaxing at rest from D_xy(t) after ``t_from``: −1/slope of the
    least-squares line through ln D_xy (the slow mode of the first-order theory,
    docs/viscous_membrane.md, once the fast one has decayed); NaN with fewer than 3
    samples above ``floor`` or a D_xy that does not decay."""
    t, D = np.asarray(t, float), np.asarray(D_xy, float)
    sel = (t >= t_from) & (D > floor)
    if np.count_nonzero(sel) < 3:
        return float("nan")
    slope = np.polyfit(t[sel], np.log(D[sel]), 1)[0]
    return float(-1.0 / slope) if slope < 0 else float("nan")


def relaxation_summary(series: dict[str, np.ndarray], stop_time: float) -> dict:
    """The summary of a run whose flow stopped at ``stop_time`` (flow.history kind stop):
    the motion is 'relaxing' (a capsule at rest is neither steady in shear nor unstable; nor a
    settled motion in shear: settled 0), the relaxation time is fitted over the last two thirds
    of the rest."""
    t = np.asarray(series["t"], float)
    t_from = stop_time + (float(t[-1]) - stop_time) / 3.0
    return {"motion": "relaxing", "settled": 0.0, "relaxation_time": relaxation_time(t, series["D_xy"], t_from),
            "flow_stop_time": float(stop_time)}


def run_summary(series: dict[str, np.ndarray], **classifier_options) -> dict:
    """Summary of a run from its time series (t, D_xy, θ, ttf_ratio, tt_angle,
    Sxy_star, N1_star, N2_star; the director, the shape's axes and semi-axes when
    recorded): the motion (classify_orbit, on the body's symmetry axis: body_axis) and
    whether it has settled, and the time-mean and standard deviation over the
    averaging window of every quantity in :data:`SUMMARY_QUANTITIES`. ttf_ratio comes
    from the whole revolutions of the tracked nodes' angle since the window start (or
    the second half of the run, if earlier) when there is at least one, else from the
    mean rate; the body's and the membrane's rotations beside it (rotation_rates), the
    orbit's numbers (orbit_summary) and the shape's oscillation period."""
    t = np.asarray(series["t"], float)
    aspect_ratio = classifier_options.pop("aspect_ratio", 1.0)
    D_xy, theta = np.asarray(series["D_xy"], float), np.asarray(series["theta"], float)
    axis = body_axis(series, aspect_ratio)
    shape = _stack_shape(series)
    motion = classify_orbit(t, D_xy, theta, axis, aspect_ratio, shape=shape, **classifier_options)
    t0, t1 = motion["t_from"], motion["t_to"]
    out: dict = {"motion": motion["motion"], "settled": float(motion["settled"])}
    for name in SUMMARY_QUANTITIES:
        s = np.asarray(series[name], float)
        ts = t
        if name == "theta":  # over the rows where θ is defined (NaN: no long axis)
            s = unwrap_defined(s)
            ts, s = t[np.isfinite(s)], s[np.isfinite(s)]
        mean, std = window_stats(ts, s, t0, t1) if ts.size else (float("nan"), float("nan"))
        if name == "theta":
            mean = np.pi / 2 - (np.pi / 2 - mean) % np.pi  # back into (−π/2, π/2]
        out[name], out[f"{name}_std"] = mean, std
    if "tt_angle" in series and t.size >= 2:
        rate = revolution_rate(t, series["tt_angle"], min(t0, 0.5 * t[-1]))
        if rate is not None:
            out["ttf_ratio"] = float(rate / RIGID_SPHERE_ROTATION_RATE)
    if out["motion"] in TURNING_MOTIONS or motion.get("turning"):
        # the long axis turns through every angle: a mean θ over whole turns is no property of
        # the motion (the folded mean of a uniform turn is arbitrary, its spread the whole range)
        out["theta"] = out["theta_std"] = float("nan")
    for name in ("centroid_velocity_y", "slip_velocity_x", "dissipation_ratio", *CONDUIT_COLUMNS):  # issues 41, 42, 53
        s = np.asarray(series.get(name, ()), float)
        if s.size == t.size and np.isfinite(s).all() and t.size:
            out[name], out[f"{name}_std"] = window_stats(t, s, t0, t1)
    out["averaging_t_from"], out["averaging_t_to"] = t0, t1
    out.update(_drift_summary(series, t))
    for key in ("period", "D_xy_mean", "D_xy_amplitude", "theta_mean", "theta_amplitude"):
        out[key] = motion[key]
    out["orbits_averaged"] = motion.get("orbits_averaged", 0.0)
    out["shape_period"] = _shape_period(t, shape, D_xy, classifier_options.get("rtol", 1e-2)) if t.size else float("nan")
    tt = np.asarray(series["tt_angle"], float) if "tt_angle" in series else None
    out.update(rotation_rates(t, t0, t1, axis, theta, tt, D_xy, bool(motion.get("turning"))))
    if axis is not None or "director_x" in series:
        orbit = orbit_summary(t, axis if axis is not None else _stack(series, "director"), aspect_ratio)
        orbit.pop("_passages")
        out.update(orbit)
        if not motion.get("turning"):
            out["orbit_period"] = float("nan")  # passages of a swinging or still axis are no orbit
    return out


def _drift_summary(series: dict[str, np.ndarray], t: np.ndarray) -> dict:
    """The scene's own numbers of one capsule (issue 54): the wall's gap at the start, at the end and its
    smallest (a run with a wall or a conduit); the centroid's y at the start and the end and its
    migration across the flow, the difference (rows written before these columns were kept: none)."""
    out: dict = {}
    for name, keys in (("wall_gap", ("wall_gap_initial", "wall_gap_final", "wall_gap_min")),
                       ("centroid_y", ("centroid_y_initial", "centroid_y_final", None))):
        s = np.asarray(series.get(name, ()), float)
        if not (t.size and s.size == t.size and np.isfinite(s).all()):
            continue
        first, last, third = keys
        out[first], out[last] = float(s[0]), float(s[-1])
        if third:
            out[third] = float(s.min())
        else:
            out["migration_y"] = float(s[-1] - s[0])
    return out


def centroid_travel(first: dict | None, last: dict | None) -> float:
    """How far the centroid went from the first row to the last, in units of a (several
    capsules: the farthest); NaN without both rows."""
    if not first or not last or any(f"centroid_{c}" not in row for row in (first, last) for c in "xyz"):
        return float("nan")
    d = np.stack([np.asarray(last[f"centroid_{c}"], float) - np.asarray(first[f"centroid_{c}"], float)
                  for c in "xyz"], axis=-1)
    return float(np.max(np.linalg.norm(np.atleast_2d(d), axis=-1)))


def scene_summary(observer) -> dict:
    """The summary of a run of several capsules: each capsule's run_summary (its own series and
    aspect ratio) in the nested ``capsule`` group, one value per capsule; beside it the scene's
    value of each number, the mean over the capsules (the suspension's particle stress is the
    mean stresslet), the motion common to every capsule (else "mixed"), and for a pair the
    relative trajectory's numbers: cross-stream separation at the start, its peak and its end,
    the streamwise separation at the end, and the closest approach."""
    parts = [run_summary(observer.capsule_series(i), aspect_ratio=part.aspect_ratio)
             for i, part in enumerate(observer.parts)]
    motions = [p["motion"] for p in parts]
    out: dict = {"motion": motions[0] if len(set(motions)) == 1 else "mixed"}
    per: dict = {"motion": np.array(motions, dtype=object)}
    for key in parts[0]:
        if key == "motion":
            continue
        values = np.array([float(p.get(key, np.nan)) for p in parts])
        per[key] = values
        out[key] = float(np.mean(values))
    out["capsule"] = per
    history = observer.history
    gap = np.asarray(history.get("min_capsule_gap", ()), float)
    if gap.size:
        out["min_capsule_gap"] = float(np.min(gap))
    sep = {c: np.asarray(history.get(f"separation_{c}", ()), float) for c in "xyz"}
    if sep["y"].size and np.isfinite(sep["y"]).all():
        out["separation_y_initial"] = float(sep["y"][0])
        out["separation_y_final"] = float(sep["y"][-1])
        out["separation_y_peak"] = float(sep["y"][np.argmax(np.abs(sep["y"]))])
        out["separation_x_final"] = float(sep["x"][-1])
    return out


# ---------------------------------------------------------------- the per-step row

COMPRESSION_TOL = 1e-10  # in E_s: below round-off of the tension at the rest shape

#: a capsule in a conduit (capsim.scene.conduit, issue 53): its speed along the conduit (units of the
#: mean velocity U), the pressure drop it adds, its migration and its lengths along and across
CONDUIT_COLUMNS = ("centroid_velocity_x", "extra_pressure_drop", "axis_offset", "length_along", "width_across")
#: time-series columns that the summary and the stopping rules read back
HISTORY_COLUMNS = ("t", "dt", "tt_angle", *SUMMARY_QUANTITIES, "director_x", "director_y", "director_z",
                   # the shape's orientation and semi-axes (issue 39): the body's axis, its shape period
                   "long_axis_x", "long_axis_y", "long_axis_z", "short_axis_x", "short_axis_y", "short_axis_z",
                   "ellipsoid_a", "ellipsoid_b", "ellipsoid_c",
                   # the body's drift across and along the flow (issues 41, 42): lift or migration, slip
                   "centroid_velocity_y", "slip_velocity_x", "dissipation_ratio", *CONDUIT_COLUMNS,
                   # a wall's gap and the migration across the flow, from start to end (issue 54)
                   "wall_gap", "centroid_y",
                   # the membrane's area: the record's largest change (skalak_c auto's promise, issue 55)
                   "area")
#: several capsules: the scene's columns the summary reads back (a pair's relative trajectory)
SCENE_HISTORY_COLUMNS = ("min_capsule_gap", "separation_x", "separation_y", "separation_z")


#: time.stop_when_settled waits this many slow relaxation times of the capsule before it may stop:
#: a red cell in a viscous medium (dextran, 200 1/s: G 2.24, λ 0.2, kτ ≈ 16) held its shape and
#: tilt over 3/k at kt 12 and was stopped as a settled 'steady', then swung from kt ~20 on
SETTLE_RELAXATION_TIMES = 3.0


def slow_relaxation_time(model) -> float:
    """kτ of the slow shape mode of the first-order theory (capsim.scene.small_deformation) for the
    model's G, λ, K_s/G_s (the law's small-strain moduli) and membrane shear viscosity; 0 where
    the theory has no elastic membrane (a drop)."""
    from capsim.scene.small_deformation import LinearCapsule

    try:
        law, params = model.law, model.law_params
        shear = float(law.shear_modulus(**params))
        if not shear > 0.0:
            return 0.0
        viscous = getattr(model, "viscous", None)
        bq = float(getattr(viscous, "shear", 0.0) or 0.0) if viscous is not None else 0.0
        cap = LinearCapsule(Ca=float(model.shear_rate_G) / shear, viscosity_ratio=float(model.viscosity_ratio),
                            area_over_shear=float(law.area_modulus(**params)) / shear, Bq_shear=bq)
        tau = cap.relaxation_times()[0]
        return float(tau) if np.isfinite(tau) and tau > 0 else 0.0
    except Exception:  # noqa: BLE001 - a law or model the theory does not cover: no wait
        return 0.0


class StepObserver:
    """Turns an accepted state into the row of the time series.

    Owns the tank-treading tracker and the history of the columns in
    :data:`HISTORY_COLUMNS` (for the run summary and the stopping rules); its
    ``state()`` / ``restore()`` carry the tracker across a checkpoint, and
    ``resume(rows)`` rebuilds the history from the rows already on disk.
    """

    def __init__(self, model, rest_positions: np.ndarray, axis=(0.0, 1.0, 0.0), axes=None) -> None:
        self.model = model
        #: several capsules (capsim.scene.bodies): each its own row of every per-capsule column (CAPSULE_COLUMNS)
        self.bodies = model.scene.layout if model.scene.several else None
        if self.bodies is None:
            self.tracker = TankTreadingTracker(rest_positions)
            rest_geometry = model.disc.geometry(rest_positions)
            self.director = MaterialDirector(rest_geometry, axis)
            #: r of Jeffery's orbit (orbit constant, period) for the run summary
            self.aspect_ratio = rest_aspect_ratio(rest_geometry, axis)
        else:
            axes = [axis] * self.bodies.count if axes is None else list(axes)
            rest_geometry = model.disc.geometry(rest_positions)
            self.parts = [_CapsulePart(model, self.bodies, i, rest_positions, rest_geometry, axes[i])
                          for i in range(self.bodies.count)]
            self.aspect_ratio = self.parts[0].aspect_ratio
        #: the kt before which time.stop_when_settled does not stop: SETTLE_RELAXATION_TIMES of the
        #: capsule's slow first-order relaxation time (its G, λ, K_s/G_s and membrane viscosity)
        self.settle_after = SETTLE_RELAXATION_TIMES * slow_relaxation_time(model)
        #: the columns kept in memory (one capsule's, and a scene's own where it has several)
        self.history_columns = HISTORY_COLUMNS + (SCENE_HISTORY_COLUMNS if self.bodies is not None else ())
        self.history: dict[str, list[float]] = {key: [] for key in self.history_columns}
        self.first: dict | None = None
        self.last: dict | None = None
        #: the columns of the run file being continued, when it was written before some of
        #: today's (an extension of an old run keeps the file's columns; None: all of them)
        self.columns: frozenset[str] | None = None

    def observe(self, t: float, y: np.ndarray, u: np.ndarray, state, dt: float, error: float,
                work: dict[str, float]) -> dict:
        """The row at an accepted state: ``state`` is the membrane state at y,
        ``work`` the cumulative cost counters and the stages of the step. With several
        capsules every per-capsule column holds one value per capsule (an array)."""
        if self.bodies is not None:
            return self._observe_scene(t, y, u, state, dt, error, work)
        model = self.model
        row = {"t": t, "dt": dt, "error_estimate": error}
        strain, counts = state.row_strain
        row.update(capsule_row(model, y, u, state.geometry, state.density, state.weights, strain,
                               model.disc.elements, self.director, vertex_counts=counts))
        self._continue_lines(row)
        if model.viscous is not None:
            center = np.array([row["centroid_x"], row["centroid_y"], row["centroid_z"]])
            S_v, viscous_row = self._viscous(y, u, state, center, row["volume"])
            S_star = row.pop("_S_star") + S_v
            row.update(viscous_row)
            row.update(stresslet_observables(S_star))
            row["dissipation_ratio"] = dissipation_ratio(S_star, model.rate_of_strain(center))
        row.pop("_S_star", None)
        center = np.array([row["centroid_x"], row["centroid_y"], row["centroid_z"]])
        row.update(self.tracker.update(y, u, center))
        self._end_clearance(row, y)
        return self._close_row(row, work)

    def _end_clearance(self, row: dict, y: np.ndarray) -> None:
        """The private ``_end_clearance`` (never a column): how far the membranes are from the end of
        a conduit's meshed stretch (capsim.runs.stopping ends the run there)."""
        clearance, follows = self.model.scene.end_clearance(y)
        if np.isfinite(clearance):
            row["_end_clearance"] = clearance
            row["_end_follows"] = follows

    def _close_row(self, row: dict, work: dict[str, float]) -> dict:
        """The solve's and the cost's columns, the file's own columns only (an old run extended),
        remembered as the last row."""
        info = self.model.last_solve_info
        row["solver_iterations"] = float(info.get("iterations", 0))
        row["solver_residual"] = float(info.get("residual", 0.0))
        row.update({key: float(value) for key, value in work.items()})
        if self.columns is not None:
            row = {key: value for key, value in row.items() if key in self.columns or key.startswith("_")}
        self._remember(row)
        return row

    def _observe_scene(self, t: float, y: np.ndarray, u: np.ndarray, state, dt: float, error: float,
                       work: dict[str, float]) -> dict:
        """The row of a scene of several capsules: each capsule's row (as one capsule's), stacked
        into one array per column, and the scene's own columns: the smallest gap, a pair's separation,
        the suspension's mean stresslet (capsim.quantities)."""
        model, bodies = self.model, self.bodies
        strain = state.strain
        # a viscous membrane: its traction joins each capsule's stresslet (as one capsule's: _viscous)
        traction = model.viscous.traction(y, state.geometry, u) if model.viscous is not None else None
        rows = []
        for part in self.parts:
            rows.append(part.row(y, u, state, strain, self.last, traction))
        row: dict = {"t": t, "dt": dt, "error_estimate": error}
        for key in rows[0]:
            if key != "_S_star":
                row[key] = np.array([r[key] for r in rows])
        S_mean = np.mean([r["_S_star"] for r in rows], axis=0)
        for key, value in stresslet_observables(S_mean).items():
            row[f"suspension_{key}"] = value
        row["min_capsule_gap"] = smallest_gap(y, bodies)
        if bodies.count == 2:  # the pair's relative trajectory: capsule 1's centroid less capsule 0's
            for c in "xyz":
                row[f"separation_{c}"] = float(row[f"centroid_{c}"][1] - row[f"centroid_{c}"][0])
        self._end_clearance(row, y)
        return self._close_row(row, work)

    def capsule_series(self, i: int) -> dict[str, np.ndarray]:
        """The history as one capsule's (every per-capsule column at capsule i), for the summary."""
        out = {}
        for key, values in self.history.items():
            a = np.asarray(values, dtype=float)
            out[key] = a[:, i] if a.ndim == 2 else a
        return out

    def _continue_lines(self, row: dict) -> None:
        """The shape's axes are lines: each row keeps the sign that points it along the row
        before (the first row's: its first component that is not ~0 positive), so that a
        series of long_axis or short_axis is continuous (issue 39: a stateless convention
        flipped the sign whenever the leading component crossed zero, a short axis near y at
        every step of a swinging disk)."""
        if self.last is None:
            return
        for name in ("long_axis", "short_axis"):
            keys = [f"{name}_{c}" for c in "xyz"]
            if not all(k in self.last for k in keys):
                continue
            if sum(row[k] * self.last[k] for k in keys) < 0.0:
                for k in keys:
                    row[k] = -row[k]

    def _viscous(self, y: np.ndarray, u: np.ndarray, state, center: np.ndarray, volume: float) -> tuple:
        """A viscous membrane's traction joins the elastic one in the stresslet (Batchelor's
        surface formula holds for any interfacial force; docs/viscous_membrane.md, eq. V12):
        its share of S* (the stresslet is linear in the traction: Δf_v/G's at G = 1, λ = 1 is
        what it adds to the elastic one's at G), its dissipation rate uᵀK u (μk²a³) and that over the power the
        flow spends on the particle, S:E (the elastic energy is stored, not dissipated: in a
        steady state the rest of S:E is the fluids')."""
        model = self.model
        elements = model.disc.elements
        traction = model.viscous.traction(y, state.geometry, u)  # Δf_v/G, units μk
        S_v = particle_stresslet(state.geometry, np.ascontiguousarray(traction[elements]), u, elements,
                                 model.disc.reg_phi, center, volume, 1.0, 1.0)
        dissipation = model.viscous.dissipation(y, u)  # K of the solve at these positions
        return S_v, {"Sxy_viscous_star": float(S_v[0, 1]), "viscous_dissipation": dissipation}

    def _remember(self, row: dict) -> None:
        if self.first is None:
            self.first = row
        self.last = row
        for key in self.history_columns:
            self.history[key].append(row.get(key, float("nan")))

    def resume(self, rows: dict[str, np.ndarray]) -> None:
        """Continue after the rows already written (a resumed run). A file written before a
        column existed keeps its columns (the new ones are left out of its rows) and the
        history holds NaN for them (the summary then falls back: body_axis). With several
        capsules a per-capsule column is (steps, capsules)."""
        n = len(rows["t"])
        self.columns = frozenset(rows) if rows else None

        def values(a):
            a = np.asarray(a, dtype=float)
            return [float(v) for v in a] if a.ndim == 1 else [np.array(v) for v in a]

        def at(a, k):
            a = np.asarray(a, dtype=float)
            return float(a[k]) if a.ndim == 1 else np.array(a[k])

        blank = float("nan") if self.bodies is None else np.full(self.bodies.count, np.nan)
        self.history = {key: values(rows[key]) if key in rows else [blank] * n for key in self.history_columns}
        self.first = {key: at(v, 0) for key, v in rows.items()}
        self.last = {key: at(v, -1) for key, v in rows.items()}

    def state(self) -> dict[str, np.ndarray]:
        if self.bodies is not None:
            return {f"capsule{i}.tracker.{k}": v for i, part in enumerate(self.parts)
                    for k, v in part.tracker.state().items()}
        return {f"tracker.{k}": v for k, v in self.tracker.state().items()}

    def restore(self, state: dict[str, np.ndarray]) -> None:
        if self.bodies is not None:
            for i, part in enumerate(self.parts):
                prefix = f"capsule{i}.tracker."
                part.tracker.restore({k.removeprefix(prefix): v for k, v in state.items() if k.startswith(prefix)})
            return
        self.tracker.restore({k.removeprefix("tracker."): v for k, v in state.items() if k.startswith("tracker.")})


def boundary_quantities(model, nodes: np.ndarray, geometry, density: np.ndarray, weights: np.ndarray,
                        u: np.ndarray, elements: np.ndarray, center: np.ndarray, lam: float) -> dict:
    """The scene's boundaries' own columns of one capsule (capsim.scene.Boundary.quantities: a
    conduit's additional pressure drop), from the capsule's load and velocity at its rule points
    (interpolated only where a boundary reports any: the plane wall does not)."""
    reporting = [b for b in model.scene.boundaries if b.reports_quantities]
    if not reporting:
        return {}
    phi = model.disc.reg_phi
    df = interpolate(phi, density) if density.ndim == 3 else np.broadcast_to(density[:, None, :], geometry.points.shape)
    w = geometry.weights if weights is None else weights
    load_w = (df * w[..., None]).reshape(-1, 3)
    u_points = interpolate(phi, u[elements]).reshape(-1, 3)
    normals_w = (geometry.normals * geometry.weights[..., None]).reshape(-1, 3)
    points = geometry.points.reshape(-1, 3)
    row: dict = {}
    for boundary in reporting:
        row.update(boundary.quantities(nodes, points, load_w, u_points, normals_w, center, model.shear_rate_G, lam))
    return row


def capsule_row(model, y: np.ndarray, u: np.ndarray, geometry, density: np.ndarray, weights: np.ndarray,
                strain, elements: np.ndarray, director: MaterialDirector, material: dict | None = None,
                vertex_counts: np.ndarray | None = None) -> dict:
    """One capsule's columns at an accepted state (its nodes y, u, its elements' geometry,
    density and weights, its vertex strain, its own connectivity): shape, orientation, membrane
    state, centroid motion, stresslet (and, as "_S_star", the stresslet tensor itself).
    ``material``: the capsule's own law parameters, modulus ratio and λ (several capsules of
    their own membranes; None: the model's). ``vertex_counts``: how many of the membrane's vertices
    each strained vertex stands for (one vertex of each orbit of a symmetric state; None: itself)."""
    law_params = model.law_params if material is None else material["law_params"]
    modulus = 1.0 if material is None else material["modulus_ratio"]
    lam = model.viscosity_ratio if material is None else material["viscosity_ratio"]
    # the largest stretch, and the compressive tensions (where a membrane without bending stiffness
    # would wrinkle), in one pass
    smax, lowest, compressed = row_tension_summary(strain, model.law, law_params, modulus, -COMPRESSION_TOL,
                                                   vertex_counts)
    row = step_observables(y, elements, geometry, smax)
    center = np.array([row["centroid_x"], row["centroid_y"], row["centroid_z"]])
    # the director's, the centroid velocity's and the stresslet's surface integrals in one pass (issue 57:
    # each was its own numpy pass, ~0.1 ms of a level-2 row), the contour method's element-constant Δf too
    sums = row_surface_sums(geometry, density, weights, u, elements, model.disc.reg_phi, center, director)
    values = sums.values.tolist()  # Python floats from here (a numpy call between evaluations costs ~10 µs)
    d = values[24:27]
    norm = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    row.update(director_observables([v / norm for v in d]))
    row["min_tension"] = lowest / model.shear_rate_G
    row["compressed_fraction"] = compressed
    volume = row["volume"]
    row.update({f"centroid_velocity_{c}": values[i] + values[3 + i] / volume for i, c in enumerate("xyz")})
    u_far = model.undisturbed(center[None])[0]  # the undisturbed flow at the centre, now
    for i, c in enumerate("xyz"):
        row[f"slip_velocity_{c}"] = row[f"centroid_velocity_{c}"] - float(u_far[i])
    gap = model.scene.boundary_gap(y)  # the scene's boundaries (a wall): the guard min_wall_gap reads it
    if gap is not None:
        row["wall_gap"] = gap
    row.update(boundary_quantities(model, y, geometry, density, weights, u, elements, center, lam))
    S_star = sums.stresslet_of(values, row["volume"], model.shear_rate_G, lam)
    row["_S_star"] = S_star
    row.update(stresslet_observables(S_star))
    row["dissipation_ratio"] = dissipation_ratio(S_star, model.rate_of_strain(center))
    return row


class _CapsulePart:
    """One capsule of a scene of several, as the observer sees it: its nodes, vertices and
    elements in the scene's arrays, its own connectivity, its tank-treading tracker and
    material director."""

    def __init__(self, model, bodies, i: int, rest_positions: np.ndarray, rest_geometry, axis) -> None:
        self.index = i
        material = getattr(model.membrane, "material", None)  # the capsules' own membranes and λ
        self.material = None if material is None else {
            "law_params": material["law_params"][i], "modulus_ratio": material["modulus_ratios"][i],
            "viscosity_ratio": material["viscosity_ratios"][i]}
        self.nodes, self.vertices, self.elements = bodies.nodes(i), bodies.vertices(i), bodies.elements(i)
        own = np.empty(bodies.count * bodies.nodes_per_body, dtype=np.int64)
        own[self.nodes] = np.arange(bodies.nodes_per_body)
        self.own_elements = np.ascontiguousarray(own[model.disc.elements[self.elements]])
        self.model = model
        rest = np.ascontiguousarray(rest_positions[self.nodes])
        self.tracker = TankTreadingTracker(rest)
        rest_geometry = self._geometry(rest_geometry)  # the scene's, this capsule's elements
        self.director = MaterialDirector(rest_geometry, axis)
        self.aspect_ratio = rest_aspect_ratio(rest_geometry, axis)

    def _geometry(self, geo):
        e = self.elements
        return type(geo)(geo.points[e], geo.normals[e], geo.weights[e])

    def row(self, y: np.ndarray, u: np.ndarray, state, strain, last: dict | None,
            viscous_traction: np.ndarray | None = None) -> dict:
        from capsim.numerics.membrane import VertexStrain

        v = self.vertices
        mine = VertexStrain(strain.A[v], strain.B[v], strain.normals[v], strain.inv1[v], strain.inv2[v])
        yi, ui = np.ascontiguousarray(y[self.nodes]), np.ascontiguousarray(u[self.nodes])
        e = self.elements
        model = self.model
        geometry = self._geometry(state.geometry)
        row = capsule_row(model, yi, ui, geometry, np.ascontiguousarray(state.density[e]),
                          np.ascontiguousarray(state.weights[e]), mine, self.own_elements, self.director,
                          self.material)
        if viscous_traction is not None:  # the membrane's viscous share of the stresslet and its dissipation
            center = np.array([row["centroid_x"], row["centroid_y"], row["centroid_z"]])
            own = np.ascontiguousarray(viscous_traction[self.nodes][self.own_elements])
            S_v = particle_stresslet(geometry, own, ui, self.own_elements, model.disc.reg_phi, center, row["volume"],
                                     1.0, 1.0)
            S_star = row["_S_star"] + S_v
            row["_S_star"] = S_star
            row.update(stresslet_observables(S_star))
            row["dissipation_ratio"] = dissipation_ratio(S_star, model.rate_of_strain(center))
            alone = np.zeros_like(u)  # K is block-diagonal: this capsule's uᵀK u
            alone[self.nodes] = u[self.nodes]
            row["Sxy_viscous_star"] = float(S_v[0, 1])
            row["viscous_dissipation"] = model.viscous.dissipation(y, alone)
        if last is not None:  # continuous axes, as one capsule's (StepObserver._continue_lines)
            index = self.index
            for name in ("long_axis", "short_axis"):
                keys = [f"{name}_{c}" for c in "xyz"]
                if all(k in last for k in keys) and sum(row[k] * last[k][index] for k in keys) < 0.0:
                    for k in keys:
                        row[k] = -row[k]
        center = np.array([row["centroid_x"], row["centroid_y"], row["centroid_z"]])
        row.update(self.tracker.update(yi, ui, center))
        return row
