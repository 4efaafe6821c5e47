"""Time integrators: every registered scheme against an exact solution; RKC's
order, stability interval and stage count; a capsule run against a tight
RKF2(3) reference; interrupted runs of the schemes with state (rkc, linearly_implicit) resumed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from capsim.config import apply_overrides
from capsim.runs.runner import run_case
from capsim.storage.store import read_trajectory
from capsim.solve.timestepping import (
    SCHEMES, RungeKuttaChebyshev, attempt_step, make_integrator, rkc_coefficients, rkc_stages_for, rkc_step,
    RKF23,
)

from stiff_problems import RHO, RKF23_LIMIT, Y0, capsule_case as _capsule, exact, linear
from interrupts import InterruptAfter as _InterruptAfter


def _rkc_fixed(h: float, t_end: float) -> np.ndarray:
    coef = rkc_coefficients(rkc_stages_for(h * RHO, 1000))
    y = Y0.copy()
    for _ in range(int(round(t_end / h))):
        y = rkc_step(linear, y, linear(y), h, coef)
    return y


def test_rkc_coefficients_integrate_y_prime_equals_y_to_second_order():
    """The stability polynomial R(z) = 1 + z + z²/2 + O(z³) (second order) for any s."""
    for s in (2, 3, 7, 20):
        coef = rkc_coefficients(s)
        for z in (1e-2, 2e-2):
            r = rkc_step(lambda y: y, np.ones(1), np.ones(1), z, coef)[0]
            assert abs(r - (1 + z + z * z / 2)) < 0.2 * z**3, (s, z)


def test_rkc_stability_interval_grows_like_s_squared():
    for s in (2, 5, 10, 40):
        beta = rkc_coefficients(s).beta
        assert 0.6 * s * s <= beta + 1.0 <= 0.7 * s * s + 2.0, (s, beta)
        # |R(−β)| ≤ 1 at the end of the interval, > 1 just beyond (damping ε = 2/13: |R| ≤ 1 − ε/3 inside)
        coef = rkc_coefficients(s)
        inside = rkc_step(lambda y: -y, np.ones(1), -np.ones(1), 0.999 * beta, coef)[0]
        beyond = rkc_step(lambda y: -y, np.ones(1), -np.ones(1), 1.1 * beta, coef)[0]
        assert abs(inside) <= 1.0 and abs(beyond) > 1.0, (s, inside, beyond)


def test_rkc_stage_count_is_the_fewest_that_cover_h_rho():
    for h_rho in (0.5, 10.0, 250.0, 3000.0):
        s = rkc_stages_for(h_rho, 1000)
        assert rkc_coefficients(s).beta >= h_rho
        assert s == 2 or rkc_coefficients(s - 1).beta < h_rho
    assert rkc_stages_for(1e6, 50) == 50


def test_rkc_converges_at_second_order_on_a_stiff_linear_problem():
    t_end = 1.0
    errors = [float(np.abs(_rkc_fixed(h, t_end) - exact(t_end)).max()) for h in (0.04, 0.02, 0.01)]
    orders = [math.log2(errors[i] / errors[i + 1]) for i in range(2)]
    assert all(1.8 <= p <= 2.3 for p in orders), (errors, orders)


def test_rkc_is_stable_at_100_times_the_rkf23_limit():
    h = 100 * RKF23_LIMIT
    y = _rkc_fixed(h, 2.0)
    assert np.abs(y - exact(2.0)).max() < 1e-3
    # the same step blows RKF2(3) up: the assertion above is not trivially met
    z = Y0.copy()
    for _ in range(20):
        z = attempt_step(linear, z, h, RKF23, 1.0).y
    assert np.abs(z).max() > 1e6


@pytest.mark.parametrize("name", sorted(n for n, cls in SCHEMES.items() if cls.stepped))  # auto resolves to one
def test_every_scheme_follows_the_exact_solution(name):
    integ = make_integrator(name, lambda y: (linear(y), None), Y0, rtol=1e-5, dt_initial=1e-5,
                            dt_min=1e-12, dt_max=1.0)
    integ.start()
    t_end = 3.0
    while integ.t < t_end - 1e-12:
        trial = integ.attempt(t_end)
        assert trial.finite
    assert abs(integ.t - t_end) < 1e-12
    assert np.abs(integ.y - exact(t_end)).max() < 1e-3


def test_rkc_spends_fewer_evaluations_than_rkf23_on_the_stiff_problem():
    counts = {}
    for name in ("rkf23", "rkc"):
        integ = make_integrator(name, lambda y: (linear(y), None), Y0, rtol=1e-4, dt_initial=1e-5,
                                dt_min=1e-12, dt_max=1.0)
        integ.start()
        while integ.t < 3.0 - 1e-12:
            integ.attempt(3.0)
        counts[name] = integ.evaluations
        assert np.abs(integ.y - exact(3.0)).max() < 1e-2
    assert counts["rkf23"] > 10 * counts["rkc"], counts


def _max_error_over_run(name: str, rtol: float, t_end: float = 3.0) -> float:
    """max over accepted steps of |y − y_exact|∞ on the stiff linear problem."""
    integ = make_integrator(name, lambda y: (linear(y), None), Y0, rtol=rtol, dt_initial=1e-5,
                            dt_min=1e-12, dt_max=1.0)
    integ.start()
    worst = 0.0
    while integ.t < t_end - 1e-12:
        if integ.attempt(t_end).accepted:
            worst = max(worst, float(np.abs(integ.y - exact(integ.t)).max()))
    return worst


RTOLS = (1e-2, 1e-3, 1e-4, 1e-5)


def test_rkc_error_is_proportional_to_rtol_per_unit_step(monkeypatch):
    """docs/time_stepping.md, "One promise for time.rtol": rkc's estimate is of the solution it
    advances, so per step its global error grows like rtol^(2/3) (measured here: error / rtol
    0.14 at 1e-2, 4.1 at 1e-5); per unit step like rtol (0.06 to 0.16)."""
    ratios = [_max_error_over_run("rkc", rtol) / rtol for rtol in RTOLS]
    assert max(ratios) <= 0.5 and max(ratios) / min(ratios) <= 4.0, ratios
    monkeypatch.setattr(RungeKuttaChebyshev, "UNIT_STEP", None)  # the per-step control it replaced
    per_step = [_max_error_over_run("rkc", rtol) / rtol for rtol in RTOLS]
    assert per_step[-1] / per_step[0] >= 20.0 and per_step[-1] > 2.0, per_step


def test_one_rtol_bounds_every_schemes_error_alike():
    """The same rtol, the same bound (c = 1.5 on this problem; rkf23 is the largest, 1.3, at its
    stability limit where its steps are far shorter than accuracy asks)."""
    for name in ("rkf23", "rkc", "linearly_implicit"):
        for rtol in RTOLS:
            assert _max_error_over_run(name, rtol, t_end=1.0) <= 1.5 * rtol, (name, rtol)


def test_spectral_radius_estimate_bounds_the_largest_eigenvalue():
    integ = make_integrator("rkc", lambda y: (linear(y), None), Y0, rtol=1e-4, dt_initial=1e-3,
                            dt_min=1e-12, dt_max=1.0)
    integ.start()
    rho = integ.spectral_radius()
    assert RHO <= rho <= 1.3 * RHO
    assert integ.rho_evaluations <= integ.RHO_MAX_ITER


def test_rkc_capsule_matches_a_tight_rkf23_reference(tmp_path):
    """Sphere, level 2, G = 0.05, kt 2: RKC at rtol 1e-3 against RKF2(3) at rtol 1e-6,
    max over t of |ΔD_xy| ≤ 1e-4, with fewer velocity evaluations."""
    ref = run_case(_capsule(tmp_path, "ref", **{"time.rtol": 1e-6}))
    rkc = run_case(_capsule(tmp_path, "rkc", **{"time.rtol": 1e-3, "time.scheme": "rkc"}))
    assert ref["status"] == rkc["status"] == "completed"
    want, got = read_trajectory(ref["path"])["timeseries"], read_trajectory(rkc["path"])["timeseries"]
    d_ref = np.interp(got["t"], want["t"], want["D_xy"])
    assert np.abs(got["D_xy"] - d_ref).max() <= 1e-4
    assert rkc["velocity_evaluations"] < ref["velocity_evaluations"] / 2
    assert got["velocity_evaluations"][-1] == rkc["velocity_evaluations"]
    assert np.all(got["stages"][1:] >= 2)



RESUMED = {
    # the spectral radius, its vector and age, the stage count and the controller's memory
    "rkc": {"time.rho_refresh_steps": 3},
    # the Hessian's age and where it was built (rebuilt there on resume), the factor's γh
    "linearly_implicit": {"time.jacobian_refresh_steps": 3},
    "linearly_implicit/dense": {"time.scheme": "linearly_implicit", "time.preconditioner": "dense",
                                "time.jacobian_refresh_steps": 3},
}


@pytest.mark.parametrize("lam", [1.0, 5.0])
@pytest.mark.parametrize("scheme", sorted(RESUMED))
def test_resumed_run_repeats_the_uninterrupted_one(tmp_path, scheme, lam):
    """The scheme's state is in the checkpoint: the step sequence is the same."""
    t_end = 1.5 if lam == 1.0 else 0.6  # every λ = 5 evaluation is a GMRES solve
    settings = {"time.scheme": scheme, **RESUMED[scheme]}
    case = _capsule(tmp_path, f"{scheme.replace('/', '-')}{lam:g}", **{"mesh.level": 1, "time.t_end": t_end,
                                                                       "flow.viscosity_ratio": lam, **settings})
    assert run_case(case, progress=_InterruptAfter(4))["status"] == "interrupted"
    resumed = run_case(case, resume=True)
    reference = run_case(apply_overrides(case, **{"output.path": str(tmp_path / "reference.h5")}))
    assert resumed["status"] == reference["status"] == "completed"
    assert resumed["steps"] == reference["steps"]
    assert resumed["velocity_evaluations"] == reference["velocity_evaluations"]
    got, want = read_trajectory(case.output.path), read_trajectory(reference["path"])
    for key in ("t", "D_xy", "theta", "stages", "velocity_evaluations", "layer_applications", "linear_iterations"):
        np.testing.assert_allclose(got["timeseries"][key], want["timeseries"][key], rtol=0, atol=1e-10, err_msg=key)


def test_rkc_at_its_stage_bound_shortens_steps_and_says_so(tmp_path):
    case = _capsule(tmp_path, "bound", **{"time.scheme": "rkc", "mesh.level": 1, "time.t_end": 0.5,
                                          "time.max_stages": 2, "time.dt_initial": 0.1})
    result = run_case(case)
    assert result["status"] == "completed"
    assert "steps shortened to the stability limit of time.max_stages = 2" in result["status_reason"]
    assert read_trajectory(result["path"])["timeseries"]["stages"].max() == 2
