"""No lost work, clean failures: stability guards, checkpoints and --resume,
SIGTERM/SIGKILL, and every malformed input file in tests/data/bad/."""

from __future__ import annotations

import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from capsim.face.cli import app
from capsim.config import Case, ConfigError, Guards, apply_overrides, case_from_dict
from capsim.runs.runner import ResumeError, run_case
from capsim.runs.stopping import guard_violation
from capsim.storage.store import TrajectoryError, checkpoint_path, read_checkpoint, read_trajectory
from capsim.campaigns.summary import read_run_status
from interrupts import InterruptAfter as _InterruptAfter

BAD = Path(__file__).parents[1] / "data" / "bad"

# Each bad file and what its one-line error must say: the field, the value and what is allowed.
EXPECTED = {
    "case_G_zero.yaml": "flow.shear_rate_G = 0: must be > 0",
    "case_G_negative.yaml": "flow.shear_rate_G = -0.1: must be > 0",
    "case_G_nan.yaml": "flow.shear_rate_G = nan: must be a finite number",
    "case_G_string.yaml": "flow.shear_rate_G = 'fast': must be a number",
    "case_lambda_zero.yaml": "flow.viscosity_ratio = 0: must be > 0",
    "case_lambda_negative.yaml": "flow.viscosity_ratio = -5: must be > 0",
    "case_level_absurd.yaml": "mesh.level = 40: must be <= 6",
    "case_level_negative.yaml": "mesh.level = -1: must be >= 0",
    "case_level_float.yaml": "mesh.level = 2.5: must be an integer",
    "case_level_string.yaml": "mesh.level = '3': must be an integer",
    "case_unknown_law.yaml": "membrane.law = 'hooke': must be one of 'thin_shell'",
    "case_unknown_shape.yaml": "shape.kind = 'cube': must be one of 'sphere'",
    "case_unknown_field.yaml": "flow.shear_rate: unknown field 'shear_rate' (allowed: shear_rate_G",
    "case_unknown_section.yaml": "flwo: unknown field 'flwo' (allowed: name",
    "case_nesting_list.yaml": "flow = [0.1, 1.0]: must be a mapping of fields",
    "case_nesting_scalar.yaml": "mesh = 3: must be a mapping of fields",
    "case_nesting_flat.yaml": "shear_rate_G: unknown field 'shear_rate_G'",
    "case_empty.yaml": "file is empty (expected a mapping with at least 'name')",
    "case_comments_only.yaml": "file is empty",
    "case_not_yaml.yaml": "not valid YAML: expected ',' or ']', but got ':' (line 2",
    "case_binary.yaml": "not a text file (expected YAML)",
    "case_top_level_list.yaml": "top level must be a mapping of fields, got list",
    "case_missing_name.yaml": "name: required field is missing",
    "case_bad_name.yaml": "name = 'my run/1': must contain only letters",
    "case_duplicate_key.yaml": "duplicate key 'flow' (line 3",
    "case_t_end_inf.yaml": "time.t_end = inf: must be a finite number",
    "case_rtol_too_large.yaml": "time.rtol = 2.0: must be < 1",
    "case_dt_max_below_min.yaml": "time.dt_max = 0.01: must be > dt_min (0.1)",
    "case_oblate_aspect.yaml": "shape.aspect_ratio = 2.0: must be in (0, 1) for an oblate spheroid",
    "case_regular_order.yaml": "quadrature.regular_order = 5: must be one of 1, 3",
    "case_tilt_range.yaml": "initial_tilt_deg = 180: must be <= 90",
    "case_steady_int.yaml": "time.stop_when_steady = 1: must be true or false",
    "case_guard_negative.yaml": "guards.min_element_quality = -0.5: must be >= 0",
    "case_checkpoint_zero.yaml": "output.checkpoint_every_steps = 0: must be >= 1",
    "case_unwritable_output.yaml": "output path /dev/null/bad.h5: cannot create its directory /dev/null",
    "case_output_is_directory.yaml": "output path /tmp is a directory",
    "case_does_not_exist.yaml": "case_does_not_exist.yaml: no such file",
    "case_bending_string.yaml": "membrane.bending_modulus = 'abc': must be a number",
    "case_bending_contour.yaml": "bending_modulus = 0.01 needs traction: galerkin (got traction: contour)",
    "campaign_empty.yaml": "top level must be a mapping of fields",
    "campaign_not_yaml.yaml": "not valid YAML",
    "campaign_missing_output.yaml": "output: required field is missing",
    "campaign_unknown_sweep_field.yaml": "'flow.shear_rate' is not a case field (flow has: shear_rate_G",
    "campaign_negative_G.yaml": "flow.shear_rate_G = -0.2: must be > 0",
    "campaign_sweep_not_list.yaml": "sweep.flow.shear_rate_G = 0.1: input should be a valid list",
    "campaign_zip_unequal.yaml": "zip lists must have equal lengths",
    "campaign_base_nan.yaml": "base: flow.viscosity_ratio = nan: must be a finite number",
    "campaign_sweep_section.yaml": "'flow' is a section; sweep one of its fields",
    "campaign_unknown_law.yaml": "membrane.law = 'hooke': must be one of",
    "campaign_unwritable_dir.yaml": "/dev/null/out",
    "campaign_does_not_exist.yaml": "campaign_does_not_exist.yaml: no such file",
}
# Given to `summarize` and to `run --resume`, not to `run` or `sweep`.
TRAJECTORY_FILES = ("truncated.h5", "not_hdf5.h5")
CHECKPOINT_FILES = ("garbage.ckpt.npz",)

_KNOWN: dict = {}


def _fails_cleanly(result, expected: str) -> str:
    """Exit 2, one line on stderr naming `expected`, nothing on stdout, no traceback."""
    assert result.exit_code == 2, result.output
    assert isinstance(result.exception, SystemExit), result.exception
    assert result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("error: ")
    assert expected in lines[0]
    return lines[0]


def test_every_bad_file_is_checked():
    on_disk = {p.name for p in BAD.iterdir()}
    assert on_disk == {n for n in EXPECTED if "does_not_exist" not in n} | set(TRAJECTORY_FILES) | set(CHECKPOINT_FILES)
    assert len(on_disk) >= 30


@pytest.mark.parametrize(
    "name", [pytest.param(n, marks=_KNOWN[n]) if n in _KNOWN else n for n in sorted(EXPECTED)]
)
def test_bad_input_fails_cleanly(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a default output path would land here
    command = "sweep" if name.startswith("campaign_") else "run"
    result = CliRunner().invoke(app, [command, str(BAD / name), "-q"])
    _fails_cleanly(result, EXPECTED[name])
    assert list(tmp_path.iterdir()) == []  # no partial output


@pytest.mark.parametrize("name", TRAJECTORY_FILES)
def test_summarize_refuses_a_broken_trajectory(name, tmp_path):
    path = tmp_path / name
    shutil.copy(BAD / name, path)
    result = CliRunner().invoke(app, ["summarize", str(path)])
    _fails_cleanly(result, str(path))
    assert sorted(tmp_path.iterdir()) == [path]


def test_reader_names_a_truncated_trajectory():
    with pytest.raises(TrajectoryError, match=r"truncated\.h5: .*(truncated|corrupt)"):
        read_trajectory(BAD / "truncated.h5")


# ---------------------------------------------------------------- guards


def _row(**changes) -> dict:
    row = {"t": 1.0, "volume": 4.18879, "area": 12.566, "min_element_quality": 0.8, "max_principal_stretch": 1.2}
    return {**row, **changes}


@pytest.mark.parametrize(
    "changes, expected",
    [
        ({}, None),
        ({"area": float("nan")}, "guard non_finite: area = nan"),
        ({"min_element_quality": 0.04}, "guard min_element_quality: worst element quality = 0.04 < 0.05"),
        ({"volume": 4.18879 * 1.02}, "guard max_volume_drift: |V/V0 - 1| = 0.02 > 0.01"),
        ({"volume": 4.18879 * 0.98}, "guard max_volume_drift: |V/V0 - 1| = 0.02 > 0.01"),
        ({"area": 12.566 * 3.5}, "guard max_area_change: |A/A0 - 1| = 2.5 > 2"),
        ({"max_principal_stretch": 11.0}, "guard max_principal_stretch: largest principal stretch = 11 > 10"),
    ],
)
def test_guard_names_itself_and_its_value(changes, expected):
    assert guard_violation(_row(**changes), _row(), Guards()) == expected


def _case(tmp_path: Path, name: str = "robust", **dotted) -> Case:
    base = {
        "name": name,
        "flow": {"shear_rate_G": 0.2},
        "mesh": {"level": 0},
        "time": {"t_end": 0.5},
        "output": {"path": str(tmp_path / f"{name}.h5"), "snapshot_every": 0.2, "checkpoint_every_steps": 4},
    }
    case = case_from_dict(base)
    return apply_overrides(case, **dotted) if dotted else case


def test_tripped_guard_stops_unstable_and_keeps_every_step(tmp_path):
    case = _case(tmp_path, **{"guards.min_element_quality": 0.99, "time.t_end": 1.0})
    summary = run_case(case)
    assert summary["status"] == "unstable"
    assert summary["status_reason"].startswith("guard min_element_quality: worst element quality = ")
    assert summary["status_reason"].endswith(f"< 0.99 at kt = {summary['t']:.6g}")
    data = read_trajectory(case.output.path)
    assert data["attrs"]["status"] == "unstable"
    assert data["attrs"]["status_reason"] == summary["status_reason"]
    q = data["timeseries"]["min_element_quality"]
    assert len(q) == summary["steps"] + 1  # step 0 and every accepted step, the tripping one last
    assert q[-1] < 0.99 <= q[:-1].min()
    assert data["timeseries"]["t"][-1] == summary["t"] < 1.0
    assert data["snapshot_t"][-1] == summary["t"]
    assert not checkpoint_path(case.output.path).exists()


def test_far_too_loose_tolerance_stops_unstable(tmp_path):
    # A stiff membrane (small G) stepped with rtol = 0.9: explicit steps far past the
    # elastic stability limit pump the discrete volume within a few steps.
    case = case_from_dict({
        "name": "loose", "flow": {"shear_rate_G": 0.05}, "mesh": {"level": 1},
        # rkf23: an explicit scheme whose step follows the tolerance, not the stiffness (rkc would stay stable)
        "time": {"t_end": 20.0, "rtol": 0.9, "dt_initial": 0.01, "scheme": "rkf23"},
        "output": {"path": str(tmp_path / "loose.h5")},
    })
    summary = run_case(case)
    assert summary["status"] == "unstable"
    assert summary["status_reason"].startswith("guard max_volume_drift: |V/V0 - 1| = ")
    assert summary["status_reason"].endswith(f"> 0.01 at kt = {summary['t']:.6g}")
    assert summary["motion"] == "unstable"
    data = read_trajectory(case.output.path)
    assert data["attrs"]["status"] == "unstable"
    ts = data["timeseries"]
    assert len(ts["t"]) == summary["steps"] + 1 >= 3
    assert ts["t"][-1] == summary["t"] < 20.0
    drift = np.abs(ts["volume"] / ts["volume"][0] - 1.0)
    assert drift[-1] > 0.01 >= drift[:-1].max()  # every step up to the one that crossed the guard


# ---------------------------------------------------------------- checkpoints and resume



@pytest.fixture(scope="module")
def interrupted(tmp_path_factory):
    """A level-0 run stopped after 7 steps (last checkpoint at step 4) and its case."""
    tmp = tmp_path_factory.mktemp("interrupted")
    case = _case(tmp)
    summary = run_case(case, progress=_InterruptAfter(7))
    return case, summary


def test_interrupt_writes_a_checkpoint_and_a_readable_file(interrupted):
    case, summary = interrupted
    assert summary["status"] == "interrupted"
    assert summary["status_reason"].startswith("interrupted by SIGINT at kt = ")
    data = read_trajectory(case.output.path)
    assert data["attrs"]["status"] == "interrupted"
    assert len(data["timeseries"]["t"]) == 8
    saved = read_checkpoint(checkpoint_path(case.output.path))
    assert int(saved["steps"]) == 7  # written again at the stop, from the last accepted step
    assert float(saved["t"]) == summary["t"] == data["timeseries"]["t"][-1]


def test_resume_is_bit_identical_with_viscosity_contrast_and_bending(tmp_path):
    """λ = 5 (GMRES warm-started from the previous velocity and right-hand side, both
    in the checkpoint) with a bending modulus: the resumed run repeats the
    uninterrupted one to 1e-10."""
    dotted = {"flow.viscosity_ratio": 5.0, "membrane.bending_modulus": 1e-3, "mesh.level": 1, "time.t_end": 0.4}
    case = _case(tmp_path, "contrast", **dotted)
    assert run_case(case, progress=_InterruptAfter(7))["status"] == "interrupted"
    resumed = run_case(case, resume=True)
    reference = run_case(apply_overrides(case, **{"output.path": str(tmp_path / "reference.h5")}))
    assert resumed["status"] == reference["status"] == "completed"
    assert resumed["steps"] == reference["steps"]
    got, want = read_trajectory(case.output.path), read_trajectory(reference["path"])
    for key in ("t", "D_xy", "theta", "N1_star", "N2_star"):
        np.testing.assert_allclose(got["timeseries"][key], want["timeseries"][key], rtol=0, atol=1e-10, err_msg=key)


def _copy_run(case: Case, to: Path) -> Case:
    path = to / "moved.h5"
    shutil.copy(case.output.path, path)
    shutil.copy(checkpoint_path(case.output.path), checkpoint_path(path))
    return apply_overrides(case, **{"output.path": str(path)})


def test_resume_matches_uninterrupted_run(interrupted, tmp_path):
    case, _ = interrupted
    moved = _copy_run(case, tmp_path)
    resumed = run_case(moved, resume=True)
    reference = run_case(apply_overrides(case, **{"output.path": str(tmp_path / "reference.h5")}))
    assert resumed["status"] == reference["status"] == "completed"
    assert resumed["steps"] == reference["steps"]
    assert abs(resumed["final_D_xy"] - reference["final_D_xy"]) <= 1e-10
    got, want = read_trajectory(moved.output.path), read_trajectory(reference["path"])
    for key, series in want["timeseries"].items():
        np.testing.assert_allclose(got["timeseries"][key], series, rtol=0, atol=1e-10, err_msg=key)
    np.testing.assert_array_equal(got["snapshot_t"], want["snapshot_t"])
    np.testing.assert_allclose(got["positions"], want["positions"], rtol=0, atol=1e-10)
    assert got["summary"]["motion"] == want["summary"]["motion"]
    assert not checkpoint_path(moved.output.path).exists()  # a finished run needs none


def _resume_cli(case: Case, tmp_path: Path):
    case_file = tmp_path / "case.yaml"
    case_file.write_text(case.to_yaml())
    return CliRunner().invoke(app, ["run", str(case_file), "-q", "--resume"])


def _snapshot(directory: Path) -> dict:
    return {p.name: p.read_bytes() for p in directory.iterdir()}


@pytest.mark.parametrize(
    "damage, expected",
    [
        ("truncated_trajectory", "moved.h5: unreadable HDF5 file (truncated or corrupt?)"),
        ("not_hdf5_trajectory", "moved.h5: not an HDF5 file"),
        ("missing_trajectory", "moved.h5: no such file"),
        ("garbage_checkpoint", "moved.h5.ckpt.npz: unreadable checkpoint"),
        ("missing_checkpoint", "moved.h5: the run ended 'interrupted' and left no checkpoint to continue from"),
        ("another_case", "belongs to another case: flow.shear_rate_G = 0.2 in the checkpoint, 0.3 now"),
    ],
)
def test_resume_refuses_cleanly_and_touches_nothing(interrupted, tmp_path, damage, expected):
    case, _ = interrupted
    runs = tmp_path / "runs"
    runs.mkdir()
    moved = _copy_run(case, runs)
    path, ckpt = Path(moved.output.path), checkpoint_path(moved.output.path)
    if damage == "truncated_trajectory":
        shutil.copy(BAD / "truncated.h5", path)
    elif damage == "not_hdf5_trajectory":
        shutil.copy(BAD / "not_hdf5.h5", path)
    elif damage == "missing_trajectory":
        path.unlink()
    elif damage == "garbage_checkpoint":
        shutil.copy(BAD / "garbage.ckpt.npz", ckpt)
    elif damage == "missing_checkpoint":
        ckpt.unlink()
    elif damage == "another_case":
        moved = apply_overrides(moved, **{"flow.shear_rate_G": 0.3})
    before = _snapshot(runs)
    line = _fails_cleanly(_resume_cli(moved, tmp_path), expected)
    assert line.startswith("error: cannot resume: ")
    assert _snapshot(runs) == before
    with pytest.raises(ResumeError) as info:
        run_case(moved, resume=True)
    assert expected in str(info.value)
    assert _snapshot(runs) == before


def _checkpointed_steps(ckpt: Path) -> int:
    """Steps in the checkpoint (-1 if none yet): replaced atomically, so safe to
    read while the run goes on, unlike its HDF5 file."""
    try:
        return int(read_checkpoint(ckpt)["steps"])
    except Exception:
        return -1


def _wait_for_checkpoint(proc: subprocess.Popen, ckpt: Path, steps: int) -> None:
    deadline = time.monotonic() + 120.0
    while _checkpointed_steps(ckpt) < steps:
        assert proc.poll() is None, proc.stderr.read().decode()
        assert time.monotonic() < deadline, f"no checkpoint of step {steps} after 120 s"
        time.sleep(0.02)


def test_sigkill_sigterm_and_resume_match_uninterrupted_run(tmp_path):
    """A level-1 run killed with SIGKILL at a random moment, resumed, stopped
    with SIGTERM, resumed again to the end: same steps as an uninterrupted run."""
    seed = int.from_bytes(os.urandom(4), "little")
    rng = random.Random(seed)
    case = case_from_dict({
        # kt 12 (~270 steps): at kt 1.2 (34 steps) a fast machine ran from the chosen checkpoint
        # to within 4 steps of the end before the kill landed, and the resumed run finished
        # before the SIGTERM this test sends it; at kt 3 (67 steps, 0.3 s once the run file's
        # flushes got cheaper) the resumed run could end before the test saw its checkpoint
        # rtol 1e-4 (not auto's 2e-3 at level 1): the ~270 steps the timing above was made for
        "name": "killed", "flow": {"shear_rate_G": 0.2}, "mesh": {"level": 1}, "time": {"t_end": 12.0, "rtol": 1e-4},
        "output": {"path": str(tmp_path / "killed.h5"), "snapshot_every": 0.5, "checkpoint_every_steps": 2},
    })
    case_file = tmp_path / "case.yaml"
    case_file.write_text(case.to_yaml())
    path, ckpt = Path(case.output.path), checkpoint_path(case.output.path)
    cmd = [sys.executable, "-m", "capsim.face.cli", "run", str(case_file), "-q"]

    # SIGKILL somewhere after a random checkpoint (the run takes about 270 steps)
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _wait_for_checkpoint(proc, ckpt, rng.randrange(0, 16, 2))
    time.sleep(rng.uniform(0.0, 0.1))
    proc.kill()
    proc.wait()
    data = read_trajectory(path)  # readable after SIGKILL
    assert data["attrs"]["status"] == "running", f"seed {seed}"
    killed_at = _checkpointed_steps(ckpt)
    assert len(data["timeseries"]["t"]) >= killed_at + 1

    proc = subprocess.Popen(cmd + ["--resume"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _wait_for_checkpoint(proc, ckpt, killed_at + 4)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 1, err
    data = read_trajectory(path)
    assert data["attrs"]["status"] == "interrupted", f"seed {seed}"
    assert data["attrs"]["status_reason"].startswith("interrupted by SIGTERM at kt = ")
    assert _checkpointed_steps(ckpt) == len(data["timeseries"]["t"]) - 1

    done = subprocess.run(cmd + ["--resume"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    got = read_trajectory(path)
    assert got["attrs"]["status"] == "completed"
    reference = run_case(apply_overrides(case, **{"output.path": str(tmp_path / "reference.h5")}))
    want = read_trajectory(reference["path"])
    assert len(got["timeseries"]["t"]) == len(want["timeseries"]["t"]) == reference["steps"] + 1, f"seed {seed}"
    assert abs(got["timeseries"]["D_xy"][-1] - want["timeseries"]["D_xy"][-1]) <= 1e-10, f"seed {seed}"
    np.testing.assert_allclose(got["timeseries"]["t"], want["timeseries"]["t"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(got["positions"], want["positions"], rtol=0, atol=1e-10)
    assert not ckpt.exists()


# ---------------------------------------------------------------- schema fuzzing

_values = st.one_of(
    st.none(), st.booleans(), st.integers(-10**6, 10**6), st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=12), st.lists(st.integers(), max_size=3),
)
_sections = {
    "shape": ["kind", "aspect_ratio", "c0"], "membrane": ["law", "psi", "skalak_c", "traction"],
    "flow": ["shear_rate_G", "viscosity_ratio"], "mesh": ["base", "level"], "time": ["t_end", "rtol", "dt_min"],
    "guards": ["min_element_quality", "max_volume_drift"], "output": ["path", "checkpoint_every_steps"],
}
_section = st.sampled_from(sorted(_sections)).flatmap(
    lambda s: st.tuples(st.just(s), st.one_of(
        _values, st.dictionaries(st.sampled_from(_sections[s] + ["typo"]), _values, max_size=3))))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(name=st.one_of(st.just("fuzz"), _values), sections=st.lists(_section, max_size=4))
def test_fuzzed_case_dicts_validate_or_fail_in_one_line(name, sections):
    d = {"name": name, **dict(sections)}
    try:
        case = case_from_dict(d)
    except ConfigError as exc:
        message = str(exc)
        assert "\n" not in message and message.startswith("<dict>: ")
        return
    assert case_from_dict(yaml.safe_load(case.to_yaml())) == case


def test_step_collapse_guard_names_the_stall():
    from capsim.runs.stopping import step_collapse

    steady = [0.05] * 300
    assert step_collapse(steady, 1e-3) is None
    stalled = [0.05] * 250 + [1e-5] * 20
    reason = step_collapse(stalled, 1e-3)
    assert reason is not None and "min_dt_fraction" in reason and "1e-05" in reason
    assert step_collapse([0.05] * 100 + [1e-5] * 20, 1e-3) is None  # too short a history to judge


def test_sweep_stops_on_sigterm_to_its_process_group_with_idle_workers(tmp_path):
    """A batch system's SIGTERM reaches the parent and every worker. Workers that
    had no run left must not die of it (they wait for work holding the task queue's
    lock; dying there hung the pool's shutdown): the sweep exits promptly, the
    running case is closed as 'interrupted' and the finished ones stay completed."""
    campaign = tmp_path / "c.yaml"
    campaign.write_text(yaml.safe_dump({
        "name": "sigterm",
        # a checkpoint every 5 steps: the sign that the long run has taken steps (by default the first is 10 s in)
        "base": {"shape": {"kind": "sphere"}, "time": {"t_end": 60.0}, "output": {"checkpoint_every_steps": 5}},
        "sweep": {},
        "zip": {"flow.shear_rate_G": [0.1, 0.2, 0.3], "mesh.level": [2, 0, 0], "time.t_end": [60.0, 0.3, 0.3]},
        "output": {"dir": str(tmp_path / "out")},
    }))
    proc = subprocess.Popen(
        [sys.executable, "-m", "capsim.face.cli", "sweep", str(campaign), "--workers", "3", "-q"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
    )
    out = tmp_path / "out"
    deadline = time.monotonic() + 180.0
    # wait until both short runs are done and the long one has written some steps
    while True:
        assert proc.poll() is None, proc.stderr.read()
        assert time.monotonic() < deadline, "the short runs did not finish in 180 s"
        done = [p for p in out.glob("*.h5") if "level0" in p.name and read_run_status(p) == "completed"]
        long_run = [p for p in out.glob("*level2*.ckpt.npz")]
        if len(done) == 2 and long_run:
            break
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGTERM)
    try:
        proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        pytest.fail("the sweep did not exit within 30 s of SIGTERM")
    statuses = sorted(read_run_status(p) for p in out.glob("*.h5"))
    assert statuses == ["completed", "completed", "interrupted"]



def _as_killed_early(path: Path) -> None:
    """Make a completed run's file look like one whose process was killed before its first checkpoint:
    status 'running', no end state (and no checkpoint beside it)."""
    with h5py.File(path, "a") as f:
        f.attrs["status"] = "running"
        for name in ("end_state", "end_state_byte"):
            del f[name]
    assert not checkpoint_path(path).exists()


def test_resume_starts_again_a_run_killed_before_its_first_checkpoint(tmp_path):
    # checkpoints by wall time (10 s by default): a run killed in its first seconds has none; --resume then
    # runs the case again, which is what continuing from its first state would do
    case = case_from_dict({"name": "early", "flow": {"shear_rate_G": 0.2}, "mesh": {"level": 0},
                           "time": {"t_end": 0.5}, "output": {"path": str(tmp_path / "early.h5")}})
    assert run_case(case)["status"] == "completed"
    reference = read_trajectory(case.output.path)["timeseries"]
    _as_killed_early(Path(case.output.path))
    result = run_case(case, resume=True)
    assert result["status"] == "completed"
    again = read_trajectory(case.output.path)["timeseries"]
    for key in ("t", "D_xy", "theta"):
        np.testing.assert_array_equal(again[key], reference[key])
    # failed before its first checkpoint (a full disk refused even the failure's): started again too
    _as_killed_early(Path(case.output.path))
    with h5py.File(case.output.path, "a") as f:
        f.attrs["status"] = "failed"
    assert run_case(case, resume=True)["status"] == "completed"
    np.testing.assert_array_equal(read_trajectory(case.output.path)["timeseries"]["D_xy"], reference["D_xy"])
    # a file of another case left 'running' is not this run's to start again: refused, untouched
    _as_killed_early(Path(case.output.path))
    before = Path(case.output.path).read_bytes()
    with pytest.raises(ResumeError, match="left no checkpoint"):
        run_case(apply_overrides(case, **{"flow.shear_rate_G": 0.3}), resume=True)
    assert Path(case.output.path).read_bytes() == before
