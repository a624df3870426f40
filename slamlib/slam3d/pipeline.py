"""``ParticleSLAM3D``: the twelve steps as a per-frame method, with its configuration and a dead-reckoning twin.

The filter object is thin state (particles, log-weights, map, previous IMU sample, trajectories) around the pure
step functions of :mod:`slamlib.slam3d.steps`. :meth:`ParticleSLAM3D.register_frame` is step 12, the loop body:
it reads like the list of steps. Particles are poses ``T_world_body`` of the vehicle body = the IMU frame; the
world is the body pose at the first registered frame (see :mod:`slamlib.slam3d.steps`).

Dead reckoning from the same IMU samples (the same :func:`slamlib.odometry.imu_increment` as step 5, without
noise and without the scans) is kept alongside as the baseline: ``slam.dr_poses``.

Likelihood tempering
--------------------
The map score of a particle is a sum over ``N`` scan points of per-point log-likelihoods (:mod:`slamlib.maps.base`)
which treats the points as independent. They are not (neighbouring points see the same surface, the map is
itself built from earlier noisy scans), so the raw sum is far too confident: weights would collapse onto one
particle. The pipeline uses ``log L_i = score_i / (N * temperature)``: the scan counts as ``1 / temperature``
independent points whatever sample size ``N`` is chosen (Grisetti et al. 2007 and most LIDAR particle filters
smooth the observation likelihood the same way).

Coarse to fine (``refine``)
---------------------------
With few particles in 6 dimensions the best of the cloud is still a few centimetres / tenths of a degree from the
likelihood's peak. ``refine = k`` adds ``k`` annealing rounds inside the frame (Deutscher, Blake & Reid, "Articulated
body motion capture by annealed particle filtering", CVPR 2000): resample by the current weights, perturb with the
noise shrunk by ``refine_shrink``, score again. The result is still a particle filter (a sequence of
importance-sampling / resampling stages on the same posterior), just with a sharper proposal.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from slamlib.kernels import get_backend
from slamlib.maps import make_map
from slamlib.slam3d import steps
from slamlib.slam3d.preprocess import sample_points

__all__ = ["SLAM3DConfig", "ParticleSLAM3D", "MAP_NAMES", "make_slam_map"]

#: Names accepted for ``SLAM3DConfig.map_type`` -> :func:`slamlib.maps.make_map` kinds.
MAP_NAMES = {"voxel": "voxel_hash", "bvh": "morton_bvh", "voxel_hash": "voxel_hash", "morton_bvh": "morton_bvh"}


@dataclass
class SLAM3DConfig:
    """Settings of :class:`ParticleSLAM3D` (defaults tuned on the default synthetic drive, 2 CPU cores).

    Attributes
    ----------
    particles : int
        Number of particles ``P``.
    points : int
        Scan points sampled for scoring (step 8) per frame (the map merge uses the whole down-sampled scan).
    map_type : str
        ``"voxel"`` (hashed NDT voxels, :class:`slamlib.maps.VoxelHashMap`) or ``"bvh"`` (exact points in a
        Morton-code BVH, :class:`slamlib.maps.MortonBVHMap`).
    map_params : dict
        Extra keyword arguments for the map's constructor (e.g. ``{"voxel_size": 0.5}``).
    backend : str
        ``"numpy"`` (reference, slow), ``"cpu"`` (Numba) or ``"cuda"``.
    seed : int
        Seed of the filter's ``numpy.random.Generator`` (noise, scoring sample, resampling offsets).
    min_range, max_range : float
        Scan range crop in metres (step 2).
    voxel_size : float
        Scan down-sampling voxel in metres (step 2).
    sigma_xyz_per_m, sigma_xyz_per_s, sigma_rpy_per_m, sigma_rpy_per_s : 3-tuples
        Step 6 noise per axis (body x, y, z / roll, pitch, yaw): metres per metre travelled, metres per second,
        radians per metre, radians per second (:func:`slamlib.slam3d.steps.motion_noise_sigma`).
    temperature : float
        Likelihood tempering: ``log L = score / (N * temperature)`` (see the module docstring).
    ess_fraction : float
        Resample when the effective sample size is below ``ess_fraction * P`` (1.0: every frame).
    estimate : str
        Step 9: ``"best"`` particle or ``"mean"`` (weighted mean of the particles near the best).
    refine : int
        Annealing rounds per frame (coarse to fine); 0 = plain particle filter.
    refine_shrink : float
        Noise scale factor per annealing round.
    prune_every, prune_radius : int, float
        Every ``prune_every`` frames, drop map elements farther than ``prune_radius`` metres from the vehicle
        (bounded memory and lookup time on long drives; 0 disables).
    keep_pruned : bool
        Keep the pruned elements' points (not their statistics) in ``ParticleSLAM3D.archive`` for the exported
        map (:meth:`ParticleSLAM3D.map_points`).
    """

    particles: int = 300
    points: int = 1000
    map_type: str = "voxel"
    map_params: dict = field(default_factory=dict)
    backend: str = "cpu"
    seed: int = 0
    min_range: float = 3.0
    max_range: float = 60.0
    voxel_size: float = 0.25
    sigma_xyz_per_m: tuple = (0.02, 0.02, 0.01)
    sigma_xyz_per_s: tuple = (0.05, 0.05, 0.05)
    sigma_rpy_per_m: tuple = (0.0005, 0.0005, 0.002)
    sigma_rpy_per_s: tuple = (0.002, 0.002, 0.005)
    temperature: float = 0.02
    ess_fraction: float = 0.5
    estimate: str = "best"
    refine: int = 0
    refine_shrink: float = 0.4
    prune_every: int = 20
    prune_radius: float = 120.0
    keep_pruned: bool = True

    def __post_init__(self):
        if self.map_type not in MAP_NAMES:
            raise ValueError(f"map_type must be 'voxel' or 'bvh', got {self.map_type!r}")
        if int(self.particles) < 1 or int(self.points) < 1:
            raise ValueError("particles and points must be >= 1")
        if not self.temperature > 0:
            raise ValueError("temperature must be > 0")
        if self.estimate not in ("best", "mean"):
            raise ValueError(f"estimate must be 'best' or 'mean', got {self.estimate!r}")

    def as_dict(self) -> dict:
        """JSON-friendly dict of the settings."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}

    def noise_sigma(self, trans_delta, dt: float) -> np.ndarray:
        """Step 6's ``sigma (6,)`` for a frame with body motion ``trans_delta`` over ``dt`` seconds."""
        return steps.motion_noise_sigma(trans_delta, dt, self.sigma_xyz_per_m, self.sigma_xyz_per_s,
                                        self.sigma_rpy_per_m, self.sigma_rpy_per_s)


def make_slam_map(map_type: str = "voxel", **params):
    """A fresh map: ``"voxel"`` -> :class:`~slamlib.maps.VoxelHashMap` (capacity ``2**19`` unless given),
    ``"bvh"`` -> :class:`~slamlib.maps.MortonBVHMap`."""
    kind = MAP_NAMES[map_type]
    if kind == "voxel_hash":
        params.setdefault("capacity", 2**19)
    return make_map(kind, **params)


class ParticleSLAM3D:
    """Particle-filter SLAM on 6-DoF poses with a LIDAR map (the twelve steps of :mod:`slamlib.slam3d.steps`).

    Parameters
    ----------
    config : SLAM3DConfig, optional
        Settings (defaults if omitted).
    T_velo_imu : (4, 4), optional
        Calibration ``p_velo = T_velo_imu p_imu`` (KITTI ``calib_imu_to_velo.txt``; default identity: scans
        already in the body frame).
    T0 : (4, 4), optional
        Body pose at the first frame (default identity: the world is the first body pose).

    Attributes
    ----------
    R, t, log_w : the particles ``(P, 3, 3)``, ``(P, 3)`` and their log-weights ``(P,)``.
    map : :class:`slamlib.maps.Map3D` in the world frame.
    poses : list of (4, 4) SLAM estimates ``T_world_body``, one per registered frame.
    dr_poses : list of (4, 4) dead-reckoning poses from the same IMU samples.
    n_resampled : number of frames in which step 11 resampled.
    archive : list of (K, 3) float32 points pruned from the map (``keep_pruned``); see :meth:`map_points`.
    imu_prev : ``(velocity (3,), angular_rate (3,))`` of the last registered frame (None before the first).
    last : dict with this frame's intermediate results (scores, sample, sigma, ...), for plots and tests.
    """

    def __init__(self, config: SLAM3DConfig | None = None, T_velo_imu=None, T0=None):
        self.config = cfg = config if config is not None else SLAM3DConfig()
        self.backend = get_backend(cfg.backend)
        self.rng = np.random.default_rng(cfg.seed)
        self.T_body_velo = None if T_velo_imu is None else np.linalg.inv(np.asarray(T_velo_imu, dtype=np.float64))
        self.map = make_slam_map(cfg.map_type, **cfg.map_params)
        self.R, self.t, self.log_w = steps.initialise_particles(cfg.particles, T0)    # step 1
        self.T0 = np.eye(4) if T0 is None else np.asarray(T0, dtype=np.float64)
        self.poses: list[np.ndarray] = []
        self.dr_poses: list[np.ndarray] = []
        self.n_resampled = 0
        self.archive: list[np.ndarray] = []
        self.last: dict = {}
        self.imu_prev = None

    # ----------------------------------------------------------------------------------------- step 12
    def register_frame(self, frame) -> np.ndarray:
        """Run steps 2-11 on one frame (``.scan``, ``.velocity``, ``.angular_rate``, ``.dt``); return the pose.

        The first frame only builds the map at the start pose. Returns ``T_world_body`` (4, 4).
        """
        cfg, be = self.config, self.backend
        points = steps.read_scan(frame, self.T_body_velo, cfg.min_range, cfg.max_range, cfg.voxel_size)  # 2
        v, w = steps.read_imu(frame)                                                                     # 3
        dt = steps.read_timing(frame)                                                                    # 4
        if self.imu_prev is None:  # first frame: the map starts at the start pose
            return self._accept(self.T0, self.T0, points, (v, w))
        rpy, dp = steps.motion_increment(*self.imu_prev, v, w, dt)
        sigma = cfg.noise_sigma(dp, dt)
        noise = self.rng.standard_normal((len(self.t), 6))
        self.R, self.t = steps.move_particles(self.R, self.t, rpy, dp, noise, sigma, be)          # 5 + 6
        sample = sample_points(points, cfg.points, self.rng)
        self._weigh(sample)                                                                              # 7 + 8
        for _ in range(cfg.refine):  # coarse to fine: resample, shrink the noise, weigh again
            self._resample(1.0)
            self.R, self.t = steps.perturb_with_noise(self.R, self.t, sigma * cfg.refine_shrink, self.rng, be)
            self._weigh(sample)
        T_best, best = steps.pick_best_particle(self.log_w, self.R, self.t, cfg.estimate)                # 9
        T_dr = self.dr_poses[-1] @ _increment(rpy, dp)
        self.last.update(sigma=sigma, sample=sample, best=best, rpy_delta=rpy, trans_delta=dp)
        pose = self._accept(T_best, T_dr, points, (v, w))                                               # 10
        self._resample(cfg.ess_fraction)                                                                 # 11
        return pose

    # ----------------------------------------------------------------------------------------- helpers
    def _weigh(self, sample) -> None:
        """Steps 7 + 8: score every particle and fold the tempered log-likelihood into the log-weights."""
        scores = steps.score_particles(self.R, self.t, sample, self.map, self.backend)
        loglik = scores / (len(sample) * self.config.temperature)
        self.log_w = steps.normalise_log_weights(self.log_w + loglik)
        self.last["scores"] = scores

    def _resample(self, ess_fraction: float) -> None:
        self.R, self.t, self.log_w, done = steps.resample_particles(self.R, self.t, self.log_w, self.rng,
                                                                    self.backend, ess_fraction)
        self.n_resampled += int(done)

    def _accept(self, T, T_dr, points, imu) -> np.ndarray:
        """Step 10 and bookkeeping: merge the scan at ``T``, record the poses, prune the map now and then."""
        steps.merge_scan(self.map, T, points, self.backend)
        self.poses.append(np.asarray(T, dtype=np.float64))
        self.dr_poses.append(np.asarray(T_dr, dtype=np.float64))
        self.imu_prev = imu
        self.last["points"] = points
        k = len(self.poses)
        if self.config.prune_every and k % self.config.prune_every == 0:
            self._prune(np.asarray(T, dtype=np.float64)[:3, 3])
        return self.poses[-1]

    def _prune(self, center) -> None:
        """Drop map elements farther than ``prune_radius`` from ``center``; keep their points in ``archive``."""
        r = self.config.prune_radius
        if self.config.keep_pruned:
            pts = self.map.points()
            far = np.sum((pts.astype(np.float64) - center) ** 2, axis=1) > r**2  # the maps' own eviction rule
            if far.any():
                self.archive.append(pts[far])
        self.map.prune(center, r)

    def map_points(self) -> np.ndarray:
        """All map points (M, 3) float32, world frame: the live map's plus the pruned ones kept in ``archive``."""
        return np.concatenate(self.archive + [self.map.points()]) if self.archive else self.map.points()

    # ----------------------------------------------------------------------------------------- results
    @property
    def trajectory(self) -> np.ndarray:
        """SLAM poses ``T_world_body`` (F, 4, 4) of the registered frames."""
        return np.array(self.poses).reshape(-1, 4, 4)

    @property
    def dead_reckoning(self) -> np.ndarray:
        """Dead-reckoning poses (F, 4, 4) from the same IMU samples."""
        return np.array(self.dr_poses).reshape(-1, 4, 4)

    def particle_poses(self) -> np.ndarray:
        """The particles as 4x4 poses (P, 4, 4)."""
        from slamlib.geometry import make_pose
        return make_pose(self.R, self.t)


def _increment(rpy, dp) -> np.ndarray:
    from slamlib.odometry import increment_matrix
    return increment_matrix(rpy, dp)
