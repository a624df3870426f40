"""Lookup-table Gaussian noise: one pure integer function for numpy, Numba CPU and CUDA.

Step 6 of the filter ("perturb with noise") needs six standard-normal draws per particle per frame
(translation x, y, z, then roll, pitch, yaw; see ``move_particles`` in CONTRIBUTING.md). On a GPU a
stateful generator (e.g. xoroshiro128+, :mod:`numba.cuda.random`) needs 16 bytes of state per thread, an
initialisation pass (``create_xoroshiro128p_states``: jump-ahead per thread) and a Box-Muller transform per
draw. The seed project (Gothoskar & Tabrizi 2017, after the *circleRenderer* assignment of CMU 15-418)
instead read a **table** of 256 Normal(0, 1) samples through six shuffled **index tables** (permutations of
``0..255``) addressed by ``threadIdx & 0xFF``. That is cheap but broken as a noise source: the index does not
depend on the frame, so each particle receives *the same* "noise" at every step (lag-1 correlation 1), and
threads ``i`` and ``i + 256`` receive identical noise.

This module keeps the tables and fixes the addressing with a stateless **counter-based hash** (in the spirit
of Salmon et al., "Parallel random numbers: as easy as 1, 2, 3", SC 2011): for thread (particle) ``i``,
frame ``s``, stream seed ``q`` and component ``k``::

    h   = fmix32(i ^ fmix32(s ^ fmix32(q ^ SALT)))         # 32-bit MurmurHash3 finaliser (Appleby), nested
    x   = h & (T - 1)                                      # low  log2(T) bits
    y   = (h >> (32 - log2 T)) & (T - 1)                   # high log2(T) bits (disjoint from x for T <= 2**16)
    idx = perm[k, x] ^ y                                   # index table k, then an XOR scramble
    n_k = normal[idx]

``fmix32`` is a bijection of 32-bit words with full avalanche, so for a fixed frame the map ``i -> h`` is
one-to-one (no two of the first 2**32 particles share ``h``), and changing ``s`` or ``q`` re-draws every
particle. Two particles receive the same six draws only if ``2 log2 T`` bits of their hashes agree
(probability ``T**-2``; 6e-8 for ``T = 4096``). The six components read the same ``(x, y)`` through six
independent permutations, so they are pairwise uncorrelated to ``O(T**-1/2)``.

The table holds exact normal quantiles ``Phi^-1((j + 1/2) / T)`` rescaled to variance 1 (``exact=True``), or
``T`` draws of a seeded ``numpy`` generator (``exact=False``). Every draw is one of ``T`` values: the
distribution is the table's (KS distance to N(0, 1) about ``1 / (2 T)`` for exact quantiles).

Write-once integer math
-----------------------
:func:`make_lut_functions` builds ``fmix32``, ``counter_hash``, ``lut_index`` and ``lut_draw`` from one
Python source with a decorator: the identity (numpy, vectorised over arrays of
thread indexes), ``numba.njit`` (CPU), or ``numba.cuda.jit(device=True)`` (GPU; built in
:mod:`slamlib.kernels.cuda`). All arithmetic is on ``uint64`` holding 32-bit words, masked after every
multiplication, so nothing overflows and numpy, Numba and the CUDA simulator (which runs device code on numpy
scalars) agree bit for bit; all constants are ``np.uint64`` so Numba never promotes ``uint64 op int64`` to
float. The same pattern builds the maps' integer codes (:func:`slamlib.maps.codes.make_code_functions`) and
the kernels' per-point math (:func:`slamlib.kernels.device.make_point_functions`).

References: Appleby, MurmurHash3 (``fmix32``); Salmon, Moraes, Dror & Shaw, "Parallel random numbers: as
easy as 1, 2, 3", SC 2011 (counter-based generators); Vigna, xoroshiro128+ (the stateful baseline).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import cache
from typing import NamedTuple

import numpy as np

#: Number of draws per particle per frame: translation x, y, z then roll, pitch, yaw.
N_COMPONENTS = 6
#: Default table size exponent (T = 4096 entries, 16 KiB of float32: fits in L1 / shared memory).
DEFAULT_BITS = 12
#: The seed project's table size exponent (T = 256).
SEED_BITS = 8

_M32 = np.uint64(0xFFFFFFFF)
_C1 = np.uint64(0x85EBCA6B)
_C2 = np.uint64(0xC2B2AE35)
_S13 = np.uint64(13)
_S16 = np.uint64(16)
_S32 = np.uint64(32)
_ONE = np.uint64(1)
_SALT = np.uint64(0x9E3779B9)  # 2**32 / golden ratio, so that seed 0 is not a fixed point
_BYTE = np.uint64(0xFF)


class NoiseTables(NamedTuple):
    """The lookup tables: ``normal`` (T,) float32 Normal(0, 1) values, ``perm`` (6, T) int32 permutations
    of ``0..T-1`` (one per component), ``bits = log2 T``."""

    normal: np.ndarray
    perm: np.ndarray
    bits: int


def make_tables(seed: int, bits: int = DEFAULT_BITS, exact: bool = True) -> NoiseTables:
    """Build the Normal table and the six index tables from ``seed`` (numpy ``default_rng``).

    Parameters
    ----------
    seed : int
        Seed of the numpy generator that draws the permutations (and the values when ``exact=False``).
    bits : int
        ``T = 2**bits`` entries, ``1 <= bits <= 16`` (so the two halves of the 32-bit hash are disjoint).
    exact : bool
        ``True``: the values are the normal quantiles ``Phi^-1((j + 1/2) / T)``, then scaled so that the table
        has mean 0 and variance 1 exactly (up to float32 rounding). ``False``: ``T`` seeded normal draws.
    """
    if not 1 <= int(bits) <= 16:
        raise ValueError(f"bits must be in [1, 16], got {bits}")
    bits = int(bits)
    T = 1 << bits
    rng = np.random.default_rng(seed)
    if exact:
        from scipy.special import ndtri

        q = ndtri((np.arange(T) + 0.5) / T)
        q = q - q.mean()
        q = q / np.sqrt(np.mean(q * q))
        normal = q.astype(np.float32)
    else:
        normal = rng.standard_normal(T).astype(np.float32)
    perm = np.stack([rng.permutation(T) for _ in range(N_COMPONENTS)]).astype(np.int32)
    return NoiseTables(normal, perm, bits)


def _identity(fn):
    return fn


def make_lut_functions(deco: Callable = _identity) -> dict:
    """Compile the integer hash and the table lookups with ``deco`` (identity, ``njit``, ``cuda.jit(device=True)``).

    Returns a dict of functions (all take and return scalars; the identity build also takes arrays of ``thread``):

    ``fmix32(h)``
        MurmurHash3 32-bit finaliser of ``h`` (uint64 holding a 32-bit word).
    ``frame_key(step, seed)``
        ``fmix32(step ^ fmix32(seed ^ SALT))``: the part of the hash shared by every thread of one frame.
    ``thread_hash(thread, key)``
        ``fmix32(thread ^ key)``: the 32-bit hash ``h`` of a thread, given its frame's ``key``.
    ``counter_hash(thread, step, seed)``
        ``thread_hash(thread, frame_key(step, seed))`` = ``fmix32(thread ^ fmix32(step ^ fmix32(seed ^ SALT)))``
        (inputs taken mod 2**32).
    ``hash_index(h, k, perm, bits)``
        ``perm[k, x] ^ y`` with ``x``, ``y`` the low and high ``bits`` bits of ``h`` (int64): component ``k``'s
        table index. A kernel that needs all six components hashes once and calls this six times.
    ``lut_index(thread, step, seed, k, perm, bits)``
        ``hash_index(counter_hash(thread, step, seed), k, perm, bits)``: table index (int64) of component ``k``
        for ``thread`` at frame ``step`` (module docstring).
    ``lut_draw(thread, step, seed, k, normal, perm, bits)``
        ``normal[lut_index(...)]``.
    """

    def fmix32(h):
        h = h & _M32
        h = h ^ (h >> _S16)
        h = (h * _C1) & _M32
        h = h ^ (h >> _S13)
        h = (h * _C2) & _M32
        h = h ^ (h >> _S16)
        return h

    fmix32 = deco(fmix32)

    def frame_key(step, seed):
        inner = fmix32((np.uint64(seed) & _M32) ^ _SALT)
        return fmix32((np.uint64(step) & _M32) ^ inner)

    frame_key = deco(frame_key)

    def thread_hash(thread, key):
        return fmix32((np.uint64(thread) & _M32) ^ key)

    thread_hash = deco(thread_hash)

    def counter_hash(thread, step, seed):
        return thread_hash(thread, frame_key(step, seed))

    counter_hash = deco(counter_hash)

    def hash_index(h, k, perm, bits):
        b = np.uint64(bits)
        mask = (_ONE << b) - _ONE
        x = h & mask
        y = (h >> (_S32 - b)) & mask
        return np.int64(np.uint64(perm[k, x]) ^ y)

    hash_index = deco(hash_index)

    def lut_index(thread, step, seed, k, perm, bits):
        return hash_index(counter_hash(thread, step, seed), k, perm, bits)

    lut_index = deco(lut_index)

    def lut_draw(thread, step, seed, k, normal, perm, bits):
        return normal[lut_index(thread, step, seed, k, perm, bits)]

    lut_draw = deco(lut_draw)
    return {
        "fmix32": fmix32,
        "frame_key": frame_key,
        "thread_hash": thread_hash,
        "counter_hash": counter_hash,
        "hash_index": hash_index,
        "lut_index": lut_index,
        "lut_draw": lut_draw,
    }


_NP = make_lut_functions()
#: Vectorised numpy builds (accept arrays of thread indexes).
fmix32 = _NP["fmix32"]
frame_key = _NP["frame_key"]
counter_hash = _NP["counter_hash"]
lut_index = _NP["lut_index"]


def _check(tables: NoiseTables, n: int, step: int, seed: int):
    if n < 0 or step < 0 or seed < 0:
        raise ValueError(f"n, step and seed must be >= 0, got {n}, {step}, {seed}")
    if tables.perm.shape != (N_COMPONENTS, 1 << tables.bits) or tables.normal.shape != (
        1 << tables.bits,
    ):
        raise ValueError(
            "tables.perm must be (6, T) and tables.normal (T,) with T = 2**bits"
        )


def lut_normal(
    tables: NoiseTables, n: int, step: int, seed: int, start: int = 0
) -> np.ndarray:
    """Standard-normal draws (n, 6) float32 for threads ``start .. start+n-1`` at frame ``step`` (numpy).

    Row ``i`` is component ``k = 0..5`` of :func:`lut_index` with ``thread = start + i``; the CUDA kernels
    compute exactly these values on the device (``slamlib.kernels.cuda``), so this array can be passed to the
    CPU backends to reproduce a GPU run.
    """
    _check(tables, n, step, seed)
    thread = np.arange(start, start + n, dtype=np.uint64)
    out = np.empty((n, N_COMPONENTS), np.float32)
    for k in range(N_COMPONENTS):
        out[:, k] = tables.normal[
            lut_index(thread, step, seed, k, tables.perm, tables.bits)
        ]
    return out


def seed_lut_normal(
    tables: NoiseTables, n: int, step: int = 0, seed: int = 0
) -> np.ndarray:
    """The seed project's variant (n, 6) float32: ``normal[perm[k, i & 0xFF]]``, the same at every ``step``.

    ``step`` and ``seed`` are accepted (and ignored) so the two variants can be swapped in experiments; use
    ``make_tables(seed, bits=SEED_BITS)`` for the seed's 256-entry tables. Kept to demonstrate the pitfall.
    """
    _check(tables, n, step, seed)
    if tables.bits < SEED_BITS:
        raise ValueError(
            "the seed variant needs tables with at least 256 entries (bits >= 8)"
        )
    thread = np.arange(n, dtype=np.uint64)
    out = np.empty((n, N_COMPONENTS), np.float32)
    for k in range(N_COMPONENTS):
        out[:, k] = tables.normal[tables.perm[k, thread & _BYTE]]
    return out


class LutNoise(NamedTuple):
    """Where ``move_particles`` gets its noise from: LUT draws for ``thread = particle index`` at frame ``step``.

    Pass an instance instead of a ``(P, 6)`` array to the CUDA backend's ``move_particles`` to generate the
    noise on the device (no host-to-device copy); :meth:`draw` gives the identical array on the host.
    """

    tables: NoiseTables
    step: int
    seed: int

    def draw(self, n: int) -> np.ndarray:
        """The (n, 6) float32 draws the device would generate (see :func:`lut_normal`)."""
        return lut_normal(self.tables, n, self.step, self.seed)


# ----------------------------------------------------------------------------------------------- Numba CPU
@cache
def numba_functions() -> dict:
    """The ``@njit`` builds of :func:`make_lut_functions` plus a ``prange`` ``fill`` kernel (built once: a
    compile cache of pure functions, not state)."""
    from numba import njit

    fns = make_lut_functions(njit(inline="always"))
    fns["fill"] = _make_fill(fns["lut_draw"])
    return fns


def _make_fill(lut_draw):
    from numba import njit, prange

    @njit(parallel=True)
    def fill(normal, perm, bits, step, seed, out):
        for i in prange(out.shape[0]):
            for k in range(out.shape[1]):
                out[i, k] = lut_draw(i, step, seed, k, normal, perm, bits)

    return fill


def lut_normal_nb(tables: NoiseTables, n: int, step: int, seed: int) -> np.ndarray:
    """:func:`lut_normal` computed by a Numba ``prange`` kernel (same values, bit for bit)."""
    _check(tables, n, step, seed)
    out = np.empty((n, N_COMPONENTS), np.float32)
    numba_functions()["fill"](
        tables.normal,
        tables.perm,
        np.int64(tables.bits),
        np.int64(step),
        np.int64(seed),
        out,
    )
    return out


# ---------------------------------------------------------------------------------------------- statistics
def noise_statistics(samples: np.ndarray) -> dict:
    """Moments and Kolmogorov-Smirnov distance to N(0, 1) of a sample (any shape, flattened).

    Returns ``{"n", "mean", "var", "kurtosis"}`` (Pearson kurtosis, 3 for a normal) and ``"ks"`` (the KS statistic
    ``sup |F_n - Phi|``; for ``n`` true normal draws it is about ``0.87 / sqrt(n)`` at the median).
    """
    from scipy import stats

    x = np.asarray(samples, dtype=np.float64).ravel()
    m = x.mean()
    v = x.var()
    return {
        "n": int(x.size),
        "mean": float(m),
        "var": float(v),
        "kurtosis": float(np.mean((x - m) ** 4) / v**2),
        "ks": float(stats.kstest(x, "norm").statistic),
    }


def lag_correlation(series: np.ndarray, lag: int = 1, axis: int = 0) -> float:
    """Pearson correlation between ``series`` and itself shifted by ``lag`` along ``axis`` (pooled over the rest).

    With ``series`` (steps, particles): ``axis=0`` is the correlation of one particle's draws at consecutive
    frames; ``axis=1`` between neighbouring threads at the same frame.
    """
    x = np.moveaxis(np.asarray(series, dtype=np.float64), axis, 0)
    a = x[:-lag].ravel()
    b = x[lag:].ravel()
    a = a - a.mean()
    b = b - b.mean()
    den = np.sqrt(np.sum(a * a) * np.sum(b * b))
    return float(np.sum(a * b) / den) if den > 0 else float("nan")
