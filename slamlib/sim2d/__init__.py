"""Particle SLAM in the plane: walls and pillars, wheel odometry and a scanning LIDAR, the twelve steps in 2D.

* :mod:`slamlib.sim2d.world`: :func:`make_world`, :class:`Route2D`, :class:`SensorModel2D`, :func:`cast_rays`,
  :func:`simulate` -> :class:`Recording2D` of :class:`Frame2D` objects.
* :mod:`slamlib.sim2d.steps`: the eleven step functions under the contract of :mod:`slamlib.contract`
  (particles ``(P, 3)`` poses ``(x, y, theta)``) and the map :class:`OccupancyGrid2D` with two scoring rules,
  the seed's density grid and the likelihood field.
* :mod:`slamlib.sim2d.particle_maps`: :class:`ParticleMaps2D`, one map per particle in shared
  copy-on-write tiles (Rao-Blackwellised particle SLAM).
* :mod:`slamlib.sim2d.filter`: :class:`ParticleSLAM2D` (``step(frame)`` is the twelve steps, one shared map),
  :class:`ParticleMapsSLAM2D` (the same steps, a map per particle) and :func:`run_slam_2d` ->
  :class:`SLAM2DResult`.
* :mod:`slamlib.sim2d.plot`: figures and the animation of the book's chapter (imports matplotlib when called).

Example::

    from slamlib.sim2d import make_world, simulate, run_slam_2d
    rec = simulate(make_world(seed=0), seed=0)
    result = run_slam_2d(rec, n_particles=200, seed=0)
    print(result.summary())
"""

from slamlib.sim2d.filter import (
    ParticleMapsSLAM2D,
    ParticleSLAM2D,
    SLAM2DResult,
    StepInfo2D,
    dead_reckon_2d,
    default_motion_noise,
    position_rmse,
    run_slam_2d,
)
from slamlib.sim2d.particle_maps import ParticleMaps2D
from slamlib.sim2d.steps import (
    MAP_KINDS,
    OccupancyGrid2D,
    initialise_particles,
    merge_scan,
    offset_by_motion,
    perturb_with_noise,
    pick_best_particle,
    read_imu,
    read_scan,
    read_timing,
    resample_particles,
    score_particles,
    transform_scan,
)
from slamlib.sim2d.world import (
    Frame2D,
    Recording2D,
    Route2D,
    SensorModel2D,
    World2D,
    cast_rays,
    integrate_arc,
    make_world,
    scan_at,
    simulate,
    wrap_angle,
)

__all__ = [
    "Frame2D",
    "MAP_KINDS",
    "OccupancyGrid2D",
    "ParticleMaps2D",
    "ParticleMapsSLAM2D",
    "ParticleSLAM2D",
    "Recording2D",
    "Route2D",
    "SLAM2DResult",
    "SensorModel2D",
    "StepInfo2D",
    "World2D",
    "cast_rays",
    "dead_reckon_2d",
    "default_motion_noise",
    "initialise_particles",
    "integrate_arc",
    "make_world",
    "merge_scan",
    "offset_by_motion",
    "perturb_with_noise",
    "pick_best_particle",
    "position_rmse",
    "read_imu",
    "read_scan",
    "read_timing",
    "resample_particles",
    "run_slam_2d",
    "scan_at",
    "score_particles",
    "simulate",
    "transform_scan",
    "wrap_angle",
]
