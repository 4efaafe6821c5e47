"""An accuracy target met by measuring (``accuracy.method: measure``, or ``auto`` where the error
model cannot place the case; issue 44).

The ladder runs the case at mesh levels 1, 2, … at one tolerance (``capsim.accuracy.ladder_rtol``:
its time error a tenth of the target) and, after each, estimates that run's error from the levels
below it (``capsim.accuracy.measured_error``: Richardson with the observed order of the last two
differences, or the training's smallest order from two levels). The first run whose estimate
(plus its predicted time error) meets the target is kept; levels whose differences change sign or
grow are not yet converging and are never accepted. Past ``accuracy.max_level`` the finest run is
kept and the target is said NOT met, with the estimate.

Every level runs into a hidden file beside the output and, completed, replaces the output with
the ladder so far in its ``accuracy`` group (:func:`capsim.store.move_run`,
:func:`capsim.store.write_accuracy`): the output is always the finest completed level, so a
ladder stopped or failing at a later level loses nothing it had (the stopped level's own file and
checkpoint go; the verdict says why it stopped). The file that stays is a plain run of its level
and rtol (its case has no target, so ``--resume --t-end`` extends it as any run).
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path
from typing import Any, Callable

from capsim.config import Case, apply_overrides
from capsim.errors import first_line

#: θ's differences between levels are taken modulo π (the orientation of the shear plane's ellipse)
PERIODS = {"theta": math.pi}


def run_measured(case: Case, run_one: Callable, progress=None, overwrite: bool = True):
    """Run the ladder for the case's accuracy target, each level by ``run_one(case, progress=…,
    overwrite=…)`` (:func:`capsim.runner.run_case`, which calls this: passed in, not imported);
    returns the kept run's :class:`capsim.runner.RunResult` with ``accuracy`` the verdict (one line)."""
    from capsim import accuracy as error_model
    from capsim.checkpoint import checkpoint_path
    from capsim.store import move_run, write_accuracy
    from capsim.study import run_final_values

    target = case.accuracy
    q = target.quantity
    relative = q not in error_model.model()["absolute"]
    entry, label = error_model.entry(case.error_model_features())
    # the runs share one rtol: their differences are the mesh's; the time error is the model's, added
    time_error = error_model.safety(q) * error_model.time_error(entry, q, case.time.rtol)
    out = Path(case.output.path)
    work = out.with_name(f".{out.name}.ladder-{os.getpid()}.h5")  # beside it: one file system, one rename
    record: dict[str, Any] = {"level": [], "values": [], "errors": [], "orders": [], "evaluations": [],
                              "wall_time_s": []}
    kept, verdict, met = None, "", False
    for level in range(1, target.max_level + 1):
        # the level's plain case as the output will hold it; it runs into the hidden file beside
        plain = apply_overrides(case, **{"accuracy": None, "mesh.level": level, "time.rtol": case.time.rtol})
        try:
            result = run_one(apply_overrides(plain, **{"output.path": str(work)}), progress=progress, overwrite=True)
        except Exception as exc:  # a solve that diverges: the run file says 'failed' and the run raises
            if kept is None:  # as a plain run: its failed file at the output path, and the error
                _give_output(work, out, plain, overwrite)
                raise
            result, stopped = None, f"the level-{level} run failed: {type(exc).__name__}: {first_line(exc, '')}"
        else:  # stopped, failed or unstable: the ladder ends with it, said so
            stopped = (None if result.status == "completed"
                       else f"the level-{level} run {result.status}: {result.status_reason}")
        if stopped:
            if kept is None:  # nothing kept yet: the run's own file, where the output was to be, says why
                _give_output(work, out, plain, overwrite)
                return dataclasses.replace(result, path=str(out),
                                           accuracy=f"accuracy {q} {target.target:g}: {stopped}; target unchecked")
            for leftover in (work, checkpoint_path(work)):
                leftover.unlink(missing_ok=True)
            verdict = f"{verdict}; the ladder then stopped ({stopped})"
            write_accuracy(out, {**_scalars(q, target, case, met, verdict, label), **record})
            return dataclasses.replace(kept, accuracy=verdict)
        record["level"].append(level)
        record["values"].append(run_final_values(work)[q])  # several capsules: their mean
        record["evaluations"].append(int(result.velocity_evaluations or 0))
        record["wall_time_s"].append(float(result.wall_time_s or 0.0))
        estimate = error_model.measured_error(record["values"], relative, PERIODS.get(q))
        error = estimate["error"] + time_error  # inf at the first level: no estimate
        record["errors"].append(float(error) if math.isfinite(error) else math.nan)
        record["orders"].append(float(estimate["order"]))
        met = estimate["converging"] and error <= target.target
        # each completed level replaces the one before at the output path, with the ladder so far:
        # a ladder stopped later keeps the finest level it completed
        move_run(work, out, plain.to_yaml(), overwrite=overwrite or level > 1, requested_case_yaml=case.to_yaml())
        kept = dataclasses.replace(result, path=str(out))
        verdict = _verdict(q, target, case, record, estimate, met)
        if not met and level == target.max_level:
            finer = error_model.predicted_cost(entry, level + 1, case.time.rtol, case.time.t_end)
            verdict += f" by accuracy.max_level {level} (level {level + 1} would cost ~{finer:.2g} s, predicted)"
        elif not met:
            verdict += f" yet (the ladder goes on to level {level + 1})"
        write_accuracy(out, {**_scalars(q, target, case, met, verdict, label), **record})
        if met:
            break
    return dataclasses.replace(kept, accuracy=verdict)


def _give_output(work: Path, out: Path, plain: Case, overwrite: bool) -> None:
    """The first level's run that did not complete takes the output path, as a plain run's file would
    be there; its checkpoint goes (a ladder is not resumed)."""
    from capsim.checkpoint import checkpoint_path
    from capsim.store import move_run

    if work.exists():
        move_run(work, out, plain.to_yaml(), overwrite=overwrite)
    checkpoint_path(work).unlink(missing_ok=True)


def _scalars(q: str, target, case: Case, met: bool, verdict: str, label: str) -> dict[str, Any]:
    return {"quantity": q, "target": float(target.target), "rtol": float(case.time.rtol), "met": bool(met),
            "verdict": verdict, "error_model": label}


def _verdict(q: str, target, case: Case, record: dict[str, Any], estimate: dict[str, Any], met: bool) -> str:
    level, error = record["level"][-1], record["errors"][-1]
    if len(record["level"]) == 1:
        return (f"accuracy {q} {target.target:g}: level {level} at rtol {case.time.rtol:g} kept, its error not "
                "estimated (one level): target NOT met")
    how = (f"order {estimate['order']:.2g} observed" if estimate["order_from_levels"] and estimate["converging"]
           else f"order {estimate['order']:.2g} assumed from two levels" if estimate["converging"]
           else "levels not yet converging: the larger difference")
    return (f"accuracy {q} {target.target:g}: level {level} at rtol {case.time.rtol:g} kept, its error {error:.2g} "
            f"({how}; measured on levels {', '.join(map(str, record['level']))}, {sum(record['wall_time_s']):.1f} s "
            f"in all): target {'met' if met else 'NOT met'}")
