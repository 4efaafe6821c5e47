"""Time integrators of dx/dt = u(x): a registry of schemes, each owning its step policy.

A scheme is a class registered by name (dedalus style; adding one is adding an
entry). An integrator owns everything that carries over from one step to the
next — positions, the velocity there, t, the step size, the step-size
controller's memory and any scheme state (RKC's spectral radius) — and
exposes it as :meth:`Integrator.state` / :meth:`Integrator.restore` for
checkpoints. Every velocity evaluation goes through the integrator, which
counts them: rejected attempts and spectral-radius probes included.

Step policy common to all schemes: a step is clipped so as not to pass
``t_stop`` (the end of the run or the next snapshot time); a clipped step that
is accepted does not shrink the step size of the next one (it was clipped, not
limited by accuracy). Stopping rules are kept apart (``stopping.py``).

Schemes:

``rkf23``  Runge–Kutta–Fehlberg 2(3), the seed's (§3; Stoer & Bulirsch 1976).
           Three velocity evaluations per step,

               k1 = f(y), k2 = f(y + h k1), k3 = f(y + h/4 (k1 + k2)),
               y2 = y + h/2 (k1 + k2)            (second order, Heun)
               y3 = y + h/6 (k1 + k2 + 4 k3)     (third order, Simpson)

           accepted when max_i |y3 − y2|_i ≤ rtol · max(1, |y|_∞) (|y| about each capsule's centroid:
           scene_size) and advanced
           with y3 (local extrapolation). Its real stability interval is about
           [−2.5, 0]: the membrane's stiffness pins dt at ≈ 2.5/ρ ∝ G h.

``rkc``    Second-order Runge–Kutta–Chebyshev with damping ε = 2/13 and the
           embedded error estimate of Sommeijer, Shampine & Verwer, J. Comput.
           Appl. Math. 88 (1998) 315–326 (eqs. 2.4–2.6 and §3; Verwer,
           Hundsdorfer & Sommeijer 1990). s stages are stable on [−β(s), 0],
           β(s) = (1 + w0)/w1 ≈ 0.653 s², for s velocity evaluations, so the
           number of stages of a step follows from h·ρ, ρ an estimate of the
           spectral radius of ∂u/∂x from a nonlinear power iteration with
           finite-difference Jacobian–vector products (as in the RKC code).
           The step size comes from the error estimate alone, controlled per
           unit step (UNIT_STEP: accepted when est ≤ rtol · max(1, |y|∞) · h/1),
           so that its error is proportional to rtol like the others'
           (docs/time_stepping.md, "One promise for time.rtol").
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, fields
from typing import Any, Callable, ClassVar, Literal

import numpy as np
from pydantic import Field

from capsim.numerics.krylov import LinearSolveFailed, SolverDivergence

#: rhs(y) -> (velocity, auxiliary state of that evaluation, e.g. the membrane state)
RightHandSide = Callable[[np.ndarray], tuple[np.ndarray, Any]]


@functools.cache
def _memory_fields(cls: type) -> tuple[str, ...]:
    """A controller class's private fields (read at every accepted step: dataclasses.fields is slow)."""
    return tuple(f.name for f in fields(cls) if f.name.startswith("_"))


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

    def state(self) -> dict[str, float]:
        """The controller's memory (its private fields)."""
        return {name: getattr(self, name) for name in _memory_fields(type(self))}

    def restore(self, state: dict[str, float]) -> None:
        for name, value in state.items():
            setattr(self, name, float(value))


# ---------------------------------------------------------------- the error norm's length


def scene_size(bodies: Any) -> Callable[[np.ndarray], float]:
    """The length an error estimate is relative to (time.rtol · this): max(1, the largest
    extent of a capsule about its own centroid). Measured from the origin (max |y|), a capsule
    carried away from it (translating in Poiseuille flow, a pair separating in shear) had its
    tolerance loosened in proportion to its distance: a pair 35 a apart drifted 1 % in volume
    where one capsule at the origin drifts 2e-4. ``bodies``: the scene's capsules (None: one)."""
    from capsim.numerics.kernels import spread_about_mean  # one pass (issue 57); numba loads with the run

    def spread(part: np.ndarray) -> float:
        return spread_about_mean(np.ascontiguousarray(part if part.ndim == 2 else part.reshape(-1, 1)))

    def size(y: np.ndarray) -> float:
        if bodies is None or bodies.count == 1:
            return max(1.0, spread(y))
        extent = 0.0
        for part in bodies.split(y):
            extent = max(extent, spread(part))
        return max(1.0, extent)

    return size


@functools.cache
def _kernels():
    """capsim.numerics.kernels, imported on first use (reading a case loads no numba) and then held: the
    step's kernels are looked up every step, an import statement there cost ~3 µs a step."""
    from capsim.numerics import kernels

    return kernels


def load_step_kernels() -> None:
    """Load (or compile) the step's vector kernels with the signatures a run calls them with: the
    warm-up's tiny run may step with another scheme than the run it prepares (its level's choice)."""
    from capsim.numerics.kernels import (
        all_finite, max_abs, mean_row_max_abs, rkc_error_estimate, rkc_stage, spread_about_mean,
    )

    flat, rows = np.zeros(3), np.zeros((1, 3))
    rkc_stage(flat, flat, flat, flat, flat, 1.0, 0.0, 0.0, 0.0, 0.0)
    rkc_error_estimate(flat, flat, flat, flat, 1.0)
    max_abs(flat)
    all_finite(flat)
    spread_about_mean(rows)
    mean_row_max_abs(rows)


def scene_error(size_of: Callable[[np.ndarray], float], carried: bool = False
                ) -> Callable[[np.ndarray, np.ndarray, float], float]:
    """The scaled error of an estimate `est` at y, est's max norm over rtol · size_of(y) (accepted
    at ≤ 1). ``carried``: one capsule in a linear flow without a wall, whose shape does not depend
    on where it is (the flow about its centroid is the same everywhere: capsim.solve.solver's
    carried_velocity). Once it is farther from the origin than its own size, its translation's
    error is taken relative to its distance (rtol of the position, as of any large number) and
    the rest — shape and turn — relative to its size as before: held to rtol in units of a, an
    extension's outflow (x = 2 e^kt) cost 2194 steps to kt 14 where the capsule at the origin
    took 98, every one of them spent on the 13th digit of x (level 0)."""
    max_abs, mean_row_max_abs = _kernels().max_abs, _kernels().mean_row_max_abs

    def plain(est: np.ndarray, y: np.ndarray, rtol: float) -> float:
        return max_abs(est.ravel()) / (rtol * size_of(y))

    if not carried:
        return plain

    def error(est: np.ndarray, y: np.ndarray, rtol: float) -> float:
        size = size_of(y)
        far = mean_row_max_abs(np.ascontiguousarray(y))
        if not far > size:  # near the origin: as every other scene
            return max_abs(est.ravel()) / (rtol * size)
        move = est.mean(axis=0)
        return max(float(np.abs(est - move).max()) / (rtol * size), float(np.abs(move).max()) / (rtol * far))

    return error


def max_step(case: Any) -> float:
    """The longest step a run of `case` takes: time.dt_max, or less where the flow's history
    needs it resolved (an oscillation: capsim.scene.flows.History.max_step). Every scheme's controller
    caps its step there; the stability limits (rkf23's pinned step, rkc's stage count for h·ρ)
    apply below it (the automatic scheme's choice is made without it: Automatic.predict)."""
    from capsim.scene.flows import history_max_step  # numpy only

    return min(float(case.time.dt_max), history_max_step(case.flow.history))


def _carried_scene(scene: Any) -> bool:
    """One capsule in a linear flow without a boundary (scene_error's ``carried``)."""
    return scene.translation_invariant and scene.body_count == 1


# ---------------------------------------------------------------- embedded Runge–Kutta pairs


@dataclass(frozen=True)
class EmbeddedScheme:
    """Butcher tableau of an explicit embedded pair."""

    name: str
    c: tuple[float, ...]
    a: tuple[tuple[float, ...], ...]
    b_high: tuple[float, ...]
    b_low: tuple[float, ...]
    order_low: int  # order of the error estimate (step-size exponent 1/(order_low+1))
    reference: str


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
    size: float | None = None,
    error_of: Callable[[np.ndarray, np.ndarray, float], float] | None = None,
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
    if error_of is not None:  # the integrator's error norm (scene_error)
        err = error_of(dt * (dy_high - dy_low), y, rtol)
    else:
        scale = rtol * (max(1.0, float(np.abs(y).max())) if size is None else size)
        err = float(np.abs(dt * (dy_high - dy_low)).max()) / scale
    return StepResult(y_new, err, stages[0])


RKF23 = EmbeddedScheme(
    name="rkf23",
    c=(0.0, 1.0, 0.5),
    a=((), (1.0,), (0.25, 0.25)),
    b_high=(1 / 6, 1 / 6, 4 / 6),
    b_low=(0.5, 0.5, 0.0),
    order_low=2,
    reference="Fehlberg RK2(3); Stoer & Bulirsch (1976); seed §3",
)


# ---------------------------------------------------------------- integrators


@dataclass
class Trial:
    """What one attempted step did."""

    accepted: bool
    finite: bool      # False: the trial produced non-finite positions or error (nothing was changed)
    h: float          # the step size tried
    error: float      # scaled local error estimate (≤ 1: accepted)
    stages: int       # velocity evaluations of this attempt
    aux: Any = None   # auxiliary state of the velocity at the accepted positions (membrane state)


SCHEMES: dict[str, type[Integrator]] = {}

#: the scheme a case gets without time.scheme
DEFAULT_SCHEME = "auto"

#: most nodes the dense stage preconditioner takes: it holds a few (3N)² matrices
#: (76 MB each at level 3, N = 1026) and its LU costs (3N)³/3 multiply-adds
DENSE_MAX_NODES = 1100


def register_scheme(cls: type[Integrator]) -> type[Integrator]:
    """Register a scheme under ``cls.name``. Its ``option_fields`` become fields of the case's
    ``time`` section (capsim.config builds the schema from the registry), its ``description``
    part of ``time.scheme``'s, its :meth:`Integrator.settings` what it is built with."""
    SCHEMES[cls.name] = cls
    return cls


def build_integrator(case: Any, rhs: RightHandSide, y0: np.ndarray, model: Any) -> Integrator:
    """The integrator of ``case.time.scheme`` for a run of `case` on `model`, starting at ``y0``
    (a scheme that chooses, ``auto``, resolves to the one it picks; ``choice`` says why)."""
    cls, choice, spent, case = SCHEMES[case.time.scheme].resolve(case, model, rhs, y0)
    integrator = cls(rhs, y0, **cls.settings(case, model))
    integrator.choice = choice
    integrator.evaluations += spent  # a choice's measurements are part of the run's cost
    return integrator


def make_integrator(name: str, rhs: RightHandSide, y0: np.ndarray, **options: Any) -> Integrator:
    """An integrator of the registered scheme ``name`` starting at ``y0`` (t = 0)."""
    try:
        cls = SCHEMES[name]
    except KeyError:
        raise ValueError(f"unknown time scheme {name!r} (allowed: {', '.join(SCHEMES)})") from None
    return cls(rhs, y0, **options)


class Integrator:
    """Base of the registered schemes: positions, velocity there, time and step size.

    ``start()`` evaluates the velocity at the initial positions and returns its
    auxiliary state; ``attempt(t_stop)`` tries one step that does not pass
    ``t_stop`` and, when it is accepted, advances and evaluates the velocity at
    the new positions (the first stage of the next step).

    A scheme declares what a case may set for it: ``option_fields`` (name →
    (type, pydantic Field): the schema fragment of ``time.<name>``, its default,
    bounds and description), ``description`` (its line in ``time.scheme``'s help),
    :meth:`settings` (its constructor's options from a case and its model) and
    :meth:`case_problem` (a case it cannot run, as one line).
    """

    option_fields: ClassVar[dict[str, tuple[Any, Any]]] = {}
    description: ClassVar[str] = ""

    @classmethod
    def settings(cls, case: Any, model: Any) -> dict[str, Any]:
        """The constructor's options for a run of `case` on `model` (common: tolerance and step bounds)."""
        tc = case.time
        scene = model.scene  # capsim.scene.Scene: the capsules' layout, whether one is carried
        size_of = scene_size(scene.layout)
        return {"rtol": tc.rtol, "dt_initial": tc.dt_initial, "dt_min": tc.dt_min, "dt_max": max_step(case),
                "size_of": size_of, "error_of": scene_error(size_of, carried=_carried_scene(scene))}

    @classmethod
    def case_problem(cls, case: Any) -> tuple[str, Any, str] | None:
        """(field, value, what is wrong) for a case this scheme cannot run; None when it can."""
        return None

    #: schemes whose options this one reads too (a scheme that picks among them)
    uses_options_of: ClassVar[tuple[str, ...]] = ()
    #: whether the scheme steps itself (False: it resolves to another, :meth:`resolve`)
    stepped: ClassVar[bool] = True
    #: why this scheme runs (set by :func:`build_integrator`; '' when it was named)
    choice: str = ""

    @classmethod
    def resolve(cls, case: Any, model: Any, rhs: RightHandSide, y0: np.ndarray) -> tuple[type, str, int, Any]:
        """(the scheme that runs, why, velocity evaluations spent choosing, the case it is built
        from): itself and the case, unless it chooses."""
        return cls, "", 0, case

    name: ClassVar[str]
    order_low: ClassVar[int]
    reference: ClassVar[str]
    #: the error norm's calibration (time.rtol's one promise, docs/time_stepping.md): a step is
    #: accepted when its estimate is at most TOLERANCE_FACTOR · rtol · max(1, |y|∞), and, where
    #: UNIT_STEP is set, that times h / UNIT_STEP (error per unit step)
    TOLERANCE_FACTOR: ClassVar[float] = 1.0
    UNIT_STEP: ClassVar[float | None] = None

    def __init__(self, rhs: RightHandSide, y0: np.ndarray, *, rtol: float, dt_initial: float,
                 dt_min: float, dt_max: float, size_of: Callable[[np.ndarray], float] | None = None,
                 error_of: Callable[[np.ndarray, np.ndarray, float], float] | None = None,
                 **scheme_options: Any) -> None:
        if scheme_options:
            raise TypeError(f"{self.name}: unknown options {sorted(scheme_options)}")
        self._rhs = rhs
        #: the length the error norm is relative to: max(1, each capsule's extent about its centroid)
        self.size_of = size_of or scene_size(None)
        #: the scaled error of an estimate (scene_error: a far capsule's translation relative to its distance)
        self.error_of = error_of or scene_error(self.size_of)
        self.rtol = rtol
        self.error_rtol = rtol * self.TOLERANCE_FACTOR  # what the error norm divides by
        self.controller = StepController(rtol=rtol, dt_min=dt_min, dt_max=dt_max)
        self.y = np.array(y0, dtype=float)
        self.u: np.ndarray | None = None
        self.t = 0.0
        self.dt = min(dt_initial, dt_max)  # a history's bound (max_step) may be below time.dt_initial
        self.steps = 0
        self.rejected = 0
        self.evaluations = 0  # every velocity evaluation: stages, rejected attempts, probes
        self.last_stages = 0
        self.failed_velocity_solves = 0  # trial states whose velocity solve missed its tolerance (rejected)
        self.last_divergence = ""

    # -- evaluations -----------------------------------------------------
    def evaluate(self, y: np.ndarray) -> tuple[np.ndarray, Any]:
        self.evaluations += 1
        return self._rhs(y)

    def velocity(self, y: np.ndarray) -> np.ndarray:
        return self.evaluate(y)[0]

    #: the time of the evaluation being made (a flow whose rate varies in time reads it)
    stage_t: float = 0.0

    def _at(self, times) -> Callable[[np.ndarray], np.ndarray]:
        """``velocity`` with stage_t set to each of `times` in turn: the stages' own times."""
        times = iter(times)

        def f(y: np.ndarray) -> np.ndarray:
            self.stage_t = next(times)
            return self.velocity(y)

        return f

    def start(self) -> Any:
        self.stage_t = self.t
        self.u, aux = self.evaluate(self.y)
        return aux

    # -- one step ---------------------------------------------------------
    def attempt(self, t_stop: float) -> Trial:
        h = min(self.dt, t_stop - self.t)
        try:
            trial, y_new, cap = self._try(h)
        except SolverDivergence as exc:
            # the velocity solve at a trial state missed its tolerance (a state the step should not
            # reach): rejected and retried smaller, as a failed stage solve; the dt guard ends a run
            # whose steps collapse on it (before: the run ended in a traceback)
            self.failed_velocity_solves += 1
            self.last_divergence = str(exc)
            trial, y_new, cap = Trial(False, True, h, math.inf, 0), self.y, False
        if not trial.finite:
            return trial
        clipped = h < self.dt or cap
        # an error per unit step grows like h^(order_low) rather than h^(order_low + 1)
        dt_next = self.controller.next_dt(trial.h, trial.error, self.order_low - (self.UNIT_STEP is not None))
        if trial.accepted:
            self.y = y_new
            self.t += trial.h
            self.steps += 1
            self.last_stages = trial.stages
            if trial.aux is None:  # the scheme did not need the velocity at the new positions
                self.stage_t = self.t
                self.u, trial.aux = self.evaluate(y_new)
                trial.stages += 1
                self.last_stages += 1
            if clipped:
                dt_next = max(dt_next, self.dt)
        else:
            self.rejected += 1
        self.dt = dt_next
        return trial

    def _try(self, h: float) -> tuple[Trial, np.ndarray, bool]:
        """(trial, new positions, whether h was cut below the step size by the scheme)."""
        raise NotImplementedError

    def note(self) -> str:
        """What the run's status should say about the scheme ('' if nothing)."""
        if not self.failed_velocity_solves:
            return ""
        return (f"{self.failed_velocity_solves} trial steps rejected: their velocity solve missed its tolerance "
                f"(last: {self.last_divergence})")

    # -- checkpoints -------------------------------------------------------
    _STATE_ARRAYS: ClassVar[tuple[str, ...]] = ("y", "u")
    _STATE_SCALARS: ClassVar[tuple[str, ...]] = ("t", "dt", "steps", "rejected", "evaluations", "last_stages")

    def state(self) -> dict[str, Any]:
        """Everything the next step depends on, as arrays and scalars."""
        out: dict[str, Any] = {k: np.array(getattr(self, k), copy=True) for k in self._STATE_ARRAYS
                               if getattr(self, k) is not None}
        out.update({k: getattr(self, k) for k in self._STATE_SCALARS})
        out.update({f"controller.{k}": v for k, v in self.controller.state().items()})
        return out

    def restore(self, state: dict[str, Any]) -> None:
        for key in self._STATE_ARRAYS:
            if key in state:
                setattr(self, key, np.array(state[key], dtype=float, copy=True))
        for key in self._STATE_SCALARS:
            kind = type(getattr(self, key))
            setattr(self, key, kind(state[key]))
        self.controller.restore({k.removeprefix("controller."): v for k, v in state.items()
                                 if k.startswith("controller.")})


@register_scheme
class EmbeddedRungeKutta(Integrator):
    """The seed's RKF2(3) pair (module docstring); local extrapolation."""

    name = "rkf23"
    description = ("the seed's Runge-Kutta-Fehlberg 2(3), pinned at the membrane's stability limit "
                   "dt ~ G h")
    tableau: ClassVar[EmbeddedScheme] = RKF23
    order_low = RKF23.order_low
    reference = RKF23.reference

    def _try(self, h: float) -> tuple[Trial, np.ndarray, bool]:
        stages = self._at([self.t + c * h for c in self.tableau.c[1:]])
        res = attempt_step(stages, self.y, h, self.tableau, self.error_rtol, k1=self.u, error_of=self.error_of)
        finite = bool(np.isfinite(res.error) and np.all(np.isfinite(res.y)))
        trial = Trial(accepted=finite and res.error <= 1.0, finite=finite, h=h, error=res.error,
                      stages=len(self.tableau.c) - 1)
        return trial, res.y, False


# ---------------------------------------------------------------- Runge–Kutta–Chebyshev


@dataclass(frozen=True)
class ChebyshevCoefficients:
    """Coefficients of the s-stage second-order RKC method (SSV 1998, eq. 2.4–2.6)."""

    s: int
    mu: np.ndarray        # μ_j
    nu: np.ndarray        # ν_j
    mu_tilde: np.ndarray  # μ̃_j
    gamma_tilde: np.ndarray  # γ̃_j
    beta: float           # stability interval [−β, 0]
    c: np.ndarray = None  # c_j: the time of stage Y_j as a fraction of the step (c_s = 1)

    def __post_init__(self):
        if self.c is None:  # the recursion of rkc_step applied to y' = 1 (every method is consistent)
            c = np.zeros(self.s + 1)
            c[1] = self.mu_tilde[1]
            for j in range(2, self.s + 1):
                c[j] = self.mu[j] * c[j - 1] + self.nu[j] * c[j - 2] + self.mu_tilde[j] + self.gamma_tilde[j]
            object.__setattr__(self, "c", c)


@functools.lru_cache(maxsize=None)  # a run uses a few dozen stage counts, each many times
def rkc_coefficients(s: int, damping: float = 2.0 / 13.0) -> ChebyshevCoefficients:
    """b_j = T_j''(w0)/T_j'(w0)², a_j = 1 − b_j T_j(w0), w0 = 1 + ε/s²,
    w1 = T_s'(w0)/T_s''(w0); b_0 = b_1 = b_2 (SSV 1998, §2)."""
    if s < 2:
        raise ValueError(f"RKC needs at least 2 stages, got {s}")
    w0 = 1.0 + damping / s**2
    T, dT, d2T = np.zeros(s + 1), np.zeros(s + 1), np.zeros(s + 1)
    T[0], T[1], dT[1] = 1.0, w0, 1.0
    for j in range(2, s + 1):
        T[j] = 2 * w0 * T[j - 1] - T[j - 2]
        dT[j] = 2 * T[j - 1] + 2 * w0 * dT[j - 1] - dT[j - 2]
        d2T[j] = 4 * dT[j - 1] + 2 * w0 * d2T[j - 1] - d2T[j - 2]
    w1 = dT[s] / d2T[s]
    b = np.empty(s + 1)
    b[2:] = d2T[2:] / dT[2:] ** 2
    b[0] = b[1] = b[2]
    a = 1.0 - b * T
    mu, nu, mu_t, gamma_t = (np.zeros(s + 1) for _ in range(4))
    mu_t[1] = b[1] * w1
    for j in range(2, s + 1):
        mu[j] = 2 * b[j] * w0 / b[j - 1]
        nu[j] = -b[j] / b[j - 2]
        mu_t[j] = 2 * b[j] * w1 / b[j - 1]
        gamma_t[j] = -a[j - 1] * mu_t[j]
    return ChebyshevCoefficients(s, mu, nu, mu_t, gamma_t, beta=(1.0 + w0) / w1)


def rkc_step(f: Callable[[np.ndarray], np.ndarray], y0: np.ndarray, f0: np.ndarray, h: float,
             coef: ChebyshevCoefficients) -> np.ndarray:
    """One RKC step of size h from y0 (f0 = f(y0)): the three-term recursion
    (SSV 1998, eq. 2.4), s − 1 evaluations of f, a few vectors of memory.

        Y_1 = Y_0 + μ̃_1 h F_0
        Y_j = (1 − μ_j − ν_j) Y_0 + μ_j Y_{j−1} + ν_j Y_{j−2} + μ̃_j h F(Y_{j−1}) + γ̃_j h F_0
    """
    rkc_stage = _kernels().rkc_stage  # the stage's five vectors in one pass (issue 57)
    y_prev2, y_prev = y0, y0 + (coef.mu_tilde[1] * h) * f0
    for j in range(2, coef.s + 1):
        fj = f(y_prev)
        y_j = rkc_stage(y0.ravel(), y_prev.ravel(), y_prev2.ravel(), fj.ravel(), f0.ravel(),
                        1.0 - coef.mu[j] - coef.nu[j], coef.mu[j], coef.nu[j], coef.mu_tilde[j] * h,
                        coef.gamma_tilde[j] * h).reshape(y0.shape)
        y_prev2, y_prev = y_prev, y_j
    return y_prev


def rkc_stages_for(h_rho: float, max_stages: int) -> int:
    """Fewest stages (≥ 2) whose stability interval covers h·ρ, capped at ``max_stages``."""
    s = max(2, int(math.ceil(math.sqrt(max(h_rho, 0.0) / 0.65))))
    while s > 2 and rkc_coefficients(s - 1).beta >= h_rho:
        s -= 1
    while s < max_stages and rkc_coefficients(s).beta < h_rho:
        s += 1
    return min(s, max_stages)


@register_scheme
class RungeKuttaChebyshev(Integrator):
    """Second-order RKC (module docstring). Options:

    ``max_stages``: bound of the stage count. A step that would need more is
    shortened to the stability interval of ``max_stages`` stages (counted in
    ``stage_bound_hits``); the run goes on at that step, as the RKC code does.
    ``rho_refresh_steps``: accepted steps between spectral-radius estimates
    (the estimate is also redone after a rejection, RKC code).
    ``probe_scale``: size of the finite-difference perturbation, relative to
    max(1, |y|₂): √ε_machine for an exact velocity; larger when the velocity is
    a GMRES solve (λ ≠ 1), whose residual would otherwise swamp the difference.
    """

    name = "rkc"
    description = ("second-order Runge-Kutta-Chebyshev (Sommeijer, Shampine & Verwer 1998), as many "
                   "stages per step as the stiffness needs, step size from the error estimate alone")
    option_fields = {
        "max_stages": (int, Field(
            200, ge=2, le=1000, strict=True,
            description="rkc: bound of the stages per step; a step that needs more is shortened to what this "
            "many stages keep stable (the stability interval grows like 0.65 s^2)")),
        "rho_refresh_steps": (int, Field(
            25, ge=1, le=10000, strict=True,
            description="rkc: accepted steps between estimates of the spectral radius (also redone after a "
            "rejection)")),
    }
    order_low = 2  # the SSV estimate is O(h³): step-size exponent 1/3 (1/2 per unit step)
    # The SSV estimate is of the local error of the solution advanced (no local extrapolation,
    # unlike rkf23 and ros34pw2): per step, the global error would grow like rtol^(2/3) (measured:
    # error / rtol 40x larger at rtol 1e-5 than at 1e-2); per unit of kt it grows like rtol, as the
    # others' (docs/time_stepping.md, "One promise for time.rtol")
    UNIT_STEP = 1.0

    @classmethod
    def settings(cls, case: Any, model: Any) -> dict[str, Any]:
        tc = case.time
        # a GMRES velocity (λ ≠ 1, a viscous membrane) is exact only to its tolerance: probe with a
        # perturbation whose response stands well above that noise
        viscosity = getattr(case.membrane, "viscosity", None)
        exact = (all(lam == 1.0 for lam in case.viscosity_ratios)
                 and not (viscosity is not None and viscosity.active))
        return {**super().settings(case, model), "max_stages": tc.max_stages,
                "rho_refresh_steps": tc.rho_refresh_steps,
                "probe_scale": 1.5e-8 if exact else max(1.5e-8, 100.0 * case.solver.tol)}
    reference = "Sommeijer, Shampine & Verwer, J. Comput. Appl. Math. 88 (1998) 315-326"
    RHO_SAFETY = 1.2      # the power iteration approaches ρ from below (RKC code)
    RHO_MAX_ITER = 30
    RHO_RTOL = 0.01

    def __init__(self, rhs: RightHandSide, y0: np.ndarray, *, max_stages: int = 200, rho_refresh_steps: int = 25,
                 probe_scale: float = 1.5e-8, **common: Any) -> None:
        super().__init__(rhs, y0, **common)
        self.max_stages = int(max_stages)
        self.rho_refresh_steps = int(rho_refresh_steps)
        self.probe_scale = float(probe_scale)
        self.rho = 0.0                          # spectral radius estimate (with safety)
        self.rho_vector: np.ndarray | None = None  # warm start of the power iteration
        # accepted steps since the estimate; none yet reads as due (a checkpoint holds counts >= 0:
        # a run interrupted before its first estimate resumes)
        self.rho_age = self.rho_refresh_steps
        self.rho_evaluations = 0
        self.stage_bound_hits = 0

    _STATE_ARRAYS = Integrator._STATE_ARRAYS + ("rho_vector",)
    _STATE_SCALARS = Integrator._STATE_SCALARS + ("rho", "rho_age", "rho_evaluations", "stage_bound_hits")

    def note(self) -> str:
        notes = [super().note()] + ([f"rkc: {self.stage_bound_hits} steps shortened to the stability limit of "
                                     f"time.max_stages = {self.max_stages} stages"] if self.stage_bound_hits else [])
        return "; ".join(n for n in notes if n)

    def spectral_radius(self) -> float:
        """Nonlinear power iteration on v ↦ u(y + v) − u(y), warm-started from
        the last vector; each iteration costs one velocity evaluation."""
        y, u0 = self.y, self.u
        self.stage_t = self.t  # u0 is the velocity at this time
        # the probe's size from the shape about its (whole-unit) mean, not the origin: 1e6 a away
        # |y| made the "small" perturbation 1.5 a, a nonlinear probe (the origin's to the bit)
        delta = self.probe_scale * max(1.0, float(np.linalg.norm(y - np.round(y.mean(axis=0)))))
        v = self.rho_vector if self.rho_vector is not None else u0
        norm = float(np.linalg.norm(v))
        if not norm > 0.0:
            v = np.random.default_rng(0).standard_normal(y.shape)
            norm = float(np.linalg.norm(v))
        v = v * (delta / norm)
        sigma = 0.0
        for it in range(self.RHO_MAX_ITER):
            dv = self.velocity(y + v) - u0
            self.rho_evaluations += 1
            dnorm = float(np.linalg.norm(dv))
            if not math.isfinite(dnorm):  # overflowed: no finite spectral radius to report
                sigma = math.inf
                break
            if not dnorm > 0.0:
                break
            sigma_new = dnorm / delta
            v = dv * (delta / dnorm)
            if it > 0 and abs(sigma_new - sigma) <= self.RHO_RTOL * sigma_new:
                sigma = sigma_new
                break
            sigma = sigma_new
        self.rho_vector = v / delta
        self.rho = self.RHO_SAFETY * sigma
        self.rho_age = 0
        return self.rho

    def _try(self, h: float) -> tuple[Trial, np.ndarray, bool]:
        if self.rho_age >= self.rho_refresh_steps:
            self.spectral_radius()
        cut = False
        if not math.isfinite(self.rho):
            # the Jacobian overflowed (an absurdly stiff membrane): no stage count is stable, and
            # the run's non-finite guard, not an OverflowError in the stage count, ends it
            return Trial(False, False, h, math.inf, 0), self.y, cut
        s = rkc_stages_for(h * self.rho, self.max_stages)
        coef = rkc_coefficients(s)
        if h * self.rho > coef.beta:  # at the bound: the longest step s_max stages keep stable
            h, cut = coef.beta / self.rho, True
            self.stage_bound_hits += 1
        kernels = _kernels()
        y0, f0 = self.y, self.u
        y_new = rkc_step(self._at(self.t + h * coef.c[1:s]), y0, f0, h, coef)
        if not kernels.all_finite(y_new.ravel()):
            return Trial(False, False, h, math.inf, s - 1), y_new, cut
        self.stage_t = self.t + h
        u_new, aux = self.evaluate(y_new)
        # SSV 1998 (3.1): local error estimate of the second-order solution
        est = kernels.rkc_error_estimate(y0.ravel(), y_new.ravel(), f0.ravel(), u_new.ravel(), h)
        est = est.reshape(y0.shape)
        err = self.error_of(est, y0, self.error_rtol)
        if self.UNIT_STEP is not None:
            err *= self.UNIT_STEP / h
        finite = math.isfinite(err) and kernels.all_finite(u_new.ravel())
        accepted = finite and err <= 1.0
        if accepted:
            self.u = u_new
            self.rho_age += 1
        elif self.rho_age > 0:  # re-estimate before the retry unless it was made at these positions
            self.rho_age = self.rho_refresh_steps
        return Trial(accepted, finite, h, err, s, aux=aux if accepted else None), y_new, cut


# ---------------------------------------------------------------- linearly implicit (Rosenbrock-W)


class DenseStageSolver:
    """Stage solver for small systems: J by forward differences of the velocity
    (one evaluation per unknown, counted by the integrator), dense LU solves."""

    def __init__(self, velocity: Callable[[np.ndarray], np.ndarray]) -> None:
        self._velocity = velocity
        self._x: np.ndarray | None = None
        self._jacobian: np.ndarray | None = None
        self.linear_iterations = 0

    def freeze(self, x: np.ndarray, u: np.ndarray) -> None:
        if self._x is x:
            return
        flat = x.ravel()
        f0 = u.ravel()
        jac = np.empty((flat.size, flat.size))
        for j in range(flat.size):
            eps = 1.5e-8 * max(1.0, abs(flat[j]))
            xp = flat.copy()
            xp[j] += eps
            jac[:, j] = (self._velocity(xp.reshape(x.shape)).ravel() - f0) / eps
        self._x, self._jacobian = x, jac

    def solve(self, r: np.ndarray, gamma_h: float, tol: float, **_: Any) -> np.ndarray:
        n = r.size
        return np.linalg.solve(np.eye(n) - gamma_h * self._jacobian, r.ravel()).reshape(r.shape)

    def state(self) -> dict[str, Any]:
        return {}

    def restore(self, state: dict[str, Any]) -> None:
        self._x = self._jacobian = None


@dataclass(frozen=True)
class RosenbrockTableau:
    """A Rosenbrock-W method in the transformed form that needs no J products
    (Hairer & Wanner II, §IV.7, eq. 7.25, with U_i = Σ_j Γ_ij h k_j):

        (I − γhJ) U_i = γ (h f(y + Σ_{j<i} a_ij U_j) + Σ_{j<i} c_ij U_j)
        y_{n+1} = y + Σ m_j U_j,   error estimate Σ (m_j − m̂_j) U_j.
    """

    name: str
    gamma: float
    a: np.ndarray      # (s, s) strictly lower
    c: np.ndarray      # (s, s) strictly lower
    m: np.ndarray      # (s,)
    m_hat: np.ndarray  # (s,) embedded solution
    order: int
    order_low: int
    reference: str

    @classmethod
    def from_k_form(cls, name: str, gamma: float, alpha, gamma_offdiag, b, b_hat, order: int, order_low: int,
                    reference: str) -> "RosenbrockTableau":
        """From the classical form (I − γhJ) k_i = f(y + h Σ α_ij k_j) + hJ Σ γ_ij k_j,
        y_{n+1} = y + h Σ b_i k_i: A = αΓ⁻¹, C = diag(1/γ) − Γ⁻¹, m = bΓ⁻¹."""
        big_gamma = np.asarray(gamma_offdiag, dtype=float) + gamma * np.eye(len(b))
        inv = np.linalg.inv(big_gamma)
        return cls(name, gamma, np.asarray(alpha, dtype=float) @ inv, np.diag(np.diag(inv)) - inv,
                   np.asarray(b, dtype=float) @ inv, np.asarray(b_hat, dtype=float) @ inv, order, order_low, reference)


_G2 = 1.0 + 1.0 / math.sqrt(2.0)
ROSENBROCK = {
    # Verwer, Spee, Blom & Hundsdorfer (1999) eq. 2.2, given in their own transformed form:
    # (I − γhJ) k1 = f(y), (I − γhJ) k2 = f(y + h k1) − 2 k1, y1 = y + (3/2) h k1 + (1/2) h k2,
    # here with U_i = γ h k_i; embedded: linearly implicit Euler y + h k1 (their §2.2)
    "ros2": RosenbrockTableau(
        "ros2", _G2, a=np.array([[0.0, 0.0], [1.0 / _G2, 0.0]]), c=np.array([[0.0, 0.0], [-2.0 / _G2, 0.0]]),
        m=np.array([1.5 / _G2, 0.5 / _G2]), m_hat=np.array([1.0 / _G2, 0.0]), order=2, order_low=1,
        reference="ROS2: Verwer, Spee, Blom & Hundsdorfer, SIAM J. Sci. Comput. 20 (1999) 1456-1480"),
    # Rang & Angermann (2005): four stages, third order for any J (a W-method), L-stable,
    # stiffly accurate, with a second-order embedded solution
    "ros34pw2": RosenbrockTableau.from_k_form(
        "ros34pw2", 4.3586652150845900e-1,
        alpha=[[0, 0, 0, 0], [8.7173304301691801e-1, 0, 0, 0],
               [8.4457060015369423e-1, -1.1299064236484185e-1, 0, 0], [0, 0, 1, 0]],
        gamma_offdiag=[[0, 0, 0, 0], [-8.7173304301691801e-1, 0, 0, 0],
                       [-9.0338057013044082e-1, 5.4180672388095326e-2, 0, 0],
                       [2.4212380706095346e-1, -1.2232505839045147, 5.4526025533510214e-1, 0]],
        b=[2.4212380706095346e-1, -1.2232505839045147, 1.5452602553351020, 4.3586652150845900e-1],
        b_hat=[3.7810903145819369e-1, -9.6042292212423178e-2, 0.5, 2.1793326075422950e-1],
        order=3, order_low=2,
        reference="ROS34PW2: Rang & Angermann, BIT Numer. Math. 45 (2005) 761-787"),
}


@register_scheme
class LinearlyImplicit(Integrator):
    """Rosenbrock-W methods (``method``: a key of :data:`ROSENBROCK`, default ros34pw2).

    A Rosenbrock-W method keeps its order for any matrix J, so J may be the
    velocity's Jacobian with the layer operators frozen at y_n and the stage
    equations may be solved by preconditioned GMRES (``capsim.numerics.linearization``).
    L-stable for the exact Jacobian: h is limited by accuracy alone.

    ``ros34pw2`` (Rang & Angermann 2005): 4 stages, third order, error estimate
    of second order (step-size exponent 1/3, as RKF2(3)'s), three velocity
    evaluations and four stage solves per step. ``ros2`` (Verwer et al. 1999):
    2 stages, second order, first-order estimate (exponent 1/2: the estimate
    overstates the error of the solution it advances with), one evaluation and
    two stage solves per step. Both evaluate f at the new positions for the next step.

    Options: ``stage_solver`` (a ``linearization.StageSolver`` for a capsule; by
    default a :class:`DenseStageSolver`, for small systems) and ``linear_tol``: a
    stage solve stops when its error moves the step by at most ``linear_tol`` ×
    rtol · max(1, |y|) (from U_i = r_i + γh P z_i: |δy| ≤ Σ|m_j| γh |δz|, the stage
    operator's inverse being bounded by ~1).
    """

    name = "linearly_implicit"
    description = "a Rosenbrock-W method (time.rosenbrock) with GMRES stage solves, no stability limit"
    option_fields = {
        "rosenbrock": (Literal["ros34pw2", "ros2"], Field(
            "ros34pw2",
            description="linearly_implicit: ros34pw2, third order, 4 stages (Rang & Angermann 2005); ros2, "
            "second order, 2 stages (Verwer et al. 1999)")),
        "preconditioner": (Literal["local", "dense", "none"], Field(
            "local",
            description="linearly_implicit: preconditioner of the stage solves; local: the membrane's Hessian "
            "with the single layer as a local drag, factorised once per step; dense: the frozen stage operator "
            "itself (layer matrices, Hessian, mass matrix) LU-factorised, for meshes of at most "
            f"{DENSE_MAX_NODES} nodes (level 3 octahedron); both need membrane.traction galerkin; none: plain "
            "GMRES")),
        "linear_tol": (float, Field(
            0.1, gt=0, le=1,
            description="linearly_implicit: a stage solve stops when its error moves the step by at most "
            "this fraction of rtol")),
        "linear_max_iter": (int, Field(
            300, ge=1, le=10000, strict=True,
            description="linearly_implicit: GMRES iterations per stage solve before the step is retried smaller")),
        "jacobian_refresh_steps": (int, Field(
            10, ge=1, le=10000, strict=True,
            description="linearly_implicit: steps between rebuilds of the preconditioner (the membrane Hessian, "
            "and the layer matrices of preconditioner dense), applied between rebuilds in the frame of the "
            "capsule's best-fit rotation; the Jacobian-vector products are always those of the current step")),
    }
    order_low = 2
    reference = "Rosenbrock-W: ROS34PW2 (Rang & Angermann 2005) or ROS2 (Verwer et al. 1999)"

    @classmethod
    def settings(cls, case: Any, model: Any) -> dict[str, Any]:
        from capsim.numerics.linearization import StageSolver  # scipy's sparse LU: only for this scheme

        tc = case.time
        return {**super().settings(case, model), "linear_tol": tc.linear_tol, "method": tc.rosenbrock,
                "stage_solver": StageSolver(model, preconditioner=tc.preconditioner, max_iter=tc.linear_max_iter,
                                            refresh_steps=tc.jacobian_refresh_steps,
                                            max_dense_nodes=DENSE_MAX_NODES)}

    @classmethod
    def case_problem(cls, case: Any) -> tuple[str, Any, str] | None:
        viscosity = getattr(case.membrane, "viscosity", None)
        if viscosity is not None and viscosity.active:
            return ("time.scheme", cls.name,
                    "cannot run a viscous membrane (membrane.viscosity): its stage Jacobian "
                    "(capsim.numerics.linearization) leaves out the viscous membrane operator; use scheme rkf23 or rkc")
        if getattr(case.flow, "rate_factor", None) is not None:  # its W-method stages take no ∂f/∂t
            return ("time.scheme", cls.name,
                    f"cannot run flow.history kind {case.flow.history.kind} (a rate that varies in time: its stages "
                    "take no time derivative); use scheme rkf23, rkc or auto")
        from capsim.scene import Scene  # numpy only: the schema's validation asks this

        # what it cannot run is asked of the scene's features, not of a flow's or a section's name
        scene = Scene.of(case)
        if scene.several:  # its deflation and volume correction are one capsule's
            return ("time.scheme", cls.name, "cannot run several capsules yet (its stage Jacobian deflates one "
                    "capsule's volume mode); use scheme rkf23, rkc or auto")
        if scene.has_boundary:  # its frozen-layer Jacobian has no boundary's regular part (the wall's image)
            labels = " and ".join(b.label for b in scene.boundaries)
            return ("time.scheme", cls.name, f"cannot run a case with a {labels} yet (its stage Jacobian has no "
                    f"{labels} image); use scheme rkf23, rkc or auto")
        if not scene.uniform_gradient:  # its stage Jacobian takes one constant far-field gradient
            return ("time.scheme", cls.name,
                    f"cannot run flow.kind {scene.flow_kind} (its stage Jacobian takes a constant far-field gradient); "
                    "use scheme rkf23, rkc or auto")
        pre = case.time.preconditioner
        if pre in ("local", "dense") and case.membrane.traction != "galerkin":
            return ("time.preconditioner", pre,
                    f"needs membrane.traction: galerkin (got {case.membrane.traction}); use preconditioner: none")
        if pre == "dense" and case.mesh.n_nodes > DENSE_MAX_NODES:
            return ("time.preconditioner", pre,
                    f"takes meshes of at most {DENSE_MAX_NODES} nodes (mesh.level {case.mesh.level} "
                    f"{case.mesh.base} has {case.mesh.n_nodes}); use preconditioner: local")
        return None

    def __init__(self, rhs: RightHandSide, y0: np.ndarray, *, stage_solver: Any = None, linear_tol: float = 0.1,
                 method: str = "ros34pw2", **common: Any) -> None:
        super().__init__(rhs, y0, **common)
        if method not in ROSENBROCK:
            raise ValueError(f"unknown Rosenbrock method {method!r} (allowed: {', '.join(ROSENBROCK)})")
        self.tableau = ROSENBROCK[method]
        self.order_low = self.tableau.order_low
        self.stage_solver = stage_solver if stage_solver is not None else DenseStageSolver(self.velocity)
        self.linear_tol = float(linear_tol)
        self.failed_solves = 0

    _STATE_SCALARS = Integrator._STATE_SCALARS + ("failed_solves",)

    @property
    def linear_iterations(self) -> int:
        return int(self.stage_solver.linear_iterations)

    @property
    def layer_matrices(self) -> int:
        return int(getattr(self.stage_solver, "layer_matrices", 0))

    def state(self) -> dict[str, Any]:
        out = super().state()
        out.update({f"stage.{k}": v for k, v in self.stage_solver.state().items()})
        return out

    def restore(self, state: dict[str, Any]) -> None:
        super().restore({k: v for k, v in state.items() if not k.startswith("stage.")})
        self.stage_solver.restore({k.removeprefix("stage."): v for k, v in state.items() if k.startswith("stage.")})

    def note(self) -> str:
        notes = [super().note()] + ([f"linearly_implicit: {self.failed_solves} stage solves missed their tolerance "
                                     "(steps retried smaller)"] if self.failed_solves else [])
        return "; ".join(n for n in notes if n)

    def _try(self, h: float) -> tuple[Trial, np.ndarray, bool]:
        tab, y0 = self.tableau, self.y
        scale = self.error_rtol * self.size_of(y0)
        gh = tab.gamma * h
        tol = self.linear_tol * scale / (gh * float(np.abs(tab.m).sum()))
        self.stage_solver.freeze(y0, self.u)
        stages: list[np.ndarray] = []
        evaluations = 0
        try:
            for i in range(len(tab.m)):
                if i == 0 or not np.any(tab.a[i, :i]):
                    f = self.u
                else:
                    f = self.velocity(y0 + sum(tab.a[i, j] * stages[j] for j in range(i) if tab.a[i, j]))
                    evaluations += 1
                r = h * f + sum(tab.c[i, j] * stages[j] for j in range(i) if tab.c[i, j])
                stages.append(self.stage_solver.solve(tab.gamma * r, gh, tol))
        except LinearSolveFailed:
            self.failed_solves += 1
            return Trial(False, True, h, math.inf, evaluations), y0, False
        y_new = y0 + sum(mj * u for mj, u in zip(tab.m, stages))
        est = sum((mj - mh) * u for mj, mh, u in zip(tab.m, tab.m_hat, stages))
        err = self.error_of(est, y0, self.error_rtol)
        finite = bool(np.isfinite(err) and np.all(np.isfinite(y_new)))
        return Trial(finite and err <= 1.0, finite, h, err, evaluations), y_new, False


# ---------------------------------------------------------------- the automatic choice


@register_scheme
class Automatic(Integrator):
    """``time.scheme: auto`` (the default): picks rkf23, rkc or linearly_implicit (with the local
    or the dense preconditioner) for a run, the one of the least predicted wall time, and is
    never itself stepped (issue 44: its former thresholds, counted in layer applications on
    level-3 cases, sent level 2 to the linearly implicit scheme where rkc was 1.9x faster).

    It estimates the spectral radius ρ of the velocity's Jacobian at the rest shape by rkc's
    power iteration (10-30 evaluations, counted in the run's cost), and with it the layer
    applications an evaluation takes (1 at λ = 1, more where the double layer is solved for),
    then predicts for each candidate the counts of a run to t_end — accepted steps, velocity
    evaluations, further layer applications, stage-solve GMRES iterations, dense layer matrices
    — and prices them with ``capsim.solve.scheme_cost.costs_for`` (seconds per operation at this
    mesh's nodes, a table measured once by ``benchmarks/scheme_cost.py``; nothing is timed in
    the run, so the choice is deterministic: same rest shape, same measurement, same table, and a
    resumed run makes it again). The counts (per unit time):

    - rkf23: a step of h = min(RKF23_H_ACC (rtol/1e-3)^(1/3), RKF23_STABILITY · RHO_SAFETY/ρ)
      (its accuracy step, third order by local extrapolation, and its stability limit: a
      three-stage third-order method is stable on [−2.51, 0]; the probe's ρ is RHO_SAFETY = 1.2
      times the power iteration's), three evaluations each;
    - rkc: a step of h_acc = H_ACC (rtol/1e-3)^(1/2) (its error is controlled per unit step), s ≈
      (ρ h / 0.65)^(1/2) stages (at least 2; the stability interval grows like 0.65 s²) plus
      RKC_EXTRA evaluations a step (ρ's refreshes, rejections);
    - linearly_implicit: a step of LI_H_ACC (rtol/1e-3)^(1/3), LI_EVALUATIONS evaluations and
      GMRES iterations a step: LI_ITERATIONS_DENSE with the dense preconditioner, LI_ITERATIONS_LOCAL
      + LI_ITERATIONS_SLOPE ln(ρh) with the local one (it grows with the stiffness); a dense
      layer matrix (two at λ ≠ 1) every time.jacobian_refresh_steps steps and one at the start.

    Every accuracy step is multiplied by ((1 + λ)/2)^(1/2) (the most viscous capsule's λ): the
    velocity operator slows the membrane's motion by about 2/(1 + λ), and rtol_promise.md's (d),
    λ = 5, and (e), λ = 10, step 1.6x and 2.7x longer than the λ = 1 cases (rkc at 1e-4). The step
    constants are medians over the short runs of benchmarks/rtol_promise.md (cases (a)-(i) at
    rtol 1e-4 and 1e-3, levels 2-4); benchmarks/auto_choice.md checks the pick against every fixed
    scheme in wall time at levels 2 and 3 (rtol 1e-4: it picks the fastest on every case, its
    median at most 1.20x the fastest's, the probe's evaluations and the load's noise included).
    Every scheme keeps time.rtol's one promise (docs/time_stepping.md), so all are candidates at
    every λ (the rule that sent λ ≥ 8 to the linearly implicit scheme, for case (e), is gone: in
    wall time that scheme is the slowest there, 4-7x rkc's). The linearly implicit scheme needs the
    galerkin traction and no viscous membrane (``LinearlyImplicit.case_problem``); the dense
    preconditioner meshes of at most DENSE_MAX_NODES nodes, and a preconditioner the user chose is
    kept. The choice's text (the run file's ``time_scheme_choice``) gives ρ and each candidate's
    predicted seconds, least first.
    """

    name = "auto"
    description = ("picks rkf23, rkc or linearly_implicit for the run, the least predicted wall time from the "
                   "measured spectral radius, the tolerance and the mesh (the run file says which and why)")
    uses_options_of = ("rkc", "linearly_implicit")
    stepped = False
    order_low = 2
    reference = "capsim: benchmarks/auto_choice.md"
    #: rkc's accuracy-limited step at rtol 1e-3 (exponent 1/2: error per unit step): the median
    #: step of rtol_promise.md's rkc runs (cases (a)-(g), short runs, transient included) at
    #: rtol 1e-3 and 1e-4, 0.053 and 0.018 (their second halves, in the longer runs of
    #: benchmarks/time_schemes.md, step about 1.5x longer)
    H_ACC = 0.055
    #: evaluations a step beyond rkc's stages (ρ refreshed every 25 steps, rejected steps):
    #: rtol_promise.md's rkc runs at rtol 1e-4 take 2.4-2.5 evaluations a step at 2 stages
    RKC_EXTRA = 0.4
    #: rkf23's accuracy-limited step at rtol 1e-3 (exponent 1/3; rtol_promise.md where its
    #: stability does not bind, (d)-(f) at 1e-4: 0.042-0.116, median 0.061), and its stability
    #: limit × the true ρ (the probe's ρ is RHO_SAFETY times it: (a), (b), (c) step at 3.0/ρ)
    RKF23_H_ACC = 0.13
    RKF23_STABILITY = 2.51
    #: the linearly implicit scheme's step at rtol 1e-3 (exponent 1/3): rtol_promise.md's runs,
    #: medians 0.067 at 1e-3 and 0.047 at 1e-4 (2-4x rkc's)
    LI_H_ACC = 0.09
    #: ros34pw2: three evaluations a step and the one at the new positions
    LI_EVALUATIONS = 4.0
    #: GMRES iterations a step (four stage solves): the dense preconditioner's 9-17 on
    #: rtol_promise.md's cases; the local one's 17 (a: ρh ≈ 7) to 32 (g: ρh ≈ 400)
    LI_ITERATIONS_DENSE = 12.0
    LI_ITERATIONS_LOCAL = 12.0
    LI_ITERATIONS_SLOPE = 3.0
    #: the stiffness ρh those iteration counts were measured over (the local preconditioner's 17-32);
    #: beyond it the count grows faster than ln(ρh): the ektacytometry red cell (Skalak C = 1000, level 2,
    #: 0.1 Pa) at ρh ≈ 6600 took 154 iterations a step, not the model's 38, and 86 s, not the
    #: predicted 11 s. The choice's text says when a prediction is so extrapolated.
    LI_CALIBRATED_RHO_H = 400.0
    #: a stage solve's iteration at λ ≠ 1 takes about this many layer applications (the double
    #: layer's solve inside the Jacobian-vector product; rtol_promise.md (d), (e): 2.1-2.2)
    LI_LAYERS_PER_ITERATION = 2.1

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        raise TypeError("scheme auto resolves to another scheme (build_integrator); it is not stepped itself")

    @classmethod
    def _implicit_ok(cls, case: Any) -> bool:
        return LinearlyImplicit.case_problem(case) is None

    @classmethod
    def _with_preconditioner(cls, case: Any, preconditioner: str) -> Any:
        dense = case.time.model_copy(update={"preconditioner": preconditioner})
        return case.model_copy(update={"time": dense})

    @classmethod
    def candidates(cls, case: Any) -> dict[str, Any]:
        """{label: the case it runs} of the schemes auto may pick for `case` (labels: rkf23, rkc,
        linearly_implicit, linearly_implicit/dense)."""
        out: dict[str, Any] = {"rkf23": case, "rkc": case}
        if cls._implicit_ok(case):
            if "preconditioner" in case.time.model_fields_set:  # the user's choice stays
                label = "linearly_implicit" + ("/dense" if case.time.preconditioner == "dense" else "")
                out[label] = case
            else:
                local = cls._with_preconditioner(case, "local")
                if cls._implicit_ok(local):
                    out["linearly_implicit"] = local
                if case.mesh.n_nodes <= DENSE_MAX_NODES:
                    dense = cls._with_preconditioner(case, "dense")
                    if cls._implicit_ok(dense):
                        out["linearly_implicit/dense"] = dense
        return out

    @classmethod
    def extrapolation_note(cls, case: Any, rho: float) -> str | None:
        """Why the linearly implicit scheme's predicted time is not to be trusted here (ρh beyond
        LI_CALIBRATED_RHO_H), else None."""
        rho_h = rho * cls.li_step(case)
        if not rho_h > cls.LI_CALIBRATED_RHO_H:
            return None
        return (f"linearly_implicit's prediction is extrapolated: its GMRES iterations were measured to "
                f"ρh = {cls.LI_CALIBRATED_RHO_H:g}, here ρh = {rho_h:.3g} (at ρh 6600 a run took 7.6x the predicted "
                "time: docs/time_stepping.md, 'How to count cost')")

    @staticmethod
    def viscous_step_factor(case: Any) -> float:
        """((1 + λ)/2)^(1/2), λ the most viscous capsule's: the accuracy steps' factor (class docstring)."""
        return math.sqrt((1.0 + max(case.viscosity_ratios)) / 2.0)

    @classmethod
    def li_step(cls, case: Any) -> float:
        """The linearly implicit scheme's predicted (accuracy) step: LI_H_ACC (rtol/1e-3)^(1/3), times
        the viscous step factor, at most time.dt_max."""
        tc = case.time
        return min(tc.dt_max, cls.viscous_step_factor(case) * cls.LI_H_ACC * (tc.rtol / 1e-3) ** (1.0 / 3.0))

    @classmethod
    def predict(cls, case: Any, rho: float, layers_per_evaluation: float = 1.0, n_nodes: int | None = None,
                target_fraction: float = 0.25) -> dict[str, tuple[float, dict[str, float]]]:
        """{candidate: (predicted wall seconds of the run to t_end, its predicted counts)} from
        the spectral radius ρ and an evaluation's layer applications (class docstring)."""
        from capsim.solve.scheme_cost import costs_for, seconds

        tc = case.time
        t_end = float(tc.t_end)
        costs = costs_for(int(n_nodes or case.mesh.n_nodes), target_fraction)
        lam = max(case.viscosity_ratios)
        extra = max(layers_per_evaluation - 1.0, 0.0)
        rho = max(rho, 1e-300)
        slow = cls.viscous_step_factor(case)
        out: dict[str, tuple[float, dict[str, float]]] = {}

        def explicit(h: float, per_step: float) -> dict[str, float]:
            steps = t_end / h
            return {"step": steps, "evaluation": steps * per_step, "layer": steps * per_step * extra}

        # time.dt_max, not a history's bound (max_step): the accuracy steps below are the steady
        # flow's; under an oscillation bounded to 1/20 of its period rkc, predicted cheaper per
        # capped step, took 9231 steps at ω 1000 (rtol 2e-3) where rkf23 took the bound's 3184
        for label, sub in cls.candidates(case).items():
            if label == "rkf23":
                h = min(tc.dt_max, slow * cls.RKF23_H_ACC * (tc.rtol / 1e-3) ** (1.0 / 3.0),
                        cls.RKF23_STABILITY * RungeKuttaChebyshev.RHO_SAFETY / rho)
                counts = explicit(h, 3.0)
            elif label == "rkc":
                h = min(tc.dt_max, slow * cls.H_ACC * (tc.rtol / 1e-3) ** 0.5)
                stages = max(2.0, math.sqrt(rho * h / 0.65))
                max_stages = float(getattr(tc, "max_stages", 200))
                if stages > max_stages:  # at the bound: the step is what max_stages keep stable
                    stages, h = max_stages, 0.65 * max_stages ** 2 / rho
                counts = explicit(h, stages + cls.RKC_EXTRA)
            else:
                dense = label.endswith("/dense")
                h = cls.li_step(case)
                steps = t_end / h
                per_step = (cls.LI_ITERATIONS_DENSE if dense else
                            cls.LI_ITERATIONS_LOCAL + cls.LI_ITERATIONS_SLOPE * math.log(max(rho * h, 1.0)))
                its = steps * per_step
                evaluations = steps * cls.LI_EVALUATIONS
                per_iteration = 1.0 if lam == 1.0 else min(layers_per_evaluation, cls.LI_LAYERS_PER_ITERATION)
                refresh = float(getattr(tc, "jacobian_refresh_steps", 10))
                counts = {"step": steps, "evaluation": evaluations,
                          "layer": evaluations * extra + its * per_iteration,
                          "iteration_dense" if dense else "iteration_local": its,
                          "matrix": (1.0 if lam == 1.0 else 2.0) * (1.0 + steps / refresh) if dense else 0.0}
            out[label] = (seconds(counts, costs), counts)
        return out

    @classmethod
    def resolve(cls, case: Any, model: Any, rhs: RightHandSide, y0: np.ndarray) -> tuple[type, str, int, Any]:
        # the probe must not change the run: its warm starts are undone (its work stays counted),
        # so that an auto run is, to the bit, the run of the scheme it picks
        saved = model.state()
        before = {k: float(saved.get(k, 0) or 0) for k in
                  ("velocity_evaluations", "single_layer_applications", "double_layer_applications")}
        try:
            probe = RungeKuttaChebyshev(rhs, y0, **RungeKuttaChebyshev.settings(case, model))
            probe.start()
            rho = probe.spectral_radius()
            spent = probe.evaluations
        finally:
            counters = {k: v for k, v in model.state().items() if not k.startswith("warm_")}
            model.restore({**saved, **counters})
        if not math.isfinite(rho):
            # the velocity's Jacobian overflowed (e.g. bending 1e300): no scheme is stable; rkf23
            # needs no stage count, and the run's guards end it with status unstable
            return (EmbeddedRungeKutta, f"ρ = {rho:g} (the velocity's Jacobian overflowed): no scheme is stable "
                    "at any step", spent, case)
        after = {k: float(counters.get(k, 0) or 0) for k in before}
        evaluations = after["velocity_evaluations"] - before["velocity_evaluations"]
        layers = (after["single_layer_applications"] + after["double_layer_applications"]
                  - before["single_layer_applications"] - before["double_layer_applications"])
        per_evaluation = layers / evaluations if evaluations > 0 else 1.0
        disc = getattr(model, "disc", None)
        n_nodes = int(getattr(disc, "n_nodes", 0) or case.mesh.n_nodes)
        targets = getattr(disc, "targets", None)
        fraction = len(targets) / n_nodes if targets is not None and n_nodes else 0.25
        predicted = cls.predict(case, rho, per_evaluation, n_nodes, fraction)
        best = min(predicted, key=lambda k: predicted[k][0])
        chosen = cls.candidates(case)[best]
        scheme = {"rkf23": EmbeddedRungeKutta, "rkc": RungeKuttaChebyshev}.get(best, LinearlyImplicit)
        notes = []
        if not cls._implicit_ok(case):
            notes.append("linearly_implicit cannot run this case")
        extrapolated = cls.extrapolation_note(case, rho) if any(k.startswith("linearly_implicit") for k in predicted) \
            else None
        if extrapolated:
            notes.append(extrapolated)
        ranked = sorted(predicted, key=lambda k: predicted[k][0])
        why = (f"least predicted wall time: ρ = {rho:.3g}, {per_evaluation:.3g} layer applications an evaluation, "
               f"{n_nodes} nodes; predicted " + ", ".join(f"{predicted[k][0]:.3g} s {k}" for k in ranked))
        return scheme, why + "".join(f"; {n}" for n in notes), spent, chosen
