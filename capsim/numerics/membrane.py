"""Membrane constitutive laws and elastic tensions (seed §2, 2.5–2.10, 3.4–3.6).

Tensions are in units of E_s. With principal stretches λ1, λ2 the invariants are
Λ1 = ln(λ1 λ2) and Λ2 = (λ1² + λ2²)/2 − 1, and the Cauchy tension is (seed 2.7)

    T = e^{−Λ1} [W_1 (I − n n) + W_2 B],   W_i = ∂W/∂Λ_i,   B = A·Aᵀ.

Each law is a registry entry giving (W, W_1, W_2) as vectorised functions of
(Λ1, Λ2) and its small-strain shear and area-dilation moduli G_s, K_s in units
of E_s. Derived from the invariant forms:

* thin shell (Barthès-Biesel & Rallison 1981, seed 2.8):
  W = (1/3)(−Λ1 + Λ2 + Λ1²);  G_s = 1/3, K_s = 1.
* neo-Hookean, W = (1/6)(λ1² + λ2² + 1/(λ1²λ2²) − 3) = (1/6)(2Λ2 + e^{−2Λ1} − 1)
  (the seed's printed 2.9 has e^{−2Λ2} where e^{−2Λ1} is needed); G_s = 1/3, K_s = 1.
* Mooney–Rivlin with ψ' (Li et al. 1988): (1−ψ') × neo-Hookean +
  (ψ'/6)(2Λ2 e^{−2Λ1} + 2 e^{−2Λ1} + e^{2Λ1} − 3) [= (ψ'/6)(λ1²λ2² + 1/λ1² + 1/λ2² − 3)];
  G_s = 1/3, K_s = 1 for every ψ'.
* Skalak et al. (1973) in the form of Barthès-Biesel, Diaz & Dhenin (2002),
  W = (G_s/4)[I1² + 2 I1 − 2 I2 + C I2²], I1 = λ1² + λ2² − 2 = 2Λ2,
  I2 = λ1²λ2² − 1 = e^{2Λ1} − 1, with G_s = 1/3 (so that G = μka/E_s means the
  same shear stiffness for every law) and C the dimensionless area parameter:
  G_s = 1/3, K_s = G_s(1 + 2C) = (1 + 2C)/3. The seed's (2.10) is the same
  energy with its B = 2 G_s = 2/3 and its C = 2 C G_s = 2C/3 (in units of E_s),
  once its misprinted e^{2Λ2} is read as e^{2Λ1}; its shear modulus is B/2 and
  its area modulus B/2 + C.

* surface tension (a clean drop, no membrane elasticity): W = γ λ1λ2 = γ e^{Λ1}
  per unit rest area, i.e. γ times the current area, with γ = 1 in the units of
  the modulus scale, so that T = γ(I − n n) at every deformation and G = μka/γ
  is the drop's capillary number. G_s = 0; there is no small-strain area modulus
  either (the tension does not depend on the strain), reported as K_s = 0.
  Useful as a check against the classical small-deformation theory of drops.

For the elastic laws the Poisson ratio is ν_s = (K_s − G_s)/(K_s + G_s) and the
capillary number of papers that scale by G_s is Ca = μka/G_s = G/G_s = 3G.
docs/laws.md gives the derivations.
"""

from __future__ import annotations

import inspect
import time
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Callable

import numpy as np

from capsim.numerics import kernels
from capsim.numerics.mesh import linear_subtriangles  # noqa: F401 - used here, and offered here as before

Array = np.ndarray


@dataclass(frozen=True)
class MembraneLaw:
    name: str
    energy: Callable[..., Array]
    derivatives: Callable[..., tuple[Array, Array]]
    shear_modulus: Callable[..., float]
    area_modulus: Callable[..., float]
    parameters: tuple[str, ...] = field(default_factory=tuple)
    #: the area the Galerkin traction is solved per (a key of TRACTION_MEASURES): "rest" for an
    #: elastic membrane, whose nodes stay with its material and whose area change is smooth and
    #: bounded; "current" for a clean drop, whose rest shape means nothing and whose nodes drift
    #: with the surface flow (per unit rest area its level-2 N1* at Ca = 0.05 was 4.6 % above
    #: theory and growing, against 1.4 % per unit current area: docs/method.md)
    measure: str = "rest"


def _thin_shell_w(l1, l2):
    return (-l1 + l2 + l1 * l1) / 3.0


def _thin_shell_dw(l1, l2):
    return (2.0 * l1 - 1.0) / 3.0, np.full_like(l1, 1.0 / 3.0)


def _mooney_rivlin_w(l1, l2, psi=0.0):
    e = np.exp(-2.0 * l1)
    nh = (2.0 * l2 + e - 1.0) / 6.0
    extra = (2.0 * l2 * e + 2.0 * e + np.exp(2.0 * l1) - 3.0) / 6.0
    return (1.0 - psi) * nh + psi * extra


def _mooney_rivlin_dw(l1, l2, psi=0.0):
    e = np.exp(-2.0 * l1)
    w1 = (1.0 - psi) * (-e / 3.0) + psi * (-4.0 * l2 * e - 4.0 * e + 2.0 * np.exp(2.0 * l1)) / 6.0
    w2 = (1.0 - psi) / 3.0 + psi * e / 3.0
    return w1, w2


_SKALAK_GS = 1.0 / 3.0  # shear modulus in units of E_s, as for the other laws


def _skalak_w(l1, l2, skalak_c=10.0):
    i1 = 2.0 * l2
    i2 = np.exp(2.0 * l1) - 1.0
    return 0.25 * _SKALAK_GS * (i1 * i1 + 2.0 * i1 - 2.0 * i2 + skalak_c * i2 * i2)


def _skalak_dw(l1, l2, skalak_c=10.0):
    # chain rule with ∂I1/∂Λ2 = 2 and ∂I2/∂Λ1 = 2 e^{2Λ1}
    e2 = np.exp(2.0 * l1)
    i2 = e2 - 1.0
    w1 = _SKALAK_GS * (skalak_c * i2 - 1.0) * e2
    w2 = _SKALAK_GS * (2.0 * l2 + 1.0)
    return w1, w2


def _surface_tension_w(l1, l2):
    return np.exp(l1)


def _surface_tension_dw(l1, l2):
    return np.exp(l1), np.zeros_like(l2)


LAWS: dict[str, MembraneLaw] = {
    "thin_shell": MembraneLaw("thin_shell", _thin_shell_w, _thin_shell_dw, lambda: 1 / 3, lambda: 1.0),
    "neo_hookean": MembraneLaw(
        "neo_hookean",
        lambda l1, l2: _mooney_rivlin_w(l1, l2, 0.0),
        lambda l1, l2: _mooney_rivlin_dw(l1, l2, 0.0),
        lambda: 1 / 3,
        lambda: 1.0,
    ),
    "mooney_rivlin": MembraneLaw(
        "mooney_rivlin", _mooney_rivlin_w, _mooney_rivlin_dw, lambda psi=0.0: 1 / 3, lambda psi=0.0: 1.0, ("psi",)
    ),
    "skalak": MembraneLaw(
        "skalak", _skalak_w, _skalak_dw, lambda skalak_c=10.0: _SKALAK_GS,
        lambda skalak_c=10.0: _SKALAK_GS * (1.0 + 2.0 * skalak_c), ("skalak_c",),
    ),
    "surface_tension": MembraneLaw(
        "surface_tension", _surface_tension_w, _surface_tension_dw, lambda: 0.0, lambda: 0.0, measure="current",
    ),
}


def get_law(name: str) -> MembraneLaw:
    if name not in LAWS:
        raise ValueError(f"unknown membrane law {name!r} (allowed: {sorted(LAWS)})")
    return LAWS[name]


def law_attributes(name: str, params: dict | None = None) -> dict:
    """The law, its parameters and its small-strain moduli, for storing with a run.

    Moduli are in units of E_s; parameters the law does not take are ignored and
    missing ones take the law's defaults. ``ca_over_G`` = E_s/G_s converts G =
    μka/E_s to the capillary number Ca = μka/G_s of papers that scale by G_s.
    """
    law = get_law(name)
    params = dict(params or {})
    defaults = inspect.signature(law.derivatives).parameters
    used = {p: float(params.get(p, defaults[p].default)) for p in law.parameters}
    g_s = float(law.shear_modulus(**used))
    k_s = float(law.area_modulus(**used))
    elastic = g_s > 0.0
    return {
        "name": law.name,
        "parameters": used,
        "G_s": g_s,
        "K_s": k_s,
        # a drop (surface tension) has no Poisson ratio, and G is its capillary number
        "poisson_ratio": (k_s - g_s) / (k_s + g_s) if elastic else float("nan"),
        "ca_over_G": 1.0 / g_s if elastic else 1.0,
        "units": "E_s",
    }


@dataclass(frozen=True)
class VertexStrain:
    """Strain state at the vertex nodes."""

    A: Array          # (N_v, 3, 3) surface deformation gradient
    B: Array          # (N_v, 3, 3) left Cauchy–Green tensor A·Aᵀ
    normals: Array    # (N_v, 3) current unit normals
    inv1: Array       # Λ1 = ln(λ1 λ2)
    inv2: Array       # Λ2 = (λ1² + λ2²)/2 − 1

    @cached_property  # read by the stretch guard and the principal tensions of each recorded step
    def principal_stretches(self) -> tuple[Array, Array]:
        """λ1 ≥ λ2 from B's trace and its deviator in the tangent plane: λ1² − λ2² =
        √(2 |B − (tr B / 2)(I − n n)|²). From tr² − 4 det B (as until 2026-12-06) the difference lost half
        the digits where the stretches are near equal: at rest it read 1e-8, the tensions ±1e-8 E_s
        and a quarter of a sphere's vertices "compressed" (COMPRESSION_TOL 1e-10)."""
        tr = 2.0 * (self.inv2 + 1.0)
        n = self.normals
        projector = np.eye(3)[None] - n[:, :, None] * n[:, None, :]
        deviator = self.B - 0.5 * tr[:, None, None] * projector
        disc = np.sqrt(2.0 * np.einsum("vij,vij->v", deviator, deviator))
        return np.sqrt(0.5 * (tr + disc)), np.sqrt(np.maximum(0.5 * (tr - disc), 0.0))


def strain_from_gradient(A: Array, normals: Array) -> VertexStrain:
    B = np.einsum("vik,vjk->vij", A, A)
    tr = np.einsum("vii->v", B)
    tr2 = np.einsum("vij,vji->v", B, B)
    det2 = 0.5 * (tr * tr - tr2)  # λ1²λ2²: B has rank 2 by construction
    inv1 = 0.5 * np.log(det2)
    inv2 = 0.5 * tr - 1.0
    return VertexStrain(A, B, normals, inv1, inv2)


def tension_tensor(strain: VertexStrain, law: MembraneLaw, params: dict) -> Array:
    """T = e^{−Λ1}[W_1 (I − nn) + W_2 B] at the vertex nodes (seed 2.7)."""
    w1, w2 = law.derivatives(strain.inv1, strain.inv2, **params)
    n = strain.normals
    proj = np.eye(3)[None] - n[:, :, None] * n[:, None, :]
    scale = np.exp(-strain.inv1)
    return scale[:, None, None] * (w1[:, None, None] * proj + w2[:, None, None] * strain.B)


def _law_derivatives(strain: VertexStrain, law: MembraneLaw, params: dict) -> tuple[Array, Array]:
    """W_1, W_2 at the vertices, one value each (a law may give a constant)."""
    shape = strain.inv1.shape
    return tuple(w if type(w) is np.ndarray and w.shape == shape else np.broadcast_to(np.asarray(w, float), shape)
                 for w in law.derivatives(strain.inv1, strain.inv2, **params))


def principal_tensions(strain: VertexStrain, law: MembraneLaw, params: dict) -> tuple[Array, Array]:
    """Principal tensions τ1 ≥ τ2 at the vertices, τi = e^{−Λ1}(W_1 + W_2 λi²) (the
    eigenvalues of T in the tangent plane; seed 2.7 in principal axes)."""
    l1, l2 = strain.principal_stretches
    return kernels.principal_tensions(*_law_derivatives(strain, law, params), strain.inv1, l1, l2)


#: row_tension_summary's counts when every vertex stands for itself
_ONE_EACH = np.zeros(0)


def row_tension_summary(strain: VertexStrain, law: MembraneLaw, params: dict, modulus: float, threshold: float,
                        counts: Array | None = None) -> tuple[float, float, float]:
    """What a recorded row reads of the membrane's state, in one pass: the largest principal stretch,
    the smallest τ2 of :func:`principal_tensions` times ``modulus`` and the share of the vertices with
    τ2 below ``threshold`` (each standing for ``counts`` vertices: one vertex of each symmetry orbit)."""
    l1, l2 = strain.principal_stretches
    return kernels.membrane_row_summary(*_law_derivatives(strain, law, params), strain.inv1, l1, l2, float(modulus),
                                        threshold, _ONE_EACH if counts is None else counts)


# ---------------------------------------------------------------- bending

# Sphere calibration of the hinge energy: for a smooth surface triangulated
# near-equilaterally, θ_e ≈ κ_⊥ (h1 + h2)/3 across an edge, so that
# Σ θ_e² |e|²/A_e → (4/3) ∫ ⟨κ_⊥²⟩ dA; on a sphere ⟨κ_⊥²⟩ = H², and (3/2) of it
# is the Helfrich energy (κ/2) ∫ (2H)² dA (tests/numerics/test_bending.py checks 8πκ).
HINGE_CALIBRATION = 1.5


def surface_hinges(triangles: Array) -> Array:
    """(H, 4) hinges (o1, o2, a, b) of a closed, consistently oriented triangulation:
    a→b is an edge of triangle (a, b, o1) and b→a of triangle (b, a, o2)."""
    tri = np.asarray(triangles, dtype=np.int64)
    directed = {}
    for t in tri:
        for k in range(3):
            a, b, o = int(t[k]), int(t[(k + 1) % 3]), int(t[(k + 2) % 3])
            if (a, b) in directed:
                raise ValueError("triangulation is not consistently oriented (an edge repeats in one direction)")
            directed[(a, b)] = o
    hinges = []
    for (a, b), o1 in directed.items():
        if a < b:
            if (b, a) not in directed:
                raise ValueError(f"edge ({a}, {b}) has one triangle: the surface is not closed")
            hinges.append((o1, directed[(b, a)], a, b))
    return np.array(hinges, dtype=np.int64)


@dataclass(frozen=True)
class HingeBending:
    """Bending resistance relative to the rest shape, as a dihedral-hinge energy

        E_b = (3/2) κ Σ_e (θ_e − θ̄_e)² |ē|² / Ā_e

    over the edges of the linear sub-triangulation of the quadratic mesh (four
    straight triangles per element), θ the signed angle between the outward
    normals of the two triangles at edge e, θ̄, |ē| and Ā_e (the two triangles'
    area) at the rest shape. On a smooth surface it tends to the Helfrich energy
    (κ/2) ∫ (2H − 2H̄)² dA plus a deviatoric part of the same order (a hinge sees
    the normal curvature across its edge), with κ = ``modulus`` in units of E_s a².
    Its gradient is added to the membrane's energy gradient (Galerkin forces).
    """

    hinges: Array
    theta0: Array
    weight: Array
    modulus: float

    @classmethod
    def from_rest(cls, rest_positions: Array, elements: Array, modulus: float | Array) -> "HingeBending":
        """``modulus``: κ, or one κ per node (several capsules: each hinge takes its edge's first
        node's; ``modulus`` then keeps the largest)."""
        triangles = linear_subtriangles(elements)
        hinges = surface_hinges(triangles)
        X = np.ascontiguousarray(rest_positions, dtype=np.float64)
        o1, o2, a, b = hinges.T
        e = X[b] - X[a]
        area = 0.5 * (np.linalg.norm(np.cross(e, X[o1] - X[a]), axis=1)
                      + np.linalg.norm(np.cross(X[o2] - X[a], e), axis=1))
        length2 = np.einsum("ij,ij->i", e, e)
        kappa = modulus if np.ndim(modulus) == 0 else np.asarray(modulus, dtype=np.float64)[a]
        weight = HINGE_CALIBRATION * kappa * length2 / area
        theta0 = hinge_angles(X, hinges)
        return cls(hinges, theta0, np.ascontiguousarray(weight), float(np.max(modulus)))

    def energy_gradient(self, x: Array) -> tuple[float, Array]:
        return kernels.hinge_bending_gradient(np.ascontiguousarray(x), self.hinges, self.theta0, self.weight)


def hinge_angles(x: Array, hinges: Array) -> Array:
    """Signed dihedral angles θ of the hinges (positive where convex)."""
    return kernels.hinge_angles(np.ascontiguousarray(x, dtype=np.float64), np.asarray(hinges, dtype=np.int64))


# ---------------------------------------------------------------- membrane force

TRACTION_METHODS = ("galerkin", "contour")


# ---------------------------------------------------------------- the mass-matrix solve

#: a configuration farther than this (relative to its size) from having the mesh's symmetry
#: has its mass matrix solved in full: a run's positions have it to the bit (they are
#: expanded from the targets), a finite-difference probe of size ε·|v| does not
ASYMMETRY_TOL = 1e-13

#: fill-reducing ordering of the reduced mass matrix's factorisation (scipy's splu): MMD on
#: A + Aᵀ keeps the factor small (about 2.4× the nonzeros of the full matrix at level 3)
MASS_ORDERING = "MMD_AT_PLUS_A"


@dataclass(frozen=True)
class ReducedMass:
    """The mass-matrix solve M·Δf = b (three components) on the unknowns that the mesh's
    symmetry leaves: y, one per (target node, component) that the symmetry does not force
    to zero, with Δf = E y, Δf[j, c] = sign[j, c]·y[col[j, c]] (0 where col is −1).
    For an equivariant b (the energy gradient at a symmetric configuration) the Galerkin
    system K y = Eᵀ b, K = Eᵀ (M ⊗ I₃) E (SPD), has the solution of the full system, at
    about a quarter of its size under quarter symmetry; without symmetry K is M three
    times on the diagonal. Built once per discretisation: K's CSR pattern and, for every
    entry of M's rows at the target nodes and component c, its slot in K (−1: none) and
    weight (its sign times the orbit's size): K from the target rows alone
    (``data_from_target_rows``)."""

    col: Array
    sign: Array
    target_node: Array
    target_comp: Array
    inv_mult: Array
    indptr: Array
    indices: Array
    row_entries: Array
    row_slot: Array
    row_weight: Array
    diag_slot: Array   # the position of each row's diagonal entry in K's CSR values

    @property
    def size(self) -> int:
        return int(self.target_node.size)

    @classmethod
    def of(cls, disc) -> "ReducedMass":
        n = disc.n_nodes
        if disc.symmetry == "none":
            targets, source = np.arange(n), np.arange(n)
            signs, zero = np.ones((n, 3)), np.zeros((n, 3), dtype=bool)
        else:
            targets, source, signs, zero = disc.targets, disc._sym_source, disc._sym_signs, disc._sym_zero
        free = ~zero[targets]  # (n_t, 3): the unknowns; a node's zero components are its target's
        uid = np.full(free.shape, -1, dtype=np.int64)
        uid[free] = np.arange(int(free.sum()))
        col = uid[source]
        col[zero] = -1
        t_idx, comp = np.nonzero(free)  # row-major, the order of uid
        n_red = t_idx.size
        inv_mult = 1.0 / np.bincount(col[col >= 0], minlength=n_red)
        rows = np.repeat(np.arange(n), np.diff(disc.mass_indptr))
        cols = disc.mass_indices
        u, v = col[rows], col[cols]  # (nnz, 3)
        valid = (u >= 0) & (v >= 0)
        keys = np.where(valid, u * n_red + v, -1)
        uniq, inverse = np.unique(keys[valid], return_inverse=True)
        slot = np.full(keys.shape, -1, dtype=np.int64)
        slot[valid] = inverse
        indptr = np.concatenate([[0], np.cumsum(np.bincount(uniq // n_red, minlength=n_red))]).astype(np.int64)
        slot_sign = signs[rows] * signs[cols]
        # the entries of the target nodes' rows, each weighted by its orbit's size (row_weight)
        is_target = np.zeros(n, dtype=bool)
        is_target[targets] = True
        entries = np.flatnonzero(is_target[rows])
        row_u = u[entries]
        row_weight = np.where(row_u >= 0, slot_sign[entries] / inv_mult[np.maximum(row_u, 0)], 0.0)
        red_indices = (uniq % n_red).astype(np.int64)
        diag_slot = np.flatnonzero(red_indices == np.repeat(np.arange(n_red), np.diff(indptr)))
        assert diag_slot.size == n_red
        return cls(
            col=np.ascontiguousarray(col, dtype=np.int64), sign=np.ascontiguousarray(signs, dtype=np.float64),
            target_node=targets[t_idx].astype(np.int64), target_comp=comp.astype(np.int64),
            inv_mult=np.ascontiguousarray(inv_mult), indptr=indptr, indices=red_indices,
            row_entries=entries.astype(np.int64),
            row_slot=np.ascontiguousarray(slot[entries]), row_weight=np.ascontiguousarray(row_weight),
            diag_slot=diag_slot.astype(np.int64),
        )

    def data_from_target_rows(self, mass_data: Array) -> Array:
        """K's values from the rows of M at the target nodes alone (``Discretization.
        mass_matrix_data`` over ``target_elements``: the other rows need not be assembled, and
        a full M serves as well); by the group's invariance each row of an orbit contributes
        what the target's does, so this is Eᵀ (M ⊗ I₃) E to rounding at a configuration with
        the symmetry."""
        return kernels.reduced_mass_data_rows(mass_data, self.row_entries, self.row_slot, self.row_weight,
                                              int(self.indices.size))

    def rhs_from_target_rows(self, rhs: Array) -> Array:
        """b = Eᵀ rhs for an equivariant rhs from its target nodes' rows alone."""
        return kernels.reduce_rhs_at_targets(rhs, self.target_node, self.target_comp, self.inv_mult)


@dataclass(frozen=True)
class MassFactor:
    """The exact factorisation of the reduced mass matrix K0 at one configuration, as the
    arrays ``kernels.solve_reduced_mass`` takes: Pr K0 Pc = L U with L's strictly lower
    part and U's strictly upper part by columns (CSC), U's inverse diagonal, the
    permutations, K0's diagonal and the position of the diagonal in K's pattern (the
    solve scales the factor by √(diag K0 / diag K)). K0 is SPD and factored without
    pivoting (scipy's symmetric mode), so the preconditioner it gives is SPD too."""

    arrays: tuple

    @property
    def triangular(self) -> tuple:
        """The factor's own arrays (L, U, U's inverse diagonal, the permutations) without the
        diagonal scaling's: what an exact solve with K0 takes (``kernels.solve_reduced_direct``)."""
        return self.arrays[:-2]

    @classmethod
    def of(cls, reduced: ReducedMass, data: Array) -> "MassFactor":
        import scipy.sparse as sp
        from scipy.sparse.linalg import splu

        n = reduced.size
        k = sp.csc_matrix(sp.csr_matrix((data, reduced.indices, reduced.indptr), shape=(n, n)))
        lu = splu(k, permc_spec=MASS_ORDERING, diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        lower = sp.tril(lu.L, k=-1, format="csc")
        upper = sp.triu(lu.U, k=1, format="csc")

        def csc(a):
            return (a.indptr.astype(np.int64), a.indices.astype(np.int64), np.ascontiguousarray(a.data))

        return cls((*csc(lower), *csc(upper), np.ascontiguousarray(1.0 / lu.U.diagonal()),
                    lu.perm_r.astype(np.int64), lu.perm_c.astype(np.int64),
                    np.ascontiguousarray(data[reduced.diag_slot]), reduced.diag_slot))


@dataclass
class MembraneState:
    """Everything the membrane step produced at one configuration.

    The vertex strain and tension are computed on first use: the Galerkin
    traction does not need them, so the three evaluations of an RKF23 step skip
    them and only the recorded (accepted) states pay for them. So is the Galerkin
    traction per unit current area (``traction``): the evaluation solves for the force
    per unit rest area (``rest_traction``), which is what the single layer integrates
    over the rest shape's ``measure``.
    """

    geometry: Any      # geometry.ElementGeometry of the configuration
    density: Array     # Δf as the single layer takes it: (N_e, 6, 3) nodal (galerkin) or (N_e, 3) (contour)
    #: the vertex strain and a function giving the vertex tension (made when read)
    vertex_state: Callable[[], tuple[VertexStrain, Callable[[], Array]]] = field(repr=False)
    #: galerkin: the measure the density is per (RestTractionSolve: the rest shape's area
    #: element, solver.RestMeasure); None: per unit current area
    measure: Any = None
    #: galerkin: the solved nodal field (N_p, 3): F per unit rest area with a measure, else Δf
    solved: Array | None = None
    current_traction: Callable[[], Array] | None = field(default=None, repr=False)
    mass_iterations: int = 0
    #: a symmetric configuration's vertex strain at one vertex of each orbit and the orbits' numbers
    #: of vertices (MembraneForce.orbit_strain); None: the whole membrane's
    orbit_state: Callable[[], tuple[VertexStrain, Array]] | None = field(default=None, repr=False)

    @property
    def row_strain(self) -> tuple[VertexStrain, Array | None]:
        """The vertex strain a recorded row reads and how many vertices each of its stands for (None: one):
        at one vertex of each orbit of a symmetric configuration unless the whole membrane's is made."""
        if self.orbit_state is None or "_vertex" in self.__dict__:
            return self.strain, None
        return self.orbit_state()

    @cached_property
    def _vertex(self) -> tuple[VertexStrain, Array]:
        return self.vertex_state()

    @property
    def strain(self) -> VertexStrain:
        return self._vertex[0]

    @cached_property
    def tension(self) -> Array:
        """(N_v, 3, 3) Cauchy tension at the vertex nodes (seed 2.7)."""
        return self._vertex[1]()

    @cached_property
    def traction(self) -> Array:
        """Δf per unit current area: (N_p, 3) nodal (galerkin; with a rest measure the
        quadratic field with the same moments ∫ φ_i Δf dA as the rest traction's
        ∫ φ_i F dA0, solved when read), or (N_e, 3) per element (contour)."""
        if self.current_traction is not None:
            return self.current_traction()
        return self.density if self.solved is None else self.solved

    @property
    def rest_traction(self) -> Array | None:
        """F = Δf dA/dA0 at the nodes (N_p, 3) when the solve was per unit rest area, else None."""
        return None if self.measure is None else self.solved

    @property
    def weights(self) -> Array:
        """The regular rule's weights that ``density`` is integrated with: the rest shape's
        (galerkin) or the configuration's (contour)."""
        return self.geometry.weights if self.measure is None else self.measure.reg_weights


class RestTractionSolve:
    """The Galerkin traction per unit rest area (measure "rest", the elastic laws): F with
    M0·F = ∂E/∂x, M0 the rest shape's mass matrix, factorised once on the unknowns the
    mesh's symmetry leaves (``ReducedMass``) and solved exactly by that factor at every
    evaluation (no assembly, no iterations, no state); the single layer integrates F over
    the rest shape's ``measure`` (``solver.RestMeasure``). ``MembraneForce`` explains why."""

    name = "rest"

    def __init__(self, force: "MembraneForce"):
        self.force = force
        self.reset()

    def reset(self) -> None:
        """Forget everything built from the rest shape (a new one)."""
        self._measure = None
        self._data: Array | None = None  # M0's values (_mass_data)
        self._factor: MassFactor | None = None
        self._factor_for: ReducedMass | None = None  # the unknowns it was made on
        self._full_lu = None

    @property
    def measure(self):
        """The rest shape's area element at every rule point (``solver.RestMeasure``)."""
        if self._measure is None:
            self._measure = self.force.disc.rest_measure(self.force.rest_positions)
        return self._measure

    def _mass_data(self) -> Array:
        """M0's values in the mass-matrix pattern (assembled once)."""
        if self._data is None:
            disc = self.force.disc
            self._data = disc.mass_matrix_data(disc.geometry(np.ascontiguousarray(self.force.rest_positions)))
        return self._data

    def mass_matrix(self):
        """M0, the (scalar) mass matrix of the rest shape, as a SciPy CSR matrix (N_p × N_p)."""
        import scipy.sparse as sp

        disc = self.force.disc
        return sp.csr_matrix((self._mass_data(), disc.mass_indices, disc.mass_indptr), shape=(disc.n_nodes,) * 2)

    def mass_lu(self):
        """SciPy's LU of the whole M0 (made once): solves for any right-hand side."""
        if self._full_lu is None:
            from scipy.sparse.linalg import splu

            self._full_lu = splu(self.mass_matrix().tocsc())
        return self._full_lu

    def frozen(self, x: Array, geo) -> tuple:
        """(M, its LU, the measure) of the linearly implicit scheme's step at x: M0's."""
        return self.mass_matrix(), self.mass_lu(), self.measure

    def solve_equivariant(self, rhs: Array) -> Array:
        """M0⁻¹ rhs (N_p, 3) for an equivariant rhs (read at the target nodes only), on the
        unknowns the mesh's symmetry leaves, by the factor of the reduced M0 (made once per
        symmetry); the viscous membrane's inner solves use it too."""
        reduced = self.force.reduced_mass()
        if self._factor is None or self._factor_for is not reduced:
            self._factor = MassFactor.of(reduced, reduced.data_from_target_rows(self._mass_data()))
            self._factor_for = reduced
        return kernels.solve_reduced_direct(rhs, reduced.target_node, reduced.target_comp, reduced.inv_mult,
                                            reduced.col, reduced.sign, *self._factor.triangular)

    def solve(self, x: Array, geo, rhs: Array, symmetric: bool, clock) -> tuple[Array, int]:
        """F with M0·F = rhs (N_p, 3), and 0 iterations: ``solve_equivariant`` with the mesh's
        symmetry (rhs the energy gradient at a symmetric configuration), otherwise (a
        finite-difference probe without the symmetry) the LU of the whole M0."""
        traction = self.solve_equivariant(rhs) if symmetric else self.mass_lu().solve(np.asfortranarray(rhs))
        clock.lap("mass_solve")
        return traction, 0

    def state(self) -> dict:
        return {}

    def restore(self, state: dict) -> None:
        pass


class CurrentTractionSolve:
    """The Galerkin traction per unit current area (measure "current", the clean drop): Δf
    with M(x)·Δf = ∂E/∂x, M assembled at every evaluation (under a symmetry only on the
    elements holding a target: its target rows) and solved on the unknowns the symmetry
    leaves by conjugate gradients from the previous Δf, preconditioned by a factorisation
    kept while it serves and scaled on both sides by √(diag K0 / diag K), the local change
    of area since it was made (``kernels.solve_reduced_mass``): 2-3 iterations at level 3.
    The previous Δf and where the factor was made are the warm start, part of ``state()``."""

    name = "current"
    measure = None

    def __init__(self, force: "MembraneForce", *, tol: float = 1e-8, max_iter: int = 500,
                 refactor_iterations: int = 4):
        self.force = force
        self.tol = tol
        self.max_iter = max_iter
        # refactored where a solve needed more than refactor_iterations iterations; the
        # pattern never changes, the values slowly
        self.refactor_iterations = int(refactor_iterations)
        self.factor: MassFactor | None = None
        self.factor_x: Array | None = None
        self.factorizations = 0
        self.last: Array | None = None

    def reset(self) -> None:
        pass

    def frozen(self, x: Array, geo) -> tuple:
        """(M, its LU, the measure) of the linearly implicit scheme's step at x: M(x)'s."""
        from scipy.sparse.linalg import splu

        mass = self.force.disc.mass_matrix(geo)
        return mass, splu(mass.tocsc()), None

    def solve(self, x: Array, geo, rhs: Array, symmetric: bool, clock) -> tuple[Array, int]:
        """Δf with M(x)·Δf = rhs and the iterations (the reduced system from the target
        nodes' rows of M and rhs with the symmetry, else the full one)."""
        disc = self.force.disc
        data = disc.mass_matrix_data(geo, disc.target_elements if symmetric else None)
        clock.lap("mass_assembly")
        if symmetric:
            reduced = self.force.reduced_mass()
            out = self._solve_reduced(x, reduced.data_from_target_rows(data), reduced.rhs_from_target_rows(rhs))
        else:
            out = self._solve_full(data, rhs)
        clock.lap("mass_solve")
        return out

    def _factor(self, x: Array, data: Array) -> MassFactor:
        """The factorisation in use: the kept one, else that at factor_x (a restored state),
        else that at x (data: the reduced mass matrix at x)."""
        if self.factor is None:
            reduced = self.force.reduced_mass()
            if self.factor_x is None:
                self.factor_x = np.array(x, copy=True)
            else:
                disc = self.force.disc
                geo = disc.geometry(self.factor_x)
                data = reduced.data_from_target_rows(disc.mass_matrix_data(geo, disc.target_elements))
            self.factor = MassFactor.of(reduced, data)
            self.factorizations += 1
        return self.factor

    def _solve_full(self, mass_data: Array, rhs: Array) -> tuple[Array, int]:
        # a configuration without the mesh's symmetry (a finite-difference probe of a
        # Jacobian): the right-hand side is not equivariant and the reduced system would
        # drop its other part; the full system by Jacobi-preconditioned CG, the kept
        # factorisation untouched
        disc = self.force.disc
        guess = self.last if self.last is not None else np.zeros_like(rhs)
        traction, iterations = kernels.block_cg(
            disc.mass_indptr, disc.mass_indices, mass_data, rhs, guess, self.tol, self.max_iter)
        self.last = traction
        return traction, int(iterations)

    def _solve_reduced(self, x: Array, data: Array, b: Array) -> tuple[Array, int]:
        reduced = self.force.reduced_mass()
        guess = self.last if self.last is not None else np.zeros(reduced.col.shape)
        factor = self._factor(x, data)
        traction, iterations = kernels.solve_reduced_mass(
            reduced.indptr, reduced.indices, data, b, guess, reduced.col, reduced.sign, reduced.target_node,
            reduced.target_comp, reduced.inv_mult, self.tol, self.max_iter, *factor.arrays,
        )
        if iterations > self.refactor_iterations:
            self.factor = MassFactor.of(reduced, data)
            self.factor_x = np.array(x, copy=True)
            self.factorizations += 1
        self.last = traction
        return traction, int(iterations)

    def state(self) -> dict:
        """The warm start: the last Δf and where the mass matrix was factored (together they
        make the next solve bit for bit)."""
        def copy(a):
            return None if a is None else np.array(a, copy=True)

        return {"traction": copy(self.last), "factor_x": copy(self.factor_x)}

    def restore(self, state: dict) -> None:
        t = state.get("traction")
        self.last = None if t is None else np.array(t, dtype=np.float64, copy=True)
        fx = state.get("factor_x")
        fx = None if fx is None else np.array(fx, dtype=np.float64, copy=True)
        if fx is None or self.factor_x is None or not np.array_equal(fx, self.factor_x):
            self.factor = None  # refactored at fx (or at the next configuration) on first use
        self.factor_x = fx


#: how the Galerkin traction is solved, by the measure its law names (MembraneLaw.measure)
TRACTION_MEASURES = {"rest": RestTractionSolve, "current": CurrentTractionSolve}


class MembraneForce:
    """Positions → membrane state with the traction jump Δf (bending included).

    Built once per run from the discretisation (``solver.Discretization``: the
    mesh, its quadrature tables and the mass-matrix pattern), the rest positions,
    the law and its parameters, the bending modulus κ (0: none) and the traction
    method:

    galerkin: by virtual work (every node, mid-edge nodes included, is elastically
    restrained), the traction's moments against every basis function are the energy
    gradient, ∫ φ_i Δf dA = ∂E/∂x_i with E = ∫ W dA_0 (+ the hinge bending energy).
    How it is solved is the law's ``measure`` (``TRACTION_MEASURES``): per unit rest
    area for the elastic laws (``RestTractionSolve``): with F = Δf dA/dA0 the same
    moments read ∫ φ_i F dA0 = ∂E/∂x_i, M0·F = ∂E/∂x with M0 the rest shape's mass
    matrix, the same at every configuration (a total Lagrangian form), and the single
    layer integrates F over the rest shape's measure, ∫ G·F dA0 = ∫ G·Δf dS. The
    quadratic F and the quadratic Δf of M(x)·Δf = ∂E/∂x have the same moments against
    every quadratic, so every integral of a quadratic against them agrees (the
    stresslet's ∫ Δf x dS among them: x is quadratic) and their single layers differ
    only by the kernel's departure from a quadratic, O(h³) (docs/known_answers.md,
    "Exact and classical": the traction's measure). Per unit current area for the
    clean drop (``CurrentTractionSolve``), whose nodes drift with the surface flow.
    ``MembraneState.traction`` is Δf per unit current area either way.
    contour: the seed's element average (3.6), −(1/S_e)∮ T·b dl from vertex
    tensions, used element-constant (3.7), per unit current area.

    ``stage_times`` accumulates the seconds spent on the geometry and on the
    membrane mechanics; ``evaluations`` counts the calls.
    """

    def __init__(
        self,
        disc,
        rest_positions: Array,
        law: MembraneLaw | None = None,
        law_params: dict | None = None,
        *,
        bending_modulus: float = 0.0,
        bending: HingeBending | None = None,
        traction_method: str = "galerkin",
        material: dict | None = None,
    ):
        if traction_method not in TRACTION_METHODS:
            raise ValueError(f"unknown traction method {traction_method!r} (allowed: {TRACTION_METHODS})")
        self.disc = disc
        self.law = law if law is not None else get_law("thin_shell")
        self.traction_solve = TRACTION_MEASURES[self.law.measure](self)
        self.rest_positions = rest_positions
        self.law_params = dict(law_params or {})
        #: several capsules of their own membranes (capsim.scene.bodies.materials): the law's parameters and
        #: the modulus per element and per vertex, κ per node; None: one membrane everywhere
        self.material = material
        if material is not None and bending is None and float(np.max(material["node_bending"])) > 0.0:
            bending = HingeBending.from_rest(rest_positions, disc.elements, material["node_bending"])
        elif bending is None and bending_modulus > 0.0:
            bending = HingeBending.from_rest(rest_positions, disc.elements, bending_modulus)
        if bending is not None and traction_method != "galerkin":
            raise ValueError("bending needs the galerkin traction method")
        self.bending = bending
        self.traction_method = traction_method
        self._reduced_mass: tuple[str, ReducedMass] | None = None  # (the symmetry it is for, the tables)
        self.stage_times = {"geometry": 0.0, "membrane": 0.0}
        self.evaluations = 0
        self.last_mass_iterations = 0  # iterations of the last mass-matrix solve

    def state(self) -> dict[str, Array | None]:
        """The traction solve's warm start (per unit current area: the last Δf and where the
        mass matrix was factored; per unit rest area: none) and the counter."""
        return {**self.traction_solve.state(), "evaluations": np.array(self.evaluations, dtype=np.int64)}

    def restore(self, state: dict) -> None:
        self.traction_solve.restore(state)
        self.evaluations = int(state.get("evaluations", 0))

    def reduced_mass(self) -> ReducedMass:
        """The tables of the mass solve on the unknowns the mesh's symmetry leaves, built once
        per symmetry (the viscous membrane's solve uses the same unknowns)."""
        if self._reduced_mass is None or self._reduced_mass[0] != self.disc.symmetry:
            self._reduced_mass = (self.disc.symmetry, ReducedMass.of(self.disc))
        return self._reduced_mass[1]

    @property
    def rest_positions(self) -> Array:
        return self._rest_positions

    @rest_positions.setter
    def rest_positions(self, value: Array) -> None:
        self._rest_positions = value
        self._rest_metric = None  # the rest shape's metric at the Gauss points, built on first use
        self._rest_inverse = None  # ... and its frames at the vertices (kernels.vertex_rest_inverse)
        self.traction_solve.reset()

    def _symmetric(self, x: Array) -> bool:
        reduced = self.reduced_mass()
        return kernels.asymmetry(x, reduced.col, reduced.sign, reduced.target_node) <= ASYMMETRY_TOL * np.abs(x).max()

    def current_traction(self, geo, rhs: Array) -> Array:
        """Δf per unit current area: M(x)·Δf = rhs by the sparse LU of M at x (not the
        evaluation's path when the solve is per unit rest area: read by the exports)."""
        from scipy.sparse.linalg import splu

        return splu(self.disc.mass_matrix(geo).tocsc()).solve(np.asfortranarray(rhs))

    def _vertex_state(self, x: Array) -> tuple[VertexStrain, Callable[[], Array]]:
        """The vertex strain at x, and the vertex tension as a function (issue 57: a recorded row reads
        the strain alone, the principal stretches and tensions; the tension tensor, ~35 µs at level 3,
        only the contour traction and the exports)."""
        disc = self.disc
        strain = self._vertex_strain(x, disc.all_elements, disc.all_vertices)
        return strain, lambda: self._vertex_tension(strain)

    def _vertex_strain(self, x: Array, elems: Array, vertices: Array) -> VertexStrain:
        """The strain at ``vertices`` from ``elems`` (every element of each of them): kernels.vertex_strain."""
        disc = self.disc
        if self._rest_inverse is None:
            self._rest_inverse = kernels.vertex_rest_inverse(
                np.ascontiguousarray(self.rest_positions, dtype=np.float64), disc.elements, disc.n_vertices,
                disc.vertex_dxi, disc.vertex_deta)[0]
        A, normals, B, inv1, inv2, l1, l2 = kernels.vertex_strain(
            x, disc.elements, disc.n_vertices, disc.vertex_dxi, disc.vertex_deta, self._rest_inverse, elems, vertices)
        strain = VertexStrain(A, B, normals, inv1, inv2)
        # the kernel's principal stretches as the cached property's value (a row reads them: issue 57)
        strain.__dict__["principal_stretches"] = (l1, l2)
        return strain

    def orbit_strain(self, x: Array) -> tuple[VertexStrain, Array]:
        """The vertex strain of a symmetric configuration at one vertex of each orbit, and the orbits'
        numbers of vertices: what a recorded row reads of it (the largest stretch,
        the smallest tension, the compressed share) at a quarter of the work under quarter symmetry
        (issue 57). The mesh's symmetry group maps vertices to vertices, and a symmetric x has the
        same strain at every vertex of an orbit (to round-off)."""
        disc = self.disc
        vertices, elems, counts = disc.vertex_orbits()
        return self._vertex_strain(x, elems, vertices), counts

    def _vertex_tension(self, strain: VertexStrain) -> Array:
        material = self.material
        if material is None:
            return tension_tensor(strain, self.law, self.law_params)
        tension = tension_tensor(strain, self.law, material["vertex_params"])
        return material["vertex_scale"][:, None, None] * tension

    def gauss_point_strain(self, x: Array, elems: Array | None = None) -> tuple[Array, ...]:
        """Λ1, Λ2, the dual tangents and J0 at the Gauss points of ``elems`` (default: every
        element) at configuration x (``kernels.gauss_point_strain``)."""
        disc = self.disc
        if self._rest_metric is None:
            self._rest_metric = kernels.rest_metric(
                np.ascontiguousarray(self.rest_positions, dtype=np.float64), disc.elements, disc.mem_dxi,
                disc.mem_deta)
        elems = disc.all_elements if elems is None else elems
        return kernels.gauss_point_strain(x, disc.elements, elems, disc.mem_dxi, disc.mem_deta, self._rest_metric)

    def _energy_gradient(self, x: Array, elems: Array | None = None) -> Array:
        """∂E/∂x, complete at every node all of whose elements are in ``elems`` (default all)."""
        disc = self.disc
        elems = disc.all_elements if elems is None else elems
        inv1, inv2, dual_cur, dual_ref, jac0 = self.gauss_point_strain(x, elems)
        material = self.material
        if material is None:
            w1, w2 = self.law.derivatives(inv1, inv2, **self.law_params)
        else:  # several capsules of their own membranes: parameters and modulus per element
            params = {k: v[elems][:, None] for k, v in material["element_params"].items()}
            w1, w2 = self.law.derivatives(inv1, inv2, **params)
            scale = material["element_scale"][elems][:, None]
            w1, w2 = w1 * scale, w2 * scale
        rhs = kernels.galerkin_energy_gradient(
            disc.elements, elems, disc.n_nodes, disc.mem_dxi, disc.mem_deta, disc.mem_w,
            jac0, np.ascontiguousarray(w1), np.ascontiguousarray(w2), dual_cur, dual_ref,
        )
        if self.bending is not None:
            rhs = rhs + self.bending.energy_gradient(x)[1]
        return rhs

    def energy_gradient(self, x: Array) -> Array:
        """∂E/∂x at every node (N_p, 3): the right-hand side of M·Δf = ∂E/∂x
        (galerkin only; bending included). The linearly implicit scheme
        differentiates it (capsim.numerics.linearization)."""
        if self.traction_method != "galerkin":
            raise ValueError("the energy gradient needs the galerkin traction method")
        return self._energy_gradient(np.ascontiguousarray(x, dtype=np.float64))

    def element_traction(self, x: Array, geo=None, tension: Array | None = None) -> Array:
        """The contour method's element-constant Δf (N_e, 3) at x (seed 3.6–3.7; no
        counters): from the geometry and vertex tensions, computed here unless given."""
        disc = self.disc
        geo = disc.geometry(x) if geo is None else geo
        tension = self._vertex_state(x)[1]() if tension is None else tension
        return kernels.element_tractions(
            x, disc.elements, np.ascontiguousarray(tension), disc.contour_s, disc.contour_w, geo.element_areas,
        )

    def __call__(self, x: Array) -> MembraneState:
        """Tensions and the traction jump Δf at configuration x."""
        self.evaluations += 1
        clock = self.disc.clock
        clock.start()
        t0 = time.perf_counter()
        disc = self.disc
        geo = disc.geometry(x)
        t1 = time.perf_counter()
        self.stage_times["geometry"] += t1 - t0
        clock.lap("geometry")
        vertex_state = lambda: self._vertex_state(x)  # noqa: E731
        if self.traction_method == "contour":
            state = MembraneState(geo, np.empty(0), vertex_state)
            state.density = self.element_traction(x, geo, state.tension)
            self.stage_times["membrane"] += time.perf_counter() - t1
            clock.lap("contour_traction")
            return state
        # with the symmetry the reduced solve reads only the target nodes' rows: the strain and
        # the energy gradient on the elements holding a target (175 of 512 at level 3 under
        # quarter symmetry)
        symmetric = self._symmetric(x)
        rhs = self._energy_gradient(x, disc.target_elements if symmetric else None)
        clock.lap("strain")
        solved, iterations = self.traction_solve.solve(x, geo, rhs, symmetric, clock)
        self.last_mass_iterations = iterations
        density = kernels.gather_nodal(solved, disc.elements)
        self.stage_times["membrane"] += time.perf_counter() - t1
        clock.lap("gather")
        measure = self.traction_solve.measure
        current = None
        if measure is not None:  # Δf per unit current area when read (the other rows of rhs expanded then)
            def current() -> Array:
                return self.current_traction(geo, disc.expand(rhs[disc.targets]) if symmetric else rhs)
        orbit_state = (lambda: self.orbit_strain(x)) if symmetric and disc.symmetry != "none" else None  # noqa: E731
        return MembraneState(geo, density, vertex_state, measure, solved, current, iterations, orbit_state)
