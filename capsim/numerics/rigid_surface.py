"""The single-layer operator of a rigid surface of 6-node triangles (a conduit's wall).

The wall carries a traction density q given by its nodal values and interpolated
quadratically over each element; its velocity is

    (W q)(x) = ∫_S G(x, y)·q(y) dS(y),   G = I/r + r r/r³,  r = y − x

(capsim's unnormalised Stokeslet, as ``kernels.stokeslet_sum``: no 1/8π). At the wall's
own nodes this is the dense matrix :func:`single_layer_matrix`, built once per run and
factorised; at targets off the wall (a capsule's nodes) :func:`single_layer_at`, or, for
targets far from every wall element, ``stokeslet_sum`` over :func:`point_strengths_of`.

Rules per (target, element) pair, as elsewhere in capsim: the Duffy rule singular at the
target's local node on the elements holding it, a subdivided rule on elements near the
target (distance < factor × the element's longest vertex edge), the regular rule on the
rest. The distance to an element is that to its four flat sub-triangles (vertex and
mid-edge nodes), which the curved element leaves by O(h² κ).

A closed wall's W has a null space: ∫ G·n dS = 0 (the Stokeslet is solenoidal), so W n ≈ 0
with n the nodal normals (:func:`nodal_normals`); :func:`surface_integral_weights` gives
the weights of ∫ q·n dS = Σ_j w_j q_j·n_j with which a rank-one term removes it.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from capsim.numerics.geometry import shape_functions
from capsim.numerics.kernels import element_quadrature
from capsim.numerics.quadrature import NODE_ETA, NODE_XI, singular_rules, subdivided_rule, triangle_rule

_JIT = dict(cache=True, fastmath=True, error_model="numpy", boundscheck=False)

__all__ = [
    "single_layer_matrix", "single_layer_at", "point_strengths_of",
    "surface_integral_weights", "nodal_normals", "element_sizes",
]


# ---------------------------------------------------------------- element distances

@njit(inline="always")
def _point_triangle_distance2(px, py, pz, a, b, c):
    """Squared distance from p to the flat triangle (a, b, c) (Ericson 2005, §5.1.5:
    the closest point by Voronoi regions of the vertices, edges and face)."""
    abx, aby, abz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    acx, acy, acz = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    apx, apy, apz = px - a[0], py - a[1], pz - a[2]
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return apx * apx + apy * apy + apz * apz
    bpx, bpy, bpz = px - b[0], py - b[1], pz - b[2]
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return bpx * bpx + bpy * bpy + bpz * bpz
    cpx, cpy, cpz = px - c[0], py - c[1], pz - c[2]
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return cpx * cpx + cpy * cpy + cpz * cpz
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        qx, qy, qz = apx - v * abx, apy - v * aby, apz - v * abz
        return qx * qx + qy * qy + qz * qz
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        qx, qy, qz = apx - w * acx, apy - w * acy, apz - w * acz
        return qx * qx + qy * qy + qz * qz
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        qx = bpx - w * (c[0] - b[0])
        qy = bpy - w * (c[1] - b[1])
        qz = bpz - w * (c[2] - b[2])
        return qx * qx + qy * qy + qz * qz
    denom = 1.0 / (va + vb + vc)
    v = vb * denom
    w = vc * denom
    qx, qy, qz = apx - v * abx - w * acx, apy - v * aby - w * acy, apz - v * abz - w * acz
    return qx * qx + qy * qy + qz * qz


@njit(inline="always")
def _element_distance(px, py, pz, x, elements, e):
    """Distance from p to element e's four flat sub-triangles (v0 m01 m20, m01 v1 m12,
    m20 m12 v2, m01 m12 m20)."""
    v0, v1, v2 = x[elements[e, 0]], x[elements[e, 1]], x[elements[e, 2]]
    m01, m12, m20 = x[elements[e, 3]], x[elements[e, 4]], x[elements[e, 5]]
    d = _point_triangle_distance2(px, py, pz, v0, m01, m20)
    d = min(d, _point_triangle_distance2(px, py, pz, m01, v1, m12))
    d = min(d, _point_triangle_distance2(px, py, pz, m20, m12, v2))
    d = min(d, _point_triangle_distance2(px, py, pz, m01, m12, m20))
    return np.sqrt(d)


@njit(inline="always")
def _near_distance(px, py, pz, x, elements, e, cen, rad, reach):
    """The element's distance if it is below reach, else reach (cheap bounding-sphere
    rejection first: most elements are far)."""
    dx = px - cen[e, 0]
    dy = py - cen[e, 1]
    dz = pz - cen[e, 2]
    lim = reach + rad[e]
    if dx * dx + dy * dy + dz * dz >= lim * lim:
        return reach
    return min(reach, _element_distance(px, py, pz, x, elements, e))


# ---------------------------------------------------------------- the matrix

@njit(inline="always")
def _element_blocks(acc, x0, y0, z0, p, w, phi):
    """acc[a] = Σ_q φ_a(q) w_q G(p_q − x0) (the six entries g00 g11 g22 g01 g02 g12) for
    the rule points p (m, 3), area weights w (m,), basis values phi (m, 6)."""
    for a in range(6):
        for c in range(6):
            acc[a, c] = 0.0
    for q in range(w.shape[0]):
        dx = p[q, 0] - x0
        dy = p[q, 1] - y0
        dz = p[q, 2] - z0
        rinv = 1.0 / np.sqrt(dx * dx + dy * dy + dz * dz)
        rw = rinv * w[q]
        r3 = rw * rinv * rinv
        g00 = rw + dx * dx * r3
        g11 = rw + dy * dy * r3
        g22 = rw + dz * dz * r3
        g01 = dx * dy * r3
        g02 = dx * dz * r3
        g12 = dy * dz * r3
        for a in range(6):
            ph = phi[q, a]
            acc[a, 0] += ph * g00
            acc[a, 1] += ph * g11
            acc[a, 2] += ph * g22
            acc[a, 3] += ph * g01
            acc[a, 4] += ph * g02
            acc[a, 5] += ph * g12


@njit(parallel=True, **_JIT)
def _single_layer_matrix_kernel(x, elements, size, cen, rad, near_factor,
                                reg_p, reg_w, reg_phi, fine_p, fine_w, fine_phi, sing_p, sing_w, sing_phi):
    """W (3N, 3N): row block i (prange), each element's six 3×3 column blocks by its rule."""
    n = x.shape[0]
    ne = elements.shape[0]
    out = np.empty((3 * n, 3 * n))
    for i in prange(n):
        # each row is zeroed by its own thread (first touch, and no serial memset)
        for r in range(3):
            for c in range(3 * n):
                out[3 * i + r, c] = 0.0
        acc = np.empty((6, 6))
        x0, y0, z0 = x[i, 0], x[i, 1], x[i, 2]
        for e in range(ne):
            k = -1
            for a in range(6):
                if elements[e, a] == i:
                    k = a
            if k >= 0:
                _element_blocks(acc, x0, y0, z0, sing_p[e, k], sing_w[e, k], sing_phi[k])
            else:
                reach = near_factor * size[e]
                if _near_distance(x0, y0, z0, x, elements, e, cen, rad, reach) < reach:
                    _element_blocks(acc, x0, y0, z0, fine_p[e], fine_w[e], fine_phi)
                else:
                    _element_blocks(acc, x0, y0, z0, reg_p[e], reg_w[e], reg_phi)
            for a in range(6):
                col = 3 * elements[e, a]
                out[3 * i, col] += acc[a, 0]
                out[3 * i, col + 1] += acc[a, 3]
                out[3 * i, col + 2] += acc[a, 4]
                out[3 * i + 1, col] += acc[a, 3]
                out[3 * i + 1, col + 1] += acc[a, 1]
                out[3 * i + 1, col + 2] += acc[a, 5]
                out[3 * i + 2, col] += acc[a, 4]
                out[3 * i + 2, col + 1] += acc[a, 5]
                out[3 * i + 2, col + 2] += acc[a, 2]
    return out


# ---------------------------------------------------------------- off-surface targets

@njit(inline="always")
def _near_element(x0, y0, z0, x, elements, q, e, phi, dxi, deta, w, lo, hi):
    """∫_e G·q dS by the rule points lo..hi−1 of the tables (positions, Jacobian and
    density interpolated from the element's six nodes at every point)."""
    ux = 0.0
    uy = 0.0
    uz = 0.0
    for j in range(lo, hi):
        px = 0.0
        py = 0.0
        pz = 0.0
        ax = 0.0
        ay = 0.0
        az = 0.0
        bx = 0.0
        by = 0.0
        bz = 0.0
        fx = 0.0
        fy = 0.0
        fz = 0.0
        for a in range(6):
            node = elements[e, a]
            ph = phi[j, a]
            d1 = dxi[j, a]
            d2 = deta[j, a]
            xa = x[node, 0]
            ya = x[node, 1]
            za = x[node, 2]
            px += ph * xa
            py += ph * ya
            pz += ph * za
            ax += d1 * xa
            ay += d1 * ya
            az += d1 * za
            bx += d2 * xa
            by += d2 * ya
            bz += d2 * za
            fx += ph * q[node, 0]
            fy += ph * q[node, 1]
            fz += ph * q[node, 2]
        nx = ay * bz - az * by
        ny = az * bx - ax * bz
        nz = ax * by - ay * bx
        wj = w[j] * np.sqrt(nx * nx + ny * ny + nz * nz)
        dx = px - x0
        dy = py - y0
        dz = pz - z0
        rinv = 1.0 / np.sqrt(dx * dx + dy * dy + dz * dz)
        rg = (dx * fx + dy * fy + dz * fz) * rinv * rinv * rinv * wj
        ux += fx * wj * rinv + dx * rg
        uy += fy * wj * rinv + dy * rg
        uz += fz * wj * rinv + dz * rg
    return ux, uy, uz


@njit(parallel=True, **_JIT)
def _single_layer_at_kernel(targets, x, elements, q, size, cen, rad, near_factor, max_levels,
                            reg_p, reg_s, lvl_phi, lvl_dxi, lvl_deta, lvl_w, lvl_off):
    """∫ G·q dS at each target (prange): the regular points' Stokeslets (reg_p (E, m, 3),
    strengths reg_s (E, m, 3)), or on a near element the subdivided rule of level L
    (rows lvl_off[L−1]..lvl_off[L] of the tables), L growing as the distance falls."""
    nt = targets.shape[0]
    ne = elements.shape[0]
    m = reg_p.shape[1]
    out = np.empty((nt, 3))
    for t in prange(nt):
        x0, y0, z0 = targets[t, 0], targets[t, 1], targets[t, 2]
        ux = 0.0
        uy = 0.0
        uz = 0.0
        for e in range(ne):
            reach = near_factor * size[e]
            d = _near_distance(x0, y0, z0, x, elements, e, cen, rad, reach)
            if d < reach:
                # one level per halving of d: sub-triangles of size h/2^L then meet the far
                # criterion d ≥ near_factor · h/2^L until max_levels caps them
                lv = max_levels
                if d > 0.0:
                    lv = min(max_levels, max(1, int(np.ceil(np.log2(reach / d)))))
                sx, sy, sz = _near_element(x0, y0, z0, x, elements, q, e, lvl_phi, lvl_dxi, lvl_deta, lvl_w,
                                           lvl_off[lv - 1], lvl_off[lv])
                ux += sx
                uy += sy
                uz += sz
            else:
                for j in range(m):
                    dx = reg_p[e, j, 0] - x0
                    dy = reg_p[e, j, 1] - y0
                    dz = reg_p[e, j, 2] - z0
                    gx = reg_s[e, j, 0]
                    gy = reg_s[e, j, 1]
                    gz = reg_s[e, j, 2]
                    rinv = 1.0 / np.sqrt(dx * dx + dy * dy + dz * dz)
                    rg = (dx * gx + dy * gy + dz * gz) * rinv * rinv * rinv
                    ux += gx * rinv + dx * rg
                    uy += gy * rinv + dy * rg
                    uz += gz * rinv + dz * rg
        out[t, 0] = ux
        out[t, 1] = uy
        out[t, 2] = uz
    return out


# ---------------------------------------------------------------- numpy wrappers

def _mesh(positions, elements):
    return (np.ascontiguousarray(positions, dtype=np.float64),
            np.ascontiguousarray(elements, dtype=np.int64))


def element_sizes(positions: np.ndarray, elements: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each element's size (longest vertex edge), vertex centroid, and the radius about the
    centroid that holds its six nodes: (E,), (E, 3), (E,)."""
    x, el = _mesh(positions, elements)
    v = x[el[:, :3]]
    size = np.linalg.norm(v - np.roll(v, 1, axis=1), axis=2).max(axis=1)
    cen = v.mean(axis=1)
    # ×1.1: the curved element bulges past its nodes by O(h² κ)
    rad = 1.1 * np.linalg.norm(x[el] - cen[:, None, :], axis=2).max(axis=1)
    return size, cen, rad


def _rule(x, el, xi, eta, w):
    """Points (E, m, 3), area weights (E, m) and basis values (m, 6) of one rule."""
    phi, dxi, deta = shape_functions(xi, eta)
    pts, _, wts = element_quadrature(x, el, np.ascontiguousarray(phi), np.ascontiguousarray(dxi),
                                     np.ascontiguousarray(deta), np.ascontiguousarray(w))
    return pts, wts, np.ascontiguousarray(phi)


def single_layer_matrix(positions: np.ndarray, elements: np.ndarray, n_points: int = 7, duffy_n: int = 6,
                        near_factor: float = 2.0, near_levels: int = 2) -> np.ndarray:
    """The single layer at every node as a dense (3N, 3N) matrix acting on nodal densities.

    W[3i+a, 3j+b] = Σ_e ∫_e G_ab(x_i, y) φ_k(j)(y) dS(y). Elements holding node i: the Duffy
    rule singular at its local node (``singular_rules(duffy_n)``); elements within
    near_factor × their size of x_i: ``subdivided_rule(n_points, near_levels)``; others the
    regular rule ``triangle_rule(n_points)``. Dense: (3N)² doubles, 1.2 GB at N = 4098.
    """
    x, el = _mesh(positions, elements)
    size, cen, rad = element_sizes(x, el)
    reg_p, reg_w, reg_phi = _rule(x, el, *triangle_rule(n_points))
    fine_p, fine_w, fine_phi = _rule(x, el, *subdivided_rule(n_points, near_levels))
    sxi, seta, sw = singular_rules(duffy_n)
    ne, md = el.shape[0], sw.shape[1]
    sing_p = np.empty((ne, 6, md, 3))
    sing_w = np.empty((ne, 6, md))
    sing_phi = np.empty((6, md, 6))
    for k in range(6):
        sing_p[:, k], sing_w[:, k], sing_phi[k] = _rule(x, el, sxi[k], seta[k], sw[k])
    return _single_layer_matrix_kernel(x, el, size, cen, rad, float(near_factor),
                                       reg_p, reg_w, reg_phi, fine_p, fine_w, fine_phi, sing_p, sing_w, sing_phi)


def point_strengths_of(positions: np.ndarray, elements: np.ndarray, q: np.ndarray,
                       n_points: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """The regular rule as point Stokeslets: points (E·n, 3) and strengths q(y)·w dS (E·n, 3),
    so that ``kernels.stokeslet_sum(targets, points, strengths)`` is ∫ G·q dS at targets
    far (≳ 3 element sizes) from every element."""
    x, el = _mesh(positions, elements)
    pts, wts, phi = _rule(x, el, *triangle_rule(n_points))
    qe = np.asarray(q, dtype=np.float64)[el]  # (E, 6, 3)
    strengths = np.einsum("ma,ead,em->emd", phi, qe, wts)
    return pts.reshape(-1, 3), np.ascontiguousarray(strengths.reshape(-1, 3))


def single_layer_at(targets: np.ndarray, positions: np.ndarray, elements: np.ndarray, q: np.ndarray,
                    n_points: int = 7, near_factor: float = 3.0, max_levels: int = 3) -> np.ndarray:
    """∫_S G(t, y)·q(y) dS(y) at targets t off the surface: (T, 3), q nodal (N, 3).

    Elements within near_factor × their size of a target are integrated on
    ``subdivided_rule(n_points, L)``, L = ⌈log2(near_factor·size/d)⌉ clipped to
    1..max_levels for a target at distance d (one more level per halving of d); the rest
    by the regular rule. A target on the surface itself is not supported (the rule has no
    singular treatment).
    """
    x, el = _mesh(positions, elements)
    t = np.ascontiguousarray(np.atleast_2d(targets), dtype=np.float64)
    qn = np.ascontiguousarray(q, dtype=np.float64)
    size, cen, rad = element_sizes(x, el)
    pts, strengths = point_strengths_of(x, el, qn, n_points)
    m = triangle_rule(n_points)[2].size
    # the subdivided rules of levels 1..max_levels stacked, level L in rows off[L−1]..off[L]
    xi, eta, w = (np.concatenate(c) for c in zip(*(subdivided_rule(n_points, lv) for lv in range(1, max_levels + 1))))
    phi, dxi, deta = (np.ascontiguousarray(a) for a in shape_functions(xi, eta))
    off = np.array([0] + [m * 4**lv for lv in range(1, max_levels + 1)], dtype=np.int64).cumsum()
    return _single_layer_at_kernel(t, x, el, qn, size, cen, rad, float(near_factor), int(max_levels),
                                   pts.reshape(-1, m, 3), strengths.reshape(-1, m, 3), phi, dxi, deta,
                                   np.ascontiguousarray(w), off)


def surface_integral_weights(positions: np.ndarray, elements: np.ndarray, n_points: int = 7) -> np.ndarray:
    """w_j = ∫_S φ_j dS (N,), so that ∫ f dS = Σ_j w_j f_j for a nodal field f. On flat
    elements the vertex nodes' weights vanish (∫ φ_vertex = 0 for quadratic triangles):
    only the curvature gives them a small value."""
    x, el = _mesh(positions, elements)
    _, wts, phi = _rule(x, el, *triangle_rule(n_points))
    out = np.zeros(x.shape[0])
    np.add.at(out, el.ravel(), (wts @ phi).ravel())
    return out


def nodal_normals(positions: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """The outward unit normal at each node (N, 3): the mean of the holding elements'
    normals there (∂x/∂ξ × ∂x/∂η at the node), weighted by the elements' areas."""
    x, el = _mesh(positions, elements)
    _, dxi, deta = shape_functions(NODE_XI, NODE_ETA)  # (6 nodes, 6 basis)
    xe = x[el]
    a = np.einsum("ka,ead->ekd", dxi, xe)
    b = np.einsum("ka,ead->ekd", deta, xe)
    n = np.cross(a, b)
    n /= np.linalg.norm(n, axis=2, keepdims=True)
    _, area, _ = _rule(x, el, *triangle_rule(7))
    out = np.zeros_like(x)
    np.add.at(out, el.ravel(), (n * area.sum(axis=1)[:, None, None]).reshape(-1, 3))
    return out / np.linalg.norm(out, axis=1, keepdims=True)
