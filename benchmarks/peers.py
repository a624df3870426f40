"""``slamlib bench peers``: KISS-ICP, the LIDAR odometry to beat, beside slamlib's particle SLAM in each mode.

KISS-ICP (Vizzo et al., "KISS-ICP: In Defense of Point-to-Point ICP", RA-L 2023; ``pip install kiss-icp``, MIT
licence) registers each full scan against a local voxel map with point-to-point ICP and an adaptive threshold.
It uses the LIDAR only. slamlib runs in each of its modes (:data:`MODES`): the default (LIDAR + IMU), LIDAR-only
(constant-velocity motion, scan matching on) and the default with loop closure (``slamlib run --loop-closure``: a
:class:`slamlib.loops.LoopCloser` fed every frame inside the frame's timing, its re-anchored poses scored). All of
them run on the same frames, one after the other in one process, and are scored with the same metrics
(:func:`slamlib.metrics.trajectory_metrics`) against the same ground truth, on these drives:

* the **realistic default drive** (``default_drive()``: swept scans, traffic, wandering IMU biases; what
  ``slamlib run`` uses), where KISS-ICP de-skews the swept scans and its poses are moved to the frames' pose times,
  as in ``slamlib sweep``;
* the **realistic whole routes** of :data:`WHOLE_ROUTES` (``default_drive(full=True, route=...)``, the same
  realism), each KITTI odometry sequence's whole length in the raw layout, so that every mode, the IMU's too, runs
  over thousands of frames and several loops;
* the **still** default drive and the **whole route** still (``realism=False``, scans cast from one pose, KISS-ICP
  without de-skewing), the rows of the earlier runs, kept for their history.

KISS-ICP gets the raw Velodyne scan (``x, y, z`` float64, its default configuration); its poses
``P_k = T_{velo_0 <- velo_k}`` become body (IMU) poses ``T_velo_imu^{-1} P_k T_velo_imu`` (KITTI
``calib_imu_to_velo.txt``). slamlib runs :class:`~slamlib.slam3d.SLAM3DConfig` defaults (300 particles, voxel map,
Numba CPU), the mode's settings added.

Reported per drive and method: per-frame time (median, from the registration call alone, file reading excluded),
frames/s of that median, the mean frame time beside it (``frame_ms_mean``, the median of the repeats' means: the
loop closer's work comes in bursts, a local map's registration and the pose graph's optimisation every ~50 m, which
a median does not see), and ATE / RPE / KITTI error. The full run takes each drive ``REPEATS`` times, the methods in
turn (each realistic whole route ``WHOLE_ROUTE_REPEATS`` times), and reports every repeat's medians and, per slamlib
mode, the ratio of KISS-ICP's median to the mode's in each repeat (``speed_ratio_per_repeat``) beside the median of
the repeats. ``--quick``: the first 60 frames of the still drive, once.
"""

from __future__ import annotations

import numpy as np

HELP = "KISS-ICP (LIDAR-only ICP odometry) beside slamlib's particle SLAM on the same drive: time per frame, ATE"

#: Runs of every method on each drive in the full benchmark (their frame-time medians vary between runs).
REPEATS = 3
#: The KITTI odometry routes whose whole length the full benchmark drives with all realism (each drive's frame count
#: and path length are in the result).
WHOLE_ROUTES = ("07", "05", "00")
#: Runs of every method on each whole route: one, its median over thousands of frames (the full benchmark takes
#: about half an hour on two cores as it is).
WHOLE_ROUTE_REPEATS = 1
#: slamlib's modes: the name of its rows, and the settings (:meth:`SLAM3DConfig.of`) added to the defaults. The
#: default mode keeps the name ``slamlib`` of the earlier results.
MODES = {
    "slamlib": {},
    "slamlib_lidar_only": {"model": "constant_velocity"},
    "slamlib_loop_closure": {},
}
#: The modes run with ``run_drive(loop_closure=True)``: their rows score the loop-closed poses.
LOOP_CLOSURE_MODES = ("slamlib_loop_closure",)

INSTALL_HINT = "slamlib bench peers needs KISS-ICP: pip install kiss-icp (or pip install -e '.[peers]')"


def whole_route_name(route: str) -> str:
    """The name of the realistic whole ``route``'s drive in the result's ``drives``."""
    return f"realistic whole route {route} (full=True)"


def _kiss_icp(drive, swept: bool) -> tuple[np.ndarray, np.ndarray]:
    """KISS-ICP over ``drive`` (:func:`slamlib.peers.kiss_icp_poses`; ``swept`` scans de-skewed, the poses moved to
    the frames' pose times, as in ``slamlib sweep``): body poses ``(F, 4, 4)`` and per-frame registration seconds
    ``(F,)``."""
    from slamlib.peers import kiss_icp_poses

    return kiss_icp_poses(drive, drive.T_velo_imu, deskew=swept, pose_times=swept)


def _compare(drive, repeats: int = 1) -> dict:
    """Every slamlib mode and KISS-ICP on ``drive``, ``repeats`` times in turn: per-frame medians of every repeat,
    KISS-ICP's over each mode's per repeat, and the metrics of the first repeat (``repeat_pose_difference_max``: the
    largest difference of any later repeat's pose matrices from the first's). KISS-ICP de-skews the scans when
    slamlib does (:func:`slamlib.slam3d.steps.should_deskew`: scans taken over a sweep)."""
    from slamlib.metrics import trajectory_distances, trajectory_metrics
    from slamlib.slam3d import SLAM3DConfig, run_drive, steps

    swept = steps.should_deskew(drive[0])
    # every scan read once, untimed, so that it is in the page cache: slamlib reads each scan inside its frame's
    # time (step 2), KISS-ICP outside its registration call, and a scan read from disk would cost the first method
    # alone (the whole routes are GBs); the points of every 25th scan for the result
    n_points = [len(drive[k].scan) for k in range(len(drive))][::25]

    methods = (*MODES, "kiss_icp")
    medians = {m: [] for m in methods}
    # the means too: the loop closer's work comes in bursts, which medians hide
    means = {m: [] for m in methods}
    spread = dict.fromkeys(
        methods, 0.0
    )  # largest difference of a repeat's poses from the first's
    first = {}
    for r in range(repeats):
        poses = {}
        for mode, settings in MODES.items():
            closing = mode in LOOP_CLOSURE_MODES
            run = run_drive(
                drive, SLAM3DConfig.of(**settings), progress=False, loop_closure=closing
            )
            poses[mode] = np.asarray(run.loop_closed if closing else run.poses)
            medians[mode].append(float(np.median(run.frame_seconds[1:])))
            means[mode].append(float(np.mean(run.frame_seconds[1:])))
            if mode == "slamlib":
                slam = run  # the default mode's run: the ground truth and dead reckoning
        poses["kiss_icp"], kiss_seconds = _kiss_icp(drive, swept)
        medians["kiss_icp"].append(float(np.median(kiss_seconds[1:])))
        means["kiss_icp"].append(float(np.mean(kiss_seconds[1:])))
        if r == 0:
            first = poses
        # slamlib repeats bit for bit; KISS-ICP's parallel sums may differ in the last bits
        for m in methods:
            spread[m] = max(spread[m], float(np.max(np.abs(poses[m] - first[m]))))
    gt = slam.ground_truth
    rows = {}
    for m in methods:
        median = float(np.median(medians[m]))
        rows[m] = {
            "frame_ms_median": round(median * 1e3, 2),
            "fps_median": round(1.0 / median, 1),
            "frame_ms_median_per_repeat": [round(x * 1e3, 2) for x in medians[m]],
            "frame_ms_mean_per_repeat": [round(x * 1e3, 2) for x in means[m]],
            "frame_ms_mean": round(float(np.median(means[m])) * 1e3, 2),
            "repeat_pose_difference_max": spread[m],
            **{
                k: round(float(v), 5) for k, v in trajectory_metrics(first[m], gt).items()
            },
        }
        if m != "kiss_icp":
            rows[m]["speed_ratio_per_repeat"] = [
                round(k / s, 3) for k, s in zip(medians["kiss_icp"], medians[m])
            ]
    rows["dead_reckoning"] = {
        k: round(float(v), 5)
        for k, v in trajectory_metrics(slam.dead_reckoning, gt).items()
    }
    out = {
        "frames": int(len(gt)),
        "path_length_m": round(float(trajectory_distances(gt)[-1]), 1),
        "scan_points_median": int(np.median(n_points)),
        "swept": bool(swept),
        "repeats": repeats,
        "speed_ratio_per_repeat": rows["slamlib"]["speed_ratio_per_repeat"],
        **rows,
    }
    print(
        {"frames": out["frames"]} | {m: rows[m]["speed_ratio_per_repeat"] for m in MODES},
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
    drives = {}
    if not quick:
        realistic = KittiRawDrive(*default_drive(progress=False))
        drives[f"realistic default drive {DEFAULT_FRAMES}"] = _compare(realistic, repeats)
    drives[f"default drive {DEFAULT_FRAMES}"] = _compare(drive, repeats)
    if not quick:
        whole = default_drive(full=True, progress=False, realism=False)
        drives["whole route (full=True)"] = _compare(KittiRawDrive(*whole), repeats)
        for route in WHOLE_ROUTES:
            source = default_drive(full=True, route=route, progress=False)
            drives[whole_route_name(route)] = _compare(
                KittiRawDrive(*source), WHOLE_ROUTE_REPEATS
            )
    return {
        "modes": MODES,
        "loop_closure_modes": list(LOOP_CLOSURE_MODES),
        "kiss_icp_version": version("kiss-icp"),
        "numba_threads": int(numba.get_num_threads()),
        "drives": drives,
    }
