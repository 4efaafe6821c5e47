"""The Galerkin traction per unit rest area (total Lagrangian form; docs/method.md, "Numerical
method": membrane forces; docs/known_answers.md, "Exact and classical": the traction's measure): the layer kernels integrate a density
over the rest shape's measure as they integrate one over the current surface's, and the single
layer of the rest traction F differs from that of the traction per unit current area Δf only by
the kernel's departure from a quadratic: by O(h³) or faster."""

import numpy as np

from capsim.config import case_from_dict
from capsim.solve.solver import build_model

_C, _S = np.cos(0.6), np.sin(0.6)
_F = np.diag([1.15, 0.88, 1.0 / (1.15 * 0.88)]) @ np.array([[_C, -_S, 0], [_S, _C, 0], [0, 0, 1]]).T


def _model(level: int, **quadrature):
    spec = {"name": "m", "mesh": {"level": level, "symmetry": "none"}, "flow": {"shear_rate_G": 0.1}}
    if quadrature:
        spec["quadrature"] = quadrature
    return build_model(case_from_dict(spec))


def test_rest_measure_of_the_configuration_is_the_current_measure():
    """With the configuration itself as the 'rest shape', the rest-measure paths of the single
    layer (regular sum, Duffy corrections from the J0 table, near-field corrections) and of
    the dense layer matrix give the current-measure results to 1e-12; with the true rest shape
    the layer matrix is the single layer's matrix on rest densities (S f = SL[f] to 1e-12)."""
    model, X = _model(2, near_field_factor=1.5)
    disc = model.disc
    rng = np.random.default_rng(5)
    x = X @ _F + 0.01 * rng.standard_normal(X.shape)
    geo = disc.geometry(x)
    assert disc.near_pairs(x, geo)[1].size > 0  # the near-field path runs
    f = rng.standard_normal(x.shape)
    density = np.ascontiguousarray(f[disc.elements])
    current = disc.single_layer(x, geo, density)
    as_rest = disc.single_layer(x, geo, density, disc.rest_measure(x))
    assert np.abs(as_rest - current).max() <= 1e-12 * np.abs(current).max()
    s_current = disc.layer_matrix(x, geo, "single")
    s_as_rest = disc.layer_matrix(x, geo, "single", disc.rest_measure(x))
    assert np.abs(s_as_rest - s_current).max() <= 1e-12 * np.abs(s_current).max()
    rest = disc.rest_measure(X)
    on_rest = disc.single_layer(x, geo, density, rest)
    assert np.abs(on_rest - current).max() >= 1e-3 * np.abs(current).max()  # a different measure
    s_rest = disc.layer_matrix(x, geo, "single", rest)
    assert np.abs(s_rest @ f.ravel() - on_rest.ravel()).max() <= 1e-12 * np.abs(on_rest).max()


def _single_layer_difference(level: int) -> float:
    model, X = _model(level)
    disc = model.disc
    x = X @ _F
    state = model.membrane(x)
    current = disc.single_layer(x, state.geometry, np.ascontiguousarray(state.traction[disc.elements]))
    rest = disc.single_layer(x, state.geometry, state.density, state.measure)
    return float(np.abs(rest - current).max() / np.abs(current).max())


def test_single_layer_of_the_rest_traction_converges_to_that_of_the_current_traction():
    """F (M0·F = ∂E/∂x) and Δf (M(x)·Δf = ∂E/∂x) have the same moments against every quadratic,
    so their single layers differ only through the Stokeslet's departure from its quadratic
    interpolant: on a sphere stretched by 15 % and turned, max relative difference 2.0e-4 at
    level 2 and 2.5e-5 at level 3 (8.1× per halving of h; 1.9e-6 at level 4), far inside the
    method's own error at these levels (D_xy at level 3 against level 4: ~1e-3)."""
    d2, d3 = _single_layer_difference(2), _single_layer_difference(3)
    assert d2 <= 4e-4 and d3 <= 5e-5
    assert d2 / d3 >= 6.0


def test_state_weights_name_the_density_measure():
    """MembraneState.weights are the rest shape's for the galerkin density (per unit rest area)
    and the configuration's for the contour one (per unit current area). With them the galerkin
    density's total force ∫ F dS0 = Σ_i ∂E/∂x_i is zero to rounding (E is unchanged by a
    translation), while with the configuration's weights it is not (a configuration without
    symmetry, which would cancel it anyway)."""
    model, X = _model(2)
    state = model.membrane(X @ _F + 0.01 * np.random.default_rng(2).standard_normal(X.shape))
    assert np.array_equal(state.weights, state.measure.reg_weights)
    fq = np.einsum("qa,ead->eqd", model.disc.reg_phi, state.density)
    scale = np.einsum("eqd,eq->", np.abs(fq), state.weights)
    assert np.abs(np.einsum("eqd,eq->d", fq, state.weights)).max() <= 1e-12 * scale
    assert np.abs(np.einsum("eqd,eq->d", fq, state.geometry.weights)).max() >= 1e-4 * scale
    spec = {"name": "m", "mesh": {"level": 2}, "membrane": {"traction": "contour"}}
    contour, Y = build_model(case_from_dict(spec))
    state = contour.membrane(Y @ _F)
    assert state.measure is None and state.weights is state.geometry.weights
