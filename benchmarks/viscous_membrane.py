"""Cost of a viscous membrane (issue 28): the sphere at level 3 (kt 0-4) and 4 (kt 0-0.5), G = 0.1, λ = 1,
elastic against Bq_s = 1 at the same tolerance, per scheme, and the viscous solve's
preconditioners (capsim.numerics.viscosity: frozen, rest, local, none). Counts (velocity evaluations,
layer applications, GMRES iterations) do not drift with the machine's load; wall time does.

    python benchmarks/viscous_membrane.py      # writes benchmarks/viscous_membrane.{json,md} (~6 min on an idle machine)

Single-threaded: capsim's thread policy (capsim.numerics.threads) with one thread, and one BLAS
thread (OPENBLAS/OMP/MKL_NUM_THREADS=1, which that policy does not set): with a
multi-threaded BLAS on a loaded two-core machine GMRES's short dot products cost more
than the layer sums (level 4, four viscous solves: 11.7 s against 2.1 s).
"""

from __future__ import annotations

import json
import os
import statistics
import tempfile
import time
from pathlib import Path

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):  # before numpy loads BLAS
    os.environ.setdefault(_name, "1")

from capsim.numerics.threads import apply_policy  # noqa: E402 (before numba loads)

apply_policy(1)

HERE = Path(__file__).resolve().parent
REPEATS = 3  # level 3's cost rows (COST_ROWS): wall time is the median of this many interleaved runs
COST_ROWS = ("elastic", "Bq 1, frozen")  # labels; with every scheme they are run with (auto too)
LEVEL4 = [  # the same at level 4, kt 0-0.5
    ("elastic", "rkf23", 0.0, None),
    ("Bq 1, frozen", "rkf23", 1.0, "frozen"),
    ("Bq 1, none", "rkf23", 1.0, "none"),
]
CASES = [  # (label, scheme, Bq_s, preconditioner of the viscous solve)
    ("elastic", "rkf23", 0.0, None),
    ("Bq 1, frozen", "rkf23", 1.0, "frozen"),
    ("Bq 1, rest", "rkf23", 1.0, "rest"),
    ("Bq 1, local", "rkf23", 1.0, "local"),
    ("Bq 1, none", "rkf23", 1.0, "none"),
    ("elastic", "rkc", 0.0, None),
    ("Bq 1, frozen", "rkc", 1.0, "frozen"),
    ("elastic", "auto", 0.0, None),  # the default scheme: what a user who sets none gets
    ("Bq 1, frozen", "auto", 1.0, "frozen"),
    ("Bq 1 + Bq_d 1, frozen", "rkf23", 1.0, "frozen"),
]


def run_one(scheme: str, bq: float, preconditioner: str | None, dilatational: float, t_end: float, level: int):
    import capsim.numerics.viscosity as viscosity
    from capsim.config import case_from_dict
    from _common import run_or_stop
    from capsim.storage.store import read_trajectory

    original = viscosity.KelvinVoigtMembrane.__init__
    made = []

    def init(self, *args, **kw):
        original(self, *args, **{**kw, "preconditioner": preconditioner or "frozen"})
        made.append(self)

    viscosity.KelvinVoigtMembrane.__init__ = init
    try:
        with tempfile.TemporaryDirectory() as tmp:
            block = {"viscosity": {"shear": bq, "dilatational": dilatational}} if bq else {}
            case = case_from_dict({"name": "b", "mesh": {"level": level}, "flow": {"shear_rate_G": 0.1},
                                   "membrane": block, "time": {"t_end": t_end, "scheme": scheme},
                                   "output": {"path": f"{tmp}/b.h5", "snapshot_every": t_end}})
            t0 = time.perf_counter()
            r = run_or_stop(case)
            wall = time.perf_counter() - t0
            if r["status"] != "completed":  # a guard's stop is not a cost row either
                raise SystemExit(f"benchmark run ended {r['status']!r}: no table written")
            ts = read_trajectory(case.output.path)["timeseries"]
            iters = ts["solver_iterations"]
            return {"steps": r["steps"], "evaluations": r["velocity_evaluations"],
                    "layer_applications": r["layer_applications"], "wall_s": wall,
                    "mean_iterations": float(iters[1:].mean()), "max_iterations": int(iters.max()),
                    "factorizations": made[-1].factorizations if made else 0,
                    "scheme_used": r.get("scheme") or scheme,
                    "D_xy": r["final_D_xy"], "theta": r["final_theta"]}
    finally:
        viscosity.KelvinVoigtMembrane.__init__ = original


def table(rows: list[dict]) -> list[str]:
    ref = {r["scheme"]: r for r in rows if r["case"] == "elastic"}
    lines = ["| case | scheme | steps | evaluations | layer applications | GMRES its/eval (max) | sparse LUs | "
             "wall s | evaluations / elastic | layers / elastic | wall / elastic | D_xy | θ |", "|" + "---|" * 13]
    for r in rows:
        e = ref[r["scheme"]]
        used = r.get("scheme_used", r["scheme"])
        scheme = r["scheme"] if used == r["scheme"] else f"{r['scheme']} ({used})"
        lines.append(f"| {r['case']} | {scheme} | {r['steps']} | {r['evaluations']} | {r['layer_applications']} | "
                     f"{r['mean_iterations']:.1f} ({r['max_iterations']}) | {r['factorizations']} | {r['wall_s']:.1f} | "
                     f"{r['evaluations'] / e['evaluations']:.2f} | "
                     f"{r['layer_applications'] / e['layer_applications']:.2f} | {r['wall_s'] / e['wall_s']:.2f} | "
                     f"{r['D_xy']:.4f} | {r['theta']:.4f} |")
    return lines


def main() -> None:
    run_one("rkf23", 1.0, "frozen", 0.0, 0.05, 1)  # compile the kernels outside the timings
    out, text = {}, ["# Cost of a viscous membrane", "",
                     "Sphere, thin shell, G = 0.1, λ = 1, rtol 1e-4, solver.tol 1e-6, one thread (BLAS too); "
                     "written by `python benchmarks/viscous_membrane.py`. Ratios are against the elastic run of "
                     "the same scheme (auto: against the elastic run under auto, each with what auto picked, in "
                     "brackets); 'sparse LUs' counts the preconditioner's factorisations. At level 3 the elastic and "
                     "'Bq 1, frozen' rows' wall times are medians of three interleaved runs, the others single runs."]
    for level, t_end, cases in ((3, 4.0, CASES), (4, 0.5, LEVEL4)):
        rows = {}
        # the cost rows (the elastic and the default viscous run of each scheme) are repeated
        # REPEATS times, interleaved, and their wall time is the median: a loaded machine's
        # drift then falls on both sides of each ratio; the counts do not vary (checked)
        for repeat in range(REPEATS if level == 3 else 1):
            for label, scheme, bq, pre in cases:
                if repeat and label not in COST_ROWS:
                    continue
                dil = 1.0 if "Bq_d" in label else 0.0
                got = run_one(scheme, bq, pre, dil, t_end, level)
                row = rows.setdefault((label, scheme), {"case": label, "scheme": scheme, **got, "walls_s": []})
                assert all(row[k] == got[k] for k in ("steps", "evaluations", "layer_applications"))
                row["walls_s"].append(got["wall_s"])
                row["wall_s"] = statistics.median(row["walls_s"])
                print(level, repeat, label, scheme, got, flush=True)
        rows = list(rows.values())
        out[f"level {level}"] = {"t_end": t_end, "rows": rows}
        text += ["", f"## Level {level}, kt 0–{t_end:g}", "", *table(rows)]
    (HERE / "viscous_membrane.json").write_text(json.dumps(out, indent=1))
    (HERE / "viscous_membrane.md").write_text("\n".join(text) + "\n")


if __name__ == "__main__":
    main()
