"""The per-step observables' numba kernels (issue 57) against the numpy integrals they replace:
the same values to round-off, on a deformed, turned and displaced surface (far from the origin too)."""

import numpy as np
import pytest

from capsim.numerics.geometry import (
    centroid, element_geometry, min_quality, numpy_quadrature, second_moment, shape_functions, surface_moments,
    vertex_triangle_quality, volume_area,
)
from capsim.numerics.mesh import unit_sphere_mesh
from capsim.numerics.quadrature import triangle_rule


def _surface(offset):
    """A level-2 sphere stretched to an ellipsoid (2, 1, 0.5), turned about z and y, moved by `offset`."""
    mesh = unit_sphere_mesh(level=2)
    x = mesh.positions * np.array([2.0, 1.0, 0.5])
    c, s = np.cos(0.4), np.sin(0.4)
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    return np.ascontiguousarray(x @ turn.T + offset), mesh.elements


@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (3.0, -2.0, 1.0), (1e6, 0.0, 0.0)])
def test_surface_moments_are_the_numpy_integrals(offset):
    x, elements = _surface(np.array(offset))
    geo = element_geometry(x, elements)
    V, S, c, M = surface_moments(geo)
    V0, S0 = volume_area(geo)
    c0 = centroid(geo, V0)
    M0 = second_moment(geo, c0)
    assert V == pytest.approx(V0, rel=1e-12) and S == pytest.approx(S0, rel=1e-12)
    assert np.allclose(c, c0, rtol=0, atol=1e-11 * max(1.0, np.abs(offset).max()) ** 0.5)
    assert np.allclose(M, M0, rtol=0, atol=1e-12 * np.abs(M0).max()) and np.allclose(M, M.T, atol=0)
    # and the known answer: an ellipsoid (2, 1, 0.5) has V = 4π/3 and ∫ x_i² dV = V a_i²/5 in its frame
    assert V == pytest.approx(4 * np.pi / 3, rel=2e-3)
    assert np.sort(np.linalg.eigvalsh(M)) == pytest.approx(V0 / 5 * np.array([0.25, 1.0, 4.0]), rel=1e-2)
    with numpy_quadrature():  # the numpy path (a check before a run): the same numbers
        V1, S1, c1, M1 = surface_moments(geo)
    assert (V1, S1) == (V0, S0) and np.array_equal(c1, c0) and np.array_equal(M1, M0)


def _reynolds_velocity(geo, u, elements, phi, c, V):
    """dc/dt by the numpy einsums the row's kernel replaced: U + ∮ (x − c) ((u − U)·n) dS / V."""
    Um = u.mean(axis=0)
    uq = np.einsum("qk,ekc->eqc", phi, u[elements] - Um)
    flux = np.einsum("eqc,eqc->eq", uq, geo.normals) * geo.weights
    return Um + np.einsum("eq,eqc->c", flux, geo.points - c) / V


def _kernel_velocity(geo, u, elements, phi, c, V):
    """dc/dt by the row's one-pass kernel (capsim.solve.observables.row_surface_sums)."""
    from capsim.solve.observables import MaterialDirector, row_surface_sums

    density = np.zeros((elements.shape[0], 6, 3))
    director = MaterialDirector(geo, (0.0, 0.0, 1.0))
    return row_surface_sums(geo, density, geo.weights, np.ascontiguousarray(u), elements, phi, c,
                            director).centroid_velocity(V)


def test_centroid_velocity_kernel_is_the_reynolds_integral():
    """A rigid motion U + ω × (x − c) moves the centroid at U; a uniform expansion u = x − c leaves it;
    and a general field gives the numpy einsum's value to round-off."""
    x, elements = _surface(np.array([3.0, -2.0, 1.0]))
    geo = element_geometry(x, elements)
    V, _, c, _ = surface_moments(geo)
    xi, eta, _ = triangle_rule(6)
    phi = shape_functions(xi, eta)[0]
    U, w = np.array([0.3, -0.2, 0.1]), np.array([0.0, 0.0, 0.5])
    rigid = U + np.cross(w, x - c)
    assert _kernel_velocity(geo, rigid, elements, phi, c, V) == pytest.approx(U, abs=1e-4)
    rng = np.random.default_rng(57)
    u = np.ascontiguousarray(rng.normal(size=x.shape))
    expected = _reynolds_velocity(geo, u, elements, phi, c, V)
    got = _kernel_velocity(geo, u, elements, phi, c, V)
    assert np.allclose(got, expected, rtol=0, atol=1e-13 * np.abs(expected).max() + 1e-15)


def test_min_quality_is_the_smallest_vertex_triangle_quality():
    x, elements = _surface(np.zeros(3))
    assert min_quality(x, elements) == pytest.approx(vertex_triangle_quality(x, elements).min(), rel=1e-13)
    # an equilateral triangle is 1, a flattened one tends to 0
    tri = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, np.sqrt(3) / 2, 0.0], [0.5, 1e-3, 0.0]])
    assert min_quality(tri, np.array([[0, 1, 2]])) == pytest.approx(1.0, rel=1e-14)
    assert min_quality(tri, np.array([[0, 1, 2], [0, 1, 3]])) == pytest.approx(4 * np.sqrt(3) * 5e-4 / 1.500002, rel=1e-6)


@pytest.mark.parametrize("lam", [1.0, 5.0])
@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (3.0, -2.0, 1.0), (1e4, 0.0, 0.0)])
def test_row_sums_are_the_director_centroid_velocity_and_stresslet(offset, lam):
    """The row's one-pass surface integrals (capsule_row) against the numpy functions they replace:
    MaterialDirector, the Reynolds integral of the centroid's velocity and particle_stresslet (element-nodal
    Δf, and the contour method's element-constant one), on a turned, displaced ellipsoid with a random
    traction (per a rest measure of other weights) and velocity; and a known answer: a rigid rotation's
    stresslet has no velocity term (∫ (ω × y) n + n (ω × y) dS = 0, symmetric part)."""
    from capsim.solve.observables import MaterialDirector, particle_stresslet, row_surface_sums

    x, elements = _surface(np.array(offset))
    geo = element_geometry(x, elements)
    V, _, c, _ = surface_moments(geo)
    xi, eta, _ = triangle_rule(6)
    phi = shape_functions(xi, eta)[0]
    rng = np.random.default_rng(5)
    u = np.ascontiguousarray(rng.normal(size=x.shape))
    density = rng.normal(size=(elements.shape[0], 6, 3))
    rest_weights = geo.weights * (1.0 + 0.1 * rng.random(geo.weights.shape))  # "per unit rest area"
    rest = element_geometry(_surface(np.zeros(3))[0] * 0.9, elements)
    director = MaterialDirector(rest, (0.0, 0.0, 1.0))
    sums = row_surface_sums(geo, density, rest_weights, u, elements, phi, c, director)
    scale = max(1.0, float(np.abs(offset).max()))
    assert np.allclose(sums.director, director(geo), rtol=0, atol=1e-12 * scale)
    expected_v = _reynolds_velocity(geo, u, elements, phi, c, V)
    got_v = sums.centroid_velocity(V)
    assert np.allclose(got_v, expected_v, rtol=0, atol=1e-12)
    S0 = particle_stresslet(geo, density, u, elements, phi, c, V, 0.1, lam, rest_weights)
    assert np.allclose(sums.stresslet(V, 0.1, lam), S0, rtol=0, atol=1e-12 * np.abs(S0).max())
    constant = density.mean(axis=1)  # the contour method's element-constant Δf
    S1 = particle_stresslet(geo, constant, u, elements, phi, c, V, 0.1, lam, rest_weights)
    S1_sums = row_surface_sums(geo, constant, rest_weights, u, elements, phi, c, director).stresslet(V, 0.1, lam)
    assert np.allclose(S1_sums, S1, rtol=0, atol=1e-12 * np.abs(S1).max())
    spin = np.ascontiguousarray(np.cross([0.0, 0.0, 0.7], x - c))
    S_spin = row_surface_sums(geo, np.zeros_like(density), rest_weights, spin, elements, phi, c, director)
    assert np.abs(S_spin.stresslet(V, 0.1, lam)).max() < 1e-3
