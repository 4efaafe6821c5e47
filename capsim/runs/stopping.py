"""Every rule that ends a run, in one place.

:func:`stop_reason` is asked before every attempted step; it returns ``None``
(go on) or a :class:`Stop` with the run's final status and a one-line reason.
Rules, in the order they are checked:

1. a stop signal (SIGINT/SIGTERM) → ``interrupted``;
2. the last attempt produced non-finite positions or error → ``unstable``;
3. after an accepted step: a stability guard (non-finite observables,
   element quality, volume drift, area change, stretch) or a step-size
   collapse → ``unstable``; the steady state or a settled orbit, when asked for →
   ``completed``;
4. the step size below ``time.dt_min`` → ``unstable``;
5. ``t_end`` reached → ``completed``;
6. ``time.max_steps`` accepted steps → ``unstable``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import math

import numpy as np

from capsim.config import Guards, Time
from capsim.solve.observables import MAY_BE_UNDEFINED, is_steady, series_settled
from capsim.storage.schedules import end_tolerance  # noqa: F401 - a stop rule, kept beside the cadences


@dataclass(frozen=True)
class Stop:
    status: str   # completed, unstable or interrupted
    reason: str


def step_collapse(dts: Sequence[float], min_fraction: float, window: int = 200, recent: int = 20) -> str | None:
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


#: a centroid carried farther than this from the origin (an extension's outflow: 2 e^kt) stops the
#: run: every shape value is measured about the centroid and a linear flow's uniform part is carried
#: exactly (capsim.solve.solver), but the positions' own round-off, 1e-16 |x|, is 1e-7 a here, 1e-6 of a
#: level-3 element, and grows with |x| (config.MAX_COORDINATE bounds the start 1000 times nearer)
MAX_CENTROID_COORDINATE = 1e9


def _all_finite(row: dict) -> bool:
    """Whether every value of the row is finite: the common case, asked once per accepted step (a
    float by math.isfinite, 40 times cheaper than numpy's reduction on a scalar)."""
    for value in row.values():
        if type(value) is float:
            if not math.isfinite(value):
                return False
        elif not np.all(np.isfinite(value)):
            return False
    return True


def guard_violation(row: dict, row0: dict, guards: Guards) -> str | None:
    """The first stability guard an accepted step crosses, as 'guard NAME: value', or None."""
    # a column the observer may leave undefined (NaN: observables.MAY_BE_UNDEFINED) is a property of
    # the state, not a failure, as long as D_xy itself is finite
    # (several capsules: a per-capsule column is an array, its worst capsule decides)
    bad = [] if _all_finite(row) else [key for key, value in row.items()
                                       if not np.all(np.isfinite(value))
                                       and not (key in MAY_BE_UNDEFINED
                                                and np.all(np.isnan(value) | np.isfinite(value))
                                                and np.all(np.isfinite(row.get("D_xy", np.nan))))]
    if bad:
        value = np.asarray(row[bad[0]])
        shown = value if value.ndim == 0 else value[~np.isfinite(value)][0]
        return f"guard non_finite: {bad[0]} = {shown}"
    checks = (
        ("min_element_quality", "worst element quality", row["min_element_quality"], "<", guards.min_element_quality),
        ("max_volume_drift", "|V/V0 - 1|", abs(row["volume"] / row0["volume"] - 1.0), ">", guards.max_volume_drift),
        ("max_area_change", "|A/A0 - 1|", abs(row["area"] / row0["area"] - 1.0), ">", guards.max_area_change),
        ("max_principal_stretch", "largest principal stretch", row["max_principal_stretch"], ">",
         guards.max_principal_stretch),
    ) + ((("min_wall_gap", "gap between membrane and wall", row["wall_gap"], "<", guards.min_wall_gap),)
         if "wall_gap" in row else ()) + ((("min_capsule_gap", "gap between two capsules", row["min_capsule_gap"],
                                            "<", guards.min_capsule_gap),) if "min_capsule_gap" in row else ())
    for name, label, value, op, limit in checks:
        if type(value) is not float:  # several capsules: an array, its worst capsule decides
            value = float(np.min(value)) if op == "<" else float(np.max(value))
        if (value < limit) if op == "<" else (value > limit):
            # as many digits as show the crossing ('1.00011 > 1.0001', not '1 > 1.0001')
            shown = next((text for text in (f"{value:.{d}g}" for d in (4, 6, 8, 10, 13, 17))
                          if (float(text) < limit if op == "<" else float(text) > limit)), repr(value))
            return f"guard {name}: {label} = {shown} {op} {limit:g}" if float(f"{limit:g}") == limit else \
                f"guard {name}: {label} = {shown} {op} {limit!r}"
    far = max((abs(v) if type(v := row[f"centroid_{c}"]) is float else float(np.max(np.abs(v)))
               for c in "xyz" if f"centroid_{c}" in row), default=0.0)
    if far > MAX_CENTROID_COORDINATE:
        return (f"guard max_centroid_coordinate: a centroid coordinate = {far:.4g} a > {MAX_CENTROID_COORDINATE:g} "
                "(carried out by the flow): the positions' round-off, 1e-16 |x|, would pass 1e-7 a; the rows "
                "so far stand (start nearer the origin, or end the run earlier)")
    return None


@dataclass(frozen=True)
class LoopState:
    """What the rules look at: the integrator's position and the last attempt."""

    t: float
    dt: float
    steps: int
    signal: str | None = None         # name of a pending stop signal
    attempted: bool = False           # an attempt was made since the last check
    finite: bool = True               # ... and it produced finite values
    accepted: bool = False            # ... and it was accepted
    h: float = 0.0                    # its step size
    wall_s: float = 0.0               # wall time of this invocation (time.max_wall_s is per invocation)


def _settled(history: dict[str, list[float]], aspect_ratio: float) -> bool:
    """The run summary's own ``settled`` (observables.series_settled: the same classifier, on
    the same body axis), asked once per unit of kt (it reads the whole history)."""
    t = history["t"]
    if len(t) < 3 or np.floor(t[-1]) == np.floor(t[-2]):
        return False
    return series_settled(history, aspect_ratio)


def stop_reason(state: LoopState, time: Time, guards: Guards, row: dict | None, row0: dict | None,
                history: dict[str, list[float]], aspect_ratio: float = 1.0, settle_after: float = 0.0) -> Stop | None:
    """The first rule (module docstring) that ends the run, or None. ``settle_after``: the kt
    before which stop_when_settled does not stop (a few of the capsule's own relaxation times)."""
    if state.signal is not None:
        return Stop("interrupted", f"interrupted by {state.signal}")
    at = f"at kt = {state.t:.6g}"
    if state.attempted and not state.finite:
        return Stop("unstable", f"guard non_finite: positions {at} (dt = {state.h:.3g})")
    if state.attempted and state.accepted:
        violation = guard_violation(row, row0, guards) or step_collapse(history["dt"], guards.min_dt_fraction)
        if violation is not None:
            return Stop("unstable", f"{violation} {at}")
        if "_end_clearance" in row and np.min(row["_end_clearance"]) < 0.0:  # a conduit's meshed stretch (capsim.scene.conduit)
            if row.get("_end_follows"):
                return Stop("unstable", f"guard conduit window: a membrane reached the end of the conduit's window "
                            f"{at} (the capsules outgrew it: elongated or drifted apart); give a longer conduit.length")
            return Stop("completed", f"the capsule passed through: a membrane reached the end of the conduit's "
                        f"meshed stretch {at} (its ends lie the truncation margin beyond)")
        if time.stop_when_steady and is_steady(history["t"], history["D_xy"], history["theta"]):
            return Stop("completed", f"steady state reached {at}")
        if time.stop_when_settled and state.t >= settle_after and _settled(history, aspect_ratio):
            return Stop("completed", f"orbit settled {at}")
    if state.attempted and state.dt < time.dt_min:
        return Stop("unstable", f"guard dt_min: step size collapsed to dt = {state.dt:.3g} < {time.dt_min:g} {at}")
    if state.t >= time.t_end - end_tolerance(time.t_end):
        return Stop("completed", "")
    if time.max_wall_s is not None and state.wall_s >= time.max_wall_s:
        return Stop("interrupted", f"wall-time limit time.max_wall_s = {time.max_wall_s:g} s reached")
    if state.steps >= time.max_steps:
        return Stop("unstable", f"max_steps = {time.max_steps} reached {at}")
    return None


