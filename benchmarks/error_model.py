"""The error model of time.rtol auto and of the accuracy target (issue 44): how large the mesh's
error and the time scheme's error are in the values a run reports, and what a run costs,
measured on training cases that span the shapes, laws, λ and G the validation covers.

For each training case:

- the mesh: levels 1, 2, 3 at rtol 1e-5; the error of each level against the Richardson
  extrapolation of the three (observed order, clipped to [1.5, 4]);
- time: level 2 at rtol 1e-2 … 1e-5 against rtol 1e-6 on the same mesh;
- cost: the velocity evaluations of each run and the wall time per evaluation at each level.

The model (capsim/solve/error_model.json, read by capsim.solve.accuracy) keeps, for each quantity, the
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
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np

from capsim.solve.accuracy import SAFETY_QUANTILE, observed_order

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "capsim" / "solve" / "error_model.json"
MD = ROOT / "benchmarks" / "error_model.md"
PARTIAL = Path(tempfile.gettempdir()) / "capsim-error-model-rows.json"

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
    "prolate 1.5, neo-Hookean, G 0.05, λ 1": {"shape": {"kind": "prolate", "aspect_ratio": 1.5},
                                              "membrane": {"law": "neo_hookean"}, "flow": {"shear_rate_G": 0.05}},
    "prolate 2.5, Skalak C 1, G 0.2, λ 5": {"shape": {"kind": "prolate", "aspect_ratio": 2.5},
                                            "membrane": {"law": "skalak", "skalak_c": 1.0},
                                            "flow": {"shear_rate_G": 0.2, "viscosity_ratio": 5.0}},
    "oblate 0.6, thin shell, G 0.1, λ 5": {"shape": {"kind": "oblate", "aspect_ratio": 0.6},
                                           "flow": {"shear_rate_G": 0.1, "viscosity_ratio": 5.0}},
    "sphere, Skalak C 1, G 0.025, λ 1": {"membrane": {"law": "skalak", "skalak_c": 1.0},
                                         "flow": {"shear_rate_G": 0.025}},
    "sphere, Mooney-Rivlin, G 0.1, λ 0.3": {"membrane": {"law": "mooney_rivlin"},
                                            "flow": {"shear_rate_G": 0.1, "viscosity_ratio": 0.3}},
    "biconcave, thin shell, G 0.3, λ 1": {"shape": {"kind": "biconcave"}, "flow": {"shear_rate_G": 0.3}},
    "biconcave, neo-Hookean, G 0.05, λ 5": {"shape": {"kind": "biconcave"}, "membrane": {"law": "neo_hookean"},
                                            "flow": {"shear_rate_G": 0.05, "viscosity_ratio": 5.0}},
}
#: and a grid over the rest shape, law, G and λ (none of them a case of benchmarks/accuracy_target.py,
#: which checks the model on cases it was not built from)
GRID_SHAPES = {"sphere": {}, "prolate 1.5": {"kind": "prolate", "aspect_ratio": 1.5},
               "prolate 3": {"kind": "prolate", "aspect_ratio": 3.0}, "oblate 0.5": {"kind": "oblate", "aspect_ratio": 0.5},
               "biconcave": {"kind": "biconcave"}}
GRID_LAWS = {"thin shell": {"law": "thin_shell"}, "neo-Hookean": {"law": "neo_hookean"},
             "Skalak C 10": {"law": "skalak", "skalak_c": 10.0}}
GRID_G, GRID_LAMBDA = (0.025, 0.08, 0.3), (0.3, 1.0, 5.0)
for _shape, _shape_fields in GRID_SHAPES.items():
    for _law, _law_fields in GRID_LAWS.items():
        for _G in GRID_G:
            for _lam in GRID_LAMBDA:
                TRAINING.setdefault(f"grid: {_shape}, {_law}, G {_G:g}, λ {_lam:g}",
                                    {"shape": _shape_fields, "membrane": _law_fields,
                                     "flow": {"shear_rate_G": _G, "viscosity_ratio": _lam}})
#: and the grid's edges: small G and large λ, and bending (κ 1e-3), on the thin-shell law
for _shape, _shape_fields in GRID_SHAPES.items():
    if _shape == "prolate 3":
        continue
    for _lam in (1.0, 10.0):
        TRAINING.setdefault(f"edge: {_shape}, thin shell, G 0.005, λ {_lam:g}",
                            {"shape": _shape_fields, "flow": {"shear_rate_G": 0.005, "viscosity_ratio": _lam}})
        TRAINING.setdefault(f"edge: {_shape}, thin shell, κ 1e-3, G 0.1, λ {_lam:g}",
                            {"shape": _shape_fields, "membrane": {"bending_modulus": 1e-3},
                             "flow": {"shear_rate_G": 0.1, "viscosity_ratio": _lam}})
QUANTITIES = ("D_xy", "theta", "Sxy_star")
#: θ's error is absolute (rad: θ is an angle, 0 where the shape is round); the others relative
ABSOLUTE = ("theta",)
MESH_LEVELS, TIME_RTOLS, REFERENCE_RTOL, MESH_RTOL = (1, 2, 3), (1e-2, 1e-3, 1e-4, 1e-5), 1e-6, 1e-5
T_END = 4.0


def run_values(d: dict, path: str | Path) -> dict:
    """One run of the case dict `d` into `path`: its values of QUANTITIES at t_end (NaN unless it
    completed), status, velocity evaluations, wall time, level and rtol. A run that raises (a λ solve
    that does not converge) is a failed run, said in its status. This benchmark's training and the
    accuracy target's (accuracy_target.py) run through it."""
    from capsim.config import case_from_dict
    from capsim.runs.runner import run_case
    from capsim.storage.store import read_run_record

    case = case_from_dict({**d, "output": {"path": str(path)}})
    try:
        result = run_case(case, overwrite=True)
    except Exception as exc:  # noqa: BLE001 - said in the status
        status, evaluations, wall = f"failed: {exc}"[:200], 0, math.nan
    else:
        status, evaluations, wall = result.status, result.velocity_evaluations, result.wall_time_s
    last = read_run_record(path)["last"] if status == "completed" else {}
    return {**{q: last.get(q, math.nan) for q in QUANTITIES}, "status": status, "evaluations": evaluations,
            "wall": wall, "level": case.mesh.level, "rtol": case.time.rtol}


def case_dict(fields: dict, level: int, rtol: float) -> dict:
    """A training case's dict at this level and rtol, to T_END (its fields merged per section)."""
    d = {"name": "train", "mesh": {"level": level}, "time": {"t_end": T_END, "rtol": rtol}}
    for key, value in fields.items():
        d[key] = {**d.get(key, {}), **value}
    return d


def _run(fields: dict, level: int, rtol: float, tmp: str) -> dict:
    """One training run's values at t_end, its velocity evaluations and wall time (it must complete)."""
    d = case_dict(fields, level, rtol)
    values = run_values(d, Path(tmp) / f"run-{level}-{rtol:g}.h5")
    if values["status"] != "completed":
        raise RuntimeError(f"{d}: {values['status']}")
    return values


def richardson3(values: np.ndarray) -> tuple[float, float]:
    """(the Richardson extrapolation, the order) of a value at three consecutive levels: the
    observed order, clipped to [1.5, 4] (2 where the differences change sign): the model's recipe."""
    d1, d2 = values[1] - values[0], values[2] - values[1]
    observed = observed_order(d1, d2)
    order = float(np.clip(2.0 if observed is None else observed, 1.5, 4.0))
    return float(values[2] + d2 / (2.0**order - 1.0)), order


def measure(label: str, fields: dict, tmp: str) -> dict:
    mesh = [_run(fields, level, MESH_RTOL, tmp) for level in MESH_LEVELS]
    time = [_run(fields, 2, rtol, tmp) for rtol in (*TIME_RTOLS, REFERENCE_RTOL)]
    out: dict = {"label": label, "mesh": {}, "time": {}, "cost": {}}
    for q in QUANTITIES:
        values = np.array([m[q] for m in mesh])
        reference, order = richardson3(values)
        scale = 1.0 if q in ABSOLUTE else max(abs(reference), 1e-12)
        out["mesh"][q] = {"errors": [float(abs(v - reference) / scale) for v in values], "order": order,
                          "reference": float(reference)}
        tv = np.array([t[q] for t in time])  # rtols loosest first, the reference last
        tscale = 1.0 if q in ABSOLUTE else max(abs(tv[-1]), 1e-12)
        out["time"][q] = [float(abs(v - tv[-1]) / tscale / r) for v, r in zip(tv[:-1], TIME_RTOLS)]
    out["cost"]["evaluations_per_kt"] = [t["evaluations"] / T_END for t in time[:-1]]
    out["cost"]["seconds_per_evaluation"] = {str(lv): m["wall"] / m["evaluations"] for lv, m in zip(MESH_LEVELS, mesh)}
    return out


def features(label: str) -> dict:
    """The case's features as capsim computes them (Case.error_model_features)."""
    from capsim.config import case_from_dict

    return case_from_dict(case_dict(TRAINING[label], 2, 1e-4)).error_model_features()


def _entry(row: dict) -> dict:
    """One training case's model: its error per level (mesh; levels 4-6 continued with its
    observed order), per rtol (time, made non-decreasing in rtol), and its cost law."""
    out: dict = {"label": row["label"], "features": features(row["label"]), "mesh": {}, "time": {}, "order": {}}
    for q in QUANTITIES:
        errors, order = row["mesh"][q]["errors"], row["mesh"][q]["order"]
        per_level = {str(lv): float(e) for lv, e in zip(MESH_LEVELS, errors)}
        for lv in (4, 5, 6):  # each level halves h: the error falls by 2^order
            per_level[str(lv)] = per_level[str(lv - 1)] / 2.0**order
        out["mesh"][q], out["order"][q] = per_level, order
        errs = np.array([ratio * rtol for ratio, rtol in zip(row["time"][q], TIME_RTOLS)])
        errs = np.maximum.accumulate(errs[::-1])[::-1]  # TIME_RTOLS loosest first
        out["time"][q] = {f"{rtol:g}": float(e) for rtol, e in zip(TIME_RTOLS, errs)}
    logs = -np.log(np.array(TIME_RTOLS))
    evaluations = np.log(np.array(row["cost"]["evaluations_per_kt"]))
    b = float(np.polyfit(logs, evaluations, 1)[0])
    out["evaluations_per_kt"] = {"a": float(np.exp(evaluations - b * logs).max()), "b": b}
    return out


def leave_one_out(cases: list[dict]) -> dict:
    """Each training case predicted from the others (capsim.solve.accuracy.nearest): the ratios actual /
    predicted of the mesh error at levels 1-3, per quantity."""
    from capsim.solve import accuracy

    ratios: dict = {q: [] for q in QUANTITIES}
    for k, case in enumerate(cases):
        others = cases[:k] + cases[k + 1:]
        predicted, _ = accuracy.nearest(case["features"], others)
        for q in QUANTITIES:
            for lv in MESH_LEVELS:
                ratios[q].append(case["mesh"][q][str(lv)] / predicted["mesh"][q][str(lv)])
    return ratios


def level4_ratio_measured() -> float:
    """The seconds of one evaluation at level 4 over level 3 (median of a sphere at λ 1 and 5, G 0.1,
    rtol 1e-3, to kt 0.5): level 4 is where a target's choice meets the dense sums' N² cost."""
    from capsim.config import case_from_dict
    from capsim.runs.runner import run_case

    ratios = []
    for lam in (1.0, 5.0):
        per = {}
        for level in (3, 4):
            with tempfile.TemporaryDirectory() as tmp:
                r = run_case(case_from_dict({"name": "cost", "mesh": {"level": level}, "time": {"t_end": 0.5, "rtol": 1e-3},
                                             "flow": {"shear_rate_G": 0.1, "viscosity_ratio": lam},
                                             "output": {"path": str(Path(tmp) / "c.h5")}}))
            per[level] = r.wall_time_s / r.velocity_evaluations
        ratios.append(per[4] / per[3])
    return float(np.median(ratios))


def fit(rows: list[dict], level4_ratio: float) -> dict:
    """The model: one entry per training case, the safety factor of each quantity (the ratio
    actual / predicted that SAFETY_QUANTILE of the left-out cases stay under, at least 1), and
    the seconds of one evaluation at each level (the median over the cases)."""
    from capsim.solve import accuracy

    cases = [_entry(r) for r in rows]
    ratios = leave_one_out(cases)
    model: dict = {"quantities": list(QUANTITIES), "absolute": list(ABSOLUTE), "t_end": T_END,
                   "time_rtols": [float(r) for r in TIME_RTOLS], "cases": cases,
                   "safety": {q: max(1.0, float(np.quantile(ratios[q], accuracy.SAFETY_QUANTILE))) for q in QUANTITIES},
                   "leave_one_out": ratios}
    seconds = {str(lv): float(np.median([r["cost"]["seconds_per_evaluation"][str(lv)] for r in rows]))
               for lv in MESH_LEVELS}
    seconds["4"] = seconds["3"] * level4_ratio
    for lv in (5, 6):  # an evaluation's work grows as the nodes², 4² a level (the dense sums)
        seconds[str(lv)] = seconds[str(lv - 1)] * 16.0
    model["seconds_per_evaluation"] = seconds
    return model


#: the targets of the left-out decision table (relative for D_xy and S*_xy, rad for θ)
DECISION_TARGETS = {"D_xy": (5e-2, 2e-2, 1e-2, 5e-3, 2e-3), "theta": (2e-2, 1e-2, 5e-3, 2e-3),
                    "Sxy_star": (5e-2, 2e-2, 1e-2, 5e-3)}


def decisions(model: dict) -> dict:
    """What the predicted choice of level does on the training cases left out one at a time: for each
    quantity and target that some level 1-3 of the case meets (its mesh error), the level
    capsim.solve.accuracy.choose's rule picks (the first whose predicted mesh error × the safety factor meets
    the target) against the cheapest that meets it: the same, finer, coarser (and of those, missed),
    with the safety factor, without it, and with factors below 1. A level finer than the cheapest costs 2-2.4× at level 1→2
    and more above (benchmarks/accuracy_target.md): this is how often no predicted choice is within 2×."""
    from capsim.solve import accuracy

    cases, out = model["cases"], {}
    # each case predicted from the others once (the quantities and factors below read the same prediction)
    predictions = [accuracy.nearest(case["features"], cases[:k] + cases[k + 1:])[0] for k, case in enumerate(cases)]
    for q in QUANTITIES:
        # the model's factor, none, and factors below 1 (a prediction taken as an overestimate)
        for label, factor in (("with", model["safety"][q]), ("none", 1.0), ("0.5", 0.5), ("0.33", 1 / 3)):
            n = same = finer = coarser = missed = 0
            for case, predicted in zip(cases, predictions):
                actual = [case["mesh"][q][str(lv)] for lv in MESH_LEVELS]
                for target in DECISION_TARGETS[q]:
                    cheapest = next((lv for lv, e in zip(MESH_LEVELS, actual) if e <= target), None)
                    if cheapest is None:
                        continue
                    chosen = next((lv for lv in accuracy.levels() if factor * predicted["mesh"][q][str(lv)] <= target),
                                  max(accuracy.levels()) + 1)
                    n += 1
                    same += chosen == cheapest
                    finer += chosen > cheapest
                    coarser += chosen < cheapest
                    missed += chosen < cheapest and actual[chosen - 1] > target
            out[(q, label)] = {"n": n, "same": same / n, "finer": finer / n, "coarser": coarser / n,
                               "met": 1.0 - missed / n}
    return out


def report(model: dict, rows: list[dict]) -> str:
    ratios, safety = model["leave_one_out"], model["safety"]
    lines = ["Each training case left out and predicted from the others (capsim.solve.accuracy.nearest): the ratio "
             "actual / predicted of its mesh error at levels 1-3; the safety factor a target's prediction is "
             f"multiplied by covers {100 * SAFETY_QUANTILE:g} % of them:", "",
             "| quantity | ratios: 10 % | median | 90 % | largest | safety factor |", "|---|---|---|---|---|---|"]
    for q in QUANTITIES:
        r = np.array(ratios[q])
        lines.append(f"| {q} | {np.quantile(r, 0.1):.2g} | {np.median(r):.2g} | {np.quantile(r, 0.9):.2g} | "
                     f"{r.max():.2g} | {safety[q]:.2g} |")
    lines += ["", "What the predicted level does on the same left-out cases (capsim.solve.accuracy.choose's rule on the mesh "
              "error, targets " + "; ".join(f"{q} {', '.join(f'{t:g}' for t in ts)}" for q, ts in DECISION_TARGETS.items())
              + ", each that a level 1-3 of the case meets): the level chosen against the cheapest that meets the "
              "target, at the model's safety factor, none, and factors below 1. A level finer than needed costs "
              "2-2.4× at level 1 → 2 and more above (the accuracy target's table below), so these are how often a "
              "predicted choice can be within 2× of the cheapest: at no margin does the prediction from these "
              "features pick the cheapest level in much more than 6 targets of 10, and the margins that come "
              "nearest miss 1 target in 7-10:", "",
              "| quantity | safety factor | targets | cheapest level chosen | finer | coarser | met |",
              "|---|---|---|---|---|---|---|"]
    for (q, label), d in decisions(model).items():
        factor = {"with": f"{model['safety'][q]:.2g} (the model's)", "none": "1 (none)"}.get(label, label)
        lines.append(f"| {q} | {factor} | {d['n']} | {100 * d['same']:.0f} % | {100 * d['finer']:.0f} % | "
                     f"{100 * d['coarser']:.0f} % | {100 * d['met']:.0f} % |")
    lines += ["", f"The {len(model['cases'])} training cases (kt 4): mesh error at each level (relative; θ in rad) "
              "against the Richardson extrapolation of levels 1-3 at rtol 1e-5 (observed order), and D_xy's time "
              "error at rtol 1e-3 and 1e-4 (level 2, against rtol 1e-6):", "",
              "| training case | D_xy level 1 | 2 | 3 | θ level 1 | 2 | 3 | S*_xy level 1 | 2 | 3 | "
              "D_xy time, rtol 1e-3 | 1e-4 |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for c in model["cases"]:
        mesh = " | ".join(f"{c['mesh'][q][lv]:.2g}" for q in QUANTITIES for lv in ("1", "2", "3"))
        lines.append(f"| {c['label']} | {mesh} | {c['time']['D_xy']['0.001']:.2g} | {c['time']['D_xy']['0.0001']:.2g} |")
    sec = model["seconds_per_evaluation"]
    lines += ["", "Seconds per evaluation (one core, median over the training cases): " +
              ", ".join(f"level {lv} {v:.2g}" for lv, v in sec.items()) + f" (level 4: level 3 × {model['level4_ratio']:.2g}, measured on a sphere at λ 1 and 5; levels 5-6: ×16 a "
              "level, the dense sums' N², not measured)."]
    failed = [label for label in TRAINING if label not in {r["label"] for r in rows}]
    if failed:
        lines += ["", "Training cases that did not run to kt 4 (a guard stopped them; left out): " + "; ".join(failed) + "."]
    return "\n".join(lines) + "\n"


def _measure_alone(label: str) -> dict:
    """measure() in a worker process, in its own temporary folder; a run that fails is a row that says so."""
    with tempfile.TemporaryDirectory() as tmp:
        try:
            return measure(label, TRAINING[label], tmp)
        except RuntimeError as exc:
            return {"label": label, "failed": str(exc)[-300:]}


def main() -> None:
    # the rows kept in the model file are reused (--fit: no runs at all; --all: measure every case again)
    kept = {} if "--all" in sys.argv else {r["label"]: r for r in json.loads(MODEL.read_text()).get("rows", [])}
    if PARTIAL.exists() and "--all" not in sys.argv:  # an interrupted measurement goes on where it stopped
        kept.update({r["label"]: r for r in json.loads(PARTIAL.read_text())})
    missing = [label for label in TRAINING if label not in kept and "--fit" not in sys.argv]
    workers = int(next((a.split("=", 1)[1] for a in sys.argv if a.startswith("--workers=")), "1"))
    with ProcessPoolExecutor(max_workers=workers) as pool:
        for label, row in zip(missing, pool.map(_measure_alone, missing)):
            print(label, "failed: " + row["failed"] if "failed" in row else "", flush=True)
            kept[label] = row
            PARTIAL.write_text(json.dumps(list(kept.values()), indent=1) + "\n")  # kept as it goes
    # a training case that cannot run (a guard stops it) is said and left out
    rows = [kept[label] for label in TRAINING if label in kept and "failed" not in kept[label]]
    previous = json.loads(MODEL.read_text()).get("level4_ratio") if MODEL.exists() else None
    level4_ratio = previous if "--fit" in sys.argv and previous else level4_ratio_measured()
    model = fit(rows, level4_ratio)
    model["level4_ratio"] = level4_ratio
    model["rows"] = rows
    MODEL.write_text(json.dumps(model, indent=1) + "\n")
    MD.write_text(report(model, rows))
    print(MD.read_text())


if __name__ == "__main__":
    sys.exit(main())
