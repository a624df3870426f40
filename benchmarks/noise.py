"""``slamlib bench noise``: lookup-table Gaussian noise vs real generators, cost (samples/s) and quality.

Cost, on the CPU, for ``n`` particles x 6 draws (one frame of step 6): the LUT in numpy and in a Numba
``prange`` kernel (:mod:`slamlib.noise`), the seed project's variant, numpy's ``Generator.standard_normal``,
Numba's own CPU RNG (``np.random.standard_normal`` inside ``@njit(parallel=True)``, per-thread Mersenne
Twister + polar method) and xoroshiro128+ (the ``numba.cuda.random`` device functions compiled for the CPU,
Box-Muller; state initialisation timed separately).

Quality: moments, KS distance and lag-1 correlations across frames and across threads of each source, and a
small 1D particle filter (:func:`filter_1d`) run with each source (RMSE of the estimate, and how often the
truth lies inside the particle cloud's central 95 % interval).
"""

from __future__ import annotations

import warnings
from typing import Callable

import numpy as np
from numba.core.errors import NumbaWarning

from slamlib import noise as N

HELP = "lookup-table Gaussian noise vs numpy / Numba / xoroshiro128+: samples per second and quality"


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
        from numba.cuda.random import init_xoroshiro128p_states_cpu, xoroshiro128p_dtype, xoroshiro128p_normal_float32

        states = np.empty(P, dtype=xoroshiro128p_dtype)
        # Under the CUDA simulator these run as plain Python on numpy uint64 scalars: the seeding (splitmix64)
        # and each draw (s0 + s1) rely on uint64 wrap-around, which numpy reports as an overflow (harmless, exact).
        with warnings.catch_warnings(), np.errstate(over="ignore"):
            warnings.simplefilter("ignore", NumbaWarning)
            init_xoroshiro128p_states_cpu(states, seed, 0)

        def draw(step):
            with warnings.catch_warnings(), np.errstate(over="ignore"):
                warnings.simplefilter("ignore", NumbaWarning)
                return np.array([xoroshiro128p_normal_float32(states, i) for i in range(P)], np.float64)

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


def filter_1d(source: str, P: int = 200, steps: int = 100, seed: int = 0, q: float = 0.3, r: float = 1.0,
              u: float = 1.0) -> dict:
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
    return {"rmse": float(np.sqrt(np.mean(err**2))), "coverage": float(np.mean(inside)),
            "spread": float(np.mean(spread))}


def dead_reckoning_spread(source: str, P: int = 200, steps: int = 100, seed: int = 0, q: float = 0.3) -> np.ndarray:
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


# -------------------------------------------------------------------------------------------------- timing
def _numba_rng_fill():
    from numba import njit, prange

    @njit(parallel=True)
    def fill(out):
        for i in prange(out.shape[0]):
            for k in range(out.shape[1]):
                out[i, k] = np.random.standard_normal()

    return fill


def _xoroshiro_fill():
    from numba import njit, prange
    from numba.cuda.random import xoroshiro128p_normal_float32

    @njit(parallel=True)
    def fill(states, out):
        for i in prange(out.shape[0]):
            for k in range(out.shape[1]):
                out[i, k] = xoroshiro128p_normal_float32(states, i)

    return fill


def run(quick: bool = False) -> dict:
    """Time each source for ``n`` particles x 6 draws; measure quality and the 1D filter with each source."""
    from numba import config as numba_config

    from slamlib.bench import median_time

    n = 100_000 if quick else 1_000_000
    repeat = 3 if quick else 7
    tables = N.make_tables(1)
    t8 = N.make_tables(1, bits=N.SEED_BITS)
    out = np.empty((n, N.N_COMPONENTS), np.float32)
    rows = []

    def add(name, fn, note=""):
        t = median_time(fn, repeat=repeat)
        rows.append({"source": name, "n_particles": n, "samples": n * 6, **t,
                     "samples_per_s": n * 6 / t["median_s"], "note": note})

    rng = np.random.default_rng(0)
    add("numpy Generator (float32)", lambda: rng.standard_normal((n, 6), dtype=np.float32), "PCG64 + ziggurat")
    add("LUT numpy", lambda: N.lut_normal(tables, n, 3, 7), "T = 4096, vectorised")
    add("LUT Numba prange", lambda: N.lut_normal_nb(tables, n, 3, 7), "T = 4096")
    add("seed LUT numpy", lambda: N.seed_lut_normal(t8, n), "T = 256, index = thread & 0xFF (broken)")
    fill = _numba_rng_fill()
    add("Numba CPU RNG prange", lambda: fill(out), "np.random inside @njit(parallel): per-thread MT19937")
    xo = {}
    if not getattr(numba_config, "ENABLE_CUDASIM", False):
        from numba.cuda.random import init_xoroshiro128p_states_cpu, xoroshiro128p_dtype

        states = np.empty(n, dtype=xoroshiro128p_dtype)
        xo["init_s"] = median_time(lambda: init_xoroshiro128p_states_cpu(states, 1, 0), repeat=1)["median_s"]
        xfill = _xoroshiro_fill()
        add("xoroshiro128+ Numba prange", lambda: xfill(states, out), "numba.cuda.random on the CPU; Box-Muller")
    quality = {name: source_quality(name, P=512 if name != "xoroshiro" else 256, steps=60 if quick else 100)
               for name in SOURCES}
    runs = 3 if quick else 10
    filt = {}
    for name in SOURCES:
        res = [filter_1d(name, P=128, steps=60 if quick else 100, seed=s) for s in range(runs)]
        filt[name] = {key: float(np.mean([r[key] for r in res])) for key in res[0]}
        filt[name]["runs"] = runs
    steps = 60 if quick else 100
    spread = {name: float(dead_reckoning_spread(name, P=256, steps=steps)[-1]) for name in SOURCES}
    return {"n_particles": n, "rows": rows, "xoroshiro_state_init_s": xo.get("init_s"), "quality": quality,
            "filter_1d": {"P": 128, "q": 0.3, "r": 1.0, "results": filt},
            "dead_reckoning": {"P": 256, "q": 0.3, "steps": steps, "expected_spread": 0.3 * float(np.sqrt(steps)),
                               "spread": spread}}
