"""Symmetries of the problem (issue 14): the mirror z → −z and the rotation by π
about the z-axis, (x, y, z) → (−x, −y, z), map simple shear and every rest shape
(tilted about z) onto themselves; together they let the boundary integrals be
evaluated at one node of each orbit of four (about a quarter of the nodes)."""

import numpy as np
import pytest

from capsim.config import case_from_dict
from capsim.numerics.membrane import MembraneForce
from capsim.numerics.mesh import rest_shape_mesh
from capsim.runs.runner import run_case
from capsim.solve.solver import CapsuleModel, Discretization, FarField, build_model
from capsim.storage.store import read_trajectory

GROUP = {"mirror": np.array([1.0, 1.0, -1.0]), "rotation": np.array([-1.0, -1.0, 1.0])}
SHAPES = [
    ("sphere", {}, 0.0),
    ("oblate", {"aspect_ratio": 0.5}, 30.0),
    ("prolate", {"aspect_ratio": 1.6}, 17.0),
    ("biconcave", {}, 45.0),
]


def _is_symmetric(values, x, signs, scale=1.0):
    """values(S x) = S values(x) to the bit, node by node."""
    from scipy.spatial import cKDTree

    _, image = cKDTree(x).query(x * signs)
    assert np.abs(x[image] - x * signs).max() == 0.0
    return np.array_equal(values[image], values * signs)


@pytest.mark.parametrize("base", ["octahedron", "icosahedron"])
@pytest.mark.parametrize("kind,params,tilt", SHAPES)
def test_every_rest_shape_has_the_group_of_four(base, kind, params, tilt):
    mesh = rest_shape_mesh(kind, base, 2, tilt, **params)
    disc = Discretization(mesh.elements, mesh.n_vertices)
    X = disc.enable_symmetry(mesh.positions)
    assert disc.symmetry == "mirror_z+rotation_z"
    n = mesh.n_nodes
    # orbits of 4, except the nodes on z = 0 and the two poles on the z-axis (orbits of 2)
    assert n / 4 <= disc.targets.size <= n / 4 + np.sqrt(n)
    assert np.abs(X - mesh.positions).max() < 1e-12
    normals = disc.nodal_normals(X)
    for signs in GROUP.values():
        assert _is_symmetric(X, X, signs)
        assert _is_symmetric(normals, X, signs)


def test_a_mesh_without_the_rotation_falls_back_to_the_mirror_and_then_to_none():
    mesh = rest_shape_mesh("oblate", "octahedron", 1, 20.0, aspect_ratio=0.6)
    cases = {
        (0.0, 0.1, 0.0): "mirror_z",      # off the z-axis: no rotation
        (0.0, 0.0, 0.1): "rotation_z",    # off z = 0: no mirror
        (0.1, 0.0, 0.1): "none",
    }
    for shift, expected in cases.items():
        disc = Discretization(mesh.elements, mesh.n_vertices)
        X = disc.enable_symmetry(mesh.positions + np.array(shift))
        assert disc.symmetry == expected
        assert (X is None) == (expected == "none")
        if expected == "none":
            assert disc.targets.size == mesh.n_nodes
    disc = Discretization(mesh.elements, mesh.n_vertices)
    disc.enable_mirror_symmetry(mesh.positions)
    assert disc.symmetry == "mirror_z"


@pytest.mark.parametrize("base", ["octahedron", "icosahedron"])
@pytest.mark.parametrize("kind,params,tilt", SHAPES)
def test_the_image_search_finds_what_a_kd_tree_finds(base, kind, params, tilt):
    """solver._images_within (no scipy.spatial at start-up, issue 29) gives cKDTree's nearest
    node wherever every node has an image within the tolerance, and None where one has not."""
    from scipy.spatial import cKDTree

    from capsim.solve.solver import _images_within

    x = rest_shape_mesh(kind, base, 2, tilt, **params).positions
    tol = 1e-9 * np.abs(x).max()
    signs = [*GROUP.values(), GROUP["mirror"] * GROUP["rotation"], np.array([1.0, -1.0, 1.0])]
    for points in (x, x + np.random.default_rng(3).normal(scale=1e-4, size=x.shape)):
        for g in signs:
            dist, image = cKDTree(points).query(points * g)
            found = _images_within(points, points * g, tol)
            if dist.max() <= tol:
                np.testing.assert_array_equal(found, image)
            else:
                assert found is None


@pytest.mark.parametrize("symmetry, group, orbits", [
    ("quarter", "mirror_z+rotation_z", 32), ("half", "inversion", 64), ("mirror_z", "mirror_z", 64), ("none", "none", 128),
])
def test_the_flux_of_an_equivariant_field_over_element_orbits_is_the_whole_flux(symmetry, group, orbits):
    """u·n is the same on every element of an orbit when u has the mesh's symmetry: the
    velocity's volume correction sums one element of each orbit times its size (a quarter of
    the elements under quarter symmetry), equal to the sum over every element to 1e-13 for the
    nodal normals (flux ≈ the area) and a velocity; the orbits' sizes add up to the elements."""
    spec = {"name": "m", "mesh": {"level": 2}, "shape": {"kind": "prolate", "aspect_ratio": 2.0},
            "initial_tilt_deg": 30.0}
    model, X = build_model(case_from_dict(spec), symmetry=symmetry)
    disc = model.disc
    assert disc.symmetry == group and disc.orbit_elements.size == orbits
    assert disc.orbit_sizes.sum() == disc.elements.shape[0]
    x = X * np.array([1.1, 0.95, 1.0])
    geo = disc.geometry(x)
    u = model.velocity(x)
    u = u + 0.3 * disc.nodal_normals(x)  # a field with a net flux
    for field in (disc.nodal_normals(x), u):
        whole, by_orbit = disc.flux(geo, field), disc.flux(geo, field, equivariant=True)
        assert abs(by_orbit - whole) <= 1e-13 * np.einsum("eq->", geo.weights) * np.abs(field).max()


def test_a_flow_without_the_symmetry_is_refused():
    mesh = rest_shape_mesh("sphere", "octahedron", 1)
    disc = Discretization(mesh.elements, mesh.n_vertices)
    X = disc.enable_symmetry(mesh.positions)
    forces = MembraneForce(disc, X)
    extensional = FarField(np.diag([1.0, -0.5, -0.5]))  # invariant under both: accepted
    CapsuleModel(disc=disc, membrane=forces, shear_rate_G=0.1, far_field=extensional)
    with pytest.raises(ValueError, match="not invariant"):
        CapsuleModel(disc=disc, membrane=forces, shear_rate_G=0.1, far_field=FarField([[0, 0, 1], [0, 0, 0], [0, 0, 0]]))


@pytest.mark.parametrize("lam", [1.0, 5.0])
def test_quarter_symmetry_gives_the_velocity_of_every_node(lam):
    """A deformed tilted oblate: velocity with the group of four = velocity with
    every node integrated, to 1e-10, and at a quarter of the layer work."""
    mesh = rest_shape_mesh("oblate", "icosahedron", 2, 30.0, aspect_ratio=0.6)
    models = {}
    for sym in ("none", "mirror_z", "mirror_z+rotation_z"):
        disc = Discretization(mesh.elements, mesh.n_vertices)
        X = mesh.positions
        if sym != "none":
            X = disc.enable_symmetry(X, rotation=sym != "mirror_z")
            assert disc.symmetry == sym
        models[sym] = (CapsuleModel(
            disc=disc, membrane=MembraneForce(disc, X), shear_rate_G=0.1, viscosity_ratio=lam, solver_tol=1e-12,
        ), X)
    X = models["mirror_z+rotation_z"][1]
    x = X @ np.diag([1.2, 0.85, 1.0 / 1.02])  # keeps both symmetries, changes the shape
    u = {k: m.velocity(x) for k, (m, _) in models.items()}
    scale = np.abs(u["none"]).max()
    for k in ("mirror_z", "mirror_z+rotation_z"):
        assert np.abs(u[k] - u["none"]).max() / scale < 1e-10
    for signs in GROUP.values():
        assert _is_symmetric(u["mirror_z+rotation_z"], x, signs)
    m = models["mirror_z+rotation_z"][0]
    assert m.counts["velocity_evaluations"] == 1 and m.counts["single_layer_applications"] == 1
    if lam != 1.0:
        assert m.last_solve_info["residual"] <= 1e-11
        assert m.counts["double_layer_applications"] >= m.last_solve_info["iterations"] >= 1


def _series(tmp_path, kind, params, tilt, lam, sym):
    case = case_from_dict(
        {
            "name": f"sym-{kind}-{lam}-{sym}",
            "shape": {"kind": kind, **params},
            "initial_tilt_deg": tilt,
            "flow": {"shear_rate_G": 0.1, "viscosity_ratio": lam},
            "mesh": {"level": 1, "symmetry": sym},
            "time": {"t_end": 0.4},
            "solver": {"tol": 1e-10},
            "output": {"path": str(tmp_path / f"{kind}-{lam}-{sym}.h5")},
        }
    )
    assert build_model(case)[0].disc.symmetry == ("mirror_z+rotation_z" if sym else "none")
    summary = run_case(case)
    assert summary["status"] == "completed"
    return read_trajectory(case.output.path)["timeseries"]


@pytest.mark.parametrize("lam", [1.0, 5.0])
@pytest.mark.parametrize("kind,params,tilt", [("sphere", {}, 0.0), ("oblate", {"aspect_ratio": 0.6}, 30.0)])
def test_quarter_symmetry_changes_nothing_but_the_cost(tmp_path, kind, params, tilt, lam):
    full = _series(tmp_path, kind, params, tilt, lam, False)
    quarter = _series(tmp_path, kind, params, tilt, lam, True)
    assert len(full["t"]) == len(quarter["t"])
    for key in ("t", "D_xy", "theta"):
        np.testing.assert_allclose(quarter[key], full[key], rtol=0, atol=1e-10, err_msg=key)


def _element_orbits_by_tuples(elements, perms):
    """The element orbits as the dict of sorted node tuples found them (before issue 57's numpy keys)."""
    index = {tuple(sorted(e)): i for i, e in enumerate(elements.tolist())}
    images = np.array([[index[tuple(sorted(p[e]))] for e in elements.tolist()] for p in perms])
    reps = np.flatnonzero(images.min(axis=0) == np.arange(elements.shape[0]))
    return reps, np.array([np.unique(images[:, r]).size for r in reps], dtype=np.float64)


@pytest.mark.parametrize("base", ["octahedron", "icosahedron"])
@pytest.mark.parametrize("kind,params,tilt", SHAPES)
@pytest.mark.parametrize("mode", ["auto", "mirror_z", "half"])
def test_the_element_orbits_are_those_of_the_sorted_node_tuples(base, kind, params, tilt, mode):
    """solver._element_orbits (integer keys of each element's sorted vertices) finds the orbits and their
    sizes that the node tuples of its first version found, for every group a rest shape has."""
    from capsim.solve import solver

    mesh = rest_shape_mesh(kind, base, 2, tilt, **params)
    seen = {}
    original = solver._element_orbits
    solver._element_orbits = lambda elements, perms: seen.setdefault("args", (elements, perms)) and original(
        elements, perms)
    try:
        disc = Discretization(mesh.elements, mesh.n_vertices)
        if disc.enable_symmetry(mesh.positions, mode=mode) is None:
            pytest.skip(f"{kind} has no {mode} group")
    finally:
        solver._element_orbits = original
    elements, perms = seen["args"]
    reps, sizes = original(elements, perms)
    reference_reps, reference_sizes = _element_orbits_by_tuples(elements, perms)
    assert np.array_equal(reps, reference_reps) and np.array_equal(sizes, reference_sizes)
    assert sizes.sum() == elements.shape[0] and len(perms) >= 1
