"""Orbits you can trust (issue 39; issue 38, finding 13): the three-dimensional motion
classifier (capsim.solve.observables.classify_orbit, docs/method.md, "Motion classes") on
constructed series whose answer is known, and on short runs.

* A rigid spheroid's Jeffery orbit (the analytic solution, docs/known_answers.md, "Jeffery's
  orbits off the plane"): kayaking, tumbling or rolling by its orbit constant C, settled, with
  Jeffery's period, C, and a body that turns while the membrane does not move on it.
* The same orbit with C falling 10 % per orbit: not settled, drifting_to_rolling, the change
  measured as −10 %.
* A red cell tank-treading and swinging near the shear plane, its material director circling
  off the plane with the membrane: swinging (the old classifier, reading the director, said
  kayaking), the body still, the membrane tank-treading.
* A prolate or biconcave disk with its axis exactly on z: no turn from round-off azimuths.
* The t = 0 row of an off-plane red cell: no tie-break spike in D_xy.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from capsim.solve.observables import (
    DRIFT_RTOL,
    SETTLED_RTOL,
    ellipsoid_of_moment,
    run_summary,
    series_settled,
)
from capsim.quantities import MOTIONS, SETTLED_MOTIONS, TURNING_MOTIONS, canonical_motion

VOLUME = 4.0 * math.pi / 3.0


# ---------------------------------------------------------------- constructed series


def _jeffery_angles(t: np.ndarray, r: float, C) -> tuple[np.ndarray, np.ndarray]:
    """Jeffery's solution (docs/known_answers.md): φ from y towards x with tan φ = r tan(k t /
    (r + 1/r)), φ(0) = 0, continuous; θ from z with tan θ = C r / (r² cos²φ + sin²φ)^½ (C may
    vary with t: a constructed drift); C = inf is the shear plane."""
    w = t / (r + 1.0 / r)
    phi = np.unwrap(np.arctan2(r * np.sin(w), np.cos(w)))
    C = np.broadcast_to(np.asarray(C, float), t.shape)
    theta = np.where(np.isinf(C), np.pi / 2, np.arctan(C * r / np.sqrt(r**2 * np.cos(phi) ** 2 + np.sin(phi) ** 2)))
    return theta, phi


def _series(t: np.ndarray, p: np.ndarray, r: float, *, tt_angle: np.ndarray | None = None,
            director: np.ndarray | None = None, semi=None) -> dict:
    """The time series a run of a rigid spheroid with axis p(t) would write: the shape's
    observables from the second moment of the spheroid (semi-axes (axis, equator) of unit
    volume), the material director (p for a rigid body) and the tracked nodes' angle."""
    if semi is None:
        eq = r ** (-1.0 / 3.0)
        semi = (r * eq, eq)
    ax, eq = semi
    rows = []
    for q in p:
        M = VOLUME / 5.0 * (eq**2 * (np.eye(3) - np.outer(q, q)) + ax**2 * np.outer(q, q))
        rows.append(ellipsoid_of_moment(M, VOLUME))
    ones = np.ones_like(t)
    series = {"t": t, "D_xy": np.array([e["D_xy"] for e in rows]), "theta": np.array([e["theta"] for e in rows]),
              "ttf_ratio": ones, "Sxy_star": ones, "N1_star": ones, "N2_star": ones,
              "tt_angle": np.zeros_like(t) if tt_angle is None else tt_angle}
    d = p if director is None else director
    for k, c in enumerate("xyz"):
        series[f"director_{c}"] = d[:, k]
        series[f"long_axis_{c}"] = np.array([e["long_axis"][k] for e in rows])
        series[f"short_axis_{c}"] = np.array([e["short_axis"][k] for e in rows])
    for k, c in enumerate("abc"):
        series[f"ellipsoid_{c}"] = np.array([e[f"ellipsoid_{c}"] for e in rows])
    return series


def _axis(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    return np.stack([np.sin(theta) * np.sin(phi), np.sin(theta) * np.cos(phi), np.cos(theta)], axis=1)


def _rigid_tt_angle(t: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """The tracked nodes of a body turning rigidly in the plane: their mean angle (atan2(y, x),
    clockwise negative) turns with the axis's azimuth (from y towards x, clockwise positive)."""
    return 0.3 - (phi - phi[0])


@pytest.mark.parametrize("r", [0.4, 2.5])
@pytest.mark.parametrize("polar_deg, motion", [(50.0, "kayaking"), (90.0, "tumbling")])
def test_a_rigid_spheroids_jeffery_orbit_is_classified_by_its_C_and_settled(r, polar_deg, motion):
    T = 2 * math.pi * (r + 1 / r)
    t = np.linspace(0.0, 3.3 * T, 6000)
    C = math.tan(math.radians(polar_deg)) if polar_deg != 90.0 else math.inf
    theta, phi = _jeffery_angles(t, r, C)
    p = _axis(theta, phi)
    s = run_summary(_series(t, p, r, tt_angle=_rigid_tt_angle(t, phi) if polar_deg == 90.0 else None),
                    aspect_ratio=r)
    assert s["motion"] == motion and s["settled"] == 1.0
    assert s["motion"] in SETTLED_MOTIONS and s["motion"] in TURNING_MOTIONS
    # one meaning of the period: the axis once round, Jeffery's 2π(r + 1/r)
    assert s["orbit_period"] == pytest.approx(T, rel=1e-4) and s["period"] == s["orbit_period"]
    assert s["orbit_periods"] == 3 and s["orbits_averaged"] == 2
    assert s["orbit_period_change"] < 1e-4
    if polar_deg != 90.0:
        assert s["orbit_constant"] == pytest.approx(C, rel=1e-4)
        assert s["orbit_constant_first"] == pytest.approx(C, rel=1e-4)
        assert abs(s["orbit_constant_change"]) < 1e-4 and abs(s["orbit_constant_drift"]) < 1e-4
        assert s["final_polar_angle"] < math.pi / 2 - 0.1
    else:
        assert math.isinf(s["orbit_constant"]) and s["final_polar_angle"] == pytest.approx(math.pi / 2)
        # the nodes turn with the body: no tank-treading, a rigid turn, and ttf_ratio says so
        assert abs(s["tank_treading_ratio"]) < 1e-6 and s["rigid_turn"] == 1.0 and s["ttf_ratio_kind"] == 2.0
    # the body turns once per orbit on average: 2π/T over k/2
    assert s["body_rotation_ratio"] == pytest.approx(2 * (2 * math.pi / T), rel=1e-3)
    # a rigid body's shape does not oscillate; θ turns through every angle: no mean
    assert math.isnan(s["shape_period"]) and math.isnan(s["theta"])
    # the stop rule reads the same verdict
    assert series_settled(_series(t, p, r), r)


def test_under_two_whole_orbits_a_jeffery_orbit_is_kayaking_but_not_settled():
    r = 0.4
    T = 2 * math.pi * (r + 1 / r)
    t = np.linspace(0.0, 1.6 * T, 3000)
    p = _axis(*_jeffery_angles(t, r, 1.5))
    s = run_summary(_series(t, p, r), aspect_ratio=r)
    assert s["motion"] == "kayaking" and s["settled"] == 0.0
    assert s["orbit_periods"] == 1 and abs(s["orbit_constant_change"]) < 1e-4  # from the last two half orbits
    assert not series_settled(_series(t, p, r), r)


def test_an_axis_resting_on_z_is_rolling_and_settled():
    r = 0.4
    t = np.linspace(0.0, 40.0, 800)
    p = np.tile([0.0, 0.0, 1.0], (t.size, 1))
    # the membrane spins about z at the rigid sphere's rate: tank-treading on a still body
    s = run_summary(_series(t, p, r, tt_angle=-0.5 * t), aspect_ratio=r)
    assert s["motion"] == "rolling" and s["settled"] == 1.0
    assert s["final_polar_angle"] == 0.0 and math.isnan(s["orbit_period"]) and s["orbit_periods"] == 0
    assert s["ttf_ratio_kind"] == 0.0 and s["tank_treading_ratio"] == pytest.approx(1.0, abs=1e-9)


@pytest.mark.parametrize("factor, motion", [(0.9, "drifting_to_rolling"), (1.1, "drifting_to_plane")])
def test_an_orbit_constant_changing_10_percent_per_orbit_is_a_drift_not_settled(factor, motion):
    r = 0.4
    T = 2 * math.pi * (r + 1 / r)
    t = np.linspace(0.0, 4.2 * T, 8000)
    p = _axis(*_jeffery_angles(t, r, 0.8 * factor ** (t / T)))
    series = _series(t, p, r)
    s = run_summary(series, aspect_ratio=r)
    assert s["motion"] == motion and s["settled"] == 0.0
    assert s["motion"] in TURNING_MOTIONS and s["motion"] not in SETTLED_MOTIONS
    assert abs(s["orbit_constant_change"]) >= DRIFT_RTOL
    assert s["orbit_constant_change"] == pytest.approx(factor - 1.0, abs=0.01)
    # the run's mean per orbit, from the first whole orbit to the last (3 orbits apart): compounded
    assert s["orbit_periods"] == 4
    assert s["orbit_constant_drift"] == pytest.approx((factor**3 - 1.0) / 3.0, rel=0.05)
    assert s["orbit_period"] == pytest.approx(T, rel=1e-3)  # the period holds: C does not change it
    assert not series_settled(series, r)


def test_a_swinging_red_cell_near_the_shear_plane_is_swinging_not_kayaking():
    """A red cell (r = 0.4) tank-treading with its normal 5° off the shear plane, swinging
    (the normal's azimuth ±0.15 rad, the shape breathing, period 9.6): its membrane carries the
    material director round off the plane (polar 60°) at the tank-treading rate."""
    r, Tsw = 0.4, 9.6
    t = np.linspace(0.0, 60.0, 6000)
    swing = np.sin(2 * np.pi * t / Tsw)
    polar = np.radians(85.0)
    phi = 0.3 + 0.15 * swing
    normal = _axis(np.full_like(t, polar), phi)
    # the material director circles z with the membrane (clockwise, at 0.6 k/2)
    w = 0.3 * t
    director = _axis(np.full_like(t, np.radians(60.0)), w)
    series = _series(t, normal, r, tt_angle=-0.3 * t, director=director)
    series["ellipsoid_a"] = series["ellipsoid_a"] * (1 + 0.05 * swing)  # the shape breathes
    s = run_summary(series, aspect_ratio=r)
    assert s["motion"] == "swinging" and s["settled"] == 1.0
    assert s["period"] == pytest.approx(Tsw, rel=1e-2) and s["shape_period"] == pytest.approx(Tsw, rel=1e-2)
    assert abs(s["body_rotation_ratio"]) < 0.02 and s["ttf_ratio_kind"] == 0.0
    assert s["tank_treading_ratio"] == pytest.approx(0.6, rel=0.05)
    assert math.isnan(s["orbit_period"]) and s["motion"] not in TURNING_MOTIONS
    # the material director alone (a run file written before issue 39) would have said kayaking
    old = {k: v for k, v in series.items() if not k.startswith(("long_axis", "short_axis"))}
    assert run_summary(old, aspect_ratio=r)["motion"] == "kayaking"


def test_a_still_off_plane_axis_with_a_tank_treading_membrane_is_off_plane_tank_treading():
    r = 0.4
    t = np.linspace(0.0, 40.0, 2000)
    p = _axis(np.full_like(t, np.radians(40.0)), np.full_like(t, 0.2))
    s = run_summary(_series(t, p, r, tt_angle=-0.35 * t), aspect_ratio=r)
    assert s["motion"] == "off_plane_tank_treading" and s["settled"] == 1.0
    assert s["tank_treading_ratio"] == pytest.approx(0.7, rel=1e-6) and s["ttf_ratio_kind"] == 0.0
    # tilting towards z, still: a drift, not settled
    p = _axis(np.radians(40.0) - 0.004 * t, np.full_like(t, 0.2))
    s = run_summary(_series(t, p, r, tt_angle=-0.35 * t), aspect_ratio=r)
    assert s["motion"] == "drifting_to_rolling" and s["settled"] == 0.0


def test_the_class_names_are_one_list_and_old_names_still_read():
    assert set(SETTLED_MOTIONS) - {"oscillating"} <= set(MOTIONS)
    assert set(TURNING_MOTIONS) <= set(MOTIONS)
    assert canonical_motion("oscillating") == "swinging" and canonical_motion("kayaking") == "kayaking"
    assert SETTLED_RTOL < DRIFT_RTOL


# ---------------------------------------------------------------- short runs


def _run(tmp_path, name, shape, axis, t_end, level=1, symmetry="auto"):
    from capsim.config import case_from_dict
    from capsim.runs.runner import run_case
    from capsim.storage.store import read_trajectory

    case = case_from_dict({
        "name": name, "shape": shape, "initial_axis": axis, "flow": {"shear_rate_G": 0.1},
        "mesh": {"level": level, "symmetry": symmetry}, "time": {"t_end": t_end},
        "output": {"path": str(tmp_path / f"{name}.h5"), "snapshot_every": 10.0},
    })
    s = run_case(case)
    return s, read_trajectory(s["path"])


@pytest.mark.parametrize("shape, symmetry", [({"kind": "prolate", "aspect_ratio": 2.0}, "none"),
                                             ({"kind": "biconcave"}, "quarter")])
def test_an_axis_exactly_on_z_does_not_turn_from_round_off(tmp_path, shape, symmetry):
    """Issue 38, finding 13: the director stays on z to ~1e-17, and its azimuth is round-off
    that 'turned through π': the run was kayaking with θ NaN. Now: rolling (the axis is on z),
    not settled (kt 0.2 is too short to tell), no orbit."""
    s, traj = _run(tmp_path, shape["kind"], shape, [0.0, 0.0, 1.0], 0.2, symmetry=symmetry)
    ts = traj["timeseries"]
    assert np.abs(ts["director_x"]).max() < 1e-12 and np.abs(ts["director_y"]).max() < 1e-12
    assert s["motion"] == "rolling" and s["settled"] == 0.0
    assert s["orbit_periods"] == 0 and math.isnan(s["orbit_period"]) and s["final_polar_angle"] < 1e-9


def test_the_first_row_of_an_off_plane_red_cell_is_no_tie_break(tmp_path):
    """A biconcave disk 45° out of the plane: at t = 0 two of its semi-axes are equal, and the
    round-off of their eigenvectors decided which axes counted as in-plane (D_xy 0.52 at t = 0,
    4e-4 on the next row). The pair is now split as the shear splits it: the first row is the
    limit of the next ones."""
    s, traj = _run(tmp_path, "rbc45", {"kind": "biconcave"}, [0.0, 0.70710678, 0.70710678], 0.02, level=1)
    ts = traj["timeseries"]
    D = ts["D_xy"]
    assert D[0] < 1e-6 and abs(D[1] - D[0]) < 5e-3 and np.all(np.abs(np.diff(D[:5])) < 5e-3)
    for name in ("axis_L", "axis_l", "axis_W", "long_axis_x", "long_axis_y", "long_axis_z"):
        assert abs(ts[name][1] - ts[name][0]) < 5e-3, name
    # the axes are lines stored with a continuous sign: no row flips against the one before
    for name in ("long_axis", "short_axis"):
        v = np.stack([ts[f"{name}_{c}"] for c in "xyz"], axis=1)
        assert np.all(np.einsum("ij,ij->i", v[1:], v[:-1]) > 0.99), name
    assert ts["short_axis_y"][0] == pytest.approx(ts["short_axis_y"][1], abs=1e-3)  # the disk's normal


# ---------------------------------------------------------------- the closing table


def test_the_closing_table_shows_the_orbit_of_a_run_that_has_one():
    from capsim.face.display import summary_rows

    r = 0.4
    T = 2 * math.pi * (r + 1 / r)
    t = np.linspace(0.0, 1.6 * T, 3000)
    p = _axis(*_jeffery_angles(t, r, 1.5))
    s = run_summary(_series(t, p, r), aspect_ratio=r)
    rows = dict(summary_rows({**s, "status": "completed", "t": float(t[-1])}))
    assert rows["motion"] == "kayaking (not settled)"  # under two whole orbits
    assert rows["orbit period kT"].startswith(f"{T:.4g} (the axis once round; 1 whole orbit")
    assert rows["orbit constant C"].startswith("1.5, +0.0 % per orbit now")
    assert float(rows["axis from vorticity z (deg)"].split()[0]) == pytest.approx(
        math.degrees(s["final_polar_angle"]), abs=0.01)
    assert "body turn, membrane on it (/f_s)" in rows and "period kT" not in rows  # one period, the orbit's
    # a sphere has no axis: no orbit rows; a settled class is shown as it is
    sphere = dict(summary_rows({"status": "completed", "motion": "steady", "settled": 1.0,
                                "final_polar_angle": math.pi / 2, "jeffery_aspect_ratio": 1.0}))
    assert sphere["motion"] == "steady" and "axis from vorticity z (deg)" not in sphere
    # an old run file's class (no settled flag) reads as today's
    assert dict(summary_rows({"status": "completed", "motion": "oscillating"}))["motion"] == "swinging"


# ---------------------------------------------------------------- the figure


def test_the_orbit_figure_marks_the_class_and_the_settled_window(tmp_path):
    from capsim.face.plot import plot

    r = 0.4
    T = 2 * math.pi * (r + 1 / r)
    t = np.linspace(0.0, 3.3 * T, 3000)
    p = _axis(*_jeffery_angles(t, r, 1.2))
    series = _series(t, p, r)
    summary = run_summary(series, aspect_ratio=r)
    fig = plot({"timeseries": series, "summary": summary}, "orbit", tmp_path / "orbit.png")
    ax = fig.axes[0]
    assert ax.get_title() == "motion: kayaking, settled"
    edges = [line.get_xdata()[0] for line in ax.get_lines() if line.get_linestyle() == "--"]
    assert edges == pytest.approx([summary["averaging_t_from"], summary["averaging_t_to"]])
    assert summary["averaging_t_to"] - summary["averaging_t_from"] == pytest.approx(2 * T, rel=1e-3)
    labels = ax.get_legend_handles_labels()[1]
    assert "averaging window over 2 whole orbits" in labels
    assert any(label.startswith("axis: polar angle") for label in labels)  # the body's axis, not the director
    assert fig.axes[1].get_xlabel() == "axis $x$" and "short axis of the shape" in fig.caption
    # drifting: not settled, said so
    p = _axis(*_jeffery_angles(t, r, 0.8 * 0.9 ** (t / T)))
    series = _series(t, p, r)
    fig = plot({"timeseries": series, "summary": run_summary(series, aspect_ratio=r)}, "orbit")
    assert fig.axes[0].get_title() == "motion: drifting_to_rolling, not settled"


# ---------------------------------------------------------------- run files written before issue 39


def test_an_old_run_file_still_summarises_plots_and_extends(tmp_path):
    """A run file without the short axis and the new summary fields (as capsim wrote them
    before issue 39), its class `oscillating`: the campaign record reads it, the orbit figure
    falls back to the material director, and --resume --t-end extends it with its own columns
    (the summary then classifies on the director, the new fields of its rows left out)."""
    import h5py

    from capsim.config import case_from_dict
    from capsim.face.plot import plot
    from capsim.runs.runner import run_case
    from capsim.storage.store import read_trajectory
    from capsim.campaigns.summary import read_run

    path = tmp_path / "old.h5"
    case = case_from_dict({
        "name": "old", "shape": {"kind": "oblate", "aspect_ratio": 0.6}, "initial_axis": [0, 0.6, 0.8],
        "flow": {"shear_rate_G": 0.1}, "mesh": {"level": 0}, "time": {"t_end": 0.1},
        "output": {"path": str(path), "snapshot_every": 0.1}})
    run_case(case)
    new_summary = ("settled", "orbit_constant_change", "orbit_period_change", "orbits_averaged", "shape_period",
                   "body_rotation_ratio", "tank_treading_ratio", "rigid_turn", "ttf_ratio_kind")
    with h5py.File(path, "a") as f:
        for name in [k for k in f["timeseries"] if k.startswith("short_axis")]:
            del f["timeseries"][name]
        for name in new_summary:
            del f["summary"][name]
        del f["summary"]["motion"]
        f["summary"]["motion"] = "oscillating"
    record = read_run(path)
    assert record["motion"] == "oscillating" and record["steady_average"] == 1  # a settled class of its day
    assert all(math.isnan(record.get(name, float("nan"))) for name in new_summary)
    assert "the material director" in plot(path, "orbit").caption
    from capsim.api import run

    extended = run(case, resume=True, sets=["time.t_end=0.2"])
    assert extended.status == "completed" and extended.t == pytest.approx(0.2)
    ts = read_trajectory(path)["timeseries"]
    assert "short_axis_x" not in ts and ts["t"][-1] == pytest.approx(0.2)
    assert extended.summary["motion"] in MOTIONS


def test_the_docs_and_the_quantity_table_name_the_classes_the_classifier_has():
    """Issue 38, finding 9: the motion classes differed between the user guide, the quantity
    table and method.md. Each names every class of capsim.quantities.MOTIONS, and no class
    the classifier does not have (an old name only as such)."""
    import re
    from pathlib import Path

    from capsim.quantities import MOTION_ALIASES, MOTION_MEANINGS, TABLE

    root = Path(__file__).resolve().parents[2]
    method = (root / "docs" / "method.md").read_text(encoding="utf-8")
    section = method.split("## Motion classes", 1)[1].split("\n## ", 1)[0]
    guide = (root / "docs" / "user_guide.md").read_text(encoding="utf-8")
    guide_row = next(line for line in guide.splitlines() if line.startswith("| `motion` |"))
    table = TABLE["motion"].definition
    assert set(MOTION_MEANINGS) == set(MOTIONS)
    for where, text in (("method.md", section), ("user guide", guide_row), ("quantity table", table)):
        missing = [m for m in MOTIONS if m != "relaxing" and m not in text]
        assert not missing, (where, missing)
        for old in MOTION_ALIASES:  # an old name appears only beside what it means now
            assert all("before issue 39" in text[max(0, m.start() - 150):m.end() + 150]
                       for m in re.finditer(rf"\b{old}\b", text)), (where, old)


def test_stop_when_settled_stops_on_the_summarys_own_rule(tmp_path):
    """A level-0 oblate (b/a = 0.6, G = 0.2) swings from kt ≈ 10 on: time.stop_when_settled
    stops it once its last two cycles agree, and the summary of the stopped run says settled."""
    from capsim.config import case_from_dict
    from capsim.runs.runner import run_case

    case = case_from_dict({
        "name": "swing", "shape": {"kind": "oblate", "aspect_ratio": 0.6}, "flow": {"shear_rate_G": 0.2},
        "mesh": {"level": 0}, "time": {"t_end": 80.0, "rtol": 1e-3, "scheme": "rkc", "dt_initial": 0.01,
                                       "stop_when_settled": True},
        "output": {"path": str(tmp_path / "swing.h5"), "snapshot_every": 40.0},
    })
    s = run_case(case)
    assert s["status"] == "completed" and s["status_reason"].startswith("orbit settled"), s["status_reason"]
    assert s["t"] < 60.0 and s["motion"] == "swinging" and s["settled"] == 1.0
    assert s["period"] == pytest.approx(s["shape_period"], rel=0.05)  # the swing seen in θ and in the shape
    assert s["ttf_ratio_kind"] == 0.0 and abs(s["body_rotation_ratio"]) < 0.01  # the membrane tank-treads


def test_an_axis_still_tilting_into_the_plane_is_not_settled_and_a_swing_about_it_is_in_the_plane():
    """Issue 39's campaign (dextran): a disk started off the plane reaches it slowly while its
    in-plane shape already holds; stop_when_settled stopped such runs as a settled 'steady'. And
    a normal swinging about the plane by up to ±11° is in the plane by its mean tilt (one motion
    at both mesh levels, not off_plane_tank_treading at one and swinging at the other)."""
    from capsim.solve.observables import classify_orbit

    t = np.linspace(0.0, 20.0, 801)
    D, theta = np.full_like(t, 0.1), np.full_like(t, 0.3)

    def director(beta, phi=0.5):
        return np.stack([np.sin(beta) * np.sin(phi), np.sin(beta) * np.cos(phi), np.cos(beta)], axis=1)

    tilting = classify_orbit(t, D, theta, director(np.pi / 2 - 0.15 * np.exp(-t / 20.0)), 0.3)
    assert tilting["motion"] == "steady" and not tilting["settled"]
    still = classify_orbit(t, D, theta, director(np.full_like(t, np.pi / 2 - 0.05)), 0.3)
    assert still["motion"] == "steady" and still["settled"]
    swing = np.pi / 2 - np.deg2rad(11.0) * np.abs(np.sin(2 * np.pi * t / 4.0))  # up to 11°, ~7° on average
    assert classify_orbit(t, D, theta, director(swing), 0.3)["motion"] in ("steady", "swinging")


def test_stop_when_settled_waits_a_few_of_the_capsules_own_relaxation_times():
    """Issue 39's campaign: a red cell in dextran (G 2.24, λ 0.2, a viscous membrane) held its
    shape and tilt over 3/k at kt 12 and was stopped as a settled 'steady', then swung from kt ~20
    on. The stop rule now waits SETTLE_RELAXATION_TIMES slow relaxation times of the first-order
    theory (kτ = 12.1 G for a thin-shell sphere at λ = 1; longer with λ, G and membrane viscosity)."""
    from capsim.config import case_from_dict
    from capsim.solve.observables import SETTLE_RELAXATION_TIMES, slow_relaxation_time
    from capsim.solve.solver import build_model
    from capsim.runs.stopping import LoopState, stop_reason

    sphere, _ = build_model(case_from_dict({"name": "s", "mesh": {"level": 0}, "flow": {"shear_rate_G": 0.1}}))
    assert slow_relaxation_time(sphere) == pytest.approx(12.1 * 0.1, rel=2e-3)
    cell, _ = build_model(case_from_dict({
        "name": "c", "mesh": {"level": 0}, "shape": {"kind": "biconcave"},
        "membrane": {"law": "skalak", "skalak_c": 10.0, "viscosity": {"shear": 0.6}},
        "flow": {"shear_rate_G": 2.24, "viscosity_ratio": 0.2}}))
    wait = SETTLE_RELAXATION_TIMES * slow_relaxation_time(cell)
    assert wait > 40.0  # the stop at kt 12 cannot happen
    case = case_from_dict({"name": "s", "time": {"stop_when_settled": True, "t_end": 100.0}})
    t = np.linspace(0.0, 20.0, 401)
    history = {"t": list(t), "dt": [0.05] * t.size, "D_xy": [0.3] * t.size, "theta": [0.4] * t.size}
    for key in ("director_x", "director_y", "director_z"):
        history[key] = [float("nan")] * t.size
    row = {"volume": 1.0, "area": 1.0, "min_element_quality": 1.0, "max_principal_stretch": 1.0}
    state = LoopState(20.0, 0.05, 400, attempted=True, finite=True, accepted=True, h=0.05)
    assert stop_reason(state, case.time, case.guards, row, row, history, 1.0, 0.0).reason.startswith("orbit settled")
    assert stop_reason(state, case.time, case.guards, row, row, history, 1.0, wait) is None
