"""A benchmark never writes a partial run as a row (noticed in issue 28): run_case returns a
run a signal or the wall-time limit stopped, with status "interrupted"; the scripts'
run_or_stop (benchmarks/_common.py) ends the script there instead."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from capsim.config import case_from_dict

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from _common import run_or_stop  # noqa: E402


def _case(tmp_path, **time):
    return case_from_dict({"name": "b", "mesh": {"level": 0}, "time": {"t_end": 0.2, **time},
                           "output": {"path": str(tmp_path / "b.h5")}})


def test_an_interrupted_run_ends_the_benchmark(tmp_path):
    with pytest.raises(SystemExit, match="no table written"):
        run_or_stop(_case(tmp_path, max_wall_s=1e-9))  # stopped at its first check, as by a SIGTERM


def test_a_completed_run_is_returned(tmp_path):
    assert run_or_stop(_case(tmp_path))["status"] == "completed"
