"""The campaign's orbit-class map (`capsim plot SUMMARY.nc --kind orbit_map`, issue 39): each
run a cell over two swept fields, coloured and labelled by its class, settled or not."""

import numpy as np
import pytest
import xarray as xr
from typer.testing import CliRunner

from capsim.face.cli import app
from capsim.face.plot import CLASS_COLOURS, orbit_map_figure, plot
from capsim.campaigns.summary import write_summary


def _summary(levels=(1,)):
    """A zip summary shaped like `capsim summarize` of campaigns/rbc-orbits-45deg.yaml: shear
    rate swept, viscosity and λ zipped, mesh levels swept."""
    rates, fluids = (50.0, 200.0, 800.0), ((1.2e-3, 5.0), (30e-3, 0.2))
    rows = [(k, lev, mu, lam) for k in rates for lev in levels for mu, lam in fluids]
    motion = {5.0: "drifting_to_rolling", 0.2: "swinging"}
    n = len(rows)
    status = ["completed"] * n
    status[-1] = "unstable"
    settled = [1.0 if lam == 0.2 and lev == levels[-1] else 0.0 for _, lev, _, lam in rows]
    ds = xr.Dataset(
        {"D_xy": ("run", np.linspace(0.1, 0.6, n)), "theta": ("run", np.full(n, 0.3)),
         "motion": ("run", np.array([motion[r[3]] if s == "completed" else "unstable"
                                     for r, s in zip(rows, status)], dtype=object)),
         "status": ("run", np.array(status, dtype=object)),
         "settled": ("run", np.array(settled)),
         "steady_average": ("run", np.array([int(s and st == "completed") for s, st in zip(settled, status)]))},
        coords={"run": [f"r{i}" for i in range(n)], "shear_rate": ("run", [r[0] for r in rows]),
                "level": ("run", [r[1] for r in rows]), "viscosity": ("run", [r[2] for r in rows]),
                "viscosity_ratio": ("run", [r[3] for r in rows])},
        attrs={"title": "capsim campaign test"})
    return ds, rows, status, settled


def test_each_run_is_a_cell_at_its_rate_and_lambda_with_its_class_and_settled_flag():
    ds, rows, status, settled = _summary()
    fig = orbit_map_figure(ds)
    ax = fig.axes[0]
    # the defaults: shear rate across, λ up (the zipped viscosity is one-to-one with λ: no split)
    assert ax.get_xlabel().startswith("shear rate") and "lambda" in ax.get_ylabel()
    assert [t.get_text() for t in ax.get_xticklabels()] == ["50", "200", "800"]
    assert [t.get_text() for t in ax.get_yticklabels()] == ["0.2", "5"]
    cells = fig.map_cells
    assert len(cells) == len(rows)
    for cell in cells:
        i = next(k for k, r in enumerate(rows) if (r[0], r[3]) == (cell["x"], cell["y"]))
        assert cell["status"] == status[i]
        assert cell["settled"] == (bool(settled[i]) and status[i] == "completed")
    # every completed run's class is written in its cell, and each cell is filled with its colour
    texts = [t.get_text() for t in ax.texts]
    assert sum("drifting to\nrolling" in t or "drifting to rolling" in t for t in texts) == 3
    assert sum("not settled" in t for t in texts) == 3 and sum(t.endswith("\nsettled") for t in texts) == 2
    assert sum("unstable" in t for t in texts) == 1
    faces = [tuple(np.round(p.get_facecolor()[:3], 3)) for p in ax.patches]
    from matplotlib.colors import to_rgb

    assert faces.count(tuple(np.round(to_rgb(CLASS_COLOURS["swinging"]), 3))) == 2
    hatched = [p for p in ax.patches if p.get_hatch()]
    assert len(hatched) == len(rows) - 2  # every run that did not settle, the unstable one too
    legend = fig.legends[0]
    assert [t.get_text() for t in legend.get_texts()] == ["drifting to rolling", "swinging", "not settled"]


def test_a_further_swept_field_splits_the_cell_and_axes_can_be_chosen(tmp_path):
    ds, rows, _, _ = _summary(levels=(1, 2))
    fig = orbit_map_figure(ds)
    assert len(fig.map_cells) == len(rows) == 12
    texts = [t.get_text() for t in fig.axes[0].texts]
    assert sum(t.startswith("level 1") for t in texts) == sum(t.startswith("level 2") for t in texts) == 6
    fig = orbit_map_figure(ds, x="level", y="shear_rate")
    assert [t.get_text() for t in fig.axes[0].get_xticklabels()] == ["1", "2"]
    with pytest.raises(ValueError, match="--y 'G': not a swept field"):
        orbit_map_figure(ds, y="G")
    # through the CLI, from a netCDF written as capsim summarize writes it
    nc = write_summary(ds, tmp_path / "s.nc")
    out = tmp_path / "map.png"
    result = CliRunner().invoke(app, ["plot", str(nc), "--kind", "orbit_map", "--x", "shear_rate", "--y",
                                      "viscosity_ratio", "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    result = CliRunner().invoke(app, ["plot", str(nc), "--kind", "steady", "--y", "level", "-o", str(tmp_path / "x.png")])
    assert result.exit_code == 2 and "--y 'level': only for --kind orbit_map" in result.stderr


def test_a_summary_without_classes_is_refused_in_one_line():
    ds = xr.Dataset({"D_xy": ("run", [0.1, 0.2])}, coords={"run": ["a", "b"], "shear_rate_G": ("run", [0.1, 0.2])})
    with pytest.raises(ValueError, match="no 'motion'"):
        plot(ds, "orbit_map")


def test_a_grid_summary_maps_every_combination():
    """A grid summary (swept fields as dimensions): the axes are its two dimensions, each run
    at its own pair, a missing run grey with its status."""
    G, lam = np.array([0.01, 0.1]), np.array([0.2, 1.0, 5.0])
    dims = ("shear_rate_G", "viscosity_ratio")
    motion = np.array([["steady", "swinging", "tumbling"], ["steady", "", "kayaking"]], dtype=object)
    status = np.array([["completed"] * 3, ["completed", "missing", "completed"]], dtype=object)
    ds = xr.Dataset({"D_xy": (dims, np.ones((2, 3))), "motion": (dims, motion), "status": (dims, status),
                     "steady_average": (dims, np.array([[1, 1, 0], [1, 0, 1]]))},
                    coords={"shear_rate_G": G, "viscosity_ratio": lam})
    cells = {(c["x"], c["y"]): c for c in orbit_map_figure(ds).map_cells}
    assert len(cells) == 6
    for i, g in enumerate(G):
        for j, v in enumerate(lam):
            cell = cells[(g, v)]
            assert cell["status"] == status[i, j]
            if status[i, j] == "completed":
                assert cell["motion"] == motion[i, j] and cell["settled"] == bool(ds["steady_average"].values[i, j])
    assert not cells[(0.1, 1.0)]["settled"]
