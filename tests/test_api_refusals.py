"""The Python library's refusals and promises (issue 38's findings): documented exception
classes with one-line messages (findings 7, 19), sweep and study from a plain script
(finding 12), error estimates of the window they sit beside (finding 14), a damaged
checkpoint called damaged (finding 20, part), and the API page's statements (finding 9, the
part in capsim/api.py). Tiny runs only (mesh level 0, kt <= 0.1)."""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

import capsim
from capsim import api
from capsim.storage.checkpoint import CheckpointError, ResumeError, load_end_state, read_checkpoint
from capsim.config import ConfigError
from capsim.storage.store import TrajectoryError, TrajectoryWriter, read_trajectory

ROOT = Path(__file__).resolve().parents[1]


def _one_line(exc: BaseException) -> str:
    text = str(exc)
    assert text and "\n" not in text, repr(text)
    return text


def _tiny(tmp_path: Path, name: str = "tiny", t_end: float = 0.05, **extra) -> dict:
    return {"name": name, "mesh": {"level": 0}, "time": {"t_end": t_end},
            "output": {"path": str(tmp_path / f"{name}.h5"), "snapshot_every": t_end}, **extra}


def _header_only_run_file(path: Path) -> None:
    """A capsim run file with three rows, written as a run writes one (no simulation needed)."""
    elements = np.array([[0, 1, 2, 3, 4, 5]], dtype=np.int64)
    rest = np.zeros((6, 3))
    writer = TrajectoryWriter(path, config_yaml=capsim.load_case({"name": "h"}).to_yaml(), elements=elements,
                              rest_positions=rest, version="test")
    for k in range(3):
        writer.append_step({"t": 0.1 * k, "D_xy": 0.01 * k})
    writer.close("completed")


# ---------------------------------------------------------------- finding 7


def test_summarize_of_a_directory_that_holds_no_campaign_is_a_config_error(tmp_path):
    (tmp_path / "runs").mkdir()
    with pytest.raises(ConfigError) as info:
        capsim.summarize(tmp_path / "runs")
    assert "not a campaign directory" in _one_line(info.value)
    with pytest.raises(ConfigError, match="no such directory"):
        capsim.summarize(tmp_path / "nowhere")


def test_run_refuses_overwrite_with_resume_before_anything(tmp_path):
    case = _tiny(tmp_path)
    with pytest.raises(ConfigError) as info:
        capsim.run(case, overwrite=True, resume=True)
    assert "overwrite and resume" in _one_line(info.value)
    assert not list(tmp_path.iterdir())  # nothing written, nothing computed


# ---------------------------------------------------------------- finding 12

_PLAIN_SCRIPT = """\
import capsim
done = capsim.sweep("camp.yaml", workers=2)
print("SWEEP", done["completed"], done["failed"], done["total"], flush=True)
ds = capsim.study({{"name": "s", "time": {{"t_end": {t_end}}}}}, levels=[0, 1], rtols=[1e-3], workers=2)
print("STUDY", " ".join(str(s) for s in ds["status"].values.ravel()), flush=True)
"""


def _python(script: Path, cwd: Path) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("CAPSIM_",))}
    env["PYTHONPATH"] = str(ROOT)
    return subprocess.run([sys.executable, str(script)], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=600, stdin=subprocess.DEVNULL)


def test_sweep_and_study_with_workers_run_from_a_plain_script(tmp_path):
    """The README's Python sweep as a plain script (no `if __name__ == "__main__":` guard):
    every run completes, once; the study with two workers too; no traceback."""
    t_end = 0.02
    (tmp_path / "camp.yaml").write_text(yaml.safe_dump({
        "name": "plain", "base": {"mesh": {"level": 0}, "time": {"t_end": t_end},
                                  "output": {"snapshot_every": t_end}},
        "sweep": {"flow.shear_rate_G": [0.05, 0.1]}, "output": {"dir": "out"}}))
    script = tmp_path / "plain.py"
    script.write_text(_PLAIN_SCRIPT.format(t_end=t_end))
    out = _python(script, tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "Traceback" not in out.stderr, out.stderr[-3000:]
    assert out.stdout.count("SWEEP") == 1 and "SWEEP 2 0 2" in out.stdout, out.stdout
    assert "STUDY completed completed" in out.stdout, out.stdout


def test_a_spawned_reimport_of_the_script_is_refused_in_one_line_naming_the_guard(tmp_path):
    """A pool of the script's own (spawn) runs the script again in its child: there sweep and
    study refuse, saying what to add, instead of starting the batch once more."""
    script = tmp_path / "own_pool.py"
    script.write_text(textwrap.dedent("""\
        import multiprocessing as mp
        import capsim
        from capsim.config import ConfigError

        def nothing():
            pass

        if __name__ == "__main__":
            child = mp.get_context("spawn").Process(target=nothing)
            child.start()
            child.join()
            print("PARENT", child.exitcode, flush=True)
        else:  # the child, importing this script again
            for call in (lambda: capsim.sweep("missing-campaign.yaml"),
                         lambda: capsim.study({"name": "x"}, levels=[0], workers=2)):
                try:
                    call()
                except ConfigError as exc:
                    print("REFUSED", exc, flush=True)
        """))
    out = _python(script, tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    refused = [line for line in out.stdout.splitlines() if line.startswith("REFUSED")]
    assert len(refused) == 2, out.stdout + out.stderr[-2000:]
    for line in refused:
        assert 'if __name__ == "__main__":' in line, line
    assert "capsim.sweep" in refused[0] and "capsim.study" in refused[1]
    assert "PARENT 0" in out.stdout


_DIE = "CAPSIM_TEST_WORKER_DIES_ON_IMPORT"
if os.environ.get(_DIE) and __import__("multiprocessing").current_process().name != "MainProcess":
    os._exit(3)  # a worker process importing this module (to unpickle _task) dies as it starts


def _task(item, progress):
    return {"status": "completed", "status_reason": ""}


def test_workers_that_die_as_they_start_leave_a_failed_record_for_every_item(monkeypatch):
    """Workers that die before running anything (pool after pool) used to leave items with no
    record at all: `completed 0, failed 0`, and a study's TypeError."""
    from capsim.campaigns.executor import run_batch

    monkeypatch.setenv(_DIE, "1")  # inherited by the workers, which die importing this module
    outcome = run_batch(["a"], _task, keys=["a"], workers=1,
                        failure=lambda i, status, reason: {"status": status, "status_reason": reason})
    assert [r is not None for r in outcome.records] == [True], outcome.records
    assert {r["status"] for r in outcome.records} == {"failed"}
    assert all("never started" in r["status_reason"] for r in outcome.records), outcome.records


# ---------------------------------------------------------------- finding 14


def test_an_extended_run_keeps_no_error_estimate_of_its_earlier_window(tmp_path):
    from capsim.storage.store import write_error_estimate
    from capsim.campaigns.summary import read_run

    case = _tiny(tmp_path, t_end=0.05)
    assert capsim.run(case).status == "completed"
    path = Path(case["output"]["path"])
    with h5py.File(path, "r") as f:
        last = float(f["timeseries/D_xy"][-1])
    write_error_estimate(path, {"D_xy": 1e-3, "D_xy_value": last, "coarse_level": 0})
    assert read_run(path)["D_xy_error_estimate"] == 1e-3  # of this window: reported
    longer = dict(case, time={"t_end": 0.1})
    assert capsim.run(longer, resume=True).status == "completed"
    with h5py.File(path, "r") as f:
        assert "error_estimate" not in f and "summary" in f
    assert math.isnan(read_run(path)["D_xy_error_estimate"])


def test_an_error_estimate_of_an_earlier_end_is_not_reported_beside_a_later_summary(tmp_path):
    """A file extended before the fix still holds the old window's estimate: its value at t_end
    is not the file's last row, so summarize leaves it out."""
    from capsim.storage.store import write_error_estimate
    from capsim.campaigns.summary import read_run

    path = tmp_path / "old.h5"
    _header_only_run_file(path)
    write_error_estimate(path, {"D_xy": 1e-3, "D_xy_value": 0.5, "coarse_level": 0})
    assert math.isnan(read_run(path)["D_xy_error_estimate"])


def test_the_error_estimate_at_level_0_says_what_it_lacks(tmp_path):
    """Level 0 has no coarser mesh: no total (the time part alone, ~1e-6, is no bound of an
    error ~1e-2), the time part kept, and no 'level -1' printed."""
    from capsim.campaigns.study import error_estimate, format_error_estimate

    case = capsim.load_case(_tiny(tmp_path, t_end=0.05))
    summary = capsim.run(case)
    est = error_estimate(case, summary, workers=1)
    for q in ("D_xy", "D_xy_mean"):
        assert math.isnan(est[q]) and math.isnan(est[f"{q}_mesh"]) and math.isfinite(est[f"{q}_time"]), est
    text = format_error_estimate(summary, est)
    assert "level -1" not in text
    assert "level 0 has no coarser mesh" in text.splitlines()[0]
    d_xy = next(line for line in text.splitlines() if line.strip().startswith("D_xy "))
    assert "± unknown" in d_xy and "mesh unknown" in d_xy, d_xy


# ---------------------------------------------------------------- finding 19


def test_open_run_refuses_what_is_not_a_capsim_run_file(tmp_path):
    import xarray as xr

    with h5py.File(tmp_path / "empty.h5", "w"):
        pass
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f["x"] = np.arange(3)
    xr.Dataset({"D_xy": ("G", [0.1, 0.2])}, attrs={"campaign_yaml": "name: c"}).to_netcdf(
        tmp_path / "summary.nc", engine="h5netcdf")
    for name, said in (("empty.h5", "empty"), ("other.h5", "not a capsim run file"),
                       ("summary.nc", "campaign summary")):
        with pytest.raises(TrajectoryError) as info:
            capsim.open_run(tmp_path / name)
        assert said in _one_line(info.value) and name in str(info.value)
        with pytest.raises(TrajectoryError):
            read_trajectory(tmp_path / name)
    _header_only_run_file(tmp_path / "run.h5")
    tree = capsim.open_run(tmp_path / "run.h5")
    assert list(tree["timeseries"]["D_xy"].values) == [0.0, 0.01, 0.02]


_WRITER = """\
import sys, numpy as np, capsim
from capsim.storage.files import FileLock
from capsim.storage.store import TrajectoryWriter
path, n = sys.argv[1], 500
with FileLock(path):
    w = TrajectoryWriter(path, config_yaml=capsim.load_case({"name": "h"}).to_yaml(),
                         elements=np.array([[0, 1, 2, 3, 4, 5]]), rest_positions=np.zeros((n, 3)), version="t")
    rng = np.random.default_rng(0)
    for k in range(40):
        if k == 3:  # three rows and snapshots on disk; the rest when the reader is half-way
            w.flush()
            print("ready", flush=True)
            sys.stdin.readline()
        w.append_step({"t": 0.1 * k, "D_xy": 0.0})
        w.append_snapshot(0.1 * k, rng.random((n, 3)))
    w.flush()
    print("appended", flush=True)
    sys.stdin.readline()
    w.close("completed")
"""


def test_a_healthy_file_read_while_its_writer_appends_is_read(tmp_path, monkeypatch):
    """The window held open by construction: the reader has opened the file and read its root
    when the writer (another process, holding the run file's lock) appends 37 snapshots; read in
    place, the reader then met a chunk past the end it saw ('addr overflow': 'truncated or
    corrupt?'). Read from an image of the file, it reads the file as it was when opened."""
    import capsim.storage.store

    path = tmp_path / "run.h5"
    writer = subprocess.Popen([sys.executable, "-c", _WRITER, str(path)], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        assert writer.stdout.readline().strip() == "ready"
        read_group = capsim.storage.store._group_dataset
        appended = []

        def midway(group):
            if not appended:  # once, after the file was opened and before its groups are read
                writer.stdin.write("go\n")
                writer.stdin.flush()
                appended.append(writer.stdout.readline().strip())
            return read_group(group)

        monkeypatch.setattr(capsim.storage.store, "_group_dataset", midway)
        tree = capsim.open_run(path)
        assert appended == ["appended"]
        n_snap = tree["mesh"]["positions"].shape[0]
        assert n_snap in (3, 40) and tree["timeseries"]["t"].size == n_snap  # one consistent state
    finally:
        writer.communicate("end\n", timeout=60)


def test_a_file_being_written_is_read_or_said_to_be_being_written_never_corrupt(tmp_path, monkeypatch):
    """Held by its writer (another process holds the run file's lock), a file read at a moment
    its metadata is half-flushed is read again, and if it stays unreadable, refused as being
    written. The writer's window is held open by construction: it holds the lock until told."""
    import capsim.storage.store

    monkeypatch.setattr(capsim.storage.store, "_BUSY_WAIT_S", 0.01, raising=False)  # a quick retry
    path = tmp_path / "run.h5"
    _header_only_run_file(path)
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys; from capsim.storage.files import FileLock\n"
         f"with FileLock({str(path)!r}):\n    print('held', flush=True); sys.stdin.read()"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        assert holder.stdout.readline().strip() == "held"
        assert capsim.open_run(path)["timeseries"]["t"].size == 3  # readable: read
        whole = path.read_bytes()
        path.write_bytes(whole[: len(whole) // 2])  # as a reader may meet it mid-flush
        for read in (capsim.open_run, read_trajectory):
            with pytest.raises(TrajectoryError) as info:
                read(path)
            line = _one_line(info.value)
            assert "being written" in line and f"process {holder.pid}" in line and "corrupt" not in line, line
    finally:
        holder.communicate("", timeout=60)
    with pytest.raises(TrajectoryError, match="truncated or corrupt"):  # no writer: damaged it is
        capsim.open_run(path)


def test_summarize_of_a_file_says_a_directory_is_expected(tmp_path):
    run = tmp_path / "run.h5"
    _header_only_run_file(run)
    with pytest.raises(ConfigError) as info:
        capsim.summarize(run)
    assert "a directory of run files" in _one_line(info.value) and "got a file" in str(info.value)


_SMALL = {"name": "x", "time": {"t_end": 0.01}}  # were a refusal missing, the study would be tiny


@pytest.mark.parametrize("call, name", [
    (lambda tmp: capsim.summarize(tmp, units="bogus"), "units"),
    (lambda tmp: capsim.study(_SMALL, levels=[], rtols=[1e-3]), "levels"),
    (lambda tmp: capsim.study(_SMALL, levels=[0], rtols="1e-3"), "rtols"),
    (lambda tmp: capsim.study(_SMALL, levels=[0.5], rtols=[1e-3]), "levels"),
    (lambda tmp: capsim.study(_SMALL, levels=[0], rtols=[1e-3], workers=0), "workers"),
    (lambda tmp: capsim.study(_SMALL, levels=[0], rtols=[1e-3], runs_dir=5), "runs_dir"),
    (lambda tmp: capsim.summarize(tmp, output=5), "output"),
    (lambda tmp: capsim.sweep(5), "campaign"),
    (lambda tmp: capsim.open_run(5), "path"),
    (lambda tmp: capsim.warm_up(5), "cases"),
    (lambda tmp: capsim.load_campaign(tmp / "c.yaml", max_runs="5"), "max_runs"),
])
def test_a_bad_argument_is_a_config_error_naming_it(tmp_path, call, name):
    with pytest.raises(ConfigError) as info:
        call(tmp_path)
    assert _one_line(info.value).startswith(f"{name} = ")


def test_a_single_set_text_is_a_list_of_one():
    assert capsim.load_case({"name": "x"}, sets="mesh.level=1").mesh.level == 1


def test_a_single_case_path_to_warm_up_is_a_list_of_one(tmp_path):
    with pytest.raises(ConfigError) as info:
        capsim.warm_up(str(tmp_path / "missing.yaml"))
    assert "missing.yaml: no such file" in _one_line(info.value)


def test_a_single_input_path_is_that_file_not_its_characters(tmp_path):
    from capsim.storage.files import OutputError

    precious = tmp_path / "notes.txt"
    precious.write_text("mine")
    case = {**_tiny(tmp_path), "output": {"path": str(precious)}}
    with pytest.raises(OutputError) as info:
        capsim.run(case, overwrite=True, inputs=str(precious))
    assert "input" in _one_line(info.value)
    assert precious.read_text() == "mine"


@pytest.mark.parametrize("workers", [0, -1, 2.5, True])
def test_sweep_refuses_the_workers_the_cli_refuses(tmp_path, workers):
    campaign = tmp_path / "camp.yaml"
    campaign.write_text(yaml.safe_dump({"name": "w", "base": {"mesh": {"level": 0}, "time": {"t_end": 0.02}},
                                        "sweep": {"flow.shear_rate_G": [0.05]},
                                        "output": {"dir": str(tmp_path / "out")}}))
    with pytest.raises(ConfigError) as info:
        capsim.sweep(campaign, workers=workers)
    assert _one_line(info.value).startswith("workers = ")
    assert not (tmp_path / "out").exists()  # refused before anything ran


# ---------------------------------------------------------------- finding 20 (part)


@pytest.mark.parametrize("garbage", [b"\x80\x04garbage that is no archive" * 8, b""])
def test_a_damaged_checkpoint_or_end_state_is_called_damaged_never_loaded_unsafely(tmp_path, garbage):
    ckpt = tmp_path / "run.h5.ckpt.npz"
    ckpt.write_bytes(garbage)
    with pytest.raises(CheckpointError) as info:
        read_checkpoint(ckpt)
    line = _one_line(info.value)
    assert "damaged" in line and "--overwrite" in line
    assert not re.search(r"pickle|unsafe", line, re.I), line
    case = capsim.load_case({"name": "x"})
    with pytest.raises(ResumeError) as info:
        load_end_state(garbage, tmp_path / "run.h5", case)
    line = _one_line(info.value)
    assert "damaged" in line and not re.search(r"pickle|unsafe", line, re.I), line


# ---------------------------------------------------------------- the API page (api.py's docstrings)


def _docstrings() -> str:
    return "\n".join([api.__doc__ or ""] + [getattr(api, n).__doc__ or "" for n in api.__all__]
                     + [capsim.campaigns.study.study.__doc__ or ""])


def test_the_api_docstrings_are_markdown_not_rest():
    """mkdocstrings renders them as Markdown: a reST role or table shows raw on the page."""
    text = _docstrings()
    assert not re.search(r":(func|class|mod|data|meth):`", text), re.findall(r":\w+:`[^`]*`", text)[:5]
    assert not re.search(r"^\s*=+\s+=+", text, re.M)


def test_the_api_docstrings_cite_groups_and_dimensions_the_files_have(tmp_path):
    from capsim.quantities import GROUPS
    from capsim.campaigns.summary import _dim_names

    text = _docstrings()
    for group in re.findall(r"`/(\w+)`", text):
        assert group in GROUPS, f"/{group} is no group of a run file"
    assert "/snapshots" not in text
    summarize_doc = api.summarize.__doc__
    for dim in _dim_names(["flow.shear_rate_G", "flow.viscosity_ratio"]).values():
        assert f"`{dim}`" in summarize_doc
    assert "`G`" not in summarize_doc and "`lam`" not in summarize_doc
    for exc in ("ConfigError", "OutputError", "LockedError", "StorageError", "ResumeError", "TrajectoryError"):
        assert exc in api.__doc__
