"""A velocity solve that misses its tolerance (λ ≠ 1: GMRES) is a state of the run, not a crash (issue 55:
the red cell at 12.5 Pa with time.scheme linearly_implicit ended in a SolverDivergence traceback after
12000 GMRES iterations). At a trial state the step is rejected and retried smaller, the run's status
says how often; at the first state the run ends unstable, its file written and readable."""
from __future__ import annotations

import capsim
from capsim.numerics.krylov import SolverDivergence
from capsim.solve.solver import CapsuleModel

BASE = {"name": "div", "flow": {"G": 0.1, "viscosity_ratio": 5.0}, "mesh": {"level": 1},
        "time": {"t_end": 0.3, "scheme": "rkc"}, "output": {"snapshot_every": 0.3}}


def _failing(monkeypatch, when):
    """CapsuleModel.velocity raising SolverDivergence on the calls `when` (a set of call numbers, or all)."""
    velocity, calls = CapsuleModel.velocity, {"n": 0}

    def flaky(self, x, state=None):
        calls["n"] += 1
        if when is None or calls["n"] in when:
            raise SolverDivergence("velocity solve did not converge: residual 1e-2 > tol 1e-6 (test)")
        return velocity(self, x, state)

    monkeypatch.setattr(CapsuleModel, "velocity", flaky)


def test_a_trial_states_divergence_rejects_the_step(tmp_path, monkeypatch):
    plain = capsim.run(BASE, output=tmp_path / "plain.h5")
    _failing(monkeypatch, {6, 7})  # evaluations inside the first steps' trials (1: the start, 2-5: the probe)
    result = capsim.run(BASE, output=tmp_path / "run.h5")
    assert result.status == "completed", result.status_reason
    assert "trial steps rejected: their velocity solve missed its tolerance" in result.status_reason
    assert result.rejected_steps >= 1
    # the retried steps reach the same shape at t_end, within the run's tolerance (its steps differ)
    assert abs(result["final_D_xy"] - plain["final_D_xy"]) < 5e-3 * plain["final_D_xy"]


def test_a_divergence_at_the_first_state_ends_the_run_unstable(tmp_path, monkeypatch):
    _failing(monkeypatch, None)
    result = capsim.run(BASE, output=tmp_path / "run.h5")
    assert result.status == "unstable"
    assert result.status_reason.startswith("guard solver: at kt = 0 velocity solve did not converge")
    assert capsim.open_run(result.path).attrs["status"] == "unstable"  # the file is there and readable
    auto = capsim.run({**BASE, "time": {"t_end": 0.3}}, output=tmp_path / "auto.h5")  # the probe at set-up
    assert auto.status == "unstable" and "during set-up" in auto.status_reason


def test_the_solve_tolerance_follows_the_step_error_budget(tmp_path):
    """A pre-stressed red cell at G 0.0095 (stress-free oblate 0.9, λ 0.42, a viscous membrane): its relaxation
    velocity (|u| ~ 40) times solver.tol 1e-6 put a floor under the error per unit step above 1, and the steps
    collapsed at kt = 0 (guard dt_min). The solve's tolerance now follows the step's error budget."""
    case = {"name": "prestressed", "shape": {"kind": "biconcave"},
            "membrane": {"law": "skalak", "skalak_c": 10.0, "reference_shape": {"kind": "oblate", "aspect_ratio": 0.9},
                         "viscosity": {"shear": 0.92}, "bending_modulus": 2.7e-3},
            "flow": {"G": 0.0095, "viscosity_ratio": 0.418}, "mesh": {"level": 1},
            "time": {"t_end": 0.05, "rtol": 1e-4, "scheme": "rkc"}, "output": {"snapshot_every": 0.05}}
    result = capsim.run(case, output=tmp_path / "run.h5")
    assert result.status == "completed", result.status_reason
    assert result.steps > 5
