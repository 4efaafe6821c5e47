"""Issue 16: physical units in (``capsim units``, a case's ``physical:`` block, configs/rbc.yaml).

The two worked examples of capsim/units.py (and the README), by hand:

- red blood cell: k = 100 1/s, μ = 1.2 mPa s, a = 2.8 um, G_s = 6 uN/m:
  Ca = μka/G_s = 1.2e-3 · 100 · 2.8e-6 / 6e-6 = 0.056, G = Ca/3, 1/k = 0.01 s;
- alginate capsule: k = 10 1/s, μ = 1 Pa s, a = 1 mm, E_s = 0.1 N/m:
  G = μka/E_s = 1 · 10 · 1e-3 / 0.1 = 0.1, Ca = 3G = 0.3, 1/k = 0.1 s.
"""

import json
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from capsim.face.cli import app
from capsim.config import ConfigError, case_from_dict, load_case
from capsim.units import UnitsError, conversion, parse

ROOT = Path(__file__).resolve().parents[1]
RBC = {"--shear-rate": "100 1/s", "--viscosity": "1.2 mPa*s", "--radius": "2.8 um", "--shear-modulus": "6 uN/m"}
ALGINATE = {"--shear-rate": "10 1/s", "--viscosity": "1 Pa*s", "--radius": "1 mm", "--surface-modulus": "0.1 N/m"}
HAND = {  # the hand computations of the docstring
    "rbc": {"Ca": 1.2e-3 * 100 * 2.8e-6 / 6e-6, "G": 1.2e-3 * 100 * 2.8e-6 / 6e-6 / 3, "time_unit_s": 0.01},
    "alginate": {"G": 1.0 * 10 * 1e-3 / 0.1, "Ca": 3 * 1.0 * 10 * 1e-3 / 0.1, "time_unit_s": 0.1},
}

runner = CliRunner()


def _args(options):
    return ["units", *[x for kv in options.items() for x in kv]]


@pytest.mark.parametrize(("name", "options"), [("rbc", RBC), ("alginate", ALGINATE)])
def test_units_json_equals_the_hand_computation(name, options):
    result = runner.invoke(app, _args(options) + ["--json"])
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    for key, value in HAND[name].items():
        assert out[key] == pytest.approx(value, rel=1e-12), key
    assert out["Ca"] == pytest.approx(3 * out["G"], rel=1e-12)
    text = runner.invoke(app, _args(options))
    assert text.exit_code == 0 and f"{HAND[name]['G']:.6g}" in text.stdout and "1/k" in text.stdout


def test_other_spellings_of_the_same_values():
    a = conversion("100 1/s", "1.2 mPa*s", "2.8 um", shear_modulus="6 uN/m")
    b = conversion("100 Hz", "1.2 cP", "2.8e-3 mm", shear_modulus="6e-3 dyn/cm")  # 1 dyn/cm = 1 mN/m
    for key in ("G", "Ca", "time_unit_s"):
        assert a[key] == pytest.approx(b[key], rel=1e-12)


@pytest.mark.parametrize(("change", "words"), [
    ({"--radius": "2.8 kg"}, "--radius: '2.8 kg' is not a length"),
    ({"--radius": "2.8"}, "--radius: '2.8' has no units"),
    ({"--viscosity": "1.2 furlongz"}, "--viscosity: cannot read"),
    ({"--shear-rate": "-100 1/s"}, "--shear-rate: '-100 1/s' must be positive"),
    ({"--viscosity": None}, "give --viscosity"),
    ({"--shear-modulus": None}, "--surface-modulus or --shear-modulus"),
    ({"--surface-modulus": "18 uN/m"}, "only one of --surface-modulus and --shear-modulus"),
])
def test_bad_units_or_missing_values_are_one_line_exit_2(change, words):
    options = {k: v for k, v in {**RBC, **change}.items() if v is not None}
    result = runner.invoke(app, _args(options))
    assert result.exit_code == 2, result.output
    assert result.stdout == ""
    line = result.stderr.strip()
    assert "\n" not in line and line.startswith("error: units: ") and words in line, line


def test_parse_refuses_what_is_not_a_quantity():
    assert parse("1.2 mPa*s", "viscosity") == pytest.approx(1.2e-3)
    for bad in (1.2, True, None, "", "1.2 m/s"):
        with pytest.raises(UnitsError):
            parse(bad, "viscosity")


# ---------------------------------------------------------------- the physical: block of a case

PHYSICAL = {"shear_rate": "10 1/s", "viscosity": "1 Pa*s", "radius": "1 mm", "surface_modulus": "0.1 N/m"}


def test_physical_block_gives_G_and_both_are_stored(tmp_path):
    case = case_from_dict({"name": "p", "physical": PHYSICAL})
    assert case.flow.shear_rate_G == pytest.approx(HAND["alginate"]["G"], rel=1e-12)
    resolved = yaml.safe_load(case.to_yaml())
    assert resolved["physical"]["radius"] == "1 mm" and resolved["flow"]["shear_rate_G"] == case.flow.shear_rate_G
    path = tmp_path / "resolved.yaml"
    path.write_text(case.to_yaml())
    assert load_case(path) == case  # the resolved case (both given, and agreeing) loads back
    rbc = case_from_dict({"name": "r", "physical": {**PHYSICAL, "surface_modulus": None, "shear_modulus": "6 uN/m",
                                                    "shear_rate": "100 1/s", "viscosity": "1.2 mPa*s",
                                                    "radius": "2.8 um"}})
    assert rbc.flow.shear_rate_G == pytest.approx(HAND["rbc"]["G"], rel=1e-12)


@pytest.mark.parametrize(("case", "words"), [
    ({"flow": {"shear_rate_G": 0.2}, "physical": PHYSICAL},
     "flow.shear_rate_G = 0.2: give flow.shear_rate_G or physical, not both"),
    ({"physical": {**PHYSICAL, "radius": "1 kg"}}, "physical.radius = '1 kg': '1 kg' is not a length"),
    ({"physical": {**PHYSICAL, "radius": 1.0}}, "physical.radius = 1.0: must be a quantity with units"),
    ({"physical": {k: v for k, v in PHYSICAL.items() if k != "viscosity"}},
     "physical.viscosity: required field is missing"),
    ({"physical": {**PHYSICAL, "shear_modulus": "6 uN/m"}}, "give surface_modulus (E_s) or shear_modulus (G_s), not both"),
    ({"physical": {**PHYSICAL, "tension": "1 N/m"}}, "physical.tension: unknown field 'tension'"),
])
def test_bad_physical_block_is_one_line(case, words, tmp_path):
    with pytest.raises(ConfigError) as info:
        case_from_dict({"name": "p", **case}, source="c.yaml")
    assert words in str(info.value) and "\n" not in str(info.value), str(info.value)
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump({"name": "p", **case}))
    result = runner.invoke(app, ["validate", str(path)])
    assert result.exit_code == 2 and words in result.stderr and result.stderr.count("\n") == 1, result.stderr


def test_rbc_preset_resolves_with_its_documented_G():
    case = load_case(ROOT / "configs" / "rbc.yaml")
    G = 1.2e-3 * 100 * 2.8e-6 / (3 * 2.5e-6)  # μ k a / E_s, E_s = 3 G_s
    assert case.flow.shear_rate_G == pytest.approx(G, rel=1e-12) == pytest.approx(0.0448, rel=1e-12)
    assert case.membrane.bending_modulus == pytest.approx(1.8e-19 / (3 * 2.5e-6 * 2.8e-6 ** 2), rel=0.01)
    assert (case.membrane.law, case.membrane.skalak_c, case.flow.viscosity_ratio) == ("skalak", 10.0, 5.0)


# ---------------------------------------------------------------- issue 30: physical values set and swept


def test_set_a_physical_value_on_the_red_cell_recomputes_G():
    from capsim.config import apply_overrides

    case = load_case(ROOT / "configs" / "rbc.yaml")
    half = apply_overrides(case, **{"physical.shear_rate": "50 1/s"})
    # G = μka/E_s = 1.2e-3 · 50 · 2.8e-6 / (3 · 2.5e-6) = 0.0224 (the preset, at 100 1/s: 0.0448)
    assert half.flow.shear_rate_G == pytest.approx(1.2e-3 * 50 * 2.8e-6 / 7.5e-6, rel=1e-12)
    assert case.flow.shear_rate_G == pytest.approx(2 * half.flow.shear_rate_G, rel=1e-12)
    result = runner.invoke(app, ["validate", str(ROOT / "configs" / "sphere.yaml"), "--set", "physical.shear_rate=50 1/s"])
    assert result.exit_code == 2 and len(result.stderr.strip().splitlines()) == 1
    assert "physical.viscosity: required field is missing" in result.stderr


def test_a_sweep_over_a_physical_value_has_an_SI_coordinate(tmp_path):
    from capsim.campaigns.campaign import campaign_from_dict, expand_campaign
    from capsim.campaigns.summary import _coordinate

    base = {"physical": {"shear_rate": "100 1/s", "viscosity": "1.2 mPa*s", "radius": "2.8 um",
                         "shear_modulus": "2.5 uN/m"}, "mesh": {"level": 0}}
    campaign = campaign_from_dict({"name": "rates", "base": base, "sweep": {"physical.shear_rate": ["50 1/s", "0.1 1/ms"]},
                                   "output": {"dir": str(tmp_path / "out")}})
    G = [load_G(spec) for spec in expand_campaign(campaign)]
    assert G == pytest.approx([1.2e-3 * 50 * 2.8e-6 / 7.5e-6, 1.2e-3 * 100 * 2.8e-6 / 7.5e-6], rel=1e-12)
    name, values, attrs = _coordinate("shear_rate", "physical.shear_rate", ["50 1/s", "0.1 1/ms"])
    assert list(values) == pytest.approx([50.0, 100.0]) and attrs["units"] == "1/s"
    assert attrs["case_field_values"] == "50 1/s; 0.1 1/ms"


def load_G(spec) -> float:
    return yaml.safe_load(spec.case_yaml)["flow"]["shear_rate_G"]


def test_capillary_number_and_physical_bending_give_G_and_kappa_by_hand():
    from capsim.config import apply_overrides

    sphere = case_from_dict({"name": "ca", "flow": {"capillary_number": 0.3}})
    assert sphere.flow.shear_rate_G == pytest.approx(0.1, rel=1e-12)  # G = Ca/3 (G_s = E_s/3)
    drop = case_from_dict({"name": "ca", "flow": {"capillary_number": 0.3}, "membrane": {"law": "surface_tension"}})
    assert drop.flow.shear_rate_G == pytest.approx(0.3, rel=1e-12)  # a drop: Ca = μka/γ = G
    assert apply_overrides(sphere, **{"flow.capillary_number": 0.6}).flow.shear_rate_G == pytest.approx(0.2)
    with pytest.raises(ConfigError, match="give flow.shear_rate_G or flow.capillary_number, not both"):
        case_from_dict({"name": "ca", "flow": {"capillary_number": 0.3, "shear_rate_G": 0.2}})
    # κ = 1.8e-19 J, E_s = 3 × 2.5 uN/m, a = 2.8 um: κ/(E_s a²) = 1.8e-19 / (7.5e-6 × 7.84e-12) = 3.0612e-3
    rbc = apply_overrides(load_case(ROOT / "configs" / "rbc.yaml"), **{"physical.bending_modulus": "1.8e-19 J"})
    assert rbc.membrane.bending_modulus == pytest.approx(1.8e-19 / (7.5e-6 * 2.8e-6**2), rel=1e-12)
    assert apply_overrides(rbc, **{"time.t_end": 1.0}).membrane.bending_modulus == rbc.membrane.bending_modulus
    result = runner.invoke(app, ["validate", str(ROOT / "configs" / "rbc.yaml"), "--set", "physical.bending_modulus=2 m"])
    assert result.exit_code == 2 and len(result.stderr.strip().splitlines()) == 1
    assert "physical.bending_modulus = '2 m': '2 m' is not an energy (a bending modulus)" in result.stderr


# ---------------------------------------------------------------- issue 30: the capillary number as an input


def test_capillary_number_alone_gives_the_G_of_flow_capillary_number():
    result = runner.invoke(app, ["units", "--capillary-number", "0.3", "--json"])
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    assert out["G"] == pytest.approx(0.1, rel=1e-12)  # G = Ca/3 by hand
    assert out["G"] == pytest.approx(case_from_dict({"name": "c", "flow": {"capillary_number": 0.3}}).flow.shear_rate_G,
                                     rel=1e-12)
    text = runner.invoke(app, ["units", "--capillary-number", "0.3"]).stdout
    assert "G  = Ca / 3 = 0.1" in text and "flow.capillary_number" in text


@pytest.mark.parametrize(("left_out", "SI"), [
    ("--shear-rate", 100.0),         # k = Ca G_s / (μ a) = 0.056 × 6e-6 / (1.2e-3 × 2.8e-6) = 100 1/s
    ("--viscosity", 1.2e-3),         # μ = Ca G_s / (k a)
    ("--radius", 2.8e-6),            # a = Ca G_s / (μ k)
    ("--shear-modulus", 6e-6),       # G_s = μ k a / Ca
])
def test_capillary_number_solves_for_the_fourth_value(left_out, SI):
    options = {k: v for k, v in RBC.items() if k != left_out}
    result = runner.invoke(app, _args(options) + ["--capillary-number", "0.056", "--json"])
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    assert out["solved"] == left_out[2:].replace("-", "_")
    assert out[f"{out['solved']}_SI"] == pytest.approx(SI, rel=1e-12)
    for key, value in HAND["rbc"].items():  # the same conversion as with all four given
        assert out[key] == pytest.approx(value, rel=1e-12), key


@pytest.mark.parametrize(("args", "words"), [
    (["--capillary-number", "-1"], "--capillary-number -1.0: must be a positive, finite number"),
    (["--capillary-number", "nan"], "--capillary-number nan: must be a positive, finite number"),
    (["--capillary-number", "abc"], "'--capillary-number'"),
    (["--capillary-number", "0.1", "--radius", "2.8 um"], "missing --shear-rate, --viscosity, --shear-modulus"),
    (["--capillary-number", "0.1", *_args(RBC)[1:]], "not all four"),
    (["--capillary-number", "0.1", "--viscosity", "1.2 kg", "--radius", "2.8 um", "--shear-modulus", "6 uN/m"],
     "--viscosity: '1.2 kg' is not a dynamic viscosity"),
])
def test_bad_capillary_number_input_is_one_line_exit_2(args, words):
    result = runner.invoke(app, ["units", *args])
    assert result.exit_code == 2, result.output
    line = result.stderr.strip()
    assert "\n" not in line and line.startswith("error: ") and words in line, line


def test_set_a_physical_value_recomputes_every_field_derived_from_it():
    """DERIVED_FIELDS covers physical.membrane_viscosity, and a radius changes Bq and κ/(E_s a²)
    too when the case computes them from physical (before: 'give membrane.viscosity.shear or
    physical.membrane_viscosity, not both')."""
    from capsim.config import apply_overrides

    viscous = load_case(ROOT / "configs" / "rbc-viscous.yaml")  # μ_s = 1e-7 N s/m, μ = 1.2 mPa s, a = 2.8 µm
    assert viscous.membrane.viscosity.shear == pytest.approx(1e-7 / (1.2e-3 * 2.8e-6), rel=1e-12)
    doubled = apply_overrides(viscous, **{"physical.membrane_viscosity": "2e-7 N*s/m"})
    assert doubled.membrane.viscosity.shear == pytest.approx(2e-7 / (1.2e-3 * 2.8e-6), rel=1e-12)
    wider = apply_overrides(viscous, **{"physical.radius": "3 um"})
    assert wider.membrane.viscosity.shear == pytest.approx(1e-7 / (1.2e-3 * 3e-6), rel=1e-12)
    rbc = apply_overrides(load_case(ROOT / "configs" / "rbc.yaml"), **{"physical.bending_modulus": "1.8e-19 J"})
    wider = apply_overrides(rbc, **{"physical.radius": "3 um"})
    assert wider.membrane.bending_modulus == pytest.approx(1.8e-19 / (7.5e-6 * 3e-6**2), rel=1e-12)
    # a κ given as membrane.bending_modulus (configs/rbc.yaml) is the user's, kept
    kept = apply_overrides(load_case(ROOT / "configs" / "rbc.yaml"), **{"physical.radius": "3 um"})
    assert kept.membrane.bending_modulus == 3.06e-3
