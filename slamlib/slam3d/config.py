"""Settings of the 3D particle SLAM, in four groups: scan (step 2), motion (steps 5-6), map (steps 8 and 10), filter.

Every default is written once, here: the step functions of :mod:`slamlib.slam3d.steps` take these groups as
their default arguments, and ``slamlib run`` reads its option defaults from them. Defaults are tuned on the
default synthetic drive on 2 CPU cores (``slamlib bench slam3d``).

Build a configuration by group (``SLAM3DConfig(filter=FilterConfig(particles=100))``) or by setting name
(``SLAM3DConfig.of(particles=100, max_range=30.0)``: every setting name is unique across the groups).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields, replace

import numpy as np

from slamlib.kernels import DEFAULT_BACKEND
from slamlib.kitti.velodyne import SWEEP_PERIOD_S
from slamlib.maps import DEFAULT_MAP_KIND, MAP_TYPES, make_map
from slamlib.resampling import DEFAULT_ESS_FRACTION

__all__ = [
    "MOTION_MODELS",
    "ScanConfig",
    "MotionConfig",
    "MapConfig",
    "FilterConfig",
    "SLAM3DConfig",
    "MAP_KINDS",
    "OLD_MAP_NAMES",
]

#: Map kinds (:func:`slamlib.maps.make_map`, the keys of :data:`slamlib.maps.MAP_TYPES`): hashed NDT voxels, exact
#: points in a Morton-code BVH.
MAP_KINDS = tuple(MAP_TYPES)
#: Earlier spellings of the map kinds, still accepted by ``slamlib run --map`` (with a note) but not here.
OLD_MAP_NAMES = {"voxel": "voxel_hash", "bvh": "morton_bvh"}
#: Most particles: the particle arrays take ~200 bytes each (pose, noise, weights, copies when resampling), so
#: 10**7 particles already need ~2 GB; more would fail to allocate (10**9 asked for 67 GiB) or run for hours a frame.
MAX_PARTICLES = 10_000_000
#: Most scan points scored per particle per frame (a LIDAR scan has ~120k before down-sampling).
MAX_SCORED_POINTS = 1_000_000
#: Most point scores per frame, ``particles * scored_points`` (work per frame; 10**10 is minutes per frame on a GPU).
MAX_POINT_SCORES = 10_000_000_000
#: Most annealing rounds per frame (each one costs a whole scoring pass).
MAX_REFINE = 100
#: Most Gauss-Newton steps of the scan matcher per frame (``FilterConfig.scan_match_iterations``; each a pass over
#: the whole down-sampled scan).
MAX_SCAN_MATCH_ITERATIONS = 100
#: Most frames the LIDAR-only velocity is averaged over (``MotionConfig.cv_window``; 10 frames = 1 s at 10 Hz).
MAX_CV_WINDOW = 10
#: Map constructor parameters that must be finite and > 0 (:class:`slamlib.maps.VoxelHashMap`,
#: :class:`slamlib.maps.MortonBVHMap`).
POSITIVE_MAP_PARAMS = (
    "voxel_size",
    "capacity",
    "min_sigma",
    "m_max",
    "radius",
    "sigma",
    "quantum",
    "max_points",
)


def _finite(name: str, value) -> float:
    """``float(value)``, or ValueError naming ``name`` when it is not a finite number."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not np.isfinite(x):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return x


def _integer(name: str, value, low: int, high: int | None = None) -> int:
    """``int(value)`` within ``[low, high]``, or ValueError naming ``name`` and the allowed range."""
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, np.integer))
        and not (
            isinstance(value, (float, np.floating))
            and np.isfinite(value)
            and float(value).is_integer()
        )
    ):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    v = int(value)
    if v < low or (high is not None and v > high):
        allowed = f">= {low}" if high is None else f"in [{low}, {high:,}]"
        raise ValueError(f"{name} must be {allowed}, got {value!r}")
    return v


@dataclass(frozen=True)
class ScanConfig:
    """Step 2: how a raw scan becomes the body-frame points the filter uses.

    Attributes
    ----------
    min_range, max_range : float
        Range crop in the Velodyne frame, metres (drops returns off the car itself and sparse far returns).
    downsample_voxel : float
        Edge of the scan's down-sampling voxel, metres (one point kept per voxel; 0 = off). Not the map's voxel
        (:attr:`MapConfig.params` ``voxel_size``).
    deskew : bool or None
        Motion-compensate each scan (:func:`slamlib.slam3d.steps.deskew_scan`) with the frame's motion. ``None``
        (the default): for the scans taken over a sweep, the frames whose ``swept`` says so
        (:func:`slamlib.slam3d.steps.should_deskew`: real KITTI raw drives and synthetic drives written with
        ``distortion``, the default drive among them), not for scans cast from one pose or already
        motion-compensated (the KITTI odometry benchmark's), where it would add the very error it removes.
        ``True`` / ``False``: every frame / none.
    sweep_period : float
        Seconds one sweep takes (KITTI's HDL-64E: 0.10315 s, measured on raw drive 0001).
    """

    min_range: float = 3.0
    max_range: float = 60.0
    downsample_voxel: float = 0.25
    deskew: bool | None = None
    sweep_period: float = SWEEP_PERIOD_S

    def __post_init__(self):
        _finite("min_range", self.min_range)
        if (
            not 0 <= self.min_range < self.max_range
        ):  # max_range may be inf (no far crop), not NaN
            raise ValueError(
                f"need 0 <= min_range < max_range, got {self.min_range}, {self.max_range}"
            )
        if not _finite("downsample_voxel", self.downsample_voxel) >= 0:
            raise ValueError(
                f"downsample_voxel must be >= 0 (0 = off), got {self.downsample_voxel}"
            )
        if not _finite("sweep_period", self.sweep_period) > 0:
            raise ValueError(f"sweep_period must be > 0 s, got {self.sweep_period}")
        if self.deskew is not None and not isinstance(self.deskew, (bool, np.bool_)):
            raise ValueError(
                f"deskew must be True, False or None (when the scans are swept), got {self.deskew!r}"
            )


#: Step 3's motion sources: the IMU's velocities and rates, or the filter's own last estimated motion held
#: (LIDAR-only; :func:`slamlib.slam3d.steps.read_imu`).
MOTION_MODELS = ("imu", "constant_velocity")
#: The :class:`MotionConfig` fields that are not per-axis spreads.
_MOTION_SCALARS = ("model", "cv_start_rounds", "cv_window", "cv_damping")


@dataclass(frozen=True)
class MotionConfig:
    """Steps 3, 5 and 6: where the motion comes from, and the spread of the motion noise per axis (body x, y, z,
    then roll, pitch, yaw).

    ``sigma_xyz = sigma_xyz_per_m |dp| + sigma_xyz_per_s dt`` (metres) and
    ``sigma_rpy = sigma_rpy_per_m |dp| + sigma_rpy_per_s dt`` (radians), with ``|dp|`` the distance travelled in
    the frame: odometry errors grow with distance (scale errors, slip) and with time (biases), as the odometry
    motion model's ``alpha`` parameters (Thrun, Burgard & Fox 2005, table 5.5).

    **LIDAR-only** (``model="constant_velocity"``, or any frame without IMU values): step 3 holds the last
    estimated twist (:func:`slamlib.odometry.twist_between`), and its error over a frame is the change of velocity
    in that frame, ``a dt`` over ``dt`` seconds, i.e. ``a dt^2`` in position (``alpha dt^2`` in angle). Step 6
    adds ``cv_accel dt^2`` (m) and ``cv_angular_accel dt^2`` (rad) to the spreads above, with ``a`` and ``alpha``
    the accelerations a car typically has between two scans: about 2 m/s^2 forward (braking, pulling away),
    0.5 m/s^2 sideways and up, 0.5 rad/s^2 in yaw (entering a turn), 0.2 rad/s^2 in roll and pitch. At 10 Hz that is
    2 cm and 0.29 deg: several times the IMU model's spread, which the particles must cover.

    The held twist is that of the last ``cv_window`` frames (the motion from the pose ``cv_window`` frames back to
    the last one, over their time: one frame's estimate is noisy, and constant velocity would carry its noise into
    the next frame), its six components (``v`` forward, left, up, then the rates about them) multiplied by
    ``cv_damping``: a car's vertical velocity and its roll and pitch rates are close to zero, so an estimate of
    them is mostly noise, which held drifts the height and the pitch. Both are off by default (``cv_window`` 1 frame,
    ``cv_damping`` all 1: no damping); why, and how to choose them (``slamlib sweep``): the book's "Why these
    defaults" (``book/defaults.md``).

    At the second frame LIDAR-only knows no motion yet: the spread is ``cv_start_speed dt`` (speeds a car may have
    when the sequence starts: 15 m/s forward, 1 and 0.5 m/s sideways and up; 0.05, 0.05, 0.3 rad/s in roll, pitch,
    yaw), narrowed by ``cv_start_rounds`` annealing rounds that halve it (:mod:`slamlib.slam3d.pipeline`).
    """

    sigma_xyz_per_m: tuple = (0.02, 0.02, 0.01)
    sigma_xyz_per_s: tuple = (0.05, 0.05, 0.05)
    sigma_rpy_per_m: tuple = (0.0005, 0.0005, 0.002)
    sigma_rpy_per_s: tuple = (0.002, 0.002, 0.005)
    model: str = "imu"
    cv_accel: tuple = (2.0, 0.5, 0.5)
    cv_angular_accel: tuple = (0.2, 0.2, 0.5)
    cv_start_speed: tuple = (15.0, 1.0, 0.5, 0.05, 0.05, 0.3)
    cv_start_rounds: int = 8
    cv_window: int = 1
    cv_damping: tuple = (1.0, 1.0, 1.0, 1.0, 1.0, 1.0)

    def __post_init__(self):
        if self.model not in MOTION_MODELS:
            raise ValueError(
                f"model must be one of {', '.join(MOTION_MODELS)}, got {self.model!r}"
            )
        _integer("cv_start_rounds", self.cv_start_rounds, 0, MAX_REFINE)
        _integer("cv_window", self.cv_window, 1, MAX_CV_WINDOW)
        damping = np.asarray(self.cv_damping, dtype=np.float64)
        if damping.shape != (6,) or not np.all((damping >= 0) & (damping <= 1)):
            raise ValueError(
                f"cv_damping must be 6 numbers in [0, 1], got {self.cv_damping!r}"
            )
        object.__setattr__(self, "cv_damping", tuple(float(x) for x in damping))
        for f in fields(self):
            if f.name in _MOTION_SCALARS:
                continue
            v = np.asarray(getattr(self, f.name), dtype=np.float64)
            size = 6 if f.name == "cv_start_speed" else 3
            if v.shape != (size,) or not np.all(np.isfinite(v)) or not np.all(v >= 0):
                raise ValueError(
                    f"{f.name} must be {size} finite non-negative numbers, got {getattr(self, f.name)!r}"
                )
            object.__setattr__(self, f.name, tuple(float(x) for x in v))

    def sigma(
        self, trans_delta, dt: float, constant_velocity: bool = False, start: bool = False
    ) -> np.ndarray:
        """Standard deviations ``(6,)`` for a frame that moved ``trans_delta`` (3,) metres in ``dt`` seconds; with
        ``constant_velocity`` (LIDAR-only) widened by ``cv_accel dt^2`` and ``cv_angular_accel dt^2``; ``start``
        (LIDAR-only, no motion known yet) adds ``cv_start_speed dt``."""
        d, dt = float(np.linalg.norm(trans_delta)), float(dt)
        s = np.empty(6)
        s[:3] = (
            np.asarray(self.sigma_xyz_per_m) * d + np.asarray(self.sigma_xyz_per_s) * dt
        )
        s[3:] = (
            np.asarray(self.sigma_rpy_per_m) * d + np.asarray(self.sigma_rpy_per_s) * dt
        )
        if constant_velocity:
            s[:3] += np.asarray(self.cv_accel) * dt**2
            s[3:] += np.asarray(self.cv_angular_accel) * dt**2
        if start:
            s += np.asarray(self.cv_start_speed) * dt
        return s

    def scaled(self, k: float) -> MotionConfig:
        """All spreads (and the LIDAR-only accelerations) multiplied by ``k`` (``slamlib run --noise``)."""
        return replace(
            self,
            **{
                f.name: tuple(k * x for x in getattr(self, f.name))
                for f in fields(self)
                if f.name not in _MOTION_SCALARS
            },
        )


@dataclass(frozen=True)
class MapConfig:
    """Steps 8 and 10: the map structure and how it forgets.

    Attributes
    ----------
    kind : str
        ``"voxel_hash"`` (hashed NDT voxels, :class:`slamlib.maps.VoxelHashMap`) or ``"morton_bvh"`` (exact points
        in a Morton-code BVH, :class:`slamlib.maps.MortonBVHMap`).
    params : dict
        Keyword arguments of the map's constructor (e.g. ``{"voxel_size": 0.5}``); the constructor's defaults for
        the others (the voxel map's ``capacity``: :data:`slamlib.maps.DEFAULT_VOXEL_CAPACITY`, 2**19 slots).
    prune_every, prune_radius : int, float
        Every ``prune_every`` frames drop map elements farther than ``prune_radius`` metres from the vehicle
        (bounded memory and lookup time on long drives; 0 disables).
    keep_pruned : bool
        Keep the pruned elements' points for the exported map (:meth:`ParticleSLAM3D.map_points`).
    transient_span : int
        Every ``transient_span`` frames evict the voxels hit only within fewer than ``transient_span`` consecutive
        frames and not in the last ``transient_span`` (:meth:`slamlib.maps.VoxelHashMap.evict_transients`): the
        trails of moving cars and people, which a static surface in view does not leave. 0 (default) keeps
        every voxel; the voxel map only. Evicted voxels are not archived.
    """

    kind: str = DEFAULT_MAP_KIND
    params: dict = field(default_factory=dict)
    prune_every: int = 20
    prune_radius: float = 120.0
    keep_pruned: bool = True
    transient_span: int = 0

    def __post_init__(self):
        if self.kind not in MAP_KINDS:
            hint = (
                f" (now called {OLD_MAP_NAMES[self.kind]!r})"
                if self.kind in OLD_MAP_NAMES
                else ""
            )
            raise ValueError(
                f"map kind must be one of {', '.join(map(repr, MAP_KINDS))}, got {self.kind!r}{hint}"
            )
        if int(self.prune_every) < 0 or not self.prune_radius > 0:
            raise ValueError(
                f"need prune_every >= 0 and prune_radius > 0, got {self.prune_every}, "
                f"{self.prune_radius}"
            )
        _integer("transient_span", self.transient_span, 0)  # frames; 0 = off
        if self.transient_span and self.kind != "voxel_hash":
            raise ValueError(
                f"transient_span needs the 'voxel_hash' map (its voxels remember when they were hit), "
                f"got kind {self.kind!r}"
            )
        for name, value in dict(self.params).items():
            if name in POSITIVE_MAP_PARAMS and not _finite(name, value) > 0:
                raise ValueError(
                    f"map parameter {name} must be finite and > 0, got {value!r}"
                )

    def make(self):
        """A fresh, empty map of this kind (:func:`slamlib.maps.make_map`)."""
        return make_map(self.kind, **self.params)


@dataclass(frozen=True)
class FilterConfig:
    """The particle filter around the steps.

    Attributes
    ----------
    particles : int
        Number of particles ``P``.
    scored_points : int
        Scan points sampled for scoring (step 8) per frame; step 10 merges the whole down-sampled scan.
    temperature : float
        Likelihood tempering: ``log L = score / (N * temperature)`` (:mod:`slamlib.slam3d.pipeline`).
    ess_fraction : float
        Step 11 resamples when the effective sample size is below ``ess_fraction * P`` (1.0: every frame; default
        :data:`slamlib.resampling.DEFAULT_ESS_FRACTION`, 0.5, shared with the 1D and 2D filters).
    estimate : str
        Step 9: ``"best"`` particle or ``"mean"`` (weighted mean of the particles near the best).
    refine : int
        Annealing rounds per frame (coarse to fine); 0 = plain particle filter.
    refine_shrink : float
        Noise scale factor per annealing round.
    lidar_only_ground_share : float
        LIDAR-only: the share of road points in step 8's sample (the rest stands above the road;
        :func:`slamlib.slam3d.preprocess.thin_ground`). 1 keeps the scan's own mix.
    tilt_sigma : float
        Radians; > 0 holds roll and pitch to gravity: step 8 adds :func:`slamlib.slam3d.stages.prior.tilt_log_prior`
        with the up direction the accelerometer measured over the last ``tilt_window`` seconds
        (:func:`slamlib.slam3d.stages.prior.gravity_up`). 0 (default) = off; needs an IMU with ``specific_force``.
        ``sigma`` is the prior's weight against the map as much as an error bar on the measured up; the value the
        realistic sweeps use, and why: book chapter 09 and "Why these defaults" (``book/defaults.md``).
    tilt_window : float
        Seconds of accelerometer samples behind each up measurement (longer: less noise from the velocities).
    tilt_bias_sigma, tilt_world_sigma : float
        Radians; with the prior on, the filter also estimates, by least squares over the frames whose window spans
        ``tilt_window`` (:func:`slamlib.slam3d.stages.prior.tilt_calibration_update`), the accelerometer's bias as
        an angle ``b / g``, with prior standard deviation ``tilt_bias_sigma`` (default 0.01: 0.1 m/s^2), and how far the
        world's z (the first body pose's) is from gravity's up, with ``tilt_world_sigma``. 0 holds either at 0.
        The default 0 for the world takes the first pose as level (the synthetic drives start level): a slow tilt
        drift of the map looks exactly like a tilted world, so estimating the world's up also gives in to that
        drift. A bias turns with the body and a map's tilt does not, so turns tell those two apart.
    tilt_heading_bins : int
        Sectors of heading that weigh alike in that fit (:func:`slamlib.slam3d.stages.prior.balance_heading_bins`),
        so that a long straight does not pass its share of the map's tilt to the bias; 1 = every frame alike.
    scan_match : bool or None
        After step 9, move the best particle's pose to the nearest peak of the map score with Gauss-Newton on the
        whole down-sampled scan (:func:`slamlib.slam3d.match.match_scan`), and the particles with it (the
        improved proposal of Grisetti et al. 2007). ``None`` (default): on LIDAR-only, where the constant-velocity
        prior leaves the filter the most to find, off with an IMU; True / False force it. Voxel hash map only
        (other maps are left as they are).
    scan_match_iterations : int
        Most Gauss-Newton steps per frame (each one only if it lowers the cost; the iteration also stops once a step
        is tiny). Default 15; why: "Why these defaults" (``book/defaults.md``).
    """

    particles: int = 300
    scored_points: int = 1000
    temperature: float = 0.02
    ess_fraction: float = DEFAULT_ESS_FRACTION
    estimate: str = "best"
    refine: int = 0
    refine_shrink: float = 0.4
    lidar_only_ground_share: float = 0.1
    tilt_sigma: float = 0.0
    tilt_window: float = 2.0
    tilt_bias_sigma: float = 0.01
    tilt_world_sigma: float = 0.0
    tilt_heading_bins: int = 8
    scan_match: bool | None = None
    scan_match_iterations: int = 15

    def __post_init__(self):
        if int(self.particles) < 1 or int(self.scored_points) < 1:
            raise ValueError(
                f"particles and scored_points must be >= 1, got {self.particles}, {self.scored_points}"
            )
        p = _integer("particles", self.particles, 1, MAX_PARTICLES)
        n = _integer("scored_points", self.scored_points, 1, MAX_SCORED_POINTS)
        if p * n > MAX_POINT_SCORES:
            raise ValueError(
                f"particles x scored_points = {p * n:,} point scores per frame is more than "
                f"{MAX_POINT_SCORES:,}; use fewer particles or points"
            )
        if not _finite("temperature", self.temperature) > 0:
            raise ValueError(
                f"temperature must be finite and > 0, got {self.temperature}"
            )
        if not 0 <= _finite("ess_fraction", self.ess_fraction) <= 1:
            raise ValueError(f"ess_fraction must be in [0, 1], got {self.ess_fraction}")
        if self.estimate not in ("best", "mean"):
            raise ValueError(f"estimate must be 'best' or 'mean', got {self.estimate!r}")
        if int(self.refine) < 0 or not 0 < self.refine_shrink <= 1:
            raise ValueError(
                f"need refine >= 0 and 0 < refine_shrink <= 1, got {self.refine}, {self.refine_shrink}"
            )
        _integer("refine", self.refine, 0, MAX_REFINE)
        if (
            not _finite("tilt_sigma", self.tilt_sigma) >= 0
            or not _finite("tilt_window", self.tilt_window) > 0
        ):
            raise ValueError(
                f"need tilt_sigma >= 0 (0 = off) and tilt_window > 0, got {self.tilt_sigma}, "
                f"{self.tilt_window}"
            )
        _integer("tilt_heading_bins", self.tilt_heading_bins, 1)
        if self.scan_match is not None and not isinstance(
            self.scan_match, (bool, np.bool_)
        ):
            raise ValueError(
                f"scan_match must be True, False or None (LIDAR-only), got {self.scan_match!r}"
            )
        _integer(
            "scan_match_iterations",
            self.scan_match_iterations,
            1,
            MAX_SCAN_MATCH_ITERATIONS,
        )
        for name in ("tilt_bias_sigma", "tilt_world_sigma"):
            if not _finite(name, getattr(self, name)) >= 0:
                raise ValueError(
                    f"need {name} >= 0 (0 = held at 0), got {getattr(self, name)}"
                )
        if not 0 <= _finite("lidar_only_ground_share", self.lidar_only_ground_share) <= 1:
            raise ValueError(
                f"lidar_only_ground_share must be in [0, 1], got {self.lidar_only_ground_share}"
            )


_GROUPS = {
    "scan": ScanConfig,
    "motion": MotionConfig,
    "map": MapConfig,
    "filter": FilterConfig,
}


@dataclass(frozen=True)
class SLAM3DConfig:
    """All settings of :class:`slamlib.slam3d.ParticleSLAM3D`: four groups, the compute backend and the seed.

    Attributes
    ----------
    scan, motion, map, filter : :class:`ScanConfig`, :class:`MotionConfig`, :class:`MapConfig`,
        :class:`FilterConfig`.
    backend : str
        ``"numpy"`` (reference, slow), ``"cpu"`` (Numba; the default, :data:`slamlib.kernels.DEFAULT_BACKEND`) or
        ``"cuda"``.
    seed : int
        Seed of the filter's ``numpy.random.Generator`` (noise, scoring sample, resampling offsets).
    """

    scan: ScanConfig = field(default_factory=ScanConfig)
    motion: MotionConfig = field(default_factory=MotionConfig)
    map: MapConfig = field(default_factory=MapConfig)
    filter: FilterConfig = field(default_factory=FilterConfig)
    backend: str = DEFAULT_BACKEND
    seed: int = 0

    def __post_init__(self):
        _integer("seed", self.seed, 0)

    @classmethod
    def of(cls, **settings) -> SLAM3DConfig:
        """The default configuration with ``settings`` changed by name, e.g.
        ``of(particles=100, kind="morton_bvh")``."""
        return cls().with_(**settings)

    def with_(self, **settings) -> SLAM3DConfig:
        """A copy with ``settings`` changed by name (group fields, or ``backend`` / ``seed``)."""
        groups = {g: {} for g in _GROUPS}
        top = {}
        for name, value in settings.items():
            owner = [g for g, c in _GROUPS.items() if name in {f.name for f in fields(c)}]
            if owner:
                groups[owner[0]][name] = value
            elif name in ("backend", "seed"):
                top[name] = value
            else:
                known = sorted(
                    {f.name for c in _GROUPS.values() for f in fields(c)}
                    | {"backend", "seed"}
                )
                raise ValueError(
                    f"unknown SLAM3D setting {name!r}; known: {', '.join(known)}"
                )
        changed = {g: replace(getattr(self, g), **kw) for g, kw in groups.items() if kw}
        return replace(self, **changed, **top)

    def as_dict(self) -> dict:
        """JSON-friendly nested dict of the settings."""

        def plain(v):
            if isinstance(v, dict):
                return {k: plain(x) for k, x in v.items()}
            return list(v) if isinstance(v, tuple) else v

        return plain(asdict(self))
