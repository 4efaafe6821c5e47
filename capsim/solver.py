"""Velocity of the membrane nodes: tensions → tractions → boundary integrals.

Pure orchestration: the loops are in ``kernels.py``. In units of a, 1/k, ka and
E_s the boundary-integral equation (seed 2.11; design.md) reads

    u(x0) = 2/(1+λ) u∞(x0) − 1/(4π(1+λ) G) ∫ Δf·G dS + (1−λ)/(4π(1+λ)) PV∫ u·Tn dS

with u∞ = (y, 0, 0) and G = μka/E_s; at λ = 1 the double layer vanishes and the
velocity is explicit.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Callable

import numpy as np

from capsim import kernels
from capsim.geometry import ElementGeometry, element_geometry, interpolate, shape_functions
from capsim.membrane import MembraneLaw, VertexStrain, get_law, strain_from_gradient, tension_tensor
from capsim.mesh import node_element_incidence
from capsim.quadrature import NODE_XI, NODE_ETA, gauss_legendre_01, singular_rules, subdivided_rule, triangle_rule


def shear_flow(x: np.ndarray) -> np.ndarray:
    """Undisturbed simple shear u∞ = (y, 0, 0) in units of ka."""
    u = np.zeros_like(x)
    u[:, 0] = x[:, 1]
    return u


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
        self.mirror: np.ndarray | None = None
        fxi, feta, fw = subdivided_rule(self.regular_order, self.near_field_levels)
        fphi, fdxi, fdeta = shape_functions(fxi, feta)
        self.fine_phi, self.fine_dxi, self.fine_deta = (np.ascontiguousarray(a) for a in (fphi, fdxi, fdeta))
        self.fine_w = np.ascontiguousarray(fw)
        self._near: tuple | None = None  # (geometry, offsets, elements) of the last configuration

    def enable_mirror_symmetry(self, positions: np.ndarray) -> np.ndarray | None:
        """Use the symmetry of the problem about the plane z = 0.

        Shear flow (y, 0, 0) and every rest shape here (tilted about z) are
        mirror-symmetric in z, so the velocities of the nodes with z < 0 follow
        from those with z > 0: the boundary integrals are evaluated at about half
        the nodes (the seed used this symmetry too). Returns the positions made
        exactly symmetric, or None (and nothing changes) if the mesh has no
        mirror image of every node.
        """
        from scipy.spatial import cKDTree

        reflected = positions * np.array([1.0, 1.0, -1.0])
        dist, mirror = cKDTree(positions).query(reflected)
        scale = np.abs(positions).max()
        if dist.max() > 1e-9 * scale or np.any(mirror[mirror] != np.arange(len(mirror))):
            return None
        self.mirror = mirror.astype(np.int64)
        self.targets = np.flatnonzero(np.arange(len(mirror)) <= mirror).astype(np.int64)
        self._self_mirror = np.flatnonzero(mirror == np.arange(len(mirror)))
        sym = positions.copy()
        sym[self.mirror[self.targets]] = positions[self.targets] * np.array([1.0, 1.0, -1.0])
        sym[self._self_mirror, 2] = 0.0
        return sym

    def expand(self, values_at_targets: np.ndarray) -> np.ndarray:
        """Nodal vectors from their values at the target nodes (mirror in z)."""
        if self.mirror is None:
            return values_at_targets
        out = np.empty((self.n_nodes, 3))
        out[self.mirror[self.targets]] = values_at_targets * np.array([1.0, 1.0, -1.0])
        out[self.targets] = values_at_targets
        out[self._self_mirror, 2] = 0.0
        return out

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

    def mass_matrix_data(self, geo: ElementGeometry) -> np.ndarray:
        return kernels.assemble_mass_matrix(self.elements, self.mass_slot, self.reg_phi, geo.weights, self.mass_nnz)

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

    def single_layer(self, x: np.ndarray, geo: ElementGeometry, density: np.ndarray) -> np.ndarray:
        """∫ G·f dS at every node for a density given per element.

        density: (N_e, 3) element-constant (seed 3.7) or (N_e, 6, 3) element
        nodal values interpolated quadratically.
        """
        if density.ndim == 2:
            nodal = np.repeat(density[:, None, :], 6, axis=1)
            point_density = np.repeat(density[:, None, :], geo.weights.shape[1], axis=1)
        else:
            nodal = density
            point_density = interpolate(self.reg_phi, density)
        nodal, point_density = np.ascontiguousarray(nodal), np.ascontiguousarray(point_density)
        strengths = (point_density * geo.weights[..., None]).reshape(-1, 3)
        u = kernels.stokeslet_sum(x[self.targets], geo.points.reshape(-1, 3), strengths)
        u += kernels.single_layer_singular_correction(
            x, self.elements, self.inc_offsets, self.inc_elem, self.inc_local,
            nodal, geo.points, geo.weights, point_density,
            self.sing_phi, self.sing_dxi, self.sing_deta, self.sing_w, self.targets,
        )
        near = self.near_pairs(x, geo)
        if near is not None:
            u += kernels.single_layer_near_correction(
                x, self.elements, nodal, geo.points, geo.weights, point_density,
                self.fine_phi, self.fine_dxi, self.fine_deta, self.fine_w, self.targets, near[0], near[1],
            )
        return self.expand(u)


    def nodal_normals(self, x: np.ndarray) -> np.ndarray:
        """Unit normals at all nodes: mean of the element normals at each node
        (mirror-symmetric to the bit when the symmetry is in use)."""
        n = kernels.nodal_unit_normals(np.ascontiguousarray(x), self.elements, self.node_dxi, self.node_deta)
        return n if self.mirror is None else self.expand(n[self.targets])

    def flux(self, geo: ElementGeometry, u: np.ndarray) -> float:
        """∫ u·n dS of a nodal field u interpolated quadratically over the elements."""
        n_q = geo.normals * geo.weights[..., None]
        return float((interpolate(self.reg_phi, u[self.elements]) * n_q).sum())

    def double_layer(self, x: np.ndarray, geo: ElementGeometry, u: np.ndarray, u_target: np.ndarray | None = None) -> np.ndarray:
        """D[u](x0) = ∫ (u − u0)·T·n dS at every node, u quadratic over elements.

        With n outward, PV∫ u·Tn dS = D[u] − 4π u0 (design.md), so rigid-body
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
            geo.points, nw, u_pts, self.sing_phi, self.sing_dxi, self.sing_deta, self.sing_w, t,
        )
        near = self.near_pairs(x, geo)
        if near is not None:
            out += kernels.double_layer_near_correction(
                x, u, u_target, self.elements, geo.points, nw, u_pts,
                self.fine_phi, self.fine_dxi, self.fine_deta, self.fine_w, t, near[0], near[1],
            )
        return self.expand(out)


@dataclass
class MembraneState:
    """Everything the membrane step produced at one configuration.

    The vertex strain and tension are computed on first use: the Galerkin
    traction does not need them, so the three evaluations of an RKF23 step skip
    them and only the recorded (accepted) states pay for them.
    """

    traction: np.ndarray    # Δf: (N_p, 3) nodal (galerkin) or (N_e, 3) element-averaged (contour)
    geometry: ElementGeometry
    density: np.ndarray     # Δf as the single layer takes it: (N_e, 6, 3) or (N_e, 3)
    vertex_state: Callable[[], tuple[VertexStrain, np.ndarray]] = field(repr=False)
    mass_iterations: int = 0

    @cached_property
    def _vertex(self) -> tuple[VertexStrain, np.ndarray]:
        return self.vertex_state()

    @property
    def strain(self) -> VertexStrain:
        return self._vertex[0]

    @property
    def tension(self) -> np.ndarray:
        """(N_v, 3, 3) Cauchy tension at the vertex nodes (seed 2.7)."""
        return self._vertex[1]


TRACTION_METHODS = ("galerkin", "contour")


@dataclass
class CapsuleModel:
    """The right-hand side dx/dt = u(x) of one capsule in shear flow."""

    disc: Discretization
    rest_positions: np.ndarray
    shear_rate_G: float
    viscosity_ratio: float = 1.0
    law: MembraneLaw = field(default_factory=lambda: get_law("thin_shell"))
    law_params: dict = field(default_factory=dict)
    traction_method: str = "galerkin"
    mass_tol: float = 1e-8
    stage_times: dict = field(default_factory=lambda: {"geometry": 0.0, "membrane": 0.0, "single_layer": 0.0, "solve": 0.0})
    _last_traction: np.ndarray | None = field(default=None, repr=False)
    volume_correction: bool = True
    solver_method: str = "gmres"
    solver_tol: float = 1e-8
    solver_max_iter: int = 200
    # bending resistance (membrane.HingeBending), added to the Galerkin energy gradient
    bending: Any = None
    _last_velocity: np.ndarray | None = field(default=None, repr=False)
    _last_rhs: np.ndarray | None = field(default=None, repr=False)
    # iterations and relative residual of the last velocity solve (0 at λ = 1)
    last_solve_info: dict = field(default_factory=lambda: {"iterations": 0, "residual": 0.0})

    def membrane(self, x: np.ndarray) -> MembraneState:
        """Tensions and the traction jump Δf at configuration x.

        galerkin: Δf is the quadratic field whose moments against every basis
        function equal the energy gradient, M·Δf = ∂E/∂x with E = ∫ W dA_0
        (principle of virtual work; every node, mid-edge nodes included, is
        elastically restrained). contour: the seed's element average (3.6),
        −(1/S_e)∮ T·b dl from vertex tensions, used element-constant (3.7).
        """
        t0 = time.perf_counter()
        disc = self.disc
        geo = disc.geometry(x)
        t1 = time.perf_counter()
        def vertex_state() -> tuple[VertexStrain, np.ndarray]:
            A, n_cur, _ = kernels.vertex_deformation_gradient(
                x, self.rest_positions, disc.elements, disc.n_vertices, disc.vertex_dxi, disc.vertex_deta,
            )
            strain = strain_from_gradient(A, n_cur)
            return strain, tension_tensor(strain, self.law, self.law_params)

        iterations = 0
        if self.traction_method == "galerkin":
            inv1, inv2, dual_cur, dual_ref, jac0 = kernels.gauss_point_strain(
                x, self.rest_positions, disc.elements, disc.mem_dxi, disc.mem_deta,
            )
            w1, w2 = self.law.derivatives(inv1, inv2, **self.law_params)
            rhs = kernels.galerkin_energy_gradient(
                disc.elements, disc.n_nodes, disc.mem_dxi, disc.mem_deta, disc.mem_w,
                jac0, np.ascontiguousarray(w1), np.ascontiguousarray(w2), dual_cur, dual_ref,
            )
            if self.bending is not None:
                rhs = rhs + self.bending.energy_gradient(x)[1]
            data = disc.mass_matrix_data(geo)
            guess = self._last_traction if self._last_traction is not None else np.zeros_like(rhs)
            traction, iterations = kernels.block_cg(
                disc.mass_indptr, disc.mass_indices, data, rhs, guess, self.mass_tol, 500,
            )
            self._last_traction = traction
            density = np.ascontiguousarray(traction[disc.elements])
        elif self.traction_method == "contour":
            state = MembraneState(np.empty(0), geo, np.empty(0), vertex_state)
            traction = kernels.element_tractions(
                x, disc.elements, np.ascontiguousarray(state.tension), disc.contour_s, disc.contour_w, geo.element_areas,
            )
            state.traction = state.density = traction
            self.stage_times["geometry"] += t1 - t0
            self.stage_times["membrane"] += time.perf_counter() - t1
            return state
        else:
            raise ValueError(f"unknown traction method {self.traction_method!r} (allowed: {TRACTION_METHODS})")
        t2 = time.perf_counter()
        self.stage_times["geometry"] += t1 - t0
        self.stage_times["membrane"] += t2 - t1
        return MembraneState(traction, geo, density, vertex_state, iterations)

    def velocity(self, x: np.ndarray, state: MembraneState | None = None) -> np.ndarray:
        """Nodal velocities (N_p, 3) at configuration x.

        With the desingularised double layer the equation of design.md becomes

            u = u∞ − SL[Δf]/(8πG) + (1−λ)/(8π) D[u],   D[u] = ∫ (u − u0)·T·n dS,

        explicit at λ = 1. For λ ≠ 1 the operator A = I − (1−λ)/(8π) D has
        eigenvalue 1 on rigid motions and λ on the volume-changing normal mode;
        the latter is deflated (Pozrikidis 1992, §6) by adding (1−λ) n ⟨n, u⟩/S,
        which vanishes on every volume-preserving velocity, so that the spectrum
        lies between 1 and λ and both λ → 0 and λ → ∞ stay well posed.
        """
        if state is None:
            state = self.membrane(x)
        lam = self.viscosity_ratio
        t0 = time.perf_counter()
        sl = self.disc.single_layer(x, state.geometry, state.density)
        t1 = time.perf_counter()
        self.stage_times["single_layer"] += t1 - t0
        u_explicit = shear_flow(x) - sl / (8.0 * np.pi * self.shear_rate_G)
        needs_normals = lam != 1.0 or self.volume_correction
        normals = self.disc.nodal_normals(x) if needs_normals else None
        if lam == 1.0:
            self.last_solve_info = {"iterations": 0, "residual": 0.0}
            u = u_explicit
        else:
            u = self._solve_double_layer(x, state.geometry, u_explicit, normals)
            self.stage_times["solve"] += time.perf_counter() - t1
        if self.volume_correction:
            # The exact velocity conserves volume; the discretised single layer
            # does so only to its quadrature error, which a stiff membrane
            # (small G) amplifies by 1/G, and a slowly deflating capsule gains
            # excess area and deforms without stretching: remove the net flux
            # with a uniform normal velocity.
            geo = state.geometry
            u = u - (self.disc.flux(geo, u) / self.disc.flux(geo, normals)) * normals
        return u

    def _solve_double_layer(
        self, x: np.ndarray, geo: ElementGeometry, rhs: np.ndarray, normals: np.ndarray
    ) -> np.ndarray:
        lam = self.viscosity_ratio
        disc = self.disc
        c = (1.0 - lam) / (8.0 * np.pi)
        area = geo.weights.sum()

        def apply(u):
            return u - c * disc.double_layer(x, geo, u) + (1.0 - lam) * normals * (disc.flux(geo, u) / area)

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
        if residual > self.solver_tol and self.solver_method == "gmres":
            from scipy.sparse.linalg import LinearOperator, gmres

            # solve for the correction A·δ = r from δ = 0: GMRES's own residual
            # history is then the true relative residual of u + δ
            n = b.size
            op = LinearOperator((n, n), matvec=lambda v: apply(v.reshape(-1, 3)).ravel(), dtype=float)
            history: list[float] = []
            rnorm = residual * bnorm
            delta, _ = gmres(
                op, r.ravel(), rtol=self.solver_tol * bnorm / rnorm, atol=0.0,
                restart=min(60, self.solver_max_iter), maxiter=self.solver_max_iter,
                callback=lambda pr: history.append(float(pr)), callback_type="pr_norm",
            )
            u = u + delta.reshape(-1, 3)
            iterations = len(history)
            if history:
                residual = history[-1] * rnorm / bnorm
        elif residual > self.solver_tol:
            # successive substitution (seed §3) as Richardson iteration with the
            # optimal step for a spectrum in [min(1, λ), max(1, λ)]: rate |1−λ|/(1+λ)
            omega = 2.0 / (1.0 + lam)
            while residual > self.solver_tol and iterations < self.solver_max_iter:
                u = u + omega * r
                r = rhs - apply(u)
                residual = float(np.linalg.norm(r)) / bnorm
                iterations += 1
        self.last_solve_info = {"iterations": int(iterations), "residual": residual}
        if not residual <= 10.0 * self.solver_tol:
            raise SolverDivergence(
                f"velocity solve did not converge: residual {residual:.2e} > tol {self.solver_tol:.1e} "
                f"after {iterations} iterations ({self.solver_method}, viscosity_ratio = {lam:g})"
            )
        self._last_velocity = u
        return u


class SolverDivergence(RuntimeError):
    """The λ ≠ 1 velocity solve missed its tolerance."""
