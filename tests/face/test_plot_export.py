"""capsim plot (every kind) and capsim export (xdmf, vtu round-trips through meshio)."""

import struct
import xml.etree.ElementTree as ET

import h5py
import meshio
import numpy as np
import pytest
import xarray as xr
from typer.testing import CliRunner

from capsim.face.cli import app
from capsim.config import case_from_dict
from capsim.face.export import export_run, membrane_fields, model_for, snapshot_fields
from capsim.face.plot import DPI, FIGSIZE, KINDS, SCENE_KINDS, plot, relaxation_time, xy_section
from capsim.runs.runner import run_case
from capsim.storage.store import read_trajectory
from capsim.campaigns.summary import write_summary

WIDTH, HEIGHT = round(FIGSIZE[0] * DPI), round(FIGSIZE[1] * DPI)


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """Level-1 sphere, G = 0.1, λ = 1, to kt = 0.3 with four snapshots (about a second)."""
    path = tmp_path_factory.mktemp("tiny") / "tiny.h5"
    case = case_from_dict({
        "name": "tiny", "shape": {"kind": "sphere"}, "membrane": {"law": "thin_shell"},
        "flow": {"shear_rate_G": 0.1, "viscosity_ratio": 1.0},
        "mesh": {"base": "octahedron", "level": 1}, "time": {"t_end": 0.3},
        "output": {"path": str(path), "snapshot_every": 0.1},
    })
    assert run_case(case)["status"] == "completed"
    return path


@pytest.fixture(scope="module")
def summary_nc(tmp_path_factory):
    """A summary netCDF shaped like `capsim summarize` output on a G × λ grid."""
    G = np.array([0.0125, 0.025, 0.05, 0.1])
    lam = np.array([0.2, 1.0, 5.0])
    D = 25.0 / 4.0 * G[:, None] * (1.0 - 0.5 * G[:, None]) * np.ones((1, lam.size))
    theta = np.pi / 4 - 0.3 * G[:, None] * lam[None, :]
    ds = xr.Dataset(
        {"D_xy": (("shear_rate_G", "viscosity_ratio"), D),
         "theta": (("shear_rate_G", "viscosity_ratio"), theta),
         "status": (("shear_rate_G", "viscosity_ratio"), np.full(D.shape, "completed", dtype=object))},
        coords={"shear_rate_G": G, "viscosity_ratio": lam},
        attrs={"title": "capsim campaign test"},
    )
    return write_summary(ds, tmp_path_factory.mktemp("summary") / "summary.nc")


def _orbit_summary():
    """A zip summary with motion classes over shear rate x λ (as `capsim summarize` writes it)."""
    rate, lam = [50.0, 50.0, 200.0, 200.0, 800.0, 800.0], [5.0, 0.2] * 3
    motion = ["drifting_to_rolling", "off_plane_tank_treading", "drifting_to_rolling", "swinging", "kayaking", "unstable"]
    return xr.Dataset(
        {"D_xy": ("run", np.full(6, 0.1)), "theta": ("run", np.full(6, 0.3)), "motion": ("run", np.array(motion, object)),
         "status": ("run", np.array(["completed"] * 5 + ["unstable"], object)),
         "steady_average": ("run", np.array([0, 1, 0, 1, 1, 0]))},
        coords={"run": list("abcdef"), "shear_rate": ("run", rate), "viscosity_ratio": ("run", lam)})


def _conduit_summary():
    """A grid summary of capsules in tubes over radius × G (as `capsim summarize` writes it)."""
    radius, G = np.array([1.6, 2.5]), np.array([0.05, 0.1])
    grid = ("radius", "shear_rate_G")
    values = {name: (grid, np.array([[1.0, 1.1], [1.2, 1.3]])) for name in
              ("D_xy", "theta", "centroid_velocity_x", "extra_pressure_drop", "length_along", "width_across")}
    values["steady_average"] = (grid, np.ones((2, 2), dtype=np.int8))
    return xr.Dataset(values, coords={"radius": ("radius", radius, {"case_field": "conduit.radius"}),
                                      "shear_rate_G": G})


def png_size(path):
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", head[16:24])


EXPECTED_LABELS = {
    "deformation": [("$kt$", "$D_{xy}$")],
    "inclination": [("$kt$", r"$\theta/\pi$")],
    "contour": [("$x/a$", "$y/a$")],
    "trajectory": [("$x/a$", "$y/a$")],
    "tensions": [(r"arc length along the section, $s/L$", "principal tension $/E_s$")],
    "rheology": [("$kt$", r"$S^*_{xy}$, $N_1^*$, $N_2^*$")],
    "steady": [("", "$D_{xy}$"), ("$G = \\mu k a / E_s$", r"$\theta/\pi$")],
    "orbit": [("$kt$", r"angle / $\pi$"), ("director $x$", "director $y$"), ("director $y$", "director $z$")],
    "orbit_map": [("shear rate $k$ (1/s)", r"viscosity ratio $\lambda$")],
    "conduit": [("", r"speed $/ U$"), ("", r"$\Delta P^+ a/(\mu U)$"),
                (r"$G = \mu U/E_s$ (Ca)", r"length, width $/a$")],
    "migration": [("$kt$", "$y_c/a$")],
}


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_every_kind_writes_a_png_with_labelled_axes(kind, tiny_run, summary_nc, tmp_path):
    if kind in SCENE_KINDS:  # a run of several capsules only: drawn in tests/face/test_capsules_output.py
        with pytest.raises(ValueError, match="the run holds one"):
            plot(tiny_run, kind, tmp_path / f"{kind}.png")
        assert not (tmp_path / f"{kind}.png").exists()
        return
    if kind == "lift":  # a summary over wall.distance or wall runs: drawn in tests/face/test_scene_figures.py
        with pytest.raises(ValueError, match="has none"):
            plot(tiny_run, kind, tmp_path / f"{kind}.png")
        return
    source = {"steady": summary_nc, "orbit_map": _orbit_summary(), "conduit": _conduit_summary()}.get(kind, tiny_run)
    out = tmp_path / f"{kind}.png"
    fig = plot(source, kind, out)
    labels = [(ax.get_xlabel(), ax.get_ylabel()) for ax in fig.axes]
    assert labels == EXPECTED_LABELS[kind]
    assert all(ax.has_data() for ax in fig.axes)
    assert out.stat().st_size > 5000
    assert png_size(out) == (WIDTH, HEIGHT)


def test_deformation_overlays_first_order_theory(tiny_run):
    fig = plot(tiny_run, "deformation")
    ax = fig.axes[0]
    lines = {line.get_label(): line for line in ax.get_lines()}
    assert np.allclose(lines[r"$D_\infty = 25G/4$ (Barthès-Biesel & Rallison 1981)"].get_ydata(), 25.0 / 4.0 * 0.1)
    theory = next(line for label, line in lines.items() if label.startswith("first order"))
    t, D = theory.get_xdata(), theory.get_ydata()
    tau = 4.03 * 3 * 0.1
    assert np.allclose(D, 0.625 * (1 - np.exp(-t / tau)))
    # capsim's D_xy and the transient agree at early times (slope D∞/τ).
    run = read_trajectory(tiny_run)["timeseries"]
    k = np.searchsorted(run["t"], 0.1)
    assert run["D_xy"][k] == pytest.approx(0.625 * (1 - np.exp(-run["t"][k] / tau)), rel=0.15)


def test_relaxation_time_table():
    assert relaxation_time(0.1, 1.0) == pytest.approx(4.03 * 0.3)
    assert relaxation_time(0.1, 0.2) == pytest.approx(2.63 * 0.3)
    assert relaxation_time(0.1, 5.0) == pytest.approx(11.0 * 0.3)
    assert relaxation_time(0.1, 10.0) is None


def test_contour_at_chosen_times_and_trajectory_node(tiny_run):
    fig = plot(tiny_run, "contour", times=[0.0, 0.3])
    assert [line.get_label() for line in fig.axes[0].get_lines()] == ["kt = 0", "kt = 0.3"]
    fig = plot(tiny_run, "trajectory")
    data = read_trajectory(tiny_run)
    X = data["rest_positions"]
    assert X[fig.path_node, 1:] == pytest.approx([0.0, 0.0]) and X[fig.path_node, 0] == X[:, 0].max()
    path_line = next(line for line in fig.axes[0].get_lines() if line.get_label() == f"node {fig.path_node}")
    assert np.allclose(path_line.get_xdata(), data["positions"][:, fig.path_node, 0])


def test_xy_section_of_a_sphere_is_a_circle():
    from capsim.numerics.mesh import unit_sphere_mesh

    mesh = unit_sphere_mesh("octahedron", 3)
    x = mesh.positions * np.array([1.5, 1.0, 1.0])
    p, v = xy_section(x, mesh.elements, 0.0, values=x[:, 0])
    assert np.allclose(p[:, 2], 0.0)
    assert np.allclose(v, p[:, 0])
    r = np.hypot(p[:, 0] / 1.5, p[:, 1])
    assert r.max() <= 1.0 + 1e-12 and r.min() > 0.99
    c = p.mean(axis=0)
    angles = np.arctan2(p[:, 1] - c[1], p[:, 0] - c[0])
    assert np.all(np.diff(angles) > 0)  # ordered around the contour
    assert np.linalg.norm(np.diff(p, axis=0), axis=1).min() > 1e-3  # no repeated crossings
    p_off, _ = xy_section(x, mesh.elements, 0.5)
    assert np.allclose(p_off[:, 2], 0.5)


def test_principal_tensions_of_an_inflated_sphere_are_isotropic(tiny_run):
    data = read_trajectory(tiny_run)
    model = model_for(data)
    fields = membrane_fields(model, 1.1 * np.asarray(data["rest_positions"]))
    assert np.allclose(fields["principal_stretch_1"], 1.1)
    assert np.allclose(fields["principal_stretch_2"], 1.1)
    t1, t2 = fields["principal_tension_1"], fields["principal_tension_2"]
    assert np.all(t1 > 0)
    assert np.allclose(t1, t2, rtol=1e-8)
    trace = fields["tension"][:, [0, 4, 8]].sum(axis=1)
    assert np.allclose(trace, t1 + t2)


@pytest.fixture
def written(monkeypatch):
    """The fields export_run computes, snapshot by snapshot, to compare with what is read back."""
    import capsim.face.export

    out = []

    def recording(*args, **kwargs):
        fields = snapshot_fields(*args, **kwargs)
        out.append(fields)
        return fields

    monkeypatch.setattr(capsim.face.export, "snapshot_fields", recording)
    return out


def test_xdmf_export_round_trips_through_meshio(tiny_run, tmp_path, written):
    files = export_run(tiny_run, tmp_path / "xdmf", "xdmf")
    data = read_trajectory(tiny_run)
    n_snap, n_nodes = data["positions"].shape[:2]
    assert files[0].suffix == ".xdmf"
    with meshio.xdmf.TimeSeriesReader(files[0]) as reader:
        points, cells = reader.read_points_cells()
        assert points.shape == (n_nodes, 3)
        assert np.array_equal(points, data["positions"][0])
        assert [c.type for c in cells] == ["triangle6"]
        assert np.array_equal(cells[0].data, data["elements"])
        assert reader.num_steps == n_snap
        for k in range(n_snap):
            t, point_data, cell_data = reader.read_data(k)
            assert t == data["snapshot_t"][k]
            assert np.array_equal(point_data["displacement"] + data["rest_positions"], data["positions"][k])
            point, cell = written[k]
            if k == 0:  # unstressed rest shape at λ = 1: Δf = 0 and u = u∞ = (y, 0, 0)
                x = data["positions"][0]
                assert np.allclose(point_data["velocity"], np.stack([x[:, 1], 0 * x[:, 1], 0 * x[:, 1]], 1), atol=1e-12)
                assert np.allclose(point_data["principal_tension_1"], 0.0, atol=1e-12)
            assert set(point_data) == set(point)
            for name, value in point.items():
                assert point_data[name].shape[0] == n_nodes
                assert np.array_equal(point_data[name], value), name
            assert np.array_equal(cell_data["traction"][0], cell["traction"])
    # The surface moves: every grid has its own geometry.
    root = ET.parse(files[0]).getroot()
    geometry = [item.text.split(":")[1] for item in root.iter("DataItem") if item.text.endswith(tuple(
        f"/geometry/{k}" for k in range(n_snap)))]
    assert len(set(geometry)) == n_snap
    with h5py.File(files[1], "r") as h5:
        for k in range(n_snap):
            assert np.array_equal(h5[f"geometry/{k}"][()], data["positions"][k])


def test_vtu_export_round_trips_through_meshio(tiny_run, tmp_path, written):
    files = export_run(tiny_run, tmp_path / "vtu", "vtu")
    data = read_trajectory(tiny_run)
    n_snap = len(data["snapshot_t"])
    pvd, vtus = files[0], files[1:]
    assert pvd.suffix == ".pvd" and len(vtus) == n_snap
    steps = ET.parse(pvd).getroot().findall("./Collection/DataSet")
    assert [float(s.get("timestep")) for s in steps] == list(data["snapshot_t"])
    assert [s.get("file") for s in steps] == [f.name for f in vtus]
    for k, f in enumerate(vtus):
        mesh = meshio.read(f)
        assert mesh.points.shape[0] == data["rest_positions"].shape[0]
        assert np.array_equal(mesh.points, data["positions"][k])
        assert mesh.cells[0].type == "triangle6"
        assert np.array_equal(mesh.cells[0].data, data["elements"])
        point, cell = written[k]
        assert set(mesh.point_data) == set(point)
        for name, value in point.items():
            assert np.array_equal(mesh.point_data[name], value), name
        assert np.array_equal(mesh.cell_data["traction"][0], cell["traction"])


def test_cli_plot_and_export(tiny_run, summary_nc, tmp_path):
    runner = CliRunner()
    out = tmp_path / "c.png"
    result = runner.invoke(app, ["plot", str(tiny_run), "--kind", "contour", "-o", str(out), "-t", "0", "-t", "0.3"])
    assert result.exit_code == 0, result.output
    assert png_size(out) == (WIDTH, HEIGHT)
    result = runner.invoke(app, ["plot", str(summary_nc), "--kind", "steady", "-o", str(tmp_path / "s.png")])
    assert result.exit_code == 0, result.output
    result = runner.invoke(app, ["plot", str(tiny_run), "--kind", "nonsense"])
    assert result.exit_code == 2
    result = runner.invoke(app, ["plot", str(tmp_path / "missing.h5"), "--kind", "deformation"])
    assert result.exit_code == 2
    result = runner.invoke(app, ["export", str(tiny_run), "--format", "vtu", "-o", str(tmp_path / "e"), "--no-fields"])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "e" / "tiny.pvd").exists()
    assert set(meshio.read(tmp_path / "e" / "tiny_0000.vtu").point_data) == {"displacement"}
    result = runner.invoke(app, ["export", str(tiny_run), "--format", "stl"])
    assert result.exit_code == 2


def test_steady_groups_runs_of_a_non_grid_summary():
    ds = xr.Dataset(
        {"D_xy": ("run", [0.1, 0.2, 0.15]), "theta": ("run", [0.7, 0.6, 0.65])},
        coords={"run": ["a", "b", "c"], "shear_rate_G": ("run", [0.05, 0.1, 0.05]),
                "viscosity_ratio": ("run", [1.0, 1.0, 5.0])},
    )
    fig = plot(ds, "steady")
    lines = {line.get_label(): line for line in fig.axes[0].get_lines()}
    assert list(lines) == ["λ = 1", "λ = 5", "first order, $25G/4$ (Barthès-Biesel & Rallison 1981)"]  # as a grid labels them
    assert list(lines["λ = 1"].get_xdata()) == [0.05, 0.1]
    assert list(lines["λ = 1"].get_ydata()) == [0.1, 0.2]


def test_steady_adds_tank_treading_and_stresslet_panels_when_summarised(summary_nc, tmp_path):
    """Seed figs 11 and 13: TTF/f_s and S*_xy, N1*, N2* against G, beside D_xy and θ."""
    ds = xr.load_dataset(summary_nc)
    shape = ds["D_xy"].shape
    G = ds["shear_rate_G"].values[:, None] * np.ones(shape)
    for name, values in {"ttf_ratio": 1 - G, "Sxy_star": 1 - 2 * G, "N1_star": 19 * G, "N2_star": -4 * G}.items():
        ds[name] = (("shear_rate_G", "viscosity_ratio"), values)
    out = tmp_path / "steady4.png"
    fig = plot(ds, "steady", out)
    labels = [(ax.get_xlabel(), ax.get_ylabel()) for ax in fig.axes]
    assert labels == [("", "$D_{xy}$"), ("", r"TTF $/ f_s$"), ("$G = \\mu k a / E_s$", r"$\theta/\pi$"),
                      ("$G = \\mu k a / E_s$", r"$S^*_{xy}$, $N_1^*$, $N_2^*$")]
    ttf_lines = [line for line in fig.axes[1].get_lines() if line.get_label() == "λ = 5"]
    assert np.allclose(ttf_lines[0].get_ydata(), 1 - ds["shear_rate_G"].values)
    assert png_size(out)[0] > WIDTH


def test_deformation_overlays_several_runs_each_with_its_theory(tiny_run, tmp_path):
    """Seed figs 4–6 put several G on one axis: one coloured line and one theory curve per run."""
    other = tmp_path / "G0.05.h5"
    case = case_from_dict({
        "name": "tiny-G0.05", "flow": {"shear_rate_G": 0.05}, "mesh": {"level": 1},
        "time": {"t_end": 0.2}, "output": {"path": str(other), "snapshot_every": 0.1},
    })
    assert run_case(case)["status"] == "completed"
    fig = plot([tiny_run, other], "deformation")
    lines = fig.axes[0].get_lines()
    runs = [line for line in lines if line.get_label().startswith("G = ")]
    assert [line.get_label() for line in runs] == ["G = 0.1, λ = 1", "G = 0.05, λ = 1"]
    plateaus = sorted(line.get_ydata()[0] for line in lines if line.get_linestyle() == ":")
    assert np.allclose(plateaus, [25 / 4 * 0.05, 25 / 4 * 0.1])
    fig = plot([tiny_run, other], "inclination")
    assert len([line for line in fig.axes[0].get_lines() if line.get_label().startswith("G = ")]) == 2
    runner = CliRunner()
    out = tmp_path / "both.png"
    result = runner.invoke(app, ["plot", str(tiny_run), str(other), "--kind", "deformation", "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert png_size(out) == (WIDTH, HEIGHT)
    result = runner.invoke(app, ["plot", str(tiny_run), str(other), "--kind", "contour"])
    assert result.exit_code == 2 and "takes one PATH" in result.output


def test_cli_names_the_plot_kinds_the_plot_module_has():
    from capsim.face.cli import _PLOT_KINDS

    assert _PLOT_KINDS == tuple(KINDS)


# ------------------------------------------------------------ journal-ready figures (issue 30, finding 4)


def test_pdf_embeds_truetype_fonts_and_svg_keeps_text(tiny_run, tmp_path):
    plot(tiny_run, "deformation", tmp_path / "d.pdf")
    pdf = (tmp_path / "d.pdf").read_bytes()
    assert b"/FontFile2" in pdf and b"/Type3" not in pdf  # Type 42 (TrueType), no Type 3
    plot(tiny_run, "deformation", tmp_path / "d.svg")
    svg = (tmp_path / "d.svg").read_text()
    assert "<text" in svg and "D_{xy}" not in svg.split("<text", 1)[0][-200:]


def test_size_label_and_a_legend_inside_when_there_is_room(tiny_run, tmp_path):
    runner = CliRunner()
    other = tmp_path / "copy.h5"
    other.write_bytes(tiny_run.read_bytes())
    out = tmp_path / "d.png"
    result = runner.invoke(app, ["plot", str(tiny_run), str(other), "--kind", "deformation", "--size", "3.3,2.5",
                                 "--label", "first", "--label", "second", "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert png_size(out) == (330, 250)
    fig = plot([str(tiny_run), str(other)], "deformation", labels=["first", "second"], size=(3.3, 2.5))
    ax = fig.axes[0]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels[:2] == ["first", "second"]
    # without --label two runs of one case still get labels that tell them apart
    auto = [t.get_text() for t in plot([str(tiny_run), str(other)], "deformation").axes[0].get_legend().get_texts()]
    assert len(set(auto[:2])) == 2, auto
    # the contour's legend fits inside, covering no line: it does not take a quarter of the width
    fig = plot(tiny_run, "contour")
    box, axes_box = fig.axes[0].get_legend().get_window_extent(), fig.axes[0].get_window_extent()
    assert axes_box.x0 <= box.x0 and box.x1 <= axes_box.x1 and axes_box.width > 0.8 * fig.bbox.width


@pytest.mark.parametrize("args, expected", [
    (["--size", "3x2"], "--size '3x2': must be W,H in inches"),
    (["--size", "0.5,2"], "--size '0.5,2': W and H must be in [1, 30] inches"),
    (["--label", "a", "--label", "b"], "--label given 2 times for 1 runs: give one per PATH, in order"),
    (["--x", "shear_rate_G"], "--x 'shear_rate_G': only for --kind steady"),
    # issue 38, finding 18: each factor within its range, the product 72000² pixels (~20 GB): refused at once
    (["--size", "30,30", "--dpi", "2400"], "--size 30,30 at --dpi 2400 is 72000 x 72000 = 5.18e+09 pixels, more "
                                           "than the 1e+08 a PNG may have: lower --dpi (at most 333 at this size)"),
    # finding 20: a size too small for the axes was four UserWarnings and a collapsed figure
    (["--size", "1,1"], "--size 1,1: too small for --kind deformation, its axes collapse under their labels and "
                        "caption; give at least about"),
])
def test_bad_figure_options_are_one_line_exit_2(tiny_run, tmp_path, args, expected):
    import time
    import warnings

    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no UserWarning on the way to the refusal
        result = CliRunner().invoke(app, ["plot", str(tiny_run), "--kind", "deformation", "-o", str(tmp_path / "f.png"),
                                          *args])
    assert result.exit_code == 2 and len(result.stderr.strip().splitlines()) == 1, result.output
    assert expected in result.stderr
    assert not (tmp_path / "f.png").exists() and time.perf_counter() - start < 30


def test_a_small_size_that_fits_draws_cleanly_and_the_hint_fits(tiny_run, tmp_path):
    import re
    import warnings

    result = CliRunner().invoke(app, ["plot", str(tiny_run), "--kind", "deformation", "--size", "1,1",
                                      "-o", str(tmp_path / "f.png")])
    w, h = (float(v) for v in re.search(r"at least about ([\d.]+),([\d.]+) inches", result.stderr).groups())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        plot(tiny_run, "deformation", tmp_path / "g.png", size=(w + 0.1, h + 0.1))
        plot(tiny_run, "deformation", tmp_path / "v.pdf", size=(30, 30), dpi=2400)  # vector: no pixel bound


def test_the_caption_is_the_resolved_case_not_its_name(tmp_path):
    path = tmp_path / "named.h5"
    case = case_from_dict({
        "name": "sphere-G0.1", "flow": {"shear_rate_G": 0.05}, "mesh": {"level": 0}, "time": {"t_end": 0.05},
        "output": {"path": str(path), "snapshot_every": 0.05},
    })
    run_case(case)
    caption = plot(path, "deformation").caption
    assert "G = 0.05" in caption and "G0.1" not in caption
