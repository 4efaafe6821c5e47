"""The one table of quantities (capsim.quantities) against what the writers write.

A short real run (with its error estimate), a small zip campaign and its netCDF
summary, and a small study file: every dataset and variable they write has an
entry of the table, carries that entry's attributes on disk, and every entry is
used by one of them (or listed in quantities.PLANNED, which nothing may write).
Root attributes of a run file and global attributes of the netCDF files are
metadata, not quantities, and are not in the table.
"""

import math

import h5py
import numpy as np
import pytest
import xarray as xr

from capsim import quantities
from capsim.campaigns.campaign import campaign_from_dict, run_campaign
from capsim.config import case_from_dict
from capsim.quantities import PLANNED, TABLE, attrs_for, key_for
from capsim.runs.runner import run_case
from capsim.storage.store import read_case, read_run_record, read_run_status, write_error_estimate
from capsim.campaigns.study import error_estimate, run_study, write_study
from capsim.campaigns.summary import summarize_campaign, write_summary

_UDUNITS = {"1", "rad", "degree", "s"}  # what the table uses; a later CF issue may add more


def _decoded(value):
    return value.decode() if isinstance(value, bytes) else value


def _check_run_file(path, used):
    """Every dataset of a run file: an entry, and its attributes on disk."""
    problems = []

    def visit(name, obj):
        if not isinstance(obj, h5py.Dataset):
            return
        parts = name.split("/")
        where = None if parts[0] in ("mesh", "timeseries") else parts[0]
        try:
            key = key_for(parts[-1], where)
        except KeyError:
            problems.append(f"{path.name}:/{name} has no entry")
            return
        used.add(key)
        on_disk = {k: _decoded(v) for k, v in obj.attrs.items() if k in ("long_name", "units", "definition", "scale")}
        if on_disk != TABLE[key].attrs():
            problems.append(f"{path.name}:/{name}: attributes {on_disk} are not those of entry {key!r}")
        is_string = h5py.check_string_dtype(obj.dtype) is not None
        if not on_disk.get("long_name") or (not is_string and not on_disk.get("units")):
            problems.append(f"{path.name}:/{name}: empty long_name or units")

    with h5py.File(path, "r") as f:
        f.visititems(visit)
        for group in f.values():
            if isinstance(group, h5py.Group):
                assert group.attrs.get("definition"), f"group {group.name} has no definition"
    return problems


def _check_netcdf(ds, where, used):
    problems = []
    for name, var in ds.variables.items():
        if name == "run":  # the run dimension of a zip campaign: its values are run ids
            key = key_for("run_id")
        else:
            key = key_for(var.attrs.get("case_field", name).rsplit(".", 1)[-1], where)
        used.add(key)
        expected = attrs_for(key.rsplit("/", 1)[-1], where) if "/" in key else attrs_for(key)
        for attr, value in expected.items():
            if var.attrs.get(attr) != value:
                problems.append(f"{where}:{name}.{attr} = {var.attrs.get(attr)!r}, entry {key!r} says {value!r}")
        is_string = var.dtype.kind in "OUS"
        if not var.attrs.get("long_name") or (not is_string and not var.attrs.get("units")):
            problems.append(f"{where}:{name}: empty long_name or units")
    return problems


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """The files of a short run, a 2-run zip campaign and a 2-setting study."""
    tmp = tmp_path_factory.mktemp("quantities")
    case = case_from_dict({
        "name": "q", "mesh": {"level": 1}, "time": {"t_end": 0.05},
        "output": {"path": str(tmp / "run.h5"), "snapshot_every": 0.05},
    })
    summary = run_case(case)
    write_error_estimate(case.output.path, error_estimate(case, summary, workers=1))
    # a viscous membrane in a flow that stops: its columns and the relaxation summary
    run_case(case_from_dict({
        "name": "qv", "mesh": {"level": 1}, "time": {"t_end": 0.05},
        "flow": {"history": {"kind": "stop", "stop_time": 0.02}}, "membrane": {"viscosity": {"shear": 1.0}},
        "output": {"path": str(tmp / "viscous.h5"), "snapshot_every": 0.05},
    }))

    # a red cell whose area modulus skalak_c auto chose: the record's area tolerance
    run_case(case_from_dict({
        "name": "qa", "mesh": {"level": 0}, "time": {"t_end": 0.02}, "shape": {"kind": "biconcave"},
        "membrane": {"law": "skalak", "skalak_c": "auto"},
        "output": {"path": str(tmp / "auto.h5"), "snapshot_every": 0.02},
    }))

    # a capsule near a wall: its gap column
    run_case(case_from_dict({
        "name": "qw", "mesh": {"level": 0}, "time": {"t_end": 0.02}, "wall": {"distance": 3.0},
        "output": {"path": str(tmp / "wall.h5"), "snapshot_every": 0.02},
    }))

    # a capsule in a tube (issue 53): the conduit's columns (a coarse wall: its columns, not its accuracy)
    run_case(case_from_dict({
        "name": "qc", "mesh": {"level": 0}, "time": {"t_end": 0.02}, "flow": {"kind": "conduit"},
        "conduit": {"kind": "tube", "radius": 2.0, "element_size": 1.0},
        "output": {"path": str(tmp / "conduit.h5"), "snapshot_every": 0.02},
    }))

    # a pair of capsules: the capsule dimension, the scene's columns and the pair's summary
    run_case(case_from_dict({
        "name": "qp", "mesh": {"level": 0}, "time": {"t_end": 0.02},
        "capsules": [{"center": [-2.0, 0.2, 0.0]}, {"center": [2.0, -0.2, 0.0]}],
        "output": {"path": str(tmp / "pair.h5"), "snapshot_every": 0.02},
    }))

    # a measured accuracy target: the kept run's accuracy group (capsim.runs.ladder)
    run_case(case_from_dict({
        "name": "qa", "time": {"t_end": 0.02}, "output": {"path": str(tmp / "measured.h5")},
        "accuracy": {"quantity": "D_xy", "target": 0.5, "method": "measure", "max_level": 2},
    }))

    campaign = campaign_from_dict({
        "name": "q", "base": {"shape": {"kind": "prolate"}, "time": {"t_end": 0.02}},
        "sweep": {},
        "zip": {  # every case field that has an entry of its own
            "flow.shear_rate_G": [0.05, 0.1], "flow.viscosity_ratio": [1.0, 2.0],
            "initial_tilt_deg": [0.0, 10.0], "shape.aspect_ratio": [1.2, 1.5],
            "membrane.law": ["skalak", "mooney_rivlin"], "membrane.skalak_c": [5.0, 10.0],
            "membrane.psi": [0.0, 0.2], "mesh.level": [0, 1], "time.rtol": [1e-3, 1e-4],
            "quadrature.regular_order": [6, 7],
        },
        "output": {"dir": str(tmp / "campaign")},
    })
    result = run_campaign(campaign, workers=1)
    assert result["completed"] == 2, result
    nc = write_summary(summarize_campaign(tmp / "campaign"), tmp / "summary.nc")

    study_case = case_from_dict({"name": "s", "time": {"t_end": 0.02},
                                 "output": {"path": str(tmp / "unused.h5")}})
    study = write_study(run_study(study_case, levels=[0, 1], rtols=[1e-3], workers=1, out_dir=tmp / "study"),
                        tmp / "study.nc")
    # a study of the orbit's numbers (capsim study --quantity orbit)
    orbit_study = write_study(run_study(study_case, levels=[0, 1], rtols=[1e-3], workers=1, quantity="orbit",
                                        out_dir=tmp / "study_orbit"), tmp / "study_orbit.nc")
    run_files = [tmp / "run.h5", tmp / "viscous.h5", tmp / "auto.h5", tmp / "wall.h5", tmp / "conduit.h5", tmp / "pair.h5", tmp / "measured.h5", *sorted((tmp / "campaign").glob("*.h5"))]
    return case, summary, run_files, nc, (study, orbit_study)


def test_every_quantity_written_has_its_entry_and_every_entry_is_used(written):
    _, _, run_files, nc, study = written
    used: set[str] = set()
    problems = []
    for path in run_files:
        problems += _check_run_file(path, used)
    for path, where in ((nc, "campaign"), (study[0], "study"), (study[1], "study")):
        with xr.open_dataset(path, engine="netcdf4") as ds:
            problems += _check_netcdf(ds.load(), where, used)
    assert not problems, "\n".join(problems)
    # nothing planned is written yet (remove a name from PLANNED once a writer writes it) …
    assert not PLANNED & used, f"written now, remove from quantities.PLANNED: {sorted(PLANNED & used)}"
    # … and every other entry describes something written
    unused = set(TABLE) - used - PLANNED
    assert not unused, f"table entries no writer uses: {sorted(unused)}"


def test_entries_are_well_formed():
    for key, q in TABLE.items():
        assert q.long_name and q.definition, key
        assert q.units in _UDUNITS or q.units == "", (key, q.units)
        if q.scale:
            assert q.units == "1", (key, "a capsim scale belongs to a dimensionless value")
    # string-valued entries are the categorical ones
    assert {k for k, q in TABLE.items() if q.units == ""} == {
        "status", "status_reason", "motion", "law", "membrane_law/name", "run_id", "accuracy/quantity",
        "accuracy/verdict", "accuracy/error_model"}
    # one name, one meaning: the long_name of D_xy is the same in the run file, summary and study
    assert attrs_for("D_xy")["long_name"] == attrs_for("D_xy", "campaign")["long_name"]
    assert attrs_for("D_xy", "study")["long_name"].startswith(attrs_for("D_xy")["long_name"])
    assert attrs_for("t") == {"long_name": "time", "units": "1", "scale": "1/k",
                              "definition": TABLE["t"].definition}
    with pytest.raises(KeyError, match="no entry"):
        attrs_for("not_a_quantity")


def test_store_readers_on_a_real_run(written):
    case, summary, run_files, _, _ = written
    path = run_files[0]
    assert read_case(path) == case
    assert read_run_status(path) == "completed"
    assert read_run_status(path.with_name("missing.h5")) is None
    record = read_run_record(path)
    assert record["attrs"]["status"] == "completed"
    assert record["run"]["steps"] == summary["steps"] == record["n_steps"] - 1
    assert record["first"]["t"] == 0.0 and math.isclose(record["last"]["t"], case.time.t_end)
    assert record["summary"]["motion"] == summary["motion"]
    with h5py.File(path, "r") as f:
        assert "error_estimate" in f and f["error_estimate"].attrs["definition"] == quantities.GROUPS["error_estimate"]
        assert np.isfinite(f["error_estimate/D_xy"][()])
