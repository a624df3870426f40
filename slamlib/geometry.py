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
* A rotation vector ``phi`` (radians) is the axis times the angle: ``R = Exp(phi)`` (:func:`so3_exp`), ``phi =
  Log(R)`` (:func:`so3_log`).

References: KITTI raw data paper (Geiger et al., IJRR 2013), section on OXTS; pykitti ``utils.rotx/roty/rotz``;
for ``Exp`` and ``Log``, Barfoot, "State Estimation for Robotics" (2017), sec. 7.1.3, and Shepperd, "Quaternion from
rotation matrix", J. Guidance and Control 1(3), 1978.
The tests check these hand-written formulas against :class:`scipy.spatial.transform.Rotation`.
"""

from __future__ import annotations

import math

import numpy as np

#: Below this angle (rad) the rotation formulas switch to Taylor series, whose closed forms lose digits to
#: cancellation there: :func:`so3_exp` (``sin a / a``, ``(1 - cos a) / a^2``), :func:`so3_log` (``atan2(s, w) /
#: s``) and :func:`slamlib.odometry.so3_left_jacobian`. The terms the series leave out are of order ``a^4 / 120``,
#: below 1e-18.
SMALL_ANGLE = 1e-4


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


def skew(v) -> np.ndarray:
    """``[v]x (..., 3, 3)`` of ``v (..., 3)``: the matrix with ``[v]x u = v x u``."""
    v = np.asarray(v, dtype=np.float64)
    K = np.zeros(v.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2] = -v[..., 2], v[..., 1]
    K[..., 1, 0], K[..., 1, 2] = v[..., 2], -v[..., 0]
    K[..., 2, 0], K[..., 2, 1] = -v[..., 1], v[..., 0]
    return K


def so3_exp(phi) -> np.ndarray:
    """Rodrigues' formula: the rotations ``R = Exp(phi) (..., 3, 3)`` of rotation vectors ``phi (..., 3)`` (rad).

    ``R = I + (sin a / a) K + ((1 - cos a) / a^2) K^2`` with ``a = |phi|``, ``K = [phi]x`` (:func:`skew`); below
    :data:`SMALL_ANGLE` the coefficients are their Taylor series ``1 - a^2/6`` and ``1/2 - a^2/24``.
    """
    phi = np.asarray(phi, dtype=np.float64)
    a2 = (phi * phi).sum(axis=-1)
    a = np.sqrt(a2)
    small = a < SMALL_ANGLE
    a_safe = np.where(small, 1.0, a)
    c1 = np.where(small, 1.0 - a2 / 6.0, np.sin(a_safe) / a_safe)
    c2 = np.where(small, 0.5 - a2 / 24.0, (1.0 - np.cos(a_safe)) / a_safe**2)
    K = skew(phi)
    return np.eye(3) + c1[..., None, None] * K + c2[..., None, None] * (K @ K)


def so3_log(R) -> np.ndarray:
    """The rotation vector ``phi = Log(R) (3,)`` (rad, ``|phi| <= pi``) of one rotation ``R (3, 3)``.

    Through the unit quaternion ``(w, x, y, z)``, ``w >= 0``: ``phi = 2 atan2(|v|, w) v / |v|`` with ``v = (x, y,
    z)``, accurate at every angle (the trace formula ``cos a = (tr R - 1) / 2`` loses the axis near ``a = pi`` and
    the angle near 0). The quaternion is Shepperd's: it starts from the largest of ``4 w^2 = 1 + tr R`` and ``4
    x^2 = 1 + 2 R_00 - tr R`` (and ``y``, ``z`` alike), so it never divides by a small number. Below ``|v| <``
    :data:`SMALL_ANGLE` ``2 atan2(|v|, w) / |v|`` is its series ``2 / w (1 - |v|^2 / (3 w^2))``. Scalar
    arithmetic: it runs once a frame, where numpy's per-call overhead would cost more than the math.
    """
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = np.asarray(
        R, dtype=np.float64
    ).tolist()
    tr = r00 + r11 + r22
    four_sq = (1.0 + tr, 1.0 + 2.0 * r00 - tr, 1.0 + 2.0 * r11 - tr, 1.0 + 2.0 * r22 - tr)
    pick = max(range(4), key=four_sq.__getitem__)
    big = 0.5 * math.sqrt(four_sq[pick])
    k = 0.25 / big
    # the off-diagonal differences and sums give the other three components from the largest
    d_zy, d_xz, d_yx = (r21 - r12) * k, (r02 - r20) * k, (r10 - r01) * k
    s_xy, s_xz, s_yz = (r01 + r10) * k, (r02 + r20) * k, (r12 + r21) * k
    w, x, y, z = (
        (big, d_zy, d_xz, d_yx),
        (d_zy, big, s_xy, s_xz),
        (d_xz, s_xy, big, s_yz),
        (d_yx, s_xz, s_yz, big),
    )[pick]
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    s = math.sqrt(x * x + y * y + z * z)
    if s < SMALL_ANGLE:
        scale = 2.0 / w * (1.0 - s * s / (3.0 * w * w))
    else:
        scale = 2.0 * math.atan2(s, w) / s
    return np.array([scale * x, scale * y, scale * z])


def transform_points(T, points) -> np.ndarray:
    """Apply pose ``T`` (4, 4) to ``points`` (N, 3): ``p' = R p + t``. Keeps the points' float dtype."""
    T = np.asarray(T)
    pts = np.asarray(points)
    dtype = pts.dtype if np.issubdtype(pts.dtype, np.floating) else np.float64
    R = T[:3, :3].astype(dtype)
    t = T[:3, 3].astype(dtype)
    return pts @ R.T + t
