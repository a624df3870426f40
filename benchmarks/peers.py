"""``slamlib bench peers``: KISS-ICP, the LIDAR odometry to beat, beside slamlib's particle SLAM on one drive.

KISS-ICP (Vizzo et al., "KISS-ICP: In Defense of Point-to-Point ICP", RA-L 2023; ``pip install kiss-icp``, MIT
licence) registers each full scan against a local voxel map with point-to-point ICP and an adaptive threshold.
It uses the LIDAR only; slamlib's filter uses the LIDAR and the IMU. Both run here on the same frames of the
still default synthetic drive (``default_drive(realism=False)``; the realistic drives are ``slamlib sweep``'s),
one after the other in one process, and are scored with the same metrics
(:func:`slamlib.metrics.trajectory_metrics`) against the same ground truth:

* KISS-ICP gets the raw Velodyne scan (``x, y, z`` float64, its default configuration, de-skewing off since the
  synthetic scans are cast from one pose). Its poses ``P_k = T_{velo_0 <- velo_k}`` are turned into body (IMU)
  poses ``T_{body_0 <- body_k} = T_velo_imu^{-1} P_k T_velo_imu`` (KITTI ``calib_imu_to_velo.txt``).
* slamlib runs :class:`~slamlib.slam3d.SLAM3DConfig` defaults (300 particles, voxel map, Numba CPU).

Reported per method: per-frame time (median, from the registration call alone, file reading excluded), frames/s
of that median, and ATE / RPE / KITTI error. ``--quick`` uses the first 60 frames of the 300-frame drive;
the full run adds the whole ~690 m route.
"""

from __future__ import annotations

import numpy as np

HELP = "KISS-ICP (LIDAR-only ICP odometry) beside slamlib's particle SLAM on the same drive: time per frame, ATE"

INSTALL_HINT = "slamlib bench peers needs KISS-ICP: pip install kiss-icp (or pip install -e '.[peers]')"


def _kiss_icp(drive) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """KISS-ICP over ``drive`` (:func:`slamlib.peers.kiss_icp_poses`, de-skewing off: the synthetic scans are cast
    from one pose); body poses ``(F, 4, 4)``, per-frame registration seconds ``(F,)`` and the points of every 25th
    scan (read again, outside the timing)."""
    from slamlib.peers import kiss_icp_poses

    poses, seconds = kiss_icp_poses(drive, drive.T_velo_imu, deskew=False)
    return poses, seconds, np.asarray([len(drive[k].scan) for k in range(0, len(drive), 25)])


def _compare(drive) -> dict:
    from slamlib.metrics import trajectory_distances, trajectory_metrics
    from slamlib.slam3d import SLAM3DConfig, run_drive

    slam = run_drive(drive, SLAM3DConfig(), progress=False)
    gt = slam.ground_truth
    kiss_poses, kiss_seconds, n_points = _kiss_icp(drive)
    rows = {}
    for name, poses, seconds in (("kiss_icp", kiss_poses, kiss_seconds),
                                 ("slamlib", slam.poses, slam.frame_seconds)):
        median = float(np.median(seconds[1:]))
        rows[name] = {"frame_ms_median": round(median * 1e3, 2), "fps_median": round(1.0 / median, 1),
                      **{k: round(float(v), 5) for k, v in trajectory_metrics(poses, gt).items()}}
    rows["dead_reckoning"] = {k: round(float(v), 5)
                              for k, v in trajectory_metrics(slam.dead_reckoning, gt).items()}
    out = {"frames": int(len(gt)), "path_length_m": round(float(trajectory_distances(gt)[-1]), 1),
           "scan_points_median": int(np.median(n_points)),
           **rows}
    print(out, flush=True)
    return out


def run(quick: bool = False) -> dict:
    try:
        import kiss_icp  # noqa: F401
    except ImportError:
        raise SystemExit(INSTALL_HINT) from None
    import numba
    from importlib.metadata import version

    from slamlib.kitti import KittiRawDrive
    from slamlib.synth import DEFAULT_FRAMES, default_drive

    source = default_drive(progress=False, realism=False)
    drive = KittiRawDrive(*source, frames=range(0, 60) if quick else None)
    _compare(KittiRawDrive(*source, frames=range(0, 5)))  # JIT compilation and caches, untimed
    drives = {f"default drive {DEFAULT_FRAMES}": _compare(drive)}
    if not quick:
        whole = default_drive(full=True, progress=False, realism=False)
        drives["whole route (full=True)"] = _compare(KittiRawDrive(*whole))
    return {"kiss_icp_version": version("kiss-icp"), "numba_threads": int(numba.get_num_threads()),
            "drives": drives}
