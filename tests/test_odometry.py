"""Tests of the IMU motion increment and dead reckoning (slamlib.odometry)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from slamlib.geometry import make_pose, rpy_to_matrix, skew
from slamlib.odometry import (
    dead_reckon,
    imu_increment,
    imu_increments,
    increment_matrix,
    so3_left_jacobian,
)


def _rel(a, b):
    return np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-12)


def test_straight_constant_velocity_is_exact():
    n, dt = 200, 0.1
    v = np.tile([10.0, 0.0, 0.0], (n, 1))
    T = dead_reckon(v, np.zeros((n, 3)), np.full(n, dt))
    assert np.allclose(T[-1, :3, 3], [10.0 * dt * (n - 1), 0, 0], rtol=1e-12)
    assert np.allclose(T[-1, :3, :3], np.eye(3))


@pytest.mark.parametrize("dt", [0.01, 0.1, 0.5])
def test_constant_turn_circle_is_exact(dt):
    speed, radius = 8.0, 25.0
    w = speed / radius
    n = int(2 * np.pi / w / dt) + 1
    T = dead_reckon(
        np.tile([speed, 0, 0], (n, 1)), np.tile([0, 0, w], (n, 1)), np.full(n, dt)
    )
    t = dt * np.arange(n)
    truth = np.c_[radius * np.sin(w * t), radius * (1 - np.cos(w * t)), np.zeros(n)]
    assert np.max(np.linalg.norm(T[:, :3, 3] - truth, axis=1)) < 1e-6 * radius
    yaw = Rotation.from_matrix(T[:, :3, :3]).as_euler("xyz")[:, 2]
    assert np.allclose(np.unwrap(yaw), w * t, atol=1e-9)


def test_helix_with_climb_is_exact():
    dt, n, v, w = 0.1, 300, np.array([5.0, 0.0, 0.5]), np.array([0.0, 0.0, 0.2])
    T = dead_reckon(np.tile(v, (n, 1)), np.tile(w, (n, 1)), np.full(n, dt))
    t = dt * (n - 1)
    truth = np.array(
        [5.0 / 0.2 * np.sin(0.2 * t), 5.0 / 0.2 * (1 - np.cos(0.2 * t)), 0.5 * t]
    )
    assert _rel(T[-1, :3, 3], truth) < 1e-6


def test_increment_convention_matches_backend_interface():
    rpy, tr = imu_increment(
        [3, 0.1, 0], [0.01, 0.02, 0.3], [3.2, 0.1, 0], [0.0, 0.02, 0.35], 0.1
    )
    inc = increment_matrix(rpy, tr)
    assert np.allclose(inc[:3, :3], rpy_to_matrix(rpy))
    T_old = make_pose(rpy_to_matrix([0.1, -0.2, 1.0]), [1, 2, 3])
    T_new = T_old @ inc
    # rotation increment is Exp(mean w dt)
    assert np.allclose(
        inc[:3, :3],
        Rotation.from_rotvec(0.1 * np.array([0.005, 0.02, 0.325])).as_matrix(),
    )
    assert np.allclose(T_new[:3, 3], T_old[:3, 3] + T_old[:3, :3] @ tr)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-3, 3), min_size=12, max_size=12), st.floats(0.01, 0.5))
def test_vectorised_equals_scalar_and_second_order(vals, dt):
    a = np.array(vals).reshape(4, 3)
    rpy_v, tr_v = imu_increments(
        a[None, 0], a[None, 1], a[None, 2], a[None, 3], np.array([dt])
    )
    rpy_s, tr_s = imu_increment(a[0], a[1], a[2], a[3], dt)
    assert np.allclose(rpy_v[0], rpy_s) and np.allclose(tr_v[0], tr_s)
    # small-angle: translation ~ mean v dt rotated by half the rotation, to second order in dt
    vb, wb = (a[0] + a[2]) / 2, (a[1] + a[3]) / 2
    half = Rotation.from_rotvec(wb * dt / 2).as_matrix() @ (vb * dt)
    assert (
        np.linalg.norm(tr_s - half)
        <= 0.05 * (np.linalg.norm(wb) * dt) ** 2 * np.linalg.norm(vb) * dt + 1e-12
    )


# ------------------------------------------------------------------ the formulas, value by value
def _c1_c2(a):
    """Reference coefficients of J, without cancellation: (1-cos a)/a^2 = sin(a/2)^2/(a^2/2); series for c2."""
    c1 = 0.5 * (np.sinc(a / 2 / np.pi)) ** 2
    c2 = (
        (1 / 6 - a**2 / 120 + a**4 / 5040 - a**6 / 362880)
        if a < 1e-2
        else (a - np.sin(a)) / a**3
    )
    return c1, c2


@pytest.mark.parametrize("a", [0.0, 1e-6, 5e-5, 9.9e-5, 2e-4, 1e-2, 0.5, 2.0, 3.0])
def test_left_jacobian_coefficients(a):
    # phi = (x, x, 0): J[0, 2] = c1 * x (K^2[0, 2] = 0) and J[0, 1] = c2 * x^2 (K[0, 1] = 0), so each
    # coefficient is read off one entry to full relative precision.
    x = a / np.sqrt(2)
    J = so3_left_jacobian([x, x, 0.0])
    c1, c2 = _c1_c2(a)
    # above the series threshold the closed form itself loses ~1e-16 / a^2 to cancellation
    rtol = 1e-13 if a < 1e-4 else max(1e-13, 1e-15 / a**2)
    if a > 0:
        assert J[0, 2] / x == pytest.approx(c1, rel=rtol, abs=0)
        assert J[0, 1] / x**2 == pytest.approx(c2, rel=rtol, abs=0)
    K = skew(np.array([x, x, 0.0]))
    np.testing.assert_allclose(J, np.eye(3) + c1 * K + c2 * K @ K, rtol=0, atol=1e-12)


def test_left_jacobian_batched():
    phi = np.array([[0.0, 0.0, 1e-5], [0.3, -0.2, 1.0]])
    J = so3_left_jacobian(phi)
    assert J.shape == (2, 3, 3)
    for k in range(2):
        np.testing.assert_allclose(J[k], so3_left_jacobian(phi[k]), atol=1e-15)


def test_left_jacobian_is_the_mean_rotation():
    # J(phi) = int_0^1 Exp(s phi) ds (Barfoot eq. 7.86), by Gauss-Legendre quadrature
    phi = np.array([0.4, -0.9, 1.3])
    s, w = np.polynomial.legendre.leggauss(30)
    s, w = (s + 1) / 2, w / 2
    ref = sum(wi * Rotation.from_rotvec(si * phi).as_matrix() for si, wi in zip(s, w))
    np.testing.assert_allclose(so3_left_jacobian(phi), ref, atol=1e-13)


def test_imu_increment_values_for_a_turn():
    # constant v = (4, 0, 0), w = (0, 0, 0.5) for dt = 0.2: yaw 0.1, chord of the circle of radius 8
    rpy, tr = imu_increment([4.0, 0, 0], [0, 0, 0.5], [4.0, 0, 0], [0, 0, 0.5], 0.2)
    np.testing.assert_allclose(rpy, [0.0, 0.0, 0.1], atol=1e-15)
    np.testing.assert_allclose(
        tr, [8.0 * np.sin(0.1), 8.0 * (1 - np.cos(0.1)), 0.0], rtol=1e-12, atol=1e-15
    )
    # the mean of the two samples is used: (2, 0, 0)+(6, 0, 0) and (0,0,0)+(0,0,1)
    rpy2, tr2 = imu_increment([2.0, 0, 0], [0, 0, 0.0], [6.0, 0, 0], [0, 0, 1.0], 0.2)
    np.testing.assert_allclose(rpy2, rpy, atol=1e-15)
    np.testing.assert_allclose(tr2, tr, atol=1e-15)


def test_increment_matrix_values():
    inc = increment_matrix([0.0, 0.0, np.pi / 2], [1.0, 2.0, 3.0])
    np.testing.assert_allclose(
        inc, [[0, -1, 0, 1], [1, 0, 0, 2], [0, 0, 1, 3], [0, 0, 0, 1]], atol=1e-15
    )


def test_dead_reckon_starts_at_T0_and_composes_on_its_right():
    T0 = make_pose(rpy_to_matrix([0.1, -0.2, 0.7]), [5.0, -3.0, 1.0])
    one = dead_reckon([[1.0, 0, 0]], [[0, 0, 0.1]], [0.1], T0=T0)
    assert one.shape == (1, 4, 4)
    np.testing.assert_array_equal(one[0], T0)
    np.testing.assert_array_equal(
        dead_reckon([[1.0, 0, 0]], [[0, 0, 0.1]], [0.1])[0], np.eye(4)
    )
    rng = np.random.default_rng(3)
    v, w, dts = (
        rng.normal(size=(6, 3)),
        rng.normal(scale=0.3, size=(6, 3)),
        rng.uniform(0.05, 0.2, 6),
    )
    T = dead_reckon(v, w, dts, T0=T0)
    T_id = dead_reckon(v, w, dts)
    np.testing.assert_allclose(T, T0 @ T_id, atol=1e-12)
    # two samples: one increment, dts[0] ignored
    T2 = dead_reckon(v[:2], w[:2], [99.0, dts[1]])
    rpy, tr = imu_increment(v[0], w[0], v[1], w[1], dts[1])
    np.testing.assert_allclose(T2[1], increment_matrix(rpy, tr), atol=1e-15)
    np.testing.assert_allclose(T_id[1], T2[1], atol=1e-15)


def test_left_jacobian_float32_input_and_zero_without_warnings():
    import warnings

    phi32 = np.float32([0.3, -0.7, 1.9])
    J = so3_left_jacobian(phi32)
    assert J.dtype == np.float64
    np.testing.assert_allclose(
        J, so3_left_jacobian(phi32.astype(np.float64)), rtol=0, atol=1e-15
    )
    with warnings.catch_warnings():
        # the closed form is never evaluated at a = 0 (no 0/0)
        warnings.simplefilter("error")
        np.testing.assert_array_equal(
            so3_left_jacobian(np.zeros((2, 3))), np.broadcast_to(np.eye(3), (2, 3, 3))
        )
