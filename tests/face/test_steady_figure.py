"""The steady figure shows settled runs only as results (issue 30, finding 3)."""

import numpy as np
import pytest
import xarray as xr
from typer.testing import CliRunner

from capsim.face.cli import app
from capsim.face.plot import plot
from capsim.campaigns.summary import write_summary


def _grid(steady_average):
    """A 2 × 2 G × λ summary with window stds; steady_average as given."""
    G, lam = np.array([0.05, 0.1]), np.array([1.0, 5.0])
    dims = ("shear_rate_G", "viscosity_ratio")
    D = np.array([[0.30, 0.28], [0.55, 0.5]])
    return xr.Dataset(
        {"D_xy": (dims, D), "theta": (dims, np.full(D.shape, 0.7)), "D_xy_std": (dims, np.full(D.shape, 0.02)),
         "theta_std": (dims, np.full(D.shape, 0.01)), "steady_average": (dims, np.asarray(steady_average, np.int8)),
         "status": (dims, np.full(D.shape, "completed", dtype=object)),
         "motion": (dims, np.full(D.shape, "transient", dtype=object))},
        coords={"shear_rate_G": G, "viscosity_ratio": lam},
    )


def _data_lines(ax):
    return [line for line in ax.get_lines() if line.get_label().startswith("λ")]


def test_transient_runs_are_no_curve_and_the_figure_says_so():
    fig = plot(_grid([[0, 0], [0, 0]]), "steady")
    assert _data_lines(fig.axes[0]) == []  # no curve through transient values
    crosses = [line for line in fig.axes[0].get_lines() if line.get_label().startswith("not settled")]
    assert len(crosses) == 1 and len(crosses[0].get_xdata()) == 4
    assert "4 of 4 runs not settled (4 transient motion)" in fig.steady_note
    assert fig.steady_note in fig.caption and fig._supxlabel.get_text().replace("\n", " ").endswith(fig.steady_note)


def test_settled_runs_carry_the_window_spread_as_error_bars():
    fig = plot(_grid([[1, 1], [1, 0]]), "steady")
    lines = {line.get_label(): line for line in _data_lines(fig.axes[0])}
    assert list(lines["λ = 1"].get_xdata()) == [0.05, 0.1] and list(lines["λ = 5"].get_xdata()) == [0.05]
    bars = [c for c in fig.axes[0].collections if c.get_segments()]
    spans = sorted(float(seg[1][1] - seg[0][1]) for c in bars for seg in c.get_segments())
    assert spans == pytest.approx([0.04] * 3)  # ± D_xy_std = 0.02 on the three settled runs
    assert "1 of 4 runs not settled" in fig.steady_note


def test_a_lambda_only_and_a_zip_campaign_plot_against_their_field(tmp_path):
    lam_only = _grid([[1, 1], [1, 1]]).isel(shear_rate_G=0, drop=True)
    fig = plot(lam_only, "steady")
    assert fig.axes[1].get_xlabel() == r"viscosity ratio $\lambda$"
    zipped = xr.Dataset(
        {"D_xy": ("run", [0.1, 0.2, 0.3]), "theta": ("run", [0.7, 0.6, 0.5]), "steady_average": ("run", [1, 1, 0])},
        coords={"run": ["a", "b", "c"], "viscosity_ratio": ("run", [0.2, 1.0, 5.0]),
                "initial_tilt_deg": ("run", [0.0, 10.0, 20.0])},
    )
    fig = plot(zipped, "steady", x="initial_tilt_deg")
    assert fig.axes[1].get_xlabel() == "initial tilt (deg)"
    with pytest.raises(ValueError, match=r"--x 'level': not a numeric swept field .*allowed: viscosity_ratio, initial_tilt_deg"):
        plot(zipped, "steady", x="level")
    path = write_summary(_grid([[1, 1], [1, 1]]), tmp_path / "s.nc")
    result = CliRunner().invoke(app, ["plot", str(path), "--kind", "steady", "--x", "nope", "-o", str(tmp_path / "s.png")])
    assert result.exit_code == 2 and len(result.stderr.strip().splitlines()) == 1
    assert "--x 'nope': not a numeric swept field of the summary (allowed: shear_rate_G, viscosity_ratio)" in result.stderr


# ---------------------------------------------------------------- periodic runs (issue 30, noticed)


def test_a_periodic_run_is_settled_with_its_half_amplitude_as_error_bar():
    """A swinging (oscillating) run at G = 0.1, λ = 5: its point is open, its error bar the
    half peak-to-peak of the last cycle (0.05), not the window std (0.02); a tumbling run at
    G = 0.1, λ = 1 has a D_xy point (± its half-amplitude 0.08) and no θ point."""
    ds = _grid([[1, 1], [1, 1]])
    dims = ("shear_rate_G", "viscosity_ratio")
    ds["motion"] = (dims, np.array([["steady", "steady"], ["tumbling", "oscillating"]], dtype=object))
    ds["D_xy_amplitude"] = (dims, np.array([[np.nan, np.nan], [0.08, 0.05]]))
    ds["theta_amplitude"] = (dims, np.array([[np.nan, np.nan], [np.nan, 0.1]]))
    ds["theta"] = ds["theta"].where(ds["motion"] != "tumbling")  # as the summary writes it
    fig = plot(ds, "steady")
    bars = [c for c in fig.axes[0].collections if c.get_segments()]
    spans = sorted(round(float(seg[1][1] - seg[0][1]), 12) for c in bars for seg in c.get_segments())
    assert spans == pytest.approx([0.04, 0.04, 0.1, 0.16])  # steady ± 0.02; swinging ± 0.05; tumbling ± 0.08
    open_points = [line for line in fig.axes[0].get_lines() if line.get_markerfacecolor() == "white"]
    assert sorted(float(x) for line in open_points for x in line.get_xdata()) == [0.1, 0.1]
    theta_bars = [c for c in fig.axes[1].collections if c.get_segments()]
    theta_spans = sorted(round(float(seg[1][1] - seg[0][1]), 12) for c in theta_bars for seg in c.get_segments()
                         if len(seg) == 2)
    # θ/π: steady ± 0.01/π, swinging ± 0.1/π; the tumbling run's NaN θ draws no bar
    assert theta_spans == pytest.approx(sorted([0.02 / np.pi] * 2 + [0.2 / np.pi]))
    theta_points = [y for line in _data_lines(fig.axes[1]) for x, y in zip(line.get_xdata(), line.get_ydata())
                    if x == 0.1 and np.isfinite(y)]
    assert theta_points and all(y == pytest.approx(0.7 / np.pi) for y in theta_points)  # only the swinging run
    assert "open points: periodic runs" in fig.steady_note and "half the peak-to-peak" in fig.steady_note


def test_the_summary_gives_a_tumbling_run_no_mean_theta(monkeypatch):
    import capsim.campaigns.summary as summary

    def fake(path):
        return {"attrs": {"status": "completed"}, "n_steps": 10, "first": {}, "last": {}, "run": {},
                "summary": {"motion": path, "D_xy": 0.3, "theta": 0.2, "theta_std": 0.9, "D_xy_amplitude": 0.08}}

    monkeypatch.setattr(summary, "read_run_record", fake)
    tumbling, swinging = summary.read_run("tumbling"), summary.read_run("oscillating")
    assert tumbling["steady_average"] == 1 and swinging["steady_average"] == 1  # settled, as a cycle
    assert np.isnan(tumbling["theta"]) and np.isnan(tumbling["theta_std"])  # its long axis turns round
    assert tumbling["D_xy"] == 0.3 and tumbling["D_xy_amplitude"] == 0.08
    assert swinging["theta"] == 0.2  # a swinging run has a mean inclination


def test_a_campaign_where_every_run_tumbles_says_so_in_the_theta_panel():
    """No run has a mean θ (all tumble: the red cells of campaigns/rbc-shear-rates.yaml): the
    θ panel carries a sentence instead of an empty frame with meaningless ticks."""
    ds = _grid([[1, 1], [1, 1]])
    dims = ("shear_rate_G", "viscosity_ratio")
    ds["motion"] = (dims, np.full((2, 2), "tumbling", dtype=object))
    ds["D_xy_amplitude"] = (dims, np.full((2, 2), 0.08))
    ds["theta"] = ds["theta"].where(ds["motion"] != "tumbling")
    fig = plot(ds, "steady")
    theta_ax = fig.axes[1]
    texts = [t.get_text() for t in theta_ax.texts]
    assert any("every run tumbles" in t for t in texts), texts
    assert list(theta_ax.get_yticks()) == []
    # with one mean θ the panel draws it and says nothing of the kind
    ds["theta"] = ds["theta"].where(ds["motion"] != "tumbling", 0.7)
    fig = plot(ds, "steady")
    assert not any("every run tumbles" in t.get_text() for t in fig.axes[1].texts)


def test_settled_points_carry_their_motion_class():
    """Issue 39: a settled point's marker names its class (a steady one keeps its group's
    circle), open where it is a cycle, and the legend says what each marker is; an old
    summary's `oscillating` is drawn as swinging."""
    ds = _grid([[1, 1], [1, 1]])
    dims = ("shear_rate_G", "viscosity_ratio")
    ds["motion"] = (dims, np.array([["steady", "rolling"], ["oscillating", "kayaking"]], dtype=object))
    fig = plot(ds, "steady")
    ax = fig.axes[0]
    marked = {(line.get_marker(), line.get_markerfacecolor() == "white"): list(line.get_xdata())
              for line in ax.get_lines() if line.get_linestyle() == "None" and len(line.get_xdata())}
    assert marked[("v", False)] == [0.05]  # rolling: a state, filled
    assert marked[("s", True)] == [0.1] and marked[("D", True)] == [0.1]  # swinging, kayaking: cycles, open
    labels = ax.get_legend_handles_labels()[1]
    assert {"rolling", "swinging (mean over whole periods)", "kayaking (mean over whole periods)"} <= set(labels)


# ---------------------------------------------------------------- per flow kind (issue 52)


def _campaign_summary(kind_base: dict, sweep: dict) -> xr.Dataset:
    """A 2-run G sweep summary of the campaign `kind_base` (stored as `capsim summarize` does), with
    what a run in planar extension measures: θ and S*_xy 0 by symmetry, no tank-treading."""
    import yaml

    G = np.array([0.005, 0.01])
    dims = ("shear_rate_G",)
    ds = xr.Dataset(
        {"D_xy": (dims, 25 / 2 * G), "theta": (dims, np.zeros(2)), "steady_average": (dims, np.ones(2, np.int8)),
         "ttf_ratio": (dims, np.full(2, np.nan)), "Sxy_star": (dims, np.zeros(2)),
         "N1_star": (dims, 30 * G), "N2_star": (dims, -15 * G)},
        coords={"shear_rate_G": G},
    )
    ds.attrs["campaign_yaml"] = yaml.safe_dump({"name": "c", "base": kind_base, "sweep": sweep})
    return ds


def _panels(fig) -> list[str]:
    return [ax.get_ylabel() for ax in fig.axes]


def _theory(ax) -> dict[str, np.ndarray]:
    return {line.get_label(): np.asarray(line.get_ydata()) for line in ax.get_lines()
            if line.get_label().startswith("first order")}


def test_the_steady_figure_of_planar_extension_has_its_own_panels_and_line():
    """Planar extension: θ is 0 and S*_xy vanishes by the flow's symmetry and no membrane tank-treads
    as in shear: no θ panel (the old tree drew a panel of zeros), no TTF panel (an empty frame),
    S*_xy not drawn; D_xy against G with the first-order 25G/2, not the shear's 25G/4."""
    ds = _campaign_summary({"flow": {"kind": "planar_extension"}}, {"flow.shear_rate_G": [0.005, 0.01]})
    fig = plot(ds, "steady")
    assert _panels(fig) == [r"$D_{xy}$", r"$N_1^*$, $N_2^*$"]
    lines = _theory(fig.axes[0])
    assert list(lines) == ["first order, $25G/2$ (Barthès-Biesel & Rallison 1981, pure strain)"]
    g = np.asarray(next(line for line in fig.axes[0].get_lines() if line.get_label().startswith("first")).get_xdata())
    assert np.allclose(lines[next(iter(lines))], 12.5 * g)
    assert not any("S^*_{xy}" in label for label in fig.axes[1].get_legend_handles_labels()[1])
    assert fig.axes[-1].get_xlabel()  # the bottom panel names the swept field


def test_the_steady_figure_draws_no_line_where_no_theory_is_derived():
    """Pre-inflated capsules in shear (Lac et al.'s 5 %): the panels of shear, no first-order line
    (25G/4 is ~35 % off a pre-stretched membrane); a Poiseuille flow: D_xy and θ only, no line."""
    fig = plot(_campaign_summary({"shape": {"inflation": 0.05}}, {"flow.G": [0.005, 0.01]}), "steady")
    assert len(fig.axes) == 4 and all(_theory(ax) == {} for ax in fig.axes)
    ds = _campaign_summary({"flow": {"kind": "poiseuille", "poiseuille_radius": 5.0},
                            "initial_center": [0.0, 1.0, 0.0]}, {"flow.G": [0.005, 0.01]})
    fig = plot(ds, "steady")
    assert _panels(fig) == [r"$D_{xy}$", r"$\theta/\pi$"] and all(_theory(ax) == {} for ax in fig.axes)


def test_the_steady_figure_of_simple_shear_is_as_it_was():
    fig = plot(_campaign_summary({}, {"flow.G": [0.005, 0.01]}), "steady")
    assert _panels(fig) == [r"$D_{xy}$", r"TTF $/ f_s$", r"$\theta/\pi$", r"$S^*_{xy}$, $N_1^*$, $N_2^*$"]
    assert list(_theory(fig.axes[0])) == ["first order, $25G/4$ (Barthès-Biesel & Rallison 1981)"]
