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
    values = sums.values.tolist()  # the row's own path: the stresslet from Python floats, the same arithmetic
    assert np.array_equal(sums.stresslet_of(values, V, 0.1, lam), sums.stresslet(V, 0.1, lam))
    spin = np.ascontiguousarray(np.cross([0.0, 0.0, 0.7], x - c))
    S_spin = row_surface_sums(geo, np.zeros_like(density), rest_weights, spin, elements, phi, c, director)
    assert np.abs(S_spin.stresslet(V, 0.1, lam)).max() < 1e-3


def _vertex_gradient_reference(x, X, elements, n_vertices, vdxi, vdeta):
    """The vertex deformation gradient of seed 3.4 in plain numpy, element by element: per element
    and vertex A_e = [t1 t2 0] [T1 T2 N]⁻¹, the tangents projected on the vertex's angle-weighted
    tangent planes, averaged over the vertex's elements weighted by their angles there."""
    def tangents(y, e, k):
        nodes = y[elements[e]]
        return vdxi[k] @ nodes, vdeta[k] @ nodes

    def normals(y):
        n, w = np.zeros((n_vertices, 3)), np.zeros(n_vertices)
        angles = np.zeros((len(elements), 3))
        for e in range(len(elements)):
            for k in range(3):
                t1, t2 = tangents(y, e, k)
                a, b = [(t1, t2), (-t1, t2 - t1), (-t2, t1 - t2)][k]
                angles[e, k] = np.arctan2(np.linalg.norm(np.cross(a, b)), a @ b)
                m = np.cross(t1, t2)
                n[elements[e, k]] += angles[e, k] * m / np.linalg.norm(m)
                w[elements[e, k]] += angles[e, k]
        return n / np.linalg.norm(n, axis=1)[:, None], w, angles

    n, w, angles = normals(x)
    N, _, _ = normals(X)
    A = np.zeros((n_vertices, 3, 3))
    for e in range(len(elements)):
        for k in range(3):
            v = elements[e, k]
            t = [t - (t @ n[v]) * n[v] for t in tangents(x, e, k)]
            T = [t - (t @ N[v]) * N[v] for t in tangents(X, e, k)]
            A[v] += angles[e, k] / w[v] * np.column_stack([t[0], t[1], np.zeros(3)]) @ np.linalg.inv(
                np.column_stack([T[0], T[1], N[v]]))
    return A, n


def test_vertex_strain_kernel_is_the_seed_gradient_and_its_strain():
    """kernels.vertex_strain (with its rest frames made once, issue 57) against the element-by-element
    gradient of seed 3.4 and membrane.strain_from_gradient's B, Λ1, Λ2, on a deformed, turned surface
    whose rest shape is a sphere; and a rigid turn of the rest shape carries no strain."""
    from capsim.numerics.kernels import vertex_rest_inverse, vertex_strain
    from capsim.numerics.membrane import strain_from_gradient
    from capsim.solve.solver import Discretization

    mesh = unit_sphere_mesh(level=1)
    X = np.ascontiguousarray(mesh.positions)
    disc = Discretization(mesh.elements, mesh.n_vertices)
    x = np.ascontiguousarray(X * np.array([1.3, 0.9, 0.8]) + 0.05 * X[:, [1, 2, 0]] ** 2)
    rest = vertex_rest_inverse(X, disc.elements, disc.n_vertices, disc.vertex_dxi, disc.vertex_deta)[0]
    A, n, B, inv1, inv2, l1, l2 = vertex_strain(x, disc.elements, disc.n_vertices, disc.vertex_dxi, disc.vertex_deta,
                                                rest, disc.all_elements, disc.all_vertices)
    A0, n0 = _vertex_gradient_reference(x, X, disc.elements, disc.n_vertices, disc.vertex_dxi, disc.vertex_deta)
    assert np.allclose(A, A0, rtol=0, atol=1e-13) and np.allclose(n, n0, rtol=0, atol=1e-14)
    reference = strain_from_gradient(A, n)
    assert np.allclose(B, reference.B, rtol=0, atol=1e-13)
    assert np.allclose(inv1, reference.inv1, rtol=0, atol=1e-13) and np.allclose(inv2, reference.inv2, rtol=0, atol=1e-13)
    assert np.allclose(l1, reference.principal_stretches[0], rtol=1e-13) and \
        np.allclose(l2, reference.principal_stretches[1], rtol=1e-13)
    assert np.abs(inv2).max() > 0.05  # the surface is strained
    c, s = np.cos(0.7), np.sin(0.7)
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    _, _, _, inv1, inv2, l1, l2 = vertex_strain(np.ascontiguousarray(X @ turn.T + 5.0), disc.elements, disc.n_vertices,
                                                disc.vertex_dxi, disc.vertex_deta, rest, disc.all_elements,
                                                disc.all_vertices)
    assert np.abs(inv1).max() < 1e-13 and np.abs(inv2).max() < 1e-13
    # the stretches to round-off (λ1² − λ2² from B's deviator: from tr² − 4 det it was √(round-off), 1e-8)
    assert np.abs(l1 - 1.0).max() < 1e-13 and np.abs(l2 - 1.0).max() < 1e-13


@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (3.4, -2.6, 1.0), (1e6 + 0.3, 0.0, -7.0)])
def test_rounded_mean_point_is_the_reference_point(offset):
    """The kernel's reference point is geometry.reference_point's: whole units, the origin at the origin."""
    from capsim.numerics.geometry import reference_point
    from capsim.numerics.kernels import rounded_mean_point

    x, elements = _surface(np.array(offset))
    geo = element_geometry(x, elements)
    p = rounded_mean_point(geo.points)
    assert np.array_equal(p, reference_point(geo)) and np.array_equal(p, np.round(offset))


def _moments_for_the_ellipsoid():
    """Second moments: general, a shape of revolution (about z, about x, about a tilted axis: a
    degenerate pair), a sphere (all three equal), and out of the shear plane's order."""
    rng = np.random.default_rng(7)
    out = []
    for axes in ([1.3, 0.9, 0.6], [1.0, 1.0, 0.4], [0.4, 1.0, 1.0], [1.0, 1.0, 1.0], [0.5, 0.8, 1.6]):
        for _ in range(3):
            q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
            out.append(q @ np.diag(np.square(axes)) @ q.T)
        out.append(np.diag(np.square(axes)))
    return out


@pytest.mark.parametrize("k", range(20))
def test_ellipsoid_kernel_is_the_observers_ellipsoid(k):
    """kernels.ellipsoid_of_moment (the row's, issue 57) gives observables.ellipsoid_of_moment's axes,
    D_xy, θ and axis lines to round-off, degenerate pairs and the undefined θ of a sphere included."""
    from capsim.numerics.kernels import ellipsoid_of_moment as kernel
    from capsim.solve.observables import (
        _ELLIPSOID_COLUMNS, _TIE_BREAK, DEGENERATE_GAP, THETA_UNDEFINED_GAP, ellipsoid_of_moment,
    )

    M = np.ascontiguousarray(_moments_for_the_ellipsoid()[k])
    volume = 4.0 * np.pi / 3.0
    reference = ellipsoid_of_moment(M, volume)
    values = dict(zip(_ELLIPSOID_COLUMNS, kernel(M, volume, _TIE_BREAK, DEGENERATE_GAP, THETA_UNDEFINED_GAP)))
    for key, name in (("L", "axis_L"), ("l", "axis_l"), ("W", "axis_W"), ("D_xy", "D_xy"),
                      ("ellipsoid_a", "ellipsoid_a"), ("ellipsoid_b", "ellipsoid_b"), ("ellipsoid_c", "ellipsoid_c")):
        assert values[name] == pytest.approx(reference[key], rel=1e-12, abs=1e-14), name
    if np.isnan(reference["theta"]):
        assert np.isnan(values["theta"])
    else:
        assert values["theta"] == pytest.approx(reference["theta"], abs=1e-9)
    long_axis = [values[f"long_axis_{c}"] for c in "xyz"]
    short_axis = [values[f"short_axis_{c}"] for c in "xyz"]
    a, b, c = reference["ellipsoid_a"], reference["ellipsoid_b"], reference["ellipsoid_c"]
    if a - b > 1e-6 * a:  # a line is defined where its axis is not degenerate
        assert np.allclose(long_axis, reference["long_axis"], atol=1e-9)
    if b - c > 1e-6 * a:
        assert np.allclose(short_axis, reference["short_axis"], atol=1e-9)


@pytest.mark.parametrize("config", ["configs/sphere.yaml", "configs/rbc.yaml"])
def test_a_rows_strain_at_one_vertex_of_each_orbit_is_the_whole_membranes(config):
    """Under the mesh's symmetry a row reads the strain at one vertex of each orbit (issue 57): the
    largest stretch, the smallest tension and the compressed share are the whole membrane's, on a
    sheared state of the demo's sphere (quarter symmetry) and of the red cell."""
    from pathlib import Path

    from capsim.api import load_case
    from capsim.solve.observables import MaterialDirector, capsule_row
    from capsim.solve.solver import build_model

    root = Path(__file__).resolve().parents[2]
    case = load_case(root / config, sets=["mesh.level=2"])
    model, X = build_model(case)
    assert model.disc.symmetry != "none"
    u0 = model.undisturbed(X)
    x = np.ascontiguousarray(model.disc.expand((X + 0.3 * u0 + 0.05 * X ** 2)[model.disc.targets]))
    state = model.membrane(x)
    strain, counts = state.row_strain
    assert counts is not None and counts.sum() == model.disc.n_vertices and len(counts) < model.disc.n_vertices / 2
    full = state.strain
    u = model.velocity(x, state)
    director = MaterialDirector(model.disc.geometry(X), (0.0, 0.0, 1.0))
    args = (model, x, u, state.geometry, state.density, state.weights)
    orbit_row = capsule_row(*args, strain, model.disc.elements, director, vertex_counts=counts)
    full_row = capsule_row(*args, full, model.disc.elements, director)
    assert full_row["max_principal_stretch"] > 1.05 and full_row["compressed_fraction"] > 0.0
    for key in ("max_principal_stretch", "min_tension"):
        assert orbit_row[key] == pytest.approx(full_row[key], rel=1e-12), key
    assert orbit_row["compressed_fraction"] == full_row["compressed_fraction"]
    assert state.row_strain[0] is full  # once the whole membrane's strain is made, the row reads it


def test_a_membrane_at_rest_has_no_tension_and_no_compressed_vertex():
    """The first row of a run (the rest shape) carries no tension: the principal tensions are round-off
    and no vertex is compressed (until 2026-12-06 the stretches' difference came from tr² − 4 det B,
    √(round-off) = 1e-8 at rest: min_tension −7e-8 G and 24 % of a sphere's vertices 'compressed')."""
    from capsim.numerics.membrane import principal_tensions
    from capsim.api import load_case
    from capsim.solve.solver import build_model
    from pathlib import Path

    case = load_case(Path(__file__).resolve().parents[2] / "configs/sphere.yaml", sets=["mesh.level=2"])
    model, X = build_model(case)
    state = model.membrane(np.ascontiguousarray(model.disc.expand(X[model.disc.targets])))
    for strain in (state.row_strain[0], state.strain):
        l1, l2 = strain.principal_stretches
        assert np.abs(l1 - 1.0).max() < 1e-13 and np.abs(l2 - 1.0).max() < 1e-13
        t1, t2 = principal_tensions(strain, model.law, model.law_params)
        assert np.abs(t1).max() < 1e-12 and np.abs(t2).max() < 1e-12


@pytest.mark.parametrize("law, params", [("thin_shell", {}), ("skalak", {"skalak_c": 10.0}),
                                         ("neo_hookean", {}), ("mooney_rivlin", {"psi": 0.3})])
def test_membrane_row_summary_is_the_principal_tensions(law, params):
    """The row's membrane columns in one pass (kernels.membrane_row_summary) against
    membrane.principal_tensions and numpy: the largest stretch, the smallest τ2 (times a modulus ratio)
    and the compressed share, each vertex counted once or weighted by the vertices it stands for."""
    from capsim.numerics import kernels
    from capsim.numerics.membrane import LAWS, VertexStrain, principal_tensions

    if law not in LAWS:
        pytest.skip(f"no law {law}")
    rng = np.random.default_rng(11)
    n = 40
    F = np.eye(3) + 0.4 * rng.normal(size=(n, 3, 3))
    F[:, :, 2] = 0.0  # the tangent plane's gradient: B = F Fᵀ of rank 2 with normal z
    B = F @ np.transpose(F, (0, 2, 1))
    B[:, 2, :] = B[:, :, 2] = 0.0
    normals = np.tile([0.0, 0.0, 1.0], (n, 1))
    trace = np.einsum("vii->v", B)
    det = B[:, 0, 0] * B[:, 1, 1] - B[:, 0, 1] * B[:, 1, 0]
    inv1, inv2 = 0.5 * np.log(det), 0.5 * trace - 1.0
    strain = VertexStrain(np.zeros((n, 3, 3)), B, normals, inv1, inv2)
    l1, l2 = strain.principal_stretches
    tau1, tau2 = principal_tensions(strain, LAWS[law], params)
    w1, w2 = LAWS[law].derivatives(inv1, inv2, **params)
    w1, w2 = np.broadcast_to(w1, inv1.shape).copy(), np.broadcast_to(w2, inv1.shape).copy()
    threshold = float(np.median(tau2))  # about half the vertices "compressed"
    for modulus in (1.0, 2.5):
        for counts in (np.zeros(0), rng.integers(1, 5, size=n).astype(float)):
            largest, lowest, share = kernels.membrane_row_summary(w1, w2, inv1, l1, l2, modulus, threshold, counts)
            assert largest == np.max(l1)
            assert lowest == pytest.approx(modulus * tau2.min(), rel=1e-14, abs=1e-15)
            below = modulus * tau2 < threshold
            expected = below.mean() if counts.size == 0 else counts @ below / counts.sum()
            assert share == pytest.approx(expected, rel=1e-14)
            assert 0.0 < share < 1.0
