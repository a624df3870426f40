"""slamlib.synth.tilt: a drive whose first pose stands tilted against gravity."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from slamlib.geometry import make_pose, rpy_to_matrix
from slamlib.odometry import GRAVITY
from slamlib.synth.tilt import KITTI_0001_START_TILT, StartTilted


@dataclass(frozen=True)
class _Frame:
    points: np.ndarray
    specific_force: np.ndarray | None


class _StillDrive:
    """A body at rest in a level world (first pose level, then turned and tilted a little): its accelerometer
    reads ``g R_k^T e_z``; frame 3 has no accelerometer."""

    def __init__(self):
        self.R = [rpy_to_matrix([0.0, 0.0, 0.7])] + [
            rpy_to_matrix([0.01 * k, -0.02 * k, 0.7 + 0.3 * k]) for k in range(1, 5)
        ]
        self.T_velo_imu = np.eye(4)

    def __len__(self):
        return len(self.R)

    def __getitem__(self, k):
        force = None if k == 3 else GRAVITY * self.R[k].T @ [0.0, 0.0, 1.0]
        return _Frame(np.full((2, 4), float(k)), force)

    def ground_truth_poses(self, frame="imu"):
        return np.stack([make_pose(R, [0.0, 0.0, 0.0]) for R in self.R])


def test_start_tilted_turns_gravity_in_the_accelerometer_only():
    """Each frame's specific force gains ``g R_k^T (R_0 R_b^T e_z - e_z)``: at rest, the first body then reads
    gravity's up at ``R_b^T e_z``, tilted by the roll and pitch, and every later body the same world up seen from
    its own rotation; the scans, a frame without an accelerometer and the drive's other attributes stay as they
    are."""
    drive = _StillDrive()
    roll, pitch = KITTI_0001_START_TILT
    tilted = StartTilted(drive, roll, pitch)
    assert len(tilted) == len(drive) and tilted.start_tilt == (roll, pitch)
    assert tilted.T_velo_imu is drive.T_velo_imu
    up0 = rpy_to_matrix([roll, pitch, 0.0]).T @ [0.0, 0.0, 1.0]
    np.testing.assert_allclose(tilted[0].specific_force, GRAVITY * up0, atol=1e-12)
    world_up = drive.R[0] @ up0  # gravity's up in the world, now tilted
    for k in (1, 2, 4, -1):
        np.testing.assert_allclose(
            tilted[k].specific_force, GRAVITY * drive.R[k].T @ world_up, atol=1e-12
        )
        np.testing.assert_array_equal(tilted[k].points, drive[k].points)
    assert tilted[3].specific_force is None
    # drive 0001's start: about 37 mrad between gravity's up and the first pose's z
    angle = np.arccos(up0[2])
    assert angle == pytest.approx(np.hypot(roll, pitch), rel=1e-3) and 0.03 < angle < 0.04


def test_a_level_start_is_the_drive_itself():
    drive = _StillDrive()
    level = StartTilted(drive, 0.0, 0.0)
    for k in (0, 1, 4):
        np.testing.assert_array_equal(level[k].specific_force, drive[k].specific_force)
