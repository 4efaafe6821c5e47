"""Every script of examples/ runs, at the tests' tiny size (CAPSIM_EXAMPLES_TINY=1: mesh level
0-1, kt <= 0.2), in a fresh process as a user runs it, writes what it says and is shown in
docs/examples.md."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted(p for p in (ROOT / "examples").glob("*.py") if not p.name.startswith("_"))
# what each example must leave behind (relative to its output folder) and print
EXPECTED = {
    "run_and_plot": (["sphere.h5", "sphere_deformation.png"], "completed: D_xy = "),
    "sweep_and_summary": (["sweep/summary.nc"], "4 runs: 4 completed"),
    "red_cell_units": (["rbc.h5"], "G = 0.0448, Ca = 0.1344, time unit 1/k = 10 ms"),
    "accuracy_study": (["study.nc", "study.png"], "reference (finest)"),
    "paraview_export": (["export_xdmf/export.xdmf"], "open "),
}


def test_there_are_four_to_six_examples_each_expected_and_documented():
    assert 4 <= len(EXAMPLES) <= 6
    assert {p.stem for p in EXAMPLES} == set(EXPECTED)
    shown = (ROOT / "docs" / "examples.md").read_text()
    for p in EXAMPLES:
        assert f'--8<-- "examples/{p.name}"' in shown, f"docs/examples.md does not show {p.name}"


@pytest.mark.parametrize("script", EXAMPLES, ids=lambda p: p.stem)
def test_example_runs_at_tiny_size(script, tmp_path):
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_", "CAPSIM_"))}
    env.update(CAPSIM_EXAMPLES_TINY="1", CAPSIM_EXAMPLES_OUT=str(tmp_path / "out"),
               PYTHONPATH=os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep))
    done = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    files, printed = EXPECTED[script.stem]
    for name in files:
        assert (tmp_path / "out" / name).is_file(), f"{script.name} did not write {name}"
    assert printed in done.stdout, done.stdout
