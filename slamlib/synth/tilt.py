"""A drive whose first pose stands tilted against gravity, from one that starts level.

The filter takes its first body pose as the world (:class:`slamlib.slam3d.ParticleSLAM3D`), and the synthetic
drives start level, so in their world gravity's up is the world's ``e_z``. A real drive starts wherever the car
stood: KITTI raw 2011_09_26 drive 0001's first OXTS packet reads a roll of 35.8 mrad and a pitch of 9.0 mrad (a
cambered road), so in its first pose's frame gravity's up is ``R_b^T e_z``, ``R_b`` the roll and pitch. Nothing
but the accelerometer feels which way gravity points; a drive that started tilted by ``R_b`` differs from the level
one only in its specific force,

    f_k' = f_k + g R_k^T (R_0 R_b^T e_z - e_z),

``R_k`` the body's rotation in the synthetic world (the level first pose ``R_0``, yaw only), ``g`` the generator's
gravity. The scans, rates, velocities and ground truth (the trajectory in the first pose's frame) stay as they
are, so one drive tells how a filter copes with its start standing tilted against gravity.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from slamlib.geometry import rpy_to_matrix
from slamlib.odometry import GRAVITY

__all__ = ["StartTilted", "KITTI_0001_START_TILT"]

#: ``(roll, pitch)`` (rad) of KITTI raw 2011_09_26 drive 0001's first OXTS packet: how far a real drive's first
#: pose stood from level.
KITTI_0001_START_TILT = (0.0358, 0.0090)


class StartTilted:
    """``drive`` (a :class:`slamlib.kitti.KittiRawDrive` or anything with frames that carry ``specific_force`` and
    ``ground_truth_poses("imu")``), its first pose tilted by ``roll`` and ``pitch`` (rad) against gravity (module
    docstring); every other attribute is the drive's."""

    def __init__(self, drive, roll: float, pitch: float):
        self.drive, self.start_tilt = drive, (float(roll), float(pitch))
        R = np.asarray(drive.ground_truth_poses("imu"), dtype=np.float64)[:, :3, :3]
        up = R[0] @ rpy_to_matrix([roll, pitch, 0.0]).T @ [0.0, 0.0, 1.0]
        # per frame, the body-frame change of gravity's pull: g R_k^T (up - e_z)
        self.shift = GRAVITY * np.einsum("kji,j->ki", R, up - [0.0, 0.0, 1.0])

    def __len__(self) -> int:
        return len(self.drive)

    def __getitem__(self, k):
        frame = self.drive[k]
        if frame.specific_force is None:
            return frame
        k = range(len(self))[k]
        return dataclasses.replace(
            frame, specific_force=frame.specific_force + self.shift[k]
        )

    def __getattr__(self, name):
        return getattr(self.drive, name)
