"""``slamlib bench slam3d``: frames/s and accuracy of the 3D particle SLAM on the still default synthetic drive.

Workload: the still default synthetic drive (:func:`slamlib.synth.default_drive` with ``realism=False``: no sweep
distortion, traffic or bias walk, so that the timings stay comparable with the committed history; KITTI 07 route,
~100,000-point HDL-64E scans), frames ``FRAMES`` (``QUICK_FRAMES`` with ``--quick``), default :class:`SLAM3DConfig`
except the number of particles (100, 300, 1000) and the map kind (``voxel_hash``, ``morton_bvh``), Numba CPU
backend. Each configuration runs once after a short untimed warm-up (JIT caches, page cache).

Reported per configuration:

* ``fps``: frames / wall-clock seconds of the whole loop, **including** reading and validating each frame's
  files (scan + OXTS), as ``slamlib run`` experiences it;
* ``fps_median``: ``1 / median`` of the per-frame ``register_frame`` times (steps 2-11, no file reading): robust
  to other processes' bursts on a shared machine;
* ``ate_rmse_m`` of SLAM and of dead reckoning from the same IMU data, their ratio, and the KITTI translational
  error (%) when the range is over 100 m.

``long``: the default configuration over the whole synthetic route (``default_drive(full=True, realism=False)``,
~1,100 frames, ~690 m, generated on first use), for the KITTI metric on a drive of more than 500 m (skipped with
``--quick``).
"""

from __future__ import annotations

import numpy as np

HELP = (
    "3D particle SLAM on the default synthetic drive: frames/s for 100/300/1000 particles"
    " x voxel_hash/morton_bvh, ATE"
)

FRAMES = (0, 300)
QUICK_FRAMES = (0, 40)
PARTICLES = (100, 300, 1000)
QUICK_PARTICLES = (100, 300)
MAPS = ("voxel_hash", "morton_bvh")  # slamlib.slam3d.MAP_KINDS


def run(quick: bool = False) -> dict:
    import numba

    from slamlib.kitti import KittiRawDrive
    from slamlib.slam3d import SLAM3DConfig, evaluate, run_drive
    from slamlib.synth import default_drive

    basedir, date, drive_id = default_drive(progress=False, realism=False)
    a, b = QUICK_FRAMES if quick else FRAMES
    drive = KittiRawDrive(basedir, date, drive_id, frames=range(a, b))
    warm = KittiRawDrive(basedir, date, drive_id, frames=range(0, 5))
    rows = []
    for kind in MAPS:
        # JIT / cache warm-up
        run_drive(warm, SLAM3DConfig.of(kind=kind, particles=50), progress=False)
        for P in QUICK_PARTICLES if quick else PARTICLES:
            cfg = SLAM3DConfig.of(particles=P, kind=kind)
            r = run_drive(drive, cfg, progress=False)
            m = evaluate(r)
            row = {
                "map": kind,
                "particles": P,
                "points": cfg.filter.scored_points,
                "frames": m["frames"],
                "fps": round(r.fps, 2),
                "fps_median": round(float(1.0 / np.median(r.frame_seconds[1:])), 2),
                "ate_rmse_m": round(m["slam"]["ate_rmse_m"], 4),
                "dead_reckoning_ate_rmse_m": round(m["dead_reckoning"]["ate_rmse_m"], 4),
            }
            row["ate_ratio_dr_over_slam"] = round(
                row["dead_reckoning_ate_rmse_m"] / row["ate_rmse_m"], 1
            )
            if "kitti_t_err_percent" in m["slam"]:
                row["kitti_t_err_percent"] = round(m["slam"]["kitti_t_err_percent"], 3)
                row["dead_reckoning_kitti_t_err_percent"] = round(
                    m["dead_reckoning"]["kitti_t_err_percent"], 3
                )
            rows.append(row)
            print(row, flush=True)
    long = None if quick else _long_run()
    return {
        "long": long,
        "workload": {
            "drive": "slamlib.synth.default_drive(realism=False)",
            "frames": [a, b],
            "path_length_m": round(m["path_length_m"], 1),
            "backend": "cpu",
            "numba_threads": int(numba.get_num_threads()),
            # the rows change filter.particles and map.kind
            "config": SLAM3DConfig().as_dict(),
        },
        "results": rows,
    }


def _long_run() -> dict:
    """The default configuration over the whole synthetic route: accuracy on a drive of more than 500 m."""
    from slamlib.kitti import KittiRawDrive
    from slamlib.slam3d import SLAM3DConfig, evaluate, run_drive
    from slamlib.synth import default_drive

    drive = KittiRawDrive(*default_drive(full=True, progress=False, realism=False))
    cfg = SLAM3DConfig()
    r = run_drive(drive, cfg, progress=False)
    m = evaluate(r)
    out = {
        "drive": "slamlib.synth.default_drive(full=True, realism=False)",
        "frames": m["frames"],
        "path_length_m": round(m["path_length_m"], 1),
        "particles": cfg.filter.particle_count(),
        "map": cfg.map.kind,
        "fps": round(r.fps, 2),
        "fps_median": round(float(1.0 / np.median(r.frame_seconds[1:])), 2),
    }
    for key in ("slam", "dead_reckoning"):
        out[key] = {
            k: round(float(v), 5)
            for k, v in m[key].items()
            if isinstance(v, (int, float))
        }
    print({"long": out}, flush=True)
    return out
