"""Integer codes shared by the maps and the kernels: packed voxel keys, their hash, 3D Morton codes.

Each function exists as a Numba scalar function (``*_nb``, usable from ``@njit`` and ``prange`` kernels) and as a
vectorised numpy function, and both follow the formulas below bit for bit (the tests check it).

* Voxel / quantised index of a coordinate ``x`` with cell size ``h``: ``i = floor(x / h)`` (computed as
  ``floor(x * (1/h))`` in float64), valid in ``[-2**20, 2**20)``; ``u = i + 2**20`` is in ``[0, 2**21)``.
* Packed voxel key: ``key = ux | uy << 21 | uz << 42`` (int64, non-negative).
* Hash (Fibonacci / multiplicative hashing, Knuth TAOCP vol. 3, sec. 6.4):
  ``slot = ((uint64(key) * 0x9E3779B97F4A7C15) mod 2**64) >> (64 - log2_capacity)``.
* Morton code (Z-order, Morton 1966): bits of ``ux, uy, uz`` interleaved, ``x`` in bit ``3b``, ``y`` in
  ``3b+1``, ``z`` in ``3b+2`` (63 bits, int64, non-negative); ``code >> 3L`` is the code of the level-``L`` cell.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from slamlib.maps.base import AXIS_OFFSET, BITS_PER_AXIS, HASH_MULTIPLIER

_AXIS_MASK = (1 << BITS_PER_AXIS) - 1
_HASH_U64 = np.uint64(HASH_MULTIPLIER)


@njit(cache=True, inline="always")
def axis_index_nb(x, inv_h):
    """``floor(x * inv_h) + 2**20`` as int64 (``-1`` style out-of-range is checked with :func:`in_range_nb`)."""
    return np.int64(np.floor(x * inv_h)) + AXIS_OFFSET


@njit(cache=True, inline="always")
def in_range_nb(u):
    """True when the offset index ``u`` fits in 21 bits."""
    return u >= 0 and u <= _AXIS_MASK


@njit(cache=True, inline="always")
def pack_key_nb(ux, uy, uz):
    """Packed voxel key ``ux | uy << 21 | uz << 42`` of offset indices (each in ``[0, 2**21)``)."""
    return ux | (uy << 21) | (uz << 42)


@njit(cache=True, inline="always")
def hash_slot_nb(key, log2_capacity):
    """Home slot ``((uint64(key) * 0x9E3779B97F4A7C15) mod 2**64) >> (64 - log2_capacity)``."""
    h = np.uint64(key) * _HASH_U64
    return np.int64(h >> np.uint64(64 - log2_capacity))


@njit(cache=True, inline="always")
def find_slot_nb(keys, key, log2_capacity, max_probe):
    """Slot holding ``key`` in the linear-probing table ``keys``, or -1 (stops at an empty slot)."""
    mask = (np.int64(1) << log2_capacity) - 1
    s = hash_slot_nb(key, log2_capacity)
    for _ in range(max_probe + 1):
        k = keys[s]
        if k == key:
            return s
        if k == -1:
            return -1
        s = (s + 1) & mask
    return -1


@njit(cache=True, inline="always")
def _part1by2_nb(v):
    v = v & 0x1FFFFF
    v = (v | (v << 32)) & 0x1F00000000FFFF
    v = (v | (v << 16)) & 0x1F0000FF0000FF
    v = (v | (v << 8)) & 0x100F00F00F00F00F
    v = (v | (v << 4)) & 0x10C30C30C30C30C3
    v = (v | (v << 2)) & 0x1249249249249249
    return v


@njit(cache=True, inline="always")
def morton_nb(ux, uy, uz):
    """63-bit Morton code of offset indices (int64 each in ``[0, 2**21)``)."""
    return _part1by2_nb(np.int64(ux)) | (_part1by2_nb(np.int64(uy)) << 1) | (_part1by2_nb(np.int64(uz)) << 2)


# ---------------------------------------------------------------------------------------------- numpy versions
def axis_indices(points, inv_h: float) -> tuple[np.ndarray, np.ndarray]:
    """Offset indices ``floor(p * inv_h) + 2**20`` (N, 3) int64 of points (N, 3), and the in-range mask (N,)."""
    p = np.asarray(points, dtype=np.float64)
    u = np.floor(p * inv_h)
    ok = np.all(np.isfinite(u), axis=1)
    u = np.where(np.isfinite(u), u, -1.0)
    u = u.astype(np.int64) + AXIS_OFFSET
    ok &= np.all((u >= 0) & (u <= _AXIS_MASK), axis=1)
    return u, ok


def pack_keys(u: np.ndarray) -> np.ndarray:
    """Packed keys ``ux | uy << 21 | uz << 42`` of offset indices (N, 3) int64."""
    u = np.asarray(u, dtype=np.int64)
    return u[:, 0] | (u[:, 1] << 21) | (u[:, 2] << 42)


def hash_slots(keys: np.ndarray, log2_capacity: int) -> np.ndarray:
    """Home slots of packed keys (vectorised :func:`hash_slot_nb`)."""
    h = np.asarray(keys, dtype=np.int64).astype(np.uint64) * _HASH_U64  # wraps mod 2**64
    return (h >> np.uint64(64 - log2_capacity)).astype(np.int64)


def _part1by2(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=np.int64) & 0x1FFFFF
    v = (v | (v << 32)) & 0x1F00000000FFFF
    v = (v | (v << 16)) & 0x1F0000FF0000FF
    v = (v | (v << 8)) & 0x100F00F00F00F00F
    v = (v | (v << 4)) & 0x10C30C30C30C30C3
    v = (v | (v << 2)) & 0x1249249249249249
    return v


def morton_codes(u: np.ndarray) -> np.ndarray:
    """Morton codes (N,) int64 of offset indices (N, 3) int64 (vectorised :func:`morton_nb`)."""
    u = np.asarray(u, dtype=np.int64)
    return _part1by2(u[:, 0]) | (_part1by2(u[:, 1]) << 1) | (_part1by2(u[:, 2]) << 2)
