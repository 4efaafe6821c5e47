"""The accuracy knob for the scene's own quantities (issue 54, part 3): lift, slip, separation, migration
and gap, short names mapped to summary columns in one table; the error model has no training case
for any, so each is measured (the ladder), never predicted; a quantity the scene lacks is refused in
one line naming what is allowed; and one real ladder on a wall's lift, checked against a finer level."""

from __future__ import annotations

import h5py
import pytest

from capsim.config import case_from_dict
from capsim.runs import ladder
from capsim.runs.runner import run_case, run_ladder
from capsim.solve import accuracy
from capsim.storage.store import read_run_record

WALL = {"flow": {"shear_rate_G": 0.1}, "wall": {"distance": 1.6}}
PAIR = {"capsules": [{"center": [-2.0, 0.3, 0.0]}, {"center": [2.0, -0.3, 0.0]}]}
POISEUILLE = {"flow": {"kind": "poiseuille", "poiseuille_radius": 5.0}, "initial_center": [0.0, 1.5, 0.0]}


def _features(**scene):
    return case_from_dict({"name": "f", "time": {"t_end": 1.0}, **scene}).error_model_features()


def test_the_short_names_map_to_summary_columns_in_one_table():
    assert {accuracy.canonical(s): s for s in ("lift", "slip", "separation", "migration", "gap")} == {
        "centroid_velocity_y": "lift", "slip_velocity_x": "slip", "separation_y_final": "separation",
        "migration_y": "migration", "wall_gap_final": "gap"}
    assert set(accuracy.SCENE_QUANTITIES) <= set(accuracy.QUANTITY_NAMES)
    assert accuracy.canonical("D") == "D_xy" and accuracy.is_relative("centroid_velocity_y")
    with pytest.raises(accuracy.AccuracyError, match=r"^accuracy\.quantity = 'height': allowed: D_xy, theta, "
                                                     r"Sxy_star .*lift, slip, separation, migration, gap"):
        accuracy.canonical("height")


@pytest.mark.parametrize("quantity, scene", [("lift", WALL), ("slip", WALL), ("gap", WALL),
                                             ("separation", PAIR), ("migration", POISEUILLE), ("slip", POISEUILLE)])
def test_a_scene_quantity_is_measured_never_predicted(quantity, scene):
    features = _features(**scene)
    best = accuracy.plan(quantity, 1e-2, 1.0, features, "auto")
    assert best["method"] == "measure" and best["level"] == 1
    assert f"no training case for {quantity} ({accuracy.canonical(quantity)})" in best["why"]
    assert best["rtol"] == 1e-3  # its assumed time error (1 × rtol) a tenth of the target
    with pytest.raises(accuracy.AccuracyError, match=r"accuracy\.method = 'predict': the error model has no "
                                                     f"training case for {quantity}"):
        accuracy.plan(quantity, 1e-2, 1.0, features, "predict")


@pytest.mark.parametrize("quantity, scene, needs, allowed", [
    ("lift", {}, "a plane wall", "D_xy, theta, Sxy_star"),
    ("lift", POISEUILLE, "a plane wall", "D_xy, theta, Sxy_star, slip, migration"),
    ("separation", WALL, "two capsules", "D_xy, theta, Sxy_star, lift, slip, gap"),
    ("migration", WALL, "a Poiseuille flow", "D_xy, theta, Sxy_star, lift, slip, gap"),
    ("gap", PAIR, "a wall or a conduit", "D_xy, theta, Sxy_star, slip, separation"),
])
def test_a_quantity_the_scene_has_not_is_refused_in_one_line(quantity, scene, needs, allowed):
    with pytest.raises(accuracy.AccuracyError) as err:
        accuracy.plan(quantity, 1e-2, 1.0, _features(**scene), "auto")
    text = str(err.value)
    assert "\n" not in text and text.startswith(f"accuracy.quantity = {quantity!r}: ")
    assert f"needs {needs}" in text and text.endswith(f"allowed here: {allowed}")


def test_the_migration_on_the_poiseuille_axis_is_fixed_by_symmetry():
    on_axis = _features(**{**POISEUILLE, "initial_center": [0.0, 0.0, 0.0]})
    with pytest.raises(accuracy.AccuracyError, match="does not migrate"):
        accuracy.plan("migration", 1e-2, 1.0, on_axis, "measure")


def test_a_value_within_its_error_of_zero_is_said_so_not_judged_relative():
    """A lift that tends to 0 (far from the wall): relative to it the error means nothing; the verdict says
    so and gives the absolute error, and the target is not met."""
    case = case_from_dict({"name": "z", "time": {"t_end": 1.0, "rtol": 1e-3}, "mesh": {"level": 1}, **WALL})
    values = [2e-5, -1e-5, 4e-6]
    estimate = accuracy.measured_error(values, relative=True)
    record = {"level": [1, 2, 3], "values": values, "errors": [float("nan"), 1.0, estimate["error"]],
              "absolute_errors": [float("nan"), 1e-5, estimate["error"] * abs(values[-1])], "wall_time_s": [1.0] * 3}
    target = type("T", (), {"target": 1e-2})()
    text = ladder._verdict("centroid_velocity_y", target, case, record, estimate, False)
    assert estimate["error"] >= accuracy.MEANINGLESS_RELATIVE
    assert "target NOT met; lift (centroid_velocity_y) = 4e-06 is within its error of 0" in text
    assert f"its absolute error {record['absolute_errors'][-1]:.2g} is the statement" in text


def test_a_real_ladder_on_a_walls_lift_reads_the_window_mean_and_is_right_against_level_4(tmp_path):
    """Levels 1-3 at rtol 1e-3 (a few seconds): the value each level reads is its summary's window-mean lift;
    the kept level's estimate meets 1e-2, and its true error against level 4 does too."""
    base = case_from_dict({"name": "lw", "time": {"t_end": 1.0}, **WALL, "output": {"path": str(tmp_path / "l.h5")},
                           "accuracy": {"quantity": "D_xy", "target": 0.01, "method": "measure", "max_level": 3}})
    best = accuracy.plan("lift", 1e-2, 1.0, base.error_model_features(), "auto", 3)
    # the case's schema takes D_xy, θ and S*_xy by name: the lift's target is set on the resolved case
    case = base.model_copy(update={
        "accuracy": base.accuracy.model_copy(update={"quantity": best["quantity"], "target": 1e-2,
                                                    "choice": best["why"]}),
        "time": base.time.model_copy(update={"rtol": best["rtol"]})})
    result = run_ladder(case)
    assert result.status == "completed" and result.accuracy_met, result.accuracy
    with h5py.File(tmp_path / "l.h5", "r") as f:
        levels, values = list(f["accuracy/level"][()]), f["accuracy/values"][()]
        errors, absolute = f["accuracy/errors"][()], f["accuracy/absolute_errors"][()]
    assert levels == [1, 2, 3] and errors[-1] <= 1e-2 and absolute[-1] == pytest.approx(errors[-1] * values[-1])
    assert values[-1] == read_run_record(tmp_path / "l.h5")["summary"]["centroid_velocity_y"]
    assert "relative" in result.accuracy and "absolute" in result.accuracy and "target met" in result.accuracy
    fine = run_case(case_from_dict({"name": "l4", "time": {"t_end": 1.0, "rtol": best["rtol"]}, "mesh": {"level": 4},
                                    **WALL, "output": {"path": str(tmp_path / "l4.h5")}}))
    truth = abs(values[-1] - fine.summary["centroid_velocity_y"]) / abs(fine.summary["centroid_velocity_y"])
    assert truth <= 1e-2 and truth <= 3 * errors[-1], (truth, errors[-1])
