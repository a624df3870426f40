"""``slamlib bench loops``: slamlib with loop closure beside KISS-SLAM on whole realistic synthetic drives.

Workload: synthetic KITTI raw drives along the **whole** real routes of KITTI odometry 07, 05 and 00 (1,101, 2,761
and 4,541 frames) with all realism on, as ``slamlib sweep --distortion --traffic --bias-walk`` writes them (scans
swept column by column, KITTI-city traffic, wandering IMU biases; :class:`slamlib.experiments.sweep.DriveOptions`),
scene seeds :data:`SEEDS`, named in this module before the benchmark first ran and never used for development
(loop closure was developed on route 07, seeds 0-2). Drives are written once into slamlib's cache.
``--quick``: the first 150 frames of 07, the first seed.

On the same frames, one after the other in one process:

* slamlib, its defaults (IMU + LIDAR, de-skewing the swept scans), with ``run_drive(..., loop_closure=True)``
  (:mod:`slamlib.loops`): the filter's own poses (``slamlib``) and the re-anchored ones
  (``slamlib_loop_closure``), one run (the back end's work is inside each frame's timing, so both rows carry the
  same frames/s);
* KISS-SLAM 0.0.2 (:func:`slamlib.peers.kiss_slam_poses`, its default configuration with de-skewing on, its poses
  moved to the frames' pose times as ``slamlib sweep`` does).

Reported per drive and method: KITTI translational error (%), ATE RMSE (m), frames/s as ``1 / median`` of the
per-frame times and as frames over their sum (``fps_mean``: the back ends' occasional heavy frames count there);
slamlib's closures, kept or not, how each was proposed, and its relative pose's error against the ground truth
(m, degrees); KISS-SLAM's accepted closures. Beside them, ``no_revisit``: the first 300 frames of 07, where the
route never comes back, and the closures slamlib accepted there (none, issue 31 asks), per seed.
"""

from __future__ import annotations

import numpy as np

HELP = "slamlib with loop closure vs KISS-SLAM on whole realistic synthetic 07, 05, 00, 2 seeds"

ROUTES = ("07", "05", "00")
#: Scene seeds of the committed run, named before it (fresh: never run in development).
SEEDS = (41, 42)
QUICK_FRAMES = (0, 150)
NO_REVISIT_FRAMES = (0, 300)


def _drive(route: str, seed: int, frames, select=None):
    """The realistic raw drive of ``route`` and ``seed`` over ``frames`` (a ``(first, end)`` of the route),
    written once into slamlib's cache; ``select``: a range of its frames to read (all when ``None``)."""
    from slamlib.experiments.sweep import DriveOptions, SweepTask, drive_task
    from slamlib.kitti import KittiRawDrive
    from slamlib.paths import cache_dir

    realistic = DriveOptions(distortion=True, traffic=1.0, bias_walk=True)
    task = SweepTask(route, tuple(frames), seed, "raw", "slamlib", {}, realistic)
    base = drive_task(task, cache_dir() / "synth")
    return KittiRawDrive(base, "2011_09_26", 1, frames=select)


def _closure_rows(run, gt) -> list:
    """Each slamlib closure: local maps, frames, kept, proposed by, and its relative pose's error against the
    truth."""
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
                "proposed_by": c.proposed_by,
                "fitness": round(c.fitness, 3),
                "error_m": round(float(np.linalg.norm(err[:3, 3])), 4),
                "error_deg": round(float(angle), 4),
            }
        )
    return rows


def run(quick: bool = False) -> dict:
    from importlib.metadata import version

    import numba

    from benchmarks.lidar_only import _row
    from slamlib.metrics import trajectory_distances
    from slamlib.peers import kiss_slam_poses
    from slamlib.slam3d import SLAM3DConfig, run_drive

    frames = QUICK_FRAMES if quick else (0, None)
    drives, no_revisit = [], []
    for seed in SEEDS[:1] if quick else SEEDS:
        for route in ("07",) if quick else ROUTES:
            drive = _drive(route, seed, frames)
            slam = run_drive(
                drive,
                SLAM3DConfig(seed=seed),
                progress=True,
                desc=f"slamlib {route} seed {seed}",
                loop_closure=True,
            )
            kiss, kiss_seconds, kiss_closures = kiss_slam_poses(
                drive, deskew=True, pose_times=True
            )
            gt = slam.ground_truth  # the IMU's, from the first frame's
            row = {
                "route": route,
                "seed": seed,
                "frames": len(drive),
                "path_length_m": round(float(trajectory_distances(gt)[-1]), 1),
                "slamlib": _row(slam.poses, slam.frame_seconds, gt),
                "slamlib_loop_closure": _row(slam.loop_closed, slam.frame_seconds, gt),
                "kiss_slam": _row(kiss, kiss_seconds, gt),
                "local_maps": len(slam.loop_closer.mapper.maps),
                "closures": _closure_rows(slam, gt),
                "kiss_slam_closures": len(kiss_closures),
            }
            drives.append(row)
            print(route, seed, row, flush=True)
        # the first frames of 07 never come back: a closure there is false
        a, b = NO_REVISIT_FRAMES
        whole = _drive("07", seed, frames)
        short = _drive("07", seed, frames, range(a, min(b, len(whole))))
        closer = run_drive(
            short, SLAM3DConfig(seed=seed), progress=False, loop_closure=True
        ).loop_closer
        no_revisit.append(
            {
                "route": "07",
                "seed": seed,
                "frames": [a, len(short)],
                "closures": len(closer.closures),
                "kept": int(sum(c.kept for c in closer.closures)),
            }
        )
    return {
        "seeds": list(SEEDS[:1] if quick else SEEDS),
        "realism": "distortion, traffic x1, bias walk",
        "kiss_slam_version": version("kiss-slam"),
        "map_closures_version": version("map-closures"),
        "gtsam_version": version("gtsam"),
        "numba_threads": int(numba.get_num_threads()),
        "drives": drives,
        "no_revisit": no_revisit,
    }
