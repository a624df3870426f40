"""``slamlib bench loops``: slamlib with loop closure beside KISS-SLAM on whole synthetic sequences.

Workload: the synthetic KITTI odometry sequences of ``slamlib bench lidar_only`` (no IMU: both methods LIDAR-only),
along the **whole** real routes of KITTI odometry 07, 05 and 00 (1,101, 2,761 and 4,541 frames), seed 0, cached
once (:func:`benchmarks.lidar_only._sequence`). ``--quick``: the first 150 frames of 07.

On the same frames, one after the other in one process:

* slamlib, its defaults, with ``run_drive(..., loop_closure=True)`` (:mod:`slamlib.loops`): the filter's own
  poses (``slamlib``) and the re-anchored ones (``slamlib_loop_closure``), one run (the back end's work is inside
  each frame's timing, so both rows carry the same frames/s);
* KISS-SLAM 0.0.2 (:func:`slamlib.peers.kiss_slam_poses`, its default configuration, de-skewing off: the scans are
  cast from one pose).

Reported per route and method: KITTI translational error (%), ATE RMSE (m), frames/s (``1 / median`` of the
per-frame times); slamlib's closures, kept or not, each with its relative pose's error against the ground truth
(m, degrees); KISS-SLAM's accepted closures. Beside them, ``no_revisit``: the first 300 frames of 07, where the
route never comes back, and the closures slamlib accepted there (none, issue 31 asks).
"""

from __future__ import annotations

import numpy as np

HELP = "slamlib with loop closure vs KISS-SLAM on whole synthetic 07, 05, 00 (LIDAR-only)"

ROUTES = ("07", "05", "00")
QUICK_FRAMES = (0, 150)
NO_REVISIT_FRAMES = (0, 300)


def _closure_rows(run, gt) -> list:
    """Each slamlib closure: local maps, frames, kept, and its relative pose's error against the truth."""
    from slamlib.geometry import invert_pose

    rows = []
    for c in run.loop_closer.closures:
        q, r = c.query_frame, c.reference_frame
        err = invert_pose(invert_pose(gt[q]) @ gt[r]) @ c.relative
        angle = np.degrees(np.arccos(np.clip((np.trace(err[:3, :3]) - 1) / 2, -1, 1)))
        rows.append(
            {
                "query_frame": int(q),
                "reference_frame": int(r),
                "kept": c.kept,
                "fitness": round(c.fitness, 3),
                "error_m": round(float(np.linalg.norm(err[:3, 3])), 4),
                "error_deg": round(float(angle), 4),
            }
        )
    return rows


def run(quick: bool = False) -> dict:
    from importlib.metadata import version

    import numba

    from benchmarks.lidar_only import _row, _sequence
    from slamlib.metrics import trajectory_distances
    from slamlib.peers import kiss_slam_poses
    from slamlib.slam3d import SLAM3DConfig, run_drive

    routes = {}
    for route in ("07",) if quick else ROUTES:
        seq = _sequence(route, QUICK_FRAMES if quick else (0, None))
        gt = seq.ground_truth_poses()
        slam = run_drive(
            seq, SLAM3DConfig(), progress=True, desc=f"slamlib {route}", loop_closure=True
        )
        kiss, kiss_seconds, kiss_closures = kiss_slam_poses(seq)
        closures = _closure_rows(slam, gt)
        row = {
            "frames": len(seq),
            "path_length_m": round(float(trajectory_distances(gt)[-1]), 1),
            "slamlib": _row(slam.poses, slam.frame_seconds, gt),
            "slamlib_loop_closure": _row(slam.loop_closed, slam.frame_seconds, gt),
            "kiss_slam": _row(kiss, kiss_seconds, gt),
            "local_maps": len(slam.loop_closer.mapper.maps),
            "closures": closures,
            "kiss_slam_closures": len(kiss_closures),
        }
        row["ate_ratio_loop_closure_over_kiss_slam"] = round(
            row["slamlib_loop_closure"]["ate_rmse_m"] / row["kiss_slam"]["ate_rmse_m"], 3
        )
        routes[route] = row
        print(route, row, flush=True)
    a, b = NO_REVISIT_FRAMES
    first = _sequence("07", (0, None)) if not quick else _sequence("07", QUICK_FRAMES)
    from slamlib.kitti import KittiOdometrySequence

    short = KittiOdometrySequence(
        first.basedir, first.sequence, frames=range(a, min(b, len(first)))
    )
    no_revisit = run_drive(short, SLAM3DConfig(), progress=False, loop_closure=True)
    return {
        "seed": 0,
        "kiss_slam_version": version("kiss-slam"),
        "map_closures_version": version("map-closures"),
        "gtsam_version": version("gtsam"),
        "numba_threads": int(numba.get_num_threads()),
        "routes": routes,
        "no_revisit": {
            "route": "07",
            "frames": [a, len(short)],
            "closures": len(no_revisit.loop_closer.closures),
            "kept": int(sum(c.kept for c in no_revisit.loop_closer.closures)),
        },
    }
