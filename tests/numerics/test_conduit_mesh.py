"""Conduit wall meshes (capsim/numerics/conduit_mesh.py): closed, outward, mirror-symmetric, and
their area and enclosed volume converge to the exact ones like h^4 (quadratic elements; h^3 asked)."""

import numpy as np
import pytest

from capsim.numerics.conduit_mesh import (INLET, OUTLET, SIDE, axial_spacing, axisymmetric_conduit_mesh,
                                          cosine_constriction_radius, duct_mesh, tube_mesh)
from capsim.numerics.geometry import element_geometry, numpy_quadrature, volume_area


def measure(mesh):
    with numpy_quadrature():
        geo = element_geometry(mesh.positions, mesh.elements)
    return geo, *volume_area(geo)


def axisymmetric_exact(r, dr, breaks, L):
    """Area (caps included) and volume of the conduit r(x), |x| <= L/2, by 200-point
    Gauss–Legendre on each piece between ``breaks`` (where r is smooth)."""
    t, w = np.polynomial.legendre.leggauss(200)
    edges = np.concatenate([[-L / 2], breaks, [L / 2]])
    area = np.pi * (r(edges[0]) ** 2 + r(edges[-1]) ** 2)
    volume = 0.0
    for a, b in zip(edges[:-1], edges[1:]):
        x, wx = 0.5 * (a + b) + 0.5 * (b - a) * t, 0.5 * (b - a) * w
        area += 2 * np.pi * wx @ (r(x) * np.sqrt(1 + dr(x) ** 2))
        volume += np.pi * wx @ r(x) ** 2
    return float(area), float(volume)


R, L = 1.0, 6.0
RC, ELL = 0.6, 1.5
cosine = cosine_constriction_radius(R, RC, ELL)
cosine_slope = lambda x: np.where(np.abs(x) < ELL, (R - RC) * 0.5 * np.pi / ELL * np.sin(np.pi * x / ELL), 0.0)
bump = lambda x: R - (R - RC) * np.exp(-np.asarray(x) ** 2)  # C-infinity, unlike the cosine's C1 at |x| = ℓ
bump_slope = lambda x: 2 * (R - RC) * x * np.exp(-x**2)


def relative_errors(build, exact, sizes):
    area, volume = exact
    out = []
    for h in sizes:
        _, v, s = measure(build(h))
        out.append((abs(s - area) / area, abs(v - volume) / volume))
    return np.array(out)


@pytest.mark.parametrize("name", ["tube", "bump", "round caps"])
def test_smooth_conduits_area_and_volume_converge_like_h4(name):
    if name == "tube":
        build = lambda h: tube_mesh(R, L, h, 2 * h, 1.0)
        exact = (2 * np.pi * R * L + 2 * np.pi * R**2, np.pi * R**2 * L)
    elif name == "round caps":  # a tube closed by two hemispheres (the conduit's runs use these ends)
        build = lambda h: tube_mesh(R, L, h, 2 * h, 1.0, caps="round")
        exact = (2 * np.pi * R * L + 4 * np.pi * R**2, np.pi * R**2 * L + 4 / 3 * np.pi * R**3)
    else:
        build = lambda h: axisymmetric_conduit_mesh(bump, L, h, 2 * h, 1.5)
        exact = axisymmetric_exact(bump, bump_slope, [], L)
    errors = relative_errors(build, exact, (0.4, 0.2, 0.1))
    # measured at h = 0.4, 0.2, 0.1, tube: area 2.8e-5, 1.8e-6, 1.1e-7, volume 4.9e-5, 3.1e-6, 1.9e-7
    # (order 4.0); bump: area 3.5e-5, 2.7e-6, 2.1e-7, volume 6.8e-5, 5.2e-6, 4.1e-7 (order 3.7)
    assert np.all(errors[-1] < 2e-6), errors
    order = np.log2(errors[:-1] / errors[1:])
    # the round caps' pole (its ring of fan elements) costs half an order at the coarsest step: 3.3, then 4.0
    assert np.all(order > (3.2 if name == "round caps" else 3.5)), order


def test_cosine_constriction_converges_at_least_like_h3():
    """r'' jumps at |x| = ℓ, which falls anywhere in an element: an O(h³) error whose constant
    oscillates with the stations' phase. Each level stays under 2× the h³ line from the coarsest."""
    sizes = np.array([0.4, 0.2, 0.1, 0.05])
    errors = relative_errors(lambda h: axisymmetric_conduit_mesh(cosine, L, h, 2 * h, 2.0),
                             axisymmetric_exact(cosine, cosine_slope, [-ELL, ELL], L), sizes)
    # measured: area 2.4e-5, 1.3e-6, 2.9e-7, 2.7e-8; volume 4.6e-5, 1.8e-6, 5.7e-7, 5.6e-8
    bound = 2 * errors[0] * (sizes[:, None] / sizes[0]) ** 3
    assert np.all(errors <= bound), (errors, bound)
    assert np.all(errors[-1] < 1e-7), errors


def test_duct_area_and_volume_are_exact():
    a, b = 1.0, 0.5
    for h in (0.4, 0.25):
        _, v, s = measure(duct_mesh(a, b, L, h, 2 * h, 1.0))
        assert s == pytest.approx(2 * (2 * a + 2 * b) * L + 2 * 4 * a * b, rel=1e-13)
        assert v == pytest.approx(4 * a * b * L, rel=1e-13)


MESHES = {
    "tube": lambda: tube_mesh(R, L, 0.3, 0.9, 1.0),
    "tube n_theta=12": lambda: tube_mesh(R, L, 0.5, 1.0, 1.0, n_theta=12),
    "tube round caps": lambda: tube_mesh(R, L, 0.3, 0.9, 1.0, caps="round"),
    "constriction": lambda: axisymmetric_conduit_mesh(cosine, L, 0.3, 0.9, 1.0),
    "duct": lambda: duct_mesh(1.0, 0.6, L, 0.3, 0.9, 1.0),
    "square duct": lambda: duct_mesh(0.5, 0.5, 4.0, 0.5, 0.5, 4.0),
}


@pytest.fixture(scope="module", params=sorted(MESHES))
def mesh(request):
    return MESHES[request.param]()


def test_normals_point_out_of_the_fluid(mesh):
    geo, _, _ = measure(mesh)
    n, p = geo.normals, geo.points
    side = mesh.part == SIDE
    radial = p[side].copy()
    radial[..., 0] = 0.0
    assert np.einsum("eqd,eqd->eq", n[side], radial).min() > 0
    half = 0.5 * mesh.length
    if p[mesh.part == OUTLET][..., 0].max() > half + 1e-9:  # round caps: out of the hemisphere's centre
        for part, sign in ((INLET, -1.0), (OUTLET, 1.0)):
            out = p[mesh.part == part] - [sign * half, 0.0, 0.0]
            assert np.einsum("eqd,eqd->eq", n[mesh.part == part], out).min() > 0
        return
    assert np.abs(n[mesh.part == INLET] - [-1, 0, 0]).max() < 1e-12
    assert np.abs(n[mesh.part == OUTLET] - [1, 0, 0]).max() < 1e-12
    half = 0.5 * mesh.length
    assert np.abs(p[mesh.part == INLET][..., 0] + half).max() < 1e-12
    assert np.abs(p[mesh.part == OUTLET][..., 0] - half).max() < 1e-12


def test_mesh_is_closed_and_consistently_oriented(mesh):
    e = mesh.elements
    directed = np.concatenate([e[:, [0, 1, 3]], e[:, [1, 2, 4]], e[:, [2, 0, 5]]])
    # each directed vertex edge once; its reverse once, carrying the same mid-node
    keys = {(a, b): m for a, b, m in directed.tolist()}
    assert len(keys) == len(directed)
    assert all(keys.get((b, a)) == m for (a, b), m in keys.items())
    assert np.all(e[:, :3] < mesh.n_vertices) and np.all(e[:, 3:] >= mesh.n_vertices)
    assert np.array_equal(np.unique(e), np.arange(mesh.n_nodes))  # every node used
    n_edges = len(directed) // 2
    assert mesh.n_vertices - n_edges + mesh.n_elements == 2  # Euler: a sphere's topology
    assert mesh.n_nodes == mesh.n_vertices + n_edges


def _node_map(x, y):
    """Index j of y matching each row of x (to 1e-12), or fail."""
    d = np.linalg.norm(x[:, None, :] - y[None, :, :], axis=2)
    j = d.argmin(axis=1)
    assert d[np.arange(len(x)), j].max() < 1e-12
    return j


@pytest.mark.parametrize("flip", [[1, -1, 1], [1, 1, -1], [-1, 1, 1]], ids=["y->-y", "z->-z", "x->-x"])
def test_mirror_symmetry(mesh, flip):
    x = mesh.positions
    perm = _node_map(x * flip, x)
    assert len(np.unique(perm)) == len(perm)
    side = mesh.part == SIDE if flip[0] == -1 else slice(None)  # x → −x swaps the caps, which differ
    elements = {tuple(sorted(row)) for row in mesh.elements[side].tolist()}
    mapped = {tuple(sorted(row)) for row in perm[mesh.elements[side]].tolist()}
    assert mapped == elements


def test_nodes_lie_on_the_exact_surface():
    r_of = cosine_constriction_radius(R, RC, ELL)
    m = axisymmetric_conduit_mesh(r_of, L, 0.3, 0.9, 1.0)
    side_nodes = np.unique(m.elements[m.part == SIDE])
    p = m.positions[side_nodes]
    assert np.abs(np.hypot(p[:, 1], p[:, 2]) - r_of(p[:, 0])).max() < 1e-14
    cap_nodes = np.unique(m.elements[m.part != SIDE])
    p = m.positions[cap_nodes]
    assert np.abs(np.abs(p[:, 0]) - L / 2).max() == 0.0
    assert np.hypot(p[:, 1], p[:, 2]).max() <= R * (1 + 1e-15)
    # the axial mid-nodes sit at the stations' midpoints
    stations = axial_spacing(L, 0.3, 0.9, 1.0)
    xs = np.unique(np.round(m.positions[:, 0], 12))
    expected = np.unique(np.round(np.concatenate([stations, 0.5 * (stations[1:] + stations[:-1])]), 12))
    assert np.array_equal(xs, expected)


def test_cap_elements_are_roughly_isotropic():
    from capsim.numerics.geometry import vertex_triangle_quality
    for n_theta in (8, 16, 32, 64):
        m = tube_mesh(R, L, 0.5, 1.0, 1.0, n_theta=n_theta)
        q = vertex_triangle_quality(m.positions, m.elements[m.part != SIDE])
        assert q.min() > 0.6, (n_theta, q.min())


@pytest.mark.parametrize("args", [(10.0, 0.3, 1.0, 1.5, 1.25), (10.0, 0.2, 0.2, 1.0, 1.25), (8.0, 0.1, 2.0, 0.0, 1.1),
                                  (4.0, 0.3, 1.0, 3.0, 1.25), (7.3, 0.17, 0.9, 0.6, 1.5)])
def test_axial_spacing(args):
    length, near, far, near_half, growth = args
    x = axial_spacing(*args)
    dx = np.diff(x)
    assert x[0] == -length / 2 and x[-1] == length / 2
    assert np.array_equal(x, -x[::-1])  # symmetric to the bit
    assert 0.0 in x
    assert dx.min() > 0
    ratio = dx[1:] / dx[:-1]
    assert ratio.max() <= growth * (1 + 1e-12) and ratio.min() >= 1 / growth / (1 + 1e-12)
    assert dx.max() <= far * (1 + 1e-12)
    near_steps = dx[np.maximum(np.abs(x[1:]), np.abs(x[:-1])) <= near_half]
    if near_steps.size:
        assert near_steps.max() <= near * (1 + 1e-12)
        assert near_steps.min() >= near * 0.75   # Δξ = total/n with n >= total, and total >= 6 here
    # the far spacing is reached when there is room: the end steps are within a factor growth of it
    if length / 2 - near_half > 6 * far:
        assert dx[0] >= far / growth


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError):
        axial_spacing(1.0, 0.2, 0.1, 0.2)
    with pytest.raises(ValueError):
        tube_mesh(1.0, 2.0, 0.3, 0.3, 1.0, n_theta=10)
