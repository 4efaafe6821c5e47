"""One run, end to end: case → mesh → time loop → HDF5 trajectory.

This is the single boundary where a ``Case`` is unpacked into arrays and
scalars for the numerics, and where results are written out.
"""

from __future__ import annotations

import signal
import threading
import time
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Callable

import numpy as np
import yaml

from capsim import __version__
from capsim.config import Case, Guards
from capsim.timestepping import SCHEMES, StepController, attempt_step
from capsim.membrane import law_attributes, principal_tensions
from capsim.mesh import SurfaceMesh, rest_shape_attributes
from capsim.observables import (
    SUMMARY_QUANTITIES, TankTreadingTracker, is_steady, particle_stresslet, run_summary,
    step_observables, stresslet_observables,
)
from capsim.solver import CapsuleModel, build_model
from capsim.store import (
    CheckpointError, TrajectoryError, TrajectoryWriter, checkpoint_path, read_checkpoint, remove_checkpoint,
    write_checkpoint,
)

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

    def check(self) -> None:
        if self.signum is not None:
            raise _StopRequested(signal.Signals(self.signum).name)

    def __exit__(self, *exc) -> bool:
        for sig, old in self._old.items():
            signal.signal(sig, old)
        return False


@dataclass(frozen=True)
class _Committed:
    """Everything the time loop carries from one accepted step to the next: a
    checkpoint of it, with the trajectory's first ``steps + 1`` rows, restarts
    the run on the same step sequence."""

    y: np.ndarray
    k1: np.ndarray  # velocity at y: the first RKF stage of the next step
    t: float
    dt: float
    steps: int
    rejected: int
    next_snapshot: float
    last_snapshot_t: float
    n_snapshots: int
    tracker_raw: np.ndarray
    tracker_unwrapped: np.ndarray
    # solver warm starts: they move results only at the 1e-10 level, but a bit-identical restart needs them
    warm_traction: np.ndarray | None
    warm_velocity: np.ndarray | None
    warm_rhs: np.ndarray | None
    # the step-size controller's memory (private fields, e.g. the PI rule's previous error)
    controller_state: dict

    @classmethod
    def take(cls, model: CapsuleModel, tracker: TankTreadingTracker, controller: StepController,
             **loop) -> _Committed:
        def copy(a):
            return None if a is None else np.array(a, copy=True)

        return cls(
            tracker_raw=copy(tracker._raw), tracker_unwrapped=copy(tracker._unwrapped),
            warm_traction=copy(model._last_traction), warm_velocity=copy(model._last_velocity),
            warm_rhs=copy(model._last_rhs),
            controller_state={f.name: getattr(controller, f.name) for f in fields(controller) if f.name.startswith("_")},
            **{k: copy(v) if isinstance(v, np.ndarray) else v for k, v in loop.items()},
        )

    def restore(self, model: CapsuleModel, tracker: TankTreadingTracker, controller: StepController) -> None:
        tracker._raw, tracker._unwrapped = self.tracker_raw.copy(), self.tracker_unwrapped.copy()
        model._last_traction = None if self.warm_traction is None else self.warm_traction.copy()
        model._last_velocity = None if self.warm_velocity is None else self.warm_velocity.copy()
        model._last_rhs = None if self.warm_rhs is None else self.warm_rhs.copy()
        for name, value in self.controller_state.items():
            setattr(controller, name, value)

    def to_arrays(self, config_yaml: str, wall_s: float) -> dict:
        out = {k: v for k, v in vars(self).items() if v is not None and k != "controller_state"}
        out.update({f"controller.{k}": v for k, v in self.controller_state.items()})
        return {**out, "config_yaml": config_yaml, "wall_s": wall_s, "format": _CHECKPOINT_FORMAT}

    @classmethod
    def from_arrays(cls, d: dict) -> _Committed:
        def scalar(value):
            return value.item() if value is not None and value.ndim == 0 else value

        kwargs = {f.name: scalar(d.get(f.name)) for f in fields(cls) if f.name != "controller_state"}
        kwargs["controller_state"] = {
            k.removeprefix("controller."): scalar(v) for k, v in d.items() if k.startswith("controller.")
        }
        return cls(**kwargs)


_CHECKPOINT_FORMAT = 1


def step_collapse(dts: list[float], min_fraction: float, window: int = 200, recent: int = 20) -> str | None:
    """Stepping that has stalled: the median of the last ``recent`` accepted steps
    below ``min_fraction`` × the median of the last ``window`` (e.g. a rim
    folding onto itself makes the near-singular velocity erratic and the error
    control shrinks dt by orders of magnitude while kt stands still)."""
    if len(dts) < window:
        return None
    typical = float(np.median(dts[-window:]))
    now = float(np.median(dts[-recent:]))
    if now < min_fraction * typical:
        return f"guard min_dt_fraction: median dt of the last {recent} steps = {now:.3g} < {min_fraction:g} x {typical:.3g}"
    return None


def guard_violation(row: dict, row0: dict, guards: Guards) -> str | None:
    """The first stability guard an accepted step crosses, as 'guard NAME: value', or None."""
    bad = [key for key, value in row.items() if not np.isfinite(value)]
    if bad:
        return f"guard non_finite: {bad[0]} = {row[bad[0]]}"
    checks = (
        ("min_element_quality", "worst element quality", row["min_element_quality"], "<", guards.min_element_quality),
        ("max_volume_drift", "|V/V0 - 1|", abs(row["volume"] / row0["volume"] - 1.0), ">", guards.max_volume_drift),
        ("max_area_change", "|A/A0 - 1|", abs(row["area"] / row0["area"] - 1.0), ">", guards.max_area_change),
        ("max_principal_stretch", "largest principal stretch", row["max_principal_stretch"], ">",
         guards.max_principal_stretch),
    )
    for name, label, value, op, limit in checks:
        if (value < limit) if op == "<" else (value > limit):
            return f"guard {name}: {label} = {value:.4g} {op} {limit:g}"
    return None


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


def run_case(case: Case, progress: ProgressCallback | None = None, resume: bool = False) -> dict:
    """Run one case and write its trajectory; returns the run summary.

    With ``resume`` the run continues from the checkpoint ``<output>.ckpt.npz``
    of an earlier, interrupted run of the same case (raising :class:`ResumeError`
    before touching any file when it cannot), on the same step sequence as an
    uninterrupted run. The checkpoint is written every
    ``output.checkpoint_every_steps`` steps or ``checkpoint_every_s`` seconds,
    kept when the run is interrupted or fails, removed when it ends otherwise.
    """
    with _StopSignals() as stop:
        return _run(case, progress, resume, stop)


def _run(case: Case, progress: ProgressCallback | None, resume: bool, stop: _StopSignals) -> dict:
    wall0 = time.perf_counter()
    path = Path(case.output.path)
    ckpt_path = checkpoint_path(path)
    config_yaml = case.to_yaml()
    if resume:
        try:
            saved = read_checkpoint(ckpt_path)
        except CheckpointError as exc:
            raise ResumeError(str(exc)) from None
        if int(saved.get("format", -1)) != _CHECKPOINT_FORMAT or "config_yaml" not in saved:
            raise ResumeError(f"{ckpt_path}: not a capsim checkpoint of format {_CHECKPOINT_FORMAT}")
        saved_case = yaml.safe_load(str(saved["config_yaml"]))
        diff = _first_difference(_step_defining(case.model_dump(mode="json")), _step_defining(saved_case))
        if diff is not None:
            raise ResumeError(f"{ckpt_path}: belongs to another case: {diff}")
        try:
            start = _Committed.from_arrays(saved)
        except (TypeError, ValueError, AttributeError) as exc:
            raise ResumeError(f"{ckpt_path}: incomplete checkpoint: {exc}") from None
        wall_before = float(saved["wall_s"])

    model, X = build_model(case)
    elements = model.disc.elements
    scheme = SCHEMES["rkf23"]
    tc = case.time
    controller = StepController(rtol=tc.rtol, dt_min=tc.dt_min, dt_max=tc.dt_max)
    tracker = TankTreadingTracker(X)
    history: dict[str, list[float]] = {}

    if resume:
        try:
            writer = TrajectoryWriter.reopen(path, start.steps + 1, start.n_snapshots)
        except TrajectoryError as exc:
            raise ResumeError(str(exc)) from None
        writer.set_attrs(config_yaml=config_yaml)
        rows = writer.steps()
        for key in ("t", "dt", "tt_angle", *SUMMARY_QUANTITIES):
            history[key] = [float(v) for v in rows[key]]
        row0 = {key: float(v[0]) for key, v in rows.items()}
        last = {key: float(v[-1]) for key, v in rows.items()}
        start.restore(model, tracker, controller)
    else:
        remove_checkpoint(ckpt_path)  # a stale one belongs to the run this one overwrites
        writer = TrajectoryWriter(
            path, config_yaml=config_yaml, elements=elements, rest_positions=X, version=__version__,
            attrs={"n_nodes": X.shape[0], "n_elements": elements.shape[0], "time_scheme": scheme.name},
        )
        # the law with its parameters and moduli, and the rest shape's measures
        law = law_attributes(case.membrane.law, model.law_params)
        writer.write_group("membrane_law", {k: v for k, v in law.items() if k != "parameters"}
                           | {"parameters": law["parameters"] or {"none": 0.0}})
        writer.write_group("rest_shape", rest_shape_attributes(SurfaceMesh(X, elements, model.disc.n_vertices)))
        wall_before = 0.0

    def record(t_now: float, y_now: np.ndarray, u_now: np.ndarray, state, dt_used: float, err: float) -> dict:
        smax = float(np.max(state.strain.principal_stretches[0]))
        row = {"t": t_now, "dt": dt_used, "error_estimate": err}
        row.update(step_observables(y_now, elements, state.geometry, smax))
        # compressive tensions: where a membrane without bending stiffness would wrinkle
        _, tau2 = principal_tensions(state.strain, model.law, model.law_params)
        row["min_tension"] = float(tau2.min()) / model.shear_rate_G
        row["compressed_fraction"] = float(np.mean(tau2 < -COMPRESSION_TOL))
        center = np.array([row["centroid_x"], row["centroid_y"], row["centroid_z"]])
        S_star = particle_stresslet(
            state.geometry, state.density, u_now, elements, model.disc.reg_phi, center, row["volume"],
            model.shear_rate_G, model.viscosity_ratio,
        )
        row.update(stresslet_observables(S_star))
        row.update(tracker.update(y_now, u_now, center))
        row["solver_iterations"] = float(model.last_solve_info.get("iterations", 0))
        row["solver_residual"] = float(model.last_solve_info.get("residual", 0.0))
        writer.append_step(row)
        for key in ("t", "dt", "tt_angle", *SUMMARY_QUANTITIES):
            history.setdefault(key, []).append(row[key])
        return row

    def velocity(x: np.ndarray) -> np.ndarray:
        stop.check()
        return model.velocity(x)

    def save_checkpoint(c: _Committed) -> None:
        writer.flush()  # the rows the checkpoint counts on must be on disk first
        write_checkpoint(ckpt_path, c.to_arrays(config_yaml, wall_before + time.perf_counter() - wall0))

    eps = 1e-12 * max(1.0, tc.t_end)
    status, reason = "completed", ""
    committed: _Committed | None = None
    try:
        if resume:
            committed = start
        else:
            state = model.membrane(X)
            k1 = model.velocity(X, state)
            row0 = last = record(0.0, X, k1, state, 0.0, 0.0)
            writer.append_snapshot(0.0, X)
            committed = _Committed.take(
                model, tracker, controller, y=X.copy(), k1=k1, t=0.0, dt=tc.dt_initial, steps=0, rejected=0,
                next_snapshot=case.output.snapshot_every, last_snapshot_t=0.0, n_snapshots=1,
            )
            save_checkpoint(committed)
        c = committed
        y, k1, t, dt, steps, rejected = c.y, c.k1, c.t, c.dt, c.steps, c.rejected
        next_snapshot, last_snapshot_t, n_snapshots = c.next_snapshot, c.last_snapshot_t, c.n_snapshots
        ckpt_steps, ckpt_wall = steps, time.perf_counter()
        while t < tc.t_end - eps:
            stop.check()
            if steps >= tc.max_steps:
                status, reason = "unstable", f"max_steps = {tc.max_steps} reached at kt = {t:.6g}"
                break
            h = min(dt, tc.t_end - t, next_snapshot - t)
            clipped = h < dt
            res = attempt_step(velocity, y, h, scheme, tc.rtol, k1=k1)
            if not np.isfinite(res.error) or not np.all(np.isfinite(res.y)):
                status, reason = "unstable", f"guard non_finite: positions at kt = {t:.6g} (dt = {h:.3g})"
                break
            dt_next = controller.next_dt(h, res.error, scheme.order_low)
            if res.error <= 1.0:
                y = res.y
                t += h
                steps += 1
                state = model.membrane(y)
                k1 = model.velocity(y, state)
                last = record(t, y, k1, state, h, res.error)
                if t >= next_snapshot - eps:
                    writer.append_snapshot(t, y)
                    last_snapshot_t = t
                    n_snapshots += 1
                    next_snapshot += case.output.snapshot_every
                if clipped:
                    dt_next = max(dt_next, dt)
                dt = dt_next
                committed = _Committed.take(
                    model, tracker, controller, y=y, k1=k1, t=t, dt=dt, steps=steps, rejected=rejected,
                    next_snapshot=next_snapshot, last_snapshot_t=last_snapshot_t, n_snapshots=n_snapshots,
                )
                if progress is not None:
                    progress({"t": t, "dt": h, "D_xy": last["D_xy"], "step": steps, "t_end": tc.t_end})
                violation = guard_violation(last, row0, case.guards) or step_collapse(
                    history["dt"], case.guards.min_dt_fraction
                )
                if violation is not None:
                    status, reason = "unstable", f"{violation} at kt = {t:.6g}"
                    break
                if tc.stop_when_steady and is_steady(history["t"], history["D_xy"], history["theta"]):
                    reason = f"steady state reached at kt = {t:.6g}"
                    break
                if (steps - ckpt_steps >= case.output.checkpoint_every_steps
                        or time.perf_counter() - ckpt_wall >= case.output.checkpoint_every_s):
                    save_checkpoint(committed)
                    ckpt_steps, ckpt_wall = steps, time.perf_counter()
            else:
                rejected += 1
                dt = dt_next
            if dt < tc.dt_min:
                status, reason = "unstable", (
                    f"guard dt_min: step size collapsed to dt = {dt:.3g} < {tc.dt_min:g} at kt = {t:.6g}"
                )
                break
    except (KeyboardInterrupt, _StopRequested, SystemError) as exc:
        if isinstance(exc, SystemError) and stop.signum is None:
            _fail(writer, committed, save_checkpoint, exc)
            raise
        status = "interrupted"
        signame = signal.Signals(stop.signum).name if stop.signum is not None else "SIGINT"
        reason = f"interrupted by {signame}" + (f" ({type(exc).__name__})" if isinstance(exc, SystemError) else "")
    except Exception as exc:  # keep what was computed, say why it stopped
        _fail(writer, committed, save_checkpoint, exc)
        raise
    if committed is None:  # stopped before the first row: nothing to summarise
        writer.close(status, reason)
        return {"status": status, "status_reason": reason, "path": str(path), "t": 0.0, "steps": 0}
    if status == "interrupted":
        # Continue from the last accepted step: whatever came after it is redone on resume.
        c = committed
        y, t, steps, rejected, last_snapshot_t = c.y, c.t, c.steps, c.rejected, c.last_snapshot_t
        reason = f"{reason} at kt = {t:.6g}"
        save_checkpoint(c)
    else:
        remove_checkpoint(ckpt_path)
    wall = wall_before + time.perf_counter() - wall0
    if last_snapshot_t < t:
        writer.append_snapshot(t, y)
    summary = {
        "status": status,
        "status_reason": reason,
        "path": str(path),
        "t": t,
        "steps": steps,
        "rejected_steps": rejected,
        "wall_time_s": wall,
        "D_xy": last["D_xy"],
        "theta": last["theta"],
        "volume_drift": (last["volume"] - row0["volume"]) / row0["volume"],
        "area_change": last["area"] / row0["area"] - 1.0,
        "min_element_quality": last["min_element_quality"],
        "max_principal_stretch": last["max_principal_stretch"],
        "min_tension": last["min_tension"],
        "compressed_fraction": last["compressed_fraction"],
        "bending_modulus": float(case.membrane.bending_modulus),
    }
    writer.write_group("run", {k: v for k, v in summary.items() if k not in ("status", "status_reason", "path")})
    # The summary (motion and window means) replaces the final D_xy and θ, kept as final_*.
    summary["final_D_xy"], summary["final_theta"] = summary["D_xy"], summary["theta"]
    if history:
        motion = run_summary({k: np.asarray(v) for k, v in history.items()})
        if status == "unstable":
            motion["motion"] = "unstable"
        writer.write_group("summary", motion)
        writer.set_attrs(motion=motion["motion"])
        summary.update(motion)
    writer.close(status, reason)
    return summary


COMPRESSION_TOL = 1e-10  # in E_s: below round-off of the tension at the rest shape


def _fail(writer: TrajectoryWriter, committed: _Committed | None, save, exc: BaseException) -> None:
    if committed is not None:
        save(committed)
    first = str(exc).splitlines()[0] if str(exc) else ""
    t = committed.t if committed is not None else 0.0
    writer.close("failed", f"{type(exc).__name__}: {first} at kt = {t:.6g}")
