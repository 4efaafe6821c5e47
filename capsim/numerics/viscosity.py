"""Membrane viscosity: a registry of viscous membrane models and their velocity solve.

A viscous membrane adds to the elastic tension a tension that depends on the
membrane's rate of deformation. In units of E_s (tension) and k (rate), with the
Boussinesq numbers Bq_s = μ_s/(μa) and Bq_d = μ_d/(μa) (μ the outer viscosity),
the Kelvin–Voigt membrane (Barthès-Biesel & Sgaier 1985, their eq. 2.6; Yazdani
& Bagchi 2013; docs/viscous_membrane.md, eq. V1) carries

    T_v = G [2 Bq_s (D − ½ tr(D) P) + Bq_d tr(D) P],   D = ½ P(∇_s u + ∇_s uᵀ)P,

P = I − nn the surface projector. Its traction Δf_v = −∇_s·T_v is linear in the
membrane velocity u: by virtual power (as the elastic Galerkin traction, seed
3.4–3.6 replaced by M·Δf = ∂E/∂x) M·Δf_v = G·K u with K the viscous stiffness
of ``kernels.viscous_membrane_blocks`` (eq. V3). The velocity equation of
``solver.CapsuleModel.velocity`` (seed 2.11 in capsim's units) gains a term in u,

    A u + SL[M⁻¹K u]/(8π) = u∞ − SL[Δf_e]/(8πG)                     (V4)

(A = I at λ = 1, else the deflated double-layer operator); G cancels from the
viscous term, which is why the Boussinesq number is the parameter. As the elastic
traction (``membrane.MembraneForce``), the viscous one is solved per unit rest area for
an elastic membrane, M = M0 the rest shape's mass matrix and SL over the rest shape's
measure (the inner solves M0⁻¹K u then exact, by the elastic traction's factor), and
per unit current area for a drop, M = M(x) (conjugate gradients). (V4) is solved
by GMRES (``capsim.numerics.krylov``) at every velocity evaluation, on the unknowns the mesh's
symmetry leaves (``_Reduction``), warm-started from the last two solutions extrapolated
(``_extrapolation``), right-preconditioned by the "local drag" approximation
SL[w] ≈ s w (s a fraction of the single layer's Rayleigh quotient on white noise at the
rest shape, where the finest modes, the stiff ones, dominate: ``drag_scale``):

    Z⁻¹ ≈ ( (1+λ)/2 M + s/(8π) K )⁻¹ M

factorised (sparse LU) at the rest shape and again wherever a solve took more than
REFRESH_ITERATIONS, applied in the frame of the best-fit rotation from the nodes where it
was factorised ("frozen"; the others, measured against it, in docs/viscous_membrane.md).

Registry: a model is an entry of :data:`VISCOSITY_MODELS` (its parameters, their
meaning, its source); ``build`` makes its solver. Only the Kelvin–Voigt membrane
is implemented; the standard linear solid (a Maxwell branch whose stress is
state) is not (docs/viscous_membrane.md says why).

This module imports no numba at import time (config.py reads the registry).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np


#: SuperLU options for the preconditioner's matrix (1+λ)/2 M + s/(8π) K, symmetric positive
#: definite: a minimum-degree ordering of A + Aᵀ and diagonal pivots keep the symmetric
#: structure (level 3: 0.50 million nonzeros in L + U against 0.88 with the default
#: COLAMD, the triangular solves that every GMRES iteration applies correspondingly cheaper)
SPD_LU = {"permc_spec": "MMD_AT_PLUS_A", "diag_pivot_thresh": 0.0, "options": {"SymmetricMode": True}}


def is_active(params: dict | None) -> bool:
    """Whether a viscosity block changes anything (every Boussinesq number 0: the elastic code path)."""
    return bool(params) and any(float(v) > 0.0 for k, v in params.items() if k != "model")


class KelvinVoigtMembrane:
    """The solver of (V4) for one discretisation (module docstring).

    ``stiffness(x)`` is K (sparse, 3N × 3N, node-major); ``solve(model, x, geo,
    rhs, normals)`` returns u. ``iterations`` counts GMRES iterations over the
    run (part of the model's checkpoint state).
    """

    name = "kelvin_voigt"

    #: preconditioners of the solve (docs/viscous_membrane.md, where benchmarks/viscous_membrane.py's
    #: measurements chose frozen): frozen, rest, local (module docstring) and none (plain GMRES)
    PRECONDITIONERS = ("frozen", "rest", "local", "none")
    #: frozen: refactorise where the last solve took more GMRES iterations than this (level 3,
    #: Bq 1, rkf23, kt 0-4, three alternated runs each: 10 → 2381 layer applications, 6.0 s;
    #: 8 → 2221, 5.6 s; 7 → 2166, 5.6 s; 6 → 2151, 7.0 s, the factorisations then costing more
    #: than the iterations they save)
    REFRESH_ITERATIONS = 7

    def __init__(self, disc, rest_positions: np.ndarray, *, shear: float, dilatational: float = 0.0,
                 preconditioner: str = "frozen") -> None:
        if preconditioner not in self.PRECONDITIONERS:
            raise ValueError(f"unknown preconditioner {preconditioner!r} (allowed: {self.PRECONDITIONERS})")
        self.preconditioner = preconditioner
        for field_name, v in (("shear", shear), ("dilatational", dilatational)):
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"membrane.viscosity.{field_name} = {v!r}: must be a finite number >= 0")
        self.disc = disc
        self.shear = float(shear)
        self.dilatational = float(dilatational)
        self.rest_positions = np.ascontiguousarray(rest_positions, dtype=np.float64)
        e = np.asarray(disc.elements, dtype=np.int64)
        dof = (3 * e[:, :, None] + np.arange(3)[None, None, :]).reshape(e.shape[0], 18)
        rows, cols = np.repeat(dof, 18, axis=1).ravel(), np.tile(dof, (1, 18)).ravel()
        # K's sparsity is the mesh's: its CSR pattern and where each element-block entry
        # lands in it are found once, so an assembly is one bincount (a COO-to-CSR
        # conversion with its sort cost three times the blocks' kernel at level 3)
        n = 3 * disc.n_nodes
        keys, self._scatter = np.unique(rows * n + cols, return_inverse=True)
        self._indices = (keys % n).astype(np.int32)
        self._indptr = np.searchsorted(keys // n, np.arange(n + 1)).astype(np.int32)
        self._drag: float | None = None
        self._rest_factor = None
        self._factor_x: np.ndarray | None = None  # frozen: where the factor is built (None: the rest shape)
        self._operators: tuple | None = None  # (x, K, mass matrix, its LU or None) of the last assembly
        self._reduction: _Reduction | None = None  # the solve's unknowns (_reduction_for)
        # (x, u, rhs) of the last two converged solves: the warm start's extrapolation (solve);
        # part of the checkpoint (the model's state "warm_viscous_history")
        self.history: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self.iterations = 0
        self.factorizations = 0  # sparse LUs of a preconditioner (not checkpointed: a benchmark count)

    # -- operators ---------------------------------------------------------------
    def stiffness(self, x: np.ndarray):
        """K at configuration x (eq. V3), with c_s = Bq_s and c_d = Bq_d (G cancels, eq. V4)."""
        import scipy.sparse as sp

        from capsim.numerics.kernels import viscous_membrane_blocks

        disc = self.disc
        blocks = viscous_membrane_blocks(
            np.ascontiguousarray(x), disc.elements, disc.mem_dxi, disc.mem_deta, disc.mem_w,
            self.shear, self.dilatational)
        n = 3 * disc.n_nodes
        data = np.bincount(self._scatter, weights=blocks.ravel(), minlength=self._indices.size)
        return sp.csr_matrix((data, self._indices, self._indptr), shape=(n, n))

    def _cached(self, x: np.ndarray):
        """(K, mass matrix) of the last assembly when it was at x, else None."""
        cached = self._operators
        if cached is not None and cached[0].shape == x.shape and np.array_equal(cached[0], x):
            return cached[1:3]
        return None

    def operators(self, x: np.ndarray, geo):
        """(K, the mass matrix M(x)) at configuration x: those of the last solve when it was at x
        (the accepted positions, which the observables then read), else assembled (M(x) only
        when asked: a solve per unit rest area needs none)."""
        cached = self._cached(x)
        if cached is not None and cached[1] is not None:
            return cached
        K = cached[0] if cached is not None else self.stiffness(x)
        mass = self.disc.mass_matrix(geo)
        self._operators = (np.array(x, copy=True), K, mass, None)
        return K, mass

    def _stiffness_at(self, x: np.ndarray):
        """K at x, kept for the observables (the mass matrix assembled only if they ask)."""
        cached = self._cached(x)
        if cached is not None:
            return cached[0]
        K = self.stiffness(x)
        self._operators = (np.array(x, copy=True), K, None, None)
        return K

    def traction(self, x: np.ndarray, geo, u: np.ndarray) -> np.ndarray:
        """M⁻¹K u at the nodes (N_p, 3): the viscous traction jump Δf_v over G, i.e. in units
        of μk (times G: in the E_s/a of the elastic Δf). Read by the observables at accepted
        states only: the mass matrix's LU is made here, once per configuration."""
        from scipy.sparse.linalg import splu

        K, mass = self.operators(x, geo)
        x_kept, _, _, mass_lu = self._operators
        if mass_lu is None:
            mass_lu = splu(mass.tocsc())
            self._operators = (x_kept, K, mass, mass_lu)
        return mass_lu.solve(np.asfortranarray((K @ u.ravel()).reshape(-1, 3)))

    def dissipation(self, x: np.ndarray, u: np.ndarray) -> float:
        """uᵀK u = ∫ T_v:D dA / G: the membrane's viscous dissipation rate in units of μ k² a³."""
        cached = self._cached(x)
        K = cached[0] if cached is not None else self.stiffness(x)
        return float(u.ravel() @ (K @ u.ravel()))

    #: the constant drag as a fraction of the single layer's Rayleigh quotient on white noise
    #: (drag_scale): the quotient is the mean of SL's spectrum, dominated by the finest modes,
    #: while the smooth modes, where SL is larger, are those GMRES then has to resolve; a smaller
    #: drag balances the two (level 2, no symmetry, layer applications per solve over kt 0-1:
    #: fraction 1 → 7.2, 0.5 → 6.5, 0.35 → 6.3, 0.25 → 6.6; docs/viscous_membrane.md)
    DRAG_FRACTION = 0.35

    def drag_scale(self, model: "CapsuleModel") -> float:
        """s = DRAG_FRACTION · ⟨v, SL[v]⟩/⟨v, v⟩ at the rest shape for white noise v (fixed
        seed) with the mesh's symmetry (its values at the symmetry's targets, expanded: the
        layer sums are evaluated at the targets, so for any other field SL[v] would not be
        v's single layer and the quotient would depend on the symmetry in use); computed once,
        from the rest positions, so that a resumed run uses the same value."""
        if self._drag is None:
            x = self.rest_positions
            self._drag = self.DRAG_FRACTION * max(self.disc.noise_rayleigh_quotient(x, self.disc.geometry(x)), 0.0)
        return self._drag

    @staticmethod
    def _rest_traction(model: "CapsuleModel"):
        """The elastic traction's solve when it is per unit rest area (``membrane.
        RestTractionSolve``: the viscous one then is too, M0·Δf_v = G K u, by its factor), else
        None (a drop: per unit current area, M(x)·Δf_v = G K u)."""
        solve = model.membrane.traction_solve
        return solve if solve.measure is not None else None

    def _reduction_for(self, model: "CapsuleModel") -> "_Reduction":
        """The unknowns of the solve: those the mesh's symmetry leaves, the membrane force's
        (``MembraneForce.reduced_mass``; every node's three components without a symmetry).
        The layer sums are evaluated at the symmetry's targets and expanded
        (solver.Discretization), so the velocity is equivariant whatever the unknowns."""
        reduced = model.membrane.reduced_mass()
        if self._reduction is None or self._reduction.reduced is not reduced:
            self._reduction = _Reduction.of(reduced, self.disc.n_nodes)
        return self._reduction

    def _factors(self, model: "CapsuleModel", red: "_Reduction", X: np.ndarray, K=None, mass=None) -> tuple:
        """At configuration X: the LU of the local-drag matrix Eᵀ((1+λ)/2 M⊗I₃ + s/(8π) K)E
        on the solve's unknowns and the factorisation of the reduced mass matrix EᵀM⊗I₃E
        (``membrane.MassFactor``), which preconditions the mass solves of nearby configurations
        (the mass matrix is that of the shape: unchanged by a rotation). M is the rest shape's
        M0 when the tractions are per unit rest area (``_rest_traction``)."""
        from scipy.sparse.linalg import splu

        from capsim.numerics.membrane import MassFactor

        disc = self.disc
        rest = self._rest_traction(model)
        if rest is not None:
            mass = rest.mass_matrix()
        elif mass is None:
            mass = disc.mass_matrix(disc.geometry(X))
        if K is None:
            K = self.stiffness(X)
        c = self.drag_scale(model) / (8.0 * np.pi)
        a = 0.5 * (1.0 + model.viscosity_ratio)
        mass_data = red.reduced.data_from_target_rows(mass.data)
        reduced_mass = red.csr(mass_data)
        drag = red.project(c * K) + a * reduced_mass
        self.factorizations += 1
        # (per unit rest area the inner mass solves use the elastic traction's exact factor)
        mass_factor = None if rest is not None else MassFactor.of(red.reduced, mass_data)
        return splu(drag.tocsc(), **SPD_LU), reduced_mass, mass_factor

    def _rest_preconditioner(self, model: "CapsuleModel", red: "_Reduction", x: np.ndarray):
        """(preconditioner, mass factor): the local-drag preconditioner factorised at the rest
        shape (``rest``) or where the last refactorisation was (``frozen``), applied in the
        frame of the best-fit rotation from those nodes to x (Kabsch 1976): a tank-treading
        membrane carries its nodes round while its shape stays, and K of a rotated mesh is the
        rotated K. ``frozen`` refactorises at the configuration of a solve that took more than
        REFRESH_ITERATIONS (the shape has moved away); where is part of the checkpoint, so a
        resumed run rebuilds the same factor."""
        from capsim.numerics.geometry import best_rotation

        X = self.rest_positions if self._factor_x is None else self._factor_x
        if self._rest_factor is None or self._rest_factor[0] is not red:
            self._rest_factor = (red, *self._factors(model, red, X))
        _, lu, reduced_mass, mass_factor = self._rest_factor
        return red.preconditioner(lu, reduced_mass, best_rotation(X, x)), mass_factor

    # -- the velocity solve -----------------------------------------------------
    def solve(self, model: "CapsuleModel", x: np.ndarray, geo, rhs: np.ndarray, normals: np.ndarray | None,
              ) -> np.ndarray:
        """u of (V4) to the relative residual ``model.solver_tol``; sets the model's
        ``last_solve_info`` (the model raises when the residual missed the tolerance) and
        warm starts, counts its layer applications.

        The unknowns are those the mesh's symmetry leaves (a quarter of the nodes' components
        under quarter symmetry: ``_Reduction``), weighted by the square root of their orbit's
        size, so that the Euclidean norm GMRES minimises is that of the full nodal vector and
        the iterates are those of the full solve (Krylov vectors of an equivariant system stay
        equivariant): the sparse products, mass solves and triangular solves of every
        iteration shrink with the unknowns, the layer sums are evaluated at the targets anyway."""
        from capsim.numerics.kernels import solve_reduced_mass
        from capsim.numerics.krylov import gmres

        disc, counts = model.disc, model.counts
        self._operators = None  # a new configuration: assembled once, kept for the observables
        rest = self._rest_traction(model)
        if rest is None:
            K, mass = self.operators(x, geo)
        else:
            K, mass = self._stiffness_at(x), None
        red = self._reduction_for(model)
        r = red.reduced
        double = model.double_layer_operator(x, geo, normals) if model.solves_double_layer else None
        elements = disc.elements

        if self.preconditioner == "local":  # factorised here, at x
            lu, reduced_mass, mass_factor = self._factors(model, red, x, K, mass)
            precondition = red.preconditioner(lu, reduced_mass, None)
        elif self.preconditioner in ("rest", "frozen"):
            precondition, mass_factor = self._rest_preconditioner(model, red, x)
        else:
            from capsim.numerics.membrane import MassFactor

            precondition = None
            mass_factor = None if rest is not None else MassFactor.of(r, r.data_from_target_rows(mass.data))

        if rest is not None:  # Δf_v per unit rest area: M0⁻¹ K u by the elastic traction's factor, exactly
            measure, viscous_density = rest.measure, rest.solve_equivariant
        else:  # per unit current area: conjugate gradients on M(x), preconditioned by the factor
            measure, mass_data, zeros = None, r.data_from_target_rows(mass.data), np.zeros((disc.n_nodes, 3))
            # the inner mass solves, to well below the outer tolerance (GMRES's operator then is
            # linear to that accuracy), not below round-off
            mass_tol = max(1e-3 * model.solver_tol, 1e-13)

            def viscous_density(rhs: np.ndarray) -> np.ndarray:
                return solve_reduced_mass(
                    r.indptr, r.indices, mass_data, r.rhs_from_target_rows(rhs), zeros, r.col, r.sign,
                    r.target_node, r.target_comp, r.inv_mult, mass_tol, 200, *mass_factor.arrays)[0]

        def apply(w: np.ndarray) -> np.ndarray:
            u = red.full(w)
            density = viscous_density((K @ u.ravel()).reshape(-1, 3))
            sl = disc.single_layer(x, geo, np.ascontiguousarray(density[elements]), measure,
                                   boundaries=model.scene.boundaries)  # the scene's wall: Blake's image too
            counts["single_layer_applications"] += 1
            base = u if double is None else double(u)
            return red.restrict(base + sl / (8.0 * np.pi))

        identity = precondition is None
        if identity:
            def precondition(y: np.ndarray) -> np.ndarray:
                return y

        b = red.restrict(rhs)
        last_u, last_rhs = model._last_velocity, model._last_rhs
        alpha = self._extrapolation(x, rhs)
        if alpha is not None:
            # the velocity and the right-hand side extrapolated along the line through the last
            # two solves' configurations to this one's projection on it, plus the preconditioned
            # rest of the right-hand side: the start's residual falls from ~8e-3 to ~1.5e-3
            # (median, level 3, Bq 1, rkf23, kt 0-2): GMRES iterations per solve 8.1 -> 7.0
            # (rkf23), 7.5 -> 4.9 (rkc, whose stages lie on a smooth path)
            (_, u1, b1), (_, u2, b2) = self.history
            guess = red.restrict(u2 + alpha * (u2 - u1))
            guess = guess + precondition(b - red.restrict(b2 + alpha * (b2 - b1)))
        elif last_u is not None and last_u.shape == rhs.shape:
            guess = red.restrict(last_u)
            if last_rhs is not None and last_rhs.shape == rhs.shape:
                guess = guess + precondition(b - red.restrict(last_rhs))
        else:
            guess = precondition(b)
        model._last_rhs = rhs
        bnorm = max(float(np.linalg.norm(b)), 1e-300)
        res = b - apply(guess)
        residual = float(np.linalg.norm(res)) / bnorm
        w, iterations = guess, 0
        if residual > model.solver_tol:
            restart = min(60, model.solver_max_iter)
            delta, iterations, rnorm = gmres(
                apply, res, model.solver_tol * bnorm, precondition=None if identity else precondition,
                max_iter=model.solver_max_iter * restart, restart=restart, callback=model.interrupt_check)
            w = guess + delta
            residual = rnorm / bnorm
        self.iterations += int(iterations)
        if self.preconditioner == "frozen" and iterations > self.REFRESH_ITERATIONS:
            self._factor_x, self._rest_factor = np.array(x, copy=True), None
        model.last_solve_info = {"iterations": int(iterations), "residual": residual}
        u = red.full(w)
        if not residual <= 10.0 * model.solver_tol:  # the model raises SolverDivergence
            return u
        model._last_velocity = u
        self.history = [*self.history[-1:], (np.array(x, copy=True), u, np.array(rhs, copy=True))]
        return u

    #: the warm start extrapolates no further than this many times the last two solves' distance
    #: (a spectral-radius probe's configurations lie ~1e-4 apart, relative, and their velocities
    #: differ by that times ρ plus the solve's tolerance: extrapolating far would amplify the latter)
    EXTRAPOLATION_LIMIT = 4.0

    def _extrapolation(self, x: np.ndarray, rhs: np.ndarray) -> float | None:
        """α with x ≈ x₂ + α (x₂ − x₁) (least squares) for the last two solves' x₁, x₂, or None
        (fewer than two, other shapes, or |α| beyond EXTRAPOLATION_LIMIT)."""
        if len(self.history) < 2 or any(h[1].shape != rhs.shape for h in self.history):
            return None
        (x1, _, _), (x2, _, _) = self.history
        dx = x2 - x1
        norm2 = float(np.vdot(dx, dx))
        if not norm2 > 0.0:
            return None
        alpha = float(np.vdot(x - x2, dx)) / norm2
        return alpha if abs(alpha) <= self.EXTRAPOLATION_LIMIT else None


@dataclass(frozen=True)
class _Reduction:
    """The unknowns of the viscous solve: w[k] = √m_k · u[target_node[k], target_comp[k]]
    for the unknowns of ``membrane.ReducedMass`` (m_k the size of its orbit: the number of
    nodal components that are ± that one), u = E w/√m with E (3N × n) the signed expansion.
    For an equivariant u, |w|₂ = |u|₂."""

    reduced: Any           # membrane.ReducedMass
    expansion: Any         # E, CSR (3N × n)
    restriction: Any       # Eᵀ, CSR
    pick: np.ndarray       # (n,) flat index 3 j + c of each unknown's target component
    weight: np.ndarray     # (n,) √m

    @classmethod
    def of(cls, reduced, n_nodes: int) -> "_Reduction":
        import scipy.sparse as sp

        valid = reduced.col >= 0
        rows = (3 * np.arange(n_nodes)[:, None] + np.arange(3)[None, :])[valid]
        expansion = sp.csr_matrix((reduced.sign[valid], (rows, reduced.col[valid])),
                                  shape=(3 * n_nodes, reduced.size))
        return cls(reduced, expansion, expansion.T.tocsr(), 3 * reduced.target_node + reduced.target_comp,
                   np.sqrt(1.0 / reduced.inv_mult))

    def full(self, w: np.ndarray) -> np.ndarray:
        """u (N, 3) of the weighted unknowns w."""
        return (self.expansion @ (w / self.weight)).reshape(-1, 3)

    def restrict(self, u: np.ndarray) -> np.ndarray:
        """w of an equivariant nodal field u (N, 3)."""
        return self.weight * u.ravel()[self.pick]

    def csr(self, reduced_data: np.ndarray):
        import scipy.sparse as sp

        r = self.reduced
        return sp.csr_matrix((reduced_data, r.indices, r.indptr), shape=(r.size, r.size))

    def project(self, matrix):
        """Eᵀ A E of a (3N × 3N) matrix A that commutes with the symmetry."""
        return (self.restriction @ matrix @ self.expansion).tocsr()

    def preconditioner(self, lu, mass, rot: np.ndarray | None):
        """w ↦ the local-drag approximation of the operator's inverse (module docstring) on
        the unknowns: z = (Eᵀ D E)⁻¹ (Eᵀ M⊗I₃ E) y, with D the drag matrix and M the mass
        matrix where ``lu`` was factorised (``KelvinVoigtMembrane._factors``; the reduced
        mass matrix ``mass``), applied in the frame of the rotation rot from there (None:
        the same frame). A rotation about the symmetry axis keeps a field equivariant."""
        def turn(v: np.ndarray, r: np.ndarray) -> np.ndarray:  # unweighted unknowns, turned by r
            return ((self.expansion @ v).reshape(-1, 3) @ r).ravel()[self.pick]

        def precondition(w: np.ndarray) -> np.ndarray:
            y = w / self.weight
            if rot is not None:
                y = turn(y, rot)
            z = lu.solve(mass @ y)
            if rot is not None:
                z = turn(z, rot.T)
            return self.weight * z

        return precondition


@dataclass(frozen=True)
class ViscosityModel:
    """A registry entry: the model's name, its parameters (Boussinesq numbers,
    ≥ 0) with their meaning, its source and the class that solves (V4) with it."""

    name: str
    parameters: dict
    reference: str
    solver: type  # built with (disc, rest_positions, **parameters)


VISCOSITY_MODELS: dict[str, ViscosityModel] = {
    "kelvin_voigt": ViscosityModel(
        "kelvin_voigt",
        {"shear": "surface shear viscosity as a Boussinesq number Bq_s = μ_s/(μ a)",
         "dilatational": "surface dilatational viscosity Bq_d = μ_d/(μ a) (isotropic viscous tension μ_d tr D)"},
        "Barthès-Biesel & Sgaier, J. Fluid Mech. 160 (1985) 119-135; Yazdani & Bagchi, J. Fluid Mech. 718 (2013) "
        "569-595",
        KelvinVoigtMembrane,
    ),
}


def build(disc, rest_positions: np.ndarray, params: dict | None) -> KelvinVoigtMembrane | None:
    """The viscous membrane of a case's ``membrane.viscosity`` block, or None when it
    changes nothing (no block, or every Boussinesq number 0: today's elastic path)."""
    if not is_active(params):
        return None
    params = dict(params)
    name = params.pop("model", "kelvin_voigt")
    if name not in VISCOSITY_MODELS:
        raise ValueError(f"unknown membrane viscosity model {name!r} (allowed: {sorted(VISCOSITY_MODELS)})")
    return VISCOSITY_MODELS[name].solver(disc, rest_positions, **params)
