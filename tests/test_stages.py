"""The stages the 3D filter chooses once (:mod:`slamlib.slam3d.stages`), tested one at a time: the prior stage
(:mod:`slamlib.slam3d.stages.prior`: gravity's up from the IMU, the calibration of the world's up and the
accelerometer's bias in heading sectors, the log-prior of the particles' tilt, and the TiltPrior / NoPrior stages)
and the polish stage (:mod:`slamlib.slam3d.stages.polish`: ScanMatch / NoPolish). How the filter chooses and
runs them: test_pipeline.py."""

import functools
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from world3d import simulate, tiny_config

from slamlib.geometry import make_pose, rpy_to_matrix
from slamlib.odometry import GRAVITY
from slamlib.slam3d import Particles3D, ParticleSLAM3D, steps
from slamlib.slam3d.config import TiltConfig
from slamlib.slam3d.match import MATCH_TOLERANCE
from slamlib.slam3d.preprocess import road_mask
from slamlib.slam3d.stages import Annealing, NoPolish, NoPrior, ScanMatch, TiltPrior
from slamlib.slam3d.stages.prior import (
    balance_heading_bins,
    gravity_up,
    gravity_up_from_positions,
    heading_bin,
    tilt_calibration,
    tilt_calibration_add,
    tilt_calibration_bins,
    tilt_calibration_estimate,
    tilt_calibration_prior,
    tilt_calibration_rows,
    tilt_calibration_update,
    tilt_kalman_update,
    tilt_log_prior,
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


def _route_positions(k: int, n: int = 20, every: float = 0.1):
    """The body positions (m, world) of :func:`_route_window`'s samples."""
    route = _route()
    return route.position(np.arange(route.t0, route.t1, every)[k - n : k + 1])


def test_gravity_up_from_positions_separates_gravity_from_the_vehicles_acceleration():
    """The same as from the velocities: on KITTI 07's real route, exact samples over a 2 s window give the up
    within 2 mrad of the truth: the double integral smooths the trapezoid rule's error at 10 Hz."""
    errors = []
    for k in range(20, 390, 5):
        R, f, _, dts = _route_window(k)
        true_up = R[-1].T @ [0.0, 0.0, 1.0]
        up = gravity_up_from_positions(R, _route_positions(k), f, dts)
        errors.append(np.linalg.norm(up - true_up))
    assert max(errors) < 2e-3 and np.mean(errors) < 5e-4


def test_gravity_up_from_positions_is_not_moved_by_the_velocities_errors():
    """With the IMU's velocities off as the synthetic OXTS makes them (0.05 m/s white noise, 1.5 % scale on the
    forward speed, 0.03 m/s sideways bias) and the positions off by 1 cm (a scan match's), the up from the
    positions errs several times less than the up from the velocities (module docstring: ``dp / (g T^2 / 2)``
    against ``dv / (g T)``)."""
    rng = np.random.default_rng(3)
    from_velocity, from_positions = [], []
    for k in range(20, 390, 5):
        R, f, v, dts = _route_window(k)
        true_up = R[-1].T @ [0.0, 0.0, 1.0]
        v_meas = v * [1.015, 1.0, 1.0] + [0.0, 0.03, 0.0] + rng.normal(0, 0.05, v.shape)
        p_meas = _route_positions(k) + rng.normal(0, 0.01, (len(dts), 3))
        from_velocity.append(np.linalg.norm(gravity_up(R, f, v_meas, dts) - true_up))
        from_positions.append(
            np.linalg.norm(gravity_up_from_positions(R, p_meas, f, dts) - true_up)
        )
    assert np.sqrt(np.mean(np.square(from_velocity))) > 2 * np.sqrt(
        np.mean(np.square(from_positions))
    )


def test_gravity_up_from_positions_needs_only_the_relative_poses():
    """A common rigid motion of every pose (a filter whose world has tilted and moved) changes nothing."""
    R, f, _, dts = _route_window(300)
    p = _route_positions(300)
    tilt = Rotation.from_rotvec([0.02, -0.03, 0.4]).as_matrix()
    moved = gravity_up_from_positions(tilt @ R, p @ tilt.T + [1e3, -2e3, 50.0], f, dts)
    np.testing.assert_allclose(moved, gravity_up_from_positions(R, p, f, dts), atol=1e-9)


def test_gravity_up_from_positions_of_a_still_tilted_body_and_of_no_window():
    R = rpy_to_matrix([0.05, -0.03, 1.0])
    f = GRAVITY * R.T @ [0.0, 0.0, 1.0]
    up = gravity_up_from_positions(
        np.stack([R] * 3), np.zeros((3, 3)), np.stack([f] * 3), [0.0, 0.1, 0.1]
    )
    np.testing.assert_allclose(up, R.T @ [0.0, 0.0, 1.0], atol=1e-12)
    # two frames cannot fit a start position, a start velocity and gravity
    assert (
        gravity_up_from_positions(
            R[None].repeat(2, 0), np.zeros((2, 3)), [f, f], [0.0, 0.1]
        )
        is None
    )
    assert (
        gravity_up_from_positions(
            R[None].repeat(3, 0), np.zeros((3, 3)), [f] * 3, [0.0] * 3
        )
        is None
    )


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


def test_tilt_calibration_rows_are_the_measured_up_to_first_order():
    """``y = u - R^T e_z = H x`` to first order: an up measured in a world whose up is ``e_z + (a, b, 0)``, by an
    accelerometer biased by ``(c, d)``, is ``H x`` up to terms of second order in the milliradians (below 1e-4
    here, against first-order terms over 4e-3), and ``H``'s last two columns hold still as the body turns."""
    x = np.array([0.004, -0.003, 0.002, 0.005])
    for rpy in ([0.02, -0.01, 0.3], [-0.03, 0.02, 2.5]):
        R = rpy_to_matrix(rpy)
        g_w = np.array([x[0], x[1], 1.0]) / np.hypot(np.hypot(x[0], x[1]), 1.0)
        up = R.T @ g_w + [x[2], x[3], 0.0]
        H, y = tilt_calibration_rows(R, up)
        assert H.shape == (3, 4) and np.abs(y).max() > 4e-3
        np.testing.assert_allclose(y, H @ x, atol=1e-4)
        np.testing.assert_array_equal(H[:, 2:], np.eye(3)[:, :2])


def test_tilt_kalman_update_without_a_walk_is_the_least_squares():
    """With no walk the Kalman filter is recursive least squares: after any frames its state is
    :func:`tilt_calibration`'s answer from the same frames at weight ``1 / r`` and the same prior (as the linear
    fit is, the tilt and the bias as angles)."""
    rng = np.random.default_rng(5)
    sigma_world, sigma_bias, r = 0.02, 0.01, 0.004**2
    info, eta, free = tilt_calibration_prior(sigma_world, sigma_bias)
    x, P = np.zeros(4), np.diag(np.repeat([sigma_world, sigma_bias], 2) ** 2)
    for yaw in rng.uniform(-np.pi, np.pi, 30):
        R = rpy_to_matrix([0.01 * np.sin(yaw), -0.02 * np.cos(yaw), yaw])
        up = _measured_up(R) + rng.normal(0, 0.004, 3)
        info, eta = tilt_calibration_update(info, eta, R, up, 1 / r)
        x, P = tilt_kalman_update(x, P, R, up, r, 0.0)
    np.testing.assert_allclose(x, np.linalg.solve(info, eta), atol=1e-12)
    np.testing.assert_allclose(P, np.linalg.inv(info), rtol=1e-9)


def test_tilt_kalman_update_keeps_the_bias_where_the_tilt_walks():
    """Along KITTI 07 (its turns), the filter's tilt walking at 1e-6 rad^2/s and a constant bias, the up measured
    to 2 mrad a frame: the Kalman filter's bias ends within half the least squares' error (which holds the
    world's up still, and so passes the walk to the bias), and it follows the walk itself."""
    rng = np.random.default_rng(7)
    route = _route()
    t = np.arange(route.t0, route.t1, 0.1)
    rotations = route.rotation(t)
    walk = np.cumsum(rng.normal(0, np.sqrt(1e-6 * 0.1), (len(t), 2)), axis=0)
    bias, r = np.array([0.003, -0.003]), 0.002**2
    info, eta, free = tilt_calibration_prior(0.0, 0.01)
    x, P = np.zeros(4), np.diag([0.0, 0.0, 1e-4, 1e-4])
    for R, e in zip(rotations, walk):
        g_w = np.r_[e, 1.0] / np.linalg.norm(np.r_[e, 1.0])
        up = R.T @ g_w + np.r_[bias, 0.0] + rng.normal(0, 0.002, 3)
        info, eta = tilt_calibration_update(info, eta, R, up, 1 / r)
        x, P = tilt_kalman_update(x, P, R, up, r, 1e-6 * 0.1)
    _, least_squares = tilt_calibration(info, eta, free)
    assert np.linalg.norm(x[2:] - bias) < np.linalg.norm(least_squares[:2] - bias) / 2
    assert np.linalg.norm(x[:2] - walk[-1]) < 0.3 * np.linalg.norm(walk[-1])


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
    # no data: the prior's mean
    assert np.array_equal(tilt_calibration(info, eta, free)[0], [0.0, 0.0, 1.0])
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
    # 0.8 x 5 mrad of the map's pitch taken for a bias
    assert abs(time_weighted[0] - BIAS[0]) > 3e-3


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


# ------------------------------------------------------------------------------------------ tilt prior
def test_tilt_log_prior_penalises_roll_and_pitch_not_yaw():
    from slamlib.slam3d.stages.prior import tilt_log_prior

    R = rpy_to_matrix(np.array([[0, 0, 0], [0, 0, 2.0], [0.01, 0, 0], [0, -0.02, 0.5]]))
    lp = tilt_log_prior(Particles3D(R, np.zeros((4, 3))), [0.0, 0.0, 1.0], 0.005)
    assert lp[0] == 0.0 and lp[1] == pytest.approx(0.0, abs=1e-20)  # yaw is free
    # small angles: |R^T e_z - e_z| = 2 sin(a / 2) ~ a, so the prior is -0.5 (a / sigma)^2
    assert lp[2] == pytest.approx(-0.5 * (0.01 / 0.005) ** 2, rel=1e-4)
    assert lp[3] == pytest.approx(-0.5 * (0.02 / 0.005) ** 2, rel=1e-4)


def test_tilt_calibration_is_the_least_squares_of_the_filters_own_frames():
    """The filter's bias and world's up are :func:`slamlib.slam3d.stages.prior.tilt_calibration` of its own
    rotations (step 9) and measured ups, over the frames whose window spans ``tilt_window``, each weighing
    ``dt / tilt_window`` of a ``tilt_sigma`` measurement, in heading sectors that weigh alike (the identification
    itself: the tilt calibration tests above). A biased accelerometer on a turning drive moves both away from the
    prior's zero."""
    frames, _ = simulate(40, yaw_rate=0.6)
    for f in frames:
        f.specific_force = f.specific_force + [0.05, -0.04, 0.0]
    sigma, window = 0.005, 1.05  # not a multiple of dt = 0.1, whose sums round either way
    slam = ParticleSLAM3D(
        tiny_config(
            tilt_sigma=sigma,
            tilt_window=window,
            tilt_world_sigma=0.02,
            tilt_up="velocity",
            tilt_bias="sectors",
        )
    )
    info0, eta0, free = tilt_calibration_prior(0.02, slam.config.prior.tilt_bias_sigma)
    bins = slam.config.prior.tilt_heading_bins
    infos, etas, weights = np.zeros((bins, 4, 4)), np.zeros((bins, 4)), np.zeros(bins)
    used = 0
    for f in frames:
        slam.register_frame(f)
        if (
            slam.prior.up is not None
            and sum(s[2] for s in list(slam.prior.samples)[1:]) >= window
        ):
            R = slam.poses[-1][:3, :3]
            b = heading_bin(R, bins)
            infos[b], etas[b] = tilt_calibration_update(
                infos[b], etas[b], R, slam.prior.up, f.dt / window / sigma**2
            )
            weights[b] += f.dt / window / sigma**2
            used += 1
    info, eta = balance_heading_bins(infos, etas, weights)
    world_up, bias = tilt_calibration(info0 + info, eta0 + eta, free)
    # frames 0..11: no window yet, or one shorter than 1.05 s
    assert used == len(frames) - 12
    assert np.count_nonzero(weights) >= 3  # the drive turns through several sectors
    np.testing.assert_allclose(slam.prior.up_bias, bias, atol=1e-12)
    np.testing.assert_allclose(slam.prior.world_up, world_up, atol=1e-12)
    assert np.abs(bias).max() > 1e-3 and np.abs(world_up[:2]).max() > 1e-4


def test_tilt_log_prior_measures_the_tilt_from_the_worlds_up():
    """With the world's up ``g_w`` off ``e_z``, a particle tilted like the world and a measured up ``e_z`` agree."""
    from slamlib.slam3d.stages.prior import tilt_log_prior

    world = rpy_to_matrix([0.01, -0.02, 0.0])
    R = np.stack([world, np.eye(3)])
    lp = tilt_log_prior(
        Particles3D(R, np.zeros((2, 3))), [0.0, 0.0, 1.0], 0.005, world @ [0.0, 0.0, 1.0]
    )
    assert lp[0] == pytest.approx(0.0, abs=1e-20)
    assert lp[1] == pytest.approx(-0.5 * (0.01**2 + 0.02**2) / 0.005**2, rel=1e-3)
    np.testing.assert_array_equal(
        tilt_log_prior(Particles3D(R, np.zeros((2, 3))), [0.0, 0.0, 1.0], 0.005),
        tilt_log_prior(
            Particles3D(R, np.zeros((2, 3))), [0.0, 0.0, 1.0], 0.005, [0.0, 0.0, 1.0]
        ),
    )


def test_the_bias_variance_is_the_priors_before_any_frame_and_shrinks_as_the_car_turns():
    from slamlib.slam3d.stages.prior import tilt_calibration_bias_variance

    prior, sums = tilt_calibration_prior(0.0, 0.01), tilt_calibration_bins(8)
    assert tilt_calibration_bias_variance(prior, sums) == pytest.approx(0.01**2)
    for yaw in np.linspace(0, 2 * np.pi, 40, endpoint=False):
        R = rpy_to_matrix([0.0, 0.0, yaw])
        tilt_calibration_add(sums, R, R[2], 1e5)  # 1e5 = one frame of sigma ~3 mrad
    assert tilt_calibration_bias_variance(prior, sums) < 0.01**2 / 100
    # held at zero: no uncertainty
    held = tilt_calibration_prior(0.0, 0.0)
    assert tilt_calibration_bias_variance(held, tilt_calibration_bins(8)) == 0.0


def test_up_scatter_estimates_the_measured_ups_variance_per_axis():
    """Residuals of two independent windows, N(0, sigma^2) on each tilt axis: the mean of up_scatter is sigma^2."""
    from slamlib.slam3d.stages.prior import up_scatter

    rng = np.random.default_rng(0)
    sigma = 0.004
    r = rng.normal(0, sigma, (4000, 2, 3)) * [1.0, 1.0, 0.0]
    samples = [up_scatter(a, b) for a, b in r]
    assert np.mean(samples) == pytest.approx(sigma**2, rel=0.05)
    assert up_scatter([0.001, 0.0, 0.0], [0.0, 0.0, 0.0]) == pytest.approx(0.25e-6)


@pytest.mark.parametrize("noise", [0.02, 0.3])
def test_auto_tilt_sigma_follows_the_accelerometers_consistency(noise):
    """``tilt_sigma="auto"``: the up's noise starts at AUTO_TILT_SIGMA_START and, once windows have turned over, is
    the measured up's scatter (:func:`slamlib.slam3d.stages.prior.gravity_up`'s errors over a window of ``T = 1`` s,
    per tilt axis): the velocity noise at its two ends, ``sqrt(2) sigma_v / (g T)``, and the accelerometer's white
    noise integrated by the trapezoid rule over 10 samples, ``sigma_f dt sqrt(9.5) / (g T)``; larger for the
    noisier accelerometer, within the bounds."""
    from slamlib.slam3d.stages.prior import (
        AUTO_TILT_SIGMA_MAX,
        AUTO_TILT_SIGMA_MIN,
        AUTO_TILT_SIGMA_START,
        tilt_calibration_bias_variance,
    )

    frames, _ = simulate(70, yaw_rate=0.3)
    rng = np.random.default_rng(5)
    for f in frames:
        f.specific_force = f.specific_force + rng.normal(0, noise, 3)
    slam = ParticleSLAM3D(
        tiny_config(
            tilt_sigma="auto", tilt_window=1.0, tilt_up="velocity", tilt_bias="sectors"
        )
    )
    for f in frames[:5]:
        slam.register_frame(f)
    assert slam.prior.noise_sigma == AUTO_TILT_SIGMA_START and slam.prior.auto
    for f in frames[5:]:
        slam.register_frame(f)
    assert AUTO_TILT_SIGMA_MIN <= slam.prior.sigma <= AUTO_TILT_SIGMA_MAX
    # frames 21-69 each compared with one a window before
    assert slam.prior.scatter.weight > 30
    # simulate's IMU: velocity noise 0.02 m/s, accelerometer noise 0.05 m/s^2 (plus this test's)
    sigma_v, sigma_f = 0.02, np.hypot(0.05, noise)
    expected = np.hypot(np.sqrt(2) * sigma_v, sigma_f * 0.1 * np.sqrt(9.5)) / GRAVITY
    # within 40 %: ~50 differences (a sigma good to ~10 %), and the filter's own tilt, which a noisy up pulls
    # about, changes a little over a window too
    assert slam.prior.noise_sigma == pytest.approx(
        np.clip(expected, AUTO_TILT_SIGMA_MIN, AUTO_TILT_SIGMA_MAX), rel=0.4
    )
    # the prior's sigma adds the fitted bias's own uncertainty to the up's noise
    bias_var = tilt_calibration_bias_variance(
        slam.prior.calibration_prior, slam.prior.bins
    )
    assert slam.prior.sigma == pytest.approx(
        np.clip(
            np.sqrt(slam.prior.noise_sigma**2 + bias_var),
            AUTO_TILT_SIGMA_MIN,
            AUTO_TILT_SIGMA_MAX,
        )
    )
    assert slam.prior.sigma >= slam.prior.noise_sigma


def test_tilt_gain_is_the_steady_state_kalman_gain_of_a_random_walk():
    """A state that random-walks ``q dt`` per frame, measured each frame with variance ``R = sigma^2 W / dt``: the
    Riccati recursion's limit; about ``dt sqrt(q / (sigma^2 W))`` while that is small; 0 for no walk; and
    :func:`tilt_sigma_for_gain`'s ``sigma`` against the map's information gives the frame that same gain."""
    from slamlib.slam3d.stages.prior import tilt_gain, tilt_sigma_for_gain

    q, noise, W, dt = 2e-6, 0.005**2, 2.0, 0.1
    Q, R = q * dt, noise * W / dt
    P = 1.0
    for _ in range(20000):
        k = P / (P + R)
        P = (1 - k) * P + Q  # update, then the next frame's prediction
    assert tilt_gain(q, noise, W, dt) == pytest.approx(P / (P + R), rel=1e-9)
    assert tilt_gain(q, noise, W, dt) == pytest.approx(
        dt * np.sqrt(q / (noise * W)), rel=0.05
    )
    assert tilt_gain(0.0, noise, W, dt) == tilt_gain(-1e-6, noise, W, dt) == 0.0
    assert (
        tilt_gain(4 * q, noise, W, dt)
        > tilt_gain(q, noise, W, dt)
        > tilt_gain(q, 4 * noise, W, dt)
    )
    information = 2e6  # rad^-2, the map's on the tilt
    for k in (0.01, 0.3, 0.9):
        hold = 1 / tilt_sigma_for_gain(k, information) ** 2
        assert hold / (information + hold) == pytest.approx(k)
    assert tilt_sigma_for_gain(0.0, information) == np.inf


@pytest.mark.parametrize("q", [0.0, 4e-6])
def test_adaptive_reads_the_tilts_walk_and_the_windows_noise_from_the_residuals_at_two_lags(
    q,
):
    """Residuals that are a random walk of rate ``q`` per axis plus white noise of 5 mrad: ``walk_rate`` reads
    ``q`` back (the noise, the same at both lags, drops out), about 0 when nothing walks, and ``window_noise``
    the noise's variance (``D(2 W) - q W``: the walk over the shorter lag taken out)."""
    from slamlib.slam3d.stages.prior import ADAPTIVE_TILT_LAG_S

    prior = TiltPrior(TiltConfig(tilt_sigma="adaptive"))
    rng = np.random.default_rng(11)
    dt, sigma = 0.1, 0.005
    walk = np.zeros(3)
    rates, noises, readings, errors = [], [], [], []
    for _ in range(12000):
        walk[:2] += rng.normal(0, np.sqrt(q * dt), 2)
        prior.record(walk + rng.normal(0, sigma, 3) * [1, 1, 0], dt)
        if prior.time > 2 * ADAPTIVE_TILT_LAG_S:
            rates.append(prior.walk_rate())
            noises.append(prior.window_noise())
            readings.append(prior.walk_reading())
            errors.append(prior.walk_standard_error())
    # the means over 20 minutes of 30 s running means
    assert np.mean(rates) == pytest.approx(q, abs=max(0.3 * q, 0.3e-6))
    assert np.mean(noises) == pytest.approx(sigma**2, rel=0.1)
    # the walk's standard error bounds the readings' own spread from above (module docstring)
    assert np.mean(errors) > np.std(readings) > 0
    # the history reaches back the longer lag, no further
    assert (
        prior.time - prior.history[1][0]
        < ADAPTIVE_TILT_LAG_S
        <= (prior.time - prior.history[0][0])
    )


def test_truncated_normal_mean_is_scipys():
    """The walk's mean given that it is at least 0: scipy's truncated normal, also far below 0 (where the
    ``phi / Phi`` ratio of the textbook form would be 0 / 0), and the reading itself, clipped, without a spread."""
    from scipy.stats import truncnorm

    from slamlib.slam3d.stages.prior import truncated_normal_mean

    for mean, sd in (
        (1.0, 1.0),
        (0.0, 1.0),
        (-3.0, 1.0),
        (-40.0, 1.0),
        (5e-6, 1e-6),
        (-2e-6, 1e-6),
    ):
        expected = truncnorm.mean(-mean / sd, np.inf, loc=mean, scale=sd)
        assert truncated_normal_mean(mean, sd) == pytest.approx(expected, rel=1e-9)
    assert truncated_normal_mean(0.0, 1.0) == pytest.approx(np.sqrt(2 / np.pi))
    assert (
        truncated_normal_mean(-1e-6, 0.0) == 0.0
        and truncated_normal_mean(2e-6, 0.0) == 2e-6
    )


def test_adaptive_holds_the_match_to_gravity_and_reads_the_maps_information():
    """``tilt_sigma="adaptive"``: the scan match carries the prior even with ``match_tilt`` off, the prior learns the
    map's information on the tilt from it (per point and temperature: the Gauss-Newton tilt block over ``n T``),
    and ``sigma`` starts at AUTO_TILT_SIGMA_START and stays within its bounds."""
    from slamlib.slam3d.stages.prior import (
        ADAPTIVE_TILT_SIGMA_MAX,
        AUTO_TILT_SIGMA_MIN,
        AUTO_TILT_SIGMA_START,
    )

    frames, _ = simulate(40, yaw_rate=0.3)
    slam = ParticleSLAM3D(tiny_config(tilt_sigma="adaptive", tilt_window=1.0))
    for f in frames[:3]:
        slam.register_frame(f)
    assert isinstance(slam.polish, ScanMatch) and slam.polish.prior is slam.prior
    assert slam.prior.adaptive and slam.prior.sigma == AUTO_TILT_SIGMA_START
    sigmas = []
    for f in frames[3:]:
        slam.register_frame(f)
        sigmas.append(slam.prior.sigma)
    assert slam.prior.map_information > 0
    assert all(AUTO_TILT_SIGMA_MIN <= s <= ADAPTIVE_TILT_SIGMA_MAX for s in sigmas)
    # the information from a known curvature: roll and pitch 4e6 and 2e6 over n T = 100 * 2, where roll and a
    # sideways shift trade off, half of roll's is left with the shift free
    prior = TiltPrior(TiltConfig(tilt_sigma="adaptive"))
    C = np.diag([4e6, 2e6, 9e9, 1e6, 1e6, 1e6])
    prior.observe_map(C, 100, 2.0)
    assert prior.map_information == pytest.approx(3e6 / 200)
    C[0, 4] = C[4, 0] = np.sqrt(0.5 * 4e6 * 1e6)
    prior.observe_map(C, 100, 2.0)
    assert prior.map_information == pytest.approx((2e6 + 2e6) / 2 / 200)
    before = prior.map_information
    prior.observe_map(-C, 100, 2.0)  # not positive definite: kept
    assert prior.map_information == before


# ------------------------------------------------------------------------------------------ prior: edge cases
def test_gravity_up_of_a_window_that_spans_no_time_is_none():
    """Two samples 0 s apart: no time to integrate over, no up (not a division by zero)."""
    f = np.array([[0.0, 0.0, GRAVITY]] * 2)
    assert gravity_up(np.stack([np.eye(3)] * 2), f, np.zeros((2, 3)), [0.0, 0.0]) is None


def test_tilt_calibration_prior_is_the_inverse_variances_of_the_free_pairs():
    info, eta, free = tilt_calibration_prior(0.0, 0.02)
    np.testing.assert_allclose(info, np.diag([0.0, 0.0, 2500.0, 2500.0]))
    assert np.array_equal(free, [False, False, True, True]) and not eta.any()


def test_tilt_calibration_update_adds_the_weighted_normal_equations():
    """A body rolled 90 degrees (rows R^T e_x = e_x, R^T e_y = -e_z, R^T e_z = e_y) measuring up (0.1, 0.2, 0.3):
    H = [e_x, -e_z, e_x, e_y] as columns, y = u - e_y, by hand."""
    R = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    info, eta = tilt_calibration_update(np.eye(4), np.ones(4), R, [0.1, 0.2, 0.3], 2.0)
    HtH = np.array([[1, 0, 1, 0], [0, 1, 0, 0], [1, 0, 1, 0], [0, 0, 0, 1.0]])
    np.testing.assert_allclose(info, np.eye(4) + 2.0 * HtH)
    np.testing.assert_allclose(eta, 1.0 + 2.0 * np.array([0.1, -0.3, 0.1, -0.8]))


# ------------------------------------------------------------------------------------------ prior: the stages
def _force_frame(up=(0.0, 0.0, 1.0)):
    """A frame whose accelerometer feels gravity along the body's ``up`` (at rest)."""
    up = np.asarray(up, dtype=np.float64)
    return SimpleNamespace(specific_force=GRAVITY * up / np.linalg.norm(up))


def _measure_frame(prior, k, dt, up=(0.0, 0.0, 1.0)):
    """Frame ``k`` of a still body at the origin into ``prior``, ``dt`` after the one before."""
    still = (np.zeros(3), np.zeros(3))
    prior.measure(_force_frame(up), still, dt, still, [np.eye(4)] * (k + 1))


def _measure(prior, n, dt, up=(0.0, 0.0, 1.0)):
    """``n`` frames (:func:`_measure_frame`) into ``prior``; its ``(len(samples), up_span)`` after each."""
    seen = []
    for k in range(n):
        _measure_frame(prior, k, dt, up)
        seen.append((len(prior.samples), prior.up_span))
    return seen


def test_tilt_prior_keeps_the_fewest_samples_that_span_the_window():
    """Frames 0.25 s apart (exact in binary): a 0.5 s window holds three samples (two intervals; the oldest goes
    once the others span the window exactly), a 0.25 s window two."""
    prior = TiltPrior(TiltConfig(tilt_sigma=0.005, tilt_window=0.5))
    assert prior.up is None and prior.up_span == 0.0 and len(prior.samples) == 0
    assert _measure(prior, 5, 0.25) == [(1, 0.0), (2, 0.25), (3, 0.5), (3, 0.5), (3, 0.5)]
    np.testing.assert_allclose(prior.up, [0.0, 0.0, 1.0], atol=1e-12)
    short = TiltPrior(TiltConfig(tilt_sigma=0.005, tilt_window=0.25))
    assert _measure(short, 4, 0.25) == [(1, 0.0), (2, 0.25), (2, 0.25), (2, 0.25)]


def test_tilt_prior_frame_without_an_accelerometer_empties_the_window():
    prior = TiltPrior(TiltConfig(tilt_sigma=0.005, tilt_window=0.5))
    _measure(prior, 3, 0.25)
    assert prior.up is not None
    prior.measure(
        SimpleNamespace(), (np.zeros(3), np.zeros(3)), 0.25, None, [np.eye(4)] * 4
    )
    assert prior.up is None and len(prior.samples) == 0 and prior.held_up() is None
    log_weights = np.array([-1.0, -2.0])
    particles = Particles3D(np.stack([np.eye(3)] * 2), np.zeros((2, 3)))
    assert prior.weigh(particles, log_weights) is log_weights


def test_tilt_prior_calibrates_once_the_window_spans_tilt_window_with_weight_dt_over_window():
    """Frames 0.25 s apart, window 0.5 s: the first two frames (spans 0 and 0.25 s) add nothing and hold nothing,
    the third (span exactly 0.5 s) adds ``dt / window / sigma^2`` to its heading's sector; the estimate follows the
    sums, and step 8 weighs with the measured up less the bias against the estimated world's up."""
    sigma, up = 0.005, rpy_to_matrix([0.01, -0.02, 0.0]).T @ [0.0, 0.0, 1.0]
    config = TiltConfig(
        tilt_sigma=sigma, tilt_window=0.5, tilt_world_sigma=0.02, tilt_bias="sectors"
    )
    prior = TiltPrior(config)
    for k in range(3):
        _measure_frame(prior, k, 0.25, up)
        prior.calibrate(np.eye(4), 0.25)
        assert prior.bins[2].sum() == (0.0 if k < 2 else 0.25 / 0.5 / sigma**2)
        assert (prior.held_up() is None) == (k < 2)  # step 8 holds nothing until then
    sums = tilt_calibration_bins(config.tilt_heading_bins)
    tilt_calibration_add(sums, np.eye(3), prior.up, 0.25 / 0.5 / sigma**2)
    for got, want in zip(prior.bins, sums):
        np.testing.assert_array_equal(got, want)
    world_up, bias = tilt_calibration_estimate(prior.calibration_prior, sums)
    np.testing.assert_array_equal(prior.world_up, world_up)
    np.testing.assert_array_equal(prior.up_bias, bias)
    assert np.abs(bias).max() > 1e-3 and np.abs(world_up[:2]).max() > 1e-3
    # step 8: exactly the log-prior of the measured up less the bias, from the estimated world's up
    R = rpy_to_matrix(np.array([[0.0, 0.0, 0.0], [0.01, -0.02, 0.3], [-0.02, 0.0, 1.0]]))
    particles, log_weights = (
        Particles3D(R, np.zeros((3, 3))),
        np.array([-1.0, -2.0, -3.0]),
    )
    np.testing.assert_array_equal(prior.held_up(), prior.up - bias)
    want = log_weights + tilt_log_prior(particles, prior.up - bias, sigma, world_up)
    np.testing.assert_array_equal(prior.weigh(particles, log_weights), want)


@pytest.mark.parametrize("source", ["velocity", "positions"])
def test_tilt_prior_measures_the_up_from_the_source_it_was_given(source):
    """Along KITTI 07, frame by frame: ``tilt_up`` chooses what the stage's up is measured from, the IMU's
    velocities (:func:`gravity_up`) or the filter's poses, the registered ones and this frame's prediction
    (:func:`gravity_up_from_positions`), over the fewest frames that span the window."""
    from slamlib.slam3d.stages.motion import measured_increment

    R, f, v, dts = _route_window(30, n=30)
    poses = [make_pose(r, p) for r, p in zip(R, _route_positions(30, n=30))]
    prior = TiltPrior(TiltConfig(tilt_sigma=0.005, tilt_window=1.0, tilt_up=source))
    for k in range(len(dts)):
        increment = (
            measured_increment(poses[k - 1], poses[k]) if k else (np.zeros(3),) * 2
        )
        prior.measure(
            SimpleNamespace(specific_force=f[k]),
            (v[k], np.zeros(3)),
            dts[k],
            increment,
            poses[: max(k, 1)],
        )
    window = slice(len(dts) - 11, None)  # 1 s at 10 Hz: ten intervals
    T = np.array(poses[window])
    want = (
        gravity_up_from_positions(T[:, :3, :3], T[:, :3, 3], f[window], dts[window])
        if source == "positions"
        else gravity_up(T[:, :3, :3], f[window], v[window], dts[window])
    )
    np.testing.assert_allclose(prior.up, want, atol=1e-9)
    assert np.linalg.norm(prior.up - R[-1].T @ [0.0, 0.0, 1.0]) < 6e-3


def test_tilt_kalman_update_with_a_world_tilt_takes_a_tilted_start_for_the_world():
    """A state of six: a world tilted 30 mrad from the start (a drive that starts on a slope), a bias, and a map
    that starts right and walks later. The first windows' discrepancy goes to the world's tilt, not to the map's
    walk or the bias; the turns then tell the bias apart. The four-state filter, with no world, takes the start's
    tilt for bias (its map's tilt starts at 0 and walks slowly), and a turn later is still off by milliradians:
    the prior would hold the tilt to an up off by that much."""
    rng = np.random.default_rng(4)
    world, bias = np.array([0.03, -0.01]), np.array([0.004, -0.002])
    noise = 1e-3
    x6, P6 = np.zeros(6), np.diag(np.repeat([0.05, 0.0, 0.01], 2) ** 2)
    x4, P4 = np.zeros(4), np.diag(np.repeat([0.0, 0.01], 2) ** 2)
    for k in range(600):
        R = rpy_to_matrix([0.0, 0.0, 0.01 * k])  # a slow turn: every heading
        g_w = np.array([*world, 1.0]) / np.linalg.norm([*world, 1.0])
        up = R.T @ g_w + [*bias, 0.0] + rng.normal(0, noise, 3)
        x6, P6 = tilt_kalman_update(x6, P6, R, up, noise**2, 1e-8)
        x4, P4 = tilt_kalman_update(x4, P4, R, up, noise**2, 1e-8)
        if k == 20:  # a few windows in, before the turn has gone far
            assert np.abs(x6[:2] - world).max() < 0.005 and np.abs(x6[2:4]).max() < 0.005
            assert np.abs(x4[2:] - bias).max() > 0.02  # the four-state: the tilt as bias
    np.testing.assert_allclose(x6[:2], world, atol=2e-3)
    np.testing.assert_allclose(x6[4:], bias, atol=1e-3)
    assert np.abs(x6[2:4]).max() < 3e-3
    assert np.abs(x4[2:] - bias).max() > 0.005


def test_tilt_prior_with_a_kalman_world_holds_to_the_estimated_world_up():
    """``tilt_bias = "kalman"`` with ``tilt_world_sigma`` > 0: six states, and step 8 holds the particles' up in
    the estimated world's up (``world_up`` from the state's first two), less the bias."""
    sigma, up = 0.005, rpy_to_matrix([0.02, -0.01, 0.0]).T @ [0.0, 0.0, 1.0]
    config = TiltConfig(
        tilt_sigma=sigma, tilt_window=0.5, tilt_bias="kalman", tilt_world_sigma=0.05
    )
    prior = TiltPrior(config)
    assert prior.state.shape == (6,) and np.allclose(np.diag(prior.cov)[:2], 0.05**2)
    for k in range(6):
        _measure_frame(prior, k, 0.25, up)
        prior.calibrate(np.eye(4), 0.25)
    expected = np.array([*prior.state[:2], 1.0])
    np.testing.assert_allclose(prior.world_up, expected / np.linalg.norm(expected))
    # the measured up (body = world here) goes mostly to the world (prior sigma 50 mrad against
    # the bias's 10)
    assert np.all(0.8 * up[:2] < prior.world_up[:2]) and np.all(
        prior.world_up[:2] < up[:2]
    )
    np.testing.assert_array_equal(prior.up_bias, [*prior.state[4:], 0.0])


def test_tilt_prior_with_a_kalman_bias_holds_the_up_less_the_filters_bias():
    """``tilt_bias = "kalman"`` with the world held level (``tilt_world_sigma = 0``, four states): once the window
    spans ``tilt_window`` each frame goes into :func:`tilt_kalman_update` (the measurement's variance
    ``sigma^2 window / dt``, the walk ``TILT_WALK_RATE dt``, starting from the world's and the bias's prior
    sigmas), no heading sectors are kept, the world's up stays ``e_z``, and step 8 holds to the up less the
    filter's bias."""
    from slamlib.slam3d.stages.prior import TILT_WALK_RATE

    sigma, up = 0.005, rpy_to_matrix([0.01, -0.02, 0.0]).T @ [0.0, 0.0, 1.0]
    config = TiltConfig(
        tilt_sigma=sigma, tilt_window=0.5, tilt_bias="kalman", tilt_world_sigma=0.0
    )
    prior = TiltPrior(config)
    x, P = np.zeros(4), np.diag([0.0, 0.0, 0.01**2, 0.01**2])
    for k in range(4):
        _measure_frame(prior, k, 0.25, up)
        prior.calibrate(np.eye(4), 0.25)
        if k >= 2:
            x, P = tilt_kalman_update(
                x, P, np.eye(3), prior.up, sigma**2 * 0.5 / 0.25, TILT_WALK_RATE * 0.25
            )
    np.testing.assert_allclose(prior.state, x, atol=1e-15)
    np.testing.assert_allclose(prior.cov, P, atol=1e-18)
    assert not hasattr(prior, "bins") and abs(x[2]) > 1e-3
    np.testing.assert_array_equal(prior.world_up, [0.0, 0.0, 1.0])
    np.testing.assert_array_equal(prior.held_up(), prior.up - np.r_[x[2:], 0.0])


def _settled_prior(up, frames: int = 40):
    """A default-configured :class:`TiltPrior` (a 0.5 s window) after ``frames`` frames of a still, level body
    measuring ``up``, each passing the guard and calibrated."""
    prior = TiltPrior(TiltConfig(tilt_window=0.5))
    for k in range(frames):
        _measure_frame(prior, k, 0.25, up)
        assert prior.check(np.eye(3))
        prior.calibrate(np.eye(4), 0.25)
    return prior


def test_the_guard_steps_the_prior_back_where_the_up_and_the_maps_fit_disagree_and_resumes():
    """:meth:`TiltPrior.check`: a measured up that agrees with the map's fit (the body level, the up level) passes;
    one 5 degrees off, once the calibration knows the world and the bias, steps the prior back: no weight, no
    held up (so no gravity in the match), no calibration; when they agree again the prior holds again."""
    from slamlib.slam3d.stages.prior import TILT_GATE_CHI2

    level = np.array([0.0, 0.0, 1.0])
    prior = _settled_prior(level)
    assert prior.n_stepped_back == 0 and prior.disagreement < 1.0
    off = rpy_to_matrix([np.radians(5.0), 0.0, 0.0]).T @ level
    states = []
    for k in range(40, 48):  # the window fills with the wrong up
        _measure_frame(prior, k, 0.25, off)
        prior.check(np.eye(3))
        prior.calibrate(np.eye(4), 0.25)
        states.append((prior.stepped_back, prior.state.copy(), np.diag(prior.cov).copy()))
    assert prior.stepped_back and prior.disagreement > TILT_GATE_CHI2
    assert prior.held_up() is None and prior.measured_up() is not None
    particles = Particles3D(np.stack([np.eye(3)] * 2), np.zeros((2, 3)))
    log_w = np.array([-1.0, -2.0])
    assert prior.weigh(particles, log_w) is log_w
    # once stepped back, the wrong ups go neither into the world nor the bias
    first = next(i for i, (back, _, _) in enumerate(states) if back)
    assert first <= 2  # within the frames the window takes to fill
    for _, state, var in states[first:]:
        np.testing.assert_array_equal(state, states[first][1])
        np.testing.assert_array_equal(var, states[first][2])
    for k in range(48, 56):  # agreeing again
        _measure_frame(prior, k, 0.25, level)
        prior.check(np.eye(3))
    assert not prior.stepped_back and prior.held_up() is not None
    assert prior.n_stepped_back >= 4
    prior.stepped_back, prior.up = True, None  # no up measured: nothing to disagree with
    assert prior.check(np.eye(3)) and not prior.stepped_back and prior.disagreement == 0.0


def test_the_guard_is_wide_open_while_the_worlds_tilt_is_unknown():
    """At the start the world's tilt is known only to ``tilt_world_sigma`` (50 mrad): a body on a 3-degree slope
    measures an up 3 degrees from the map's (the map's world is the first pose), which the guard lets pass, and
    the calibration learns it as the world's tilt; the same disagreement later, once learnt, would not pass."""
    slope = rpy_to_matrix([0.0, np.radians(3.0), 0.0]).T @ [0.0, 0.0, 1.0]
    prior = _settled_prior(slope)  # every frame checked and passed inside
    assert prior.n_stepped_back == 0
    assert np.degrees(np.arccos(prior.world_up[2])) > 2.5  # learnt as the world's tilt
    for k in range(40, 48):
        _measure_frame(prior, k, 0.25, [0.0, 0.0, 1.0])
        prior.check(np.eye(3))
    assert prior.stepped_back


def test_scan_match_takes_the_maps_own_fit_where_the_guard_steps_the_prior_back(
    monkeypatch,
):
    """With a prior the stage matches twice: with gravity's term, then on from there on the map alone; the
    second is checked against the measured up (:meth:`TiltPrior.check`), and is the frame's pose where they
    disagree. While the prior is stepped back the match carries no gravity and is checked as it is."""
    points, pose = _road_scan(), make_pose(np.eye(3), [1.0, 2.0, 0.0])
    particles = Particles3D(np.eye(3)[None], np.zeros((1, 3)))
    prior = _settled_prior(np.array([0.0, 0.0, 1.0]))
    tilted = make_pose(rpy_to_matrix([np.radians(6.0), 0.0, 0.0]), [1.0, 2.0, 0.0])
    answers = iter(
        [pose, tilted, tilted]
    )  # with gravity, the map alone; then the map alone again

    calls = []

    def fake(pose, points, world_map, iterations, road=None, tolerance=None, tilt=None):
        calls.append(tilt)
        return next(answers)

    monkeypatch.setattr("slamlib.slam3d.stages.polish.match_scan", fake)
    stage = ScanMatch(4, prior=prior, temperature=0.02)
    matched, _ = stage(pose, points, particles, "map")
    assert calls[0] is not None and calls[1] is None  # gravity's term, then none
    assert prior.stepped_back
    np.testing.assert_array_equal(matched, tilted)  # the scan decides
    matched, _ = stage(pose, points, particles, "map")
    assert len(calls) == 3 and calls[2] is None  # stepped back: one match, the map's
    np.testing.assert_array_equal(matched, tilted)


def test_no_prior_measures_weighs_and_calibrates_nothing():
    prior, log_weights = NoPrior(), np.array([-1.0, -2.0])
    particles = Particles3D(np.stack([np.eye(3)] * 2), np.zeros((2, 3)))
    assert prior.measure(_force_frame(), (np.zeros(3),), 0.1, None, [np.eye(4)]) is None
    assert prior.up is None and prior.weigh(particles, log_weights) is log_weights
    assert prior.calibrate(np.eye(4), 0.1) is None and prior.up is None


# ------------------------------------------------------------------------------------------ polish
def _road_scan():
    """A flat road 1.7 m below the body and walls beside it: body-frame points (N, 3)."""
    rng = np.random.default_rng(7)
    road = np.c_[rng.uniform(-20, 20, (300, 2)), np.full(300, -1.7)]
    walls = np.c_[
        rng.uniform(-20, 20, 200), np.repeat([-6.0, 6.0], 100), rng.uniform(0, 3, 200)
    ]
    return np.r_[road, walls]


def _fake_match(monkeypatch, matched):
    """``match_scan`` replaced by one that records its arguments and answers ``matched``."""
    calls = []

    def fake(pose, points, world_map, iterations, road=None, tolerance=None, tilt=None):
        calls.append((pose, points, world_map, iterations, road, tolerance, tilt))
        return matched

    monkeypatch.setattr("slamlib.slam3d.stages.polish.match_scan", fake)
    return calls


def test_scan_match_passes_the_road_only_when_asked_and_its_tolerance(monkeypatch):
    """``road=True`` (LIDAR-only) hands the match :func:`road_mask` of the scan; the default hands it none. The
    stage's ``tolerance`` (default :data:`MATCH_TOLERANCE`) reaches the match."""
    points, pose = _road_scan(), make_pose(np.eye(3), [1.0, 2.0, 0.0])
    particles = Particles3D(np.eye(3)[None], np.zeros((1, 3)))
    calls = _fake_match(monkeypatch, pose)
    assert ScanMatch(4).road is False
    ScanMatch(4)(pose, points, particles, "map")
    ScanMatch(4, road=True)(pose, points, particles, "map")
    assert calls[0][3] == 4 and calls[0][4] is None
    assert calls[0][5] == MATCH_TOLERANCE  # the default, unless given
    ScanMatch(4, tolerance=1e-3)(pose, points, particles, "map")
    assert calls[2][5] == 1e-3
    mask = road_mask(points)
    assert mask[:300].all() and not mask[300:].all()  # the scan has a road plane and more
    assert calls[1][3] == 4 and calls[1][2] == "map"
    np.testing.assert_array_equal(calls[1][4], mask)


def test_scan_match_holds_the_priors_up_weighed_as_step_8_weighs_it(monkeypatch):
    """With a tilt prior the stage hands the match the prior's up less its bias, its world's up, and the weight
    ``n * temperature / sigma^2`` for its ``n`` matched points; none before the prior has measured an up over a
    whole window, and none without a prior."""
    points, pose = _road_scan(), make_pose(np.eye(3), [1.0, 2.0, 0.0])
    particles = Particles3D(np.eye(3)[None], np.zeros((1, 3)))
    calls = _fake_match(monkeypatch, pose)
    prior = TiltPrior(TiltConfig(tilt_sigma=0.004))
    prior.up_bias = np.array([0.002, -0.001, 0.0])
    ScanMatch(4, prior=prior, temperature=0.02)(pose, points, particles, "map")
    prior.up, prior.up_span = np.array([0.01, 0.0, 1.0]), 0.9 * prior.window
    ScanMatch(4, prior=prior, temperature=0.02)(pose, points, particles, "map")
    prior.up_span = prior.window
    ScanMatch(4, prior=prior, temperature=0.02)(pose, points, particles, "map")
    ScanMatch(4)(pose, points, particles, "map")
    assert calls[0][6] is None and calls[1][6] is None and calls[3][6] is None
    up, world_up, weight = calls[2][6]
    np.testing.assert_array_equal(up, [0.008, 0.001, 1.0])
    assert world_up is prior.world_up
    assert weight == pytest.approx(len(points) * 0.02 / 0.004**2)


def test_scan_match_moves_every_particle_by_the_matched_correction_and_counts_frames(
    monkeypatch,
):
    """``C = T_matched T^-1`` applied in the world frame: the particle at ``T`` lands on ``T_matched``, every other
    particle ``T_i`` on ``C T_i`` (the 4 x 4 products, by hand)."""
    pose = make_pose(rpy_to_matrix([0.01, -0.02, 0.5]), [3.0, -1.0, 0.2])
    matched = make_pose(rpy_to_matrix([0.015, -0.01, 0.55]), [3.4, -0.7, 0.25])
    _fake_match(monkeypatch, matched)
    R = np.stack(
        [pose[:3, :3], rpy_to_matrix([0.0, 0.0, 1.0]), rpy_to_matrix([0.1, 0.0, -2.0])]
    )
    t = np.array([pose[:3, 3], [10.0, 0.0, 0.0], [-5.0, 7.0, 1.0]])
    stage = ScanMatch(3)
    assert stage.n_matched == 0
    got, moved = stage(pose, _road_scan(), Particles3D(R, t), None)
    assert got is matched and stage.n_matched == 1
    C = matched @ np.linalg.inv(pose)
    for i in range(3):
        want = C @ make_pose(R[i], t[i])
        np.testing.assert_allclose(moved.R[i], want[:3, :3], atol=1e-12)
        np.testing.assert_allclose(moved.t[i], want[:3, 3], atol=1e-12)
    np.testing.assert_allclose(make_pose(moved.R[0], moved.t[0]), matched, atol=1e-12)
    stage(pose, _road_scan(), Particles3D(R, t), None)
    assert stage.n_matched == 2


def test_correction_distance_is_the_body_frame_correction_in_spreads():
    """``D = pose^-1 matched`` in step 6's coordinates (body x, y, z, roll, pitch, yaw) over ``sigma``: a move of
    0.3 m forward and 0.02 rad of yaw, in the body frame of a pose turned by 0.5 rad, is (3, 0, 0, 0, 0, 4)
    spreads of (0.1 m, 5 mrad) away, 5 in all; the world-frame offset of the same move is not what counts."""
    from slamlib.slam3d.stages.polish import correction_distance

    pose = make_pose(rpy_to_matrix([0.0, 0.0, 0.5]), [3.0, -1.0, 0.2])
    D = make_pose(rpy_to_matrix([0.0, 0.0, 0.02]), [0.3, 0.0, 0.0])
    sigma = [0.1, 0.1, 0.1, 0.005, 0.005, 0.005]
    assert correction_distance(pose, pose @ D, sigma) == pytest.approx(5.0, rel=1e-9)
    assert correction_distance(pose, pose, sigma) == pytest.approx(0.0, abs=1e-12)
    # the same world-frame offset applied on the world's side is another body-frame move
    assert correction_distance(pose, D @ pose, sigma) != pytest.approx(5.0, rel=1e-3)


def test_scan_match_gate_keeps_step_9s_pose_when_the_match_leaps_beyond_the_spreads(
    monkeypatch,
):
    """A match within ``gate`` spreads is taken; one beyond leaves the pose and the particles as they were and
    counts as rejected; ``gate`` 0, or no ``sigma``, takes every match. ``max_kept_distance`` is the largest
    correction taken."""
    pose = make_pose(rpy_to_matrix([0.0, 0.0, 0.5]), [3.0, -1.0, 0.2])
    particles = Particles3D(pose[None, :3, :3].copy(), pose[None, :3, 3].copy())
    sigma = np.array([0.1, 0.1, 0.1, 0.005, 0.005, 0.005])
    near = pose @ make_pose(np.eye(3), [0.3, 0.0, 0.0])  # 3 spreads
    leap = pose @ make_pose(rpy_to_matrix([0.0, 0.0, 0.25]), [0.0, 0.6, 0.0])  # ~50
    stage = ScanMatch(3, gate=10.0)
    _fake_match(monkeypatch, near)
    got, moved = stage(pose, _road_scan(), particles, None, sigma)
    assert got is near and stage.n_rejected == 0
    assert stage.last_distance == pytest.approx(3.0)
    _fake_match(monkeypatch, leap)
    got, moved = stage(pose, _road_scan(), particles, None, sigma)
    assert got is pose and moved is particles
    assert stage.n_rejected == 1 and stage.n_matched == 2 and stage.last_distance > 10
    # the largest kept correction is the near one's: the rejected leap does not count
    assert stage.max_kept_distance == pytest.approx(3.0)
    for ungated, sig in (
        (ScanMatch(3, gate=0.0), sigma),
        (ScanMatch(3, gate=10.0), None),
    ):
        got, _ = ungated(pose, _road_scan(), particles, None, sig)
        assert got is leap and ungated.n_rejected == 0


def test_no_polish_keeps_the_pose_and_the_particles():
    pose, particles = np.eye(4), Particles3D(np.eye(3)[None], np.zeros((1, 3)))
    stage = NoPolish()
    got_pose, got_particles = stage(pose, _road_scan(), particles, None)
    assert got_pose is pose and got_particles is particles and stage.n_matched == 0
    assert stage(pose, _road_scan(), particles, None, np.ones(6))[0] is pose
    assert stage.n_rejected == 0 and stage.max_kept_distance == 0.0


def pose_at(position):
    """``T_world_body`` (4, 4) at ``position`` (3,), unrotated."""
    T = np.eye(4)
    T[:3, 3] = position
    return T


def test_forward_line_stratifies_the_forward_spread_on_the_clouds_mean_pose():
    """``P`` poses on the mean pose's forward axis (body x), at ``spread`` times the standard normal's quantiles
    ``(i + 1/2) / P``: symmetric about the mean position, ordered, their spread ``spread`` to within the
    stratification's shortfall, and all with the mean rotation (here the one rotation the cloud is turned by, its
    particles' small yaws either side of it cancelling)."""
    from statistics import NormalDist

    from slamlib.slam3d.stages.search import forward_line

    P, yaw = 100, 0.5
    rng = np.random.default_rng(3)
    yaws = yaw + np.r_[1, -1] * 0.01  # two particles either side of the mean yaw
    R = np.array([rpy_to_matrix([0.0, 0.0, y]) for y in np.resize(yaws, P)])
    t = np.array([3.0, -1.0, 0.2]) + rng.normal(0.0, 0.1, (P, 3))
    line = forward_line(Particles3D(R, t), 1.5)
    np.testing.assert_allclose(
        line.R, np.repeat(rpy_to_matrix([0, 0, yaw])[None], P, 0), atol=1e-12
    )
    forward = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    offsets = (line.t - t.mean(axis=0)) @ forward
    np.testing.assert_allclose(
        line.t - t.mean(axis=0), offsets[:, None] * forward, atol=1e-12
    )
    assert offsets[0] == pytest.approx(1.5 * NormalDist().inv_cdf(0.5 / P))
    np.testing.assert_allclose(offsets, -offsets[::-1], atol=1e-12)
    assert np.all(np.diff(offsets) > 0) and 0.95 * 1.5 < offsets.std() < 1.5


def test_a_start_search_with_the_line_keeps_a_higher_optimum_off_standing_still():
    """A score with a narrow peak (0.1 m wide in x, 10 mrad in yaw) at 0.83 m forward beside a broad basin at 0 (a
    start at speed, the road's rings pulling toward no motion), on 16 seeded starts. With ``start_line`` the search
    runs from the drawn cloud (its first weighing as without the line) and then from :func:`forward_line` of it, and
    keeps the line's where its best particle ``score`` ranks higher and lies farther than ``resolution`` from the
    drawn search's best and from the last pose (standing still). So its best score is never below the
    search without the line, equal to it (the same particles and weights: the line's search draws from its own
    stream) wherever the drawn search is kept, and it reaches the peak more often; on a tie, or with the two ends
    nearer than ``resolution``, the drawn search is kept."""
    from slamlib.slam3d.stages.search import forward_line

    PEAK, WIDTH, BASIN = 0.83, 0.05, 0.5

    def true_score(
        particles, sample=None
    ):  # the peak is as narrow in yaw (5 mrad) as in x
        x, yaw = particles.t[:, 0], np.arctan2(particles.R[:, 1, 0], particles.R[:, 0, 0])
        peak = -(((x - PEAK) / WIDTH) ** 2) - (yaw / 0.005) ** 2
        return np.maximum(peak, -1.0 - (x / BASIN) ** 2) * 10.0

    def level_score(particles, sample=None):
        return np.zeros(len(particles.t))

    def normalised(log_w):
        return log_w - np.logaddexp.reduce(log_w)

    P, sigma = 100, np.array([1.5, 0.1, 0.05, 0.005, 0.005, 0.03])
    start = Particles3D(np.repeat(np.eye(3)[None], P, 0), np.zeros((P, 3)))

    def search(drawn, seed, start_line, score=true_score, resolution=0.0):
        weighed, last = [], {}

        def weigh(
            particles, log_weights, sample
        ):  # records the raw scores, as the filter's
            weighed.append(particles)
            last["scores"] = score(particles)
            return normalised(log_weights + last["scores"])

        # no rounds after the start search, as by default (AnnealConfig.anneal_rounds 0)
        stage = Annealing(
            0,
            0.5,
            weigh,
            np.random.default_rng(seed),
            "numpy",
            0.0,
            0,
            start_line,
            last,
            resolution,
        )
        got = stage(drawn, normalised(score(drawn)), None, sigma, 8, np.eye(4))
        # the stage leaves the kept search's scores as the last ones
        assert start_line is False or np.array_equal(last["scores"], score(got[0]))
        return got, weighed, stage

    at_peak = {False: 0, True: 0}
    for draw_seed in range(4):
        drawn = steps.perturb_with_noise(
            start, sigma, np.random.default_rng(draw_seed), backend="numpy"
        )
        for seed in range(4):
            (off, off_w), off_weighed, _ = search(drawn, seed, False)
            assert len(off_weighed) == 8
            (on, on_w), weighed, stage = search(drawn, seed, True)
            assert len(weighed) == 8 + 1 + 8 and np.array_equal(
                weighed[0].t, off_weighed[0].t
            )
            assert np.array_equal(weighed[8].t, forward_line(drawn, sigma[0]).t)
            assert true_score(on).max() >= true_score(off).max()
            if not stage.n_line_wins:
                assert np.array_equal(on.t, off.t) and np.array_equal(on_w, off_w)
            for line, (particles, log_w) in ((False, (off, off_w)), (True, (on, on_w))):
                at_peak[line] += abs(particles.t[np.argmax(log_w), 0] - PEAK) < WIDTH
            # a level score: a tie, the drawn search kept
            (level_off, _), _, _ = search(drawn, seed, False, level_score)
            (kept, kept_w), _, stage = search(drawn, seed, True, level_score)
            assert stage.n_line_wins == 0 and np.array_equal(kept.t, level_off.t)
            # two ends nearer than the map's resolution are one optimum: the drawn one is kept
            (kept, kept_w), _, stage = search(drawn, seed, True, true_score, 2 * PEAK)
            assert stage.n_line_wins == 0 and np.array_equal(kept.t, off.t)
    assert at_peak[True] >= at_peak[False] + 8, at_peak
    with pytest.raises(ValueError, match="start_line needs the filter's last scores"):
        Annealing(0, 0.5, None, np.random.default_rng(1), "numpy", 0.0, 0, True)


# (the drawn search's end, the line's, standing still: metres forward; the search kept), resolution 0.5 m
START_ENDS = {
    "route 00: the line found the peak the drawn search missed": (0.0, 1.0, 0.0, "line"),
    "the straight street: the line's higher end is no motion": (1.0, 0.0, 0.0, "drawn"),
    "the same ends, standing still beyond them": (1.0, 0.0, 3.0, "line"),
    "the drawn search overshot: the line's end nearer standing still": (
        1.84,
        0.83,
        0.0,
        "line",
    ),
    "one optimum: the ends nearer than the map's resolution": (1.0, 1.2, 0.0, "drawn"),
    "the line's end within the resolution of standing still": (1.0, 0.3, 0.0, "drawn"),
}


@pytest.mark.parametrize(
    "drawn_x, line_x, standstill_x, kept", START_ENDS.values(), ids=START_ENDS.keys()
)
def test_the_start_line_keeps_the_lines_end_only_higher_apart_and_off_standing_still(
    monkeypatch, drawn_x, line_x, standstill_x, kept
):
    """The choice between the two start searches, on given ends: the line's search is kept where its best particle
    scores higher than the drawn search's and lies farther than ``resolution`` both from it and from the last pose
    (module docstring, "The start's line"). The score prefers the line's end in every case here, as the rings'
    no-motion basin does on the straight street: the score alone cannot tell route 00's start from the street's."""
    P, resolution = 4, 0.5

    def cloud(x):
        return Particles3D(
            np.repeat(np.eye(3)[None], P, 0), np.tile([x, 0.0, 0.0], (P, 1))
        )

    def score(particles):  # the line's end scores 5 above the drawn one's
        return np.where(np.isclose(particles.t[:, 0], line_x), 0.0, -5.0)

    last = {}
    stage = Annealing(
        0,
        0.5,
        lambda p, w, s: w,
        np.random.default_rng(1),
        "numpy",
        0.0,
        0,
        True,
        last,
        resolution,
    )
    ends = {id(stage.rng): cloud(drawn_x), id(stage.line_rng): cloud(line_x)}
    log_w = np.full(P, -np.log(P))

    def searched(particles, w, sample, sigma, rounds, rng):  # its last weighing's scores
        last["scores"] = score(ends[id(rng)])
        return ends[id(rng)], w

    monkeypatch.setattr(stage, "_search", searched)
    got, _ = stage(cloud(0.0), log_w, None, np.ones(6), 2, pose_at([standstill_x, 0, 0]))
    want = line_x if kept == "line" else drawn_x
    assert np.all(got.t[:, 0] == want) and stage.n_line_wins == int(kept == "line")
    np.testing.assert_array_equal(last["scores"], score(got))  # the kept search's
    # the choice recorded: both ends, their scores, standing still and which was kept
    start = stage.last_start
    assert start["kept"] == kept and start["standstill"][0] == standstill_x
    assert (start["drawn"][0], start["line"][0]) == (drawn_x, line_x)
    assert start["line_score"] - start["drawn_score"] == 5.0


def _annealing(monkeypatch, collapsed_calls, collapse_ess=0.5, collapse_rounds=3):
    """An :class:`Annealing` of 1 round (shrink 0.5) whose weighing collapses the weights onto one particle for its
    first ``collapsed_calls`` calls and leaves them uniform after; step 6's spreads recorded in ``sigmas``."""
    sigmas, calls = [], []

    def perturb(particles, sigma, rng, noise=None, backend=None):
        sigmas.append(float(np.asarray(sigma)[0]))
        return particles

    def weigh(particles, log_weights, sample):
        calls.append(1)
        P = len(log_weights)
        if len(calls) <= collapsed_calls:
            return np.r_[0.0, np.full(P - 1, -1e3)]
        return np.full(P, -np.log(P))

    monkeypatch.setattr(steps, "perturb_with_noise", perturb)
    search = Annealing(
        1, 0.5, weigh, np.random.default_rng(0), "numpy", collapse_ess, collapse_rounds
    )
    return search, sigmas


def test_the_rounds_after_a_start_search_go_on_from_its_last_spread(monkeypatch):
    """At a start the ``start_rounds`` rounds halve the spread (``START_SHRINK``); the frame's regular round and
    the further rounds while the weights collapse then shrink it on from there, not from step 6's (wide) start
    spread again."""
    search, sigmas = _annealing(monkeypatch, collapsed_calls=99, collapse_rounds=2)
    P = 10
    particles = Particles3D(np.repeat(np.eye(3)[None], P, axis=0), np.zeros((P, 3)))
    search(particles, np.full(P, -np.log(P)), None, np.ones(6), start_rounds=3)
    np.testing.assert_allclose(sigmas, 0.5 ** np.arange(1, 3 + 1 + 2 + 1))
    assert search.n_rounds == 3 + 1 + 2 and search.n_collapse_rounds == 2


@pytest.mark.parametrize(
    "collapsed_calls, collapse_ess, further",
    [(0, 0.5, 0), (1, 0.5, 1), (2, 0.5, 2), (99, 0.5, 3), (99, 0.0, 0)],
)
def test_annealing_adds_rounds_while_the_weights_collapse(
    monkeypatch, collapsed_calls, collapse_ess, further
):
    """After its fixed round, the search runs a further round while ``ESS < collapse_ess * P`` (one particle
    holding all the weight: ESS 1 of 10), at most ``collapse_rounds`` (3) of them, each shrinking the spread by
    ``anneal_shrink`` once more than the one before; uniform weights (ESS = P) or ``collapse_ess`` 0 stop it."""
    search, sigmas = _annealing(monkeypatch, collapsed_calls, collapse_ess)
    P = 10
    particles = Particles3D(np.repeat(np.eye(3)[None], P, axis=0), np.zeros((P, 3)))
    search(particles, np.full(P, -np.log(P)), None, np.ones(6))
    assert search.n_collapse_rounds == further
    assert search.n_rounds == 1 + further
    np.testing.assert_allclose(sigmas, 0.5 ** np.arange(1, 2 + further))
