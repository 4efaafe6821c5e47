"""`capsim run --resume --t-end T` extends a completed run (issue 30, finding 5)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from capsim.face.cli import app
from capsim.config import apply_overrides, case_from_dict
from capsim.runs.runner import ResumeError, run_case
from capsim.storage.store import checkpoint_path, read_trajectory


def _case(tmp_path: Path, t_end: float, name: str = "extend"):
    return case_from_dict({
        "name": "extend", "flow": {"shear_rate_G": 0.2}, "mesh": {"level": 0}, "time": {"t_end": t_end},
        "output": {"path": str(tmp_path / f"{name}.h5"), "snapshot_every": 0.2, "checkpoint_every_steps": 4},
    })


def _extend_cli(case_file: Path, *args: str):
    return CliRunner().invoke(app, ["run", str(case_file), "-q", "--resume", *args])


@pytest.fixture(scope="module")
def completed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("extend")
    case = _case(tmp, 0.4)
    assert run_case(case)["status"] == "completed"
    case_file = tmp / "case.yaml"
    case_file.write_text(case.to_yaml())
    return tmp, case, case_file


def test_a_completed_run_extended_is_the_longer_run(completed, tmp_path):
    tmp, case, case_file = completed
    assert not checkpoint_path(case.output.path).exists()
    result = _extend_cli(case_file, "--t-end", "0.8")
    assert result.exit_code == 0, result.output
    reference = run_case(_case(tmp_path, 0.8, "reference"))
    got, want = read_trajectory(case.output.path), read_trajectory(reference["path"])
    assert got["attrs"]["status"] == "completed"
    assert len(got["timeseries"]["t"]) == len(want["timeseries"]["t"])  # appended to the same file
    for key in ("t", "D_xy", "theta", "volume"):
        np.testing.assert_allclose(got["timeseries"][key], want["timeseries"][key], rtol=0, atol=1e-10, err_msg=key)
    np.testing.assert_array_equal(got["snapshot_t"], want["snapshot_t"])
    np.testing.assert_allclose(got["positions"], want["positions"], rtol=0, atol=1e-10)
    assert not checkpoint_path(case.output.path).exists()
    # and once more, from the extended run's own end state
    assert _extend_cli(case_file, "--t-end", "1.0").exit_code == 0
    assert read_trajectory(case.output.path)["timeseries"]["t"][-1] == pytest.approx(1.0)


def test_an_extension_to_an_earlier_time_or_another_case_is_refused(tmp_path):
    case = _case(tmp_path, 0.4)
    run_case(case)
    before = Path(case.output.path).read_bytes()
    with pytest.raises(ResumeError, match=r"already reached kt = 0.4; time.t_end = 0.4 must be later"):
        run_case(case, resume=True)
    with pytest.raises(ResumeError, match="belongs to another case: flow.shear_rate_G"):
        run_case(apply_overrides(case, **{"flow.shear_rate_G": 0.1, "time.t_end": 0.8}), resume=True)
    case_file = tmp_path / "case.yaml"
    case_file.write_text(case.to_yaml())
    result = _extend_cli(case_file, "--t-end", "0.2")
    assert result.exit_code == 2 and len(result.stderr.strip().splitlines()) == 1, result.output
    assert "must be later to extend it (--t-end)" in result.stderr
    assert Path(case.output.path).read_bytes() == before  # refused before touching anything
