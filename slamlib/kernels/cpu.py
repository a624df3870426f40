"""Numba CPU backend (``get_backend("cpu")``): ``@njit(parallel=True, cache=True)`` kernels over ``prange``.

Same functions, shapes and math as :mod:`slamlib.kernels.reference` (see CONTRIBUTING.md, "Backend interface
(3D)", and :mod:`slamlib.maps.base` for the map lookups). The per-particle and per-point math (rotation from
roll/pitch/yaw, motion update, point transform, NDT voxel term, hash / find-slot / Morton / find-cell) is not
written here: it is the ``njit(inline="always")`` build of :func:`slamlib.kernels.device.make_point_functions`,
the same source the CUDA backend compiles with ``cuda.jit(device=True)``. This module arranges the loops:

* ``move_particles``: ``prange`` over blocks of ``PARTICLE_BLOCK`` particles; each particle's update is kept
  in registers (the row primitives of :mod:`slamlib.kernels.device`) on flat arrays with unsigned indexes, so
  LLVM vectorises the loop (SIMD lanes over consecutive particles, table reads as gathers); ``out=`` (in place
  with ``out=(R, t)``); with a :class:`slamlib.noise.LutNoise` the draws are made inside the kernel (one
  counter hash per particle) from per-call tables of ``sigma * value`` and of ``cos``/``sin`` of the rotation
  draws, with the values of the unfused path bit for bit. ``move_particles_soa`` is the same for particles
  stored component-major (``R (3, 3, P)``, ``t (3, P)``, float64 or float32): the layout whose loads are
  contiguous per component, and float32 halves the bytes per particle.
* ``transform_points``: ``prange`` over spans of ``TRANSFORM_CHUNK`` points of the flat float32 array, unsigned
  indexes so that LLVM vectorises the span's loop; float32 arithmetic (like
  :func:`slamlib.geometry.transform_points`) with contraction into FMAs only (``fastmath={"contract"}``), so it
  agrees with the other backends to float32 rounding, not bit for bit; ``out=`` (in place with ``out=points``).
  ``out=`` buffers of ``STREAM_MIN_POINTS`` or more are written in whole cache lines with non-temporal stores,
  which skip the read of each destination line before it is written, and the large loops prefetch their input
  (:mod:`slamlib.kernels.memory_hints`): the same floats, a third less memory traffic out of place.
* ``score_particles`` is fused: each task takes a chunk of ``POINT_CHUNK`` scan points and a chunk of
  ``PARTICLE_CHUNK`` particles; for each point it loops over the particles (their copies of the point land in
  the same few voxels / cells, so map memory stays in cache), transforms in registers (float64) and looks up;
  per-(point chunk, particle) partial sums are added in a fixed order, so results do not depend on the thread
  count, and no ``P x N`` array is ever built. Two-way chunking keeps all cores busy for few particles with
  many points as well as many particles with few points. It does not use ``fastmath``: ``floor`` at
  voxel/cell boundaries must agree with the reference bit for bit.
* The Morton map's query is a CPU-specific exact branch-and-bound search (:func:`morton_nn_nb`: warm start from
  the previous particle's neighbour, a per-task cache of cell look-ups, descent into sub-cells of long runs)
  built from the shared pieces; it returns the same ``min(d_nn^2, r^2)`` as the shared brute-force query.
"""

from __future__ import annotations

import hashlib
import math

import numba
import numpy as np
from numba import njit, prange

from slamlib.kernels.device import NO_BLOCK, make_point_functions
from slamlib.kernels.memory_hints import (
    LINE_BYTES,
    LINE_F32,
    prefetch,
    store_fence,
    stream_line,
)
from slamlib.maps.base import KIND_MORTON, KIND_VOXEL_HASH
from slamlib.noise import N_COMPONENTS, LutNoise, frame_key, make_lut_functions

# The shared math is inlined into the kernels below. Numba's on-disk cache (cache=True) is keyed on this file's
# timestamp only, so after editing slamlib/kernels/device.py or slamlib/maps/codes.py clear it
# (rm -rf "$NUMBA_CACHE_DIR", _cache/numba in the Makefile) or the cached kernels keep the old math.
_F = make_point_functions(njit(inline="always"))
_rpy_rotation_cs = _F["rpy_rotation_cs"]
_rpy_rotation = _F["rpy_rotation"]
_row_times = _F["row_times"]
_row_step = _F["row_step"]
_world_point = _F["world_point"]
_voxel_cell = _F["voxel_cell"]
_corner_slot = _F["corner_slot"]
_corner_weight = _F["corner_weight"]
_slot_term = _F["slot_term"]
_hash_slot = _F["hash_slot"]
_morton = _F["morton"]
_find_cell = _F["find_cell"]
_cell_block = _F["cell_block"]
_cells_per_axis = _F["cells_per_axis"]
_nearest_in_run = _F["nearest_in_run"]

_L = make_lut_functions(njit(inline="always"))
_frame_key = _L["frame_key"]
_thread_hash = _L["thread_hash"]
_hash_index = _L["hash_index"]
# unsigned index arithmetic: no negative-index wrap-around test in the loops, so LLVM vectorises them
_U1, _U2, _U3, _U4, _U5, _U6, _U9 = (np.uint64(k) for k in (1, 2, 3, 4, 5, 6, 9))


@njit(cache=True, inline="always")
def _ceil_div(n, chunk):
    """``ceil(n / chunk)`` for ``n >= 0``, ``chunk >= 1``: the number of tasks of ``chunk`` items covering ``n``."""
    return (n + chunk - 1) // chunk


#: Scan points per parallel task of ``score_particles``.
POINT_CHUNK = 64
#: Particles per parallel task of ``score_particles`` (inner loop: one point, consecutive particles).
PARTICLE_CHUNK = 64


# --------------------------------------------------------------------------------------------- move particles
#: Particles per parallel task of ``move_particles``.
PARTICLE_BLOCK = 1024
#: With LUT noise and more than ``LUT_TRIG_TABLE_RATIO * T`` particles (``T`` table entries), ``move_particles``
#: tabulates ``cos``/``sin`` of the table's rotation draws once per call (6 T calls) instead of 6 calls per particle.
LUT_TRIG_TABLE_RATIO = 1


@njit(cache=True, inline="always")
def _move_particle(R, t, R_new, t_new, r, rs, cs, q, ts, d, n, sx, sy, sz):
    """One particle of the fused move on flat arrays: ``R_new = R_i dR N``, ``t_new = t_i + R_i dR s``.

    ``R[r + a rs + b cs]`` is ``R_i[a, b]`` and ``t[q + a ts]`` is ``t_i[a]`` (unsigned indexes: particle-major
    ``(P, 3, 3)`` has ``r = 9 i, rs = 3, cs = 1``, component-major ``(3, 3, P)`` has ``r = i, rs = 3 P, cs = P``);
    ``d``, ``n`` are ``dR`` and ``N`` as row-major 9-tuples, ``s = (sx, sy, sz)`` the body-frame step. Row ``a``
    of the result needs row ``a`` of ``R_i`` only, so ``R_new`` may be ``R`` (in place)."""
    for a in range(3):
        k = r + rs * np.uint64(a)
        a0, a1, a2 = _row_times(
            R[k],
            R[k + cs],
            R[k + cs + cs],
            d[0],
            d[1],
            d[2],
            d[3],
            d[4],
            d[5],
            d[6],
            d[7],
            d[8],
        )
        R_new[k], R_new[k + cs], R_new[k + cs + cs] = _row_times(
            a0, a1, a2, n[0], n[1], n[2], n[3], n[4], n[5], n[6], n[7], n[8]
        )
        m = q + ts * np.uint64(a)
        t_new[m] = _row_step(t[m], a0, a1, a2, sx, sy, sz)


@njit(parallel=True, cache=True)
def _lut_tables_nb(normal, sigma, step_tab, trig_tab, with_trig):
    """The per-call tables of the fused LUT move: ``step_tab[k, j] = sigma[k] * normal[j]`` (k = 0, 1, 2) and, if
    ``with_trig``, ``trig_tab[k, j, 0], trig_tab[k, j, 1] = cos, sin(sigma[3 + k] * normal[j])`` (side by side: one
    cache line); the same float64 values the unfused kernel forms from ``noise = lut.draw(P)``."""
    for j in prange(normal.shape[0]):
        v = np.float64(normal[j])
        for k in range(3):
            step_tab[k, j] = sigma[k] * v
            if with_trig:
                a = sigma[3 + k] * v
                trig_tab[k, j, 0] = math.cos(a)
                trig_tab[k, j, 1] = math.sin(a)


def _cache_by_build(kernel, **build):
    """Key ``kernel``'s entries in Numba's on-disk cache by its bytecode and the constants of its ``build``, not by
    a pickle of its closure; returns ``kernel``.

    Numba keys a cached closure by its bytecode and a pickle of its closure's cells (``Cache._index_key`` in
    ``numba.core.caching``). The move kernels close over ``move_one``, a jitted function, whose pickle holds an
    identifier drawn anew in every process: every run missed the cache, compiled them again (seconds of a warm
    start) and added an entry to their index. Their builds differ by the constants named here, and nothing
    else. As Numba's own key, this one does not see changes to jitted functions of other files; a change to this
    file empties the cache as before (the index holds the source's time stamp)."""
    cache = getattr(kernel, "_cache", None)
    if not hasattr(cache, "_index_key"):  # caching off, or another Numba's cache
        return kernel
    code = hashlib.sha256(kernel.py_func.__code__.co_code).hexdigest()
    constants = hashlib.sha256(repr(sorted(build.items())).encode()).hexdigest()
    cache._index_key = lambda sig, codegen: (
        sig,
        codegen.magic_tuple(),
        (code, constants),
    )
    return kernel


def _make_move_kernels(soa: bool):
    """The fused move kernels (drawn noise, LUT noise with and without the trig table) for one particle layout,
    ``soa`` a constant of the build: a layout test inside the loop would stop LLVM from vectorising it (one build
    per layout, each cached, keyed by its build: :func:`_cache_by_build`)."""

    @njit(inline="always")
    def move_one(R, t, R_new, t_new, i, p, d, n, sx, sy, sz):
        """Particle ``i`` of ``p`` in this build's layout (:func:`_move_particle`)."""
        if soa:
            _move_particle(R, t, R_new, t_new, i, _U3 * p, p, i, p, d, n, sx, sy, sz)
        else:
            _move_particle(
                R, t, R_new, t_new, _U9 * i, _U3, _U1, _U3 * i, _U1, d, n, sx, sy, sz
            )

    @njit(parallel=True, cache=True)
    def _move_nb(R, t, d, trans_delta, noise, sigma, R_new, t_new, P, block):
        """The fused move with drawn ``noise`` (flat: ``(P, 6)``, or ``(6, P)`` when ``soa``) over flat particles."""
        p = np.uint64(P)
        for b in prange(_ceil_div(P, block)):
            for i in range(np.uint64(b * block), np.uint64(min(P, (b + 1) * block))):
                e, es = (i, p) if soa else (_U6 * i, _U1)  # noise[i, k] = noise[e + k es]
                n = _rpy_rotation(
                    sigma[3] * noise[e + _U3 * es],
                    sigma[4] * noise[e + _U4 * es],
                    sigma[5] * noise[e + _U5 * es],
                )
                move_one(
                    R,
                    t,
                    R_new,
                    t_new,
                    i,
                    p,
                    d,
                    n,
                    trans_delta[0] + sigma[0] * noise[e],
                    trans_delta[1] + sigma[1] * noise[e + es],
                    trans_delta[2] + sigma[2] * noise[e + _U2 * es],
                )

    def make_lut(with_trig):
        @njit(parallel=True, cache=True)
        def _move_lut_nb(
            R,
            t,
            d,
            trans_delta,
            sigma,
            key,
            perm,
            bits,
            normal,
            step_tab,
            trig_tab,
            R_new,
            t_new,
            P,
            block,
        ):
            """The fused move with LUT noise drawn in the loop (one counter hash per particle) over flat particles."""
            p = np.uint64(P)
            for b in prange(_ceil_div(P, block)):
                for i in range(np.uint64(b * block), np.uint64(min(P, (b + 1) * block))):
                    # one hash per particle; the six table indexes come from it
                    h = _thread_hash(i, key)
                    i3 = _hash_index(h, 3, perm, bits)
                    i4 = _hash_index(h, 4, perm, bits)
                    i5 = _hash_index(h, 5, perm, bits)
                    if with_trig:  # a constant of the build, like soa
                        n = _rpy_rotation_cs(
                            trig_tab[0, i3, 0],
                            trig_tab[0, i3, 1],
                            trig_tab[1, i4, 0],
                            trig_tab[1, i4, 1],
                            trig_tab[2, i5, 0],
                            trig_tab[2, i5, 1],
                        )
                    else:
                        n = _rpy_rotation(
                            sigma[3] * normal[i3],
                            sigma[4] * normal[i4],
                            sigma[5] * normal[i5],
                        )
                    move_one(
                        R,
                        t,
                        R_new,
                        t_new,
                        i,
                        p,
                        d,
                        n,
                        trans_delta[0] + step_tab[0, _hash_index(h, 0, perm, bits)],
                        trans_delta[1] + step_tab[1, _hash_index(h, 1, perm, bits)],
                        trans_delta[2] + step_tab[2, _hash_index(h, 2, perm, bits)],
                    )

        return _cache_by_build(_move_lut_nb, soa=soa, with_trig=with_trig)

    return _cache_by_build(_move_nb, soa=soa), make_lut(True), make_lut(False)


#: ``_MOVE[soa] = (drawn noise, LUT noise with the trig table, LUT noise calling cos/sin)``: particle-major
#: ``R (P, 3, 3), t (P, 3)`` (``soa=False``) and component-major ``R (3, 3, P), t (3, P)``.
_MOVE = {soa: _make_move_kernels(soa) for soa in (False, True)}


def kernels_cached() -> bool | None:
    """Whether Numba's on-disk cache holds compiled scoring kernels for this source (an index whose stamp matches
    this file), so that a run loads its kernels instead of compiling them (seconds); None when this Numba cannot
    tell. Numba writes the whole cache of a run at once, so one scoring kernel stands for the rest."""
    try:
        return any(
            bool(kernel._cache._cache_file._load_index())  # {} when missing or stale
            for kernel in (_score_voxel_nb, _score_morton_nb)
        )
    except AttributeError:  # another Numba's cache layout, or caching off
        return None


def _launch(kernel, n, chunk, *args):
    """``kernel(*args, chunk)``, a ``prange`` over ``ceil(n / chunk)`` tasks of ``chunk`` items, on one thread
    when that is a single task: waking the pool's other threads would cost more than the work (and on a busy
    machine, a scheduler time slice). The thread count is restored afterwards."""
    if n > chunk:
        return kernel(*args, chunk)
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        return kernel(*args, chunk)
    finally:
        numba.set_num_threads(threads)


def _check_particles(R, t):
    R = np.ascontiguousarray(R, dtype=np.float64)
    t = np.ascontiguousarray(t, dtype=np.float64)
    if R.ndim != 3 or R.shape[1:] != (3, 3) or t.shape != (R.shape[0], 3):
        raise ValueError(
            f"particles need R (P, 3, 3) and t (P, 3), got {R.shape} and {t.shape}"
        )
    return R, t


def _vector(x, n, name):
    """``x`` as a contiguous float64 array of ``n`` values (any shape holding ``n`` values, as ``reshape``)."""
    v = np.ascontiguousarray(x, dtype=np.float64)
    if v.size != n:
        raise ValueError(f"{name} must have {n} values, got shape {v.shape}")
    return v.reshape(n)


def _check_out(out, like, name):
    """``out`` as a destination for an array shaped and typed like ``like``: C-contiguous, same dtype and shape."""
    if not (
        isinstance(out, np.ndarray)
        and out.dtype == like.dtype
        and out.shape == like.shape
        and out.flags.c_contiguous
        and out.flags.writeable
    ):
        raise ValueError(
            f"{name} must be a writeable C-contiguous {like.dtype} array of shape {like.shape}"
        )
    if out is not like and np.may_share_memory(out, like) and not _same_memory(out, like):
        raise ValueError(
            f"{name} overlaps its input without being the same array (in place needs out=the input)"
        )
    return out


def _same_memory(a, b):
    return (
        a.__array_interface__["data"][0] == b.__array_interface__["data"][0]
        and a.shape == b.shape
    )


def move_particles(R, t, rpy_delta, trans_delta, noise, sigma, out=None):
    """Steps 5 + 6 fused (see :func:`slamlib.kernels.reference.move_particles`), parallel over particles.

    ``noise`` is a ``(P, 6)`` standard-normal array, or a :class:`slamlib.noise.LutNoise`: then particle ``i``'s
    draws are generated inside the kernel (``thread = i``; one counter hash per particle, six table reads),
    the values of ``noise.draw(P)`` bit for bit, so no ``(P, 6)`` array is written or read. With more particles
    than table entries, the cosines and sines of the table's rotation draws (``cos``, ``sin`` of
    ``sigma[3 + k] * normal[j]``, 6 T calls) and the translation steps ``sigma[k] * normal[j]`` are tabulated
    once per call, so the kernel calls no ``cos``/``sin`` per particle (the same float64 values: identical results).

    ``out=(R_out (P, 3, 3) f8, t_out (P, 3) f8)`` receives the result (C-contiguous; ``out=(R, t)`` updates the
    particles in place: particle ``i`` is read before it is written); returns ``(R_new, t_new)``.
    """
    R, t = _check_particles(R, t)
    return _move(R, t, R.shape[0], rpy_delta, trans_delta, noise, sigma, out, soa=False)


def move_particles_soa(R, t, rpy_delta, trans_delta, noise, sigma, out=None):
    """:func:`move_particles` for particles stored component-major (structure of arrays): ``R (3, 3, P)``,
    ``t (3, P)``, float64 or float32 (kept: a float32 pair computes in float32), noise ``(6, P)`` or a
    :class:`slamlib.noise.LutNoise` (the same draws for particle ``i``).

    The same math per particle (``R[:, :, i]`` is ``R_i``); the layout is what differs. Consecutive particles
    sit side by side in each of the 12 component arrays, so the loop runs on SIMD lanes, and float32 halves the
    bytes a particle moves (96 read and written in place, against 192 for a float64 ``(P, 3, 3)`` pose):
    ``slamlib bench particles`` measures both. ``out=(R_out, t_out)`` as in :func:`move_particles`.
    """
    R, t = _check_particles_soa(R, t)
    return _move(R, t, R.shape[2], rpy_delta, trans_delta, noise, sigma, out, soa=True)


def _check_particles_soa(R, t):
    dtype = (
        np.float32
        if getattr(R, "dtype", None) == np.float32
        and getattr(t, "dtype", None) == np.float32
        else np.float64
    )
    R = np.ascontiguousarray(R, dtype=dtype)
    t = np.ascontiguousarray(t, dtype=dtype)
    if R.ndim != 3 or R.shape[:2] != (3, 3) or t.shape != (3, R.shape[2]):
        raise ValueError(
            f"component-major particles need R (3, 3, P) and t (3, P), got {R.shape} and {t.shape}"
        )
    return R, t


def _move(R, t, P, rpy_delta, trans_delta, noise, sigma, out, soa):
    """The checks and launch shared by both layouts; arithmetic in ``R.dtype``."""
    dtype = R.dtype
    sigma = _vector(sigma, 6, "sigma")
    rpy = _vector(rpy_delta, 3, "rpy_delta")
    trans = _vector(trans_delta, 3, "trans_delta").astype(dtype)
    # dR as a row-major 9-tuple: registers in the loop
    d = tuple(np.asarray(_rpy_rotation(*rpy), dtype))
    if out is None:
        R_new, t_new = np.empty_like(R), np.empty_like(t)
    else:
        R_new, t_new = _check_out(out[0], R, "out[0]"), _check_out(out[1], t, "out[1]")
    flat = (R.reshape(-1), t.reshape(-1))
    flat_new = (R_new.reshape(-1), t_new.reshape(-1))
    if isinstance(noise, LutNoise):
        if noise.step < 0 or noise.seed < 0:
            raise ValueError("LutNoise step and seed must be >= 0")
        tables = noise.tables
        T = tables.normal.shape[0]
        if tables.perm.shape != (N_COMPONENTS, T) or T != 1 << tables.bits:
            raise ValueError(
                "LutNoise tables need normal (T,) and perm (6, T) with T = 2**bits"
            )
        with_trig = P > LUT_TRIG_TABLE_RATIO * T
        step_tab = np.empty((3, T))
        trig_tab = np.zeros((3, T, 2) if with_trig else (3, 1, 2))
        _lut_tables_nb(tables.normal, sigma, step_tab, trig_tab, with_trig)
        key = np.uint64(frame_key(np.uint64(noise.step), np.uint64(noise.seed)))
        _launch(
            _MOVE[soa][1 if with_trig else 2],
            P,
            PARTICLE_BLOCK,
            *flat,
            d,
            trans,
            sigma.astype(dtype),
            key,
            tables.perm,
            np.int64(tables.bits),
            tables.normal,
            step_tab.astype(dtype),
            trig_tab.astype(dtype),
            *flat_new,
            P,
        )
        return R_new, t_new
    shape = (6, P) if soa else (P, 6)
    noise = np.ascontiguousarray(noise, dtype=dtype)
    if noise.shape != shape:
        raise ValueError(
            f"noise must have shape {'(6, P)' if soa else '(P, 6)'} = {shape}, got {noise.shape}"
        )
    _launch(
        _MOVE[soa][0],
        P,
        PARTICLE_BLOCK,
        *flat,
        d,
        trans,
        noise.reshape(-1),
        sigma.astype(dtype),
        *flat_new,
        P,
    )
    return R_new, t_new


# ------------------------------------------------------------------------------------------- transform points
#: Points per parallel task of ``transform_points``: a contiguous span of ``3 * TRANSFORM_CHUNK`` floats whose
#: loop LLVM vectorises (AVX2: 8 points per step, de-interleaved with shuffles).
TRANSFORM_CHUNK = 1 << 14
#: Points per group of the streaming kernels: 16 points are 48 float32, exactly 3 whole 64-byte lines (48 is
#: the least common multiple of 3 floats per point and 16 per line).
STREAM_GROUP = LINE_F32
#: ``out=`` buffers of at least this many points (48 MiB) are written by the streaming kernel, with
#: non-temporal whole-line stores (see :mod:`slamlib.kernels.memory_hints`); smaller ones, and fresh outputs,
#: with plain stores, which leave the result in cache for its reader. Measured crossover on the 2-core Xeon
#: (480 MiB shared L3): plain stores faster up to 2e6 points, streaming from 4e6 (8e6 when ``out`` was just
#: written and is still cached).
STREAM_MIN_POINTS = 1 << 22
#: Software-prefetch distance of the streaming kernels, in floats ahead of the group being read (2 KiB;
#: measured in place at 1e8 points on the Xeon: 1 and 2 KiB best, 4 and 8 KiB half the gain, 32 KiB none).
PREFETCH_AHEAD = 512
#: Bytes of one point of ``transform_points``: x, y, z float32.
_POINT_BYTES = 3 * np.dtype(np.float32).itemsize


@njit(parallel=True, cache=True, fastmath={"contract"})
def _transform_nb(R, t, x, y, chunk):
    """``y[3j:3j+3] = R[0] x[3j:3j+3] + t[0]`` over the flat float32 arrays ``x``, ``y`` (3N,). Unsigned indexes:
    no negative-index wrap-around test, so the inner loop vectorises."""
    n = x.shape[0] // 3
    for c in prange(_ceil_div(n, chunk)):
        _transform_span(R, t, x, y, c * chunk, min(n, (c + 1) * chunk))


@njit(cache=True, inline="always")
def _transform_span(R, t, x, y, a, b):
    """Points ``[a, b)`` of :func:`_transform_nb`, plain stores."""
    for j in range(a, b):
        k = _U3 * np.uint64(j)
        wx, wy, wz = _world_point(R, t, 0, x[k], x[k + _U1], x[k + _U2])
        y[k] = wx
        y[k + _U1] = wy
        y[k + _U2] = wz


@njit(cache=True, inline="always")
def _prefetch_group(x, k):
    """Prefetch the 3 lines of the group ``PREFETCH_AHEAD`` floats past ``x[k]`` (within ``x``)."""
    for q in range(3):
        ahead = k + np.uint64(PREFETCH_AHEAD + LINE_F32 * q)
        if ahead < x.shape[0]:
            prefetch(x, ahead)


@njit(parallel=True, cache=True, fastmath={"contract"})
def _transform_stream_nb(R, t, x, y, head, chunk):
    """:func:`_transform_nb` writing ``y`` in whole lines with non-temporal stores, for outputs too large to
    stay in cache. ``head`` (< 16) is the number of points before the first whose output ``y[3 head]``
    starts a 64-byte line; from there, each group of ``STREAM_GROUP`` points is 3 whole lines, computed into
    a 48-float line buffer (L1) and streamed out. The head and the tail (< 16 points each) get plain stores,
    from the first task. ``chunk`` is in groups; each task ends with a store fence."""
    n = x.shape[0] // 3
    head = min(head, n)
    groups = (n - head) // STREAM_GROUP
    for c in prange(max(1, _ceil_div(groups, chunk))):
        if c == 0:
            _transform_span(R, t, x, y, 0, head)
            _transform_span(R, t, x, y, head + groups * STREAM_GROUP, n)
        lines = np.empty(3 * STREAM_GROUP, np.float32)
        for g in range(c * chunk, min(groups, (c + 1) * chunk)):
            a = head + g * STREAM_GROUP
            k0 = _U3 * np.uint64(a)
            _prefetch_group(x, k0)
            # min(): a trip count known only at run time, so LLVM vectorises this as a loop; a constant 16
            # is fully unrolled into slower straight-line code (measured 84 against 54 ms at 1e8 points)
            for j in range(min(STREAM_GROUP, n - a)):
                k = _U3 * np.uint64(j)
                wx, wy, wz = _world_point(
                    R, t, 0, x[k0 + k], x[k0 + k + _U1], x[k0 + k + _U2]
                )
                lines[k] = wx
                lines[k + _U1] = wy
                lines[k + _U2] = wz
            for q in range(3):
                stream_line(
                    y, k0 + np.uint64(LINE_F32 * q), lines, np.uint64(LINE_F32 * q)
                )
        # the stores are weakly ordered: all in memory before the caller reads y
        store_fence()


@njit(parallel=True, cache=True, fastmath={"contract"})
def _transform_inplace_nb(R, t, x, chunk):
    """:func:`_transform_nb` with ``y = x`` (one array: no aliasing check for LLVM to fail), prefetching
    ``PREFETCH_AHEAD`` floats ahead, one group of ``STREAM_GROUP`` points at a time (its lines are in cache,
    dirty, after the loop: no read for ownership to avoid)."""
    n = x.shape[0] // 3
    for c in prange(_ceil_div(n, chunk)):
        end = min(n, (c + 1) * chunk)
        for a in range(c * chunk, end, STREAM_GROUP):
            _prefetch_group(x, _U3 * np.uint64(a))
            _transform_span(R, t, x, x, a, min(end, a + STREAM_GROUP))


def _stream_head(y):
    """Points before the first one whose output starts a cache line: ``h`` in [0, 16) with
    ``address(y) + 12 h = 0 (mod 64)`` (one exists for any 4-byte aligned ``y``: 3 is invertible mod 16);
    None for a misaligned ``y``. ``y`` is the float32 output, (N, 3) or flat (3N,)."""
    address = y.__array_interface__["data"][0]
    return next(
        (
            h
            for h in range(STREAM_GROUP)
            if (address + _POINT_BYTES * h) % LINE_BYTES == 0
        ),
        None,
    )


def transform_points(T, points, out=None):
    """``p' = R p + t`` for ``T`` (4, 4) and ``points`` (N, 3) float32 -> (N, 3) float32 (float32 arithmetic).

    ``out`` (N, 3) float32, C-contiguous, receives the result and is returned (no allocation: a caller that
    reuses a buffer pays no page faults); ``out=points`` transforms in place (when ``points`` is already a
    C-contiguous float32 array). Parallel over spans of ``TRANSFORM_CHUNK`` points; the arithmetic is float32
    with contraction into FMAs (agrees with the reference to float32 rounding, not bit for bit). An ``out``
    buffer of ``STREAM_MIN_POINTS`` points or more is written past the cache (non-temporal stores: memory
    traffic 24 instead of 36 bytes per point), so a large result is not in cache afterwards; the floats are the
    same either way.
    """
    T = np.asarray(T)  # cast to float32 below
    pts = np.ascontiguousarray(points, dtype=np.float32)
    if T.shape != (4, 4) or pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(
            f"need T (4, 4) and points (N, 3), got {T.shape} and {pts.shape}"
        )
    # the pose as a batch of one particle: R (1, 3, 3), t (1, 3) float32
    R32 = np.ascontiguousarray(T[None, :3, :3], dtype=np.float32)
    t32 = np.ascontiguousarray(T[None, :3, 3], dtype=np.float32)
    fresh = out is None
    if fresh:
        out = np.empty_like(pts)
    elif out is pts or (
        isinstance(out, np.ndarray) and out.shape == pts.shape and _same_memory(out, pts)
    ):
        _check_out(out, pts, "out")
        _launch(
            _transform_inplace_nb, len(pts), TRANSFORM_CHUNK, R32, t32, out.reshape(-1)
        )
        return out
    else:
        _check_out(out, pts, "out")
    # a fresh array's pages are zeroed by the OS as they fault in, which leaves each in cache: plain stores then
    # hit, where non-temporal ones would first have to push the line out (measured 1.3x slower at 1e7 and 1e8)
    head = _stream_head(out) if len(pts) >= STREAM_MIN_POINTS and not fresh else None
    if head is None:
        _launch(
            _transform_nb,
            len(pts),
            TRANSFORM_CHUNK,
            R32,
            t32,
            pts.reshape(-1),
            out.reshape(-1),
        )
    else:
        # one task per thread: each task ends with a store fence, which waits for its write-combining buffers
        per_thread = max(1, _ceil_div(len(pts) // STREAM_GROUP, numba.get_num_threads()))
        _transform_stream_nb(R32, t32, pts.reshape(-1), out.reshape(-1), head, per_thread)
    return out


# ------------------------------------------------------------------------------------------------- scoring
@njit(cache=True, inline="always")
def _n_chunks(N, P, pt_chunk, part_chunk):
    """Number of point chunks and of particle chunks; tasks are their ``npc * nqc`` pairs."""
    return _ceil_div(N, pt_chunk), _ceil_div(P, part_chunk)


@njit(cache=True, inline="always")
def _task_span(task, nqc, N, P, pt_chunk, part_chunk):
    """``(c, j0, j1, i0, i1)``: task ``task`` scores points ``j0:j1`` (point chunk ``c``) for particles ``i0:i1``."""
    c = task // nqc
    i0 = (task - c * nqc) * part_chunk
    return c, c * pt_chunk, min(N, (c + 1) * pt_chunk), i0, min(P, i0 + part_chunk)


@njit(cache=True)
def _sum_chunks(partial):
    """Per-particle sums (P,) of ``partial`` (npc, P), added in chunk order (independent of the thread count)."""
    out = np.zeros(partial.shape[1])
    for c in range(partial.shape[0]):
        for i in range(partial.shape[1]):
            out[i] += partial[c, i]
    return out


#: Voxel blocks whose 8 corner slots one scoring task remembers (:func:`score_particles`, voxel hash map).
BLOCK_CACHE = 4


@njit(parallel=True, cache=True)
def _score_voxel_nb(
    R,
    t,
    pts,
    keys,
    mean,
    icov,
    inv_h,
    log2_capacity,
    max_probe,
    m_max,
    pt_chunk,
    part_chunk,
):
    P = R.shape[0]
    N = pts.shape[0]
    npc, nqc = _n_chunks(N, P, pt_chunk, part_chunk)
    partial = np.zeros((npc, P))
    miss = -0.5 * m_max
    for task in prange(npc * nqc):
        c, j0, j1, i0, i1 = _task_span(task, nqc, N, P, pt_chunk, part_chunk)
        # the 8 corner slots of the last BLOCK_CACHE blocks looked up (oldest replaced first): the particles'
        # copies of a point straddle a few neighbouring blocks, which one remembered block would keep swapping
        bx = np.full(BLOCK_CACHE, NO_BLOCK)
        by = np.full(BLOCK_CACHE, NO_BLOCK)
        bz = np.full(BLOCK_CACHE, NO_BLOCK)
        slots = np.empty((BLOCK_CACHE, 8), np.int64)
        cur, oldest = 0, 0
        for j in range(j0, j1):
            x, y, z = np.float64(pts[j, 0]), np.float64(pts[j, 1]), np.float64(pts[j, 2])
            for i in range(i0, i1):
                wx, wy, wz = _world_point(R, t, i, x, y, z)
                ux0, uy0, uz0, fx, fy, fz, ok = _voxel_cell(wx, wy, wz, inv_h)
                if not ok:
                    partial[c, i] += miss
                    continue
                if ux0 != bx[cur] or uy0 != by[cur] or uz0 != bz[cur]:
                    cur = -1
                    for e in range(BLOCK_CACHE):
                        if ux0 == bx[e] and uy0 == by[e] and uz0 == bz[e]:
                            cur = e
                            break
                    if cur < 0:
                        cur, oldest = oldest, (oldest + 1) % BLOCK_CACHE
                        bx[cur], by[cur], bz[cur] = ux0, uy0, uz0
                        for k in range(8):
                            slots[cur, k] = _corner_slot(
                                ux0, uy0, uz0, k, keys, log2_capacity, max_probe
                            )
                total = 0.0  # voxel_term's sum, in its corner order: the same bits
                for k in range(8):
                    total += _corner_weight(fx, fy, fz, k) * _slot_term(
                        wx, wy, wz, slots[cur, k], mean, icov, m_max
                    )
                partial[c, i] += total
    return _sum_chunks(partial)


#: log2 of the entries (2**8 = 256) of the per-task direct-mapped cache of cell look-ups in ``score_particles``
#: (Morton map).
CELL_CACHE_BITS = 8


@njit(cache=True, inline="always")
def _find_cell_cached_nb(cell_codes, code, cache_code, cache_k, cache_bits):
    """``find_cell`` through a direct-mapped cache of ``2**cache_bits`` entries addressed by the code's hash
    (``cache_code`` starts filled with -1).

    The copies of one scan point under nearby particles fall in the same few cells, so most binary searches
    (about 15 unpredictable branches each, the main cost of a query) are answered from the cache."""
    e = _hash_slot(code, cache_bits)
    if cache_code[e] == code:
        return cache_k[e]
    k = _find_cell(cell_codes, code)
    cache_code[e] = code
    cache_k[e] = k
    return k


@njit(cache=True, inline="always")
def _axis_gap(u, c, size):
    """Distance (in quanta) along one axis from coordinate ``u`` to the cell ``[c size, (c + 1) size)``."""
    lo = c * size
    if u < lo:
        return lo - u
    hi = lo + size
    if u > hi:
        return u - hi
    return 0.0


#: Runs of at most this many points are scanned linearly instead of split further.
MORTON_LEAF = 64


@njit(cache=True, inline="always")
def _push(stack, sp, lo, hi, level, nx, ny, nz):
    """Push the octree node ``(nx, ny, nz)`` of ``level`` holding the run ``codes[lo:hi]``; return the new ``sp``."""
    stack[sp, 0] = lo
    stack[sp, 1] = hi
    stack[sp, 2] = level
    stack[sp, 3] = nx
    stack[sp, 4] = ny
    stack[sp, 5] = nz
    return sp + 1


@njit(cache=True)
def morton_nn_nb(
    wx,
    wy,
    wz,
    codes,
    points,
    cell_codes,
    cell_start,
    cell_lo,
    cell_hi,
    quantum,
    cell_level,
    best,
    best_j,
    stack,
    leaf,
    cache_code,
    cache_k,
    cache_bits,
):
    """Nearest stored point to world point ``(wx, wy, wz)`` closer than ``sqrt(best)``: ``(best, best_j)``.

    Exact branch-and-bound search of the implicit octree over the sorted Morton codes (see ``MortonLookup``):
    the 2x2x2 block of level-``cell_level`` cells nearest the point (``cell_block``; the one holding it first),
    each found by binary search in ``cell_codes`` (skipped when the tight box ``cell_lo``/``cell_hi`` of its
    points is not nearer than ``best``); a node whose run has more than ``leaf`` points is split into its
    8 child runs (consecutive in Morton order, bounded by binary search on ``codes >> 3 (level - 1)``), the child
    holding the point visited first; nodes whose box is not nearer than ``best`` are skipped. Pass
    ``best = radius^2, best_j = -1`` for a plain query, or a smaller ``best`` with the index ``best_j`` of a point
    at that squared distance (warm start); the result is ``min(d_nn^2, best)`` either way (the same value as
    the brute-force ``morton_d2`` of :mod:`slamlib.kernels.device`, which the CUDA kernel uses).
    ``stack`` is scratch space, int64 of shape ``(8 * (cell_level + 2), 6)``; ``cache_code`` (length
    ``2**cache_bits``, filled with -1 before first use) and ``cache_k`` cache cell look-ups between calls.
    """
    ux, uy, uz, cx0, cy0, cz0, ok = _cell_block(wx, wy, wz, quantum, cell_level)
    if not ok:
        return best, best_j
    size0 = np.float64(np.int64(1) << cell_level)
    lim = _cells_per_axis(cell_level)
    q2 = quantum * quantum
    # round 0: the cell that holds the point; round 1: the other seven
    for rnd in range(2):
        for blk in range(8):
            cx = cx0 + (blk & 1)
            cy = cy0 + ((blk >> 1) & 1)
            cz = cz0 + (blk >> 2)
            if cx < 0 or cy < 0 or cz < 0 or cx >= lim or cy >= lim or cz >= lim:
                continue
            gx = _axis_gap(ux, cx, size0)
            gy = _axis_gap(uy, cy, size0)
            gz = _axis_gap(uz, cz, size0)
            box2 = (gx * gx + gy * gy + gz * gz) * q2
            if (rnd == 0) != (box2 == 0.0) or box2 >= best:
                continue
            k = _find_cell_cached_nb(
                cell_codes, _morton(cx, cy, cz), cache_code, cache_k, cache_bits
            )
            if k < 0:
                continue
            gx = max(np.float64(cell_lo[k, 0]) - wx, 0.0, wx - np.float64(cell_hi[k, 0]))
            gy = max(np.float64(cell_lo[k, 1]) - wy, 0.0, wy - np.float64(cell_hi[k, 1]))
            gz = max(np.float64(cell_lo[k, 2]) - wz, 0.0, wz - np.float64(cell_hi[k, 2]))
            if gx * gx + gy * gy + gz * gz >= best:
                continue  # the tight box of the cell's points is too far
            sp = _push(stack, 0, cell_start[k], cell_start[k + 1], cell_level, cx, cy, cz)
            while sp > 0:
                sp -= 1
                lo = stack[sp, 0]
                hi = stack[sp, 1]
                lev = stack[sp, 2]
                nx = stack[sp, 3]
                ny = stack[sp, 4]
                nz = stack[sp, 5]
                size = np.float64(np.int64(1) << lev)
                gx = _axis_gap(ux, nx, size)
                gy = _axis_gap(uy, ny, size)
                gz = _axis_gap(uz, nz, size)
                if (gx * gx + gy * gy + gz * gz) * q2 >= best:
                    continue
                if hi - lo <= leaf or lev == 0:
                    best, best_j = _nearest_in_run(
                        points, lo, hi, wx, wy, wz, best, best_j
                    )
                    continue
                shift = 3 * (lev - 1)
                parent = (codes[lo] >> shift) >> 3
                half = size * 0.5
                # the child holding the point (if any) is pushed last, so it is searched first
                hold = -1
                if ux >= nx * size and uy >= ny * size and uz >= nz * size:
                    hxi = np.int64(ux - nx * size >= half)
                    hyi = np.int64(uy - ny * size >= half)
                    hzi = np.int64(uz - nz * size >= half)
                    if (
                        ux < (nx + 1) * size
                        and uy < (ny + 1) * size
                        and uz < (nz + 1) * size
                    ):
                        hold = hxi | (hyi << 1) | (hzi << 2)
                start = lo
                hold_lo = 0
                hold_hi = 0
                for ch in range(8):
                    # end of child ch: first index in [start, hi) whose level-(lev-1) prefix exceeds it
                    target = (parent << 3) | ch
                    l2 = start
                    h2 = hi
                    while l2 < h2:
                        mid = (l2 + h2) >> 1
                        if (codes[mid] >> shift) <= target:
                            l2 = mid + 1
                        else:
                            h2 = mid
                    if l2 > start:
                        if ch == hold:
                            hold_lo = start
                            hold_hi = l2
                        else:
                            sp = _push(
                                stack,
                                sp,
                                start,
                                l2,
                                lev - 1,
                                2 * nx + (ch & 1),
                                2 * ny + ((ch >> 1) & 1),
                                2 * nz + (ch >> 2),
                            )
                    start = l2
                if hold_hi > hold_lo:
                    sp = _push(
                        stack,
                        sp,
                        hold_lo,
                        hold_hi,
                        lev - 1,
                        2 * nx + (hold & 1),
                        2 * ny + ((hold >> 1) & 1),
                        2 * nz + (hold >> 2),
                    )
    return best, best_j


@njit(parallel=True, cache=True)
def _score_morton_nb(
    R,
    t,
    pts,
    codes,
    points,
    cell_codes,
    cell_start,
    cell_lo,
    cell_hi,
    quantum,
    cell_level,
    radius,
    sigma,
    pt_chunk,
    part_chunk,
    leaf,
    cache_bits,
):
    P = R.shape[0]
    N = pts.shape[0]
    npc, nqc = _n_chunks(N, P, pt_chunk, part_chunk)
    partial = np.zeros((npc, P))
    r2 = radius * radius
    scale = -0.5 / (sigma * sigma)
    for task in prange(npc * nqc):
        stack = np.empty((8 * (cell_level + 2), 6), np.int64)
        cache_code = np.full(1 << cache_bits, -1, np.int64)
        cache_k = np.empty(1 << cache_bits, np.int64)
        c, j0, j1, i0, i1 = _task_span(task, nqc, N, P, pt_chunk, part_chunk)
        for j in range(j0, j1):
            x, y, z = np.float64(pts[j, 0]), np.float64(pts[j, 1]), np.float64(pts[j, 2])
            prev = -1
            for i in range(i0, i1):
                wx, wy, wz = _world_point(R, t, i, x, y, z)
                best, found = r2, -1
                # warm start: the previous particle's neighbour bounds this one's distance
                if prev >= 0:
                    best, found = _nearest_in_run(
                        points, prev, prev + 1, wx, wy, wz, r2, -1
                    )
                best, prev = morton_nn_nb(
                    wx,
                    wy,
                    wz,
                    codes,
                    points,
                    cell_codes,
                    cell_start,
                    cell_lo,
                    cell_hi,
                    quantum,
                    cell_level,
                    best,
                    found,
                    stack,
                    leaf,
                    cache_code,
                    cache_k,
                    cache_bits,
                )
                partial[c, i] += scale * best
    return _sum_chunks(partial)


def score_particles(R, t, points, lookup):
    """Fused transform + lookup log-likelihood (P,) float64 (see :func:`slamlib.kernels.reference.score_particles`).

    ``lookup`` is a :class:`~slamlib.maps.base.VoxelHashLookup` or :class:`~slamlib.maps.base.MortonLookup`.
    """
    R, t = _check_particles(R, t)
    pts = np.ascontiguousarray(points, dtype=np.float32)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {pts.shape}")
    if lookup.kind == KIND_VOXEL_HASH:
        return _score_voxel_nb(
            R,
            t,
            pts,
            lookup.keys,
            lookup.mean,
            lookup.icov,
            float(lookup.inv_voxel_size),
            int(lookup.log2_capacity),
            int(lookup.max_probe),
            float(lookup.m_max),
            POINT_CHUNK,
            PARTICLE_CHUNK,
        )
    if lookup.kind == KIND_MORTON:
        return _score_morton_nb(
            R,
            t,
            pts,
            lookup.codes,
            lookup.points,
            lookup.cell_codes,
            lookup.cell_start,
            lookup.cell_lo,
            lookup.cell_hi,
            float(lookup.quantum),
            int(lookup.cell_level),
            float(lookup.radius),
            float(lookup.sigma),
            POINT_CHUNK,
            PARTICLE_CHUNK,
            MORTON_LEAF,
            CELL_CACHE_BITS,
        )
    raise ValueError(f"unknown lookup kind {lookup.kind!r}")


# ----------------------------------------------------------------------------------------------- resampling
@njit(cache=True)
def _systematic_nb(c, u0):
    P = c.shape[0]
    out = np.empty(P, np.int64)
    j = 0
    for i in range(P):
        u = (u0 + i) / P
        while j < P - 1 and not (u < c[j]):
            j += 1
        out[i] = j
    return out


def systematic_resample(weights, u0):
    """Systematic resampling (P,) int64 (see :func:`slamlib.kernels.reference.systematic_resample`), O(P)."""
    w = np.ascontiguousarray(weights, dtype=np.float64)
    if (
        w.ndim != 1
        or w.size == 0
        or np.any(~np.isfinite(w))
        or np.any(w < 0)
        or not w.sum() > 0
    ):
        raise ValueError(
            "weights must be a non-empty 1-D array of finite non-negative numbers with positive sum"
        )
    if not 0.0 <= u0 < 1.0:
        raise ValueError(f"u0 must be in [0, 1), got {u0}")
    c = np.cumsum(w / w.sum())  # the same normalised cumulative sum as the reference
    c[-1] = 1.0
    return _systematic_nb(c, float(u0))
