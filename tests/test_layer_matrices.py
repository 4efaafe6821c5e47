"""The layer operators as dense matrices (Discretization.layer_matrix): the same
rules as the matrix-free sums, so S f and D u equal single_layer and double_layer."""

from __future__ import annotations

import numpy as np
import pytest

from capsim.config import case_from_dict
from capsim.solver import build_model


def _model(shape, tilt=0.0, **quadrature):
    spec = {"name": "m", "mesh": {"level": 1}, "shape": shape, "quadrature": quadrature, "initial_tilt_deg": tilt}
    return build_model(case_from_dict(spec))


@pytest.mark.parametrize("shape, tilt, quadrature", [
    ({"kind": "sphere"}, 0.0, {}),
    ({"kind": "oblate", "aspect_ratio": 0.4}, 20.0, {}),
    ({"kind": "oblate", "aspect_ratio": 0.3}, 0.0, {"near_field_factor": 0.8}),  # near pairs on the rim
])
def test_layer_matrices_equal_the_matrix_free_layers(shape, tilt, quadrature):
    """|S f − SL[f]| and |D u − D[u]| ≤ 1e-12 relative for a symmetric random field
    (the matrix-free layers evaluate a quarter of the nodes and expand by symmetry,
    the matrices every row), on a deformed shape so that no symmetry of the sphere helps."""
    model, X = _model(shape, tilt, **quadrature)
    disc = model.disc
    x = X * np.array([1.1, 0.95, 1.02])
    geo = disc.geometry(x)
    rng = np.random.default_rng(7)
    f = disc.expand(rng.standard_normal(x.shape)[disc.targets])
    if quadrature:
        assert disc.near_pairs(x, geo)[1].size > 0  # the near field is exercised
    single = disc.single_layer(x, geo, np.ascontiguousarray(f[disc.elements]))
    got = disc.layer_matrix(x, geo, "single") @ f.ravel()
    assert np.abs(got - single.ravel()).max() <= 1e-12 * np.abs(single).max()
    double = disc.double_layer(x, geo, f)
    got = disc.layer_matrix(x, geo, "double") @ f.ravel()
    assert np.abs(got - double.ravel()).max() <= 1e-12 * np.abs(double).max()


def test_double_layer_matrix_annihilates_rigid_motions_and_flux_weights_give_the_flux():
    """D[u] = 0 for u = U + Ω × x (the desingularised double layer, exact for any rule),
    and the flux weights reproduce ∫ u·n dS."""
    model, X = _model({"kind": "sphere"})
    disc = model.disc
    geo = disc.geometry(X)
    d = disc.layer_matrix(X, geo, "double")
    rigid = np.array([0.3, -0.2, 0.5]) + np.cross(np.array([0.1, 0.7, -0.4]), X)
    assert np.abs(d @ rigid.ravel()).max() <= 1e-12 * np.abs(d).max()
    u = np.random.default_rng(2).standard_normal(X.shape)
    assert (disc.flux_weights(geo) * u).sum() == pytest.approx(disc.flux(geo, u), rel=1e-13)


@pytest.mark.parametrize("shape, tilt", [({"kind": "sphere"}, 0.0), ({"kind": "oblate", "aspect_ratio": 0.4}, 20.0)])
def test_repeated_applications_use_correction_weights_equal_to_the_direct_correction(shape, tilt):
    """The second application of a layer at one configuration (a GMRES solve's) takes its
    singular correction from weights built once (Discretization.correction_weights): the
    same layer to 1e-14 relative, for a density the first application did not see, and for
    the double layer with a u0 other than u; the first application computes it directly."""
    model, X = _model(shape, tilt)
    disc = model.disc
    x = X * np.array([1.1, 0.95, 1.02])
    geo = disc.geometry(x)
    rng = np.random.default_rng(3)
    first, second = (disc.expand(rng.standard_normal(x.shape)[disc.targets]) for _ in range(2))
    for kind in ("single", "double"):
        apply = ((lambda f: disc.single_layer(x, geo, np.ascontiguousarray(f[disc.elements]))) if kind == "single"
                 else (lambda f: disc.double_layer(x, geo, f, 0.5 * f)))
        direct = apply(second)  # at a new configuration for this kind: direct
        assert disc.correction_weights(kind, x, disc.geometry(x)) is None  # another geometry: direct again
        apply(first)
        assert disc._weights[kind][1] is None  # one application so far: no weights
        weighted = apply(second)
        assert disc._weights[kind][1] is not None
        assert np.abs(weighted - direct).max() <= 1e-14 * np.abs(direct).max()
