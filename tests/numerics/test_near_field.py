"""Near-field quadrature (quadrature.near_field_factor): elements close to a node
without holding it, as at the sharp rim of a flat capsule, integrated on
subdivided triangles. Checked with the exact identities of a closed surface,
PV∫ T·n dS = −4π I (double layer) and ∫ G·n dS = 0 (single layer), at every node.
"""

from __future__ import annotations

import numpy as np
import pytest

from capsim.numerics.mesh import rest_shape_mesh
from capsim.numerics.quadrature import subdivided_rule
from capsim.solve.solver import Discretization


def _identity_errors(kind: str, aspect_ratio: float, level: int, **quadrature) -> tuple[float, float]:
    mesh = rest_shape_mesh(kind, "octahedron", level, 0.0, aspect_ratio=aspect_ratio)
    x = mesh.positions
    disc = Discretization(mesh.elements, mesh.n_vertices, **quadrature)
    geo = disc.geometry(x)
    n = disc.nodal_normals(x)
    sl = np.abs(disc.single_layer(x, geo, np.ascontiguousarray(n[mesh.elements]))).max() / (16 * np.pi / 3)
    dl = 0.0
    for j in range(3):
        u = np.zeros_like(x)
        u[:, j] = 1.0
        d = disc.double_layer(x, geo, u, np.zeros_like(x))  # u0 = 0: the principal value itself
        dl = max(dl, np.abs(d[:, j] + 4 * np.pi).max() / (4 * np.pi), np.abs(np.delete(d, j, axis=1)).max() / (4 * np.pi))
    return sl, dl


def test_subdivided_rule_integrates_polynomials():
    xi, eta, w = subdivided_rule(6, 2)
    assert len(w) == 6 * 16 and w.sum() == pytest.approx(0.5)
    # the 6-point rule has degree 4 and so has the composite: ∫ ξ²η² = 2! 2! / 6!, ∫ ξ⁴ = 4!/6!
    assert (w * xi**2 * eta**2).sum() == pytest.approx(4 / 720, rel=1e-12)
    assert (w * xi**4).sum() == pytest.approx(24 / 720, rel=1e-12)
    # degree 5 is not exact, but closer than the single rule
    exact = 12 / 5040
    x1, e1, w1 = subdivided_rule(6, 0)
    assert abs((w * xi**3 * eta**2).sum() - exact) < abs((w1 * x1**3 * e1**2).sum() - exact) / 100


def test_near_field_fixes_the_rim_of_a_flat_spheroid():
    """b/a = 0.3, level 3. Measured: default DL identity error 6.6e-2, SL 4.2e-4;
    near field 0.5 with singular order 8: 5.5e-3 and 4.5e-5."""
    sl0, dl0 = _identity_errors("oblate", 0.3, 3)
    sl1, dl1 = _identity_errors("oblate", 0.3, 3, near_field_factor=0.5, near_field_levels=1, singular_order=8)
    assert dl0 > 0.05 and sl0 > 2e-4  # the defect the option is for
    assert dl1 < 0.01 and sl1 < 1e-4
    assert dl1 < dl0 / 8


def test_near_field_leaves_a_sphere_as_accurate_as_before():
    sl0, dl0 = _identity_errors("sphere", 1.0, 2)
    sl1, dl1 = _identity_errors("sphere", 1.0, 2, near_field_factor=1.0, near_field_levels=2, singular_order=8)
    assert sl1 <= max(sl0, 1e-4) and dl1 <= 1.1 * dl0


def test_near_pairs_exclude_the_elements_holding_the_node():
    mesh = rest_shape_mesh("oblate", "octahedron", 2, 0.0, aspect_ratio=0.3)
    disc = Discretization(mesh.elements, mesh.n_vertices, near_field_factor=1.0)
    x = mesh.positions
    offsets, elems = disc.near_pairs(x, disc.geometry(x))
    assert len(elems) > 0
    for i, node in enumerate(disc.targets):
        near = set(elems[offsets[i]:offsets[i + 1]].tolist())
        holding = set(np.flatnonzero((mesh.elements == node).any(axis=1)).tolist())
        assert not near & holding


def test_a_run_with_the_near_field_matches_the_default_closely(tmp_path):
    """A λ = 5 oblate run (level 1, kt 0.3): the option changes the solution by the
    quadrature error it removes, small against D_xy itself."""
    from capsim.config import case_from_dict
    from capsim.runs.runner import run_case

    finals = []
    for quadrature in ({}, {"near_field_factor": 0.5, "singular_order": 8}):
        case = case_from_dict({
            "name": "nf", "shape": {"kind": "oblate", "aspect_ratio": 0.5}, "initial_tilt_deg": 45.0,
            "flow": {"shear_rate_G": 0.2, "viscosity_ratio": 5.0}, "mesh": {"level": 1},
            "quadrature": quadrature, "time": {"t_end": 0.3},
            "output": {"path": str(tmp_path / f"nf{len(quadrature)}.h5"), "snapshot_every": 100.0},
        })
        summary = run_case(case)
        assert summary["status"] == "completed"
        finals.append(summary["final_D_xy"])
    assert finals[1] == pytest.approx(finals[0], rel=0.02)
    assert finals[1] != finals[0]
