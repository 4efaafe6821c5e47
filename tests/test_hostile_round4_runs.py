"""Issue 38 (round four), the findings about runs: the automatic scheme at extreme stiffness,
a stop during its start-up probe, wall-clock stops that resume, extending a campaign, the
output check under the lock, Ctrl-C twice."""

from __future__ import annotations

import math

import numpy as np
import pytest

from capsim.timestepping import Automatic, EmbeddedRungeKutta, RungeKuttaChebyshev, make_integrator


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

    class Model:
        def state(self):
            return {}

        def restore(self, state):
            pass

    case = case_from_dict({"name": "x", "mesh": {"level": 0}})
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

from capsim.cli import app
from capsim.config import case_from_dict
from capsim.runner import run_case

cli = CliRunner()


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
    from capsim.files import OutputError

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
    from capsim.store import read_case

    assert read_case(written).name == "second"  # the other run's file is intact
