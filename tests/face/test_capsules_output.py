"""Figures and ParaView export of a run of several capsules (issue 43, deliverable 4): the
time-series kinds draw one line per capsule, the sections every capsule's outline, the kind
`separation` a pair's relative trajectory (its data are the run's separation columns) and, for
more capsules, their centroid paths; `orbit` refuses a scene in one line; the export holds every
capsule's surface and the field `capsule` (point and cell); a one-capsule run is as it was."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import matplotlib.pyplot as plt
import meshio
import numpy as np
import pytest
from typer.testing import CliRunner

from capsim.face.cli import app
from capsim.config import case_from_dict
from capsim.face.export import export_run, membrane_fields, model_for
from capsim.face.plot import KINDS, SCENE_KINDS, capsule_count, plot, scene_bodies
from capsim.runs.runner import run_case
from capsim.storage.store import read_trajectory

CENTERS = ([2.5, -0.25, 0.0], [-2.5, 0.25, 0.0])


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """Two capsules at level 1 to kt = 1 (about a second): capsule 0 prestressed by the top-level
    shape.inflation 0.05, capsule 1 with a shape of its own and none."""
    path = tmp_path_factory.mktemp("pair") / "pair.h5"
    case = case_from_dict({
        "name": "pair", "mesh": {"level": 1}, "flow": {"shear_rate_G": 0.1}, "shape": {"inflation": 0.05},
        "time": {"t_end": 1.0}, "output": {"path": str(path), "snapshot_every": 0.5},
        "capsules": [{"center": CENTERS[0]}, {"center": CENTERS[1], "shape": {"kind": "sphere", "inflation": 0.0}}],
    })
    assert run_case(case)["status"] == "completed"
    return path


@pytest.fixture(scope="module")
def single(tmp_path_factory):
    path = tmp_path_factory.mktemp("single") / "one.h5"
    case = case_from_dict({"name": "one", "mesh": {"level": 1}, "flow": {"shear_rate_G": 0.1},
                           "time": {"t_end": 0.3}, "output": {"path": str(path), "snapshot_every": 0.1}})
    assert run_case(case)["status"] == "completed"
    return path


def _labelled(ax) -> dict:
    return {line.get_label(): line for line in ax.get_lines() if not line.get_label().startswith("_")}


def _draw(path, kind, tmp_path):
    out = tmp_path / f"{kind}.png"
    fig = plot(path, kind, out)
    assert out.stat().st_size > 5000
    return fig


def test_the_layout_of_the_stored_scene(pair):
    data = read_trajectory(pair)
    assert capsule_count(data) == 2
    bodies = scene_bodies(data)
    n = data["rest_positions"].shape[0]
    assert bodies.count == 2 and bodies.nodes_per_body * 2 == n
    for i in range(2):  # capsule i's nodes sit about its centre
        assert np.allclose(data["rest_positions"][bodies.nodes(i)].mean(axis=0), CENTERS[i], atol=1e-9)


@pytest.mark.parametrize("kind, column", [("deformation", "D_xy"), ("inclination", "theta")])
def test_time_series_kinds_draw_one_line_per_capsule(pair, tmp_path, kind, column):
    data = read_trajectory(pair)
    fig = _draw(pair, kind, tmp_path)
    lines = _labelled(fig.axes[0])
    assert {"capsule 0", "capsule 1"} <= set(lines) and "capsim" not in lines
    values = data["timeseries"][column]
    for j in range(2):
        y = np.asarray(lines[f"capsule {j}"].get_ydata(), float)
        if kind == "deformation":
            assert np.array_equal(y, values[:, j])
        else:  # θ/π where defined (it is, but at kt = 0 where the spheres have no long axis)
            ok = np.isfinite(y)
            assert ok.sum() >= len(values) - 2
            assert np.allclose(y[ok] * np.pi, values[:len(y), j][ok])
    assert lines["capsule 0"].get_color() != lines["capsule 1"].get_color()
    assert "2 capsules" in fig.caption
    plt.close(fig)


def test_rheology_draws_every_capsules_stresslet(pair, tmp_path):
    data = read_trajectory(pair)
    fig = _draw(pair, "rheology", tmp_path)
    ax = fig.axes[0]
    sxy = [line for line in ax.get_lines() if line.get_color() == "C0" and len(line.get_xdata()) > 2]
    assert len(sxy) == 2
    for j, line in enumerate(sxy):
        assert np.array_equal(line.get_ydata(), data["timeseries"]["Sxy_star"][:, j])
    assert {"capsule 0", "capsule 1"} <= set(_labelled(ax))
    plt.close(fig)


def test_contour_draws_every_capsules_outline(pair, tmp_path):
    fig = _draw(pair, "contour", tmp_path)
    ax = fig.axes[0]
    centres = [np.mean(np.column_stack([line.get_xdata(), line.get_ydata()]), axis=0) for line in ax.get_lines()
               if len(line.get_xdata()) > 4]
    for c in CENTERS:  # the first snapshot's outlines sit about each capsule's centre
        assert min(np.hypot(*(p - c[:2])) for p in centres) < 0.05
    assert sorted(t.get_text() for t in ax.texts) == ["0", "1"]
    assert len([label for label in _labelled(ax) if label.startswith("kt = ")]) == 3  # one entry a time
    plt.close(fig)


def test_trajectory_draws_both_outlines_and_names_the_nodes_capsule(pair, tmp_path):
    fig = _draw(pair, "trajectory", tmp_path)
    ax = fig.axes[0]
    node = fig.path_node
    assert f"node {node} (capsule 0)" in _labelled(ax)  # the rest node farthest along +x: capsule 0's
    outlines = [line for line in ax.get_lines() if line.get_linestyle() == "--"]
    assert len(outlines) == 4  # two capsules, first and last snapshot
    plt.close(fig)


def test_tensions_draws_each_capsule_along_its_section(pair, tmp_path):
    fig = _draw(pair, "tensions", tmp_path)
    labels = set(_labelled(fig.axes[0]))
    assert {rf"$\tau_{k}$, capsule {j}" for k in (1, 2) for j in (0, 1)} <= labels
    plt.close(fig)


def test_separation_draws_the_runs_separation_columns(pair, tmp_path):
    data = read_trajectory(pair)
    fig = _draw(pair, "separation", tmp_path)
    ax = fig.axes[0]
    line = _labelled(ax)["relative trajectory"]
    assert np.array_equal(line.get_xdata(), data["timeseries"]["separation_x"])
    assert np.array_equal(line.get_ydata(), data["timeseries"]["separation_y"])
    assert np.allclose(data["timeseries"]["separation_x"][0], CENTERS[1][0] - CENTERS[0][0], atol=1e-9)
    assert (ax.get_xlabel(), ax.get_ylabel()) == (r"$\Delta x/a$", r"$\Delta y/a$")
    plt.close(fig)


def test_separation_of_three_capsules_draws_each_centroid_path(tmp_path):
    path = tmp_path / "three.h5"
    case = case_from_dict({"name": "three", "mesh": {"level": 1}, "flow": {"shear_rate_G": 0.1},
                           "time": {"t_end": 0.2}, "output": {"path": str(path)},
                           "capsules": [{"center": [3, -0.5, 0]}, {"center": [0, 0, 0]}, {"center": [-3, 0.5, 0]}]})
    assert run_case(case)["status"] == "completed"
    data = read_trajectory(path)
    fig = _draw(path, "separation", tmp_path)
    lines = _labelled(fig.axes[0])
    for j in range(3):
        assert np.array_equal(lines[f"capsule {j}"].get_xdata(), data["timeseries"]["centroid_x"][:, j])
        assert np.array_equal(lines[f"capsule {j}"].get_ydata(), data["timeseries"]["centroid_y"][:, j])
    plt.close(fig)


def _one_line_error(args) -> str:
    result = CliRunner().invoke(app, ["plot", *args])
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.output
    return lines[0]


def test_orbit_refuses_a_scene_and_separation_one_capsule_in_one_line(pair, single, tmp_path):
    text = _one_line_error([str(pair), "--kind", "orbit", "-o", str(tmp_path / "o.png")])
    assert "--kind orbit" in text and "2 capsules" in text
    assert not (tmp_path / "o.png").exists()
    text = _one_line_error([str(single), "--kind", "separation", "-o", str(tmp_path / "s.png")])
    assert "--kind separation" in text and "holds one" in text
    assert SCENE_KINDS == ("separation",) and set(SCENE_KINDS) <= set(KINDS)


def test_the_cli_draws_a_pair(pair, tmp_path):
    for kind in ("deformation", "separation", "contour"):
        result = CliRunner().invoke(app, ["plot", str(pair), "--kind", kind, "-o", str(tmp_path / f"{kind}.pdf")])
        assert result.exit_code == 0, result.output
        assert (tmp_path / f"{kind}.pdf").read_bytes()[:5] == b"%PDF-"


@pytest.mark.parametrize("fmt", ["xdmf", "vtu"])
def test_the_export_holds_every_capsule_and_the_capsule_field(pair, tmp_path, fmt):
    data = read_trajectory(pair)
    n, elements = data["rest_positions"].shape[0], data["elements"]
    bodies = scene_bodies(data)
    expected_cell = np.repeat([0, 1], elements.shape[0] // 2)
    files = export_run(pair, tmp_path / fmt, fmt)
    if fmt == "xdmf":
        root = ET.parse(files[0]).getroot()
        info = {i.get("Name"): i.get("Value") for i in root.iter("Information")}
        assert info["units_capsule"] == "1"
        with meshio.xdmf.TimeSeriesReader(files[0]) as reader:
            points, cells = reader.read_points_cells()
            steps = [reader.read_data(k) for k in range(reader.num_steps)]
        assert len(steps) == len(data["snapshot_t"])
        meshes = [(points, cells, point, cell) for _, point, cell in steps]
    else:
        meshes = []
        for f in files[1:]:
            mesh = meshio.read(f)
            meshes.append((mesh.points, mesh.cells, mesh.point_data, mesh.cell_data))
        assert len(meshes) == len(data["snapshot_t"])
    for points, cells, point, cell in meshes:
        assert points.shape == (n, 3)  # every capsule's nodes
        assert [c.type for c in cells] == ["triangle6"] and np.array_equal(cells[0].data, elements)
        assert np.array_equal(point["capsule"], bodies.node_body)
        assert set(np.unique(point["capsule"])) == {0, 1}
        assert np.array_equal(cell["capsule"][0], expected_cell)
        assert {"velocity", "principal_tension_1", "displacement"} <= set(point)
    for i in range(2):  # capsule i's points are its surface, about its centre
        assert np.allclose(meshes[0][0][meshes[0][2]["capsule"] == i].mean(axis=0), CENTERS[i], atol=1e-9)


def test_the_export_without_fields_and_in_physical_units_keeps_the_capsule_field(pair, tmp_path):
    files = export_run(pair, tmp_path / "bare", "vtu", fields=False)
    mesh = meshio.read(files[1])
    assert set(mesh.point_data) == {"displacement", "capsule"}
    assert set(np.unique(mesh.point_data["capsule"])) == {0, 1}


def test_each_capsules_reference_is_its_own_inflation(pair):
    """At kt = 0 capsule 0 carries the prestress of its inflation 0.05, capsule 1 (a shape of its
    own, no inflation) none: the export's model shrinks each capsule by its own inflation."""
    data = read_trajectory(pair)
    bodies = scene_bodies(data)
    fields = membrane_fields(model_for(data), np.asarray(data["positions"][0], dtype=np.float64))
    t0, t1 = (fields["principal_tension_2"][bodies.nodes(i)] for i in range(2))
    assert t0.min() > 0.01
    assert np.abs(fields["principal_tension_1"][bodies.nodes(1)]).max() < 1e-9 and np.abs(t1).max() < 1e-9


def test_a_one_capsule_run_is_as_it_was(single, tmp_path):
    data = read_trajectory(single)
    assert capsule_count(data) == 1
    fig = plot(single, "deformation")
    lines = _labelled(fig.axes[0])
    assert lines["capsim"].get_color() == "k" and not any(label.startswith("capsule") for label in lines)
    assert fig.caption == "sphere, thin_shell, λ = 1, G = 0.1, mesh octahedron level 1 (66 nodes)"
    plt.close(fig)
    fig = plot(single, "contour")
    assert not fig.axes[0].texts
    assert fig.caption == "sphere, thin_shell, λ = 1, G = 0.1, mesh octahedron level 1 (66 nodes)"
    plt.close(fig)
    fig = plot(single, "tensions")
    assert set(_labelled(fig.axes[0])) == {r"$\tau_1$", r"$\tau_2$"}
    plt.close(fig)
    fig = plot(single, "rheology")
    assert "first order" in _labelled(fig.axes[0])
    plt.close(fig)
    files = export_run(single, tmp_path / "x", "xdmf", fields=False)
    root = ET.parse(files[0]).getroot()
    assert "units_capsule" not in {i.get("Name") for i in root.iter("Information")}
    with meshio.xdmf.TimeSeriesReader(files[0]) as reader:
        reader.read_points_cells()
        _, point, cell = reader.read_data(0)
    assert set(point) == {"displacement"} and not cell
