"""What the benchmark scripts share: a run that a signal stopped ends the benchmark; the timing
benchmarks' source trees and fresh interpreters.

run_case catches SIGTERM/SIGINT/SIGHUP and returns the run so far with status
"interrupted" (so that nothing written is lost); a benchmark that took that for a
result would write a partial run as a row of its table. capsim is imported only when a run
is made (after each script has applied the thread policy; the timing benchmarks' parent
processes import none of it).
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

#: Python source for a timing benchmark's worker interpreter: ``timed(cls, name, key)`` wraps a method so
#: that ``clock[key]`` sums its wall time, the outermost call only (``flush`` is also called by ``append_step``)
TIMED_SOURCE = r"""
clock, depth = {}, {}
def timed(cls, name, key):
    original = getattr(cls, name)
    clock.setdefault(key, 0.0)
    def wrapper(*a, **k):
        depth[key] = depth.get(key, 0) + 1
        s = time.perf_counter()
        try:
            return original(*a, **k)
        finally:
            depth[key] -= 1
            if depth[key] == 0:
                clock[key] += time.perf_counter() - s
    setattr(cls, name, wrapper)
"""


def fresh_env(tree: Path) -> dict:
    """The environment of a fresh interpreter timing ``tree``'s capsim: one thread, the byte-code cache
    on (``PYTHONDONTWRITEBYTECODE`` unset: an installed package has its .pyc; without them every command
    compiles capsim's sources again, ~0.1 s)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env.update(PYTHONPATH=str(tree), OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1",
               NUMBA_NUM_THREADS="1")
    return env


def export_commit(commit: str, dest: Path) -> Path:
    """The source tree of ``commit`` (git archive) in the new folder ``dest``: a timing benchmark's baseline."""
    dest.mkdir()
    archive = subprocess.run(["git", "archive", commit], cwd=ROOT, check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    return dest


def silhouette(positions: np.ndarray, elements: np.ndarray, subdivisions: int = 6) -> tuple[float, float]:
    """The cell's outline seen along the shear gradient y, as a rheoscope or an ektacytometer's laser sees it
    (benchmarks/tran_son_tay.py, benchmarks/rbc_high_stress.py): its half-length
    along the flow x and half-width along the vorticity z, (max − min)/2 of the membrane's points, each
    6-node element sampled on a grid of ``subdivisions`` per side (the midside nodes alone miss the bulge
    of a curved element at the tips)."""
    from capsim.numerics.geometry import interpolate, shape_functions

    n = subdivisions
    grid = np.array([(i / n, j / n) for i in range(n + 1) for j in range(n + 1 - i)])
    phi, _, _ = shape_functions(grid[:, 0], grid[:, 1])
    points = interpolate(phi, positions[elements]).reshape(-1, 3)
    extent = points.max(axis=0) - points.min(axis=0)
    return float(extent[0] / 2), float(extent[2] / 2)


def run_or_stop(case):
    """run_case(case), except that an interrupted run ends the script without a table."""
    from capsim.runs.runner import run_case

    result = run_case(case)
    if result["status"] == "interrupted":
        raise SystemExit(f"benchmark run {case.name!r} {result.get('status_reason') or 'interrupted'}: "
                         "no table written (a partial run is never a row)")
    return result


def save_figure(fig, path: Path, dpi: int = 120) -> None:
    """Lay the figure out, write it to `path` (its folder made) and close it."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
