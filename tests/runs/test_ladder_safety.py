"""The accuracy ladder's data safety and verdicts (issue 51, findings 7, 8, 9 and 13): it holds its
output's lock from start to end, a signal leaves an honest and (at level 1) resumable file, nothing
hidden stays beside the output, and how it ended is its status and exit code, not 'completed' for all."""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys

import h5py
import numpy as np
import pytest

from capsim.storage.checkpoint import checkpoint_path
from capsim.config import apply_overrides, case_from_dict
from capsim.storage.files import FileLock, LockedError, StorageError
from capsim.runs.runner import run_ladder as run_measured
from capsim.runs.runner import run_case
from capsim.storage.store import read_case

TARGET = {"quantity": "D_xy", "target": 0.05, "method": "measure"}


def _case(path, t_end=0.5, **target):
    return case_from_dict({"name": "l", "time": {"t_end": t_end}, "output": {"path": str(path)},
                           "accuracy": {**TARGET, **target}})


def _hidden(directory):
    return sorted(p.name for p in directory.iterdir() if p.name.startswith("."))


def _at_level(level, act):
    """run_one for run_measured: at `level`, ``act(case, state)`` at the third accepted step."""
    def run_one(case, progress=None, overwrite=True):
        def hook(state):
            if case.mesh.level == level and state["step"] == 3:
                act(case, state)
        return run_case(case, progress=hook, overwrite=overwrite)
    return run_one


def test_the_ladder_holds_its_outputs_lock_across_levels(tmp_path):
    """Finding 7. A run into the ladder's output between (or during) its levels is refused by the
    output's lock, not replaced by the next level (before, the ladder took the lock only for each
    rename: that run completed into the path and was then replaced). A lock held before the ladder
    starts refuses it with nothing written, no hidden level file beside."""
    out = tmp_path / "lad.h5"
    refused = []

    def intruder(case, state):
        other = apply_overrides(case_from_dict({"name": "x", "time": {"t_end": 0.1}, "mesh": {"level": 0}}),
                                **{"output.path": str(out)})
        with pytest.raises(LockedError) as err:
            run_case(other, overwrite=True)  # `capsim run X -o lad.h5 --overwrite` meanwhile
        refused.append(str(err.value))
        with pytest.raises(LockedError):
            run_measured(_case(out), run_case)  # a second ladder on the same output

    result = run_measured(_case(out, max_level=2), _at_level(2, intruder))
    assert len(refused) == 1 and "in use by another capsim process" in refused[0]
    assert result.status == "completed" and read_case(out).mesh.level == 2 and read_case(out).name == "l"
    assert _hidden(tmp_path) == []

    held = tmp_path / "held.h5"
    with FileLock(held), pytest.raises(LockedError):
        run_measured(_case(held), run_case)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lad.h5"]


def test_sigterm_during_level_1_leaves_a_resumable_run_and_during_level_2_says_interrupted(tmp_path):
    """Finding 8 (and 13's interrupted ladder). SIGTERM during level 1: status 'interrupted', the
    level-1 run at the output with its checkpoint (before, the checkpoint was deleted and --resume
    failed), and ``run_case(read_case(out), resume=True)`` completes it. SIGTERM during level 2:
    status 'interrupted' (before: 'completed'), the output level 1's completed run, NOT met."""
    def term(case, state):
        os.kill(os.getpid(), signal.SIGTERM)

    out = tmp_path / "one.h5"
    first = run_measured(_case(out), _at_level(1, term))
    assert first.status == "interrupted" and "SIGTERM" in first.status_reason
    assert checkpoint_path(out).exists() and _hidden(tmp_path) == []  # before: the checkpoint was deleted
    assert f"capsim run {out} --resume" in first.status_reason and "target unchecked" in first.accuracy
    assert first.accuracy_met is False
    resumed = run_case(read_case(out), resume=True)
    assert resumed.status == "completed" and resumed.t == pytest.approx(0.5)

    out2 = tmp_path / "two.h5"
    second = run_measured(_case(out2), _at_level(2, term))
    assert second.status == "interrupted" and second.accuracy_met is False
    assert "keeps level 1" in second.status_reason and "interrupted" in second.accuracy
    with h5py.File(out2) as f:
        assert f.attrs["status"] == "completed" and not bool(f["accuracy/met"][()])
        assert "SIGTERM" in f["accuracy/verdict"][()].decode()
    assert not checkpoint_path(out2).exists() and _hidden(tmp_path) == []


def test_a_later_ladder_removes_what_a_killed_one_left_and_a_raising_one_leaves_nothing(tmp_path):
    """Finding 9. The hidden files of a ladder killed with -9 (its level file, checkpoint, lock and
    temporary copy, named with its dead pid) are removed by the next ladder on that output; those of
    a live process stay. A ladder whose level raises after writing (a second Ctrl-C while the level
    closes) leaves no hidden file (before, its level file stayed)."""
    out = tmp_path / "lad.h5"
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    stale = [f".lad.h5.ladder-{dead}.h5", f".lad.h5.ladder-{dead}.h5.ckpt.npz",
             f"..lad.h5.ladder-{dead}.h5.capsim-lock", f"..lad.h5.ladder-{dead}.tmp-{dead}.h5"]
    live = f".lad.h5.ladder-{os.getppid()}.h5"  # a process that exists: never touched
    for name in stale + [live, ".other.h5.ladder-1.h5"]:
        (tmp_path / name).write_bytes(b"x" * 1000)
    result = run_measured(_case(out, max_level=2), run_case)
    assert result.path == str(out)
    assert _hidden(tmp_path) == sorted([live, ".other.h5.ladder-1.h5"])

    def second_ctrl_c(case, progress=None, overwrite=True):
        ran = run_case(case, overwrite=overwrite)
        if case.mesh.level == 2:
            raise KeyboardInterrupt  # after the level's file was written, before the ladder kept it
        return ran

    other = tmp_path / "k" / "k.h5"
    other.parent.mkdir()
    with pytest.raises(KeyboardInterrupt):
        run_measured(_case(other), second_ctrl_c)
    assert [p.name for p in other.parent.iterdir()] == ["k.h5"] and read_case(other).mesh.level == 1


def test_a_full_disk_says_what_stays_and_never_that_the_ladder_resumes(tmp_path):
    """Finding 13 (the disk-full message). A level's write failing (ENOSPC) ends the ladder with
    StorageError (exit 2) naming the output, not the hidden level file; at level 2 it says the output
    keeps level 1 and that a ladder is not resumed (before: '--resume continues', of a removed file)."""
    def full(case, state):
        raise OSError(errno.ENOSPC, "No space left on device")

    out = tmp_path / "lad.h5"
    with pytest.raises(StorageError) as err:
        run_measured(_case(out), _at_level(2, full))
    text = str(err.value)
    assert "No space left" in text and "keeps level 1" in text and "not resumed" in text
    assert "--resume continues" not in text and ".ladder-" not in text
    assert read_case(out).mesh.level == 1 and _hidden(tmp_path) == []
    first = tmp_path / "first.h5"
    with pytest.raises(StorageError) as err:
        run_measured(_case(first), _at_level(1, full))
    assert ".ladder-" not in str(err.value) and str(first) in str(err.value) and "not resumed" in str(err.value)
    assert _hidden(tmp_path) == []


def test_a_target_not_met_exits_3_and_the_summary_says_whether_it_was_met(tmp_path):
    """Finding 13. ``capsim run`` of a measured target NOT met by max_level exits 3 (before: 0), the
    file 'completed' and its verdict NOT met; a campaign summary's ``accuracy_target_met`` reads 0
    for it, 1 for a target met and NaN for a run without a measured target."""
    from capsim.campaigns.summary import read_run

    path = tmp_path / "c.yaml"
    path.write_text(f"name: c\ntime: {{t_end: 0.5}}\noutput: {{path: {tmp_path / 'c.h5'}}}\n")
    out = subprocess.run([sys.executable, "-m", "capsim.face.cli", "run", str(path), "--accuracy", "D_xy=1e-6", "--set",
                          "accuracy.method=measure", "--set", "accuracy.max_level=2", "-q"],
                         capture_output=True, text=True)
    assert out.returncode == 3, out.stderr
    assert out.stdout.strip().splitlines()[-1].startswith("accuracy D_xy 1e-06: level 2")
    assert "NOT met" in out.stdout.strip().splitlines()[-1]
    assert read_run(tmp_path / "c.h5")["accuracy_target_met"] == 0.0
    met = run_measured(_case(tmp_path / "m.h5", target=0.5, max_level=2), run_case)
    assert met.accuracy_met is True and read_run(tmp_path / "m.h5")["accuracy_target_met"] == 1.0
    plain = run_case(case_from_dict({"name": "p", "time": {"t_end": 0.1}, "mesh": {"level": 0},
                                     "output": {"path": str(tmp_path / "p.h5")}}))
    assert plain.status == "completed" and np.isnan(read_run(tmp_path / "p.h5")["accuracy_target_met"])


def test_a_plain_run_on_the_output_also_removes_a_killed_ladders_files(tmp_path):
    """Finding 9, the other way in: ``capsim run X -o lad.h5 --overwrite`` after a ladder on lad.h5
    was killed with -9 removes its hidden files of the dead process (before, they stayed for ever)."""
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    for name in (f".lad.h5.ladder-{dead}.h5", f".lad.h5.ladder-{dead}.h5.ckpt.npz"):
        (tmp_path / name).write_bytes(b"x" * 1000)
    run_case(case_from_dict({"name": "p", "time": {"t_end": 0.05}, "mesh": {"level": 0},
                             "output": {"path": str(tmp_path / "lad.h5")}}))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lad.h5"]


def test_a_signal_between_two_levels_stops_the_ladder_before_the_next(tmp_path):
    """SIGTERM after level 1 completed and before level 2 starts (the ladder's own handler, not a
    level's): level 2 is not started, status 'interrupted', level 1 kept (before, SIGTERM there
    killed the process outright, leaving its hidden files)."""
    def then_term(case, progress=None, overwrite=True):
        ran = run_case(case, overwrite=overwrite)
        if case.mesh.level == 1:
            os.kill(os.getpid(), signal.SIGTERM)
        return ran

    def unhandled(signum, frame):  # what the test sees where no ladder handles it (the old tree: the process died)
        raise RuntimeError("SIGTERM reached the default handler")

    out = tmp_path / "b.h5"
    before = signal.signal(signal.SIGTERM, unhandled)
    try:
        result = run_measured(_case(out), then_term)
    finally:
        signal.signal(signal.SIGTERM, before)
    assert result.status == "interrupted" and "before level 2 started" in result.accuracy
    assert read_case(out).mesh.level == 1 and _hidden(tmp_path) == []
