"""The no-slip plane wall (the case's ``wall:`` section): the first boundary kind.

Everything that knows where the wall lies is here: its normal and its position are properties
of the wall (:class:`PlaneWall`), and the solver, guards, observables, plots and export ask it
through the boundary interface (capsim.scene.boundaries). Its regular part of the Green's
function is the image system of Blake (1971), integrated by the kernels
``capsim.numerics.kernels.wall_image_sum`` and ``wall_image_double_layer``, which take the wall's
height as a number (kernels take and return arrays): this module is their one call site.

The kernels are written in the frame whose y-axis is the wall's normal; the wall's normal is
that axis (:data:`NORMAL_AXIS`), the velocity gradient's direction of the one flow that
vanishes on a plane (simple shear, :attr:`PlaneWall.flows`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from capsim.scene.flows import FarField
from capsim.scene.boundaries import Boundary, register_boundary

#: the coordinate axis the wall's normal points along (into the fluid): y, the shear's gradient
NORMAL_AXIS = 1


@dataclass(frozen=True)
class AffineFarField:
    """u∞(x) = L·x + c: a linear flow shifted so that it vanishes on a wall (simple shear above
    the plane y = y_w: u∞ = (y − y_w, 0, 0))."""

    base: FarField
    offset: tuple
    linear: ClassVar[bool] = True

    @property
    def matrix(self) -> np.ndarray:
        return self.base.matrix

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return self.base(x) + np.asarray(self.offset)

    def gradient_at(self, point: np.ndarray) -> np.ndarray:
        return self.base.matrix

    def is_invariant(self, signs: np.ndarray) -> bool:
        return self.base.is_invariant(signs) and bool(np.array_equal(signs * np.asarray(self.offset), self.offset))


@register_boundary
@dataclass(frozen=True)
class PlaneWall(Boundary):
    """A no-slip plane wall at rest, ``height`` its position along its normal (units of a)."""

    name: ClassVar[str] = "plane_wall"
    section: ClassVar[str] = "wall"
    description: ClassVar[str] = ("a no-slip plane wall at rest below the capsules, its normal along the shear's "
                                  "gradient (Blake's image system)")
    uses: ClassVar[tuple[str, ...]] = ("distance",)
    flows: ClassVar[tuple[str, ...]] = ("simple_shear",)  # the flows that vanish on a plane y = const
    label: ClassVar[str] = "wall"

    height: float

    @classmethod
    def from_case(cls, case: Any) -> "PlaneWall | None":
        # the case's wall_y: wall.distance below the first capsule's initial centre (capsim.config)
        return None if case.wall is None else cls(float(case.wall_y))

    @property
    def normal(self) -> np.ndarray:
        """The unit normal into the fluid."""
        n = np.zeros(3)
        n[NORMAL_AXIS] = 1.0
        return n

    @property
    def point(self) -> np.ndarray:
        """A point of the wall."""
        return self.height * self.normal

    def far_field(self, field: Any) -> AffineFarField:
        """The undisturbed flow that vanishes on the wall: L·(x − height n)."""
        return AffineFarField(field, tuple(float(v) for v in -field.matrix[:, NORMAL_AXIS] * self.height))

    def gap(self, x: np.ndarray) -> float:
        return float(x[:, NORMAL_AXIS].min() - self.height)

    def single_layer(self, targets: np.ndarray, points: np.ndarray, strengths: np.ndarray) -> np.ndarray:
        from capsim.numerics.kernels import wall_image_sum  # numba: only when a wall's run evaluates a velocity

        return wall_image_sum(targets, points, strengths, self.height)

    def double_layer(self, targets: np.ndarray, points: np.ndarray, normals_w: np.ndarray,
                     u_points: np.ndarray) -> np.ndarray:
        from capsim.numerics.kernels import wall_image_double_layer

        return wall_image_double_layer(targets, points, normals_w, u_points, self.height)

    def outline_xy(self, lo: float, hi: float, depth: float = 0.15) -> tuple[np.ndarray, np.ndarray]:
        y = self.height
        return np.array([[lo, y], [hi, y]]), np.array([[lo, y - depth], [hi, y - depth], [hi, y], [lo, y]])

    def patch(self, x: np.ndarray, margin: float = 2.0) -> np.ndarray:
        xs = np.asarray(x, dtype=np.float64).reshape(-1, 3)
        x0, x1 = xs[:, 0].min() - margin, xs[:, 0].max() + margin
        z0, z1 = xs[:, 2].min() - margin, xs[:, 2].max() + margin
        y = self.height
        return np.array([[x0, y, z0], [x1, y, z0], [x1, y, z1], [x0, y, z1]], dtype=np.float64)

