"""Ask for an accuracy, get the cheapest run (issue 44): time.rtol auto and the accuracy target
(capsim.solve.accuracy, the error model of benchmarks/error_model.py)."""

from __future__ import annotations

import json
import subprocess
import sys

import h5py
import pytest

from capsim.solve import accuracy
from capsim.config import ConfigError, apply_overrides, case_from_dict
from capsim.runs.runner import run_case


def test_rtol_auto_keeps_the_time_error_below_a_tenth_of_the_mesh_error():
    """The rule itself, on the model: at every level the chosen rtol's predicted time error is at
    most a tenth of the mesh error of every quantity, and the next looser rtol of the ladder is
    not (unless the loosest already is); finer meshes get tighter tolerances."""
    entry, _ = accuracy.entry()
    chosen = []
    for level in accuracy.levels():
        rtol, why = accuracy.auto_rtol(level)
        chosen.append(rtol)
        assert f"level-{level}" in why
        for q in accuracy.model()["quantities"]:
            assert accuracy.time_error(entry, q, rtol) <= 0.1 * accuracy.mesh_error(entry, q, level) or \
                rtol == accuracy.RTOL_LADDER[-1]
        looser = [r for r in accuracy.RTOL_LADDER if r > rtol]
        if looser:
            assert any(accuracy.time_error(entry, q, looser[-1]) > 0.1 * accuracy.mesh_error(entry, q, level)
                       for q in accuracy.model()["quantities"])
    assert chosen == sorted(chosen, reverse=True)


def test_a_case_without_rtol_takes_auto_and_says_why_and_a_number_wins():
    case = case_from_dict({"name": "a", "mesh": {"level": 3}})
    assert case.time.rtol == accuracy.auto_rtol(3)[0] == 5e-4
    assert case.time.rtol_choice.startswith("auto: rtol 0.0005")
    given = case_from_dict({"name": "a", "mesh": {"level": 3}, "time": {"rtol": 1e-4}})
    assert given.time.rtol == 1e-4 and given.time.rtol_choice is None
    # λ ≠ 1 takes its own row of the model (a tenfold time error: a tighter tolerance)
    viscous = case_from_dict({"name": "a", "mesh": {"level": 3}, "flow": {"viscosity_ratio": 5.0}})
    assert viscous.time.rtol < case.time.rtol
    # the resolved case reads back as it was; another level chooses again, a campaign's identity does not move
    again = case_from_dict(case.model_dump(mode="json"))
    assert (again.time.rtol, again.time.rtol_choice) == (case.time.rtol, case.time.rtol_choice)
    coarser = apply_overrides(again, **{"mesh.level": 2})
    assert coarser.time.rtol == accuracy.auto_rtol(2)[0] > case.time.rtol
    assert "rtol" not in case.model_dump(exclude_unset=True).get("time", {})


def test_rtol_auto_on_the_demo_case_is_cheaper_and_moves_nothing_the_mesh_resolves(tmp_path):
    """The demo (configs/sphere.yaml, level 3, kt 10) at rtol auto against 1e-4: at least 1.5× fewer
    velocity evaluations (measured 1045 against 1609), D_xy and θ within a tenth of the level-3 mesh
    error of the model (measured: 5e-6 and 6e-6 rad)."""
    runs = {}
    for name, rtol in (("auto", "auto"), ("tight", 1e-4)):
        d = {"name": name, "flow": {"shear_rate_G": 0.1}, "mesh": {"level": 3}, "time": {"t_end": 10.0, "rtol": rtol},
             "output": {"path": str(tmp_path / f"{name}.h5")}}
        runs[name] = run_case(case_from_dict(d))
    auto, tight = runs["auto"], runs["tight"]
    assert auto.rtol == 5e-4 and auto.rtol_choice.startswith("auto")
    assert tight.velocity_evaluations >= 1.5 * auto.velocity_evaluations
    entry, _ = accuracy.entry()
    D = tight.summary["D_xy"]
    assert abs(auto.summary["D_xy"] - D) < 0.1 * accuracy.mesh_error(entry, "D_xy", 3) * D
    assert abs(auto.summary["theta"] - tight.summary["theta"]) < 0.1 * accuracy.mesh_error(entry, "theta", 3)
    with h5py.File(tmp_path / "auto.h5", "r") as f:
        assert f.attrs["time_rtol"] == 5e-4 and f.attrs["time_rtol_choice"].startswith("auto")


def test_an_accuracy_target_picks_the_cheapest_level_and_rtol_that_meet_it():
    case = case_from_dict({"name": "a", "time": {"t_end": 10.0}, "accuracy": {"quantity": "D_xy", "target": 1e-2}})
    entry, _ = accuracy.entry(case.error_model_features())
    level, rtol, factor = case.mesh.level, case.time.rtol, accuracy.safety("D_xy")
    predicted = factor * (accuracy.mesh_error(entry, "D_xy", level) + accuracy.time_error(entry, "D_xy", rtol))
    assert factor >= 1.0 and predicted <= 1e-2
    cost = accuracy.predicted_cost(entry, level, rtol, 10.0)
    for other in accuracy.levels():  # nothing cheaper meets it
        for r in accuracy.RTOL_LADDER:
            if factor * (accuracy.mesh_error(entry, "D_xy", other) + accuracy.time_error(entry, "D_xy", r)) <= 1e-2:
                assert accuracy.predicted_cost(entry, other, r, 10.0) >= cost
    assert "predicted error" in case.accuracy.choice and case.time.rtol_choice == case.accuracy.choice
    finer = case_from_dict({"name": "a", "time": {"t_end": 10.0}, "accuracy": {"quantity": "D_xy", "target": 1e-3}})
    assert finer.mesh.level > level or finer.time.rtol < rtol


def test_a_case_takes_its_nearest_training_cases_and_a_shape_none_has_takes_the_envelope():
    """nearest(): a training case's own features give that case alone (distance 0, nothing within
    the tie); a G between two training cases' gives the larger error of both; a rest shape no
    training case has gives the envelope of all, and says so."""
    cases = accuracy.model()["cases"]
    for c in cases[:5]:
        entry, label = accuracy.nearest(c["features"])
        if label == c["label"]:
            assert entry["mesh"] == accuracy.merge([c])["mesh"]
    first = cases[0]["features"]
    assert accuracy.distance(first, first) == 0.0
    assert accuracy.distance(first, {**first, "shape": "other"}) >= accuracy.DISTANCE["shape"]
    spheres = [c for c in cases if c["features"]["shape"] == "sphere"]
    entry, label = accuracy.nearest({**first, "shape": "prolate"}, spheres)
    assert label.startswith("the envelope") and entry["mesh"] == accuracy.merge(spheres)["mesh"]


def test_an_uncertain_prediction_says_so_and_names_the_check():
    """A case farther than FAR from every training case (bending at G 0.0005: the training's bending
    cases are at G 0.1, its smallest G 0.005 has no bending) is outside the model's range: a target
    says so, and rtol auto falls back to OUTSIDE_RTOL; training cases that disagree SPREAD-fold make
    the prediction uncertain; both say which check to run. A case amid agreeing training cases says
    nothing."""
    fields = {"name": "a", "flow": {"shear_rate_G": 0.0005}, "membrane": {"bending_modulus": 1e-3}}
    far = case_from_dict({**fields, "accuracy": {"quantity": "theta", "target": 0.5, "method": "predict"}})
    assert "outside the error model's range" in far.accuracy.choice and "accuracy.method measure" in far.accuracy.choice
    # under method auto (the default) such a case is run as predicted at level 1 or 2 (said so), and
    # measured where the prediction is finer (MEASURE_ABOVE_LEVEL), said why
    assert case_from_dict({**fields, "accuracy": {"quantity": "theta", "target": 0.5}}).accuracy.method == "predict"
    measured = case_from_dict({**fields, "accuracy": {"quantity": "theta", "target": 0.05}})
    assert measured.accuracy.method == "measure" and "outside the error model's range" in measured.accuracy.choice
    assert "it predicts level 3" in measured.accuracy.choice
    auto = case_from_dict({**fields, "mesh": {"level": 2}})
    assert auto.time.rtol <= accuracy.OUTSIDE_RTOL and "outside the training's range" in auto.time.rtol_choice
    near = case_from_dict({"name": "a", "flow": {"shear_rate_G": 0.1}, "accuracy": {"quantity": "D_xy", "target": 2e-2}})
    assert "check it" not in near.accuracy.choice
    # an uncertain prediction of a fine level: method predict refuses it in one line, naming the method
    # that measures the case; auto measures it (an oblate 0.7 between oblate 0.5 training cases that
    # converge (G 0.08) and some that do not (G 0.025))
    oblate = {"name": "a", "shape": {"kind": "oblate", "aspect_ratio": 0.7}, "membrane": {"law": "neo_hookean"},
              "flow": {"shear_rate_G": 0.05, "viscosity_ratio": 3.0}}
    with pytest.raises(ConfigError) as err:
        case_from_dict({**oblate, "accuracy": {"quantity": "D_xy", "target": 2e-2, "method": "predict"}})
    assert "\n" not in str(err.value) and "accuracy.method measure" in str(err.value) and "disagree" in str(err.value)
    auto = case_from_dict({**oblate, "accuracy": {"quantity": "D_xy", "target": 2e-2}})
    assert auto.accuracy.method == "measure" and auto.mesh.level == 1 and "disagree" in auto.accuracy.choice
    assert auto.time.rtol == accuracy.ladder_rtol("D_xy", 2e-2, auto.error_model_features())
    a, b = (json.loads(json.dumps(c)) for c in accuracy.model()["cases"][:2])
    b["mesh"]["D_xy"]["2"] = 11 * a["mesh"]["D_xy"]["2"]
    entry = {**accuracy.merge([a, b]), "members": [a, b]}
    assert "disagree 11-fold at level 2" in accuracy.uncertainty(entry, "D_xy", 2)
    b["mesh"]["D_xy"]["2"] = 9 * a["mesh"]["D_xy"]["2"]
    assert accuracy.uncertainty(entry, "D_xy", 2) == ""


def test_the_safety_factor_is_the_quantile_of_the_left_out_cases():
    """The model file's safety factors are what the code's nearest() gives now: each training case
    predicted from the others, the SAFETY_QUANTILE of actual / predicted mesh error at levels 1-3
    (at least 1). Changing DISTANCE or TIE without refitting (make bench-error-model) fails here."""
    import numpy as np

    cases = accuracy.model()["cases"]
    for q in accuracy.model()["quantities"]:
        ratios = []
        for k, c in enumerate(cases):
            predicted, _ = accuracy.nearest(c["features"], cases[:k] + cases[k + 1:])
            ratios += [c["mesh"][q][lv] / predicted["mesh"][q][lv] for lv in ("1", "2", "3")]
        assert accuracy.safety(q) == pytest.approx(max(1.0, float(np.quantile(ratios, accuracy.SAFETY_QUANTILE))),
                                                   rel=1e-12)


@pytest.mark.parametrize("fields, field", [
    ({"accuracy": {"quantity": "theta", "target": 1e-8}}, "accuracy.target"),      # finer than level 6
    ({"accuracy": {"quantity": "volume", "target": 1e-3}}, "accuracy.quantity"),   # no value in the model
    ({"accuracy": {"quantity": "D_xy", "target": 1e-2}, "mesh": {"level": 2}}, "accuracy"),  # both given
])
def test_an_impossible_target_is_refused_in_one_line(fields, field):
    with pytest.raises(ConfigError) as err:
        case_from_dict({"name": "a", **fields})
    assert "\n" not in str(err.value) and field in str(err.value)


def test_verify_says_whether_the_target_was_met(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text(f"name: c\nflow: {{shear_rate_G: 0.1}}\ntime: {{t_end: 2}}\noutput: {{path: {tmp_path / 'c.h5'}}}\n")
    out = subprocess.run([sys.executable, "-m", "capsim.face.cli", "run", str(path), "--accuracy", "D_xy=1e-2", "--verify",
                          "-q"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stderr.startswith("accuracy D_xy 0.01: level 2")  # the prediction, before the run
    last = out.stdout.strip().splitlines()[-1]
    assert last.startswith("verify: D_xy error") and "target met" in last
    bad = subprocess.run([sys.executable, "-m", "capsim.face.cli", "run", str(path), "--accuracy", "D_xy"],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "--accuracy" in bad.stderr and len(bad.stderr.strip().splitlines()) == 1


def test_the_ladder_estimate_is_richardson_with_the_observed_order():
    """measured_error on values f_L = f* + C 2^(-pL): from three levels, the observed order p and the
    exact error of the last; from two, order LADDER_TWO_LEVEL_ORDER (1.5): an estimate above the true
    error for any p >= 1.5; differences that change sign or grow are not converging (never accepted);
    θ's differences are taken modulo π."""
    import math

    f_star, C = 0.4, -0.3
    for p in (1.5, 2.0, 3.0):
        f = [f_star + C * 2.0 ** (-p * level) for level in (1, 2, 3)]
        three = accuracy.measured_error(f, relative=True)
        assert three["converging"] and three["order"] == pytest.approx(p, rel=1e-9)
        assert three["error"] == pytest.approx(abs(f[-1] - f_star) / abs(f[-1]), rel=1e-9)
        two = accuracy.measured_error(f[:2], relative=False)
        assert two["order"] == accuracy.LADDER_TWO_LEVEL_ORDER and not two["order_from_levels"]
        assert abs(f[1] - f_star) <= two["error"] <= 1.0001 * abs(f[1] - f_star) * (2**p - 1) / (2**1.5 - 1)
    # beyond LADDER_MAX_ORDER the order is clipped (the estimate grows, never shrinks)
    f = [f_star + C * 2.0 ** (-6 * level) for level in (1, 2, 3)]
    assert accuracy.measured_error(f, relative=False)["order"] == accuracy.LADDER_MAX_ORDER
    for f in ([0.37, 0.33, 0.35], [0.30, 0.31, 0.33]):  # a sign change; a growing difference
        e = accuracy.measured_error(f, relative=False)
        assert not e["converging"] and e["error"] == pytest.approx(max(abs(f[2] - f[1]), abs(f[1] - f[0])))
    # θ near ±π/2 (one orientation): 1.5706 and -1.5706 differ by 0.001 modulo π, not by π
    theta = [1.5606, 1.5706, -1.5706]
    e = accuracy.measured_error(theta, relative=False, period=math.pi)
    assert e["converging"] and e["error"] < 1e-3


def test_a_measured_target_keeps_the_first_level_whose_own_estimate_meets_it(tmp_path):
    """The ladder on the demo's sphere (kt 2): D_xy to 5 % is met at level 2 by its estimate from
    levels 1-2, and a level-3 run confirms it (|D2 − D3| / D3 below the target); the kept file is
    the plain level-2 run with the ladder's record; a target beyond max_level says NOT met."""
    import h5py

    from capsim.runs.runner import run_case
    from capsim.storage.store import read_case

    base = {"name": "m", "flow": {"shear_rate_G": 0.1}, "time": {"t_end": 2.0}}
    case = case_from_dict({**base, "accuracy": {"quantity": "D_xy", "target": 0.05, "method": "measure"},
                           "output": {"path": str(tmp_path / "m.h5")}})
    result = run_case(case)
    assert result.status == "completed" and "level 2" in result.accuracy and "target met" in result.accuracy
    kept = read_case(result.path)
    assert kept.mesh.level == 2 and kept.accuracy is None and kept.time.rtol == case.time.rtol
    with h5py.File(result.path) as f:
        levels, values, errors = (f["accuracy"][k][()] for k in ("level", "values", "errors"))
        assert list(levels) == [1, 2] and bool(f["accuracy/met"][()]) and errors[-1] <= 0.05
        assert values[-1] == float(f["timeseries/D_xy"][-1])
    finer = run_case(case_from_dict({**base, "mesh": {"level": 3}, "time": {**base["time"], "rtol": case.time.rtol},
                                     "output": {"path": str(tmp_path / "f.h5")}}))
    assert abs(values[-1] - finer.final_D_xy) / finer.final_D_xy <= 0.05
    short = run_case(case_from_dict({**base, "accuracy": {"quantity": "D_xy", "target": 1e-4, "method": "measure",
                                                          "max_level": 2},
                                     "output": {"path": str(tmp_path / "s.h5")}}))
    assert "NOT met by accuracy.max_level 2" in short.accuracy
    with h5py.File(short.path) as f:
        assert not bool(f["accuracy/met"][()]) and list(f["accuracy/level"][()]) == [1, 2]
    from capsim.storage.checkpoint import ResumeError

    with pytest.raises(ResumeError):
        run_case(case, resume=True)


def test_the_cli_prints_the_plan_before_and_the_verdict_after_a_measured_target(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text(f"name: c\nflow: {{shear_rate_G: 0.1}}\ntime: {{t_end: 1}}\noutput: {{path: {tmp_path / 'c.h5'}}}\n")
    out = subprocess.run([sys.executable, "-m", "capsim.face.cli", "run", str(path), "--accuracy", "D_xy=5e-2", "--set",
                          "accuracy.method=measure", "--verify", "-q"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stderr.startswith("accuracy D_xy 0.05: measured, asked for")  # the plan, before the runs
    last = out.stdout.strip().splitlines()[-1]
    assert last.startswith("accuracy D_xy 0.05: level 2") and last.endswith("target met")


def test_a_ladder_stopped_at_a_later_level_keeps_the_finest_level_it_completed(tmp_path):
    """Ctrl-C during level 2 (raised from the progress callback): the output is level 1's completed
    run with the ladder so far (one level: its error not estimated, NOT met) and the verdict says why
    it stopped; no hidden level file or checkpoint is left beside it."""
    import h5py

    from capsim.runs.runner import run_ladder as run_measured
    from capsim.storage.store import read_case

    def stop_at_level_2(case, progress=None, overwrite=True):
        def interrupt(state):
            if case.mesh.level == 2 and state["step"] >= 3:
                raise KeyboardInterrupt
        return run_case(case, progress=interrupt, overwrite=overwrite)

    case = case_from_dict({"name": "k", "time": {"t_end": 1.0}, "output": {"path": str(tmp_path / "k.h5")},
                           "accuracy": {"quantity": "D_xy", "target": 0.05, "method": "measure"}})
    result = run_measured(case, stop_at_level_2)
    # the ladder was interrupted (issue 51): its status says so, the file kept is level 1's completed run
    assert result.status == "interrupted" and "level 1" in result.accuracy and "interrupted" in result.accuracy
    assert read_case(tmp_path / "k.h5").mesh.level == 1
    with h5py.File(tmp_path / "k.h5") as f:
        assert f.attrs["status"] == "completed" and list(f["accuracy/level"][()]) == [1]
        assert not bool(f["accuracy/met"][()]) and "stopped" in f["accuracy/verdict"][()].decode()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["k.h5"]


def test_a_ladder_level_that_raises_keeps_the_finest_completed_level_and_leaves_nothing_beside_it(tmp_path):
    """A level whose run raises (an error of the code, raised from the progress callback: the run marks
    its file 'failed' and raises; a velocity solve that diverges is no such error but ends its run
    unstable: tests/runs/test_solver_divergence.py) ends the ladder as a stopped level does: level 1 kept, the verdict
    says which level failed and why, no hidden file left. At level 1, with nothing kept, the error is
    raised as a plain run's would be, its 'failed' file at the output path."""
    import h5py

    from capsim.runs.runner import run_ladder as run_measured

    class Crash(RuntimeError):
        """An error of the code in the middle of a level's run."""

    def diverge_at(level):
        def run_one(case, progress=None, overwrite=True):
            def diverge(state):
                if case.mesh.level == level and state["step"] >= 3:
                    raise Crash("the run broke at step 3")
            return run_case(case, progress=diverge, overwrite=overwrite)
        return run_one

    target = {"quantity": "D_xy", "target": 0.05, "method": "measure"}
    case = case_from_dict({"name": "d", "time": {"t_end": 1.0}, "output": {"path": str(tmp_path / "d.h5")},
                           "accuracy": target})
    result = run_measured(case, diverge_at(2))
    assert result.status == "failed" and "level 1" in result.accuracy  # the ladder failed; level 1 kept (issue 51)
    assert "the level-2 run failed: Crash: the run broke at step 3" in result.accuracy
    with h5py.File(tmp_path / "d.h5") as f:
        assert f.attrs["status"] == "completed" and list(f["accuracy/level"][()]) == [1]
        assert "Crash" in f["accuracy/verdict"][()].decode()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.h5"]
    first = case_from_dict({"name": "e", "time": {"t_end": 1.0}, "output": {"path": str(tmp_path / "e" / "e.h5")},
                            "accuracy": target})
    (tmp_path / "e").mkdir()
    with pytest.raises(Crash):
        run_measured(first, diverge_at(1))
    with h5py.File(tmp_path / "e" / "e.h5") as f:
        assert f.attrs["status"] == "failed" and "Crash" in f.attrs["status_reason"]
    assert [p.name for p in (tmp_path / "e").iterdir() if p.name.startswith(".")] == []


def test_a_campaign_of_accuracy_targets_runs_summarizes_and_resumes(tmp_path):
    """A sweep whose base has an accuracy target (the warm-up's level-0 copy drops the target, as it
    once did not): a measured run's kept file is the campaign's own (its requested case), summarized
    'completed' at the level the ladder kept, and skipped by a second sweep."""
    import capsim

    campaign = tmp_path / "c.yaml"
    campaign.write_text(f"name: c\nbase:\n  time: {{t_end: 0.5}}\n  accuracy: {{quantity: D_xy, target: 0.05, "
                        f"method: measure}}\nsweep:\n  flow.shear_rate_G: [0.1]\noutput: {{dir: {tmp_path / 'out'}}}\n")
    first = capsim.sweep(campaign, workers=1)
    assert first["completed"] == 1, first
    ds = capsim.summarize(tmp_path / "out")
    assert list(ds["status"].values.ravel()) == ["completed"] and int(ds["level"].values.ravel()[0]) >= 2
    again = capsim.sweep(campaign, workers=1)
    assert again["completed"] == 0 and again["skipped"] == 1, again
