"""Explicit embedded Runge–Kutta stepping with local error control.

Schemes are data (a Butcher tableau registered by name). The default is the
Runge–Kutta–Fehlberg 2(3) pair used by the seed (§3; Stoer & Bulirsch): three
velocity evaluations per step,

    k1 = f(y), k2 = f(y + h k1), k3 = f(y + h/4 (k1 + k2)),
    y2 = y + h/2 (k1 + k2)            (second order, Heun)
    y3 = y + h/6 (k1 + k2 + 4 k3)     (third order, Simpson)

The step is accepted when max_i |y3 − y2|_i ≤ rtol · max(1, |y|_∞) and advanced
with y3 (local extrapolation). The step-size policy (safety factor, growth
limits, dt bounds) is kept apart from the stopping rules (``runner.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np


@dataclass(frozen=True)
class EmbeddedScheme:
    name: str
    c: tuple[float, ...]
    a: tuple[tuple[float, ...], ...]
    b_high: tuple[float, ...]
    b_low: tuple[float, ...]
    order_low: int  # order of the error estimate (step-size exponent 1/(order_low+1))
    reference: str


SCHEMES: dict[str, EmbeddedScheme] = {}


def register(scheme: EmbeddedScheme) -> EmbeddedScheme:
    SCHEMES[scheme.name] = scheme
    return scheme


register(
    EmbeddedScheme(
        name="rkf23",
        c=(0.0, 1.0, 0.5),
        a=((), (1.0,), (0.25, 0.25)),
        b_high=(1 / 6, 1 / 6, 4 / 6),
        b_low=(0.5, 0.5, 0.0),
        order_low=2,
        reference="Fehlberg RK2(3); Stoer & Bulirsch (1976); seed §3",
    )
)


@dataclass
class StepController:
    """Proportional-integral step-size control (Gustafsson 1991).

    After an accepted step h ← h·safety·err^{−α}·err_prev^{β}; after a rejected
    one the plain error-per-step rule. At the elastic stability limit, where
    small-G runs spend their time, the integral term damps the accept/reject
    oscillation of the classic rule. ``pi=False`` gives the classic rule.
    """

    rtol: float = 1e-4
    dt_min: float = 1e-8
    dt_max: float = 0.5
    safety: float = 0.9
    max_growth: float = 2.0
    max_shrink: float = 0.2
    pi: bool = True
    alpha: float = 0.7
    beta: float = 0.4
    _err_prev: float = 1.0

    def next_dt(self, dt: float, err: float, order_low: int) -> float:
        if not np.isfinite(err):
            return dt * self.max_shrink
        err = max(err, 1e-12)
        k = order_low + 1
        if self.pi and err <= 1.0:
            factor = self.safety * err ** (-self.alpha / k) * self._err_prev ** (self.beta / k)
            self._err_prev = err
        else:
            factor = self.safety * err ** (-1.0 / k)
        factor = min(self.max_growth, max(self.max_shrink, factor))
        return min(self.dt_max, dt * factor)


@dataclass
class StepResult:
    y: np.ndarray
    error: float
    k1: np.ndarray


def attempt_step(
    f: Callable[[np.ndarray], np.ndarray],
    y: np.ndarray,
    dt: float,
    scheme: EmbeddedScheme,
    rtol: float,
    k1: np.ndarray | None = None,
) -> StepResult:
    """One trial step; returns the higher-order solution and its scaled error.

    ``k1`` may be passed in when f(y) is already known (a rejected step retried
    from the same state reuses it).
    """
    stages = []
    for i, ci in enumerate(scheme.c):
        if i == 0 and k1 is not None:
            stages.append(k1)
            continue
        yi = y.copy()
        for aij, kj in zip(scheme.a[i], stages):
            yi += dt * aij * kj
        stages.append(f(yi))
    dy_high = sum(b * k for b, k in zip(scheme.b_high, stages))
    dy_low = sum(b * k for b, k in zip(scheme.b_low, stages))
    y_new = y + dt * dy_high
    scale = rtol * max(1.0, float(np.abs(y).max()))
    err = float(np.abs(dt * (dy_high - dy_low)).max()) / scale
    return StepResult(y_new, err, stages[0])
