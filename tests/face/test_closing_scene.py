"""The scene's own quantities in the closing table and the run summary (issue 54, part 2): a wall run
shows its lift, slip and gap, a Poiseuille run its migration, each the number its summary (and the
campaign's record of it) holds; a scene without them shows no such row."""

from __future__ import annotations

import pytest

from capsim.config import case_from_dict
from capsim.face.display import scene_features, summary_rows
from capsim.campaigns.summary import read_run
from capsim.runs.runner import run_case

WALL = {"flow": {"shear_rate_G": 0.1}, "wall": {"distance": 1.6}}
POISEUILLE = {"flow": {"kind": "poiseuille", "poiseuille_radius": 5.0, "shear_rate_G": 0.1},
              "initial_center": [0.0, 1.5, 0.0]}


def _run(tmp_path, name, scene, t_end=1.0):
    case = case_from_dict({"name": name, "mesh": {"level": 1}, "time": {"t_end": t_end, "rtol": 1e-3},
                           "output": {"path": str(tmp_path / f"{name}.h5")}, **scene})
    result = run_case(case)
    assert result.status == "completed"
    return dict(result.as_dict()), dict(summary_rows(dict(result.as_dict())))


@pytest.fixture(scope="module")
def wall_run(tmp_path_factory):
    return _run(tmp_path_factory.mktemp("wall"), "wall", WALL)


def test_a_wall_run_shows_its_lift_slip_and_gap_as_its_summary_holds_them(wall_run):
    summary, rows = wall_run
    assert scene_features(summary) == {"wall": True, "conduit": False, "varying_gradient": False}
    lift, slip = summary["centroid_velocity_y"], summary["slip_velocity_x"]
    # the physics, not only the text: a sphere at h 1.6 in the wall's shear drifts away from it and lags
    assert 1e-3 < lift < 0.1 and -0.2 < slip < -1e-3
    assert rows["lift velocity, y (k a)"] == f"{lift:.6f} ± {summary['centroid_velocity_y_std']:.2e}"
    assert rows["slip velocity, x (k a)"] == f"{slip:.6f} ± {summary['slip_velocity_x_std']:.2e}"
    g0, gmin, g1 = summary["wall_gap_initial"], summary["wall_gap_min"], summary["wall_gap_final"]
    assert abs(g0 - 0.6) < 0.05 and gmin <= min(g0, g1) and g1 > g0  # lifted: the gap grew
    assert rows["wall gap (a)"] == f"{g0:.4g} at the start, smallest {gmin:.4g}, {g1:.4g} at the end"
    assert "migration in y (a)" not in rows  # a wall's drift is its lift, not a Poiseuille migration


def test_the_campaign_record_carries_the_same_numbers(wall_run):
    summary, _ = wall_run
    record = read_run(summary["path"])
    for name in ("centroid_velocity_y", "centroid_velocity_y_std", "slip_velocity_x", "wall_gap_initial",
                 "wall_gap_min", "wall_gap_final", "migration_y"):
        assert record[name] == pytest.approx(summary[name], rel=1e-12, abs=1e-15), name
    # the migration is the centroid's y from start to end: here the wall's lift carried it up
    assert record["migration_y"] == pytest.approx(summary["centroid_y_final"] - summary["centroid_y_initial"],
                                                  abs=1e-12)
    assert record["migration_y"] > 0


def test_a_poiseuille_run_shows_its_migration_and_no_wall_rows(tmp_path):
    summary, rows = _run(tmp_path, "pois", POISEUILLE)
    y0, y1, moved = summary["centroid_y_initial"], summary["centroid_y_final"], summary["migration_y"]
    assert abs(y0 - 1.5) < 1e-9 and moved == pytest.approx(y1 - y0, abs=1e-12)
    assert -0.05 < moved < -1e-4  # a deformable capsule migrates toward the axis
    text = rows["migration in y (a)"]
    assert text.startswith(f"{y0:.4g} -> {y1:.4g} ({moved:+.4g} over kt {summary['t']:.4g}: "
                           f"{moved / summary['t']:+.3g} k a on average)")
    assert text.endswith(f"over the window {summary['centroid_velocity_y']:.6f} ± "
                         f"{summary['centroid_velocity_y_std']:.2e}")
    assert not any(key.startswith(("lift", "slip", "wall gap")) for key in rows)


def test_unbounded_shear_shows_none_of_the_scene_rows():
    rows = dict(summary_rows({"status": "completed", "t": 1.0, "centroid_velocity_y": 0.0, "centroid_y_initial": 0.0,
                              "centroid_y_final": 0.0, "migration_y": 0.0,
                              "scene": {"wall": False, "conduit": False, "varying_gradient": False}}))
    assert not any(key.startswith(("lift", "slip", "wall gap", "migration")) for key in rows)
