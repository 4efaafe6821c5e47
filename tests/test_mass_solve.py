"""The Galerkin traction's mass-matrix solve M·Δf = ∂E/∂x (issue 29, item 3): solved on the
unknowns the mesh's symmetry leaves, preconditioned by a kept factorisation, it gives the
full system's solution; the factorisation's place is part of the model state, so that a
restored model continues bit for bit; the benchmark builds its model with build_model."""

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

from capsim.benchmark import SPLIT_STAGES, _model, bench_case, bench_velocity, split_lines
from capsim.solver import build_model

# a deformed, tilted configuration in the shear plane: it keeps every symmetry of the mesh
_C, _S = np.cos(0.6), np.sin(0.6)
_F = np.diag([1.15, 0.88, 1.0 / (1.15 * 0.88)]) @ np.array([[_C, -_S, 0], [_S, _C, 0], [0, 0, 1]]).T
_STEP = np.eye(3) + 2e-3 * np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])


@pytest.mark.parametrize("symmetry, group, fraction", [
    ("quarter", "mirror_z+rotation_z", 0.27), ("half", "inversion", 0.51),
    ("mirror_z", "mirror_z", 0.53), ("none", "none", 1.0),
])
def test_reduced_solve_is_the_full_solve(symmetry, group, fraction):
    """Δf from the reduced system equals scipy's direct solve of the full M·Δf = b to
    1e-9 (the CG tolerance is 1e-8 of max|b| on the residual; M's condition number is
    about 30), its residual meets that tolerance, it has the configuration's symmetry
    exactly, and the reduced system has about 1/4 (quarter), 1/2 (half, mirror) of the
    full system's unknowns (a node on a mirror plane has a component forced to zero)."""
    model, X = build_model(bench_case(2), symmetry=symmetry)
    disc, membrane = model.disc, model.membrane
    assert disc.symmetry == group
    x = X @ _F
    data = disc.mass_matrix_data(disc.geometry(x))
    rhs = membrane.energy_gradient(x)
    traction, iterations = membrane.solve_mass(x, data, rhs)
    mass = sp.csr_matrix((data, disc.mass_indices, disc.mass_indptr), shape=(disc.n_nodes,) * 2)
    exact = spsolve(mass.tocsc(), rhs)
    scale = np.abs(exact).max()
    assert np.abs(traction - exact).max() <= 1e-9 * scale
    assert np.abs(mass @ traction - rhs).max() <= 1e-8 * np.abs(rhs).max()
    # factored at this very configuration: the first iteration solves
    assert iterations == 1 and membrane.mass_factorizations == 1
    assert membrane.reduced_mass().size <= fraction * 3 * disc.n_nodes
    if group != "none":
        assert np.array_equal(disc.expand(traction[disc.targets]), traction)


def _strain_path(membrane, disc, x, step, n):
    """n solves along x·stepᵏ: (iterations, refactored) of each; every one meets the tolerance."""
    history = []
    for _ in range(n):
        x = x @ step
        before = membrane.mass_factorizations
        state = membrane(x)
        history.append((state.mass_iterations, membrane.mass_factorizations - before))
        data = disc.mass_matrix_data(state.geometry)
        mass = sp.csr_matrix((data, disc.mass_indices, disc.mass_indptr), shape=(disc.n_nodes,) * 2)
        rhs = membrane.energy_gradient(x)
        assert np.abs(mass @ state.traction - rhs).max() <= 1e-8 * np.abs(rhs).max()
    return x, history


def test_kept_factorisation_serves_and_is_replaced_when_it_no_longer_does():
    """Along a path of small strain steps (8 % in all) the factorisation at the start serves
    every solve in at most 3 iterations: the diagonal scaling √(diag K0 / diag K) takes up
    the change of area (without it the same path needed 3-5 iterations and a new factor).
    Along steps ten times larger (80 %) a factor is replaced, at the configuration of a solve
    that needed more than mass_refactor_iterations, and only there."""
    model, X = build_model(bench_case(2))
    membrane, disc = model.membrane, model.disc
    x = X @ _F
    model.velocity(x)
    assert membrane.mass_factorizations == 1
    x, history = _strain_path(membrane, disc, x, _STEP, 40)
    assert membrane.mass_factorizations == 1 and max(its for its, _ in history) <= 3
    _, history = _strain_path(membrane, disc, x, np.eye(3) + 10.0 * (_STEP - np.eye(3)), 40)
    limit = membrane.mass_refactor_iterations
    assert all(refactored == (its > limit) for its, refactored in history)
    assert 1 <= sum(refactored for _, refactored in history) <= 10


def test_restored_model_continues_bit_for_bit():
    """The factorisation's configuration is in the model state (warm_mass_factor_x): a
    model restored from another's state, even one that never factored, gives the same
    velocities to the bit, and a fresh state (no factor) refactors on first use."""
    a, X = build_model(bench_case(2))
    b, _ = build_model(bench_case(2))
    x = X @ _F
    for _ in range(12):
        x = x @ _STEP
        a.velocity(x)
    saved = a.state()
    # factored at the first configuration: b, left alone, would factor at its next one
    assert np.array_equal(saved["warm_mass_factor_x"], X @ _F @ _STEP)
    b.restore(saved)
    for _ in range(5):
        x = x @ _STEP
        assert np.array_equal(a.velocity(x), b.velocity(x))
    assert np.array_equal(a.state()["warm_mass_factor_x"], b.state()["warm_mass_factor_x"])
    b.restore({})
    assert b.membrane._mass_factor is None and b.membrane._mass_factor_x is None
    b.velocity(x)
    assert np.array_equal(b.state()["warm_mass_factor_x"], x)


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
    assert set(r["split_s"]) == {"geometry", "strain", "mass_assembly", "mass_solve", "gather", "interpolation",
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
    solved in full (its residual within the CG tolerance, 1e-8 of max|b|, and scipy's direct
    solve to 1e-7: M's condition number is about 30) and the kept factorisation is untouched;
    a perturbation with the symmetry keeps the reduced solve."""
    model, X = build_model(bench_case(2))
    disc, membrane = model.disc, model.membrane
    x = X @ _F
    model.velocity(x)
    kept = membrane._mass_factor
    v = np.random.default_rng(3).standard_normal(x.shape)
    for probe, reduced in ((x + 1e-7 * v, False), (x + 1e-7 * disc.expand(v[disc.targets]), True)):
        state = membrane(probe)
        data = disc.mass_matrix_data(state.geometry)
        mass = sp.csr_matrix((data, disc.mass_indices, disc.mass_indptr), shape=(disc.n_nodes,) * 2)
        rhs = membrane.energy_gradient(probe)
        exact = spsolve(mass.tocsc(), rhs)
        assert np.abs(mass @ state.traction - rhs).max() <= 1e-8 * np.abs(rhs).max()
        assert np.abs(state.traction - exact).max() <= 1e-7 * np.abs(exact).max()
        assert membrane._mass_factor is kept
        symmetric = np.array_equal(disc.expand(state.traction[disc.targets]), state.traction)
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
