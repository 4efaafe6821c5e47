"""One run, end to end: case → model → time loop → run file.

The loop only loops: the integrator (``timestepping.py``) owns the step
policy and its state, :func:`stopping.stop_reason` every rule that ends a run,
the observer (``observables.StepObserver``) the row of each accepted step, the
schedules (``schedules.py``) when snapshots and checkpoints are written, and
the store (``store.py``) the file. A checkpoint is the ``state()`` of each of
them; a resumed run repeats the uninterrupted one step for step.
"""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np
import yaml

from capsim import __version__
from capsim.config import Case
from capsim.errors import first_line
from capsim.membrane import law_attributes
from capsim.mesh import SurfaceMesh, rest_shape_attributes
from capsim.observables import StepObserver, run_summary
from capsim.schedules import CheckpointSchedule, SnapshotSchedule
from capsim.solver import CapsuleModel, build_model
from capsim.stopping import LoopState, Stop, end_tolerance, stop_reason
from capsim.store import (
    CheckpointError, TrajectoryError, TrajectoryWriter, checkpoint_path, read_checkpoint, remove_checkpoint,
    write_checkpoint,
)
from capsim.timestepping import Integrator, make_integrator

__all__ = ["ResumeError", "RunResult", "build_model", "run_case"]

ProgressCallback = Callable[[dict], None]


class ResumeError(Exception):
    """A run that cannot be resumed (no or damaged checkpoint, unreadable
    trajectory, a different case); the message is one line."""


class _StopRequested(Exception):
    pass


class _StopSignals:
    """SIGINT and SIGTERM ask the run to stop at its next velocity evaluation.

    Raising from the handler could land inside a numba kernel, where a
    KeyboardInterrupt surfaces as a SystemError with the run half-updated; a
    flag is read only between evaluations. A second SIGINT raises at once.
    Campaign workers ignore SIGINT (the parent decides) and keep ignoring it.
    """

    def __init__(self) -> None:
        self.signum: int | None = None
        self._old: dict[int, object] = {}

    def __enter__(self) -> _StopSignals:
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                if signal.getsignal(sig) is not signal.SIG_IGN:
                    self._old[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum, frame) -> None:
        if self.signum is not None and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.signum = signum

    @property
    def name(self) -> str | None:
        return None if self.signum is None else signal.Signals(self.signum).name

    def check(self) -> None:
        if self.signum is not None:
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
    velocity_evaluations: int | None = None
    layer_applications: int | None = None
    final_D_xy: float | None = None
    final_theta: float | None = None
    volume_drift: float | None = None
    area_change: float | None = None
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


def run_case(case: Case, progress: ProgressCallback | None = None, resume: bool = False) -> RunResult:
    """Run one case and write its trajectory; returns the run's result.

    With ``resume`` the run continues from the checkpoint ``<output>.ckpt.npz``
    of an earlier, interrupted run of the same case (raising :class:`ResumeError`
    before touching any file when it cannot), on the same step sequence as an
    uninterrupted run. The checkpoint is written every
    ``output.checkpoint_every_steps`` steps or ``checkpoint_every_s`` seconds,
    kept when the run is interrupted or fails, removed when it ends otherwise.
    """
    with _StopSignals() as stop:
        return _Run(case, progress, resume, stop).execute()


# ---------------------------------------------------------------- checkpoints

_CHECKPOINT_FORMAT = 2
_PARTS = ("integrator", "model", "observer", "snapshots")


def _flatten(parts: dict[str, dict[str, Any]]) -> dict[str, Any]:
    return {f"{part}.{key}": value for part, state in parts.items() for key, value in state.items()
            if value is not None}


def _unflatten(arrays: dict[str, Any]) -> dict[str, dict[str, Any]]:
    parts: dict[str, dict[str, Any]] = {part: {} for part in _PARTS}
    for key, value in arrays.items():
        part, _, rest = key.partition(".")
        if part in parts:
            parts[part][rest] = value.item() if isinstance(value, np.ndarray) and value.ndim == 0 else value
    return parts


def _step_defining(case: dict) -> dict:
    """The part of a resolved case that fixes the step sequence: a run may be
    resumed after moving its files or changing its guards and checkpoint cadence."""
    out = {k: v for k, v in case.items() if k != "guards"}
    out["output"] = {k: v for k, v in case.get("output", {}).items() if k == "snapshot_every"}
    return out


def _first_difference(a: dict, b: dict, prefix: str = "") -> str | None:
    for key in sorted(set(a) | set(b), key=str):
        va, vb = a.get(key), b.get(key)
        if isinstance(va, dict) and isinstance(vb, dict):
            found = _first_difference(va, vb, f"{prefix}{key}.")
            if found:
                return found
        elif va != vb:
            return f"{prefix}{key} = {vb!r} in the checkpoint, {va!r} now"
    return None


def _load_checkpoint(path: Path, case: Case) -> tuple[dict[str, dict[str, Any]], float]:
    """The parts of a checkpoint of this case and the wall time spent before it."""
    try:
        saved = read_checkpoint(path)
    except CheckpointError as exc:
        raise ResumeError(str(exc)) from None
    if int(saved.get("format", -1)) != _CHECKPOINT_FORMAT or "config_yaml" not in saved:
        raise ResumeError(f"{path}: not a capsim checkpoint of format {_CHECKPOINT_FORMAT}")
    saved_case = yaml.safe_load(str(saved["config_yaml"]))
    diff = _first_difference(_step_defining(case.model_dump(mode="json")), _step_defining(saved_case))
    if diff is not None:
        raise ResumeError(f"{path}: belongs to another case: {diff}")
    return _unflatten(saved), float(saved["wall_s"])


# ---------------------------------------------------------------- one run


def _integrator_options(case: Case) -> dict[str, Any]:
    tc = case.time
    options = {"rtol": tc.rtol, "dt_initial": tc.dt_initial, "dt_min": tc.dt_min, "dt_max": tc.dt_max}
    if tc.scheme == "rkc":
        # a GMRES velocity (λ ≠ 1) is exact only to its tolerance: probe with a
        # perturbation whose response stands well above that noise
        exact = case.flow.viscosity_ratio == 1.0
        options.update(max_stages=tc.max_stages, rho_refresh_steps=tc.rho_refresh_steps,
                       probe_scale=1.5e-8 if exact else max(1.5e-8, 100.0 * case.solver.tol))
    return options


class _Run:
    """The parts of one run and the loop that drives them."""

    def __init__(self, case: Case, progress: ProgressCallback | None, resume: bool, stop: _StopSignals) -> None:
        self.wall0 = time.perf_counter()
        self.case, self.progress, self.stop = case, progress, stop
        self.path = Path(case.output.path)
        self.ckpt_path = checkpoint_path(self.path)
        self.config_yaml = case.to_yaml()
        saved, self.wall_before = _load_checkpoint(self.ckpt_path, case) if resume else (None, 0.0)
        self.model, X = build_model(case)
        self.integrator: Integrator = make_integrator(case.time.scheme, self._rhs, X, **_integrator_options(case))
        self.observer = StepObserver(self.model, X)
        self.snapshots = SnapshotSchedule(case.output.snapshot_every)
        self.checkpoints = CheckpointSchedule(case.output.checkpoint_every_steps, case.output.checkpoint_every_s)
        self.committed: dict[str, dict[str, Any]] | None = None
        if saved is not None:
            self._reopen(saved)
        else:
            self._create(X)

    # -- parts ----------------------------------------------------------------
    def _rhs(self, x: np.ndarray):
        self.stop.check()
        state = self.model.membrane(x)
        return self.model.velocity(x, state), state

    def _work(self) -> dict[str, float]:
        counts = self.model.counts
        return {
            "velocity_evaluations": self.integrator.evaluations,
            "stages": self.integrator.last_stages,
            "layer_applications": counts["single_layer_applications"] + counts["double_layer_applications"],
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
        remove_checkpoint(self.ckpt_path)  # a stale one belongs to the run this one overwrites
        model, case = self.model, self.case
        elements = model.disc.elements
        self.writer = TrajectoryWriter(
            self.path, config_yaml=self.config_yaml, elements=elements, rest_positions=X, version=__version__,
            attrs={"n_nodes": X.shape[0], "n_elements": elements.shape[0], "time_scheme": case.time.scheme,
                   "symmetry": model.disc.symmetry},
        )
        self.writer.write_membrane_law(law_attributes(case.membrane.law, model.law_params))
        self.writer.write_rest_shape(rest_shape_attributes(SurfaceMesh(X, elements, model.disc.n_vertices)))

    def _reopen(self, saved: dict[str, dict[str, Any]]) -> None:
        try:
            self._restore(saved)
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise ResumeError(f"{self.ckpt_path}: incomplete checkpoint: {type(exc).__name__}: {exc}") from None
        try:
            self.writer = TrajectoryWriter.reopen(self.path, self.integrator.steps + 1, self.snapshots.count)
        except TrajectoryError as exc:
            raise ResumeError(str(exc)) from None
        self.writer.set_attrs(config_yaml=self.config_yaml)
        self.observer.resume(self.writer.steps())
        self.committed = saved

    def _save_checkpoint(self, parts: dict[str, dict[str, Any]]) -> None:
        self.writer.flush()  # the rows the checkpoint counts on must be on disk first
        wall = self.wall_before + time.perf_counter() - self.wall0
        # steps and t also at the top level: where the checkpoint stands, for whoever watches it
        header = {"config_yaml": self.config_yaml, "wall_s": wall, "format": _CHECKPOINT_FORMAT,
                  "steps": parts["integrator"]["steps"], "t": parts["integrator"]["t"]}
        write_checkpoint(self.ckpt_path, {**_flatten(parts), **header})
        self.checkpoints.taken(int(parts["integrator"]["steps"]))

    def _accepted(self, trial) -> None:
        """Record an accepted step: its row, a snapshot when due, a checkpoint when due."""
        ig = self.integrator
        row = self.observer.observe(ig.t, ig.y, ig.u, trial.aux, trial.h, trial.error, self._work())
        self.writer.append_step(row)
        if self.snapshots.due(ig.t, end_tolerance(self.case.time.t_end)):
            self.writer.append_snapshot(ig.t, ig.y)
            self.snapshots.taken(ig.t)
        self.committed = self._parts()
        if self.progress is not None:
            self.progress({"t": ig.t, "dt": trial.h, "D_xy": row["D_xy"], "step": ig.steps,
                           "t_end": self.case.time.t_end})
        if self.checkpoints.due(ig.steps):
            self._save_checkpoint(self.committed)

    # -- the loop ----------------------------------------------------------------
    def _loop(self) -> Stop:
        ig, tc, stop = self.integrator, self.case.time, self.stop
        if self.committed is None:  # a new run: the rest shape is the first row and snapshot
            aux = ig.start()
            self.observer.observe(0.0, ig.y, ig.u, aux, 0.0, 0.0, self._work())
            self.writer.append_step(self.observer.last)
            self.writer.append_snapshot(0.0, ig.y)
            self.snapshots.taken(0.0)
            self.committed = self._parts()
            self._save_checkpoint(self.committed)
        state = LoopState(ig.t, ig.dt, ig.steps, signal=stop.name)
        while (outcome := stop_reason(state, tc, self.case.guards, self.observer.last, self.observer.first,
                                      self.observer.history)) is None:
            trial = ig.attempt(min(tc.t_end, self.snapshots.next_time))
            if trial.accepted:
                self._accepted(trial)
            state = LoopState(ig.t, ig.dt, ig.steps, signal=stop.name, attempted=True, finite=trial.finite,
                              accepted=trial.accepted, h=trial.h)
        return outcome

    def execute(self) -> RunResult:
        try:
            outcome = self._loop()
        except (KeyboardInterrupt, _StopRequested, SystemError) as exc:
            if isinstance(exc, SystemError) and self.stop.signum is None:
                self._fail(exc)
                raise
            suffix = f" ({type(exc).__name__})" if isinstance(exc, SystemError) else ""
            outcome = Stop("interrupted", f"interrupted by {self.stop.name or 'SIGINT'}{suffix}")
        except Exception as exc:  # keep what was computed, say why it stopped
            self._fail(exc)
            raise
        if self.committed is None:  # stopped before the first row: nothing to summarise
            self.writer.close(outcome.status, outcome.reason)
            return RunResult(outcome.status, outcome.reason, str(self.path))
        return self._finish(outcome)

    def _finish(self, outcome: Stop) -> RunResult:
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
        if self.snapshots.last_time < ig.t:
            self.writer.append_snapshot(ig.t, ig.y)
        first, last = self.observer.first, self.observer.last
        work = self._work()
        result = RunResult(
            status=status, status_reason=reason, path=str(self.path), t=ig.t, steps=ig.steps,
            rejected_steps=ig.rejected, wall_time_s=self.wall_before + time.perf_counter() - self.wall0,
            scheme=ig.name, velocity_evaluations=int(work["velocity_evaluations"]),
            layer_applications=int(work["layer_applications"]),
            final_D_xy=last["D_xy"], final_theta=last["theta"],
            volume_drift=(last["volume"] - first["volume"]) / first["volume"],
            area_change=last["area"] / first["area"] - 1.0,
            min_element_quality=last["min_element_quality"], max_principal_stretch=last["max_principal_stretch"],
            min_tension=last["min_tension"], compressed_fraction=last["compressed_fraction"],
            bending_modulus=float(self.case.membrane.bending_modulus),
        )
        self.writer.write_run_record({k: v for k, v in result.record().items() if k != "scheme"})
        motion = run_summary({k: np.asarray(v) for k, v in self.observer.history.items()})
        if status == "unstable":
            motion["motion"] = "unstable"
        self.writer.write_summary(motion)
        self.writer.set_attrs(motion=motion["motion"])
        self.writer.close(status, reason)
        return RunResult(**{**{f.name: getattr(result, f.name) for f in fields(result)}, "summary": motion})

    def _fail(self, exc: BaseException) -> None:
        if self.committed is not None:
            self._save_checkpoint(self.committed)
        first = first_line(exc, default="")
        t = float(self.committed["integrator"]["t"]) if self.committed is not None else 0.0
        self.writer.close("failed", f"{type(exc).__name__}: {first} at kt = {t:.6g}")
