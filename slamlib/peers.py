"""Other LIDAR odometry and SLAM methods run on slamlib's frames, to compare with: KISS-ICP and KISS-SLAM.

KISS-ICP (I. Vizzo, T. Guadagnino, B. Mersch, L. Wiesmann, J. Behley, C. Stachniss, "KISS-ICP: In Defense of
Point-to-Point ICP -- Simple, Accurate, and Robust Registration If Done the Right Way", IEEE RA-L 2023;
``pip install kiss-icp``, MIT licence) registers each full scan against a local voxel map with point-to-point ICP,
an adaptive threshold and a constant-velocity prediction. It is installed with ``pip install -e '.[peers]'``
(``make setup`` does).

KISS-SLAM (T. Guadagnino, B. Mersch, S. Gupta, I. Vizzo, G. Grisetti, C. Stachniss, "KISS-SLAM: A Simple, Robust,
and Accurate 3D LiDAR SLAM System With Enhanced Generalization Capabilities", IROS 2025; ``pip install kiss-slam``,
MIT licence) adds loop closure to KISS-ICP's odometry: local maps every 100 m, MapClosures' place recognition,
ICP verification by overlap, and a pose graph optimised after each closure and, at the end, frame by frame
(:func:`kiss_slam_poses` runs it as its own pipeline does).

Frames: KISS-ICP estimates Velodyne poses ``P_k = T_{velo_0 <- velo_k}``; :func:`kiss_icp_poses` returns them as
body poses ``T_{body_0 <- body_k} = T_velo_imu^{-1} P_k T_velo_imu`` (the identity calibration for LIDAR-only data,
whose body is the Velodyne), the frame slamlib's trajectories use.

Times: a pose is the sensor's at one instant, and KISS-ICP's is not the instant KITTI stamps its ground truth at.
De-skewing, KISS-ICP moves every point of a scan to the *end* of the sweep (``Preprocessing.cpp``: the point at
normalised sweep time ``s`` in [0, 1] by ``Exp((s - 1) Log D)``, ``D`` its last frame-to-frame motion), so the
pose it then registers is the sweep end's, half a sweep (51.6 ms) after the scan's mid-sweep stamp; without
de-skewing the pose is about the mid-sweep one. A KITTI raw frame's pose (OXTS) comes another 12-24 ms after the
mid-sweep stamp (``Frame.scan_time_offset_s``). :func:`kiss_icp_poses` with ``pose_times=True`` moves each pose to
the frame's pose time along KISS-ICP's own constant-velocity motion, as one interpolates any trajectory to the
ground truth's stamps before comparing (:func:`move_along`).
"""

from __future__ import annotations

import contextlib
import os
import sys
import time

import numpy as np

from slamlib.kitti.velodyne import SWEEP_PERIOD_S
from slamlib.odometry import imu_increment, increment_matrix, twist_between

__all__ = [
    "kiss_icp_poses",
    "kiss_slam_poses",
    "kiss_icp_available",
    "move_along",
    "pose_time_fraction",
    "INSTALL_HINT",
]

INSTALL_HINT = (
    "KISS-ICP is not installed: pip install kiss-icp (or pip install -e '.[peers]')"
)


def kiss_icp_available() -> bool:
    """Whether the ``kiss_icp`` package can be imported."""
    try:
        import kiss_icp  # noqa: F401
    except ImportError:
        return False
    return True


def move_along(pose, motion, fraction: float) -> np.ndarray:
    """``pose @ Exp(fraction * Log(motion))``: ``pose (4, 4)`` moved on by ``fraction`` of the rigid ``motion
    (4, 4)`` (both in the pose's own frame), at constant body twist; ``fraction`` 1 gives ``pose @ motion``, -1
    ``pose @ inv(motion)``, 0 ``pose``. Exp/Log of SE(3) are :func:`slamlib.odometry.twist_between` and
    :func:`~slamlib.odometry.imu_increment` with equal samples (Sola, Deray, Atchuthan, "A micro Lie theory for
    state estimation in robotics", 2018, eqs. 172-174)."""
    v, w = twist_between(np.eye(4), motion, 1.0)
    return np.asarray(pose, dtype=np.float64) @ increment_matrix(
        *imu_increment(v, w, v, w, float(fraction))
    )


def pose_time_fraction(
    scan_time_offset_s: float, deskew: bool, sweep_period: float = SWEEP_PERIOD_S
) -> float:
    """How many sweeps after KISS-ICP's pose of a scan the frame's pose is: ``(t_pose - t_kiss) / T``.

    ``t_kiss`` is the sweep's end with ``deskew`` (the scan stamp ``+ T / 2``), the scan's mid-sweep stamp without;
    the frame's pose is ``scan_time_offset_s`` (scan stamp minus pose stamp, s; about -17 ms on KITTI raw, 0 when the
    ground truth is the scan's, as in the odometry layout) before the stamp. ``T`` = ``sweep_period`` (s).
    """
    t_kiss = 0.5 * sweep_period if deskew else 0.0
    return (-float(scan_time_offset_s) - t_kiss) / sweep_period


def _calibration(frames, T_velo_imu):
    """``(T_velo_imu, its inverse)``: the one given, else the frames' ``T_velo_imu``, else the identity."""
    if T_velo_imu is None:
        T_velo_imu = getattr(frames, "T_velo_imu", None)
    T_velo_imu = (
        np.eye(4) if T_velo_imu is None else np.asarray(T_velo_imu, dtype=np.float64)
    )
    return T_velo_imu, np.linalg.inv(T_velo_imu)


def _points_and_stamps(frame, deskew: bool):
    """A frame's ``(N, 3)`` float64 Velodyne points and, when de-skewing, each point's normalised sweep time by
    KISS-ICP's rule for KITTI, ``s = 0.5 (1 - atan2(y, x) / pi)`` (else an empty array)."""
    points = np.asarray(frame.scan[:, :3], dtype=np.float64)
    if not deskew:
        return points, np.zeros(0)
    return points, 0.5 * (1.0 - np.arctan2(points[:, 1], points[:, 0]) / np.pi)


def _time_offset(frame) -> float:
    """A frame's ``scan_time_offset_s`` (scan stamp minus pose stamp, s), 0 when it has none."""
    return float(getattr(frame, "scan_time_offset_s", 0.0))


def _at_pose_time(
    pose, delta, offset: float, deskew: bool, sweep_period: float
) -> np.ndarray:
    """A KISS pipeline's Velodyne ``pose`` moved to its frame's pose time (``offset``: :func:`_time_offset`) along
    its last motion ``delta`` (one sweep): :func:`move_along` by :func:`pose_time_fraction`."""
    return move_along(pose, delta, pose_time_fraction(offset, deskew, sweep_period))


def kiss_icp_poses(
    frames,
    T_velo_imu=None,
    deskew: bool = False,
    pose_times: bool = False,
    sweep_period: float = SWEEP_PERIOD_S,
    max_threads: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Run KISS-ICP (its default configuration) over ``frames`` (each with ``.scan`` (N, 4), Velodyne frame).

    ``T_velo_imu`` (4, 4): the calibration to express the poses in the body frame (default: the frames'
    ``T_velo_imu`` attribute, or the identity). ``deskew``: KISS-ICP's own motion compensation, with each point's
    time from its azimuth (KISS-ICP's rule for KITTI, ``s = 0.5 (1 - atan2(y, x) / pi)``).
    ``pose_times``: move each pose from the instant KISS-ICP's refers to (see the module docstring) to the frame's
    pose time (``frame.scan_time_offset_s``, 0 when absent) along KISS-ICP's last motion ``D`` taken as one sweep of
    ``sweep_period`` s: ``P @ Exp(f Log D)``, ``f`` = :func:`pose_time_fraction`. For swept scans compared with
    ground truth stamped elsewhere (a KITTI raw drive's OXTS poses); not for scans cast from one instant.
    ``max_threads``: the threads of its registration (``registration.max_num_threads``; 0, its default, all cores).

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
    config.registration.max_num_threads = int(max_threads)
    odometry = KissICP(config)
    T_velo_imu, T_imu_velo = _calibration(frames, T_velo_imu)
    poses, seconds = [], []
    for frame in frames:
        points, stamps = _points_and_stamps(frame, deskew)
        t0 = time.perf_counter()
        odometry.register_frame(points, stamps)
        seconds.append(time.perf_counter() - t0)
        pose = odometry.last_pose
        if pose_times:
            pose = _at_pose_time(
                pose, odometry.last_delta, _time_offset(frame), deskew, sweep_period
            )
        poses.append(T_imu_velo @ pose @ T_velo_imu)
    return np.asarray(poses).reshape(-1, 4, 4), np.asarray(seconds)


@contextlib.contextmanager
def _quiet_output():
    """The process's stdout and stderr (file descriptors 1 and 2: Python's prints and the C++ optimiser's
    iteration log alike) sent to ``/dev/null`` for the block. An exception still reaches the caller, and its
    traceback the terminal, once the block has left."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = {fd: os.dup(fd) for fd in (1, 2)}
    try:
        with open(os.devnull, "wb") as null:
            for fd in saved:
                os.dup2(null.fileno(), fd)
        with open(os.devnull, "w") as sink:
            with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
                yield
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        for fd, copy in saved.items():
            os.dup2(copy, fd)
            os.close(copy)


def kiss_slam_poses(
    frames,
    T_velo_imu=None,
    deskew: bool = False,
    pose_times: bool = False,
    sweep_period: float = SWEEP_PERIOD_S,
    max_threads: int = 0,
) -> tuple[np.ndarray, np.ndarray, list]:
    """Run KISS-SLAM 0.0.2 (its default configuration) over ``frames`` (``.scan`` (N, 4), Velodyne frame), as its
    own pipeline does: ``process_scan`` per frame, then the last local map closed, dropped, and the frame-by-frame
    pose graph optimised (``fine_grained_optimization``).

    ``T_velo_imu``, ``deskew``, ``pose_times``, ``sweep_period`` and ``max_threads`` as :func:`kiss_icp_poses`'s;
    the motion each optimised pose is moved along is the one from the frame before, ``D_k = P_{k-1}^{-1} P_k`` (the
    identity for the first frame), KISS-ICP's ``last_delta`` on the optimised trajectory.

    Returns ``(poses (F, 4, 4) body, seconds (F,), closures)``: each frame's ``process_scan`` time (the final
    optimisation spread evenly over the frames, so that ``1 / median`` and the mean both count it) and the closures
    KISS-SLAM accepted, ``(reference local map, query local map)`` pairs. KISS-SLAM's own output (stdout and stderr)
    goes nowhere. Raises ``ImportError`` naming the install when it is missing.
    """
    try:
        from kiss_slam.config.config import load_config
        from kiss_slam.slam import KissSLAM
    except ImportError:
        raise ImportError(
            "KISS-SLAM is not installed: `make setup` installs kiss-slam 0.0.2 (and map-closures 2.2.0) "
            "without their dependencies, see pyproject.toml's `loops` extra"
        ) from None

    config = load_config(None)
    config.odometry.preprocessing.deskew = bool(deskew)
    config.odometry.registration.max_num_threads = int(max_threads)
    T_velo_imu, T_imu_velo = _calibration(frames, T_velo_imu)
    seconds, offsets = [], []
    with _quiet_output():
        slam = KissSLAM(config)
        for frame in frames:
            offsets.append(_time_offset(frame))
            points, stamps = _points_and_stamps(frame, deskew)
            t0 = time.perf_counter()
            slam.process_scan(points, stamps)
            seconds.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        slam.generate_new_node()
        slam.local_map_graph.erase_last_local_map()
        poses, _ = slam.fine_grained_optimization()
        final = time.perf_counter() - t0
    seconds = np.asarray(seconds) + final / max(1, len(seconds))
    poses = np.asarray(poses).reshape(-1, 4, 4)
    if pose_times and len(poses):
        deltas = np.concatenate([np.eye(4)[None], np.linalg.inv(poses[:-1]) @ poses[1:]])
        poses = np.array(
            [
                _at_pose_time(p, d, offset, deskew, sweep_period)
                for p, d, offset in zip(poses, deltas, offsets)
            ]
        )
    return (
        T_imu_velo @ poses @ T_velo_imu,
        seconds,
        [tuple(c) for c in slam.get_closures()],
    )
