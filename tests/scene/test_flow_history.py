"""Rates that change in time (issue 41, item 2): the flow.history registry of capsim.scene.flows.
Known answer (docs/known_answers.md, "Flows beyond simple shear"): small-amplitude oscillating
shear against the first-order theory's response (capsim.scene.small_deformation), its amplitude and
phase lag at ωτ = 0.3, 1, 3; a step in the rate; the kinds' fields refused in one line."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from capsim.config import ConfigError, case_from_dict
from capsim.runs.runner import run_case
from capsim.scene.small_deformation import LinearCapsule

G = 0.01


def _fit(t: np.ndarray, s: np.ndarray, omega: float) -> tuple[float, float]:
    """(amplitude, phase lag) of s ≈ R sin(ωt − φ) + c by least squares."""
    A = np.stack([np.sin(omega * t), np.cos(omega * t), np.ones_like(t)], axis=1)
    a, b, _ = np.linalg.lstsq(A, s, rcond=None)[0]
    return float(np.hypot(a, b)), float(np.arctan2(-b, a))


def _theory(omega: float, t_end: float) -> tuple[float, float]:
    """The first-order theory's response to the rate sin(ωt): d x/dt = J_rest x + a(t) (J_flow x + f)
    (LinearCapsule.jacobian: the rotation by the spin enters with the rate too), from rest; the
    deformation's xy part is the S1 coefficient a1 (= D sin 2θ)."""
    cap = LinearCapsule.from_G(G)
    J_rest, _ = cap.jacobian(shear=False)
    J_shear, f = cap.jacobian(shear=True)
    J_flow = J_shear - J_rest

    def rhs(t, x):
        return J_rest @ x + np.sin(omega * t) * (J_flow @ x + f)

    t = np.linspace(t_end - 2 * 2 * np.pi / omega, t_end, 400)
    sol = solve_ivp(rhs, (0.0, t_end), np.zeros(4), t_eval=t, rtol=1e-10, atol=1e-12, method="LSODA")
    return _fit(t, sol.y[0], omega)


def _run(tmp_path, name: str, t_end: float, **history) -> dict:
    flow = {"shear_rate_G": G}
    if history:
        flow["history"] = history
    case = case_from_dict({"name": name, "flow": flow, "mesh": {"level": 1}, "time": {"t_end": t_end},
                           "output": {"path": str(tmp_path / f"{name}.h5")}})
    assert run_case(case).status == "completed"
    with h5py.File(case.output.path, "r") as f:
        return {k: f[f"timeseries/{k}"][()] for k in ("t", "D_xy", "theta")}


@pytest.mark.parametrize("omega_tau", [0.3, 1.0, 3.0])
def test_small_amplitude_oscillating_shear_follows_the_first_order_response(tmp_path, omega_tau):
    """Amplitude (relative to the steady deformation of the same mesh, which carries the
    level's own ~7 % error at level 1) and phase lag of D sin 2θ within 5 % of the theory's."""
    tau = LinearCapsule.from_G(G).relaxation_times()[0]
    omega = omega_tau / tau
    period = 2 * np.pi / omega
    t_end = 5 * tau + 2 * period
    run = _run(tmp_path, f"osc{omega_tau}", t_end, kind="oscillating", omega=omega)
    t, s = run["t"], run["D_xy"] * np.sin(2 * run["theta"])
    last = t >= t_end - 2 * period
    amplitude, lag = _fit(t[last], s[last], omega)
    steady = _run(tmp_path, "steady", 6 * tau)["D_xy"][-1]
    theory_amplitude, theory_lag = _theory(omega, t_end)
    theory_steady = LinearCapsule.from_G(G).steady_shear()[0]
    assert amplitude / steady == pytest.approx(theory_amplitude / theory_steady, rel=0.05)
    assert lag == pytest.approx(theory_lag, rel=0.05, abs=0.02)


def test_a_step_in_the_rate_lands_on_its_time_and_the_shape_follows(tmp_path):
    run = _run(tmp_path, "step", 1.5, kind="step", step_time=0.75, step_factor=2.0)
    t, D = run["t"], run["D_xy"]
    assert np.any(np.isclose(t, 0.75, rtol=0, atol=1e-12))  # a step lands on it
    before, after = D[np.searchsorted(t, 0.74)], D[-1]
    assert after / before == pytest.approx(2.0, rel=0.05)  # linear at this G


def test_the_history_kinds_take_their_fields_and_refuse_the_others_in_one_line():
    def case(**history):
        return case_from_dict({"name": "h", "flow": {"history": history}})

    with pytest.raises(ConfigError, match="omega = None: is required with kind: oscillating"):
        case(kind="oscillating")
    with pytest.raises(ConfigError, match="applies only to kind: oscillating"):
        case(kind="step", step_time=1.0, step_factor=2.0, omega=1.0)
    with pytest.raises(ConfigError, match="strictly increasing"):
        case(kind="table", table=[[0, 1], [2, 1], [1, 0]])
    with pytest.raises(ConfigError, match="omega"):
        case(kind="oscillating", omega=-1.0)
    with pytest.raises(ConfigError, match="cannot run flow.history kind oscillating"):
        case_from_dict({"name": "h", "flow": {"history": {"kind": "oscillating", "omega": 1.0}},
                        "time": {"scheme": "linearly_implicit"}})
    assert case(kind="table", table=[[0, 0], [1, 1]]).flow.rate_factor(0.5) == 0.5


def test_the_dissipation_ratio_follows_the_rate_of_the_moment(tmp_path):
    """dissipation_ratio divides by the rate of strain of the moment, the rate's factor a(t)
    included: a stiff capsule in oscillating shear stays at the rigid sphere's 1 while a(t) is
    0.48 (the far field's gradient alone gave a(t) itself)."""
    case = case_from_dict({"name": "d", "flow": {"shear_rate_G": 0.0005,
                                                 "history": {"kind": "oscillating", "omega": 2.0}},
                           "mesh": {"level": 1}, "time": {"t_end": 0.25}, "output": {"path": str(tmp_path / "d.h5")}})
    assert run_case(case).status == "completed"
    with h5py.File(case.output.path, "r") as f:
        ratio = f["timeseries/dissipation_ratio"][-1]
    assert np.sin(2.0 * 0.25) < 0.5
    assert ratio == pytest.approx(1.0, abs=0.03)
