"""The Galerkin traction's mass-matrix solve (issue 29, item 3): the force per unit rest area F
solves M0·F = ∂E/∂x with the rest shape's mass matrix M0, on the unknowns the mesh's symmetry
leaves, by a factorisation made once; it equals the full system's solution, has the moments of
the traction per unit current area, and carries no state, so a restored model continues bit for
bit; the benchmark builds its model with build_model."""

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

from capsim.runs.benchmark import SPLIT_STAGES, _model, bench_case, bench_velocity, split_lines
from capsim.solve.solver import build_model

# a deformed, tilted configuration in the shear plane: it keeps every symmetry of the mesh
_C, _S = np.cos(0.6), np.sin(0.6)
_F = np.diag([1.15, 0.88, 1.0 / (1.15 * 0.88)]) @ np.array([[_C, -_S, 0], [_S, _C, 0], [0, 0, 1]]).T
_STEP = np.eye(3) + 2e-3 * np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])


def _mass(disc, geo) -> sp.csr_matrix:
    return sp.csr_matrix((disc.mass_matrix_data(geo), disc.mass_indices, disc.mass_indptr), shape=(disc.n_nodes,) * 2)


@pytest.mark.parametrize("symmetry, group, fraction", [
    ("quarter", "mirror_z+rotation_z", 0.27), ("half", "inversion", 0.51),
    ("mirror_z", "mirror_z", 0.53), ("none", "none", 1.0),
])
def test_reduced_solve_is_the_full_solve(symmetry, group, fraction):
    """F from the reduced system's factor equals scipy's direct solve of the full M0·F = b to
    1e-12 (a direct solve; M0's condition number is about 30), it has the configuration's
    symmetry exactly, and the reduced system has about 1/4 (quarter), 1/2 (half, mirror) of
    the full system's unknowns (a node on a mirror plane has a component forced to zero)."""
    model, X = build_model(bench_case(2), symmetry=symmetry)
    disc, membrane = model.disc, model.membrane
    assert disc.symmetry == group
    x = X @ _F
    state = membrane(x)
    rhs = membrane.energy_gradient(x)
    exact = spsolve(_mass(disc, disc.geometry(X)).tocsc(), rhs)
    assert np.abs(state.rest_traction - exact).max() <= 1e-12 * np.abs(exact).max()
    assert membrane.reduced_mass().size <= fraction * 3 * disc.n_nodes
    if group != "none":
        assert np.array_equal(disc.expand(state.rest_traction[disc.targets]), state.rest_traction)


def test_rest_traction_has_the_moments_of_the_current_traction():
    """∫ φ_i F dA0 = ∫ φ_i Δf dA = ∂E/∂x_i: the traction per unit current area (solved when
    read, M(x)·Δf = ∂E/∂x) and the rest traction give the same integral of every quadratic,
    so the same elastic stresslet ∫ Δf x dS to 1e-12, while the fields themselves differ by
    the change of area (here up to ~15 %); the factor is made once along a path of strain."""
    model, X = build_model(bench_case(2))
    disc, membrane = model.disc, model.membrane
    x = X @ _F
    for _ in range(5):
        x = x @ _STEP
        state = membrane(x)
        factor = membrane.traction_solve._factor
        rhs = membrane.energy_gradient(x)
        geo = state.geometry
        assert np.abs(_mass(disc, geo) @ state.traction - rhs).max() <= 1e-12 * np.abs(rhs).max()
        moments = [np.einsum("qa,ead,eq,eqj->dj", disc.reg_phi, f[disc.elements], w, geo.points)
                   for f, w in ((state.rest_traction, state.weights), (state.traction, geo.weights))]
        assert np.abs(moments[0] - moments[1]).max() <= 1e-12 * np.abs(moments[1]).max()
        assert np.abs(state.rest_traction - state.traction).max() >= 0.02 * np.abs(state.traction).max()
    assert membrane.traction_solve._factor is factor


def test_restored_model_continues_bit_for_bit():
    """The rest traction's solve keeps no state: a model restored from another's state gives
    the same velocities to the bit, and the warm-start entries of earlier versions' checkpoints
    (warm_traction, warm_mass_factor_x) are taken and change nothing."""
    a, X = build_model(bench_case(2))
    b, _ = build_model(bench_case(2))
    x = X @ _F
    for _ in range(12):
        x = x @ _STEP
        a.velocity(x)
    saved = a.state()
    assert "warm_traction" not in saved and "warm_mass_factor_x" not in saved
    b.restore({**saved, "warm_traction": np.ones(X.shape), "warm_mass_factor_x": X})
    for _ in range(5):
        x = x @ _STEP
        assert np.array_equal(a.velocity(x), b.velocity(x))


def test_benchmark_model_is_the_run_model():
    """The benchmark's model is build_model's: the same velocity to the bit as the model a
    run builds from the same case; the mirror alone, not a case setting, is the builder's
    symmetry override, and an unknown override is refused naming it."""
    case = bench_case(1)
    bench_model, X = _model(case, True)
    run_model, Y = build_model(case)
    assert np.array_equal(X, Y)
    assert np.array_equal(bench_model.velocity(X @ _F), run_model.velocity(Y @ _F))
    assert _model(case, "mirror_z")[0].disc.symmetry == "mirror_z"
    assert _model(case, False)[0].disc.symmetry == "none"
    with pytest.raises(ValueError, match="symmetry = 'sideways': must be one of auto, quarter"):
        build_model(case, symmetry="sideways")


def test_bench_prints_the_split_per_stage():
    """capsim bench's split: every stage of an evaluation at λ = 1 is timed (and only
    those of the registry), the Stokeslet sum among them, and the lines name each."""
    r = bench_velocity(level=1, repeat=2, compare_symmetry=False)
    assert set(r["split_s"]) == {"geometry", "strain", "mass_solve", "gather", "interpolation",
                                 "stokeslet_sum", "singular_correction", "expand", "far_field", "normals",
                                 "volume_correction"}
    assert set(r["split_s"]) <= set(SPLIT_STAGES)
    assert all(v > 0.0 for v in r["split_s"].values())
    lines = split_lines(r)
    assert all(stage in lines for stage in r["split_s"]) and "outside the Stokeslet sum" in lines
    r5 = bench_velocity(level=1, viscosity_ratio=5.0, repeat=1, compare_symmetry=False)
    assert "double_layer_solve" in r5["split_s"]


def test_configuration_without_the_symmetry_is_solved_in_full():
    """A finite-difference probe x + εv with a random v (ε = 1e-7) has no symmetry: its
    energy gradient is not equivariant, and the reduced system would drop that part. It is
    solved in full (scipy's direct solve of M0·F = b to 1e-12) and the reduced factor is
    untouched; a perturbation with the symmetry keeps the reduced solve."""
    model, X = build_model(bench_case(2))
    disc, membrane = model.disc, model.membrane
    x = X @ _F
    model.velocity(x)
    kept = membrane.traction_solve._factor
    mass0 = _mass(disc, disc.geometry(X)).tocsc()
    v = np.random.default_rng(3).standard_normal(x.shape)
    for probe, reduced in ((x + 1e-7 * v, False), (x + 1e-7 * disc.expand(v[disc.targets]), True)):
        state = membrane(probe)
        exact = spsolve(mass0, membrane.energy_gradient(probe))
        assert np.abs(state.rest_traction - exact).max() <= 1e-12 * np.abs(exact).max()
        assert membrane.traction_solve._factor is kept
        symmetric = np.array_equal(disc.expand(state.rest_traction[disc.targets]), state.rest_traction)
        assert symmetric == reduced


@pytest.mark.parametrize("symmetry", ["quarter", "half", "mirror_z", "none"])
def test_reduced_system_from_the_target_rows_is_that_of_the_whole_mesh(symmetry):
    """An evaluation assembles the strain, the energy gradient and the mass matrix only on
    the elements holding a target node (about a third of them under quarter symmetry) and
    builds the reduced system K y = Eᵀ b from the target nodes' rows, each weighted by its
    orbit's size: equal to the reduced system of the whole mesh's M and b to 1e-13."""
    model, X = build_model(bench_case(2), symmetry=symmetry)
    disc, membrane = model.disc, model.membrane
    reduced = membrane.reduced_mass()
    x = X @ _F
    geo = disc.geometry(x)
    elems = disc.target_elements
    if symmetry == "quarter":
        assert elems.size <= 0.45 * disc.elements.shape[0]  # 55 of 128 (level 3: 175 of 512)
    full_m, part_m = disc.mass_matrix_data(geo), disc.mass_matrix_data(geo, elems)
    # Eᵀ (M ⊗ I₃) E over every node, in K's pattern
    valid = reduced.col >= 0
    rows = (3 * np.arange(disc.n_nodes)[:, None] + np.arange(3)[None, :])[valid]
    E = sp.csr_matrix((reduced.sign[valid], (rows, reduced.col[valid])), shape=(3 * disc.n_nodes, reduced.size))
    mass = sp.csr_matrix((full_m, disc.mass_indices, disc.mass_indptr), shape=(disc.n_nodes,) * 2)
    k_dense = (E.T @ sp.kron(mass, sp.identity(3)) @ E).toarray()
    pattern_rows = np.repeat(np.arange(reduced.size), np.diff(reduced.indptr))
    k_full, k_rows = k_dense[pattern_rows, reduced.indices], reduced.data_from_target_rows(part_m)
    assert np.abs(k_rows - k_full).max() <= 1e-13 * np.abs(k_full).max()
    full_b, part_b = membrane.energy_gradient(x), membrane._energy_gradient(x, elems)
    assert np.abs(part_b[disc.targets] - full_b[disc.targets]).max() <= 1e-13 * np.abs(full_b).max()
    b_full = np.zeros(reduced.size)  # Eᵀ b over every node
    valid = reduced.col >= 0
    np.add.at(b_full, reduced.col[valid], (reduced.sign * full_b)[valid])
    b_rows = reduced.rhs_from_target_rows(part_b)
    assert np.abs(b_rows - b_full).max() <= 1e-13 * np.abs(b_full).max()
