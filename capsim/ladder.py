"""An accuracy target met by measuring (``accuracy.method: measure``, or ``auto`` where the error
model cannot place the case; issue 44).

The ladder runs the case at mesh levels 1, 2, … at one tolerance, its time error a tenth of the
target: predicted (``capsim.accuracy.ladder_rtol``) where the error model allows the loosest, else
measured on the case itself (level 1 at the two ``capsim.accuracy.PILOT_RTOLS``,
``capsim.accuracy.ladder_rtol_measured``) rather than paid at every level on the nearest training
cases' word; and, after each, estimates that run's error from the levels
below it (``capsim.accuracy.measured_error``: Richardson with the observed order of the last two
differences, or the training's smallest order from two levels). The first run whose estimate
(plus its time error) meets the target is kept; levels whose differences change sign or
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

#: θ's differences between levels are taken modulo π (the orientation of the shear plane's ellipse)
PERIODS = {"theta": math.pi}


def run_measured(case: Case, run_one: Callable, progress=None, overwrite: bool = True):
    """Run the ladder for the case's accuracy target, each level by ``run_one(case, progress=…,
    overwrite=…)`` (:func:`capsim.runner.run_case`, which calls this: passed in, not imported);
    returns the kept run's :class:`capsim.runner.RunResult` with ``accuracy`` the verdict (one line)."""
    from capsim import accuracy as error_model
    from capsim.checkpoint import checkpoint_path
    from capsim.store import move_run, read_run_record, write_accuracy

    target = case.accuracy
    q = target.quantity
    relative = q not in error_model.model()["absolute"]
    entry, label = error_model.entry(case.error_model_features())
    out = Path(case.output.path)
    work = out.with_name(f".{out.name}.ladder-{os.getpid()}.h5")  # beside it: one file system, one rename
    record: dict[str, Any] = {"level": [], "values": [], "errors": [], "orders": [], "evaluations": [],
                              "wall_time_s": []}
    # the runs share one rtol: their differences are the mesh's; the time error is added to each estimate
    rtol = float(case.time.rtol)
    time_error = error_model.safety(q) * error_model.time_error(entry, q, rtol)  # the model's
    pilots: dict[float, Any] = {}
    if error_model.measures_time_error(rtol, case.error_model_features()):
        # the model's nearest cases ask for a tolerance far tighter than the loosest: measure this
        # case's own time error at level 1 (two tolerances) rather than pay theirs at every level (an
        # oblate 0.4 at λ 0.5 took 5e-5 from its oblate 0.5 neighbours and cost 29× what 2e-3 did)
        pilots = _pilots(case, run_one, work, progress)
        if isinstance(pilots, tuple):  # a pilot run did not complete: the ladder ends with it
            plain, result = pilots
            failed = _pilot_path(work, float(plain.time.rtol))
            if failed.exists():  # its file (status and reason) where the output was to be
                move_run(failed, out, plain.to_yaml(), overwrite=overwrite)
            _remove(work, error_model.PILOT_RTOLS)  # and the checkpoints: a ladder is not resumed
            if isinstance(result, Exception):  # it raised: so does the ladder, as a plain run would
                raise result
            return dataclasses.replace(result, path=str(out), accuracy=(
                f"accuracy {q} {target.target:g}: the level-1 run at rtol {plain.time.rtol:g} (the time error's "
                f"measure) {result.status}: {result.status_reason}; target unchecked"))
        loose, tight = (read_run_record(pilots[r][1].path)["last"][q] for r in error_model.PILOT_RTOLS)
        measured = error_model.time_error_from_pair(loose, tight, error_model.PILOT_RTOLS, relative, PERIODS.get(q))
        rtol = error_model.ladder_rtol_measured(measured, target.target)
        time_error = measured * rtol / error_model.PILOT_RTOLS[0]
        how = (f"measured: level 1 at rtol {error_model.PILOT_RTOLS[0]:g} and {error_model.PILOT_RTOLS[1]:g} "
               f"gave {loose:.6g} and {tight:.6g}")
    else:
        how = f"predicted (error model of {label}, safety factor included)"
    kept, verdict, met = None, "", False
    for level in range(1, target.max_level + 1):
        # the level's plain case as the output will hold it; it runs into the hidden file beside
        plain = apply_overrides(case, **{"accuracy": None, "mesh.level": level, "time.rtol": rtol})
        if level == 1 and rtol in pilots:  # the time error's run at this tolerance is level 1's
            os.replace(pilots[rtol][1].path, work)
            result = dataclasses.replace(pilots[rtol][1], path=str(work))
        else:
            try:
                result = run_one(apply_overrides(plain, **{"output.path": str(work)}), progress=progress,
                                 overwrite=True)
            except Exception as exc:  # a solve that diverges: the run file says 'failed' and the run raises
                if kept is None:  # as a plain run: its failed file at the output path, and the error
                    _remove(work, error_model.PILOT_RTOLS)
                    if work.exists():
                        move_run(work, out, plain.to_yaml(), overwrite=overwrite)
                    checkpoint_path(work).unlink(missing_ok=True)  # a ladder is not resumed
                    raise
                # the finest completed level stays the output, said so (the status line below)
                result = dataclasses.replace(kept, status="failed", status_reason=_first_line(exc))
        if level == 1:  # the pilots not kept as level 1 go; their cost is the time error's
            _remove(work, error_model.PILOT_RTOLS)
            record["time_error_how"] = how
            record["pilot_evaluations"] = sum(int(r.velocity_evaluations or 0) for rr, (_, r) in pilots.items()
                                              if rr != rtol)
        if result.status != "completed":  # stopped, failed or unstable: the ladder ends with it, said so
            stopped = f"the level-{level} run {result.status}: {result.status_reason}"
            if kept is None:  # nothing kept yet: the run's own file, where the output was to be, says why
                move_run(work, out, plain.to_yaml(), overwrite=overwrite)
                checkpoint_path(work).unlink(missing_ok=True)  # a ladder is not resumed
                return dataclasses.replace(result, path=str(out),
                                           accuracy=f"accuracy {q} {target.target:g}: {stopped}; target unchecked")
            for leftover in (work, checkpoint_path(work)):
                leftover.unlink(missing_ok=True)
            verdict = f"{verdict}; the ladder then stopped ({stopped})"
            write_accuracy(out, {**_scalars(q, target, rtol, time_error, met, verdict, label), **record})
            return dataclasses.replace(kept, accuracy=verdict)
        record["level"].append(level)
        record["values"].append(read_run_record(work)["last"][q])
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
        verdict = _verdict(q, target, rtol, record, estimate, met)
        if not met and level == target.max_level:
            finer = error_model.predicted_cost(entry, level + 1, rtol, case.time.t_end)
            verdict += f" by accuracy.max_level {level} (level {level + 1} would cost ~{finer:.2g} s, predicted)"
        elif not met:
            verdict += f" yet (the ladder goes on to level {level + 1})"
        write_accuracy(out, {**_scalars(q, target, rtol, time_error, met, verdict, label), **record})
        if met:
            break
    return dataclasses.replace(kept, accuracy=verdict)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}"


def _pilots(case: Case, run_one: Callable, work: Path, progress) -> dict[float, Any] | tuple:
    """Level 1 at each of PILOT_RTOLS into its own hidden file: {rtol: (plain case, result)}; the
    (plain case, result) of the first that did not complete, or (plain case, exception) of one that raised."""
    from capsim.accuracy import PILOT_RTOLS

    runs = {}
    for r in PILOT_RTOLS:
        plain = apply_overrides(case, **{"accuracy": None, "mesh.level": 1, "time.rtol": r})
        try:
            result = run_one(apply_overrides(plain, **{"output.path": str(_pilot_path(work, r))}),
                             progress=progress, overwrite=True)
        except Exception as exc:  # noqa: BLE001 - the caller keeps its file and raises it
            return plain, exc
        if result.status != "completed":
            return plain, result
        runs[r] = (plain, result)
    return runs


def _pilot_path(work: Path, rtol: float) -> Path:
    return work.with_name(f"{work.stem}-rtol{rtol:g}.h5")


def _remove(work: Path, rtols) -> None:
    """The pilots' files and checkpoints that are not level 1's."""
    from capsim.checkpoint import checkpoint_path

    for r in rtols:
        for leftover in (_pilot_path(work, r), checkpoint_path(_pilot_path(work, r))):
            leftover.unlink(missing_ok=True)


def _scalars(q: str, target, rtol: float, time_error: float, met: bool, verdict: str, label: str) -> dict[str, Any]:
    return {"quantity": q, "target": float(target.target), "rtol": float(rtol), "time_error": float(time_error),
            "met": bool(met), "verdict": verdict, "error_model": label}


def _verdict(q: str, target, rtol: float, record: dict[str, Any], estimate: dict[str, Any], met: bool) -> str:
    level, error = record["level"][-1], record["errors"][-1]
    if len(record["level"]) == 1:
        return (f"accuracy {q} {target.target:g}: level {level} at rtol {rtol:g} kept, its error not "
                "estimated (one level): target NOT met")
    how = (f"order {estimate['order']:.2g} observed" if estimate["order_from_levels"] and estimate["converging"]
           else f"order {estimate['order']:.2g} assumed from two levels" if estimate["converging"]
           else "levels not yet converging: the larger difference")
    return (f"accuracy {q} {target.target:g}: level {level} at rtol {rtol:g} kept, its error {error:.2g} "
            f"({how}; measured on levels {', '.join(map(str, record['level']))}, {sum(record['wall_time_s']):.1f} s "
            f"in all): target {'met' if met else 'NOT met'}")
