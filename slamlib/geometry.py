"""Rigid-body geometry in 3D: rotations from roll/pitch/yaw, 4x4 poses, point transforms.

Conventions (used everywhere in slamlib):

* Angles in radians. ``rpy = (roll, pitch, yaw)`` about the body x, y, z axes.
* ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``: the KITTI OXTS / pykitti convention (intrinsic z-y'-x'',
  equivalently extrinsic x-y-z), where
  ``Rx(a) = [[1,0,0],[0,c,-s],[0,s,c]]``, ``Ry(a) = [[c,0,s],[0,1,0],[-s,0,c]]``,
  ``Rz(a) = [[c,-s,0],[s,c,0],[0,0,1]]``.
* A pose ``T_a_b`` is a 4x4 float64 homogeneous matrix that maps points from frame ``b`` into frame ``a``:
  ``p_a = T_a_b @ p_b`` (``p`` homogeneous). ``T_a_c = T_a_b @ T_b_c``.
* Points are ``(N, 3)`` arrays (float32 for scans); batches of poses are ``(P, 4, 4)``.

References: KITTI raw data paper (Geiger et al., IJRR 2013), section on OXTS; pykitti ``utils.rotx/roty/rotz``.
The tests check these hand-written formulas against :class:`scipy.spatial.transform.Rotation`.
"""

from __future__ import annotations

import numpy as np


def rot_x(a: float) -> np.ndarray:
    """Rotation by ``a`` radians about x: ``[[1,0,0],[0,cos a,-sin a],[0,sin a,cos a]]``."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> np.ndarray:
    """Rotation by ``a`` radians about y: ``[[cos a,0,sin a],[0,1,0],[-sin a,0,cos a]]``."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a: float) -> np.ndarray:
    """Rotation by ``a`` radians about z: ``[[cos a,-sin a,0],[sin a,cos a,0],[0,0,1]]``."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rpy_to_matrix(rpy) -> np.ndarray:
    """``R = Rz(yaw) Ry(pitch) Rx(roll)`` for ``rpy`` of shape (3,) or (..., 3); returns (3, 3) or (..., 3, 3).

    Written out (``c* = cos``, ``s* = sin`` of roll r, pitch p, yaw y)::

        [[cy cp, cy sp sr - sy cr, cy sp cr + sy sr],
         [sy cp, sy sp sr + cy cr, sy sp cr - cy sr],
         [-sp,   cp sr,            cp cr          ]]
    """
    rpy = np.asarray(rpy, dtype=np.float64)
    r, p, y = rpy[..., 0], rpy[..., 1], rpy[..., 2]
    cr, sr, cp, sp, cy, sy = (
        np.cos(r),
        np.sin(r),
        np.cos(p),
        np.sin(p),
        np.cos(y),
        np.sin(y),
    )
    R = np.empty(rpy.shape[:-1] + (3, 3))
    R[..., 0, 0] = cy * cp
    R[..., 0, 1] = cy * sp * sr - sy * cr
    R[..., 0, 2] = cy * sp * cr + sy * sr
    R[..., 1, 0] = sy * cp
    R[..., 1, 1] = sy * sp * sr + cy * cr
    R[..., 1, 2] = sy * sp * cr - cy * sr
    R[..., 2, 0] = -sp
    R[..., 2, 1] = cp * sr
    R[..., 2, 2] = cp * cr
    return R


def matrix_to_rpy(R) -> np.ndarray:
    """Inverse of :func:`rpy_to_matrix` for pitch in (-pi/2, pi/2): ``(roll, pitch, yaw)`` of shape (..., 3).

    ``pitch = -asin(R[2,0])``, ``roll = atan2(R[2,1], R[2,2])``, ``yaw = atan2(R[1,0], R[0,0])``.
    """
    R = np.asarray(R, dtype=np.float64)
    pitch = -np.arcsin(np.clip(R[..., 2, 0], -1.0, 1.0))
    roll = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    yaw = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return np.stack([roll, pitch, yaw], axis=-1)


def make_pose(R, t) -> np.ndarray:
    """4x4 pose from rotation ``R`` (..., 3, 3) and translation ``t`` (..., 3): ``[[R, t], [0, 1]]``."""
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    T = np.zeros(R.shape[:-2] + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def invert_pose(T) -> np.ndarray:
    """Inverse of rigid poses (..., 4, 4): ``[[R^T, -R^T t], [0, 1]]`` (exact, no general matrix inverse)."""
    T = np.asarray(T, dtype=np.float64)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    t = T[..., :3, 3]
    return make_pose(Rt, -np.einsum("...ij,...j->...i", Rt, t))


def transform_points(T, points) -> np.ndarray:
    """Apply pose ``T`` (4, 4) to ``points`` (N, 3): ``p' = R p + t``. Keeps the points' float dtype."""
    T = np.asarray(T)
    pts = np.asarray(points)
    dtype = pts.dtype if np.issubdtype(pts.dtype, np.floating) else np.float64
    R = T[:3, :3].astype(dtype)
    t = T[:3, 3].astype(dtype)
    return pts @ R.T + t
