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
