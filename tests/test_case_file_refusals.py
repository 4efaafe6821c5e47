"""Case files and physical units under hostile input (issue 38's findings):

- 5: physical values far outside where capsim is validated warn (one line naming the field, its
  value and the range); absurd ones (a radius of 2.8 m meant as 2.8 um) are refused naming the
  physical value the user gave;
- 6: ``physical.inner_viscosity`` gives λ, a conflict with flow.viscosity_ratio is refused,
  and a campaign sweeps it;
- 16: no traceback from an initial_axis component of 1e200 (validate, --set, a campaign, the
  API), from ``run --units physical`` with extreme but consistent physical values, from
  ``warm-up`` of a case whose physical bending modulus is infinite, or from
  ``python docs/gen_reference.py`` with an unknown page;
- 17: every dimensionless value computed from physical ones is finite and inside its bounds
  (κ = 1e300 J, a = 1e-300 m; ``capsim units`` never prints inf nor emits ``Infinity``);
- 20: ``initial_axis: [1e-3, 0, 1]`` (YAML strings) and ``[1e-160, 1e-160, 0]`` are directions;
  ``--set membrane.viscosity.shear=1`` makes the section; Bq beyond 1e4 names
  physical.membrane_viscosity.

Bad input: exit 2, one line naming the field, the value and what is allowed, no traceback.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from capsim.face.cli import app
from capsim.config import (
    BQ_MAX,
    PHYSICAL_G_RANGE,
    USER_NAMES,
    VALIDATED_RANGES,
    CaseWarning,
    ConfigError,
    apply_overrides,
    case_from_dict,
    load_case,
    load_case_with,
)
from capsim.units import UnitsError, conversion, physical_factors

ROOT = Path(__file__).resolve().parents[1]
runner = CliRunner()

#: a red cell's values (capsim/units.py): G = 1.2e-3 · 100 · 2.8e-6 / 18e-6 = 0.018667
RBC = {"shear_rate": "100 1/s", "viscosity": "1.2 mPa*s", "radius": "2.8 um", "shear_modulus": "6 uN/m"}


def _case(tmp_path: Path, text: str, name: str = "case.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _physical_case(tmp_path: Path, **physical: str) -> Path:
    return _case(tmp_path, yaml.safe_dump({"name": "p", "physical": {**RBC, **physical}}))


def _refused(args: list[str], *words: str) -> str:
    """The CLI refuses with exit 2 and one line holding every word; that line."""
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output and result.exception is None or isinstance(result.exception, SystemExit)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    for word in words:
        assert word in lines[0], (word, lines[0])
    return lines[0]


def _no_case_warnings(data: dict) -> None:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        case_from_dict(data)
    assert not [w for w in caught if issubclass(w.category, CaseWarning)], [str(w.message) for w in caught]


# ---------------------------------------------------------------- 5: plausibility


def test_a_radius_in_metres_is_refused_naming_the_radius(tmp_path):
    path = _physical_case(tmp_path, radius="2.8 m")
    G = 1.2e-3 * 100 * 2.8 / 18e-6
    assert G > PHYSICAL_G_RANGE[1]
    line = _refused(["validate", path], "physical.radius = '2.8 m'", f"G = mu k a / E_s = {G:.3g}",
                    f"[{PHYSICAL_G_RANGE[0]:g}, {PHYSICAL_G_RANGE[1]:g}]", "check the units")
    assert line.startswith(f"error: {path}: ")
    _refused(["run", path, "-o", tmp_path / "r.h5"], "physical.radius = '2.8 m'")
    assert not (tmp_path / "r.h5").exists()


@pytest.mark.parametrize("field, value, name", [
    ("flow.shear_rate_G", 3.0, "flow.shear_rate_G"),
    ("flow.viscosity_ratio", 500.0, "flow.viscosity_ratio"),
    ("membrane.bending_modulus", 0.5, "membrane.bending_modulus"),
    ("membrane.viscosity.shear", 200.0, "membrane.viscosity.shear"),
])
def test_a_value_outside_the_validated_range_warns_naming_field_value_and_range(field, value, name):
    data: dict = {"name": "w"}
    section, *rest = field.split(".")
    node = data.setdefault(section, {})
    for part in rest[:-1]:
        node = node.setdefault(part, {})
    node[rest[-1]] = value
    lo, hi = VALIDATED_RANGES[name]
    with pytest.warns(CaseWarning) as record:
        case = case_from_dict(data)
    texts = [str(w.message) for w in record if issubclass(w.category, CaseWarning)]
    name = USER_NAMES.get(name, name)  # flow.G: the rate's name capsim says back (issue 52)
    assert any(t.startswith(f"{name} = {value:.3g}") and f"[{lo:g}, {hi:g}]" in t for t in texts), texts
    assert all("\n" not in t for t in texts)
    assert case is not None  # a warning, not a refusal


def test_values_inside_the_validated_ranges_do_not_warn():
    _no_case_warnings({"name": "ok"})
    _no_case_warnings({"name": "rbc", "physical": RBC, "membrane": {"bending_modulus": 3e-3}})
    _no_case_warnings({"name": "v", "flow": {"shear_rate_G": 5e-4, "viscosity_ratio": 100.0},
                       "membrane": {"viscosity": {"shear": 30.0}}})


def test_a_physical_value_that_warns_is_named_in_the_warning():
    # μ_s = 1e-6 N s/m in 1.2 mPa s at a = 2.8 um: Bq = 297.6, above 30 and below 1e4
    with pytest.warns(CaseWarning, match=r"membrane.viscosity.shear = 298 \(from physical.membrane_viscosity = "
                      r"'1e-6 N\*s/m'\) is outside \[0, 30\]"):
        case = case_from_dict({"name": "v", "physical": {**RBC, "membrane_viscosity": "1e-6 N*s/m"}})
    assert case.membrane.viscosity.shear == pytest.approx(1e-6 / (1.2e-3 * 2.8e-6), rel=1e-12)


def test_the_cli_warning_is_one_line_and_the_case_still_validates(tmp_path):
    path = _case(tmp_path, "name: w\nflow: {shear_rate_G: 3}\n")
    proc = subprocess.run([sys.executable, "-m", "capsim.face.cli", "validate", str(path)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert yaml.safe_load(proc.stdout)["flow"]["G"] == 3.0  # validate names the rate G (issue 52)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    lo, hi = VALIDATED_RANGES["flow.shear_rate_G"]
    assert lines[0].startswith(f"{path}:") and f"CaseWarning: flow.G = 3 is outside [{lo:g}, {hi:g}]" in lines[0]
    # an override that brings it back in range: no warning about the file's value
    proc = subprocess.run([sys.executable, "-m", "capsim.face.cli", "validate", str(path), "--set", "flow.shear_rate_G=0.1"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr


# ---------------------------------------------------------------- 6: the inner viscosity


def test_inner_viscosity_gives_lambda_and_a_resolved_case_reloads_equal(tmp_path):
    case = case_from_dict({"name": "c", "physical": {**RBC, "inner_viscosity": "6 mPa*s"}})
    assert case.flow.viscosity_ratio == pytest.approx(6e-3 / 1.2e-3, rel=1e-12)
    path = _case(tmp_path, case.to_yaml(), "resolved.yaml")
    assert load_case(path) == case
    assert conversion(**RBC, inner_viscosity="6 mPa*s")["lambda"] == pytest.approx(5.0, rel=1e-12)


def test_inner_viscosity_and_a_different_viscosity_ratio_are_refused(tmp_path):
    path = _case(tmp_path, yaml.safe_dump({"name": "c", "flow": {"viscosity_ratio": 2.0},
                                           "physical": {**RBC, "inner_viscosity": "6 mPa*s"}}))
    _refused(["validate", path], "flow.viscosity_ratio = 2.0", "physical.inner_viscosity", "not both", "λ = 5")
    # the same λ given both ways is a resolved case: accepted
    same = case_from_dict({"name": "c", "flow": {"viscosity_ratio": 5.0}, "physical": {**RBC, "inner_viscosity":
                                                                                         "6 mPa*s"}})
    assert same.flow.viscosity_ratio == pytest.approx(5.0)


@pytest.mark.parametrize("inner, lam", [("2 Pa*s", 2 / 1.2e-3), ("1e-6 Pa*s", 1e-6 / 1.2e-3)])
def test_an_inner_viscosity_outside_lambdas_bounds_is_refused_naming_it(tmp_path, inner, lam):
    path = _physical_case(tmp_path, inner_viscosity=inner)
    _refused(["validate", path], f"physical.inner_viscosity = '{inner}'", f"λ = {lam:.3g}", "[0.001, 1000]")


def test_set_inner_viscosity_recomputes_lambda_and_a_set_lambda_conflicts(tmp_path):
    path = _physical_case(tmp_path, inner_viscosity="6 mPa*s")
    case = load_case_with(path, ["physical.inner_viscosity=12 mPa*s"])
    assert case.flow.viscosity_ratio == pytest.approx(10.0, rel=1e-12)
    assert apply_overrides(case, **{"time.t_end": 1.0}).flow.viscosity_ratio == case.flow.viscosity_ratio
    _refused(["validate", path, "--set", "flow.viscosity_ratio=2"], "flow.viscosity_ratio = 2", "not both")
    # a case without it: λ from the block
    plain = _physical_case(tmp_path)
    assert load_case_with(plain, ["physical.inner_viscosity=2.4 mPa*s"]).flow.viscosity_ratio == pytest.approx(2.0)


def test_substitution_is_checked_at_the_lambda_the_inner_viscosity_gives():
    with pytest.raises(ConfigError, match=r"solver.max_iter = 20: substitution at viscosity_ratio = 100"):
        case_from_dict({"name": "s", "solver": {"method": "substitution", "max_iter": 20},
                        "physical": {**RBC, "inner_viscosity": "120 mPa*s"}})


def test_a_campaign_sweeps_the_inner_viscosity(tmp_path):
    from capsim.campaigns.campaign import campaign_from_dict, expand_campaign
    from capsim.campaigns.summary import _coordinate

    campaign = campaign_from_dict({
        "name": "lams", "base": {"physical": RBC, "mesh": {"level": 0}},
        "sweep": {"physical.inner_viscosity": ["1.2 mPa*s", "6 mPa*s"]}, "output": {"dir": str(tmp_path / "out")}})
    lams = [yaml.safe_load(spec.case_yaml)["flow"]["viscosity_ratio"] for spec in expand_campaign(campaign)]
    assert lams == pytest.approx([1.0, 5.0], rel=1e-12)
    _, values, attrs = _coordinate("inner_viscosity", "physical.inner_viscosity", ["1.2 mPa*s", "6 mPa*s"])
    assert list(values) == pytest.approx([1.2e-3, 6e-3]) and attrs["units"] == "Pa*s"


# ---------------------------------------------------------------- 16: tracebacks


@pytest.mark.parametrize("axis", ["[1.0e+200, 0, 1]", "[1.0e+300, 1.0e+300, 1.0e+300]", "[0, -1.0e+155, 0]"])
def test_a_huge_axis_component_is_a_direction(tmp_path, axis):
    path = _case(tmp_path, f"name: a\ninitial_axis: {axis}\n")
    result = runner.invoke(app, ["validate", str(path)])
    assert result.exit_code == 0, result.output
    got = yaml.safe_load(result.stdout)["initial_axis"]
    want = [float(c) for c in yaml.safe_load(axis)]
    scale = max(abs(c) for c in want)
    norm = math.sqrt(sum((c / scale) ** 2 for c in want))
    assert got == pytest.approx([c / scale / norm for c in want], abs=1e-15)
    assert math.isclose(math.fsum(c * c for c in got), 1.0, rel_tol=1e-15)
    # --set, the API and a campaign alike
    plain = _case(tmp_path, "name: a\n", "plain.yaml")
    result = runner.invoke(app, ["validate", str(plain), "--set", f"initial_axis={axis}"])
    assert result.exit_code == 0 and yaml.safe_load(result.stdout)["initial_axis"] == got, result.output
    import capsim

    assert list(capsim.load_case(path).initial_axis) == got
    campaign = _case(tmp_path, yaml.safe_dump({"name": "c", "base": {"mesh": {"level": 0}},
                                                "sweep": {"initial_axis": [yaml.safe_load(axis), [0, 1, 0]]},
                                                "output": {"dir": str(tmp_path / "out")}}), "campaign.yaml")
    result = runner.invoke(app, ["validate", str(campaign)])
    assert result.exit_code == 0 and "Traceback" not in result.output, result.output


def test_an_axis_component_too_large_for_a_float_is_one_line(tmp_path):
    path = _case(tmp_path, "name: a\ninitial_axis: [1" + "0" * 400 + ", 0, 1]\n")
    _refused(["validate", path], "initial_axis", "must be three finite numbers")
    with pytest.raises(ConfigError, match="must be three finite numbers"):
        case_from_dict({"name": "a", "initial_axis": [10**400, 0, 1]})


def test_run_units_physical_with_extreme_consistent_values_is_one_line(tmp_path):
    # G = 1e-200 · 1e100 · 1e100 / 3 = 0.33 is sane, but a³ = 1e300 m³ is inf in µm³
    extreme = {"shear_rate": "1e-200 1/s", "viscosity": "1e100 Pa*s", "radius": "1e100 m", "shear_modulus": "1 N/m"}
    assert conversion(**extreme)["G"] == pytest.approx(1 / 3)
    with pytest.raises(UnitsError, match=r"--units physical: .*a\^3 = inf um\^3"):
        physical_factors(extreme)
    path = _case(tmp_path, yaml.safe_dump({"name": "x", "physical": extreme, "mesh": {"level": 0},
                                           "time": {"t_end": 0.01}}))
    _refused(["run", path, "--units", "physical", "-o", tmp_path / "x.h5"], "physical.radius = '1e100 m'",
             "a^3 = inf um^3")
    assert not (tmp_path / "x.h5").exists()


def test_warm_up_of_an_infinite_physical_bending_modulus_is_one_line(tmp_path):
    path = _physical_case(tmp_path, bending_modulus="1e300 J")
    _refused(["warm-up", path], "physical.bending_modulus = '1e300 J'", "κ/(E_s a²) = inf", "finite")


@pytest.mark.parametrize("args", [["bogus"], ["../case_file"], ["case_file", "quantities"]])
def test_gen_reference_with_an_unknown_page_is_one_line_exit_2(args):
    proc = subprocess.run([sys.executable, str(ROOT / "docs" / "gen_reference.py"), *args],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stdout == "", proc.stdout
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert lines[0].startswith("error: ") and "case_file, quantities" in lines[0]


def test_gen_reference_prints_a_known_page():
    proc = subprocess.run([sys.executable, str(ROOT / "docs" / "gen_reference.py"), "case_file"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and "physical.inner_viscosity" in proc.stdout, proc.stderr


# ---------------------------------------------------------------- 17: non-finite or absurd derived values


def test_an_infinite_bending_modulus_from_physical_is_refused_naming_it(tmp_path):
    path = _physical_case(tmp_path, bending_modulus="1e300 J")
    line = _refused(["validate", path], "physical.bending_modulus = '1e300 J'", "κ/(E_s a²) = inf",
                    "finite and at most 1000")
    assert "membrane.bending_modulus = inf" not in line and ".inf" not in line
    # a sane one still gives κ/(E_s a²) by hand, and later overrides are accepted
    case = load_case_with(_physical_case(tmp_path, bending_modulus="1.8e-19 J"), ["time.t_end=1"])
    assert case.membrane.bending_modulus == pytest.approx(1.8e-19 / (18e-6 * 2.8e-6**2), rel=1e-12)


def test_a_bending_modulus_above_the_bound_is_refused(tmp_path):
    # 1e-12 J / (18e-6 N/m · (2.8e-6 m)²) = 7.1e6 > 1e3: finite, but a slip of units
    _refused(["validate", _physical_case(tmp_path, bending_modulus="1e-12 J")],
             "physical.bending_modulus = '1e-12 J'", "at most 1000")


def test_a_tiny_radius_is_refused_not_a_G_of_1e_297(tmp_path):
    path = _physical_case(tmp_path, radius="1e-300 m")
    _refused(["validate", path], "physical.radius = '1e-300 m'", "G = mu k a / E_s = 6.67e-297",
             f"[{PHYSICAL_G_RANGE[0]:g}, {PHYSICAL_G_RANGE[1]:g}]")


@pytest.mark.parametrize("as_json", [False, True])
def test_capsim_units_never_prints_inf(as_json):
    args = ["units", "--shear-rate", "1e300 1/s", "--viscosity", "1e300 Pa*s", "--radius", "1 m",
            "--shear-modulus", "1 N/m"] + (["--json"] if as_json else [])
    line = _refused(args, "units:", "G = mu k a / E_s = inf", "check their units")
    assert "Infinity" not in line
    result = runner.invoke(app, ["units", *sum((["--" + k.replace("_", "-"), v] for k, v in RBC.items()), []),
                                 "--json"])
    assert result.exit_code == 0
    json.loads(result.stdout, parse_constant=lambda c: pytest.fail(f"{c} in the JSON"))


def test_every_value_derived_from_physical_is_finite():
    with pytest.raises(UnitsError, match=r"G = mu k a / E_s = inf"):
        conversion("1e300 1/s", "1e300 Pa*s", "1 m", shear_modulus="1 N/m")
    with pytest.raises(UnitsError, match=r"Bq = mu_s / \(mu a\) = inf"):
        conversion(**{**RBC, "viscosity": "1e-300 Pa*s", "radius": "1e-10 m"}, membrane_viscosity="1e300 N*s/m")


# ---------------------------------------------------------------- 20: misleading one-liners


def test_an_axis_of_yaml_strings_is_taken_as_float_fields_take_them(tmp_path):
    path = _case(tmp_path, "name: a\ninitial_axis: [1e-3, 0, 1]\n")
    assert yaml.safe_load(path.read_text())["initial_axis"][0] == "1e-3"  # PyYAML reads it as a string
    axis = load_case(path).initial_axis
    norm = math.hypot(1e-3, 1.0)
    assert axis == pytest.approx((1e-3 / norm, 0.0, 1.0 / norm), abs=1e-16)
    with pytest.raises(ConfigError, match=r"must be a list of three numbers"):
        case_from_dict({"name": "a", "initial_axis": ["x", 0, 1]})
    with pytest.raises(ConfigError, match=r"must be a list of three numbers"):
        case_from_dict({"name": "a", "initial_axis": ["nan", 0, 1]})


def test_a_tiny_axis_is_a_direction_and_zero_is_not(tmp_path):
    path = _case(tmp_path, "name: a\ninitial_axis: [1.0e-160, 1.0e-160, 0]\n")
    assert load_case(path).initial_axis == pytest.approx((math.sqrt(0.5), math.sqrt(0.5), 0.0), abs=3e-16)
    assert case_from_dict({"name": "a", "initial_axis": [5e-324, 0, 0]}).initial_axis == (1.0, 0.0, 0.0)
    _refused(["validate", _case(tmp_path, "name: a\ninitial_axis: [0, 0.0, 0]\n", "zero.yaml")],
             "initial_axis = [0, 0.0, 0]", "nonzero vector")


def test_set_creates_an_optional_section_as_a_sweep_does(tmp_path):
    path = _case(tmp_path, "name: v\n")
    result = runner.invoke(app, ["validate", str(path), "--set", "membrane.viscosity.shear=1"])
    assert result.exit_code == 0, result.output
    viscosity = yaml.safe_load(result.stdout)["membrane"]["viscosity"]
    assert viscosity["shear"] == 1.0 and viscosity["model"] == "kelvin_voigt"
    assert load_case_with(path, membrane__viscosity__shear=2).membrane.viscosity.shear == 2.0
    assert load_case_with(path, ["flow.history.kind=stop", "flow.history.stop_time=2"]).flow.stop_time == 2.0
    # not a section: still refused in one line
    _refused(["validate", path, "--set", "mesh.level.x=1"], "'mesh.level' is not a section of the case")
    _refused(["validate", path, "--set", "membrane.nothing.x=1"], "membrane.nothing")


def test_a_membrane_viscosity_beyond_the_bound_names_the_physical_field(tmp_path):
    path = _physical_case(tmp_path, membrane_viscosity="1 N*s/m")
    Bq = 1.0 / (1.2e-3 * 2.8e-6)
    assert Bq > BQ_MAX
    line = _refused(["validate", path], "physical.membrane_viscosity = '1 N*s/m'", f"Bq = mu_s / (mu a) = {Bq:.3g}",
                    f"at most {BQ_MAX:g}")
    assert "shear = 297619047" not in line


@pytest.mark.parametrize("base, axis", [("octahedron", [0, 1, 1]), ("octahedron", [0, -1, 1]),
                                        ("octahedron", [1, 1, 1]), ("octahedron", [1, 0, 1]),
                                        ("icosahedron", [0, 1, 1])])
def test_a_sphere_takes_quarter_exactly_where_auto_uses_it(base, axis):
    """A sphere keeps the mirror and the rotation whatever its axis; its mesh, turned onto the
    axis, keeps them for some axes: mesh.symmetry quarter is accepted exactly where auto uses it."""
    from capsim.solve.solver import build_model

    auto = case_from_dict({"name": "s", "initial_axis": axis, "mesh": {"level": 0, "base": base}})
    model, _ = build_model(auto)
    auto_uses_quarter = model.disc.symmetry == "mirror_z+rotation_z"
    data = {"name": "s", "initial_axis": axis, "mesh": {"level": 0, "base": base, "symmetry": "quarter"}}
    if auto_uses_quarter:
        quarter, _ = build_model(case_from_dict(data))
        assert quarter.disc.symmetry == "mirror_z+rotation_z"
    else:
        with pytest.raises(ConfigError, match=r"mesh.symmetry = 'quarter': the .* mesh of a sphere turned onto "
                           r"initial_axis .* does not keep it \(auto uses half for it\)"):
            case_from_dict(data)
    # any other shape off the plane: refused as before
    with pytest.raises(ConfigError, match=r"needs the rest shape's axis in the shear plane"):
        case_from_dict({**data, "shape": {"kind": "prolate", "aspect_ratio": 2.0}})


@pytest.mark.parametrize("axis", [[0, 1, 1], [0.3, 0.5, 0.8], [1, 2, 0], [-3.5, 1e-3, 7], [0, 3, 4]])
def test_an_ordinary_axis_normalises_to_the_bits_it_did(axis):
    """The robust normalisation (scaled first) only where the squares overflow or underflow:
    an axis that loaded before loads to the same bits, so that a run started earlier resumes
    (its stored, resolved axis is compared with the one its case file gives now)."""
    norm = math.sqrt(sum(float(c) ** 2 for c in axis))
    assert case_from_dict({"name": "a", "initial_axis": axis}).initial_axis == tuple(float(c) / norm for c in axis)


def _case_warnings_here(G: float) -> int:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        case_from_dict({"name": "w", "flow": {"shear_rate_G": G}})
    return sum(issubclass(w.category, CaseWarning) for w in caught)


def test_a_worker_process_leaves_the_warning_to_the_process_that_planned_the_runs():
    """A sweep warns once per run when it expands the campaign, not again in each worker."""
    import multiprocessing

    assert _case_warnings_here(3.0) == 1
    with multiprocessing.get_context("spawn").Pool(1) as pool:
        assert pool.apply(_case_warnings_here, (3.0,)) == 0
