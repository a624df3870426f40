"""The 3D filter's steps 1-11 one at a time (:mod:`slamlib.slam3d.steps`): each step on the tiny world's drive
(``world3d.py``) and on hand-made inputs whose expected values are computed in the test."""

import dataclasses
import re
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from world3d import SimFrame, simulate

from slamlib import geometry
from slamlib.geometry import (
    invert_pose,
    make_pose,
    matrix_to_rpy,
    rpy_to_matrix,
    transform_points,
)
from slamlib.kernels import get_backend
from slamlib.maps import VoxelHashMap
from slamlib.odometry import dead_reckon
from slamlib.slam3d import (
    MotionConfig,
    Particles3D,
    ScanConfig,
    initialise_particles,
    merge_scan,
    motion_increment,
    motion_noise_sigma,
    offset_by_motion,
    perturb_with_noise,
    pick_best_particle,
    read_imu,
    read_scan,
    read_timing,
    resample_particles,
    sample_points,
    score_particles,
    steps,
    transform_scan,
)
from slamlib.slam3d.config import ConstantVelocityConfig
from slamlib.slam3d.preprocess import deskew, sweep_times

CPU = get_backend("cpu")
NUMPY = get_backend("numpy")
SCAN = ScanConfig(2.0, 30.0, 0.3)  # the tiny world's scan settings


def random_particles(rng, P):
    R = rpy_to_matrix(rng.uniform(-0.3, 0.3, (P, 3)) * [1, 1, 10])
    t = rng.uniform(-5, 5, (P, 3))
    return Particles3D(R, t)


# ------------------------------------------------------------------------------------------ steps 1-4
def test_initialise_particles_all_at_start_pose():
    T0 = make_pose(rpy_to_matrix([0.1, -0.2, 0.3]), [1, 2, 3])
    p, log_w = initialise_particles(7, T0)
    R, t = p.R, p.t
    assert len(p) == 7 and R.shape == (7, 3, 3) and t.shape == (7, 3)
    assert np.allclose(R, T0[:3, :3]) and np.allclose(t, T0[:3, 3])
    assert np.allclose(np.exp(log_w), 1 / 7)
    with pytest.raises(ValueError):
        initialise_particles(0)


def test_read_scan_moves_points_into_the_body_frame():
    T_velo_imu = make_pose(rpy_to_matrix([0.01, -0.02, 0.03]), [-0.8, 0.3, -0.8])
    # 2nd point inside min_range
    scan = np.array([[5, 0, 0, 0.1], [0, 1, 0, 0.2], [0, 8, 1, 0.3]], np.float32)
    pts = read_scan(
        SimFrame(scan, None, None, 0.1, None, 0, 0),
        ScanConfig(3.0, 60.0, 0.0),
        invert_pose(T_velo_imu),
    )
    expected = transform_points(
        invert_pose(T_velo_imu), scan[[0, 2], :3].astype(np.float64)
    )
    assert pts.dtype == np.float32 and np.allclose(pts, expected, atol=1e-5)


def test_read_imu_and_timing(drive):
    frames, _ = drive
    v, w = read_imu(frames[3])
    assert np.array_equal(v, frames[3].velocity) and np.array_equal(
        w, frames[3].angular_rate
    )
    assert read_timing(frames[0]) == 0.0 and read_timing(frames[3]) == pytest.approx(0.1)
    with pytest.raises(ValueError):
        read_timing(SimFrame(None, None, None, -0.1, None, 0, 0))


# ------------------------------------------------------------------------------------------ steps 5-6
def test_offset_by_motion_matches_the_dead_reckoning_increment():
    rng = np.random.default_rng(1)
    v0, w0, v1, w1 = rng.normal(0, [5, 0.3, 0.1], (4, 3))
    p = random_particles(rng, 6)
    p2 = offset_by_motion(p, (v1, w1), 0.1, (v0, w0), CPU)
    # from the identity
    dr = dead_reckon(np.array([v0, v1]), np.array([w0, w1]), np.array([0.0, 0.1]))
    for i in range(6):
        expected = make_pose(p.R[i], p.t[i]) @ dr[1]
        assert np.allclose(make_pose(p2.R[i], p2.t[i]), expected, atol=1e-12)
    rpy, dp = motion_increment((v1, w1), 0.1, (v0, w0))
    assert np.allclose(make_pose(rpy_to_matrix(rpy), dp), dr[1], atol=1e-12)
    # precomputed: the same move
    given = offset_by_motion(p, (v1, w1), 0.1, (v0, w0), CPU, increment=(rpy, dp))
    assert np.array_equal(given.R, p2.R) and np.array_equal(given.t, p2.t)
    # without the previous sample, the current twist is held over dt
    held = dead_reckon(np.array([v1, v1]), np.array([w1, w1]), np.array([0.0, 0.1]))
    assert np.allclose(
        offset_by_motion(p, (v1, w1), 0.1).poses(), p.poses() @ held[1], atol=1e-12
    )


def test_perturb_with_noise_has_the_configured_spread():
    P = 20000
    sigma = np.array([0.05, 0.03, 0.01, 0.002, 0.004, 0.01])
    p, _ = initialise_particles(P)
    p2 = perturb_with_noise(p, sigma, np.random.default_rng(0), backend=CPU)
    R2, t2 = p2.R, p2.t
    spread = np.r_[t2.std(axis=0), matrix_to_rpy(R2).std(axis=0)]
    assert np.allclose(spread, sigma, rtol=0.04)
    assert np.allclose(
        np.r_[t2.mean(axis=0), matrix_to_rpy(R2).mean(axis=0)],
        0,
        atol=4 * sigma / np.sqrt(P),
    )
    assert np.allclose(R2 @ np.swapaxes(R2, 1, 2), np.eye(3), atol=1e-12)


def test_motion_noise_sigma_grows_with_distance_and_time():
    still = (np.zeros(3), np.zeros(3))

    def imu(speed):
        return np.array([speed, 0.0, 0.0]), np.zeros(3)

    s0 = motion_noise_sigma(still, 0.0)
    s1 = motion_noise_sigma(imu(10.0), 0.1)
    s2 = motion_noise_sigma(imu(20.0), 0.1)
    s3 = motion_noise_sigma(imu(5.0), 0.2)  # the same 1 m in twice the time
    assert np.all(s0 == 0) and np.all(s2 > s1) and np.all(s3 > s1)
    config = MotionConfig(
        sigma_xyz_per_m=(1, 2, 3),
        sigma_xyz_per_s=(0, 0, 0),
        sigma_rpy_per_m=(0, 0, 1),
        sigma_rpy_per_s=(0, 0, 0),
    )
    assert np.allclose(config.sigma([0, 3, 4], 0.0), [5, 10, 15, 0, 0, 5])
    assert np.allclose(
        motion_noise_sigma((np.array([0.0, 30, 40]), np.zeros(3)), 0.1, None, config),
        [5, 10, 15, 0, 0, 5],
    )
    assert np.allclose(config.scaled(2.0).sigma([0, 3, 4], 0.0), [10, 20, 30, 0, 0, 10])
    with pytest.raises(ValueError, match="sigma_xyz_per_m"):
        MotionConfig(sigma_xyz_per_m=(1, -2, 3))


def test_steps_5_then_6_equal_the_fused_move():
    rng = np.random.default_rng(2)
    p = random_particles(rng, 50)
    noise = rng.standard_normal((50, 6))
    sigma = np.array([0.1, 0.05, 0.02, 0.01, 0.01, 0.03])
    imu_prev, imu = (
        (np.array([9.0, 0.2, 0.0]), np.array([0.0, 0.01, 0.3])),
        (np.array([10.0, 0, 0]), np.zeros(3)),
    )
    a = perturb_with_noise(
        offset_by_motion(p, imu, 0.1, imu_prev, CPU), sigma, None, noise, CPU
    )
    rpy, dp = motion_increment(imu, 0.1, imu_prev)
    # the fused kernel
    Rb, tb = CPU.move_particles(p.R, p.t, rpy, rpy_to_matrix(rpy).T @ dp, noise, sigma)
    assert np.allclose(a.R, Rb, atol=1e-12) and np.allclose(a.t, tb, atol=1e-12)


# ------------------------------------------------------------------------------------------ steps 7-8
@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(-3, 3), min_size=6, max_size=6))
def test_transform_scan_is_the_rigid_transform(vals):
    R = rpy_to_matrix(vals[3:])
    t = np.array(vals[:3]) * 10
    pts = np.random.default_rng(0).uniform(-50, 50, (64, 3)).astype(np.float32)
    out = transform_scan(make_pose(R, t), pts, CPU)
    assert out.dtype == np.float32 and out.shape == pts.shape
    assert np.allclose(out, pts.astype(np.float64) @ R.T + t, atol=1e-4)
    both = transform_scan(
        Particles3D(np.stack([R, np.eye(3)]), np.stack([t, np.zeros(3)])), pts, CPU
    )
    assert (
        both.shape == (2, 64, 3)
        and np.array_equal(both[0], out)
        and np.allclose(both[1], pts)
    )


@pytest.fixture(scope="module")
def built_map(drive):
    """A map built from 5 frames at their true poses, and frame 6's body points with its true pose."""
    frames, gt = drive
    m = VoxelHashMap(capacity=2**14)
    for k in range(5):
        assert merge_scan(m, gt[k], read_scan(frames[k], SCAN), CPU) is m  # in place
    return m, read_scan(frames[6], SCAN), gt[6]


def test_score_prefers_the_true_pose(built_map):
    m, pts, T = built_map
    sample = sample_points(pts, 400, np.random.default_rng(0))
    offsets = [
        np.zeros(6),
        [0.3, 0, 0, 0, 0, 0],
        [0, -0.3, 0, 0, 0, 0],
        [0, 0, 0.2, 0, 0, 0],
        [0, 0, 0, 0.03, 0, 0],
        [0, 0, 0, 0, -0.03, 0],
        [0, 0, 0, 0, 0, 0.03],
    ]
    poses = np.array(
        [T @ make_pose(rpy_to_matrix(o[3:]), o[:3]) for o in np.asarray(offsets, float)]
    )
    scores = score_particles(
        Particles3D(poses[:, :3, :3], poses[:, :3, 3]), sample, m, CPU
    )
    assert scores.shape == (len(offsets),) and np.all(scores <= 0)
    assert np.argmax(scores) == 0 and np.all(scores[1:] < scores[0] - 1.0)


def test_numpy_and_cpu_scores_agree(built_map):
    m, pts, T = built_map
    rng = np.random.default_rng(4)
    p = Particles3D(
        T[:3, :3] @ rpy_to_matrix(rng.normal(0, 0.01, (8, 3))),
        T[:3, 3] + rng.normal(0, 0.1, (8, 3)),
    )
    sample = sample_points(pts, 200, rng)
    assert np.allclose(
        score_particles(p, sample, m, NUMPY),
        score_particles(p, sample, m, CPU),
        rtol=1e-9,
    )


# ------------------------------------------------------------------------------------------ steps 9-11
def test_pick_best_particle_best_and_local_mean():
    R = rpy_to_matrix(np.array([[0, 0, 0.0], [0, 0, 0.02], [0, 0, 0.04], [0, 0, 1.0]]))
    t = np.array([[0, 0, 0], [0.1, 0, 0], [0.2, 0, 0], [5, 0, 0]], float)
    p = Particles3D(R, t)
    log_w = np.log([0.2, 0.3, 0.2, 0.3 - 1e-9])
    T, i = pick_best_particle(p, log_w, "best")
    assert i == 1 and np.allclose(T, make_pose(R[1], t[1]))
    # particle 3 is 5 m away: not averaged in
    T, i = pick_best_particle(p, log_w, "mean", radius=0.5)
    assert (
        i == 1
        and np.allclose(T[:3, 3], [0.1, 0, 0])
        and np.allclose(matrix_to_rpy(T[:3, :3]), [0, 0, 0.02])
    )
    with pytest.raises(ValueError):
        pick_best_particle(p, log_w, "median")


def test_merge_scan_grows_the_map_where_the_pose_puts_it(drive):
    frames, gt = drive
    m = VoxelHashMap(capacity=2**14)
    pts = read_scan(frames[0], SCAN)
    merge_scan(m, gt[0], pts, CPU)
    n1 = len(m)
    T_far = make_pose(np.eye(3), [200.0, 0, 0])
    merge_scan(m, T_far, pts, CPU)
    assert n1 > 100 and len(m) > 1.8 * n1
    assert (m.points()[:, 0] > 150).sum() >= 0.9 * n1


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(-50, 0), min_size=2, max_size=60), st.integers(0, 1000))
def test_resample_keeps_count_and_draws_heavy_particles(log_w, seed):
    log_w = np.asarray(log_w)
    P = len(log_w)
    p = random_particles(np.random.default_rng(seed), P)
    R, t = p.R, p.t
    p2, lw2, done = resample_particles(
        p, log_w, np.random.default_rng(seed), ess_fraction=1.0, backend=CPU
    )
    R2, t2 = p2.R, p2.t
    assert R2.shape == R.shape and t2.shape == t.shape and lw2.shape == (P,)
    w = np.exp(log_w - log_w.max())
    w /= w.sum()
    if done:
        assert np.allclose(np.exp(lw2), 1.0 / P)
        idx = [int(np.flatnonzero(np.all(t == ti, axis=1))[0]) for ti in t2]
        counts = np.bincount(idx, minlength=P)
        # systematic: floor or ceil of P w_i
        assert np.all(np.abs(counts - P * w) < 1.0 + 1e-9)
    else:
        assert np.allclose(w, 1.0 / P) and p2 is p and np.allclose(np.exp(lw2), w)


def test_resample_only_below_the_ess_threshold():
    p, _ = initialise_particles(10)
    p = Particles3D(p.R, p.t + np.arange(10)[:, None])
    # ESS = 1 / (5 * .0225 + 5 * .0025) = 8
    log_w = np.log(np.r_[np.full(5, 0.15), np.full(5, 0.05)])
    assert not resample_particles(p, log_w, np.random.default_rng(0), 0.5, CPU)[2]
    assert resample_particles(p, log_w, np.random.default_rng(0), 0.9, CPU)[2]
    # None: always
    assert resample_particles(
        p, np.log(np.full(10, 0.1)), np.random.default_rng(0), None, CPU
    )[2]


def test_read_specific_force_checks_its_values():
    from slamlib.slam3d.steps import read_specific_force

    frame = simulate(2)[0][1]
    np.testing.assert_array_equal(read_specific_force(frame), frame.specific_force)
    assert (
        read_specific_force(
            SimFrame(
                *[
                    getattr(frame, k)
                    for k in (
                        "scan",
                        "velocity",
                        "angular_rate",
                        "dt",
                        "T_w_imu",
                        "time_s",
                        "index",
                    )
                ]
            )
        )
        is None
    )
    frame.specific_force = np.array([0.0, np.nan, 9.8])
    with pytest.raises(ValueError, match=r"specific_force \(frame 1\) must be finite"):
        read_specific_force(frame)


# ------------------------------------------------------------------ steps 1-11 value by value: messages, dtypes, limits
def test_one_particle_is_enough_and_zero_particles_is_an_error_naming_the_count():
    """Step 1 accepts ``n_particles = 1`` (identity pose, log-weight ``-log 1 = 0``) and rejects 0 with
    ``need at least one particle, got 0``."""
    particles, log_w = steps.initialise_particles(1)
    np.testing.assert_array_equal(particles.R, np.eye(3)[None])
    np.testing.assert_array_equal(particles.t, np.zeros((1, 3)))
    np.testing.assert_array_equal(log_w, [0.0])
    with pytest.raises(ValueError, match=r"^need at least one particle, got 0$"):
        steps.initialise_particles(0)


def test_an_integer_start_pose_gives_float64_particles():
    """Step 1 casts ``pose0`` to float64: an all-integer pose (a quarter turn about z at (1, 2, 3)) gives float64
    ``R`` and ``t`` with those values."""
    pose0 = [[0, -1, 0, 1], [1, 0, 0, 2], [0, 0, 1, 3], [0, 0, 0, 1]]
    particles, _ = steps.initialise_particles(2, pose0)
    assert particles.R.dtype == np.float64 and particles.t.dtype == np.float64
    np.testing.assert_array_equal(
        particles.R, [[[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]] * 2
    )
    np.testing.assert_array_equal(particles.t, [[1.0, 2.0, 3.0]] * 2)


_NO_CROP = ScanConfig(min_range=0.0, max_range=np.inf, downsample_voxel=0.0)


def test_read_scan_takes_a_plain_float64_n_by_3_array_and_returns_float32():
    """Step 2 accepts a bare (N, 3) array (no ``.scan`` attribute) and returns float32 points even for float64
    input when no ``T_body_velo`` is given (no crop, no down-sampling: the same points)."""
    pts = np.array(
        [[1.0, 2.0, 3.0], [-4.0, 5.0, 0.5], [10.25, -7.5, 1.0]], dtype=np.float64
    )
    got = steps.read_scan(pts, _NO_CROP)
    assert got.dtype == np.float32 and got.shape == (3, 3) and got.flags.c_contiguous
    np.testing.assert_array_equal(got, pts.astype(np.float32))


def test_read_scan_down_samples_with_the_configured_voxel():
    """Step 2 keeps the first point of each ``downsample_voxel`` voxel (here 0.5 m: six points in three voxels keep
    three), after the range crop; with no voxel every point in range is kept."""
    pts = np.array(
        [
            [5.0, 0.1, 0.1],
            [5.2, 0.2, 0.3],
            [5.1, 0.4, 0.2],
            [7.1, 0.1, 0.1],
            [7.3, 0.3, 0.4],
            [9.0, 0.1, 0.1],
        ],
        dtype=np.float32,
    )
    got = steps.read_scan(
        pts, ScanConfig(min_range=1.0, max_range=100.0, downsample_voxel=0.5)
    )
    np.testing.assert_array_equal(got, pts[[0, 3, 5]])
    assert (
        len(
            steps.read_scan(
                pts, ScanConfig(min_range=1.0, max_range=100.0, downsample_voxel=0.0)
            )
        )
        == 6
    )


def test_read_scan_rejects_a_scan_with_five_columns_naming_its_shape():
    """A 2-D scan whose second axis is neither 3 nor 4 is a ``ValueError`` with the full message."""
    msg = "scan must have shape (N, 3) or (N, 4), got (4, 5)"
    with pytest.raises(ValueError, match="^" + re.escape(msg) + "$"):
        steps.read_scan(np.ones((4, 5), np.float32), _NO_CROP)


def test_read_imu_reshapes_and_casts_integer_samples_of_a_frame_without_index():
    """Step 3 on a frame with no ``index`` attribute: ``velocity``/``angular_rate`` given as (1, 3) integer lists
    come back as (3,) float64 arrays with those values."""
    frame = SimpleNamespace(velocity=[[1, 2, 3]], angular_rate=[[0, 0, 1]])
    v, w = steps.read_imu(frame)
    assert v.shape == (3,) and w.shape == (3,)
    assert v.dtype == np.float64 and w.dtype == np.float64
    np.testing.assert_array_equal(v, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(w, [0.0, 0.0, 1.0])


def test_read_imu_accepts_values_exactly_at_the_oxts_limits():
    """The limits are inclusive: ``|v| = 150`` m/s and ``|w| = 50`` rad/s pass; just beyond is an error."""
    v, w = steps.read_imu(
        SimpleNamespace(velocity=[150.0, -150.0, 0.0], angular_rate=[0.0, 50.0, -50.0])
    )
    np.testing.assert_array_equal(v, [150.0, -150.0, 0.0])
    np.testing.assert_array_equal(w, [0.0, 50.0, -50.0])
    with pytest.raises(ValueError):
        steps.read_imu(
            SimpleNamespace(velocity=[150.001, 0.0, 0.0], angular_rate=[0.0, 0.0, 0.0])
        )


def test_read_imu_error_messages_name_the_quantity_limit_unit_and_where():
    """Full messages: ``IMU velocity must be finite and within +-150 m/s, got [...]`` (no frame index: nothing
    after the name), ``... angular_rate ... +-50 rad/s ...``, and for an indexed frame with an estimate the name
    is followed by `` (frame 3) (constant-velocity estimate)``."""
    with pytest.raises(
        ValueError,
        match="^"
        + re.escape(
            "IMU velocity must be finite and within +-150 m/s, got [151.0, 0.0, 0.0]"
        )
        + "$",
    ):
        steps.read_imu(
            SimpleNamespace(velocity=[151.0, 0.0, 0.0], angular_rate=[0.0, 0.0, 0.0])
        )
    with pytest.raises(
        ValueError,
        match="^"
        + re.escape(
            "IMU angular_rate must be finite and within +-50 rad/s, got [0.0, 0.0, -51.0]"
        )
        + "$",
    ):
        steps.read_imu(
            SimpleNamespace(velocity=[1.0, 0.0, 0.0], angular_rate=[0.0, 0.0, -51.0])
        )
    frame = SimpleNamespace(
        index=3, velocity=[1.0, 0.0, 0.0], angular_rate=[0.0, 0.0, 0.0]
    )
    with pytest.raises(
        ValueError,
        match="^"
        + re.escape(
            "IMU velocity (frame 3) (constant-velocity estimate) must be finite and within +-150 m/s, "
            "got [200.0, 0.0, 0.0]"
        )
        + "$",
    ):
        steps.check_twist(
            [200.0, 0.0, 0.0],
            [0.0, 0.0, 0.0],
            steps.frame_label(frame) + " (constant-velocity estimate)",
        )


def test_read_imu_without_either_imu_value_is_the_lidar_only_error():
    """A frame missing ``angular_rate`` (None or no attribute) or ``velocity`` (no attribute), with no estimate,
    is the ``has no IMU values`` error, not a failed cast or an ``AttributeError``."""
    msg = "frame (frame 4) has no IMU values: LIDAR-only step 3 needs the filter's own motion estimate"
    for frame in (
        SimpleNamespace(index=4, velocity=[1.0, 0.0, 0.0], angular_rate=None),
        SimpleNamespace(index=4, velocity=[1.0, 0.0, 0.0]),
        SimpleNamespace(index=4, angular_rate=[0.0, 0.0, 0.1]),
        SimpleNamespace(index=4),
    ):
        with pytest.raises(ValueError, match="^" + re.escape(msg) + "$"):
            steps.read_imu(frame)


def test_read_timing_rejects_a_negative_dt_naming_it():
    """Step 4: a negative ``dt`` is ``frame dt must be finite and >= 0, got -0.1``."""
    with pytest.raises(
        ValueError,
        match="^" + re.escape("frame dt must be finite and >= 0, got -0.1") + "$",
    ):
        steps.read_timing(SimpleNamespace(dt=-0.1))


def test_offset_by_motion_uses_a_given_increment_instead_of_the_imu():
    """Step 5 with ``increment=(rpy, dp)`` moves by that increment, whatever ``imu`` says: from the identity, a
    quarter turn about z and 1 m forward gives ``R = Rz(90 deg)``, ``t = (1, 0, 0)`` (``T [dR, dp]``)."""
    particles, _ = steps.initialise_particles(2)
    still = (np.zeros(3), np.zeros(3))
    moved = steps.offset_by_motion(
        particles,
        still,
        0.1,
        increment=(np.array([0.0, 0.0, np.pi / 2]), np.array([1.0, 0.0, 0.0])),
    )
    np.testing.assert_allclose(
        moved.R, [[[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]] * 2, atol=1e-12
    )
    np.testing.assert_allclose(moved.t, [[1.0, 0.0, 0.0]] * 2, atol=1e-12)


_SIMPLE_MOTION = MotionConfig(
    sigma_xyz_per_m=(1.0, 2.0, 3.0),
    sigma_xyz_per_s=(0.0, 0.0, 0.0),
    sigma_rpy_per_m=(0.1, 0.2, 0.3),
    sigma_rpy_per_s=(0.0, 0.0, 0.0),
    constant_velocity=ConstantVelocityConfig(
        accel=(100.0, 200.0, 300.0),
        angular_accel=(10.0, 20.0, 30.0),
        start_speed=(1.0, 2.0, 3.0, 4.0, 5.0, 6.0),
    ),
)


def test_motion_noise_sigma_passes_the_midpoint_distance_and_both_flags_to_the_config():
    """``sigma = per_m |dp| + per_s dt (+ cv dt^2 if constant_velocity) (+ start_speed dt if start)``, ``dp``
    the midpoint-twist translation: from rest to 4 m/s over 0.5 s (no rotation) ``|dp| = 2 * 0.5 = 1`` m
    (4 * 0.5 = 2 m without the previous sample). Hand values with per_s = 0:
    constant_velocity only -> per_m + cv * 0.25; start only -> per_m + start_speed * 0.5."""
    imu, prev = (np.array([4.0, 0.0, 0.0]), np.zeros(3)), (np.zeros(3), np.zeros(3))
    cv = steps.motion_noise_sigma(
        imu, 0.5, prev, _SIMPLE_MOTION, constant_velocity=True, start=False
    )
    np.testing.assert_allclose(cv, [26.0, 52.0, 78.0, 2.6, 5.2, 7.8], rtol=1e-12)
    start = steps.motion_noise_sigma(
        imu, 0.5, prev, _SIMPLE_MOTION, constant_velocity=False, start=True
    )
    np.testing.assert_allclose(start, [1.5, 3.0, 4.5, 2.1, 2.7, 3.3], rtol=1e-12)
    held = steps.motion_noise_sigma(imu, 0.5, None, _SIMPLE_MOTION)
    np.testing.assert_allclose(held, [2.0, 4.0, 6.0, 0.2, 0.4, 0.6], rtol=1e-12)


def test_project_to_rotation_flips_the_smallest_singular_direction_of_a_reflection():
    """``project(diag(3, 2, -1))``: ``det(U V^T) = -1``, so ``D = diag(1, 1, -1)`` and the closest rotation is the
    identity (not the reflection ``diag(1, 1, -1)``)."""
    got = steps.project_to_rotation(np.diag([3.0, 2.0, -1.0]))
    np.testing.assert_allclose(got, np.eye(3), atol=1e-12)
    assert np.linalg.det(got) == pytest.approx(1.0)


def test_mean_estimate_averages_the_particles_within_half_a_metre_of_the_best_and_ignores_a_log_weight_shift():
    """Step 9 ``pose_estimate="mean"`` with the default radius 0.5 m: particles at distance 0.5 (on the sphere, kept),
    0.45 (kept) and 0.75 (dropped) behind/below the best one at the origin; weights ``exp(log_w - log_w_best)``
    = (1, e^-1, e^-2) so a common shift of -500 in the log-weights changes nothing (no underflow).
    ``t = (e^-1 (0, 0, 0.5) + e^-2 (0, -0.45, 0)) / (1 + e^-1 + e^-2)``."""
    t = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.5], [0.0, -0.45, 0.0], [-0.75, 0.0, 0.0]])
    particles = steps.Particles3D(np.repeat(np.eye(3)[None], 4, axis=0), t)
    log_w = np.array([0.0, -1.0, -2.0, -0.5]) - 500.0
    pose, best = steps.pick_best_particle(particles, log_w, "mean")
    assert best == 0
    w = np.exp([0.0, -1.0, -2.0])
    expected_t = (
        w[1] * np.array([0.0, 0.0, 0.5]) + w[2] * np.array([0.0, -0.45, 0.0])
    ) / w.sum()
    np.testing.assert_allclose(pose[:3, 3], expected_t, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(pose[:3, :3], np.eye(3), atol=1e-12)


def test_unknown_estimate_is_an_error_naming_it():
    """Step 9 with ``pose_estimate="median"``: ``pose_estimate must be 'best' or 'mean', got 'median'``."""
    particles, log_w = steps.initialise_particles(2)
    with pytest.raises(
        ValueError,
        match="^"
        + re.escape("pose_estimate must be 'best' or 'mean', got 'median'")
        + "$",
    ):
        steps.pick_best_particle(particles, log_w, "median")


class _Map:
    """A map stub that records what step 10 merges."""

    def __init__(self):
        self.merged = []

    def merge(self, points):
        self.merged.append(points)


def test_merge_scan_uses_the_given_backend_object():
    """Step 10 moves the scan with the ``backend`` it is given: a backend object whose ``transform_points``
    records its calls (and delegates to the NumPy reference) is called once, and the map gets ``R p + t``."""
    ref = get_backend("numpy")
    calls = []

    def spy(T, pts, out=None):
        calls.append(T)
        return ref.transform_points(T, pts, out=out)

    backend = dataclasses.replace(ref, name="spy", transform_points=spy)
    pose = geometry.make_pose(
        geometry.rpy_to_matrix([0.0, 0.0, np.pi / 2]), [1.0, 2.0, 3.0]
    )
    world_map = _Map()
    assert (
        steps.merge_scan(
            world_map, pose, np.array([[1.0, 0.0, 0.0]], np.float32), backend
        )
        is world_map
    )
    assert len(calls) == 1
    np.testing.assert_allclose(world_map.merged[0], [[1.0, 3.0, 3.0]], atol=1e-6)


def test_resample_particles_draws_with_the_backends_systematic_resample():
    """Step 11 takes the indexes from the backend's ``systematic_resample``: a backend whose sampler returns
    (2, 2, 0) makes the particles (2, 2, 0) of the input, with uniform log-weights ``-log 3``."""
    calls = []

    def sampler(w, u0):
        calls.append(u0)
        return np.array([2, 2, 0])

    backend = dataclasses.replace(
        get_backend("numpy"), name="spy", systematic_resample=sampler
    )
    t = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    particles = steps.Particles3D(np.repeat(np.eye(3)[None], 3, axis=0), t)
    out, log_w, resampled = steps.resample_particles(
        particles, np.log([0.1, 0.1, 0.8]), np.random.default_rng(0), None, backend
    )
    assert resampled and len(calls) == 1
    np.testing.assert_array_equal(out.t, t[[2, 2, 0]])
    np.testing.assert_allclose(log_w, np.full(3, -np.log(3.0)), rtol=1e-12)


def test_default_ess_fraction_is_one_half():
    """Step 11's default threshold is ``ESS < 0.5 P``: weights (0.4, 0.2, 0.2, 0.2) have ``ESS = 1 / 0.28 = 3.57``,
    not below 2 -> no resampling, the log-weights come back normalised (``log w``) and the particles unchanged."""
    particles, _ = steps.initialise_particles(4)
    log_w = np.log([0.4, 0.2, 0.2, 0.2]) + 7.0
    out, new_log_w, resampled = steps.resample_particles(
        particles, log_w, np.random.default_rng(0)
    )
    assert resampled is False and out is particles
    np.testing.assert_allclose(new_log_w, np.log([0.4, 0.2, 0.2, 0.2]), rtol=1e-12)


def test_weighted_mean_pose_normalises_float32_weights_in_float64():
    """``weighted_mean_pose`` casts the weights to float64 before ``w / sum w``: float32 weights (1, 2) on
    positions 0 and 3 m give exactly ``t = 2`` m (float32 ``2/3`` would give 2.00000006)."""
    R = np.repeat(np.eye(3)[None], 2, axis=0)
    pose = steps.weighted_mean_pose(
        R, np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0]]), np.array([1, 2], np.float32)
    )
    np.testing.assert_allclose(pose[:3, 3], [2.0, 0.0, 0.0], rtol=1e-15, atol=0)


def test_mean_estimate_exponentiates_float32_log_weights_in_float64():
    """Step 9 casts the log-weights to float64: float32 log-weights (0, -1) give the mean
    ``0.3 e^-1 / (1 + e^-1)`` to float64 precision (a float32 ``exp`` is off by ~1e-8 relative)."""
    t = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0]])
    particles = steps.Particles3D(np.repeat(np.eye(3)[None], 2, axis=0), t)
    pose, best = steps.pick_best_particle(
        particles, np.array([0.0, -1.0], np.float32), "mean"
    )
    assert best == 0
    e = np.exp(-1.0)
    np.testing.assert_allclose(
        pose[:3, 3], [0.3 * e / (1.0 + e), 0.0, 0.0], rtol=1e-14, atol=0
    )


def test_deskew_scan_moves_a_one_point_scan_and_casts_an_empty_float64_scan():
    """``deskew_scan`` short-cuts only the empty scan: a single point 10 m to the left (azimuth 90 deg, fired a
    quarter sweep early) moves by ``deskew`` with its firing time ``sweep_times``; an empty float64 (0, 3) scan
    comes back as float32."""
    pts = np.array([[0.0, 10.0, 0.5]], np.float32)
    imu = (np.array([10.0, 0.0, 0.0]), np.zeros(3))
    times = sweep_times(pts, 0.1)
    assert times[0] == pytest.approx(-0.025)
    got = steps.deskew_scan(pts, imu, ScanConfig(sweep_period=0.1))
    np.testing.assert_array_equal(got, deskew(pts, *imu, times))
    # 10 m/s * -0.025 s along x
    np.testing.assert_allclose(got, [[-0.25, 10.0, 0.5]], atol=1e-5)
    empty = steps.deskew_scan(np.zeros((0, 3)), imu, ScanConfig())
    assert empty.dtype == np.float32 and empty.shape == (0, 3)


def test_project_to_rotation_of_a_float32_matrix_is_computed_in_float64():
    """``project_to_rotation`` casts to float64 before the SVD: a float32 matrix gives the polar factor of its
    float64 copy (``scipy.linalg.polar``, the closest orthogonal matrix, here with det +1) to 1e-12, not the
    ~1e-7 of a float32 SVD."""
    from scipy.linalg import polar

    M = np.array([[0.9, -0.3, 0.1], [0.35, 0.8, -0.2], [-0.05, 0.25, 1.1]], np.float32)
    expected, _ = polar(M.astype(np.float64))
    assert np.linalg.det(expected) > 0
    got = steps.project_to_rotation(M)
    assert got.dtype == np.float64
    np.testing.assert_allclose(got, expected, atol=1e-12)


def test_read_scan_time_offset_reads_the_frame_or_zero_and_rejects_the_impossible():
    assert (
        steps.read_scan_time_offset(SimpleNamespace(scan_time_offset_s=-0.0171))
        == -0.0171
    )
    # odometry layout, simulated frames
    assert steps.read_scan_time_offset(SimpleNamespace()) == 0.0
    for bad in (float("nan"), 0.2, -0.11):
        with pytest.raises(
            ValueError,
            match=r"scan time offset \(frame 3\) must be finite and within one sweep",
        ):
            steps.read_scan_time_offset(SimpleNamespace(scan_time_offset_s=bad, index=3))
    assert (
        steps.read_scan_time_offset(
            SimpleNamespace(scan_time_offset_s=0.15), ScanConfig(sweep_period=0.2)
        )
        == 0.15
    )


# ------------------------------------------------------------------ step 2's de-skewing (deskew_scan)
def _scan(n=200, seed=0):
    rng = np.random.default_rng(seed)
    az = rng.uniform(-np.pi, np.pi, n)
    r = rng.uniform(3.0, 30.0, n)
    return np.column_stack(
        [r * np.cos(az), r * np.sin(az), rng.uniform(-1.5, 1.0, n)]
    ).astype(np.float32)


TWIST = (np.array([12.0, 0.3, -0.1]), np.array([0.01, -0.02, 0.25]))


def test_deskew_scan_times_points_by_their_azimuth_in_the_velodyne_frame():
    """``steps.deskew_scan(points, imu, scan_config, T_body_velo)`` = ``preprocess.deskew`` of the body-frame points
    with the twist ``imu`` and firing times ``sweep_times(inv(T_body_velo) p, sweep_period)``: the azimuth is read
    in the Velodyne frame. A mounting turned 90 degrees about z shifts every firing time by a quarter sweep."""
    pts = _scan()
    config = ScanConfig(sweep_period=0.1)
    T = geometry.make_pose(
        geometry.rpy_to_matrix([0.0, 0.0, np.pi / 2]), [0.8, -0.3, 1.7]
    )
    velo = (pts.astype(np.float64) - T[:3, 3]) @ T[:3, :3]  # inv(T) p, written out
    expected = deskew(pts, *TWIST, sweep_times(velo, 0.1))
    got = steps.deskew_scan(pts, TWIST, config, T_body_velo=T)
    assert got.dtype == np.float32 and got.flags.c_contiguous and got.shape == pts.shape
    np.testing.assert_array_equal(got, expected)
    untilted = steps.deskew_scan(pts, TWIST, config)
    np.testing.assert_array_equal(untilted, deskew(pts, *TWIST, sweep_times(pts, 0.1)))
    # the mounting matters: a quarter sweep at 12 m/s is 0.3 m
    assert np.abs(got - untilted).max() > 0.1


def test_deskew_scan_moves_points_to_the_pose_time_given_the_scan_offset():
    """``time_offset`` (the scan's stamp relative to the pose's, ``Frame.scan_time_offset_s``) shifts every firing
    time: the points go to the frame at the pose's time. A point fired at the scan's stamp then moves by the twist
    over ``-time_offset``: 12 m/s x 20 ms = 0.24 m forward for a point straight ahead."""
    pts = _scan()
    config = ScanConfig(sweep_period=0.1)
    got = steps.deskew_scan(pts, TWIST, config, time_offset=-0.02)
    np.testing.assert_array_equal(got, deskew(pts, *TWIST, sweep_times(pts, 0.1) - 0.02))
    np.testing.assert_array_equal(
        steps.deskew_scan(pts, TWIST, config, time_offset=0.0),
        steps.deskew_scan(pts, TWIST, config),
    )
    # azimuth 0: fired at the scan's stamp
    ahead = np.array([[20.0, 0.0, 0.0]], np.float32)
    moved = steps.deskew_scan(
        ahead, (np.array([12.0, 0.0, 0.0]), np.zeros(3)), config, time_offset=-0.02
    )
    np.testing.assert_allclose(moved, [[20.0 - 0.24, 0.0, 0.0]], atol=1e-5)


def test_deskew_scan_uses_the_configured_sweep_period_and_keeps_empty_scans():
    """The firing times scale with ``ScanConfig.sweep_period`` (twice the period: twice each point's offset from
    where it was fired, to first order), and an empty scan comes back empty (0, 3) float32."""
    pts = _scan(50, 1)
    v = (np.array([10.0, 0.0, 0.0]), np.zeros(3))
    d1 = steps.deskew_scan(pts, v, ScanConfig(sweep_period=0.1)) - pts
    d2 = steps.deskew_scan(pts, v, ScanConfig(sweep_period=0.2)) - pts
    np.testing.assert_allclose(d1[:, 0], 10.0 * sweep_times(pts, 0.1), atol=1e-5)
    np.testing.assert_allclose(d2, 2 * d1, atol=1e-5)
    empty = steps.deskew_scan(np.zeros((0, 3), np.float32), v, ScanConfig())
    assert empty.shape == (0, 3) and empty.dtype == np.float32
