"""time.scheme: auto (issue 29): it picks from the measured spectral radius against the
accuracy-limited step, records what and why, and is the default."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from capsim.config import apply_overrides, case_from_dict
from capsim.runner import run_case
from capsim.solver import build_model
from capsim.timestepping import SCHEMES, build_integrator

# the cases of benchmarks/stepping.py
CASE_A = {"mesh": {"level": 3}, "flow": {"shear_rate_G": 0.1}}
CASE_G = {"mesh": {"level": 2}, "flow": {"shear_rate_G": 0.001}}
CASE_C = {"mesh": {"level": 3}, "flow": {"shear_rate_G": 0.0125}}
CASE_E = {"shape": {"kind": "oblate", "aspect_ratio": 0.5}, "mesh": {"level": 3},
          "membrane": {"bending_modulus": 1e-3}, "flow": {"shear_rate_G": 0.2, "viscosity_ratio": 10.0}}


def _chosen(spec: dict, **time):
    case = case_from_dict({"name": "x", **spec, "time": {"t_end": 2.0, **time}})
    model, X = build_model(case)

    def rhs(x):
        state = model.membrane(x)
        return model.velocity(x, state), state

    return build_integrator(case, rhs, X, model)


def test_auto_is_the_default():
    assert case_from_dict({"name": "x"}).time.scheme == "auto"
    assert "auto" in SCHEMES


def test_auto_picks_linearly_implicit_on_g_and_not_on_a_or_c():
    """Per layer application (benchmarks/time_schemes.md): (g) the linearly implicit scheme
    with the dense preconditioner, 1.8x fewer than rkc; (a) and (c) rkc, 3.8x and 3.4x fewer."""
    g = _chosen(CASE_G)
    assert g.name == "linearly_implicit" and g.stage_solver.preconditioner == "dense"
    assert "stiff" in g.choice and g.evaluations > 0  # the measurement is counted
    for spec in (CASE_A, CASE_C):
        assert _chosen(spec).name == "rkc"


def test_auto_picks_the_dense_linearly_implicit_scheme_on_e():
    """(e), λ = 10, a tumbling oblate: the linearly implicit scheme with the dense preconditioner,
    the best fixed choice there (benchmarks/time_schemes.md: 9516 layer applications against
    rkc's 16612 and rkf23's 19956 at equal accuracy)."""
    e = _chosen(CASE_E)
    assert e.name == "linearly_implicit" and e.stage_solver.preconditioner == "dense", e.choice


@pytest.mark.parametrize("rtol", [1e-2, 1e-5])
def test_auto_picks_between_rkc_and_linearly_implicit_alike_at_any_rtol(rtol):
    """Their cost ratio hardly moves with rtol (benchmarks/rtol_promise.md, (g): li/dense over rkc
    0.35 at rtol 1e-2, 0.31 at 1e-5), so neither does the choice: at rtol 3e-3 the stage count at
    rtol's own step sent (c) to li/dense, 1.26x the layer applications of rkc at equal accuracy."""
    assert _chosen(CASE_G, rtol=rtol).name == "linearly_implicit"
    assert _chosen(CASE_C, rtol=rtol).name == "rkc"


CASE_D = {"mesh": {"level": 3}, "flow": {"shear_rate_G": 0.1, "viscosity_ratio": 5.0}}


@pytest.mark.parametrize("rtol", [1e-2, 1e-4])
def test_auto_weighs_rkf23_by_its_stability_limit_too(rtol):
    """(d), λ = 5: rkf23 is pinned at its stability limit there (166 steps at rtol 1e-2 and
    1e-3 alike, benchmarks/time_schemes.md), so rkc is cheaper at any rtol (at 1e-4: 3108 layer
    applications against 3981); rkc's stage count alone (1.8 at rtol 1e-4) sent it to rkf23."""
    d = _chosen(CASE_D, rtol=rtol)
    assert d.name == "rkc", d.choice
    assert "evaluations per unit time against rkf23's" in d.choice


def test_auto_respects_what_the_linearly_implicit_scheme_cannot_run():
    stiff = {"mesh": {"level": 2}, "flow": {"shear_rate_G": 0.0002},  # stiffer than (g), contour traction
             "membrane": {"traction": "contour"}}
    ig = _chosen(stiff)
    assert ig.name == "rkc" and "cannot run" in ig.choice
    assert _chosen({**CASE_G, "flow": {"shear_rate_G": 0.001, "viscosity_ratio": 10.0}}).name == "linearly_implicit"


def test_auto_keeps_the_users_preconditioner():
    ig = _chosen(CASE_G, preconditioner="local")
    assert ig.name == "linearly_implicit" and ig.stage_solver.preconditioner == "local"


def test_an_auto_run_records_its_choice_and_resumes_on_the_same_steps(tmp_path):
    case = case_from_dict({"name": "auto", **CASE_G, "mesh": {"level": 1},
                           "time": {"t_end": 0.3, "max_wall_s": 1e-3},
                           "output": {"path": str(tmp_path / "a.h5"), "checkpoint_every_steps": 2}})
    first = run_case(case)
    assert first["status"] == "interrupted"
    done = run_case(apply_overrides(case, **{"time.max_wall_s": None}), resume=True)
    whole = run_case(apply_overrides(case, **{"time.max_wall_s": None, "output.path": str(tmp_path / "b.h5")}))
    assert done["status"] == whole["status"] == "completed"
    assert done["scheme"] == whole["scheme"] != "auto"
    assert done["steps"] == whole["steps"]
    assert done["D_xy"] == pytest.approx(whole["D_xy"], rel=1e-10, abs=1e-12)
    with h5py.File(tmp_path / "b.h5", "r") as f:
        assert f.attrs["time_scheme"] == "auto"
        assert f.attrs["time_scheme_used"] == whole["scheme"]
        assert "ρ" in str(f.attrs["time_scheme_choice"])


def test_an_auto_run_is_the_run_of_the_scheme_it_picks_to_the_bit(tmp_path):
    """The measurement undoes its warm starts: same steps, same numbers (only the counted cost differs)."""
    from capsim.store import read_trajectory

    base = {"name": "bit", "mesh": {"level": 1}, "flow": {"shear_rate_G": 0.1}, "time": {"t_end": 0.5}}
    auto = run_case(case_from_dict({**base, "output": {"path": str(tmp_path / "auto.h5")}}))
    named = run_case(case_from_dict({**base, "time": {"t_end": 0.5, "scheme": auto["scheme"]},
                                     "output": {"path": str(tmp_path / "named.h5")}}))
    a, b = (read_trajectory(r["path"])["timeseries"] for r in (auto, named))
    assert len(a["t"]) == len(b["t"])
    for name in ("t", "D_xy", "theta"):  # θ is NaN at t = 0 (a sphere has no long axis): NaN equals NaN here
        assert np.array_equal(a[name], b[name], equal_nan=True), name
    assert auto["velocity_evaluations"] > named["velocity_evaluations"]  # the measurement is counted
