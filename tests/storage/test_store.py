import signal
import subprocess
import sys
import textwrap

import h5py
import numpy as np
import pytest

from capsim.storage.store import TrajectoryError, TrajectoryWriter, read_trajectory

ELEMENTS = np.arange(8 * 6).reshape(8, 6) % 18
REST = np.random.default_rng(0).normal(size=(18, 3))


def _writer(path, **kwargs):
    return TrajectoryWriter(
        path, config_yaml="name: x\n", elements=ELEMENTS, rest_positions=REST, version="9.9", **kwargs
    )


def test_round_trip(tmp_path):
    path = tmp_path / "sub" / "run.h5"
    rng = np.random.default_rng(1)
    rows = [{"t": 0.1 * i, "dt": 0.1, "D_xy": rng.random(), "custom": float(i)} for i in range(53)]
    snaps = [(0.5 * i, rng.normal(size=REST.shape)) for i in range(3)]
    summary = {"D_xy": 0.61, "steps": 53, "note": "steady", "history": np.arange(4.0), "ok": True}
    with _writer(path, attrs={"case_name": "x"}) as w:
        for i, row in enumerate(rows):
            w.append_step(row)
            if i % 20 == 0:
                w.append_snapshot(*snaps[i // 20])
        w.write_group("summary", summary)
        w.set_attrs(wall_time_s=1.5)
        w.close("completed")

    d = read_trajectory(path)
    assert d["attrs"]["status"] == "completed"
    assert d["attrs"]["status_reason"] == ""
    assert d["attrs"]["config_yaml"] == "name: x\n"
    assert d["attrs"]["capsim_version"] == "9.9"
    assert d["attrs"]["case_name"] == "x"
    assert d["attrs"]["wall_time_s"] == 1.5
    assert "created" in d["attrs"] and "finished" in d["attrs"]
    np.testing.assert_array_equal(d["elements"], ELEMENTS)
    np.testing.assert_array_equal(d["rest_positions"], REST)
    assert set(d["timeseries"]) == {"t", "dt", "D_xy", "custom"}
    for key in rows[0]:
        np.testing.assert_array_equal(d["timeseries"][key], [row[key] for row in rows])
    np.testing.assert_array_equal(d["snapshot_t"], [t for t, _ in snaps])
    np.testing.assert_array_equal(d["positions"], np.stack([p for _, p in snaps]))
    assert d["summary"]["note"] == "steady"
    assert d["summary"]["steps"] == 53 and d["summary"]["ok"] is True
    np.testing.assert_array_equal(d["summary"]["history"], np.arange(4.0))

    with h5py.File(path, "r") as f:
        # UDUNITS units, the capsim scale apart (issue 13: was units "k^-1")
        assert f["timeseries/t"].attrs["units"] == "1" and f["timeseries/t"].attrs["scale"] == "1/k"
        assert f["timeseries/D_xy"].attrs["units"] == "1"
        assert "units" not in f["timeseries/custom"].attrs
        assert f["mesh/positions"].chunks == (1, 18, 3)


def test_step_keys_must_stay_consistent(tmp_path):
    with _writer(tmp_path / "r.h5") as w:
        w.append_step({"t": 0.0, "D_xy": 0.0})
        with pytest.raises(ValueError, match="new"):
            w.append_step({"t": 0.1, "D_xy": 0.0, "theta": 0.7})
        with pytest.raises(ValueError, match="missing"):
            w.append_step({"t": 0.1})
        with pytest.raises(ValueError, match=r"new \['theta'\], missing \['D_xy'\]"):  # as many, not the same
            w.append_step({"t": 0.1, "theta": 0.7})
        w.append_step({"t": 0.1, "D_xy": 0.2, "_end_clearance": 3.0})  # the observer's own keys are no columns
        with pytest.raises(ValueError, match="shape"):
            w.append_snapshot(0.0, np.zeros((5, 3)))


@pytest.mark.parametrize(("exc", "status"), [(RuntimeError("boom"), "failed"), (KeyboardInterrupt(), "interrupted")])
def test_exception_marks_status(tmp_path, exc, status):
    path = tmp_path / "r.h5"
    with pytest.raises(type(exc)):
        with _writer(path) as w:
            w.append_step({"t": 0.0})
            raise exc
    d = read_trajectory(path)
    assert d["attrs"]["status"] == status
    if status == "failed":
        assert d["attrs"]["status_reason"] == "RuntimeError: boom"
    assert len(d["timeseries"]["t"]) == 1


def test_close_rejects_unknown_status(tmp_path):
    w = _writer(tmp_path / "r.h5")
    with pytest.raises(ValueError, match="status"):
        w.close("done")
    w.close("unstable", "area grew by 20%")
    w.close("completed")  # already closed: no effect
    d = read_trajectory(tmp_path / "r.h5")
    assert (d["attrs"]["status"], d["attrs"]["status_reason"]) == ("unstable", "area grew by 20%")


def test_read_errors_are_one_line(tmp_path):
    missing = tmp_path / "missing.h5"
    text = tmp_path / "text.h5"
    text.write_text("not hdf5")
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["x"] = 1
    good = tmp_path / "good.h5"
    with _writer(good) as w:
        w.append_step({"t": 0.0})
    truncated = tmp_path / "truncated.h5"
    truncated.write_bytes(good.read_bytes()[:1000])
    for path, words in [(missing, "no such file"), (text, "not an HDF5"), (other, "not a capsim"), (truncated, "")]:
        with pytest.raises(TrajectoryError) as info:
            read_trajectory(path)
        message = str(info.value)
        assert message.startswith(str(path)) and words in message and "\n" not in message


_KILLED_WRITER = textwrap.dedent(
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
        w.append_step({"t": 0.1 * i, "D_xy": 0.01 * i})
    print("ready", flush=True)
    time.sleep(60)
    """
)


def test_sigkilled_writer_leaves_readable_file(tmp_path):
    path = tmp_path / "killed.h5"
    proc = subprocess.Popen([sys.executable, "-c", _KILLED_WRITER, str(path)], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "ready"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        proc.stdout.close()
    assert proc.returncode == -signal.SIGKILL
    d = read_trajectory(path)
    assert d["attrs"]["status"] == "running"
    n = len(d["timeseries"]["t"])
    assert 40 <= n <= 47
    np.testing.assert_allclose(d["timeseries"]["D_xy"], 0.01 * np.arange(n))
    np.testing.assert_array_equal(d["positions"], np.ones((1, 18, 3)))


def test_named_group_writers_label_from_the_table(tmp_path):
    from capsim.quantities import GROUPS, attrs_for

    path = tmp_path / "g.h5"
    law = {"name": "skalak", "parameters": {"skalak_c": 5.0}, "G_s": 1 / 3, "K_s": 11 / 3,
           "poisson_ratio": 0.83, "ca_over_G": 3.0, "units": "E_s"}
    with _writer(path) as w:
        w.write_membrane_law(law)
        w.write_rest_shape({"volume": 4.18, "area": 12.5, "equal_volume_radius": 1.0, "sphericity": 1.0})
        w.write_run_record({"t": 1.0, "steps": 3, "D_xy": 0.1})
        w.write_group("summary", {"D_xy": 0.1, "motion": "steady", "note": "x"})  # goes to write_summary
        w.write_group("membrane_law", dict(law, name="thin_shell", parameters={"none": 0.0}))  # older callers
    with h5py.File(path, "r") as f:
        for name in ("membrane_law", "rest_shape", "run", "summary", "mesh", "timeseries"):
            assert f[name].attrs["definition"] == GROUPS[name]
        assert f["membrane_law/name"].asstr()[()] == "thin_shell"
        assert len(f["membrane_law/parameters"]) == 0 and "units" not in f["membrane_law"]
        assert f["membrane_law/K_s"].attrs["scale"] == "E_s"
        assert f["run/t"].attrs["long_name"] == attrs_for("t")["long_name"]
        assert f["summary/motion"].attrs["units"] == ""
        assert "units" not in f["summary/note"].attrs  # no entry: written unlabelled
        assert f["mesh/elements"].attrs["long_name"] == attrs_for("elements")["long_name"]


def test_error_estimate_group_and_scalar_readers(tmp_path):
    from capsim.storage.store import read_run_record, read_run_status, write_error_estimate

    path = tmp_path / "e.h5"
    with _writer(path) as w:
        for i in range(3):
            w.append_step({"t": float(i), "volume": 4.0 + i})
        w.write_run_record({"steps": 2})
    write_error_estimate(path, {"D_xy": 1.0, "coarse_level": 0})
    write_error_estimate(path, {"D_xy": 2e-3, "coarse_level": 1})  # replaces the group
    with h5py.File(path, "r") as f:
        assert set(f["error_estimate"]) == {"D_xy", "coarse_level"} and f["error_estimate/D_xy"][()] == 2e-3
        assert f["error_estimate/D_xy"].attrs["long_name"].startswith("error estimate of")
    record = read_run_record(path)
    assert record["n_steps"] == 3 and record["first"]["volume"] == 4.0 and record["last"]["t"] == 2.0
    assert record["run"] == {"steps": 2} and record["summary"] == {} and record["attrs"]["status"] == "completed"
    assert read_run_status(path) == "completed"
    (tmp_path / "junk.h5").write_bytes(b"not hdf5")
    assert read_run_record(tmp_path / "junk.h5") is None and read_run_status(tmp_path / "junk.h5") is None


def test_read_case_errors_are_one_line(tmp_path):
    from capsim.storage.store import read_case

    with pytest.raises(TrajectoryError, match="cannot read"):
        read_case(tmp_path / "none.h5")
    with h5py.File(tmp_path / "bare.h5", "w"):
        pass
    with pytest.raises(TrajectoryError, match="no config_yaml"):
        read_case(tmp_path / "bare.h5")


def test_rows_are_flushed_every_twenty_steps_once_a_second_has_passed(tmp_path, monkeypatch):
    """The buffered rows reach the file every _STEP_FLUSH_EVERY steps when _FLUSH_INTERVAL_S has passed
    since the last flush, or at _STEP_FLUSH_MAX rows whatever the time (issue 57: a fast run flushed ~70
    columns every 20 steps); a flush's rows are the file's, read back whole."""
    import capsim.storage.store as store

    monkeypatch.setattr(store, "_FLUSH_INTERVAL_S", 3600.0)
    monkeypatch.setattr(store, "_STEP_FLUSH_MAX", 50)
    path = tmp_path / "r.h5"
    with _writer(path) as w:
        for i in range(49):
            w.append_step({"t": 0.1 * i, "D_xy": 0.0})
        assert w._unflushed_steps == 49  # twenty steps are not enough within the hour
        w.append_step({"t": 4.9, "D_xy": 0.0})
        assert w._unflushed_steps == 0  # fifty are, whatever the time
        monkeypatch.setattr(store, "_FLUSH_INTERVAL_S", 0.0)
        for i in range(50, 70):
            w.append_step({"t": 0.1 * i, "D_xy": 0.0})
            assert w._unflushed_steps == (i - 49) % 20
        w.close("completed")
    np.testing.assert_allclose(read_trajectory(path)["timeseries"]["t"], 0.1 * np.arange(70))
