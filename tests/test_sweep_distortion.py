"""Issue 11, items 1 and 4: scans cast over a sweep as KITTI's HDL-64E takes them, and slamlib's de-skewing."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from slamlib.odometry import imu_increments, increment_matrix
from slamlib.slam3d.preprocess import deskew, sweep_times
from slamlib.synth import Hdl64, build_scene, get_route, ray_directions, simulate_scan
from slamlib.synth.lidar import SCAN_PERIOD_S, column_time_offsets, ray_columns

LIDAR = Hdl64(columns=720, beam_stride=2)


def test_column_times_follow_kittis_sweep():
    off = column_time_offsets(Hdl64(columns=8), period=0.1)  # azimuths 0, 45, ..., 180, -135, ..., -45 deg
    np.testing.assert_allclose(off, [0.0, -0.0125, -0.025, -0.0375, -0.05, 0.0375, 0.025, 0.0125])
    d = ray_directions(LIDAR)
    np.testing.assert_allclose(sweep_times(d, SCAN_PERIOD_S), column_time_offsets(LIDAR)[ray_columns(LIDAR)],
                               atol=1e-9)  # slamlib's rule for a point's time = the generator's firing time


def test_deskew_is_the_se3_motion_of_the_twist():
    rng = np.random.default_rng(0)
    p = rng.uniform(-30, 30, (500, 3))
    t = rng.uniform(-0.05, 0.05, 500)
    np.testing.assert_allclose(deskew(p, np.zeros(3), np.zeros(3), t), p.astype(np.float32))
    v, w = np.array([10.0, 0.3, -0.1]), np.array([0.02, -0.01, 0.4])
    # the exact SE(3) exponential of the twist over each point's time, from the library's motion model
    exact = increment_matrix(*imu_increments(*(np.broadcast_to(x, (500, 3)) for x in (v, w, v, w)), t))
    expected = np.einsum("nij,nj->ni", exact[:, :3, :3], p) + exact[:, :3, 3]
    np.testing.assert_allclose(deskew(p, v, w, t), expected, atol=1e-3)  # J(phi) v t to second order
    # and the rotation part alone is Rodrigues' exactly
    rot = np.array([Rotation.from_rotvec(w * ti).apply(pi) for pi, ti in zip(p, t)])
    np.testing.assert_allclose(deskew(p, np.zeros(3), w, t), rot, atol=1e-4)


@pytest.fixture(scope="module")
def town():
    route = get_route("loop")  # 8 m/s around a 60 m circle: translation and rotation within the sweep
    t = np.linspace(route.t0, route.t1, 200)
    scene = build_scene(route.position(t), seed=3)
    return route, scene, scene.raycasting_scene()


def test_a_distorted_scan_deskewed_is_the_scan_at_its_timestamp(town):
    """Every point of a swept scan, cast from its column's pose, de-skewed with the route's twist, lands where the
    generator says it is in the sensor frame of the timestamp (the loop's twist is constant: exact)."""
    route, scene, rc = town
    exact = Hdl64(columns=720, beam_stride=2, sigma_range=0.0, dropout=0.0)
    t_mid = route.t0 + 5.0
    T = route.pose(t_mid)[0]  # IMU = Velodyne here: the motion is the route's
    columns = route.pose(t_mid + column_time_offsets(exact))
    swept = simulate_scan(rc, scene.albedo, T, np.random.default_rng(1), exact, column_poses=columns)
    p = swept[:, :3].astype(np.float64)
    col = np.round(np.mod(np.arctan2(p[:, 1], p[:, 0]), 2 * np.pi) / (2 * np.pi) * exact.columns).astype(int)
    P = columns[col % exact.columns]
    world = np.einsum("nij,nj->ni", P[:, :3, :3], p) + P[:, :3, 3]
    truth = (world - T[:3, 3]) @ T[:3, :3]  # the same points in the sensor frame at the timestamp
    v, w = route.velocity_body(t_mid)[0], route.angular_rate_body(t_mid)[0]
    fixed = deskew(p, v, w, sweep_times(p, SCAN_PERIOD_S))
    raw_err = np.linalg.norm(p - truth, axis=1)
    assert np.median(raw_err) > 0.1 and raw_err.max() > 0.3  # 8 m/s: up to 0.4 m at the ends of the sweep
    assert np.abs(fixed - truth).max() < 1e-3
    backwards = deskew(p, v, w, -sweep_times(p, SCAN_PERIOD_S))  # the sweep the other way round: worse than none
    assert np.median(np.linalg.norm(backwards - truth, axis=1)) > np.median(raw_err)


def test_write_drive_with_distortion_records_it_and_changes_only_the_scans(tmp_path):
    from slamlib.kitti import KittiRawDrive
    from slamlib.synth import write_drive
    from slamlib.synth.writer import drive_dir, read_marker

    a = write_drive(tmp_path / "a", "loop", frames=3, seed=4, lidar=LIDAR, progress=False)
    b = write_drive(tmp_path / "b", "loop", frames=3, seed=4, lidar=LIDAR, progress=False, distortion=True)
    assert read_marker(drive_dir(*b))["distortion"] is True and "distortion" not in read_marker(drive_dir(*a))
    da, db = KittiRawDrive(*a), KittiRawDrive(*b)
    np.testing.assert_array_equal(da.ground_truth_poses(), db.ground_truth_poses())
    assert not np.array_equal(da[1].scan, db[1].scan)
