"""Numba kernels: the hot loops, and nothing else.

Every kernel takes arrays and scalars and returns (or fills) arrays: no config
objects, no IO. ``parallel=True`` only on the outer loop over targets, each
iteration owning its output row. Compiled once and cached on disk (cache=True).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

_JIT = dict(cache=True, fastmath=True, error_model="numpy", boundscheck=False)


# ---------------------------------------------------------------- Stokeslet sums

@njit(inline="always")
def _columns(a):
    """The three columns of an (M, 3) array as contiguous arrays (unit-stride inner loops)."""
    return np.ascontiguousarray(a[:, 0]), np.ascontiguousarray(a[:, 1]), np.ascontiguousarray(a[:, 2])


@njit(parallel=True, **_JIT)
def stokeslet_sum(targets, sources, strengths):
    """u(x0) = Σ_m G(x_m, x0)·g_m with G = I/r + r r/r³, r = x_m − x0 (seed 2.12a).

    targets (Nt, 3), sources (M, 3), strengths (M, 3) → (Nt, 3). Coincident points
    are skipped (the caller replaces those contributions by singular rules).
    """
    nt = targets.shape[0]
    m = sources.shape[0]
    sx, sy, sz = _columns(sources)
    gx, gy, gz = _columns(strengths)
    out = np.zeros((nt, 3))
    for i in prange(nt):
        x0, y0, z0 = targets[i, 0], targets[i, 1], targets[i, 2]
        ux = 0.0
        uy = 0.0
        uz = 0.0
        for j in range(m):
            dx = sx[j] - x0
            dy = sy[j] - y0
            dz = sz[j] - z0
            r2 = dx * dx + dy * dy + dz * dz
            rinv = 1.0 / np.sqrt(r2) if r2 > 0.0 else 0.0
            rinv3 = rinv * rinv * rinv
            rg = (dx * gx[j] + dy * gy[j] + dz * gz[j]) * rinv3
            ux += gx[j] * rinv + dx * rg
            uy += gy[j] * rinv + dy * rg
            uz += gz[j] * rinv + dz * rg
        out[i, 0] = ux
        out[i, 1] = uy
        out[i, 2] = uz
    return out


@njit(inline="always")
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@njit(inline="always")
def _tangents(x, elements, e, dxi, deta, q):
    """The tangents ∂x/∂ξ, ∂x/∂η of element e at point q (rows q of the basis derivatives)."""
    ax = 0.0
    ay = 0.0
    az = 0.0
    bx = 0.0
    by = 0.0
    bz = 0.0
    for a in range(6):
        node = elements[e, a]
        ax += dxi[q, a] * x[node, 0]
        ay += dxi[q, a] * x[node, 1]
        az += dxi[q, a] * x[node, 2]
        bx += deta[q, a] * x[node, 0]
        by += deta[q, a] * x[node, 1]
        bz += deta[q, a] * x[node, 2]
    return ax, ay, az, bx, by, bz


@njit(inline="always")
def _element_point(xe, fe, e, phi, dxi, deta):
    """Position, unnormalised normal ∂x/∂ξ × ∂x/∂η and density at one rule point of
    element e, given the basis values and derivatives there (rows of 6); xe, fe:
    element-nodal positions and density (N_e, 6, 3)."""
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
        ph = phi[a]
        d1 = dxi[a]
        d2 = deta[a]
        xa = xe[e, a, 0]
        ya = xe[e, a, 1]
        za = xe[e, a, 2]
        px += ph * xa
        py += ph * ya
        pz += ph * za
        ax += d1 * xa
        ay += d1 * ya
        az += d1 * za
        bx += d2 * xa
        by += d2 * ya
        bz += d2 * za
        fx += ph * fe[e, a, 0]
        fy += ph * fe[e, a, 1]
        fz += ph * fe[e, a, 2]
    nx, ny, nz = _cross(ax, ay, az, bx, by, bz)
    return px, py, pz, nx, ny, nz, fx, fy, fz


@njit(parallel=True, **_JIT)
def wall_image_sum(targets, sources, strengths, y_wall):
    """The image part of Blake's (1971) Green's function of a no-slip plane wall y = y_wall:
    u(x) = Σ_m [G_B(x, x_m) − G(x − x_m)]·g_m, with (Blake's eq. 10, the wall normal e_y, the
    source at height h = y_m − y_wall, its image x_m' = x_m − 2h e_y, R = x − x_m', ε = diag(1, −1, 1))

        G_B = G(x − x_m) − G(R) + 2h ε_j ∂/∂R_j [h R_i/R³ − δ_iy/R − R_i R_y/R³],

    so that G_B vanishes on the wall (tests/scene/test_wall.py). Same normalisation as stokeslet_sum
    (G = I/r + r r/r³); regular wherever the sources are above the wall. targets (Nt, 3),
    sources (M, 3), strengths (M, 3) → (Nt, 3)."""
    nt = targets.shape[0]
    m = sources.shape[0]
    sx, sy, sz = _columns(sources)
    gx, gy, gz = _columns(strengths)
    out = np.zeros((nt, 3))
    for i in prange(nt):
        x0, y0, z0 = targets[i, 0], targets[i, 1], targets[i, 2]
        ux = 0.0
        uy = 0.0
        uz = 0.0
        for j in range(m):
            h = sy[j] - y_wall
            rx = x0 - sx[j]
            ry = y0 - (y_wall - h)
            rz = z0 - sz[j]
            rinv = 1.0 / np.sqrt(rx * rx + ry * ry + rz * rz)
            rinv3 = rinv * rinv * rinv
            rinv5 = rinv3 * rinv * rinv
            # − G(R)·g: the image Stokeslet
            gi_x, gi_y, gi_z = _stokeslet(rx, ry, rz, gx[j], gy[j], gz[j])
            ux -= gi_x
            uy -= gi_y
            uz -= gi_z
            # 2h B·ĝ, ĝ = ε g: the source dipole (h²) and the Stokeslet doublet (h)
            hx, hy, hz = gx[j], -gy[j], gz[j]
            rgh = rx * hx + ry * hy + rz * hz
            c = 3.0 * rgh * rinv5
            bx = h * (hx * rinv3 - rx * c) - (hx * ry + rx * hy) * rinv3 + rx * ry * c
            by = h * (hy * rinv3 - ry * c) + rgh * rinv3 - 2.0 * hy * ry * rinv3 + ry * ry * c
            bz = h * (hz * rinv3 - rz * c) - (hz * ry + rz * hy) * rinv3 + rz * ry * c
            ux += 2.0 * h * bx
            uy += 2.0 * h * by
            uz += 2.0 * h * bz
        out[i, 0] = ux
        out[i, 1] = uy
        out[i, 2] = uz
    return out


@njit(parallel=True, **_JIT)
def wall_image_double_layer(targets, sources, normals_w, u_sources, y_wall):
    """The image part of the double layer with a no-slip plane wall y = y_wall:
    D_image[u](x0) = Σ_m u_i(x_m) T^image_ijk(x_m, x0) n_k(x_m) w_m, T the stress tensor
    (−δ_ik P_j + ∂_k G_ij + ∂_i G_kj) of the image part of Blake's Green's function with its
    pole at the target x0 (height h = y0 − y_wall, image x0' = x0 − 2h e_y, R = x_m − x0',
    ε = diag(1, −1, 1)): the image Stokeslet's −T(R) plus the doublets'

        2h ε_j [(h − R_y) K_j − 6 (u·n) R_y R_j/R⁵ + 6 δ_jy (u·R)(n·R)/R⁵],
        K_j = −6 (u_j (n·R) + (u·R) n_j + (u·n) R_j)/R⁵ + 30 (u·R)(n·R) R_j/R⁷,

    from the image pressure P_j = −2R_j/R³ − 4h ε_j ∂_j(R_y/R³) (tests/scene/test_wall.py checks the
    contraction against finite differences of wall_image_sum and that pressure). Regular while
    the targets are above the wall: no desingularisation. Same arguments as double_layer_sum
    without u at the targets."""
    nt = targets.shape[0]
    m = sources.shape[0]
    sx, sy, sz = _columns(sources)
    nx, ny, nz = _columns(normals_w)
    vx, vy, vz = _columns(u_sources)
    out = np.zeros((nt, 3))
    for i in prange(nt):
        x0, y0, z0 = targets[i, 0], targets[i, 1], targets[i, 2]
        h = y0 - y_wall
        yi = y_wall - h  # the image pole's y
        ax = 0.0
        ay = 0.0
        az = 0.0
        for j in range(m):
            rx = sx[j] - x0
            ry = sy[j] - yi
            rz = sz[j] - z0
            rinv = 1.0 / np.sqrt(rx * rx + ry * ry + rz * rz)
            rinv2 = rinv * rinv
            rinv5 = rinv2 * rinv2 * rinv
            rinv7 = rinv5 * rinv2
            un = vx[j] * nx[j] + vy[j] * ny[j] + vz[j] * nz[j]
            ur = vx[j] * rx + vy[j] * ry + vz[j] * rz
            nr = nx[j] * rx + ny[j] * ry + nz[j] * rz
            # the image Stokeslet: −u·T(R)·n, T_ijk = −6 R_i R_j R_k/R⁵ (written out, not _stresslet:
            # it shares rinv5, u·R and n·R with the doublets below; through _stresslet the kernel,
            # applied at every GMRES iteration, took 10 % longer)
            c = 6.0 * ur * nr * rinv5
            ax += c * rx
            ay += c * ry
            az += c * rz
            # the doublets
            q = 30.0 * ur * nr * rinv7
            kx = -6.0 * (vx[j] * nr + ur * nx[j] + un * rx) * rinv5 + q * rx
            ky = -6.0 * (vy[j] * nr + ur * ny[j] + un * ry) * rinv5 + q * ry
            kz = -6.0 * (vz[j] * nr + ur * nz[j] + un * rz) * rinv5 + q * rz
            a = h - ry
            b = 6.0 * un * ry * rinv5
            ax += 2.0 * h * (a * kx - b * rx)
            ay -= 2.0 * h * (a * ky - b * ry + 6.0 * ur * nr * rinv5)  # ε_y = −1
            az += 2.0 * h * (a * kz - b * rz)
        out[i, 0] = ax
        out[i, 1] = ay
        out[i, 2] = az
    return out


@njit(inline="always")
def _stokeslet(dx, dy, dz, fx, fy, fz):
    """G·f = f/r + r (r·f)/r³ for r = (dx, dy, dz) (seed 2.12a)."""
    rinv = 1.0 / np.sqrt(dx * dx + dy * dy + dz * dz)
    rg = (dx * fx + dy * fy + dz * fz) * rinv * rinv * rinv
    return fx * rinv + dx * rg, fy * rinv + dy * rg, fz * rinv + dz * rg


@njit(inline="always")
def _stresslet(dx, dy, dz, mx, my, mz, vx, vy, vz):
    """v·T·m with T_ijk = −6 r_i r_j r_k / r⁵ for r = (dx, dy, dz) (seed 2.12b)."""
    rinv2 = 1.0 / (dx * dx + dy * dy + dz * dz)
    rinv = np.sqrt(rinv2)
    c = -6.0 * (dx * mx + dy * my + dz * mz) * rinv2 * rinv2 * rinv
    c *= dx * vx + dy * vy + dz * vz
    return c * dx, c * dy, c * dz


@njit(inline="always")
def _single_layer_element(x0, y0, z0, xe, fe, e, phi, dxi, deta, w, measure_w, weighted):
    """∫_e G·f dS by the rule (phi, dxi, deta (m, 6), w (m,)) on element e: f per unit area of
    the surface xe, or, if weighted, per unit rest area with measure_w (m,) the rule's weights
    times the rest shape's Jacobian."""
    ux = 0.0
    uy = 0.0
    uz = 0.0
    for j in range(w.shape[0]):
        px, py, pz, nx, ny, nz, fx, fy, fz = _element_point(xe, fe, e, phi[j], dxi[j], deta[j])
        wj = measure_w[j] if weighted else w[j] * np.sqrt(nx * nx + ny * ny + nz * nz)
        gx, gy, gz = _stokeslet(px - x0, py - y0, pz - z0, fx * wj, fy * wj, fz * wj)
        ux += gx
        uy += gy
        uz += gz
    return ux, uy, uz


@njit(inline="always")
def _single_layer_element_regular(x0, y0, z0, e, reg_points, reg_weights, reg_density):
    """The regular rule's share of element e in stokeslet_sum."""
    ux = 0.0
    uy = 0.0
    uz = 0.0
    for q in range(reg_weights.shape[1]):
        w = reg_weights[e, q]
        gx, gy, gz = _stokeslet(
            reg_points[e, q, 0] - x0, reg_points[e, q, 1] - y0, reg_points[e, q, 2] - z0,
            reg_density[e, q, 0] * w, reg_density[e, q, 1] * w, reg_density[e, q, 2] * w,
        )
        ux += gx
        uy += gy
        uz += gz
    return ux, uy, uz


@njit(inline="always")
def _double_layer_element(x0, y0, z0, u0, v0, w0, xe, ue, e, phi, dxi, deta, w):
    """∫_e (u − u0)·T·n dS by the rule (phi, dxi, deta (m, 6), w (m,)) on element e."""
    ax = 0.0
    ay = 0.0
    az = 0.0
    for j in range(w.shape[0]):
        px, py, pz, nx, ny, nz, ux, uy, uz = _element_point(xe, ue, e, phi[j], dxi[j], deta[j])
        tx, ty, tz = _stresslet(px - x0, py - y0, pz - z0, nx * w[j], ny * w[j], nz * w[j],
                                ux - u0, uy - v0, uz - w0)
        ax += tx
        ay += ty
        az += tz
    return ax, ay, az


@njit(inline="always")
def _double_layer_element_regular(x0, y0, z0, u0, v0, w0, e, reg_points, reg_normals_w, reg_u):
    """The regular rule's share of element e in double_layer_sum."""
    ax = 0.0
    ay = 0.0
    az = 0.0
    for q in range(reg_normals_w.shape[1]):
        tx, ty, tz = _stresslet(
            reg_points[e, q, 0] - x0, reg_points[e, q, 1] - y0, reg_points[e, q, 2] - z0,
            reg_normals_w[e, q, 0], reg_normals_w[e, q, 1], reg_normals_w[e, q, 2],
            reg_u[e, q, 0] - u0, reg_u[e, q, 1] - v0, reg_u[e, q, 2] - w0,
        )
        ax += tx
        ay += ty
        az += tz
    return ax, ay, az


@njit(**_JIT)
def expand_symmetric(values_at_targets, source, signs, zero):
    """Nodal vectors (N, 3) from their values at the target nodes: node j's component c is
    signs[j, c] times its orbit's target's, 0 where zero[j, c] (a symmetry that fixes j
    reverses it). One pass (numpy's gather, product and masked store took three)."""
    n = source.shape[0]
    out = np.empty((n, 3))
    for j in range(n):
        t = source[j]
        for c in range(3):
            out[j, c] = 0.0 if zero[j, c] else values_at_targets[t, c] * signs[j, c]
    return out


@njit(**_JIT)
def gather_nodal(values, elements):
    """Element-nodal copy (N_e, 6, 3) of a nodal field (N_p, 3): values[elements]."""
    return _gather(values, elements)


@njit(**_JIT)
def _gather(values, elements):
    """Element-nodal copy (N_e, 6, 3) of a nodal field, for contiguous reads."""
    ne = elements.shape[0]
    out = np.empty((ne, 6, 3))
    for e in range(ne):
        for a in range(6):
            for d in range(3):
                out[e, a, d] = values[elements[e, a], d]
    return out


# The singular corrections below run one Duffy rule per (target, incident element) pair: at
# level 3 under quarter symmetry 832 pairs × 16 points. Their layout is chosen for the
# vectoriser: the rule's basis tables by node ([k, a, q], q contiguous, made once per
# discretisation), the six element
# nodes' values in a 6×6 scratch block that the point loop only reads (no stores in it, so
# LLVM hoists the 36 values and vectorises over q), and the Stokeslet (stresslet) evaluated
# in the same loop as the interpolation. Same products and sums as _single_layer_element /
# _double_layer_element, only reassociated (the reductions over q).

#: the Duffy rule's point count for the default singular_order 2 (m = 4 n²): passed as a
#: literal so that LLVM sees a fixed trip count and vectorises the 16 points as whole
#: vectors (about 1.6x faster than the same loop with a run-time count, level 3)
_DUFFY_M = 16
#: targets per parallel chunk of the singular corrections (one scratch block each)
_CHUNK = 16


@njit(inline="always")
def _element_block(ev, x, elements, e, values, per_element):
    """Fill ev (6, 6) with element e's node positions (columns 0–2) and a field's values
    there (3–5): values (N_e, 6, 3) per element if per_element, else nodal (N_p, 3)."""
    for a in range(6):
        node = elements[e, a]
        ev[a, 0] = x[node, 0]
        ev[a, 1] = x[node, 1]
        ev[a, 2] = x[node, 2]
        if per_element:
            ev[a, 3] = values[e, a, 0]
            ev[a, 4] = values[e, a, 1]
            ev[a, 5] = values[e, a, 2]
        else:
            ev[a, 3] = values[node, 0]
            ev[a, 4] = values[node, 1]
            ev[a, 5] = values[node, 2]


@njit(inline="always")
def _block_value(ev, phi, q):
    """Position and field value at point q of a Duffy rule (table (6, m) [a, q]) from the
    element block ev (_element_block)."""
    px = 0.0
    py = 0.0
    pz = 0.0
    fx = 0.0
    fy = 0.0
    fz = 0.0
    for a in range(6):
        ph = phi[a, q]
        px += ph * ev[a, 0]
        py += ph * ev[a, 1]
        pz += ph * ev[a, 2]
        fx += ph * ev[a, 3]
        fy += ph * ev[a, 4]
        fz += ph * ev[a, 5]
    return px, py, pz, fx, fy, fz


@njit(inline="always")
def _block_point(ev, phi, dxi, deta, q):
    """_block_value and the unnormalised normal ∂x/∂ξ × ∂x/∂η at point q of a Duffy rule
    (tables (6, m) [a, q])."""
    px, py, pz, fx, fy, fz = _block_value(ev, phi, q)
    ax = 0.0
    ay = 0.0
    az = 0.0
    bx = 0.0
    by = 0.0
    bz = 0.0
    for a in range(6):
        d1 = dxi[a, q]
        d2 = deta[a, q]
        ax += d1 * ev[a, 0]
        ay += d1 * ev[a, 1]
        az += d1 * ev[a, 2]
        bx += d2 * ev[a, 0]
        by += d2 * ev[a, 1]
        bz += d2 * ev[a, 2]
    nx, ny, nz = _cross(ax, ay, az, bx, by, bz)
    return px, py, pz, nx, ny, nz, fx, fy, fz


@njit(inline="always")
def _duffy_single(x0, y0, z0, ev, phi, dxi, deta, w, m):
    """_single_layer_element over the first m points of one node's Duffy rule, from the
    element block ev (_element_block) and the tables phi, dxi, deta (6, m) [a, q]."""
    ux = 0.0
    uy = 0.0
    uz = 0.0
    for q in range(m):
        px, py, pz, nx, ny, nz, fx, fy, fz = _block_point(ev, phi, dxi, deta, q)
        wj = w[q] * np.sqrt(nx * nx + ny * ny + nz * nz)
        gx, gy, gz = _stokeslet(px - x0, py - y0, pz - z0, fx * wj, fy * wj, fz * wj)
        ux += gx
        uy += gy
        uz += gz
    return ux, uy, uz


@njit(inline="always")
def _duffy_single_weighted(x0, y0, z0, ev, phi, wj, m):
    """_duffy_single with the rule's weights times the measure's Jacobian given (wj, m):
    a density per unit area of the rest shape, whose Jacobian J0 at the Duffy points is
    a table built once (``solver.RestMeasure``), so no tangents are needed."""
    ux = 0.0
    uy = 0.0
    uz = 0.0
    for q in range(m):
        px, py, pz, fx, fy, fz = _block_value(ev, phi, q)
        w = wj[q]
        gx, gy, gz = _stokeslet(px - x0, py - y0, pz - z0, fx * w, fy * w, fz * w)
        ux += gx
        uy += gy
        uz += gz
    return ux, uy, uz


@njit(inline="always")
def _single_layer_correction_rows(
    x, elements, inc_offsets, inc_elem, inc_local, density, reg_points, reg_weights, reg_density,
    phi_by_node, dxi_by_node, deta_by_node, sing_w, measure_w, targets, lo, hi, ev, out,
):
    """Rows lo..hi−1 of single_layer_singular_correction into out (tables by node; ev a
    6×6 scratch block)."""
    m = sing_w.shape[1]
    rest = measure_w.shape[0] > 0
    for i_t in range(lo, hi):
        p = targets[i_t]
        x0, y0, z0 = x[p, 0], x[p, 1], x[p, 2]
        ox = 0.0
        oy = 0.0
        oz = 0.0
        for c in range(inc_offsets[p], inc_offsets[p + 1]):
            e = inc_elem[c]
            k = inc_local[c]
            _element_block(ev, x, elements, e, density, True)
            if rest:
                if m == _DUFFY_M:
                    sx, sy, sz = _duffy_single_weighted(x0, y0, z0, ev, phi_by_node[k], measure_w[e, k], _DUFFY_M)
                else:
                    sx, sy, sz = _duffy_single_weighted(x0, y0, z0, ev, phi_by_node[k], measure_w[e, k], m)
            elif m == _DUFFY_M:
                sx, sy, sz = _duffy_single(x0, y0, z0, ev, phi_by_node[k], dxi_by_node[k], deta_by_node[k],
                                           sing_w[k], _DUFFY_M)
            else:
                sx, sy, sz = _duffy_single(x0, y0, z0, ev, phi_by_node[k], dxi_by_node[k], deta_by_node[k],
                                           sing_w[k], m)
            rx, ry, rz = _single_layer_element_regular(x0, y0, z0, e, reg_points, reg_weights, reg_density)
            ox += sx - rx
            oy += sy - ry
            oz += sz - rz
        out[i_t, 0] = ox
        out[i_t, 1] = oy
        out[i_t, 2] = oz


@njit(parallel=True, **_JIT)
def single_layer_singular_correction(
    x, elements, inc_offsets, inc_elem, inc_local,
    density, reg_points, reg_weights, reg_density,
    phi_by_node, dxi_by_node, deta_by_node, sing_w, measure_w, targets,
):
    """Replace the regular-rule contribution of the elements holding each node by
    a Duffy-rule integral singular at that node (seed §3, "polar" treatment).

    density (N_e, 6, 3): per-element nodal values of the density (equal values for
    the element-constant traction of seed 3.7); reg_density (N_e, q, 3) the same at
    the regular points reg_points (N_e, q, 3) with weights reg_weights (N_e, q).
    *_by_node (6, 6, m) [k, a, q] and sing_w (6, m): the basis values, derivatives and
    weights of the Duffy rule for a singularity at local node k, the point index contiguous
    (``Discretization.duffy_by_node``). The density is per unit area of x's surface when
    measure_w is empty ((0, 6, m): the Jacobian at each Duffy point from x's tangents), else
    per unit area of the rest shape, measure_w (N_e, 6, m) the rule's weights times J0 at
    element e's Duffy points for its node k (``solver.RestMeasure``; reg_weights then the
    rest shape's too). Returns the correction (len(targets), 3) to add to
    ``stokeslet_sum`` evaluated at x[targets].

    The targets are taken in chunks of _CHUNK, each with its own 6×6 scratch block
    (prange over chunks: no allocation per target); each pair reads its element's nodes directly instead of an
    element-nodal copy of all positions (_gather) made for every call.
    """
    nt = targets.shape[0]
    out = np.zeros((nt, 3))
    n_chunks = (nt + _CHUNK - 1) // _CHUNK
    scratch = np.empty((n_chunks, 6, 6))
    for ch in prange(n_chunks):
        _single_layer_correction_rows(
            x, elements, inc_offsets, inc_elem, inc_local, density, reg_points, reg_weights, reg_density,
            phi_by_node, dxi_by_node, deta_by_node, sing_w, measure_w, targets, ch * _CHUNK,
            min(nt, (ch + 1) * _CHUNK), scratch[ch], out,
        )
    return out


@njit(**_JIT)
def surface_flux(elements, elems, sizes, phi, normals, weights, u):
    """∫ u·n dS of the nodal field u (N_p, 3) interpolated quadratically: Σ over the
    rule points (normals (N_e, q, 3), weights (N_e, q)) of the elements ``elems``, each
    counted sizes[i] times (all elements once, or one of each orbit of an invariant
    integrand times the orbit's size)."""
    total = 0.0
    for i in range(elems.shape[0]):
        e = elems[i]
        part = 0.0
        for q in range(phi.shape[0]):
            ux = 0.0
            uy = 0.0
            uz = 0.0
            for a in range(6):
                node = elements[e, a]
                f = phi[q, a]
                ux += f * u[node, 0]
                uy += f * u[node, 1]
                uz += f * u[node, 2]
            part += weights[e, q] * (ux * normals[e, q, 0] + uy * normals[e, q, 1] + uz * normals[e, q, 2])
        total += sizes[i] * part
    return total


@njit(**_JIT)
def point_strengths(phi, density, weights):
    """The density at the rule points (N_e, q, 3) from its element-nodal values
    (N_e, 6, 3), and the Stokeslet strengths, density × weight, as (N_e·q, 3): one pass."""
    ne = density.shape[0]
    nq = phi.shape[0]
    points = np.empty((ne, nq, 3))
    strengths = np.empty((ne * nq, 3))
    for e in range(ne):
        for q in range(nq):
            fx = 0.0
            fy = 0.0
            fz = 0.0
            for a in range(6):
                f = phi[q, a]
                fx += f * density[e, a, 0]
                fy += f * density[e, a, 1]
                fz += f * density[e, a, 2]
            points[e, q, 0] = fx
            points[e, q, 1] = fy
            points[e, q, 2] = fz
            w = weights[e, q]
            k = e * nq + q
            strengths[k, 0] = fx * w
            strengths[k, 1] = fy * w
            strengths[k, 2] = fz * w
    return points, strengths


@njit(**_JIT)
def element_quadrature(x, elements, phi, dxi, deta, w):
    """Points, outward unit normals and weight × Jacobian at each element's rule.

    phi, dxi, deta (q, 6): basis values/derivatives at the q rule points; w (q,).
    Returns points (N_e, q, 3), normals (N_e, q, 3), weights (N_e, q).
    """
    ne = elements.shape[0]
    nq = w.shape[0]
    pts = np.empty((ne, nq, 3))
    nrm = np.empty((ne, nq, 3))
    wts = np.empty((ne, nq))
    for e in range(ne):
        for q in range(nq):
            px = 0.0
            py = 0.0
            pz = 0.0
            ax = 0.0
            ay = 0.0
            az = 0.0
            bx = 0.0
            by = 0.0
            bz = 0.0
            for a in range(6):
                node = elements[e, a]
                xa = x[node, 0]
                ya = x[node, 1]
                za = x[node, 2]
                px += phi[q, a] * xa
                py += phi[q, a] * ya
                pz += phi[q, a] * za
                ax += dxi[q, a] * xa
                ay += dxi[q, a] * ya
                az += dxi[q, a] * za
                bx += deta[q, a] * xa
                by += deta[q, a] * ya
                bz += deta[q, a] * za
            nx, ny, nz = _cross(ax, ay, az, bx, by, bz)
            jac = np.sqrt(nx * nx + ny * ny + nz * nz)
            pts[e, q, 0] = px
            pts[e, q, 1] = py
            pts[e, q, 2] = pz
            nrm[e, q, 0] = nx / jac
            nrm[e, q, 1] = ny / jac
            nrm[e, q, 2] = nz / jac
            wts[e, q] = w[q] * jac
    return pts, nrm, wts


@njit(**_JIT)
def _vertex_tangents(x, elements, e, k, vdxi, vdeta, out, row):
    """The tangents ∂x/∂ξ, ∂x/∂η of element e at its vertex k into out[row], out[row + 1]."""
    for c in range(2):
        for d in range(3):
            out[row + c, d] = 0.0
    for a in range(6):
        node = elements[e, a]
        for d in range(3):
            out[row, d] += vdxi[k, a] * x[node, d]
            out[row + 1, d] += vdeta[k, a] * x[node, d]


@njit(**_JIT)
def _angle_weighted_normals(x, elements, n_vertices, vdxi, vdeta, elems, wanted, tang, angle):
    """The vertices' unit normals, each element's normal at the vertex weighted by its angle there
    (seed §3), at the ``wanted`` vertices (a mask) from the elements ``elems`` (all of each wanted
    vertex's); fills tang (N_e, 3, 2, 3) with their tangents and angle (N_e, 3) with their angles at
    the wanted vertices (an element's other corners are neither needed nor computed)."""
    normal = np.zeros((n_vertices, 3))
    wsum = np.zeros(n_vertices)
    for e in elems:
        for k in range(3):
            if not wanted[elements[e, k]]:
                continue
            _vertex_tangents(x, elements, e, k, vdxi, vdeta, tang[e, k], 0)
            t10, t11, t12 = tang[e, k, 0, 0], tang[e, k, 0, 1], tang[e, k, 0, 2]
            t20, t21, t22 = tang[e, k, 1, 0], tang[e, k, 1, 1], tang[e, k, 1, 2]
            # edge directions leaving vertex k (for the angle weight)
            if k == 0:
                e10, e11, e12 = t10, t11, t12
                e20, e21, e22 = t20, t21, t22
            elif k == 1:
                e10, e11, e12 = -t10, -t11, -t12
                e20, e21, e22 = t20 - t10, t21 - t11, t22 - t12
            else:
                e10, e11, e12 = -t20, -t21, -t22
                e20, e21, e22 = t10 - t20, t11 - t21, t12 - t22
            c0, c1, c2 = _cross(e10, e11, e12, e20, e21, e22)
            ang = np.arctan2(np.sqrt(c0 * c0 + c1 * c1 + c2 * c2), e10 * e20 + e11 * e21 + e12 * e22)
            angle[e, k] = ang
            nc0, nc1, nc2 = _cross(t10, t11, t12, t20, t21, t22)
            nn = np.sqrt(nc0 * nc0 + nc1 * nc1 + nc2 * nc2)
            v = elements[e, k]
            normal[v, 0] += ang * nc0 / nn
            normal[v, 1] += ang * nc1 / nn
            normal[v, 2] += ang * nc2 / nn
            wsum[v] += ang
    for v in range(n_vertices):
        a = np.sqrt(normal[v, 0] ** 2 + normal[v, 1] ** 2 + normal[v, 2] ** 2)
        if a > 0.0:  # a vertex none of whose elements is in elems keeps a zero normal (never read)
            for d in range(3):
                normal[v, d] /= a
    return normal, wsum


@njit(inline="always")
def _project_tangents(tangents, normal, out):
    """The two tangents (rows of ``tangents``) less their components along the unit ``normal``, as the
    first two columns of ``out`` (a vertex's tangent plane: seed 3.4)."""
    for col in range(2):
        s = 0.0
        for d in range(3):
            s += tangents[col, d] * normal[d]
        for d in range(3):
            out[d, col] = tangents[col, d] - s * normal[d]


@njit(**_JIT)
def vertex_rest_inverse(X, elements, n_vertices, vdxi, vdeta):
    """The rest shape's part of the vertex deformation gradient (seed 3.4), made once per rest
    shape: per element and vertex, the first two rows of R⁻¹, R = [T1 T2 N] with the rest tangents
    T1, T2 projected on the vertex's rest tangent plane (angle-weighted normal N). Returns
    (N_e, 3, 2, 3) and the rest normals N (N_v, 3)."""
    ne = elements.shape[0]
    tang = np.empty((ne, 3, 2, 3))
    angle = np.empty((ne, 3))
    n_ref, _ = _angle_weighted_normals(X, elements, n_vertices, vdxi, vdeta, np.arange(ne),
                                       np.ones(n_vertices, dtype=np.bool_), tang, angle)
    out = np.empty((ne, 3, 2, 3))
    R = np.empty((3, 3))
    for e in range(ne):
        for k in range(3):
            v = elements[e, k]
            _project_tangents(tang[e, k], n_ref[v], R)
            for d in range(3):
                R[d, 2] = n_ref[v, d]
            # explicit inverse of R = [T1 T2 N]: rows are (T2×N, N×T1, T1×T2)/det
            r0 = _cross(R[0, 1], R[1, 1], R[2, 1], R[0, 2], R[1, 2], R[2, 2])
            r1 = _cross(R[0, 2], R[1, 2], R[2, 2], R[0, 0], R[1, 0], R[2, 0])
            det = R[0, 0] * r0[0] + R[1, 0] * r0[1] + R[2, 0] * r0[2]
            for d in range(3):
                out[e, k, 0, d] = r0[d] / det
                out[e, k, 1, d] = r1[d] / det
    return out, n_ref


@njit(**_JIT)
def vertex_strain(x, elements, n_vertices, vdxi, vdeta, rest_inverse, elems, vertices):
    """Surface deformation gradient A at the vertex nodes ``vertices`` (seed 3.4) and its strain.

    Per element and vertex, A maps the reference tangents ∂X/∂ξ, ∂X/∂η to the current ones and
    the reference normal to 0: A_e = [t1 t2 0] R⁻¹ (``rest_inverse``: R⁻¹'s first two rows, from
    :func:`vertex_rest_inverse`). The element values are averaged at each vertex weighted by the
    element's angle there (seed §3). The current tangents are first projected on the nodal tangent
    planes (angle-weighted normals), so a rest or rigidly rotated mesh gives A = rotation ×
    projection exactly. With it the left Cauchy–Green tensor B = A Aᵀ and the invariants
    Λ1 = ½ ln det₂ B, Λ2 = ½ tr B − 1 (membrane.strain_from_gradient's, in the same pass).

    ``elems`` must hold every element of each of ``vertices`` (all elements and all vertices: the
    whole membrane; a symmetric configuration's orbit representatives: a quarter of the work).
    vdxi, vdeta (3, 6): basis derivatives at the three vertices.
    Returns, at ``vertices``: A (n, 3, 3), current normals (n, 3), B (n, 3, 3), Λ1 (n), Λ2 (n), the
    principal stretches λ1 ≥ λ2 (n each).
    """
    ne = elements.shape[0]
    tang = np.empty((ne, 3, 2, 3))
    angle = np.empty((ne, 3))
    slot = np.full(n_vertices, -1, dtype=np.int64)  # each vertex's row in the outputs
    for i in range(vertices.shape[0]):
        slot[vertices[i]] = i
    n_cur, wsum = _angle_weighted_normals(x, elements, n_vertices, vdxi, vdeta, elems, slot >= 0, tang, angle)
    m = vertices.shape[0]
    A = np.zeros((m, 3, 3))
    C = np.empty((3, 2))
    for e in elems:
        for k in range(3):
            v = elements[e, k]
            row = slot[v]
            if row < 0:
                continue
            _project_tangents(tang[e, k], n_cur[v], C)  # on the nodal tangent plane
            w = angle[e, k] / wsum[v]
            for i in range(3):
                for j in range(3):
                    A[row, i, j] += w * (C[i, 0] * rest_inverse[e, k, 0, j] + C[i, 1] * rest_inverse[e, k, 1, j])
    normals = np.empty((m, 3))
    B = np.empty((m, 3, 3))
    inv1 = np.empty(m)
    inv2 = np.empty(m)
    stretch1 = np.empty(m)
    stretch2 = np.empty(m)
    for r in range(m):
        for d in range(3):
            normals[r, d] = n_cur[vertices[r], d]
        tr = 0.0
        for i in range(3):
            for j in range(3):
                b = 0.0
                for k in range(3):
                    b += A[r, i, k] * A[r, j, k]
                B[r, i, j] = b
            tr += B[r, i, i]
        tr2 = 0.0
        for i in range(3):
            for j in range(3):
                tr2 += B[r, i, j] * B[r, j, i]
        det = 0.5 * (tr * tr - tr2)  # det₂ B = λ1²λ2²: B has rank 2 by construction
        inv1[r] = 0.5 * np.log(det)
        inv2[r] = 0.5 * tr - 1.0
        # the principal stretches (VertexStrain.principal_stretches' formulas): λ1² − λ2² from B's
        # deviator in the tangent plane, √(2 |B − (tr B / 2)(I − n n)|²), accurate where the two are near
        # equal (tr² − 4 det loses half the digits there: 1e-8 of noise at rest)
        half = 0.5 * tr
        dev = 0.0
        for i in range(3):
            for j in range(3):
                p = (1.0 if i == j else 0.0) - normals[r, i] * normals[r, j]
                dij = B[r, i, j] - half * p
                dev += dij * dij
        disc = np.sqrt(2.0 * dev)
        stretch1[r] = np.sqrt(0.5 * (tr + disc))
        stretch2[r] = np.sqrt(max(0.5 * (tr - disc), 0.0))
    return A, normals, B, inv1, inv2, stretch1, stretch2


@njit(parallel=True, **_JIT)
def element_tractions(x, elements, vertex_tension, s_gl, w_gl, areas):
    """Element-averaged traction jump <Δf>_e = −(1/S_e) ∮ T·b dl (seed 3.6).

    T is interpolated linearly along each curved edge from its two vertex values
    (the seed found quadratic interpolation unstable); b = t × n is the outward
    conormal, n the element normal at the edge point. Returns (N_e, 3).
    """
    ne = elements.shape[0]
    out = np.zeros((ne, 3))
    # edges as (vertex a, mid node, vertex b); parametric points ξ(s), η(s)
    ea = (0, 1, 2)
    em = (3, 4, 5)
    eb = (1, 2, 0)
    for e in prange(ne):
        fx = 0.0
        fy = 0.0
        fz = 0.0
        for edge in range(3):
            la = ea[edge]
            lm = em[edge]
            lb = eb[edge]
            va = elements[e, la]
            vm = elements[e, lm]
            vb = elements[e, lb]
            for g in range(s_gl.shape[0]):
                s = s_gl[g]
                if edge == 0:
                    xi = s
                    eta = 0.0
                elif edge == 1:
                    xi = 1.0 - s
                    eta = s
                else:
                    xi = 0.0
                    eta = 1.0 - s
                # edge tangent dx/ds (1-D quadratic Lagrange along the edge)
                ca = 4.0 * s - 3.0
                cm = 4.0 - 8.0 * s
                cb = 4.0 * s - 1.0
                tx = ca * x[va, 0] + cm * x[vm, 0] + cb * x[vb, 0]
                ty = ca * x[va, 1] + cm * x[vm, 1] + cb * x[vb, 1]
                tz = ca * x[va, 2] + cm * x[vm, 2] + cb * x[vb, 2]
                # element normal at (ξ, η)
                z = 1.0 - xi - eta
                d1 = (-(4 * z - 1), 4 * xi - 1, 0.0, 4 * (z - xi), 4 * eta, -4 * eta)
                d2 = (-(4 * z - 1), 0.0, 4 * eta - 1, -4 * xi, 4 * xi, 4 * (z - eta))
                ax = 0.0
                ay = 0.0
                az = 0.0
                bx = 0.0
                by = 0.0
                bz = 0.0
                for a in range(6):
                    node = elements[e, a]
                    ax += d1[a] * x[node, 0]
                    ay += d1[a] * x[node, 1]
                    az += d1[a] * x[node, 2]
                    bx += d2[a] * x[node, 0]
                    by += d2[a] * x[node, 1]
                    bz += d2[a] * x[node, 2]
                nx, ny, nz = _cross(ax, ay, az, bx, by, bz)
                nn = np.sqrt(nx * nx + ny * ny + nz * nz)
                nx /= nn
                ny /= nn
                nz /= nn
                # b dl = (dx/ds × n) ds
                b0, b1, b2 = _cross(tx, ty, tz, nx, ny, nz)
                w = w_gl[g]
                for i in range(3):
                    Ti0 = (1.0 - s) * vertex_tension[va, i, 0] + s * vertex_tension[vb, i, 0]
                    Ti1 = (1.0 - s) * vertex_tension[va, i, 1] + s * vertex_tension[vb, i, 1]
                    Ti2 = (1.0 - s) * vertex_tension[va, i, 2] + s * vertex_tension[vb, i, 2]
                    val = w * (Ti0 * b0 + Ti1 * b1 + Ti2 * b2)
                    if i == 0:
                        fx += val
                    elif i == 1:
                        fy += val
                    else:
                        fz += val
        out[e, 0] = -fx / areas[e]
        out[e, 1] = -fy / areas[e]
        out[e, 2] = -fz / areas[e]
    return out


# ---------------------------------------------------------------- Galerkin membrane forces

@njit(**_JIT)
def rest_metric(X, elements, dxi, deta):
    """The reference (rest-shape) metric at the Gauss points, built once per run: the
    inverse metric G^{11}, G^{12}, G^{22} of the covariant tangents T_a = ∂X/∂ξ_a and the
    reference area element J0 = √det G, as (N_e, q, 4)."""
    ne = elements.shape[0]
    nq = dxi.shape[0]
    out = np.empty((ne, nq, 4))
    for e in range(ne):
        for q in range(nq):
            A0, A1, A2, B0, B1, B2 = _tangents(X, elements, e, dxi, deta, q)
            G11 = A0 * A0 + A1 * A1 + A2 * A2
            G12 = A0 * B0 + A1 * B1 + A2 * B2
            G22 = B0 * B0 + B1 * B1 + B2 * B2
            detG = G11 * G22 - G12 * G12
            out[e, q, 0] = G22 / detG
            out[e, q, 1] = -G12 / detG
            out[e, q, 2] = G11 / detG
            out[e, q, 3] = np.sqrt(detG)
    return out


@njit(parallel=True, **_JIT)
def gauss_point_strain(x, elements, elems, dxi, deta, rest):
    """Strain invariants and dual tangent vectors at the Gauss points of the elements
    ``elems`` (indices into ``elements``; all of them, or under a symmetry those holding a
    target node), with the rest shape's metric ``rest`` from ``rest_metric``.

    With covariant tangents t_a = ∂x/∂ξ_a (current) and T_a (reference), metrics
    g_ab = t_a·t_b and G_ab = T_a·T_b:  λ1²λ2² = det g / det G,
    λ1² + λ2² = G^{ab} g_ab. Returns Λ1, Λ2 (len(elems), q), the current dual basis
    t^a = g^{ab} t_b and the "reference-dual" vectors G^{ab} t_b (len(elems), q, 2, 3),
    and the reference area element J0 (len(elems), q).
    """
    ne = elems.shape[0]
    nq = dxi.shape[0]
    inv1 = np.empty((ne, nq))
    inv2 = np.empty((ne, nq))
    dual_cur = np.empty((ne, nq, 2, 3))
    dual_ref = np.empty((ne, nq, 2, 3))
    jac0 = np.empty((ne, nq))
    for i in prange(ne):
        e = elems[i]
        for q in range(nq):
            a0, a1, a2, b0, b1, b2 = _tangents(x, elements, e, dxi, deta, q)
            g11 = a0 * a0 + a1 * a1 + a2 * a2
            g12 = a0 * b0 + a1 * b1 + a2 * b2
            g22 = b0 * b0 + b1 * b1 + b2 * b2
            detg = g11 * g22 - g12 * g12
            # inverse metrics
            gi11 = g22 / detg
            gi12 = -g12 / detg
            gi22 = g11 / detg
            Gi11 = rest[e, q, 0]
            Gi12 = rest[e, q, 1]
            Gi22 = rest[e, q, 2]
            J0 = rest[e, q, 3]
            inv1[i, q] = 0.5 * np.log(detg / (J0 * J0))
            inv2[i, q] = 0.5 * (Gi11 * g11 + 2.0 * Gi12 * g12 + Gi22 * g22) - 1.0
            dual_cur[i, q, 0, 0] = gi11 * a0 + gi12 * b0
            dual_cur[i, q, 0, 1] = gi11 * a1 + gi12 * b1
            dual_cur[i, q, 0, 2] = gi11 * a2 + gi12 * b2
            dual_cur[i, q, 1, 0] = gi12 * a0 + gi22 * b0
            dual_cur[i, q, 1, 1] = gi12 * a1 + gi22 * b1
            dual_cur[i, q, 1, 2] = gi12 * a2 + gi22 * b2
            dual_ref[i, q, 0, 0] = Gi11 * a0 + Gi12 * b0
            dual_ref[i, q, 0, 1] = Gi11 * a1 + Gi12 * b1
            dual_ref[i, q, 0, 2] = Gi11 * a2 + Gi12 * b2
            dual_ref[i, q, 1, 0] = Gi12 * a0 + Gi22 * b0
            dual_ref[i, q, 1, 1] = Gi12 * a1 + Gi22 * b1
            dual_ref[i, q, 1, 2] = Gi12 * a2 + Gi22 * b2
            jac0[i, q] = J0
    return inv1, inv2, dual_cur, dual_ref, jac0


@njit(**_JIT)
def galerkin_energy_gradient(elements, elems, n_nodes, dxi, deta, w, jac0, w1, w2, dual_cur, dual_ref):
    """b_i = ∂E/∂x_i = ∫ φ_i Δf dA for E = Σ_e ∫ W(Λ1, Λ2) dA_0, summed over the elements
    ``elems`` (the Gauss-point arrays are theirs, from ``gauss_point_strain``): complete at
    every node all of whose elements are in ``elems``.

    ∂Λ1/∂t_a = g^{ab} t_b and ∂Λ2/∂t_a = G^{ab} t_b, with t_a = Σ_i ∂φ_i/∂ξ_a x_i.
    Returns (N_p, 3).
    """
    ne = elems.shape[0]
    nq = w.shape[0]
    out = np.zeros((n_nodes, 3))
    for i in range(ne):
        e = elems[i]
        for q in range(nq):
            s = w[q] * jac0[i, q]
            c1 = s * w1[i, q]
            c2 = s * w2[i, q]
            v00 = c1 * dual_cur[i, q, 0, 0] + c2 * dual_ref[i, q, 0, 0]
            v01 = c1 * dual_cur[i, q, 0, 1] + c2 * dual_ref[i, q, 0, 1]
            v02 = c1 * dual_cur[i, q, 0, 2] + c2 * dual_ref[i, q, 0, 2]
            v10 = c1 * dual_cur[i, q, 1, 0] + c2 * dual_ref[i, q, 1, 0]
            v11 = c1 * dual_cur[i, q, 1, 1] + c2 * dual_ref[i, q, 1, 1]
            v12 = c1 * dual_cur[i, q, 1, 2] + c2 * dual_ref[i, q, 1, 2]
            for k in range(6):
                node = elements[e, k]
                d1 = dxi[q, k]
                d2 = deta[q, k]
                out[node, 0] += d1 * v00 + d2 * v10
                out[node, 1] += d1 * v01 + d2 * v11
                out[node, 2] += d1 * v02 + d2 * v12
    return out


@njit(**_JIT)
def assemble_mass_matrix(elems, csr_slot, phi, weights, nnz):
    """Values of the consistent mass matrix M_ij = ∫ φ_i φ_j dA in a fixed CSR
    pattern, summed over the elements ``elems`` (all, or those holding a target node: then
    the rows of the target nodes are complete); csr_slot (N_e, 6, 6) maps element pairs
    to CSR positions."""
    data = np.zeros(nnz)
    nq = phi.shape[0]
    for i in range(elems.shape[0]):
        e = elems[i]
        for k in range(6):
            # the element matrix is symmetric: each pair once (the same products, the same bits)
            for l in range(k, 6):
                s = 0.0
                for q in range(nq):
                    s += phi[q, k] * phi[q, l] * weights[e, q]
                data[csr_slot[e, k, l]] += s
                if l != k:
                    data[csr_slot[e, l, k]] += s
    return data


@njit(**_JIT)
def _csr_matmul(indptr, indices, data, v, out):
    n = out.shape[0]
    m = out.shape[1]
    for i in range(n):
        for c in range(m):
            out[i, c] = 0.0
        for p in range(indptr[i], indptr[i + 1]):
            a = data[p]
            j = indices[p]
            for c in range(m):
                out[i, c] += a * v[j, c]


@njit(**_JIT)
def block_cg(indptr, indices, data, rhs, x0, tol, max_iter):
    """Jacobi-preconditioned conjugate gradients for an SPD CSR matrix and
    several right-hand sides (columns of rhs) at once; stops when every column's
    residual is below tol·max‖rhs‖. Returns (x, iterations)."""
    n = rhs.shape[0]
    m = rhs.shape[1]
    dinv = np.empty(n)
    for i in range(n):
        for p in range(indptr[i], indptr[i + 1]):
            if indices[p] == i:
                dinv[i] = 1.0 / data[p]
    x = x0.copy()
    Ap = np.empty((n, m))
    _csr_matmul(indptr, indices, data, x, Ap)
    r = rhs - Ap
    z = np.empty((n, m))
    for i in range(n):
        for c in range(m):
            z[i, c] = r[i, c] * dinv[i]
    pvec = z.copy()
    rz = np.zeros(m)
    bmax = 0.0
    for i in range(n):
        for c in range(m):
            rz[c] += r[i, c] * z[i, c]
            bmax = max(bmax, abs(rhs[i, c]))
    thresh = tol * (bmax + 1e-300)
    it = 0
    pAp = np.zeros(m)
    alpha = np.zeros(m)
    rz_new = np.zeros(m)
    while it < max_iter:
        rmax = 0.0
        for i in range(n):
            for c in range(m):
                rmax = max(rmax, abs(r[i, c]))
        if rmax <= thresh:
            break
        _csr_matmul(indptr, indices, data, pvec, Ap)
        pAp[:] = 0.0
        for i in range(n):
            for c in range(m):
                pAp[c] += pvec[i, c] * Ap[i, c]
        for c in range(m):
            alpha[c] = rz[c] / pAp[c] if pAp[c] != 0.0 else 0.0
        rz_new[:] = 0.0
        for i in range(n):
            for c in range(m):
                x[i, c] += alpha[c] * pvec[i, c]
                r[i, c] -= alpha[c] * Ap[i, c]
                z[i, c] = r[i, c] * dinv[i]
                rz_new[c] += r[i, c] * z[i, c]
        for c in range(m):
            beta = rz_new[c] / rz[c] if rz[c] != 0.0 else 0.0
            rz[c] = rz_new[c]
            for i in range(n):
                pvec[i, c] = z[i, c] + beta * pvec[i, c]
        it += 1
    return x, it


@njit(**_JIT)
def _csr_matvec(indptr, indices, data, v, out):
    """out = A v for one vector (a row's sum in a register: ~3× faster than the block
    product _csr_matmul with one column, which stores into out at every entry)."""
    for i in range(out.shape[0]):
        s = 0.0
        for p in range(indptr[i], indptr[i + 1]):
            s += data[p] * v[indices[p]]
        out[i] = s


@njit(**_JIT)
def _factor_solve(r, z, w, l_indptr, l_indices, l_data, u_indptr, u_indices, u_data, u_dinv, perm_r, perm_c,
                  scale):
    """z = S A0⁻¹ S r for Pr A0 Pc = L U (scipy's splu) and S = diag(scale): the strictly
    lower part of the unit lower L and the strictly upper part of U by columns (CSC), U's
    inverse diagonal, both permutations; w is workspace. Vectors of length n. By columns
    each entry is an independent update of w (a row-wise solve chains every entry of a row
    through one sum: 1.5× slower here)."""
    n = r.shape[0]
    for i in range(n):
        w[perm_r[i]] = r[i] * scale[i]
    for j in range(n):
        wj = w[j]
        for p in range(l_indptr[j], l_indptr[j + 1]):
            w[l_indices[p]] -= l_data[p] * wj
    for j in range(n - 1, -1, -1):
        wj = w[j] * u_dinv[j]
        w[j] = wj
        for p in range(u_indptr[j], u_indptr[j + 1]):
            w[u_indices[p]] -= u_data[p] * wj
    for i in range(n):
        z[i] = w[perm_c[i]] * scale[i]


@njit(**_JIT)
def asymmetry(x, col, sign, target_node):
    """max over nodes and components of |x[j, c] − sign[j, c]·x[its target, c]| (|x[j, c]|
    where the symmetry forces it to zero): 0 for a configuration with the symmetry."""
    worst = 0.0
    for j in range(x.shape[0]):
        for c in range(3):
            u = col[j, c]
            if u >= 0:
                d = abs(x[j, c] - sign[j, c] * x[target_node[u], c])
            else:
                d = abs(x[j, c])
            worst = max(worst, d)
    return worst


@njit(**_JIT)
def solve_reduced_mass(indptr, indices, data, b, last, col, sign, target_node, target_comp, inv_mult, tol,
                       max_iter, l_indptr, l_indices, l_data, u_indptr, u_indices, u_data, u_dinv, perm_r, perm_c,
                       diag0, diag_slot):
    """Δf (N, 3) with M Δf = rhs for an equivariant rhs, solved as K y = b = Eᵀ rhs
    (``reduce_rhs_at_targets``: from the target nodes' rows) with Δf = E y (E: the unknown
    y[col[j, c]] of node j, component c, times sign[j, c]; 0 where col is −1), K = Eᵀ (M ⊗ I₃) E in CSR (indptr, indices, data; diag_slot: the
    position of each row's diagonal entry). Conjugate gradients from y = the targets'
    values of ``last``, preconditioned by S K0⁻¹ S with K0 = L U the exact factorisation
    of a nearby K (``_factor_solve``) and S = diag(√(diag K0 / diag K)): the scaling
    takes up the local change of area since K0 (K ≈ S⁻¹ K0 S⁻¹ when each node's
    neighbourhood dilates uniformly), which the factor alone does not see; measured at
    level 3, it keeps the solve at 2-3 iterations over a strain of 0.3 without a new
    factor (without it 3-5 and a refactorisation every ~100 evaluations). With K = K0
    the first iteration solves. Stops when max|r| ≤ tol·max|rhs| over the nodes (Eᵀ
    sums an orbit: its row u is the node's value times the orbit's size, 1/inv_mult[u]).
    Returns (Δf, iterations)."""
    n = target_node.shape[0]
    y = np.empty(n)
    for u in range(n):
        y[u] = last[target_node[u], target_comp[u]]
    Ap = np.empty(n)
    _csr_matvec(indptr, indices, data, y, Ap)
    r = b - Ap
    bmax = 0.0
    rmax = 0.0
    for u in range(n):
        bmax = max(bmax, abs(b[u]) * inv_mult[u])
        rmax = max(rmax, abs(r[u]) * inv_mult[u])
    thresh = tol * (bmax + 1e-300)
    it = 0
    if rmax > thresh:
        scale = np.empty(n)
        for u in range(n):
            scale[u] = np.sqrt(diag0[u] / data[diag_slot[u]])
        w = np.empty(n)
        z = np.empty(n)
        _factor_solve(r, z, w, l_indptr, l_indices, l_data, u_indptr, u_indices, u_data, u_dinv, perm_r, perm_c,
                      scale)
        pvec = z.copy()
        rz = 0.0
        for u in range(n):
            rz += r[u] * z[u]
        while it < max_iter:
            _csr_matvec(indptr, indices, data, pvec, Ap)
            pAp = 0.0
            for u in range(n):
                pAp += pvec[u] * Ap[u]
            alpha = rz / pAp if pAp != 0.0 else 0.0
            rmax = 0.0
            for u in range(n):
                y[u] += alpha * pvec[u]
                r[u] -= alpha * Ap[u]
                rmax = max(rmax, abs(r[u]) * inv_mult[u])
            it += 1
            if rmax <= thresh:
                break
            _factor_solve(r, z, w, l_indptr, l_indices, l_data, u_indptr, u_indices, u_data, u_dinv, perm_r,
                          perm_c, scale)
            rz_new = 0.0
            for u in range(n):
                rz_new += r[u] * z[u]
            beta = rz_new / rz if rz != 0.0 else 0.0
            rz = rz_new
            for u in range(n):
                pvec[u] = z[u] + beta * pvec[u]
    return _expand_reduced(y, col, sign), it


@njit(inline="always")
def _expand_reduced(y, col, sign):
    """Δf = E y (N, 3): node j's component c is sign[j, c]·y[col[j, c]], 0 where col is −1."""
    out = np.zeros(col.shape)
    for j in range(col.shape[0]):
        for c in range(3):
            u = col[j, c]
            if u >= 0:
                out[j, c] = sign[j, c] * y[u]
    return out


@njit(**_JIT)
def solve_reduced_direct(rhs, target_node, target_comp, inv_mult, col, sign, l_indptr, l_indices, l_data, u_indptr,
                         u_indices, u_data, u_dinv, perm_r, perm_c):
    """Δf (N, 3) with M Δf = rhs for an equivariant rhs by the exact factorisation of
    K = Eᵀ (M ⊗ I₃) E (``membrane.MassFactor``): b = Eᵀ rhs from the target nodes' rows
    (``reduce_rhs_at_targets``), y = K⁻¹ b (``_factor_solve``), Δf = E y."""
    b = reduce_rhs_at_targets(rhs, target_node, target_comp, inv_mult)
    n = b.shape[0]
    y = np.empty(n)
    _factor_solve(b, y, np.empty(n), l_indptr, l_indices, l_data, u_indptr, u_indices, u_data, u_dinv, perm_r,
                  perm_c, np.ones(n))
    return _expand_reduced(y, col, sign)


@njit(**_JIT)
def reduce_rhs_at_targets(rhs, target_node, target_comp, inv_mult):
    """b = Eᵀ rhs for an equivariant rhs from the target nodes' rows alone: each of an
    orbit's 1/inv_mult[u] terms of Eᵀ rhs equals the target's value (so rows elsewhere
    need not be computed)."""
    n = target_node.shape[0]
    b = np.empty(n)
    for u in range(n):
        b[u] = rhs[target_node[u], target_comp[u]] / inv_mult[u]
    return b


@njit(**_JIT)
def reduced_mass_data_rows(data, entries, slot, weight, nnz):
    """Values of K = Eᵀ (M ⊗ I₃) E from the rows of M at the target nodes alone (M's values
    elsewhere need not be assembled): entry entries[i] of M, for each component c with
    slot[i, c] ≥ 0, goes to slot[i, c] times weight[i, c] (its sign times the orbit's size:
    by the symmetry each row of an orbit contributes what the target's row does)."""
    out = np.zeros(nnz)
    for i in range(entries.shape[0]):
        a = data[entries[i]]
        for c in range(3):
            k = slot[i, c]
            if k >= 0:
                out[k] += weight[i, c] * a
    return out


# ---------------------------------------------------------------- double layer

@njit(parallel=True, **_JIT)
def double_layer_sum(targets, u_targets, sources, normals_w, u_sources):
    """D(x0) = Σ_m (u_m − u0)·T(x_m, x0)·n_m w_m with T_ijk = −6 r_i r_j r_k / r⁵,
    r = x_m − x0 (seed 2.12b), desingularised by subtracting u0 = u(x0).

    normals_w (M, 3): normal × weight at each source point; u_sources (M, 3).
    Coincident points are skipped (their elements are handled by the caller).
    """
    nt = targets.shape[0]
    m = sources.shape[0]
    sx, sy, sz = _columns(sources)
    nx, ny, nz = _columns(normals_w)
    vx, vy, vz = _columns(u_sources)
    out = np.zeros((nt, 3))
    for i in prange(nt):
        x0 = targets[i, 0]
        y0 = targets[i, 1]
        z0 = targets[i, 2]
        u0 = u_targets[i, 0]
        v0 = u_targets[i, 1]
        w0 = u_targets[i, 2]
        ax = 0.0
        ay = 0.0
        az = 0.0
        for j in range(m):
            dx = sx[j] - x0
            dy = sy[j] - y0
            dz = sz[j] - z0
            r2 = dx * dx + dy * dy + dz * dz
            rinv = 1.0 / np.sqrt(r2) if r2 > 0.0 else 0.0
            rinv2 = rinv * rinv
            c = -6.0 * (dx * nx[j] + dy * ny[j] + dz * nz[j]) * rinv2 * rinv2 * rinv
            c *= dx * (vx[j] - u0) + dy * (vy[j] - v0) + dz * (vz[j] - w0)
            ax += c * dx
            ay += c * dy
            az += c * dz
        out[i, 0] = ax
        out[i, 1] = ay
        out[i, 2] = az
    return out


@njit(inline="always")
def _duffy_double(x0, y0, z0, u0, v0, w0, ev, phi, dxi, deta, w, m):
    """_double_layer_element over the first m points of one node's Duffy rule, from the
    element block ev (positions and nodal u, _element_block) and the tables (6, m) [a, q]."""
    tx = 0.0
    ty = 0.0
    tz = 0.0
    for q in range(m):
        px, py, pz, nx, ny, nz, ux, uy, uz = _block_point(ev, phi, dxi, deta, q)
        wq = w[q]
        gx, gy, gz = _stresslet(px - x0, py - y0, pz - z0, nx * wq, ny * wq, nz * wq, ux - u0, uy - v0, uz - w0)
        tx += gx
        ty += gy
        tz += gz
    return tx, ty, tz


@njit(inline="always")
def _double_layer_correction_rows(
    x, u, u_target, elements, inc_offsets, inc_elem, inc_local, reg_points, reg_normals_w, reg_u,
    phi_by_node, dxi_by_node, deta_by_node, sing_w, targets, lo, hi, ev, out,
):
    """Rows lo..hi−1 of double_layer_singular_correction into out (tables by node; ev a
    6×6 scratch block)."""
    m = sing_w.shape[1]
    for i_t in range(lo, hi):
        p = targets[i_t]
        x0, y0, z0 = x[p, 0], x[p, 1], x[p, 2]
        u0, v0, w0 = u_target[p, 0], u_target[p, 1], u_target[p, 2]
        ox = 0.0
        oy = 0.0
        oz = 0.0
        for c in range(inc_offsets[p], inc_offsets[p + 1]):
            e = inc_elem[c]
            k = inc_local[c]
            _element_block(ev, x, elements, e, u, False)
            if m == _DUFFY_M:
                sx, sy, sz = _duffy_double(x0, y0, z0, u0, v0, w0, ev, phi_by_node[k], dxi_by_node[k],
                                           deta_by_node[k], sing_w[k], _DUFFY_M)
            else:
                sx, sy, sz = _duffy_double(x0, y0, z0, u0, v0, w0, ev, phi_by_node[k], dxi_by_node[k],
                                           deta_by_node[k], sing_w[k], m)
            rx, ry, rz = _double_layer_element_regular(x0, y0, z0, u0, v0, w0, e, reg_points, reg_normals_w, reg_u)
            ox += sx - rx
            oy += sy - ry
            oz += sz - rz
        out[i_t, 0] = ox
        out[i_t, 1] = oy
        out[i_t, 2] = oz


@njit(parallel=True, **_JIT)
def double_layer_singular_correction(
    x, u, u_target, elements, inc_offsets, inc_elem, inc_local,
    reg_points, reg_normals_w, reg_u,
    phi_by_node, dxi_by_node, deta_by_node, sing_w, targets,
):
    """Replace the regular-rule double-layer contribution of the elements
    holding each node by the Duffy rule singular at that node. The desingularised
    integrand (u − u0)·T·n is bounded but not smooth there. u: nodal values of
    the density; u_target: the value u0 subtracted at each node (normally u).
    Returns (len(targets), 3). Laid out as single_layer_singular_correction."""
    nt = targets.shape[0]
    out = np.zeros((nt, 3))
    n_chunks = (nt + _CHUNK - 1) // _CHUNK
    scratch = np.empty((n_chunks, 6, 6))
    for ch in prange(n_chunks):
        _double_layer_correction_rows(
            x, u, u_target, elements, inc_offsets, inc_elem, inc_local, reg_points, reg_normals_w, reg_u,
            phi_by_node, dxi_by_node, deta_by_node, sing_w, targets, ch * _CHUNK,
            min(nt, (ch + 1) * _CHUNK), scratch[ch], out,
        )
    return out


@njit(**_JIT)
def nodal_unit_normals(x, elements, node_dxi, node_deta):
    """Unit normals at all nodes: the mean of the normals of the elements holding
    each node, each evaluated at the node (node_dxi, node_deta: (6, 6) basis
    derivatives at the six element nodes)."""
    n_nodes = x.shape[0]
    acc = np.zeros((n_nodes, 3))
    for e in range(elements.shape[0]):
        for k in range(6):
            ax, ay, az, bx, by, bz = _tangents(x, elements, e, node_dxi, node_deta, k)
            nx, ny, nz = _cross(ax, ay, az, bx, by, bz)
            s = 1.0 / np.sqrt(nx * nx + ny * ny + nz * nz)
            v = elements[e, k]
            acc[v, 0] += nx * s
            acc[v, 1] += ny * s
            acc[v, 2] += nz * s
    for v in range(n_nodes):
        s = 1.0 / np.sqrt(acc[v, 0] ** 2 + acc[v, 1] ** 2 + acc[v, 2] ** 2)
        acc[v, 0] *= s
        acc[v, 1] *= s
        acc[v, 2] *= s
    return acc


@njit(**_JIT)
def target_unit_normals(x, elements, inc_offsets, inc_elem, inc_local, node_dxi, node_deta, targets):
    """``nodal_unit_normals`` at the target nodes only (len(targets), 3), from the elements
    holding each (in element order, as there: the same bits)."""
    out = np.zeros((targets.shape[0], 3))
    for i in range(targets.shape[0]):
        p = targets[i]
        sx = 0.0
        sy = 0.0
        sz = 0.0
        for c in range(inc_offsets[p], inc_offsets[p + 1]):
            ax, ay, az, bx, by, bz = _tangents(x, elements, inc_elem[c], node_dxi, node_deta, inc_local[c])
            nx, ny, nz = _cross(ax, ay, az, bx, by, bz)
            s = 1.0 / np.sqrt(nx * nx + ny * ny + nz * nz)
            sx += nx * s
            sy += ny * s
            sz += nz * s
        s = 1.0 / np.sqrt(sx ** 2 + sy ** 2 + sz ** 2)
        out[i, 0] = sx * s
        out[i, 1] = sy * s
        out[i, 2] = sz * s
    return out


# ---------------------------------------------------------------- bending (hinges)

@njit(inline="always")
def _dihedral(x, o1, o2, a, b):
    """Signed angle θ between the outward normals of triangles (a, b, o1) and
    (b, a, o2) about their edge a→b (positive where convex), with the vectors
    its gradient needs: |e|, e = b − a, p = o1 − a, q = o2 − a and the normals
    (twice the areas) N1 = e × p, N2 = q × e."""
    ex = x[b, 0] - x[a, 0]
    ey = x[b, 1] - x[a, 1]
    ez = x[b, 2] - x[a, 2]
    elen = np.sqrt(ex * ex + ey * ey + ez * ez)
    px = x[o1, 0] - x[a, 0]
    py = x[o1, 1] - x[a, 1]
    pz = x[o1, 2] - x[a, 2]
    qx = x[o2, 0] - x[a, 0]
    qy = x[o2, 1] - x[a, 1]
    qz = x[o2, 2] - x[a, 2]
    n1x, n1y, n1z = _cross(ex, ey, ez, px, py, pz)
    n2x, n2y, n2z = _cross(qx, qy, qz, ex, ey, ez)
    cx, cy, cz = _cross(n1x, n1y, n1z, n2x, n2y, n2z)
    sin_t = (cx * ex + cy * ey + cz * ez) / elen
    cos_t = n1x * n2x + n1y * n2y + n1z * n2z
    theta = np.arctan2(sin_t, cos_t)
    return theta, elen, ex, ey, ez, px, py, pz, qx, qy, qz, n1x, n1y, n1z, n2x, n2y, n2z


@njit(**_JIT)
def hinge_angles(x, hinges):
    """Signed dihedral angles θ of the hinges (H, 4) = (o1, o2, a, b)."""
    out = np.empty(hinges.shape[0])
    for h in range(hinges.shape[0]):
        out[h] = _dihedral(x, hinges[h, 0], hinges[h, 1], hinges[h, 2], hinges[h, 3])[0]
    return out


@njit(**_JIT)
def hinge_bending_gradient(x, hinges, theta0, weight):
    """Energy Σ_h w_h (θ_h − θ0_h)² of dihedral hinges and its gradient (N_p, 3).

    hinges (H, 4) = (o1, o2, a, b): the shared edge a→b, o1 opposite it in the
    triangle (a, b, o1), o2 in the triangle (b, a, o2), both oriented outwards.
    Gradient of θ after Bridson, Marino & Fedkiw (2003): ∂θ/∂o_i = −|e| N_i/|N_i|²,
    the edge ends take the balancing rest.
    """
    grad = np.zeros((x.shape[0], 3))
    energy = 0.0
    for h in range(hinges.shape[0]):
        o1, o2, a, b = hinges[h, 0], hinges[h, 1], hinges[h, 2], hinges[h, 3]
        theta, elen, ex, ey, ez, px, py, pz, qx, qy, qz, n1x, n1y, n1z, n2x, n2y, n2z = _dihedral(x, o1, o2, a, b)
        d = theta - theta0[h]
        energy += weight[h] * d * d
        g = 2.0 * weight[h] * d
        # ∂θ/∂o1 = −|e| N1/|N1|², ∂θ/∂o2 = −|e| N2/|N2|²
        s1 = -elen / (n1x * n1x + n1y * n1y + n1z * n1z)
        s2 = -elen / (n2x * n2x + n2y * n2y + n2z * n2z)
        # projections of the opposite vertices on the edge, as fractions of |e|
        t1 = (px * ex + py * ey + pz * ez) / (elen * elen)
        t2 = (qx * ex + qy * ey + qz * ez) / (elen * elen)
        for k, (nk1, nk2) in enumerate(((n1x, n2x), (n1y, n2y), (n1z, n2z))):
            g1 = s1 * nk1
            g2 = s2 * nk2
            grad[o1, k] += g * g1
            grad[o2, k] += g * g2
            # translation invariance and zero torque fix the edge ends
            grad[a, k] += g * (-(1.0 - t1) * g1 - (1.0 - t2) * g2)
            grad[b, k] += g * (-t1 * g1 - t2 * g2)
    return energy, grad


# ---------------------------------------------------------------- near field

@njit(**_JIT)
def _is_incident(node, e, inc_offsets, inc_elem):
    for k in range(inc_offsets[node], inc_offsets[node + 1]):
        if inc_elem[k] == e:
            return True
    return False


@njit(inline="always")
def _is_near(x, p, e, elements, cen, size, factor, inc_offsets, inc_elem):
    """Some node of element e lies within factor × size[e] of node p, which e does not hold."""
    reach = factor * size[e]
    d2 = 0.0
    for k in range(3):
        t = x[p, k] - cen[e, k]
        d2 += t * t
    if d2 > (reach + size[e]) ** 2:  # no node of e can be within reach
        return False
    for a in range(6):
        d2 = 0.0
        for k in range(3):
            t = x[p, k] - x[elements[e, a], k]
            d2 += t * t
        if d2 < reach * reach:
            return not _is_incident(p, e, inc_offsets, inc_elem)
    return False


@njit(parallel=True, **_JIT)
def near_field_pairs(x, elements, inc_offsets, inc_elem, targets, factor):
    """Elements close to each target node but not holding it: some node of the
    element lies within ``factor`` × its longest vertex-to-vertex edge of the
    target. There the regular rule under-resolves the kernel (a sharp rim, two
    faces of a thin capsule). Returns CSR (offsets (Nt+1,), elements)."""
    ne = elements.shape[0]
    nt = targets.shape[0]
    size = np.empty(ne)
    cen = np.empty((ne, 3))
    for e in range(ne):
        h2 = 0.0
        for a in range(3):
            b = (a + 1) % 3
            d = 0.0
            for k in range(3):
                t = x[elements[e, a], k] - x[elements[e, b], k]
                d += t * t
            h2 = max(h2, d)
        size[e] = np.sqrt(h2)
        for k in range(3):
            cen[e, k] = (x[elements[e, 0], k] + x[elements[e, 1], k] + x[elements[e, 2], k]) / 3.0
    counts = np.zeros(nt, dtype=np.int64)
    for it in prange(nt):
        c = 0
        for e in range(ne):
            if _is_near(x, targets[it], e, elements, cen, size, factor, inc_offsets, inc_elem):
                c += 1
        counts[it] = c
    offsets = np.zeros(nt + 1, dtype=np.int64)
    for it in range(nt):
        offsets[it + 1] = offsets[it] + counts[it]
    pair_elem = np.empty(offsets[nt], dtype=np.int64)
    for it in prange(nt):
        j = offsets[it]
        for e in range(ne):
            if _is_near(x, targets[it], e, elements, cen, size, factor, inc_offsets, inc_elem):
                pair_elem[j] = e
                j += 1
    return offsets, pair_elem


@njit(parallel=True, **_JIT)
def single_layer_near_correction(
    x, elements, nodal_density, reg_points, reg_weights, reg_density,
    fine_phi, fine_dxi, fine_deta, fine_w, measure_w, targets, pair_offsets, pair_elem,
):
    """For each (target, near element) pair: the element's ∫ G·f dS by the
    subdivided rule minus its regular-rule share already in the Stokeslet sum.
    nodal_density (N_e, 6, 3); reg_density (N_e, q, 3) at the regular points. measure_w:
    empty (0, m), a density per unit area of x's surface, else (N_e, m) the subdivided
    rule's weights times the rest shape's Jacobian (a density per unit rest area)."""
    rest = measure_w.shape[0] > 0
    xe = _gather(x, elements)
    out = np.zeros((targets.shape[0], 3))
    for it in prange(targets.shape[0]):
        p = targets[it]
        x0, y0, z0 = x[p, 0], x[p, 1], x[p, 2]
        for k in range(pair_offsets[it], pair_offsets[it + 1]):
            e = pair_elem[k]
            rx, ry, rz = _single_layer_element_regular(x0, y0, z0, e, reg_points, reg_weights, reg_density)
            sx, sy, sz = _single_layer_element(x0, y0, z0, xe, nodal_density, e, fine_phi, fine_dxi, fine_deta,
                                               fine_w, measure_w[e] if rest else fine_w, rest)
            out[it, 0] += sx - rx
            out[it, 1] += sy - ry
            out[it, 2] += sz - rz
    return out


@njit(parallel=True, **_JIT)
def double_layer_near_correction(
    x, u, u_target, elements, reg_points, reg_normals_w, reg_u,
    fine_phi, fine_dxi, fine_deta, fine_w, targets, pair_offsets, pair_elem,
):
    """As single_layer_near_correction for D[u] = ∫ (u − u0)·T·n dS."""
    xe = _gather(x, elements)
    ue = _gather(u, elements)
    out = np.zeros((targets.shape[0], 3))
    for it in prange(targets.shape[0]):
        p = targets[it]
        x0, y0, z0 = x[p, 0], x[p, 1], x[p, 2]
        u0, v0, w0 = u_target[p, 0], u_target[p, 1], u_target[p, 2]
        for k in range(pair_offsets[it], pair_offsets[it + 1]):
            e = pair_elem[k]
            rx, ry, rz = _double_layer_element_regular(x0, y0, z0, u0, v0, w0, e, reg_points, reg_normals_w, reg_u)
            sx, sy, sz = _double_layer_element(
                x0, y0, z0, u0, v0, w0, xe, ue, e, fine_phi, fine_dxi, fine_deta, fine_w
            )
            out[it, 0] += sx - rx
            out[it, 1] += sy - ry
            out[it, 2] += sz - rz
    return out


# ---------------------------------------------------------------- layer matrices
# The layer operators as dense matrices, for the stage solver's direct
# preconditioner: row blocks per target node, column blocks per source node, the
# density interpolated quadratically over each element. The same rules as the
# sums and corrections above, element by element: the regular rule everywhere,
# replaced by the Duffy rule on the elements holding the target and by the
# subdivided rule on its near elements.

@njit(**_JIT)
def _add_symmetric_block(out, i, j, s, b00, b11, b22, b01, b02, b12):
    """out[i, :, j, :] += s · B for a symmetric 3×3 B given by its six entries."""
    out[i, 0, j, 0] += s * b00
    out[i, 0, j, 1] += s * b01
    out[i, 0, j, 2] += s * b02
    out[i, 1, j, 0] += s * b01
    out[i, 1, j, 1] += s * b11
    out[i, 1, j, 2] += s * b12
    out[i, 2, j, 0] += s * b02
    out[i, 2, j, 1] += s * b12
    out[i, 2, j, 2] += s * b22


@njit(**_JIT)
def _add_stokeslet_block(out, i, nodes, phi, dx, dy, dz, w, sign):
    """out[i, :, node_a, :] += sign · w φ_a G(d) for the 6 nodes of one element."""
    rinv = 1.0 / np.sqrt(dx * dx + dy * dy + dz * dz)
    r3 = rinv * rinv * rinv
    g00 = rinv + dx * dx * r3
    g11 = rinv + dy * dy * r3
    g22 = rinv + dz * dz * r3
    g01 = dx * dy * r3
    g02 = dx * dz * r3
    g12 = dy * dz * r3
    for a in range(6):
        _add_symmetric_block(out, i, nodes[a], sign * w * phi[a], g00, g11, g22, g01, g02, g12)


@njit(**_JIT)
def _add_stresslet_block(out, i, nodes, phi, dx, dy, dz, mx, my, mz, sign):
    """The double layer's share of one rule point: K = −6 (d·m) d dᵀ / r⁵ (seed 2.12b)
    into the element's 6 node columns (× φ_a) and, desingularised, −K into column i."""
    self_node = np.int64(i)
    rinv2 = 1.0 / (dx * dx + dy * dy + dz * dz)
    c = -6.0 * sign * (dx * mx + dy * my + dz * mz) * rinv2 * rinv2 * np.sqrt(rinv2)
    k00 = c * dx * dx
    k11 = c * dy * dy
    k22 = c * dz * dz
    k01 = c * dx * dy
    k02 = c * dx * dz
    k12 = c * dy * dz
    for a in range(6):
        _add_symmetric_block(out, i, nodes[a], phi[a], k00, k11, k22, k01, k02, k12)
    # the target's own column: −K, the u0 of u − u0
    _add_symmetric_block(out, i, self_node, -1.0, k00, k11, k22, k01, k02, k12)


@njit(inline="always")
def _layer_element(out, i, x0, y0, z0, xe, nodes, e, phi, dxi, deta, w, measure_w, weighted, double, sign):
    """One element's rule (phi, dxi, deta (m, 6), w (m,)) into row i of a layer matrix;
    weighted: the single layer's density is per unit rest area, measure_w (m,) the rule's
    weights times the rest shape's Jacobian (else per unit area of x's surface)."""
    for j in range(w.shape[0]):
        # (the density slot of _element_point reads the positions again, unused here)
        px, py, pz, nx, ny, nz, _, _, _ = _element_point(xe, xe, e, phi[j], dxi[j], deta[j])
        if weighted and not double:
            _add_stokeslet_block(out, i, nodes, phi[j], px - x0, py - y0, pz - z0, measure_w[j], sign)
        elif double:
            _add_stresslet_block(out, i, nodes, phi[j], px - x0, py - y0, pz - z0,
                                 nx * w[j], ny * w[j], nz * w[j], sign)
        else:
            _add_stokeslet_block(out, i, nodes, phi[j], px - x0, py - y0, pz - z0,
                                 w[j] * np.sqrt(nx * nx + ny * ny + nz * nz), sign)


@njit(inline="always")
def _layer_element_regular(out, i, x0, y0, z0, nodes, e, reg_points, reg_weights, reg_normals_w, reg_phi,
                           double, sign):
    """The regular rule's share of element e (the precomputed points of the sums)."""
    for q in range(reg_weights.shape[1]):
        dx = reg_points[e, q, 0] - x0
        dy = reg_points[e, q, 1] - y0
        dz = reg_points[e, q, 2] - z0
        if double:
            _add_stresslet_block(out, i, nodes, reg_phi[q], dx, dy, dz, reg_normals_w[e, q, 0],
                                 reg_normals_w[e, q, 1], reg_normals_w[e, q, 2], sign)
        else:
            _add_stokeslet_block(out, i, nodes, reg_phi[q], dx, dy, dz, reg_weights[e, q], sign)


@njit(parallel=True, **_JIT)
def layer_matrix(
    x, elements, reg_points, reg_weights, reg_normals_w, reg_phi,
    inc_offsets, inc_elem, inc_local, sing_phi, sing_dxi, sing_deta, sing_w,
    fine_phi, fine_dxi, fine_deta, fine_w, pair_offsets, pair_elem, double, duffy_measure_w, fine_measure_w,
):
    """The single layer ∫ G·f dS (double=False) or the double layer
    ∫ (u − u0)·T·n dS (double=True) at every node as an (N, 3, N, 3) matrix acting
    on nodal values. pair_offsets/pair_elem: the near pairs of every node as target
    (empty offsets, all zero, when the near field is off). duffy_measure_w (N_e, 6, m),
    fine_measure_w (N_e, m_f): for a single-layer density per unit rest area, the rules'
    weights times the rest shape's Jacobian (reg_weights the rest shape's too); empty
    ((0, 6, m), (0, m_f)) for a density per unit area of x's surface."""
    rest = duffy_measure_w.shape[0] > 0
    n = x.shape[0]
    ne = elements.shape[0]
    xe = _gather(x, elements)
    out = np.zeros((n, 3, n, 3))
    for i in prange(n):
        x0, y0, z0 = x[i, 0], x[i, 1], x[i, 2]
        for e in range(ne):
            _layer_element_regular(out, i, x0, y0, z0, elements[e], e, reg_points, reg_weights,
                                   reg_normals_w, reg_phi, double, 1.0)
        for c in range(inc_offsets[i], inc_offsets[i + 1]):
            e = inc_elem[c]
            k = inc_local[c]
            _layer_element_regular(out, i, x0, y0, z0, elements[e], e, reg_points, reg_weights,
                                   reg_normals_w, reg_phi, double, -1.0)
            _layer_element(out, i, x0, y0, z0, xe, elements[e], e, sing_phi[k], sing_dxi[k], sing_deta[k],
                           sing_w[k], duffy_measure_w[e, k] if rest else sing_w[k], rest, double, 1.0)
        for c in range(pair_offsets[i], pair_offsets[i + 1]):
            e = pair_elem[c]
            _layer_element_regular(out, i, x0, y0, z0, elements[e], e, reg_points, reg_weights,
                                   reg_normals_w, reg_phi, double, -1.0)
            _layer_element(out, i, x0, y0, z0, xe, elements[e], e, fine_phi, fine_dxi, fine_deta, fine_w,
                           fine_measure_w[e] if rest else fine_w, rest, double, 1.0)
    return out


# ---------------------------------------------------------------- membrane viscosity

@njit(**_JIT)
def viscous_membrane_blocks(x, elements, dxi, deta, w, c_shear, c_dil):
    """Element blocks of the viscous stiffness K of a Kelvin–Voigt membrane
    (docs/viscous_membrane.md, eq. V3): (K u)_a = ∫ τ(u)·g_a dA with the viscous
    tension τ = 2 c_s (D − ½ tr D P) + c_d tr D P, D = ½ P(∇_s u + ∇_s uᵀ)P and
    g_a = t^α ∂φ_a/∂ξ_α the surface gradient of shape function a (t^α the dual
    basis of the current tangents). Substituting ∇_s u = Σ_b g_b ⊗ u_b gives the
    3 × 3 block of nodes (a, b),

        K_ab = ∫ [c_s (g_b ⊗ g_a + (g_a·g_b) P) + (c_d − c_s) g_a ⊗ g_b] dA,

    symmetric (K_ba = K_abᵀ) and positive semidefinite: uᵀK u = ∫ τ(u):D(u) dA is
    twice the dissipation. Returns (N_e, 18, 18), row 3a + i, column 3b + j.
    """
    ne = elements.shape[0]
    nq = w.shape[0]
    out = np.zeros((ne, 18, 18))
    g = np.empty((6, 3))
    for e in range(ne):
        for q in range(nq):
            a0, a1, a2, b0, b1, b2 = _tangents(x, elements, e, dxi, deta, q)
            g11 = a0 * a0 + a1 * a1 + a2 * a2
            g12 = a0 * b0 + a1 * b1 + a2 * b2
            g22 = b0 * b0 + b1 * b1 + b2 * b2
            detg = g11 * g22 - g12 * g12
            jac = np.sqrt(detg)
            d10 = (g22 * a0 - g12 * b0) / detg
            d11 = (g22 * a1 - g12 * b1) / detg
            d12 = (g22 * a2 - g12 * b2) / detg
            d20 = (g11 * b0 - g12 * a0) / detg
            d21 = (g11 * b1 - g12 * a1) / detg
            d22 = (g11 * b2 - g12 * a2) / detg
            n0 = (a1 * b2 - a2 * b1) / jac
            n1 = (a2 * b0 - a0 * b2) / jac
            n2 = (a0 * b1 - a1 * b0) / jac
            nn = (n0, n1, n2)
            for k in range(6):
                g[k, 0] = dxi[q, k] * d10 + deta[q, k] * d20
                g[k, 1] = dxi[q, k] * d11 + deta[q, k] * d21
                g[k, 2] = dxi[q, k] * d12 + deta[q, k] * d22
            s = w[q] * jac
            cs = s * c_shear
            cd = s * (c_dil - c_shear)
            for ka in range(6):
                for kb in range(6):
                    dot = g[ka, 0] * g[kb, 0] + g[ka, 1] * g[kb, 1] + g[ka, 2] * g[kb, 2]
                    for i in range(3):
                        for j in range(3):
                            proj = (1.0 if i == j else 0.0) - nn[i] * nn[j]
                            out[e, 3 * ka + i, 3 * kb + j] += (cs * (g[kb, i] * g[ka, j] + dot * proj)
                                                               + cd * g[ka, i] * g[kb, j])
    return out


# ---------------------------------------------------------------- per-step observables (issue 57)

@njit(**_JIT)
def rounded_mean_point(points):
    """The mean of the points (..., 3) rounded to whole units (geometry.reference_point's, ~2 µs
    against numpy's ~50 µs at level 3: a row's first call)."""
    flat = points.reshape(-1, 3)
    n = flat.shape[0]
    out = np.zeros(3)
    for i in range(n):
        for d in range(3):
            out[d] += flat[i, d]
    for d in range(3):
        out[d] = np.round(out[d] / n)
    return out


@njit(**_JIT)
def surface_moments(points, normals, weights, p):
    """The enclosed volume's moments from surface integrals at the regular points, in two
    passes (capsim.numerics.geometry's volume_area, centroid and second_moment fused):
    V = ⅓ ∫ (x − p)·n dS, S = ∫ dS, c = p + ½ ∫ |x − p|² n dS / V, and about c
    M = ⅕ ∫ y y (y·n) dS, y = x − c (seed 3.9). p: the reference point the first
    integrals are taken about (round-off far from the origin). Returns
    [V, S, c_x, c_y, c_z, M_xx, M_xy, ..., M_zz] (14 values)."""
    ne, nq = weights.shape
    V = 0.0
    S = 0.0
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    for e in range(ne):
        for q in range(nq):
            w = weights[e, q]
            y0 = points[e, q, 0] - p[0]
            y1 = points[e, q, 1] - p[1]
            y2 = points[e, q, 2] - p[2]
            n0, n1, n2 = normals[e, q, 0], normals[e, q, 1], normals[e, q, 2]
            V += (y0 * n0 + y1 * n1 + y2 * n2) * w
            S += w
            r2w = (y0 * y0 + y1 * y1 + y2 * y2) * w
            s0 += r2w * n0
            s1 += r2w * n1
            s2 += r2w * n2
    V /= 3.0
    out = np.zeros(14)
    out[0] = V
    out[1] = S
    c0 = p[0] + 0.5 * s0 / V
    c1 = p[1] + 0.5 * s1 / V
    c2 = p[2] + 0.5 * s2 / V
    out[2] = c0
    out[3] = c1
    out[4] = c2
    # M row-major in out[5:], the upper triangle summed (in scalars: registers), the lower its mirror
    m00 = m01 = m02 = m11 = m12 = m22 = 0.0
    for e in range(ne):
        for q in range(nq):
            y0 = points[e, q, 0] - c0
            y1 = points[e, q, 1] - c1
            y2 = points[e, q, 2] - c2
            ynw = (y0 * normals[e, q, 0] + y1 * normals[e, q, 1] + y2 * normals[e, q, 2]) * weights[e, q]
            m00 += y0 * y0 * ynw
            m01 += y0 * y1 * ynw
            m02 += y0 * y2 * ynw
            m11 += y1 * y1 * ynw
            m12 += y1 * y2 * ynw
            m22 += y2 * y2 * ynw
    out[5], out[6], out[7] = m00 / 5.0, m01 / 5.0, m02 / 5.0
    out[8], out[9], out[10] = m01 / 5.0, m11 / 5.0, m12 / 5.0
    out[11], out[12], out[13] = m02 / 5.0, m12 / 5.0, m22 / 5.0
    return out


@njit(**_JIT)
def _as_line(v, out, at):
    """v into out[at:at + 3] as a line: its first component that is not ~0 made positive
    (capsim.solve.observables._line)."""
    sign = 1.0
    for d in range(3):
        if abs(v[d]) > 1e-12:
            sign = 1.0 if v[d] > 0.0 else -1.0
            break
    for d in range(3):
        out[at + d] = v[d] * sign


@njit(**_JIT)
def ellipsoid_of_moment(M, volume, tie_break, degenerate_gap, theta_gap):
    """The equivalent ellipsoid of the second moment M (about the centroid) and the volume, as
    capsim.solve.observables.ellipsoid_of_moment (the reference: tests/numerics/test_step_kernels.py)
    with its principal_frame: eigenvalues within ``degenerate_gap`` (relative) spanned by the
    eigenvectors of ``tie_break`` restricted to them, most stretched first; θ NaN below ``theta_gap``.
    Returns [L, l, W, D_xy, θ, a, b, c, long axis (3), short axis (3)] (14 values)."""
    mu, vec = np.linalg.eigh(M)
    scale = max(np.abs(mu).max(), 2.2250738585072014e-308)
    start = 0
    for k in range(1, 4):
        if k == 3 or mu[k] - mu[k - 1] > degenerate_gap * scale:
            size = k - start
            if size >= 2:
                V = np.ascontiguousarray(vec[:, start:k])
                _, R = np.linalg.eigh(V.T @ tie_break @ V)
                turned = V @ R
                mean = 0.0
                for j in range(size):
                    mean += mu[start + j]
                mean /= size
                for j in range(size):
                    for d in range(3):
                        vec[d, start + j] = turned[d, size - 1 - j]  # most stretched first
                    mu[start + j] = mean
            start = k
    axes = np.sqrt(np.maximum(5.0 * mu / volume, 0.0))
    out_of_plane = 0
    for k in range(1, 3):
        if abs(vec[2, k]) > abs(vec[2, out_of_plane]):
            out_of_plane = k
    first = 1 if out_of_plane == 0 else 0
    second = 2 if out_of_plane != 2 else 1
    # the most stretched of a degenerate pair is listed first, and a tie keeps the first
    i_long, i_short = (second, first) if axes[second] > axes[first] else (first, second)
    L, l = axes[i_long], axes[i_short]
    order = np.argsort(-axes, kind="mergesort")
    out = np.empty(14)
    out[0] = L
    out[1] = l
    out[2] = axes[out_of_plane]
    out[3] = (L - l) / (L + l)
    theta = np.arctan2(vec[1, i_long], vec[0, i_long])
    if theta > np.pi / 2:
        theta -= np.pi
    elif theta <= -np.pi / 2:
        theta += np.pi
    gap = abs(mu[i_long] - mu[i_short]) / max(abs(mu[i_long]) + abs(mu[i_short]), 2.2250738585072014e-308)
    if not gap >= theta_gap:
        theta = np.nan
    out[4] = theta
    for j in range(3):
        out[5 + j] = axes[order[j]]
    _as_line(np.ascontiguousarray(vec[:, order[0]]), out, 8)
    _as_line(np.ascontiguousarray(vec[:, order[2]]), out, 11)
    return out


@njit(**_JIT)
def row_surface_sums(points, normals, weights, density_weights, density, u, elements, phi, center,
                     director_weights, mean_weights):
    """The row's surface integrals about the centroid ``center`` in one pass over the regular points
    (capsim.solve.observables.capsule_row; each of them was its own numpy pass). About the centre and
    less the mean velocity U (∮ (x − c)(U·n) dS = V U): far from the origin x and U are large and their
    round-off swamped the slip (capsim.numerics.geometry.reference_point). With u the nodal
    velocity less its mean U, interpolated by ``phi`` (Q, 6), and Δf the element-nodal ``density``
    (N_e, 6, 3) interpolated alike, returns 27 values:

    - [0:3] U, the nodes' mean velocity; [3:6] ∮ (x − c)(u·n) dS (the centroid's Reynolds flux);
    - [6:15] ∮ Δf_i (x − c)_j dS0 (``density_weights``: the measure Δf is per), row-major;
    - [15:24] ∮ u_i n_j dS (the λ ≠ 1 term of the stresslet);
    - [24:27] the material director's Σ W_p (x_p − c) − (Σ W_p) Σ w_p (x_p − c) (``director_weights`` W,
      ``mean_weights`` w summing to 1: MaterialDirector's d, the same for any reference point).
    """
    n_nodes = u.shape[0]
    out = np.zeros(27)
    for i in range(n_nodes):
        for d in range(3):
            out[d] += u[i, d]
    for d in range(3):
        out[d] /= n_nodes
    U0, U1, U2 = out[0], out[1], out[2]
    c0, c1, c2 = center[0], center[1], center[2]
    ne, nq = weights.shape
    nk = phi.shape[1]
    # scalar accumulators (LLVM keeps them in registers; sums into out[...] went through memory)
    r0 = r1 = r2 = 0.0
    e00 = e01 = e02 = e10 = e11 = e12 = e20 = e21 = e22 = 0.0
    s00 = s01 = s02 = s10 = s11 = s12 = s20 = s21 = s22 = 0.0
    d0 = d1 = d2 = 0.0
    sum_director = 0.0
    m0 = 0.0
    m1 = 0.0
    m2 = 0.0
    for e in range(ne):
        for q in range(nq):
            a0 = 0.0
            a1 = 0.0
            a2 = 0.0
            f0 = 0.0
            f1 = 0.0
            f2 = 0.0
            for k in range(nk):
                node = elements[e, k]
                f = phi[q, k]
                a0 += f * (u[node, 0] - U0)
                a1 += f * (u[node, 1] - U1)
                a2 += f * (u[node, 2] - U2)
                f0 += f * density[e, k, 0]
                f1 += f * density[e, k, 1]
                f2 += f * density[e, k, 2]
            w = weights[e, q]
            n0, n1, n2 = normals[e, q, 0], normals[e, q, 1], normals[e, q, 2]
            y0 = points[e, q, 0] - c0
            y1 = points[e, q, 1] - c1
            y2 = points[e, q, 2] - c2
            flux = (a0 * n0 + a1 * n1 + a2 * n2) * w
            r0 += flux * y0
            r1 += flux * y1
            r2 += flux * y2
            wd = density_weights[e, q]
            g0, g1, g2 = f0 * wd, f1 * wd, f2 * wd
            e00 += g0 * y0
            e01 += g0 * y1
            e02 += g0 * y2
            e10 += g1 * y0
            e11 += g1 * y1
            e12 += g1 * y2
            e20 += g2 * y0
            e21 += g2 * y1
            e22 += g2 * y2
            b0, b1, b2 = a0 * w, a1 * w, a2 * w
            s00 += b0 * n0
            s01 += b0 * n1
            s02 += b0 * n2
            s10 += b1 * n0
            s11 += b1 * n1
            s12 += b1 * n2
            s20 += b2 * n0
            s21 += b2 * n1
            s22 += b2 * n2
            p = e * nq + q
            W = director_weights[p]
            sum_director += W
            d0 += W * y0
            d1 += W * y1
            d2 += W * y2
            wm = mean_weights[p]
            m0 += wm * y0
            m1 += wm * y1
            m2 += wm * y2
    out[3], out[4], out[5] = r0, r1, r2
    out[6], out[7], out[8], out[9], out[10], out[11], out[12], out[13], out[14] = \
        e00, e01, e02, e10, e11, e12, e20, e21, e22
    out[15], out[16], out[17], out[18], out[19], out[20], out[21], out[22], out[23] = \
        s00, s01, s02, s10, s11, s12, s20, s21, s22
    out[24] = d0 - sum_director * m0
    out[25] = d1 - sum_director * m1
    out[26] = d2 - sum_director * m2
    return out


@njit(**_JIT)
def min_vertex_triangle_quality(x, elements):
    """The smallest 4√3·area / Σ edge² of the elements' vertex triangles (capsim.numerics.
    geometry.vertex_triangle_quality's minimum)."""
    worst = np.inf
    for e in range(elements.shape[0]):
        a, b, c = elements[e, 0], elements[e, 1], elements[e, 2]
        ab0, ab1, ab2 = x[b, 0] - x[a, 0], x[b, 1] - x[a, 1], x[b, 2] - x[a, 2]
        ac0, ac1, ac2 = x[c, 0] - x[a, 0], x[c, 1] - x[a, 1], x[c, 2] - x[a, 2]
        bc0, bc1, bc2 = x[c, 0] - x[b, 0], x[c, 1] - x[b, 1], x[c, 2] - x[b, 2]
        cr0 = ab1 * ac2 - ab2 * ac1
        cr1 = ab2 * ac0 - ab0 * ac2
        cr2 = ab0 * ac1 - ab1 * ac0
        area = 0.5 * np.sqrt(cr0 * cr0 + cr1 * cr1 + cr2 * cr2)
        s = (ab0 * ab0 + ab1 * ab1 + ab2 * ab2) + (bc0 * bc0 + bc1 * bc1 + bc2 * bc2) + (ac0 * ac0 + ac1 * ac1 + ac2 * ac2)
        qual = 4.0 * np.sqrt(3.0) * area / s
        if qual < worst:
            worst = qual
    return worst


# ---------------------------------------------------------------- the time step's vector work (issue 57)

@njit(**_JIT)
def spread_about_mean(a):
    """max |a − ā| over an (N, k) array, ā its mean row (the error norm's length,
    capsim.solve.timestepping.scene_size; the velocity's spread of the solve's tolerance): one pass
    for numpy's mean, subtraction, abs and max (~20 µs at level 3 in numpy, more between evaluations)."""
    n, k = a.shape
    mean = np.zeros(k)
    for i in range(n):
        for d in range(k):
            mean[d] += a[i, d]
    for d in range(k):
        mean[d] /= n
    out = 0.0
    for i in range(n):
        for d in range(k):
            out = max(out, abs(a[i, d] - mean[d]))
    return out


@njit(**_JIT)
def mean_row_max_abs(a):
    """max |ā| of an (N, k) array's mean row ā (how far a capsule's centre is from the origin)."""
    n, k = a.shape
    out = 0.0
    for d in range(k):
        m = 0.0
        for i in range(n):
            m += a[i, d]
        out = max(out, abs(m / n))
    return out


@njit(**_JIT)
def all_finite(a):
    """Whether every entry of a 1-D array (a flat view) is finite."""
    for i in range(a.shape[0]):
        if not np.isfinite(a[i]):
            return False
    return True


@njit(inline="always")
def _principal_tension_pair(w1, w2, inv1, l1, l2):
    """τ1 ≥ τ2 at one vertex, τi = e^{−Λ1}(W_1 + W_2 λi²) (seed 2.7 in principal axes)."""
    scale = np.exp(-inv1)
    t1 = scale * (w1 + w2 * l1 * l1)
    t2 = scale * (w1 + w2 * l2 * l2)
    return max(t1, t2), min(t1, t2)


@njit(**_JIT)
def principal_tensions(w1, w2, inv1, l1, l2):
    """The principal tensions τ1 ≥ τ2 at every vertex (capsim.numerics.membrane.principal_tensions)."""
    n = w1.shape[0]
    tau1, tau2 = np.empty(n), np.empty(n)
    for i in range(n):
        tau1[i], tau2[i] = _principal_tension_pair(w1[i], w2[i], inv1[i], l1[i], l2[i])
    return tau1, tau2


@njit(**_JIT)
def membrane_row_summary(w1, w2, inv1, l1, l2, modulus, threshold, counts):
    """A row's membrane columns from the vertices' strain in one pass (issue 57: ~10 numpy calls
    a row): the largest principal stretch (max λ1), the smallest of the smaller principal tensions
    τ2 (times ``modulus``; as :func:`principal_tensions`) and the share of the vertices with
    τ2 < threshold, each weighted by ``counts`` (how many vertices it stands for; an empty array: one each)."""
    largest = 0.0
    lowest = np.inf
    below = 0.0
    total = 0.0
    weighted = counts.shape[0] > 0
    for i in range(w1.shape[0]):
        largest = max(largest, l1[i])
        t = modulus * _principal_tension_pair(w1[i], w2[i], inv1[i], l1[i], l2[i])[1]
        lowest = min(lowest, t)
        c = counts[i] if weighted else 1.0
        total += c
        if t < threshold:
            below += c
    return largest, lowest, below / total


@njit(**_JIT)
def max_abs(a):
    """max |a| over a 1-D array (a flat view)."""
    out = 0.0
    for i in range(a.shape[0]):
        out = max(out, abs(a[i]))
    return out


@njit(**_JIT)
def rkc_stage(y0, y_prev, y_prev2, f, f0, c0, c1, c2, c3, c4):
    """c0 y0 + c1 y_prev + c2 y_prev2 + c3 f + c4 f0 over 1-D arrays (flat views), the RKC recursion's
    stage (capsim.solve.timestepping.rkc_step; SSV 1998, eq. 2.4) in one pass."""
    out = np.empty_like(y0)
    for i in range(y0.shape[0]):
        out[i] = c0 * y0[i] + c1 * y_prev[i] + c2 * y_prev2[i] + c3 * f[i] + c4 * f0[i]
    return out


@njit(**_JIT)
def rkc_error_estimate(y0, y_new, f0, f_new, h):
    """(12 (y0 − y_new) + 6 h (f0 + f_new)) / 15 over 1-D arrays (flat views), RKC's local error
    estimate (SSV 1998, eq. 3.1)."""
    out = np.empty_like(y0)
    for i in range(y0.shape[0]):
        out[i] = (12.0 * (y0[i] - y_new[i]) + 6.0 * h * (f0[i] + f_new[i])) / 15.0
    return out


@njit(**_JIT)
def tank_treading_angles(x, u, nodes, center, raw_before, unwrapped_before):
    """The tracked nodes' angles about the centre in the xy-plane, unwrapped from the last step's
    (capsim.solve.observables.TankTreadingTracker.update; no node turns by π in a step), and their
    mean rate ⟨(r × u)_z / |r|²⟩. ``raw_before`` empty: the first step. Returns (ω, the mean unwrapped
    angle, raw, unwrapped)."""
    n = nodes.shape[0]
    raw = np.empty(n)
    unwrapped = np.empty(n)
    omega = 0.0
    angle = 0.0
    first = raw_before.shape[0] == 0
    for i in range(n):
        r0 = x[nodes[i], 0] - center[0]
        r1 = x[nodes[i], 1] - center[1]
        omega += (r0 * u[nodes[i], 1] - r1 * u[nodes[i], 0]) / (r0 * r0 + r1 * r1)
        raw[i] = np.arctan2(r1, r0)
        if first:
            unwrapped[i] = raw[i]
        else:
            turn = (raw[i] - raw_before[i] + np.pi) % (2 * np.pi) - np.pi
            unwrapped[i] = unwrapped_before[i] + turn
        angle += unwrapped[i]
    return omega / n, angle / n, raw, unwrapped
