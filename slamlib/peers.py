"""Other LIDAR odometry methods run on slamlib's frames, to compare with: KISS-ICP.

KISS-ICP (I. Vizzo, T. Guadagnino, B. Mersch, L. Wiesmann, J. Behley, C. Stachniss, "KISS-ICP: In Defense of
Point-to-Point ICP -- Simple, Accurate, and Robust Registration If Done the Right Way", IEEE RA-L 2023;
``pip install kiss-icp``, MIT licence) registers each full scan against a local voxel map with point-to-point ICP,
an adaptive threshold and a constant-velocity prediction. It is installed with ``pip install -e '.[peers]'``
(``make setup`` does).

Frames: KISS-ICP estimates Velodyne poses ``P_k = T_{velo_0 <- velo_k}``; :func:`kiss_icp_poses` returns them as
body poses ``T_{body_0 <- body_k} = T_velo_imu^{-1} P_k T_velo_imu`` (the identity calibration for LIDAR-only data,
whose body is the Velodyne), the frame slamlib's trajectories use.
"""

from __future__ import annotations

import time

import numpy as np

__all__ = ["kiss_icp_poses", "kiss_icp_available", "INSTALL_HINT"]

INSTALL_HINT = "KISS-ICP is not installed: pip install kiss-icp (or pip install -e '.[peers]')"


def kiss_icp_available() -> bool:
    """Whether the ``kiss_icp`` package can be imported."""
    try:
        import kiss_icp  # noqa: F401
    except ImportError:
        return False
    return True


def kiss_icp_poses(frames, T_velo_imu=None, deskew: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Run KISS-ICP (its default configuration) over ``frames`` (each with ``.scan`` (N, 4), Velodyne frame).

    ``T_velo_imu`` (4, 4): the calibration to express the poses in the body frame (default: the frames'
    ``T_velo_imu`` attribute, or the identity). ``deskew``: KISS-ICP's own motion compensation, with each point's
    time from its azimuth (KISS-ICP's rule for KITTI, ``s = 0.5 (1 - atan2(y, x) / pi)``).

    Returns ``(poses (F, 4, 4) body, seconds (F,))``: the poses and each frame's registration time (the
    ``register_frame`` call alone). Raises ``ImportError`` with :data:`INSTALL_HINT` when KISS-ICP is missing.
    """
    try:
        from kiss_icp.config import load_config
        from kiss_icp.kiss_icp import KissICP
    except ImportError:
        raise ImportError(INSTALL_HINT) from None

    config = load_config(None)
    config.data.deskew = bool(deskew)
    odometry = KissICP(config)
    if T_velo_imu is None:
        T_velo_imu = getattr(frames, "T_velo_imu", None)
    T_velo_imu = np.eye(4) if T_velo_imu is None else np.asarray(T_velo_imu, dtype=np.float64)
    T_imu_velo = np.linalg.inv(T_velo_imu)
    poses, seconds = [], []
    for frame in frames:
        points = np.asarray(frame.scan[:, :3], dtype=np.float64)
        stamps = (0.5 * (1.0 - np.arctan2(points[:, 1], points[:, 0]) / np.pi) if deskew else np.zeros(0))
        t0 = time.perf_counter()
        odometry.register_frame(points, stamps)
        seconds.append(time.perf_counter() - t0)
        poses.append(T_imu_velo @ odometry.last_pose @ T_velo_imu)
    return np.asarray(poses).reshape(-1, 4, 4), np.asarray(seconds)
