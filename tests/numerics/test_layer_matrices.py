"""The layer operators as dense matrices (Discretization.layer_matrix): the same
rules as the matrix-free sums, so S f and D u equal single_layer and double_layer."""

from __future__ import annotations

import numpy as np
import pytest

from capsim.config import case_from_dict
from capsim.solve.solver import build_model


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


def _reference_corrections(disc, x, geo, density, u, u_target, targets):
    """The singular corrections as the first kernels computed them, in NumPy over all
    (target, incident element) pairs at once: the Duffy rule of the target's local node
    (positions, tangents and density interpolated from the six element nodes at every
    point) minus the regular rule of the element, summed per target.
    Returns (single, double), each (len(targets), 3)."""
    rows, elems, local = [], [], []
    for i, p in enumerate(targets):
        c = slice(disc.inc_offsets[p], disc.inc_offsets[p + 1])
        elems.append(disc.inc_elem[c])
        local.append(disc.inc_local[c])
        rows.append(np.full(disc.inc_elem[c].size, i))
    rows, elems, local = (np.concatenate(a) for a in (rows, elems, local))
    x0 = x[targets][rows][:, None, :]
    xe = x[disc.elements[elems]]  # (pairs, 6, 3)
    pts = np.einsum("pqa,pad->pqd", disc.sing_phi[local], xe)
    n = np.cross(np.einsum("pqa,pad->pqd", disc.sing_dxi[local], xe),
                 np.einsum("pqa,pad->pqd", disc.sing_deta[local], xe))
    w = disc.sing_w[local]

    def stokeslet(r, g):
        rn = np.linalg.norm(r, axis=-1)[..., None]
        return (g / rn + r * (r * g).sum(-1)[..., None] / rn**3).sum(1)

    def stresslet(r, m, v):
        rn = np.linalg.norm(r, axis=-1)[..., None]
        return (-6.0 * r * ((r * m).sum(-1) * (r * v).sum(-1))[..., None] / rn**5).sum(1)

    f = np.einsum("pqa,pad->pqd", disc.sing_phi[local], density[elems])
    sing = stokeslet(pts - x0, f * (w * np.linalg.norm(n, axis=-1))[..., None])
    reg = stokeslet(geo.points[elems] - x0, np.einsum("qa,pad->pqd", disc.reg_phi, density[elems])
                    * geo.weights[elems][..., None])
    single = np.zeros((targets.size, 3))
    np.add.at(single, rows, sing - reg)
    u0 = u_target[targets][rows][:, None, :]
    ue = np.einsum("pqa,pad->pqd", disc.sing_phi[local], u[disc.elements[elems]])
    sing = stresslet(pts - x0, n * w[..., None], ue - u0)
    reg = stresslet(geo.points[elems] - x0, geo.normals[elems] * geo.weights[elems][..., None],
                    np.einsum("qa,pad->pqd", disc.reg_phi, u[disc.elements[elems]]) - u0)
    double = np.zeros((targets.size, 3))
    np.add.at(double, rows, sing - reg)
    return single, double


@pytest.mark.parametrize("singular_order", [1, 2, 3])  # m = 4, 16 (the kernels' fixed-count loop), 36 points
def test_singular_corrections_equal_a_direct_reference(singular_order):
    """The kernels' singular corrections (single and double layer), restructured for speed
    (basis tables by node, one vectorised loop over a pair's Duffy points), equal the
    straightforward per-pair sums of the reference to 1e-12 relative: on a deformed level-2
    mesh, at every node and at the symmetry targets."""
    from capsim.numerics import kernels

    spec = {"name": "m", "mesh": {"level": 2}, "shape": {"kind": "oblate", "aspect_ratio": 0.5},
            "quadrature": {"singular_order": singular_order}, "initial_tilt_deg": 20.0}
    model, X = build_model(case_from_dict(spec))
    disc = model.disc
    assert disc.symmetry != "none" and disc.targets.size < disc.n_nodes
    rng = np.random.default_rng(11)
    x = X * np.array([1.1, 0.95, 1.02]) + 0.01 * rng.standard_normal(X.shape)  # no symmetry left
    geo = disc.geometry(x)
    density = rng.standard_normal((disc.elements.shape[0], 6, 3))
    u = rng.standard_normal(x.shape)
    u_target = 0.5 * u
    point_density, _ = kernels.point_strengths(disc.reg_phi, density, geo.weights)
    nw = np.ascontiguousarray(geo.normals * geo.weights[..., None])
    u_pts = np.ascontiguousarray(np.einsum("qa,ead->eqd", disc.reg_phi, u[disc.elements]))
    tables = (*disc.duffy_by_node, disc.sing_w)
    no_measure = np.zeros((0, 6, disc.sing_w.shape[1]))  # a density per unit area of x's surface
    for targets in (disc.targets, np.arange(disc.n_nodes, dtype=np.int64)):
        single = kernels.single_layer_singular_correction(
            x, disc.elements, disc.inc_offsets, disc.inc_elem, disc.inc_local,
            density, geo.points, geo.weights, point_density, *tables, no_measure, targets)
        double = kernels.double_layer_singular_correction(
            x, u, u_target, disc.elements, disc.inc_offsets, disc.inc_elem, disc.inc_local,
            geo.points, nw, u_pts, *tables, targets)
        ref_single, ref_double = _reference_corrections(disc, x, geo, density, u, u_target, targets)
        assert np.abs(single - ref_single).max() <= 1e-12 * np.abs(ref_single).max()
        assert np.abs(double - ref_double).max() <= 1e-12 * np.abs(ref_double).max()
