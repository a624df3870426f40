"""The 3D filter's steps 1-11 one at a time (:mod:`slamlib.slam3d.steps`): each step on the tiny world's drive
(``world3d.py``) and on hand-made inputs whose expected values are computed in the test."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from world3d import SimFrame, simulate

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
    transform_scan,
)

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
    scan = np.array(
        [[5, 0, 0, 0.1], [0, 1, 0, 0.2], [0, 8, 1, 0.3]], np.float32
    )  # 2nd point inside min_range
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
    dr = dead_reckon(
        np.array([v0, v1]), np.array([w0, w1]), np.array([0.0, 0.1])
    )  # from the identity
    for i in range(6):
        expected = make_pose(p.R[i], p.t[i]) @ dr[1]
        assert np.allclose(make_pose(p2.R[i], p2.t[i]), expected, atol=1e-12)
    rpy, dp = motion_increment((v1, w1), 0.1, (v0, w0))
    assert np.allclose(make_pose(rpy_to_matrix(rpy), dp), dr[1], atol=1e-12)
    given = offset_by_motion(
        p, (v1, w1), 0.1, (v0, w0), CPU, increment=(rpy, dp)
    )  # precomputed: the same move
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
    Rb, tb = CPU.move_particles(
        p.R, p.t, rpy, rpy_to_matrix(rpy).T @ dp, noise, sigma
    )  # the fused kernel
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
    T, i = pick_best_particle(
        p, log_w, "mean", radius=0.5
    )  # particle 3 is 5 m away: not averaged in
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
        assert np.all(
            np.abs(counts - P * w) < 1.0 + 1e-9
        )  # systematic: floor or ceil of P w_i
    else:
        assert np.allclose(w, 1.0 / P) and p2 is p and np.allclose(np.exp(lw2), w)


def test_resample_only_below_the_ess_threshold():
    p, _ = initialise_particles(10)
    p = Particles3D(p.R, p.t + np.arange(10)[:, None])
    log_w = np.log(
        np.r_[np.full(5, 0.15), np.full(5, 0.05)]
    )  # ESS = 1 / (5 * .0225 + 5 * .0025) = 8
    assert not resample_particles(p, log_w, np.random.default_rng(0), 0.5, CPU)[2]
    assert resample_particles(p, log_w, np.random.default_rng(0), 0.9, CPU)[2]
    assert resample_particles(
        p, np.log(np.full(10, 0.1)), np.random.default_rng(0), None, CPU
    )[2]  # None: always


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
