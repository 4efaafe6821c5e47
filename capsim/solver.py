"""Velocity of the membrane nodes from the membrane force: boundary integrals.

``membrane.MembraneForce`` gives the traction jump Δf; this module turns it into
velocities (single layer, the λ ≠ 1 double-layer solve, the volume correction)
in a linear far-field flow given as data (``FarField``, simple shear by
default), using the mesh's symmetries when it has them. ``build_model(case)``
builds the complete model. Pure orchestration: the loops are in ``kernels.py``.
In units of a, 1/k, ka and
E_s the boundary-integral equation (seed 2.11; docs/conventions.md) reads

    u(x0) = 2/(1+λ) u∞(x0) − 1/(4π(1+λ) G) ∫ Δf·G dS + (1−λ)/(4π(1+λ)) PV∫ u·Tn dS

with u∞ = (y, 0, 0) and G = μka/E_s; at λ = 1 the double layer vanishes and the
velocity is explicit.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from capsim import kernels
from capsim.geometry import ElementGeometry, element_geometry, interpolate, shape_functions
from capsim.krylov import gmres
from capsim.membrane import TRACTION_METHODS, MembraneForce, MembraneState, get_law  # noqa: F401 (re-exported)
from capsim.mesh import node_element_incidence, rest_shape_mesh
from capsim.quadrature import NODE_XI, NODE_ETA, gauss_legendre_01, singular_rules, subdivided_rule, triangle_rule
from capsim.stageclock import StageClock
from capsim.viscosity import build as build_viscous

if TYPE_CHECKING:
    from capsim.config import Case


def shear_flow(x: np.ndarray) -> np.ndarray:
    """Undisturbed simple shear u∞ = (y, 0, 0) in units of ka."""
    u = np.zeros_like(x)
    u[:, 0] = x[:, 1]
    return u


SIMPLE_SHEAR = ((0.0, 1.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))


@dataclass(frozen=True)
class FarField:
    """A linear undisturbed flow u∞(x) = L·x, L the velocity gradient in units of k
    (L_ij = ∂u_i/∂x_j). The default is simple shear u∞ = (y, 0, 0)."""

    gradient: tuple = SIMPLE_SHEAR

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

    def is_invariant(self, signs: np.ndarray) -> bool:
        """Whether the flow maps onto itself under x → S x, S = diag(signs)."""
        S = np.diag(signs)
        return bool(np.array_equal(S @ self.matrix @ S, self.matrix))


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


#: a direction along which no two nodes of a symmetric mesh are expected to project alike
#: (a coordinate axis is not: a whole symmetry plane of nodes shares x = 0)
_SORT_DIRECTION = np.array([1.0, 2.0**0.5, 3.0**0.5]) / 6.0**0.5


def _images_within(points: np.ndarray, queries: np.ndarray, tol: float) -> np.ndarray | None:
    """For each query the index of its nearest point, or None where some query has no
    point within `tol`. What scipy's cKDTree(points).query(queries) gives whenever every
    query has a point that near, without importing scipy.spatial (~0.1 s of every run's
    start-up): a point within tol of q projects within tol of q onto a unit direction, so
    the candidates are a window of the points sorted by that projection (a few each)."""
    key = points @ _SORT_DIRECTION
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    qkey = queries @ _SORT_DIRECTION
    lo = np.searchsorted(sorted_key, qkey - tol, side="left")
    counts = np.searchsorted(sorted_key, qkey + tol, side="right") - lo
    if np.any(counts == 0):
        return None
    which = np.repeat(np.arange(len(queries)), counts)  # the query of each candidate pair
    first = np.cumsum(counts) - counts
    candidate = order[np.repeat(lo - first, counts) + np.arange(counts.sum())]
    d2 = ((points[candidate] - queries[which]) ** 2).sum(axis=1)
    best = np.lexsort((d2, which))[first]  # per query, its candidates by distance: the nearest first
    if np.any(d2[best] > tol * tol):
        return None
    return candidate[best]


def _symmetry_table(positions: np.ndarray, generators: list[np.ndarray]):
    """Orbits of the nodes under the group generated by the sign maps
    ``generators`` (commuting involutions): (targets, source, signs, zero, perms) such
    that value[j] = signs[j] · value_at_targets[source[j]], with value[j, c] = 0
    where zero[j, c] (a group element fixing node j reverses component c); perms the
    image of every node under each group element. None if some node has no image."""
    group = [np.ones(3)]
    for g in generators:
        group += [h * g for h in group]
    n = len(positions)
    nodes = np.arange(n)
    tol = 1e-9 * np.abs(positions).max()
    perms = [nodes]
    for g in group[1:]:
        image = _images_within(positions, positions * g, tol)
        if image is None or np.any(image[image] != nodes):
            return None
        perms.append(image)
    rep = np.min(np.stack(perms), axis=0)
    targets = np.flatnonzero(rep == nodes).astype(np.int64)
    source = np.searchsorted(targets, rep).astype(np.int64)
    signs = np.empty((n, 3))
    assigned = np.zeros(n, dtype=bool)
    zero = np.zeros((n, 3), dtype=bool)
    for g, perm in zip(group, perms):
        hit = (perm[rep] == nodes) & ~assigned
        signs[hit] = g
        assigned |= hit
        fixed = perm == nodes
        zero[fixed] |= (g < 0)[None, :]
    assert assigned.all()
    return targets, source, signs, zero, perms


def _element_orbits(elements: np.ndarray, perms: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(one element of each orbit under the node permutations ``perms``, the orbit's size)."""
    index = {tuple(sorted(e)): i for i, e in enumerate(elements.tolist())}
    images = np.array([[index[tuple(sorted(p[e]))] for e in elements.tolist()] for p in perms])
    first = images.min(axis=0)
    reps = np.flatnonzero(first == np.arange(elements.shape[0]))
    sizes = np.array([np.unique(images[:, r]).size for r in reps], dtype=np.float64)
    return reps.astype(np.int64), sizes


@dataclass(frozen=True)
class RestMeasure:
    """The area element of the rest shape at every rule point, for a density given per unit
    rest area (the Galerkin membrane traction, ``membrane.MembraneForce``): the integrals
    of such a density F take F dA0 where a density per unit current area takes f dA
    (F dA0 = f dA). Built once per rest shape (``Discretization.rest_measure``):
    reg_weights (N_e, q) the regular rule's weights times J0, duffy_weights (N_e, 6, m)
    the Duffy rule's for a singularity at each local node, fine_weights (N_e, m_f) the
    near field's subdivided rule's."""

    reg_weights: np.ndarray
    duffy_weights: np.ndarray
    fine_weights: np.ndarray


@dataclass
class Discretization:
    """Static tables of a mesh and its quadrature rules (built once per run)."""

    elements: np.ndarray
    n_vertices: int
    regular_order: int = 6
    singular_order: int = 2
    contour_order: int = 4
    membrane_order: int = 6
    # near field: elements within near_field_factor × their size of a target node
    # (not holding it) are integrated on 4^near_field_levels sub-triangles; 0 = off
    near_field_factor: float = 0.0
    near_field_levels: int = 1

    def __post_init__(self):
        n_nodes = int(self.elements.max()) + 1
        self.n_nodes = n_nodes
        self.inc_offsets, self.inc_elem, self.inc_local = node_element_incidence(self.elements, n_nodes)
        xi, eta, _ = triangle_rule(self.regular_order)
        self.reg_phi = np.ascontiguousarray(shape_functions(xi, eta)[0])
        sx, se, sw = singular_rules(self.singular_order)
        m = sx.shape[1]
        phi = np.empty((6, m, 6))
        dxi = np.empty((6, m, 6))
        deta = np.empty((6, m, 6))
        for k in range(6):
            phi[k], dxi[k], deta[k] = shape_functions(sx[k], se[k])
        self.sing_phi, self.sing_dxi, self.sing_deta, self.sing_w = phi, dxi, deta, np.ascontiguousarray(sw)
        # the same tables as the singular corrections read them: [k, a, q], the points contiguous
        self.duffy_by_node = tuple(np.ascontiguousarray(t.transpose(0, 2, 1)) for t in (phi, dxi, deta))
        _, vdxi, vdeta = shape_functions(NODE_XI[:3], NODE_ETA[:3])
        self.vertex_dxi, self.vertex_deta = np.ascontiguousarray(vdxi), np.ascontiguousarray(vdeta)
        self.contour_s, self.contour_w = gauss_legendre_01(self.contour_order)
        _, ndxi, ndeta = shape_functions(NODE_XI, NODE_ETA)
        self.node_dxi, self.node_deta = ndxi, ndeta
        mxi, meta, mw = triangle_rule(self.membrane_order)
        mphi, mdxi, mdeta = shape_functions(mxi, meta)
        self.mem_phi, self.mem_dxi, self.mem_deta, self.mem_w = mphi, mdxi, mdeta, mw
        self._build_mass_pattern()
        self.targets = np.arange(n_nodes, dtype=np.int64)
        self.all_elements = np.arange(self.elements.shape[0], dtype=np.int64)
        self.target_elements = self.all_elements  # the elements holding a target node
        self._ones = np.ones(self.elements.shape[0])
        self.orbit_elements, self.orbit_sizes = self.all_elements, self._ones
        self.symmetry = "none"  # or a key of SYMMETRY_GROUPS (enable_symmetry)
        fxi, feta, fw = subdivided_rule(self.regular_order, self.near_field_levels)
        fphi, fdxi, fdeta = shape_functions(fxi, feta)
        self.fine_phi, self.fine_dxi, self.fine_deta = (np.ascontiguousarray(a) for a in (fphi, fdxi, fdeta))
        self.fine_w = np.ascontiguousarray(fw)
        self._near: tuple | None = None  # (geometry, offsets, elements) of the last configuration
        # the kernels' "no rest measure" (a density per unit area of the current surface)
        self._current_measure = RestMeasure(np.zeros((0, 0)), np.zeros((0, 6, m)), np.zeros((0, fw.size)))
        # the per-stage split of an evaluation, shared with the membrane force (capsim bench)
        self.clock = StageClock()

    def enable_symmetry(self, positions: np.ndarray, rotation: bool = True, mode: str | None = None) -> np.ndarray | None:
        """Use the symmetries of the problem: the mirror z → −z, the rotation by π
        about the z-axis, (x, y, z) → (−x, −y, z), and the point inversion x → −x.

        Shear flow (y, 0, 0) and every rest shape tilted about z are invariant under
        the mirror and the rotation; velocities transform as positions do
        (u → S u, S = diag(1, 1, −1) or diag(−1, −1, 1)). Together with their
        product (the inversion) they form a group of four, so the boundary
        integrals are evaluated at one node of each orbit (about a quarter of the
        nodes; the seed used both symmetries) and expanded. A rest shape turned
        out of the shear plane keeps only the inversion (half of the nodes).

        ``mode`` is a key of SYMMETRY_CANDIDATES (the case's mesh.symmetry); without
        it, ``rotation`` picks the old boolean setting ("auto") or the mirror only.
        Uses the first group of the mode's list that the mesh has (an image of every
        node); ``self.symmetry`` says which ("mirror_z+rotation_z", "mirror_z",
        "rotation_z", "inversion" or "none"). Returns the positions made exactly
        symmetric, or None (and nothing changes) if the mesh has none of them.
        """
        if mode is None:
            mode = "auto" if rotation else "mirror_z"
        for name in SYMMETRY_CANDIDATES[mode]:
            table = _symmetry_table(positions, SYMMETRY_GROUPS[name])
            if table is not None:
                break
        else:
            return None
        self.symmetry = name
        self._near = None
        self.targets, self._sym_source, self._sym_signs, self._sym_zero, perms = table
        # an invariant integrand (the flux u·n of an equivariant u) takes the same value on every
        # element of an orbit: ``flux`` sums one element of each, times the orbit's size
        self.orbit_elements, self.orbit_sizes = _element_orbits(self.elements, perms)
        holds_target = np.zeros(self.elements.shape[0], dtype=bool)
        for p in self.targets:
            holds_target[self.inc_elem[self.inc_offsets[p]:self.inc_offsets[p + 1]]] = True
        self.target_elements = np.flatnonzero(holds_target).astype(np.int64)
        return self.expand(positions[self.targets])

    def enable_mirror_symmetry(self, positions: np.ndarray) -> np.ndarray | None:
        """The mirror z → −z only (see ``enable_symmetry``)."""
        return self.enable_symmetry(positions, rotation=False)

    def expand(self, values_at_targets: np.ndarray) -> np.ndarray:
        """Nodal vectors from their values at the target nodes: node j = S·(its
        orbit's target), components that a symmetry fixing j reverses set to 0."""
        if self.symmetry == "none":
            return values_at_targets
        return kernels.expand_symmetric(np.ascontiguousarray(values_at_targets, dtype=np.float64),
                                        self._sym_source, self._sym_signs, self._sym_zero)

    def _build_mass_pattern(self) -> None:
        """CSR pattern of the consistent mass matrix and the slot of every
        element pair (k, l) in it, so that assembly is a scatter-add."""
        ne = self.elements.shape[0]
        rows = np.repeat(self.elements, 6, axis=1).ravel()
        cols = np.tile(self.elements, (1, 6)).ravel()
        keys = rows * self.n_nodes + cols
        uniq, inverse = np.unique(keys, return_inverse=True)
        self.mass_indices = (uniq % self.n_nodes).astype(np.int64)
        urows = uniq // self.n_nodes
        self.mass_indptr = np.concatenate([[0], np.cumsum(np.bincount(urows, minlength=self.n_nodes))]).astype(np.int64)
        self.mass_slot = inverse.reshape(ne, 6, 6).astype(np.int64)
        self.mass_nnz = uniq.size

    def mass_matrix_data(self, geo: ElementGeometry, elems: np.ndarray | None = None) -> np.ndarray:
        """M's values in its CSR pattern, summed over ``elems`` (default every element;
        ``target_elements``: the rows of the target nodes are complete, the others not)."""
        elems = self.all_elements if elems is None else elems
        return kernels.assemble_mass_matrix(elems, self.mass_slot, self.reg_phi, geo.weights, self.mass_nnz)

    def mass_matrix(self, geo: ElementGeometry):
        """The mass matrix at this geometry as a SciPy CSR matrix (N_p × N_p)."""
        import scipy.sparse as sp

        return sp.csr_matrix((self.mass_matrix_data(geo), self.mass_indices, self.mass_indptr),
                             shape=(self.n_nodes, self.n_nodes))

    def geometry(self, x: np.ndarray) -> ElementGeometry:
        return element_geometry(x, self.elements, self.regular_order)

    def near_pairs(self, x: np.ndarray, geo: ElementGeometry) -> tuple[np.ndarray, np.ndarray] | None:
        """(offsets, elements) of the near-field pairs at this configuration, found
        once per geometry (the λ ≠ 1 solve applies the double layer many times)."""
        if self.near_field_factor <= 0.0:
            return None
        if self._near is None or self._near[0] is not geo:
            offsets, elems = kernels.near_field_pairs(
                np.ascontiguousarray(x), self.elements, self.inc_offsets, self.inc_elem,
                self.targets, float(self.near_field_factor),
            )
            self._near = (geo, offsets, elems)
        return self._near[1], self._near[2]

    def rest_measure(self, rest_positions: np.ndarray) -> RestMeasure:
        """The rest shape's area element at every rule point (``RestMeasure``): the weights
        of ``kernels.element_quadrature`` at the rest shape for each rule."""
        X = np.ascontiguousarray(rest_positions, dtype=np.float64)

        def weights(phi: np.ndarray, dxi: np.ndarray, deta: np.ndarray, w: np.ndarray) -> np.ndarray:
            return kernels.element_quadrature(X, self.elements, np.ascontiguousarray(phi), np.ascontiguousarray(dxi),
                                              np.ascontiguousarray(deta), np.ascontiguousarray(w))[2]

        duffy = np.stack([weights(self.sing_phi[k], self.sing_dxi[k], self.sing_deta[k], self.sing_w[k])
                          for k in range(6)], axis=1)
        fine = weights(self.fine_phi, self.fine_dxi, self.fine_deta, self.fine_w)
        return RestMeasure(np.ascontiguousarray(self.geometry(X).weights), np.ascontiguousarray(duffy), fine)

    def single_layer(self, x: np.ndarray, geo: ElementGeometry, density: np.ndarray,
                     measure: RestMeasure | None = None) -> np.ndarray:
        """∫ G·f dS at every node for a density given per element.

        density: (N_e, 3) element-constant (seed 3.7) or (N_e, 6, 3) element
        nodal values interpolated quadratically; per unit area of the surface x, or per
        unit area of the rest shape with its ``measure`` (∫ G·F dA0).
        """
        clock = self.clock
        clock.start()
        weights = geo.weights if measure is None else measure.reg_weights
        measure = self._current_measure if measure is None else measure
        if density.ndim == 2:
            nodal = np.repeat(density[:, None, :], 6, axis=1)
            point_density = np.repeat(density[:, None, :], weights.shape[1], axis=1)
            strengths = (point_density * weights[..., None]).reshape(-1, 3)
        else:
            nodal = np.ascontiguousarray(density)
            point_density, strengths = kernels.point_strengths(self.reg_phi, nodal, weights)
        nodal, point_density = np.ascontiguousarray(nodal), np.ascontiguousarray(point_density)
        clock.lap("interpolation")
        u = kernels.stokeslet_sum(x[self.targets], geo.points.reshape(-1, 3), strengths)
        clock.lap("stokeslet_sum")
        u += kernels.single_layer_singular_correction(
            x, self.elements, self.inc_offsets, self.inc_elem, self.inc_local,
            nodal, geo.points, weights, point_density, *self.duffy_by_node, self.sing_w, measure.duffy_weights,
            self.targets,
        )
        clock.lap("singular_correction")
        near = self.near_pairs(x, geo)
        if near is not None:
            u += kernels.single_layer_near_correction(
                x, self.elements, nodal, geo.points, weights, point_density,
                self.fine_phi, self.fine_dxi, self.fine_deta, self.fine_w, measure.fine_weights, self.targets,
                near[0], near[1],
            )
            clock.lap("near_correction")
        u = self.expand(u)
        clock.lap("expand")
        return u

    def noise_rayleigh_quotient(self, x: np.ndarray, geo: ElementGeometry, seed: int = 12345) -> float:
        """⟨v, SL[v]⟩/⟨v, v⟩ for white noise v (fixed seed) with the mesh's symmetry (its values
        at the symmetry's targets, expanded): the mean of the single layer's spectrum, dominated
        by the finest modes, where it acts most locally. The layer sums are evaluated at the
        targets, so for noise without the symmetry SL[v] would not be v's single layer and the
        quotient would depend on the symmetry in use (a quarter of it under quarter symmetry)."""
        v = np.random.default_rng(seed).standard_normal(x.shape)
        if self.symmetry != "none":
            v = self.expand(v[self.targets])
        sl = self.single_layer(x, geo, np.ascontiguousarray(v[self.elements]))
        return float(np.vdot(v, sl)) / float(np.vdot(v, v))

    def nodal_normals(self, x: np.ndarray) -> np.ndarray:
        """Unit normals at all nodes: mean of the element normals at each node
        (symmetric to the bit when a symmetry is in use)."""
        x = np.ascontiguousarray(x)
        if self.symmetry == "none":
            return kernels.nodal_unit_normals(x, self.elements, self.node_dxi, self.node_deta)
        # at the targets only, from the elements holding them
        return self.expand(kernels.target_unit_normals(
            x, self.elements, self.inc_offsets, self.inc_elem, self.inc_local, self.node_dxi, self.node_deta,
            self.targets))

    def flux(self, geo: ElementGeometry, u: np.ndarray, equivariant: bool = False) -> float:
        """∫ u·n dS of a nodal field u interpolated quadratically over the elements; for an
        ``equivariant`` u (the mesh's symmetry maps u as it maps positions: u·n is the same on
        every element of an orbit) over one element of each orbit, times its size (a quarter
        of the elements under quarter symmetry)."""
        elems, sizes = (self.orbit_elements, self.orbit_sizes) if equivariant else (self.all_elements, self._ones)
        return float(kernels.surface_flux(self.elements, elems, sizes, self.reg_phi, geo.normals, geo.weights,
                                          np.ascontiguousarray(u, dtype=np.float64)))

    def double_layer(self, x: np.ndarray, geo: ElementGeometry, u: np.ndarray, u_target: np.ndarray | None = None) -> np.ndarray:
        """D[u](x0) = ∫ (u − u0)·T·n dS at every node, u quadratic over elements.

        With n outward, PV∫ u·Tn dS = D[u] − 4π u0 (docs/conventions.md), so rigid-body
        motions give D = 0 and u = n on the unit sphere gives D = 8π n0.
        """
        if u_target is None:
            u_target = u
        u_pts = interpolate(self.reg_phi, u[self.elements])
        nw = geo.normals * geo.weights[..., None]
        t = self.targets
        out = kernels.double_layer_sum(
            x[t], np.ascontiguousarray(u_target[t]), geo.points.reshape(-1, 3), nw.reshape(-1, 3), u_pts.reshape(-1, 3)
        )
        out += kernels.double_layer_singular_correction(
            x, u, u_target, self.elements, self.inc_offsets, self.inc_elem, self.inc_local,
            geo.points, nw, u_pts, *self.duffy_by_node, self.sing_w, t,
        )
        near = self.near_pairs(x, geo)
        if near is not None:
            out += kernels.double_layer_near_correction(
                x, u, u_target, self.elements, geo.points, nw, u_pts,
                self.fine_phi, self.fine_dxi, self.fine_deta, self.fine_w, t, near[0], near[1],
            )
        return self.expand(out)

    def layer_matrix(self, x: np.ndarray, geo: ElementGeometry, kind: str,
                     measure: RestMeasure | None = None) -> np.ndarray:
        """The single (kind "single") or double ("double") layer as a dense
        (3N, 3N) matrix on nodal values (node-major, then component), with the
        rules of ``single_layer``/``double_layer`` (density interpolated
        quadratically; u_target = u; the single layer's density per unit rest area with
        a ``measure``): ``single_layer(x, geo, f[elements], measure).ravel()
        == S @ f.ravel()`` to round-off. Every row is computed, symmetry or not: the
        kernel evaluations of about four applications under quarter symmetry, each
        scattered into six node columns (8–13 ms at level 2, 85 ms at level 3, about
        30 and 40 applications of wall time), and 8·(3N)² bytes."""
        n = self.n_nodes
        if self.near_field_factor > 0.0:
            offsets, elems = kernels.near_field_pairs(
                np.ascontiguousarray(x), self.elements, self.inc_offsets, self.inc_elem,
                np.arange(n, dtype=np.int64), float(self.near_field_factor))
        else:
            offsets, elems = np.zeros(n + 1, dtype=np.int64), np.zeros(0, dtype=np.int64)
        nw = np.ascontiguousarray(geo.normals * geo.weights[..., None])
        double = kind == "double"
        rest = self._current_measure if measure is None or double else measure
        weights = geo.weights if measure is None or double else measure.reg_weights
        out = kernels.layer_matrix(
            np.ascontiguousarray(x), self.elements, geo.points, weights, nw, self.reg_phi,
            self.inc_offsets, self.inc_elem, self.inc_local,
            self.sing_phi, self.sing_dxi, self.sing_deta, self.sing_w,
            self.fine_phi, self.fine_dxi, self.fine_deta, self.fine_w, offsets, elems, double,
            rest.duffy_weights, rest.fine_weights)
        return out.reshape(3 * n, 3 * n)

    def flux_weights(self, geo: ElementGeometry) -> np.ndarray:
        """w (N, 3) with ``flux(geo, u) == (w * u).sum()``."""
        per_node = np.einsum("qa,eqd->ead", self.reg_phi, geo.normals * geo.weights[..., None])
        out = np.zeros((self.n_nodes, 3))
        np.add.at(out, self.elements, per_node)
        return out


COUNTERS = ("velocity_evaluations", "single_layer_applications", "double_layer_applications")


@dataclass(kw_only=True)
class CapsuleModel:
    """The right-hand side dx/dt = u(x) of one capsule in a linear flow.

    ``membrane`` turns positions into the membrane state with Δf (membrane.py);
    this model turns Δf into velocities (single layer, the λ ≠ 1 double-layer
    solve, the volume correction). Built complete by ``build_model(case)``.
    """

    disc: Discretization
    membrane: MembraneForce
    shear_rate_G: float
    viscosity_ratio: float = 1.0
    far_field: FarField = field(default_factory=FarField)
    volume_correction: bool = True
    solver_method: str = "gmres"
    solver_tol: float = 1e-8
    solver_max_iter: int = 200
    # called between the iterations of a velocity solve; raises to stop a long one
    # (the runner passes its SIGINT/SIGTERM flag's check); no signal handling here
    interrupt_check: Callable[[], None] | None = field(default=None, repr=False, compare=False)
    # y ↦ Ã⁻¹ y for an Ã near this configuration's A (λ ≠ 1), the right preconditioner of
    # the velocity solve: the dense stage preconditioner's LU of A at the start of the step
    double_layer_preconditioner: Callable[[np.ndarray], np.ndarray] | None = field(
        default=None, repr=False, compare=False)
    # the membrane's viscosity (capsim.viscosity), None for a purely elastic membrane:
    # then the velocity is a solve at every λ (viscosity.py, eq. V4)
    viscous: Any = None
    # flow.history kind stop: the kt at which the flow stops (None: steady shear); the runner
    # calls stop_flow() there, and the checkpoint says whether it has (state: "flow_stopped")
    flow_stop_time: float | None = None
    flow_stopped: bool = field(default=False, init=False)
    _flowing: FarField | None = field(default=None, init=False, repr=False)
    # iterations and relative residual of the last velocity solve (0 at λ = 1)
    last_solve_info: dict = field(default_factory=lambda: {"iterations": 0, "residual": 0.0}, init=False)
    # cumulative work: velocity evaluations and layer applications (each GMRES or
    # Richardson iteration applies the double layer once)
    counts: dict = field(default_factory=lambda: dict.fromkeys(COUNTERS, 0), init=False)
    solver_times: dict = field(default_factory=lambda: {"single_layer": 0.0, "solve": 0.0}, init=False)
    # GMRES warm start and predictor: the last solution and right-hand side
    _last_velocity: np.ndarray | None = field(default=None, init=False, repr=False)
    _last_rhs: np.ndarray | None = field(default=None, init=False, repr=False)

    def __post_init__(self):
        if self.solver_method not in SOLVER_METHODS:
            raise ValueError(f"unknown solver method {self.solver_method!r} (allowed: {SOLVER_METHODS})")
        if self.membrane.disc is not self.disc:
            raise ValueError("the membrane force and the model must share one Discretization")
        for g in SYMMETRY_GROUPS.get(self.disc.symmetry, []):
            if not self.far_field.is_invariant(g):
                raise ValueError(f"the far-field flow is not invariant under the mesh symmetry {self.disc.symmetry!r}")

    # ---- the membrane's settings, as the runner and the exporters read them
    @property
    def law(self):
        return self.membrane.law

    @property
    def law_params(self) -> dict:
        return self.membrane.law_params

    @property
    def bending(self):
        return self.membrane.bending

    @property
    def traction_method(self) -> str:
        return self.membrane.traction_method

    @property
    def rest_positions(self) -> np.ndarray:
        return self.membrane.rest_positions

    @rest_positions.setter
    def rest_positions(self, value: np.ndarray) -> None:
        self.membrane.rest_positions = value

    @property
    def stage_times(self) -> dict:
        """Seconds spent per stage so far: geometry and membrane (membrane force),
        single layer and λ ≠ 1 solve (this model). A fresh dict on every read."""
        return {**self.membrane.stage_times, **self.solver_times}

    def reset_stage_times(self) -> None:
        for times in (self.membrane.stage_times, self.solver_times):
            for k in times:
                times[k] = 0.0
        self.disc.clock.reset()

    @property
    def split_times(self) -> dict:
        """Seconds per fine stage since the last reset (``capsim.stageclock``): geometry,
        strain, mass_assembly, mass_solve, gather, interpolation, stokeslet_sum,
        singular_correction, expand, far_field, normals, volume_correction, and where
        they run near_correction, double_layer_solve, viscous_solve, contour_traction."""
        return dict(self.disc.clock.times)

    # ---- checkpoints
    #: the membrane force's warm-start entries → their names in the model state (warm_<name>)
    MEMBRANE_WARM_STARTS = {"traction": "traction", "factor_x": "mass_factor_x"}

    def state(self) -> dict[str, np.ndarray | None]:
        """All memory a bit-identical restart needs: the warm starts (GMRES solution and
        right-hand side) and the cumulative work counters. (The membrane's rest traction is
        solved directly: no warm start.)"""
        def copy(a):
            return None if a is None else np.array(a, copy=True)

        membrane = self.membrane.state()
        out: dict[str, np.ndarray | None] = {
            # the traction solve's warm start, where it has one (per unit current area: a drop)
            **{f"warm_{k}": copy(membrane[m]) for m, k in self.MEMBRANE_WARM_STARTS.items() if m in membrane},
            "warm_velocity": copy(self._last_velocity),
            "warm_rhs": copy(self._last_rhs),
            "membrane_evaluations": np.array(self.membrane.evaluations, dtype=np.int64),
        }
        out.update({k: np.array(v, dtype=np.int64) for k, v in self.counts.items()})
        if self.viscous is not None:
            out["viscous_iterations"] = np.array(self.viscous.iterations, dtype=np.int64)
            out["warm_viscous_factor_x"] = copy(self.viscous._factor_x)
            # the (x, u, rhs) of each of the last (two) solves, stacked into one (n, 3) array as the
            # checkpoint's warm starts are
            out["warm_viscous_history"] = (np.concatenate([a for h in self.viscous.history for a in h])
                                           if self.viscous.history else None)
        if self.flow_stop_time is not None:
            out["flow_stopped"] = np.array(self.flow_stopped, dtype=np.int64)
        return out

    def restore(self, state: dict) -> None:
        """Undo to a ``state()``: missing warm starts are cleared, missing counters 0. The
        membrane's warm starts (warm_traction, warm_mass_factor_x: the iterative solve per
        unit current area's) are taken and ignored by a solve per unit rest area, which
        has none (a checkpoint written before it was the elastic laws' solve)."""
        known = {"warm_traction", "warm_mass_factor_x", "warm_velocity", "warm_rhs", "membrane_evaluations",
                 *COUNTERS}
        if self.viscous is not None:
            known |= {"viscous_iterations", "warm_viscous_factor_x", "warm_viscous_history"}
        if self.flow_stop_time is not None:
            known.add("flow_stopped")
        unknown = set(state) - known
        if unknown:
            raise ValueError(f"unknown model state entries {sorted(unknown)}")

        def copy(key):
            a = state.get(key)
            return None if a is None else np.array(a, dtype=np.float64, copy=True)

        self.membrane.restore({**{m: copy(f"warm_{k}") for m, k in self.MEMBRANE_WARM_STARTS.items()},
                               "evaluations": state.get("membrane_evaluations", 0)})
        self._last_velocity = copy("warm_velocity")
        self._last_rhs = copy("warm_rhs")
        self.counts = {k: int(state.get(k, 0)) for k in COUNTERS}
        if self.viscous is not None:
            self.viscous.iterations = int(state.get("viscous_iterations", 0))
            history = copy("warm_viscous_history")
            self.viscous.history = ([] if history is None else
                                    [tuple(h) for h in history.reshape(-1, 3, self.disc.n_nodes, 3)])
            self.viscous._factor_x = copy("warm_viscous_factor_x")
            self.viscous._rest_factor = None  # rebuilt where the checkpoint says, at the next solve
        if state.get("flow_stopped"):
            self.stop_flow()
        elif self.flow_stopped:  # undone to a state before the stop
            self.far_field, self.flow_stopped = self._flowing, False

    def stop_flow(self) -> None:
        """No undisturbed flow from now on (flow.history kind stop): u∞ = 0."""
        if not self.flow_stopped:
            self._flowing = self.far_field
        self.far_field = FarField(((0.0,) * 3,) * 3)
        self.flow_stopped = True

    def velocity(self, x: np.ndarray, state: MembraneState | None = None) -> np.ndarray:
        """Nodal velocities (N_p, 3) at configuration x.

        With the desingularised double layer the equation of docs/conventions.md becomes

            u = u∞ − SL[Δf]/(8πG) + (1−λ)/(8π) D[u],   D[u] = ∫ (u − u0)·T·n dS,

        explicit at λ = 1. For λ ≠ 1 the operator A = I − (1−λ)/(8π) D has
        eigenvalue 1 on rigid motions and λ on the volume-changing normal mode;
        the latter is deflated (Pozrikidis 1992, §6) by adding (1−λ) n ⟨n, u⟩/S,
        which vanishes on every volume-preserving velocity, so that the spectrum
        lies between 1 and λ and both λ → 0 and λ → ∞ stay well posed.
        """
        if state is None:
            state = self.membrane(x)
        self.counts["velocity_evaluations"] += 1
        lam = self.viscosity_ratio
        t0 = time.perf_counter()
        sl = self.disc.single_layer(x, state.geometry, state.density, state.measure)
        self.counts["single_layer_applications"] += 1
        t1 = time.perf_counter()
        self.solver_times["single_layer"] += t1 - t0
        clock = self.disc.clock
        u_explicit = self.far_field(x) - sl / (8.0 * np.pi * self.shear_rate_G)
        clock.lap("far_field")
        needs_normals = lam != 1.0 or self.volume_correction
        normals = self.disc.nodal_normals(x) if needs_normals else None
        clock.lap("normals")
        if self.viscous is not None:
            u = self.viscous.solve(self, x, state.geometry, u_explicit, normals)
            self.solver_times["solve"] += time.perf_counter() - t1
            clock.lap("viscous_solve")
            info = self.last_solve_info
            if not info["residual"] <= 10.0 * self.solver_tol:
                raise SolverDivergence(
                    f"viscous membrane velocity solve did not converge: residual {info['residual']:.2e} > tol "
                    f"{self.solver_tol:.1e} after {info['iterations']} iterations "
                    f"(membrane.viscosity.shear = {self.viscous.shear:g})")
        elif lam == 1.0:
            self.last_solve_info = {"iterations": 0, "residual": 0.0}
            u = u_explicit
        else:
            u = self._solve_double_layer(x, state.geometry, u_explicit, normals)
            if self.disc.symmetry != "none":
                # GMRES's dense products (BLAS) need not treat mirror rows alike:
                # keep the solution, and so the positions, exactly symmetric
                u = self.disc.expand(u[self.disc.targets])
            self.solver_times["solve"] += time.perf_counter() - t1
            clock.lap("double_layer_solve")
        if self.volume_correction:
            # The exact velocity conserves volume; the discretised single layer
            # does so only to its quadrature error, which a stiff membrane
            # (small G) amplifies by 1/G, and a slowly deflating capsule gains
            # excess area and deforms without stretching: remove the net flux
            # with a uniform normal velocity.
            # (u and the nodal normals are expanded from the targets: equivariant)
            u = self.remove_net_flux(state.geometry, u, normals, equivariant=True)
            clock.lap("volume_correction")
        return u

    def remove_net_flux(self, geo: ElementGeometry, u: np.ndarray, normals: np.ndarray,
                        normal_flux: float | None = None, equivariant: bool = False) -> np.ndarray:
        """The volume correction P: u − n ⟨n, u⟩/⟨n, n⟩ (fluxes over the surface);
        ``normal_flux``, ⟨n, n⟩, when the caller applies P many times at one configuration;
        ``equivariant``: u and the normals have the mesh's symmetry (``Discretization.flux``)."""
        if normal_flux is None:
            normal_flux = self.disc.flux(geo, normals, equivariant)
        return u - (self.disc.flux(geo, u, equivariant) / normal_flux) * normals

    def double_layer_operator(self, x: np.ndarray, geo: ElementGeometry, normals: np.ndarray):
        """u ↦ A u = u − (1−λ)/(8π) D[u] + (1−λ) n ⟨n, u⟩/S at configuration x,
        the deflated operator of the λ ≠ 1 equation (``velocity``); each call counts
        one double-layer application."""
        lam = self.viscosity_ratio
        disc = self.disc
        c = (1.0 - lam) / (8.0 * np.pi)
        area = geo.weights.sum()
        counts = self.counts

        def apply(u):
            counts["double_layer_applications"] += 1
            return u - c * disc.double_layer(x, geo, u) + (1.0 - lam) * normals * (disc.flux(geo, u) / area)

        return apply

    def _solve_double_layer(
        self, x: np.ndarray, geo: ElementGeometry, rhs: np.ndarray, normals: np.ndarray
    ) -> np.ndarray:
        lam = self.viscosity_ratio
        apply = self.double_layer_operator(x, geo, normals)
        if self._last_velocity is not None and self._last_velocity.shape == rhs.shape:
            guess = self._last_velocity
            if self._last_rhs is not None and self._last_rhs.shape == rhs.shape:
                # the operator's spectrum lies in [min(1, λ), max(1, λ)]: carry the change
                # of the right-hand side over with the Richardson step 2/(1+λ)
                guess = guess + (2.0 / (1.0 + lam)) * (rhs - self._last_rhs)
        else:
            guess = rhs
        self._last_rhs = rhs
        b = rhs.ravel()
        bnorm = max(float(np.linalg.norm(b)), 1e-300)
        u = guess.copy()
        r = rhs - apply(u)
        residual = float(np.linalg.norm(r)) / bnorm
        iterations = 0
        check = self.interrupt_check or (lambda: None)
        if residual > self.solver_tol and self.solver_method == "gmres":
            # the correction A·δ = r from δ = 0: the residual GMRES reports is the true
            # one of u + δ (right preconditioning, capsim.krylov)
            restart = min(60, self.solver_max_iter)
            delta, iterations, rnorm = gmres(
                lambda v: apply(v.reshape(-1, 3)).ravel(), r.ravel(), self.solver_tol * bnorm,
                precondition=self.double_layer_preconditioner, max_iter=self.solver_max_iter * restart,
                restart=restart, callback=check)
            u = u + delta.reshape(-1, 3)
            residual = rnorm / bnorm
        elif residual > self.solver_tol:
            # successive substitution (seed §3) as Richardson iteration with the
            # optimal step for a spectrum in [min(1, λ), max(1, λ)]: rate |1−λ|/(1+λ)
            omega = 2.0 / (1.0 + lam)
            while residual > self.solver_tol and iterations < self.solver_max_iter:
                u = u + omega * r
                r = rhs - apply(u)
                residual = float(np.linalg.norm(r)) / bnorm
                iterations += 1
                check()
        self.last_solve_info = {"iterations": int(iterations), "residual": residual}
        if not residual <= 10.0 * self.solver_tol:
            raise SolverDivergence(
                f"velocity solve did not converge: residual {residual:.2e} > tol {self.solver_tol:.1e} "
                f"after {iterations} iterations ({self.solver_method}, viscosity_ratio = {lam:g})"
            )
        self._last_velocity = u
        return u


SOLVER_METHODS = ("gmres", "substitution")


class SolverDivergence(RuntimeError):
    """The λ ≠ 1 velocity solve missed its tolerance."""


def build_model(case: Case, rest_positions: np.ndarray | None = None, *,
                symmetry: str | None = None) -> tuple[CapsuleModel, np.ndarray]:
    """The complete right-hand side of a case; returns (model, rest positions).

    The mesh of the rest shape, its discretisation with the symmetries it has
    (``mesh.symmetry``: the mirror z → −z and the rotation by π about z, which
    simple shear and every tilted rest shape share; the positions are made
    exactly symmetric), the membrane force and the flow. ``rest_positions``
    replaces the rebuilt rest shape (a stored one, e.g. for an export; same mesh).
    ``symmetry`` (a key of SYMMETRY_CANDIDATES) replaces mesh.symmetry: "mirror_z",
    the mirror alone, is no case setting but the benchmark measures it.
    """
    mode = case.mesh.symmetry if symmetry is None else symmetry
    if mode not in SYMMETRY_CANDIDATES:
        raise ValueError(f"symmetry = {mode!r}: must be one of {', '.join(SYMMETRY_CANDIDATES)}")
    mesh = rest_shape_mesh(
        case.shape.kind, case.mesh.base, case.mesh.level, case.initial_tilt_deg, axis=case.initial_axis,
        aspect_ratio=case.shape.aspect_ratio, c0=case.shape.c0, c2=case.shape.c2, c4=case.shape.c4,
    )
    disc = Discretization(
        mesh.elements, mesh.n_vertices,
        regular_order=case.quadrature.regular_order,
        singular_order=case.quadrature.singular_order,
        near_field_factor=case.quadrature.near_field_factor,
        near_field_levels=case.quadrature.near_field_levels,
    )
    positions = mesh.positions
    if mode != "none":
        symmetric = disc.enable_symmetry(positions, mode=mode)
        if symmetric is not None:
            positions = symmetric
        elif mode != "auto":
            raise ValueError(f"mesh.symmetry = {mode}: the mesh of this rest shape does not have it")
    rest = positions if rest_positions is None else np.asarray(rest_positions, dtype=np.float64)
    if rest.shape != positions.shape:
        raise ValueError(f"rest positions of shape {rest.shape} for a mesh of {positions.shape[0]} nodes")
    law = get_law(case.membrane.law)
    forces = MembraneForce(
        disc, rest, law, {p: getattr(case.membrane, p) for p in law.parameters},
        bending_modulus=case.membrane.bending_modulus,
        traction_method=case.membrane.traction,
    )
    viscosity = case.membrane.viscosity
    viscous = build_viscous(disc, rest, None if viscosity is None else viscosity.model_dump())
    model = CapsuleModel(
        disc=disc,
        membrane=forces,
        shear_rate_G=case.flow.shear_rate_G,
        viscosity_ratio=case.flow.viscosity_ratio,
        volume_correction=case.solver.volume_correction,
        solver_method=case.solver.method,
        solver_tol=case.solver.tol,
        solver_max_iter=case.solver.max_iter,
        viscous=viscous,
        flow_stop_time=case.flow.stop_time,
    )
    return model, rest
