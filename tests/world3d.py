"""A tiny in-memory 3D world and a drive through it, shared by the tests of the 3D filter (steps, stages,
pipeline, whole runs): scans on a small town seen from a known trajectory, with a biased IMU."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slamlib.geometry import invert_pose, make_pose, rpy_to_matrix, transform_points
from slamlib.odometry import GRAVITY, dead_reckon
from slamlib.slam3d import SLAM3DConfig, crop_range


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
        capacity=2**14,
        sigma_xyz_per_m=(0.06, 0.04, 0.02),
        sigma_rpy_per_s=(0.01, 0.01, 0.06),
        seed=3,
    )
    base.update(kw)
    return SLAM3DConfig.of(**base)
