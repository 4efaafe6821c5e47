"""A case is resolved once, before its cross-field checks (issue 52): the values capsim derives
from what was given (G from flow.capillary_number or the physical block, λ, κ, Bq) come first, and
the error model chooses the level and time.rtol for the case's own G, λ and bending. Before, the
choice read the defaults (G 0.1, λ 1) of a case given in physical units or by its capillary
number: the same physics got another rtol (and another level for an accuracy target) depending on
how it was written."""
from __future__ import annotations

import pytest

from capsim.config import Case, ConfigError, case_from_dict

#: one capsule in physical units: G = μ k a / E_s with E_s = 3 G_s: 0.1 Pa s · 2 1/s · 5 µm / 18 µN/m = 0.0556
PHYSICAL = {"shear_rate": "2 1/s", "viscosity": "0.1 Pa*s", "radius": "5 um", "shear_modulus": "6 uN/m"}


def _same_choice(a: Case, b: Case) -> None:
    assert a.flow.shear_rate_G == pytest.approx(b.flow.shear_rate_G, rel=1e-12)
    assert (a.mesh.level, a.time.rtol) == (b.mesh.level, b.time.rtol)
    assert a.time.rtol_choice == b.time.rtol_choice


def test_rtol_auto_is_chosen_for_the_G_of_the_capillary_number():
    by_ca = Case(name="ca", flow={"capillary_number": 0.01})
    by_G = Case(name="g", flow={"G": by_ca.flow.shear_rate_G})
    assert by_ca.flow.shear_rate_G < 0.01  # far from the default 0.1, where the error model chooses otherwise
    _same_choice(by_ca, by_G)


def test_rtol_auto_is_chosen_for_the_G_and_lambda_of_the_physical_block():
    physical = dict(PHYSICAL, inner_viscosity="0.5 Pa*s")  # λ = 5
    by_units = Case(name="u", physical=physical)
    by_values = Case(name="v", flow={"G": by_units.flow.shear_rate_G, "viscosity_ratio": by_units.flow.viscosity_ratio})
    assert by_units.flow.viscosity_ratio == pytest.approx(5.0)
    _same_choice(by_units, by_values)
    assert by_units.error_model_features() == by_values.error_model_features()


def test_an_accuracy_target_chooses_for_the_physical_G():
    by_units = Case(name="u", physical=PHYSICAL, accuracy={"quantity": "D_xy", "target": 1e-2})
    by_values = Case(name="v", flow={"G": by_units.flow.shear_rate_G}, accuracy={"quantity": "D_xy", "target": 1e-2})
    _same_choice(by_units, by_values)
    assert by_units.accuracy.choice == by_values.accuracy.choice


def test_a_capsules_own_G_is_checked_against_the_physical_G():
    """capsules[i].modulus_ratio gives the capsule G / ratio: the check reads the physical G (0.556, so
    a ratio of 0.002 gives 278, beyond the 100 any membrane takes), not the default 0.1 (50, let through)."""
    physical = dict(PHYSICAL, shear_rate="20 1/s")
    capsules = [{"center": [0, 0, 0]}, {"center": [3, 0, 0], "modulus_ratio": 0.002}]
    with pytest.raises(ConfigError, match=r"capsules\[1\]\.modulus_ratio.*modulus_ratio = 278,"):
        case_from_dict({"name": "p", "physical": physical, "capsules": capsules, "mesh": {"level": 1}})


def test_a_resolved_case_reloads_to_itself():
    case = Case(name="u", physical=PHYSICAL, accuracy={"quantity": "D_xy", "target": 1e-2})
    again = case_from_dict(case.model_dump(mode="json"))
    assert again.model_dump(mode="json") == case.model_dump(mode="json")


def test_a_scene_quantity_target_resolves_to_the_ladder():
    """accuracy: {quantity: lift} in a case file: stored as the column it names, measured (the error
    model has no training case for it), refused in one line where the scene has no wall."""
    case = case_from_dict({"name": "w", "wall": {"distance": 3.0}, "time": {"t_end": 2.0},
                           "accuracy": {"quantity": "lift", "target": 0.05}})
    assert case.accuracy.quantity == "centroid_velocity_y"
    assert (case.accuracy.method, case.mesh.level) == ("measure", 1)
    assert case_from_dict(case.model_dump(mode="json")).accuracy.choice == case.accuracy.choice
    with pytest.raises(ConfigError, match=r"accuracy\.quantity.*needs a plane wall"):
        case_from_dict({"name": "u", "accuracy": {"quantity": "lift", "target": 0.05}})
    with pytest.raises(ConfigError, match=r"accuracy\.quantity = 'lifts'.*allowed: D_xy, theta, Sxy_star"):
        case_from_dict({"name": "u", "accuracy": {"quantity": "lifts", "target": 0.05}})
