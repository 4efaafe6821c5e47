"""An accuracy target met by measuring (``accuracy.method: measure``, or ``auto`` where the error
model cannot place the case; issue 44).

The ladder runs the case at mesh levels 1, 2, … at one tolerance (``capsim.accuracy.ladder_rtol``:
its time error a tenth of the target) and, after each, estimates that run's error from the levels
below it (``capsim.accuracy.measured_error``: Richardson with the observed order of the last two
differences, or the training's smallest order from two levels). The first run whose estimate
(plus its predicted time error) meets the target is kept; levels whose differences change sign or
grow are not yet converging and are never accepted. Past ``accuracy.max_level`` the finest run is
kept and the target is said NOT met, with the estimate.

Every level writes the case's own output path (the next level replaces the run before it): the
file that stays is the kept run, a plain run of its level and rtol (its case has no target, so a
``--resume --t-end`` extends it as any run), with the ladder's record in its ``accuracy`` group
(:func:`capsim.store.write_accuracy`). A stopped ladder leaves the level it was running as an
interrupted run, as any run does.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from capsim.config import Case, apply_overrides

#: θ's differences between levels are taken modulo π (the orientation of the shear plane's ellipse)
PERIODS = {"theta": math.pi}


def _value_at_t_end(path: str, quantity: str) -> float:
    import h5py

    with h5py.File(path, "r") as f:
        return float(f["timeseries"][quantity][-1])


def run_measured(case: Case, progress=None, overwrite: bool = True):
    """Run the ladder for the case's accuracy target; returns the kept run's
    :class:`capsim.runner.RunResult` with ``accuracy`` the verdict (one line)."""
    from capsim import accuracy as error_model
    from capsim.runner import run_case
    from capsim.store import write_accuracy

    target = case.accuracy
    q = target.quantity
    relative = q not in error_model.model()["absolute"]
    entry, label = error_model.entry(case.error_model_features())
    # the runs share one rtol: their differences are the mesh's; the time error is the model's, added
    time_error = error_model.safety(q) * error_model.time_error(entry, q, case.time.rtol)
    record: dict[str, Any] = {"level": [], "values": [], "errors": [], "orders": [], "evaluations": [],
                              "wall_time_s": []}
    result, met, estimate = None, False, None
    for level in range(1, target.max_level + 1):
        run = apply_overrides(case, **{"accuracy": None, "mesh.level": level, "time.rtol": case.time.rtol})
        result = run_case(run, progress=progress, overwrite=overwrite or level > 1)
        if result.status != "completed":  # stopped, failed or unstable: the ladder ends with it, said so
            verdict = (f"accuracy {q} {target.target:g}: the ladder stopped at level {level} (the run {result.status}: "
                       f"{result.status_reason}); target unchecked")
            return dataclasses.replace(result, accuracy=verdict)
        record["level"].append(level)
        record["values"].append(_value_at_t_end(result.path, q))
        record["evaluations"].append(int(result.velocity_evaluations or 0))
        record["wall_time_s"].append(float(result.wall_time_s or 0.0))
        estimate = error_model.measured_error(record["values"], relative, PERIODS.get(q))
        record["errors"].append(float(estimate["error"] + time_error) if len(record["values"]) > 1 else math.nan)
        record["orders"].append(float(estimate["order"]))
        if len(record["values"]) > 1 and estimate["converging"] and estimate["error"] + time_error <= target.target:
            met = True
            break
    error = record["errors"][-1]
    how = (f"order {estimate['order']:.2g} observed" if estimate["order_from_levels"] and estimate["converging"]
           else f"order {estimate['order']:.2g} assumed from two levels" if estimate["converging"]
           else "levels not yet converging: the larger difference")
    verdict = (f"accuracy {q} {target.target:g}: level {level} at rtol {case.time.rtol:g} kept, its error "
               f"{error:.2g} ({how}; measured on levels {', '.join(map(str, record['level']))}, "
               f"{sum(record['wall_time_s']):.1f} s in all): target {'met' if met else 'NOT met'}")
    if not met:
        finer = error_model.predicted_cost(entry, level + 1, case.time.rtol, case.time.t_end)
        verdict += f" by accuracy.max_level {level} (level {level + 1} would cost ~{finer:.2g} s, predicted)"
    write_accuracy(result.path, {"quantity": q, "target": float(target.target), "rtol": float(case.time.rtol),
                                 "met": met, "verdict": verdict, "error_model": label, **record})
    return dataclasses.replace(result, accuracy=verdict)
