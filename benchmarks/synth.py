"""``slamlib bench synth``: speed of the synthetic drive generator (:mod:`slamlib.synth`).

Workload: route 07 (KITTI odometry key frames ``0:FRAMES``, ``0:QUICK_FRAMES`` with ``--quick``), the
full-resolution HDL-64E model (``Hdl64()``: 64 beams x 2000 columns, ~105,000 points per scan), the default seed.

Reported:

* ``scene``: building the town around the route (:func:`~slamlib.synth.build_scene`) and its open3d
  ``RaycastingScene`` (BVH build), median of a few runs, and the scene's triangle count;
* ``scan``: ray casting one scan (:func:`~slamlib.synth.simulate_scan`: cast every ray, noise, dropouts,
  reflectance), median over scans from poses spread along the route (each repeat takes the next pose), and
  points per scan (mean, min, max over those scans);
* ``drive``: wall time of one :func:`~slamlib.synth.write_drive` of the whole route into a temporary folder
  (everything: OXTS, scene, every scan, files), per frame and in frames/s, and the bytes written.

open3d ray casting uses every core (``threads`` reports what the machine has).
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np

HELP = "synthetic drive generator: scene build, one full HDL-64E scan ray cast, writing a 100-frame drive"

ROUTE = "07"
FRAMES = 100
QUICK_FRAMES = 10


def _folder_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in Path(path).rglob("*") if p.is_file())


def run(quick: bool = False) -> dict:
    import open3d as o3d

    from benchmarks import median_time
    from slamlib.geometry import invert_pose
    from slamlib.kitti.calib import load_T_velo_imu
    from slamlib.paths import kitti_sample_dir
    from slamlib.synth import (
        Hdl64,
        build_scene,
        ray_directions,
        resolve_route,
        simulate_scan,
        write_drive,
    )
    from slamlib.synth.writer import SCAN_PERIOD

    n_frames = QUICK_FRAMES if quick else FRAMES
    repeat = 3 if quick else 7
    lidar = Hdl64()
    route, n = resolve_route(ROUTE, (0, n_frames))
    t = route.t0 + SCAN_PERIOD * np.arange(n)
    # as write_drive samples the route
    dense_t = np.linspace(t[0], t[-1], max(2, int((t[-1] - t[0]) * 20) + 2))
    positions = route.position(dense_t)

    def make_scene():
        s = build_scene(positions, seed=0)
        return s, s.raycasting_scene()

    scene, rc = make_scene()
    scene_time = median_time(make_scene, repeat=3 if quick else 5)
    print(
        f"scene: {scene.n_triangles:,} triangles, build + BVH {scene_time['median_s'] * 1e3:.0f} ms"
    )

    T_velo_imu = load_T_velo_imu(kitti_sample_dir() / "raw" / "2011_09_26")
    T_w_velo = route.pose(t) @ invert_pose(T_velo_imu)
    dirs = ray_directions(lidar)
    rng = np.random.default_rng(0)
    counts = []
    poses = iter(np.linspace(0, n - 1, repeat + 1).round().astype(int).tolist())

    def one_scan():
        k = next(poses, n // 2)
        counts.append(len(simulate_scan(rc, scene.albedo, T_w_velo[k], rng, lidar, dirs)))

    scan_time = median_time(one_scan, repeat=repeat)
    scan_counts = counts[1:]  # the warm-up scan is not timed
    print(
        f"one scan: {len(dirs):,} rays -> {np.mean(scan_counts):,.0f} points, {scan_time['median_s'] * 1e3:.0f} ms"
    )

    with tempfile.TemporaryDirectory(prefix="slamlib-bench-synth-") as tmp:
        t0 = time.perf_counter()
        write_drive(tmp, ROUTE, frames=(0, n_frames), seed=0, lidar=lidar, progress=False)
        drive_s = time.perf_counter() - t0
        written = _folder_bytes(Path(tmp))
    print(
        f"drive: {n} frames in {drive_s:.1f} s ({n / drive_s:.1f} frames/s), {written / 1e6:.0f} MB"
    )

    return {
        "route": ROUTE,
        "frames": int(n),
        "columns": lidar.columns,
        "beams": 64 // lidar.beam_stride,
        "rays_per_scan": int(len(dirs)),
        "threads": os.cpu_count(),
        "open3d": o3d.__version__,
        "scene": {**scene_time, "triangles": int(scene.n_triangles)},
        "scan": {
            **scan_time,
            "points_mean": float(np.mean(scan_counts)),
            "points_min": int(np.min(scan_counts)),
            "points_max": int(np.max(scan_counts)),
            "points_per_s": float(np.mean(scan_counts) / scan_time["median_s"]),
        },
        "drive": {
            "seconds": float(drive_s),
            "per_frame_s": float(drive_s / n),
            "frames_per_s": float(n / drive_s),
            "bytes": int(written),
            "runs": 1,
        },
    }
