"""The conduits' fully developed flows (capsim/scene/conduit_profiles.py), U = 1, μ = 1."""

import numpy as np
import pytest

from capsim.scene.conduit_profiles import (ZETA5, duct_centerline_velocity, duct_gradient, duct_pressure_gradient,
                                           duct_velocity, duct_wall_shear, tube_gradient, tube_pressure_gradient,
                                           tube_velocity, tube_wall_shear)

T, W = np.polynomial.legendre.leggauss(80)
DUCTS = [(1.0, 1.0), (1.0, 0.4), (0.3, 1.7)]


def test_tube_mean_wall_shear_and_gradient():
    R = 0.7
    # polar Gauss–Legendre (exact for this polynomial)
    r, wr = 0.5 * R * (T + 1), 0.5 * R * W
    th = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    rr, tt = np.meshgrid(r, th, indexing="ij")
    u = tube_velocity(rr * np.cos(tt), rr * np.sin(tt), R)
    mean = np.sum(wr[:, None] * rr * u) * (2 * np.pi / len(th)) / (np.pi * R**2)
    assert mean == pytest.approx(1.0, abs=1e-14)
    assert tube_velocity(R * np.cos(th), R * np.sin(th), R) == pytest.approx(0.0, abs=1e-15)
    # force balance: wall shear × perimeter = G × area
    assert tube_wall_shear(R) * 2 * np.pi * R == pytest.approx(tube_pressure_gradient(R) * np.pi * R**2, rel=1e-15)
    p = np.array([[0.3, R, 0.0], [0.0, 0.2, -0.3]])
    L = tube_gradient(p, R)
    assert np.hypot(L[0, 0, 1], L[0, 0, 2]) == pytest.approx(tube_wall_shear(R), rel=1e-15)
    assert L[1, 0, 1] == pytest.approx(-4 * 0.2 / R**2) and L[1, 0, 2] == pytest.approx(4 * 0.3 / R**2)
    assert np.count_nonzero(L[:, 1:, :]) == 0 and np.count_nonzero(L[:, :, 0]) == 0


@pytest.mark.parametrize("a,b", DUCTS)
def test_duct_mean_is_one(a, b):
    y, z = np.meshgrid(a * T, b * T, indexing="ij")
    mean = np.sum(np.outer(W, W) * duct_velocity(y, z, a, b)) / 4
    # 80×80 Gauss–Legendre; the corner singularity (r² log r) limits it: measured |error| < 1e-13
    assert mean == pytest.approx(1.0, abs=1e-11)


@pytest.mark.parametrize("a,b", DUCTS)
def test_duct_vanishes_on_the_walls(a, b):
    s = np.concatenate([np.linspace(-1, 1, 41), [-1 + 1e-9, 1 - 1e-7, 0.999]])
    assert np.abs(duct_velocity(a * s, b, a, b)).max() < 1e-12
    assert np.abs(duct_velocity(a * s, -b, a, b)).max() < 1e-12
    assert np.abs(duct_velocity(a, b * s, a, b)).max() < 1e-12
    assert np.abs(duct_velocity(-a, b * s, a, b)).max() < 1e-12


@pytest.mark.parametrize("a,b", DUCTS)
def test_duct_laplacian_and_gradient_by_finite_differences(a, b):
    rng = np.random.default_rng(1)
    y, z = rng.uniform(-0.95 * a, 0.95 * a, 20), rng.uniform(-0.95 * b, 0.95 * b, 20)
    h = 1e-3 * min(a, b)
    u = lambda dy, dz: duct_velocity(y + dy, z + dz, a, b)
    lap = (u(h, 0) + u(-h, 0) + u(0, h) + u(0, -h) - 4 * u(0, 0)) / h**2
    G = duct_pressure_gradient(a, b)
    # O(h²) truncation (~1e-7 G) and round-off 1e-16/h² (~1e-9 G)
    assert np.abs(lap + G).max() < 1e-5 * G
    grad = duct_gradient(np.column_stack([np.zeros_like(y), y, z]), a, b)
    fd_y, fd_z = (u(h, 0) - u(-h, 0)) / (2 * h), (u(0, h) - u(0, -h)) / (2 * h)
    scale = G * max(a, b)
    assert np.abs(grad[:, 0, 1] - fd_y).max() < 1e-6 * scale
    assert np.abs(grad[:, 0, 2] - fd_z).max() < 1e-6 * scale
    assert np.count_nonzero(grad[:, 1:, :]) == 0


@pytest.mark.parametrize("a,b", DUCTS)
def test_duct_wall_shear_balances_the_pressure_gradient(a, b):
    # ∮ |du/dn| dl = G·area. 80-point Gauss–Legendre on each side after s = (15t − 10t³ + 3t⁵)/8,
    # which flattens the corners' r log r terms: measured 2e-12 (4e-8 without the substitution)
    s, ds = (15 * T - 10 * T**3 + 3 * T**5) / 8, 15 / 8 * (1 - T**2) ** 2
    top = np.column_stack([0 * s, a * s, np.full_like(s, b)])
    side = np.column_stack([0 * s, np.full_like(s, a), b * s])
    total = 2 * (a * (W * ds) @ duct_wall_shear(top, a, b) + b * (W * ds) @ duct_wall_shear(side, a, b))
    assert total == pytest.approx(duct_pressure_gradient(a, b) * 4 * a * b, rel=1e-10)
    # the shear vanishes at the corners and is largest mid-side of the long walls
    assert duct_wall_shear(np.array([[0.0, a, b]]), a, b)[0] == 0.0
    with pytest.raises(ValueError):
        duct_wall_shear(np.array([[0.0, 0.5 * a, 0.5 * b]]), a, b)


def test_square_duct_known_numbers():
    # Shah & London (1978): u_max/U = 2.0962 and fRe = 56.91 (Darcy f, Re on D_h = 2a) = 4 × 14.227 (Fanning)
    a = 0.8
    assert duct_centerline_velocity(a, a) == pytest.approx(2.0962, abs=1e-4)
    G = duct_pressure_gradient(a, a)
    # Darcy f = 8 τ_w/(ρU²), mean τ_w = G·area/perimeter = G a/2, Re = U·2a: fRe = 8 G a²
    assert 8 * G * a**2 == pytest.approx(56.91, abs=5e-3)


def test_symmetric_under_swapping_the_sides():
    y, z = np.array([0.1, -0.7, 0.35]), np.array([0.2, 0.05, -0.15])
    assert duct_velocity(y, z, 1.0, 0.4) == pytest.approx(duct_velocity(z, y, 0.4, 1.0), abs=1e-13)
    assert duct_velocity(y, z, 1.0, 0.4) == pytest.approx(duct_velocity(-y, -z, 1.0, 0.4), abs=1e-13)


@pytest.mark.parametrize("ratio", [0.1, 0.01, 0.001])
def test_wide_duct_tends_to_plane_poiseuille(ratio):
    # U/G = (b²/3)(1 − (192/π⁵)(31/32)ζ(5) b/a) and u_max/G = b²/2, each up to O(e^{−πa/(2b)}):
    # u_max/U = 1.5/(1 − 0.6302 b/a) → 1.5
    expected = 1.5 / (1 - 192 / np.pi**5 * 31 / 32 * ZETA5 * ratio)
    tol = 4 * np.exp(-np.pi / (2 * ratio)) + 1e-12   # 6e-7 at b/a = 0.1, then round-off
    assert duct_centerline_velocity(1.0, ratio) == pytest.approx(expected, rel=tol)
    assert duct_centerline_velocity(ratio, 1.0) == pytest.approx(expected, rel=tol)
    assert abs(duct_centerline_velocity(1.0, ratio) - 1.5) < 1.1 * ratio  # 0.945 b/a + O((b/a)²)


def test_points_outside_the_duct_are_refused():
    with pytest.raises(ValueError):
        duct_velocity(1.1, 0.0, 1.0, 0.5)
