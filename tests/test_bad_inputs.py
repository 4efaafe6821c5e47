"""Hostile and careless inputs (issue 19, items 8-11): every one is refused by the
CLI with exit 2 and one line that names the file, the field (or the YAML problem
and its line), the value and what is allowed — no traceback, no file written,
the input untouched, and in bounded time (no alias bomb, FIFO or huge grid hangs).

The files live in tests/data/invalid/; the few that cannot be stored in git (a
FIFO, /dev/zero, a 2 MB file, a directory) are made by the tests.
"""

from __future__ import annotations

import hashlib
import os
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from capsim.face.cli import app

DATA = Path(__file__).parent / "data" / "invalid"

_BOOL = "not true (YAML reads yes/no/on/off as booleans)"
_RANGE_LAMBDA = "must be in [0.001, 1000]"
_SNAP = "must be >= max(time.dt_min, time.t_end / 10000)"

# file -> what its one line must say after the file name (field = value: allowed)
EXPECTED = {
    # YAML structure: refused before any object is built
    "case_alias_bomb.yaml": "not valid YAML: aliases expand to more than 100000 values",
    "case_alias_bomb_in_field.yaml": "not valid YAML: aliases expand to more than 100000 values (an alias bomb?) (line",
    "case_nested_lists.yaml": "not valid YAML: nested deeper than 32 levels (line 2",
    "case_nested_mappings.yaml": "not valid YAML: nested deeper than 32 levels (line",
    "case_list_as_key.yaml": "not valid YAML: a key must be a plain name, not a list (line 3",
    "case_mapping_as_key.yaml": "not valid YAML: a key must be a plain name, not a mapping (line 2",
    "case_self_referencing_alias.yaml": "not valid YAML: an alias refers to itself (line 2",
    "case_undefined_alias.yaml": "not valid YAML: found undefined alias 'nowhere' (line 2",
    "case_two_documents.yaml": "not valid YAML: but found another document (line 2",
    "case_python_tag.yaml": "not valid YAML: could not determine a constructor for the tag",
    "case_bad_merge.yaml": "not valid YAML: expected a mapping for merging",
    "case_duplicate_nested_key.yaml": "not valid YAML: duplicate key 'viscosity_ratio' (line 4",
    "case_huge_unknown_key.yaml": "flow.'qqqqq",
    "case_huge_string_value.yaml": "flow.shear_rate_G = '9z9z9z",
    # YAML 1.1 booleans and other coercions
    "case_G_yes.yaml": f"flow.shear_rate_G = True: must be a number, {_BOOL}",
    "case_lambda_on.yaml": f"flow.viscosity_ratio = True: must be a number, {_BOOL}",
    "case_tilt_no.yaml": "initial_tilt_deg = False: must be a number, not false",
    "case_level_yes.yaml": f"mesh.level = True: must be an integer, {_BOOL}",
    "case_regular_order_true.yaml": "quadrature.regular_order = True: must be one of 1, 3, 4, 6, 7, 12, not true",
    "case_max_steps_true.yaml": f"time.max_steps = True: must be an integer, {_BOOL}",
    "case_dt_initial_true.yaml": f"time.dt_initial = True: must be a number, {_BOOL}",
    "case_guard_drift_yes.yaml": f"guards.max_volume_drift = True: must be a number, {_BOOL}",
    "case_checkpoint_seconds_off.yaml": "output.checkpoint_every_s = False: must be a number, not false",
    "case_near_field_yes.yaml": f"quadrature.near_field_factor = True: must be a number, {_BOOL}",
    "case_bending_on.yaml": f"membrane.bending_modulus = True: must be a number, {_BOOL}",
    "case_name_yes.yaml": f"name = True: must be a string, {_BOOL}",
    "case_output_path_true.yaml": f"output.path = True: must be a string, {_BOOL}",
    "case_volume_correction_zero.yaml": "solver.volume_correction = 0: must be true or false",
    "case_volume_correction_quoted.yaml": "solver.volume_correction = 'yes': must be true or false",
    # issue 26: mesh.symmetry is auto | quarter | half | none (true/false still read as auto/none)
    "case_symmetry_one.yaml": "mesh.symmetry = 1: must be one of auto, quarter, half, none",
    "case_symmetry_quoted.yaml": "mesh.symmetry = 'true': must be one of auto, quarter, half, none",
    "case_axis_zero.yaml": "initial_axis = [0, 0, 0]: must be a nonzero vector",
    "case_axis_nan.yaml": "initial_axis = [1, nan, 0]: must be three finite numbers",
    "case_axis_and_tilt.yaml": "initial_axis = [0.0, 0.7071067811865475, 0.7071067811865475]: give initial_axis "
                               "or initial_tilt_deg (= 30), not both",
    "case_quarter_off_plane.yaml": "mesh.symmetry = 'quarter': needs the rest shape's axis in the shear plane",
    "case_G_hex_string.yaml": "flow.shear_rate_G = '0x1A': must be a number",
    "case_G_inf_string.yaml": "flow.shear_rate_G = 'inf': must be a number",
    "case_G_list.yaml": "flow.shear_rate_G = [0.1, 0.2]: must be a number",
    "case_snapshot_word.yaml": "output.snapshot_every = 'often': must be a number",
    "case_tol_word.yaml": "solver.tol = 'tight': must be a number",
    "case_solver_max_iter_float.yaml": "solver.max_iter = 50.0: must be an integer",
    # bounds from what the numerics can do
    "case_snapshot_every_tiny.yaml": f"output.snapshot_every = 1e-200: {_SNAP} = 0.001",
    "case_snapshot_below_dt_min.yaml": f"output.snapshot_every = 0.004: {_SNAP} = 0.01",
    "case_snapshot_too_many.yaml": f"output.snapshot_every = 0.05: {_SNAP} = 0.2",
    "case_solver_tol_tiny.yaml": "solver.tol = 1e-20: must be >= 1e-14",
    "case_solver_max_iter_huge.yaml": "solver.max_iter = 1000000000: must be <= 1000",
    "case_solver_max_iter_one.yaml": "solver.max_iter = 1: must be >= 20",
    "case_substitution_too_few.yaml": "solver.max_iter = 100: substitution at viscosity_ratio = 50 needs >= 346",
    "case_rtol_tiny.yaml": "time.rtol = 1e-15: must be >= 1e-10",
    "case_t_end_tiny.yaml": "time.t_end = 1e-09: must be >= max(1e-6, dt_min = 1e-08): a shorter run takes no step",
    "case_t_end_below_dt_min.yaml": "time.t_end = 0.001: must be >= max(1e-6, dt_min = 0.01)",
    "case_lambda_huge.yaml": f"flow.viscosity_ratio = 1e+300: {_RANGE_LAMBDA}",
    "case_lambda_tiny.yaml": f"flow.viscosity_ratio = 1e-09: {_RANGE_LAMBDA}",
    "case_oblate_aspect_tiny.yaml": "shape.aspect_ratio = 1e-300: must be in [0.05, 20]",
    "case_prolate_aspect_huge.yaml": "shape.aspect_ratio = 1e+300: must be in [0.05, 20]",
    "case_evans_fung_hollow_center.yaml": "shape.c0 = -0.1: the Evans-Fung thickness",
    "case_evans_fung_negative_rim.yaml": "shape.c4 = -4.0: the Evans-Fung thickness c0 + c2 s + c4 s² = -1.79 <= 0 at s",
    "case_evans_fung_all_zero.yaml": "shape.c0 = 0.0: the Evans-Fung thickness",
    "case_evans_fung_huge.yaml": "shape.c2 = 1e+300: must be <= 10",
    "case_skalak_c_huge.yaml": "membrane.skalak_c = 1000000000.0: must be in (0, 10000] (or auto)",
    "case_skalak_c_automatic.yaml": "membrane.skalak_c = 'automatic': must be a number in (0, 1e4] or auto",
    "case_skalak_c_nan.yaml": "membrane.skalak_c = nan: must be a finite number in (0, 1e4] or auto",
    "case_rtol_list.yaml": "time.rtol = ['auto']: must be a number in [1e-10, 1) or auto",
    "case_skalak_c_auto_sphere.yaml": "membrane.skalak_c = 'auto': needs a rest shape with excess area",
    "case_area_tolerance_without_auto.yaml": "membrane.area_tolerance = 0.05: applies only to skalak_c: auto",
    "case_name_too_long.yaml": "name = 'capsulecapsule",
    "case_level_huge_integer.yaml": "mesh.level = 1000000000000000000000000000000: must be <= 6",
    # fields that the chosen shape or law ignores
    "case_biconcave_with_aspect.yaml": "shape.aspect_ratio = 0.4: applies only to spheroids (oblate, prolate), not to kind: biconcave",
    "case_oblate_with_c2.yaml": "shape.c2 = 1.5: applies only to biconcave shapes, not to kind: oblate",
    "case_sphere_with_c4.yaml": "shape.c4 = -2.0: applies only to biconcave shapes, not to kind: sphere",
    "case_psi_with_thin_shell.yaml": "membrane.psi = 0.4: applies only to law: mooney_rivlin, not to law: thin_shell",
    "case_psi_with_neo_hookean.yaml": "membrane.psi = 0.2: applies only to law: mooney_rivlin, not to law: neo_hookean",
    "case_skalak_c_with_mooney_rivlin.yaml": "membrane.skalak_c = 5.0: applies only to law: skalak, not to law: mooney_rivlin",
    "case_skalak_c_with_default_law.yaml": "membrane.skalak_c = 2.0: applies only to law: skalak, not to law: thin_shell",
    # unknown choices
    "case_solver_method_unknown.yaml": "solver.method = 'conjugate_gradient': must be one of 'gmres' or 'substitution'",
    "case_traction_unknown.yaml": "membrane.traction = 'finite_elements': must be one of 'galerkin' or 'contour'",
    "case_base_unknown.yaml": "mesh.base = 'dodecahedron': must be one of 'octahedron' or 'icosahedron'",
    # campaigns
    "campaign_alias_bomb.yaml": "not valid YAML: aliases expand to more than 100000 values",
    "campaign_nested_lists.yaml": "not valid YAML: nested deeper than 32 levels",
    "campaign_list_as_key.yaml": "not valid YAML: a key must be a plain name, not a list (line 4",
    "campaign_base_list_key.yaml": "not valid YAML: a key must be a plain name, not a list (line 5",
    "campaign_self_referencing_alias.yaml": "not valid YAML: an alias refers to itself",
    "campaign_too_many_runs.yaml": "sweep/zip: the campaign has 14641 runs",
    "campaign_run_ids_too_long.yaml": "sweep/zip: run flow.shear_rate_G=0.1",
    "campaign_sweep_yes.yaml": f"run flow.shear_rate_G=True: flow.shear_rate_G = True: must be a number, {_BOOL}",
    "campaign_name_too_long.yaml": "sweepsweep': must have at most 100 characters",  # the case schema's words (one formatter)
    "campaign_psi_with_default_law.yaml": "membrane.psi = 0.1: applies only to law: mooney_rivlin",
    "campaign_lambda_huge.yaml": f"flow.viscosity_ratio = 1e+300: {_RANGE_LAMBDA}",
    "campaign_snapshot_tiny.yaml": f"base: output.snapshot_every = 1e-300: {_SNAP}",
    "campaign_zip_biconcave_aspect.yaml": "shape.aspect_ratio = 0.5: applies only to spheroids",
    "campaign_max_iter_one.yaml": "base: solver.max_iter = 1: must be >= 20",
    "campaign_t_end_tiny.yaml": "time.t_end = 1e-13: must be >= max(1e-6",
    "campaign_volume_correction_ints.yaml": "solver.volume_correction = 0: must be true or false",
    "campaign_evans_fung_no_surface.yaml": "shape.c0 = -0.5: the Evans-Fung thickness",
    "campaign_huge_sweep_key.yaml": "sweep: 'flow.wwwww",
}

# messages that must say more than the table's prefix
EXTRA = {
    "campaign_run_ids_too_long.yaml": ("has an id of 336 characters", "more than 200", "255 bytes"),
    "campaign_too_many_runs.yaml": ("more than --max-runs 10000",),
    "case_huge_unknown_key.yaml": ("unknown field", "(allowed: shear_rate_G, capillary_number, viscosity_ratio, history, kind, velocity_gradient, poiseuille_radius)"),
    "case_huge_string_value.yaml": ("must be a number",),
    "case_name_too_long.yaml": ("must have at most 200 characters",),
    "case_evans_fung_hollow_center.yaml": ("give no surface", "must be > 0 on [0, 1]"),
}

MAX_LINE = 500  # characters: a bounded prefix of every value, never the whole of it


def _command(path: Path) -> list[str]:
    return ["sweep", str(path), "-q"] if path.name.startswith("campaign_") else ["validate", str(path)]


def _fails_cleanly(args: list[str], expected: str, where: Path, seconds: float = 10.0) -> str:
    before = sorted(os.listdir(where))
    t0 = time.monotonic()
    result = CliRunner().invoke(app, args)
    elapsed = time.monotonic() - t0
    assert result.exit_code == 2, (result.exit_code, result.output, result.exception)
    assert isinstance(result.exception, SystemExit), result.exception
    assert result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr[:2000]
    line = lines[0]
    assert line.startswith("error: "), line
    assert "Traceback" not in line
    assert expected in line, line
    assert len(line) <= MAX_LINE, len(line)
    assert elapsed < seconds, f"took {elapsed:.1f} s"
    assert sorted(os.listdir(where)) == before  # nothing written
    return line


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_every_invalid_file_is_checked():
    on_disk = {p.name for p in DATA.iterdir()}
    assert on_disk == set(EXPECTED)
    assert len(on_disk) >= 60


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_invalid_input_is_refused_in_one_line(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a default output path or campaign dir would land here
    path = DATA / name
    digest = _digest(path)
    line = _fails_cleanly(_command(path), EXPECTED[name], tmp_path)
    assert line.startswith(f"error: {path}: "), line  # names the file
    for words in EXTRA.get(name, ()):
        assert words in line, line
    assert _digest(path) == digest  # the input is untouched


@pytest.mark.parametrize("name", sorted(n for n in EXPECTED if n.startswith("case_")))
def test_run_refuses_the_same_cases_before_writing(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = DATA / name
    line = _fails_cleanly(["run", str(path), "-q", "-o", str(tmp_path / "out.h5")], EXPECTED[name], tmp_path)
    assert line.startswith(f"error: {path}: "), line


# ------------------------------------------------------------ files git cannot hold


def _special(kind: str, tmp_path: Path) -> Path:
    path = tmp_path / f"{kind}.yaml"
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "dev_zero":
        path.symlink_to("/dev/zero")
    elif kind == "directory":
        path.mkdir()
    elif kind == "too_large":
        path.write_text("name: big\n" + "# padding\n" * 220_000)
    return path


_SPECIAL = {
    "fifo": "not a regular file (a pipe, device or socket)",
    "dev_zero": "not a regular file (a pipe, device or socket)",
    "directory": "is a directory, not a YAML file",
    "too_large": "a YAML input is at most 1048576 bytes",
}


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs a POSIX file system")
@pytest.mark.parametrize("command", ["validate", "run", "sweep"])
@pytest.mark.parametrize("kind", sorted(_SPECIAL))
def test_non_regular_or_huge_files_are_refused_without_reading(kind, command, tmp_path, monkeypatch):
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    path = _special(kind, tmp_path)
    args = [command, str(path)] + (["-q"] if command != "validate" else [])
    line = _fails_cleanly(args, _SPECIAL[kind], work, seconds=5.0)  # a FIFO must not block
    assert line.startswith(f"error: {path}: "), line


# ------------------------------------------------------------ grid size and bench options


def test_max_runs_refuses_a_grid_up_front(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    campaign = tmp_path / "grid.yaml"
    values = ", ".join(f"{0.01 * (i + 1):.2f}" for i in range(300))
    tilts = ", ".join(str(i % 90) for i in range(300))
    campaign.write_text(
        f"name: grid\noutput: {{dir: out}}\nsweep:\n  flow.shear_rate_G: [{values}]\n  initial_tilt_deg: [{tilts}]\n"
    )
    # 90 000 runs: refused from the size alone, long before 90 000 cases could be validated
    before = sorted(os.listdir(tmp_path))
    result = CliRunner().invoke(app, ["sweep", str(campaign), "-q"])
    assert result.exit_code == 2
    assert "the campaign has 90000 runs (shear_rate_G 300 x initial_tilt_deg 300)" in result.stderr
    assert result.stderr.count("\n") == 1 and sorted(os.listdir(tmp_path)) == before
    small = tmp_path / "small.yaml"
    small.write_text("name: small\noutput: {dir: out}\nsweep:\n  flow.shear_rate_G: [0.1, 0.2, 0.3]\n")
    _fails_cleanly(["sweep", str(small), "-q", "--max-runs", "2"], "the campaign has 3 runs", tmp_path)
    _fails_cleanly(["sweep", str(small), "-q", "--max-runs", "0"], "--max-runs = 0: must be >= 1", tmp_path)


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["--level", "40"], "bench options: mesh.level = 40: must be <= 6"),
        (["--level", "-1"], "bench options: mesh.level = -1: must be >= 0"),
        (["--level", "2", "--viscosity-ratio", "nan"], "flow.viscosity_ratio = nan: must be a finite number"),
        (["--level", "2", "--viscosity-ratio", "inf"], "flow.viscosity_ratio = inf: must be a finite number"),
        (["--level", "2", "--viscosity-ratio", "1e300"], f"flow.viscosity_ratio = 1e+300: {_RANGE_LAMBDA}"),
        (["--level", "2", "--viscosity-ratio", "-2"], "flow.viscosity_ratio = -2.0: must be > 0"),
        (["--level", "2", "--repeat", "0"], "--repeat = 0: must be an integer in [1, 1000]"),
        (["--level", "2", "--repeat", "1000000000"], "--repeat = 1000000000: must be an integer in [1, 1000]"),
    ],
)
def test_bench_checks_its_options_like_run(args, expected, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _fails_cleanly(["bench", *args], expected, tmp_path)
