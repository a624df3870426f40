"""Particle SLAM in one dimension: a simulated world and sensors, and the twelve steps on a line.

* :mod:`slamlib.sim1d.world`: :func:`make_world`, :class:`VelocityProfile`, :class:`SensorModel1D`,
  :func:`simulate` -> :class:`Recording1D` of :class:`Frame` objects.
* :mod:`slamlib.sim1d.steps`: one pure function per step, keeping the step contract shared with the 3D filter
  (:mod:`slamlib.contract`: names, leading parameters, results), the :class:`OccupancyGrid1D` map (changed in
  place by step 10), its likelihood field and :func:`extract_landmarks`.
* :mod:`slamlib.sim1d.filter`: :class:`ParticleSLAM1D` (``step(frame)`` is the twelve steps) and
  :func:`run_slam_1d` -> :class:`SLAM1DResult`.
* :mod:`slamlib.sim1d.plot`: figures and the animation used by the book (imports matplotlib when called).

Example::

    from slamlib.sim1d import make_world, simulate, run_slam_1d
    rec = simulate(make_world(seed=0), n_frames=300, seed=0)
    result = run_slam_1d(rec, n_particles=200, seed=0)
    print(result.summary())
"""

from slamlib.sim1d.filter import (
    ParticleSLAM1D,
    SLAM1DResult,
    StepInfo,
    dead_reckon,
    run_slam_1d,
)
from slamlib.sim1d.steps import (
    OccupancyGrid1D,
    extract_landmarks,
    initialise_particles,
    likelihood_field,
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
from slamlib.sim1d.world import (
    Frame,
    Recording1D,
    SensorModel1D,
    VelocityProfile,
    World1D,
    make_world,
    scan_landmarks,
    simulate,
)

__all__ = [
    "Frame",
    "OccupancyGrid1D",
    "ParticleSLAM1D",
    "Recording1D",
    "SLAM1DResult",
    "SensorModel1D",
    "StepInfo",
    "VelocityProfile",
    "World1D",
    "dead_reckon",
    "extract_landmarks",
    "initialise_particles",
    "likelihood_field",
    "make_world",
    "merge_scan",
    "offset_by_motion",
    "perturb_with_noise",
    "pick_best_particle",
    "read_imu",
    "read_scan",
    "read_timing",
    "resample_particles",
    "run_slam_1d",
    "scan_landmarks",
    "score_particles",
    "simulate",
    "transform_scan",
]
