"""One run, end to end: case → mesh → time loop → HDF5 trajectory.

This is the single boundary where a ``Case`` is unpacked into arrays and
scalars for the numerics, and where results are written out.
"""

from __future__ import annotations

import signal
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from capsim import __version__
from capsim.config import Case
from capsim.integrate import SCHEMES, StepController, attempt_step
from capsim.membrane import get_law
from capsim.mesh import rest_shape_mesh
from capsim.observables import (
    SUMMARY_QUANTITIES, TankTreadingTracker, is_steady, particle_stresslet, run_summary,
    step_observables, stresslet_observables,
)
from capsim.solver import CapsuleModel, Discretization
from capsim.store import TrajectoryWriter

ProgressCallback = Callable[[dict], None]


def build_model(case: Case) -> tuple[CapsuleModel, np.ndarray]:
    """Rest mesh and right-hand side of a case; returns (model, rest positions)."""
    mesh = rest_shape_mesh(
        case.shape.kind, case.mesh.base, case.mesh.level, case.initial_tilt_deg,
        aspect_ratio=case.shape.aspect_ratio, c0=case.shape.c0, c2=case.shape.c2, c4=case.shape.c4,
    )
    disc = Discretization(
        mesh.elements, mesh.n_vertices,
        regular_order=case.quadrature.regular_order,
        singular_order=case.quadrature.singular_order,
    )
    law = get_law(case.membrane.law)
    params = {p: getattr(case.membrane, p) for p in law.parameters}
    model = CapsuleModel(
        disc, mesh.positions, case.flow.shear_rate_G, case.flow.viscosity_ratio, law, params,
        traction_method=case.membrane.traction,
        volume_correction=case.solver.volume_correction,
        solver_method=case.solver.method,
        solver_tol=case.solver.tol,
        solver_max_iter=case.solver.max_iter,
    )
    return model, mesh.positions


class _StopRequested(Exception):
    pass


@dataclass
class _SignalGuard:
    """Turn SIGTERM into an exception so the run can close its file cleanly."""

    def __enter__(self):
        self._old = None
        try:
            self._old = signal.signal(signal.SIGTERM, self._handle)
        except ValueError:  # not in the main thread
            self._old = None
        return self

    def _handle(self, signum, frame):
        raise _StopRequested(f"signal {signum}")

    def __exit__(self, *exc):
        if self._old is not None:
            signal.signal(signal.SIGTERM, self._old)
        return False


def run_case(case: Case, progress: ProgressCallback | None = None) -> dict:
    """Run one case and write its trajectory; returns the run summary."""
    wall0 = time.perf_counter()
    model, X = build_model(case)
    elements = model.disc.elements
    path = Path(case.output.path)
    scheme = SCHEMES["rkf23"]
    tc = case.time
    controller = StepController(rtol=tc.rtol, dt_min=tc.dt_min, dt_max=tc.dt_max)

    writer = TrajectoryWriter(
        path, config_yaml=case.to_yaml(), elements=elements, rest_positions=X, version=__version__,
        attrs={"n_nodes": X.shape[0], "n_elements": elements.shape[0], "time_scheme": scheme.name},
    )
    y = X.copy()
    t = 0.0
    dt = tc.dt_initial
    steps = rejected = 0
    status, reason = "completed", ""
    history: dict[str, list[float]] = {}
    tracker = TankTreadingTracker(X)
    eps = 1e-12 * max(1.0, tc.t_end)
    last_snapshot_t = -1.0

    def record(t_now: float, y_now: np.ndarray, u_now: np.ndarray, state, dt_used: float, err: float) -> dict:
        smax = float(np.max(state.strain.principal_stretches[0]))
        row = {"t": t_now, "dt": dt_used, "error_estimate": err}
        row["solver_iterations"] = float(model.last_solve_info["iterations"])
        row["solver_residual"] = float(model.last_solve_info["residual"])
        row.update(step_observables(y_now, elements, state.geometry, smax))
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
        for key in ("t", "tt_angle", *SUMMARY_QUANTITIES):
            history.setdefault(key, []).append(row[key])
        return row

    with _SignalGuard():
        try:
            state = model.membrane(y)
            k1 = model.velocity(y, state)
            row0 = record(t, y, k1, state, 0.0, 0.0)
            V0 = row0["volume"]
            writer.append_snapshot(t, y)
            last_snapshot_t = t
            next_snapshot = case.output.snapshot_every
            last = row0
            while t < tc.t_end - eps:
                if steps >= tc.max_steps:
                    status, reason = "unstable", f"max_steps = {tc.max_steps} reached at kt = {t:.6g}"
                    break
                h = min(dt, tc.t_end - t, next_snapshot - t)
                clipped = h < dt
                res = attempt_step(model.velocity, y, h, scheme, tc.rtol, k1=k1)
                if not np.isfinite(res.error) or not np.all(np.isfinite(res.y)):
                    status, reason = "unstable", f"non-finite positions at kt = {t:.6g} (dt = {h:.3g})"
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
                        next_snapshot += case.output.snapshot_every
                    if clipped:
                        dt_next = max(dt_next, dt)
                    if progress is not None:
                        progress({"t": t, "dt": h, "D_xy": last["D_xy"], "step": steps, "t_end": tc.t_end})
                    if tc.stop_when_steady and is_steady(history["t"], history["D_xy"], history["theta"]):
                        reason = f"steady state reached at kt = {t:.6g}"
                        break
                else:
                    rejected += 1
                dt = dt_next
                if dt < tc.dt_min:
                    status, reason = "unstable", (
                        f"step size collapsed: dt = {dt:.3g} < dt_min = {tc.dt_min:g} at kt = {t:.6g}"
                    )
                    break
        except (KeyboardInterrupt, _StopRequested) as exc:
            status, reason = "interrupted", f"{type(exc).__name__} {exc} at kt = {t:.6g}".strip()
        except Exception as exc:  # keep what was computed, say why it stopped
            writer.close("failed", f"{type(exc).__name__}: {exc} at kt = {t:.6g}")
            raise
        wall = time.perf_counter() - wall0
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
            "volume_drift": (last["volume"] - V0) / V0,
            "area_change": last["area"] / row0["area"] - 1.0,
            "min_element_quality": last["min_element_quality"],
            "max_principal_stretch": last["max_principal_stretch"],
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

