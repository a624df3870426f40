"""Settings of the 3D particle SLAM, one group per stage of the filter (:mod:`slamlib.slam3d.stages`).

========== ======================== ============================================================================
group      class                    what it sets
========== ======================== ============================================================================
scan       :class:`ScanConfig`      step 2: crop, down-sampling, de-skewing
motion     :class:`MotionConfig`    steps 3, 5, 6: the motion source and step 6's spread; its
                                    ``constant_velocity`` (:class:`ConstantVelocityConfig`) the LIDAR-only source
map        :class:`MapConfig`       steps 8 and 10: the map structure, its parameters typed per kind
upkeep     :class:`UpkeepConfig`    after step 10: pruning and eviction
filter     :class:`FilterConfig`    the particle filter itself: particles, scoring sample, tempering, steps 9, 11
prior      :class:`TiltConfig`      step 8's second term: roll and pitch held to gravity
search     :class:`AnnealConfig`    annealing rounds inside a frame
polish     :class:`ScanMatchConfig` scan matching of step 9's pose
========== ======================== ============================================================================

Every default is written once: here, or as a constant of the lower module that owns it (the backend, the
map's parameters, ``ess_fraction``), which the field takes. The step functions of :mod:`slamlib.slam3d.steps`
resolve their defaults from these groups, and ``slamlib run`` reads its option defaults from them
(``tests/test_defaults.py`` checks both). Why a default has its value: the book's "Why these defaults".

Build a configuration by group (``SLAM3DConfig(filter=FilterConfig(particles=100))``) or by setting name
(``SLAM3DConfig.of(particles=100, max_range=30.0, anneal_rounds=2)``: every setting name is unique across the
groups; a nested group by its name and a dict, ``of(constant_velocity={"window": 3})``, or dotted,
``of(**{"constant_velocity.window": 3})``). The names before the stages (``refine``, ``estimate``, ``cv_*``,
``lidar_only_ground_share``, a map's ``params`` dict, ``None`` for ``deskew`` / ``scan_match``) are still
accepted by :meth:`SLAM3DConfig.of` with a ``DeprecationWarning`` naming the new one (:data:`RENAMED`).
"""

from __future__ import annotations

import inspect
import warnings
from dataclasses import (
    asdict,
    dataclass,
    field,
    fields,
    is_dataclass,
    make_dataclass,
    replace,
)

import numpy as np

from slamlib.kernels import BACKENDS, DEFAULT_BACKEND
from slamlib.kitti.velodyne import SWEEP_PERIOD_S
from slamlib.maps import DEFAULT_MAP_KIND, MAP_TYPES, make_map
from slamlib.resampling import DEFAULT_ESS_FRACTION
from slamlib.slam3d.match import MATCH_TOLERANCE

__all__ = [
    "AUTO",
    "IMU_PARTICLES",
    "LIDAR_ONLY_PARTICLES",
    "MOTION_MODELS",
    "POSE_ESTIMATES",
    "ScanConfig",
    "ConstantVelocityConfig",
    "MotionConfig",
    "VoxelHashParams",
    "MortonBVHParams",
    "MapConfig",
    "UpkeepConfig",
    "FilterConfig",
    "TiltConfig",
    "AnnealConfig",
    "ScanMatchConfig",
    "SLAM3DConfig",
    "MAP_KINDS",
    "TILT_UP_SOURCES",
    "TILT_BIAS_MODELS",
    "OLD_MAP_NAMES",
    "RENAMED",
]

#: A setting left to the data: ``deskew`` (the scans that were swept), ``scan_match`` (on unless the tilt prior is on
#: and ``match_tilt`` off),
#: ``particles`` (by the mode).
AUTO = "auto"
#: ``TiltConfig.tilt_sigma = "adaptive"``: the prior's weight from how far the tilt has walked against the
#: accelerometer's noise (:mod:`slamlib.slam3d.stages.prior`, "How much to trust the accelerometer").
ADAPTIVE = "adaptive"
#: ``TiltConfig.tilt_up``: what separates gravity from the vehicle's acceleration, the IMU's velocities or the
#: filter's own positions over the window (the default) (:mod:`slamlib.slam3d.stages.prior`).
TILT_UP_SOURCES = ("velocity", "positions")
#: ``TiltConfig.tilt_bias``: how the accelerometer's bias is told from the map's tilt, least squares in heading
#: sectors with the world's up held, or a Kalman filter that lets the tilt walk (the default)
#: (:mod:`slamlib.slam3d.stages.prior`).
TILT_BIAS_MODELS = ("sectors", "kalman")
#: ``FilterConfig.particles = "auto"`` with an IMU: with scan matching on, the fewest particles tried (100, 200, 300)
#: that lost no development run to KISS-ICP ("Why these defaults", ``book/defaults_record.md``).
IMU_PARTICLES = 300
#: ``FilterConfig.particles = "auto"`` LIDAR-only: scan matching climbs from step 9's pose to the peak, so the
#: particles need only find its basin (why this many: "Why these defaults", ``book/defaults_record.md``).
LIDAR_ONLY_PARTICLES = 100
#: Map kinds (:func:`slamlib.maps.make_map`, the keys of :data:`slamlib.maps.MAP_TYPES`): hashed NDT voxels, exact
#: points in a Morton-code BVH.
MAP_KINDS = tuple(MAP_TYPES)
#: Earlier spellings of the map kinds, still accepted by ``slamlib run --map`` (with a note) but not here.
OLD_MAP_NAMES = {"voxel": "voxel_hash", "bvh": "morton_bvh"}
#: Step 9's estimates: the best particle, or the weighted mean of the particles near it.
POSE_ESTIMATES = ("best", "mean")
#: Most particles: the particle arrays take ~200 bytes each (pose, noise, weights, copies when resampling), so
#: 10**7 particles already need ~2 GB; more would fail to allocate (10**9 asked for 67 GiB) or run for hours a frame.
MAX_PARTICLES = 10_000_000
#: Most scan points scored per particle per frame (a LIDAR scan has ~120k before down-sampling).
MAX_SCORED_POINTS = 1_000_000
#: Most point scores per frame, ``particles * scored_points`` (work per frame; 10**10 is minutes per frame on a GPU).
MAX_POINT_SCORES = 10_000_000_000
#: Most annealing rounds per frame (each one costs a whole scoring pass).
MAX_ANNEAL_ROUNDS = 100
#: Most Newton steps of the scan matcher per frame (``ScanMatchConfig.scan_match_iterations``; each a pass
#: over the matched points, ``ScanMatchConfig.match_voxel``).
MAX_SCAN_MATCH_ITERATIONS = 100
#: The scan match's validation gate (``ScanMatchConfig.match_gate``), in step 6's spreads. Were the corrections
#: Gaussian with the spread's deviations, 5.3 would pass all but one in ten thousand (the chi-square quantile of
#: 6 degrees of freedom); they are not: the spread is the motion's uncertainty, and the climb's own steps add a
#: heavier tail. On the route 07 development drives (scene seeds 0-3, with and without the IMU) every correction
#: outside two leaps was at most 18.9 spreads; the leaps, which broke two LIDAR-only runs, were 114 and 353
#: (``book/defaults_record.md``, "The scan match's gate"). Too low a gate rejects a true correction, and the next frame
#: then needs a larger one; too high a gate lets a smaller leap through. 30 is 1.6 times the first, a quarter of
#: the second.
MATCH_GATE = 30.0
#: Most frames the LIDAR-only velocity is averaged over (``ConstantVelocityConfig.window``; 10 frames = 1 s at
#: 10 Hz).
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
#: Setting names before the filter's stages, and the names that replaced them (:meth:`SLAM3DConfig.of`).
RENAMED = {
    "refine": "anneal_rounds",
    "refine_shrink": "anneal_shrink",
    "estimate": "pose_estimate",
    "cv_accel": "constant_velocity.accel",
    "cv_angular_accel": "constant_velocity.angular_accel",
    "cv_start_speed": "constant_velocity.start_speed",
    "cv_start_rounds": "constant_velocity.start_rounds",
    "cv_window": "constant_velocity.window",
    "cv_damping": "constant_velocity.damping",
    "lidar_only_ground_share": "constant_velocity.ground_share",
}


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


def _tri_state(name: str, value, what: str):
    """``value`` of a tri-state setting: ``"auto"`` (:data:`AUTO`), True or False; ``None``, the spelling before,
    becomes ``"auto"`` with a DeprecationWarning. ValueError naming ``name`` otherwise."""
    if value is None:
        warnings.warn(
            f"{name}=None is now {name}={AUTO!r}", DeprecationWarning, stacklevel=4
        )
        return AUTO
    if isinstance(value, str) and value == AUTO:
        return AUTO
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    raise ValueError(f"{name} must be True, False or {AUTO!r} ({what}), got {value!r}")


def _spreads(owner, names_sizes) -> None:
    """Check and store as float tuples the per-axis spreads ``names_sizes`` of the frozen dataclass ``owner``."""
    for name, size in names_sizes:
        v = np.asarray(getattr(owner, name), dtype=np.float64)
        if v.shape != (size,) or not np.all(np.isfinite(v)) or not np.all(v >= 0):
            raise ValueError(
                f"{name} must be {size} finite non-negative numbers, got {getattr(owner, name)!r}"
            )
        object.__setattr__(owner, name, tuple(float(x) for x in v))


@dataclass(frozen=True)
class ScanConfig:
    """Step 2, the scan stage: how a raw scan becomes the body-frame points the filter uses.

    Attributes
    ----------
    min_range, max_range : float
        Range crop in the Velodyne frame, metres (drops returns off the car itself and sparse far returns).
    downsample_voxel : float
        Edge of the scan's down-sampling voxel, metres (one point kept per voxel; 0 = off). Not the map's voxel
        (:attr:`VoxelHashParams.voxel_size`).
    deskew : "auto", True or False
        Motion-compensate each scan (:func:`slamlib.slam3d.steps.deskew_scan`) with the frame's motion. ``"auto"``
        (the default): the frames whose ``swept`` says their scan was taken over a sweep
        (:func:`slamlib.slam3d.steps.should_deskew`: real KITTI raw drives and synthetic drives written with
        ``distortion``, the default drive among them), not scans cast from one pose or already
        motion-compensated (the KITTI odometry benchmark's), where it would add the very error it removes.
        True / False: every frame / none.
    sweep_period : float
        Seconds one sweep takes (KITTI's HDL-64E: 0.10315 s, measured on raw drive 0001).
    """

    min_range: float = 3.0
    max_range: float = 60.0
    downsample_voxel: float = 0.25
    deskew: str | bool = AUTO
    sweep_period: float = SWEEP_PERIOD_S

    def __post_init__(self):
        _finite("min_range", self.min_range)
        # max_range may be inf (no far crop), not NaN
        if not 0 <= self.min_range < self.max_range:
            raise ValueError(
                f"need 0 <= min_range < max_range, got {self.min_range}, {self.max_range}"
            )
        if not _finite("downsample_voxel", self.downsample_voxel) >= 0:
            raise ValueError(
                f"downsample_voxel must be >= 0 (0 = off), got {self.downsample_voxel}"
            )
        if not _finite("sweep_period", self.sweep_period) > 0:
            raise ValueError(f"sweep_period must be > 0 s, got {self.sweep_period}")
        deskew = _tri_state("deskew", self.deskew, "when the scans are swept")
        object.__setattr__(self, "deskew", deskew)


#: Step 3's motion sources: the IMU's velocities and rates (LIDAR-only when the data has none), or the filter's
#: own last estimated motion held (LIDAR-only; :class:`slamlib.slam3d.stages.ConstantVelocity`).
MOTION_MODELS = ("imu", "constant_velocity")


@dataclass(frozen=True)
class ConstantVelocityConfig:
    """The LIDAR-only motion source (:class:`slamlib.slam3d.stages.ConstantVelocity`): step 3 holds the filter's
    own last estimated twist, step 6 covers what that cannot know.

    Its error over a frame is the change of velocity in that frame, ``a dt`` over ``dt`` seconds, i.e. ``a dt^2``
    in position (``alpha dt^2`` in angle): step 6 adds ``accel dt^2`` (m) and ``angular_accel dt^2`` (rad) to the
    motion spreads, with ``a`` and ``alpha`` the accelerations a car typically has between two scans: about
    2 m/s^2 forward (braking, pulling away), 0.5 m/s^2 sideways and up, 0.5 rad/s^2 in yaw (entering a turn),
    0.2 rad/s^2 in roll and pitch. At 10 Hz that is 2 cm and 0.29 deg: several times the IMU model's spread.

    Attributes
    ----------
    accel, angular_accel : (3,) m/s^2 forward, left, up; (3,) rad/s^2 about them.
    start_speed : (6,)
        At the second frame no motion is known yet: the spread is ``start_speed dt``, speeds a car may have when
        the sequence starts (15 m/s forward, 1 and 0.5 m/s sideways and up; 0.05, 0.05, 0.3 rad/s in roll,
        pitch, yaw), narrowed by ``start_rounds`` annealing rounds that halve it.
    start_rounds : int
    start_line : bool
        The start search runs a second time from ``P`` poses on a line along the forward axis, the forward
        spread's normal quantiles (:func:`slamlib.slam3d.stages.search.forward_line`), and the filter keeps that
        search where it found another and better optimum, not the one at standing still: its best particle scores
        higher and lies farther than the map's resolution both from the first search's and from the last pose.
        The speed is the start's one large unknown, and independent draws in six dimensions can miss the score's
        narrow peak at it. The last condition holds where the scan's own rings score no motion above the true one
        (a straight street): their optimum sits at standing still ("Why these defaults").
    window : int
        Frames the held twist spans (the motion from the pose ``window`` frames back to the last one, over their
        time: one frame's estimate is noisy, and held it carries its noise into the next frame). 1: the last frame.
    damping : (6,) in [0, 1]
        Factors on the held twist's components (``v`` forward, left, up, then the rates about them): a car's
        vertical velocity and roll and pitch rates are near zero, so an estimate of them is mostly noise, which
        held drifts the height and the pitch. All 1 (no damping) by default; why: "Why these defaults".
    ground_share : float in [0, 1]
        The share of road points in step 8's sample (the rest stands above the road;
        :func:`slamlib.slam3d.preprocess.thin_ground`): the road's rings in the map pull a constant-velocity
        estimate toward zero motion. 1 keeps the scan's own mix.
    """

    accel: tuple = (2.0, 0.5, 0.5)
    angular_accel: tuple = (0.2, 0.2, 0.5)
    start_speed: tuple = (15.0, 1.0, 0.5, 0.05, 0.05, 0.3)
    start_rounds: int = 8
    start_line: bool = True
    window: int = 1
    damping: tuple = (1.0, 1.0, 1.0, 1.0, 1.0, 1.0)
    ground_share: float = 0.1

    def __post_init__(self):
        _integer("start_rounds", self.start_rounds, 0, MAX_ANNEAL_ROUNDS)
        if not isinstance(self.start_line, (bool, np.bool_)):
            raise ValueError(f"start_line must be True or False, got {self.start_line!r}")
        _integer("window", self.window, 1, MAX_CV_WINDOW)
        damping = np.asarray(self.damping, dtype=np.float64)
        if damping.shape != (6,) or not np.all((damping >= 0) & (damping <= 1)):
            raise ValueError(f"damping must be 6 numbers in [0, 1], got {self.damping!r}")
        object.__setattr__(self, "damping", tuple(float(x) for x in damping))
        _spreads(self, (("accel", 3), ("angular_accel", 3), ("start_speed", 6)))
        if not 0 <= _finite("ground_share", self.ground_share) <= 1:
            raise ValueError(f"ground_share must be in [0, 1], got {self.ground_share}")

    def scaled(self, k: float) -> ConstantVelocityConfig:
        """The accelerations and start speeds multiplied by ``k``."""
        return replace(
            self,
            **{n: tuple(k * x for x in getattr(self, n)) for n in _CV_SPREADS},
        )


#: The :class:`ConstantVelocityConfig` fields that are spreads (scaled with the motion noise).
_CV_SPREADS = ("accel", "angular_accel", "start_speed")
#: The :class:`MotionConfig` per-axis spreads.
_MOTION_SPREADS = (
    "sigma_xyz_per_m",
    "sigma_xyz_per_s",
    "sigma_rpy_per_m",
    "sigma_rpy_per_s",
)


@dataclass(frozen=True)
class MotionConfig:
    """Steps 3, 5 and 6, the motion stage: where the motion comes from, and the spread of the motion noise per axis
    (body x, y, z, then roll, pitch, yaw).

    ``sigma_xyz = sigma_xyz_per_m |dp| + sigma_xyz_per_s dt`` (metres) and
    ``sigma_rpy = sigma_rpy_per_m |dp| + sigma_rpy_per_s dt`` (radians), with ``|dp|`` the distance travelled in
    the frame: odometry errors grow with distance (scale errors, slip) and with time (biases), as the odometry
    motion model's ``alpha`` parameters (Thrun, Burgard & Fox 2005, table 5.5).

    ``model``: ``"imu"`` (the IMU's velocities and rates; LIDAR-only on data without them) or
    ``"constant_velocity"`` (LIDAR-only whatever the data). LIDAR-only, ``constant_velocity``
    (:class:`ConstantVelocityConfig`) sets the held twist and what step 6 adds for it.

    Self-tuning (:mod:`slamlib.slam3d.stages.tuning`): with ``self_tuning`` (default True) the stage fits its
    source's scale errors and biases to the filter's innovations, corrects step 5's increment by them and spreads
    step 6 by ``sqrt((tuning_gain q)^2 + tuning_floor^2)``, ``q`` the innovations' scatter per axis; the spreads
    above then serve only the first ``tuning_warmup`` frames. ``tuning_memory`` and ``tuning_noise_memory`` are the
    seconds the fit and the scatter remember; ``tuning_floor`` (6,) is in m, m, m, rad, rad, rad. Why these values:
    "Why these defaults" (``book/defaults_record.md``).
    """

    sigma_xyz_per_m: tuple = (0.02, 0.02, 0.01)
    sigma_xyz_per_s: tuple = (0.05, 0.05, 0.05)
    sigma_rpy_per_m: tuple = (0.0005, 0.0005, 0.002)
    sigma_rpy_per_s: tuple = (0.002, 0.002, 0.005)
    model: str = "imu"
    constant_velocity: ConstantVelocityConfig = field(
        default_factory=ConstantVelocityConfig
    )
    self_tuning: bool = True
    tuning_gain: float = 1.5
    tuning_memory: float = 30.0
    tuning_noise_memory: float = 15.0
    tuning_floor: tuple = (0.005, 0.005, 0.005, 0.0003, 0.0003, 0.0005)
    tuning_warmup: int = 20

    def __post_init__(self):
        if self.model not in MOTION_MODELS:
            raise ValueError(
                f"model must be one of {', '.join(MOTION_MODELS)}, got {self.model!r}"
            )
        _spreads(self, [(name, 3) for name in _MOTION_SPREADS] + [("tuning_floor", 6)])
        if not isinstance(self.self_tuning, (bool, np.bool_)):
            raise ValueError(
                f"self_tuning must be True or False, got {self.self_tuning!r}"
            )
        for name in ("tuning_gain", "tuning_memory", "tuning_noise_memory"):
            if not _finite(name, getattr(self, name)) > 0:
                raise ValueError(
                    f"{name} must be finite and > 0, got {getattr(self, name)!r}"
                )
        _integer("tuning_warmup", self.tuning_warmup, 1)
        if not isinstance(self.constant_velocity, ConstantVelocityConfig):
            raise ValueError(
                f"constant_velocity must be a ConstantVelocityConfig, got {self.constant_velocity!r}"
            )

    def sigma(
        self, trans_delta, dt: float, constant_velocity: bool = False, start: bool = False
    ) -> np.ndarray:
        """Standard deviations ``(6,)`` for a frame that moved ``trans_delta`` (3,) metres in ``dt`` seconds; with
        ``constant_velocity`` (LIDAR-only) widened by ``accel dt^2`` and ``angular_accel dt^2``; ``start``
        (LIDAR-only, no motion known yet) adds ``start_speed dt`` (:class:`ConstantVelocityConfig`)."""
        d, dt = float(np.linalg.norm(trans_delta)), float(dt)
        cv = self.constant_velocity
        s = np.empty(6)
        s[:3] = (
            np.asarray(self.sigma_xyz_per_m) * d + np.asarray(self.sigma_xyz_per_s) * dt
        )
        s[3:] = (
            np.asarray(self.sigma_rpy_per_m) * d + np.asarray(self.sigma_rpy_per_s) * dt
        )
        if constant_velocity:
            s[:3] += np.asarray(cv.accel) * dt**2
            s[3:] += np.asarray(cv.angular_accel) * dt**2
        if start:
            s += np.asarray(cv.start_speed) * dt
        return s

    def scaled(self, k: float) -> MotionConfig:
        """All spreads (and the LIDAR-only accelerations and start speeds) multiplied by ``k``
        (``slamlib run --noise``)."""
        spreads = {n: tuple(k * x for x in getattr(self, n)) for n in _MOTION_SPREADS}
        return replace(
            self, **spreads, constant_velocity=self.constant_velocity.scaled(k)
        )


def _map_params_class(kind: str, name: str):
    """A frozen dataclass of the constructor parameters of the map ``kind``, with the constructor's own defaults
    (written once, there), each checked finite and > 0 where :data:`POSITIVE_MAP_PARAMS` says so."""
    cls = MAP_TYPES[kind]
    params = [
        p for p in inspect.signature(cls.__init__).parameters.values() if p.name != "self"
    ]

    def __post_init__(self):
        for p in params:
            value = getattr(self, p.name)
            if p.name in POSITIVE_MAP_PARAMS and not _finite(p.name, value) > 0:
                raise ValueError(
                    f"map parameter {p.name} must be finite and > 0, got {value!r}"
                )

    doc = (
        f"Parameters of :class:`slamlib.maps.{cls.__name__}` (the map kind ``{kind!r}``), with its defaults: "
        + ", ".join(f"``{p.name}={p.default!r}``" for p in params)
        + "."
    )
    return make_dataclass(
        name,
        [(p.name, p.annotation, field(default=p.default)) for p in params],
        frozen=True,
        namespace={
            "__post_init__": __post_init__,
            "__doc__": doc,
            "__module__": __name__,
        },
    )


VoxelHashParams = _map_params_class("voxel_hash", "VoxelHashParams")
MortonBVHParams = _map_params_class("morton_bvh", "MortonBVHParams")


@dataclass(frozen=True)
class MapConfig:
    """Steps 8 and 10: the map structure and its parameters.

    Attributes
    ----------
    kind : str
        ``"voxel_hash"`` (hashed NDT voxels, :class:`slamlib.maps.VoxelHashMap`) or ``"morton_bvh"`` (exact points
        in a Morton-code BVH, :class:`slamlib.maps.MortonBVHMap`).
    voxel_hash, morton_bvh : :class:`VoxelHashParams`, :class:`MortonBVHParams`
        Each kind's constructor parameters, typed, with the constructor's defaults; :meth:`make` uses those of
        ``kind``.
    """

    kind: str = DEFAULT_MAP_KIND
    voxel_hash: VoxelHashParams = field(default_factory=VoxelHashParams)
    morton_bvh: MortonBVHParams = field(default_factory=MortonBVHParams)

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

    @property
    def params(self) -> dict:
        """The constructor parameters of the chosen kind, as keyword arguments."""
        return asdict(getattr(self, self.kind))

    def make(self):
        """A fresh, empty map of this kind (:func:`slamlib.maps.make_map`)."""
        return make_map(self.kind, **self.params)


@dataclass(frozen=True)
class UpkeepConfig:
    """After step 10, the upkeep stage: what the map forgets (:class:`slamlib.slam3d.stages.MapUpkeep`).

    Attributes
    ----------
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

    prune_every: int = 20
    prune_radius: float = 120.0
    keep_pruned: bool = True
    transient_span: int = 0

    def __post_init__(self):
        if int(self.prune_every) < 0 or not self.prune_radius > 0:
            raise ValueError(
                f"need prune_every >= 0 and prune_radius > 0, got {self.prune_every}, "
                f"{self.prune_radius}"
            )
        _integer("transient_span", self.transient_span, 0)  # frames; 0 = off


@dataclass(frozen=True)
class FilterConfig:
    """The particle filter around the steps.

    Attributes
    ----------
    particles : int or "auto"
        Number of particles ``P``; ``"auto"`` (default): :data:`IMU_PARTICLES` (300) with an IMU,
        :data:`LIDAR_ONLY_PARTICLES` (100) LIDAR-only
        (:meth:`particle_count`; the filter sets it at the first frame, when the mode is known).
    scored_points : int
        Scan points sampled for scoring (step 8) per frame; step 10 merges the whole down-sampled scan.
    temperature : float
        Likelihood tempering: ``log L = score / (N * temperature)`` (:mod:`slamlib.slam3d.pipeline`).
    ess_fraction : float
        Step 11 resamples when the effective sample size is below ``ess_fraction * P`` (1.0: every frame; default
        :data:`slamlib.resampling.DEFAULT_ESS_FRACTION`, 0.5, shared with the 1D and 2D filters).
    pose_estimate : str
        Step 9: ``"best"`` particle or ``"mean"`` (weighted mean of the particles near the best).
    """

    particles: int | str = AUTO
    scored_points: int = 1000
    temperature: float = 0.02
    ess_fraction: float = DEFAULT_ESS_FRACTION
    pose_estimate: str = "best"

    def __post_init__(self):
        if not isinstance(self.particles, str):
            _integer("particles", self.particles, 1, MAX_PARTICLES)
        elif self.particles != AUTO:
            raise ValueError(
                f"particles must be an integer or {AUTO!r}, got {self.particles!r}"
            )
        # the most particles either mode will carry
        p = max(self.particle_count(lidar_only) for lidar_only in (False, True))
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
        if self.pose_estimate not in POSE_ESTIMATES:
            raise ValueError(
                f"pose_estimate must be 'best' or 'mean', got {self.pose_estimate!r}"
            )

    def particle_count(self, lidar_only: bool = False) -> int:
        """``P`` in the mode: ``particles`` when a number, else :data:`LIDAR_ONLY_PARTICLES` LIDAR-only and
        :data:`IMU_PARTICLES` with an IMU."""
        if self.particles == AUTO:
            return LIDAR_ONLY_PARTICLES if lidar_only else IMU_PARTICLES
        return int(self.particles)


@dataclass(frozen=True)
class TiltConfig:
    """Step 8's second term, the prior stage: roll and pitch held to gravity
    (:class:`slamlib.slam3d.stages.TiltPrior`).

    Attributes
    ----------
    tilt_sigma : float
        Radians; > 0 holds roll and pitch to gravity: step 8 adds :func:`slamlib.slam3d.stages.prior.tilt_log_prior`
        with the up direction the accelerometer measured over the last ``tilt_window`` seconds
        (:func:`slamlib.slam3d.stages.prior.gravity_up`). 0 = off; needs an IMU with ``specific_force`` (without
        one the prior is off whatever this is). ``sigma`` is the prior's weight against the map as much as an error
        bar on the measured up; the default 0.003 (3 mrad, with ``ScanMatchConfig.match_tilt`` on) and why: book
        chapter 09 and "Why these defaults" (``book/defaults_record.md``).
        ``"auto"``: ``sigma`` is the measured up's own scatter; ``"adaptive"``: the weight is the gain a Kalman
        filter would give gravity, from that scatter, how far the tilt has walked, and the map's own information
        on the tilt, which the scan match measures, so ``"adaptive"`` also turns ``ScanMatchConfig.match_tilt``
        on (:mod:`slamlib.slam3d.stages.prior`, "How much to trust the accelerometer").
    tilt_window : float
        Seconds of accelerometer samples behind each up measurement (longer: less noise from the velocities); the
        prior holds nothing until the window spans them, at a drive's start and after a frame without an
        accelerometer.
    tilt_bias_sigma, tilt_world_sigma : float
        Radians; with the prior on, the filter also estimates the accelerometer's bias as an angle ``b / g``, with
        prior standard deviation ``tilt_bias_sigma`` (default 0.01: 0.1 m/s^2), and how far the world's z (the
        first body pose's) is from gravity's up, with prior standard deviation ``tilt_world_sigma`` (default 0.05:
        a drive may start on a slope or a cambered road; KITTI raw drive 0001's first pose stands 37 mrad from
        level). 0 holds either at 0. With ``tilt_bias = "kalman"`` the world's tilt is a constant state beside the
        map's walking tilt error, so what the first windows measure goes to the world and a slow drift after it
        to the walk (book chapter 09, "A drive that starts tilted", and fresh10 in ``book/defaults_record.md``). With
        ``"sectors"`` (least squares over the frames whose window spans ``tilt_window``,
        :func:`slamlib.slam3d.stages.prior.tilt_calibration_update`) a slow tilt drift of the map looks exactly like
        a tilted world, so a world estimated there also gives in to that drift; chapter 09 ran ``"sectors"`` with
        the world held (0). A bias turns with the body and a map's tilt does not, so turns tell those two apart.
    tilt_heading_bins : int
        Sectors of heading that weigh alike in that fit (:func:`slamlib.slam3d.stages.prior.balance_heading_bins`),
        so that a long straight does not pass its share of the map's tilt to the bias; 1 = every frame alike.
    tilt_up : str
        What separates gravity from the vehicle's own acceleration over the window: ``"velocity"`` the IMU's
        velocities at its ends (:func:`slamlib.slam3d.stages.prior.gravity_up`), ``"positions"`` (default) the
        filter's own positions over it (:func:`slamlib.slam3d.stages.prior.gravity_up_from_positions`: the
        velocities' noise, scale error and bias drop out).
    tilt_bias : str
        How the bias is told from the map's tilt: ``"sectors"`` least squares over the heading sectors, the world's
        up held (:func:`slamlib.slam3d.stages.prior.tilt_calibration_update`); ``"kalman"`` (default) a Kalman
        filter whose state also holds the map's tilt error as a random walk
        (:func:`slamlib.slam3d.stages.prior.tilt_kalman_update`, the tilt starting at 0; with ``tilt_world_sigma``
        > 0 the state holds the world's tilt too, constant, with that prior sigma, ahead of the walk, and step 8
        holds to that world's up; ``tilt_heading_bins`` unused).
    """

    tilt_sigma: float | str = 0.003
    tilt_window: float = 2.0
    tilt_bias_sigma: float = 0.01
    tilt_world_sigma: float = 0.05
    tilt_heading_bins: int = 8
    tilt_up: str = TILT_UP_SOURCES[1]
    tilt_bias: str = TILT_BIAS_MODELS[1]

    def __post_init__(self):
        for name, choices in (
            ("tilt_up", TILT_UP_SOURCES),
            ("tilt_bias", TILT_BIAS_MODELS),
        ):
            if getattr(self, name) not in choices:
                raise ValueError(
                    f"{name} must be one of {', '.join(map(repr, choices))}, got {getattr(self, name)!r}"
                )
        auto = isinstance(self.tilt_sigma, str)
        if auto and self.tilt_sigma not in (AUTO, ADAPTIVE):
            raise ValueError(
                f"tilt_sigma must be a number >= 0, {AUTO!r} or {ADAPTIVE!r}, got {self.tilt_sigma!r}"
            )
        if (
            not (auto or _finite("tilt_sigma", self.tilt_sigma) >= 0)
            or not _finite("tilt_window", self.tilt_window) > 0
        ):
            raise ValueError(
                f"need tilt_sigma >= 0 (0 = off), {AUTO!r} or {ADAPTIVE!r} and tilt_window > 0, "
                f"got {self.tilt_sigma}, "
                f"{self.tilt_window}"
            )
        _integer("tilt_heading_bins", self.tilt_heading_bins, 1)
        for name in ("tilt_bias_sigma", "tilt_world_sigma"):
            if not _finite(name, getattr(self, name)) >= 0:
                raise ValueError(
                    f"need {name} >= 0 (0 = held at 0), got {getattr(self, name)}"
                )


@dataclass(frozen=True)
class AnnealConfig:
    """The search stage: annealing rounds inside a frame, coarse to fine (:class:`slamlib.slam3d.stages.Annealing`).

    Attributes
    ----------
    anneal_rounds : int
        Rounds per frame, each resampling, perturbing with step 6's spread shrunk and weighing again; 0 = a plain
        particle filter.
    anneal_shrink : float
        Spread factor per round, in ``(0, 1]``.
    collapse_ess, collapse_rounds : float, int
        Further rounds, at most ``collapse_rounds``, while the effective sample size is below ``collapse_ess`` times
        the particles (the weights collapsed: the likelihood is much narrower than the spread); 0 = off, the
        default. Why: "Why these defaults".
    """

    anneal_rounds: int = 0
    anneal_shrink: float = 0.4
    collapse_ess: float = 0.0
    collapse_rounds: int = 3

    def __post_init__(self):
        _integer("anneal_rounds", self.anneal_rounds, 0, MAX_ANNEAL_ROUNDS)
        _integer("collapse_rounds", self.collapse_rounds, 0, MAX_ANNEAL_ROUNDS)
        if not 0 <= _finite("collapse_ess", self.collapse_ess) <= 1:
            raise ValueError(f"collapse_ess must be in [0, 1], got {self.collapse_ess}")
        if not 0 < _finite("anneal_shrink", self.anneal_shrink) <= 1:
            raise ValueError(f"anneal_shrink must be in (0, 1], got {self.anneal_shrink}")


@dataclass(frozen=True)
class ScanMatchConfig:
    """The polish stage: scan matching of step 9's pose (:class:`slamlib.slam3d.stages.ScanMatch`).

    Attributes
    ----------
    scan_match : "auto", True or False
        After step 9, move the best particle's pose to the nearest peak of the map score by Newton steps on the
        down-sampled scan thinned to ``match_voxel`` (:func:`slamlib.slam3d.match.match_scan`), and the particles
        with it (the improved proposal of Grisetti et al. 2007). ``"auto"`` (default): on in both modes (LIDAR-only
        with the road's points holding height and tilt only, :class:`slamlib.slam3d.stages.ScanMatch`), except
        with the tilt prior (``TiltConfig.tilt_sigma`` not 0) and ``match_tilt`` off, when the matcher, climbing
        the map score alone, would undo the prior's pull toward gravity; True forces it, False turns it off (the
        filter alone). Why on with an IMU: "Why these defaults". Voxel hash map only (other maps are left as they
        are).
    scan_match_iterations : int
        Most Newton steps per frame (each one only if it lowers the cost; the iteration also stops once a step is
        tiny). Default 15; why: "Why these defaults" (``book/defaults_record.md``).
    match_voxel : float
        The scan is matched on its points thinned to one per cube of this edge (metres; 0 = every down-sampled
        point, :func:`slamlib.slam3d.preprocess.voxel_downsample` order). KISS-ICP registers a scan thinned
        three times coarser than the map it builds (Vizzo et al. 2023, Sec. III-B) for the same reason: the normal
        equations summed over a few thousand well-spread points fix six numbers as well as over all of them, and the
        dense returns near the car no longer outweigh the rest. Default 0.5 m, the map's voxel edge (why:
        "Why these defaults").
    match_tolerance : float
        The iteration ends at the first step shorter than this (``|delta|`` of the rotation vector and the
        translation, radians and metres alike), without taking it: near the peak the steps shrink faster than
        geometrically, so the rest of the way is shorter still. Default 1e-5 (half a millimetre at 50 m); why
        not KISS-ICP's 1e-4: "Why these defaults".
    match_gate : float
        The farthest the match may move step 9's pose, in step 6's spreads: the correction ``c`` (body x, y, z,
        roll, pitch, yaw, as step 6's noise) is kept when ``sqrt(sum_a (c_a / sigma_a)^2) <= match_gate`` with
        ``sigma`` the frame's spread, otherwise step 9's pose stands (a validation gate, Bar-Shalom & Fortmann,
        "Tracking and Data Association", 1988, sec. 2.3). The cloud spans the motion's uncertainty, so its best
        particle is already within a few spreads of the truth; a Newton climb that ends far outside it has
        followed a wrong peak (moving cars, a repeated facade). Default :data:`MATCH_GATE`; 0: no gate.
    match_tilt : bool
        With the tilt prior on (``TiltConfig.tilt_sigma`` not 0), the match's cost carries it too, weighed as step
        8 weighs it (:mod:`slamlib.slam3d.match`, "Gravity's term"), and ``scan_match = "auto"`` is then on.
        Default True; False: the match on the map score alone, and ``"auto"`` off with the prior.
    """

    scan_match: str | bool = AUTO
    scan_match_iterations: int = 15
    match_voxel: float = 0.5
    match_tolerance: float = MATCH_TOLERANCE
    match_gate: float = MATCH_GATE
    match_tilt: bool = True

    def __post_init__(self):
        object.__setattr__(
            self, "scan_match", _tri_state("scan_match", self.scan_match, "on")
        )
        if not isinstance(self.match_tilt, (bool, np.bool_)):
            raise ValueError(f"match_tilt must be True or False, got {self.match_tilt!r}")
        _integer(
            "scan_match_iterations",
            self.scan_match_iterations,
            1,
            MAX_SCAN_MATCH_ITERATIONS,
        )
        if not _finite("match_voxel", self.match_voxel) >= 0:
            raise ValueError(
                f"match_voxel must be >= 0 (0 = every point), got {self.match_voxel}"
            )
        if not _finite("match_tolerance", self.match_tolerance) > 0:
            raise ValueError(
                f"match_tolerance must be > 0 (radians and metres), got {self.match_tolerance}"
            )
        if not _finite("match_gate", self.match_gate) >= 0:
            raise ValueError(
                f"match_gate must be >= 0 (spreads; 0 = no gate), got {self.match_gate}"
            )


#: The groups of :class:`SLAM3DConfig`, by field name.
_GROUPS = {
    "scan": ScanConfig,
    "motion": MotionConfig,
    "map": MapConfig,
    "upkeep": UpkeepConfig,
    "filter": FilterConfig,
    "prior": TiltConfig,
    "search": AnnealConfig,
    "polish": ScanMatchConfig,
}
#: Nested groups: name -> (the group holding it, its class).
_NESTED = {
    "constant_velocity": ("motion", ConstantVelocityConfig),
    "voxel_hash": ("map", VoxelHashParams),
    "morton_bvh": ("map", MortonBVHParams),
}
_TOP = ("backend", "seed")


def _leaves() -> dict[str, tuple[str, ...]]:
    """Every setting's name and its path: group fields by their own name (nested groups excepted); a nested
    group's fields as ``nested.field`` and, for the maps' parameters (unique names), also by their own name."""
    paths = {}
    for g, cls in _GROUPS.items():
        for f in fields(cls):
            if f.name not in _NESTED:
                paths[f.name] = (g, f.name)
    for nested, (g, cls) in _NESTED.items():
        for f in fields(cls):
            paths[f"{nested}.{f.name}"] = (g, nested, f.name)
            if g == "map":
                paths.setdefault(f.name, (g, nested, f.name))
    return paths


_PATHS = _leaves()


def _replace_path(obj, path: tuple[str, ...], value):
    """``obj`` with the field at ``path`` replaced; a dataclass value replaces a whole group, a dict updates it."""
    head, rest = path[0], path[1:]
    current = getattr(obj, head)
    if rest:
        return replace(obj, **{head: _replace_path(current, rest, value)})
    if isinstance(value, dict) and is_dataclass(current):
        value = replace(current, **value)
    return replace(obj, **{head: value})


@dataclass(frozen=True)
class SLAM3DConfig:
    """All settings of :class:`slamlib.slam3d.ParticleSLAM3D`: one group per stage (module docstring), the compute
    backend and the seed.

    Attributes
    ----------
    scan, motion, map, upkeep, filter, prior, search, polish : :class:`ScanConfig`, :class:`MotionConfig`,
        :class:`MapConfig`, :class:`UpkeepConfig`, :class:`FilterConfig`, :class:`TiltConfig`,
        :class:`AnnealConfig`, :class:`ScanMatchConfig`.
    backend : str
        ``"numpy"`` (reference, slow), ``"cpu"`` (Numba; the default, :data:`slamlib.kernels.DEFAULT_BACKEND`) or
        ``"cuda"``.
    seed : int
        Seed of the filter's ``numpy.random.Generator`` (noise, scoring sample, resampling offsets).
    """

    scan: ScanConfig = field(default_factory=ScanConfig)
    motion: MotionConfig = field(default_factory=MotionConfig)
    map: MapConfig = field(default_factory=MapConfig)
    upkeep: UpkeepConfig = field(default_factory=UpkeepConfig)
    filter: FilterConfig = field(default_factory=FilterConfig)
    prior: TiltConfig = field(default_factory=TiltConfig)
    search: AnnealConfig = field(default_factory=AnnealConfig)
    polish: ScanMatchConfig = field(default_factory=ScanMatchConfig)
    backend: str = DEFAULT_BACKEND
    seed: int = 0

    def __post_init__(self):
        _integer("seed", self.seed, 0)
        if self.backend not in BACKENDS:
            raise ValueError(
                f"backend must be one of {', '.join(map(repr, BACKENDS))}, got {self.backend!r}"
            )
        for g, cls in _GROUPS.items():
            if not isinstance(getattr(self, g), cls):
                raise ValueError(
                    f"{g} must be a {cls.__name__}, got {getattr(self, g)!r}"
                )
        if self.upkeep.transient_span and self.map.kind != "voxel_hash":
            raise ValueError(
                f"transient_span needs the 'voxel_hash' map (its voxels remember when they were hit), "
                f"got kind {self.map.kind!r}"
            )

    @classmethod
    def of(cls, **settings) -> SLAM3DConfig:
        """The default configuration with ``settings`` changed by name, e.g.
        ``of(particles=100, kind="morton_bvh")``."""
        return cls().with_(**settings)

    def with_(self, **settings) -> SLAM3DConfig:
        """A copy with ``settings`` changed by name: a setting (:meth:`setting_names`), a group or nested group
        (a dataclass, or a dict of the fields to change), or ``backend`` / ``seed``. A name of :data:`RENAMED`
        (and a map's ``params`` dict) is taken as its new name, with a DeprecationWarning."""
        config = self
        for name, value in self._renamed(settings).items():
            if name in _TOP or name in _GROUPS:
                path = (name,)
            elif name in _NESTED:
                path = (_NESTED[name][0], name)
            elif name in _PATHS:
                path = _PATHS[name]
            else:
                raise ValueError(
                    f"unknown SLAM3D setting {name!r}; known: {', '.join(self.setting_names())}"
                )
            config = _replace_path(config, path, value)
        return config

    def _renamed(self, settings: dict) -> dict:
        """``settings`` with the names before the stages (:data:`RENAMED`, a map's ``params``) under their new
        names, each with a DeprecationWarning."""
        out = {}
        for name, value in settings.items():
            if name in RENAMED:
                warnings.warn(
                    f"SLAM3D setting {name!r} is now {RENAMED[name]!r}",
                    DeprecationWarning,
                    stacklevel=4,
                )
                out[RENAMED[name]] = value
            elif name == "params":
                kind = settings.get("kind", self.map.kind)
                warnings.warn(
                    f"a map's params dict is now its typed group {kind!r} "
                    f"(e.g. of({kind}={{...}}), or each parameter by name)",
                    DeprecationWarning,
                    stacklevel=4,
                )
                out[kind] = dict(value)
            else:
                out[name] = value
        return out

    @staticmethod
    def setting_names() -> list[str]:
        """Every name :meth:`of` takes for one setting, sorted."""
        return sorted(set(_PATHS) | set(_TOP))

    def as_dict(self) -> dict:
        """JSON-friendly nested dict of the settings."""

        def plain(v):
            if isinstance(v, dict):
                return {k: plain(x) for k, x in v.items()}
            return list(v) if isinstance(v, tuple) else v

        return plain(asdict(self))
