"""The Galerkin traction's solve per unit current area (a clean drop, law surface_tension: its
nodes drift with the surface flow and its rest shape means nothing; membrane.CurrentTractionSolve):
M(x)·Δf = ∂E/∂x on the unknowns the mesh's symmetry leaves, by conjugate gradients preconditioned
by a kept factorisation, gives the full system's solution; the factorisation's place is part of
the model state, so that a restored model continues bit for bit."""

import numpy as np
import pytest
from scipy.sparse.linalg import spsolve

from capsim.config import case_from_dict
from capsim.solve.solver import build_model

# a deformed, tilted configuration in the shear plane: it keeps every symmetry of the mesh
_C, _S = np.cos(0.6), np.sin(0.6)
_F = np.diag([1.15, 0.88, 1.0 / (1.15 * 0.88)]) @ np.array([[_C, -_S, 0], [_S, _C, 0], [0, 0, 1]]).T
_STEP = np.eye(3) + 2e-3 * np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])


def _drop(symmetry: str = "auto"):
    """A level-2 clean drop's model with the builder's symmetry setting (the mirror alone is not a case setting)."""
    case = case_from_dict({"name": "drop", "membrane": {"law": "surface_tension"}, "mesh": {"level": 2},
                           "flow": {"shear_rate_G": 0.1}})
    return build_model(case, symmetry=symmetry)


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
    model, X = _drop(symmetry)
    disc, membrane = model.disc, model.membrane
    assert disc.symmetry == group and membrane.traction_solve.name == "current"
    x = X @ _F
    state = membrane(x)
    traction, iterations = state.traction, state.mass_iterations
    rhs = membrane.energy_gradient(x)
    mass = disc.mass_matrix(state.geometry)
    exact = spsolve(mass.tocsc(), rhs)
    scale = np.abs(exact).max()
    assert state.measure is None and state.rest_traction is None
    assert np.abs(traction - exact).max() <= 1e-9 * scale
    assert np.abs(mass @ traction - rhs).max() <= 1e-8 * np.abs(rhs).max()
    # factored at this very configuration: the first iteration solves
    assert iterations == 1 and membrane.traction_solve.factorizations == 1
    assert membrane.reduced_mass().size <= fraction * 3 * disc.n_nodes
    if group != "none":
        assert np.array_equal(disc.expand(traction[disc.targets]), traction)


def _strain_path(membrane, disc, x, step, n):
    """n solves along x·stepᵏ: (iterations, refactored) of each; every one meets the tolerance."""
    history = []
    for _ in range(n):
        x = x @ step
        before = membrane.traction_solve.factorizations
        state = membrane(x)
        history.append((state.mass_iterations, membrane.traction_solve.factorizations - before))
        mass = disc.mass_matrix(state.geometry)
        rhs = membrane.energy_gradient(x)
        assert np.abs(mass @ state.traction - rhs).max() <= 1e-8 * np.abs(rhs).max()
    return x, history


def test_kept_factorisation_serves_and_is_replaced_when_it_no_longer_does():
    """Along a path of small strain steps (8 % in all) the factorisation at the start serves
    every solve in at most 3 iterations: the diagonal scaling √(diag K0 / diag K) takes up
    the change of area (without it the same path needed 3-5 iterations and a new factor).
    Along steps ten times larger (80 %) a factor is replaced, at the configuration of a solve
    that needed more than mass_refactor_iterations, and only there."""
    model, X = _drop()
    membrane, disc = model.membrane, model.disc
    x = X @ _F
    model.velocity(x)
    assert membrane.traction_solve.factorizations == 1
    x, history = _strain_path(membrane, disc, x, _STEP, 40)
    assert membrane.traction_solve.factorizations == 1 and max(its for its, _ in history) <= 3
    _, history = _strain_path(membrane, disc, x, np.eye(3) + 10.0 * (_STEP - np.eye(3)), 40)
    limit = membrane.traction_solve.refactor_iterations
    assert all(refactored == (its > limit) for its, refactored in history)
    assert 1 <= sum(refactored for _, refactored in history) <= 10


def test_restored_model_continues_bit_for_bit():
    """The factorisation's configuration is in the model state (warm_mass_factor_x): a
    model restored from another's state, even one that never factored, gives the same
    velocities to the bit, and a fresh state (no factor) refactors on first use."""
    a, X = _drop()
    b, _ = _drop()
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
    assert b.membrane.traction_solve.factor is None and b.membrane.traction_solve.factor_x is None
    b.velocity(x)
    assert np.array_equal(b.state()["warm_mass_factor_x"], x)


def test_configuration_without_the_symmetry_is_solved_in_full():
    """A finite-difference probe x + εv with a random v (ε = 1e-7) has no symmetry: its
    energy gradient is not equivariant, and the reduced system would drop that part. It is
    solved in full (its residual within the CG tolerance, 1e-8 of max|b|, and scipy's direct
    solve to 1e-7: M's condition number is about 30) and the kept factorisation is untouched;
    a perturbation with the symmetry keeps the reduced solve."""
    model, X = _drop()
    disc, membrane = model.disc, model.membrane
    x = X @ _F
    model.velocity(x)
    kept = membrane.traction_solve.factor
    v = np.random.default_rng(3).standard_normal(x.shape)
    for probe, reduced in ((x + 1e-7 * v, False), (x + 1e-7 * disc.expand(v[disc.targets]), True)):
        state = membrane(probe)
        mass = disc.mass_matrix(state.geometry)
        rhs = membrane.energy_gradient(probe)
        exact = spsolve(mass.tocsc(), rhs)
        assert np.abs(mass @ state.traction - rhs).max() <= 1e-8 * np.abs(rhs).max()
        assert np.abs(state.traction - exact).max() <= 1e-7 * np.abs(exact).max()
        assert membrane.traction_solve.factor is kept
        symmetric = np.array_equal(disc.expand(state.traction[disc.targets]), state.traction)
        assert symmetric == reduced
