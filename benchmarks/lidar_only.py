"""``slamlib bench lidar_only``: LIDAR-only slamlib beside KISS-ICP on synthetic KITTI odometry sequences (issue 12).

Workload: synthetic sequences in the KITTI odometry layout (:func:`slamlib.synth.write_sequence`: no IMU, scans
cast from one pose each, ground truth ``poses/NN.txt``) along the **whole** real routes of KITTI odometry 07, 05
and 00 (1,101, 2,761 and 4,541 frames; ~0.7, 2.2 and 3.7 km), seed 0, generated once into
:func:`slamlib.paths.cache_dir` (~1.6 GB per 1,000 frames). ``--quick``: the first 150 frames of 07, one filter seed.

Both methods run on the same frames, one after the other in one process, LIDAR only:

* slamlib: :class:`~slamlib.slam3d.SLAM3DConfig` defaults; without an IMU the filter is LIDAR-only (constant
  velocity, :mod:`slamlib.slam3d.pipeline`), and each frame's best pose is scan-matched (``ScanMatchConfig.scan_match``
  None: on LIDAR-only; :mod:`slamlib.slam3d.match`). Run once per filter seed of :data:`FILTER_SEEDS` (the particle
  filter is random: on route 05, filter seeds 0 to 3 gave KITTI errors from 0.105 to 0.152 %), each route's row the
  median of the seeds' (each seed's row kept beside it);
* KISS-ICP (:func:`slamlib.peers.kiss_icp_poses`, its default configuration, de-skewing off: the synthetic scans
  are cast from one pose).

Reported per route and method: the KITTI translational error (%, segments of 100..800 m), ATE RMSE (m), frames/s
(``1 / median`` of the per-frame registration times), and slamlib's error over KISS-ICP's. Issue 12 asks for at
most 1 % and at most 1.25x KISS-ICP's on every route; issue 33 for twice KISS-ICP's frames/s.
"""

from __future__ import annotations

import numpy as np

HELP = "LIDAR-only slamlib vs KISS-ICP on synthetic KITTI odometry sequences along the whole 07, 05, 00 routes"

ROUTES = ("07", "05", "00")
QUICK_FRAMES = (0, 150)
#: The synthetic sequences' seed (the world, the sensor noise).
SEED = 0
#: The particle filter's seeds (``SLAM3DConfig.seed``): the benchmark's one seed before, and the next two.
FILTER_SEEDS = (0, 1, 2)


def _sequence(route: str, frames):
    """The cached synthetic odometry sequence of ``route`` (:func:`slamlib.synth.write_sequence`), written once."""
    import hashlib
    import json

    from slamlib.kitti import KittiOdometrySequence
    from slamlib.paths import cache_dir
    from slamlib.synth import GENERATOR_VERSION, write_sequence
    from slamlib.synth.writer import read_marker

    key = hashlib.sha1(
        json.dumps([GENERATOR_VERSION, route, frames, SEED]).encode()
    ).hexdigest()[:12]
    base = cache_dir() / "synth" / f"odometry-{key}"
    marker = read_marker(base / "sequences" / route)
    if marker is None or marker.get("version") != GENERATOR_VERSION:
        write_sequence(base, route, route, frames=frames, seed=SEED, progress=True)
    return KittiOdometrySequence(base, route)


def _row(poses, seconds, gt) -> dict:
    from slamlib.metrics import trajectory_metrics

    m = trajectory_metrics(poses, gt)
    return {
        "kitti_t_err_percent": round(
            float(m.get("kitti_t_err_percent", float("nan"))), 4
        ),
        "ate_rmse_m": round(float(m["ate_rmse_m"]), 4),
        "fps_median": round(float(1.0 / np.median(seconds[1:])), 2),
        # frames over their summed time: a back end's occasional heavy frames count here, not in the median
        "fps_mean": round(float(len(seconds[1:]) / np.sum(seconds[1:])), 2),
    }


def _median_row(rows: dict) -> dict:
    """Each entry's median over the seeds' rows."""
    first = next(iter(rows.values()))
    return {k: round(float(np.median([r[k] for r in rows.values()])), 4) for k in first}


def run(quick: bool = False) -> dict:
    from importlib.metadata import version

    import numba

    from slamlib.metrics import trajectory_distances
    from slamlib.peers import kiss_icp_poses
    from slamlib.slam3d import SLAM3DConfig, run_drive

    routes = {}
    seeds = FILTER_SEEDS[:1] if quick else FILTER_SEEDS
    for route in ("07",) if quick else ROUTES:
        seq = _sequence(route, QUICK_FRAMES if quick else (0, None))
        gt = seq.ground_truth_poses()
        per_seed = {}
        for seed in seeds:
            slam = run_drive(
                seq,
                SLAM3DConfig.of(seed=seed),
                progress=True,
                desc=f"slamlib {route} seed {seed}",
            )
            per_seed[str(seed)] = _row(slam.poses, slam.frame_seconds, gt)
        kiss, kiss_seconds = kiss_icp_poses(seq)
        row = {
            "frames": len(seq),
            "path_length_m": round(float(trajectory_distances(gt)[-1]), 1),
            "slamlib": _median_row(per_seed),
            "slamlib_per_seed": per_seed,
            "kiss_icp": _row(kiss, kiss_seconds, gt),
        }
        row["t_err_ratio_slamlib_over_kiss"] = round(
            row["slamlib"]["kitti_t_err_percent"]
            / row["kiss_icp"]["kitti_t_err_percent"],
            3,
        )
        routes[route] = row
        print(route, row, flush=True)
    return {
        "seed": SEED,
        "filter_seeds": list(seeds),
        "kiss_icp_version": version("kiss-icp"),
        "numba_threads": int(numba.get_num_threads()),
        "config": SLAM3DConfig().as_dict(),
        "routes": routes,
    }
