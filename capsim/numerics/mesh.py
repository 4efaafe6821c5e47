"""Surface meshes of 6-node quadratic triangles (seed §3, figure 2a).

A regular octahedron (8 faces) or icosahedron (20 faces) is subdivided ``level``
times into 4 triangles each; new points are projected radially onto the unit
sphere. Every final triangle becomes a 6-node element whose mid-edge nodes are
the projected edge midpoints, so N_e = 4^level · N_e0 and N_p = 2 N_e + 2.

Node ordering: the N_v vertex nodes come first (0 … N_v−1), then the mid-edge
nodes. Element connectivity rows are (v0, v1, v2, m01, m12, m20), counter-clockwise
seen from outside, so that ∂x/∂ξ × ∂x/∂η points out of the capsule.

Rest shapes are maps of the unit sphere (the seed maps its sphere grid to
spheroids and the biconcave disk so that high-curvature rims keep fine elements);
each is registered in ``REST_SHAPES`` and scaled so that the equal-volume sphere
has radius 1 (the length scale a of G = μka/E_s).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Callable

import numpy as np


@dataclass(frozen=True)
class SurfaceMesh:
    """Node positions (N_p, 3) and 6-node connectivity (N_e, 6)."""

    positions: np.ndarray
    elements: np.ndarray
    n_vertices: int

    @property
    def n_nodes(self) -> int:
        return self.positions.shape[0]

    @property
    def n_elements(self) -> int:
        return self.elements.shape[0]


def _octahedron() -> tuple[np.ndarray, np.ndarray]:
    v = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    f = np.array(
        [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]]
    )
    return v, f


def _icosahedron() -> tuple[np.ndarray, np.ndarray]:
    p = (1.0 + np.sqrt(5.0)) / 2.0
    v = np.array(
        [
            [-1, p, 0], [1, p, 0], [-1, -p, 0], [1, -p, 0],
            [0, -1, p], [0, 1, p], [0, -1, -p], [0, 1, -p],
            [p, 0, -1], [p, 0, 1], [-p, 0, -1], [-p, 0, 1],
        ],
        float,
    )
    v /= np.linalg.norm(v, axis=1)[:, None]
    f = np.array(
        [
            [0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11],
            [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8],
            [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
            [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1],
        ]
    )
    return v, f


BASE_POLYHEDRA: dict[str, Callable[[], tuple[np.ndarray, np.ndarray]]] = {
    "octahedron": _octahedron,
    "icosahedron": _icosahedron,
}


def _orient_outward(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    outward = np.einsum("ij,ij->i", np.cross(b - a, c - a), a + b + c) > 0
    faces = faces.copy()
    faces[~outward] = faces[~outward][:, [0, 2, 1]]
    return faces


def _midpoint_index(cache: dict, points: list, i: int, j: int) -> int:
    key = (i, j) if i < j else (j, i)
    k = cache.get(key)
    if k is None:
        m = 0.5 * (points[i] + points[j])
        points.append(m / np.linalg.norm(m))
        k = len(points) - 1
        cache[key] = k
    return k


def unit_sphere_mesh(base: str = "octahedron", level: int = 3) -> SurfaceMesh:
    """Subdivided octahedron or icosahedron projected on the unit sphere (made once per process for
    each base and level: a campaign's runs share it, issue 57; each caller gets its own arrays)."""
    if base not in BASE_POLYHEDRA:
        raise ValueError(f"unknown base polyhedron {base!r} (allowed: {sorted(BASE_POLYHEDRA)})")
    mesh = _unit_sphere_mesh(base, int(level))
    return SurfaceMesh(mesh.positions.copy(), mesh.elements.copy(), mesh.n_vertices)


@functools.lru_cache(maxsize=8)
def _unit_sphere_mesh(base: str, level: int) -> SurfaceMesh:
    vertices, faces = BASE_POLYHEDRA[base]()
    faces = _orient_outward(vertices, faces)
    points = [p for p in vertices]
    for _ in range(level):
        cache: dict = {}
        new_faces = []
        for a, b, c in faces:
            ab = _midpoint_index(cache, points, a, b)
            bc = _midpoint_index(cache, points, b, c)
            ca = _midpoint_index(cache, points, c, a)
            new_faces += [(a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca)]
        faces = np.array(new_faces)
    n_vertices = len(points)
    cache = {}
    elements = np.empty((len(faces), 6), dtype=np.int64)
    for e, (a, b, c) in enumerate(faces):
        elements[e] = (
            a, b, c,
            _midpoint_index(cache, points, a, b),
            _midpoint_index(cache, points, b, c),
            _midpoint_index(cache, points, c, a),
        )
    return SurfaceMesh(np.array(points), elements, n_vertices)


def node_element_incidence(elements: np.ndarray, n_nodes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """CSR list of (element, local node index) pairs holding each node.

    Returns (offsets (N_p+1,), element ids, local indices 0-5).
    """
    nodes = elements.ravel()
    order = np.argsort(nodes, kind="stable")
    counts = np.bincount(nodes, minlength=n_nodes)
    offsets = np.concatenate([[0], np.cumsum(counts)])
    elem_ids = (order // 6).astype(np.int64)
    local = (order % 6).astype(np.int64)
    return offsets.astype(np.int64), elem_ids, local


# ---------------------------------------------------------------- rest shapes

def _sphere(p: np.ndarray, **_: float) -> np.ndarray:
    return p.copy()


def _spheroid(p: np.ndarray, aspect_ratio: float = 1.0, **_: float) -> np.ndarray:
    # Symmetry axis along y, the shear-gradient direction, as for the biconcave
    # disk (3.2): the seed's printed map scales z, which would put the axis on the
    # vorticity axis, where no inclination θ0 (seed §5, fig. 14) could be set.
    q = p.copy()
    q[:, 1] *= aspect_ratio
    return q


def _biconcave(p: np.ndarray, c0: float = 0.207, c2: float = 2.003, c4: float = -1.123, **_: float) -> np.ndarray:
    # seed (3.2): the disk's axis is y (the shear-gradient direction), r² = x² + z²
    r2 = p[:, 0] ** 2 + p[:, 2] ** 2
    q = p.copy()
    # on the unit sphere y = ±(1 − r²)^½, so this is (3.2) with the sign kept;
    # the polynomial is the full thickness, hence the factor ½. Evans & Fung's
    # shape is z = ±½[1 − (r/R0)²]^½ [C0 + C2 (r/R0)² + C4 (r/R0)⁴] (the seed's
    # printed 3.1 drops the square on r/R0 and the ½); with the default
    # coefficients the discretised disk has sphericity 0.746 (seed §5: 0.75).
    q[:, 1] = 0.5 * p[:, 1] * (c0 + c2 * r2 + c4 * r2**2)
    return q


REST_SHAPES: dict[str, Callable[..., np.ndarray]] = {
    "sphere": _sphere,
    "oblate": _spheroid,
    "prolate": _spheroid,
    "biconcave": _biconcave,
}


def rotation_about_z(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_onto(axis) -> np.ndarray:
    """The smallest rotation R with R ŷ = axis (unit): about z when the axis lies in the
    shear plane (then R = rotation_about_z(t) for axis (−sin t, cos t, 0), as a tilt),
    else about ŷ × axis (Rodrigues' formula)."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    if a[2] == 0.0:
        return rotation_about_z(np.arctan2(-a[0], a[1]))
    k = np.array([a[2], 0.0, -a[0]])  # ŷ × a
    s, c = np.linalg.norm(k), a[1]
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + K + K @ K * ((1.0 - c) / s**2)


def rest_shape_mesh(
    kind: str = "sphere",
    base: str = "octahedron",
    level: int = 3,
    tilt_deg: float = 0.0,
    axis=None,
    **shape_params: float,
) -> SurfaceMesh:
    """Rest shape mapped from the unit-sphere mesh, with equal-volume radius 1.

    The volume is measured on the discretised (quadratic) surface so that the
    discrete equal-volume radius is 1 to round-off; ``tilt_deg`` then rotates the
    shape about z, the vorticity axis, or ``axis`` (a direction; not with a tilt)
    turns its symmetry axis, y, onto that direction by :func:`rotation_onto`.
    """
    from capsim.numerics.geometry import element_geometry, volume_area

    if kind not in REST_SHAPES:
        raise ValueError(f"unknown rest shape {kind!r} (allowed: {sorted(REST_SHAPES)})")
    sphere = unit_sphere_mesh(base, level)
    x = REST_SHAPES[kind](sphere.positions, **shape_params)
    geo = element_geometry(x, sphere.elements, 6)
    volume, _ = volume_area(geo)
    x *= (4.0 * np.pi / 3.0 / volume) ** (1.0 / 3.0)
    if axis is not None:
        if tilt_deg != 0.0:
            raise ValueError("give tilt_deg or axis, not both")
        x = x @ rotation_onto(axis).T
    else:
        x = x @ rotation_about_z(np.deg2rad(tilt_deg)).T
    return SurfaceMesh(x, sphere.elements, sphere.n_vertices)


def rest_shape_attributes(mesh: SurfaceMesh) -> dict:
    """Volume V, area S, equal-volume radius and sphericity of a discretised shape.

    The sphericity is the area of the equal-volume sphere over the area of the
    shape, s = (36πV²)^{1/3}/S ≤ 1: the seed (§5) defines it in words this way
    and quotes s < 1, though its printed formula is the reciprocal.
    """
    from capsim.numerics.geometry import element_geometry, volume_area

    volume, area = volume_area(element_geometry(mesh.positions, mesh.elements, 6))
    return {
        "volume": volume,
        "area": area,
        "equal_volume_radius": (3.0 * volume / (4.0 * np.pi)) ** (1.0 / 3.0),
        "sphericity": (36.0 * np.pi * volume**2) ** (1.0 / 3.0) / area,
    }


def linear_subtriangles(elements: np.ndarray) -> np.ndarray:
    """Each 6-node triangle as its four straight sub-triangles, oriented as the element."""
    e = np.asarray(elements)
    v0, v1, v2, m01, m12, m20 = (e[:, i] for i in range(6))
    return np.concatenate([
        np.stack([v0, m01, m20], 1), np.stack([m01, v1, m12], 1),
        np.stack([m20, m12, v2], 1), np.stack([m01, m12, m20], 1),
    ])


# ---------------------------------------------------------------- stress-free shapes (issue 55)
#
# A membrane's stress-free shape (membrane.reference_shape) is a second map of the same unit-sphere
# mesh: node k of the stress-free surface and node k of the initial (rest) surface are the images
# of one point of the sphere, so the membrane's strain at t = 0 is the map from one to the other.
# The maps of REST_SHAPES change only the coordinate along the symmetry axis, as a function of
# the distance from it, so the two surfaces' material points lie on one line parallel to the axis
# (the parametrisation of Peng, Mashayekh & Zhu 2014 and Cordasco, Yazdani & Bagchi 2014, who map
# a spheroidal stress-free state onto the biconcave cell). The stress-free surface is scaled to
# the initial surface's area: a red cell's membrane keeps its area (its area modulus is 10^4 of
# the shear modulus), so the stress-free state differs from the cell by its volume.

#: the reduced volumes the biconcave stress-free family reaches: its thickness scaled by s in
#: (0, 2]; the reduced volume peaks at 0.74 near s = 2 (flatter or fatter disks), and a nearly
#: spherical state is an oblate spheroid (reference_shape kind oblate)
BICONCAVE_REDUCED_VOLUME = (0.3, 0.72)


def reduced_volume(volume: float, area: float) -> float:
    """ν = V / (4π/3 (S/4π)^{3/2}): the volume over that of the sphere of the same area (1: a sphere)."""
    return float(volume / (4.0 * np.pi / 3.0 * (area / (4.0 * np.pi)) ** 1.5))


def _biconcave_profile_reduced_volume(scale: float, c0: float, c2: float, c4: float, n: int = 400) -> float:
    """ν of the continuous Evans-Fung disk with its thickness scaled by `scale`: the meridian
    r = sin t, y = ½ scale cos t (c0 + c2 r² + c4 r⁴), t in [0, π/2], is smooth in t (the rim's
    infinite slope dy/dr is not), so Gauss-Legendre converges spectrally."""
    g, w = np.polynomial.legendre.leggauss(n)
    t = 0.25 * np.pi * (g + 1.0)
    w = 0.25 * np.pi * w
    r, dr = np.sin(t), np.cos(t)
    h = c0 + c2 * r**2 + c4 * r**4
    dh = (2.0 * c2 * r + 4.0 * c4 * r**3) * dr
    y = 0.5 * scale * np.cos(t) * h
    dy = 0.5 * scale * (-np.sin(t) * h + np.cos(t) * dh)
    area = 2.0 * 2.0 * np.pi * np.sum(w * r * np.hypot(dr, dy))  # both faces
    volume = 2.0 * 2.0 * np.pi * np.sum(w * r * y * dr)  # ∫ 2πr · y dr, both halves
    return reduced_volume(volume, area)


def biconcave_thickness_scale(target: float, c0: float = 0.207, c2: float = 2.003, c4: float = -1.123) -> float:
    """The factor s on the Evans-Fung thickness that gives the disk the reduced volume `target`
    (on its continuous surface; the mesh's differs by its discretisation error)."""
    from scipy.optimize import brentq

    lo, hi = BICONCAVE_REDUCED_VOLUME
    if not lo <= target <= hi:
        raise ValueError(f"reduced volume {target:g} outside [{lo:g}, {hi:g}], what the biconcave family reaches")
    return float(brentq(lambda s: _biconcave_profile_reduced_volume(s, c0, c2, c4) - target, 0.05, 2.0, xtol=1e-14))


def stress_free_positions(kind: str, area: float, sphere: SurfaceMesh, *, tilt_deg: float = 0.0, axis=None,
                          aspect_ratio: float = 1.0, reduced_volume_target: float | None = None,
                          c0: float = 0.207, c2: float = 2.003, c4: float = -1.123) -> np.ndarray:
    """A stress-free surface on the unit-sphere mesh `sphere` (:func:`unit_sphere_mesh`; node k the
    image of the sphere's node k, as in :func:`rest_shape_mesh`): a sphere, an oblate spheroid of
    `aspect_ratio`, or the Evans-Fung disk of coefficients (c0, c2, c4) with its thickness scaled to
    `reduced_volume_target`; turned as the rest shape is (`tilt_deg` or `axis`), centred at the
    origin, and scaled so that its discretised area is `area`."""
    from capsim.numerics.geometry import element_geometry, volume_area

    if kind == "biconcave":
        scale = 1.0 if reduced_volume_target is None else biconcave_thickness_scale(reduced_volume_target, c0, c2, c4)
        x = _biconcave(sphere.positions, c0=c0, c2=c2, c4=c4)
        x[:, 1] *= scale
    elif kind in ("sphere", "oblate"):
        x = _spheroid(sphere.positions, aspect_ratio=aspect_ratio)
    else:
        raise ValueError(f"unknown stress-free shape {kind!r} (allowed: sphere, oblate, biconcave)")
    _, own = volume_area(element_geometry(x, sphere.elements, 6))
    x *= np.sqrt(area / own)
    if axis is not None:
        if tilt_deg != 0.0:
            raise ValueError("give tilt_deg or axis, not both")
        return x @ rotation_onto(axis).T
    return x @ rotation_about_z(np.deg2rad(tilt_deg)).T
