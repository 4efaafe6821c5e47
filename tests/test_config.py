import math
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from capsim.config import Case, ConfigError, apply_overrides, case_from_dict, load_case


def _write(tmp_path, text, name="case.yaml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def _one_line_error(func, *args, **kwargs) -> str:
    with pytest.raises(ConfigError) as info:
        func(*args, **kwargs)
    message = str(info.value)
    assert "\n" not in message
    return message


def test_defaults_round_trip_through_yaml(tmp_path):
    case = Case(name="x")
    loaded = load_case(_write(tmp_path, case.to_yaml()))
    assert loaded == case
    assert loaded.output.path == "runs/x.h5"
    assert loaded.to_yaml() == case.to_yaml()


def test_non_default_case_round_trips(tmp_path):
    case = case_from_dict(
        {
            "name": "rbc_1",
            "shape": {"kind": "biconcave"},
            "membrane": {"law": "skalak", "skalak_c": 2.5},
            "flow": {"shear_rate_G": 0.05, "viscosity_ratio": 5.0},
            "initial_tilt_deg": -30.0,
            "mesh": {"base": "icosahedron", "level": 2},
            "time": {"rtol": "1e-5", "dt_min": 1e-9},
            "output": {"path": "out/{name}-lam5.h5"},
        }
    )
    assert case.time.rtol == 1e-5
    assert case.output.path == "out/rbc_1-lam5.h5"
    assert load_case(_write(tmp_path, case.to_yaml())) == case


def test_demo_config_is_valid():
    case = load_case(Path(__file__).parents[1] / "configs" / "sphere.yaml")
    assert case.name == "sphere-G0.1"
    assert case.output.path == "runs/sphere-G0.1.h5"
    assert case.flow.shear_rate_G == 0.1


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("name: x\nflow: {shear_rate_G: -1.0}\n", "case.yaml: flow.shear_rate_G = -1.0: must be > 0"),
        ("name: x\nflow: {shear_rate_G: 0}\n", "flow.shear_rate_G = 0: must be > 0"),
        ("name: x\nflow: {viscosity_ratio: 0.0}\n", "flow.viscosity_ratio = 0.0: must be > 0"),
        ("name: x\nflow: {viscosity_ratio: .nan}\n", "flow.viscosity_ratio = nan: must be a finite number"),
        ("name: x\nmesh: {level: 99}\n", "mesh.level = 99: must be <= 6"),
        ("name: x\nmesh: {level: 2.5}\n", "mesh.level = 2.5: must be an integer"),
        ("name: x\nmembrane: {law: hooke}\n", "membrane.law = 'hooke': must be one of 'thin_shell'"),
        ("name: x\nshape: {kind: oblate, aspect_ratio: 2.0}\n", "shape.aspect_ratio = 2.0: must be in (0, 1)"),
        ("name: x\nshape: {kind: prolate, aspect_ratio: 0.5}\n", "shape.aspect_ratio = 0.5: must be > 1"),
        ("name: x\ntime: {dt_min: 1.0, dt_max: 0.5}\n", "time.dt_max = 0.5: must be > dt_min"),
        ("name: x\ninitial_tilt_deg: 120\n", "initial_tilt_deg = 120: must be <= 90"),
        ("name: x\nquadrature: {regular_order: 5}\n", "quadrature.regular_order = 5: must be one of 1, 3"),
        ("name: 'a b'\n", "name = 'a b': must contain only letters"),
        ("flow: {shear_rate_G: 0.1}\n", "name: required field is missing"),
        ("name: x\nflow: 3\n", "flow = 3: must be a mapping"),
    ],
)
def test_bad_values_name_field_and_value(tmp_path, text, expected):
    path = _write(tmp_path, text)
    message = _one_line_error(load_case, path)
    assert message.startswith(str(path) + ": ")
    assert expected.removeprefix("case.yaml: ") in message


def test_unknown_field_names_it_and_lists_allowed(tmp_path):
    message = _one_line_error(load_case, _write(tmp_path, "name: x\nflow: {shear_rate: 0.1}\n"))
    assert "flow.shear_rate: unknown field 'shear_rate'" in message
    assert "(allowed: shear_rate_G, capillary_number, viscosity_ratio, history, kind, velocity_gradient, poiseuille_radius)" in message


def test_unknown_top_level_field(tmp_path):
    message = _one_line_error(load_case, _write(tmp_path, "name: x\nmeshh: {level: 2}\n"))
    assert "unknown field 'meshh'" in message and "mesh," in message


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("", "file is empty"),
        ("# only a comment\n", "file is empty"),
        ("name: [unclosed\n", "not valid YAML"),
        ("name: x\nname: y\n", "duplicate key 'name'"),
        ("- name: x\n", "top level must be a mapping"),
        ("just a string\n", "top level must be a mapping"),
    ],
)
def test_bad_files(tmp_path, text, expected):
    path = _write(tmp_path, text)
    message = _one_line_error(load_case, path)
    assert message.startswith(str(path) + ": ")
    assert expected in message


def test_missing_file(tmp_path):
    path = tmp_path / "nope.yaml"
    assert _one_line_error(load_case, path) == f"{path}: no such file"


def test_binary_file_is_refused(tmp_path):
    path = tmp_path / "case.yaml"
    path.write_bytes(b"\x89HDF\r\n\x1a\n\xff\xfe\x00")
    assert str(path) in _one_line_error(load_case, path)


def test_many_errors_stay_on_one_line():
    message = _one_line_error(
        case_from_dict,
        {"name": "", "flow": {"shear_rate_G": -1, "viscosity_ratio": -1}, "mesh": {"level": -1}, "x": 1},
        source="s",
    )
    assert "more" in message


def test_apply_overrides_revalidates_and_copies():
    case = Case(name="x")
    changed = apply_overrides(case, **{"time.t_end": 5.0, "mesh.level": 2})
    assert (changed.time.t_end, changed.mesh.level) == (5.0, 2)
    assert (case.time.t_end, case.mesh.level) == (10.0, 3)
    assert apply_overrides(case, name="y").output.path == "runs/y.h5"
    assert "mesh.level = 9" in _one_line_error(apply_overrides, case, **{"mesh.level": 9})
    assert "unknown field 'levl'" in _one_line_error(apply_overrides, case, **{"mesh.levl": 2})
    assert "not a section" in _one_line_error(apply_overrides, case, **{"name.x": 2})


def test_case_is_immutable():
    case = Case(name="x")
    with pytest.raises(Exception):
        case.flow.shear_rate_G = 1.0  # type: ignore[misc]


_scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(10**30), max_value=10**30),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=12),
    st.sampled_from(["sphere", "oblate", "skalak", "gmres", "octahedron", "1e-4", "x"]),
)
_keys = st.sampled_from(
    ["name", "shape", "kind", "aspect_ratio", "membrane", "law", "psi", "flow", "shear_rate_G",
     "viscosity_ratio", "initial_tilt_deg", "mesh", "level", "base", "quadrature",
     "regular_order", "time", "t_end", "dt_min", "dt_max", "dt_initial", "rtol", "solver",
     "method", "output", "path", "snapshot_every", "bogus"]
) | st.text(max_size=6)
_values = st.recursive(
    _scalars,
    lambda children: st.lists(children, max_size=3) | st.dictionaries(_keys, children, max_size=5),
    max_leaves=12,
)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.one_of(st.dictionaries(_keys, _values, max_size=8), _values))
def test_fuzzed_dicts_give_case_or_config_error(d):
    try:
        case = case_from_dict(d)
    except ConfigError as exc:
        assert "\n" not in str(exc)
        return
    assert isinstance(case, Case)
    assert math.isfinite(case.flow.shear_rate_G)
    assert yaml.safe_load(case.to_yaml())["name"] == case.name


# ---------------------------------------------------------------- hostile inputs (issue 19)


@pytest.mark.parametrize(
    "data",
    [
        {"shape": {"kind": "biconcave"}},
        {"shape": {"kind": "oblate", "aspect_ratio": 0.3}},
        {"shape": {"kind": "prolate", "aspect_ratio": 3.0}},
        {"membrane": {"law": "mooney_rivlin", "psi": 0.3}},
        {"membrane": {"law": "skalak", "skalak_c": 2.5}},
        {"membrane": {"law": "surface_tension"}},
        {"flow": {"viscosity_ratio": 5.0}, "solver": {"method": "substitution"}},
    ],
)
def test_every_kind_and_law_round_trips_and_takes_overrides(tmp_path, data):
    """to_yaml writes every field, those the shape or law ignores at their defaults: still valid."""
    case = case_from_dict({"name": "x", **data})
    assert load_case(_write(tmp_path, case.to_yaml())) == case
    assert apply_overrides(case, **{"mesh.level": 1}).mesh.level == 1


def test_foreign_fields_at_their_default_are_harmless():
    case = case_from_dict({"name": "x", "shape": {"kind": "biconcave", "aspect_ratio": 1.0},
                           "membrane": {"law": "thin_shell", "psi": 0.0, "skalak_c": 10.0}})
    assert case.shape.kind == "biconcave"


def test_numbers_take_decimal_strings_but_never_booleans():
    assert case_from_dict({"name": "x", "time": {"rtol": "1e-5"}}).time.rtol == 1e-5  # PyYAML's "1e-5"
    assert case_from_dict({"name": "x", "flow": {"shear_rate_G": 1}}).flow.shear_rate_G == 1.0
    for value in (True, False, "yes", "nan", "1_0", "0x10", " "):
        message = _one_line_error(case_from_dict, {"name": "x", "flow": {"shear_rate_G": value}}, source="s")
        assert "flow.shear_rate_G" in message and "must be a number" in message


def test_substitution_needs_enough_iterations_for_its_rate():
    # rate |1 - 5| / (1 + 5) = 2/3: ln(1e-6) / ln(2/3) = 34.07 -> 35
    ok = {"name": "x", "flow": {"viscosity_ratio": 5.0}, "solver": {"method": "substitution", "max_iter": 35}}
    assert case_from_dict(ok).solver.max_iter == 35
    ok["solver"]["max_iter"] = 34
    assert "needs >= 35 iterations" in _one_line_error(case_from_dict, ok, source="s")
    # at lambda = 1 there is no solve: any max_iter in range is fine
    assert case_from_dict({"name": "x", "solver": {"method": "substitution", "max_iter": 20}})


def test_alias_bomb_is_refused_before_it_is_built(tmp_path):
    lines = ["name: x", "a0: &a0 [" + ", ".join(["0.1"] * 10) + "]"]
    lines += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]" for i in range(1, 12)]  # 10^12 values
    import time

    t0 = time.monotonic()
    message = _one_line_error(load_case, _write(tmp_path, "\n".join(lines) + "\n"))
    assert time.monotonic() - t0 < 2.0
    assert "aliases expand to more than" in message


def test_shared_aliases_within_the_limit_still_load(tmp_path):
    text = "name: x\nflow: &f {shear_rate_G: 0.2}\nmesh: {level: 2}\n"
    assert load_case(_write(tmp_path, text)).flow.shear_rate_G == 0.2
    merged = "name: x\nmesh: {<<: &m {level: 2}, base: icosahedron}\n"
    assert load_case(_write(tmp_path, merged)).mesh.level == 2


def test_huge_values_are_shown_as_a_bounded_prefix():
    import time

    huge = {"flow": [list(range(1000))] * 1000, "name": "x" * 1_000_000}
    t0 = time.monotonic()
    message = _one_line_error(case_from_dict, huge, source="s")
    assert time.monotonic() - t0 < 1.0
    assert len(message) < 600
    assert "name = 'xxx" in message and "must have at most 200 characters" in message


def test_first_line_helper():
    from capsim.errors import first_line

    assert first_line(ValueError("a\nb")) == "a"
    assert first_line(ValueError()) == "ValueError"
    assert first_line(ValueError(), default="") == ""
