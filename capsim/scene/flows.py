"""The scene's far field: the undisturbed flows a capsule can be put in (``flow.kind``).

One registry, :data:`FLOWS`: each kind says what its rate is, which fields of ``flow`` it
reads, and builds the undisturbed velocity u∞(x) the boundary-integral equation takes as
data (docs/conventions.md; seed 2.11). Every flow is made dimensionless by its own rate:
lengths by a, velocities by rate·a, time by 1/rate, and G = μ·rate·a/E_s (``flow.shear_rate_G``)
for every kind:

==================== ============================================ ==========================
kind                 u∞ (units of rate·a, x in units of a)          rate
==================== ============================================ ==========================
simple_shear         (y, 0, 0)                                     k, the shear rate
planar_extension     (x, −y, 0)                                    ε, the extension rate
uniaxial_extension   (x, −y/2, −z/2)                               ε, the extension rate
linear               L·x, L = flow.velocity_gradient (traceless)   the scale L is given in
poiseuille           R (1 − (y² + z²)/R²) e_x, R = poiseuille_radius U/R (U: centreline speed)
==================== ============================================ ==========================

Adding a flow is one class here (and its known answer and test). The symmetries of the
scene (:data:`SYMMETRY_GROUPS`: diagonal sign maps x → S x under which the far field maps
onto itself, u∞(S x) = S u∞(x)) are the ones ``mesh.symmetry: auto`` may use; the mesh
decides which of them it has. This module is plain numpy: the case schema imports it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

SIMPLE_SHEAR = ((0.0, 1.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))

# The symmetries used: diagonal sign maps x → S x (and u → S u). Simple shear and
# every rest shape here tilted about z are invariant under MIRROR_Z and ROTATION_Z;
# under INVERSION (their product) whatever the orientation: u∞(−x) = −u∞(x) for any
# linear flow, and every rest shape is centred and symmetric under x → −x.
MIRROR_Z = np.array([1.0, 1.0, -1.0])
ROTATION_Z = np.array([-1.0, -1.0, 1.0])  # rotation by π about the z-axis
INVERSION = np.array([-1.0, -1.0, -1.0])  # the point inversion x → −x

#: group name → generators (Discretization.symmetry, the run file's 'symmetry' attribute)
SYMMETRY_GROUPS = {
    "mirror_z+rotation_z": [MIRROR_Z, ROTATION_Z],
    "mirror_z": [MIRROR_Z],
    "rotation_z": [ROTATION_Z],
    "inversion": [INVERSION],
}
#: mesh.symmetry → the groups tried, largest first. auto keeps the order of the old
#: boolean setting (quarter, then one of its halves), then the inversion, which every
#: centred orientation has: an in-plane case is unchanged to the bit.
SYMMETRY_CANDIDATES = {
    "auto": ("mirror_z+rotation_z", "mirror_z", "rotation_z", "inversion"),
    "quarter": ("mirror_z+rotation_z",),
    "half": ("inversion",),
    "mirror_z": ("mirror_z",),
    "none": (),
}


@dataclass(frozen=True)
class FarField:
    """A linear undisturbed flow u∞(x) = L·x, L the velocity gradient in units of the rate
    (L_ij = ∂u_i/∂x_j). The default is simple shear u∞ = (y, 0, 0)."""

    gradient: tuple = SIMPLE_SHEAR
    #: the velocity's Jacobian is the constant ``matrix`` (the linearly implicit scheme uses it)
    linear: ClassVar[bool] = True

    def __post_init__(self):
        L = np.asarray(self.gradient, dtype=np.float64)
        if L.shape != (3, 3) or not np.all(np.isfinite(L)):
            raise ValueError(f"the far-field velocity gradient must be a finite 3 × 3 matrix, got {self.gradient!r}")
        object.__setattr__(self, "gradient", tuple(map(tuple, L.tolist())))

    @property
    def matrix(self) -> np.ndarray:
        return np.array(self.gradient)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        # entry by entry, so that simple shear gives u_x = y to the bit
        u = np.zeros_like(x)
        for i in range(3):
            for j in range(3):
                if self.gradient[i][j] != 0.0:
                    u[:, i] += self.gradient[i][j] * x[:, j]
        return u

    def gradient_at(self, point: np.ndarray) -> np.ndarray:
        """∂u_i/∂x_j at `point` (3,): the constant L."""
        return self.matrix

    def is_invariant(self, signs: np.ndarray) -> bool:
        """Whether the flow maps onto itself under x → S x, S = diag(signs)."""
        S = np.diag(signs)
        return bool(np.array_equal(S @ self.matrix @ S, self.matrix))


@dataclass(frozen=True)
class PoiseuilleFarField:
    """Unbounded Poiseuille flow along x about the x-axis, u∞ = R (1 − (y² + z²)/R²) e_x in
    units of (U/R)·a: the centreline speed U is R in these units, the wall shear rate 2."""

    radius: float
    linear: ClassVar[bool] = False

    def __call__(self, x: np.ndarray) -> np.ndarray:
        u = np.zeros_like(x)
        u[:, 0] = self.radius - (x[:, 1] ** 2 + x[:, 2] ** 2) / self.radius
        return u

    @property
    def matrix(self) -> np.ndarray:
        raise ValueError("Poiseuille flow has no constant velocity gradient")

    def gradient_at(self, point: np.ndarray) -> np.ndarray:
        L = np.zeros((3, 3))
        L[0, 1], L[0, 2] = -2.0 * point[1] / self.radius, -2.0 * point[2] / self.radius
        return L

    def is_invariant(self, signs: np.ndarray) -> bool:
        # u_x is even in y and z and independent of x: u(S x) = S u(x) needs S_x = +1
        return bool(signs[0] == 1.0)


# ---------------------------------------------------------------- the registry

#: flow.kind → its class (the schema's choices, the CLI's, the docs' table follow this)
FLOWS: dict[str, type["Flow"]] = {}


class Kind:
    """What every kind of a registry declares (flow.kind, flow.history.kind): its ``name``, a
    one-line ``description``, ``uses`` (the optional fields of its section it reads; every one of
    them is required, any other refused: :func:`fields_problem`) and :meth:`problem` (a setting
    of those fields it cannot take, as (field, value, why))."""

    name: ClassVar[str]
    description: ClassVar[str]
    uses: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def problem(cls, section: Any) -> tuple[str, Any, str] | None:
        return None


def _registrar(registry: dict) -> Any:
    def register(cls: type) -> type:
        registry[cls.name] = cls
        return cls

    return register


def fields_problem(section: Any, registry: dict, fields: tuple[str, ...]) -> tuple[str, Any, str] | None:
    """(field, value, why) for a section (flow, flow.history) whose optional ``fields`` do not fit
    its kind: one the kind reads left out, or one only another kind reads given; else the kind's
    own :meth:`Kind.problem`; None when it fits."""
    kind = registry[section.kind]
    for name in fields:
        value = getattr(section, name)
        if name in kind.uses and value is None:
            return (name, None, f"is required with kind: {section.kind}")
        if name not in kind.uses and value is not None:
            owners = ", ".join(k for k, c in registry.items() if name in c.uses)
            return (name, value, f"applies only to kind: {owners}, not to kind: {section.kind}; remove it")
    return kind.problem(section)


register_flow = _registrar(FLOWS)


class Flow(Kind):
    """A kind of undisturbed flow: :meth:`far_field` builds u∞ from the case's flow section;
    ``rate`` says what its rate is."""

    rate: ClassVar[str]
    #: above a critical rate a capsule finds no steady shape and keeps elongating (the extensions:
    #: no rotation relieves the stretch); a run it ends is said so (motion "elongating")
    elongates_without_bound: ClassVar[bool] = False

    #: where this kind's first-order (small-deformation) steady shape is derived and checked
    #: (docs/known_answers.md); None: none is, and the figures draw no theory line
    first_order_source: ClassVar[str | None] = None
    #: the first-order θ, S*_xy and N1*/G where derived (simple shear's), and whether the shear's
    #: impulsive-start transient applies
    first_order_extras: ClassVar[dict[str, Any]] = {}
    #: the steady summary's quantities this kind defines (the others are fixed by its symmetry or
    #: have no meaning in it: θ in extension is 0, S*_xy vanishes, there is no tank-treading
    #: frequency of a sphere in shear to compare with); the steady figure draws a panel for each
    steady_quantities: ClassVar[tuple[str, ...]] = ("D_xy", "theta", "Sxy_star", "N1_star", "N2_star")

    @classmethod
    def far_field(cls, flow: Any) -> Any:
        raise NotImplementedError

    @classmethod
    def first_order(cls, flow: Any) -> Any:
        """The first-order theory of an initially spherical, stress-free ν_s = 1/2 capsule in this
        flow (capsim.scene.small_deformation.FirstOrder: D_xy = α G (e1 − e2)/2 of the strain rate's xy
        block), or None where none is derived. capsim.scene.small_deformation.first_order_theory says
        whether a whole scene meets its assumptions."""
        if cls.first_order_source is None:
            return None
        from capsim.scene.small_deformation import FirstOrder, first_order_D_xy

        return FirstOrder(first_order_D_xy(cls.far_field(flow).matrix, 1.0), cls.first_order_source,
                          **cls.first_order_extras)


@register_flow
class SimpleShear(Flow):
    name = "simple_shear"
    description = "u∞ = k (y, 0, 0): x the flow, y the gradient, z the vorticity direction"
    rate = "k, the shear rate"
    first_order_source = "Barthès-Biesel & Rallison 1981"
    # θ = π/4, S*_xy = 1 and N1* = 19G: docs/known_answers.md, "Capsule: first-order small-deformation theory"
    first_order_extras = {"theta": math.pi / 4, "Sxy_star": 1.0, "N1_over_G": 19.0, "ttf_ratio": 1.0,
                          "transient": True}
    steady_quantities = ("D_xy", "theta", "ttf_ratio", "Sxy_star", "N1_star", "N2_star")

    @classmethod
    def far_field(cls, flow: Any) -> FarField:
        return FarField(SIMPLE_SHEAR)


@register_flow
class PlanarExtension(Flow):
    name = "planar_extension"
    elongates_without_bound = True
    description = "u∞ = ε (x, −y, 0): stretching along x, compression along y (a four-roll mill, a cross-slot)"
    rate = "ε, the extension rate"
    # twice the shear's 25G/4 (docs/known_answers.md, "Flows beyond simple shear"; tests/scene/test_flows.py)
    first_order_source = "Barthès-Biesel & Rallison 1981, pure strain"
    # θ is 0 and S*_xy vanishes by the flow's symmetry; nothing tank-treads as in shear
    steady_quantities = ("D_xy", "N1_star", "N2_star")

    @classmethod
    def far_field(cls, flow: Any) -> FarField:
        return FarField(((1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 0.0)))


@register_flow
class UniaxialExtension(Flow):
    name = "uniaxial_extension"
    elongates_without_bound = True
    description = "u∞ = ε (x, −y/2, −z/2): axisymmetric stretching along x"
    rate = "ε, the extension rate"
    # 3/4 of planar's (E's xy eigenvalues 1, −1/2): docs/known_answers.md, "Flows beyond simple shear"
    first_order_source = "Barthès-Biesel & Rallison 1981, pure strain"
    steady_quantities = ("D_xy", "N1_star", "N2_star")

    @classmethod
    def far_field(cls, flow: Any) -> FarField:
        return FarField(((1.0, 0.0, 0.0), (0.0, -0.5, 0.0), (0.0, 0.0, -0.5)))


@register_flow
class Linear(Flow):
    name = "linear"
    description = ("u∞ = L·x with L = flow.velocity_gradient (L_ij = ∂u_i/∂x_j, traceless), in units of the "
                   "rate that G and the time unit use")
    rate = "the scale L is written in (simple shear is [[0, 1, 0], [0, 0, 0], [0, 0, 0]])"
    uses = ("velocity_gradient",)

    @classmethod
    def far_field(cls, flow: Any) -> FarField:
        return FarField(tuple(tuple(float(v) for v in row) for row in flow.velocity_gradient))

    @classmethod
    def problem(cls, flow: Any) -> tuple[str, Any, str] | None:
        L = flow.velocity_gradient
        try:
            M = np.asarray(L, dtype=float)
        except (TypeError, ValueError):
            M = np.zeros(0)
        if M.shape != (3, 3) or not np.all(np.isfinite(M)):
            return ("velocity_gradient", L, "must be 3 rows of 3 finite numbers")
        scale = float(np.abs(M).max())
        if scale == 0.0:
            return ("velocity_gradient", L, "is zero: no flow (give flow.history kind stop for a capsule at rest)")
        if abs(np.trace(M)) > 1e-9 * scale:
            return ("velocity_gradient", L, f"has trace {np.trace(M):g}: an incompressible flow's gradient is traceless")
        if not 0.1 <= scale <= 10.0:
            return ("velocity_gradient", L, "has its largest entry outside [0.1, 10]: write it in units of its own "
                    "rate (largest entry about 1) and put the rate into G")
        return None


@register_flow
class Poiseuille(Flow):
    name = "poiseuille"
    description = ("unbounded Poiseuille flow u∞ = U (1 − (y² + z²)/R²) e_x about the x-axis, R = "
                   "flow.poiseuille_radius (units of a); the capsule placed with initial_center")
    rate = "U/R, the centreline speed over the radius (the wall shear rate is 2U/R)"
    uses = ("poiseuille_radius",)
    # no first-order theory is derived here (the strain rate varies over the capsule); the
    # stresslet is not a rheology of the suspension in a flow that is not linear
    steady_quantities = ("D_xy", "theta")

    @classmethod
    def far_field(cls, flow: Any) -> PoiseuilleFarField:
        return PoiseuilleFarField(float(flow.poiseuille_radius))


@dataclass(frozen=True)
class ConduitFlowPlaceholder:
    """flow.kind conduit before its conduit places it: the scene's conduit (capsim.scene.conduit)
    replaces it by the fully developed flow of its cross-section (Scene.far_field)."""

    linear: ClassVar[bool] = False

    def __call__(self, x: np.ndarray) -> np.ndarray:
        raise ValueError("flow.kind conduit needs a conduit section (the conduit's flow)")

    def is_invariant(self, signs: np.ndarray) -> bool:
        return bool(signs[0] == 1.0)


@register_flow
class PressureDriven(Flow):
    name = "conduit"
    description = ("the pressure-driven flow of the case's conduit (its conduit section: a tube, a duct) along +x, "
                   "fully developed, U its mean velocity; the capsule placed with initial_center")
    rate = "U/a, the conduit's mean velocity over the capsule's radius: G = μU/E_s is the conduit's capillary number"
    # no first-order theory: the capsule's strain rate varies over it; D_xy and θ are what the
    # steady summary compares (the capsule's shape in the flow's plane)
    steady_quantities = ("D_xy", "theta")

    @classmethod
    def far_field(cls, flow: Any) -> ConduitFlowPlaceholder:
        return ConduitFlowPlaceholder()


#: the optional fields of ``flow`` that some kind reads
FLOW_FIELDS = tuple(sorted({f for cls in FLOWS.values() for f in cls.uses}))


def far_field_of(flow: Any) -> Any:
    """The undisturbed velocity of a case's flow section."""
    return FLOWS[flow.kind].far_field(flow)


def symmetries_kept(field: Any) -> tuple[str, ...]:
    """The groups of :data:`SYMMETRY_GROUPS` under which a far field maps onto itself."""
    return tuple(name for name, generators in SYMMETRY_GROUPS.items()
                 if all(field.is_invariant(g) for g in generators))


# ---------------------------------------------------------------- time dependence (flow.history)


@dataclass(frozen=True)
class ScaledFarField:
    """A far field times a constant (a step in the rate, flow.history kind step)."""

    field: Any
    factor: float

    @property
    def linear(self) -> bool:
        return self.field.linear

    @property
    def matrix(self) -> np.ndarray:
        return self.factor * self.field.matrix

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return self.factor * self.field(x)

    def gradient_at(self, point: np.ndarray) -> np.ndarray:
        return self.factor * self.field.gradient_at(point)

    def is_invariant(self, signs: np.ndarray) -> bool:
        return self.field.is_invariant(signs)


def scaled(field: Any, factor: float) -> Any:
    """The far field times `factor`; a linear field stays a FarField (0: the zero gradient, as
    kind stop has always used)."""
    if isinstance(field, FarField):
        return FarField(tuple(tuple(factor * v for v in row) for row in field.gradient))
    return ScaledFarField(field, float(factor))


#: flow.history.kind → its class: how the rate changes in time, as a factor a(t) of the
#: flow's rate (times stay in units of 1/rate, the rate being the flow's own before any change)
FLOW_HISTORIES: dict[str, type["History"]] = {}
register_history = _registrar(FLOW_HISTORIES)


class History(Kind):
    """How the rate changes in time.
    ``jump``: (time, factor after it) of a jump in the rate, which the steps land on (the runner
    scales the far field there, and the checkpoint records that it has; None: none);
    ``factor(history)``: a(t) for a rate that varies smoothly (evaluated at every stage's time;
    None: constant between jumps);
    ``breakpoints(history)``: every kt at which a(t) or its slope changes abruptly (a jump, a
    table's corners), sorted: the runner ends a step on each, so that no stage straddles one
    (a pulse shorter than a step was stepped over: the stages never saw it);
    ``max_step(history)``: the longest step that resolves a(t) (inf: no bound; the error
    estimate alone cannot be trusted with a forcing it may alias, docs/time_stepping.md)."""

    #: how the steps follow the history (time.rtol auto's reason says it)
    steps: ClassVar[str] = ""

    @classmethod
    def jump(cls, history: Any) -> tuple[float, float] | None:
        return None

    @classmethod
    def factor(cls, history: Any) -> Any:
        return None

    @classmethod
    def breakpoints(cls, history: Any) -> tuple[float, ...]:
        jump = cls.jump(history)
        return () if jump is None else (jump[0],)

    @classmethod
    def max_step(cls, history: Any) -> float:
        return float("inf")


@register_history
class Steady(History):
    name = "steady"
    description = "the rate throughout"


@register_history
class Stop(History):
    name = "stop"
    steps = "a step ends on stop_time"
    description = "the rate until kt = stop_time, then no flow (the capsule relaxes at rest)"
    uses = ("stop_time",)

    @classmethod
    def jump(cls, history: Any) -> tuple[float, float] | None:
        return (float(history.stop_time), 0.0)


@register_history
class Step(History):
    name = "step"
    steps = "a step ends on step_time"
    description = "the rate until kt = step_time, then step_factor times it (a step in shear rate)"
    uses = ("step_time", "step_factor")

    @classmethod
    def jump(cls, history: Any) -> tuple[float, float] | None:
        return (float(history.step_time), float(history.step_factor))


@register_history
class Oscillating(History):
    name = "oscillating"
    description = ("the rate times sin(ω t), ω = omega in units of the rate (oscillatory shear from rest: "
                   "the strain amplitude is 1/ω)")
    uses = ("omega",)

    #: the steps per period of sin(ω t) the step is bounded by (max_step): docs/time_stepping.md,
    #: "Flows that change in time". Measured at ω 10000 (level 0, kt 1, rtol 1e-4): without a bound
    #: D_xy(kt 1) was 8× its converged value (the error estimate aliased the forcing, 3 steps a
    #: period); 5 steps a period left 1.3e-3 of it, 10 left 6.5e-5
    STEPS_PER_PERIOD = 10
    steps = f"each step at most 1/{STEPS_PER_PERIOD} of the oscillation's period"

    @classmethod
    def factor(cls, history: Any) -> Any:
        omega = float(history.omega)
        return lambda t: float(np.sin(omega * t))

    @classmethod
    def max_step(cls, history: Any) -> float:
        return 2.0 * np.pi / (float(history.omega) * cls.STEPS_PER_PERIOD)


@register_history
class Table(History):
    name = "table"
    steps = "a step ends on each of the table's times"
    description = ("a piecewise-linear factor of the rate: table [[t0, a0], [t1, a1], ...] (times increasing; "
                   "a0 before t0, the last factor after the last time)")
    uses = ("table",)

    @classmethod
    def factor(cls, history: Any) -> Any:
        t, a = np.asarray(history.table, dtype=float).T
        return lambda s: float(np.interp(s, t, a))

    @classmethod
    def breakpoints(cls, history: Any) -> tuple[float, ...]:
        return tuple(sorted(float(row[0]) for row in history.table))

    @classmethod
    def problem(cls, history: Any) -> tuple[str, Any, str] | None:
        rows = history.table
        try:
            arr = np.asarray(rows, dtype=float)
        except (TypeError, ValueError):
            arr = np.zeros((0, 3))
        if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] < 2 or not np.all(np.isfinite(arr)):
            return ("table", rows, "must be at least two rows [kt, factor] of finite numbers")
        if not np.all(np.diff(arr[:, 0]) > 0) or arr[0, 0] < 0:
            return ("table", rows, "needs times from 0 on, strictly increasing")
        if np.abs(arr[:, 1]).max() > 100:
            return ("table", rows, "has a factor beyond ±100: write the rate's scale into G")
        return None


def history_breakpoints(history: Any) -> tuple[float, ...]:
    """The kt at which a flow.history (None: steady) changes abruptly, sorted (History.breakpoints)."""
    return () if history is None else FLOW_HISTORIES[history.kind].breakpoints(history)


def history_max_step(history: Any) -> float:
    """The longest step that resolves a flow.history (None: steady; inf: no bound)."""
    return float("inf") if history is None else float(FLOW_HISTORIES[history.kind].max_step(history))


#: the optional fields of ``flow.history`` that some kind reads
HISTORY_FIELDS = tuple(sorted({f for cls in FLOW_HISTORIES.values() for f in cls.uses}))
