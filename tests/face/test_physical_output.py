"""Issue 30: `--units physical` for the outputs (closing table, summary, figures, export).

Hand values, for a red cell of radius a = 2.8 µm in plasma μ = 1.2 mPa s, shear modulus
G_s = 6 µN/m (E_s = 3 G_s = 18 µN/m), sheared at k = 50 1/s:

- time unit 1/k = 1/50 s = 0.02 s; a length of 1 a = 2.8 µm;
- tension unit μka = 1.2e-3 × 50 × 2.8e-6 = 1.68e-7 N/m = 0.168 µN/m; E_s = 18 µN/m;
- stresslet unit (5/2) μ k V, V = (4π/3) a³: 2.5 × 1.2e-3 × 50 × 4.18879 × 2.1952e-17 m³
  = 1.37928e-17 N m = 13.7928 pN µm;
- tank-treading frequency unit f_s = k/(4π) = 3.97887 Hz (revolutions per second);
- velocity unit ka = 1.4e-4 m/s = 140 µm/s; traction unit E_s/a = 18e-6/2.8e-6 = 6.42857 Pa.

Every physical unit comes from capsim.quantities (SCALE_UNITS), never spelled in a writer.
"""

import math
import xml.etree.ElementTree as ET

import h5py
import numpy as np
import pytest
import xarray as xr
from typer.testing import CliRunner

from capsim.campaigns.campaign import campaign_from_dict, run_campaign
from capsim.face.cli import app
from capsim.config import case_from_dict
from capsim.face.display import summary_rows
from capsim.quantities import SCALE_UNITS, physical_attrs, physical_units
from capsim.runs.runner import run_case
from capsim.storage.store import read_trajectory
from capsim.campaigns.summary import summarize_campaign, write_summary
from capsim.units import physical_factors

PHYSICAL = {"shear_rate": "50 1/s", "viscosity": "1.2 mPa*s", "radius": "2.8 um", "shear_modulus": "6 uN/m"}
STRESSLET = 2.5 * 1.2e-3 * 50 * (4.0 / 3.0 * math.pi * 2.8e-6**3)  # N m
HAND = {  # the factor from capsim's scale to the unit shown, by hand (module docstring)
    "1/k": 0.02, "a": 2.8, "mu k a": 1.2e-3 * 50 * 2.8e-6 * 1e6, "E_s": 18.0, "5/2 mu k V": STRESSLET * 1e18,
    "k/(4 pi)": 50 / (4 * math.pi), "a k": 2.8e-6 * 50 * 1e6, "E_s/a": 18e-6 / 2.8e-6,
    "E_s a^2": 18e-6 * 2.8e-6**2, "a^2": 2.8**2, "a^3": 2.8**3, "mu": 1.2, "mu k^2 a^3": 1.2e-3 * 50**2 * 2.8e-6**3 * 1e15,
}
runner = CliRunner()


def test_factors_equal_the_hand_values():
    factors = physical_factors(PHYSICAL)
    assert set(factors) == set(SCALE_UNITS) == set(HAND)
    for scale, value in HAND.items():
        assert factors[scale] == pytest.approx(value, rel=1e-12), scale
    assert HAND["5/2 mu k V"] == pytest.approx(13.7928, rel=1e-5)
    # the unit each quantity is shown in is its scale's, from the one table
    assert physical_units("t") == ("s", "1/k") and physical_units("period") == ("s", "1/k")
    assert physical_units("ttf_ratio") == ("Hz", "k/(4 pi)") and physical_units("Sxy_star")[0] == "pN*um"
    assert physical_units("min_tension") == ("uN/m", "mu k a") and physical_units("D_xy") == ("1", "")
    attrs = physical_attrs("Sxy_star")
    assert attrs["units"] == "pN*um" and "scale" not in attrs and attrs["long_name"] == "particle stresslet S_xy"


def _case(tmp, name="rbc", physical=True, **extra):
    data = {"name": name, "shape": {"kind": "biconcave"}, "membrane": {"law": "skalak"},
            "flow": {"viscosity_ratio": 5.0}, "mesh": {"level": 0}, "time": {"t_end": 0.05},
            "output": {"path": str(tmp / f"{name}.h5"), "snapshot_every": 0.025}, **extra}
    if physical:
        data["physical"] = dict(PHYSICAL)
    else:
        data["flow"]["shear_rate_G"] = 0.01
    return case_from_dict(data)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("physical")
    rbc, plain = _case(tmp), _case(tmp, "plain", physical=False)
    assert rbc.flow.shear_rate_G == pytest.approx(1.2e-3 * 50 * 2.8e-6 / 18e-6, rel=1e-12)
    return {"tmp": tmp, "rbc": rbc, "summary": run_case(rbc), "plain": run_case(plain), "plain_path": tmp / "plain.h5"}


def test_closing_table_in_physical_units(runs):
    summary = dict(runs["summary"])
    capsim_rows = dict(summary_rows(summary))
    rows = dict(summary_rows(summary, physical_factors(PHYSICAL)))
    assert float(rows["t (s)"]) == pytest.approx(summary["t"] * 0.02, rel=1e-5)
    assert float(capsim_rows["t"]) == pytest.approx(summary["t"], rel=1e-5)
    sxy = float(rows["S_xy (pN*um)"].split(" ± ")[0])
    assert sxy == pytest.approx(summary["Sxy_star"] * HAND["5/2 mu k V"], rel=1e-5)
    f = float(rows["TTF f (Hz)"].split(" ± ")[0])
    assert f == pytest.approx(summary["ttf_ratio"] * 50 / (4 * math.pi), rel=1e-5)
    assert rows["D_xy"] == capsim_rows["D_xy"] and rows["theta/pi"] == capsim_rows["theta/pi"]  # ratios
    assert "uN/m" in rows["compressed vertices"]
    low = float(rows["compressed vertices"].split("smallest tension ")[1].split()[0])
    assert low == pytest.approx(summary["min_tension"] * HAND["mu k a"], rel=2e-3)  # 3 digits shown


def test_figures_in_physical_units(runs):
    from capsim.face.export import membrane_fields, model_for
    from capsim.face.plot import plot

    path = runs["rbc"].output.path
    data = read_trajectory(path)
    t_end = float(data["timeseries"]["t"][-1])
    fig = plot(path, "deformation", units="physical")
    ax = fig.axes[0]
    assert ax.get_xlabel() == "$t$ (s)"
    assert float(np.nanmax(ax.get_lines()[0].get_xdata())) == pytest.approx(t_end * 0.02, rel=1e-12)
    fig = plot(path, "contour", units="physical")
    ax = fig.axes[0]
    assert ax.get_xlabel() == "$x$ (µm)" and ax.get_ylabel() == "$y$ (µm)"
    assert float(np.max(ax.get_lines()[0].get_xdata())) == pytest.approx(
        2.8 * float(np.max(plot(path, "contour").axes[0].get_lines()[0].get_xdata())), rel=1e-12)
    assert ax.get_legend().get_texts()[0].get_text() == "t = 0 s"
    fig = plot(path, "tensions", units="physical")
    ax = fig.axes[0]
    assert ax.get_ylabel() == "principal tension (µN/m)"
    capsim_tau1 = plot(path, "tensions").axes[0].get_lines()[0].get_ydata()  # in E_s
    np.testing.assert_allclose(ax.get_lines()[0].get_ydata(), 18.0 * capsim_tau1, rtol=1e-12)  # E_s = 18 µN/m
    x = np.asarray(data["positions"][-1], float)
    tau1 = membrane_fields(model_for(data), x)["principal_tension_1"]
    assert float(np.max(capsim_tau1)) <= float(tau1.max()) * (1 + 1e-9)  # the section's are the vertices' in E_s
    assert "t = 0.001 s" in fig.caption  # kt = 0.05 × 0.02 s
    fig = plot(path, "rheology", units="physical")
    assert fig.axes[0].get_ylabel().endswith("(pN µm)")
    sxy = np.asarray(data["timeseries"]["Sxy_star"], float)
    np.testing.assert_allclose(fig.axes[0].get_lines()[0].get_ydata(), sxy * HAND["5/2 mu k V"], rtol=1e-12)


def test_export_in_physical_units(runs, tmp_path):
    from capsim.face.export import export_run

    path = runs["rbc"].output.path
    files = export_run(path, tmp_path / "phys", "xdmf", units="physical")
    plain = export_run(path, tmp_path / "plain", "xdmf")
    root = ET.parse(files[0]).getroot()
    info = {i.get("Name"): i.get("Value") for i in root.iter("Information")}
    assert info["units_time"] == "s" and info["units_geometry"] == "um"
    assert info["units_velocity"] == "um/s" and info["units_traction"] == "Pa" and info["units_tension"] == "uN/m"
    assert info["units_principal_stretch_1"] == "1"
    assert {a.get("Name") for a in root.iter("Attribute")} <= {n[len("units_"):] for n in info}
    import meshio

    with meshio.xdmf.TimeSeriesReader(files[0]) as reader:  # ParaView's readers take it as before
        reader.read_points_cells()
        assert reader.num_steps == len(list(root.iter("Time")))
        t, point_data, _ = reader.read_data(reader.num_steps - 1)
        assert set(point_data) >= {"displacement", "velocity", "tension"}
    times = [float(t.get("Value")) for t in root.iter("Time")]
    plain_times = [float(t.get("Value")) for t in ET.parse(plain[0]).getroot().iter("Time")]
    np.testing.assert_allclose(times, np.asarray(plain_times) * 0.02, rtol=1e-12)
    with h5py.File(files[1]) as phys, h5py.File(plain[1]) as ref:
        np.testing.assert_allclose(phys["geometry/1"][()], 2.8 * ref["geometry/1"][()], rtol=1e-12)
        np.testing.assert_allclose(phys["node/velocity/1"][()], 140.0 * ref["node/velocity/1"][()], rtol=1e-12)
        np.testing.assert_allclose(phys["cell/traction/1"][()], HAND["E_s/a"] * ref["cell/traction/1"][()], rtol=1e-12)


@pytest.fixture(scope="module")
def physical_sweep(tmp_path_factory):
    """Two shear rates of the red cell: the factors differ between the runs."""
    tmp = tmp_path_factory.mktemp("sweep")
    base = {"shape": {"kind": "biconcave"}, "membrane": {"law": "skalak"}, "mesh": {"level": 0},
            "time": {"t_end": 0.02}, "physical": {**PHYSICAL, "bending_modulus": "1.8e-19 J"}}
    campaign = campaign_from_dict({"name": "phys", "base": base, "sweep": {"physical.shear_rate": ["50 1/s", "100 1/s"]},
                                   "output": {"dir": str(tmp / "phys")}})
    result = run_campaign(campaign, workers=1)
    assert result["completed"] == result["total"] == 2, result
    return tmp


def test_summary_in_physical_units_is_cf_clean(physical_sweep, tmp_path):
    from cf_checks import cf_counts as _cf_counts

    plain = summarize_campaign(physical_sweep / "phys")
    ds = summarize_campaign(physical_sweep / "phys", units="physical")
    k = np.array([50.0, 100.0])
    np.testing.assert_allclose(ds["shear_rate"].values, k)
    np.testing.assert_allclose(ds["averaging_t_from"].values, plain["averaging_t_from"].values / k, rtol=1e-12)
    assert ds["averaging_t_from"].attrs["units"] == "s" and "scale" not in ds["averaging_t_from"].attrs
    tension = 1.2e-3 * k * 2.8e-6 * 1e6  # μka in µN/m, per run
    np.testing.assert_allclose(ds["min_tension"].values, plain["min_tension"].values * tension, rtol=1e-12)
    stresslet = STRESSLET * 1e18 * k / 50
    np.testing.assert_allclose(ds["Sxy_star"].values, plain["Sxy_star"].values * stresslet, rtol=1e-12)
    assert ds["Sxy_star"].attrs["units"] == "pN*um"
    np.testing.assert_allclose(ds["bending_modulus"].values, 1.8e-19, rtol=1e-12)  # κ back in J
    np.testing.assert_array_equal(ds["D_xy"].values, plain["D_xy"].values)  # a ratio either way
    assert "capsim_units" in ds.attrs
    path = write_summary(ds, tmp_path / "phys.nc")
    counts = _cf_counts(path, tmp_path)
    assert counts["FATAL"] == 0 and counts["ERROR"] == 0 and counts["WARN"] == 0, counts


def _one_line_exit_2(result, *words):
    assert result.exit_code == 2, result.output
    line = result.stderr.strip()
    assert "\n" not in line and line.startswith("error: "), result.stderr
    for word in words:
        assert word in line, line
    return line


def test_units_physical_without_a_physical_block_is_one_line_exit_2(runs, tmp_path):
    plain = str(runs["plain_path"])
    need = ("--units physical", "no physical block", "--units capsim")
    _one_line_exit_2(runner.invoke(app, ["plot", plain, "--kind", "deformation", "--units", "physical",
                                         "-o", str(tmp_path / "d.png")]), *need)
    _one_line_exit_2(runner.invoke(app, ["export", plain, "--units", "physical", "-o", str(tmp_path / "x")]), *need)
    case = tmp_path / "plain.yaml"
    case.write_text("name: plain\nmesh: {level: 0}\ntime: {t_end: 0.01}\n"
                    f"output: {{path: {tmp_path / 'never.h5'}}}\n")
    _one_line_exit_2(runner.invoke(app, ["run", str(case), "--units", "physical", "-q"]), *need)
    assert not (tmp_path / "never.h5").exists()  # refused before the run
    for command in (["run", str(case)], ["plot", plain, "--kind", "contour"], ["export", plain],
                    ["summarize", str(tmp_path)]):
        _one_line_exit_2(runner.invoke(app, command + ["--units", "si"]), "--units", "'si'", "capsim", "physical")


def test_summarize_units_physical_of_a_campaign_without_physical_block(tmp_path):
    campaign = campaign_from_dict({"name": "g", "base": {"mesh": {"level": 0}, "time": {"t_end": 0.01}},
                                   "sweep": {"flow.shear_rate_G": [0.05]}, "output": {"dir": str(tmp_path / "g")}})
    run_campaign(campaign, workers=1)
    _one_line_exit_2(runner.invoke(app, ["summarize", str(tmp_path / "g"), "--units", "physical"]),
                     "--units physical", "no physical block")
    assert not (tmp_path / "g" / "summary.nc").exists()


def test_steady_figure_refuses_physical_units(tmp_path):
    ds = xr.Dataset({"D_xy": ("shear_rate_G", [0.1, 0.2]), "theta": ("shear_rate_G", [0.7, 0.6])},
                    coords={"shear_rate_G": [0.05, 0.1]})
    path = write_summary(ds, tmp_path / "s.nc")
    _one_line_exit_2(runner.invoke(app, ["plot", str(path), "--kind", "steady", "--units", "physical",
                                         "-o", str(tmp_path / "s.png")]), "--units physical", "--kind steady")


def test_the_cli_choices_are_the_unit_systems():
    from capsim.face import cli
    from capsim.quantities import UNIT_SYSTEMS

    assert cli._UNIT_SYSTEMS == UNIT_SYSTEMS


def test_run_prints_its_closing_table_in_physical_units(tmp_path):
    case = tmp_path / "cell.yaml"
    case.write_text("name: cell\nmesh: {level: 0}\ntime: {t_end: 0.01}\n"
                    "physical: {shear_rate: 50 1/s, viscosity: 1.2 mPa*s, radius: 2.8 um, shear_modulus: 6 uN/m}\n"
                    f"output: {{path: {tmp_path / 'cell.h5'}}}\n")
    result = runner.invoke(app, ["run", str(case), "--units", "physical", "-q"])
    assert result.exit_code == 0, result.output
    rows = {line.split("  ")[0].strip(): line for line in result.stdout.splitlines() if line.strip()}
    assert "t (s)" in rows and rows["t (s)"].split()[-1] == "0.0002"  # kt = 0.01 × 0.02 s
    assert "S_xy (pN*um)" in rows and "TTF f (Hz)" in rows and "kt" not in result.stdout.split("wall time")[0]


def test_the_compression_line_gives_the_bending_modulus_in_its_units():
    """One convention per screen: next to a tension in µN/m the bending modulus is in J
    (κ = 3e-3 E_s a², E_s = 18 µN/m, a = 2.8 µm: 4.23e-19 J by hand), and in capsim's
    scales it names E_s a²."""
    from capsim.face.display import _compression

    summary = {"compressed_fraction": 0.5, "min_tension": -0.1, "shear_rate_G": 0.05, "bending_modulus": 3e-3}
    physical = _compression(summary, physical_factors(PHYSICAL))
    assert f"{3e-3 * 18e-6 * 2.8e-6**2:.3g} J" == "4.23e-19 J" and "held by the bending modulus 4.23e-19 J" in physical
    assert "held by the bending modulus 0.003 E_s a²" in _compression(summary)
