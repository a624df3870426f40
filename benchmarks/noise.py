"""``slamlib bench noise``: lookup-table Gaussian noise vs real generators, cost (samples/s) and quality.

Cost, on the CPU, for ``n`` particles x 6 draws (one frame of step 6): the LUT in numpy and in a Numba
``prange`` kernel (:mod:`slamlib.noise`), the seed project's variant, numpy's ``Generator.standard_normal``,
Numba's own CPU RNG (``np.random.standard_normal`` inside ``@njit(parallel=True)``, per-thread Mersenne
Twister + polar method) and xoroshiro128+ (the ``numba.cuda.random`` device functions compiled for the CPU,
Box-Muller; state initialisation timed separately).

Quality (:mod:`slamlib.noise_quality`): moments, KS distance and lag-1 correlations across frames and across
threads of each source, and a small 1D particle filter (:func:`~slamlib.noise_quality.filter_1d`) run with each
source (RMSE of the estimate, and how often the truth lies inside the particle cloud's central 95 % interval).
"""

from __future__ import annotations

import numpy as np

from slamlib import noise as N
from slamlib.noise_quality import (
    SOURCES,
    dead_reckoning_spread,
    filter_1d,
    source_quality,
)

HELP = "lookup-table Gaussian noise vs numpy / Numba / xoroshiro128+: samples per second and quality"


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

    from benchmarks import median_time

    n = 100_000 if quick else 1_000_000
    repeat = 3 if quick else 7
    tables = N.make_tables(1)
    t8 = N.make_tables(1, bits=N.SEED_BITS)
    out = np.empty((n, N.N_COMPONENTS), np.float32)
    rows = []

    def add(name, fn, note=""):
        t = median_time(fn, repeat=repeat)
        rows.append(
            {
                "source": name,
                "n_particles": n,
                "samples": n * 6,
                **t,
                "samples_per_s": n * 6 / t["median_s"],
                "note": note,
            }
        )

    rng = np.random.default_rng(0)
    add(
        "numpy Generator (float32)",
        lambda: rng.standard_normal((n, 6), dtype=np.float32),
        "PCG64 + ziggurat",
    )
    add("LUT numpy", lambda: N.lut_normal(tables, n, 3, 7), "T = 4096, vectorised")
    add("LUT Numba prange", lambda: N.lut_normal_nb(tables, n, 3, 7), "T = 4096")
    add(
        "seed LUT numpy",
        lambda: N.seed_lut_normal(t8, n),
        "T = 256, index = thread & 0xFF (broken)",
    )
    fill = _numba_rng_fill()
    add(
        "Numba CPU RNG prange",
        lambda: fill(out),
        "np.random inside @njit(parallel): per-thread MT19937",
    )
    xo = {}
    if not getattr(numba_config, "ENABLE_CUDASIM", False):
        from numba.cuda.random import init_xoroshiro128p_states_cpu, xoroshiro128p_dtype

        states = np.empty(n, dtype=xoroshiro128p_dtype)
        xo["init_s"] = median_time(
            lambda: init_xoroshiro128p_states_cpu(states, 1, 0), repeat=1
        )["median_s"]
        xfill = _xoroshiro_fill()
        add(
            "xoroshiro128+ Numba prange",
            lambda: xfill(states, out),
            "numba.cuda.random on the CPU; Box-Muller",
        )
    quality = {
        name: source_quality(
            name, P=512 if name != "xoroshiro" else 256, steps=60 if quick else 100
        )
        for name in SOURCES
    }
    runs = 3 if quick else 10
    filt = {}
    for name in SOURCES:
        res = [
            filter_1d(name, P=128, steps=60 if quick else 100, seed=s)
            for s in range(runs)
        ]
        filt[name] = {key: float(np.mean([r[key] for r in res])) for key in res[0]}
        filt[name]["runs"] = runs
    steps = 60 if quick else 100
    spread = {
        name: float(dead_reckoning_spread(name, P=256, steps=steps)[-1])
        for name in SOURCES
    }
    return {
        "n_particles": n,
        "rows": rows,
        "xoroshiro_state_init_s": xo.get("init_s"),
        "quality": quality,
        "filter_1d": {"P": 128, "q": 0.3, "r": 1.0, "results": filt},
        "dead_reckoning": {
            "P": 256,
            "q": 0.3,
            "steps": steps,
            "expected_spread": 0.3 * float(np.sqrt(steps)),
            "spread": spread,
        },
    }
