"""An accuracy target met by measuring (``accuracy.method: measure``, or ``auto`` where the error
model cannot place the case).

The ladder runs the case at mesh levels 1, 2, … at one tolerance (``capsim.solve.accuracy.ladder_rtol``:
its time error a tenth of the target) and, after each, estimates that run's error from the levels
below it (``capsim.solve.accuracy.measured_error``: Richardson with the observed order of the last two
differences, or the training's smallest order from two levels). The first run whose estimate
(plus its predicted time error) meets the target is kept; levels whose differences change sign or
grow are not yet converging and are never accepted. Past ``accuracy.max_level`` the finest run is
kept and the target is said NOT met, with the estimate.

Every level runs into a hidden file beside the output (:func:`capsim.storage.files.ladder_work_path`)
and, completed, replaces the output with the ladder so far in its ``accuracy`` group
(:func:`capsim.storage.store.move_run`, :func:`capsim.storage.store.write_accuracy`): the output is always the
finest completed level, so a ladder stopped or failing at a later level loses nothing it had (the
stopped level's own file and checkpoint go; the verdict says why it stopped). The file that stays
is a plain run of its level and rtol (its case has no target, so ``--resume --t-end`` extends it as
any run).

The ladder holds its output's lock (:class:`capsim.storage.files.FileLock`, the one a plain run takes)
from before its first level to after its last write: a run, an extension or a second ladder on the
same output meanwhile is refused, never silently replaced by the ladder's next level. Under that
lock it first removes what a ladder killed outright left beside the output
(:func:`capsim.storage.files.remove_stale_ladder_files`), and whatever way it ends it leaves no hidden file
of its own. A level-1 run stopped by a signal or a full disk takes the output path with its
checkpoint: ``capsim run OUT --resume`` finishes it as the plain level-1 run it is (the ladder
itself is never resumed).

How it ends (docs/data_safety.md, "How a ladder ends"; ``capsim run``'s exit code): the target met
(status ``completed``, ``accuracy_met`` True, exit 0); not met by ``accuracy.max_level``
(``completed``, ``accuracy_met`` False, exit 3); a level interrupted (``interrupted``, exit 1);
a level failed, unstable or raising (its status, exit 1; raised at level 1, as a plain run's
error); a full disk (:class:`capsim.storage.files.StorageError`, exit 2). Whenever a level was kept, the
output is it, with ``accuracy/met`` saying whether its target was met.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any, Callable

from capsim.config import Case, apply_overrides
from capsim.errors import first_line

#: θ's differences between levels are taken modulo π (the orientation of the shear plane's ellipse)
PERIODS = {"theta": math.pi}


def run_measured(case: Case, run_one: Callable, progress=None, overwrite: bool = True, *,
                 stop_signals: Callable, result_type: type):
    """Run the ladder for the case's accuracy target, each level by ``run_one(case, progress=…,
    overwrite=…)`` (:func:`capsim.runs.runner.run_case`, which calls this: passed in, not imported);
    returns the kept run's :class:`capsim.runs.runner.RunResult` with ``accuracy`` the verdict (one line),
    ``accuracy_met`` whether it meets the target, and the status of how the ladder ended.
    ``stop_signals`` (the runner's signal guard) and ``result_type`` (``RunResult``) come from the
    runner too: the ladder stops on the same signals and returns the same result, without an
    import of the runner (which imports this module)."""
    from capsim.storage.checkpoint import checkpoint_path
    from capsim.storage.files import FileLock, OutputError, ladder_work_path, remove_stale_ladder_files

    out = Path(case.output.path)
    with stop_signals() as stop, FileLock(out) as lock:
        if not overwrite and out.exists():  # checked again under the lock, as a plain run does
            raise OutputError(f"{out} exists (written by another run since this one was started); "
                              "use --overwrite to replace it")
        remove_stale_ladder_files(out)
        work = ladder_work_path(out)  # beside it: one file system, one rename
        try:
            return _climb(case, run_one, progress, out, work, lock, stop, result_type)
        finally:  # whatever way it ends (a second Ctrl-C, a refusal, an error): nothing hidden stays
            for leftover in (work, checkpoint_path(work)):
                leftover.unlink(missing_ok=True)


def _climb(case: Case, run_one: Callable, progress, out: Path, work: Path, lock, stop, RunResult):
    from capsim.solve import accuracy as error_model
    from capsim.storage.files import StorageError
    from capsim.storage.store import write_accuracy

    target = case.accuracy
    q = target.quantity
    relative = error_model.is_relative(q)
    features = case.error_model_features()
    entry, label = error_model.entry(features)
    # the runs share one rtol: their differences are the mesh's; the time error is the model's (a scene
    # quantity's: assumed, capsim.solve.accuracy.SCENE_TIME_ERROR), added
    time_error = error_model.ladder_time_error(q, case.time.rtol, features)
    record: dict[str, Any] = {"level": [], "values": [], "errors": [], "absolute_errors": [], "orders": [],
                              "evaluations": [], "wall_time_s": []}
    kept, verdict, met = None, "", False
    for level in range(1, target.max_level + 1):
        # the level's plain case as the output will hold it; it runs into the hidden file beside
        plain = apply_overrides(case, **{"accuracy": None, "mesh.level": level, "time.rtol": case.time.rtol})
        result, status = None, "interrupted"
        if stop.signum is not None:  # a signal between two levels: the next one is not started
            stopped = f"interrupted by {stop.name} before level {level} started"
            if kept is None:
                return RunResult("interrupted", f"{stopped}: nothing was computed or written; run it again", str(out),
                                 accuracy=f"accuracy {q} {target.target:g}: {stopped}; target unchecked",
                                 accuracy_met=False)
        else:
            try:
                result = run_one(apply_overrides(plain, **{"output.path": str(work)}), progress=progress,
                                 overwrite=True)
            except StorageError as exc:  # a full disk: exit 2 as a plain run's, said what stays
                raise _storage_stop(exc, level, kept, work, out, plain, lock, q, target, case, verdict, record, label)
            except Exception as exc:  # a solve that diverges: the run file says 'failed' and the run raises
                if kept is None:  # as a plain run: its failed file at the output path, and the error
                    _give_output(work, out, plain, lock)
                    raise
                status, stopped = "failed", f"the level-{level} run failed: {type(exc).__name__}: {first_line(exc, '')}"
            else:  # stopped, failed or unstable: the ladder ends with it, said so
                status = result.status
                stopped = (None if result.status == "completed"
                           else f"the level-{level} run {result.status}: {result.status_reason}")
        if stopped:
            if kept is None:  # nothing kept yet: the run's own file, where the output was to be, says why
                resumable = _give_output(work, out, plain, lock)
                reason = result.status_reason
                if resumable:
                    reason += (f"; level 1 of the ladder, kept with its checkpoint: capsim run {out} --resume "
                               "finishes that level as a plain run (the ladder is not resumed)")
                return dataclasses.replace(result, path=str(out), status_reason=reason, accuracy_met=False,
                                           accuracy=f"accuracy {q} {target.target:g}: {stopped}; target unchecked")
            verdict = f"{verdict}; the ladder then stopped ({stopped})"
            write_accuracy(out, {**_scalars(q, target, case, met, verdict, label), **record}, held=lock)
            reason = (f"the ladder stopped at level {level} ({stopped}); {out} keeps level {level - 1}, completed "
                      f"(target {'met' if met else 'NOT met'}); a ladder is not resumed: run the case again "
                      "(--overwrite) to measure further")
            return dataclasses.replace(kept, status=status, status_reason=reason, accuracy=verdict, accuracy_met=met)
        record["level"].append(level)
        record["values"].append(_final_value(work, q))
        record["evaluations"].append(int(result.velocity_evaluations or 0))
        record["wall_time_s"].append(float(result.wall_time_s or 0.0))
        estimate = error_model.measured_error(record["values"], relative, PERIODS.get(q))
        error = estimate["error"] + time_error  # inf at the first level: no estimate
        record["errors"].append(float(error) if math.isfinite(error) else math.nan)
        # the convention is relative, the absolute beside it (θ's is absolute: the same number)
        absolute = error * abs(record["values"][-1]) if relative else error
        record["absolute_errors"].append(float(absolute) if math.isfinite(absolute) else math.nan)
        record["orders"].append(float(estimate["order"]))
        met = estimate["converging"] and error <= target.target
        # each completed level replaces the one before at the output path, with the ladder so far:
        # a ladder stopped later keeps the finest level it completed
        from capsim.storage.store import move_run

        move_run(work, out, plain.to_yaml(), overwrite=True, requested_case_yaml=case.to_yaml(), held=lock)
        kept = dataclasses.replace(result, path=str(out))
        verdict = _verdict(q, target, case, record, estimate, met)
        if not met and level == target.max_level:
            finer = error_model.predicted_cost(entry, level + 1, case.time.rtol, case.time.t_end)
            verdict += f" by accuracy.max_level {level} (level {level + 1} would cost ~{finer:.2g} s, predicted)"
        elif not met:
            verdict += f" yet (the ladder goes on to level {level + 1})"
        write_accuracy(out, {**_scalars(q, target, case, met, verdict, label), **record}, held=lock)
        if met:
            break
    return dataclasses.replace(kept, accuracy=verdict, accuracy_met=bool(met))


def _storage_stop(exc: Exception, level: int, kept, work: Path, out: Path, plain: Case, lock, q: str, target,
                  case: Case, verdict: str, record: dict, label: str) -> Exception:
    """The StorageError a level's full disk ends the ladder with, saying what the output holds: at
    level 1 that level's run with its checkpoint (a plain run's message stands, of the output's
    path); later, the finest completed level (its level file and checkpoint removed)."""
    from capsim.storage.files import StorageError
    from capsim.storage.store import write_accuracy

    text = first_line(exc, "")
    if kept is None:
        try:
            _give_output(work, out, plain, lock)
        except (OSError, StorageError) as again:  # not even that could be written: nothing is kept
            return StorageError(f"{out}: cannot write: the ladder's level 1 stopped ({text}) and could not be kept "
                                f"({first_line(again, '')}); nothing was written at {out}")
        return StorageError(f"{text.replace(str(work), str(out))} (level 1 of the ladder, a plain run: the ladder "
                            "itself is not resumed)")
    # the level's own message names its hidden file and offers a --resume of it: the cause alone
    cause = text.partition("; the run stopped")[0].replace(f"{work}: ", "").replace(str(work), "the level's file")
    verdict = f"{verdict}; the ladder then stopped (the level-{level} run could not be written: {cause})"
    try:
        write_accuracy(out, {**_scalars(q, target, case, False, verdict, label), **record}, held=lock)
    except (OSError, StorageError):
        pass  # the kept level stands with the ladder's record of the level before
    return StorageError(f"{out}: cannot write level {level} of the ladder ({cause}); {out} keeps level {level - 1}, "
                        "completed (target NOT met); the level's file and checkpoint were removed and a ladder is "
                        "not resumed: make room and run the case again (--overwrite)")


def _give_output(work: Path, out: Path, plain: Case, lock) -> bool:
    """The first level's run that did not complete takes the output path, as a plain run's file
    would be there, with its checkpoint (an interrupted one's: ``--resume`` finishes that run);
    whether a checkpoint came with it."""
    from capsim.storage.checkpoint import checkpoint_path
    from capsim.storage.store import move_run

    if not work.exists():  # stopped before its first row: nothing was written, the output is as it was
        return False
    resumable = checkpoint_path(work).exists()
    move_run(work, out, plain.to_yaml(), overwrite=True, held=lock)
    return resumable


def _final_value(path: Path, q: str) -> float:
    """The target's value of a level's run file: the model's quantities at t_end (several capsules,
    their mean, θ each unwrapped); a scene quantity (capsim.solve.accuracy.SCENE_QUANTITIES: the lift's
    window mean, the pair's final separation, the migration) from the run's summary, as the closing
    table shows it (NaN where the summary has none)."""
    import h5py

    from capsim.solve.accuracy import SCENE_QUANTITIES
    from capsim.solve.observables import capsule_mean

    with h5py.File(path, "r", locking=False) as f:
        if q in SCENE_QUANTITIES:
            summary = f.get("summary")
            return float(summary[q][()]) if summary is not None and q in summary else math.nan
        return float(capsule_mean(f["timeseries"][q][()], angle=q in PERIODS)[-1])


def _scalars(q: str, target, case: Case, met: bool, verdict: str, label: str) -> dict[str, Any]:
    return {"quantity": q, "target": float(target.target), "rtol": float(case.time.rtol), "met": bool(met),
            "verdict": verdict, "error_model": label}


def _verdict(q: str, target, case: Case, record: dict[str, Any], estimate: dict[str, Any], met: bool) -> str:
    level, error = record["level"][-1], record["errors"][-1]
    if len(record["level"]) == 1:
        return (f"accuracy {q} {target.target:g}: level {level} at rtol {case.time.rtol:g} kept, its error not "
                "estimated (one level): target NOT met")
    from capsim.solve.accuracy import MEANINGLESS_RELATIVE, is_relative, short_name

    how = (f"order {estimate['order']:.2g} observed" if estimate["order_from_levels"] and estimate["converging"]
           else f"order {estimate['order']:.2g} assumed from two levels" if estimate["converging"]
           else "levels not yet converging: the larger difference")
    relative = is_relative(q)
    size = f"{error:.2g} relative, {record['absolute_errors'][-1]:.2g} absolute" if relative else f"{error:.2g}"
    text = (f"accuracy {q} {target.target:g}: level {level} at rtol {case.time.rtol:g} kept, its error {size} "
            f"({how}; measured on levels {', '.join(map(str, record['level']))}, {sum(record['wall_time_s']):.1f} s "
            f"in all): target {'met' if met else 'NOT met'}")
    value = record["values"][-1]
    if not math.isfinite(value):  # a summary without it (a run file written before it was kept)
        text += f"; the level-{level} run has no value of {short_name(q)}"
    elif relative and not error < MEANINGLESS_RELATIVE:  # said, not hidden
        # a value within its own error of 0 (a lift far from the wall): relative to it the error means nothing
        text += (f"; {short_name(q)} = {value:.3g} is within its error of 0, where a relative error means nothing: "
                 f"its absolute error {record['absolute_errors'][-1]:.2g} is the statement (no relative target can "
                 "be met on a value near 0)")
    return text
