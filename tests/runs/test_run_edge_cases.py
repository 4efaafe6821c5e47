"""Runs at their edges (issue 38's findings): the automatic scheme at extreme stiffness,
a stop during its start-up probe, wall-clock stops that resume, extending a campaign, the
output check under the lock, Ctrl-C twice."""

from __future__ import annotations

import math

import numpy as np
import pytest

from capsim.solve.timestepping import Automatic, EmbeddedRungeKutta, RungeKuttaChebyshev, make_integrator


def _overflowing(y: np.ndarray):
    """A velocity whose Jacobian overflows (a membrane of bending 1e300 does this)."""
    return 1e300 * np.sinh(50.0 * y) * 1e10, None


def test_rkc_with_an_overflowing_jacobian_fails_its_trial_instead_of_raising():
    """Finding 1: ρ = inf made rkc's stage count raise OverflowError; the trial is now
    non-finite (the run's guard then says unstable)."""
    integ = make_integrator("rkc", _overflowing, np.ones(6), rtol=1e-3, dt_initial=1e-3, dt_min=1e-9, dt_max=0.1)
    integ.start()
    assert math.isinf(integ.spectral_radius())
    trial = integ.attempt(1.0)
    assert not trial.finite and not trial.accepted


def test_auto_with_an_infinite_spectral_radius_picks_a_scheme_and_says_why(monkeypatch):
    """Finding 1: auto divided by the stability step 2.5/ρ = 0 (ZeroDivisionError)."""
    from capsim.config import case_from_dict

    monkeypatch.setattr(RungeKuttaChebyshev, "spectral_radius", lambda self: math.inf)

    from capsim.scene import Scene

    case = case_from_dict({"name": "x", "mesh": {"level": 0}})

    class Model:
        scene = Scene.of(case)  # what the schemes ask of the run's scene

        def state(self):
            return {}

        def restore(self, state):
            pass

    y0 = np.ones(6)
    cls, why, _, _ = Automatic.resolve(case, Model(), lambda y: (np.zeros_like(y), None), y0)
    assert cls is EmbeddedRungeKutta
    assert "ρ = inf" in why and "overflowed" in why


# ---------------------------------------------------------------- a stop during set-up (finding 2)

import os
import signal
from pathlib import Path

import yaml
from typer.testing import CliRunner

from capsim.face.cli import app
from capsim.config import case_from_dict
from capsim.runs.runner import run_case

cli = CliRunner()


@pytest.fixture
def ctrl_c():
    """SIGINT as Ctrl-C in a terminal, however the tests were started (a background job inherits
    it ignored, and capsim keeps an ignored SIGINT ignored); restored afterwards."""
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, old)


def _case(tmp: Path, name: str = "r", **sections) -> dict:
    out = {"name": name, "flow": {"shear_rate_G": 0.2}, "mesh": {"level": 0}, "time": {"t_end": 0.3},
           "output": {"path": str(tmp / f"{name}.h5"), "snapshot_every": 0.1, "checkpoint_every_steps": 3}}
    for key, value in sections.items():
        out[key] = {**out.get(key, {}), **value}
    return out


def test_sigterm_during_the_automatic_schemes_probe_is_an_interrupted_run_not_a_traceback(tmp_path, monkeypatch):
    """Finding 2: SIGTERM while auto estimated ρ raised _StopRequested out of the CLI."""
    probe = RungeKuttaChebyshev.spectral_radius

    def interrupted_probe(self):
        os.kill(os.getpid(), signal.SIGTERM)  # the handler only sets a flag: read at the next evaluation
        return probe(self)

    monkeypatch.setattr(RungeKuttaChebyshev, "spectral_radius", interrupted_probe)
    case_path = tmp_path / "r.yaml"
    case_path.write_text(yaml.safe_dump(_case(tmp_path, flow={"viscosity_ratio": 2.0})))
    result = cli.invoke(app, ["run", str(case_path), "-q"])
    assert result.exit_code == 1, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    assert "interrupted" in result.output and "SIGTERM" in result.output
    assert "during set-up" in result.output
    assert not (tmp_path / "r.h5").exists()
    # run again: it completes (nothing of the stopped attempt is in the way)
    monkeypatch.setattr(RungeKuttaChebyshev, "spectral_radius", probe)
    again = cli.invoke(app, ["run", str(case_path), "-q"])
    assert again.exit_code == 0, again.output


def test_a_sigterm_during_set_up_leaves_an_existing_file_as_it_was(tmp_path, monkeypatch):
    case = case_from_dict(_case(tmp_path, flow={"viscosity_ratio": 2.0}))
    assert run_case(case).status == "completed"
    before = (tmp_path / "r.h5").read_bytes()
    probe = RungeKuttaChebyshev.spectral_radius

    def interrupted_probe(self):
        os.kill(os.getpid(), signal.SIGTERM)
        return probe(self)

    monkeypatch.setattr(RungeKuttaChebyshev, "spectral_radius", interrupted_probe)
    result = run_case(case)
    assert result.status == "interrupted" and "nothing was computed" in result.status_reason
    assert (tmp_path / "r.h5").read_bytes() == before


# ---------------------------------------------------------------- the output check under the lock (finding 11)


def test_a_run_file_written_between_the_check_and_the_lock_is_not_replaced(tmp_path, monkeypatch):
    """Finding 11: api.run checked the output before run_case took the lock; a second run into
    the same new path that completed in between was replaced by the first. The window is held
    open by construction: the second run is done inside the first's pre-lock warm-up."""
    import capsim.api as api
    from capsim.storage.files import OutputError

    first = case_from_dict(_case(tmp_path, name="first"))
    second = case_from_dict({**_case(tmp_path, name="second"), "output": {"path": str(tmp_path / "first.h5")}})
    real = api._apply_thread_policy

    def meanwhile(*args, **kwargs):  # called after the output check, before the run takes its lock
        real(*args, **kwargs)
        monkeypatch.setattr(api, "_apply_thread_policy", real)
        assert run_case(second).status == "completed"

    monkeypatch.setattr(api, "_apply_thread_policy", meanwhile)
    written = (tmp_path / "first.h5")
    with pytest.raises(OutputError, match="exists"):
        api.run(first)
    from capsim.storage.store import read_case

    assert read_case(written).name == "second"  # the other run's file is intact


# ---------------------------------------------------------------- wall-clock stops that resume (finding 3)


def test_a_wall_clock_stop_resumes_with_the_same_case_and_advances_each_invocation(tmp_path):
    """Finding 3: time.max_wall_s counted the run's total time, so --resume of the same case
    stopped again at once (t unchanged). Per invocation, every resume advances."""
    case = case_from_dict(_case(tmp_path, time={"t_end": 0.3, "max_wall_s": 1e-3}))
    result = run_case(case)
    assert result.status == "interrupted" and "max_wall_s" in result.status_reason
    times = [result.t]
    for _ in range(3):
        result = run_case(case, resume=True)
        assert result.status in ("interrupted", "completed")
        assert result.t > times[-1], times
        times.append(result.t)


def test_a_sweep_resumes_runs_its_wall_clock_limit_stopped(tmp_path):
    from capsim.campaigns.campaign import campaign_from_dict, run_campaign

    base = _case(tmp_path, time={"t_end": 0.2, "max_wall_s": 1e-3})
    base.pop("name")
    base["output"] = {"checkpoint_every_steps": 3}
    campaign = campaign_from_dict({"name": "w", "base": base, "sweep": {"flow.shear_rate_G": [0.1]},
                                   "output": {"dir": str(tmp_path / "runs")}})
    first = run_campaign(campaign, workers=1)
    assert first["records"][0]["status"] == "interrupted", first["records"]
    from capsim.storage.store import read_trajectory

    path = tmp_path / "runs" / (first["records"][0]["run_id"] + ".h5")
    t_first = read_trajectory(path)["timeseries"]["t"][-1]
    run_campaign(campaign, workers=1)
    assert read_trajectory(path)["timeseries"]["t"][-1] > t_first


# ---------------------------------------------------------------- extending runs and campaigns (finding 4)


def _campaign_file(tmp: Path, t_end: float) -> Path:
    base = _case(tmp, time={"t_end": t_end})
    base.pop("name")
    base["output"] = {"snapshot_every": 0.1}
    path = tmp / "c.yaml"
    path.write_text(yaml.safe_dump({"name": "ext", "base": base, "sweep": {"flow.shear_rate_G": [0.1, 0.2]},
                                    "output": {"dir": str(tmp / "runs")}}))
    return path


def test_a_campaign_extends_to_a_later_t_end_with_one_command(tmp_path):
    """Finding 4: sweep --set time.t_end=... was refused as another campaign."""
    from capsim.storage.store import read_trajectory

    path = _campaign_file(tmp_path, 0.2)
    assert cli.invoke(app, ["sweep", str(path), "-q", "--workers", "1"]).exit_code == 0
    files = sorted((tmp_path / "runs").glob("*.h5"))
    short = {f.name: read_trajectory(f)["timeseries"]["t"] for f in files}
    plan = cli.invoke(app, ["validate", str(path), "--set", "time.t_end=0.4"])
    assert plan.exit_code == 0 and plan.output.count("  extend  ") == 2, plan.output
    result = cli.invoke(app, ["sweep", str(path), "-q", "--workers", "1", "--set", "time.t_end=0.4"])
    assert result.exit_code == 0, result.output
    for f in files:
        t = read_trajectory(f)["timeseries"]["t"]
        assert t[-1] == pytest.approx(0.4)
        np.testing.assert_array_equal(t[: short[f.name].size], short[f.name])  # appended, not redone
    summary = cli.invoke(app, ["summarize", str(tmp_path / "runs")])
    assert summary.exit_code == 0, summary.output
    import xarray as xr

    with xr.open_dataset(tmp_path / "runs" / "summary.nc") as ds:
        assert set(ds["status"].values.ravel()) == {"completed"}
        assert float(ds["averaging_t_to"].max()) == pytest.approx(0.4)


def test_a_run_file_given_as_the_case_extends_that_run(tmp_path):
    """Finding 4: capsim run RUN.h5 --resume --t-end 0.4 read the run file as YAML."""
    from capsim.storage.store import read_trajectory

    case_path = tmp_path / "r.yaml"
    case_path.write_text(yaml.safe_dump(_case(tmp_path)))
    assert cli.invoke(app, ["run", str(case_path), "-q"]).exit_code == 0
    moved = tmp_path / "moved.h5"
    (tmp_path / "r.h5").rename(moved)  # the run file's own path wins over the output.path it stored
    result = cli.invoke(app, ["run", str(moved), "--resume", "--t-end", "0.4", "-q"])
    assert result.exit_code == 0, result.output
    assert read_trajectory(moved)["timeseries"]["t"][-1] == pytest.approx(0.4)
    assert not (tmp_path / "r.h5").exists()
    refused = cli.invoke(app, ["run", str(moved), "--t-end", "0.5", "-q"])
    assert refused.exit_code == 2 and "--resume" in refused.output


def test_sweep_quiet_names_each_unfinished_run_once(tmp_path):
    """Finding 20: sweep -q printed each run that did not complete twice."""
    base = _case(tmp_path, time={"t_end": 0.2, "max_wall_s": 1e-3})
    base.pop("name")
    base["output"] = {"checkpoint_every_steps": 3}
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump({"name": "w", "base": base, "sweep": {"flow.shear_rate_G": [0.1]},
                                    "output": {"dir": str(tmp_path / "runs")}}))
    result = cli.invoke(app, ["sweep", str(path), "-q", "--workers", "1"])
    assert result.exit_code == 1
    lines = [line for line in result.output.splitlines() if "interrupted: wall-time limit" in line]
    assert len(lines) == 1, result.output


# ---------------------------------------------------------------- Ctrl-C twice (finding 15)


@pytest.mark.parametrize("extend", [False, True])
def test_a_second_ctrl_c_while_the_run_closes_its_file_does_not_leave_it_running(tmp_path, monkeypatch, extend, ctrl_c):
    """Finding 15: two SIGINTs a few ms apart (during an extension) left files 'running' with no
    summary: the second raised KeyboardInterrupt while the run wrote its summary after the first.
    The window is held open: the second SIGINT is sent from inside the summary's write."""
    import h5py

    from capsim.config import apply_overrides
    from capsim.storage.store import TrajectoryWriter

    case = case_from_dict(_case(tmp_path, time={"t_end": 0.2}))
    if extend:
        assert run_case(case).status == "completed"
        case = apply_overrides(case, **{"time.t_end": 5.0})
    steps = []

    def first_ctrl_c(state):
        steps.append(state["step"])
        if len(steps) == 3:
            os.kill(os.getpid(), signal.SIGINT)

    write_summary = TrajectoryWriter.write_summary

    def second_ctrl_c(self, summary):
        os.kill(os.getpid(), signal.SIGINT)
        return write_summary(self, summary)

    monkeypatch.setattr(TrajectoryWriter, "write_summary", second_ctrl_c)
    result = run_case(case, progress=first_ctrl_c, resume=extend)
    assert result.status == "interrupted" and "SIGINT" in result.status_reason
    with h5py.File(case.output.path, "r") as f:
        assert f.attrs["status"] == "interrupted"
        assert "summary" in f
    monkeypatch.setattr(TrajectoryWriter, "write_summary", write_summary)
    assert run_case(apply_overrides(case, **{"time.t_end": 0.4}), resume=True).status == "completed"


# ---------------------------------------------------------------- resume messages that say what is so (finding 20)


def test_an_interrupted_run_resumes_to_another_t_end(tmp_path):
    """Finding 20: --resume --t-end on an interrupted run said 'belongs to another case: time.t_end'."""
    from capsim.storage.checkpoint import ResumeError
    from capsim.config import apply_overrides

    case = case_from_dict(_case(tmp_path, time={"t_end": 1.0, "max_wall_s": 1e-3}))
    stopped = run_case(case)
    assert stopped.status == "interrupted"
    later = apply_overrides(case, **{"time.t_end": 0.5, "time.max_wall_s": None})
    assert run_case(later, resume=True).status == "completed"
    # a t_end before where the run stopped is refused, saying so
    case2 = case_from_dict(_case(tmp_path, name="s", time={"t_end": 1.0, "max_wall_s": 1e-3}))
    stopped = run_case(case2)
    while stopped.t < 0.05:
        stopped = run_case(case2, resume=True)
    with pytest.raises(ResumeError, match="stopped at kt"):
        run_case(apply_overrides(case2, **{"time.t_end": stopped.t / 2}), resume=True)


def test_extending_a_run_that_stopped_on_its_own_rule_says_why_it_cannot(tmp_path):
    """Finding 20: extending a settled run said 'no checkpoint'."""
    from capsim.storage.checkpoint import ResumeError
    from capsim.config import apply_overrides

    case = case_from_dict(_case(tmp_path, time={"t_end": 0.2}))
    assert run_case(case).status == "completed"
    import h5py

    with h5py.File(case.output.path, "a") as f:  # as a run stopped by stop_when_settled leaves it
        del f["end_state"]
    with pytest.raises(ResumeError, match="stopping rule"):
        run_case(apply_overrides(case, **{"time.t_end": 0.4}), resume=True)
    with pytest.raises(ResumeError, match="no run file here"):
        run_case(apply_overrides(case, **{"output.path": str(tmp_path / "none.h5")}), resume=True)


# ---------------------------------------------------------------- error output (finding 10)


def test_a_zip_of_unequal_lists_is_refused_without_printing_the_campaign(tmp_path):
    """Finding 10: the one line began with the whole campaign dict ('= {'base': ...')."""
    path = tmp_path / "z.yaml"
    path.write_text(yaml.safe_dump({"name": "z", "base": {"mesh": {"level": 0}},
                                    "zip": {"flow.shear_rate_G": [0.1, 0.2], "flow.viscosity_ratio": [1.0]},
                                    "output": {"dir": str(tmp_path / "runs")}}))
    for command in (["sweep", str(path)], ["validate", str(path)]):
        result = cli.invoke(app, command)
        assert result.exit_code == 2
        lines = result.output.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("error: "), result.output
        assert "zip lists must have equal lengths" in lines[0] and "{" not in lines[0], lines[0]


def test_a_guard_reason_shows_the_digits_that_cross_the_limit():
    """Finding 20: 'largest principal stretch = 1 > 1.0001'."""
    from capsim.runs.stopping import guard_violation

    guards = case_from_dict({"name": "x", "guards": {"max_principal_stretch": 1.0001}}).guards
    row0 = {"volume": 1.0, "area": 1.0, "min_element_quality": 1.0, "max_principal_stretch": 1.0}
    reason = guard_violation({**row0, "max_principal_stretch": 1.00011}, row0, guards)
    value, limit = reason.split("= ")[1].split(" > ")
    assert float(value) > float(limit) == 1.0001, reason


def test_make_docs_refuses_a_site_that_is_a_link(tmp_path):
    """Finding 18: mkdocs build --clean (make docs) emptied the directory site/ linked to."""
    import shutil
    import subprocess
    import time

    if shutil.which("make") is None:
        pytest.skip("make is not installed")
    repo = Path(__file__).resolve().parents[2]
    (tmp_path / "pyproject.toml").write_text("")
    time.sleep(0.01)
    (tmp_path / ".venv").mkdir()
    for stamp in (".installed", ".docs-tools"):
        (tmp_path / ".venv" / stamp).write_text("")  # newer than pyproject.toml: nothing to install
    precious = tmp_path / "mine"
    precious.mkdir()
    (precious / "thesis.tex").write_text("keep me")
    (tmp_path / "site").symlink_to(precious)
    done = subprocess.run(["make", "-f", str(repo / "Makefile"), "docs"], cwd=tmp_path, capture_output=True, text=True)
    assert done.returncode != 0 and "symbolic link" in done.stderr
    assert (precious / "thesis.tex").read_text() == "keep me"


@pytest.mark.parametrize("shared", [True, False])
def test_the_error_prefix_is_the_same_whether_or_not_stderr_shares_a_pipe(tmp_path, shared):
    """Finding 10: the prefix was 'Error:' or 'error:' depending on whether stderr shared a pipe
    with stdout. A usage error and a case error, through a real process both ways."""
    import subprocess
    import sys

    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\nmesh: {level: 99}\n")
    for args in (["run", "--bogus", "x"], ["validate", str(bad)]):
        done = subprocess.run([sys.executable, "-m", "capsim.face.cli", *args], stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT if shared else subprocess.PIPE, text=True)
        text = (done.stdout if shared else done.stderr).strip()
        assert done.returncode == 2 and text.startswith("error: ") and "\n" not in text, text
