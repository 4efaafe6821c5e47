"""The scene's boundaries: the registry of boundary kinds and the one interface each kind meets.

A boundary is what bounds the fluid besides the capsules (a plane wall today; a tube or a
periodic box are new modules here). Its kind is one class registered in
:data:`BOUNDARIES` on the flow registry's pattern (capsim.scene.flows.Kind: ``name``,
``description``, ``uses``, ``problem``), plus ``section``, the case's field that places it, and
:meth:`Boundary.from_case`, which builds the boundary of a case (None when the case has none).

The boundary-integral equation with a boundary keeps its free-space sums and adds, per
boundary, a regular part (an image system, a periodic lattice sum): the Green's function is
G = G_free + G_boundary, G_boundary regular while the membrane stays off the boundary. So a
boundary contributes through these methods alone, and the solver, guards, observables, plots
and export ask them — never where the boundary lies:

- :meth:`Boundary.placed`: the boundary as it lies for the capsules' nodes at one evaluation
  (itself, or a straight conduit's piece centred on them);
- :meth:`Boundary.far_field`: the undisturbed flow the boundary admits (a no-slip wall: the flow
  shifted to vanish on it);
- :meth:`Boundary.gap`: the smallest distance of the membrane's nodes from it (units of a): the
  guard's (guards.min_wall_gap), the run's ``wall_gap`` column, and where the quadrature of its
  regular part switches to the subdivided rule;
- :meth:`Boundary.single_layer` and :meth:`Boundary.double_layer`: its regular part of the two
  layers at the targets, from the quadrature points' strengths (the kernels take arrays);
- :meth:`Boundary.outline_xy` and :meth:`Boundary.patch`: what the plots and the ParaView export
  draw of it.

This module is plain numpy (the case schema's validation reaches it).
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from capsim.scene.flows import Kind, _registrar

#: boundary kind → its class (the scene's boundaries are built from the case by these)
BOUNDARIES: dict[str, type["Boundary"]] = {}
register_boundary = _registrar(BOUNDARIES)


class Boundary(Kind):
    """A kind of boundary of the fluid, and (an instance) one boundary of a scene."""

    #: the case's field whose section places a boundary of this kind
    section: ClassVar[str]
    #: the flow kinds (capsim.scene.flows.FLOWS) whose far field this boundary admits
    flows: ClassVar[tuple[str, ...]] = ()
    #: the name its drawing carries in plots and in the export's file name
    label: ClassVar[str] = "boundary"

    @classmethod
    def from_case(cls, case: Any) -> "Boundary | None":
        """The boundary of this kind a case places (None: none)."""
        raise NotImplementedError

    def far_field(self, field: Any) -> Any:
        """The undisturbed flow of the scene bounded by this boundary, from the flow's own."""
        raise NotImplementedError

    def placed(self, x: np.ndarray) -> "Boundary":
        """The boundary as it lies for the capsules' nodes x (N, 3) at one evaluation: itself,
        unless it follows them (a straight conduit's truncated piece is centred on them)."""
        return self

    def gap(self, x: np.ndarray) -> float:
        """The smallest distance of the nodes x (N, 3) from the boundary (units of a)."""
        raise NotImplementedError

    def single_layer(self, targets: np.ndarray, points: np.ndarray, strengths: np.ndarray) -> np.ndarray:
        """Σ_m G_boundary(target, point_m)·strength_m at every target (T, 3)."""
        raise NotImplementedError

    def double_layer(self, targets: np.ndarray, points: np.ndarray, normals_w: np.ndarray,
                     u_points: np.ndarray) -> np.ndarray:
        """Σ_m u_m·T_boundary(point_m, target)·(n w)_m at every target (T, 3)."""
        raise NotImplementedError

    @property
    def follows(self) -> bool:
        """Whether where it stops being modelled follows the capsules (a straight conduit's window)."""
        return False

    def end_clearance(self, x: np.ndarray) -> float:
        """How far the membranes' nodes x (N, 3) are from where the boundary stops being modelled
        (a conduit's meshed stretch; inf: everywhere)."""
        return float("inf")

    #: whether :meth:`quantities` gives columns (the observer interpolates the load only for those that do)
    reports_quantities: ClassVar[bool] = False

    def quantities(self, nodes: np.ndarray, points: np.ndarray, load_w: np.ndarray, u_points: np.ndarray,
                   normals_w: np.ndarray, center: np.ndarray, G: float, viscosity_ratio: float) -> dict:
        """The boundary's own columns of one capsule (a conduit's additional pressure drop), from
        the capsule's rule points, its load and velocity there (times the weights); none by default."""
        return {}

    def outline_xy(self, lo: float, hi: float) -> tuple[np.ndarray, np.ndarray]:
        """(its trace in the xy-plane between x = lo and hi (k, 2), the solid side's band (m, 2))."""
        raise NotImplementedError

    def patch(self, x: np.ndarray, margin: float = 2.0) -> np.ndarray:
        """Corners (4, 3) of a piece of the boundary under positions x (any (..., 3)), margin a beyond."""
        raise NotImplementedError

    def drawing(self, x: np.ndarray, margin: float = 2.0) -> tuple[np.ndarray, list[tuple[str, np.ndarray]]]:
        """The piece of the boundary the ParaView export draws beside positions x (any (..., 3)):
        (points (P, 3), [(meshio cell type, cells)]); by default the quad of :meth:`patch`."""
        return np.asarray(self.patch(x, margin), dtype=np.float64), [("quad", np.array([[0, 1, 2, 3]], dtype=np.int64))]


def boundaries_of(case: Any) -> tuple[Boundary, ...]:
    """Every boundary a case places, in the registry's order."""
    return tuple(b for b in (kind.from_case(case) for kind in BOUNDARIES.values()) if b is not None)
