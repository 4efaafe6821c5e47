"""Closed surface meshes of conduits: a tube, a constricted tube, a rectangular duct.

The conduit's axis is x and the flow goes along +x. The conduit is cut at x = ±L/2 and closed
there by two flat end caps, so that the wall is one closed surface of 6-node quadratic
triangles, the capsule's elements (capsim/numerics/mesh.py: rows (v0, v1, v2, m01, m12, m20),
the vertex nodes numbered first). ∂x/∂ξ × ∂x/∂η points out of the enclosed fluid.

The side wall is structured: rings of vertices at the axial stations of
:func:`axial_spacing` (fine near x = 0 where the capsule is, graded geometrically towards the
caps). Each quad of two neighbouring rings is split along the diagonal chosen by its quadrant
of the (y, z) plane and the sign of x, so that the mesh maps onto itself under y → −y and
z → −z (and x → −x). Mid-edge nodes lie on the exact surface.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from capsim.numerics.mesh import SurfaceMesh

SIDE, INLET, OUTLET = 0, 1, 2


@dataclass(frozen=True)
class ConduitMesh(SurfaceMesh):
    """A capsule mesh's nodes (N, 3), 6-node elements (E, 6) and vertex count, with the part of each
    element (0 side wall, 1 inlet cap at x = −L/2, 2 outlet cap at x = +L/2) and the length L
    between the caps."""

    part: np.ndarray = None  # type: ignore[assignment]
    length: float = 0.0


# ------------------------------------------------------------------ axial stations

def axial_spacing(length: float, size_near: float, size_far: float, near_half_length: float,
                  growth: float = 1.25) -> np.ndarray:
    """Stations x_k from −L/2 to L/2, symmetric about 0 (a station at 0).

    The spacing is ≈ ``size_near`` (at most) for |x| ≤ ``near_half_length``, then grows by at most
    ``growth`` per station up to ``size_far``. The stations equidistribute ξ(x) = ∫ dx/h(x) with the
    size function h = size_near·growth^(ξ − ξ_near) capped at size_far; an even whole number of
    steps Δξ ≤ 1 gives consecutive spacings whose ratio is ≤ growth^Δξ ≤ growth.
    """
    if not (length > 0 and 0 < size_near <= size_far and near_half_length >= 0 and growth > 1):
        raise ValueError("axial_spacing needs length > 0, 0 < size_near <= size_far, near_half_length >= 0, "
                         f"growth > 1 (got {length}, {size_near}, {size_far}, {near_half_length}, {growth})")
    half = 0.5 * length
    h0, hf, c = float(size_near), float(size_far), math.log(growth)
    a = min(float(near_half_length), half)
    grow_len = (hf - h0) / c               # the x-extent of the growth zone
    xi_a = a / h0
    xi_b = xi_a + math.log(hf / h0) / c

    def xi_of(x: float) -> float:
        if x <= a:
            return x / h0
        if x <= a + grow_len:
            return xi_a + math.log1p(c * (x - a) / h0) / c
        return xi_b + (x - a - grow_len) / hf

    def x_of(xi: np.ndarray) -> np.ndarray:
        near = h0 * xi
        grown = a + h0 * np.expm1(c * (xi - xi_a)) / c
        far = a + grow_len + hf * (xi - xi_b)
        return np.where(xi <= xi_a, near, np.where(xi <= xi_b, grown, far))

    total = 2.0 * xi_of(half)
    n = 2 * max(1, math.ceil(0.5 * total))   # even, so that 0 is a station, and Δξ = total/n <= 1
    t = (np.arange(n + 1) - n // 2) * (total / n)
    x = np.sign(t) * x_of(np.abs(t))
    x[0], x[n // 2], x[-1] = -half, 0.0, half
    return x


# ------------------------------------------------------------------ assembly

def _side_wall(stations: np.ndarray, n_ring: int, ring: Callable[[np.ndarray, np.ndarray], np.ndarray]):
    """Vertex positions and triangles of the structured side wall.

    ``ring(x, s)`` is the surface point at axial position x and ring coordinate s (in units of
    the ring's node spacing, periodic with n_ring). Returns vertices ((m+1)·n, 3), triangles
    (T, 3) (vertex k·n + j) and their edge mid-points (T, 3, 3) (edges 01, 12, 20) taken at the
    parameter midpoints, so on the surface.
    """
    m, n = len(stations) - 1, n_ring
    kk, jj = np.meshgrid(np.arange(m + 1), np.arange(n), indexing="ij")
    vertices = ring(stations[kk.ravel()], jj.ravel().astype(float))
    k, j = (g.ravel() for g in np.meshgrid(np.arange(m), np.arange(n), indexing="ij"))
    xm = 0.5 * (stations[k] + stations[k + 1])
    centre = ring(xm, j + 0.5)
    # "/" joins (x_k, s_j) to (x_k+1, s_j+1); a mirror y → −y, z → −z or x → −x turns it into "\"
    slash = (centre[:, 1] * centre[:, 2] > 0) ^ (xm < 0)
    # quad corners as (station index, ring coordinate unwrapped): a (k, j), b (k, j+1), c (k+1, j+1), d (k+1, j)
    corners = {"a": (k, j), "b": (k, j + 1), "c": (k + 1, j + 1), "d": (k + 1, j)}
    # both splits keep e_θ × e_x orientation (radially outward): (a,b,c)+(a,c,d) or (a,b,d)+(b,c,d)
    tris_k, tris_s = [], []
    for names_slash, names_back in ((("a", "b", "c"), ("a", "b", "d")), (("a", "c", "d"), ("b", "c", "d"))):
        ks = np.where(slash[:, None], np.stack([corners[c][0] for c in names_slash], 1),
                      np.stack([corners[c][0] for c in names_back], 1))
        ss = np.where(slash[:, None], np.stack([corners[c][1] for c in names_slash], 1),
                      np.stack([corners[c][1] for c in names_back], 1))
        tris_k.append(ks)
        tris_s.append(ss)
    tk = np.concatenate(tris_k)
    ts = np.concatenate(tris_s)
    triangles = tk * n + ts % n
    xv = stations[tk]
    mids = np.empty(tk.shape + (3,))
    for e, (p, q) in enumerate(((0, 1), (1, 2), (2, 0))):
        mids[:, e] = ring(0.5 * (xv[:, p] + xv[:, q]), 0.5 * (ts[:, p] + ts[:, q]).astype(float))
    return vertices, triangles.astype(np.int64), mids


def _orient_cap(points: np.ndarray, triangles: np.ndarray, sign: float) -> np.ndarray:
    """Triangles reordered so that the vertex triangle's normal has n_x of the given sign."""
    a, b, c = (points[triangles[:, i]] for i in range(3))
    wrong = np.sign(np.cross(b - a, c - a)[:, 0]) != sign
    triangles = triangles.copy()
    triangles[wrong] = triangles[wrong][:, [0, 2, 1]]
    return triangles


def _straight_mids(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    p = points[triangles]
    return 0.5 * (p + p[:, [1, 2, 0]])


def _assemble(vertices: np.ndarray, triangles: list[np.ndarray], mids: list[np.ndarray], parts: list[int],
              length: float) -> ConduitMesh:
    """6-node elements from vertex triangles: one mid-node per edge, at the mid-point given with
    the edge's FIRST occurrence (the side wall comes first, so the cap's rim takes its nodes)."""
    tri = np.concatenate(triangles)
    mid = np.concatenate(mids).reshape(-1, 3)
    part = np.concatenate([np.full(len(t), p, dtype=np.int8) for t, p in zip(triangles, parts)])
    edges = np.sort(np.stack([tri, tri[:, [1, 2, 0]]], axis=2).reshape(-1, 2), axis=1)
    _, first, inverse = np.unique(edges, axis=0, return_index=True, return_inverse=True)
    n_v = len(vertices)
    elements = np.concatenate([tri, n_v + inverse.reshape(-1, 3)], axis=1).astype(np.int64)
    positions = np.concatenate([vertices, mid[first]])
    return ConduitMesh(np.ascontiguousarray(positions, dtype=np.float64), elements, n_v, part, float(length))


# ------------------------------------------------------------------ tubes

def _disk_rings(n_rim: int) -> list[int]:
    """Node counts of a cap's rings, centre (1) to rim (n_rim): rings a radial step apart with
    ≈ 2π·i nodes (isotropic elements), multiples of 4 for the mirror symmetry."""
    p = max(1, round(n_rim / (2.0 * math.pi)))
    counts = [1] + [min(n_rim, 4 * max(2, round(math.pi * i / 2.0))) for i in range(1, p)] + [n_rim]
    return counts


def _quadrant_zipper(inner: np.ndarray, outer: np.ndarray) -> list[tuple[tuple[int, int], ...]]:
    """Triangles between two rings' first-quadrant nodes (positions, angle 0 to π/2 inclusive),
    as (ring 0 inner / 1 outer, node) triples; advancing on the shorter diagonal."""
    tris = []
    if len(inner) == 1:  # the centre: a fan
        return [((0, 0), (1, b), (1, b + 1)) for b in range(len(outer) - 1)]
    a = b = 0
    while a < len(inner) - 1 or b < len(outer) - 1:
        advance_inner = b == len(outer) - 1 or (
            a < len(inner) - 1
            and np.linalg.norm(outer[b] - inner[a + 1]) < np.linalg.norm(inner[a] - outer[b + 1]))
        if advance_inner:
            tris.append(((0, a), (1, b), (0, a + 1)))
            a += 1
        else:
            tris.append(((0, a), (1, b), (1, b + 1)))
            b += 1
    return tris


def _tube_cap(rim_ids: np.ndarray, radius: float, x: float, first_id: int):
    """Interior vertices and triangles of a flat disk cap whose rim is the ring ``rim_ids``
    (node j at angle 2πj/n). One quadrant is zipped ring to ring and mirrored into the others."""
    n_rim = len(rim_ids)
    counts = _disk_rings(n_rim)
    p = len(counts) - 1
    ids, pts, new = [], [], first_id
    for i, n_i in enumerate(counts):
        if i == p:
            ids.append(np.asarray(rim_ids))
            ang = 2 * np.pi * np.arange(n_i) / n_i
            pts.append(np.stack([np.cos(ang), np.sin(ang)], 1) * radius)
            continue
        ids.append(np.arange(new, new + n_i))
        new += n_i
        ang = 2 * np.pi * np.arange(n_i) / n_i
        pts.append(np.stack([np.cos(ang), np.sin(ang)], 1) * radius * i / p if i else np.zeros((1, 2)))
    vertices = np.concatenate([np.column_stack([np.full(len(q), x), q]) for q in pts[:p]])
    triangles = []
    for i in range(p):
        q_in = pts[i][: counts[i] // 4 + 1] if counts[i] > 1 else pts[i]
        q_out = pts[i + 1][: counts[i + 1] // 4 + 1]
        for tri in _quadrant_zipper(q_in, q_out):
            rings = [i + r for r, _ in tri]
            nodes = [j for _, j in tri]
            # node j at angle θ_j: z → −z is θ → −θ, y → −y is θ → π − θ, both θ → θ + π
            for sign, shift in ((1, 0), (-1, 0), (-1, 2), (1, 2)):
                triangles.append([ids[r][(sign * j + shift * (counts[r] // 4)) % counts[r]]
                                  for r, j in zip(rings, nodes)])
    return vertices, np.array(triangles, dtype=np.int64)


def axisymmetric_conduit_mesh(radius_of_x: Callable[[np.ndarray], np.ndarray], length: float, size_near: float,
                              size_far: float, near_half_length: float, n_theta: int | None = None,
                              growth: float = 1.25) -> ConduitMesh:
    """Closed mesh of the axisymmetric conduit r = radius_of_x(x), |x| ≤ L/2, with flat end caps.

    ``n_theta`` vertices per ring (a multiple of 4; by default the largest circumference over
    ``size_near``). Caps: concentric rings about a central node, the rim shared with the wall.
    """
    stations = axial_spacing(length, size_near, size_far, near_half_length, growth)
    radius_of = lambda x: np.broadcast_to(np.asarray(radius_of_x(np.asarray(x, float)), float), np.shape(x))
    mids = 0.5 * (stations[1:] + stations[:-1])
    r_max = float(max(radius_of(stations).max(), radius_of(mids).max()))
    if n_theta is None:
        n_theta = max(8, 4 * math.ceil(2 * math.pi * r_max / (4 * size_near)))
    if n_theta % 4 or n_theta < 8:
        raise ValueError(f"n_theta must be a multiple of 4, at least 8 (got {n_theta})")

    def ring(x, s):
        theta = 2 * np.pi * np.asarray(s) / n_theta
        r = radius_of(x)
        return np.stack([np.asarray(x, float) + 0 * theta, r * np.cos(theta), r * np.sin(theta)], axis=-1)

    side_v, side_t, side_m = _side_wall(stations, n_theta, ring)
    n_side = len(side_v)
    m = len(stations) - 1
    half = 0.5 * length
    vertices, triangles, mid_list = [side_v], [side_t], [side_m]
    for part, k, sign in ((INLET, 0, -1.0), (OUTLET, m, 1.0)):
        rim = k * n_theta + np.arange(n_theta)
        first = n_side + sum(len(v) for v in vertices[1:])
        cap_v, cap_t = _tube_cap(rim, float(radius_of(stations[k])), -half if k == 0 else half, first)
        vertices.append(cap_v)
        points = np.concatenate(vertices)
        cap_t = _orient_cap(points, cap_t, sign)
        triangles.append(cap_t)
        mid_list.append(_straight_mids(points, cap_t))
    return _assemble(np.concatenate(vertices), triangles, mid_list, [SIDE, INLET, OUTLET], length)


def round_caps(mesh: ConduitMesh) -> ConduitMesh:
    """The conduit with its flat end caps bent into hemispheres of the end radius (axisymmetric
    ends): a cap node at distance r from the axis moves to polar angle φ = (π/2)(r/R) of the
    sphere about (±L/2, 0, 0), so the rim stays and the surface meets the side wall with its
    tangent. A smooth closed surface: its traction density (continuous at the nodes) can carry a
    uniform pressure, which a flat cap's corner cannot (the normal jumps there)."""
    positions = mesh.positions.copy()
    cap_nodes = np.unique(mesh.elements[mesh.part != SIDE])
    moved = np.setdiff1d(cap_nodes, np.unique(mesh.elements[mesh.part == SIDE]))
    p = positions[moved]
    r, theta = np.hypot(p[:, 1], p[:, 2]), np.arctan2(p[:, 2], p[:, 1])
    rim = np.unique(np.intersect1d(cap_nodes, np.unique(mesh.elements[mesh.part == SIDE])))
    radius = float(np.hypot(positions[rim, 1], positions[rim, 2]).mean())
    phi = 0.5 * np.pi * r / radius
    positions[moved, 0] = np.sign(p[:, 0]) * (0.5 * mesh.length + radius * np.cos(phi))
    positions[moved, 1] = radius * np.sin(phi) * np.cos(theta)
    positions[moved, 2] = radius * np.sin(phi) * np.sin(theta)
    return ConduitMesh(positions, mesh.elements, mesh.n_vertices, mesh.part, mesh.length)


def tube_mesh(radius: float, length: float, size_near: float, size_far: float, near_half_length: float,
              n_theta: int | None = None, caps: str = "flat") -> ConduitMesh:
    """Closed mesh of the circular tube of ``radius`` (see :func:`axisymmetric_conduit_mesh`);
    ``caps`` "round": hemispherical ends (:func:`round_caps`) beyond x = ±L/2."""
    mesh = axisymmetric_conduit_mesh(lambda x: np.full(np.shape(x), float(radius)), length, size_near, size_far,
                                     near_half_length, n_theta)
    if caps not in ("flat", "round"):
        raise ValueError(f"caps must be 'flat' or 'round', got {caps!r}")
    return round_caps(mesh) if caps == "round" else mesh


def cosine_constriction_radius(radius: float, throat_radius: float, half_length: float) -> Callable:
    """r(x) = R − (R − Rc)(1 + cos(πx/ℓ))/2 for |x| < ℓ, else R (smooth, C¹ at |x| = ℓ)."""
    R, Rc, ell = float(radius), float(throat_radius), float(half_length)

    def r(x):
        x = np.asarray(x, dtype=float)
        return np.where(np.abs(x) < ell, R - (R - Rc) * 0.5 * (1.0 + np.cos(np.pi * x / ell)), R)

    return r


# ------------------------------------------------------------------ duct

def duct_mesh(half_y: float, half_z: float, length: float, size_near: float, size_far: float,
              near_half_length: float, growth: float = 1.25) -> ConduitMesh:
    """Closed mesh of the duct |y| ≤ half_y, |z| ≤ half_z, |x| ≤ L/2: four structured flat faces
    (the corners' edges shared) and two flat rectangular caps, mirror-symmetric in y and z."""
    stations = axial_spacing(length, size_near, size_far, near_half_length, growth)
    ny = 2 * max(1, math.ceil(half_y / size_near))
    nz = 2 * max(1, math.ceil(half_z / size_near))
    # i/(n/2) for integer i: exactly antisymmetric, so the mirror maps nodes onto nodes to the bit
    ys = half_y * np.arange(-ny // 2, ny // 2 + 1) / (ny // 2)
    zs = half_z * np.arange(-nz // 2, nz // 2 + 1) / (nz // 2)
    # the ring: the cap grid's boundary counter-clockwise in (y, z) from (half_y, 0), as (iy, iz)
    h = nz // 2
    loop = ([(ny, iz) for iz in range(h, nz)] + [(iy, nz) for iy in range(ny, 0, -1)]
            + [(0, iz) for iz in range(nz, 0, -1)] + [(iy, 0) for iy in range(0, ny)]
            + [(ny, iz) for iz in range(0, h)])
    loop_arr = np.array(loop)
    n_ring = len(loop)
    yr = np.append(ys[loop_arr[:, 0]], ys[loop_arr[0, 0]])
    zr = np.append(zs[loop_arr[:, 1]], zs[loop_arr[0, 1]])
    knots = np.arange(n_ring + 1, dtype=float)

    def ring(x, s):
        s = np.asarray(s, float)
        x = np.asarray(x, float) + 0 * s
        return np.stack([x, np.interp(s, knots, yr), np.interp(s, knots, zr)], axis=-1)

    side_v, side_t, side_m = _side_wall(stations, n_ring, ring)
    m = len(stations) - 1
    half = 0.5 * length
    vertices, triangles, mid_list = [side_v], [side_t], [side_m]
    ring_index = {tuple(p): j for j, p in enumerate(loop)}
    for part, k, sign in ((INLET, 0, -1.0), (OUTLET, m, 1.0)):
        first = sum(len(v) for v in vertices)
        ids = np.empty((ny + 1, nz + 1), dtype=np.int64)
        new = []
        for iy in range(ny + 1):
            for iz in range(nz + 1):
                if (iy, iz) in ring_index:
                    ids[iy, iz] = k * n_ring + ring_index[(iy, iz)]
                else:
                    ids[iy, iz] = first + len(new)
                    new.append((-half if k == 0 else half, ys[iy], zs[iz]))
        vertices.append(np.array(new, dtype=float).reshape(-1, 3))
        iy, iz = (g.ravel() for g in np.meshgrid(np.arange(ny), np.arange(nz), indexing="ij"))
        slash = (ys[iy] + ys[iy + 1]) * (zs[iz] + zs[iz + 1]) > 0
        p00, p10, p11, p01 = ids[iy, iz], ids[iy + 1, iz], ids[iy + 1, iz + 1], ids[iy, iz + 1]
        t1 = np.where(slash[:, None], np.stack([p00, p10, p11], 1), np.stack([p00, p10, p01], 1))
        t2 = np.where(slash[:, None], np.stack([p00, p11, p01], 1), np.stack([p10, p11, p01], 1))
        points = np.concatenate(vertices)
        cap_t = _orient_cap(points, np.concatenate([t1, t2]), sign)
        triangles.append(cap_t)
        mid_list.append(_straight_mids(points, cap_t))
    return _assemble(np.concatenate(vertices), triangles, mid_list, [SIDE, INLET, OUTLET], length)
