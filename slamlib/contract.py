"""The twelve-step contract that every dimension of particle SLAM implements (1D, 2D, 3D).

One algorithm, told at growing dimension: each ``steps`` module (:mod:`slamlib.sim1d.steps`,
:mod:`slamlib.sim2d.steps`, :mod:`slamlib.slam3d.steps`) defines one function per step, 1 to 11, with **the same
name, the same leading parameters in the same order and the same kind of result** (:data:`STEPS`). What a
dimension needs beyond that (a compute ``backend``, map settings, a likelihood width) comes after them and has a
default, so a call written with the shared parameters alone works at every dimension. Step 12 is the filter
object's per-frame method ``step(frame) -> StepInfo`` (:data:`FILTER_STEP`, the :class:`ParticleFilter`
protocol), which calls steps 2-11 in the order :data:`LOOP_ORDER`; :class:`StepsFilter` writes that loop once
for the dimensions that need nothing between the steps (1D, 2D).

``tests/test_contract.py`` checks each steps module against :data:`STEPS` with :func:`check_steps_module`.

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

Shared meanings
---------------
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
from dataclasses import dataclass
from types import ModuleType
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np

from slamlib.resampling import (
    effective_sample_size,
    normalise_log_weights,
    weights_from_log_weights,
)

__all__ = [
    "FILTER_STEP",
    "LOOP_ORDER",
    "ParticleFilter",
    "STEPS",
    "StepInfo",
    "StepSpec",
    "StepsFilter",
    "check_steps_module",
]


@dataclass(frozen=True)
class StepSpec:
    """One step of the contract: its number, function (or method) name, shared leading parameters and result."""

    number: int
    name: str
    params: tuple[str, ...]
    returns: str
    does: str


#: The contract: steps 1-11, functions of every dimension's steps module (step 12 is :data:`FILTER_STEP`).
STEPS: tuple[StepSpec, ...] = (
    StepSpec(
        1,
        "initialise_particles",
        ("n_particles", "pose0"),
        "(particles, log_weights)",
        "P copies of the start pose (default: the world origin), uniform log-weights -log P",
    ),
    StepSpec(
        2,
        "read_scan",
        ("frame",),
        "points",
        "the frame's scan in the body frame (preprocessed: cropped, down-sampled)",
    ),
    StepSpec(
        3,
        "read_imu",
        ("frame",),
        "imu",
        "the IMU's body velocities (and angular rates)",
    ),
    StepSpec(4, "read_timing", ("frame",), "dt", "seconds since the previous frame"),
    StepSpec(
        5,
        "offset_by_motion",
        ("particles", "imu", "dt"),
        "particles",
        "every particle moved by the IMU's motion over dt, in its own body frame",
    ),
    StepSpec(
        6,
        "perturb_with_noise",
        ("particles", "sigma", "rng"),
        "particles",
        "every particle moved by its own Gaussian draw scaled by sigma",
    ),
    StepSpec(
        7,
        "transform_scan",
        ("particles", "points"),
        "world points",
        "the body-frame scan placed in the world by each particle's pose (or one pose)",
    ),
    StepSpec(
        8,
        "score_particles",
        ("particles", "points", "world_map"),
        "scores (P,) log-likelihoods",
        "how well each particle's transformed scan fits the map (steps 7 + 8, fused where it pays)",
    ),
    StepSpec(
        9,
        "pick_best_particle",
        ("particles", "log_weights"),
        "(pose, index)",
        "the estimate of this frame: the highest-weight particle's pose and its index",
    ),
    StepSpec(
        10,
        "merge_scan",
        ("world_map", "pose", "points"),
        "world_map (changed in place)",
        "the scan, placed by the chosen pose, added to the map (in place)",
    ),
    StepSpec(
        11,
        "resample_particles",
        ("particles", "log_weights", "rng"),
        "(particles, log_weights, resampled)",
        "systematic resampling when the effective sample size drops (slamlib.resampling.resample_indexes)",
    ),
)

#: Step 12: the filter object's per-frame method (:class:`ParticleFilter`), one call per frame.
FILTER_STEP = StepSpec(
    12,
    "step",
    ("frame",),
    "StepInfo",
    "one frame: steps 2-11 in the order LOOP_ORDER on the filter's state (step 1 is its constructor)",
)

#: The steps that one call of step 12 makes, in order: step 1 belongs to the constructor, step 7 is fused into 8.
LOOP_ORDER: tuple[int, ...] = (2, 3, 4, 5, 6, 8, 9, 10, 11)


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
    constructor's. ``isinstance(f, ParticleFilter)`` checks only that the three names exist.
    """

    particles: Any
    log_weights: np.ndarray

    def step(self, frame) -> StepInfo: ...


class StepsFilter:
    """Step 12 written once: ``step(frame)`` calls a steps module's functions in the order :data:`LOOP_ORDER`.

    For a dimension whose filter does nothing between the steps (1D, 2D; 3D's filter adds tempering, annealing,
    scan matching and a tilt prior and keeps its own loop). A subclass sets the class attribute ``steps`` (its
    steps module) and passes the shared settings to ``__init__``; what it adds to the calls it says by overriding
    :meth:`scan_options` (step 2), :meth:`score_options` (step 8) and :meth:`mean_pose` (the optional
    :attr:`StepInfo.mean`). Every step is called with the contract's parameters first and the additions as
    keywords, so its defaults stand for whatever the subclass does not add.

    Parameters (the same names and order at every dimension that uses it)
    ----------
    n_particles : int
        P; step 1 puts all of them at the world origin with log-weights ``-log P``.
    world_map : the dimension's map, empty or not; changed in place by every :meth:`step` (step 10).
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
        ess_fraction: float | None = 0.5,
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
        self.particles, self.log_weights = self.steps.initialise_particles(
            n_particles
        )  # 1
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
        scores = s.score_particles(
            moved, points, self.world_map, **self.score_options()
        )  # 7 + 8
        log_w = normalise_log_weights(self.log_weights + scores)
        pose, best = s.pick_best_particle(moved, log_w)  # 9
        s.merge_scan(self.world_map, pose, points)  # 10
        self.particles, self.log_weights, resampled = s.resample_particles(  # 11
            moved, log_w, self.rng, self.ess_fraction
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
    """Where ``module`` breaks the contract: one line per problem (empty when it keeps it).

    For every :data:`STEPS` entry the module must define a function of that name whose leading parameters are
    exactly ``spec.params`` (names and order) and whose other parameters all have defaults.
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
