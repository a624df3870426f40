"""Tests of the 3D particle SLAM pipeline (slamlib.slam3d): each step alone, the per-frame loop on a tiny
in-memory world, determinism, backends agreeing, and the ``slamlib run`` command on a tiny synthetic drive."""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slamlib.geometry import (
    invert_pose,
    make_pose,
    matrix_to_rpy,
    rpy_to_matrix,
    transform_points,
)
from slamlib.kernels import get_backend
from slamlib.maps import VoxelHashMap
from slamlib.metrics import absolute_trajectory_error
from slamlib.odometry import (
    GRAVITY,
    dead_reckon,
)
from slamlib.slam3d import (
    MotionConfig,
    Particles3D,
    ParticleSLAM3D,
    ScanConfig,
    SLAM3DConfig,
    crop_range,
    initialise_particles,
    merge_scan,
    motion_increment,
    motion_noise_sigma,
    offset_by_motion,
    parse_frames,
    perturb_with_noise,
    pick_best_particle,
    read_imu,
    read_scan,
    read_timing,
    resample_particles,
    run_drive,
    sample_points,
    score_particles,
    transform_scan,
    voxel_downsample,
)
from slamlib.slam3d.stages.prior import (
    balance_heading_bins,
    heading_bin,
    tilt_calibration,
    tilt_calibration_prior,
    tilt_calibration_update,
)

CPU = get_backend("cpu")
NUMPY = get_backend("numpy")


# ------------------------------------------------------------------------------------------ a tiny world
def world_points(seed: int = 0) -> np.ndarray:
    """Points (M, 3) on a small town: ground at z = -1.7 m, two stepped facades along x, boxes at random yaw."""
    rng = np.random.default_rng(seed)
    parts = [np.c_[rng.uniform(-45, 45, (12000, 2)), np.full(12000, -1.7)]]
    for side in (-1.0, 1.0):  # facades at |y| = 9 (+0.8 every other 5 m step)
        x = rng.uniform(-45, 45, 5000)
        y = side * (9.0 + 0.8 * (np.floor(x / 5.0) % 2))
        parts.append(np.c_[x, y, rng.uniform(-1.7, 4.0, 5000)])
        xs = np.repeat(np.arange(-45, 45, 5.0), 60)  # the step faces (normal to x)
        parts.append(
            np.c_[
                xs, side * rng.uniform(9.0, 9.8, xs.size), rng.uniform(-1.7, 4.0, xs.size)
            ]
        )
    for cx, cy, yaw in rng.uniform(
        [-40, -7, 0], [40, 7, np.pi], (10, 3)
    ):  # 2 x 1 x 1.5 m boxes
        u = rng.uniform(-1, 1, (500, 3)) * [1.0, 0.5, 0.75]
        face = rng.integers(0, 3, 500)
        u[np.arange(500), face] = (
            np.sign(u[np.arange(500), face]) * np.array([1.0, 0.5, 0.75])[face]
        )
        parts.append(u @ rpy_to_matrix([0, 0, yaw]).T + [cx, cy, -0.95])
    return np.vstack(parts).astype(np.float32)


@dataclass
class SimFrame:
    """What ParticleSLAM3D reads from a frame (the slamlib.kitti.Frame attributes it uses)."""

    scan: np.ndarray
    velocity: np.ndarray
    angular_rate: np.ndarray
    dt: float
    T_w_imu: np.ndarray
    time_s: float
    index: int
    specific_force: np.ndarray | None = None


def simulate(n: int = 30, seed: int = 0, speed: float = 5.0, yaw_rate: float = 0.15):
    """Frames of a drive through :func:`world_points`: scans (body frame, range 2-30 m, 1 cm noise, 4,000 random
    points each) and an IMU with 6 % speed scale error and a 0.06 rad/s yaw-rate bias. Returns (frames, gt)."""
    rng = np.random.default_rng(seed + 1)
    world = world_points(seed)
    dt = np.full(n, 0.1)
    v = np.tile([speed, 0.0, 0.0], (n, 1))
    w = np.tile([0.0, 0.0, yaw_rate], (n, 1))
    T0 = make_pose(np.eye(3), [-20.0, -2.0, 0.0])
    gt = dead_reckon(v, w, dt, T0)
    frames = []
    for k in range(n):
        body = transform_points(invert_pose(gt[k]), world)
        body = crop_range(body, 2.0, 30.0)
        body = body[rng.choice(len(body), min(4000, len(body)), replace=False)]
        body = body + rng.normal(0, 0.01, body.shape).astype(np.float32)
        scan = np.c_[body, np.full(len(body), 0.5)].astype(np.float32)
        v_meas = v[k] * [1.06, 1.0, 1.0] + rng.normal(0, 0.02, 3)
        w_meas = w[k] + [0.0, 0.0, 0.06] + rng.normal(0, 0.002, 3)
        # level, constant twist: the accelerometer feels the centripetal w x v and gravity
        f_meas = np.cross(w[k], v[k]) + [0.0, 0.0, GRAVITY] + rng.normal(0, 0.05, 3)
        frames.append(
            SimFrame(
                scan, v_meas, w_meas, 0.0 if k == 0 else 0.1, gt[k], 0.1 * k, k, f_meas
            )
        )
    return frames, invert_pose(gt[0])[None] @ gt


def tiny_config(**kw) -> SLAM3DConfig:
    base = dict(
        particles=100,
        scored_points=300,
        min_range=2.0,
        max_range=30.0,
        downsample_voxel=0.3,
        params={"capacity": 2**14},
        sigma_xyz_per_m=(0.06, 0.04, 0.02),
        sigma_rpy_per_s=(0.01, 0.01, 0.06),
        seed=3,
    )
    base.update(kw)
    return SLAM3DConfig.of(**base)


SCAN = ScanConfig(2.0, 30.0, 0.3)  # the tiny world's scan settings


@pytest.fixture(scope="module")
def drive():
    return simulate()


def random_particles(rng, P):
    R = rpy_to_matrix(rng.uniform(-0.3, 0.3, (P, 3)) * [1, 1, 10])
    t = rng.uniform(-5, 5, (P, 3))
    return Particles3D(R, t)


# ------------------------------------------------------------------------------------------ preprocessing
def test_crop_range_keeps_the_annulus():
    pts = np.array([[1, 0, 0], [0, 3, 0], [0, 0, 10], [20, 0, 0]], np.float32)
    assert np.array_equal(crop_range(pts, 2.0, 15.0), pts[1:3])


def test_voxel_downsample_one_exact_point_per_voxel():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-3, 3, (5000, 3)).astype(np.float32)
    out = voxel_downsample(pts, 1.0)
    keys = np.floor(out / 1.0).astype(int)
    assert (
        len(np.unique(keys, axis=0))
        == len(out)
        == len(np.unique(np.floor(pts).astype(int), axis=0))
    )
    # kept points are input points (the first of each voxel, in input order)
    first = {}
    for i, k in enumerate(map(tuple, np.floor(pts).astype(int))):
        first.setdefault(k, i)
    assert np.array_equal(out, pts[sorted(first.values())])


def test_sample_points_is_seeded_and_distinct():
    pts = np.arange(3000, dtype=np.float32).reshape(1000, 3)
    a = sample_points(pts, 100, np.random.default_rng(5))
    b = sample_points(pts, 100, np.random.default_rng(5))
    c = sample_points(pts, 100, np.random.default_rng(6))
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert len(np.unique(a[:, 0])) == 100
    assert len(sample_points(pts, 5000, np.random.default_rng(0))) == 1000


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


# ------------------------------------------------------------------------------------------ step 12
def test_register_frame_beats_dead_reckoning(drive):
    frames, gt = drive
    slam = ParticleSLAM3D(tiny_config())
    for f in frames:
        slam.register_frame(f)
    ate_slam = absolute_trajectory_error(slam.trajectory, gt).rmse
    ate_dr = absolute_trajectory_error(slam.dead_reckoning, gt).rmse
    assert ate_dr > 0.3  # the IMU alone drifts
    assert ate_slam < ate_dr / 4
    assert slam.n_resampled > 0 and len(slam.poses) == len(frames)


def test_dead_reckoning_twin_is_the_imu_integral(drive):
    frames, _ = drive
    slam = ParticleSLAM3D(tiny_config(particles=5, scored_points=50))
    for f in frames[:6]:
        slam.register_frame(f)
    v = np.array([f.velocity for f in frames[:6]])
    w = np.array([f.angular_rate for f in frames[:6]])
    assert np.allclose(
        slam.dead_reckoning, dead_reckon(v, w, [f.dt for f in frames[:6]]), atol=1e-12
    )


def test_same_seed_same_trajectory_other_seed_differs(drive):
    frames, _ = drive

    def traj(seed):
        slam = ParticleSLAM3D(tiny_config(particles=50, scored_points=200, seed=seed))
        for f in frames[:8]:
            slam.register_frame(f)
        return slam.trajectory

    a, b, c = traj(1), traj(1), traj(2)
    assert np.array_equal(a, b)
    assert not np.allclose(a[1:], c[1:])


def test_numpy_and_cpu_backends_give_the_same_trajectory(drive):
    frames, _ = drive

    def traj(backend):
        slam = ParticleSLAM3D(
            tiny_config(particles=16, scored_points=100, backend=backend, seed=7)
        )
        for f in frames[:4]:
            slam.register_frame(f)
        return slam.trajectory

    assert np.allclose(traj("numpy"), traj("cpu"), atol=1e-9)


def test_cuda_backend_gives_the_cpu_trajectory(drive):
    """In Numba's CUDA simulator (tests/conftest.py) unless SLAMLIB_REAL_CUDA=1: tiny sizes."""
    frames, _ = drive

    def traj(backend):
        slam = ParticleSLAM3D(
            tiny_config(
                particles=8,
                scored_points=30,
                backend=backend,
                seed=7,
                downsample_voxel=1.5,
            )
        )
        for f in frames[:3]:
            slam.register_frame(f)
        return slam.trajectory

    assert np.allclose(traj("cuda"), traj("cpu"), atol=1e-6)


def test_refine_and_bvh_map_also_track(drive):
    frames, gt = drive
    run = run_drive(
        frames[:15],
        tiny_config(kind="morton_bvh", params={}, refine=1, estimate="mean"),
        progress=False,
    )
    assert run.ground_truth is not None and np.allclose(run.ground_truth, gt[:15])
    ate_slam = absolute_trajectory_error(run.poses, run.ground_truth).rmse
    ate_dr = absolute_trajectory_error(run.dead_reckoning, run.ground_truth).rmse
    assert ate_slam < ate_dr / 2


def test_pruned_map_points_are_kept_for_export(drive):
    frames, _ = drive
    slam = ParticleSLAM3D(
        tiny_config(particles=10, scored_points=50, prune_every=5, prune_radius=12.0)
    )
    for f in frames[:10]:  # pruned after frames 5 and 10
        slam.register_frame(f)
    assert slam.archive and len(slam.map_points()) == len(slam.map) + sum(
        len(a) for a in slam.archive
    )
    assert (
        np.linalg.norm(slam.map.points() - slam.poses[-1][:3, 3], axis=1).max()
        <= 12.0 + 1e-4
    )
    assert (
        np.linalg.norm(slam.archive[-1] - slam.poses[-1][:3, 3], axis=1).min()
        > 12.0 - 1e-4
    )


def test_transient_voxels_are_evicted_every_span_frames(drive):
    frames, _ = drive
    span = 4
    slam = ParticleSLAM3D(
        tiny_config(particles=10, scored_points=50, transient_span=span, prune_every=0)
    )
    plain = ParticleSLAM3D(tiny_config(particles=10, scored_points=50, prune_every=0))
    for k, f in enumerate(frames[: 2 * span]):
        slam.register_frame(f)
        plain.register_frame(f)
        if (k + 1) % span == 0:
            assert not slam.map.transients(span).any()
    assert slam.map.frames == plain.map.frames == 2 * span
    assert len(slam.map) < len(plain.map) and plain.map.transients(span).any()


def test_config_rejects_bad_values():
    for bad, message in (
        (dict(kind="octree"), "map kind"),
        (dict(kind="voxel"), "now called 'voxel_hash'"),
        (dict(particles=0), "particles"),
        (dict(temperature=0.0), "temperature"),
        (dict(estimate="median"), "estimate"),
        (dict(min_range=5.0, max_range=4.0), "min_range"),
        (dict(voxel_size=0.3), "unknown SLAM3D setting 'voxel_size'"),
        (dict(tilt_sigma=-0.01), "tilt_sigma"),
        (dict(tilt_window=0.0), "tilt_window"),
        (dict(transient_span=-1), "transient_span must be >= 0"),
        (dict(tilt_heading_bins=0), "tilt_heading_bins must be >= 1"),
        (dict(transient_span=2.5), "transient_span must be an integer"),
        (
            dict(transient_span=10, kind="morton_bvh"),
            "transient_span needs the 'voxel_hash'",
        ),
    ):
        with pytest.raises(ValueError, match=message):
            SLAM3DConfig.of(**bad)


def test_config_changes_settings_by_name_and_keeps_the_other_defaults():
    """``of`` changes the named settings in their groups; the others keep their default values (written out here:
    tests/test_defaults.py checks that every signature repeating a setting has the config's value)."""
    c = SLAM3DConfig.of(particles=7, max_range=30.0, kind="morton_bvh", seed=4)
    assert (c.filter.particles, c.scan.max_range, c.map.kind, c.seed) == (
        7,
        30.0,
        "morton_bvh",
        4,
    )
    assert (c.scan.min_range, c.filter.scored_points, c.filter.ess_fraction) == (
        3.0,
        1000,
        0.5,
    )
    assert (c.filter.estimate, c.backend, c.map.prune_every) == ("best", "cpu", 20)
    d = c.as_dict()
    assert d["filter"]["particles"] == 7
    assert d["motion"]["sigma_xyz_per_m"] == [0.02, 0.02, 0.01]
    assert d["scan"]["min_range"] == 3.0 and d["map"]["params"] == {}
    json.dumps(d)


def test_parse_frames():
    assert parse_frames("10:20") == slice(10, 20)
    assert parse_frames("5:") == slice(5, None)
    assert parse_frames("30") == slice(0, 30)
    assert parse_frames(None) is None
    for bad in ("a:b", "20:10", "-3:5"):
        with pytest.raises(ValueError):
            parse_frames(bad)
    with pytest.raises(ValueError):
        parse_frames("100:200", n=50)


# ------------------------------------------------------------------------------------------ slamlib run
@pytest.fixture(scope="module")
def tiny_drive(tmp_path_factory):
    from slamlib.synth import Hdl64, write_drive

    base = tmp_path_factory.mktemp("kitti")
    return write_drive(
        base,
        route="07",
        frames=(0, 12),
        seed=1,
        lidar=Hdl64(columns=500, beam_stride=2),
        progress=False,
    )


def test_slamlib_run_writes_trajectories_map_metrics_and_plots(tiny_drive, tmp_path):
    from slamlib.cli import main
    from slamlib.kitti import read_kitti_poses, read_tum

    base, date, drive = tiny_drive
    out = tmp_path / "out"
    rc = main(
        [
            "run",
            "--basedir",
            str(base),
            "--date",
            date,
            "--drive",
            str(drive),
            "--frames",
            "1:11",
            "--particles",
            "50",
            "--points",
            "200",
            "--out",
            str(out),
            "--no-progress",
        ]
    )
    assert rc == 0
    slam = read_kitti_poses(out / "slam_poses.txt")
    _, tum = read_tum(out / "slam_tum.txt")
    assert slam.shape == (10, 4, 4) and np.allclose(tum, slam, atol=1e-9)
    assert read_kitti_poses(out / "dead_reckoning_poses.txt").shape == (10, 4, 4)
    info = json.loads((out / "metrics.json").read_text())
    assert info["frames"] == 10 and info["fps"] > 0 and info["frame_indices"] == [1, 10]
    assert {"slam", "dead_reckoning"} <= set(info["metrics"])
    assert info["metrics"]["slam"]["ate_rmse_m"] >= 0
    import open3d as o3d

    assert (
        len(o3d.io.read_point_cloud(str(out / "map.ply")).points)
        == info["map_points_written"]
        > 0
    )
    assert (out / "trajectory.png").stat().st_size > 1000 and (
        out / "map_topdown.png"
    ).stat().st_size > 1000


@pytest.mark.parametrize(
    "which,needle",
    [
        ("basedir", "is not a folder"),
        ("date", "dates there: 2011_09_26"),
        ("drive", "drives there: 0001"),
    ],
)
def test_slamlib_run_explains_a_wrong_drive(tiny_drive, tmp_path, which, needle):
    from slamlib.cli import main

    base, date, drive = tiny_drive
    args = {"basedir": str(base), "date": date, "drive": str(drive)}
    args[which] = {
        "basedir": str(tmp_path / "nowhere"),
        "date": "2011_10_03",
        "drive": "0042",
    }[which]
    with pytest.raises(SystemExit) as exc:
        main(
            [
                "run",
                "--basedir",
                args["basedir"],
                "--date",
                args["date"],
                "--drive",
                args["drive"],
                "--out",
                str(tmp_path / "o"),
                "--no-progress",
            ]
        )
    assert needle in str(exc.value) and "not found" in str(exc.value)


def test_slamlib_run_map_names_and_bad_settings(tiny_drive, tmp_path, capsys):
    from slamlib.cli import main

    base, date, drive = tiny_drive
    common = [
        "run",
        "--basedir",
        str(base),
        "--date",
        date,
        "--drive",
        str(drive),
        "--no-progress",
        "--no-plots",
    ]
    with pytest.raises(SystemExit) as exc:
        main(common + ["--particles", "0", "--out", str(tmp_path / "a")])
    assert "particles" in str(exc.value) and ">= 1" in str(exc.value)
    assert (
        main(
            common
            + [
                "--frames",
                "0:3",
                "--particles",
                "5",
                "--points",
                "20",
                "--map",
                "bvh",
                "--out",
                str(tmp_path / "b"),
            ]
        )
        == 0
    )
    assert "--map bvh is now called --map morton_bvh" in capsys.readouterr().out
    info = json.loads((tmp_path / "b" / "metrics.json").read_text())
    assert (
        info["config"]["map"]["kind"] == "morton_bvh"
        and info["config"]["filter"]["particles"] == 5
    )
    # a still synthetic drive (no distortion): by default (deskew None) no scan is de-skewed; --deskew does all
    assert info["config"]["scan"]["deskew"] is None and info["n_deskewed_frames"] == 0
    assert (
        main(
            common
            + [
                "--frames",
                "0:3",
                "--particles",
                "5",
                "--points",
                "20",
                "--deskew",
                "--out",
                str(tmp_path / "c"),
            ]
        )
        == 0
    )
    info = json.loads((tmp_path / "c" / "metrics.json").read_text())
    assert info["config"]["scan"]["deskew"] is True and info["n_deskewed_frames"] == 3


def test_slamlib_run_default_drive_is_realistic_unless_still(
    tiny_drive, tmp_path, monkeypatch, capsys
):
    """With no drive given, ``slamlib run`` asks for the realistic default drive; ``--still-default`` for the still
    one (``default_drive(realism=False)``), and says so."""
    import slamlib.synth
    from slamlib.cli import main

    asked = []
    monkeypatch.setattr(
        slamlib.synth, "default_drive", lambda **kw: asked.append(kw) or tiny_drive
    )
    for flags, realism in (([], True), (["--still-default"], False)):
        assert (
            main(
                [
                    "run",
                    "--frames",
                    "0:3",
                    "--particles",
                    "5",
                    "--points",
                    "20",
                    "--no-progress",
                    "--no-plots",
                    "--out",
                    str(tmp_path / str(realism)),
                ]
                + flags
            )
            == 0
        )
        assert asked[-1]["realism"] is realism
        assert ("default drive (still)" in capsys.readouterr().out) is not realism
    base, date, drive = tiny_drive
    for flag in (
        "--still-default",
        "--full-default",
    ):  # not silently ignored beside a given drive
        with pytest.raises(
            SystemExit, match=f"{flag} chooses among the synthetic default drives"
        ):
            main(
                [
                    "run",
                    "--basedir",
                    str(base),
                    "--date",
                    date,
                    "--drive",
                    str(drive),
                    flag,
                    "--out",
                    str(tmp_path / "x"),
                ]
            )


def test_crop_and_downsample_equals_crop_then_downsample():
    """The fused Numba pass of step 2 against the two numpy reference functions: same points, same order."""
    from slamlib.kitti.sample import real_scan_frames
    from slamlib.slam3d.preprocess import (
        crop_and_downsample,
        crop_range,
        voxel_downsample,
    )

    real = real_scan_frames(range(1))[0].scan
    cases = [
        (real[:, :3], 3.0, 60.0, 0.25),
        (real, 0.0, np.inf, 0.5),
        (real[:, :3], 3.0, 60.0, 0.0),
    ]
    rng = np.random.default_rng(7)
    for _ in range(30):
        scale = rng.choice([0.01, 1.0, 30.0, 1e3])
        pts = (rng.standard_normal((int(rng.integers(0, 2000)), 3)) * scale).astype(
            np.float32
        )
        cases.append(
            (
                pts,
                float(rng.uniform(0, 1)),
                float(rng.uniform(1, 50)),
                float(rng.choice([0, 0.05, 0.3])),
            )
        )
    cases.append(
        (
            np.array([[1e7, 0, 0], [1, 1, 1], [1.01, 1.01, 1.01]], np.float32),
            0.0,
            np.inf,
            0.25,
        )
    )  # far out
    for pts, lo, hi, h in cases:
        np.testing.assert_array_equal(
            crop_and_downsample(pts, lo, hi, h),
            voxel_downsample(crop_range(pts, lo, hi), h),
        )


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
    ``dt / tilt_window`` of a
    ``tilt_sigma`` measurement, in heading sectors that weigh alike (the identification itself:
    tests/test_odometry.py). A biased accelerometer on a turning drive moves both away from the prior's zero."""
    frames, _ = simulate(40, yaw_rate=0.6)
    for f in frames:
        f.specific_force = f.specific_force + [0.05, -0.04, 0.0]
    sigma, window = 0.005, 1.05  # not a multiple of dt = 0.1, whose sums round either way
    slam = ParticleSLAM3D(
        tiny_config(tilt_sigma=sigma, tilt_window=window, tilt_world_sigma=0.02)
    )
    info0, eta0, free = tilt_calibration_prior(0.02, slam.config.filter.tilt_bias_sigma)
    bins = slam.config.filter.tilt_heading_bins
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
    assert (
        used == len(frames) - 12
    )  # frames 0..11: no window yet, or one shorter than 1.05 s
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


def test_tilt_prior_pulls_a_tilted_start_back_to_gravity(drive):
    """Started with a 40 mrad pitch error (the map is built tilted), the map alone keeps the filter tilted; the
    accelerometer's up (step 3) in step 8 pulls it back toward level against that map (2 mrad: a strong prior;
    40 -> 4-13 mrad in 30 frames on seeds 0 and 1). A pose's up in its body is its rotation's third row."""
    frames, gt = drive
    T0 = make_pose(rpy_to_matrix([0.0, 0.04, 0.0]), [0.0, 0.0, 0.0])

    def run(**kw):
        slam = ParticleSLAM3D(tiny_config(**kw), T0=T0)
        for f in frames:
            slam.register_frame(f)
        return np.linalg.norm(slam.poses[-1][2, :3] - gt[-1][2, :3]), slam

    without, plain = run()
    with_prior, slam = run(
        tilt_sigma=0.002, tilt_world_sigma=0.0, tilt_bias_sigma=0.0
    )  # level world, no bias
    assert without > 0.03 and plain.prior.up is None  # the map holds the start's tilt
    assert with_prior < without / 2, (with_prior, without)
    np.testing.assert_allclose(
        slam.prior.up, gt[-1][2, :3], atol=0.01
    )  # the measured up is the true one
