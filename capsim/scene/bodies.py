"""The scene's bodies: one capsule or several (``capsules:``), in capsim.scene.

Several capsules are one surface of disjoint closed parts: every capsule's mesh (its own rest
shape, orientation and centre, the case's mesh base and level) is laid one after another into
one node and element array. The boundary-integral equation is then the one capsule's
equation on the union (Pozrikidis 1992, §5: the single and double layers of every surface act
at every point), so the layers, the membrane's forces and the time steppers run on it as
they are:

- the dense Stokeslet and double-layer sums cover every pair, capsule on capsule;
- the singular corrections see only the elements that hold a node, all on its own capsule;
- the near-field correction (``quadrature.near_field_factor``) takes any element close to a
  node that does not hold it, on its own capsule or another's: the refinement by distance
  between capsules that come close;
- the mass matrix and the bending hinges are block-diagonal (no element spans two capsules);
- ``mesh.symmetry: auto`` finds the symmetries the whole scene keeps (a pair placed
  point-symmetrically about the origin in the shear plane keeps all four: a quarter of the
  nodes).

What is per capsule is here: each capsule's node and element range, the fluxes of the volume
correction and of the λ ≠ 1 deflation (each capsule keeps its own volume), and the gap
between capsules that the contact guard reads.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from capsim.numerics.mesh import rest_shape_mesh

#: at most this many capsules in one scene (each a mesh of its own; the dense sums grow as N²)
MAX_CAPSULES = 64
#: at most this many nodes in the whole scene: the dense sums hold O(nodes) arrays per target
#: and the linearly implicit scheme a (3·nodes)² matrix; level 3 has 1026 nodes per capsule
MAX_SCENE_NODES = 200_000


@dataclass(frozen=True)
class BodySpec:
    """One capsule as the case places it: centre (units of a), rest shape, symmetry axis."""

    center: tuple[float, float, float]
    shape: Any  # capsim.config.Shape
    axis: tuple[float, float, float] | None  # None: turned about z by tilt_deg
    tilt_deg: float = 0.0
    membrane: Any = None  # capsim.config.Membrane: its own law parameters and bending (None: the case's)
    modulus_ratio: float = 1.0  # its E_s over the case's
    viscosity_ratio: float | None = None  # its λ (None: the case's)


@dataclass(frozen=True)
class Bodies:
    """The layout of the capsules in the scene's arrays. Every capsule has one mesh connectivity
    (the case's base and level): ``vertices_per_body`` vertex nodes and the mid-side nodes after
    them. The scene keeps the mesh's convention that the vertex nodes come first (the membrane's
    vertex strain is indexed by them): capsule i's vertices are nodes i·n_v … (i+1)·n_v − 1 and its
    mid-side nodes follow all capsules' vertices. ``nodes(i)`` lists capsule i's nodes in its own
    mesh's order, so ``x[nodes(i)]`` is that capsule as its own mesh."""

    count: int
    nodes_per_body: int
    elements_per_body: int
    vertices_per_body: int

    @classmethod
    def from_mesh(cls, count: int, elements: np.ndarray) -> "Bodies":
        """The layout of a scene of ``count`` capsules from its elements alone (a run file's
        /mesh/elements and its ``n_capsules`` attribute): one connectivity, vertices first."""
        n_elements, n_nodes = elements.shape[0], int(elements.max()) + 1
        n_vertices = int(elements[:, :3].max()) + 1
        return cls(count, n_nodes // count, n_elements // count, n_vertices // count)

    def nodes(self, i: int) -> np.ndarray:
        return self.node_index[i]

    @cached_property
    def node_index(self) -> tuple[np.ndarray, ...]:
        """Every capsule's nodes (``nodes``), made once: the per-step and per-solve users index with them."""
        n, nv, k = self.nodes_per_body, self.vertices_per_body, self.count
        if k == 1:
            return (np.arange(n),)
        return tuple(np.concatenate([i * nv + np.arange(nv), k * nv + i * (n - nv) + np.arange(n - nv)])
                     for i in range(k))

    def vertices(self, i: int) -> np.ndarray:
        """Capsule i's vertex nodes (the rows of the membrane's vertex strain that are its)."""
        return i * self.vertices_per_body + np.arange(self.vertices_per_body)

    def elements(self, i: int) -> slice:
        return slice(i * self.elements_per_body, (i + 1) * self.elements_per_body)

    @cached_property
    def element_index(self) -> tuple[np.ndarray, ...]:
        """Every capsule's elements as index arrays (the flux kernels take them)."""
        return tuple(np.arange(i * self.elements_per_body, (i + 1) * self.elements_per_body, dtype=np.int64)
                     for i in range(self.count))

    @cached_property
    def node_body(self) -> np.ndarray:
        """The capsule of every node (N,)."""
        out = np.empty(self.count * self.nodes_per_body, dtype=np.int64)
        for i in range(self.count):
            out[self.nodes(i)] = i
        return out

    def split(self, nodal: np.ndarray) -> list[np.ndarray]:
        """A nodal array cut into one per capsule, each in its own mesh's node order."""
        return [nodal[self.nodes(i)] for i in range(self.count)]


def body_specs(case: Any) -> list[BodySpec]:
    """The case's capsules: its ``capsules`` list (each field it leaves out taken from the
    top-level sections), else the one capsule of the top-level sections."""
    if not case.capsules:
        return [BodySpec(tuple(case.center), case.shape, case.initial_axis, case.initial_tilt_deg)]
    out = []
    for capsule in case.capsules:
        shape = capsule.shape if capsule.shape is not None else case.shape
        if capsule.initial_axis is not None or capsule.initial_tilt_deg is not None:
            axis, tilt = capsule.initial_axis, capsule.initial_tilt_deg or 0.0
        else:
            axis, tilt = case.initial_axis, case.initial_tilt_deg
        out.append(BodySpec(tuple(capsule.center), shape, axis, tilt, capsule.membrane or case.membrane,
                            float(capsule.modulus_ratio),
                            capsule.viscosity_ratio if capsule.viscosity_ratio is not None
                            else case.flow.viscosity_ratio))
    return out


def materials(specs: list[BodySpec], bodies: "Bodies", case: Any) -> dict[str, Any] | None:
    """The capsules' membranes where they differ (None where every capsule has the case's):
    per element ``element_scale`` (modulus_ratio) and ``element_params`` (the law's parameters),
    per vertex node ``vertex_scale`` and ``vertex_params``, per node ``node_bending`` (κ) and
    ``node_lambda`` (λ) — what the membrane force and the model read instead of one value."""
    from capsim.numerics.membrane import get_law

    law = get_law(case.membrane.law)
    lam = [spec.viscosity_ratio if spec.viscosity_ratio is not None else case.flow.viscosity_ratio for spec in specs]
    membranes = [spec.membrane if spec.membrane is not None else case.membrane for spec in specs]
    scale = [spec.modulus_ratio for spec in specs]
    params = {p: [getattr(m, p) for m in membranes] for p in law.parameters}
    bending = [m.bending_modulus for m in membranes]
    uniform = (len(set(lam)) == 1 and len(set(scale)) == 1 and len(set(bending)) == 1
               and all(len(set(v)) == 1 for v in params.values()))
    if uniform and scale[0] == 1.0:
        return None

    def per(values, count):
        return np.repeat(np.asarray(values, dtype=np.float64), count)

    n_e, n_v, n = bodies.elements_per_body, bodies.vertices_per_body, bodies.nodes_per_body
    node = np.empty(bodies.count * n)
    lam_nodes, bend_nodes = node.copy(), node.copy()
    for i in range(bodies.count):
        lam_nodes[bodies.nodes(i)] = lam[i]
        # κ in units of the case's E_s a²: the capsule's own κ (units of its own E_s) times its modulus
        bend_nodes[bodies.nodes(i)] = bending[i] * scale[i]
    return {"element_scale": per(scale, n_e), "vertex_scale": per(scale, n_v),
            "element_params": {p: per(v, n_e) for p, v in params.items()},
            "vertex_params": {p: per(v, n_v) for p, v in params.items()},
            "node_bending": bend_nodes, "node_lambda": None if len(set(lam)) == 1 else lam_nodes,
            "viscosity_ratios": lam, "modulus_ratios": scale, "law_params": [
                {p: v[i] for p, v in params.items()} for i in range(bodies.count)]}


def body_axis(spec: BodySpec) -> tuple[float, float, float]:
    """The capsule's symmetry axis at t = 0: its axis, or y turned by its tilt about z."""
    if spec.axis is not None:
        return tuple(float(c) for c in spec.axis)
    t = np.deg2rad(spec.tilt_deg)
    return (float(-np.sin(t)), float(np.cos(t)), 0.0)


def body_mesh(spec: BodySpec, base: str, level: int):
    """One capsule's mesh at its place (positions, elements, n_vertices)."""
    s = spec.shape
    mesh = rest_shape_mesh(s.kind, base, level, spec.tilt_deg if spec.axis is None else 0.0, axis=spec.axis,
                           aspect_ratio=s.aspect_ratio, c0=s.c0, c2=s.c2, c4=s.c4)
    center = np.asarray(spec.center, dtype=np.float64)
    positions = mesh.positions + center if np.any(center != 0.0) else mesh.positions
    return positions, mesh.elements, mesh.n_vertices


def scene_mesh(specs: list[BodySpec], base: str, level: int) -> tuple[np.ndarray, np.ndarray, int, Bodies]:
    """The union of the capsules' meshes: (positions, elements, vertex nodes, layout), every
    capsule's vertices first (``Bodies``). One capsule: its mesh as it is."""
    parts = [body_mesh(spec, base, level) for spec in specs]
    x0, e0, nv = parts[0]
    bodies = Bodies(len(parts), x0.shape[0], e0.shape[0], nv)
    if len(parts) == 1:
        return x0, e0, nv, bodies
    positions = np.empty((bodies.count * bodies.nodes_per_body, 3))
    elements = np.empty((bodies.count * bodies.elements_per_body, 6), dtype=e0.dtype)
    for i, (x, e, _) in enumerate(parts):
        index = bodies.nodes(i)  # the capsule's own node k is the scene's node index[k]
        positions[index] = x
        elements[bodies.elements(i)] = index[e]
    return positions, elements, bodies.count * nv, bodies


def reference_positions(rest: np.ndarray, bodies: Bodies, specs: list[BodySpec], *, membrane: Any = None,
                        base: str | None = None, level: int | None = None) -> np.ndarray:
    """The membranes' stress-free shapes. Each capsule's: its membrane.reference_shape (another
    surface on the same mesh, scaled to the capsule's initial area, turned as it is and placed at
    its centre: capsim.numerics.mesh.stress_free_positions; `membrane` is the case's, for the
    capsules without their own; `base` and `level` the mesh's), else its initial shape shrunk by
    1 + α about the centre it was placed at (its shape.inflation α; 0: the initial shape is
    stress-free)."""
    shapes = [_stress_free_shape(spec, membrane) for spec in specs]
    if not any(spec.shape.inflation or shape is not None for spec, shape in zip(specs, shapes)):
        return rest
    sphere = None
    if any(shape is not None for shape in shapes):
        from capsim.numerics.mesh import unit_sphere_mesh

        if base is None or level is None:
            raise ValueError("a stress-free shape other than the rest shape needs the mesh's base and level")
        sphere = unit_sphere_mesh(base, level)  # every capsule's own mesh order, made once
    out = rest.copy()
    for i, (spec, shape) in enumerate(zip(specs, shapes)):
        center, part = np.asarray(spec.center, dtype=np.float64), rest[bodies.nodes(i)]
        if shape is not None:
            out[bodies.nodes(i)] = center + _stress_free_part(spec, shape, part, sphere)
        elif spec.shape.inflation:
            out[bodies.nodes(i)] = center + (part - center) / (1.0 + spec.shape.inflation)
    return out


def _stress_free_shape(spec: BodySpec, membrane: Any) -> Any:
    """The capsule's membrane.reference_shape where it is another surface than its rest shape, else None."""
    own = spec.membrane if spec.membrane is not None else membrane
    return own.reference_shape if own is not None and own.stress_free_differs else None


def _stress_free_part(spec: BodySpec, shape: Any, part: np.ndarray, sphere) -> np.ndarray:
    """One capsule's stress-free surface about its centre, at the area of its rest nodes `part`."""
    from capsim.numerics.geometry import element_geometry, volume_area
    from capsim.numerics.mesh import stress_free_positions

    _, area = volume_area(element_geometry(np.ascontiguousarray(part), sphere.elements, 6))
    rest_shape = spec.shape
    coefficients = ({"c0": rest_shape.c0, "c2": rest_shape.c2, "c4": rest_shape.c4}
                    if rest_shape.kind == "biconcave" else {})
    return stress_free_positions(shape.kind, area, sphere, tilt_deg=spec.tilt_deg if spec.axis is None else 0.0,
                                 axis=spec.axis, aspect_ratio=shape.aspect_ratio if shape.kind == "oblate" else 1.0,
                                 reduced_volume_target=shape.reduced_volume, **coefficients)


def body_gaps(x: np.ndarray, bodies: Bodies) -> np.ndarray:
    """The smallest node-to-node distance between every pair of capsules (count × count,
    symmetric, inf on the diagonal): the gap between membranes as the mesh resolves it (it
    exceeds the true surface gap by at most the sag of an element between its nodes)."""
    from scipy.spatial import cKDTree

    k = bodies.count
    out = np.full((k, k), np.inf)
    parts = bodies.split(x)
    trees = [cKDTree(p) for p in parts]
    for i in range(k):
        for j in range(i + 1, k):
            d, _ = trees[j].query(parts[i], k=1)
            out[i, j] = out[j, i] = float(d.min())
    return out


def smallest_gap(x: np.ndarray, bodies: Bodies) -> float:
    """The smallest gap between any two capsules (inf for one)."""
    if bodies.count < 2:
        return float("inf")
    return float(body_gaps(x, bodies).min())


def _flat_triangles(elements: np.ndarray) -> np.ndarray:
    """The four flat triangles of every 6-node element (vertices 0-2, mid-side nodes 3-5:
    3 between 0 and 1, 4 between 1 and 2, 5 between 2 and 0), outward as the element."""
    e = elements
    return np.concatenate([e[:, [0, 3, 5]], e[:, [3, 1, 4]], e[:, [5, 4, 2]], e[:, [3, 4, 5]]])


def winding_numbers(points: np.ndarray, x: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """The winding number of the closed surface (x, elements) about each point: 1 inside, 0
    outside (the solid angle of every flat sub-triangle over 4π, Van Oosterom & Strackee 1983)."""
    tri = x[_flat_triangles(elements)]  # (T, 3, 3)
    out = np.empty(points.shape[0])
    for k0 in range(0, points.shape[0], 256):
        p = points[k0:k0 + 256]
        a, b, c = (tri[None, :, m, :] - p[:, None, :] for m in range(3))
        la, lb, lc = (np.linalg.norm(v, axis=-1) for v in (a, b, c))
        det = np.einsum("ptk,ptk->pt", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("ptk,ptk->pt", a, b) * lc + np.einsum("ptk,ptk->pt", b, c) * la
               + np.einsum("ptk,ptk->pt", c, a) * lb)
        out[k0:k0 + 256] = 2.0 * np.arctan2(det, den).sum(axis=1) / (4.0 * np.pi)
    return out


def start_problem(specs: list[BodySpec], base: str, level: int, min_gap: float) -> tuple[str, Any, str] | None:
    """(field, value, what) of the first capsule placed where it cannot start: inside or within
    ``min_gap`` of another (meshes at ``level``); None when every capsule can start (the wall's
    clearance: the case's wall check). Only pairs whose bounding spheres come within the gap are
    measured."""
    parts = [body_mesh(spec, base, level) for spec in specs]
    centers = [np.asarray(spec.center, dtype=np.float64) for spec in specs]
    radii = [float(np.linalg.norm(p[0] - c, axis=1).max()) for p, c in zip(parts, centers)]
    for j, (x, _, _) in enumerate(parts):
        for i in range(j):
            if np.linalg.norm(centers[i] - centers[j]) > radii[i] + radii[j] + min_gap:
                continue
            xi, ei, _ = parts[i]
            inside = winding_numbers(x, xi, ei) > 0.5
            gap = float(np.min(np.linalg.norm(x[:, None, :] - xi[None, :, :], axis=-1)))
            if inside.any() or gap < min_gap:
                what = ("overlaps" if inside.any() else
                        f"comes within {gap:.3g} a of") + f" capsule {i} at the start"
                return (f"capsules[{j}].center", list(specs[j].center),
                        f"{what}: capsules must start apart by guards.min_capsule_gap = {min_gap:g} (units of a)")
    return None


def groups_keeping_materials(specs: list[BodySpec], groups: dict[str, list[np.ndarray]]) -> set[str]:
    """The symmetry groups (``capsim.scene.flows.SYMMETRY_GROUPS``) whose every generator maps each
    capsule onto a capsule of the same membrane, modulus and λ: the mesh's symmetry search sees
    only positions, and a mirror that maps a stiff capsule onto a soft one is no symmetry."""
    centers = np.array([spec.center for spec in specs], dtype=np.float64)
    kinds = [(spec.membrane, spec.modulus_ratio, spec.viscosity_ratio) for spec in specs]
    kept = set()
    for name, generators in groups.items():
        ok = True
        for S in generators:
            images = centers * np.asarray(S, dtype=np.float64)  # a generator is a diagonal (x, y, z) → S x
            for i, image in enumerate(images):
                j = np.flatnonzero(np.linalg.norm(centers - image, axis=1) < 1e-9)
                if j.size == 0 or kinds[int(j[0])] != kinds[i]:
                    ok = False
        if ok:
            kept.add(name)
    return kept


def run_capsule_count(data: dict[str, Any]) -> int:
    """How many capsules a run file's scene holds (``store.read_trajectory``'s dict): its
    attribute ``n_capsules``, else the width of its per-capsule (t, capsule) columns, else its
    stored case's ``capsules`` list; 1 for a one-capsule run."""
    attrs = data.get("attrs", {})
    if "n_capsules" in attrs:
        return int(attrs["n_capsules"])
    for value in data.get("timeseries", {}).values():
        if np.ndim(value) == 2:
            return int(np.shape(value)[1])
    try:
        import yaml

        return max(1, len(yaml.safe_load(attrs["config_yaml"]).get("capsules") or ()))
    except Exception:  # noqa: BLE001 - without a readable case: the columns said one
        return 1


def run_bodies(data: dict[str, Any]) -> Bodies:
    """The layout of a run file's capsules in its union mesh (every capsule's vertex nodes
    first, then the mid-side nodes; capsule i's elements the block ``elements(i)``), read off
    the stored mesh and checked against it."""
    k = run_capsule_count(data)
    elements = np.asarray(data["elements"])
    n = np.asarray(data["rest_positions"]).shape[0]
    vertices = int(elements[:, 3:].min()) if elements.size else 0
    if k < 1 or n % k or elements.shape[0] % k or vertices % k:
        raise ValueError(f"the run's mesh ({n} nodes, {elements.shape[0]} elements) is not {k} capsules of one mesh")
    bodies = Bodies(k, n // k, elements.shape[0] // k, vertices // k)
    if k > 1:
        body = bodies.node_body
        for i in range(k):
            if np.any(body[elements[bodies.elements(i)]] != i):
                raise ValueError(f"the run's mesh is not {k} capsules laid one after another (capsim.scene.bodies)")
    return bodies

