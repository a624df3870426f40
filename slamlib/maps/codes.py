"""Integer codes shared by the maps and the kernels: packed voxel keys, their hash, linear probing, 3D Morton
codes and the search of a sorted cell list. Written once, compiled for numpy, Numba CPU and CUDA.

Formulas (int64 unless stated; every build follows them bit for bit, the tests check it):

* Voxel / quantised index of a coordinate ``x`` with cell size ``h``: ``i = floor(x / h)`` (computed as
  ``floor(x * (1/h))`` in float64), valid in ``[-2**20, 2**20)``; ``u = i + 2**20`` is in ``[0, 2**21)``.
* Packed voxel key: ``key = ux | uy << 21 | uz << 42`` (non-negative).
* Hash (Fibonacci / multiplicative hashing, Knuth TAOCP vol. 3, sec. 6.4):
  ``slot = ((uint64(key) * 0x9E3779B97F4A7C15) mod 2**64) >> (64 - log2_capacity)``.
* Find-slot (linear probing, Knuth TAOCP vol. 3, 6.4 algorithm L): probe ``slot, slot + 1, ...`` (mod capacity)
  until the key or an empty slot (-1), at most ``max_probe + 1`` slots.
* Morton code (Z-order, Morton 1966): bits of ``ux, uy, uz`` interleaved, ``x`` in bit ``3b``, ``y`` in
  ``3b+1``, ``z`` in ``3b+2`` (63 bits, non-negative); ``code >> 3L`` is the code of the level-``L`` cell.
* Find-cell: binary search of a code in a sorted array (lower bound, then an equality check).

Write once, compile per target
------------------------------
:func:`make_code_functions` holds the only source of these functions and compiles it with a decorator, as
:func:`slamlib.noise.make_lut_functions` does: the identity gives numpy (vectorised over arrays where noted),
``numba.njit(inline="always")`` gives the Numba CPU build (the ``*_nb`` names below, used by
:mod:`slamlib.maps.voxel_hash`), ``numba.cuda.jit(device=True)`` the CUDA build (through
:func:`slamlib.kernels.device.make_point_functions`, which adds the per-point kernel math). Functions that call
each other are built by the same factory call, so every build calls its own compiled siblings.

Under the CUDA simulator device functions run as Python on numpy scalars, so all integer arithmetic is on
explicitly typed numpy scalars (the constants below are ``np.int64`` / ``np.uint64``, so Numba never promotes
``uint64 op int64`` to float), and the 64-bit hash product is formed from 32-bit halves so that no
multiplication wraps: numpy scalars, numpy arrays, Numba and the GPU agree without overflow warnings.

Numba's on-disk cache of the ``cache=True`` callers (:mod:`slamlib.maps.voxel_hash`,
:mod:`slamlib.kernels.cpu`) is keyed on their own files: clear ``$NUMBA_CACHE_DIR`` after editing this one.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from slamlib.maps.base import AXIS_OFFSET, BITS_PER_AXIS, EMPTY_KEY, HASH_MULTIPLIER

# ------------------------------------------------------------------------------------------------- constants
#: Largest offset index on one axis, ``2**21 - 1 = 0x1FFFFF`` (also the mask of one axis in a packed key).
AXIS_MASK = np.int64((1 << BITS_PER_AXIS) - 1)
#: Bit where ``uy`` starts in a packed key (21).
KEY_SHIFT_Y = np.int64(BITS_PER_AXIS)
#: Bit where ``uz`` starts in a packed key (42).
KEY_SHIFT_Z = np.int64(2 * BITS_PER_AXIS)
#: :data:`~slamlib.maps.base.AXIS_OFFSET` (``2**20``) as a typed scalar.
AXIS_OFFSET_I64 = np.int64(AXIS_OFFSET)
#: :data:`~slamlib.maps.base.AXIS_OFFSET` as float64 (``1048576.0``), for offsetting coordinates in quanta.
AXIS_OFFSET_F64 = np.float64(AXIS_OFFSET)

# The hash multiplier 0x9E3779B97F4A7C15 (2**64 / golden ratio) in 32-bit halves: the product mod 2**64 is
# assembled from partial products that each fit in 64 bits (schoolbook multiplication, high x high dropped).
_HASH_LO, _HASH_HI = (
    np.uint64(HASH_MULTIPLIER & 0xFFFFFFFF),
    np.uint64(HASH_MULTIPLIER >> 32),
)
_M32 = np.uint64(0xFFFFFFFF)  # low 32 bits
# shift counts, typed so that Numba keeps uint64 arithmetic
_S32, _U64_BITS = np.uint64(32), np.uint64(64)

#: Masks of the five shift-or-mask steps (shifts 32, 16, 8, 4, 2) that spread the 21 bits of an index to every
#: third bit (part1by2), the magic-number form of Morton encoding (Karras 2012, "Thinking parallel, part III";
#: Baert 2013, "Morton encoding/decoding through bit interleaving"): the step with shift s copies every bit
#: group up by s bits, and its mask keeps, of the original and the copy, the bits at their final spacing.
MORTON_MASKS = (
    np.int64(0x001F00000000FFFF),
    np.int64(0x001F0000FF0000FF),
    np.int64(0x100F00F00F00F00F),
    np.int64(0x10C30C30C30C30C3),
    np.int64(0x1249249249249249),
)
_MM32, _MM16, _MM8, _MM4, _MM2 = MORTON_MASKS


def _identity(fn):
    return fn


def make_code_functions(deco: Callable = _identity) -> dict:
    """Compile the integer codes with ``deco`` (identity, ``njit(inline="always")``, ``cuda.jit(device=True)``).

    Returns a dict of scalar functions (the identity build of ``pack_key``, ``hash_slot`` and ``morton`` also
    takes int64 arrays, element-wise):

    ``axis_index(x, inv_h)``
        ``floor(x * inv_h) + 2**20`` (int64); ``x * inv_h`` must be finite and small (check it first).
    ``in_range(u)``
        True when the offset index ``u`` fits in 21 bits, ``0 <= u <= 0x1FFFFF``.
    ``pack_key(ux, uy, uz)``
        ``ux | uy << 21 | uz << 42`` of offset indices (each in ``[0, 2**21)``).
    ``hash_slot(key, log2_capacity)``
        Home slot ``((uint64(key) * 0x9E3779B97F4A7C15) mod 2**64) >> (64 - log2_capacity)`` (int64) of a
        non-negative key, ``1 <= log2_capacity <= 63``.
    ``find_slot(keys, key, log2_capacity, max_probe)``
        Slot holding ``key`` in the linear-probing table ``keys`` ((2**log2_capacity,) int64, -1 = empty), or
        -1 (stops at an empty slot or after ``max_probe + 1`` slots).
    ``part1by2(v)``
        The low 21 bits of ``v`` spread to bits ``0, 3, 6, ...``.
    ``morton(ux, uy, uz)``
        63-bit Morton code of offset indices (each in ``[0, 2**21)``).
    ``find_cell(cell_codes, code)``
        Index of ``code`` in the sorted int64 array ``cell_codes``, or -1 (binary search, ``O(log K)``).
    """

    def axis_index(x, inv_h):
        return np.int64(math.floor(x * inv_h)) + AXIS_OFFSET_I64

    def in_range(u):
        return u >= 0 and u <= AXIS_MASK

    def pack_key(ux, uy, uz):
        return ux | (uy << KEY_SHIFT_Y) | (uz << KEY_SHIFT_Z)

    def hash_slot(key, log2_capacity):
        a = np.uint64(key)
        a_lo = a & _M32
        a_hi = a >> _S32  # < 2**31 for a non-negative key
        lo = a_lo * _HASH_LO
        # bits 32..63 of the product: the cross terms and the carry of the low product (each term < 2**32)
        cross = ((a_hi * _HASH_LO) & _M32) + ((a_lo * _HASH_HI) & _M32) + (lo >> _S32)
        prod = ((cross & _M32) << _S32) | (lo & _M32)
        return np.int64(prod >> (_U64_BITS - np.uint64(log2_capacity)))

    hash_slot = deco(hash_slot)

    def find_slot(keys, key, log2_capacity, max_probe):
        mask = (np.int64(1) << log2_capacity) - 1
        s = hash_slot(key, log2_capacity)
        for _ in range(max_probe + 1):
            k = keys[s]
            if k == key:
                return s
            if k == EMPTY_KEY:
                return -1
            s = (s + 1) & mask
        return -1

    def part1by2(v):
        v = v & AXIS_MASK
        v = (v | (v << 32)) & _MM32
        v = (v | (v << 16)) & _MM16
        v = (v | (v << 8)) & _MM8
        v = (v | (v << 4)) & _MM4
        v = (v | (v << 2)) & _MM2
        return v

    part1by2 = deco(part1by2)

    def morton(ux, uy, uz):
        return (
            part1by2(np.int64(ux))
            | (part1by2(np.int64(uy)) << 1)
            | (part1by2(np.int64(uz)) << 2)
        )

    def find_cell(cell_codes, code):
        lo = 0
        hi = cell_codes.shape[0]
        while lo < hi:
            mid = (lo + hi) >> 1
            if cell_codes[mid] < code:
                lo = mid + 1
            else:
                hi = mid
        if lo < cell_codes.shape[0] and cell_codes[lo] == code:
            return lo
        return -1

    return {
        "axis_index": deco(axis_index),
        "in_range": deco(in_range),
        "pack_key": deco(pack_key),
        "hash_slot": hash_slot,
        "find_slot": deco(find_slot),
        "part1by2": part1by2,
        "morton": deco(morton),
        "find_cell": deco(find_cell),
    }


# ------------------------------------------------------------------------------------------------ Numba CPU
def _numba_build() -> dict:
    from numba import njit

    return make_code_functions(njit(inline="always"))


_NB = _numba_build()
#: The ``@njit`` builds (usable from ``@njit`` / ``prange`` code; see :func:`make_code_functions`).
axis_index_nb = _NB["axis_index"]
in_range_nb = _NB["in_range"]
pack_key_nb = _NB["pack_key"]
hash_slot_nb = _NB["hash_slot"]
find_slot_nb = _NB["find_slot"]
morton_nb = _NB["morton"]
find_cell_nb = _NB["find_cell"]

# ---------------------------------------------------------------------------------------------------- numpy
_NP = make_code_functions()


def axis_indices(points, inv_h: float) -> tuple[np.ndarray, np.ndarray]:
    """Offset indices ``floor(p * inv_h) + 2**20`` (N, 3) int64 of points (N, 3), and the in-range mask (N,).

    Non-finite coordinates are masked out (their indices are meaningless)."""
    p = np.asarray(points, dtype=np.float64)
    u = np.floor(p * inv_h)
    ok = np.all(np.isfinite(u), axis=1)
    u = np.where(np.isfinite(u), u, -1.0)
    u = u.astype(np.int64) + AXIS_OFFSET_I64
    ok &= np.all((u >= 0) & (u <= AXIS_MASK), axis=1)
    return u, ok


def pack_keys(u: np.ndarray) -> np.ndarray:
    """Packed keys ``ux | uy << 21 | uz << 42`` (N,) int64 of offset indices (N, 3) int64."""
    u = np.asarray(u, dtype=np.int64)
    return _NP["pack_key"](u[:, 0], u[:, 1], u[:, 2])


def hash_slots(keys: np.ndarray, log2_capacity: int) -> np.ndarray:
    """Home slots (N,) int64 of non-negative packed keys (N,) (the numpy build of ``hash_slot``)."""
    return _NP["hash_slot"](np.asarray(keys, dtype=np.int64), log2_capacity)


def morton_codes(u: np.ndarray) -> np.ndarray:
    """Morton codes (N,) int64 of offset indices (N, 3) int64 (the numpy build of ``morton``)."""
    u = np.asarray(u, dtype=np.int64)
    return _NP["morton"](u[:, 0], u[:, 1], u[:, 2])
