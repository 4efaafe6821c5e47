"""Figures of the scenes (issue 54): `capsim plot --kind lift` (from a campaign summary or from
wall runs, with the far-field laws of each run's own stresslet), `--kind migration` (several runs
overlaid, each kind's cross-stream position), `--kind separation` (two panels, several pairs
overlaid) and the contour figure in physical units next to a wall (every snapshot asked for,
the wall band at the wall). Real short runs at level 1 (about 30 s in all on one core)."""

from __future__ import annotations

import math

import matplotlib.pyplot as plt
import numpy as np
import pytest
import xarray as xr
import yaml
from typer.testing import CliRunner

from capsim import api
from capsim.face.cli import app
from capsim.face.plot import KINDS, plot, slip_law
from capsim.storage.store import read_trajectory

DISTANCES = (2.5, 5.0)
GS = (0.05, 0.1)
#: a wall run in physical units: G = μka/E_s = 0.05 at k = 225 1/s (a = 4 µm, E_s = 3 G_s = 18 µN/m)
PHYSICAL = {"shear_rate": "225 1/s", "radius": "4 um", "viscosity": "1 mPa s", "shear_modulus": "6 uN/m"}


@pytest.fixture(scope="module")
def lift_campaign(tmp_path_factory):
    """A 2 × 2 grid over the wall distance and G, level 1, kt 2 (a few seconds a run), summarized."""
    root = tmp_path_factory.mktemp("lift")
    campaign = {"name": "lift-test", "base": {"mesh": {"level": 1}, "time": {"t_end": 2.0},
                                              "output": {"snapshot_every": 1.0}},
                "sweep": {"wall.distance": list(DISTANCES), "flow.shear_rate_G": list(GS)},
                "output": {"dir": str(root / "runs")}}
    path = root / "lift.yaml"
    path.write_text(yaml.safe_dump(campaign))
    api.sweep(path, workers=1)
    ds = api.summarize(root / "runs")
    assert set(ds["status"].values.ravel()) == {"completed"}
    runs = {(h, G): root / "runs" / f for h, G, f in _run_files(root / "runs")}
    return root / "runs" / "summary.nc", runs


def _run_files(directory):
    import json

    for entry in json.loads((directory / "runs.json").read_text())["runs"].values():
        params = entry["params"]
        yield float(params["wall.distance"]), float(params["flow.shear_rate_G"]), entry["file"]


def _run(path, **case):
    result = api.run({"name": path.stem, "mesh": {"level": 1}, **case}, output=path)
    assert result.status == "completed"
    return path


@pytest.fixture(scope="module")
def scene_runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("scenes")
    pair = {"flow": {"shear_rate_G": 0.05}, "membrane": {"law": "neo_hookean"}, "time": {"t_end": 8.0},
            "output": {"snapshot_every": 2.0}}
    return {
        # two pairs 3 a apart along the flow, offset 1 a and 0.5 a across it: they pass each other
        "pair_1": _run(root / "pair_1.h5", capsules=[{"center": [1.5, -0.5, 0]}, {"center": [-1.5, 0.5, 0]}], **pair),
        "pair_05": _run(root / "pair_05.h5", capsules=[{"center": [1.5, -0.25, 0]}, {"center": [-1.5, 0.25, 0]}],
                        **pair),
        "poiseuille": _run(root / "pois.h5", flow={"kind": "poiseuille", "poiseuille_radius": 5.0, "shear_rate_G": 0.05},
                           initial_center=[0.0, 2.0, 0.0], time={"t_end": 2.0}),
        # kt 3 at h = 3: the capsule travels ~9 a downstream, so the snapshots spread along x
        "physical_wall": _run(root / "wall_phys.h5", wall={"distance": 3.0}, physical=PHYSICAL,
                              time={"t_end": 3.0}, output={"snapshot_every": 1.0}),
    }


def _labelled(ax) -> dict:
    return {line.get_label(): line for line in ax.get_lines() if not line.get_label().startswith("_")}


def test_the_new_kinds_are_registered():
    assert {"lift", "migration", "separation"} <= set(KINDS)


def test_lift_from_a_summary_draws_its_values_and_the_far_field_laws(lift_campaign, tmp_path):
    summary, _ = lift_campaign
    ds = xr.load_dataset(summary)
    fig = plot(summary, "lift", tmp_path / "lift.pdf")
    assert (tmp_path / "lift.pdf").read_bytes()[:5] == b"%PDF-"
    ax_lift, ax_slip = fig.axes[:2]
    assert ax_lift.get_yscale() == "log" and ax_slip.get_xscale() == "log"  # lift ∝ h⁻²: log-log
    lifts = _labelled(ax_lift)
    slips = [ln for ln in ax_slip.get_lines() if ln.get_marker() == "s"]  # one a G, in the legend's order
    theory = [ln for ln in ax_lift.get_lines() if ln.get_linestyle() == "--"]
    assert len(theory) == len(GS)
    for j, G in enumerate(GS):
        at = ds.sel(shear_rate_G=G)
        h = np.asarray(at["distance"].values, float)
        line = lifts[f"G = {G:g}"]
        np.testing.assert_array_equal(line.get_xdata(), h)
        np.testing.assert_allclose(line.get_ydata(), at["centroid_velocity_y"].values, rtol=1e-12)
        np.testing.assert_allclose(slips[j].get_ydata(), -at["slip_velocity_x"].values, rtol=1e-12)
        # the law's line: −(9/64π) S_yy/h² of each run's own stresslet, S_yy = (5/2) V (N2* − N1*)/3
        V = 4 * math.pi / 3 * (1 + at["volume_drift"].values)
        S_yy = 2.5 * V * (at["N2_star"].values - at["N1_star"].values) / 3
        np.testing.assert_allclose(theory[j].get_xdata(), h)
        np.testing.assert_allclose(theory[j].get_ydata(), -9 / (64 * math.pi) * S_yy / h**2, rtol=1e-12)
        curve = fig.lift_curves[f"G = {G:g}"]
        np.testing.assert_allclose(curve["slip_law"], slip_law(h, at["Sxy_star"].values, V), rtol=1e-12)
        # a real check of the law: at h = 5 the lift is within 12 % of it (the next term falls as h⁻²
        # relative: 2.3 % at h = 8 in docs/known_answers.md), the slip within 12 %; at 2.5 within 30 %
        lift = at["centroid_velocity_y"].values
        assert np.all(np.abs(lift / curve["lift_law"] - 1) < [0.3, 0.12]), (lift, curve["lift_law"])
        slip = at["slip_velocity_x"].values
        assert np.all(np.abs(slip / curve["slip_law"] - 1) < [0.3, 0.12]), (slip, curve["slip_law"])
    assert any("Smart & Leighton 1991" in t.get_text() for t in ax_lift.get_legend().get_texts())
    plt.close(fig)


def test_lift_from_the_runs_equals_lift_from_their_summary(lift_campaign, tmp_path):
    summary, runs = lift_campaign
    from_summary = plot(summary, "lift").lift_curves
    fig = plot([str(p) for p in runs.values()], "lift", tmp_path / "lift.svg")
    assert "<text" in (tmp_path / "lift.svg").read_text()  # journal SVG: text kept as text
    for G in GS:
        mine = next(c for label, c in fig.lift_curves.items() if label.startswith(f"G = {G:g},"))
        theirs = from_summary[f"G = {G:g}"]
        for key in ("h", "lift", "slip"):
            np.testing.assert_allclose(mine[key], theirs[key], rtol=1e-12)
        # the summary keeps V from volume_drift, the runs their last volume: the same to the drift
        np.testing.assert_allclose(mine["lift_law"], theirs["lift_law"], rtol=1e-4)
    plt.close(fig)


def test_the_cli_draws_lift_and_refuses_a_run_without_a_wall(lift_campaign, scene_runs, tmp_path):
    summary, _ = lift_campaign
    out = tmp_path / "lift.png"
    result = CliRunner().invoke(app, ["plot", str(summary), "--kind", "lift", "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert out.read_bytes()[:4] == b"\x89PNG"
    result = CliRunner().invoke(app, ["plot", str(scene_runs["poiseuille"]), "--kind", "lift", "-o",
                                      str(tmp_path / "x.png")])
    assert result.exit_code == 2 and "has none (wall:" in result.output, result.output


def test_migration_overlays_each_runs_cross_stream_position(lift_campaign, scene_runs, tmp_path):
    _, runs = lift_campaign
    near, far, pois = runs[(2.5, 0.05)], runs[(5.0, 0.05)], scene_runs["poiseuille"]
    fig = plot([str(near), str(far), str(pois)], "migration", tmp_path / "migration.svg")
    ax = fig.axes[0]
    data = [line for line in ax.get_lines() if line.get_linestyle() == "-" and not line.get_label().startswith("_")]
    assert len(data) == 3 and len({line.get_label() for line in data}) == 3
    for line, path, h in ((data[0], near, 2.5), (data[1], far, 5.0)):
        ts = read_trajectory(path)["timeseries"]
        np.testing.assert_allclose(line.get_ydata(), ts["centroid_y"] + h, rtol=1e-12)  # the height above the wall
        np.testing.assert_array_equal(line.get_xdata(), ts["t"])
    ts = read_trajectory(pois)["timeseries"]
    np.testing.assert_allclose(data[2].get_ydata(), np.hypot(ts["centroid_y"], ts["centroid_z"]), rtol=1e-12)
    assert data[2].get_ydata()[-1] < 2.0  # a deformable capsule migrates towards the axis
    # the far-field law integrated along each wall run's stresslet: the rise within 15 % at h = 5
    laws = [line for line in ax.get_lines() if line.get_linestyle() == "--"]
    assert len(laws) == 2
    rise, rise_law = data[1].get_ydata()[-1] - 5.0, laws[1].get_ydata()[-1] - 5.0
    assert rise > 0 and rise == pytest.approx(rise_law, rel=0.15)
    plt.close(fig)


def test_separation_overlays_pairs_in_two_panels(scene_runs, tmp_path):
    paths = [scene_runs["pair_1"], scene_runs["pair_05"]]
    fig = plot([str(p) for p in paths], "separation", tmp_path / "separation.pdf")
    ax, ax_t = fig.axes[:2]
    assert (ax.get_xlabel(), ax.get_ylabel()) == (r"$\Delta x/a$", r"$\Delta y/a$")
    assert (ax_t.get_xlabel(), ax_t.get_ylabel()) == ("$kt$", r"$\Delta y/a$")
    traj, time = _labelled(ax), _labelled(ax_t)
    assert len(traj) == 2 and list(traj) == list(time)  # one labelled line a run in each panel, distinct
    for line, line_t, path in zip(traj.values(), time.values(), paths):
        ts = read_trajectory(path)["timeseries"]
        np.testing.assert_array_equal(line.get_xdata(), ts["separation_x"])
        np.testing.assert_array_equal(line.get_ydata(), ts["separation_y"])
        np.testing.assert_array_equal(line_t.get_xdata(), ts["t"])
        # they passed each other (Δx changed sign) and left further apart across the flow than they came
        assert ts["separation_x"][0] < 0 < ts["separation_x"][-1]
        assert ts["separation_y"][-1] > ts["separation_y"][0]
    assert "Δy₀ = 1 a" in list(traj)[0] and "Δy₀ = 0.5 a" in list(traj)[1]
    plt.close(fig)
    one = plot(scene_runs["pair_1"], "separation")  # one run as before: its relative trajectory first
    assert "relative trajectory" in _labelled(one.axes[0]) and len(one.axes) == 2
    plt.close(one)
    result = CliRunner().invoke(app, ["plot", *map(str, paths), "--kind", "separation", "--label", "wide",
                                      "--label", "close", "-o", str(tmp_path / "s.png")])
    assert result.exit_code == 0, result.output


def test_contour_in_physical_units_next_to_a_wall_keeps_every_snapshot_and_the_wall(scene_runs, tmp_path):
    """The defect of issue 54: with --units physical the x-limits the wall had fixed stayed in units of
    a while the lines were scaled to µm (snapshots downstream fell out of view and out of the legend),
    and the wall's hatched band was not scaled at all."""
    path, times = scene_runs["physical_wall"], [0.0, 1.0, 2.0, 3.0]
    a = 4.0  # µm
    plain = plot(path, "contour", times=times)
    fig = plot(path, "contour", tmp_path / "contour.png", units="physical", times=times)
    ax, ax0 = fig.axes[0], plain.axes[0]
    sections = [ln for ln in ax.get_lines() if ln.get_label() != "wall"]
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert sum(text.startswith("t = ") for text in legend) == 4, legend
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    for line in sections:  # every section wholly in view
        x, y = np.asarray(line.get_xdata(), float), np.asarray(line.get_ydata(), float)
        assert x.min() >= x0 and x.max() <= x1 and y.min() >= y0 and y.max() <= y1
    wall = _labelled(ax)["wall"]
    np.testing.assert_allclose(wall.get_ydata(), -3.0 * a)
    # the wall runs under every section, as in units of a (its ends scaled with them)
    np.testing.assert_allclose(wall.get_xdata(), _labelled(ax0)["wall"].get_xdata() * a, rtol=1e-12)
    assert wall.get_xdata().min() <= min(ln.get_xdata().min() for ln in sections)
    assert wall.get_xdata().max() >= max(ln.get_xdata().max() for ln in sections)
    band = ax.patches[0].get_xy()
    assert band[:, 1].max() == pytest.approx(-3.0 * a) and band[:, 1].min() == pytest.approx(-3.15 * a)
    plt.close(fig)
    plt.close(plain)


def test_one_command_draws_a_campaigns_directory(lift_campaign, tmp_path):
    """capsim plot runs/<campaign> --kind lift: the directory's summary made on the fly (nothing written
    there), the same curves as from summary.nc."""
    summary, _ = lift_campaign
    directory = summary.parent
    before = sorted(p.name for p in directory.iterdir())
    out = tmp_path / "lift-dir.png"
    result = CliRunner().invoke(app, ["plot", str(directory), "--kind", "lift", "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert out.read_bytes()[:4] == b"\x89PNG"
    assert sorted(p.name for p in directory.iterdir()) == before
    from capsim.face.plot import plot

    a, b = plot(directory, "lift"), plot(summary, "lift")
    for ax_a, ax_b in zip(a.axes, b.axes):
        for la, lb in zip(ax_a.get_lines(), ax_b.get_lines()):
            np.testing.assert_array_equal(la.get_ydata(), lb.get_ydata())
