"""Issue 16: results people can open and cite.

- run files are netCDF-4 that xarray opens as they are (a short real run, a killed
  writer, a resumed one: the same D_xy(t) as the h5py reader), ``capsim.open_run``;
- the campaign summary opens with one dimension per swept field and carries each
  run's context (period, amplitudes, window, mesh, law, scheme, intrinsic viscosity,
  ``steady_average``);
- cfchecker finds no errors on a run file (and each of its groups), a grid and a zip
  sweep summary and a study file (skipped, with the reason, where cfchecker or the
  system's libudunits2 is missing: ``make cf-tools`` installs both);
- an oscillating run's period and amplitudes match its time series; a transient run is marked.

The physical-units side (``capsim units``, ``physical:``, configs/rbc.yaml) is in
tests/test_units.py.
"""

import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

import capsim
from capsim.campaigns.campaign import campaign_from_dict, run_campaign
from capsim.config import apply_overrides, case_from_dict, load_case
from capsim.quantities import CONVENTIONS, FLAGS
from capsim.runs.runner import run_case
from capsim.storage.store import TrajectoryWriter, read_trajectory
from capsim.campaigns.study import run_study, write_study
from capsim.campaigns.summary import read_run, summarize_campaign, write_summary
from cf_checks import cf_counts as _cf_counts

ROOT = Path(__file__).resolve().parents[2]


def _xr_dxy(path):
    with xr.open_dataset(path, group="timeseries", engine="h5netcdf") as ds:
        return np.asarray(ds["t"].values), np.asarray(ds["D_xy"].values)


def _same_as_h5py(path):
    """xarray (h5netcdf, as the file is) and capsim.open_run give read_trajectory's D_xy(t)."""
    want = read_trajectory(path)["timeseries"]
    t, dxy = _xr_dxy(path)
    np.testing.assert_array_equal(t, want["t"])
    np.testing.assert_array_equal(dxy, want["D_xy"])
    tree = capsim.open_run(path)
    np.testing.assert_array_equal(tree["timeseries"]["D_xy"].values, want["D_xy"])
    np.testing.assert_array_equal(tree["timeseries"]["t"].values, want["t"])
    assert tree["timeseries"]["D_xy"].dims == ("t",)
    return tree


# ---------------------------------------------------------------- a short real run (the RBC preset)


@pytest.fixture(scope="module")
def rbc_run(tmp_path_factory):
    """configs/rbc.yaml at level 1 for kt = 0.05: the preset runs, and the file is read back."""
    tmp = tmp_path_factory.mktemp("rbc")
    case = apply_overrides(load_case(ROOT / "configs" / "rbc.yaml"), **{
        "mesh.level": 1, "time.t_end": 0.05, "output.path": str(tmp / "rbc.h5"), "output.snapshot_every": 0.025})
    return case, run_case(case)


def test_short_run_opens_with_xarray_as_it_is(rbc_run):
    case, result = rbc_run
    path = case.output.path
    assert result.status == "completed"
    tree = _same_as_h5py(path)
    mesh = xr.open_dataset(path, group="mesh", engine="h5netcdf")
    assert mesh["positions"].dims == ("snapshot_t", "node", "xyz")
    assert mesh["elements"].dims == ("element", "element_node")
    assert mesh.sizes["snapshot_t"] == 3 and mesh.sizes["xyz"] == 3
    for name in ("node", "element", "element_node", "xyz", "snapshot_t"):
        assert mesh[name].attrs["long_name"], name  # every coordinate has its attributes
    summary = xr.open_dataset(path, group="summary", engine="h5netcdf")
    assert summary["motion"].item() == result["motion"]
    assert summary["D_xy"].attrs["long_name"] == tree["summary"]["D_xy"].attrs["long_name"]
    root = tree.attrs
    assert root["Conventions"] == CONVENTIONS and "1/k" in root["capsim_scales"]
    assert tree["membrane_law"]["name"].item() == "skalak"
    # the preset: Skalak, λ = 5, bending, biconcave; G from its physical block
    assert case.membrane.law == "skalak" and case.flow.viscosity_ratio == 5.0
    assert case.membrane.bending_modulus > 0 and case.shape.kind == "biconcave"
    assert case.physical is not None and case.flow.shear_rate_G == pytest.approx(1.2e-3 * 100 * 2.8e-6 / 7.5e-6)


def test_a_transient_run_is_marked(rbc_run):
    case, result = rbc_run
    assert result["motion"] == "transient"
    record = read_run(case.output.path)
    assert record["motion"] == "transient" and record["steady_average"] == 0
    assert record["law"] == "skalak" and record["level"] == 1 and record["skalak_c"] == 10.0
    assert record["time_scheme"] == FLAGS["time_scheme"].index("rkc")
    assert record["intrinsic_viscosity"] == pytest.approx(2.5 * record["Sxy_star"])


# ---------------------------------------------------------------- killed and resumed files

_KILLED = textwrap.dedent(
    """
    import sys, time
    import numpy as np
    import capsim.storage.store as store
    from capsim.storage.store import TrajectoryWriter
    store._FLUSH_INTERVAL_S = 0.0  # the rows flushed every _STEP_FLUSH_EVERY steps, however fast they come
    w = TrajectoryWriter(sys.argv[1], config_yaml="name: x\\n", elements=np.zeros((8, 6), int),
                         rest_positions=np.zeros((18, 3)), version="0")
    w.append_snapshot(0.0, np.ones((18, 3)))
    for i in range(47):  # flushed after rows 20 and 40
        w.append_step({"t": 0.1 * i, "D_xy": 0.01 * i, "theta": 0.5})
    print("ready", flush=True)
    time.sleep(60)
    """
)


def test_killed_and_resumed_files_open_with_xarray(tmp_path):
    path = tmp_path / "killed.h5"
    proc = subprocess.Popen([sys.executable, "-c", _KILLED, str(path)], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "ready"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        proc.stdout.close()
    tree = _same_as_h5py(path)  # flushed rows only, still labelled
    assert tree.attrs["status"] == "running"
    n = tree["timeseries"].sizes["t"]
    assert 40 <= n <= 47

    with TrajectoryWriter.reopen(path, n_steps=n - 5, n_snapshots=1) as w:  # back to a checkpoint, on to the end
        for i in range(n - 5, 60):
            w.append_step({"t": 0.1 * i, "D_xy": 0.01 * i, "theta": 0.5})
        w.append_snapshot(5.9, np.full((18, 3), 2.0))
    tree = _same_as_h5py(path)
    assert tree.attrs["status"] == "completed" and tree["timeseries"].sizes["t"] == 60
    np.testing.assert_allclose(tree["timeseries"]["D_xy"].values, 0.01 * np.arange(60))
    mesh = xr.open_dataset(path, group="mesh", engine="h5netcdf")
    assert mesh.sizes["snapshot_t"] == 2 and mesh["positions"].dims == ("snapshot_t", "node", "xyz")


# ---------------------------------------------------------------- campaign summaries and a study


def _campaign(tmp, kind):
    base = {"shape": {"kind": "prolate", "aspect_ratio": 1.2}, "mesh": {"level": 0}, "time": {"t_end": 0.02}}
    if kind == "grid":
        sweep = {"sweep": {"flow.shear_rate_G": [0.05, 0.1], "flow.viscosity_ratio": [1.0, 2.0]}}
    else:
        sweep = {"sweep": {}, "zip": {"flow.shear_rate_G": [0.05, 0.1], "membrane.law": ["skalak", "neo_hookean"]}}
    campaign = campaign_from_dict({"name": kind, "base": base, **sweep, "output": {"dir": str(tmp / kind)}})
    result = run_campaign(campaign, workers=1)
    assert result["completed"] == result["total"], result
    return write_summary(summarize_campaign(tmp / kind), tmp / f"{kind}.nc")


@pytest.fixture(scope="module")
def netcdf_files(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("cf")
    grid, zipped = _campaign(tmp, "grid"), _campaign(tmp, "zip")
    case = case_from_dict({"name": "s", "mesh": {"level": 0}, "time": {"t_end": 0.02},
                           "output": {"path": str(tmp / "unused.h5")}})
    study = write_study(run_study(case, levels=[0, 1], rtols=[1e-3], workers=1, out_dir=tmp / "study"),
                        tmp / "study.nc")
    return {"grid": grid, "zip": zipped, "study": study, "run": next((tmp / "grid").glob("*.h5"))}


def test_summary_opens_with_one_dimension_per_swept_field(netcdf_files):
    with xr.open_dataset(netcdf_files["grid"]) as ds:
        assert dict(ds.sizes) == {"shear_rate_G": 2, "viscosity_ratio": 2}
        assert ds.attrs["Conventions"] == CONVENTIONS
        for name in ("period", "D_xy_amplitude", "theta_amplitude", "averaging_t_from", "averaging_t_to",
                     "level", "mesh_base", "law", "skalak_c", "bending_modulus", "time_scheme", "rtol",
                     "status", "status_reason", "motion", "D_xy_error_estimate", "intrinsic_viscosity",
                     "intrinsic_viscosity_std", "steady_average"):
            assert ds[name].dims == ("shear_rate_G", "viscosity_ratio"), name
            assert ds[name].attrs["long_name"], name
        np.testing.assert_allclose(ds["intrinsic_viscosity"], 2.5 * ds["Sxy_star"])
        assert (ds["level"] == 0).all() and (ds["law"] == "thin_shell").all()
        assert list(ds["mesh_base"].attrs["flag_meanings"].split()) == list(FLAGS["mesh_base"])
        assert (ds["steady_average"] == 0).all()  # kt = 0.02: transient, and marked
        assert ds["D_xy_error_estimate"].isnull().all()  # no --error-estimate ran
    with xr.open_dataset(netcdf_files["zip"]) as ds:
        assert dict(ds.sizes) == {"run": 2}
        assert ds["run_id"].dims == ("run",) and "run_id" in ds.coords
        assert list(ds["law"].values) == ["skalak", "neo_hookean"]
        assert np.isnan(ds["skalak_c"].values[1]) and ds["skalak_c"].values[0] == 10.0


@pytest.mark.parametrize("name", ["run", "grid", "zip", "study"])
def test_cfchecker_finds_no_errors(netcdf_files, name, tmp_path):
    counts = _cf_counts(netcdf_files[name], tmp_path)
    assert counts["FATAL"] == 0 and counts["ERROR"] == 0, counts
    assert counts["WARN"] == 0, counts


def test_cfchecker_on_each_group_of_a_run_file(netcdf_files, tmp_path):
    path = netcdf_files["run"]
    with xr.open_dataset(path, engine="h5netcdf") as root:
        attrs = dict(root.attrs)
    for group in ("timeseries", "mesh", "summary", "run", "membrane_law", "rest_shape"):
        with xr.open_dataset(path, group=group, engine="h5netcdf") as ds:
            flat = ds.load()
        flat.attrs = {**attrs, **flat.attrs}
        out = tmp_path / f"{group}.nc"
        flat.to_netcdf(out, encoding={n: {"dtype": "S1"} for n, v in flat.variables.items() if v.dtype.kind in "OU"})
        counts = _cf_counts(out, tmp_path)
        assert counts["FATAL"] == 0 and counts["ERROR"] == 0, (group, counts)
        # the one warning: timeseries axis_L and axis_l differ only in case (CF 2.3 advises against it)
        assert counts["WARN"] == (1 if group == "timeseries" else 0), (group, counts)


# ---------------------------------------------------------------- an oscillating run


@pytest.fixture(scope="module")
def oscillating(tmp_path_factory):
    """A level-0 oblate spheroid (b/a = 0.6) at G = 0.2 swings (θ and D_xy oscillate at
    twice the tank-treading frequency, kT ≈ 10) from kt ≈ 10 on; rkc keeps it cheap."""
    path = tmp_path_factory.mktemp("osc") / "osc.h5"
    case = case_from_dict({
        "name": "osc", "shape": {"kind": "oblate", "aspect_ratio": 0.6}, "flow": {"shear_rate_G": 0.2},
        "mesh": {"level": 0}, "time": {"t_end": 35.0, "rtol": 1e-3, "scheme": "rkc", "dt_initial": 0.01},
        "output": {"path": str(path), "snapshot_every": 17.5},
    })
    return run_case(case)


def _peaks(t, s):
    """Times and values of the local maxima of s (parabola through each and its neighbours)."""
    i = np.flatnonzero((s[1:-1] > s[:-2]) & (s[1:-1] >= s[2:])) + 1
    out = []
    for j in i:
        (a, b, c), x = np.polyfit(t[j - 1:j + 2] - t[j], s[j - 1:j + 2], 2), 0.0
        if a < 0:
            x = -b / (2 * a)
        out.append((t[j] + x, c - b * b / (4 * a) if a < 0 else s[j]))
    return np.array(out)


def test_oscillating_summary_matches_its_time_series(oscillating):
    result = oscillating
    assert result.status == "completed" and result["motion"] == "swinging"  # named oscillating before issue 39
    ts = read_trajectory(result["path"])["timeseries"]
    t, dxy, theta = ts["t"], ts["D_xy"], np.unwrap(ts["theta"], period=np.pi)
    late = t >= t[-1] / 3
    peaks, troughs = _peaks(t[late], dxy[late]), _peaks(t[late], -dxy[late])
    assert len(peaks) >= 2 and len(troughs) >= 2
    period = float(peaks[-1, 0] - peaks[-2, 0])  # the last cycle, from maximum to maximum …
    assert troughs[-1, 0] - troughs[-2, 0] == pytest.approx(period, rel=0.05)  # … and minimum to minimum
    t1, t2 = peaks[-2, 0], peaks[-1, 0]
    cycle = (t >= t1) & (t <= t2)
    dxy_amplitude = 0.5 * np.ptp(dxy[cycle])
    theta_amplitude = 0.5 * np.ptp(theta[cycle])
    record = read_run(result["path"])  # what the campaign summary carries
    for summary in (result.summary, record):
        assert summary["period"] == pytest.approx(period, rel=0.05)
        assert summary["D_xy_amplitude"] == pytest.approx(dxy_amplitude, rel=0.05)
        assert summary["theta_amplitude"] == pytest.approx(theta_amplitude, rel=0.05)
        assert t[0] <= summary["averaging_t_from"] < summary["averaging_t_to"] <= t[-1]
    assert record["steady_average"] == 1 and record["motion"] == "swinging"
    assert record["intrinsic_viscosity"] == pytest.approx(2.5 * record["Sxy_star"])
