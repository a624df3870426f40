"""``slamlib bench scaling``: how the cost of the 3D particle SLAM grows, with fitted slopes.

Three sweeps over the still default synthetic drive (:func:`slamlib.synth.default_drive` with
``realism=False``), default :class:`slamlib.slam3d.SLAM3DConfig` (hashed NDT voxel map, Numba CPU backend) except
the swept setting:

* ``particles``: frames ``SWEEP_FRAMES`` for ``P`` in :data:`PARTICLES` (100 ... 3000);
* ``points``: the same frames for ``scored_points`` ``N`` in :data:`POINTS` (points per particle in step 8);
* ``route``: the whole route (``default_drive(full=True, realism=False)``, ~1,100 frames, ~690 m) with the default
  settings, per-frame ``register_frame`` times and the map's size every :data:`ROUTE_SNAPSHOT_EVERY` frames: is the time
  per frame flat while the map grows?

Per configuration: ``frame_ms_median`` (the median of the per-frame ``register_frame`` times, steps 2-11 without
file reading: robust to other processes on a shared machine), ``frame_ms_best``, ``fps`` (frames / wall clock of
the whole loop, file reading included) and the ATE. Fits, by least squares on the medians:

* ``frame_ms = a + b * P`` and ``frame_ms = a + b * N``: a fixed cost per frame (reading, preprocessing, merging
  the scan) plus a cost per particle (steps 5-9 and 11) or per scored point;
* along the route, ``frame_ms = a + b * k`` over frame index ``k`` (``b`` in ms per 100 frames) and the map's
  element count at each snapshot. A slope near zero means a frame costs the same at the end of the drive as at
  its start: the voxel map's lookups are O(1) and the map is pruned around the vehicle.

Each sweep runs after an untimed warm-up (JIT caches, page cache). ``--quick``: a few frames and two values per
sweep, the route replaced by the first ``QUICK_FRAMES`` frames of the default drive.
"""

from __future__ import annotations

import numpy as np

HELP = "3D SLAM cost growth: ms/frame vs particles (100..3000), vs scored points, and along the whole route"

SWEEP_FRAMES = (0, 150)
QUICK_FRAMES = (0, 20)
PARTICLES = (100, 300, 1000, 3000)
QUICK_PARTICLES = (100, 300)
POINTS = (250, 500, 1000, 2000, 4000)
QUICK_POINTS = (500, 1000)
#: Frames between two readings of the map's size along the route.
ROUTE_SNAPSHOT_EVERY = 50
#: Frames at the start of a run left out of the fits (the first frame has no map to score against).
SKIP_FRAMES = 1


def _fit(x, y) -> dict:
    """Least-squares line ``y = intercept + slope * x``, with the coefficient of determination ``r2``."""
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    slope, intercept = np.polyfit(x, y, 1)
    resid = y - (intercept + slope * x)
    total = np.sum((y - y.mean()) ** 2)
    return {
        "intercept": float(intercept),
        "slope": float(slope),
        "r2": float(1.0 - np.sum(resid**2) / total) if total > 0 else 1.0,
    }


def _row(run, evaluate, **settings) -> dict:
    ms = run.frame_seconds[SKIP_FRAMES:] * 1e3
    m = evaluate(run)
    row = dict(settings)
    row.update(
        frames=int(len(run.poses)),
        frame_ms_median=round(float(np.median(ms)), 3),
        frame_ms_best=round(float(ms.min()), 3),
        fps=round(run.fps, 2),
        ate_rmse_m=round(float(m["slam"]["ate_rmse_m"]), 4),
    )
    print(row, flush=True)
    return row


def run(quick: bool = False) -> dict:
    import os

    import numba

    from slamlib.kitti import KittiRawDrive
    from slamlib.slam3d import SLAM3DConfig, evaluate, run_drive
    from slamlib.synth import default_drive

    load_before = os.getloadavg()[0]
    basedir, date, drive_id = default_drive(progress=False, realism=False)
    a, b = QUICK_FRAMES if quick else SWEEP_FRAMES
    drive = KittiRawDrive(basedir, date, drive_id, frames=range(a, b))
    warm = KittiRawDrive(basedir, date, drive_id, frames=range(0, 5))
    run_drive(warm, SLAM3DConfig.of(particles=50), progress=False)  # JIT / cache warm-up
    default = SLAM3DConfig()

    particles = [
        _row(
            run_drive(drive, SLAM3DConfig.of(particles=P), progress=False),
            evaluate,
            particles=P,
            points=default.filter.scored_points,
        )
        for P in (QUICK_PARTICLES if quick else PARTICLES)
    ]
    points = [
        _row(
            run_drive(drive, SLAM3DConfig.of(scored_points=N), progress=False),
            evaluate,
            particles=default.filter.particle_count(),
            points=N,
        )
        for N in (QUICK_POINTS if quick else POINTS)
    ]

    route_drive = (
        drive
        if quick
        else KittiRawDrive(*default_drive(full=True, progress=False, realism=False))
    )
    r = run_drive(
        route_drive, default, progress=False, snapshot_every=ROUTE_SNAPSHOT_EVERY
    )
    ms = r.frame_seconds * 1e3
    k = np.arange(len(ms))
    snaps = [(int(pos), int(len(pts))) for pos, pts, _ in r.snapshots]
    m = evaluate(r)
    route = {
        "drive": (
            "slamlib.synth.default_drive(realism=False)"
            if quick
            else "slamlib.synth.default_drive(full=True, realism=False)"
        ),
        "frames": int(len(ms)),
        "path_length_m": round(float(m["path_length_m"]), 1),
        "particles": default.filter.particle_count(),
        "points": default.filter.scored_points,
        "map": default.map.kind,
        "fps": round(r.fps, 2),
        "ate_rmse_m": round(float(m["slam"]["ate_rmse_m"]), 4),
        "frame_ms": [round(float(x), 3) for x in ms],
        "map_elements": snaps,  # (frame position, map elements after it)
        "fit_frame_ms_vs_frame": _fit(k[SKIP_FRAMES:], ms[SKIP_FRAMES:]),
        "first_tenth_ms_median": round(
            float(np.median(ms[SKIP_FRAMES : max(SKIP_FRAMES + 1, len(ms) // 10)])), 3
        ),
        "last_tenth_ms_median": round(float(np.median(ms[-max(1, len(ms) // 10) :])), 3),
    }
    print({k_: v for k_, v in route.items() if k_ != "frame_ms"}, flush=True)
    return {
        "workload": {
            "drive": "slamlib.synth.default_drive(realism=False)",
            "frames": [a, b],
            "backend": default.backend,
            "numba_threads": int(numba.get_num_threads()),
            "config": default.as_dict(),
        },
        "particles": particles,
        "fit_ms_vs_particles": _fit(
            [r_["particles"] for r_ in particles],
            [r_["frame_ms_median"] for r_ in particles],
        ),
        "points": points,
        "fit_ms_vs_points": _fit(
            [r_["points"] for r_ in points], [r_["frame_ms_median"] for r_ in points]
        ),
        "route": route,
        # other jobs on the machine slow every row: the 1-minute load average before and after the run
        "load_average_1min": {"start": load_before, "end": os.getloadavg()[0]},
    }
