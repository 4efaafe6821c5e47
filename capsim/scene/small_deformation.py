"""First-order small-deformation theory of an initially spherical capsule with a
Kelvin–Voigt membrane (docs/viscous_membrane.md, "Small-deformation theory"; derived
for capsim, extending Barthès-Biesel & Rallison 1981 as Barthès-Biesel & Sgaier 1985
do). Pure numpy: the plots and tests read it.

The membrane displacement from the rigidly rotating rest sphere and its velocity
relative to the rotation are quadratic fields of two traceless tensors each,

    ξ = n (n·A·n) + P B n,      u_rel = n (n·U·n) + P V n,

and every operator of the problem maps (A, B) linearly, with scalar 2 × 2 matrices
(eqs. V7–V10): the membrane tension of a displacement, Δf = n (n·F_n·n) + P F_t n,

    (F_n, F_t) = L(G_s, K_s) (A, B),   L(g, k) = [[4k, −6k], [−4k, 4g + 6k]],

the same L(μ_s, μ_d) for the viscous tension of (U, V); and the Stokes flow inside
and outside the sphere (Lamb's solution, degree 2) gives the membrane velocity of
the strain rate E and the traction jump:

    (U, V) = w E + R (F_n, F_t),   w = 5/(2λ + 3),
    R = −[[10(1 + λ), 3(2 + 3λ)], [2(2 + 3λ), 12 + 13λ]] / ((19λ + 16)(2λ + 3)).

With Z = I − R L(μ_s, μ_d) the shape then obeys (corotational rate, W the spin)

    dA/dt − [W, A] = U,  Z (U, V) = w E + R L(G_s, K_s) (A, B)          (V11)

Units: lengths a, time 1/k, tensions μka; so G_s/(μka) = 1/Ca and μ_s/(μa) = Bq_s.
Checks (tests/solve/test_viscous_theory.py): without viscosity the steady deformation is
D = (5/4)(2 + ν_s)/(1 + ν_s) Ca for every λ and the slow relaxation times are
2.63, 4.03, 11.0 μa/G_s at λ = 0.2, 1, 5 (docs/known_answers.md).

In a pure strain the steady shape is A = α G E with one constant α for every λ (25/2 for
K_s/G_s = 3): :func:`first_order_D_xy` gives D_xy of any linear flow to first order in G, each
flow kind's theory line (capsim.scene.flows ``Flow.first_order``) follows, and the plots
(capsim.face.plot.first_order_theory) ask the scene whether the theory's assumptions hold
(tests/face/test_theory_lines.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FirstOrder", "LinearCapsule", "NU_HALF_LAWS", "first_order_D_xy", "membrane_matrix", "mobility",
           "strain_coefficient"]


def mobility(lam: float) -> tuple[np.ndarray, np.ndarray]:
    """(w, R) of (V10): the membrane velocity of the strain rate and of the traction jump."""
    den = (19.0 * lam + 16.0) * (2.0 * lam + 3.0)
    w = np.full(2, 5.0 / (2.0 * lam + 3.0))
    R = -np.array([[10.0 * (1.0 + lam), 3.0 * (2.0 + 3.0 * lam)],
                   [2.0 * (2.0 + 3.0 * lam), 12.0 + 13.0 * lam]]) / den
    return w, R


def membrane_matrix(shear: float, area: float) -> np.ndarray:
    """L(g, k) of (V8): tension jump of a displacement with shear modulus g and area
    modulus k (or of a velocity with surface viscosities μ_s and μ_d)."""
    return np.array([[4.0 * area, -6.0 * area], [-4.0 * area, 4.0 * shear + 6.0 * area]])


@dataclass(frozen=True)
class LinearCapsule:
    """(V11) for one capsule: ``Ca`` = μka/G_s, ``area_over_shear`` = K_s/G_s (3 for the
    thin-shell and neo-Hookean laws), λ, and the Boussinesq numbers Bq = μ_s/(μa).
    capsim's G = μka/E_s gives Ca = 3G (every law has G_s = E_s/3)."""

    Ca: float
    viscosity_ratio: float = 1.0
    area_over_shear: float = 3.0
    Bq_shear: float = 0.0
    Bq_dilatational: float = 0.0

    @classmethod
    def from_G(cls, G: float, **kw) -> "LinearCapsule":
        return cls(Ca=3.0 * G, **kw)

    def _operators(self) -> tuple[np.ndarray, np.ndarray]:
        """(Q, c): at rest d(A, B)/dt = Q (A, B); in shear the strain rate adds c E."""
        w, R = mobility(self.viscosity_ratio)
        elastic = membrane_matrix(1.0 / self.Ca, self.area_over_shear / self.Ca)
        Z = np.eye(2) - R @ membrane_matrix(self.Bq_shear, self.Bq_dilatational)
        return np.linalg.solve(Z, R @ elastic), np.linalg.solve(Z, w)

    def jacobian(self, shear: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """(J, f) with dx/dt = J x + f for x = (a1, b1, a2, b2), the coefficients of A and B
        on S1 = e_x e_y + e_y e_x and S2 = e_x e_x − e_y e_y. In shear v = (y, 0, 0):
        E = S1/2 and [W, S1] = S2, [W, S2] = −S1."""
        Q, c = self._operators()
        J = np.zeros((4, 4))
        J[:2, :2] = J[2:, 2:] = Q
        f = np.zeros(4)
        if shear:
            J[:2, 2:] = -np.eye(2)
            J[2:, :2] = np.eye(2)
            f[:2] = 0.5 * c
        return J, f

    def relaxation_times(self) -> tuple[float, float]:
        """(slow, fast) kτ of the shape at rest: −1/eigenvalues of Q."""
        Q, _ = self._operators()
        rates = np.sort(-np.linalg.eigvals(Q).real)
        return float(1.0 / rates[0]), float(1.0 / rates[1])

    def steady_state(self) -> np.ndarray:
        J, f = self.jacobian(shear=True)
        return np.linalg.solve(J, -f)

    @staticmethod
    def shape(x: np.ndarray) -> tuple[float, float]:
        """(D_xy, θ) of a state: A has the in-plane eigenvalues ±|(a1, a2)|, so the
        equivalent ellipsoid's D = |(a1, a2)| and its long axis is at ½ atan2(a1, a2)."""
        return float(np.hypot(x[0], x[2])), float(0.5 * np.arctan2(x[0], x[2]))

    def steady_shear(self) -> tuple[float, float]:
        """(D_xy, θ) of the steady tank-treading state."""
        return self.shape(self.steady_state())

    def stresslet_xy(self, x: np.ndarray | None = None) -> tuple[float, float]:
        """(S*_xy, its viscous-membrane part) in steady shear (default) or at state x (eq. V12):
        S = ∫ T dA − (1 − λ) ∫ (u n + n u) dS over the unit sphere, with
        ∫ T dA = (π/15)[(48g + 24k) B − 16k A] for a tension 2g ε + (k − g) tr ε P
        (elastic: of (A, B) with G_s, K_s; viscous: of (U, V) with μ_s, μ_d) and
        ∫ (u n + n u) dS = (16π/15) U + (24π/15) V; S* = S/(2.5 · 4π/3). The xy component
        of a tensor is its S1 coefficient. N1 and N2 are not given: terms quadratic in E
        enter them at this order (docs/known_answers.md)."""
        x = self.steady_state() if x is None else x
        J, f = self.jacobian(shear=True)
        rate = J @ x + f   # d(A, B)/dt; the corotational rate (U, V) adds the spin back
        a1, b1, a2, b2 = x
        U1, V1 = rate[0] + a2, rate[1] + b2  # U = dA/dt − [W, A]: S1 part of −[W, A] is +a2

        def tension(g, k, a, b):
            return np.pi / 15.0 * ((48.0 * g + 24.0 * k) * b - 16.0 * k * a)

        elastic = tension(1.0 / self.Ca, self.area_over_shear / self.Ca, a1, b1)
        viscous = tension(self.Bq_shear, self.Bq_dilatational, U1, V1)
        flux = (1.0 - self.viscosity_ratio) * (16.0 * np.pi / 15.0 * U1 + 24.0 * np.pi / 15.0 * V1)
        scale = 2.5 * 4.0 * np.pi / 3.0
        return float((elastic + viscous - flux) / scale), float(viscous / scale)

    def relaxation(self, t: np.ndarray, x0: np.ndarray | None = None) -> np.ndarray:
        """D_xy(t) at rest from x0 (default: the steady shear state), t measured from the stop."""
        x0 = self.steady_state() if x0 is None else x0
        J, _ = self.jacobian(shear=False)
        vals, vecs = np.linalg.eig(J)
        coef = np.linalg.solve(vecs, x0.astype(complex))
        xs = (vecs[None] * (coef * np.exp(np.multiply.outer(np.asarray(t, float), vals)))[:, None, :]).sum(-1).real
        return np.hypot(xs[:, 0], xs[:, 2])


# ------------------------------------------------------------ first order in any linear flow


def strain_coefficient(area_over_shear: float = 3.0) -> float:
    """α of the first-order steady shape A = α G E in a pure strain E (units of the rate), for any
    λ and membrane viscosity (the steady state of (V11) without spin: (A, B) = −Q⁻¹ c E, Q ∝ 1/Ca,
    Ca = 3G). 25/2 for K_s/G_s = 3 (ν_s = 1/2): twice the shear's 25/4, E_shear having the
    in-plane eigenvalues ±1/2."""
    Q, c = LinearCapsule(Ca=1.0, area_over_shear=area_over_shear)._operators()
    return float(-np.linalg.solve(Q, c)[0]) * 3.0


def first_order_D_xy(velocity_gradient, G: float, area_over_shear: float = 3.0) -> float:
    """First-order steady D_xy of an initially spherical capsule in u∞ = L·x (L in units of the
    rate G is made with): the equivalent ellipse in the xy-plane has the semi-axes 1 + the
    eigenvalues of A's xy block, A = α G E, so D_xy = α G (e1 − e2)/2 with e1 ≥ e2 the eigenvalues
    of E's xy block. At this order the spin only turns the shape (shear: θ = π/4)."""
    L = np.asarray(velocity_gradient, dtype=np.float64)
    E = 0.5 * (L + L.T)
    e = np.linalg.eigvalsh(E[:2, :2])
    return strain_coefficient(area_over_shear) * G * float(e[1] - e[0]) / 2.0


@dataclass(frozen=True)
class FirstOrder:
    """A flow kind's first-order theory of an initially spherical, stress-free capsule (ν_s = 1/2):
    steady D_xy = ``D_over_G`` G; θ where the theory gives one; S*_xy and N1*/G where derived
    (docs/known_answers.md); ``source`` names where it comes from (the figures' legends)."""

    D_over_G: float
    source: str
    theta: float | None = None
    Sxy_star: float | None = None
    N1_over_G: float | None = None
    #: the tank-treading frequency over a rigid sphere's as G → 0 (shear: 1)
    ttf_ratio: float | None = None
    #: the impulsive start's transient D∞(1 − e^{−t/τ}) with the shear's τ (docs/known_answers.md)
    transient: bool = False

    @property
    def label(self) -> str:
        """'25G/4': D∞'s constant as a fraction of G (the legends)."""
        from fractions import Fraction

        f = Fraction(self.D_over_G).limit_denominator(64)
        return f"{f.numerator}G" + (f"/{f.denominator}" if f.denominator != 1 else "")



#: the laws whose small-strain K_s/G_s is 3 (ν_s = 1/2), the theory's lines' constants
#: (docs/laws.md; a Skalak law's ν_s depends on C: no line)
NU_HALF_LAWS = ("thin_shell", "neo_hookean", "mooney_rivlin")
