"""Tests of the IMU motion increment and dead reckoning (slamlib.odometry)."""

import functools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from slamlib.geometry import make_pose, rpy_to_matrix
from slamlib.odometry import (
    GRAVITY,
    dead_reckon,
    imu_increment,
    imu_increments,
    increment_matrix,
)
from slamlib.slam3d.stages.prior import (
    balance_heading_bins,
    gravity_up,
    heading_bin,
    tilt_calibration,
    tilt_calibration_add,
    tilt_calibration_bins,
    tilt_calibration_estimate,
    tilt_calibration_prior,
    tilt_calibration_update,
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


# Value tests pinning the formulas (issue 15, mutation testing).
from slamlib.odometry import _skew, so3_left_jacobian  # noqa: E402


def _c1_c2(a):
    """Reference coefficients of J, without cancellation: (1-cos a)/a^2 = sin(a/2)^2/(a^2/2); series for c2."""
    c1 = 0.5 * (np.sinc(a / 2 / np.pi)) ** 2
    c2 = (
        (1 / 6 - a**2 / 120 + a**4 / 5040 - a**6 / 362880)
        if a < 1e-2
        else (a - np.sin(a)) / a**3
    )
    return c1, c2


def test_skew_is_the_cross_product():
    v, u = np.array([0.3, -1.2, 2.5]), np.array([-0.7, 0.4, 1.1])
    np.testing.assert_allclose(_skew(v) @ u, np.cross(v, u), atol=1e-15)
    np.testing.assert_allclose(_skew(np.stack([v, u]))[1] @ v, np.cross(u, v), atol=1e-15)


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
    K = _skew(np.array([x, x, 0.0]))
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
        warnings.simplefilter(
            "error"
        )  # the closed form is never evaluated at a = 0 (no 0/0)
        np.testing.assert_array_equal(
            so3_left_jacobian(np.zeros((2, 3))), np.broadcast_to(np.eye(3), (2, 3, 3))
        )


# ------------------------------------------------------------------------------------------ gravity_up
@functools.lru_cache(maxsize=1)
def _route():
    from slamlib.synth.routes import kitti_route

    return kitti_route("07", (0, 400))


def _route_window(k: int, n: int = 20, every: float = 0.1):
    """Samples ``k - n .. k`` at ``every`` seconds of KITTI 07's first 400 key frames (~40 s): rotations,
    specific forces, body velocities, dts."""
    route = _route()
    t = np.arange(route.t0, route.t1, every)[k - n : k + 1]
    dts = np.r_[0.0, np.diff(t)]
    return (route.rotation(t), route.specific_force_body(t), route.velocity_body(t), dts)


def test_gravity_up_separates_gravity_from_the_vehicles_acceleration():
    """On KITTI 07's real route (turns, braking, slopes) the up direction from a 2 s window of exact samples is
    within 6 mrad of the truth (the trapezoid rule's error at 10 Hz) where one sample alone is off by up to
    hundreds of milliradians (braking and turning look like tilting)."""
    errors, one_sample = [], []
    for k in range(20, 390, 5):
        R, f, v, dts = _route_window(k)
        true_up = R[-1].T @ [0.0, 0.0, 1.0]
        errors.append(np.linalg.norm(gravity_up(R, f, v, dts) - true_up))
        one_sample.append(np.linalg.norm(f[-1] / np.linalg.norm(f[-1]) - true_up))
    assert max(errors) < 6e-3 and np.mean(errors) < 1.5e-3
    assert max(one_sample) > 0.1 > 20 * np.mean(errors)


def test_gravity_up_needs_only_the_relative_rotations():
    """A common rotation of every pose (a filter whose world has tilted) changes nothing: the answer is in the
    last body frame."""
    R, f, v, dts = _route_window(300)
    tilt = Rotation.from_rotvec([0.02, -0.03, 0.4]).as_matrix()
    np.testing.assert_allclose(
        gravity_up(tilt @ R, f, v, dts), gravity_up(R, f, v, dts), atol=1e-12
    )


def test_gravity_up_of_a_still_tilted_body_and_of_no_window():
    R = rpy_to_matrix([0.05, -0.03, 1.0])
    f = GRAVITY * R.T @ [0.0, 0.0, 1.0]  # at rest the accelerometer feels only gravity
    up = gravity_up(np.stack([R, R]), np.stack([f, f]), np.zeros((2, 3)), [0.0, 0.1])
    np.testing.assert_allclose(up, R.T @ [0.0, 0.0, 1.0], atol=1e-12)
    assert gravity_up(R[None], f[None], np.zeros((1, 3)), [0.0]) is None


# ------------------------------------------------------------------------------------------ tilt calibration
WORLD_TILT = np.array([0.02, -0.01])  # the world's up off its z (rad, world x and y)
BIAS = np.array([0.003, -0.004])  # the accelerometer's bias b / g (rad, body x and y)


def _measured_up(R):
    """What an accelerometer with BIAS measures in a body R of a world whose up is off z by WORLD_TILT."""
    g_w = np.r_[WORLD_TILT, 1.0] / np.linalg.norm(np.r_[WORLD_TILT, 1.0])
    u = R.T @ g_w + np.r_[BIAS, 0.0]
    return u / np.linalg.norm(u)


def _calibrate(yaws, sigma_world=0.05, sigma_bias=0.01, weight=1e6):
    info, eta, free = tilt_calibration_prior(sigma_world, sigma_bias)
    for yaw in yaws:
        R = rpy_to_matrix([0.01 * np.sin(yaw), -0.02 * np.cos(yaw), yaw])
        info, eta = tilt_calibration_update(info, eta, R, _measured_up(R), weight)
    return tilt_calibration(info, eta, free)


def test_tilt_calibration_tells_a_tilted_world_from_a_bias_when_the_car_turns():
    """Headings all round: the world's up and the bias are both recovered (to the linearisation's second order)."""
    world_up, bias = _calibrate(np.linspace(0, 2 * np.pi, 40, endpoint=False))
    np.testing.assert_allclose(world_up[:2] / world_up[2], WORLD_TILT, atol=2e-4)
    np.testing.assert_allclose(bias, np.r_[BIAS, 0.0], atol=2e-4)
    assert np.linalg.norm(world_up) == pytest.approx(1.0)


def test_tilt_calibration_on_one_heading_sees_only_the_sum_and_splits_it_by_the_prior():
    """Driving straight (yaw 0, level) a tilted world and a bias look alike: the data fix their sum, the prior's
    variances split it (sigma_world^2 : sigma_bias^2), the least-squares answer of the indistinguishable pair."""
    info, eta, free = tilt_calibration_prior(0.05, 0.01)
    R = np.eye(3)
    for _ in range(50):
        info, eta = tilt_calibration_update(info, eta, R, _measured_up(R), 1e8)
    world_up, bias = tilt_calibration(info, eta, free)
    total = world_up[:2] / world_up[2] + bias[:2]
    np.testing.assert_allclose(total, WORLD_TILT + BIAS, atol=2e-4)
    np.testing.assert_allclose(bias[:2] / total, 0.01**2 / (0.05**2 + 0.01**2), rtol=1e-3)


def test_tilt_calibration_holds_an_unknown_with_prior_sigma_zero_at_zero():
    world_up, bias = _calibrate(
        np.linspace(0, 2 * np.pi, 40, endpoint=False), sigma_bias=0.0
    )
    assert np.all(bias == 0.0) and abs(world_up[0]) > 0.01  # the world's part still moves
    world_up, bias = _calibrate(
        np.linspace(0, 2 * np.pi, 40, endpoint=False), sigma_world=0.0, sigma_bias=0.0
    )
    assert np.array_equal(world_up, [0.0, 0.0, 1.0]) and np.all(bias == 0.0)
    info, eta, free = tilt_calibration_prior(0.05, 0.01)
    assert np.array_equal(
        tilt_calibration(info, eta, free)[0], [0.0, 0.0, 1.0]
    )  # no data: the prior's mean
    with pytest.raises(ValueError, match="sigma_world, sigma_bias >= 0"):
        tilt_calibration_prior(-0.01, 0.01)


def test_heading_bin_counts_sectors_from_minus_pi():
    assert [
        heading_bin(rpy_to_matrix([0.0, 0.0, yaw]), 8)
        for yaw in (-np.pi + 1e-9, -0.01, 0.0, 0.8, np.pi - 1e-9)
    ] == [0, 3, 4, 5, 7]
    assert heading_bin(rpy_to_matrix([0.02, -0.03, 2.0]), 1) == 0


def test_balance_heading_bins_weighs_every_used_sector_alike():
    infos = np.stack([np.eye(4) * 3.0, np.zeros((4, 4)), np.eye(4)])
    etas = np.array([[3.0, 0, 0, 0], [0, 0, 0, 0], [0, 1.0, 0, 0]])
    info, eta = balance_heading_bins(infos, etas, [3.0, 0.0, 1.0])
    # total weight 4 over two used sectors: each scaled to 2, i.e. by 2/3 and 2
    np.testing.assert_allclose(info, np.eye(4) * 4.0)
    np.testing.assert_allclose(eta, [2.0, 2.0, 0.0, 0.0])
    one = balance_heading_bins(infos[:1], etas[:1], [3.0])  # one sector: the plain sums
    np.testing.assert_allclose(one[0], infos[0])
    np.testing.assert_allclose(one[1], etas[0])
    assert not balance_heading_bins(infos, etas, [0.0, 0.0, 0.0])[0].any()


def test_balanced_bias_fit_is_not_pulled_by_a_tilted_map_on_a_long_straight():
    """A map tilted 5 mrad (fixed in the world: the filter's rotations are T R) and a true bias. Ninety frames
    east, ten west: weighed by time the fit takes 80 % of the map's tilt for a bias; with the two headings weighing
    alike the tilt cancels."""
    T = rpy_to_matrix([0.0, 0.005, 0.0])
    info0, eta0, free = tilt_calibration_prior(0.0, 0.01)
    infos, etas, weights = np.zeros((8, 4, 4)), np.zeros((8, 4)), np.zeros(8)
    plain = info0, eta0
    for yaw in [0.0] * 90 + [np.pi - 0.1] * 10:
        R = rpy_to_matrix([0.0, 0.0, yaw])
        up = R.T @ [0.0, 0.0, 1.0] + np.r_[BIAS, 0.0]
        up /= np.linalg.norm(up)
        plain = tilt_calibration_update(*plain, T @ R, up, 1e6)
        b = heading_bin(T @ R, 8)
        infos[b], etas[b] = tilt_calibration_update(infos[b], etas[b], T @ R, up, 1e6)
        weights[b] += 1e6
    info, eta = balance_heading_bins(infos, etas, weights)
    balanced = tilt_calibration(info0 + info, eta0 + eta, free)[1][:2]
    time_weighted = tilt_calibration(*plain, free)[1][:2]
    np.testing.assert_allclose(balanced, BIAS, atol=3e-4)
    assert (
        abs(time_weighted[0] - BIAS[0]) > 3e-3
    )  # 0.8 x 5 mrad of the map's pitch taken for a bias


def test_tilt_calibration_add_and_estimate_are_the_sectors_sums_balanced():
    rng = np.random.default_rng(4)
    prior, sums = tilt_calibration_prior(0.02, 0.01), tilt_calibration_bins(4)
    infos, etas, weights = np.zeros((4, 4, 4)), np.zeros((4, 4)), np.zeros(4)
    for yaw, w in zip(rng.uniform(-np.pi, np.pi, 30), rng.uniform(1.0, 3.0, 30)):
        R = rpy_to_matrix([0.0, 0.0, yaw])
        up = _measured_up(R)
        tilt_calibration_add(sums, R, up, w)
        b = heading_bin(R, 4)
        infos[b], etas[b] = tilt_calibration_update(infos[b], etas[b], R, up, w)
        weights[b] += w
    info, eta = balance_heading_bins(infos, etas, weights)
    expected = tilt_calibration(prior[0] + info, prior[1] + eta, prior[2])
    for got, want in zip(tilt_calibration_estimate(prior, sums), expected):
        np.testing.assert_array_equal(got, want)
    assert np.count_nonzero(sums[2]) == 4
