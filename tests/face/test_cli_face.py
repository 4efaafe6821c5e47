"""The command line's face (issue 17): figure formats, progress without control codes in
logs, --set, -h and examples, the overwrite guard, and the campaign dry run that lists
exactly what `capsim sweep` runs. Tiny runs only (mesh level 0-1, kt <= 0.3)."""

from __future__ import annotations

import io
import re
import struct
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from capsim.face.cli import app
from capsim.config import case_from_dict
from capsim.face.display import RunProgress, SweepProgress
from capsim.runs.runner import run_case

runner = CliRunner()
ESCAPE = re.compile(r"[\x1b\r]")  # any control sequence or carriage-return redraw


def _one_line_exit_2(result, expected: str = "") -> str:
    assert result.exit_code == 2, (result.exit_code, result.output)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("error: ") and "Traceback" not in result.output
    assert expected in lines[0], lines[0]
    return lines[0]


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """Level-1 sphere, G = 0.1, λ = 1, to kt = 0.3, four snapshots."""
    path = tmp_path_factory.mktemp("face") / "tiny.h5"
    case = case_from_dict({
        "name": "tiny", "shape": {"kind": "sphere"}, "flow": {"shear_rate_G": 0.1},
        "mesh": {"level": 1}, "time": {"t_end": 0.3},
        "output": {"path": str(path), "snapshot_every": 0.1},
    })
    assert run_case(case)["status"] == "completed"
    return path


def _tiny_case(tmp_path: Path, name: str = "tiny0", t_end: float = 0.05) -> Path:
    path = tmp_path / f"{name}.yaml"
    path.write_text(f"name: {name}\nmesh: {{level: 0}}\ntime: {{t_end: {t_end}}}\n"
                    f"output: {{path: {tmp_path / (name + '.h5')}, snapshot_every: {t_end / 2}}}\n")
    return path


# ------------------------------------------------------------ figures


@pytest.mark.parametrize(("suffix", "magic"), [(".pdf", b"%PDF-"), (".svg", b"<?xml")])
def test_plot_writes_the_format_its_suffix_names(tiny_run, tmp_path, suffix, magic):
    out = tmp_path / f"x{suffix}"
    result = runner.invoke(app, ["plot", str(tiny_run), "--kind", "deformation", "-o", str(out)])
    assert result.exit_code == 0, result.output
    head = out.read_bytes()[:64]
    assert head.startswith(magic), head
    if suffix == ".svg":
        assert b"<svg" in out.read_bytes()[:2000]
    # a second plot to the same name replaces the figure it wrote (it is a figure of this format)
    result = runner.invoke(app, ["plot", str(tiny_run), "--kind", "inclination", "-o", str(out)])
    assert result.exit_code == 0, result.output


def test_plot_dpi_sets_the_png_size(tiny_run, tmp_path):
    out = tmp_path / "x.png"
    result = runner.invoke(app, ["plot", str(tiny_run), "--kind", "contour", "-o", str(out), "--dpi", "50"])
    assert result.exit_code == 0, result.output
    head = out.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n"
    assert struct.unpack(">II", head[16:24]) == (320, 240)


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["--kind", "deformation", "-o", "{tmp}/x.jpg"], "the suffix names the format"),
        (["--kind", "steady", "-o", "{tmp}/s.png"], "is a run file; --kind steady takes a campaign summary"),
        (["--kind", "contour", "-t", "99", "-o", "{tmp}/c.png"], "--time kt = 99 is outside the run's snapshots"),
        (["--kind", "tensions", "-t", "-5", "-o", "{tmp}/c.png"], "is outside the run's snapshots"),
        (["--kind", "deformation", "--dpi", "0", "-o", "{tmp}/x.png"], "--dpi 0: must be in [10, 2400]"),
        (["--kind", "nonsense"], "'nonsense' is not one of 'deformation'"),
    ],
)
def test_plot_user_errors_are_one_line(tiny_run, tmp_path, args, expected):
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    _one_line_exit_2(runner.invoke(app, ["plot", str(tiny_run), *args]), expected)
    assert not list(tmp_path.iterdir())  # nothing written


def test_plot_and_export_refuse_what_is_not_a_run_in_one_line(tmp_path):
    text = tmp_path / "notes.h5"
    text.write_text("not hdf5\n")
    _one_line_exit_2(runner.invoke(app, ["plot", str(text), "--kind", "deformation", "-o", str(tmp_path / "a.png")]))
    _one_line_exit_2(runner.invoke(app, ["export", str(text)]), "not a capsim run file")
    _one_line_exit_2(runner.invoke(app, ["export", str(tmp_path / "missing.h5")]), "no such file")
    _one_line_exit_2(runner.invoke(app, ["export", str(text), "--format", "stl"]), "'stl' is not one of 'xdmf', 'vtu'")


def test_theta_is_not_drawn_before_it_is_defined_and_breaks_at_the_wrap():
    from capsim.face.plot import theta_for_plot

    t = np.linspace(0.0, 4.0, 9)
    D = np.array([0.0, 0.1, 0.2, 0.3, 0.3, 0.3, 0.3, 0.3, 0.3])
    theta = np.array([0.0, 0.7, 0.3, -0.5, -1.2, -1.5, 1.5, 1.2, 0.8])  # wraps from -1.5 to 1.5
    tt, th = theta_for_plot(t, theta, D)
    assert np.isnan(th[0])  # a sphere at kt = 0 has no long axis
    assert len(tt) == len(th) == 10 and np.isnan(th[6]) and np.isnan(tt[6])  # the line is broken there
    finite = th[np.isfinite(th)]
    assert np.all(np.abs(np.diff(finite[:5])) < 1.0)
    tt, th = theta_for_plot(t, theta, D, unwrap=True)
    assert len(th) == 9 and th[6] == pytest.approx(1.5 - np.pi)  # continued through -π/2


def test_theory_lines_only_where_the_theory_applies(tiny_run):
    from capsim.face.plot import inclination_figure, rheology_figure

    data_labels = {line.get_label() for line in inclination_figure(tiny_run).axes[0].get_lines()}
    assert r"first order, $\theta = \pi/4$ (Barthès-Biesel & Rallison 1981)" in data_labels  # a sphere at G = 0.1
    from capsim.storage.store import read_trajectory

    data = read_trajectory(tiny_run)
    config = yaml.safe_load(data["attrs"]["config_yaml"])
    for change in ({"shape": {"kind": "oblate", "aspect_ratio": 0.9}}, {"flow": {"shear_rate_G": 0.45}}):
        other = dict(data, attrs={**data["attrs"], "config_yaml": yaml.safe_dump({**config, **change})})
        labels = {line.get_label() for line in inclination_figure(other).axes[0].get_lines()}
        assert not any(label.startswith("first order") for label in labels), change
        labels = {line.get_label() for line in rheology_figure(other).axes[0].get_lines()}
        assert "first order" not in labels


def test_figures_carry_a_caption_and_keep_the_legend_outside(tiny_run):
    from capsim.face.plot import KINDS, SCENE_KINDS, SUMMARY_KINDS, plot

    # (a kind of several capsules refuses one: tests/face/test_capsules_output.py draws it)
    for kind in sorted(set(KINDS) - {*SUMMARY_KINDS, *SCENE_KINDS, "lift"}):  # lift: a wall's (test_scene_figures)
        fig = plot(tiny_run, kind)
        caption = fig._supxlabel.get_text()
        for words in ("sphere", "thin_shell", "λ = 1", "G = 0.1", "mesh octahedron level 1"):
            assert words in caption, (kind, caption)
        legend = fig.axes[0].get_legend()
        # issue 30 changed this: inside the axes where it covers no data, outside only where it must
        assert legend is not None and not _legend_on_data(fig.axes[0], legend), kind


def _legend_on_data(ax, legend) -> bool:
    """Any drawn vertex of a line (or midpoint of a segment) inside the legend's box."""
    box = legend.get_window_extent()
    for line in ax.get_lines():
        xy = line.get_transform().transform(np.column_stack([line.get_xdata(), line.get_ydata()]).astype(float))
        xy = np.concatenate([xy, 0.5 * (xy[1:] + xy[:-1])])
        if np.any((xy[:, 0] > box.x0) & (xy[:, 0] < box.x1) & (xy[:, 1] > box.y0) & (xy[:, 1] < box.y1)):
            return True
    return False


def test_contours_are_cut_from_the_curved_elements():
    from capsim.numerics.mesh import unit_sphere_mesh
    from capsim.face.plot import xy_section

    mesh = unit_sphere_mesh("octahedron", 1)
    flat, _ = xy_section(mesh.positions, mesh.elements, 0.3)
    curved, values = xy_section(mesh.positions, mesh.elements, 0.3, values=mesh.positions[:, 0], curved=True)
    r0 = np.sqrt(1 - 0.3 ** 2)
    err_flat = np.abs(np.hypot(flat[:, 0], flat[:, 1]) - r0).max()
    err_curved = np.abs(np.hypot(curved[:, 0], curved[:, 1]) - r0).max()
    assert err_curved < err_flat / 2 and len(curved) > 2 * len(flat)
    assert np.allclose(values, curved[:, 0])  # quadratic interpolation is exact for x itself
    assert np.allclose(curved[:, 2], 0.3)


# ------------------------------------------------------------ progress


def test_run_progress_in_a_log_is_plain_lines_one_per_interval():
    clock = iter(np.arange(0.0, 100.0, 0.25))
    stream = io.StringIO()
    progress = RunProgress(stream, terminal=False, interval_s=1.0, clock=lambda: float(next(clock)))
    for i in range(40):  # 10 s of calls, one every 0.25 s
        progress({"t": 0.3 * i / 39, "dt": 1e-3, "D_xy": 0.01, "step": i, "t_end": 0.3})
    progress.finish()
    text = stream.getvalue()
    assert not ESCAPE.search(text)
    lines = text.splitlines()
    assert len(lines) == 9 + 1  # at 1, 2, ..., 9 s, and the last state at the end
    assert all(line.startswith("kt ") and " ETA " in line and " elapsed " in line for line in lines)
    assert "(100 %)" in lines[-1] and "elapsed 0:00:10" in lines[-1]


def test_sweep_progress_in_a_log_names_running_cases_and_never_goes_stale():
    clock = iter(np.arange(0.0, 100.0, 1.0))
    stream = io.StringIO()
    progress = SweepProgress({"a": 0.3, "b": 0.3}, stream, terminal=False, interval_s=1.0,
                             clock=lambda: float(next(clock)))
    base = {"total": 3, "skipped": 1, "failed": 0}
    progress({**base, "done": 0, "running": 2, "kt": {"a": 0.0, "b": 0.0}})
    progress({**base, "done": 0, "running": 2, "kt": {"a": 0.15, "b": 0.1}})
    progress({**base, "done": 1, "running": 2, "kt": {"b": 0.2}})      # the executor's stale count
    progress({**base, "done": 2, "running": 1, "kt": {}})
    progress.finish()
    text = stream.getvalue()
    assert not ESCAPE.search(text)
    lines = text.splitlines()
    assert "a kt 0.15/0.3" in lines[0] and "b kt 0.10/0.3" in lines[0]
    assert lines[-1].startswith("runs 3/3 done (1 skipped), 0 failed, 0 running")
    assert "100 %" in lines[-1]


def test_capsim_run_into_a_log_has_no_control_codes(tmp_path):
    case = _tiny_case(tmp_path)
    result = runner.invoke(app, ["run", str(case)])
    assert result.exit_code == 0, result.output
    assert not ESCAPE.search(result.stderr) and not ESCAPE.search(result.stdout)
    assert result.stderr.strip().splitlines()[-1].startswith("kt 0.0500 / 0.05 (100 %)")
    assert re.search(r"^ status +completed$", result.stdout, re.M)


# ------------------------------------------------------------ --set, help, guard


def test_set_overrides_case_fields(tmp_path):
    case = _tiny_case(tmp_path)
    result = runner.invoke(app, ["validate", str(case), "--set", "mesh.level=1", "--set", "time.scheme=rkc",
                                 "--set", "time.rtol=1e-3", "--set", "membrane.bending_modulus=1e-4"])
    assert result.exit_code == 0, result.output
    resolved = yaml.safe_load(result.stdout)
    assert resolved["mesh"]["level"] == 1 and resolved["time"]["scheme"] == "rkc"
    assert resolved["time"]["rtol"] == 1e-3 and resolved["membrane"]["bending_modulus"] == 1e-4
    out = tmp_path / "set.h5"
    result = runner.invoke(app, ["run", str(case), "-q", "-o", str(out), "--set", "time.t_end=0.02"])
    assert result.exit_code == 0, result.output
    from capsim.storage.store import read_trajectory

    assert yaml.safe_load(read_trajectory(out)["attrs"]["config_yaml"])["time"]["t_end"] == 0.02


@pytest.mark.parametrize(
    ("sets", "expected"),
    [
        (["nonsense"], "give FIELD=VALUE"),
        (["mesh.level"], "give FIELD=VALUE"),
        (["mesh.level="], "no value after '='"),
        (["=2"], "give FIELD=VALUE"),
        (["mesh.levl=2"], "mesh.levl: unknown field 'levl'"),
        (["mesh.level=9"], "mesh.level = 9: must be <= 6"),
        (["foo.bar=1"], "'foo' is not a section of the case"),
        (["mesh.level=[1"], "the value is not YAML"),
        (["mesh.level=1", "mesh.level=2"], "--set mesh.level is given twice"),
        (["x" * 5000 + "=1"], "at most 1000 characters"),
    ],
)
def test_a_bad_set_is_one_line_exit_2(tmp_path, sets, expected):
    case = _tiny_case(tmp_path)
    args = [arg for s in sets for arg in ("--set", s)]
    for command in (["validate", str(case)], ["run", str(case), "-q"]):
        line = _one_line_exit_2(runner.invoke(app, [*command, *args]), expected)
        assert len(line) < 400
    assert not (tmp_path / "tiny0.h5").exists()


def test_h_and_an_example_in_every_commands_help():
    result = runner.invoke(app, ["-h"])
    assert result.exit_code == 0 and "--install-completion" in result.output
    commands = [c.name or c.callback.__name__ for c in app.registered_commands]
    assert {"run", "validate", "sweep", "study", "plot", "export", "summarize", "bench"} <= set(commands)
    for name in commands:
        result = runner.invoke(app, [name, "-h"])
        assert result.exit_code == 0, name
        help_text = result.output.split("Arguments", 1)[0].split("Options", 1)[0]
        assert "Example" in help_text and f"capsim {name} " in help_text, name
    # choices are listed in the help (tests/test_registries.py: and they are the registries')
    # (issue 26 added the kind orbit: the longer list now wraps right after "inclination")
    assert "<deformation|inclination" in runner.invoke(app, ["plot", "-h"]).output
    assert "<xdmf|vtu>" in runner.invoke(app, ["export", "-h"]).output
    assert "<finest|richardson>" in runner.invoke(app, ["study", "-h"]).output


def test_an_existing_completed_run_is_not_overwritten_without_overwrite(tmp_path):
    from capsim.storage.store import read_run_status

    case = _tiny_case(tmp_path)
    out = tmp_path / "tiny0.h5"
    assert runner.invoke(app, ["run", str(case), "-q"]).exit_code == 0
    before = out.read_bytes()
    line = _one_line_exit_2(runner.invoke(app, ["run", str(case), "-q"]), "exists (a capsim run file)")
    assert "--overwrite" in line and "--resume" in line
    assert out.read_bytes() == before and read_run_status(out) == "completed"
    result = runner.invoke(app, ["run", str(case), "-q", "--overwrite", "--set", "time.t_end=0.03"])
    assert result.exit_code == 0, result.output
    assert read_run_status(out) == "completed" and out.read_bytes() != before


# ------------------------------------------------------------ campaign dry run


def _dry_run(result) -> dict[str, tuple[str, str]]:
    """run id -> (action, path) from `capsim validate CAMPAIGN.yaml`."""
    assert result.exit_code == 0, result.output
    rows = {}
    for line in result.stdout.splitlines()[1:]:
        run_id, rest = line.split("  ", 1)
        action, path = re.match(r"\s*(run|skip \(completed\))\s+(\S+)", rest).groups()
        rows[run_id.strip()] = (action, path)
    return rows


def test_campaign_dry_run_lists_exactly_the_runs_the_sweep_runs(tmp_path, monkeypatch):
    import json

    monkeypatch.chdir(tmp_path)
    campaign = tmp_path / "c.yaml"
    campaign.write_text(yaml.safe_dump({
        "name": "dry", "output": {"dir": str(tmp_path / "out")},
        "base": {"mesh": {"level": 0}, "time": {"t_end": 0.05}, "output": {"snapshot_every": 0.025}},
        "sweep": {"flow.shear_rate_G": [0.05, 0.1]}, "zip": {},
    }))
    sets = ["--set", "time.scheme=rkc"]
    listed = _dry_run(runner.invoke(app, ["validate", str(campaign), *sets]))
    assert len(listed) == 2 and {a for a, _ in listed.values()} == {"run"}
    assert not (tmp_path / "out").exists()  # a dry run writes nothing
    result = runner.invoke(app, ["sweep", str(campaign), "--workers", "1", *sets])
    assert result.exit_code == 0, result.output
    index = json.loads((tmp_path / "out" / "runs.json").read_text())
    ran = {run_id: entry for run_id, entry in index["runs"].items()} if "runs" in index else index
    assert set(ran) == set(listed)
    assert {str(Path(p).resolve()) for _, p in listed.values()} == \
        {str(p.resolve()) for p in (tmp_path / "out").glob("*.h5")}
    for run_id in listed:  # the sweep's closing table names every run it ran
        assert re.search(rf"^\s*{re.escape(run_id)}\s+completed", result.stdout, re.M), result.stdout
    again = _dry_run(runner.invoke(app, ["validate", str(campaign), *sets]))
    assert again == {k: ("skip (completed)", p) for k, (_, p) in listed.items()}
    # another --set is another campaign: other run ids, all to run
    other = _dry_run(runner.invoke(app, ["validate", str(campaign), "--set", "time.scheme=rkf23"]))
    assert set(other).isdisjoint(listed) and {a for a, _ in other.values()} == {"run"}
    _one_line_exit_2(runner.invoke(app, ["validate", str(campaign), "--set", "flow.shear_rate_G=0.2"]),
                     "the campaign sweeps this field")


def test_the_compression_warning_says_what_to_do_in_one_line():
    from capsim.face.display import _compression  # the closing table lives in display (issue 27)

    text = _compression({"compressed_fraction": 0.26, "min_tension": -0.31, "bending_modulus": 0.0})
    assert "\n" not in text and text.startswith("26 %")
    assert "--set membrane.bending_modulus=" in text
    page, section = re.search(r'(docs/\w+\.md),\s"(.+?)"', text).groups()  # the docs section it cites
    cited = (Path(__file__).resolve().parents[2] / page).read_text()
    assert re.search(rf"^## {re.escape(section)}$", cited, re.M)
    assert "would wrinkle" not in (_compression({"compressed_fraction": 0.01, "min_tension": -0.01}) or "")


def test_run_progress_shows_the_runs_own_wall_clock():
    """Elapsed = the run's wall_s (the closing table's clock, compilation included), advanced by
    the time since its last report; not the time since the first step (issue 29 item 5)."""
    clock = iter([100.0, 101.0, 101.5, 102.0])  # three reports, then finish()
    stream = io.StringIO()
    progress = RunProgress(stream, terminal=False, interval_s=1.0, clock=lambda: next(clock))
    progress({"t": 0.1, "dt": 1e-3, "D_xy": 0.01, "step": 1, "t_end": 0.3, "wall_s": 20.0})  # after compiling
    progress({"t": 0.2, "dt": 1e-3, "D_xy": 0.01, "step": 2, "t_end": 0.3, "wall_s": 21.0})
    progress({"t": 0.3, "dt": 1e-3, "D_xy": 0.01, "step": 3, "t_end": 0.3, "wall_s": 3723.0})
    progress.finish()
    lines = stream.getvalue().splitlines()
    assert "elapsed 0:00:21" in lines[0]            # not 0:00:01 (the time since the first step)
    assert "elapsed 1:02:04" in lines[-1]           # 3723 s + 0.5 s since the last report (finish at 102)

    live = io.StringIO()
    clock2 = iter([0.0] * 10)
    bar = RunProgress(live, terminal=True, interval_s=0.0, clock=lambda: next(clock2))
    bar({"t": 0.3, "dt": 1e-3, "D_xy": 0.01, "step": 3, "t_end": 0.3, "wall_s": 3725.0})
    bar.finish()
    assert "1:02:05" in ESCAPE.sub("", live.getvalue())


def test_the_last_progress_report_carries_the_closing_tables_wall_time(tmp_path):
    from capsim.api import run

    case = tmp_path / "case.yaml"
    case.write_text("name: tiny\nmesh: {level: 1}\nflow: {shear_rate_G: 0.1}\ntime: {t_end: 0.2}\n"
                    f"output: {{path: {tmp_path / 'tiny.h5'}}}\n")
    reports = []
    result = run(case, progress=reports.append)
    walls = [r["wall_s"] for r in reports]
    assert walls == sorted(walls) and walls[0] > 0
    # the closing table's wall time is the last report's, plus the closing writes only
    assert 0.0 <= result.wall_time_s - walls[-1] < 0.5
