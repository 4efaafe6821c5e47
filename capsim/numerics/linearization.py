"""The stage solve of the linearly implicit scheme: (I − γh J) k = r, matrix-free.

J approximates ∂u/∂x at the start of a step, x_n, with every layer operator and
the volume correction frozen there (the Rosenbrock-W idea: ROS2 is second
order for any J, so the geometric dependence of the layers, which is not
stiff, may be left out). The stiffness is the membrane's: with the velocity of
``CapsuleModel.velocity``,

    u = P A⁻¹ b(x),   b = u∞ − SL[F]/(8πG),   M0·F = ∂E/∂x,

(A = I at λ = 1, else the deflated double-layer operator; P the volume
correction u ↦ u − n ⟨n, u⟩/⟨n, n⟩, identity when it is off) the frozen
Jacobian is J = P A⁻¹ B' with

    B' v = L∞ v − SL[M⁻¹ H v]/(8πG),

H v the change of the energy gradient ∂E/∂x along v (the sparse Hessian of
``MembraneForce.energy_gradient`` built at x_n, or, when the preconditioner's
Hessian is older than the step, a forward difference of the gradient: J is
always the step's own; bending included; the contour method differentiates
its element tractions instead), F the force per unit rest area, integrated over
the rest shape's measure, and M0 the rest shape's mass matrix (constant:
``membrane.MembraneForce``; for a clean drop, whose traction is solved per unit
current area, Δf and M(x_n) in their place).

λ = 1: GMRES solves the stage equation itself, (I − γh P B') k = r, whose
right-hand side needs no product. λ ≠ 1 does not nest a double-layer solve in
every product: with k = r + γh P z the stage equation becomes one system for z,

    (A − γh B' P) z = B' r,

whose products cost one single-layer and one double-layer application. GMRES
(``capsim.numerics.krylov``) is right-preconditioned, so the residual it reports is the
true one, and spends a product on nothing else.

Preconditioner ``local``: the membrane operator exactly, the single layer as a
local drag, SL[w] ≈ s w. Then the stage operator ≈ I + τ M⁻¹H, τ = γ h s/(8πG),
applied as (M + τH)⁻¹ M with H assembled by coloured finite differences of the
energy gradient (Curtis, Powell & Reid 1974: nodes coupled through no common
element share a colour) and factorised by a sparse LU. s is DRAG_FRACTION of the
single layer's Rayleigh quotient on white noise with the mesh's symmetry (which the
finest modes dominate, where the local approximation is best): one single-layer
application per build.

Preconditioner ``dense``: the stage operator from the dense layer matrices
(``Discretization.layer_matrix``), LU-factorised (``_dense_operators``): at
λ = 1 the membrane and single layer exactly, by the push-through identity, and
the flow term by one Neumann step; at λ ≠ 1 the z system whole, and A's LU
then also preconditions the velocity solves. ``none``: plain GMRES (the
baseline the others are measured against).

Both are rebuilt every ``refresh_steps`` steps and refactorised when γh has
moved by more than ``TAU_SLACK``; in between they are applied in the frame of
the best-fit rotation from the nodes where they were built (tank-treading turns
the membrane through them while the shape stays).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from capsim.numerics.geometry import best_rotation  # noqa: F401 (used here, and re-exported: the viscous solve shares it)
from capsim.numerics.krylov import LinearSolveFailed, gmres

__all__ = ["PRECONDITIONERS", "StageSolver", "LinearSolveFailed", "hessian_colouring"]

#: stage-solve preconditioners (the schema's choices)
PRECONDITIONERS = ("local", "dense", "none")

# forward-difference step relative to max(1, |x|): √ε_machine (Brown & Saad 1990)
_FD_SCALE = 1.5e-8


def node_adjacency(n_nodes: int, groups: list[np.ndarray]) -> sp.csr_matrix:
    """Boolean node–node matrix: i ~ j when some row of a group array holds both."""
    rows, cols = [], []
    for g in groups:
        g = np.asarray(g, dtype=np.int64)
        m = g.shape[1]
        rows.append(np.repeat(g, m, axis=1).ravel())
        cols.append(np.tile(g, (1, m)).ravel())
    r, c = np.concatenate(rows), np.concatenate(cols)
    a = sp.csr_matrix((np.ones(r.size, dtype=np.int8), (r, c)), shape=(n_nodes, n_nodes))
    a.data[:] = 1
    return a


def hessian_colouring(adjacency: sp.csr_matrix) -> np.ndarray:
    """Greedy distance-2 colouring: nodes of one colour have no neighbour in common,
    so one difference of the gradient per colour and component recovers their
    columns of the Hessian without overlap (Curtis, Powell & Reid 1974)."""
    conflict = (adjacency @ adjacency).tocsr()
    n = adjacency.shape[0]
    colour = np.full(n, -1, dtype=np.int64)
    indptr, indices = conflict.indptr, conflict.indices
    for i in range(n):
        used = set(colour[indices[indptr[i]:indptr[i + 1]]].tolist())
        c = 0
        while c in used:
            c += 1
        colour[i] = c
    return colour


def _directional_difference(f, x: np.ndarray, fx: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(f(x + εv) − f(x))/ε with ε = √ε_machine · max(1, |x|)/|v| (Brown & Saad 1990)."""
    norm = float(np.linalg.norm(v))
    if norm == 0.0:
        return np.zeros_like(fx)
    eps = _FD_SCALE * max(1.0, float(np.linalg.norm(x))) / norm
    return (f(x + eps * v) - fx) / eps


@dataclass
class _Frozen:
    """Everything frozen at x_n for the step."""

    x: np.ndarray
    geo: Any
    normals: np.ndarray | None
    normal_flux: float | None    # ⟨n, n⟩ of the volume correction P (applied at every product)
    mass: sp.csr_matrix | None   # the traction solve's scalar mass matrix (galerkin: M0, or M(x_n) for a
                                 # drop), applied per component
    mass_lu: Any | None          # its LU
    measure: Any | None          # the rest shape's area element when the density is per unit rest area
    gradient: np.ndarray | None  # ∂E/∂x at x_n (galerkin)
    traction: np.ndarray | None  # element Δf at x_n (contour)
    double_layer: Any | None     # z ↦ A z (λ ≠ 1)


class StageSolver:
    """Solves the stage equations of a linearly implicit step for one ``CapsuleModel``.

    ``freeze(x)`` fixes J at the start of a step; ``solve(r, gamma_h, tol)``
    returns k with (I − γh J) k = r to the absolute 2-norm residual ``tol``
    (in the units of the system for z, module docstring). Counts
    ``linear_iterations`` (GMRES iterations, every stage); the layer
    applications are counted in the model's own counters.
    """

    def __init__(self, model, *, preconditioner: str = "local", max_iter: int = 200,
                 refresh_steps: int = 1, max_dense_nodes: int = 1100) -> None:
        if preconditioner not in PRECONDITIONERS:
            raise ValueError(f"unknown preconditioner {preconditioner!r} (allowed: {', '.join(PRECONDITIONERS)})")
        if preconditioner in ("local", "dense") and model.traction_method != "galerkin":
            raise ValueError(f"the {preconditioner} preconditioner needs the galerkin traction method")
        if preconditioner == "dense" and model.disc.n_nodes > max_dense_nodes:
            raise ValueError(f"the dense preconditioner takes at most {max_dense_nodes} nodes "
                             f"(this mesh has {model.disc.n_nodes})")
        self.model = model
        self.preconditioner = preconditioner
        self.max_iter = int(max_iter)
        self.refresh_steps = int(refresh_steps)
        self.linear_iterations = 0
        self._frozen: _Frozen | None = None
        self._hessian: sp.csr_matrix | None = None
        self._hessian_x: np.ndarray | None = None  # where it was built
        self._hessian_mass: sp.csr_matrix | None = None  # the mass matrix there
        self._scale = 0.0           # s of the local drag
        self._hessian_age = -1      # freezes since the Hessian was built (−1: none)
        self._factor: tuple[float, Any] | None = None  # (γh, y ↦ preconditioned y) of the last factorisation
        self._dense: dict[str, Any] | None = None  # _dense_operators, where H was built
        self.layer_matrices = 0     # dense layer matrices assembled (dense preconditioner)
        self._rotation: np.ndarray | None = None  # best-fit rotation from there to this step's x
        self._colour_groups: list[tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None

    # -- the frozen operators ----------------------------------------------
    def freeze(self, x: np.ndarray, u: np.ndarray | None = None) -> None:
        """Freeze J at x (the start of a step; u, the velocity there, is not needed:
        J comes from the Hessian); a step retried from the same x keeps it."""
        if self._frozen is not None and self._frozen.x is x:
            return
        self._frozen = self._freeze_operators(x)
        if self._frozen.gradient is not None:
            if self._hessian_age < 0 or self._hessian_age >= self.refresh_steps:
                self._build_hessian()
            self._hessian_age += 1
            # a preconditioner built steps ago is applied in its own frame: the capsule's
            # membrane turns (tank-treading) while its shape stays, and a rotation
            # misaligns the preconditioner's finest modes by the distance a node travels
            self._rotation = None if self._hessian_x is x else best_rotation(self._hessian_x, x)

    def _rotate_in(self, y: np.ndarray) -> np.ndarray:
        """Rᵀ at every node: from this step's frame to the preconditioner's."""
        r = self._rotation
        return y if r is None else (y.reshape(-1, 3) @ r).ravel()

    def _rotate_out(self, z: np.ndarray) -> np.ndarray:
        """R at every node: from the preconditioner's frame to this step's."""
        r = self._rotation
        return z if r is None else (z.reshape(-1, 3) @ r.T).ravel()

    def _freeze_operators(self, x: np.ndarray) -> _Frozen:
        model, disc = self.model, self.model.disc
        geo = disc.geometry(x)
        lam = model.viscosity_ratio
        needs_normals = lam != 1.0 or model.volume_correction
        normals = disc.nodal_normals(x) if needs_normals else None
        normal_flux = disc.flux(geo, normals) if model.volume_correction else None
        mass = mass_lu = measure = gradient = traction = None
        membrane = model.membrane
        if membrane.traction_method == "galerkin":
            mass, mass_lu, measure = membrane.traction_solve.frozen(x, geo)
            gradient = membrane.energy_gradient(x)
        else:
            traction = membrane.element_traction(x)
        double_layer = model.double_layer_operator(x, geo, normals) if lam != 1.0 else None
        return _Frozen(x, geo, normals, normal_flux, mass, mass_lu, measure, gradient, traction, double_layer)

    def _project(self, v: np.ndarray) -> np.ndarray:
        """The frozen volume correction P."""
        fr = self._frozen
        if not self.model.volume_correction:
            return v
        return self.model.remove_net_flux(fr.geo, v, fr.normals, fr.normal_flux)

    def _traction_change(self, v: np.ndarray) -> np.ndarray:
        """The density change along v: M0⁻¹ H v at the nodes (galerkin: H the sparse
        Hessian when it is this step's, else a difference of the energy gradient, so
        that J is always the step's own), or the element tractions' change (contour)."""
        fr, membrane = self._frozen, self.model.membrane
        if fr.gradient is None:
            return _directional_difference(membrane.element_traction, fr.x, fr.traction, v)
        if self._hessian_x is fr.x:
            hv = (self._hessian @ v.ravel()).reshape(v.shape)
        else:
            hv = _directional_difference(membrane.energy_gradient, fr.x, fr.gradient, v)
        return fr.mass_lu.solve(np.asfortranarray(hv))

    def _layer_product(self, v: np.ndarray) -> np.ndarray:
        """B' v = L∞ v − SL[Δf'(v)]/(8πG) (one single-layer application)."""
        model, fr = self.model, self._frozen
        change = self._traction_change(v)
        density = change[model.disc.elements] if fr.gradient is not None else change  # nodal or per element
        sl = model.disc.single_layer(fr.x, fr.geo, np.ascontiguousarray(density), fr.measure)
        model.counts["single_layer_applications"] += 1
        return v @ model.far_field.matrix.T - sl / (8.0 * np.pi * model.shear_rate_G)

    # -- the preconditioner -------------------------------------------------
    def _build_hessian(self) -> None:
        """H = ∂²E/∂x² at x_n by coloured differences, and the drag s of the single layer."""
        model, fr = self.model, self._frozen
        disc, membrane = model.disc, model.membrane
        n = disc.n_nodes
        if self._colour_groups is None:  # the topology's: once per run
            groups = [disc.elements]
            if membrane.bending is not None:
                groups.append(membrane.bending.hinges)
            adj = node_adjacency(n, groups).tocoo()
            colours = hessian_colouring(adj.tocsr())
            # per colour: its nodes, and the (row node, column node) pairs of H it recovers
            self._colour_groups = [
                (np.flatnonzero(colours == c), adj.row[colours[adj.col] == c], adj.col[colours[adj.col] == c])
                for c in range(int(colours.max()) + 1)]
        eps = _FD_SCALE * max(1.0, float(np.abs(fr.x).max()))
        rows, cols, vals = [], [], []
        for nodes, out_node, in_node in self._colour_groups:
            for d in range(3):
                xp = fr.x.copy()
                xp[nodes, d] += eps
                dg = (membrane.energy_gradient(xp) - fr.gradient) / eps
                for e in range(3):
                    rows.append(3 * out_node + e)
                    cols.append(3 * in_node + d)
                    vals.append(dg[out_node, e])
        h = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * n, 3 * n))
        self._hessian = ((h + h.T) * 0.5).tocsr()
        self._hessian_x = fr.x
        self._hessian_mass = fr.mass
        self._factor = None
        if self.preconditioner == "dense":
            self._dense = self._dense_operators()
        else:
            self._scale = self._drag_scale()
        self._hessian_age = 0

    def _dense_operators(self) -> dict[str, Any]:
        """The dense preconditioner's matrices at x_n (module docstring).

        λ = 1, the equation for k: Z = I − γh P B' = I − γh P L∞ + c P S M⁻¹ H
        with c = γh/(8πG). Leaving out the flow term (not stiff: γh|L∞| ≪ 1 at the
        steps the membrane allows) the push-through identity gives
        Z⁻¹ ≈ I − c PS (M + c H PS)⁻¹ H: no M⁻¹, and per γh only the LU of
        M + c·(H PS), whose product H PS is formed once per build.
        λ ≠ 1, the equation for z: A − γh B'P itself, from the single and double
        layer matrices, LU-factorised per γh."""
        model, fr, disc = self.model, self._frozen, self.model.disc
        n = disc.n_nodes
        single = disc.layer_matrix(fr.x, fr.geo, "single", fr.measure)
        self.layer_matrices += 1
        if fr.normals is not None:  # flux weights w: ⟨n, u⟩ = w·u (P, and A's deflation)
            normals = fr.normals.ravel()
            flux_weights = disc.flux_weights(fr.geo).ravel()
            weights = flux_weights / float(flux_weights @ normals)  # P = I − n wᵀ/(w·n)
        if fr.double_layer is None:
            if model.volume_correction:
                single -= np.outer(normals, weights @ single)  # P S
            return {"ps": single, "hps": np.asarray(self._hessian @ single), "mass": fr.mass.toarray()}
        # S M⁻¹ H as (M⁻¹ Sᵀ)ᵀ per component (a dense Cholesky: SuperLU's solve is slow
        # on 9N right-hand sides), then a product with the sparse, symmetric H
        mass = scipy.linalg.cho_factor(fr.mass.toarray(), check_finite=False)
        s_minv = scipy.linalg.cho_solve(mass, np.ascontiguousarray(single.T).reshape(n, -1),
                                        overwrite_b=True, check_finite=False).reshape(3 * n, 3 * n).T
        del single
        b_prime = np.asarray(self._hessian @ s_minv.T).T
        del s_minv
        b_prime *= -1.0 / (8.0 * np.pi * model.shear_rate_G)
        idx = np.arange(n)  # + L∞ on every node's diagonal block
        b_prime.reshape(n, 3, n, 3)[idx, :, idx, :] += model.far_field.matrix
        if model.volume_correction:  # B'P
            b_prime -= np.outer(b_prime @ normals, weights)
        lam = model.viscosity_ratio
        a_matrix = disc.layer_matrix(fr.x, fr.geo, "double")
        self.layer_matrices += 1
        a_matrix *= -(1.0 - lam) / (8.0 * np.pi)
        a_matrix[np.diag_indices(3 * n)] += 1.0
        area = float(fr.geo.weights.sum())
        a_matrix += (1.0 - lam) / area * np.outer(normals, flux_weights)
        # A's LU preconditions the velocity solves of the steps to come (their A differs
        # from this one by the motion since: one or two GMRES iterations instead of ~10),
        # in the frame of the rotation since, as the stage preconditioner
        a_factor = scipy.linalg.lu_factor(a_matrix, check_finite=False)
        model.double_layer_preconditioner = lambda y: self._rotate_out(
            scipy.linalg.lu_solve(a_factor, self._rotate_in(y), check_finite=False))
        return {"a": a_matrix, "b_prime_p": b_prime}

    def _dense_factor(self, gamma_h: float):
        """The dense preconditioner at this γh: y ↦ Z⁻¹ y (``_dense_operators``)."""
        d = self._dense
        lu = scipy.linalg.lu_factor
        if "ps" in d:
            c = gamma_h / (8.0 * np.pi * self.model.shear_rate_G)
            q = c * d["hps"]  # + M (scalar, per component) on the diagonal of each node pair's block
            q4 = q.reshape(q.shape[0] // 3, 3, -1, 3)
            for a in range(3):
                q4[:, a, :, a] += d["mass"]
            factor = lu(q, overwrite_a=True, check_finite=False)
            ps, hessian, flow = d["ps"], self._hessian, self.model.far_field.matrix

            def stiff_inverse(y):
                y = self._rotate_in(y)
                return self._rotate_out(y - c * (ps @ scipy.linalg.lu_solve(factor, hessian @ y, check_finite=False)))

            def precondition(y):
                # the flow term by one Neumann step: Z⁻¹ ≈ Z̃⁻¹ + Z̃⁻¹ (γh P L∞) Z̃⁻¹, an
                # error of (γh|L∞|)², at no layer application
                t = stiff_inverse(y)
                return t + stiff_inverse(gamma_h * self._project((t.reshape(-1, 3) @ flow.T)).ravel())

            return precondition
        factor = lu(d["a"] - gamma_h * d["b_prime_p"], overwrite_a=True, check_finite=False)
        return lambda y: self._rotate_out(scipy.linalg.lu_solve(factor, self._rotate_in(y), check_finite=False))

    #: the local preconditioner's drag as a fraction of the single layer's Rayleigh quotient on
    #: white noise with the mesh's symmetry (_drag_scale). Layer applications, li, rtol as in
    #: benchmarks/stepping.py, kt 0-2 of (g) (level 2, G = 0.001) and kt 0-1 of (c) (level 3,
    #: G = 0.0125), quarter symmetry: fraction 0.125 → 1270, 1344; 0.18 → 1242, 1228;
    #: 0.25 → 1213, 1157; 0.5 → 1222, 1191; 1 → 1289, —. The quotient used to be taken with
    #: noise without the symmetry, a quarter of the true one under quarter symmetry (1211, 1152
    #: there) and the whole of it without symmetry (1310, 1427, now 1211, 1158).
    DRAG_FRACTION = 0.25

    def _drag_scale(self) -> float:
        """s = DRAG_FRACTION · ⟨v, SL[v]⟩/⟨v, v⟩ for white noise v with the mesh's symmetry
        (``Discretization.noise_rayleigh_quotient``): the same s whatever the symmetry in use."""
        model, fr = self.model, self._frozen
        quotient = model.disc.noise_rayleigh_quotient(fr.x, fr.geo)
        model.counts["single_layer_applications"] += 1
        return self.DRAG_FRACTION * max(quotient, 0.0)

    def _preconditioner(self, gamma_h: float):
        """y ↦ (approximately) Z⁻¹ y at this γh, or None (``none``). The factorisation is
        kept while γh stays within TAU_SLACK of the γh it was made for (the
        preconditioner need not match J exactly; CVODE's rule): with
        jacobian_refresh_steps > 1 that saves the LU of most steps."""
        if self.preconditioner == "none":
            return None
        if self._factor is None or abs(gamma_h / self._factor[0] - 1.0) > self.TAU_SLACK:
            factorise = self._dense_factor if self.preconditioner == "dense" else self._local_factor
            self._factor = (gamma_h, factorise(gamma_h))
        return self._factor[1]

    TAU_SLACK = 0.3

    def _local_factor(self, gamma_h: float):
        """(M + τH)⁻¹ M, τ = γh s/(8πG), with M and H where H was built (module docstring)."""
        tau = gamma_h * self._scale / (8.0 * np.pi * self.model.shear_rate_G)
        mass = self._hessian_mass
        lu = splu((sp.kron(mass, sp.identity(3), format="csr") + tau * self._hessian).tocsc())
        return lambda y: self._rotate_out(lu.solve((mass @ self._rotate_in(y).reshape(-1, 3)).ravel()))

    # -- one stage ------------------------------------------------------------
    def solve(self, r: np.ndarray, gamma_h: float, tol: float, *, floor: float = 1e-10,
              ceiling: float = 1e-2) -> np.ndarray:
        """k with (I − γh J) k = r. ``tol`` bounds the 2-norm residual in the units
        of z (module docstring: an error δz moves k by γh P δz), kept between
        ``floor`` times the right-hand side (about the best the products' round-off
        allows) and ``ceiling`` times it.

        λ = 1 (A = I): the stage equation itself, (I − γh P B') k = r, whose
        right-hand side needs no product, to the residual γh·tol. λ ≠ 1: the
        system for z, whose right-hand side B' r costs one single layer."""
        fr = self._frozen
        if fr is None:
            raise RuntimeError("freeze(x) before solve")
        shape = r.shape
        check = self.model.interrupt_check or (lambda: None)
        if fr.double_layer is None:
            def system(k_flat):
                k = k_flat.reshape(shape)
                return (k - gamma_h * self._project(self._layer_product(k))).ravel()

            b, tol = r.ravel(), gamma_h * tol
        else:
            def system(z_flat):
                z = z_flat.reshape(shape)
                return (fr.double_layer(z) - gamma_h * self._layer_product(self._project(z))).ravel()

            b = self._layer_product(r).ravel()
        bnorm = float(np.linalg.norm(b))
        if not bnorm > 0.0:
            return r.copy()
        tol = min(max(tol, floor * bnorm), ceiling * bnorm)
        solution, iterations, residual = gmres(
            system, b, tol, precondition=self._preconditioner(gamma_h), max_iter=self.max_iter,
            restart=min(60, self.max_iter), callback=check)
        self.linear_iterations += iterations
        if not residual <= tol or not np.all(np.isfinite(solution)):
            raise LinearSolveFailed(f"stage solve: residual {residual:.2e} > {tol:.2e} after {iterations} iterations")
        if fr.double_layer is None:
            return solution.reshape(shape)
        return r + gamma_h * self._project(solution.reshape(shape))

    # -- checkpoints ----------------------------------------------------------
    def state(self) -> dict[str, Any]:
        """Counters, and where the preconditioner's Hessian was built (rebuilt there on restore)."""
        out: dict[str, Any] = {"linear_iterations": self.linear_iterations, "hessian_age": self._hessian_age,
                               "layer_matrices": self.layer_matrices}
        if self._hessian_x is not None:
            out["hessian_x"] = np.array(self._hessian_x, copy=True)
        if self._factor is not None:
            out["factor_gamma_h"] = float(self._factor[0])
        return out

    def restore(self, state: dict[str, Any]) -> None:
        self._frozen = self._factor = self._hessian = self._hessian_x = self._hessian_mass = None
        self._dense = self._rotation = None
        hx = state.get("hessian_x")
        if hx is not None:
            self._frozen = self._freeze_operators(np.array(hx, dtype=float))
            self._build_hessian()
            self._frozen = None
            gamma_h = state.get("factor_gamma_h")
            if gamma_h is not None:
                self._preconditioner(float(gamma_h))  # the factorisation of the saved γh
        self._hessian_age = int(state.get("hessian_age", -1))
        self.linear_iterations = int(state.get("linear_iterations", 0))
        self.layer_matrices = int(state.get("layer_matrices", 0))
