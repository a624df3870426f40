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
of that median, and ATE / RPE / KITTI error. The full run takes each drive ``REPEATS`` times, the two methods in
turn, and reports every repeat's medians and their ratio (``speed_ratio_per_repeat``, KISS-ICP's time over
slamlib's) beside the median of the repeats. ``--quick`` uses the first 60 frames of the 300-frame drive, once;
the full run adds the whole ~690 m route.
"""

from __future__ import annotations

import numpy as np

HELP = "KISS-ICP (LIDAR-only ICP odometry) beside slamlib's particle SLAM on the same drive: time per frame, ATE"

#: Runs of both methods on each drive in the full benchmark (their frame-time medians vary between runs).
REPEATS = 3

INSTALL_HINT = "slamlib bench peers needs KISS-ICP: pip install kiss-icp (or pip install -e '.[peers]')"


def _kiss_icp(drive) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """KISS-ICP over ``drive`` (:func:`slamlib.peers.kiss_icp_poses`, de-skewing off: the synthetic scans are cast
    from one pose); body poses ``(F, 4, 4)``, per-frame registration seconds ``(F,)`` and the points of every 25th
    scan (read again, outside the timing)."""
    from slamlib.peers import kiss_icp_poses

    poses, seconds = kiss_icp_poses(drive, drive.T_velo_imu, deskew=False)
    return (
        poses,
        seconds,
        np.asarray([len(drive[k].scan) for k in range(0, len(drive), 25)]),
    )


def _compare(drive, repeats: int = 1) -> dict:
    """Both methods on ``drive``, ``repeats`` times in turn (slamlib, KISS-ICP, slamlib, ...): per-frame medians of
    every repeat, their ratio per repeat, and the metrics of the first repeat (``repeat_pose_difference_max``: the
    largest difference of any later repeat's pose matrices from the first's)."""
    from slamlib.metrics import trajectory_distances, trajectory_metrics
    from slamlib.slam3d import SLAM3DConfig, run_drive

    medians = {"kiss_icp": [], "slamlib": []}
    # largest difference of a repeat's poses from the first's
    spread = {"kiss_icp": 0.0, "slamlib": 0.0}
    for r in range(repeats):
        slam = run_drive(drive, SLAM3DConfig(), progress=False)
        kiss_poses, kiss_seconds, n_points = _kiss_icp(drive)
        if r == 0:
            first = {"kiss_icp": kiss_poses, "slamlib": np.asarray(slam.poses)}
        # slamlib repeats bit for bit; KISS-ICP's parallel sums may differ in the last bits
        else:
            for name, poses in (("kiss_icp", kiss_poses), ("slamlib", slam.poses)):
                spread[name] = max(
                    spread[name], float(np.max(np.abs(np.asarray(poses) - first[name])))
                )
        medians["slamlib"].append(float(np.median(slam.frame_seconds[1:])))
        medians["kiss_icp"].append(float(np.median(kiss_seconds[1:])))
    gt = slam.ground_truth
    rows = {}
    for name in ("kiss_icp", "slamlib"):
        median = float(np.median(medians[name]))
        rows[name] = {
            "frame_ms_median": round(median * 1e3, 2),
            "fps_median": round(1.0 / median, 1),
            "frame_ms_median_per_repeat": [round(m * 1e3, 2) for m in medians[name]],
            "repeat_pose_difference_max": spread[name],
            **{
                k: round(float(v), 5)
                for k, v in trajectory_metrics(first[name], gt).items()
            },
        }
    rows["dead_reckoning"] = {
        k: round(float(v), 5)
        for k, v in trajectory_metrics(slam.dead_reckoning, gt).items()
    }
    ratios = [k / s for k, s in zip(medians["kiss_icp"], medians["slamlib"])]
    out = {
        "frames": int(len(gt)),
        "path_length_m": round(float(trajectory_distances(gt)[-1]), 1),
        "scan_points_median": int(np.median(n_points)),
        "repeats": repeats,
        "speed_ratio_per_repeat": [round(x, 3) for x in ratios],
        **rows,
    }
    print(
        {k: v for k, v in out.items() if k in ("frames", "speed_ratio_per_repeat")},
        flush=True,
    )
    return out


def run(quick: bool = False) -> dict:
    try:
        import kiss_icp  # noqa: F401
    except ImportError:
        raise SystemExit(INSTALL_HINT) from None
    from importlib.metadata import version

    import numba

    from slamlib.kitti import KittiRawDrive
    from slamlib.synth import DEFAULT_FRAMES, default_drive

    source = default_drive(progress=False, realism=False)
    drive = KittiRawDrive(*source, frames=range(0, 60) if quick else None)
    # JIT compilation and caches, untimed
    _compare(KittiRawDrive(*source, frames=range(0, 5)))
    repeats = 1 if quick else REPEATS
    drives = {f"default drive {DEFAULT_FRAMES}": _compare(drive, repeats)}
    if not quick:
        whole = default_drive(full=True, progress=False, realism=False)
        drives["whole route (full=True)"] = _compare(KittiRawDrive(*whole), repeats)
    return {
        "kiss_icp_version": version("kiss-icp"),
        "numba_threads": int(numba.get_num_threads()),
        "drives": drives,
    }
