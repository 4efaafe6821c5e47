"""The scene (capsim/scene/, issue 52): built once from the case, its features, the plane wall as
a boundary kind (its normal and height the wall's own), and the seam a boundary contributes
through (capsim.scene.boundaries.Boundary): a kind registered outside the solver adds its
regular part of the Green's function to the velocity with nothing else changed."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from capsim.config import case_from_dict
from capsim.scene import BOUNDARIES, Boundary, Scene
from capsim.scene.plane_wall import PlaneWall

ROOT = Path(__file__).resolve().parents[2]


def _case(**extra):
    return case_from_dict({"name": "s", "mesh": {"level": 0}, "time": {"t_end": 0.1}, **extra})


def test_the_plane_wall_is_a_registered_kind_with_its_own_normal_and_height():
    scene = Scene.of(_case(wall={"distance": 2.5}, initial_center=[0.0, 1.0, 0.0]))
    assert BOUNDARIES["plane_wall"] is PlaneWall and issubclass(PlaneWall, Boundary)
    (wall,) = scene.boundaries
    assert isinstance(wall, PlaneWall) and wall.height == -1.5  # 2.5 below the centre y = 1
    assert np.array_equal(wall.normal, [0.0, 1.0, 0.0]) and np.array_equal(wall.point, [0.0, -1.5, 0.0])
    # the undisturbed shear vanishes on the wall and is the shear above it: u∞ = (y − y_w, 0, 0)
    x = np.array([[3.0, -1.5, 2.0], [0.0, 1.0, 0.0], [-2.0, 4.0, 1.0]])
    assert np.array_equal(scene.far_field(x), [[0.0, 0, 0], [2.5, 0, 0], [5.5, 0, 0]])
    assert wall.gap(x) == 0.0 and scene.boundary_gap(x[1:]) == 2.5


@pytest.mark.parametrize("extra, features", [
    ({}, dict(has_boundary=False, body_count=1, flow_kind="simple_shear", translation_invariant=True,
              uniform_gradient=True)),
    ({"wall": {"distance": 3.0}}, dict(has_boundary=True, body_count=1, translation_invariant=False)),
    ({"capsules": [{"center": [-2, 0, 0]}, {"center": [2, 0, 0]}]},
     dict(has_boundary=False, body_count=2, several=True, translation_invariant=True)),
    ({"flow": {"kind": "planar_extension", "shear_rate_G": 0.1}},
     dict(flow_kind="planar_extension", translation_invariant=True, elongates_without_bound=True)),
    ({"flow": {"kind": "poiseuille", "shear_rate_G": 0.1, "poiseuille_radius": 5.0}},
     dict(flow_kind="poiseuille", uniform_gradient=False, translation_invariant=False)),
])
def test_the_scene_says_what_it_has(extra, features):
    scene = Scene.of(_case(**extra))
    for name, value in features.items():
        assert getattr(scene, name) == value, name
    assert scene.features() == {"flow_kind": scene.flow_kind, "capsules": scene.body_count,
                                "boundaries": ("plane_wall",) if scene.has_boundary else ()}


def test_a_model_holds_its_scene_and_its_bodies_layout():
    from capsim.solve.solver import build_model

    model, X = build_model(_case(wall={"distance": 3.0}))
    assert model.scene.boundaries == (PlaneWall(-3.0),) and model.bodies.count == 1
    assert model.carried_velocity(X + 5.0) is None  # a wall: nothing is carried
    pair, _ = build_model(_case(capsules=[{"center": [-2, 0, 0]}, {"center": [2, 0, 0]}]))
    assert pair.several and pair.scene.layout is pair.bodies and pair.bodies.count == 2


@dataclasses.dataclass(frozen=True)
class _Uniform(Boundary):
    """A test boundary whose regular part of G·f is a uniform velocity: Σ G_b·s = V at every target."""

    name = "uniform_test"
    label = "uniform"
    velocity: tuple = (0.0, 0.0, 0.0)

    def far_field(self, field):
        return field

    def gap(self, x):
        return float("inf")

    def single_layer(self, targets, points, strengths):
        return np.tile(np.asarray(self.velocity), (targets.shape[0], 1))

    def double_layer(self, targets, points, normals_w, u_points):
        return np.zeros((targets.shape[0], 3))


def test_a_boundary_contributes_through_the_interface_alone():
    """A boundary kind the solver has never heard of adds its single layer to the velocity:
    a uniform V gives u − V/(8πG) at every node (a uniform field has no net flux: the volume
    correction leaves it), and a zero one changes nothing to the bit."""
    from capsim.solve.solver import build_model

    model, X = build_model(_case(mesh={"level": 1, "symmetry": "none"}, flow={"shear_rate_G": 0.1}))
    u0 = model.velocity(X)
    model.scene = dataclasses.replace(model.scene, boundaries=(_Uniform((0.0, 0.0, 0.0)),))
    assert np.array_equal(model.velocity(X), u0)
    V = np.array([0.3, -0.2, 0.1])
    model.scene = dataclasses.replace(model.scene, boundaries=(_Uniform(tuple(V)),))
    assert np.abs(model.velocity(X) - (u0 - V / (8.0 * np.pi * 0.1))).max() < 1e-12
    assert "uniform_image_sum" in model.disc.clock.times  # the stage clock names the boundary's lap


def test_building_a_scene_imports_no_numerics():
    """Scene.of of a wall-and-capsules case (the schema's validation builds one) loads no numba."""
    code = ("import json, sys\nfrom capsim.config import case_from_dict\nfrom capsim.scene import Scene\n"
            "s = Scene.of(case_from_dict({'name': 's', 'wall': {'distance': 3},"
            " 'capsules': [{'center': [-2, 0, 0]}, {'center': [2, 0, 0]}]}))\n"
            "s.far_field, s.boundary_gap(__import__('numpy').zeros((1, 3)))\n"
            "print(json.dumps([m for m in ('numba', 'scipy', 'h5py') if m in sys.modules]))")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_", "CAPSIM_"))}
    env["PYTHONPATH"] = str(ROOT)
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert json.loads(out.stdout.strip().splitlines()[-1]) == []
