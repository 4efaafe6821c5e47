"""Campaigns: schema, expansion, process-pool and Dask sweeps, resume, failures, netCDF summary."""

import os
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
import xarray as xr
import yaml

from capsim.campaigns.campaign import (
    campaign_from_dict, execute_run, expand_campaign, load_campaign, run_campaign, usable_cores,
)
from capsim.config import ConfigError
from capsim.storage.store import read_trajectory
from capsim.campaigns.summary import SUMMARY_ATTRS, summarize_campaign, write_summary

ROOT = Path(__file__).resolve().parents[2]
SMOKE = ROOT / "campaigns" / "smoke.yaml"


def smoke_dict(out_dir, **changes):
    """The CI smoke campaign (G x lambda), shortened."""
    d = yaml.safe_load(SMOKE.read_text())
    d["base"]["time"]["t_end"] = 0.25
    d["sweep"] = {"flow.shear_rate_G": [0.05, 0.1], "flow.viscosity_ratio": [1.0, 5.0]}
    d["output"]["dir"] = str(out_dir)
    d.update(changes)
    return d


# ---------------------------------------------------------------- schema


@pytest.mark.parametrize(
    "change, message",
    [
        ({"swep": {}}, "smoke.yaml: swep: unknown field 'swep' (allowed: name, base, sweep, zip, output)"),
        ({"zip": {"flow.shear_rate_G": [0.1, 0.2], "initial_tilt_deg": [0.0]}},
         "zip lists must have equal lengths (flow.shear_rate_G has 2, initial_tilt_deg has 1)"),
        ({"sweep": {"flow.shear_rate": [0.1]}}, "sweep: 'flow.shear_rate' is not a case field (flow has: shear_rate_G"),
        ({"sweep": {"flw.shear_rate_G": [0.1]}}, "sweep: 'flw.shear_rate_G' is not a case field (a case has: name"),
        ({"sweep": {"flow": [0.1]}}, "'flow' is a section"),
        ({"sweep": {"flow.shear_rate_G": [0.1, -1.0]}}, "flow.shear_rate_G = -1.0: must be > 0"),
        ({"sweep": {"flow.shear_rate_G": []}}, "sweep.flow.shear_rate_G"),
        ({"base": {"mesh": {"levl": 1}}}, "smoke.yaml: base: mesh.levl: unknown field 'levl'"),
        ({"base": {"name": "x"}}, "name and output.path are set per run"),
        ({"output": {"dir": "x", "path": "y"}}, "output.path: unknown field 'path' (allowed: dir)"),
        ({"sweep": {"flow.shear_rate_G": [0.1, 0.1]}}, "are the same case"),
    ],
)
def test_campaign_errors_are_one_line(tmp_path, change, message):
    d = smoke_dict(tmp_path)
    d.update(change)
    with pytest.raises(ConfigError) as info:
        campaign_from_dict(d, source="smoke.yaml")
    text = str(info.value)
    assert message in text
    assert "\n" not in text


def test_expansion_grid_zip_and_stable_ids(tmp_path):
    smoke = load_campaign(SMOKE)
    specs = expand_campaign(smoke)
    assert len(specs) == 4
    assert [s.grid_index for s in specs] == [(0, 0), (0, 1), (1, 0), (1, 1)]
    assert specs[1].params == {"flow.shear_rate_G": 0.05, "flow.viscosity_ratio": 5.0}
    assert specs[1].run_id.startswith("shear_rate_G0.05-viscosity_ratio5-")
    assert [s.run_id for s in expand_campaign(load_campaign(SMOKE))] == [s.run_id for s in specs]
    assert len({s.run_id for s in specs}) == 4
    d = yaml.safe_load(SMOKE.read_text())
    d["sweep"]["flow.viscosity_ratio"] = [1, 5]  # ints: the same cases, the same ids
    assert [s.run_id for s in expand_campaign(campaign_from_dict(d))] == [s.run_id for s in specs]
    assert specs[0].case().output.path == str(Path("runs/smoke") / f"{specs[0].run_id}.h5")
    # A changed base is a different case: it never reuses an old file.
    d = yaml.safe_load(SMOKE.read_text())
    d["base"]["mesh"]["level"] = 1
    assert not {s.run_id for s in expand_campaign(campaign_from_dict(d))} & {s.run_id for s in specs}
    for name in ("fig9-spheres", "fig11-ttf", "fig13-stresslet"):
        specs = expand_campaign(load_campaign(ROOT / "campaigns" / f"{name}.yaml"))
        assert len(specs) == 18 and specs[0].case().mesh.level == 3
    zipped = campaign_from_dict(smoke_dict(tmp_path, sweep={"membrane.law": ["thin_shell", "skalak"]},
                                           zip={"flow.shear_rate_G": [0.1, 0.2, 0.3], "initial_tilt_deg": [0, 10, 20]}))
    specs = expand_campaign(zipped)
    assert len(specs) == 6 and not zipped.is_grid
    assert specs[4].params == {"membrane.law": "skalak", "flow.shear_rate_G": 0.2, "initial_tilt_deg": 10}


def test_a_raising_case_is_recorded_not_raised(tmp_path, monkeypatch):
    import capsim.runs.runner

    def boom(case, progress=None):
        raise RuntimeError("solver exploded\nsecond line")

    monkeypatch.setattr(capsim.runs.runner, "run_case", boom)
    spec = expand_campaign(campaign_from_dict(smoke_dict(tmp_path)))[0]
    record = execute_run(spec)
    assert record == {"run_id": spec.run_id, "status": "failed", "status_reason": "RuntimeError: solver exploded"}


# ---------------------------------------------------------------- the batch executor


def _task(item, progress):  # module level: the spawned workers import it by name
    if item == "bad":
        raise ValueError("no good\nsecond line")
    return {"status": "completed", "status_reason": "", "item": item}


@pytest.mark.parametrize("in_process", [True, False], ids=["in-process", "pool"])
def test_executor_turns_a_raising_task_into_a_record(in_process):
    from capsim.campaigns.executor import run_batch

    items = ["a", "bad", "c"]
    done = []
    out = run_batch(
        items, _task, keys=items, workers=2, in_process=in_process, order=[2, 1, 0],
        failure=lambda i, status, reason: {"status": status, "status_reason": reason, "item": items[i]},
        on_done=lambda i, record: done.append(i),
    )
    assert not out.interrupted
    assert [r["item"] for r in out.records] == items  # item order, whatever the finishing order
    assert out.records[1] == {"status": "failed", "status_reason": "ValueError: no good", "item": "bad"}
    assert sorted(done) == [0, 1, 2]


def test_warm_up_covers_each_kind_of_kernel_once():
    from capsim.config import case_from_dict
    from capsim.campaigns.executor import distinct_kinds

    def case(**sections):
        return case_from_dict({"name": "k", **sections})

    cases = [
        case(), case(flow={"shear_rate_G": 0.2}),  # the same kernels
        case(flow={"viscosity_ratio": 5.0}), case(flow={"viscosity_ratio": 0.2}),  # λ ≠ 1: one kind
        case(membrane={"law": "skalak"}), case(membrane={"law": "neo_hookean", "bending_modulus": 0.01}),
        case(membrane={"traction": "contour"}), case(quadrature={"near_field_factor": 0.5}),
        case(mesh={"symmetry": False}),
    ]
    kinds = distinct_kinds(cases)
    assert [cases.index(c) for c in kinds] == [0, 2, 4, 5, 6, 7, 8]


# ---------------------------------------------------------------- sweeps


@pytest.fixture(scope="module")
def pool_sweep(tmp_path_factory):
    """The 2x2 smoke sweep on a 2-process pool (run once for the module)."""
    out = tmp_path_factory.mktemp("pool") / "smoke"
    campaign = campaign_from_dict(smoke_dict(out))
    seen = []
    result = run_campaign(campaign, workers=2, progress=lambda s: seen.append(dict(s, kt=dict(s["kt"]))))
    return campaign, out, result, seen


def test_pool_sweep_writes_every_run_and_summarizes(pool_sweep, tmp_path):
    campaign, out, result, seen = pool_sweep
    assert (result["total"], result["completed"], result["failed"], result["skipped"]) == (4, 4, 0, 0)
    assert sorted(p.name for p in out.glob("*.h5")) == sorted(f"{s.run_id}.h5" for s in expand_campaign(campaign))
    assert load_campaign(out / "campaign.yaml") == campaign
    assert seen[-1]["done"] == 4 and seen[-1]["running"] == 0
    assert max(s["running"] for s in seen) <= 2
    # processes x numba threads = cores
    assert {r["numba_threads"] for r in result["records"]} == {max(1, usable_cores() // 2)}

    ds = summarize_campaign(out)
    assert dict(ds.sizes) == {"shear_rate_G": 2, "viscosity_ratio": 2}
    assert list(ds["shear_rate_G"].values) == [0.05, 0.1]
    assert list(ds["viscosity_ratio"].values) == [1.0, 5.0]
    for record in result["records"]:
        s = record["summary"]
        params = next(x.params for x in expand_campaign(campaign) if x.run_id == record["run_id"])
        cell = ds.sel(shear_rate_G=params["flow.shear_rate_G"], viscosity_ratio=params["flow.viscosity_ratio"])
        assert str(cell["status"].values) == "completed"
        assert str(cell["run_id"].values) == record["run_id"]
        for name in ("D_xy", "theta", "steps", "wall_time_s", "volume_drift"):
            assert cell[name].values == s[name], name
        # The file's summary group when the run wrote one, else its last row.
        traj = read_trajectory(s["path"])
        steady = traj["summary"] or {"D_xy": traj["timeseries"]["D_xy"][-1]}
        for name in ("D_xy", "theta", "ttf_ratio", "Sxy_star", "N1_star", "N2_star", "D_xy_std", "motion"):
            if name in steady:
                assert cell[name].values == steady[name], name
    # Larger G, larger deformation (first-order theory: D_xy = 25/4 G).
    assert np.all(ds["D_xy"].sel(shear_rate_G=0.1) > ds["D_xy"].sel(shear_rate_G=0.05))

    path = write_summary(ds, tmp_path / "summary.nc")
    with xr.open_dataset(path, engine="netcdf4") as back:
        back.load()
    xr.testing.assert_identical(back, ds)
    for name in list(ds.data_vars) + ["shear_rate_G"]:
        assert {"long_name", "units", "definition"} <= set(back[name].attrs), name
        assert back[name].attrs["long_name"] == SUMMARY_ATTRS[name]["long_name"]
    assert back.attrs["campaign_yaml"] == campaign.to_yaml()
    assert "capsim_version" in back.attrs and "created" in back.attrs
    # Until the runs write a summary group, its observables are NaN / "" rather than absent.
    with h5py.File(result["records"][0]["summary"]["path"], "r") as f:
        has_summary = "summary" in f
    if not has_summary:
        assert np.isnan(back["Sxy_star"]).all() and (back["motion"] == "").all()


def test_resume_redoes_only_missing_and_unfinished_runs(pool_sweep, tmp_path):
    campaign, out, _, _ = pool_sweep
    work = tmp_path / "smoke"
    shutil.copytree(out, work)
    campaign = campaign_from_dict(dict(campaign.model_dump(mode="json"), output={"dir": str(work)}))
    specs = expand_campaign(campaign)
    # A sweep killed partway: one run never started, one was cut off while running.
    Path(specs[0].path).unlink()
    with h5py.File(specs[3].path, "r+") as f:
        f.attrs["status"] = "interrupted"
    mtimes = {s.run_id: os.stat(s.path).st_mtime_ns for s in specs[1:3]}

    result = run_campaign(campaign, workers=2)
    assert (result["skipped"], result["completed"], result["failed"]) == (2, 2, 0)
    assert sorted(r["run_id"] for r in result["records"]) == sorted([specs[0].run_id, specs[3].run_id])
    assert {s.run_id: os.stat(s.path).st_mtime_ns for s in specs[1:3]} == mtimes
    assert (summarize_campaign(work)["status"] == "completed").all()
    assert run_campaign(campaign, workers=2)["skipped"] == 4


def test_one_impossible_case_does_not_stop_the_others(tmp_path):
    # dt_min above any step the tolerance accepts: the step size collapses at once.
    d = smoke_dict(tmp_path / "bad", sweep={}, zip={
        "flow.shear_rate_G": [0.05, 0.1, 0.1],
        "time.dt_min": [1e-8, 1e-8, 0.2],
        "time.dt_initial": [1e-3, 1e-3, 0.25],
    })
    d["base"]["time"]["rtol"] = 1e-6
    result = run_campaign(campaign_from_dict(d), workers=2)
    assert (result["completed"], result["failed"]) == (2, 1)
    ds = summarize_campaign(tmp_path / "bad")
    assert dict(ds.sizes) == {"run": 3}
    assert list(ds["status"].values) == ["completed", "completed", "unstable"]
    assert "step size collapsed" in str(ds["status_reason"].values[2])
    assert list(ds["dt_min"].values) == [1e-8, 1e-8, 0.2]
    assert ds["shear_rate_G"].dims == ("run",)


def test_dask_local_cluster_gives_the_same_numbers(pool_sweep, tmp_path):
    distributed = pytest.importorskip("distributed")
    campaign, out, _, _ = pool_sweep
    campaign = campaign_from_dict(dict(campaign.model_dump(mode="json"), output={"dir": str(tmp_path / "dask")}))
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, processes=False, protocol="tcp://", host="127.0.0.1",
        dashboard_address=None,
    ) as cluster:
        assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
        result = run_campaign(campaign, scheduler=cluster.scheduler_address)
    assert (result["completed"], result["failed"]) == (4, 0)
    pool, dask = summarize_campaign(out), summarize_campaign(tmp_path / "dask")
    np.testing.assert_array_equal(dask["steps"].values, pool["steps"].values)
    # The pool's and Dask's workers run numba with different thread counts, so the
    # parallel sums round differently; the λ = 5 GMRES solves (tol 1e-6, warm-started
    # from the previous velocity and right-hand side) carry that 1e-16 difference
    # to ~4e-12 in D_xy over a run. The same numbers, to round-off:
    for name in ("D_xy", "theta"):
        np.testing.assert_allclose(dask[name].values, pool[name].values, rtol=1e-10, atol=0)
    # (V − V0)/V0 is a difference of nearly equal volumes: it carries ~1e-16
    # absolute precision, and the workers' thread counts differ (λ = 5 solves)
    np.testing.assert_allclose(dask["volume_drift"].values, pool["volume_drift"].values, rtol=0, atol=1e-14)
    assert (dask["run_id"].values == pool["run_id"].values).all()


def test_cli_sweep_and_summarize(pool_sweep, tmp_path):
    from typer.testing import CliRunner

    from capsim.face.cli import app

    campaign, out, _, _ = pool_sweep
    path = tmp_path / "c.yaml"
    path.write_text(campaign.to_yaml())
    runner = CliRunner()
    res = runner.invoke(app, ["sweep", str(path), "--workers", "2", "-q"])
    assert res.exit_code == 0, res.output
    assert "4 runs, 4 skipped" in res.output
    res = runner.invoke(app, ["summarize", str(out), "-o", str(tmp_path / "s.nc")])
    assert res.exit_code == 0, res.output
    assert xr.open_dataset(tmp_path / "s.nc").sizes == {"shear_rate_G": 2, "viscosity_ratio": 2}
    path.write_text("name: x\nsweep: {flow.shear_rate: [1]}\noutput: {dir: y}\n")
    res = runner.invoke(app, ["sweep", str(path)])
    assert res.exit_code == 2 and "is not a case field" in res.output
