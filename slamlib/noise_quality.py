"""Quality of Gaussian noise sources for a particle filter: lookup-table noise vs real generators.

A noise source (:func:`make_source`) gives ``P`` standard normals per step, one per particle slot: the
lookup-table noise of :mod:`slamlib.noise`, the seed project's variant, numpy's generator or xoroshiro128+
(``numba.cuda.random`` compiled for the CPU). :func:`source_quality` measures moments, KS distance and lag-1
correlations across steps and threads; :func:`filter_1d` runs a small 1D bootstrap particle filter with each
source (RMSE of the estimate, and how often the truth lies inside the particle cloud's central 95 % interval);
:func:`dead_reckoning_spread` shows how the cloud spreads without measurements. Their speed is measured by
``slamlib bench noise``.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np
from numba.core.errors import NumbaWarning

from slamlib import noise as N


# ------------------------------------------------------------------------------------------ noise sources
def make_source(name: str, P: int, seed: int) -> Callable[[int], np.ndarray]:
    """A noise source ``draw(step) -> (P,) float64`` standard normals for particle slots ``0..P-1``.

    ``name``: ``"lut"`` (:func:`slamlib.noise.lut_normal`, component 0), ``"seed_lut"`` (the seed project's
    256-entry variant: the same values at every step), ``"numpy"`` (``np.random.default_rng(seed)``) or
    ``"xoroshiro"`` (xoroshiro128+ from ``numba.cuda.random``, one stream per slot, Box-Muller in float32).
    """
    if name == "lut":
        tables = N.make_tables(seed)
        return lambda step: N.lut_normal(tables, P, step, seed)[:, 0].astype(np.float64)
    if name == "seed_lut":
        tables = N.make_tables(seed, bits=N.SEED_BITS)
        return lambda step: N.seed_lut_normal(tables, P, step)[:, 0].astype(np.float64)
    if name == "numpy":
        rng = np.random.default_rng(seed)
        return lambda step: rng.standard_normal(P)
    if name == "xoroshiro":
        from numba.cuda.random import (
            init_xoroshiro128p_states_cpu,
            xoroshiro128p_dtype,
            xoroshiro128p_normal_float32,
        )

        states = np.empty(P, dtype=xoroshiro128p_dtype)
        # Under the CUDA simulator these run as plain Python on numpy uint64 scalars: the seeding (splitmix64)
        # and each draw (s0 + s1) rely on uint64 wrap-around, which numpy reports as an overflow (harmless, exact).
        with warnings.catch_warnings(), np.errstate(over="ignore"):
            warnings.simplefilter("ignore", NumbaWarning)
            init_xoroshiro128p_states_cpu(states, seed, 0)

        def draw(step):
            with warnings.catch_warnings(), np.errstate(over="ignore"):
                warnings.simplefilter("ignore", NumbaWarning)
                return np.array(
                    [xoroshiro128p_normal_float32(states, i) for i in range(P)],
                    np.float64,
                )

        return draw
    raise ValueError(f"unknown noise source {name!r}")


SOURCES = ("lut", "seed_lut", "numpy", "xoroshiro")


def source_quality(name: str, P: int = 256, steps: int = 100, seed: int = 0) -> dict:
    """Moments / KS of ``steps x P`` draws of a source, and lag-1 correlations across steps and threads.

    ``r_steps``: correlation of a slot's draw with its draw at the next step (pooled over slots);
    ``r_threads``: of neighbouring slots at the same step; ``r_256``: of slots 256 apart (needs ``P > 256``).
    """
    draw = make_source(name, P, seed)
    series = np.stack([draw(s) for s in range(steps)])
    out = N.noise_statistics(series)
    out["r_steps"] = N.lag_correlation(series, 1, axis=0)
    out["r_threads"] = N.lag_correlation(series, 1, axis=1)
    out["r_256"] = N.lag_correlation(series, 256, axis=1) if P > 256 else None
    return out


def filter_1d(
    source: str,
    P: int = 200,
    steps: int = 100,
    seed: int = 0,
    q: float = 0.3,
    r: float = 1.0,
    u: float = 1.0,
) -> dict:
    """Bootstrap particle filter on a 1D random walk, with the motion noise from ``source``.

    Truth ``x_k = x_{k-1} + u + q w_k``, measurement ``z_k = x_k + r v_k`` (``w, v`` standard normal from a
    numpy generator seeded with ``seed``, the same for every source). Particles: ``x_i <- x_i + u + q n_i``
    with ``n`` from the source, weights ``exp(-(z - x_i)^2 / (2 r^2))``, estimate = weighted mean, then
    systematic resampling (:func:`slamlib.kernels.reference.systematic_resample`, offset from the generator).
    Returns ``rmse`` of the estimate, ``coverage`` = fraction of steps where the truth lies inside the central
    95 % of the particles after the prediction step, and ``spread`` = mean std of the predicted particles
    (``sqrt(q^2 + posterior var)`` when the noise is right).
    """
    from slamlib.kernels.reference import systematic_resample

    rng = np.random.default_rng(10_000 + seed)
    draw = make_source(source, P, seed)
    x_true = 0.0
    particles = rng.normal(0.0, 1.0, P)
    err, inside, spread = [], [], []
    for k in range(steps):
        x_true += u + q * rng.standard_normal()
        z = x_true + r * rng.standard_normal()
        particles = particles + u + q * draw(k)
        lo, hi = np.quantile(particles, [0.025, 0.975])
        inside.append(lo <= x_true <= hi)
        spread.append(particles.std())
        logw = -0.5 * (z - particles) ** 2 / r**2
        w = np.exp(logw - logw.max())
        err.append(np.sum(w * particles) / w.sum() - x_true)
        particles = particles[systematic_resample(w, rng.random())]
    err = np.asarray(err)
    return {
        "rmse": float(np.sqrt(np.mean(err**2))),
        "coverage": float(np.mean(inside)),
        "spread": float(np.mean(spread)),
    }


def dead_reckoning_spread(
    source: str, P: int = 200, steps: int = 100, seed: int = 0, q: float = 0.3
) -> np.ndarray:
    """Std of the particle cloud after each of ``steps`` prediction-only steps ``x_i <- x_i + q n_i`` (k,).

    With independent noise the cloud spreads like a random walk, ``q sqrt(k)``; with the seed project's noise
    (the same ``n_i`` every step) each particle moves in a straight line and the spread grows like ``q k``:
    the filter's uncertainty is wrong whenever measurements are weak (e.g. in a featureless stretch).
    """
    draw = make_source(source, P, seed)
    x = np.zeros(P)
    out = np.empty(steps)
    for k in range(steps):
        x = x + q * draw(k)
        out[k] = x.std()
    return out
