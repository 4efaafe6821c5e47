"""Does a short run tell the mesh error at t_end? (issue 44: a probe of levels 1-2 to a short time,
then the chosen level run on, would certify level 1 at a fraction of level 2's cost — if the early
error said the late one.)

The eleven training cases beside the error model's grid (benchmarks/error_model.py), levels 1, 2, 3
at rtol 1e-4 to kt 4; D_xy and θ read from the time series at kt 1, 2 and 4. At each time: the
Richardson extrapolation of the three levels (the error model's recipe, error_model.richardson3),
level 1's error against it, and the estimate a probe of levels 1-2 would make of level 1's error,
|f1 − f2| · 2^p / (2^p − 1) with p = 1.5 (the ladder's two-level order). The table gives the
probe's estimate at kt 1 and 2 over level 1's actual error at kt 4.

    python benchmarks/early_error.py [--workers=2] [--table]   # ~5 min on 2 cores (make bench-early-error)

writes benchmarks/early_error.md (included by docs/benchmarks.md) and .json.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np
from error_model import T_END, TRAINING, case_dict, richardson3

from capsim.solve.accuracy import LADDER_TWO_LEVEL_ORDER as TWO_LEVEL_ORDER  # the ladder's order from two levels

ROOT = Path(__file__).resolve().parents[1]
MD, JSON = ROOT / "benchmarks" / "early_error.md", ROOT / "benchmarks" / "early_error.json"
TIMES, RTOL, LEVELS = (1.0, 2.0, T_END), 1e-4, (1, 2, 3)  # T_END: the error model's kt 4
LABELS = [label for label in TRAINING if ":" not in label]  # not the "grid:" or "edge:" ones


def measure(label: str) -> tuple[str, dict]:
    """The case's D_xy and θ at TIMES, at each level (its time series, interpolated)."""
    import h5py

    from capsim.config import case_from_dict
    from capsim.runs.runner import run_case

    out: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        for level in LEVELS:
            d = {**case_dict(TRAINING[label], level, RTOL), "output": {"path": f"{tmp}/r{level}.h5"}}
            result = run_case(case_from_dict(d))
            with h5py.File(f"{tmp}/r{level}.h5") as f:
                t = f["timeseries/t"][()]
                out[str(level)] = {q: [float(np.interp(tt, t, f["timeseries"][q][()])) for tt in TIMES]
                                   for q in ("D_xy", "theta")}
                out[str(level)]["status"] = result.status
    return label, out


def table(rows: dict) -> str:
    lines = ["The mesh error early in a run against at its end (the eleven training cases beside the error model's "
             f"grid, levels 1-3 at rtol {RTOL:g} to kt {T_END:g}; level 1's error against the Richardson extrapolation of "
             "the three levels at the same time, relative for D_xy, rad for θ): a probe of levels 1-2 to kt 1 or 2 "
             f"estimates level 1's error as |f1 − f2| · 2^p / (2^p − 1), p = {TWO_LEVEL_ORDER:g}; the ratio of that "
             f"estimate to level 1's actual error at kt {T_END:g}:", "",
             "| training case | quantity | level 1's error at kt 1 | kt 2 | kt 4 | probe at kt 1 / error at kt 4 | "
             "probe at kt 2 / error at kt 4 |", "|---|---|---|---|---|---|---|"]
    ratios = []
    for label, out in rows.items():
        for q in ("D_xy", "theta"):
            errors, probes = [], []
            for k in range(len(TIMES)):
                values = np.array([out[str(lv)][q][k] for lv in LEVELS])
                reference, _ = richardson3(values)
                scale = 1.0 if q == "theta" else abs(reference)
                errors.append(abs(values[0] - reference) / scale)
                factor = 2.0**TWO_LEVEL_ORDER / (2.0**TWO_LEVEL_ORDER - 1.0)
                probes.append(abs(values[0] - values[1]) / scale * factor)
            r1, r2 = probes[0] / errors[-1], probes[1] / errors[-1]
            ratios.append(r1)
            lines.append(f"| {label} | {q} | {errors[0]:.2g} | {errors[1]:.2g} | {errors[2]:.2g} | {r1:.2f} | {r2:.2f} |")
    r = np.array(ratios)
    lines += ["", f"The probe at kt 1 over the error at kt {T_END:g}: median {np.median(r):.2f}, below 0.5 in "
              f"{int((r < 0.5).sum())} of {len(r)}, smallest {r.min():.2f}: the error grows as the deformation and the "
              "orientation develop, and an early probe would certify levels that miss the target at t_end."]
    return "\n".join(lines) + "\n"


def main() -> None:
    workers = int(next((a.split("=", 1)[1] for a in sys.argv if a.startswith("--workers=")), "1"))
    if "--table" not in sys.argv:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            rows = dict(pool.map(measure, LABELS))
        JSON.write_text(json.dumps(rows, indent=1) + "\n")
    rows = json.loads(JSON.read_text())
    MD.write_text(table({label: rows[label] for label in LABELS}))
    print(MD.read_text())


if __name__ == "__main__":
    sys.exit(main())
