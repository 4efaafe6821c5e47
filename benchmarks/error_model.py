"""The error model of time.rtol auto and of the accuracy target (issue 44): how large the mesh's
error and the time scheme's error are in the values a run reports, and what a run costs,
measured on training cases that span the shapes, laws, λ and G the validation covers.

For each training case:

- the mesh: levels 1, 2, 3 at rtol 1e-5; the error of each level against the Richardson
  extrapolation of the three (observed order, clipped to [1.5, 4]);
- time: level 2 at rtol 1e-2 … 1e-5 against rtol 1e-6 on the same mesh;
- cost: the velocity evaluations of each run and the wall time per evaluation at each level.

The model (capsim/error_model.json, read by capsim.accuracy) keeps, for each quantity, the
largest error over the training cases: per level for the mesh (levels 4–6 continued with the
smallest observed order), per unit rtol for time; and the cost as evaluations per unit kt,
a · rtol^(−b), times the wall time of one evaluation at each level. It writes
benchmarks/error_model.md (included by docs/benchmarks.md) beside it.

    python benchmarks/error_model.py            # ~5 min on one core
    python benchmarks/error_model.py --fit      # refit the rows the model file keeps
"""

from __future__ import annotations

import json
import math
import os
import sys
import tempfile
from pathlib import Path

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "capsim" / "error_model.json"
MD = ROOT / "benchmarks" / "error_model.md"

#: the training cases: (label, case fields); kt 4 each
TRAINING = {
    "sphere, thin shell, G 0.1, λ 1": {"flow": {"shear_rate_G": 0.1}},
    "sphere, neo-Hookean, G 0.05, λ 5": {"membrane": {"law": "neo_hookean"},
                                         "flow": {"shear_rate_G": 0.05, "viscosity_ratio": 5.0}},
    "oblate 0.5, Skalak C 10, G 0.1, λ 1": {"shape": {"kind": "oblate", "aspect_ratio": 0.5},
                                            "membrane": {"law": "skalak", "skalak_c": 10.0},
                                            "flow": {"shear_rate_G": 0.1}},
    "biconcave, Skalak C 10, κ 1e-3, G 0.2, λ 0.2": {"shape": {"kind": "biconcave"},
                                                      "membrane": {"law": "skalak", "skalak_c": 10.0,
                                                                   "bending_modulus": 1e-3},
                                                      "flow": {"shear_rate_G": 0.2, "viscosity_ratio": 0.2}},
}
QUANTITIES = ("D_xy", "theta", "Sxy_star")
#: θ's error is absolute (rad: θ is an angle, 0 where the shape is round); the others relative
ABSOLUTE = ("theta",)
MESH_LEVELS, TIME_RTOLS, REFERENCE_RTOL, MESH_RTOL = (1, 2, 3), (1e-2, 1e-3, 1e-4, 1e-5), 1e-6, 1e-5
T_END = 4.0


def _run(fields: dict, level: int, rtol: float, tmp: str) -> dict:
    """One run's values at t_end, its velocity evaluations and wall time."""
    import h5py

    from capsim.config import case_from_dict
    from capsim.runner import run_case

    path = Path(tmp) / f"run-{level}-{rtol:g}.h5"
    d = {"name": "train", "mesh": {"level": level}, "time": {"t_end": T_END, "rtol": rtol},
         "output": {"path": str(path)}}
    for key, value in fields.items():
        d[key] = {**d.get(key, {}), **value}
    result = run_case(case_from_dict(d), overwrite=True)
    if result.status != "completed":
        raise RuntimeError(f"{d}: {result.status} {result.status_reason}")
    with h5py.File(path, "r") as f:
        values = {q: float(f["timeseries"][q][-1]) for q in QUANTITIES}
    return {**values, "evaluations": result.velocity_evaluations, "wall": result.wall_time_s}


def measure(label: str, fields: dict, tmp: str) -> dict:
    mesh = [_run(fields, level, MESH_RTOL, tmp) for level in MESH_LEVELS]
    time = [_run(fields, 2, rtol, tmp) for rtol in (*TIME_RTOLS, REFERENCE_RTOL)]
    out: dict = {"label": label, "mesh": {}, "time": {}, "cost": {}}
    for q in QUANTITIES:
        values = np.array([m[q] for m in mesh])
        # the Richardson reference and the observed order of the three levels
        d1, d2 = values[1] - values[0], values[2] - values[1]
        order = float(np.clip(math.log2(d1 / d2) if d1 and d2 and d1 / d2 > 0 else 2.0, 1.5, 4.0))
        reference = values[2] + d2 / (2.0**order - 1.0)
        scale = 1.0 if q in ABSOLUTE else max(abs(reference), 1e-12)
        out["mesh"][q] = {"errors": [float(abs(v - reference) / scale) for v in values], "order": order,
                          "reference": float(reference)}
        tv = np.array([t[q] for t in time])  # rtols loosest first, the reference last
        tscale = 1.0 if q in ABSOLUTE else max(abs(tv[-1]), 1e-12)
        out["time"][q] = [float(abs(v - tv[-1]) / tscale / r) for v, r in zip(tv[:-1], TIME_RTOLS)]
    out["cost"]["evaluations_per_kt"] = [t["evaluations"] / T_END for t in time[:-1]]
    out["cost"]["seconds_per_evaluation"] = {str(lv): m["wall"] / m["evaluations"] for lv, m in zip(MESH_LEVELS, mesh)}
    return out


#: what selects a training case for a case: its rest shape and whether λ = 1 (the double-layer solve
#: changes the time error tenfold: D_xy's per unit rtol 0.06 at λ = 1, 1.1 at λ = 5)
CLASS_OF = {
    "sphere, thin shell, G 0.1, λ 1": {"shape": "sphere", "lambda_one": True},
    "sphere, neo-Hookean, G 0.05, λ 5": {"shape": "sphere", "lambda_one": False},
    "oblate 0.5, Skalak C 10, G 0.1, λ 1": {"shape": "oblate", "lambda_one": True},
    "biconcave, Skalak C 10, κ 1e-3, G 0.2, λ 0.2": {"shape": "biconcave", "lambda_one": False},
}


def _entry(rows: list[dict]) -> dict:
    """The model of a set of training cases: the largest error over them, per level (mesh;
    levels 4-6 continued with the smallest observed order) and per rtol (time, made
    non-decreasing in rtol), and their cost law."""
    out: dict = {"mesh": {}, "time": {}, "order": {}}
    for q in QUANTITIES:
        errors = np.array([r["mesh"][q]["errors"] for r in rows])  # (case, level)
        order = min(r["mesh"][q]["order"] for r in rows)
        per_level = {str(lv): float(errors[:, k].max()) for k, lv in enumerate(MESH_LEVELS)}
        for lv in (4, 5, 6):  # each level halves h: the error falls by 2^order
            per_level[str(lv)] = per_level[str(lv - 1)] / 2.0**order
        out["mesh"][q], out["order"][q] = per_level, order
        # the error at each rtol (ratio × rtol), the largest over the cases, then non-decreasing in rtol
        errs = np.array([[ratio * rtol for ratio, rtol in zip(r["time"][q], TIME_RTOLS)] for r in rows]).max(axis=0)
        errs = np.maximum.accumulate(errs[::-1])[::-1]  # TIME_RTOLS loosest first
        out["time"][q] = {f"{rtol:g}": float(e) for rtol, e in zip(TIME_RTOLS, errs)}
    logs = -np.log(np.array(TIME_RTOLS))
    fits = [np.polyfit(logs, np.log(np.array(r["cost"]["evaluations_per_kt"])), 1) for r in rows]
    b = float(np.median([f[0] for f in fits]))
    a = float(max(np.exp(np.log(np.array(r["cost"]["evaluations_per_kt"])) - b * logs).max() for r in rows))
    out["evaluations_per_kt"] = {"a": a, "b": b}
    return out


def fit(rows: list[dict]) -> dict:
    """The model: one entry per class of training case (CLASS_OF) and the envelope of all,
    and the seconds of one evaluation at each level (the median over the cases)."""
    model: dict = {"quantities": list(QUANTITIES), "absolute": list(ABSOLUTE), "t_end": T_END,
                   "time_rtols": [float(r) for r in TIME_RTOLS], "classes": [], "envelope": _entry(rows)}
    for r in rows:
        model["classes"].append({"label": r["label"], **CLASS_OF[r["label"]], **_entry([r])})
    seconds = {str(lv): float(np.median([r["cost"]["seconds_per_evaluation"][str(lv)] for r in rows]))
               for lv in MESH_LEVELS}
    for lv in (4, 5, 6):  # an evaluation's work grows as the nodes², 4² a level (the dense sums)
        seconds[str(lv)] = seconds[str(lv - 1)] * 16.0
    model["seconds_per_evaluation"] = seconds
    return model


def report(model: dict, rows: list[dict]) -> str:
    lines = ["Mesh error at each level (relative; θ in rad) against the Richardson extrapolation of levels "
             "1-3 at rtol 1e-5 (observed order), and time error at each rtol (level 2, against rtol 1e-6), "
             "at kt 4; the model of each training case is its own row, the envelope the largest of all:", "",
             "| training case | quantity | level 1 | level 2 | level 3 | order | rtol 1e-2 | 1e-3 | 1e-4 | 1e-5 |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for entry in [*model["classes"], {"label": "envelope (outside the classes)", **model["envelope"]}]:
        for q in QUANTITIES:
            e, t = entry["mesh"][q], entry["time"][q]
            lines.append(f"| {entry['label']} | {q} | {e['1']:.2g} | {e['2']:.2g} | {e['3']:.2g} | "
                         f"{entry['order'][q]:.2f} | " + " | ".join(f"{t[f'{r:g}']:.2g}" for r in TIME_RTOLS) + " |")
    c = model["seconds_per_evaluation"]
    lines += ["", "Cost: velocity evaluations per unit kt ≈ a · rtol^(−b) per class (" +
              "; ".join(f"{e['label']}: a {e['evaluations_per_kt']['a']:.3g}, b {e['evaluations_per_kt']['b']:.3g}"
                        for e in model["classes"]) + "); seconds per evaluation (one core, median): " +
              ", ".join(f"level {lv} {s:.2g}" for lv, s in c.items()) + " (levels 4-6: ×16 a level, not measured)."]
    return "\n".join(lines) + "\n"


def main() -> None:
    if "--fit" in sys.argv:  # refit the rows kept in the model file (no runs)
        rows = json.loads(MODEL.read_text())["rows"]
    else:
        rows = []
        for label, fields in TRAINING.items():
            print(label, flush=True)
            with tempfile.TemporaryDirectory() as tmp:
                rows.append(measure(label, fields, tmp))
    model = fit(rows)
    model["rows"] = rows
    MODEL.write_text(json.dumps(model, indent=1) + "\n")
    MD.write_text(report(model, rows))
    print(MD.read_text())


if __name__ == "__main__":
    sys.exit(main())
