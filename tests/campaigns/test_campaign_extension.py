"""Campaign extension under hostile input (issue 51, findings 10, 11 and the flow.G sweep of 14):
a shortened t_end refused before anything is written, a campaign of accuracy targets extended (or,
measured, refused with the reason), a sweep over a field's short name, and a sweep that Ctrl-C
(twice, or while its pool starts) and a forwarded SIGINT stop promptly and cleanly."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml

from capsim.campaigns.campaign import (
    campaign_from_dict, expand_campaign, load_campaign_with, plan_lines, run_campaign,
)
from capsim.config import ConfigError
from capsim.campaigns.summary import summarize_campaign

ROOT = Path(__file__).resolve().parents[2]


def tiny(out_dir, t_end=0.05, **base):
    """One level-0 sphere run (a second or two)."""
    return {
        "name": "ext",
        "base": {"shape": {"kind": "sphere"}, "mesh": {"level": 0}, "time": {"t_end": t_end},
                 "flow": {"shear_rate_G": 0.1}, **base},
        "sweep": {"flow.viscosity_ratio": [1.0]},
        "output": {"dir": str(out_dir)},
    }


def with_t_end(d: dict, t_end: float) -> dict:
    d = yaml.safe_load(yaml.safe_dump(d))
    d["base"]["time"]["t_end"] = t_end
    return d


def snapshot(directory: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(directory.iterdir()) if not p.name.startswith(".")}


# ---------------------------------------------------------------- finding 10


def test_a_shortened_t_end_is_refused_before_anything_is_written(tmp_path):
    out = tmp_path / "c"
    first = campaign_from_dict(tiny(out, t_end=0.1))
    assert run_campaign(first, workers=1)["completed"] == 1
    before = snapshot(out)
    shorter = campaign_from_dict(with_t_end(tiny(out), 0.05))
    with pytest.raises(ConfigError) as info:
        run_campaign(shorter, workers=1)
    text = str(info.value)
    assert "\n" not in text
    assert "time.t_end = 0.05" in text and "already run to kt 0.1" in text and "not an extension" in text
    assert "nothing was changed" in text and "--overwrite" in text and "another output.dir" in text
    assert snapshot(out) == before  # campaign.yaml, runs.json and the run file, byte for byte
    # the dry run says the same, run by run
    lines = plan_lines(shorter)
    assert lines[1].split()[1] == "refused" and lines[-1] == f"refused: {text}"
    # summarize still finds the completed run (never foreign, never NaN)
    ds = summarize_campaign(out)
    assert str(ds["status"].values.ravel()[0]) == "completed"
    assert np.isfinite(ds["D_xy"].values).all()


def test_a_predicted_accuracy_target_campaign_extends_in_place(tmp_path):
    out = tmp_path / "acc"
    target = {"accuracy": {"quantity": "D_xy", "target": 0.2, "method": "predict"}}
    d = tiny(out, t_end=0.05, **target)
    del d["base"]["mesh"]  # the target picks the level
    assert run_campaign(campaign_from_dict(d), workers=1)["completed"] == 1
    longer = campaign_from_dict(with_t_end(d, 0.1))
    (spec,) = expand_campaign(longer)
    assert plan_lines(longer)[1].split()[1] == "extend"  # what validate lists is what sweep does
    result = run_campaign(longer, workers=1)
    assert (result["completed"], result["failed"]) == (1, 0), result["records"]
    with h5py.File(spec.path, "r") as f:
        assert "resumed" in f.attrs  # extended, not redone
        stored = yaml.safe_load(f.attrs["config_yaml"])
        t = f["timeseries"]["t"][:]
    assert stored["time"]["t_end"] == 0.1 and math.isclose(t[-1], 0.1)
    assert stored["accuracy"]["choice"] == spec.case().accuracy.choice  # the prediction to the new t_end
    assert run_campaign(longer, workers=1)["skipped"] == 1
    assert str(summarize_campaign(out)["status"].values.ravel()[0]) == "completed"
    # the same t_end with another explanation of the choice (say a newer capsim's) is no extension:
    # foreign, never resumed or replaced unasked
    from capsim.campaigns.campaign import FOREIGN, _file_status

    stored["accuracy"]["choice"] += " (reworded)"
    with h5py.File(spec.path, "r+") as f:
        f.attrs["config_yaml"] = yaml.safe_dump(stored)
    assert _file_status(spec) == FOREIGN


def test_a_measured_accuracy_target_campaign_is_refused_with_the_reason(tmp_path):
    out = tmp_path / "measured"
    d = tiny(out, t_end=0.05, accuracy={"quantity": "D_xy", "target": 0.2, "method": "measure"})
    del d["base"]["mesh"]
    assert run_campaign(campaign_from_dict(d), workers=1)["completed"] == 1
    before = snapshot(out)
    longer = campaign_from_dict(with_t_end(d, 0.1))
    with pytest.raises(ConfigError) as info:
        run_campaign(longer, workers=1)
    assert "measured accuracy target" in str(info.value) and "measured the error at kt 0.05" in str(info.value)
    assert snapshot(out) == before
    assert plan_lines(longer)[1].split()[1] == "refused"


# ---------------------------------------------------------------- finding 14: flow.G


@pytest.mark.parametrize("swept, base", [("flow.G", {"shear_rate_G": 0.1}), ("flow.shear_rate_G", {"G": 0.1})])
def test_a_sweep_over_a_short_name_replaces_the_bases_long_one(tmp_path, swept, base):
    d = tiny(tmp_path)
    d["base"]["flow"] = base
    d["sweep"] = {swept: [0.05, 0.2]}
    specs = expand_campaign(campaign_from_dict(d))
    assert [s.case().flow.shear_rate_G for s in specs] == [0.05, 0.2]
    other = dict(d, sweep={"flow.shear_rate_G" if swept == "flow.G" else "flow.G": [0.05, 0.2]})
    # one field by either name: the same cases, the same digests
    assert [s.digest() for s in expand_campaign(campaign_from_dict(other))] == [s.digest() for s in specs]
    # and the same summary dimension (what plot --kind steady takes as G), before any run
    from capsim.campaigns.campaign import _Index, campaign_digest

    campaign = campaign_from_dict(d)
    tmp_path.mkdir(exist_ok=True)
    (tmp_path / "campaign.yaml").write_text(campaign.to_yaml())
    _Index(tmp_path, expand_campaign(campaign), campaign_digest(campaign)).write()
    ds = summarize_campaign(tmp_path)
    assert list(ds.sizes) == ["shear_rate_G"] and list(ds["shear_rate_G"].values) == [0.05, 0.2]
    assert ds["shear_rate_G"].attrs["case_field"] == swept and ds["shear_rate_G"].attrs["units"] == "1"


def test_one_field_by_two_names_is_refused(tmp_path):
    d = tiny(tmp_path)
    d["sweep"] = {"flow.G": [0.05, 0.2], "flow.shear_rate_G": [0.1]}
    with pytest.raises(ConfigError, match="flow.G and flow.shear_rate_G name one field"):
        campaign_from_dict(d)
    path = tmp_path / "c.yaml"
    d["sweep"] = {"flow.shear_rate_G": [0.05, 0.2]}
    path.write_text(yaml.safe_dump(d))
    with pytest.raises(ConfigError, match="--set flow.G: the campaign sweeps this field"):
        load_campaign_with(path, ["flow.G=0.3"])


# ---------------------------------------------------------------- finding 11: signals on a running sweep


def _long_campaign(tmp_path, t_end=50.0) -> Path:
    d = tiny(tmp_path / "c", t_end=t_end)
    d["base"]["time"]["rtol"] = 1e-5  # long enough to be stopped
    d["sweep"] = {"flow.viscosity_ratio": [1.0, 2.0, 3.0]}
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(d))
    return path


def _start_sweep(path: Path, *extra: str, env: dict | None = None) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "capsim.face.cli", "sweep", str(path), "--workers", "2", "-q", *extra],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT, env=env,
        start_new_session=True,  # its own process group: what Ctrl-C in a terminal signals
        # Ctrl-C's disposition, however the tests were started (a background job inherits SIGINT ignored)
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def _children(pid: int) -> list[str]:
    """Command lines of the processes whose parent is `pid` (Linux /proc)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            if ppid == pid:
                found.append((entry / "cmdline").read_bytes().replace(b"\0", b" ").decode())
        except (OSError, IndexError, ValueError):
            continue
    return found


def _wait_for(condition, proc: subprocess.Popen, seconds: float = 240.0) -> None:
    deadline = time.monotonic() + seconds
    while not condition():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the sweep never got there"
        time.sleep(0.005)


def _ends_promptly(proc: subprocess.Popen, seconds: float = 30.0) -> str:
    """The sweep's stderr, once it and every process of its group (workers, resource tracker)
    ended within `seconds` of the signal; killed and failed otherwise."""
    try:
        _, err = proc.communicate(timeout=seconds)
        deadline = time.monotonic() + 5.0
        while True:  # the workers and the resource tracker too
            try:
                os.killpg(proc.pid, 0)
            except ProcessLookupError:
                break
            assert time.monotonic() < deadline, "processes of the sweep outlived it"
            time.sleep(0.05)
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    assert "Traceback" not in err and "RuntimeError" not in err, err
    return err


pytestmark_linux = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")


@pytestmark_linux
def test_ctrl_c_twice_10_ms_apart_stops_a_running_sweep_at_once(tmp_path):
    path = _long_campaign(tmp_path)
    out = tmp_path / "c"
    proc = _start_sweep(path)
    _wait_for(lambda: len(list(out.glob("*.h5"))) >= 2, proc)  # two runs under way
    os.killpg(proc.pid, signal.SIGINT)
    time.sleep(0.01)
    os.killpg(proc.pid, signal.SIGINT)
    _ends_promptly(proc)
    assert proc.returncode == 1
    statuses = []
    for run in out.glob("*.h5"):
        with h5py.File(run, "r") as f:
            statuses.append((str(f.attrs["status"]), str(f.attrs["status_reason"])))
    assert len(statuses) >= 2 and all(s == "interrupted" and "SIGINT" in r for s, r in statuses), statuses


@pytest.mark.slow
@pytestmark_linux
def test_ctrl_c_while_the_worker_pool_starts_stops_the_sweep(tmp_path):
    path = _long_campaign(tmp_path)
    proc = _start_sweep(path)
    # the first worker process exists: it is starting (importing capsim) now
    _wait_for(lambda: any("spawn_main" in c for c in _children(proc.pid)), proc)
    os.killpg(proc.pid, signal.SIGINT)
    _ends_promptly(proc)
    assert proc.returncode == 1


@pytest.mark.slow
@pytestmark_linux
def test_sigint_to_the_sweep_alone_during_its_warm_up_stops_an_extension(tmp_path):
    """What `timeout -s INT` does: the signal reaches the sweep's process alone. Here it lands
    while the sweep warms its kernels up (a tiny run in a capsim-warm-* directory), whose
    run took the signal as its own and the sweep then ran on for the whole extension."""
    path = _long_campaign(tmp_path, t_end=0.02)
    out = tmp_path / "c"
    first = _start_sweep(path)
    assert first.wait(timeout=300) == 0, first.communicate()
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    proc = _start_sweep(path, "--set", "time.t_end=50", env={**os.environ, "TMPDIR": str(tmp)})
    _wait_for(lambda: any(p.name.startswith("capsim-warm-") for p in tmp.iterdir()), proc)
    os.kill(proc.pid, signal.SIGINT)
    _ends_promptly(proc)
    assert proc.returncode == 1
    for run in out.glob("*.h5"):  # each still the completed run it was, or stopped in its extension
        with h5py.File(run, "r") as f:
            assert str(f.attrs["status"]) in ("completed", "interrupted")
