"""Conduits (the case's ``conduit:`` section): a rigid tube or duct the capsules flow through.

A conduit is a boundary kind (capsim.scene.boundaries) whose surface is discretised: a closed
surface of 6-node triangles (the side wall, and two flat caps that close the truncated
conduit at x = ±L/2; capsim.numerics.conduit_mesh) carrying an unknown traction density q.
Everything that knows where the conduit's wall lies is here.

**The formulation** (docs/conduits.md). The undisturbed flow u∞ is the fully developed
pressure-driven flow of the empty conduit (capsim.scene.conduit_profiles; it vanishes on the
wall); the capsules' disturbance vanishes on the wall too. The disturbance velocity at a point
x of the fluid is the capsules' free-space single and double layers plus the wall's single
layer ∫_W G(x, y)·q(y) dS, and q is fixed by u_disturbance = 0 at the wall's nodes:

    W q = −c,   c = the capsules' free-space layers at the wall's nodes,

W the wall's single-layer matrix (collocation at its nodes, capsim.numerics.rigid_surface),
built and LU-factorised once per run. Eliminating q (a Schur complement) makes the conduit one
more regular part of the Green's function, as the plane wall's image is: G_conduit(x, y)·s =
−∫_W G(x, z)·(W⁻¹ G(·, y)·s)(z) dS_z, and likewise for the double layer (the conduit's Green's
function vanishes on the wall, so its double layer at the wall is minus the free-space one).
So the solver, the time schemes and the λ ≠ 1 solve run unchanged: each application of a
layer costs one capsule→wall sum, one back-substitution and one wall→capsule sum.

**The closed ends.** The truncated conduit is closed by caps on which the disturbance also
vanishes: the disturbance decays exponentially along a conduit (its slowest Stokes mode decays
like exp(−k x/h), h the half-width), so closing it a distance ℓ from the capsule errs by
O(exp(−k ℓ/h)); the disturbance pressure does not decay (the capsule's additional pressure
drop), which caps carry as a uniform normal traction. On a closed surface W has a null vector
(q = n: a uniform pressure moves no fluid), removed by a rank-one term (Pozrikidis 1992, §6.4).

**The window.** A straight conduit is the same at every x: its truncated piece is placed
centred on the capsules (their nodes' mean x) at every evaluation, so W is factorised once
and a capsule travels any distance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, ClassVar

import numpy as np

from capsim.scene.boundaries import Boundary, register_boundary
from capsim.scene.flows import Kind, _registrar

def _profiles():
    from capsim.scene import conduit_profiles  # numpy; imported where a flow is evaluated

    return conduit_profiles


#: conduit.kind → its class (the schema's choices follow this)
CONDUITS: dict[str, type["ConduitKind"]] = {}
register_conduit = _registrar(CONDUITS)


class ConduitKind(Kind):
    """A kind of conduit: its cross-section (where the wall lies, the fully developed flow in
    it, how fast a disturbance decays along it) and its surface mesh. Lengths in units of a,
    velocities in units of the mean velocity U."""

    #: whether the conduit is the same at every x (its mesh follows the capsules)
    straight: ClassVar[bool] = True

    def __init__(self, section: Any):
        self.section = section

    @property
    def half_width(self) -> float:
        """h: the smallest distance from the axis to the wall (the wall's element size scales with it)."""
        raise NotImplementedError

    @property
    def decay_rate(self) -> float:
        """k/h: a Stokes disturbance decays along the conduit like exp(−(k/h) x) (its slowest mode);
        the truncation error of closing the conduit ℓ beyond the capsule's reach is ~exp(−(k/h) ℓ)."""
        raise NotImplementedError

    @property
    def reach_y(self) -> float:
        """The wall's largest distance from the axis along y."""
        raise NotImplementedError

    def outline_y(self, x: np.ndarray) -> np.ndarray:
        """The wall's distance from the axis along y at each x (the plots' outline in z = 0)."""
        return np.full(np.shape(x), self.reach_y)

    def gap(self, x: np.ndarray) -> np.ndarray:
        """The distance of each point (N, 3) from the side wall (negative outside)."""
        raise NotImplementedError

    def velocity(self, x: np.ndarray) -> np.ndarray:
        """The fully developed flow at the points (N, 3), mean velocity 1 along x."""
        raise NotImplementedError

    def gradients(self, points: np.ndarray) -> np.ndarray:
        """∂u_i/∂x_j of the fully developed flow at the points (N, 3, 3)."""
        raise NotImplementedError

    def gradient(self, point: np.ndarray) -> np.ndarray:
        """∂u_i/∂x_j at one point (3, 3)."""
        return self.gradients(np.asarray(point, dtype=np.float64).reshape(1, 3))[0]

    @property
    def area(self) -> float:
        """The cross-section's area (the flow rate Q = U·area)."""
        raise NotImplementedError

    @property
    def centerline_velocity(self) -> float:
        raise NotImplementedError

    @property
    def pressure_gradient(self) -> float:
        """|dp/dx| of the fully developed flow (units of μU/a²)."""
        raise NotImplementedError

    def mesh(self, length: float, size_near: float, size_far: float, near_half_length: float):
        raise NotImplementedError

    def describe(self) -> str:
        raise NotImplementedError


@register_conduit
class Tube(ConduitKind):
    name = "tube"
    description = "a circular tube of radius conduit.radius about the x-axis (Poiseuille flow in it)"
    uses = ("radius",)
    @property
    def decay_rate(self) -> float:
        # the tube's slowest Stokes mode (n = 1, Papkovich–Neuber, no slip at r = R) decays like
        # exp(−2.5678 x/R); the axisymmetric one, all a capsule on the axis excites, like
        # exp(−4.4663 x/R) (docs/conduits.md, "Truncation")
        return 2.5678 / self.radius

    @property
    def radius(self) -> float:
        return float(self.section.radius)

    @property
    def half_width(self) -> float:
        return self.radius

    @property
    def reach_y(self) -> float:
        return self.radius

    def gap(self, x: np.ndarray) -> np.ndarray:
        return self.radius - np.hypot(x[:, 1], x[:, 2])

    def velocity(self, x: np.ndarray) -> np.ndarray:
        u = np.zeros_like(x)
        u[:, 0] = _profiles().tube_velocity(x[:, 1], x[:, 2], self.radius)
        return u

    def gradients(self, points: np.ndarray) -> np.ndarray:
        return _profiles().tube_gradient(np.asarray(points, dtype=np.float64).reshape(-1, 3), self.radius)

    @property
    def area(self) -> float:
        return math.pi * self.radius ** 2

    @property
    def centerline_velocity(self) -> float:
        return 2.0

    @property
    def pressure_gradient(self) -> float:
        return 8.0 / self.radius ** 2

    def mesh(self, length: float, size_near: float, size_far: float, near_half_length: float):
        from capsim.numerics.conduit_mesh import tube_mesh

        # hemispherical ends: the disturbance's uniform pressure at the ends needs a smooth surface (a flat
        # cap's corner left a spurious far velocity of 1 % of a point force's near field; docs/conduits.md)
        return tube_mesh(self.radius, length, size_near, size_far, near_half_length, caps="round")

    def describe(self) -> str:
        return f"tube R = {self.radius:g} a"


@register_conduit
class Duct(ConduitKind):
    name = "duct"
    description = ("a rectangular duct about the x-axis, |y| <= h_y and |z| <= h_z, conduit.half_widths "
                   "[h_y, h_z] (its series solution)")
    uses = ("half_widths",)

    @property
    def decay_rate(self) -> float:
        # bounded by the plane channel's slowest mode across the wider half-width (sin 2k + 2k = 0:
        # k = 2.1062, exp(−k x/h)); the duct's own modes decay faster (docs/conduits.md, "Truncation")
        return 2.1062 / max(self.half_widths)

    @property
    def half_widths(self) -> tuple[float, float]:
        hy, hz = self.section.half_widths
        return float(hy), float(hz)

    @property
    def half_width(self) -> float:
        return min(self.half_widths)

    @property
    def reach_y(self) -> float:
        return self.half_widths[0]

    def gap(self, x: np.ndarray) -> np.ndarray:
        hy, hz = self.half_widths
        return np.minimum(hy - np.abs(x[:, 1]), hz - np.abs(x[:, 2]))

    def velocity(self, x: np.ndarray) -> np.ndarray:
        hy, hz = self.half_widths
        u = np.zeros_like(x)
        u[:, 0] = _profiles().duct_velocity(x[:, 1], x[:, 2], hy, hz)
        return u

    def gradients(self, points: np.ndarray) -> np.ndarray:
        hy, hz = self.half_widths
        return _profiles().duct_gradient(np.asarray(points, dtype=np.float64).reshape(-1, 3), hy, hz)

    @property
    def area(self) -> float:
        hy, hz = self.half_widths
        return 4.0 * hy * hz

    @property
    def centerline_velocity(self) -> float:
        return float(_profiles().duct_centerline_velocity(*self.half_widths))

    @property
    def pressure_gradient(self) -> float:
        return float(_profiles().duct_pressure_gradient(*self.half_widths))

    def mesh(self, length: float, size_near: float, size_far: float, near_half_length: float):
        from capsim.numerics.conduit_mesh import duct_mesh

        return duct_mesh(*self.half_widths, length, size_near, size_far, near_half_length)

    def describe(self) -> str:
        hy, hz = self.half_widths
        return f"duct {2 * hy:g} a × {2 * hz:g} a"


@register_conduit
class Constriction(Tube):
    """A tube narrowed over a stretch: the tube's far-field flow, half-width and decay (beyond the
    narrowing it is the tube), its own wall; its undisturbed flow is the tube's Poiseuille flow
    plus the wall's response (RigidConduit.empty_flow_correction)."""

    name = "constriction"
    description = ("a circular tube of radius conduit.radius narrowing smoothly to conduit.throat_radius over |x| < "
                   "conduit.throat_length, r(x) = R − (R − R_c)(1 + cos(πx/ℓ))/2 (its flow computed once by the same "
                   "method); the capsule starts upstream (initial_center x < 0) and the run stops before it leaves "
                   "the meshed stretch")
    uses = ("radius", "throat_radius", "throat_length")
    straight = False

    @property
    def throat_radius(self) -> float:
        return float(self.section.throat_radius)

    @property
    def throat_length(self) -> float:
        return float(self.section.throat_length)

    def outline_y(self, x: np.ndarray) -> np.ndarray:
        return self.radius_at(x)

    def radius_at(self, x: np.ndarray) -> np.ndarray:
        R, Rc, ell = self.radius, self.throat_radius, self.throat_length
        x = np.asarray(x, dtype=np.float64)
        return np.where(np.abs(x) < ell, R - (R - Rc) * 0.5 * (1.0 + np.cos(np.pi * x / ell)), R)

    def gap(self, x: np.ndarray) -> np.ndarray:
        # the radial distance to the wall, times the cosine of its slope (the normal distance to first order)
        R, Rc, ell = self.radius, self.throat_radius, self.throat_length
        xs = x[:, 0]
        slope = np.where(np.abs(xs) < ell, (R - Rc) * 0.5 * np.pi / ell * np.sin(np.pi * xs / ell), 0.0)
        return (self.radius_at(xs) - np.hypot(x[:, 1], x[:, 2])) / np.sqrt(1.0 + slope**2)

    def mesh(self, length: float, size_near: float, size_far: float, near_half_length: float):
        from capsim.numerics.conduit_mesh import axisymmetric_conduit_mesh, round_caps

        return round_caps(axisymmetric_conduit_mesh(self.radius_at, length, size_near, size_far, near_half_length))

    def describe(self) -> str:
        return (f"constriction R = {self.radius:g} a to {self.throat_radius:g} a over "
                f"|x| < {self.throat_length:g} a")


#: the conduit section's fields some kind reads
CONDUIT_FIELDS = tuple(sorted({f for cls in CONDUITS.values() for f in cls.uses}))


@dataclass(frozen=True)
class ConduitFarField:
    """The fully developed pressure-driven flow of a conduit along +x, mean velocity 1 (the
    velocity unit U; the time unit a/U, so G = μU/E_s: the conduit's capillary number)."""

    kind: Any  # a ConduitKind
    #: the conduit whose empty flow adds to the kind's analytic one (a constriction); None: analytic
    conduit: Any = None
    linear: ClassVar[bool] = False

    def __call__(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64).reshape(-1, 3)
        u = self.kind.velocity(x)
        if self.conduit is not None:
            u += self.conduit.empty_flow_correction(x)
        return u

    @property
    def matrix(self) -> np.ndarray:
        raise ValueError("a conduit's flow has no constant velocity gradient")

    def gradient_at(self, point: np.ndarray) -> np.ndarray:
        L = self.kind.gradient(point)
        if self.conduit is not None:  # the computed part by central differences (it is smooth inside)
            h = 1e-4
            p = np.asarray(point, dtype=np.float64).reshape(1, 3) + h * np.vstack([np.eye(3), -np.eye(3)])
            u = self.conduit.empty_flow_correction(p)
            L = L + (u[:3] - u[3:]).T / (2 * h)
        return L

    def is_invariant(self, signs: np.ndarray) -> bool:
        # u_x is even in y and z (a tube's or a duct's cross-section is mirror-symmetric) and the
        # flow goes one way along x: S x keeps it when S_x = +1
        return bool(signs[0] == 1.0)


def conduit_kind(section: Any) -> ConduitKind:
    return CONDUITS[section.kind](section)


@register_boundary
@dataclass(frozen=True, eq=False)
class RigidConduit(Boundary):
    """A rigid conduit about the x-axis (its kind: tube, duct), truncated to ``length`` and closed
    by caps; ``size_near`` the wall's element size along the capsules' stretch, growing to
    ``size_far`` beyond."""

    name: ClassVar[str] = "conduit"
    section: ClassVar[str] = "conduit"
    description: ClassVar[str] = ("a rigid conduit (a circular tube, a rectangular duct) along x, meshed with "
                                  "6-node triangles carrying the wall's unknown traction")
    uses: ClassVar[tuple[str, ...]] = CONDUIT_FIELDS
    flows: ClassVar[tuple[str, ...]] = ("conduit",)
    label: ClassVar[str] = "conduit"
    reports_quantities: ClassVar[bool] = True

    kind: ConduitKind
    length: float
    size_near: float
    size_far: float
    near_half_length: float
    #: ℓ, how far the ends lie beyond where a membrane may reach (the stated truncation's margin)
    margin: float = 0.0
    #: the window's centre along x (a straight conduit follows its capsules: ``placed``)
    shift: float = 0.0
    operator: Any = field(default=None, repr=False)

    @classmethod
    def from_case(cls, case: Any) -> "RigidConduit | None":
        section = getattr(case, "conduit", None)
        if section is None:
            return None
        kind = conduit_kind(section)
        xs = [c.center[0] for c in case.capsules] if case.capsules else [case.center[0]]
        spread = max(abs(x - sum(xs) / len(xs)) for x in xs)
        return cls(kind, *conduit_dimensions(section, kind, min(xs) if not kind.straight else 0.0, spread))

    # ---- the scene's view
    def far_field(self, field: Any) -> ConduitFarField:
        return ConduitFarField(self.kind, None if self.kind.straight else self)

    def gap(self, x: np.ndarray) -> float:
        return float(self.kind.gap(np.asarray(x).reshape(-1, 3)).min())

    @property
    def travel_end(self) -> float:
        """|x| a membrane may reach (from the window's centre in a straight conduit): the ends'
        truncation margin short of ±L/2 (capsim.runs.stopping ends the run there: a capsule has
        passed through a constriction, or capsules have drifted apart beyond a tube's window)."""
        return 0.5 * self.length - self.margin

    def end_clearance(self, x: np.ndarray) -> float:
        """How far the membranes' nodes x (all capsules') are from the end of the meshed stretch they
        may reach (the stop rule's: capsim.runs.stopping): a constriction's fixed travel_end, a
        straight conduit's window about the nodes' mean x (capsules that drift apart leave it)."""
        xs = np.asarray(x).reshape(-1, 3)[:, 0]
        centre = float(np.mean(xs)) if self.kind.straight else 0.0
        return self.travel_end - float(np.max(np.abs(xs - centre)))

    @property
    def follows(self) -> bool:
        """Whether its meshed stretch follows the capsules (a straight conduit's window): reaching
        its end then means they outgrew it, not that they passed through."""
        return self.kind.straight

    def empty_flow_correction(self, x: np.ndarray) -> np.ndarray:
        """The empty conduit's flow less the kind's analytic one at points x (a constriction's: the
        tube's Poiseuille flow u_P plus the wall's response u_c = ∫G·q_c dS with u_c = −u_P on the
        side wall and 0 on the round ends, where the flow is fully developed; docs/conduits.md)."""
        from capsim.numerics import rigid_surface

        op = self.wall_operator()
        return rigid_surface.single_layer_at(np.ascontiguousarray(x), op.positions, op.elements, op.empty_density())

    def __eq__(self, other: object) -> bool:
        # one placement of one conduit: the solver's boundary_fine_rule cache then serves the single and
        # the double layer (and each GMRES iteration) of one evaluation from one subdivided rule
        return (isinstance(other, RigidConduit) and other.kind is self.kind and other.shift == self.shift
                and other.length == self.length)

    __hash__ = None  # type: ignore[assignment]

    def placed(self, x: np.ndarray) -> "RigidConduit":
        """The conduit as it lies for the capsules' nodes x: a straight one centred on their mean x."""
        if not self.kind.straight:
            return self
        import dataclasses

        return dataclasses.replace(self, shift=float(np.mean(x[:, 0])), operator=self.wall_operator())

    def wall_operator(self) -> "WallOperator":
        """The wall's mesh and its factorised single layer (built once per conduit, shared by
        every placement)."""
        if self.operator is not None:
            return self.operator
        return _wall_operator(self.kind.name, _section_key(self.kind.section), self.length, self.size_near,
                              self.size_far, self.near_half_length)

    # ---- the regular part of the Green's function: the wall's response (module docstring)
    def single_layer(self, targets: np.ndarray, points: np.ndarray, strengths: np.ndarray) -> np.ndarray:
        from capsim.numerics.kernels import stokeslet_sum

        op = self.wall_operator()
        c = stokeslet_sum(op.nodes_at(self.shift), np.ascontiguousarray(points), np.ascontiguousarray(strengths))
        return op.response_at(np.ascontiguousarray(targets), -c, self.shift)

    def double_layer(self, targets: np.ndarray, points: np.ndarray, normals_w: np.ndarray,
                     u_points: np.ndarray) -> np.ndarray:
        from capsim.numerics.kernels import double_layer_sum

        op = self.wall_operator()
        nodes = op.nodes_at(self.shift)
        c = double_layer_sum(nodes, np.zeros_like(nodes), np.ascontiguousarray(points),
                             np.ascontiguousarray(normals_w), np.ascontiguousarray(u_points))
        return op.response_at(np.ascontiguousarray(targets), -c, self.shift)

    # ---- drawing
    def outline_xy(self, lo: float, hi: float, depth: float = 0.15) -> tuple[np.ndarray, np.ndarray]:
        """The wall's trace in the plane z = 0 (both sides of the axis) and a band behind its lower side."""
        xs = np.linspace(lo, hi, 200)
        ys = self.kind.outline_y(xs)
        line = np.concatenate([np.stack([xs, ys], 1), [[np.nan, np.nan]], np.stack([xs, -ys], 1)])
        band = np.concatenate([np.stack([xs, -ys - depth], 1), np.stack([xs[::-1], -ys[::-1]], 1)])
        return line, band

    def drawing(self, x: np.ndarray, margin: float = 2.0) -> tuple[np.ndarray, list[tuple[str, np.ndarray]]]:
        """The conduit's side wall along the capsules' whole path (6-node triangles, margin a beyond)."""
        xs = np.asarray(x, dtype=np.float64).reshape(-1, 3)
        lo, hi = float(xs[:, 0].min()) - margin, float(xs[:, 0].max()) + margin
        size = self.size_near
        mesh = self.kind.mesh(hi - lo, size, size, hi - lo)
        side = mesh.elements[mesh.part == 0]
        used = np.unique(side)
        index = np.full(mesh.positions.shape[0], -1, dtype=np.int64)
        index[used] = np.arange(used.size)
        points = mesh.positions[used].copy()
        points[:, 0] += 0.5 * (lo + hi)
        return points, [("triangle6", index[side])]

    # ---- what the run reports
    def quantities(self, nodes: np.ndarray, points: np.ndarray, load_w: np.ndarray, u_points: np.ndarray,
                   normals_w: np.ndarray, center: np.ndarray, G: float, viscosity_ratio: float) -> dict:
        """The conduit's columns of one capsule: ``extra_pressure_drop`` ΔP+ (units of μU/a) by the
        reciprocal theorem with the empty conduit's flow (u∞, σ∞) (docs/conduits.md):

            ΔP+ Q = (1/G) ∫_S u∞·Δf dS + (λ − 1) ∫_S u·σ∞·n dS,

        Q the flow rate, Δf the membrane's load (units of E_s/a, so 1/G), u the membrane's
        velocity; ``axis_offset`` (the centroid's distance from the axis: lateral migration),
        ``length_along`` (the capsule's extent along the axis) and ``width_across`` (twice its
        largest distance from the axis line through its centroid), units of a.
        nodes: the capsule's; points, load_w (Δf·dS), u_points, normals_w (n·dS): at its rule points."""
        u_far = self.kind.velocity(points)
        work = float(np.einsum("ij,ij->", u_far, load_w)) / G
        if viscosity_ratio != 1.0 and not self.kind.straight:
            # the (λ − 1) term needs the empty conduit's own stress, and a constriction's computed flow
            # carries no pressure here: not reported rather than reported wrong (docs/conduits.md)
            work = float("nan")
        elif viscosity_ratio != 1.0:
            # σ∞ = −p∞ I + ∇u∞ + ∇u∞ᵀ, p∞ = −|dp/dx| x (a constant adds −p0 ∫u·n = 0: the volume is kept)
            p = -self.kind.pressure_gradient * (points[:, 0] - center[0])
            L = self.kind.gradients(points)
            traction = -p[:, None] * normals_w + np.einsum("kij,kj->ki", L + L.transpose(0, 2, 1), normals_w)
            work += (viscosity_ratio - 1.0) * float(np.einsum("ij,ij->", u_points, traction))
        across = np.hypot(nodes[:, 1] - center[1], nodes[:, 2] - center[2])
        return {"extra_pressure_drop": work / self.kind.area,
                "axis_offset": float(math.hypot(center[1], center[2])),
                "length_along": float(nodes[:, 0].max() - nodes[:, 0].min()),
                "width_across": float(2.0 * across.max())}


def _section_key(section: Any) -> tuple:
    return tuple((name, tuple(v) if isinstance(v, (list, tuple)) else v)
                 for name, v in sorted(vars(section).items()) if not name.startswith("_"))


#: the most nodes a conduit's wall may have: its dense matrix is (3M)² doubles, 2.6 GB at 6000; beyond
#: ~7.5k nodes (4 GB) scipy's OpenBLAS LU crashed on 2 threads here, and its factorisation takes minutes
#: (benchmarks/conduits.md: 134 s at 8130 nodes)
MAX_WALL_NODES = 6000

#: the capsule's reach along the conduit from its centre the fine wall elements cover, beyond
#: the half-width (units of a): a capsule elongated to 2.5 a stays on fine elements
NEAR_REACH = 2.5
#: the default truncation error, relative to the capsule's own values (docs/conduits.md, "Truncation")
TRUNCATION_DEFAULT = 1e-4
#: the truncation error of ends at the capsule's reach (ℓ = 0), relative: measured for a capsule off the
#: axis of a tube (a/R = 0.5, Ca 0.1; round ends) at most 3e-4 (its migration velocity), 1.1e-4 (D_xy)
TRUNCATION_AMPLITUDE = 1e-3


def truncation_margin(kind: ConduitKind, truncation: float) -> float:
    """ℓ: how far beyond the capsule's reach the ends lie for a truncation error (A exp(−k ℓ/h))."""
    return max(0.0, math.log(TRUNCATION_AMPLITUDE / truncation)) / kind.decay_rate


def conduit_dimensions(section: Any, kind: ConduitKind, start_x: float = 0.0,
                       spread: float = 0.0) -> tuple[float, float, float, float, float]:
    """(length, size_near, size_far, near_half_length, margin) of a conduit section: its length from
    the truncation error it states (the disturbance's decay, ``ConduitKind.decay_rate``);
    ``spread``: how far the capsules' centres lie from their mean x (several capsules: a straight
    conduit's window covers them all)."""
    h = kind.half_width
    near_half_length = NEAR_REACH + spread + h
    size_near = float(section.element_size) if section.element_size is not None else default_element_size(kind)
    size_far = max(size_near, 0.5 * h)
    ell = truncation_margin(kind, section.truncation)
    if section.length is not None:
        length = float(section.length)
    elif kind.straight:
        length = 2.0 * (NEAR_REACH + spread + ell)
    else:  # the capsule travels through: from its start upstream as far downstream, and the margin
        length = 2.0 * (max(kind.throat_length, abs(float(start_x))) + NEAR_REACH + ell)
    if not kind.straight:
        near_half_length = 0.5 * length  # fine wherever the capsule passes
    return length, size_near, size_far, near_half_length, ell


def default_element_size(kind: ConduitKind) -> float:
    """The wall's element size along the capsules' stretch (units of a): 1/24 of the
    half-width's circumference (the wall's traction varies on the scale of the capsule's distance
    from it, which grows with the half-width; docs/conduits.md: the accuracy it gives)."""
    return 2.0 * math.pi * kind.half_width / 24.0


def truncation_error(section: Any, kind: ConduitKind, length: float) -> float:
    """The predicted truncation error A exp(−(k/h) ℓ) of a conduit of this length, ℓ the distance from
    the capsule's reach (NEAR_REACH) to an end, A = TRUNCATION_AMPLITUDE (measured)."""
    ell = 0.5 * length - NEAR_REACH
    return TRUNCATION_AMPLITUDE * math.exp(-kind.decay_rate * ell)


class WallOperator:
    """The wall's mesh and its single layer, factorised once (module docstring)."""

    def __init__(self, mesh: Any):
        import scipy.linalg

        from capsim.numerics import rigid_surface

        self.mesh = mesh
        self.positions = np.ascontiguousarray(mesh.positions, dtype=np.float64)
        self.elements = np.ascontiguousarray(mesh.elements, dtype=np.int64)
        n = self.positions.shape[0]
        matrix = rigid_surface.single_layer_matrix(self.positions, self.elements)
        weights = rigid_surface.surface_integral_weights(self.positions, self.elements)
        normals = rigid_surface.nodal_normals(self.positions, self.elements)
        # the closed surface's null vector (a uniform pressure, q = n): W n = 0; the rank-one term
        # n (Σ w n·q) (scaled like W's entries) picks the q with Σ w n·q = 0 (Pozrikidis 1992 §6.4);
        # added by rows (an outer product would hold a second matrix)
        area = float(weights.sum())
        scale = 8.0 * math.pi * math.sqrt(area / (4.0 * math.pi)) / area
        v, u = normals.reshape(-1), (weights[:, None] * normals).reshape(-1) * scale
        for start in range(0, 3 * n, 1024):
            matrix[start:start + 1024] += np.outer(v[start:start + 1024], u)
        # factorised as its transpose: the F-ordered view of the C-ordered matrix, factorised in place
        # (lu_solve's trans=1 then solves W q = b); no copy of the largest array of the run
        self.lu = scipy.linalg.lu_factor(matrix.T, overwrite_a=True, check_finite=False)
        self.matrix_bytes = matrix.nbytes
        self.n_nodes = n
        self._empty = None
        self.analytic_velocity = None  # set by _wall_operator: the kind's analytic flow
        side = np.unique(self.elements[np.asarray(mesh.part) == 0])
        self.end_nodes = np.setdiff1d(np.arange(n), side)
        self.solves = 0
        self.last_density = np.zeros((n, 3))

    def empty_density(self) -> np.ndarray:
        """q_c of the empty conduit's flow correction: W q_c = −u_P on the side wall, 0 on the ends
        (computed once; a straight conduit's is zero)."""
        if self._empty is None:
            b = -self.analytic_velocity(self.positions)
            b[self.end_nodes] = 0.0
            self._empty = self.density(b)
        return self._empty

    def nodes_at(self, shift: float) -> np.ndarray:
        nodes = self.positions.copy()
        nodes[:, 0] += shift
        return nodes

    def density(self, wall_velocity: np.ndarray) -> np.ndarray:
        """q with W q = wall_velocity at the wall's nodes."""
        import scipy.linalg

        self.solves += 1
        q = scipy.linalg.lu_solve(self.lu, wall_velocity.reshape(-1), trans=1, check_finite=False)
        return q.reshape(-1, 3)

    def response_at(self, targets: np.ndarray, wall_velocity: np.ndarray, shift: float) -> np.ndarray:
        """∫_W G(t, y)·q(y) dS at the targets, q the density that makes wall_velocity at the nodes."""
        from capsim.numerics import rigid_surface

        q = self.density(wall_velocity)
        local = targets.copy()
        local[:, 0] -= shift
        return rigid_surface.single_layer_at(local, self.positions, self.elements, np.ascontiguousarray(q))


@lru_cache(maxsize=4)
def _wall_operator(kind_name: str, section_key: tuple, length: float, size_near: float, size_far: float,
                   near_half_length: float) -> WallOperator:
    section = _SectionView(dict(section_key))
    kind = CONDUITS[kind_name](section)
    op = WallOperator(kind.mesh(length, size_near, size_far, near_half_length))
    op.analytic_velocity = kind.velocity
    return op


class _SectionView:
    """A conduit section rebuilt from its cache key (the operator's cache is keyed by values)."""

    def __init__(self, values: dict):
        self.__dict__.update(values)
