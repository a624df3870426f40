"""Tests of the IMU motion increment and dead reckoning (slamlib.odometry)."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.spatial.transform import Rotation

from slamlib.geometry import make_pose, rpy_to_matrix
from slamlib.odometry import dead_reckon, imu_increment, imu_increments, increment_matrix


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
    T = dead_reckon(np.tile([speed, 0, 0], (n, 1)), np.tile([0, 0, w], (n, 1)), np.full(n, dt))
    t = dt * np.arange(n)
    truth = np.c_[radius * np.sin(w * t), radius * (1 - np.cos(w * t)), np.zeros(n)]
    assert np.max(np.linalg.norm(T[:, :3, 3] - truth, axis=1)) < 1e-6 * radius
    yaw = Rotation.from_matrix(T[:, :3, :3]).as_euler("xyz")[:, 2]
    assert np.allclose(np.unwrap(yaw), w * t, atol=1e-9)


def test_helix_with_climb_is_exact():
    dt, n, v, w = 0.1, 300, np.array([5.0, 0.0, 0.5]), np.array([0.0, 0.0, 0.2])
    T = dead_reckon(np.tile(v, (n, 1)), np.tile(w, (n, 1)), np.full(n, dt))
    t = dt * (n - 1)
    truth = np.array([5.0 / 0.2 * np.sin(0.2 * t), 5.0 / 0.2 * (1 - np.cos(0.2 * t)), 0.5 * t])
    assert _rel(T[-1, :3, 3], truth) < 1e-6


def test_increment_convention_matches_backend_interface():
    rpy, tr = imu_increment([3, 0.1, 0], [0.01, 0.02, 0.3], [3.2, 0.1, 0], [0.0, 0.02, 0.35], 0.1)
    inc = increment_matrix(rpy, tr)
    assert np.allclose(inc[:3, :3], rpy_to_matrix(rpy))
    T_old = make_pose(rpy_to_matrix([0.1, -0.2, 1.0]), [1, 2, 3])
    T_new = T_old @ inc
    # rotation increment is Exp(mean w dt)
    assert np.allclose(inc[:3, :3], Rotation.from_rotvec(0.1 * np.array([0.005, 0.02, 0.325])).as_matrix())
    assert np.allclose(T_new[:3, 3], T_old[:3, 3] + T_old[:3, :3] @ tr)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-3, 3), min_size=12, max_size=12), st.floats(0.01, 0.5))
def test_vectorised_equals_scalar_and_second_order(vals, dt):
    a = np.array(vals).reshape(4, 3)
    rpy_v, tr_v = imu_increments(a[None, 0], a[None, 1], a[None, 2], a[None, 3], np.array([dt]))
    rpy_s, tr_s = imu_increment(a[0], a[1], a[2], a[3], dt)
    assert np.allclose(rpy_v[0], rpy_s) and np.allclose(tr_v[0], tr_s)
    # small-angle: translation ~ mean v dt rotated by half the rotation, to second order in dt
    vb, wb = (a[0] + a[2]) / 2, (a[1] + a[3]) / 2
    half = Rotation.from_rotvec(wb * dt / 2).as_matrix() @ (vb * dt)
    assert np.linalg.norm(tr_s - half) <= 0.05 * (np.linalg.norm(wb) * dt) ** 2 * np.linalg.norm(vb) * dt + 1e-12
