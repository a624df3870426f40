"""The twelve-step contract that every dimension of particle SLAM implements (1D, 2D, 3D).

One algorithm, told at growing dimension: each ``steps`` module (:mod:`slamlib.sim1d.steps`,
:mod:`slamlib.sim2d.steps`, :mod:`slamlib.slam3d.steps`) defines one function per step, 1 to 11, with **the same
name, the same leading parameters in the same order and the same kind of result** (:data:`STEPS`). What a
dimension needs beyond that (a compute ``backend``, map settings, a likelihood width) comes after them and has a
default, so a call written with the shared parameters alone works at every dimension. Step 12 is the filter
object's per-frame method ``step(frame) -> StepInfo`` (:data:`FILTER_STEP`, the :class:`ParticleFilter`
protocol), which calls steps 2-11 in the order :data:`LOOP_ORDER`; :class:`StepsFilter` writes that loop once
for the dimensions that need nothing between the steps (1D, 2D).

The contract is checked, not only written down (``tests/test_contract.py``): :func:`check_steps_module` reads
the signatures, :func:`check_steps_run` calls every step of a dimension on a tiny example
(:class:`StepsExample`) and checks each result against its kinds (:data:`KINDS`), and :func:`check_filter_step`
checks what one call of a filter's ``step`` returns and leaves behind.

One frame, the math (Thrun, Burgard & Fox 2005, table 4.3; log-weights throughout)
----------------------------------------------------------------------------------
With particles ``x_i`` and normalised log-weights ``l_i`` (``logsumexp_i l_i = 0``) after frame ``k - 1``, frame
``k`` with scan ``z`` (step 2), motion reading ``u`` (step 3) and interval ``dt`` (step 4) does

* steps 5 + 6, the proposal: ``x_i' = f(x_i, u, dt) (+) sigma n_i``, ``n_i ~ N(0, I)``, the motion model in each
  particle's own body frame and then noise of spread ``sigma`` (``motion_noise * dt`` in 1D and 2D);
* steps 7 + 8, the likelihood: ``s_i = log p(z | x_i', m)`` against the map ``m`` built so far (the scan placed
  by each particle, scored point by point);
* the weight update (sequential importance sampling, Doucet, Godsill & Andrieu 2000):
  ``l_i' = l_i + s_i - logsumexp_j (l_j + s_j)``, i.e. ``w_i' ~ w_i p(z | x_i')`` -- the prior weight times the
  new likelihood, normalised;
* step 9, the estimate: ``i* = argmax_i l_i'`` and its pose (3D may refine it: a local weighted mean, a scan
  match);
* step 10, the map: ``m <- m + z`` placed by that pose, **in place** (one shared map from the best pose, the seed
  project's scheme; FastSLAM keeps one per particle);
* step 11: systematic resampling when ``ESS = 1 / sum_i w_i'^2 < ess_fraction * P`` (then ``l_i = -log P``).

Shared meanings (the kinds of :data:`KINDS`)
--------------------------------------------
``particles``
    The particle set: ``(P,)`` float64 positions in 1D, ``(P, 3)`` float64 poses ``(x, y, theta)`` in 2D,
    :class:`slamlib.slam3d.steps.Particles3D` ``(R (P,3,3), t (P,3))`` poses ``T_world_body`` in 3D. ``len`` is
    ``P``; indexing with an ``(P,)`` int array selects particles. Steps return new sets and leave their input
    alone.
``log_weights``
    ``(P,)`` float64 **log**-weights, normalised so that ``logsumexp = 0``
    (:func:`slamlib.resampling.normalise_log_weights`) -- at every dimension, never linear weights.
``pose``
    One particle's pose: a float in 1D, ``(3,)`` in 2D, a 4x4 ``T_world_body`` in 3D. Wherever ``particles`` is
    accepted by a transform, one ``pose`` is too (step 7 with one pose gives ``(N, ...)`` instead of
    ``(P, N, ...)``).
``points``
    The scan in the body frame: ``(N,)`` offsets in 1D, ``(N, 2)`` in 2D, ``(N, 3)`` float32 in 3D.
``imu``, ``dt``
    What step 3 and step 4 return: the body velocity (1D: m/s; 2D: ``(speed, yaw rate)``), or
    ``(velocity (3,), angular_rate (3,))`` in 3D; the frame interval in seconds (a float >= 0).
``world_map``
    The map built so far. **Step 10 changes it in place** (and returns that same object): the 3D maps are hash
    tables of tens of MiB that must not be copied every frame, and the 1D and 2D grids follow the same rule.
``rng``
    A :class:`numpy.random.Generator`, passed in: the steps keep no random state.

References: S. Thrun, W. Burgard, D. Fox, *Probabilistic Robotics* (2005), table 4.3 (particle filter);
A. Doucet, S. Godsill, C. Andrieu, "On sequential Monte Carlo sampling methods for Bayesian filtering", Statistics
and Computing 10 (2000); Gothoskar & Tabrizi, CMU 15-418 project page (2017), the twelve steps; R. Labbe,
filterpy (argument order, one interface at every dimension).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass
from types import ModuleType
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np

from slamlib.resampling import (
    DEFAULT_ESS_FRACTION,
    effective_sample_size,
    normalise_log_weights,
    weights_from_log_weights,
)

__all__ = [
    "FILTER_STEP",
    "KINDS",
    "LOOP_ORDER",
    "ParticleFilter",
    "STEPS",
    "StepInfo",
    "StepSpec",
    "StepsExample",
    "StepsFilter",
    "check_filter_step",
    "check_steps_module",
    "check_steps_run",
]


@dataclass(frozen=True)
class StepSpec:
    """One step of the contract: its number, function (or method) name, shared leading parameters, the kinds of
    its results (one name per returned value, a tuple when there are several; see :data:`KINDS`) and what it does.
    """

    number: int
    name: str
    params: tuple[str, ...]
    returns: tuple[str, ...]
    does: str

    @property
    def returns_text(self) -> str:
        """The result as written in the tables: ``points`` or ``(pose, index)``."""
        return (
            self.returns[0]
            if len(self.returns) == 1
            else "(" + ", ".join(self.returns) + ")"
        )


#: What each kind of result is; :func:`check_steps_run` checks every result against its kind.
KINDS: dict[str, str] = {
    "particles": "the particle set, as many (P) and of the same type as went in; the input left unchanged",
    "log_weights": "(P,) float64 log-weights with logsumexp 0",
    "points": "the scan in the body frame: an array of N >= 1 finite points",
    "imu": "the motion reading: finite numbers",
    "dt": "seconds since the previous frame: a float >= 0",
    "world points": "the scan placed by each particle: (P, N, ...) finite (one pose: (N, ...))",
    "scores": "(P,) finite float log-likelihoods",
    "pose": "one particle's pose: what step 7 accepts as one pose",
    "index": "an int in [0, P), the argmax of the log-weights (ties to the lowest)",
    "world_map": "the very map object it was given, changed in place",
    "resampled": "a bool: whether the particles were drawn anew (log-weights then -log P)",
    "StepInfo": "a slamlib.contract.StepInfo: what one frame did",
}

#: The contract: steps 1-11, functions of every dimension's steps module (step 12 is :data:`FILTER_STEP`).
STEPS: tuple[StepSpec, ...] = (
    StepSpec(
        1,
        "initialise_particles",
        ("n_particles", "pose0"),
        ("particles", "log_weights"),
        "P copies of the start pose (default: the world origin), uniform log-weights -log P",
    ),
    StepSpec(
        2,
        "read_scan",
        ("frame",),
        ("points",),
        "the frame's scan in the body frame (preprocessed: cropped, down-sampled)",
    ),
    StepSpec(
        3,
        "read_imu",
        ("frame",),
        ("imu",),
        "the IMU's body velocities (and angular rates)",
    ),
    StepSpec(4, "read_timing", ("frame",), ("dt",), "seconds since the previous frame"),
    StepSpec(
        5,
        "offset_by_motion",
        ("particles", "imu", "dt"),
        ("particles",),
        "every particle moved by the IMU's motion over dt, in its own body frame",
    ),
    StepSpec(
        6,
        "perturb_with_noise",
        ("particles", "sigma", "rng"),
        ("particles",),
        "every particle moved by its own Gaussian draw scaled by sigma",
    ),
    StepSpec(
        7,
        "transform_scan",
        ("particles", "points"),
        ("world points",),
        "the body-frame scan placed in the world by each particle's pose (or one pose)",
    ),
    StepSpec(
        8,
        "score_particles",
        ("particles", "points", "world_map"),
        ("scores",),
        "how well each particle's transformed scan fits the map (steps 7 + 8, fused where it pays)",
    ),
    StepSpec(
        9,
        "pick_best_particle",
        ("particles", "log_weights"),
        ("pose", "index"),
        "the estimate of this frame: the highest-weight particle's pose and its index",
    ),
    StepSpec(
        10,
        "merge_scan",
        ("world_map", "pose", "points"),
        ("world_map",),
        "the scan, placed by the chosen pose, added to the map (in place)",
    ),
    StepSpec(
        11,
        "resample_particles",
        ("particles", "log_weights", "rng"),
        ("particles", "log_weights", "resampled"),
        "systematic resampling when the effective sample size drops (slamlib.resampling.resample_indexes)",
    ),
)

#: Step 12: the filter object's per-frame method (:class:`ParticleFilter`), one call per frame.
FILTER_STEP = StepSpec(
    12,
    "step",
    ("frame",),
    ("StepInfo",),
    "one frame: steps 2-11 in the order LOOP_ORDER on the filter's state (step 1 is its constructor)",
)

#: The steps that one call of step 12 makes, in order: step 1 belongs to the constructor, step 7 is fused into 8.
LOOP_ORDER: tuple[int, ...] = (2, 3, 4, 5, 6, 8, 9, 10, 11)

_BY_NUMBER = {spec.number: spec for spec in STEPS + (FILTER_STEP,)}


# ------------------------------------------------------------------------------------------------ step 12
@dataclass(frozen=True)
class StepInfo:
    """What one call of ``step(frame)`` did (step 12), the same at every dimension, for plots and tests.

    Attributes
    ----------
    moved : particles
        The particles after steps 5-6 (3D: also after any refinement of them), the set step 11 resampled from;
        ``P`` of them, of the dimension's particle type.
    scores : (P,) float64
        Step 8's log-likelihoods ``s_i`` of ``moved`` (all zeros on a frame that was not scored: the first).
        In 1D and 2D ``log_weights = normalise(previous log-weights + scores)``; 3D tempers them first.
    log_weights : (P,) float64
        The normalised log-weights after scoring (``logsumexp = 0``), before step 11.
    weights : (P,) float64
        ``exp(log_weights)``: linear, summing to 1, for plots.
    best : int
        Step 9's index: ``argmax log_weights`` (ties to the lowest index).
    estimate : pose
        Step 9's pose, the frame's estimate (1D: a float; 2D: ``(3,)``; 3D: 4x4 ``T_world_body``). In 1D and 2D
        the pose of ``moved[best]``; 3D may refine it (a local weighted mean, a scan match).
    ess : float
        Effective sample size ``1 / sum weights^2`` (Kong, Liu & Wong 1994), in ``[1, P]``.
    resampled : bool
        Whether step 11 resampled (the filter's log-weights are then ``-log P``).
    mean : pose or None
        The weighted mean pose, where the dimension defines one (1D: ``sum_i w_i x_i``); None otherwise.
    """

    moved: Any
    scores: np.ndarray
    log_weights: np.ndarray
    weights: np.ndarray
    best: int
    estimate: Any
    ess: float
    resampled: bool
    mean: Any = None


@runtime_checkable
class ParticleFilter(Protocol):
    """Step 12 as an interface: a particle filter of any dimension.

    ``particles`` and ``log_weights`` (normalised, ``(P,)``) are its state after the last frame (after step 11);
    ``step(frame)`` runs steps 2-11 of one frame on them and returns a :class:`StepInfo`. Step 1 is the
    constructor's. ``isinstance(f, ParticleFilter)`` checks only that the three names exist;
    :func:`check_filter_step` checks what they hold.
    """

    particles: Any
    log_weights: np.ndarray

    def step(self, frame) -> StepInfo: ...


class StepsFilter:
    """Step 12 written once: ``step(frame)`` calls a steps module's functions in the order :data:`LOOP_ORDER`.

    For a dimension whose filter does nothing between the steps (1D, 2D; 3D's filter adds tempering, annealing,
    scan matching and a tilt prior and keeps its own loop). A subclass sets the class attribute ``steps`` (its
    steps module) and passes the shared settings to ``__init__``; what it adds to the calls it says by overriding
    :meth:`scan_options` (step 2), :meth:`score_options` (step 8), :meth:`merge_pose` (step 10),
    :meth:`resample_options` (step 11) and :meth:`mean_pose` (the optional
    :attr:`StepInfo.mean`). Every step is called with the contract's parameters first and the additions as
    keywords, so its defaults stand for whatever the subclass does not add. The parameters below have the same
    names and order at every dimension that uses this class.

    Parameters
    ----------
    n_particles : int
        P; step 1 puts all of them at the world origin with log-weights ``-log P``.
    world_map : the dimension's map
        Empty or not; changed in place by every :meth:`step` (step 10).
    motion_noise : float or array
        Step 6's spread **per second**, finite and >= 0: step 6 gets ``sigma = motion_noise * dt``.
    rng : numpy.random.Generator
        Source of the motion noise and the resampling offsets (``TypeError`` for anything else).
    ess_fraction : float in [0, 1] or None
        Resample when ``ESS < ess_fraction * P``; ``None`` resamples every frame.

    Attributes
    ----------
    particles, log_weights : the state after the last frame (:class:`ParticleFilter`).
    world_map, motion_noise, rng, ess_fraction : as given.
    """

    steps: ClassVar[ModuleType]

    def __init__(
        self,
        n_particles: int,
        world_map,
        motion_noise,
        rng: np.random.Generator,
        ess_fraction: float | None = DEFAULT_ESS_FRACTION,
    ):
        if not isinstance(rng, np.random.Generator):
            raise TypeError("rng must be a numpy.random.Generator")
        spread = np.asarray(motion_noise, dtype=np.float64)
        if not (np.isfinite(spread).all() and (spread >= 0).all()):
            raise ValueError(
                f"motion_noise must be finite and >= 0, got {motion_noise!r}"
            )
        if ess_fraction is not None and not 0 <= ess_fraction <= 1:
            raise ValueError(
                f"ess_fraction must be in [0, 1] or None, got {ess_fraction!r}"
            )
        # 1
        self.particles, self.log_weights = self.steps.initialise_particles(n_particles)
        self.world_map = world_map
        self.motion_noise = motion_noise
        self.rng = rng
        self.ess_fraction = ess_fraction

    def scan_options(self) -> dict:
        """Keyword arguments this dimension adds to step 2's ``read_scan(frame)`` (none here)."""
        return {}

    def score_options(self) -> dict:
        """Keyword arguments this dimension adds to step 8's ``score_particles(particles, points, world_map)``."""
        return {}

    def merge_pose(self, moved, pose):
        """What step 10 merges the scan with: the best ``pose`` (one shared map, here); a filter whose particles
        each carry a map returns every particle's pose ``moved``."""
        return pose

    def resample_options(self) -> dict:
        """Keyword arguments this dimension adds to step 11's ``resample_particles`` (none here)."""
        return {}

    def mean_pose(self, moved, weights):
        """The weighted mean pose of ``moved`` for :attr:`StepInfo.mean`, or None (none here)."""
        return None

    @property
    def weights(self) -> np.ndarray:
        """The particles' linear weights ``exp(log_weights)`` (summing to 1), for plots."""
        return weights_from_log_weights(self.log_weights)

    @property
    def estimate(self):
        """The best particle's pose (step 9 on the current state)."""
        return self.steps.pick_best_particle(self.particles, self.log_weights)[0]

    def step(self, frame) -> StepInfo:
        """Steps 2-11 for one frame (step 12 is calling this for every frame); see the module for the math."""
        s = self.steps
        points = s.read_scan(frame, **self.scan_options())  # 2
        imu = s.read_imu(frame)  # 3
        dt = s.read_timing(frame)  # 4
        moved = s.offset_by_motion(self.particles, imu, dt)  # 5
        moved = s.perturb_with_noise(moved, self.motion_noise * dt, self.rng)  # 6
        # 7 + 8
        scores = s.score_particles(moved, points, self.world_map, **self.score_options())
        log_w = normalise_log_weights(self.log_weights + scores)
        pose, best = s.pick_best_particle(moved, log_w)  # 9
        s.merge_scan(self.world_map, self.merge_pose(moved, pose), points)  # 10
        self.particles, self.log_weights, resampled = s.resample_particles(  # 11
            moved, log_w, self.rng, self.ess_fraction, **self.resample_options()
        )
        weights = weights_from_log_weights(log_w)
        return StepInfo(
            moved=moved,
            scores=scores,
            log_weights=log_w,
            weights=weights,
            best=best,
            estimate=pose,
            ess=effective_sample_size(weights),
            resampled=resampled,
            mean=self.mean_pose(moved, weights),
        )


# ------------------------------------------------------------------------------------------------ checks
def check_steps_module(module: ModuleType) -> list[str]:
    """Where ``module``'s signatures break the contract: one line per problem (empty when it keeps it).

    For every :data:`STEPS` entry the module must define a function of that name whose leading parameters are
    exactly ``spec.params`` (names and order) and whose other parameters all have defaults. What the functions
    return is :func:`check_steps_run`'s part.
    """
    problems = []
    for spec in STEPS:
        fn = getattr(module, spec.name, None)
        if not callable(fn):
            problems.append(
                f"{module.__name__}: step {spec.number} {spec.name} is missing"
            )
            continue
        params = list(inspect.signature(fn).parameters.values())
        lead = tuple(p.name for p in params[: len(spec.params)])
        if lead != spec.params:
            problems.append(
                f"{module.__name__}.{spec.name}: leading parameters {lead}, contract {spec.params}"
            )
        extra = [
            p.name
            for p in params[len(spec.params) :]
            if p.default is inspect.Parameter.empty
            and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)
        ]
        if extra:
            problems.append(
                f"{module.__name__}.{spec.name}: extra parameters without defaults: {extra}"
            )
    return problems


@dataclass(frozen=True)
class StepsExample:
    """A tiny input on which :func:`check_steps_run` calls every step of one dimension.

    Attributes
    ----------
    frame : a frame that steps 2-4 read, with a non-empty scan, ``dt > 0`` and some motion (step 5 must move the
        particles).
    new_map : callable returning a fresh, empty map of the dimension.
    map_size : callable ``map -> int``, how much a map holds (it must grow when step 10 merges a scan).
    sigma : step 6's spread, > 0 (1D: a float; 2D: ``(3,)``; 3D: ``(6,)``).
    pose0 : a start pose other than the origin, in the dimension's pose form (what step 9 returns).
    n_particles : P (at least 3: step 11's check needs a set whose ESS can drop below P / 2).
    seed : of the generator passed to steps 6 and 11.
    """

    frame: Any
    new_map: Callable[[], Any]
    map_size: Callable[[Any], int]
    sigma: Any
    pose0: Any
    n_particles: int = 6
    seed: int = 0


class _Stop(Exception):
    """A step raised or returned something the next checks cannot use: the check ends there."""


def _type_name(x) -> str:
    """``bool`` for a Python bool, ``numpy.bool`` for numpy's (which numpy 2 also calls ``bool``)."""
    t = type(x)
    return (
        t.__qualname__
        if t.__module__ == "builtins"
        else f"{t.__module__}.{t.__qualname__}"
    )


def _close(a, b) -> bool:
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    return a.shape == b.shape and bool(np.allclose(a, b, rtol=1e-9, atol=1e-9))


def _log_weights_problem(lw, n: int) -> str | None:
    """What is wrong with ``lw`` as ``(n,)`` normalised log-weights, or None."""
    if not isinstance(lw, np.ndarray) or lw.dtype != np.float64 or lw.shape != (n,):
        shape = getattr(lw, "shape", None)
        return f"log_weights {type(lw).__name__} {getattr(lw, 'dtype', '')} {shape}, not ({n},) float64"
    if np.isnan(lw).any() or np.isposinf(lw).any():
        return "log_weights hold NaN or +inf"
    total = float(np.logaddexp.reduce(lw))
    if not abs(total) < 1e-9:
        return f"log_weights are not normalised: logsumexp = {total!r}, not 0"
    return None


def check_steps_run(module: ModuleType, example: StepsExample) -> list[str]:
    """Where ``module``'s steps, **called** on ``example``, return something else than the contract says.

    Calls steps 1-11 with the contract's parameters only (every extra at its default), in the filter's order,
    and checks each result against its kinds (:data:`KINDS`): step 1 gives ``(particles, log_weights)``, ``P``
    particles at ``pose0`` (default: the origin, where step 7 leaves a scan unmoved) with log-weights ``-log P``;
    step 2 a non-empty finite scan; step 3 finite numbers; step 4 a float ``dt >= 0``; steps 5 and 6 ``P``
    particles of the input's type, moved, the input left unchanged; step 7 ``(P, N, ...)`` world points, and
    for one pose its row of them; step 9 ``(pose, index)`` with a Python ``int`` index at the argmax of the
    log-weights and the pose of that particle; step 10 the very map it was given, grown; step 8 ``(P,)`` finite
    float scores, the map unchanged; step 11 ``(particles, log_weights, resampled)``: a degenerate set resampled
    (``True``, every particle a copy of the heaviest, ``-log P``), a uniform set kept (``False``, the same
    particles and log-weights), ``resampled`` a ``bool``. Two particle sets are compared by where step 7 places
    the scan, which works at every dimension. A step that raises ends the check; its error is the last problem.

    Returns one line per problem (empty when the module keeps the contract on this example).
    """
    problems: list[str] = []
    n = example.n_particles
    rng = np.random.default_rng(example.seed)

    def problem(number: int, text: str) -> None:
        spec = _BY_NUMBER[number]
        problems.append(f"{module.__name__}.{spec.name} (step {number}): {text}")

    def call(number: int, *args):
        spec = _BY_NUMBER[number]
        try:
            out = getattr(module, spec.name)(*args)
        except Exception as e:  # the check reports it, whatever it is
            problem(number, f"raised {type(e).__name__}: {e}")
            raise _Stop from e
        if len(spec.returns) > 1 and not (
            isinstance(out, tuple) and len(out) == len(spec.returns)
        ):
            got = f"{len(out)} values" if isinstance(out, tuple) else type(out).__name__
            problem(number, f"returns {got}, the contract says {spec.returns_text}")
            raise _Stop
        return out

    def placed(particles_or_pose, points) -> np.ndarray:
        return np.asarray(module.transform_scan(particles_or_pose, points), np.float64)

    def particles_problem(number, out, given) -> None:
        size = len(out) if hasattr(out, "__len__") else None
        if type(out) is not type(given) or size != n:
            problem(
                number,
                f"returns {type(out).__name__} of {size} particles, "
                f"not {n} {type(given).__name__}",
            )
            raise _Stop

    def index_pose_problem(number, pose, index, particles, log_w, points) -> None:
        if type(index) is not int:
            problem(number, f"index is {_type_name(index)}, not int")
        elif index != int(np.argmax(log_w)):
            problem(number, f"index {index} is not the argmax {int(np.argmax(log_w))}")
        elif not _close(placed(pose, points), placed(particles, points)[index]):
            problem(
                number, f"pose does not place the scan as particle {index} does (step 7)"
            )

    try:
        # step 1, with and without a start pose
        particles, log_w = call(1, n)
        if not (hasattr(particles, "__len__") and len(particles) == n):
            problem(1, f"returns {type(particles).__name__}, not {n} particles")
            raise _Stop
        if (msg := _log_weights_problem(log_w, n)) is not None:
            problem(1, msg)
        elif not _close(log_w, np.full(n, -np.log(n))):
            problem(1, "log-weights are not uniform (-log P)")
        start, _ = call(1, n, example.pose0)
        if not _close(call(9, start, log_w)[0], example.pose0):
            problem(1, "particles do not start at pose0")
        # steps 2-4
        points = call(2, example.frame)
        if not (
            isinstance(points, np.ndarray)
            and len(points) > 0
            and np.isfinite(points).all()
        ):
            problem(2, f"points are not a non-empty finite array: {points!r:.60}")
            raise _Stop
        imu = call(3, example.frame)
        try:
            finite = bool(np.isfinite(np.asarray(imu, dtype=np.float64)).all())
        except (TypeError, ValueError):
            finite = False
        if not finite:
            problem(3, f"imu is not finite numbers: {imu!r:.60}")
        dt = call(4, example.frame)
        if type(dt) not in (float, np.float64) or not (np.isfinite(dt) and dt >= 0):
            problem(4, f"dt is {dt!r} ({_type_name(dt)}), not a float >= 0")
        # step 7 on the start set, and step 9: ties to the lowest index, the origin leaves the scan unmoved
        world = placed(particles, points)
        if world.shape[:2] != (n, len(points)) or not np.isfinite(world).all():
            problem(7, f"world points {world.shape}, not ({n}, {len(points)}, ...)")
            raise _Stop
        pose, index = call(9, particles, log_w)
        index_pose_problem(9, pose, index, particles, log_w, points)
        if not _close(placed(pose, points), np.asarray(points, np.float64)):
            problem(1, "the default start pose is not the origin (step 7 moves the scan)")
        # steps 5 and 6: new particles, moved, the input unchanged
        moved = call(5, particles, imu, dt)
        particles_problem(5, moved, particles)
        if not _close(placed(particles, points), world):
            problem(5, "changed its input particles")
        if _close(placed(moved, points), world):
            problem(5, "did not move the particles")
        before = placed(moved, points)
        noisy = call(6, moved, example.sigma, rng)
        particles_problem(6, noisy, moved)
        if not _close(placed(moved, points), before):
            problem(6, "changed its input particles")
        if _close(placed(noisy, points), before):
            problem(6, "did not move the particles")
        world = placed(noisy, points)
        # step 10 (the map must hold something for step 8 to score against)
        world_map = example.new_map()
        size = example.map_size(world_map)
        merged = call(10, world_map, pose, points)
        if merged is not world_map:
            problem(10, f"returns {type(merged).__name__}, not the map it was given")
        if not example.map_size(world_map) > size:
            problem(10, "did not change the map it was given (in place)")
        # step 8
        size = example.map_size(world_map)
        scores = call(8, noisy, points, world_map)
        if not (
            isinstance(scores, np.ndarray)
            and scores.dtype.kind == "f"
            and scores.shape == (n,)
            and np.isfinite(scores).all()
        ):
            problem(8, f"scores are not ({n},) finite floats: {scores!r:.60}")
            raise _Stop
        if example.map_size(world_map) != size:
            problem(8, "changed the map")
        # step 9 on the scored set
        log_w = normalise_log_weights(log_w + scores)
        pose, index = call(9, noisy, log_w)
        index_pose_problem(9, pose, index, noisy, log_w, points)
        # step 11: a degenerate set is resampled, a uniform one kept
        peaked = normalise_log_weights(np.r_[0.0, np.full(n - 1, -30.0)])
        for lw, must in ((peaked, True), (np.full(n, -np.log(n)), False)):
            out, out_lw, resampled = call(11, noisy, lw, rng)
            particles_problem(11, out, noisy)
            if not _close(placed(noisy, points), world):
                problem(11, "changed its input particles")
            if type(resampled) is not bool:
                problem(11, f"resampled is {_type_name(resampled)}, not bool")
            if (msg := _log_weights_problem(out_lw, n)) is not None:
                problem(11, msg)
            elif resampled is not must:
                problem(
                    11,
                    f"resampled is {resampled} for ESS {effective_sample_size(np.exp(lw)):.3g} of {n}",
                )
            elif must and not (
                _close(out_lw, np.full(n, -np.log(n)))
                and _close(placed(out, points), np.repeat(world[:1], n, axis=0))
            ):
                problem(
                    11,
                    "a resampled degenerate set is not P copies of its heaviest particle at -log P",
                )
            elif not must and not (
                _close(out_lw, lw) and _close(placed(out, points), world)
            ):
                problem(11, "a set that needs no resampling changed")
    except _Stop:
        pass
    except (
        Exception
    ) as e:  # a result the checks themselves cannot handle (step 7 on it fails): reported
        problems.append(f"{module.__name__}: the check stopped, {type(e).__name__}: {e}")
    return problems


def check_filter_step(
    filt, frame, module: ModuleType, estimate_is_best: bool = True
) -> list[str]:
    """Where one call ``filt.step(frame)`` (step 12) breaks the contract: one line per problem (empty: none).

    ``filt`` must be a :class:`ParticleFilter`, and the call must return a :class:`StepInfo` whose ``moved`` are
    ``P = len(filt.particles)`` particles, ``scores`` ``(P,)`` finite floats, ``log_weights`` normalised ``(P,)``,
    ``weights = exp(log_weights)``, ``best`` a Python ``int`` at their argmax, ``estimate`` a pose (step 7 of
    ``module`` places a scan with it) -- with ``estimate_is_best`` (1D, 2D) the pose of ``moved[best]`` --,
    ``ess = 1 / sum weights^2`` and ``resampled`` a ``bool``; afterwards ``filt`` holds ``P`` particles and
    normalised log-weights: ``-log P`` when it resampled, ``info.log_weights`` when not.
    """
    name = type(filt).__name__
    if not isinstance(filt, ParticleFilter):
        return [f"{name} is not a ParticleFilter (step, particles, log_weights)"]
    n = len(filt.particles)
    info = filt.step(frame)
    if not isinstance(info, StepInfo):
        return [f"{name}.step returns {type(info).__name__}, not StepInfo"]
    problems = []
    bad = problems.append
    if len(info.moved) != n:
        bad(f"{name}.step: moved holds {len(info.moved)} particles, not {n}")
        return problems
    scores = info.scores
    if not (
        isinstance(scores, np.ndarray)
        and scores.dtype.kind == "f"
        and scores.shape == (n,)
        and np.isfinite(scores).all()
    ):
        bad(f"{name}.step: scores are not ({n},) finite floats")
    if (msg := _log_weights_problem(info.log_weights, n)) is not None:
        bad(f"{name}.step: info.{msg}")
        return problems
    if not _close(info.weights, np.exp(info.log_weights)):
        bad(f"{name}.step: weights are not exp(log_weights)")
    if type(info.best) is not int or info.best != int(np.argmax(info.log_weights)):
        bad(f"{name}.step: best {info.best!r} is not the argmax of log_weights (an int)")
    points = module.read_scan(frame)
    try:
        at_estimate = np.asarray(module.transform_scan(info.estimate, points), float)
    except Exception as e:  # reported, whatever it is
        bad(f"{name}.step: estimate is not a pose ({type(e).__name__}: {e})")
    else:
        if estimate_is_best and type(info.best) is int and 0 <= info.best < n:
            moved_at = np.asarray(module.transform_scan(info.moved, points), float)
            if not _close(at_estimate, moved_at[info.best]):
                bad(f"{name}.step: estimate is not the pose of moved[best]")
    if not np.isclose(info.ess, 1.0 / np.sum(np.exp(info.log_weights) ** 2), rtol=1e-9):
        bad(f"{name}.step: ess {info.ess!r} is not 1 / sum(weights^2)")
    if type(info.resampled) is not bool:
        bad(f"{name}.step: resampled is {_type_name(info.resampled)}, not bool")
    if len(filt.particles) != n:
        bad(f"{name}: holds {len(filt.particles)} particles after step, not {n}")
    if (msg := _log_weights_problem(filt.log_weights, n)) is not None:
        bad(f"{name}: after step, {msg}")
    elif info.resampled and not _close(filt.log_weights, np.full(n, -np.log(n))):
        bad(f"{name}: resampled, but its log-weights are not -log P")
    elif not info.resampled and not _close(filt.log_weights, info.log_weights):
        bad(f"{name}: not resampled, but its log-weights are not info.log_weights")
    return problems
