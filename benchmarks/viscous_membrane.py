"""Cost of a viscous membrane (issue 28): the sphere at level 3, G = 0.1, λ = 1, kt 0-4,
elastic against Bq_s = 1 at the same tolerance, per scheme, and the viscous solve's
preconditioners (capsim.viscosity: frozen, rest, local, none). Counts (velocity evaluations,
layer applications, GMRES iterations) do not drift with the machine's load; wall time does.

    python benchmarks/viscous_membrane.py            # writes benchmarks/viscous_membrane.{json,md}

Single-threaded (NUMBA_NUM_THREADS=1 is set here before numba loads).
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

HERE = Path(__file__).resolve().parent
CASES = [  # (label, scheme, Bq_s, preconditioner of the viscous solve)
    ("elastic", "rkf23", 0.0, None),
    ("Bq 1, frozen", "rkf23", 1.0, "frozen"),
    ("Bq 1, rest", "rkf23", 1.0, "rest"),
    ("Bq 1, local", "rkf23", 1.0, "local"),
    ("Bq 1, none", "rkf23", 1.0, "none"),
    ("elastic", "rkc", 0.0, None),
    ("Bq 1, frozen", "rkc", 1.0, "frozen"),
    ("Bq 1 + Bq_d 1, frozen", "rkf23", 1.0, "frozen"),
]


def run_one(scheme: str, bq: float, preconditioner: str | None, dilatational: float, t_end: float, level: int):
    import capsim.viscosity as viscosity
    from capsim.config import case_from_dict
    from capsim.runner import run_case
    from capsim.store import read_trajectory

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
            r = run_case(case)
            wall = time.perf_counter() - t0
            ts = read_trajectory(case.output.path)["timeseries"]
            iters = ts["solver_iterations"]
            return {"steps": r["steps"], "evaluations": r["velocity_evaluations"],
                    "layer_applications": r["layer_applications"], "wall_s": wall,
                    "mean_iterations": float(iters[1:].mean()), "max_iterations": int(iters.max()),
                    "factorizations": made[-1].factorizations if made else 0,
                    "D_xy": r["final_D_xy"], "theta": r["final_theta"]}
    finally:
        viscosity.KelvinVoigtMembrane.__init__ = original


def main(t_end: float = 4.0, level: int = 3) -> None:
    run_one("rkf23", 1.0, "frozen", 0.0, 0.05, 1)  # compile the kernels outside the timings
    rows = []
    for label, scheme, bq, pre in CASES:
        dil = 1.0 if "Bq_d" in label else 0.0
        row = {"case": label, "scheme": scheme, **run_one(scheme, bq, pre, dil, t_end, level)}
        rows.append(row)
        print(row, flush=True)
    (HERE / "viscous_membrane.json").write_text(json.dumps({"t_end": t_end, "level": level, "rows": rows}, indent=1))
    ref = {r["scheme"]: r for r in rows if r["case"] == "elastic"}
    lines = [f"| case | scheme | steps | evaluations | layer applications | GMRES its/eval (max) | sparse LUs | "
             f"wall s | layers / elastic | wall / elastic | D_xy | θ |", "|" + "---|" * 12]
    for r in rows:
        e = ref[r["scheme"]]
        lines.append(f"| {r['case']} | {r['scheme']} | {r['steps']} | {r['evaluations']} | {r['layer_applications']} | "
                     f"{r['mean_iterations']:.1f} ({r['max_iterations']}) | {r['factorizations']} | {r['wall_s']:.1f} | "
                     f"{r['layer_applications'] / e['layer_applications']:.2f} | {r['wall_s'] / e['wall_s']:.2f} | "
                     f"{r['D_xy']:.4f} | {r['theta']:.4f} |")
    (HERE / "viscous_membrane.md").write_text(
        f"# Cost of a viscous membrane\n\nSphere, thin shell, level {level}, G = 0.1, λ = 1, kt 0–{t_end:g}, "
        "rtol 1e-4, solver.tol 1e-6, one thread; written by `python benchmarks/viscous_membrane.py`.\n"
        "Ratios are against the elastic run of the same scheme.\n\n" + "\n".join(lines) + "\n")


if __name__ == "__main__":
    main(*(float(a) for a in sys.argv[1:2]))
