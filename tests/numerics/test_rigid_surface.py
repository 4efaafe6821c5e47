"""The single layer of a rigid surface of 6-node triangles (capsim.numerics.rigid_surface),
checked on the unit sphere against the translating sphere:

    ∫_S G(t, y) dS(y)·e = (16π/3) u(t),  u = (3/4)(e/r + (e·t)t/r³) + (1/4)(e/r³ − 3(e·t)t/r⁵)

outside (r = |t| ≥ 1), and (16π/3) e inside. Derivation: a unit sphere translating with
velocity e carries the uniform traction f = −(3μ/2) e, and u(t) = −(1/8πμ) ∫ G·f dS (G
unnormalised, as capsim's) = (3/16π) ∫ G dS·e, with u the Stokes flow above (u = e on
r = 1). test_translating_sphere_formula checks it against an independent quadrature on the
exact sphere. Measured errors (relative to 16π/3) are quoted in each test.
"""

from __future__ import annotations

import time
from functools import lru_cache

import numpy as np
import pytest

from capsim.numerics.kernels import stokeslet_sum
from capsim.numerics.mesh import unit_sphere_mesh
from capsim.numerics.rigid_surface import (
    element_sizes, nodal_normals, point_strengths_of, single_layer_at, single_layer_matrix,
    surface_integral_weights,
)

C = 16.0 * np.pi / 3.0
E = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])


@lru_cache(maxsize=None)
def _mesh(base, level):
    return unit_sphere_mesh(base, level)


@lru_cache(maxsize=None)
def _matrix(base, level):
    m = _mesh(base, level)
    return single_layer_matrix(m.positions, m.elements)


def _translating_sphere(t, e=E):
    """∫_S G(t, y) dS(y)·e on the unit sphere (module docstring)."""
    r = np.maximum(np.linalg.norm(t, axis=1), 1.0)[:, None]  # inside: overwritten below
    et = (t @ e)[:, None]
    out = C * (0.75 * (e / r + et * t / r**3) + 0.25 * (e / r**3 - 3.0 * et * t / r**5))
    out[np.linalg.norm(t, axis=1) < 1.0] = C * e
    return out


def _directions(n, seed=3):
    d = np.random.default_rng(seed).standard_normal((n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_translating_sphere_formula():
    """The formula against Gauss–Legendre in cos θ × the trapezoidal rule in φ on the exact
    sphere (spectrally accurate for targets off it): 1e-10 at r = 0.5, 1.5, 3; and u = e on r = 1."""
    c, wc = np.polynomial.legendre.leggauss(80)
    ph = np.linspace(0.0, 2 * np.pi, 160, endpoint=False)
    s = np.sqrt(1 - c**2)
    y = np.stack([np.outer(s, np.cos(ph)), np.outer(s, np.sin(ph)), np.outer(c, np.ones_like(ph))], -1).reshape(-1, 3)
    w = np.repeat(wc, ph.size) * (2 * np.pi / ph.size)
    t = np.concatenate([0.5 * _directions(4), 1.5 * _directions(4, 4), 3.0 * _directions(4, 5)])
    got = stokeslet_sum(t, y, w[:, None] * E[None, :])
    assert np.abs(got - _translating_sphere(t)).max() < 1e-10 * C
    on = _directions(5, 6)
    r = np.linalg.norm(on, axis=1)[:, None]
    u = 0.75 * (E / r + (on @ E)[:, None] * on) + 0.25 * (E - 3 * (on @ E)[:, None] * on)
    assert np.abs(u - E).max() < 1e-14


@pytest.mark.parametrize("base, bound_l2", [("octahedron", 1e-3), ("icosahedron", 1.5e-4)])
def test_uniform_density_gives_the_translating_sphere_at_every_node(base, bound_l2):
    """(W e)(x_i) = (16π/3) e for all three e at once (Σ_j of W's 3×3 blocks = (16π/3) I).
    Measured max relative error, levels 1/2/3: octahedron 7.2e-3, 5.9e-4, 3.8e-5; icosahedron
    1.1e-3, 7.2e-5, 4.6e-6: order 4 (ratios 12–15.6 per halving), the geometry's error (the
    discretised sphere's area errs by as much; more quadrature points change nothing)."""
    errs = []
    for level in (1, 2, 3):
        w = _matrix(base, level)
        n = w.shape[0] // 3
        blocks = w.reshape(n, 3, n, 3).sum(axis=2)
        errs.append(np.abs(blocks - C * np.eye(3)).max() / C)
    assert errs[1] < bound_l2
    assert errs[0] / errs[1] > 8.0 and errs[1] / errs[2] > 8.0  # order ≥ 3 per halving


def test_near_rule_of_the_matrix_matters():
    """Without the subdivided rule on near elements (near_factor 0) the icosahedron level 2
    errs 2.0e-4 instead of 7.2e-5."""
    m = _mesh("icosahedron", 2)
    n = m.n_nodes
    e_on = np.abs(_matrix("icosahedron", 2) @ np.tile(E, n) - np.tile(C * E, n)).max() / C
    w_off = single_layer_matrix(m.positions, m.elements, near_factor=0.0)
    e_off = np.abs(w_off @ np.tile(E, n) - np.tile(C * E, n)).max() / C
    assert e_on < 1e-4 < e_off


@pytest.mark.parametrize("base, bound_l2, bound_l3", [("octahedron", 2e-4, 1.5e-5), ("icosahedron", 1.2e-5, 1e-6)])
def test_normal_density_is_the_null_space(base, bound_l2, bound_l3):
    """W n ≈ 0 (∫ G·n dS = 0: the Stokeslet is solenoidal), relative to ‖W‖∞ (max row sum
    of |W|, the bound of |W n| for |n| = 1; ‖W‖∞ ≈ 1.33 · 16π/3). Measured max |W n| / ‖W‖∞,
    levels 1/2/3: octahedron 7.1e-4, 1.0e-4, 7.2e-6; icosahedron 6.0e-5, 5.8e-6, 5.0e-7."""
    rel = []
    for level in (1, 2, 3):
        m = _mesh(base, level)
        w = _matrix(base, level)
        nn = nodal_normals(m.positions, m.elements)
        rel.append(np.abs(w @ nn.ravel()).max() / np.abs(w).sum(axis=1).max())
    assert rel[1] < bound_l2 and rel[2] < bound_l3
    assert rel[0] / rel[1] > 5.0 and rel[1] / rel[2] > 5.0


@pytest.mark.parametrize("base, level, tol", [("octahedron", 2, 2e-3), ("octahedron", 3, 1e-4),
                                              ("icosahedron", 2, 2e-4)])
def test_single_layer_at_targets_off_the_sphere(base, level, tol):
    """Uniform density e at targets inside (r 0, 0.5, 0.9: (16π/3) e), 0.05 and 0.02 from
    the sphere on both sides (the near rule), and outside (1.5, 3). Measured max error over
    all targets relative to 16π/3: octahedron 2 8.9e-4, octahedron 3 6.3e-5, icosahedron 2
    1.1e-4, largest 0.02 outside (the discretisation's, as for W e: 2.7e-4, 1.8e-5, 3.8e-5
    at the centre); with the near rule off (near_factor 0) the targets 0.02 off err 3.5e-2,
    1.5e-2, 1.8e-2."""
    m = _mesh(base, level)
    q = np.tile(E, (m.n_nodes, 1))
    d = _directions(60)
    t = np.concatenate([np.zeros((1, 3))] + [r * d for r in (0.5, 0.9, 0.95, 0.98, 1.02, 1.05, 1.5, 3.0)])
    err = np.abs(single_layer_at(t, m.positions, m.elements, q) - _translating_sphere(t)).max() / C
    assert err < tol
    close = np.concatenate([0.98 * d, 1.02 * d])
    err_off = np.abs(single_layer_at(close, m.positions, m.elements, q, near_factor=0.0)
                     - _translating_sphere(close)).max() / C
    assert err_off > 20 * err


@pytest.mark.parametrize("base, level", [("octahedron", 2), ("icosahedron", 2)])
def test_near_rule_reaches_1e4_at_a_tenth_of_an_element(base, level):
    """The quadrature error alone, against max_levels=6, for a smooth non-uniform density at
    targets 0.1 and 0.05 mean element sizes from the surface (both sides). Measured relative
    to max |u|: 0.1 h 6.3e-6 (octahedron), 2.4e-6 (icosahedron); 0.05 h 1.2e-4, 5.8e-5."""
    m = _mesh(base, level)
    x = m.positions
    q = np.stack([1 + x[:, 0] * x[:, 1], np.sin(2 * x[:, 2]), x[:, 1] ** 2], axis=1)
    h = element_sizes(x, m.elements)[0].mean()
    d = _directions(150, 8)
    for frac, tol in ((0.1, 1e-4), (0.05, 4e-4)):
        t = np.concatenate([d * (1 - frac * h), d * (1 + frac * h)])
        ref = single_layer_at(t, x, m.elements, q, max_levels=6)
        got = single_layer_at(t, x, m.elements, q)
        assert np.abs(got - ref).max() < tol * np.abs(ref).max()


def test_point_strengths_sum_to_the_far_field():
    """Far targets (r = 4, all elements far): stokeslet_sum over point_strengths_of equals
    single_layer_at to round-off."""
    m = _mesh("octahedron", 2)
    x = m.positions
    q = np.stack([x[:, 1], 1 + x[:, 2] ** 2, np.cos(x[:, 0])], axis=1)
    pts, s = point_strengths_of(x, m.elements, q, 7)
    assert pts.shape == s.shape == (7 * m.n_elements, 3)
    t = 4.0 * _directions(30)
    ref = single_layer_at(t, x, m.elements, q)
    assert np.abs(stokeslet_sum(t, pts, s) - ref).max() < 1e-12 * np.abs(ref).max()


def test_solve_for_the_uniform_traction():
    """W q = e at every node gives q = 3/(16π) e. Measured max relative nodal error,
    octahedron levels 1/2/3: 3.4e-2, 3.4e-3, 3.9e-4 (order ~3, as the density's
    interpolation); the drag ∫ q dS = (3/4) e to 2.6e-3, 1.8e-4, 1.1e-5 (order 4). A rank-one
    deflation with the flux functional Σ w_j q_j·n_j (the null space) changes nothing here:
    e is orthogonal to it on the sphere."""
    errs, drags = [], []
    for level in (1, 2, 3):
        m = _mesh("octahedron", level)
        w = _matrix("octahedron", level)
        n = m.n_nodes
        weights = surface_integral_weights(m.positions, m.elements)
        normals = nodal_normals(m.positions, m.elements)
        deflated = w + np.outer(normals.ravel(), (weights[:, None] * normals).ravel())
        q = np.linalg.solve(deflated, np.tile(E, n)).reshape(n, 3)
        errs.append(np.abs(q - 3 / (16 * np.pi) * E).max() / (3 / (16 * np.pi)))
        drags.append(np.abs((weights[:, None] * q).sum(axis=0) - 0.75 * E).max() / 0.75)
        assert abs((weights * (q * normals).sum(axis=1)).sum()) < 1e-12  # the constraint holds
    assert errs[1] < 5e-3 and errs[2] < 6e-4
    assert errs[1] / errs[2] > 6.0 and drags[1] / drags[2] > 10.0


def test_surface_weights_and_normals():
    """Σ w_j = the area of the discretised sphere (round-off); Σ_j w_j x_j·n_j = 3V ≈ 4π
    (the geometry's error, 1.3e-4 at octahedron 2); nodal normals = the sphere's
    (the nodes lie on it) to 2.4e-2, 3.2e-3, 4.1e-4 at levels 1/2/3 (order 3)."""
    from capsim.numerics.geometry import element_geometry

    dev = []
    for level in (1, 2, 3):
        m = _mesh("octahedron", level)
        x = m.positions
        w = surface_integral_weights(x, m.elements)
        area = element_geometry(x, m.elements, 7).weights.sum()
        assert w.sum() == pytest.approx(area, rel=1e-13)
        nn = nodal_normals(x, m.elements)
        assert np.linalg.norm(nn, axis=1) == pytest.approx(1.0, abs=1e-14)
        dev.append(np.abs(nn - x).max())
        if level == 2:
            assert (w * (x * nn).sum(axis=1)).sum() == pytest.approx(4 * np.pi, rel=1e-3)
    assert dev[2] < 1e-3 and dev[0] / dev[1] > 5 and dev[1] / dev[2] > 5


def test_matrix_timing():
    """Icosahedron level 3 (N 2562, E 1280) after compilation: measured 0.9 s on 2 cores
    (octahedron 3, N 1026: 0.3 s; octahedron 4, N 4098: 2.6 s). Bound 10 s (shared cores)."""
    m = _mesh("icosahedron", 3)
    _matrix("octahedron", 1)  # compiled
    t0 = time.perf_counter()
    w = single_layer_matrix(m.positions, m.elements)
    assert time.perf_counter() - t0 < 10.0
    assert w.shape == (3 * m.n_nodes, 3 * m.n_nodes)
