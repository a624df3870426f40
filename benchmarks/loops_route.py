"""``slamlib bench loops_route``: one drive of ``slamlib bench loops`` kept whole, for chapter 10's figures.

Workload: route :data:`ROUTE` at seed :data:`SEED`, the realistic raw drive of :mod:`benchmarks.loops` (cached), run
as that benchmark runs it: slamlib's defaults with ``loop_closure=True``, and KISS-SLAM 0.0.2 on the same frames.
slamlib is deterministic at a given seed, so its errors here equal that drive's row in ``loops.json`` (a test checks
it).

Reported: every :data:`STRIDE`-th frame's position (m, the first frame's IMU frame) of the ground truth, the filter,
the filter with loop closure and KISS-SLAM, with the distance driven; the closures (frames they join, kept); and,
for the maps before and after, the points (x, y, z, m) of the local maps that the first kept closure joins,
thinned to one per :data:`MAP_VOXEL` metres and within :data:`MAP_RADIUS` metres (horizontally) of the reference
key pose, placed by the filter's key poses and by the optimised ones. ``--quick``: the first 150 frames (no loop).
"""

from __future__ import annotations

import numpy as np

HELP = "one loops drive kept whole (07, seed 41): trajectories, closures and maps for chapter 10's figures"

ROUTE, SEED = "07", 41
#: Every this many frames are kept.
STRIDE = 2
#: The maps' points: one per this many metres ...
MAP_VOXEL = 2.0
#: ... within this many metres of the closure's reference key pose.
MAP_RADIUS = 30.0


def _xyz(poses) -> list:
    return np.round(np.asarray(poses)[::STRIDE, :3, 3], 2).tolist()


def _map_points(closer, node: int, key_pose) -> np.ndarray:
    from slamlib.geometry import transform_points
    from slamlib.loops import voxel_down_sample

    m = closer.mapper.maps[node]
    return voxel_down_sample(transform_points(key_pose, m.points), MAP_VOXEL)


def run(quick: bool = False) -> dict:
    from benchmarks.lidar_only import _row
    from benchmarks.loops import QUICK_FRAMES, _drive
    from slamlib.metrics import trajectory_distances
    from slamlib.peers import kiss_slam_poses
    from slamlib.slam3d import SLAM3DConfig, run_drive

    drive = _drive(ROUTE, SEED, QUICK_FRAMES if quick else (0, None))
    slam = run_drive(drive, SLAM3DConfig(seed=SEED), progress=True, loop_closure=True)
    gt = slam.ground_truth  # the IMU's, from the first frame's
    kiss = kiss_slam_poses(drive, deskew=True, pose_times=True)
    closer = slam.loop_closer
    closures = [
        {
            "query_frame": c.query_frame,
            "reference_frame": c.reference_frame,
            "kept": c.kept,
        }
        for c in closer.closures
    ]
    maps = None
    kept = [c for c in closer.closures if c.kept]
    if kept:
        c = kept[0]
        centre = closer.graph.poses[c.reference][:3, 3]
        maps = {"query": c.query, "reference": c.reference}
        for name, key in (
            ("before", lambda n: closer.mapper.maps[n].key_pose),
            ("after", lambda n: closer.graph.poses[n]),
        ):
            for role, node in (("reference", c.reference), ("query", c.query)):
                p = _map_points(closer, node, key(node))
                near = np.linalg.norm(p[:, :2] - centre[:2], axis=1) <= MAP_RADIUS
                maps[f"{role}_{name}"] = np.round(p[near], 2).tolist()
    return {
        "route": ROUTE,
        "seed": SEED,
        "frames": len(drive),
        "stride": STRIDE,
        "slamlib": _row(slam.poses, slam.frame_seconds, gt),
        "slamlib_loop_closure": _row(slam.loop_closed, slam.frame_seconds, gt),
        "kiss_slam": _row(kiss[0], kiss[1], gt),
        "distance_m": np.round(trajectory_distances(gt)[::STRIDE], 2).tolist(),
        "positions": {
            "ground_truth": _xyz(gt),
            "slamlib": _xyz(slam.poses),
            "slamlib_loop_closure": _xyz(slam.loop_closed),
            "kiss_slam": _xyz(kiss[0]),
        },
        "closures": closures,
        "maps": maps,
    }
