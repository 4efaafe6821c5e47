"""First-order theory lines in the figures (issue 52): drawn only where the theory's assumptions
hold, the line of the scene's flow kind, with its source in the legend (docs/known_answers.md,
"Capsule: first-order small-deformation theory" and "Flows beyond simple shear").

Simple shear: D∞ = 25G/4, θ = π/4; planar extension: 25G/2; uniaxial extension: 75G/8 (one
isotropic constant times the strain rate's in-plane eigenvalue difference); no line for a
Poiseuille flow, a flow history, a wall, several capsules, a pre-inflated or non-spherical capsule.
The figures are drawn from run records built here (no run), so each check is a fraction of a second.
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from capsim.scene.flows import FLOWS
from capsim.face.plot import deformation_figure, inclination_figure, rheology_figure
from capsim.scene.small_deformation import first_order_D_xy, strain_coefficient

G = 0.01


def _record(**case) -> dict:
    """A run record as capsim.storage.store.read_trajectory returns it: the stored case and a D_xy series."""
    d = {"name": "theory", "mesh": {"level": 1}, "time": {"t_end": 2.0}, "membrane": {"law": "neo_hookean"}}
    for key, value in case.items():
        d[key] = {**d.get(key, {}), **value} if isinstance(value, dict) else value
    d.setdefault("flow", {}).setdefault("G", G)
    t = np.linspace(0.0, 2.0, 21)
    series = {"t": t, "D_xy": 0.06 * (1 - np.exp(-t)), "theta": np.full_like(t, 0.7),
              "Sxy_star": np.ones_like(t), "N1_star": np.full_like(t, 0.1), "N2_star": np.full_like(t, -0.02)}
    return {"attrs": {"config_yaml": yaml.safe_dump(d)}, "timeseries": series,
            "rest_positions": np.zeros((66, 3))}


def _theory_levels(ax) -> list[tuple[str, float]]:
    """(label, y) of each horizontal theory line of the axes (the D∞ or θ lines)."""
    out = []
    for line in ax.get_lines():
        y = np.asarray(line.get_ydata(), dtype=float)
        if line.get_linestyle() in (":", "--") and y.size and np.all(y == y[0]):
            out.append((line.get_label(), float(y[0])))
    return out


def _legend_text(ax) -> str:
    return " | ".join(ax.get_legend_handles_labels()[1])


def test_planar_extension_draws_its_own_line_not_the_shear_one():
    """A planar-extension run: D∞ = 25G/2 with its source, never the shear's 25G/4 (the old tree
    drew 25G/4 and its shear transient on every flow kind); no π/4 inclination."""
    fig = deformation_figure(_record(flow={"kind": "planar_extension"}))
    levels = [y for _, y in _theory_levels(fig.axes[0])]
    assert levels == pytest.approx([25.0 / 2.0 * G])
    text = _legend_text(fig.axes[0])
    assert "25G/2" in text and "25G/4" not in text and "Barthès-Biesel" in text
    fig = inclination_figure(_record(flow={"kind": "planar_extension"}))
    assert _theory_levels(fig.axes[0]) == []


def test_uniaxial_extension_draws_75G_over_8():
    fig = deformation_figure(_record(flow={"kind": "uniaxial_extension"}))
    assert [y for _, y in _theory_levels(fig.axes[0])] == pytest.approx([75.0 / 8.0 * G])
    assert "75G/8" in _legend_text(fig.axes[0])


def test_simple_shear_keeps_its_lines():
    fig = deformation_figure(_record())
    assert [y for _, y in _theory_levels(fig.axes[0])] == pytest.approx([25.0 / 4.0 * G])
    assert any(line.get_label().startswith("first order, $k") for line in fig.axes[0].get_lines())  # the transient
    assert "25G/4" in _legend_text(fig.axes[0]) and "Barthès-Biesel" in _legend_text(fig.axes[0])
    assert [y for _, y in _theory_levels(inclination_figure(_record()).axes[0])] == [0.25]
    first = [y for _, y in _theory_levels(rheology_figure(_record()).axes[0])]
    assert first == pytest.approx([1.0, 19.0 * G])  # S*_xy = 1, N1* = 19G


@pytest.mark.parametrize("scene", [
    {"shape": {"inflation": 0.05}},  # pre-stretched: 25G/4 is ~35 % off what it does
    {"shape": {"kind": "prolate", "aspect_ratio": 0.5}},
    {"wall": {"distance": 2.0}},
    {"flow": {"kind": "poiseuille", "poiseuille_radius": 5.0}, "initial_center": [0.0, 1.0, 0.0]},
    {"flow": {"history": {"kind": "stop", "stop_time": 1.0}}},
    {"flow": {"kind": "planar_extension"}, "shape": {"inflation": 0.05}},
])
def test_no_line_where_no_first_order_theory_is_derived(scene):
    for figure in (deformation_figure, inclination_figure, rheology_figure):
        fig = figure(_record(**scene))
        assert _theory_levels(fig.axes[0]) == [], (figure.__name__, scene)
        assert "first order" not in _legend_text(fig.axes[0])


def test_the_first_order_constants_follow_from_the_small_deformation_theory():
    """capsim.scene.small_deformation in a pure strain E: A = α G E with α = 25/2 for K_s/G_s = 3
    (ν_s = 1/2) and twice the shear's (5/4)(2 + ν_s)/(1 + ν_s)·3 for Skalak's K_s/G_s = 21
    (C = 10); D_xy = α G (e1 − e2)/2 of E's xy block, and each flow kind's constant follows."""
    assert strain_coefficient(3.0) == pytest.approx(12.5, rel=1e-12)
    nu = 10.0 / 11.0  # Skalak C = 10: D = (5/4)(2 + ν)/(1 + ν) Ca = (15/4)(2 + ν)/(1 + ν) G
    assert strain_coefficient(21.0) / 2 == pytest.approx(15.0 / 4.0 * (2 + nu) / (1 + nu), rel=1e-12)
    coefficient = {name: (cls.first_order(None).D_over_G if cls.first_order(None) else None)
                   for name, cls in FLOWS.items() if name != "linear"}
    assert coefficient.pop("poiseuille") is None
    assert coefficient.pop("conduit") is None  # a capsule in a conduit: no first-order theory derived
    assert coefficient == pytest.approx({"simple_shear": 25 / 4, "planar_extension": 25 / 2,
                                         "uniaxial_extension": 75 / 8})
    L = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    assert first_order_D_xy(L, 0.02) == pytest.approx(25 / 4 * 0.02)
