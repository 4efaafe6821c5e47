"""Observables of a capsule configuration, cheap enough for every step.

Deformation and inclination follow the seed (3.9)–(3.10): the second moment
M = ∫_V y y dV about the centroid is matched by the ellipsoid of the same volume
and inertia, whose semi-axes are l_k = (5 μ_k / V)^½ (μ_k the eigenvalues of M).
Of the three principal axes, the one most nearly along z (vorticity) is set
aside; the other two span the shear plane and give L ≥ l and
D_xy = (L − l)/(L + l); θ ∈ (−π/2, π/2] is the angle of the long axis to x.
"""

from __future__ import annotations

import numpy as np

from capsim.geometry import ElementGeometry, centroid, second_moment, vertex_triangle_quality, volume_area


def ellipsoid_axes(geo: ElementGeometry) -> dict:
    volume, area = volume_area(geo)
    center = centroid(geo, volume)
    M = second_moment(geo, center)
    mu, vec = np.linalg.eigh(M)
    axes = np.sqrt(np.maximum(5.0 * mu / volume, 0.0))
    out_of_plane = int(np.argmax(np.abs(vec[2, :])))
    in_plane = [k for k in range(3) if k != out_of_plane]
    i_long = max(in_plane, key=lambda k: axes[k])
    i_short = min(in_plane, key=lambda k: axes[k])
    L, l = axes[i_long], axes[i_short]
    v = vec[:, i_long]
    theta = float(np.arctan2(v[1], v[0]))
    if theta > np.pi / 2:
        theta -= np.pi
    elif theta <= -np.pi / 2:
        theta += np.pi
    return {
        "volume": volume,
        "area": area,
        "centroid": center,
        "L": float(L),
        "l": float(l),
        "W": float(axes[out_of_plane]),
        "D_xy": float((L - l) / (L + l)),
        "theta": theta,
    }


def step_observables(x: np.ndarray, elements: np.ndarray, geo: ElementGeometry, max_stretch: float) -> dict:
    """The per-step time series row (everything but t and dt)."""
    e = ellipsoid_axes(geo)
    c = e["centroid"]
    return {
        "D_xy": e["D_xy"],
        "theta": e["theta"],
        "volume": e["volume"],
        "area": e["area"],
        "centroid_x": float(c[0]),
        "centroid_y": float(c[1]),
        "centroid_z": float(c[2]),
        "axis_L": e["L"],
        "axis_l": e["l"],
        "axis_W": e["W"],
        "min_element_quality": float(vertex_triangle_quality(x, elements).min()),
        "max_principal_stretch": float(max_stretch),
    }
