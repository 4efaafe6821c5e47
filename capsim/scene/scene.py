"""The Scene: what a run's capsules are put in and with, built once from the case.

A scene is its far field (the undisturbed flow, capsim.scene.flows, shifted by its boundaries where
they need it), its boundaries (capsim.scene.boundaries: a plane wall today) and its bodies
(capsim.scene.bodies: the capsules' placement, then their layout in the union mesh). The
solver, the time schemes, the guards, the observables, the plots, the export and the accuracy
knob ask the scene's features (``has_boundary``, ``body_count``, ``flow_kind``,
``translation_invariant``, ...) instead of checking the case's fields or a flow by name.

Building a scene reads the case only (no mesh, no numba: ``capsim validate`` builds it);
:meth:`Scene.meshed` lays the bodies' meshes into one surface and returns the scene with
their layout.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

from capsim.scene.flows import FLOWS, FarField, far_field_of
from capsim.scene.bodies import Bodies, BodySpec, body_specs, scene_mesh
from capsim.scene.boundaries import Boundary, boundaries_of


@dataclass(frozen=True, eq=False)
class Scene:
    """A run's far field, boundaries and bodies. ``layout`` (the bodies in the union mesh) is
    None until :meth:`meshed`; a scene made without a case (a model built by hand) is one
    capsule in its ``base_field`` without boundaries."""

    #: the flow's own undisturbed velocity (capsim.scene.flows), before any boundary shifts it
    base_field: Any = field(default_factory=FarField)
    boundaries: tuple[Boundary, ...] = ()
    specs: tuple[BodySpec, ...] = ()
    #: the case's flow.kind (None: a far field given as data)
    flow_kind: str | None = None
    layout: Bodies | None = None

    @classmethod
    def of(cls, case: Any) -> "Scene":
        """The scene of a case (its flow section, its boundary sections, its capsules)."""
        return cls(far_field_of(case.flow), boundaries_of(case), tuple(body_specs(case)), case.flow.kind)

    @cached_property
    def far_field(self) -> Any:
        """The undisturbed flow of the scene: the flow's, as each boundary admits it."""
        out = self.base_field
        for boundary in self.boundaries:
            out = boundary.far_field(out)
        return out

    # ---- features: what the scene has, for those that cannot take everything
    @property
    def has_boundary(self) -> bool:
        return bool(self.boundaries)

    @property
    def body_count(self) -> int:
        if self.layout is not None:
            return self.layout.count
        return max(1, len(self.specs))

    @property
    def several(self) -> bool:
        return self.body_count > 1

    @property
    def uniform_gradient(self) -> bool:
        """Whether the far field's velocity gradient is one constant matrix (not Poiseuille's)."""
        return bool(self.far_field.linear)

    @property
    def translation_invariant(self) -> bool:
        """Whether the scene looks the same about any point up to a uniform velocity: a linear
        far field L·x in free space (no boundary). A capsule in it may be carried (its uniform
        part taken out of the solve: CapsuleModel.carried_velocity) and its translation's error
        held relative to its distance (capsim.solve.timestepping.scene_error)."""
        return not self.boundaries and isinstance(self.far_field, FarField)

    @property
    def elongates_without_bound(self) -> bool:
        """Whether the flow has no steady shape above a critical rate (the extensions)."""
        return self.flow_kind is not None and FLOWS[self.flow_kind].elongates_without_bound

    def features(self) -> dict[str, Any]:
        """The scene's features as the accuracy knob's error model takes them."""
        return {"flow_kind": self.flow_kind, "boundaries": tuple(b.name for b in self.boundaries),
                "capsules": self.body_count}

    def first_order_theory(self, case: Any) -> Any:
        """The first-order small-deformation theory of this scene (capsim.scene.small_deformation,
        ``Flow.first_order``) where its assumptions hold: one capsule, spherical and stress-free at
        rest (no pre-inflation, no other stress-free shape: a pre-stressed membrane is stiffer), a ν_s = 1/2 law without bending
        stiffness, of the case's modulus, in an unbounded flow of constant rate (no boundary, no
        history) whose kind derives one; else None. How small G must be is the caller's."""
        from capsim.scene.small_deformation import NU_HALF_LAWS

        if self.has_boundary or self.several:
            return None
        spec = self.specs[0] if self.specs else None
        shape = spec.shape if spec is not None else case.shape
        membrane = spec.membrane if spec is not None and spec.membrane is not None else case.membrane
        if (shape.kind != "sphere" or shape.inflation or membrane.law not in NU_HALF_LAWS or membrane.bending_modulus
                or membrane.stress_free_differs):  # another stress-free shape: pre-stressed
            return None
        if spec is not None and spec.modulus_ratio != 1.0:
            return None
        if case.flow.history is not None and case.flow.history.kind != "steady":
            return None
        return FLOWS[self.flow_kind or case.flow.kind].first_order(case.flow)

    # ---- the boundaries' part, as the guards and observables read it
    def boundary_gap(self, x: np.ndarray) -> float | None:
        """The smallest distance of the nodes x from any boundary (units of a); None without one."""
        if not self.boundaries:
            return None
        return min(b.gap(x) for b in self.boundaries)

    def end_clearance(self, x: np.ndarray) -> tuple[float, bool]:
        """(how far the membranes' nodes x are from the end of what the boundaries model, inf without;
        whether that end follows the capsules: a straight conduit's window, which they outgrew)."""
        return min(((b.end_clearance(x), b.follows) for b in self.boundaries),
                   default=(float("inf"), False))

    # ---- the bodies
    def meshed(self, base: str, level: int) -> tuple[np.ndarray, np.ndarray, int, "Scene"]:
        """(positions, elements, vertex nodes, the scene with its bodies' layout): the capsules'
        meshes laid into one surface (capsim.scene.bodies.scene_mesh)."""
        positions, elements, n_vertices, layout = scene_mesh(list(self.specs), base, level)
        return positions, elements, n_vertices, dataclasses.replace(self, layout=layout)


def scene_of(case: Any) -> Scene:
    """The scene of a case (:meth:`Scene.of`)."""
    return Scene.of(case)
