"""Meshes, quadrature rules and boundary integrals against exact values."""

import numpy as np
import pytest

from capsim.numerics.geometry import element_geometry, volume_area
from capsim.numerics.mesh import unit_sphere_mesh
from capsim.numerics.quadrature import REGULAR_ORDERS, singular_rules, triangle_rule, triangle_rule_degree

from conftest import single_layer_tensor


@pytest.mark.parametrize("base,n0", [("octahedron", 8), ("icosahedron", 20)])
def test_mesh_counts_and_orientation(base, n0):
    for level in range(3):
        m = unit_sphere_mesh(base, level)
        assert m.n_elements == n0 * 4**level
        assert m.n_nodes == 2 * m.n_elements + 2
        assert np.allclose(np.linalg.norm(m.positions, axis=1), 1.0)
        geo = element_geometry(m.positions, m.elements)
        # outward normals: n·x > 0 everywhere on the unit sphere
        assert (np.einsum("eqd,eqd->eq", geo.normals, geo.points) > 0.9).all()


def test_volume_area_converge_at_observed_order():
    errs = []
    for level in range(1, 5):
        m = unit_sphere_mesh("octahedron", level)
        V, S = volume_area(element_geometry(m.positions, m.elements, 6))
        errs.append((abs(V / (4 * np.pi / 3) - 1), abs(S / (4 * np.pi) - 1)))
    errs = np.array(errs)
    orders = np.log2(errs[:-1] / errs[1:])  # h halves per level
    print("observed orders V, S:", orders.tolist())
    assert (orders > 3.5).all()  # quadratic elements: O(h⁴) for V and S
    assert errs[2, 0] < 1e-4 and errs[2, 1] < 1e-4  # level 3


@pytest.mark.parametrize("n", REGULAR_ORDERS)
def test_triangle_rules_exact_to_their_degree(n):
    xi, eta, w = triangle_rule(n)
    assert np.isclose(w.sum(), 0.5)
    deg = triangle_rule_degree(n)
    from math import factorial

    for p in range(deg + 1):
        for q in range(deg + 1 - p):
            exact = factorial(p) * factorial(q) / factorial(p + q + 2)
            assert np.isclose((w * xi**p * eta**q).sum(), exact, rtol=1e-12, atol=1e-14)


def test_duffy_rules_integrate_area_and_singularity():
    xi, eta, w = singular_rules(6)
    for k in range(6):
        assert np.isclose(w[k].sum(), 0.5)
    # ∫∫ dξ dη / r from the right-angle corner = ∫_0^{π/2} dφ / (cos φ + sin φ) = √2 ln(1 + √2)
    r0 = np.hypot(xi[0], eta[0])
    assert np.isclose((w[0] / r0).sum(), np.sqrt(2.0) * np.log(1.0 + np.sqrt(2.0)), rtol=1e-6)
    # every node: the 1/r integral converges as the rule is refined (n = 6 vs 24)
    xr, er, wr = singular_rules(24)
    nodes = [(0, 0), (1, 0), (0, 1), (0.5, 0), (0.5, 0.5), (0, 0.5)]
    for k, (a, b) in enumerate(nodes):
        coarse = (w[k] / np.hypot(xi[k] - a, eta[k] - b)).sum()
        fine = (wr[k] / np.hypot(xr[k] - a, er[k] - b)).sum()
        assert abs(coarse / fine - 1) < 1e-6


def test_single_layer_identities_on_level3_sphere(sphere3):
    mesh, disc = sphere3
    x = mesh.positions
    M = single_layer_tensor(disc, x)
    ref = 16 * np.pi / 3
    assert np.abs(M - ref * np.eye(3)).max() / ref < 5e-3
    # ∫ n·G dS = 0 for any closed surface (density = unit normal, nodal values)
    ng = disc.single_layer(x, disc.geometry(x), np.ascontiguousarray(x[mesh.elements]))
    assert np.abs(ng).max() / ref < 5e-3


def test_translating_rigid_sphere(sphere3):
    """Stokes drag: a sphere translating with U carries f = −(3/2)μU/a (uniform),
    and the single layer returns u = −1/(8π) ∫ G·f dS = U on the surface."""
    mesh, disc = sphere3
    x = mesh.positions
    U = np.array([0.3, -0.2, 0.5])
    f = np.tile(-1.5 * U, (mesh.n_elements, 1))
    u = -disc.single_layer(x, disc.geometry(x), f) / (8 * np.pi)
    assert np.abs(u - U).max() < 2e-3 * np.linalg.norm(U)
