"""One run, end to end: case → model → time loop → run file.

The loop only loops: the integrator (``timestepping.py``) owns the step
policy and its state, :func:`stopping.stop_reason` every rule that ends a run,
the observer (``observables.StepObserver``) the row of each accepted step, the
schedules (``schedules.py``) when snapshots and checkpoints are written, and
the store (``store.py``) the file. A checkpoint is the ``state()`` of each of
them; a resumed run repeats the uninterrupted one step for step.
"""

from __future__ import annotations

import bisect
import signal
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from capsim._version import __version__
from capsim.config import Case
from capsim.errors import first_line
from capsim.scene.flows import history_breakpoints
from capsim.numerics.membrane import law_attributes
from capsim.numerics.mesh import SurfaceMesh, rest_shape_attributes
from capsim.scene import body_axis, body_specs
from capsim.solve.observables import StepObserver, centroid_travel, relaxation_summary, run_summary, scene_summary
from capsim.storage.schedules import CheckpointSchedule, SnapshotSchedule
from capsim.numerics.kernels import spread_about_mean
from capsim.numerics.krylov import SolverDivergence
from capsim.solve.solver import build_model
from capsim.numerics.threads import set_run_threads
from capsim.runs.stopping import LoopState, Stop, end_tolerance, stop_reason
from capsim.storage import checkpoint
from capsim.storage.checkpoint import ResumeError, checkpoint_path, remove_checkpoint
from capsim.storage.files import remove_stale_ladder_files
from capsim.storage.store import FileLock, StorageError, TrajectoryError, TrajectoryWriter, read_end_state, read_run_status
from capsim.solve.timestepping import Integrator, build_integrator

__all__ = ["ResumeError", "RunResult", "build_model", "run_case"]

ProgressCallback = Callable[[dict], None]


#: in a campaign worker, the signal that stopped the parent (which relays every stop as SIGTERM)
RELAYED_SIGNAL: Callable[[], int | None] = lambda: None


class _StopRequested(Exception):
    pass


def _largest_area_change(areas) -> float | None:
    """max over the rows of |A/A0 - 1|, over every capsule (a scene's rows hold one area per capsule)."""
    if areas is None or len(areas) == 0:
        return None
    a = np.asarray(areas, dtype=float)
    return float(np.max(np.abs(a / a[0] - 1.0)))


#: how a run's record reduces a per-capsule column to the scene's one value (several capsules):
#: the worst capsule for the guards' quantities, the mean for the shape's
_SCENE_REDUCTION = {"min_element_quality": np.min, "max_principal_stretch": np.max, "min_tension": np.min,
                    "compressed_fraction": np.max}


def _scene_row(first: dict, last: dict) -> tuple[dict, dict]:
    """The first and last rows with every per-capsule column reduced to one number (a run of
    several capsules; one capsule's rows as they are): the worst capsule for the guards, the
    capsule whose volume and area moved most, the mean for the rest."""
    if not any(isinstance(v, np.ndarray) for v in last.values()):
        return first, last
    f, l = dict(first), dict(last)
    for key in ("volume", "area"):  # the capsule that changed most, its own first and last values
        k = int(np.argmax(np.abs(np.asarray(last[key]) / np.asarray(first[key]) - 1.0)))
        f[key], l[key] = float(first[key][k]), float(last[key][k])
    for row in (f, l):
        for key, value in row.items():
            if isinstance(value, np.ndarray):
                row[key] = float(_SCENE_REDUCTION.get(key, np.mean)(value))
    return f, l


class _StopSignals:
    """SIGINT, SIGTERM and SIGHUP ask the run to stop at its next velocity evaluation.

    Raising from the handler could land inside a numba kernel, where a
    KeyboardInterrupt surfaces as a SystemError with the run half-updated; a
    flag is read only between evaluations. A second SIGINT raises at once.
    Campaign workers ignore SIGINT (the parent decides) and keep ignoring it.
    """

    def __init__(self) -> None:
        self.signum: int | None = None
        self._old: dict[int, object] = {}
        #: set once the run acts on a stop: from then on it only closes its files, and a second
        #: Ctrl-C must not cut that short (it left files 'running' with no summary)
        self.closing = False

    def __enter__(self) -> _StopSignals:
        if threading.current_thread() is threading.main_thread():
            # SIGHUP: the terminal closed (an ssh session dropped) - stop the same way, not die 'running'
            for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
                if signal.getsignal(sig) is not signal.SIG_IGN:
                    self._old[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum, frame) -> None:
        if self.signum is not None and signum == signal.SIGINT and not self.closing:
            self.closing = True
            raise KeyboardInterrupt
        self.signum = self.signum or signum

    @property
    def name(self) -> str | None:
        if self.signum is None:
            return None
        relayed = RELAYED_SIGNAL() if self.signum == signal.SIGTERM else None
        if relayed is not None and relayed != signal.SIGTERM:  # a sweep's Ctrl-C, relayed to its workers
            return f"{signal.Signals(relayed).name} (relayed to the worker)"
        return signal.Signals(self.signum).name

    def check(self) -> None:
        if self.signum is not None:
            self.closing = True
            raise _StopRequested(self.name)

    def __exit__(self, *exc) -> bool:
        for sig, old in self._old.items():
            signal.signal(sig, old)
        return False


@dataclass(frozen=True)
class RunResult(Mapping):
    """What a run returns: how it ended, where it stands, what it cost, and the
    summary of its motion (window means, motion class, period...).

    It reads as a mapping too (``result["D_xy"]``), with the summary's window
    means in place of the final values (kept as ``final_D_xy``/``final_theta``).
    """

    status: str
    status_reason: str
    path: str
    t: float = 0.0
    steps: int = 0
    rejected_steps: int | None = None
    wall_time_s: float | None = None
    scheme: str | None = None
    scheme_choice: str | None = None
    rtol: float | None = None
    rtol_choice: str | None = None  # time.rtol auto or the accuracy target: what it chose and why
    accuracy: str | None = None  # a measured accuracy target (capsim.runs.ladder): the level kept, its error, met or not
    accuracy_met: bool | None = None  # that target met (capsim.runs.ladder; the CLI's exit code 3 when not)
    velocity_evaluations: int | None = None
    layer_applications: int | None = None
    linear_iterations: int | None = None
    layer_matrices: int | None = None
    final_D_xy: float | None = None
    final_theta: float | None = None
    volume_drift: float | None = None
    area_change: float | None = None
    largest_area_change: float | None = None  # max over the run's rows of |A/A0 - 1| (the capsule that moved most)
    area_tolerance: float | None = None  # membrane.skalak_c auto: what its C aimed at (capsim.config)
    min_element_quality: float | None = None
    max_principal_stretch: float | None = None
    min_tension: float | None = None
    compressed_fraction: float | None = None
    bending_modulus: float | None = None
    summary: dict = field(default_factory=dict)

    def record(self) -> dict[str, Any]:
        """The end-of-run values (the run file's ``run`` group): final D_xy and θ."""
        out = {f.name: getattr(self, f.name) for f in fields(self)
               if f.name not in ("status", "status_reason", "path", "summary") and getattr(self, f.name) is not None}
        if "final_D_xy" in out:
            out["D_xy"], out["theta"] = out.pop("final_D_xy"), out.pop("final_theta")
        return out

    def as_dict(self) -> dict[str, Any]:
        out = {f.name: getattr(self, f.name) for f in fields(self)
               if f.name != "summary" and getattr(self, f.name) is not None}
        if self.final_D_xy is not None:
            out["D_xy"], out["theta"] = self.final_D_xy, self.final_theta
        out.update(self.summary)
        return out

    def __getitem__(self, key: str) -> Any:
        return self.as_dict()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self.as_dict())

    def __len__(self) -> int:
        return len(self.as_dict())


def run_ladder(case: Case, run_one: Callable | None = None, progress: ProgressCallback | None = None,
               overwrite: bool = True) -> RunResult:
    """The ladder of a measured accuracy target (:func:`capsim.runs.ladder.run_measured`), each level
    run by ``run_one`` (default :func:`run_case`), under this module's signal guard and result."""
    from capsim.runs.ladder import run_measured

    return run_measured(case, run_one or run_case, progress, overwrite=overwrite, stop_signals=_StopSignals,
                        result_type=RunResult)


def run_case(case: Case, progress: ProgressCallback | None = None, resume: bool = False,
             overwrite: bool = True) -> RunResult:
    """Run one case and write its trajectory; returns the run's result.

    With ``resume`` the run continues from the checkpoint ``<output>.ckpt.npz``
    of an earlier, interrupted run of the same case (raising :class:`ResumeError`
    before touching any file when it cannot), on the same step sequence as an
    uninterrupted run. The checkpoint is written every ``output.checkpoint_every_s`` seconds (and
    ``checkpoint_every_steps`` steps where set) and when the run is stopped; a run killed or failed before its
    first (its file of this case left 'running' or 'failed', no checkpoint) is started again. The checkpoint is
    kept when the run is interrupted or fails, removed when it ends otherwise.

    The run file's lock (:class:`capsim.storage.store.FileLock`) is taken before any file
    is read, truncated or removed: a second writer of the same path gets
    :class:`capsim.storage.store.LockedError` and changes nothing. A failure to write (a
    full disk) raises :class:`capsim.storage.store.StorageError` with one line, after
    recording 'failed' and the reason in the file where that can still be written.
    With ``overwrite=False`` (the CLI without --overwrite) an existing run file found once the
    lock is held is refused (:class:`capsim.storage.files.OutputError`). A stop during set-up (before
    the first row) returns status 'interrupted' with nothing written.

    A case whose accuracy target is measured (``accuracy.method`` measure) runs the ladder of
    :mod:`capsim.runs.ladder` (levels 1, 2, … into this output path), which cannot be resumed.
    """
    if case.accuracy is not None and case.accuracy.method == "measure":
        if resume:
            raise ResumeError("a measured accuracy target's ladder is not resumed: run the case again (--overwrite) "
                              "to measure from level 1; a ladder stopped during level 1 left that level's plain run "
                              "at the output, which capsim run RUN.h5 --resume finishes (without the ladder)")
        return run_ladder(case, run_case, progress, overwrite=overwrite)
    with _StopSignals() as stop, FileLock(case.output.path):
        remove_stale_ladder_files(case.output.path)  # a killed ladder's hidden files (capsim.runs.ladder holds this lock)
        if resume and _killed_before_its_first_checkpoint(case):
            # nothing to continue from but the case: the run starts again, on the steps it had taken
            resume, overwrite = False, True
        if not overwrite and not resume and Path(case.output.path).exists():
            # checked again under the lock: another run may have written this path since the
            # caller's check (the first run after an install compiles its kernels in between)
            from capsim.storage.files import OutputError

            raise OutputError(f"{case.output.path} exists (written by another run since this one was started); "
                              "use --overwrite to replace it or --resume to continue it")
        try:
            run = _Run(case, progress, resume, stop)
        except (KeyboardInterrupt, _StopRequested):
            # stopped while the mesh, the model or the automatic scheme's probe were being set up:
            # no row, no checkpoint, no file of this run yet (an existing one is left as it was)
            return RunResult("interrupted", f"interrupted by {stop.name or 'SIGINT'} during set-up, before the "
                             "first step: nothing was computed or written; run it again (a sweep's --resume does)",
                             str(case.output.path))
        except SolverDivergence as exc:  # the automatic scheme's probe of the first state
            return RunResult("unstable", f"guard solver: during set-up (the automatic scheme's probe of the first "
                             f"state) {exc}; nothing was written", str(case.output.path))
        return run.execute()


def _killed_before_its_first_checkpoint(case: Case) -> bool:
    """True for a run file of this very case left 'running' (its process killed: SIGKILL, the
    out-of-memory killer) or 'failed' (a full disk refused even the failure's checkpoint) with neither
    a checkpoint nor an end state: stopped before its first checkpoint (output.checkpoint_every_s into
    the run), with nothing to continue from but the case. The caller holds the file's lock, so no live
    run is writing it."""
    from capsim.config import case_digest
    from capsim.storage.store import read_run_identity

    path = Path(case.output.path)
    if checkpoint_path(path).exists() or not path.exists():
        return False
    status, digest = read_run_identity(path)
    return (status in ("running", "failed") and digest == case_digest(case.model_dump(mode="json"))
            and read_end_state(path) is None)


# ---------------------------------------------------------------- one run

#: the share of a step's error budget (rtol · size per unit time) the velocity solve may take: its
#: tolerance is tightened below solver.tol where tol · the velocity's spread would pass it
SOLVE_SHARE = 0.01
#: no tighter than this (GMRES's round-off)
SOLVE_TOL_FLOOR = 1e-12


class _Run:
    """The parts of one run and the loop that drives them."""

    def __init__(self, case: Case, progress: ProgressCallback | None, resume: bool, stop: _StopSignals) -> None:
        self.wall0 = time.perf_counter()
        self.case, self.progress, self.stop = case, progress, stop
        self.path = Path(case.output.path)
        self.ckpt_path = checkpoint_path(self.path)
        self.config_yaml = case.to_yaml()
        self.extending = False  # resumed from a completed run's end state to a later t_end
        saved, self.wall_before = self._saved_state(case) if resume else (None, 0.0)
        self.model, X = build_model(case)
        set_run_threads(self.model.disc.n_nodes)  # a small mesh runs faster on one thread
        self.model.interrupt_check = stop.check  # SIGTERM honoured between GMRES iterations too
        self.integrator: Integrator = build_integrator(case, self._rhs, X, self.model)
        self.observer = StepObserver(self.model, X, case.axis, axes=[body_axis(b) for b in body_specs(case)])
        self.snapshots = SnapshotSchedule(case.output.snapshot_every)
        self.checkpoints = CheckpointSchedule(case.output.checkpoint_every_steps, case.output.checkpoint_every_s)
        self.committed: dict[str, dict[str, Any]] | None = None
        self.breakpoints = history_breakpoints(case.flow.history)  # the times the steps land on
        if saved is not None:
            self._reopen(saved)
        else:
            self._create(X)

    def _saved_state(self, case: Case) -> tuple[dict[str, dict[str, Any]], float]:
        """What --resume continues from: the checkpoint of an interrupted run or, where there
        is none, the end state of a run that reached its t_end (then extended to case.time.t_end)."""
        blob = None if self.ckpt_path.exists() else read_end_state(self.path)
        if blob is None:
            if not self.ckpt_path.exists():
                raise ResumeError(self._nothing_to_resume())
            return checkpoint.load(self.ckpt_path, case)
        self.extending = True
        return checkpoint.load_end_state(blob, self.path, case)

    def _nothing_to_resume(self) -> str:
        """Why a run file with neither a checkpoint nor an end state cannot be continued."""
        status = read_run_status(self.path)
        if status is None:
            return f"{self.path}: no run file here: nothing to resume (run the case without --resume)"
        if status == "completed":
            return (f"{self.path}: the run completed by a stopping rule before its t_end (time.stop_when_settled "
                    "or stop_when_steady), or was written by an older capsim: it keeps no end state to extend; "
                    "its summary stands, or run it again with --overwrite (and without the stopping rule)")
        return (f"{self.path}: the run ended '{status}' and left no checkpoint to continue from; "
                "run it again with --overwrite")

    def _rtol_choice(self) -> str | None:
        """Why time.rtol is what it is, for the closing table. An extension of an accuracy target's
        run keeps the level and rtol chosen at its start, and drops the prediction: that error and
        cost were for the t_end the run had then (issue 51: an extension to kt 2 showed kt 1's)."""
        choice = self.case.time.rtol_choice
        if not (self.extending and self.case.accuracy is not None and choice):
            return choice
        return (f"{choice.split(';')[0]}; kept from the run's start: its predicted error was for the t_end the "
                f"run had then, not for this extension to kt {self.case.time.t_end:g} (measure it: capsim run --verify)")

    def _area_tolerance(self) -> float | None:
        """The area tolerance skalak_c auto chose its C for (the smallest over the capsules' own membranes);
        None where no membrane's C was chosen so."""
        membranes = [self.case.membrane] + [c.membrane for c in self.case.capsules or () if c.membrane is not None]
        chosen = [m.area_tolerance for m in membranes if m.skalak_c_choice is not None]
        return min(chosen) if chosen else None

    def _wall(self) -> float:
        """Wall time the run has spent, its earlier parts (before a resume) included."""
        return self.wall_before + time.perf_counter() - self.wall0

    # -- parts ----------------------------------------------------------------
    def _rhs(self, x: np.ndarray):
        self.stop.check()
        integrator = getattr(self, "integrator", None)  # None during the automatic scheme's probe (t = 0)
        self.model.time = integrator.stage_t if integrator is not None else 0.0
        state = self.model.membrane(x)
        return self.model.velocity(x, state), state

    def _work(self) -> dict[str, float]:
        counts = self.model.counts
        return {
            "velocity_evaluations": self.integrator.evaluations,
            "stages": self.integrator.last_stages,
            "layer_applications": counts["single_layer_applications"] + counts["double_layer_applications"],
            "linear_iterations": getattr(self.integrator, "linear_iterations", 0),
            "layer_matrices": getattr(self.integrator, "layer_matrices", 0),
        }

    def _parts(self) -> dict[str, dict[str, Any]]:
        return {"integrator": self.integrator.state(), "model": self.model.state(),
                "observer": self.observer.state(), "snapshots": self.snapshots.state()}

    def _restore(self, parts: dict[str, dict[str, Any]]) -> None:
        self.integrator.restore(parts["integrator"])
        self.model.restore(parts["model"])
        self.observer.restore(parts["observer"])
        self.snapshots.restore(parts["snapshots"])

    def _create(self, X: np.ndarray) -> None:
        model, case = self.model, self.case
        elements = model.disc.elements
        self.writer = TrajectoryWriter(
            self.path, config_yaml=self.config_yaml, elements=elements, rest_positions=X, version=__version__,
            attrs={"n_nodes": X.shape[0], "n_elements": elements.shape[0], "time_scheme": case.time.scheme,
                   "time_scheme_used": self.integrator.name, "time_scheme_choice": self.integrator.choice,
                   "symmetry": model.disc.symmetry,
                   # the tolerance the run steps with, and why (time.rtol auto, the accuracy target; else given)
                   "time_rtol": float(case.time.rtol), "time_rtol_choice": case.time.rtol_choice or "given",
                   # several capsules: their layout in the mesh (capsim.scene.bodies.Bodies.from_attrs)
                   **({"n_capsules": model.bodies.count} if model.several else {})},
        )
        # only now that the new file is in place: a stale one belongs to the run this one replaced
        remove_checkpoint(self.ckpt_path)
        try:
            self.writer.write_membrane_law(law_attributes(case.membrane.law, model.law_params))
            self.writer.write_rest_shape(rest_shape_attributes(SurfaceMesh(X, elements, model.disc.n_vertices)))
        except (OSError, StorageError) as exc:
            raise self._write_failed(exc) from None

    def _reopen(self, saved: dict[str, dict[str, Any]]) -> None:
        checkpoint.check_parts(self.ckpt_path, saved, self._parts(), self.case.time.t_end)
        try:
            self._restore(saved)
        except Exception as exc:  # noqa: BLE001 - whatever a damaged state raises, one line
            raise ResumeError(f"{self.ckpt_path}: incomplete checkpoint: {type(exc).__name__}: "
                              f"{first_line(exc, default='')}") from None
        try:
            self.writer = TrajectoryWriter.reopen(self.path, self.integrator.steps + 1, self.snapshots.count,
                                                  verify=self._belongs_to_checkpoint)
        except (TrajectoryError, StorageError) as exc:
            raise ResumeError(str(exc)) from None
        stored_version = str(self.writer.attr("capsim_version", ""))
        attrs = {"config_yaml": self.config_yaml, "capsim_version": __version__}
        if stored_version and stored_version != __version__:  # the rows after the cut are this version's
            attrs["resumed_from_version"] = stored_version
        self.writer.set_attrs(**attrs)
        self.writer.drop_end_state()
        self.observer.resume(self.writer.steps())
        self.committed = saved

    def _belongs_to_checkpoint(self, data: dict[str, Any]) -> None:
        """Refuse a run file that is not the checkpoint's: another case, or rows that
        are not the ones the checkpoint continues (row `steps` at the checkpoint's t,
        the last snapshot at its time, and at its positions when taken at t)."""
        ig, snaps, path = self.integrator, self.snapshots, self.path
        stored = checkpoint.stored_case(data["attrs"].get("config_yaml"))
        if stored is None:
            raise ResumeError(f"{path}: not the checkpoint's run file: no readable config_yaml")
        now, then = checkpoint.step_defining_of(self.case.model_dump(mode="json")), checkpoint.step_defining_of(stored)
        # t_end may differ: an extended run, or an interrupted one resumed with --t-end
        now, then = checkpoint.without_t_end(now), checkpoint.without_t_end(then)
        diff = checkpoint.first_difference(now, then, where="the run file")
        if diff is not None:
            raise ResumeError(f"{path}: not the checkpoint's run file (another case): {diff}")
        t_rows = data["timeseries"]["t"]
        if t_rows[ig.steps] != ig.t:
            raise ResumeError(f"{path}: not the checkpoint's run file: row {ig.steps} is at kt = {t_rows[ig.steps]!r}, "
                              f"the checkpoint at kt = {ig.t!r}")
        n = snaps.count - 1
        snap_t = data["snapshot_t"][n]
        if snap_t != snaps.last_time or (snap_t == ig.t and not np.array_equal(data["positions"][n], ig.y)):
            raise ResumeError(f"{path}: not the checkpoint's run file: snapshot {n} (kt = {snap_t!r}) is not "
                              f"the checkpoint's (kt = {snaps.last_time!r})")

    def _save_checkpoint(self, parts: dict[str, dict[str, Any]]) -> None:
        self.writer.flush()  # the rows the checkpoint counts on must be on disk first
        checkpoint.save(self.ckpt_path, parts, self.config_yaml, self._wall())
        self.checkpoints.taken(int(parts["integrator"]["steps"]))

    def _solve_tolerance(self) -> bool:
        """The velocity solve's tolerance for the next steps: solver.tol, or tighter where its error
        would reach SOLVE_SHARE of the step's error budget, rtol · size, per unit time (the integrator's
        error per unit step has a floor at the solve's error, ~tol · the velocity's spread: a pre-
        stressed red cell at G 0.01, |u| ~ 40 from its relaxation, had its steps collapse at kt = 0 with
        solver.tol 1e-6 and ran with 1e-7). A function of the state alone, so a resumed run sets what
        the uninterrupted one did; the default runs' budget is above solver.tol (unchanged). Returns
        whether it tightened."""
        ig, model, base = self.integrator, self.model, self.case.solver.tol
        if ig.u is None:
            return False
        spread = spread_about_mean(np.ascontiguousarray(ig.u))
        budget = SOLVE_SHARE * ig.error_rtol * ig.size_of(ig.y)
        tol = max(min(base, budget / spread) if spread > 0.0 else base, SOLVE_TOL_FLOOR)
        tightened = tol < model.solver_tol
        model.solver_tol = tol
        return tightened

    def _accepted(self, trial) -> None:
        """Record an accepted step: its row, a snapshot when due, a checkpoint when due."""
        ig = self.integrator
        self._solve_tolerance()
        row = self.observer.observe(ig.t, ig.y, ig.u, trial.aux, trial.h, trial.error, self._work())
        self.writer.append_step(row)
        if self.snapshots.due(ig.t, end_tolerance(self.case.time.t_end)):
            self.writer.append_snapshot(ig.t, ig.y)
            self.snapshots.taken(ig.t)
        self.committed = self._parts()
        if self.progress is not None:
            # wall_s: the run's own clock (set-up, compilation and earlier parts included), so the
            # progress display and the closing table show one wall time
            self.progress({"t": ig.t, "dt": trial.h, "D_xy": float(np.max(row["D_xy"])), "step": ig.steps,
                           "t_end": self.case.time.t_end, "wall_s": self._wall()})
        if self.checkpoints.due(ig.steps):
            self._save_checkpoint(self.committed)

    # -- flows that change in time (flow.history) -----------------------------------
    def _next_flow_change(self) -> float:
        """The kt at which the flow changes next (the steps land on it), inf when none: the
        history's next breakpoint after the run's t (its jump, a table's corners;
        capsim.scene.flows.History.breakpoints). Read from t alone, so a resumed run lands on the
        same ones as the uninterrupted run."""
        t = self.integrator.t
        for point in self.breakpoints[bisect.bisect_right(self.breakpoints, t):]:  # a long table: from t on
            if point > t + end_tolerance(point):
                return point
        return float("inf")

    def _follow_flow_history(self) -> None:
        """Stop the flow once the run has reached flow.history.stop_time, and evaluate the
        velocity there again: the step that landed on it carries the sheared velocity
        (the schemes reuse it as their first stage). Whether it has happened is in the
        model's checkpoint state, so a resumed run does it exactly once too."""
        model, ig = self.model, self.integrator
        if model.flow_stop_time is None or model.flow_stopped:
            return
        if ig.t >= model.flow_stop_time - end_tolerance(model.flow_stop_time):
            model.stop_flow()
            ig.u, _ = ig.evaluate(ig.y)

    # -- the loop ----------------------------------------------------------------
    def _loop(self) -> Stop:
        ig, tc, stop = self.integrator, self.case.time, self.stop
        if self.committed is None:  # a new run: the rest shape is the first row and snapshot
            aux = ig.start()
            if self._solve_tolerance():  # the first velocity again, at the tolerance its size asks
                aux = ig.start()
            self.observer.observe(0.0, ig.y, ig.u, aux, 0.0, 0.0, self._work())
            self.writer.append_step(self.observer.last)
            self.writer.append_snapshot(0.0, ig.y)
            self.snapshots.taken(0.0)
            self.committed = self._parts()
            # no checkpoint of the first state: it is the case's own (a run killed before its first
            # checkpoint is started again by --resume, on the same steps); the first is due
            # output.checkpoint_every_s into the run
        else:
            self._solve_tolerance()  # resumed: as the uninterrupted run set it at this state
        state = LoopState(ig.t, ig.dt, ig.steps, signal=stop.name)
        while (outcome := stop_reason(state, tc, self.case.guards, self.observer.last, self.observer.first,
                                      self.observer.history, self.observer.aspect_ratio,
                                      self.observer.settle_after)) is None:
            self._follow_flow_history()
            trial = ig.attempt(min(tc.t_end, self.snapshots.next_time, self._next_flow_change()))
            if trial.accepted:
                self._accepted(trial)
            state = LoopState(ig.t, ig.dt, ig.steps, signal=stop.name, attempted=True, finite=trial.finite,
                              accepted=trial.accepted, h=trial.h,
                              # time.max_wall_s limits each invocation: a run it stopped resumes
                              wall_s=time.perf_counter() - self.wall0)
        return outcome

    def execute(self) -> RunResult:
        try:
            try:
                outcome = self._loop()
            except (KeyboardInterrupt, _StopRequested, SystemError) as exc:
                if isinstance(exc, SystemError) and self.stop.signum is None:
                    self._fail(exc)
                    raise
                suffix = f" ({type(exc).__name__})" if isinstance(exc, SystemError) else ""
                outcome = Stop("interrupted", f"interrupted by {self.stop.name or 'SIGINT'}{suffix}")
            except SolverDivergence as exc:  # at the first state (a trial's is rejected by the integrator)
                outcome = Stop("unstable", f"guard solver: at kt = {self.integrator.t:.6g} {exc}")
            except Exception as exc:  # keep what was computed, say why it stopped
                self._fail(exc)
                raise
            if self.committed is None:  # stopped before the first row: nothing to summarise
                self.writer.close(outcome.status, outcome.reason)
                return RunResult(outcome.status, outcome.reason, str(self.path))
            return self._finish(outcome)
        except (OSError, StorageError) as exc:  # a full disk, an I/O error: one line, the file left readable
            raise self._write_failed(exc) from None

    def _write_failed(self, exc: BaseException) -> StorageError:
        if not self.writer.closed:
            self._fail(exc)
        text = str(exc) if isinstance(exc, StorageError) else f"{self.path}: cannot write: {getattr(exc, 'strerror', None) or first_line(exc)}"
        t = float(self.committed["integrator"]["t"]) if self.committed is not None else 0.0
        if not self.writer.still_ours():
            return StorageError(f"{first_line(StorageError(text))} at kt = {t:.6g}; status 'failed'")
        kept = ("status 'failed' and the reason are in the file" if self._status_kept
                else "the file keeps its last flushed rows")
        return StorageError(f"{first_line(StorageError(text))}; the run stopped at kt = {t:.6g} ({kept}; "
                            "--resume continues from the last checkpoint once there is room)")

    def _finish(self, outcome: Stop) -> RunResult:
        self.stop.closing = True  # whatever ended the run, a Ctrl-C now must not leave the file half-closed
        status, reason = outcome.status, outcome.reason
        ig = self.integrator
        if status == "interrupted":
            # Continue from the last accepted step: whatever came after it is redone on resume.
            self._restore(self.committed)
            reason = f"{reason} at kt = {ig.t:.6g}"
            self._save_checkpoint(self.committed)
        else:
            remove_checkpoint(self.ckpt_path)
        reason = "; ".join(part for part in (reason, ig.note()) if part)
        elongating = status == "unstable" and self._kept_elongating()
        if elongating:
            D = float(np.max(self.observer.last["D_xy"]))
            reason = (f"no steady shape: the capsule kept elongating in {self.case.flow.kind} (D_xy {D:.3g} and "
                      f"rising at kt = {ig.t:.4g}: above the flow's critical rate); {reason}")
        if self.snapshots.last_time < ig.t:
            self.writer.append_snapshot(ig.t, ig.y)
        first, last = _scene_row(self.observer.first, self.observer.last)
        work = self._work()
        result = RunResult(
            status=status, status_reason=reason, path=str(self.path), t=ig.t, steps=ig.steps,
            rejected_steps=ig.rejected, wall_time_s=self._wall(),
            scheme=ig.name, scheme_choice=ig.choice or None, rtol=float(self.case.time.rtol),
            rtol_choice=self._rtol_choice(), velocity_evaluations=int(work["velocity_evaluations"]),
            layer_applications=int(work["layer_applications"]),
            linear_iterations=int(work["linear_iterations"]),
            layer_matrices=int(work["layer_matrices"]),
            final_D_xy=last["D_xy"], final_theta=last["theta"],
            volume_drift=(last["volume"] - first["volume"]) / first["volume"],
            area_change=last["area"] / first["area"] - 1.0,
            largest_area_change=_largest_area_change(self.observer.history.get("area")),
            area_tolerance=self._area_tolerance(),
            min_element_quality=last["min_element_quality"], max_principal_stretch=last["max_principal_stretch"],
            min_tension=last["min_tension"], compressed_fraction=last["compressed_fraction"],
            bending_modulus=float(self.case.membrane.bending_modulus),
        )
        self.writer.write_run_record({k: v for k, v in result.record().items()
                                      if k not in ("scheme", "scheme_choice", "rtol", "rtol_choice")})  # root attributes
        series = {k: np.asarray(v) for k, v in self.observer.history.items()}
        if self.observer.bodies is not None:  # several capsules: each one's summary and the scene's
            motion = scene_summary(self.observer)
        else:
            motion = run_summary(series, aspect_ratio=self.observer.aspect_ratio)
        motion["centroid_travel"] = centroid_travel(self.observer.first, self.observer.last)
        if self.model.flow_stopped and self.model.flow_step_factor == 0.0:  # stopped: it relaxes at rest
            motion.update(relaxation_summary(series, self.model.flow_stop_time))
        if status == "unstable":
            motion["motion"] = "elongating" if elongating else "unstable"
            motion["settled"] = 0.0
        self.writer.write_summary(motion)
        self.writer.set_attrs(motion=motion["motion"])
        if status == "completed" and not outcome.reason:  # reached t_end: it can be extended
            self.writer.write_end_state(checkpoint.end_state_bytes(self.committed, self.config_yaml, result.wall_time_s))
        self.writer.close(status, reason)
        return replace(result, summary=motion)

    _status_kept = False

    def _kept_elongating(self) -> bool:
        """Whether D_xy rose steadily over the last half of a run in a flow where a capsule can
        elongate without bound (capsim.scene.flows: elongates_without_bound): ≥ 80 % of its steps up,
        and up by more than 1 % in all."""
        if not self.model.scene.elongates_without_bound:  # the scene's flow (capsim.scene)
            return False
        t, D = (np.asarray(self.observer.history.get(k, ()), float) for k in ("t", "D_xy"))
        late = D[t >= 0.5 * t[-1]] if t.size else D
        if late.shape[0] < 4:
            return False
        late = late.reshape(late.shape[0], -1)  # one column per capsule: any capsule that kept elongating
        return bool(np.any((np.mean(np.diff(late, axis=0) > 0, axis=0) >= 0.8) & (late[-1] > 1.01 * late[0])))

    def _fail(self, exc: BaseException) -> None:
        """Keep what can be kept: a checkpoint of the last accepted step (where the
        disk takes it; else the previous one stays), and 'failed' with the reason in
        the file (where that can still be written; else its last flushed state).
        A run file deleted or replaced meanwhile is another's now: neither it nor
        the checkpoint beside it is touched."""
        if not self.writer.still_ours():
            self.writer.abandon()
            return
        if self.committed is not None:
            try:
                self._save_checkpoint(self.committed)
            except (OSError, StorageError):
                pass
        first = first_line(exc, default="")
        t = float(self.committed["integrator"]["t"]) if self.committed is not None else 0.0
        try:
            self.writer.close("failed", f"{type(exc).__name__}: {first} at kt = {t:.6g}")
            self._status_kept = True
        except Exception:  # noqa: BLE001 - the disk is full: drop the handle, keep the last flush
            self.writer.abandon()
