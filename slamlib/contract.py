"""The twelve-step contract that every dimension of particle SLAM implements (1D, 2D, 3D).

One algorithm, told at growing dimension: each ``steps`` module (:mod:`slamlib.sim1d.steps`,
:mod:`slamlib.slam3d.steps`, ...) defines one function per step with **the same name, the same leading
parameters in the same order and the same kind of result**. What a dimension needs beyond that (a compute
``backend``, map settings, a likelihood width) comes after them and has a default, so a call written with the
shared parameters alone works at every dimension. ``tests/test_contract.py`` checks each steps module against
:data:`STEPS` with :func:`check_steps_module`.

Shared meanings
---------------
``particles``
    The particle set: ``(P,)`` float64 positions in 1D; :class:`slamlib.slam3d.steps.Particles3D` ``(R (P,3,3),
    t (P,3))`` poses ``T_world_body`` in 3D. Indexing with an ``(P,)`` int array selects particles.
``log_weights``
    ``(P,)`` float64 **log**-weights, normalised so that ``logsumexp = 0``
    (:func:`slamlib.resampling.normalise_log_weights`) -- at every dimension, never linear weights.
``pose``
    One particle's pose: a float in 1D, a 4x4 ``T_world_body`` in 3D. Wherever ``particles`` is accepted by a
    transform, one ``pose`` is too.
``points``
    The scan in the body frame: ``(N,)`` offsets in 1D, ``(N, 3)`` float32 in 3D.
``imu``, ``dt``
    What step 3 and step 4 return: the body velocity (1D: m/s), or ``(velocity (3,), angular_rate (3,))`` in 3D;
    the frame interval in seconds.
``world_map``
    The map built so far. **Step 10 changes it in place** (and returns it): the 3D maps are hash tables of
    tens of MiB that must not be copied every frame, and the 1D grid follows the same rule.
``rng``
    A :class:`numpy.random.Generator`, passed in: the steps keep no random state.

References: S. Thrun, W. Burgard, D. Fox, *Probabilistic Robotics* (2005), table 4.3 (particle filter);
Gothoskar & Tabrizi, CMU 15-418 project page (2017), the twelve steps; R. Labbe, filterpy (argument order).
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass
from types import ModuleType

__all__ = ["StepSpec", "STEPS", "check_steps_module"]


@dataclass(frozen=True)
class StepSpec:
    """One step of the contract: its number, function name, shared leading parameters and result."""

    number: int
    name: str
    params: tuple[str, ...]
    returns: str
    does: str


#: The contract: steps 1-11 as functions; step 12 is the filter object's per-frame method that calls them in order.
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
        3, "read_imu", ("frame",), "imu", "the IMU's body velocities (and angular rates)"
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
        "the scan, placed by the chosen pose, added to the map",
    ),
    StepSpec(
        11,
        "resample_particles",
        ("particles", "log_weights", "rng"),
        "(particles, log_weights, resampled)",
        "systematic resampling when the effective sample size drops (slamlib.resampling.resample_indexes)",
    ),
)


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
