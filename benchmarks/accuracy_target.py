"""The accuracy target on cases the error model was not built from (issue 44): for each case and
target, capsim's answer under accuracy.method auto (the predicted (level, rtol), or the measured
ladder of capsim.runs.ladder where the error model cannot place the case), the error it achieves
against a finer reference, and its cost (a ladder's every level counted) against the cheapest
(level, rtol) of a grid that meets the target.

For each case (kt 4): the reference is the Richardson extrapolation of levels 1, 2, 3 at rtol
1e-5 (the error model's own recipe); the grid is levels 1-3 × rtol 1e-2, 2e-3, 1e-3, 1e-4 (and
1e-5, the reference runs). A target is met when |value − reference| (relative for D_xy and S*_xy, rad
for θ) is at most the target; cost is velocity evaluations × the median seconds of one evaluation
at the level (the error model's, so that the comparison does not move with the machine's load).

    python benchmarks/accuracy_target.py [--workers=2] [--case=LABEL ...] [--reuse-grid] [--table]   # ~30 min on 2 cores (make bench-accuracy-target)

writes benchmarks/accuracy_target.md (included by docs/benchmarks.md) and .json.
"""

from __future__ import annotations

import json
import math
import os
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np
from error_model import richardson3, run_values


ROOT = Path(__file__).resolve().parents[1]
MD, JSON = ROOT / "benchmarks" / "accuracy_target.md", ROOT / "benchmarks" / "accuracy_target.json"
T_END = 4.0
LEVELS, RTOLS = (1, 2, 3), (1e-2, 2e-3, 1e-3, 1e-4, 1e-5)
#: level 4 joins the grid (and the reference) where a choice takes it; its tightest run at 1e-4
#: (a time error ~1e-5, far below level 4's mesh error) keeps the benchmark to minutes
LEVEL4_RTOLS = (1e-2, 1e-3, 1e-4)

#: cases none of the training cases is (benchmarks/error_model.py): shapes, laws, λ, G, orientation
CASES = {
    "sphere, Skalak C 10, G 0.05, λ 1": {"membrane": {"law": "skalak", "skalak_c": 10.0},
                                         "flow": {"shear_rate_G": 0.05}},
    "sphere, neo-Hookean, G 0.2, λ 0.2": {"membrane": {"law": "neo_hookean"},
                                          "flow": {"shear_rate_G": 0.2, "viscosity_ratio": 0.2}},
    "prolate 2, thin shell, G 0.1, λ 1": {"shape": {"kind": "prolate", "aspect_ratio": 2.0},
                                          "flow": {"shear_rate_G": 0.1}},
    "oblate 0.7, neo-Hookean, G 0.05, λ 3": {"shape": {"kind": "oblate", "aspect_ratio": 0.7},
                                             "membrane": {"law": "neo_hookean"},
                                             "flow": {"shear_rate_G": 0.05, "viscosity_ratio": 3.0}},
    "biconcave, Skalak C 10, G 0.1, λ 1": {"shape": {"kind": "biconcave"},
                                           "membrane": {"law": "skalak", "skalak_c": 10.0},
                                           "flow": {"shear_rate_G": 0.1}},
    "sphere, thin shell, G 0.1, λ 1, tilted 30°": {"initial_tilt_deg": 30.0, "flow": {"shear_rate_G": 0.1}},
    "prolate 1.2, Mooney-Rivlin ψ 0.5, G 0.15, λ 2": {"shape": {"kind": "prolate", "aspect_ratio": 1.2},
                                                      "membrane": {"law": "mooney_rivlin", "psi": 0.5},
                                                      "flow": {"shear_rate_G": 0.15, "viscosity_ratio": 2.0}},
    "oblate 0.4, Skalak C 2, G 0.04, λ 0.5": {"shape": {"kind": "oblate", "aspect_ratio": 0.4},
                                              "membrane": {"law": "skalak", "skalak_c": 2.0},
                                              "flow": {"shear_rate_G": 0.04, "viscosity_ratio": 0.5}},
}
TARGETS = (("D_xy", 2e-2), ("D_xy", 5e-3), ("theta", 5e-3))


def _fields(fields: dict, **extra) -> dict:
    d = {"name": "t", "time": {"t_end": T_END}}
    for source in (fields, extra):
        for key, value in source.items():
            d[key] = {**d.get(key, {}), **value} if isinstance(value, dict) else value
    return d


def _chosen(fields: dict, q: str, target: float, path: Path) -> dict | str:
    """capsim's own answer to the target (accuracy.method auto): the predicted run, or the measured
    ladder (capsim.runs.ladder) with every level it ran; a refusal's one line."""
    import h5py

    from capsim.config import case_from_dict
    from capsim.runs.runner import run_case

    try:
        case = case_from_dict({**_fields(fields, accuracy={"quantity": q, "target": target}),
                               "output": {"path": str(path)}})
    except Exception as exc:  # noqa: BLE001 - a target capsim refuses (finer than any level gives)
        return str(exc).splitlines()[0]
    try:
        result = run_case(case, overwrite=True)
    except Exception as exc:  # noqa: BLE001 - said in the row
        return f"failed: {exc}"[:200]
    with h5py.File(path, "r") as f:
        value = float(f["timeseries"][q][-1])
        if case.accuracy.method == "measure":
            levels = [int(v) for v in f["accuracy/level"][()]]
            evaluations = [int(v) for v in f["accuracy/evaluations"][()]]
            own, met = float(f["accuracy/errors"][-1]), bool(f["accuracy/met"][()])
        else:
            levels, evaluations, own, met = [case.mesh.level], [result.velocity_evaluations], math.nan, None
    return {"method": case.accuracy.method, "level": levels[-1], "rtol": float(case.time.rtol), "value": value,
            "levels": levels, "evaluations": evaluations, "own_error": own, "own_met": met, "status": result.status}


def measure(label: str, fields: dict, tmp: Path, kept_grid: list | None = None) -> dict:
    from capsim.solve import accuracy

    seconds = accuracy.model()["seconds_per_evaluation"]
    # capsim's runs first: a run of level 4 brings level 4 into the grid and the reference
    choices = {(q, target): _chosen(fields, q, target, tmp / f"c-{q}-{target:g}.h5") for q, target in TARGETS}
    levels = sorted({*LEVELS, *(c["level"] for c in choices.values() if isinstance(c, dict) and c["level"] <= 4)})
    # the grid does not depend on the error model: a row measured before gives its points again (--reuse-grid)
    stored = {(int(g["level"]), float(g["rtol"])): g for g in (kept_grid or [])}
    grid = {(lv, r): stored.get((lv, r)) or run_values(_fields(fields, mesh={"level": lv}, time={"rtol": r}),
                                                       tmp / f"g{lv}-{r:g}.h5")
            for lv in levels for r in (RTOLS if lv <= 3 else LEVEL4_RTOLS)}
    finest = levels[-3:]  # the reference: Richardson of the three finest levels, each at its tightest rtol
    out: dict = {"label": label, "targets": [], "reference_levels": finest,
                 "grid": [{**run, "level": lv, "rtol": r} for (lv, r), run in grid.items()]}
    for q, target in TARGETS:
        values = np.array([grid[(lv, min(r for (l2, r) in grid if l2 == lv))][q] for lv in finest])
        reference, _ = richardson3(values)  # the error model's own recipe
        scale = 1.0 if q == "theta" else abs(reference)

        def error(v: float) -> float:
            return abs(v - reference) / scale

        def cheapest(rtol_at_most: float = math.inf) -> dict | None:
            meeting = [(run["evaluations"] * seconds[str(lv)], lv, r, error(run[q])) for (lv, r), run in grid.items()
                       if r <= rtol_at_most and error(run[q]) <= target]
            return None if not meeting else dict(zip(("cost_s", "level", "rtol", "error"), min(meeting)))

        row = {"quantity": q, "target": target, "reference": float(reference),
               "cheapest": cheapest(), "cheapest_chooseable": cheapest(max(accuracy.RTOL_LADDER))}
        c = choices[(q, target)]
        if isinstance(c, str):
            row["chosen"] = {"refused": c[:200]}
        elif c["level"] > max(finest):
            row["chosen"] = {"unchecked": f"level {c['level']} (predicted): beyond the benchmark's level {max(finest)}"}
        else:
            cost = float(sum(n * seconds[str(lv)] for lv, n in zip(c["levels"], c["evaluations"])))
            row["chosen"] = {"method": c["method"], "level": c["level"], "rtol": c["rtol"], "levels": c["levels"],
                             "error": float(error(c["value"])), "own_error": c["own_error"], "own_met": c["own_met"],
                             "cost_s": cost, "met": bool(error(c["value"]) <= target)}
            for key in ("cheapest", "cheapest_chooseable"):
                if row[key] is not None:
                    row[f"{key}_ratio"] = cost / row[key]["cost_s"]
        out["targets"].append(row)
    return out


def _measure_alone(label: str, kept_grid: list | None = None) -> dict:
    """measure() in a worker process, in its own temporary folder."""
    with tempfile.TemporaryDirectory() as tmp:
        return measure(label, CASES[label], Path(tmp), kept_grid)


def main() -> None:
    """--workers=N; --case=LABEL (repeatable): measure those cases again, keep the others' rows;
    --reuse-grid: capsim's choices run again, the grid's points taken from the JSON where it has them
    (after a change of the error model or the ladder: the grid does not depend on them)."""
    workers = int(next((a.split("=", 1)[1] for a in sys.argv if a.startswith("--workers=")), "1"))
    only = [a.split("=", 1)[1] for a in sys.argv if a.startswith("--case=")]
    unknown = [label for label in only if label not in CASES]
    if unknown:
        sys.exit(f"--case: {unknown}: not a case of this benchmark ({'; '.join(CASES)})")
    reuse = "--reuse-grid" in sys.argv
    kept = ({r["label"]: r for r in json.loads(JSON.read_text())}
            if (only or reuse or "--table" in sys.argv) and JSON.exists() else {})
    grids = {label: kept.get(label, {}).get("grid") for label in CASES} if reuse else {label: None for label in CASES}
    if reuse and not only:
        only = list(CASES)
    if "--table" in sys.argv:  # the table again from the JSON, nothing run
        only = []
    rows = {label: kept[label] for label in CASES if label in kept and label not in only}
    with ProcessPoolExecutor(max_workers=workers) as pool:
        todo = [label for label in CASES if label not in rows]
        for row in pool.map(_measure_alone, todo, [grids[label] for label in todo]):
            print(row["label"], flush=True)
            rows[row["label"]] = row
            JSON.write_text(json.dumps([rows[k] for k in CASES if k in rows], indent=1) + "\n")  # kept as it goes
    rows = [rows[k] for k in CASES]
    lines = ["The accuracy target on cases outside the error model's training (kt 4; method auto: the predicted "
             "run where the model is sure of the case, the measured ladder where it is not; error against the "
             "Richardson extrapolation of the three finest levels of the grid (1-3 at rtol 1e-5; 2-4 where capsim "
             "kept level 4, level 4 at rtol 1e-4); cost in the error model's seconds of an evaluation times the "
             "evaluations, a ladder's every level counted). The grid is levels 1-3 × rtol 1e-2, 2e-3, 1e-3, 1e-4, "
             "1e-5; its cheapest point that meets the target, and the cheapest at the tolerances capsim chooses "
             "(never looser than 2e-3: the volume guard, capsim.solve.accuracy.RTOL_LADDER):", "",
             "| case | target | capsim's run: level, rtol | own estimate | achieved error | met | "
             "cheapest of the grid | cost / cheapest | cheapest at rtol ≤ 2e-3 | cost / that |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        for t in r["targets"]:
            c = t["chosen"]
            if "refused" in c or "unchecked" in c:
                chosen = f"refused: {c['refused']}" if "refused" in c else c["unchecked"]
                own, achieved, met = "", "", "unchecked" if "unchecked" in c else ""
            else:
                chosen = f"{c['level']}, {c['rtol']:g}"
                if c["method"] == "measure":
                    chosen = f"measured (levels {'-'.join(map(str, (c['levels'][0], c['levels'][-1])))}): {chosen}"
                    own = f"{c['own_error']:.2g} ({'met' if c['own_met'] else 'NOT met'})"
                else:
                    own = "(predicted)"
                achieved, met = f"{c['error']:.2g}", "yes" if c["met"] else "NO"
            cells = []
            for key in ("cheapest", "cheapest_chooseable"):
                cheap = t[key]
                cells += [f"none (level ≤ {max(r['reference_levels'])})" if cheap is None
                          else f"{cheap['level']}, {cheap['rtol']:g}",
                          f"{t[key + '_ratio']:.2f}" if key + "_ratio" in t else ""]
            lines.append(f"| {r['label']} | {t['quantity']} {t['target']:g} | {chosen} | {own} | {achieved} | {met} | "
                         + " | ".join(cells) + " |")
    MD.write_text("\n".join(lines) + "\n")
    print(MD.read_text())


if __name__ == "__main__":
    sys.exit(main())
