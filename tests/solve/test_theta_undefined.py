"""Issue 30, finding 6: θ is NaN where the shape has no long axis in the shear plane.

An undeformed sphere's inclination is round-off of a degenerate eigenvector (a level-3
octahedron sphere gave 0.5787 rad, level 0 π/2); it is stored as NaN, and everything
downstream (the stopping rules, the classifier, the run summary, the campaign summary,
the figures, the export and the CF check) takes it.
"""

import math

import numpy as np
import pytest
import xarray as xr

from capsim.config import case_from_dict
from capsim.solve.observables import THETA_UNDEFINED_GAP, classify_motion, ellipsoid_axes, run_summary, unwrap_defined
from capsim.runs.runner import build_model, run_case
from capsim.storage.store import read_trajectory
from capsim.campaigns.summary import read_run


@pytest.mark.parametrize("base,level", [("octahedron", 0), ("octahedron", 3), ("icosahedron", 2)])
def test_a_sphere_has_no_inclination(base, level):
    case = case_from_dict({"name": "s", "mesh": {"base": base, "level": level}, "output": {"path": "unused.h5"}})
    model, X = build_model(case)
    e = ellipsoid_axes(model.disc.geometry(X))
    assert e["D_xy"] < 1e-14 and math.isnan(e["theta"])


def test_a_stretched_sphere_keeps_its_inclination():
    """A gap well above THETA_UNDEFINED_GAP (D_xy = 1e-6) has a defined θ: 45° here."""
    case = case_from_dict({"name": "s", "mesh": {"level": 2}, "output": {"path": "unused.h5"}})
    model, X = build_model(case)
    c, s = math.cos(math.pi / 4), math.sin(math.pi / 4)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    X = X @ (R @ np.diag([1 + 2e-6, 1.0, 1.0]) @ R.T)  # stretched along the 45° line (symmetric)
    e = ellipsoid_axes(model.disc.geometry(np.ascontiguousarray(X)))
    assert e["D_xy"] > 100 * THETA_UNDEFINED_GAP
    assert e["theta"] == pytest.approx(math.pi / 4, abs=1e-6)


def test_classifier_and_summary_take_an_undefined_theta():
    """Steady D_xy = 0.1, θ = 0.3 after a start with θ undefined: steady, θ's mean 0.3,
    not 'unstable' (as before: the classifier refused any non-finite θ)."""
    t = np.linspace(0.0, 20.0, 401)
    D = 0.1 * (1 - np.exp(-5 * t))
    theta = np.full_like(t, 0.3)
    theta[0] = np.nan
    assert classify_motion(t, D, theta)["motion"] == "steady"
    series = {"t": t, "D_xy": D, "theta": theta, "ttf_ratio": np.ones_like(t), "Sxy_star": np.ones_like(t),
              "N1_star": np.ones_like(t), "N2_star": np.ones_like(t)}
    out = run_summary(series)
    assert out["motion"] == "steady" and out["theta"] == pytest.approx(0.3, abs=1e-12)
    np.testing.assert_array_equal(np.isnan(unwrap_defined(theta)), np.isnan(theta))
    theta[5] = np.inf  # an infinite θ is a failure still
    assert classify_motion(t, D, theta)["motion"] == "unstable"


@pytest.fixture(scope="module")
def sphere_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("sphere")
    case = case_from_dict({"name": "s", "mesh": {"level": 1}, "time": {"t_end": 0.05},
                           "output": {"path": str(tmp / "s.h5"), "snapshot_every": 0.025}})
    return tmp, run_case(case)


def test_a_sphere_run_stores_nan_theta_at_rest_and_everything_downstream_works(sphere_run, tmp_path):
    from capsim.face.export import export_run
    from capsim.face.plot import plot

    tmp, result = sphere_run
    path = tmp / "s.h5"
    assert result.status == "completed" and result["motion"] == "transient"
    ts = read_trajectory(path)["timeseries"]
    assert math.isnan(ts["theta"][0]) and ts["D_xy"][0] < 1e-14
    assert np.isfinite(ts["theta"][1:]).all()  # the first step has a long axis, near π/4
    assert ts["theta"][1] == pytest.approx(math.pi / 4, abs=0.01)
    record = read_run(path)
    assert math.isfinite(record["theta"]) and record["theta"] == pytest.approx(math.pi / 4, abs=0.03)
    with xr.open_dataset(path, group="timeseries", engine="h5netcdf") as ds:
        assert math.isnan(float(ds["theta"].values[0]))
    for kind in ("inclination", "deformation", "contour"):
        plot(str(path), kind, tmp_path / f"{kind}.png")
        assert (tmp_path / f"{kind}.png").stat().st_size > 1000
    files = export_run(path, tmp_path / "xdmf", "xdmf", fields=False)
    assert files[0].exists()


def test_cf_check_of_a_run_with_nan_theta(sphere_run, tmp_path):
    from cf_checks import cf_counts as _cf_counts

    tmp, _ = sphere_run
    counts = _cf_counts(tmp / "s.h5", tmp_path)
    assert counts["FATAL"] == 0 and counts["ERROR"] == 0 and counts["WARN"] == 0, counts


def test_a_tumbling_run_reports_the_half_amplitude_of_D_xy():
    """θ turning clockwise at a constant rate ω = 0.3 with D_xy = 0.3 + 0.1 sin(2ωt): tumbling,
    D_xy's mean 0.3 and half peak-to-peak 0.1 over the last half turn (NaN before issue 30)."""
    t = np.linspace(0.0, 60.0, 6001)
    theta = np.pi / 2 - (0.3 * t + 0.1) % np.pi
    D = 0.3 + 0.1 * np.sin(0.6 * t)
    out = classify_motion(t, D, theta)
    assert out["motion"] == "tumbling" and out["period"] == pytest.approx(2 * np.pi / 0.3, rel=1e-3)
    assert out["D_xy_mean"] == pytest.approx(0.3, abs=1e-4) and out["D_xy_amplitude"] == pytest.approx(0.1, rel=1e-4)
    ones = np.ones_like(t)
    summary = run_summary({"t": t, "D_xy": D, "theta": theta, "ttf_ratio": ones, "Sxy_star": ones,
                           "N1_star": ones, "N2_star": ones})
    assert summary["motion"] == "tumbling" and math.isnan(summary["theta"]) and math.isnan(summary["theta_std"])
    assert summary["D_xy_amplitude"] == pytest.approx(0.1, rel=1e-4)
    from capsim.face.display import summary_rows

    assert dict(summary_rows(summary))["theta/pi"] == "undefined (NaN)"
