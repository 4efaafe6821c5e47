"""The scene: the far field, the boundaries and the bodies a run's capsules are put in.

The far field is the flow registry (``capsim/scene/flows.py``: a kind is one class) with its
first-order small-deformation theory (``capsim/scene/small_deformation.py``).

One public surface: :class:`Scene` (built once from the case: ``Scene.of(case)``), the
boundary registry (:data:`BOUNDARIES`, :class:`Boundary`; the plane wall its first kind, one
module each: ``capsim/scene/plane_wall.py``) and the bodies (the capsules' placement and
layout, ``capsim/scene/bodies.py``). The package is plain numpy: the case schema and
``capsim validate`` reach it without numba (a boundary's kernels load when a velocity is
evaluated). It imports nothing of the solve, the files or the face (tests/test_architecture.py).
"""

from capsim.scene.bodies import (MAX_CAPSULES, MAX_SCENE_NODES, Bodies, BodySpec, body_axis, body_gaps, body_mesh,
                                 body_specs, groups_keeping_materials, materials, reference_positions, run_bodies,
                                 run_capsule_count, scene_mesh, smallest_gap, start_problem, winding_numbers)
from capsim.scene.boundaries import BOUNDARIES, Boundary, boundaries_of, register_boundary
from capsim.scene import plane_wall  # noqa: F401 - registers the plane wall (a boundary kind is its module)
from capsim.scene import conduit  # noqa: F401 - registers the conduit
from capsim.scene.scene import Scene, scene_of

__all__ = ["BOUNDARIES", "Boundary", "boundaries_of", "register_boundary", "Scene", "scene_of", "Bodies",
           "BodySpec", "MAX_CAPSULES", "MAX_SCENE_NODES", "body_axis", "body_gaps", "body_mesh", "body_specs",
           "groups_keeping_materials", "materials", "reference_positions", "run_bodies", "run_capsule_count",
           "scene_mesh", "smallest_gap", "start_problem", "winding_numbers"]
