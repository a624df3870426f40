"""The 2D particle SLAM filter: a thin object whose :meth:`ParticleSLAM2D.step` is the twelve steps.

State per frame: particles ``(P, 3)`` poses ``(x, y, theta)``, their normalised **log**-weights ``(P,)`` and the
map (:class:`~slamlib.sim2d.steps.OccupancyGrid2D`, changed in place by step 10). As in 1D, log-weights
accumulate scores between resamplings (``log w_i <- log w_i + s_i``), resampling happens when the effective
sample size drops below ``ess_fraction * P``, the estimate is the best particle, and one shared map is grown from
the best pose of each frame (the seed project's scheme; FastSLAM keeps a map per particle instead).

Step 6's spread per frame is ``sigma = motion_noise * dt``, with ``motion_noise = (sigma_forward (m/s),
sigma_left (m/s), sigma_theta (rad/s))``: a speed error along the heading, a small sideways slip, and a
yaw-rate error, each held over the interval.

The per-frame loop is not written here: :class:`ParticleSLAM2D` is a :class:`slamlib.contract.StepsFilter` over
:mod:`slamlib.sim2d.steps`, whose ``step(frame)`` is the one loop that 1D and 2D share; this class adds step 2's
``max_points``. It returns the shared :class:`slamlib.contract.StepInfo` (``StepInfo2D`` is the same class).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import slamlib.sim2d.steps as steps_2d
from slamlib.contract import StepInfo, StepsFilter
from slamlib.resampling import DEFAULT_ESS_FRACTION
from slamlib.sim2d.particle_maps import DEFAULT_TILE, ParticleMaps2D
from slamlib.sim2d.steps import DEFAULT_MAP_KIND, DEFAULT_RESOLUTION, OccupancyGrid2D
from slamlib.sim2d.world import Recording2D, integrate_arc, wrap_angle

__all__ = [
    "ParticleMapsSLAM2D",
    "ParticleSLAM2D",
    "SLAM2DResult",
    "StepInfo2D",
    "dead_reckon_2d",
    "default_motion_noise",
    "position_rmse",
    "run_slam_2d",
]

#: What one :meth:`ParticleSLAM2D.step` did: :class:`slamlib.contract.StepInfo`, the class every dimension
#: returns (``moved (P, 3)``, ``estimate (3,)``, ``mean`` None); the name kept for the imports that use it.
StepInfo2D = StepInfo


def default_motion_noise(sensors) -> np.ndarray:
    """Step 6's spread per second from the odometry datasheet: ``(1.5 sigma_v + |b_v|, 0.1 m/s,
    1.5 sigma_w + |b_w|)``, the noise inflated to cover the unknown biases."""
    return np.array(
        [
            1.5 * sensors.speed_noise + abs(sensors.speed_bias),
            0.1,
            1.5 * sensors.yaw_rate_noise + abs(sensors.yaw_rate_bias),
        ]
    )


class ParticleSLAM2D(StepsFilter):
    """Particle SLAM in the plane, one :meth:`step` per frame (:class:`slamlib.contract.StepsFilter`).

    The first four parameters and ``ess_fraction`` are the same, in the same order, as
    :class:`slamlib.sim1d.ParticleSLAM1D`'s; what 2D adds comes after them with a default. Step 8's settings live
    in the map (:class:`~slamlib.sim2d.steps.OccupancyGrid2D`: ``kind``, ``sigma``, ``eps``, ``n_sat``).

    Parameters
    ----------
    n_particles : int, P.
    world_map : OccupancyGrid2D, the (usually empty) map; changed in place by every :meth:`step`.
    motion_noise : (3,) ``(sigma_forward m/s, sigma_left m/s, sigma_theta rad/s)``; step 6 uses it times ``dt``.
    rng : numpy.random.Generator, the source of motion noise and resampling offsets.
    ess_fraction : resample when ``ESS < ess_fraction * P``; ``None`` every frame.
    max_points : optional down-sampling of the scan read at step 2 (scoring and merging use the same points).
    tempering : step 8's ``beta`` in ``(0, 1]``: the scan likelihood raised to ``beta`` (1: as it is).
    """

    #: The step functions the filter runs (:mod:`slamlib.sim2d.steps`).
    #:
    #: :meta hide-value:
    steps = steps_2d

    def __init__(
        self,
        n_particles: int,
        world_map: OccupancyGrid2D,
        motion_noise,
        rng: np.random.Generator,
        ess_fraction: float | None = DEFAULT_ESS_FRACTION,
        max_points: int | None = None,
        tempering: float = 1.0,
    ):
        super().__init__(
            n_particles,
            world_map,
            np.asarray(motion_noise, dtype=np.float64).reshape(3),
            rng,
            ess_fraction,
        )
        self.max_points = max_points
        self.tempering = tempering

    def score_options(self) -> dict:
        """Step 8's tempering."""
        return {"tempering": self.tempering}

    def scan_options(self) -> dict:
        """Step 2's down-sampling."""
        return {"max_points": self.max_points}


class ParticleMapsSLAM2D(ParticleSLAM2D):
    """Rao-Blackwellised particle SLAM in the plane: every particle carries its own map (FastSLAM's scheme).

    The same twelve steps and parameters as :class:`ParticleSLAM2D`, with ``world_map`` a
    :class:`~slamlib.sim2d.particle_maps.ParticleMaps2D` of ``n_particles`` maps: step 8 scores each particle
    against its own map, step 10 merges the scan into every particle's map at that particle's pose
    (:meth:`merge_pose`), and step 11 hands each resampled particle its parent's map (:meth:`resample_options`).
    The estimate is still the best particle, whose map is ``world_map.grid(best)``.
    """

    def __init__(
        self,
        n_particles: int,
        world_map: ParticleMaps2D,
        motion_noise,
        rng: np.random.Generator,
        ess_fraction: float | None = DEFAULT_ESS_FRACTION,
        max_points: int | None = None,
        tempering: float = 1.0,
    ):
        if (
            not isinstance(world_map, ParticleMaps2D)
            or world_map.n_particles != n_particles
        ):
            raise ValueError(
                f"world_map must be a ParticleMaps2D of n_particles={n_particles} maps, got {world_map!r}"
            )
        super().__init__(
            n_particles, world_map, motion_noise, rng, ess_fraction, max_points, tempering
        )

    def merge_pose(self, moved, pose):
        """Every particle's pose: each merges the scan into its own map."""
        return moved

    def resample_options(self) -> dict:
        """The maps follow their particles through resampling."""
        return {"maps": self.world_map}


def dead_reckon_2d(recording: Recording2D, pose0=None) -> np.ndarray:
    """Odometry alone (steps 3-5 on one pose): ``(K, 3)`` poses from exact arcs of the measured ``(v, w)``."""
    poses = np.zeros((len(recording), 3))
    if pose0 is not None:
        poses[0] = pose0
    for k, f in enumerate(recording.frames[1:], start=1):
        poses[k] = integrate_arc(poses[k - 1], f.speed, f.yaw_rate, f.dt)
    return poses


def position_rmse(estimate, truth) -> float:
    """ATE without alignment (both start at the world origin): ``sqrt(mean ||p_est - p_true||^2)`` (m)."""
    d = np.asarray(estimate)[:, :2] - np.asarray(truth)[:, :2]
    return float(np.sqrt(np.mean(np.sum(d**2, axis=1))))


@dataclass
class SLAM2DResult:
    """A run: ``times (K,)``, ``true_poses``, ``estimated`` (best particle), ``dead_reckoned`` (all ``(K, 3)``),
    ``ess (K,)``, ``resampled (K,)``, the final ``world_map`` (the best particle's, with per-particle maps), and
    when kept ``particle_history (K, P, 3)`` float32, ``weight_history (K, P)`` float32. With per-particle maps
    also ``particle_maps`` (the final :class:`~slamlib.sim2d.particle_maps.ParticleMaps2D`), ``map_bytes (K,)``
    (their memory after each frame), ``disputed_tiles (K,)`` (tile positions where the particles' maps differ) and
    ``map_snapshots`` (frame -> a copy of the maps and the particles after that frame, for the frames asked)."""

    times: np.ndarray
    true_poses: np.ndarray
    estimated: np.ndarray
    dead_reckoned: np.ndarray
    ess: np.ndarray
    resampled: np.ndarray
    world_map: OccupancyGrid2D
    particle_history: np.ndarray | None = None
    weight_history: np.ndarray | None = None
    particle_maps: ParticleMaps2D | None = None
    map_bytes: np.ndarray | None = None
    disputed_tiles: np.ndarray | None = None
    map_snapshots: dict | None = None

    @property
    def slam_error(self) -> np.ndarray:
        """(K,) position error of the estimate (m)."""
        return np.hypot(*(self.estimated[:, :2] - self.true_poses[:, :2]).T)

    @property
    def dead_reckoning_error(self) -> np.ndarray:
        """(K,) position error of dead reckoning (m)."""
        return np.hypot(*(self.dead_reckoned[:, :2] - self.true_poses[:, :2]).T)

    @property
    def slam_heading_error(self) -> np.ndarray:
        """(K,) ``|heading error|`` of the estimate (rad)."""
        return np.abs(wrap_angle(self.estimated[:, 2] - self.true_poses[:, 2]))

    @property
    def dead_reckoning_heading_error(self) -> np.ndarray:
        """(K,) ``|heading error|`` of dead reckoning (rad)."""
        return np.abs(wrap_angle(self.dead_reckoned[:, 2] - self.true_poses[:, 2]))

    @property
    def ate(self) -> float:
        """Absolute trajectory error of SLAM: position RMSE over all frames, no alignment (m)."""
        return position_rmse(self.estimated, self.true_poses)

    @property
    def ate_dead_reckoning(self) -> float:
        """The same for dead reckoning (m)."""
        return position_rmse(self.dead_reckoned, self.true_poses)

    def summary(self) -> dict:
        """ATE, final errors (m, deg) of SLAM and dead reckoning, and the number of resamplings."""
        return {
            "frames": int(self.times.size),
            "slam_ate_m": self.ate,
            "slam_final_error_m": float(self.slam_error[-1]),
            "slam_final_heading_error_deg": float(
                np.degrees(self.slam_heading_error[-1])
            ),
            "dead_reckoning_ate_m": self.ate_dead_reckoning,
            "dead_reckoning_final_error_m": float(self.dead_reckoning_error[-1]),
            "dead_reckoning_final_heading_error_deg": float(
                np.degrees(self.dead_reckoning_heading_error[-1])
            ),
            "resamplings": int(self.resampled.sum()),
        }


def run_slam_2d(
    recording: Recording2D,
    n_particles: int = 200,
    seed: int = 0,
    map_kind: str = DEFAULT_MAP_KIND,
    resolution: float = DEFAULT_RESOLUTION,
    motion_noise=None,
    likelihood_sigma: float | None = None,
    eps: float = OccupancyGrid2D.eps,
    n_sat: int = OccupancyGrid2D.n_sat,
    ess_fraction: float | None = DEFAULT_ESS_FRACTION,
    max_points: int | None = None,
    tempering: float = 1.0,
    keep_history: bool = False,
    progress: bool = False,
    per_particle_maps: bool = False,
    tile: int = DEFAULT_TILE,
    margin: float = 4.0,
    snapshots: tuple = (),
) -> SLAM2DResult:
    """Run :class:`ParticleSLAM2D` over every frame of ``recording`` (step 12, the loop).

    Parameters
    ----------
    recording : from :func:`slamlib.sim2d.simulate`.
    n_particles : P; seed : the filter's generator (motion noise, resampling).
    map_kind : ``"density"`` or ``"likelihood"`` (:class:`~slamlib.sim2d.steps.OccupancyGrid2D`).
    resolution : cell size (m); the grid covers the world's structure plus the sensor range around the route.
    motion_noise : (3,) per second, default :func:`default_motion_noise` of the recording's sensors.
    likelihood_sigma : field width (m), default ``max(resolution, 2 sigma_r)``.
    eps, n_sat : see :class:`OccupancyGrid2D`; ess_fraction, max_points, tempering : see
        :class:`ParticleSLAM2D`.
    keep_history : keep the particles and weights of every frame; progress : tqdm bar.
    per_particle_maps : one map per particle (:class:`ParticleMapsSLAM2D`, tiles of ``tile`` cells a side)
        instead of one shared map grown from the best particle (:class:`ParticleSLAM2D`).
    margin : metres of grid beyond the structure and the sensor's reach round the route.
    snapshots : frames after which to keep ``(maps copy, particles, log_weights)`` (per-particle maps only); the
        maps are tagged there (:meth:`~slamlib.sim2d.particle_maps.ParticleMaps2D.tag`), so the next snapshot's
        ``maps.ancestors`` names the particles of this one that it descends from.
    """
    from tqdm.auto import tqdm

    sensors = recording.sensors
    if motion_noise is None:
        motion_noise = default_motion_noise(sensors)
    if likelihood_sigma is None:
        likelihood_sigma = max(resolution, 2 * sensors.range_noise)
    lo, hi = recording.world.bounds
    path = recording.true_poses[:, :2]
    lo = np.minimum(lo, path.min(axis=0) - sensors.max_range) - margin
    hi = np.maximum(hi, path.max(axis=0) + sensors.max_range) + margin
    world_map = OccupancyGrid2D.empty(
        lo, hi, resolution, kind=map_kind, sigma=likelihood_sigma, eps=eps, n_sat=n_sat
    )
    cls = ParticleMapsSLAM2D if per_particle_maps else ParticleSLAM2D
    if per_particle_maps:
        world_map = ParticleMaps2D(world_map, n_particles, tile)
    slam = cls(
        n_particles,
        world_map,
        motion_noise,
        np.random.default_rng(seed),
        ess_fraction=ess_fraction,
        max_points=max_points,
        tempering=tempering,
    )
    k_frames = len(recording)
    estimated = np.zeros((k_frames, 3))
    ess = np.zeros(k_frames)
    resampled = np.zeros(k_frames, dtype=bool)
    particle_history = (
        np.zeros((k_frames, n_particles, 3), np.float32) if keep_history else None
    )
    weight_history = (
        np.zeros((k_frames, n_particles), np.float32) if keep_history else None
    )
    map_bytes = np.zeros(k_frames, np.int64) if per_particle_maps else None
    disputed = np.zeros(k_frames, np.int64) if per_particle_maps else None
    kept = {} if per_particle_maps else None
    for k, frame in enumerate(
        tqdm(recording.frames, desc="sim2d SLAM", unit="frame", disable=not progress)
    ):
        info = slam.step(frame)
        estimated[k], ess[k], resampled[k] = info.estimate, info.ess, info.resampled
        if keep_history:
            particle_history[k] = info.moved
            weight_history[k] = info.weights
        if per_particle_maps:
            map_bytes[k] = slam.world_map.memory_bytes()
            disputed[k] = slam.world_map.disputed_tiles()
            if k in snapshots:
                kept[k] = (
                    slam.world_map.copy(),
                    slam.particles.copy(),
                    slam.log_weights.copy(),
                )
                slam.world_map.tag()  # later snapshots' ancestors name this one's particles
    final_map = slam.world_map
    if per_particle_maps:
        # resampling may have moved the best particle's map: take the particle at the estimate's pose (a
        # resampled copy of the best sits exactly there)
        holder = np.argmin(np.sum((slam.particles - estimated[-1]) ** 2, axis=1))
        final_map = slam.world_map.grid(int(holder))
    return SLAM2DResult(
        times=recording.times.copy(),
        true_poses=recording.true_poses.copy(),
        estimated=estimated,
        dead_reckoned=dead_reckon_2d(recording),
        ess=ess,
        resampled=resampled,
        world_map=final_map,
        particle_history=particle_history,
        weight_history=weight_history,
        particle_maps=slam.world_map if per_particle_maps else None,
        map_bytes=map_bytes,
        disputed_tiles=disputed,
        map_snapshots=kept,
    )
