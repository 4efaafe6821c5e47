"""The run file's templates (capsim.storage.store._template) change nothing in the file.

A writer copies the labelled objects a run file repeats (the mesh group, the time series' columns, the
groups of scalars) from templates made once per process, then writes the values (issue 57: HDF5 spends
~30 µs on each attribute it creates). Here the same run file is written with the templates off, with
them on at their first use (the templates made) and on again with other values (the templates reused,
their values from the earlier file overwritten): every object, its type, shape, chunks, attributes
(dimension scales by the names they point to) and values must be the same.
"""

import h5py
import numpy as np
import pytest

from capsim.numerics.threads import policy_attrs
from capsim.storage import store
from capsim.storage.store import TrajectoryWriter

ELEMENTS = np.arange(8 * 6).reshape(8, 6) % 18
#: the clock at the run's start and end, and the process's thread settings (numba's layer once a parallel
#: kernel has run): they differ between files written at other times (not compared)
CLOCK_ATTRS = {"created", "finished", *policy_attrs()}


def _write(path, seed: int) -> None:
    rng = np.random.default_rng(seed)
    rest = rng.normal(size=(18, 3))
    with TrajectoryWriter(path, config_yaml=f"name: x{seed}\n", elements=ELEMENTS + seed % 2, rest_positions=rest,
                          version="9.9", attrs={"n_nodes": 18, "time_scheme": "rk45", "time_rtol": 1e-3}) as w:
        w.write_membrane_law({"name": "skalak", "G_s": 1.0, "K_s": 3.0 + seed, "poisson_ratio": 0.5,
                              "ca_over_G": 0.1, "parameters": {"C": 1.0 + seed, "other": 2.0, "third": 3.0,
                                                               "fourth": 4}})
        w.write_rest_shape({"volume": rng.random(), "area": rng.random(), "equal_volume_radius": 1.0,
                            "sphericity": rng.random()})
        for i in range(25):
            w.append_step({"t": 0.1 * i, "dt": 0.1, "D_xy": rng.random(), "theta": rng.random(),
                           "area": rng.random(), "volume": 1.0})
            if i % 10 == 0:
                w.append_snapshot(0.1 * i, rest + rng.normal(size=rest.shape))
        w.write_run_record({"t": 2.4, "steps": 25, "rejected_steps": seed, "wall_time_s": rng.random(),
                            "velocity_evaluations": 100 + seed})
        w.write_summary({"motion": ["tank-treading", "tumbling"][seed % 2], "settled": bool(seed % 2),
                         "D_xy": rng.random(), "D_xy_std": rng.random(), "theta": rng.random(),
                         "theta_std": rng.random(), "orbit_periods": rng.random(3), "steps": 25})
        w.close("completed")


def _ref_names(f: h5py.File, value):
    """A reference attribute (DIMENSION_LIST, REFERENCE_LIST) as the names it points to."""
    if isinstance(value, h5py.Reference):
        return f[value].name
    if isinstance(value, np.void):
        return tuple(_ref_names(f, v) for v in value)
    if isinstance(value, (np.ndarray, list, tuple)):
        return [_ref_names(f, v) for v in value]
    return value.item() if isinstance(value, np.generic) else value


def _attr(f: h5py.File, value):
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.ndarray) and value.dtype.kind in "OV":
        return _ref_names(f, value)
    if isinstance(value, np.ndarray):
        return (str(value.dtype), value.tolist())
    return (type(value).__name__, value)


def _describe(path) -> dict:
    """Every object of the file: its kind, type, shape, layout, attributes and values."""
    out = {}
    with h5py.File(path, "r") as f:
        def visit(name, item):
            attrs = {key: _attr(f, item.attrs[key]) for key in item.attrs if key not in CLOCK_ATTRS}
            if isinstance(item, h5py.Group):
                out[name] = ("group", attrs)
            else:
                value = item[()]
                out[name] = ("dataset", str(item.dtype), item.shape, item.maxshape, item.chunks,
                             item.fillvalue if item.dtype.kind in "fiu" else None, attrs,
                             value.decode() if isinstance(value, bytes) else np.asarray(value).tolist())
        out["/"] = ("root", {key: _attr(f, f.attrs[key]) for key in f.attrs if key not in CLOCK_ATTRS})
        f.visititems(visit)
    return out


@pytest.fixture()
def fresh_templates(monkeypatch):
    """No templates made yet in this process; the templates on."""
    monkeypatch.setattr(store, "_templates", {})
    monkeypatch.setattr(store, "_template_file", None)
    monkeypatch.setattr(store, "_header_images", {})
    monkeypatch.setattr(store, "TEMPLATES", True)


def test_templates_change_nothing_in_the_file(tmp_path, fresh_templates, monkeypatch):
    _write(tmp_path / "first.h5", 1)  # the templates made
    made = len(store._templates)
    _write(tmp_path / "second.h5", 2)  # reused, their values overwritten
    assert len(store._templates) == made >= 5  # time series, law and its parameters, rest shape, run, summary
    assert len(store._header_images) == 1  # the mesh
    monkeypatch.setattr(store, "TEMPLATES", False)
    _write(tmp_path / "first_plain.h5", 1)
    _write(tmp_path / "second_plain.h5", 2)
    for name in ("first", "second"):
        templated, plain = _describe(tmp_path / f"{name}.h5"), _describe(tmp_path / f"{name}_plain.h5")
        assert templated.keys() == plain.keys()
        for key in plain:
            if templated[key] != plain[key]:  # say which attribute or part differs
                for i, (a, b) in enumerate(zip(templated[key], plain[key])):
                    if isinstance(b, dict):
                        assert {k: v for k, v in a.items() if b.get(k) != v} == {}, f"{key}: attributes"
                    assert a == b, f"{key}: part {i}"
    # the files differ where their values do: the comparison sees values
    assert _describe(tmp_path / "first.h5") != _describe(tmp_path / "second.h5")


def test_dimension_scales_attached_in_the_copied_groups(tmp_path, fresh_templates):
    _write(tmp_path / "a.h5", 1)
    _write(tmp_path / "b.h5", 2)
    with h5py.File(tmp_path / "b.h5", "r") as f:
        assert [s.name for s in f["timeseries/D_xy"].dims[0].values()] == ["/timeseries/t"]
        assert [[s.name for s in d.values()] for d in f["mesh/positions"].dims] == [
            ["/mesh/snapshot_t"], ["/mesh/node"], ["/mesh/xyz"]]
        np.testing.assert_array_equal(f["mesh/elements"][()], ELEMENTS)  # seed 2: its own, not seed 1's
        assert f["summary/motion"][()].decode() == "tank-treading" and not f["summary/settled"][()]


def test_runs_writing_in_threads_keep_their_own_values(tmp_path, fresh_templates):
    """A Dask worker runs several runs in threads of one process: each file's groups hold its own
    values, never another run's written into the shared template in between (the template lock)."""
    import threading

    errors = []

    def writer(k: int) -> None:
        try:
            for i in range(12):
                seed = 100 * k + i
                _write(tmp_path / f"w{seed}.h5", seed)
        except Exception as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    threads = [threading.Thread(target=writer, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    for k in range(4):
        for i in range(12):
            seed = 100 * k + i
            with h5py.File(tmp_path / f"w{seed}.h5", "r") as f:
                assert int(f["run/velocity_evaluations"][()]) == 100 + seed
                assert int(f["run/rejected_steps"][()]) == seed
                assert f["membrane_law/K_s"][()] == 3.0 + seed
                assert f.attrs["config_yaml"] == f"name: x{seed}\n"
