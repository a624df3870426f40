"""3D particle SLAM: the twelve steps on 6-DoF poses with a LIDAR map and an IMU motion model.

Quick start::

    from slamlib.kitti import KittiRawDrive
    from slamlib.slam3d import SLAM3DConfig, run_drive, evaluate
    from slamlib.synth import default_drive
    drive = KittiRawDrive(*default_drive(), frames=range(0, 100))
    run = run_drive(drive, SLAM3DConfig.of(particles=300))
    print(evaluate(run)["slam"]["ate_rmse_m"], run.fps)

Modules: :mod:`~slamlib.slam3d.steps` (one pure function per step, shared names),
:mod:`~slamlib.slam3d.config` (:class:`SLAM3DConfig` and its groups, one per stage, every default once),
:mod:`~slamlib.slam3d.stages` (motion, scan, prior, search, polish, upkeep: each one job, chosen once),
:mod:`~slamlib.slam3d.pipeline` (:class:`ParticleSLAM3D`: ``register_frame``, the steps in order, and ``step``),
:mod:`~slamlib.slam3d.preprocess` (range crop, voxel down-sampling, scoring sample),
:mod:`~slamlib.slam3d.run` (whole drives, metrics). Particles are IMU/body poses ``T_world_body``; the world is
the body pose at the first processed frame.
"""

from slamlib.slam3d.config import (
    MAP_KINDS,
    AnnealConfig,
    ConstantVelocityConfig,
    FilterConfig,
    MapConfig,
    MotionConfig,
    ScanConfig,
    ScanMatchConfig,
    SLAM3DConfig,
    TiltConfig,
    UpkeepConfig,
)
from slamlib.slam3d.pipeline import ParticleSLAM3D
from slamlib.slam3d.preprocess import crop_range, sample_points, voxel_downsample
from slamlib.slam3d.run import SLAMRun, evaluate, parse_frames, run_drive, save_run
from slamlib.slam3d.steps import (
    Particles3D,
    initialise_particles,
    merge_scan,
    motion_increment,
    motion_noise_sigma,
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

__all__ = [
    "ParticleSLAM3D",
    "SLAM3DConfig",
    "ScanConfig",
    "MotionConfig",
    "MapConfig",
    "FilterConfig",
    "ConstantVelocityConfig",
    "UpkeepConfig",
    "TiltConfig",
    "AnnealConfig",
    "ScanMatchConfig",
    "MAP_KINDS",
    "Particles3D",
    "SLAMRun",
    "run_drive",
    "evaluate",
    "save_run",
    "parse_frames",
    "crop_range",
    "voxel_downsample",
    "sample_points",
    "initialise_particles",
    "read_scan",
    "read_imu",
    "read_timing",
    "motion_increment",
    "motion_noise_sigma",
    "offset_by_motion",
    "perturb_with_noise",
    "transform_scan",
    "score_particles",
    "pick_best_particle",
    "merge_scan",
    "resample_particles",
]
