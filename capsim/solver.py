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

import numpy as np

from capsim import kernels
from capsim.geometry import ElementGeometry, element_geometry, shape_functions
from capsim.membrane import MembraneLaw, VertexStrain, get_law, strain_from_gradient, tension_tensor
from capsim.mesh import node_element_incidence
from capsim.quadrature import NODE_XI, NODE_ETA, gauss_legendre_01, singular_rules, triangle_rule


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
    singular_order: int = 3
    contour_order: int = 4
    membrane_order: int = 6

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
        mxi, meta, mw = triangle_rule(self.membrane_order)
        mphi, mdxi, mdeta = shape_functions(mxi, meta)
        self.mem_phi, self.mem_dxi, self.mem_deta, self.mem_w = mphi, mdxi, mdeta, mw
        self._build_mass_pattern()

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
            point_density = np.einsum("qk,ekd->eqd", self.reg_phi, density)
        strengths = (point_density * geo.weights[..., None]).reshape(-1, 3)
        u = kernels.stokeslet_sum(x, geo.points.reshape(-1, 3), strengths)
        u += kernels.single_layer_singular_correction(
            x, self.elements, self.inc_offsets, self.inc_elem, self.inc_local,
            np.ascontiguousarray(nodal), geo.points, geo.weights, self.reg_phi,
            self.sing_phi, self.sing_dxi, self.sing_deta, self.sing_w,
        )
        return u


@dataclass
class MembraneState:
    """Everything the membrane step produced at one configuration."""

    strain: VertexStrain
    tension: np.ndarray     # (N_v, 3, 3) at the vertex nodes
    traction: np.ndarray    # Δf: (N_p, 3) nodal (galerkin) or (N_e, 3) element-averaged (contour)
    geometry: ElementGeometry
    density: np.ndarray     # Δf as the single layer takes it: (N_e, 6, 3) or (N_e, 3)
    mass_iterations: int = 0


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
    mass_tol: float = 1e-10
    stage_times: dict = field(default_factory=lambda: {"geometry": 0.0, "membrane": 0.0, "single_layer": 0.0, "solve": 0.0})
    _last_traction: np.ndarray | None = field(default=None, repr=False)
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
        A, n_cur, _ = kernels.vertex_deformation_gradient(
            x, self.rest_positions, disc.elements, disc.n_vertices, disc.vertex_dxi, disc.vertex_deta,
        )
        strain = strain_from_gradient(A, n_cur)
        tension = tension_tensor(strain, self.law, self.law_params)
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
            data = disc.mass_matrix_data(geo)
            guess = self._last_traction if self._last_traction is not None else np.zeros_like(rhs)
            traction, iterations = kernels.block_cg(
                disc.mass_indptr, disc.mass_indices, data, rhs, guess, self.mass_tol, 500,
            )
            self._last_traction = traction
            density = np.ascontiguousarray(traction[disc.elements])
        elif self.traction_method == "contour":
            traction = kernels.element_tractions(
                x, disc.elements, np.ascontiguousarray(tension), disc.contour_s, disc.contour_w, geo.element_areas,
            )
            density = traction
        else:
            raise ValueError(f"unknown traction method {self.traction_method!r} (allowed: {TRACTION_METHODS})")
        t2 = time.perf_counter()
        self.stage_times["geometry"] += t1 - t0
        self.stage_times["membrane"] += t2 - t1
        return MembraneState(strain, tension, traction, geo, density, iterations)

    def velocity(self, x: np.ndarray, state: MembraneState | None = None) -> np.ndarray:
        """Nodal velocities (N_p, 3) at configuration x."""
        if state is None:
            state = self.membrane(x)
        lam = self.viscosity_ratio
        t0 = time.perf_counter()
        sl = self.disc.single_layer(x, state.geometry, state.density)
        t1 = time.perf_counter()
        self.stage_times["single_layer"] += t1 - t0
        rhs = 2.0 / (1.0 + lam) * shear_flow(x) - sl / (4.0 * np.pi * (1.0 + lam) * self.shear_rate_G)
        if lam == 1.0:
            return rhs
        raise NotImplementedError("viscosity_ratio != 1 needs the double layer (issue 3)")
