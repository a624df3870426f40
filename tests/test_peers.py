"""slamlib.peers: KISS-ICP's poses moved to the frames' pose times, to compare slamlib with a de-skewing peer."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm, logm

from slamlib.geometry import make_pose, rpy_to_matrix
from slamlib.kitti.velodyne import SWEEP_PERIOD_S
from slamlib.peers import move_along, pose_time_fraction

# one sweep of a turning car
MOTION = make_pose(rpy_to_matrix([0.01, -0.02, 0.08]), [1.2, 0.1, -0.05])


@pytest.mark.parametrize("fraction", [-1.0, -0.335, 0.0, 0.25, 1.0, 1.5])
def test_move_along_is_the_matrix_exponential_of_the_logarithm(fraction):
    pose = make_pose(rpy_to_matrix([0.3, -0.1, 2.0]), [5.0, -3.0, 1.0])
    expected = pose @ np.real(expm(fraction * logm(MOTION)))
    np.testing.assert_allclose(move_along(pose, MOTION, fraction), expected, atol=1e-9)


def test_move_along_by_one_and_minus_one_is_the_motion_and_its_inverse():
    np.testing.assert_allclose(move_along(np.eye(4), MOTION, 1.0), MOTION, atol=1e-12)
    np.testing.assert_allclose(move_along(MOTION, MOTION, -1.0), np.eye(4), atol=1e-12)
    half = move_along(np.eye(4), MOTION, 0.5)
    np.testing.assert_allclose(move_along(half, MOTION, 0.5), MOTION, atol=1e-12)


def test_pose_time_fraction_counts_sweeps_from_kiss_icps_instant_to_the_pose():
    # de-skewed, KISS-ICP's pose is the sweep end's: the scan's own pose is half a sweep before it
    assert pose_time_fraction(0.0, deskew=True) == pytest.approx(-0.5)
    assert pose_time_fraction(0.0, deskew=False) == 0.0
    # a KITTI raw frame: the OXTS pose 17 ms after the mid-sweep stamp (scan_time_offset_s = -0.017)
    assert pose_time_fraction(-0.017, deskew=False) == pytest.approx(
        0.017 / SWEEP_PERIOD_S
    )
    assert pose_time_fraction(-0.017, deskew=True) == pytest.approx(
        (0.017 - SWEEP_PERIOD_S / 2) / SWEEP_PERIOD_S
    )
    assert pose_time_fraction(-0.017, deskew=True, sweep_period=0.2) == pytest.approx(
        (0.017 - 0.1) / 0.2
    )


def test_kiss_icp_deskews_to_the_end_of_the_sweep():
    """The fact pose_time_fraction rests on, checked against the installed KISS-ICP: with its last motion D, a
    point at normalised sweep time s comes out at Exp((s - 1) Log D) p -- the sweep's last point stays put."""
    pytest.importorskip("kiss_icp")
    from kiss_icp.config import load_config
    from kiss_icp.preprocess import get_preprocessor

    config = load_config(None)
    config.data.deskew = True
    rng = np.random.default_rng(0)
    # the sweep's order on KITTI: from behind, clockwise
    az = np.linspace(np.pi - 1e-3, -np.pi + 1e-3, 400)
    r = rng.uniform(5.0, 40.0, az.size)
    points = np.column_stack(
        [r * np.cos(az), r * np.sin(az), rng.uniform(-1.5, 2.0, az.size)]
    )
    # KISS-ICP's KITTI rule, 0 = start
    stamps = 0.5 * (1.0 - np.arctan2(points[:, 1], points[:, 0]) / np.pi)
    out = np.asarray(get_preprocessor(config).preprocess(points, stamps, MOTION))
    # KISS-ICP normalises the stamps to [0, 1]
    s = (stamps - stamps.min()) / (stamps.max() - stamps.min())
    expected = np.array(
        [
            (move_along(np.eye(4), MOTION, si - 1.0) @ np.append(p, 1.0))[:3]
            for p, si in zip(points, s)
        ]
    )
    # it drops points outside its range limits
    keep = np.linalg.norm(expected, axis=1) > config.data.min_range
    np.testing.assert_allclose(out, expected[keep], atol=1e-9)
    # the end: unmoved
    assert (
        np.abs(out[np.argmax(s[keep])] - points[keep][np.argmax(s[keep])]).max() < 1e-12
    )


def test_kiss_slam_runs_as_its_pipeline_does_and_keeps_quiet(capfd):
    """KISS-SLAM on a short drive: one pose per frame in the body frame, a time per frame, no closure on a drive
    without revisits, and nothing printed (its Python prints and its C++ optimiser's alike)."""
    from world3d import simulate

    from slamlib.peers import kiss_slam_poses

    frames, truth = simulate()
    poses, seconds, closures = kiss_slam_poses(frames)
    assert poses.shape == (len(frames), 4, 4) and seconds.shape == (len(frames),)
    assert np.all(seconds > 0) and closures == []
    assert np.allclose(poses[0], np.eye(4), atol=1e-9)
    out, err = capfd.readouterr()
    assert out == "" and err == ""  # its C++ optimiser logs each iteration to stderr


def test_kiss_slam_poses_move_to_the_frames_pose_times_along_their_last_motion():
    """With ``pose_times``, each optimised pose moves by :func:`pose_time_fraction` of its motion from the frame
    before (none for the first frame), as :func:`kiss_icp_poses` moves KISS-ICP's."""
    from types import SimpleNamespace

    from world3d import simulate

    from slamlib.peers import kiss_slam_poses

    OFFSET = -0.017  # s: a KITTI raw frame's pose is stamped after its scan
    frames, _ = simulate(n=12)
    stamped = [SimpleNamespace(scan=f.scan, scan_time_offset_s=OFFSET) for f in frames]
    at_scans = kiss_slam_poses(stamped)[0]
    moved = kiss_slam_poses(stamped, pose_times=True)[0]
    fraction = pose_time_fraction(OFFSET, deskew=False)
    assert fraction > 0.1  # the test moves the poses measurably
    deltas = [np.eye(4)] + [np.linalg.inv(a) @ b for a, b in zip(at_scans, at_scans[1:])]
    expected = [move_along(p, d, fraction) for p, d in zip(at_scans, deltas)]
    np.testing.assert_allclose(moved, expected, atol=1e-6)
    np.testing.assert_allclose(moved[0], np.eye(4), atol=1e-9)
    assert np.abs(moved[1:, :3, 3] - at_scans[1:, :3, 3]).max() > 0.05
