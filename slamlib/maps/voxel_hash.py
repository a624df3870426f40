"""A bounded-memory hashed voxel map storing per-voxel Gaussians (NDT) for continuous, precise scoring.

Each occupied voxel (edge ``voxel_size``) keeps the count ``n``, the sum and the sum of outer products of its
points (taken relative to the voxel's corner, so float64 sums do not cancel far from the origin). From them the
map derives what scoring reads (:class:`~slamlib.maps.base.VoxelHashLookup`): the mean ``mu`` and the
regularised inverse covariance ``(Sigma + min_sigma^2 I)^-1`` with ``Sigma = S2/n - mu mu^T`` (biased). A point
``p`` in the voxel scores ``-0.5 min((p - mu)^T (Sigma + min_sigma^2 I)^-1 (p - mu), m_max)``: along a wall the
covariance is flat, so the score measures the point's distance to the wall's fitted plane with LIDAR precision
(``min_sigma``), not the voxel's size. This is the Normal Distributions Transform (Biber & Strasser, IROS 2003;
Magnusson, PhD thesis 2009) with a truncated (robust) quadratic instead of NDT's Gaussian-mixture score.

Storage: an open-addressing table of fixed ``capacity = 2**k`` slots, keys packed from the voxel indices
(21 bits per axis, see :mod:`slamlib.maps.codes`), Fibonacci hashing and linear probing (Knuth, TAOCP 6.4).
**When full**: the table accepts at most ``floor(max_load * capacity)`` voxels; points that would open a new voxel
beyond that are dropped and counted in :attr:`VoxelHashMap.n_dropped` (points in existing voxels are still
merged). Call :meth:`VoxelHashMap.prune` with the vehicle position to evict far voxels and make room.
Memory is fixed at construction: about 132 bytes per slot (:meth:`VoxelHashMap.memory_bytes`).

**Transients**: every :meth:`~VoxelHashMap.merge` is one *frame* of the map's own clock
(:attr:`VoxelHashMap.frames`), and each voxel remembers the first and the last frame that hit it.
:meth:`VoxelHashMap.evict_transients` drops the voxels that were hit only within a short span of frames and not
since: the trail a moving car or pedestrian leaves through the map, which a static surface in view does not
(it is hit frame after frame for as long as it is in range). It needs no ray casting, where occupancy mapping
clears the free space every ray passes through (OctoMap: Hornung et al., Autonomous Robots 34(3), 2013).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from slamlib.maps.base import (
    EMPTY_KEY,
    KIND_VOXEL_HASH,
    Map3D,
    VoxelHashLookup,
    as_points,
)
from slamlib.maps.codes import (
    AXIS_MASK,
    AXIS_OFFSET,
    KEY_SHIFT_Y,
    KEY_SHIFT_Z,
    axis_index_nb,
    hash_slot_nb,
    in_range_nb,
    pack_key_nb,
)

#: Hash-table slots of a voxel map when none are asked for, the 3D filter's map among them (its
#: :class:`~slamlib.slam3d.config.MapConfig` passes no ``capacity``): 2**19 slots hold up to 393,216 voxels at the
#: default ``max_load`` 0.75 and take 66 MiB (132 bytes a slot).
DEFAULT_VOXEL_CAPACITY = 2**19


@njit(cache=True)
def _update_field(s, count, s1, s2, mean, icov, corner_x, corner_y, corner_z, min_sigma2):
    """Recompute ``mean[s]`` and ``icov[s]`` of slot ``s`` from its sums (local coordinates)."""
    n = count[s]
    mx = s1[s, 0] / n
    my = s1[s, 1] / n
    mz = s1[s, 2] / n
    cxx = s2[s, 0] / n - mx * mx + min_sigma2
    cxy = s2[s, 1] / n - mx * my
    cxz = s2[s, 2] / n - mx * mz
    cyy = s2[s, 3] / n - my * my + min_sigma2
    cyz = s2[s, 4] / n - my * mz
    czz = s2[s, 5] / n - mz * mz + min_sigma2
    # inverse of the symmetric 3x3 matrix by its adjugate
    a00 = cyy * czz - cyz * cyz
    a01 = cxz * cyz - cxy * czz
    a02 = cxy * cyz - cxz * cyy
    a11 = cxx * czz - cxz * cxz
    a12 = cxy * cxz - cxx * cyz
    a22 = cxx * cyy - cxy * cxy
    det = cxx * a00 + cxy * a01 + cxz * a02
    inv = 1.0 / det
    mean[s, 0] = corner_x + mx
    mean[s, 1] = corner_y + my
    mean[s, 2] = corner_z + mz
    icov[s, 0] = a00 * inv
    icov[s, 1] = a01 * inv
    icov[s, 2] = a02 * inv
    icov[s, 3] = a11 * inv
    icov[s, 4] = a12 * inv
    icov[s, 5] = a22 * inv


@njit(cache=True)
def _merge_nb(
    points,
    keys,
    count,
    s1,
    s2,
    mean,
    icov,
    first,
    last,
    stamp,
    voxel_size,
    log2_capacity,
    max_voxels,
    min_sigma2,
    state,
):
    """Merge ``points`` (N, 3) f4 into the table; ``state = [n_voxels, max_probe, n_dropped]`` updated in place.
    A new voxel gets ``first = stamp``; every voxel hit gets ``last = stamp``."""
    inv_h = 1.0 / voxel_size
    mask = (np.int64(1) << log2_capacity) - 1
    n = points.shape[0]
    slots = np.full(n, -1, np.int64)
    for j in range(n):
        x = np.float64(points[j, 0])
        y = np.float64(points[j, 1])
        z = np.float64(points[j, 2])
        if not (
            abs(x * inv_h) < 2.0**21
            and abs(y * inv_h) < 2.0**21
            and abs(z * inv_h) < 2.0**21
        ):
            # non-finite, or so far out that the int64 conversion below could overflow
            state[2] += 1
            continue
        ux = axis_index_nb(x, inv_h)
        uy = axis_index_nb(y, inv_h)
        uz = axis_index_nb(z, inv_h)
        if not (in_range_nb(ux) and in_range_nb(uy) and in_range_nb(uz)):
            state[2] += 1
            continue
        key = pack_key_nb(ux, uy, uz)
        s = hash_slot_nb(key, log2_capacity)
        probe = 0
        while keys[s] != key and keys[s] != -1:
            s = (s + 1) & mask
            probe += 1
        if keys[s] == -1:
            if state[0] >= max_voxels:
                state[2] += 1
                continue
            keys[s] = key
            first[s] = stamp
            state[0] += 1
            if probe > state[1]:
                state[1] = probe
        lx = x - (ux - AXIS_OFFSET) * voxel_size
        ly = y - (uy - AXIS_OFFSET) * voxel_size
        lz = z - (uz - AXIS_OFFSET) * voxel_size
        count[s] += 1
        last[s] = stamp
        s1[s, 0] += lx
        s1[s, 1] += ly
        s1[s, 2] += lz
        s2[s, 0] += lx * lx
        s2[s, 1] += lx * ly
        s2[s, 2] += lx * lz
        s2[s, 3] += ly * ly
        s2[s, 4] += ly * lz
        s2[s, 5] += lz * lz
        slots[j] = s
    # refresh the field of every touched voxel (a repeat gives the same field: skip the
    # previous point's voxel, which the next points of a ring often share)
    for j in range(n):
        s = slots[j]
        if s >= 0 and (j == 0 or s != slots[j - 1]):
            key = keys[s]
            ux = key & AXIS_MASK
            uy = (key >> KEY_SHIFT_Y) & AXIS_MASK
            uz = (key >> KEY_SHIFT_Z) & AXIS_MASK
            _update_field(
                s,
                count,
                s1,
                s2,
                mean,
                icov,
                (ux - AXIS_OFFSET) * voxel_size,
                (uy - AXIS_OFFSET) * voxel_size,
                (uz - AXIS_OFFSET) * voxel_size,
                min_sigma2,
            )


@njit(cache=True)
def _reinsert_nb(
    old_keys,
    keep,
    count,
    s1,
    s2,
    mean,
    icov,
    first,
    last,
    keys,
    count2,
    s12,
    s22,
    mean2,
    icov2,
    first2,
    last2,
    log2_capacity,
):
    """Insert the kept slots of an old table into the empty table ``keys`` (same capacity); return max probe."""
    mask = (np.int64(1) << log2_capacity) - 1
    max_probe = 0
    for s_old in range(old_keys.shape[0]):
        if not keep[s_old]:
            continue
        key = old_keys[s_old]
        s = hash_slot_nb(key, log2_capacity)
        probe = 0
        while keys[s] != -1:
            s = (s + 1) & mask
            probe += 1
        if probe > max_probe:
            max_probe = probe
        keys[s] = key
        count2[s] = count[s_old]
        first2[s] = first[s_old]
        last2[s] = last[s_old]
        for a in range(3):
            s12[s, a] = s1[s_old, a]
            mean2[s, a] = mean[s_old, a]
        for a in range(6):
            s22[s, a] = s2[s_old, a]
            icov2[s, a] = icov[s_old, a]
    return max_probe


class VoxelHashMap(Map3D):
    """Hashed voxel map of per-voxel Gaussians (NDT) in the world frame, fixed memory.

    Parameters
    ----------
    voxel_size : float
        Voxel edge in metres (default 0.5; planes are fitted per voxel, so the score's precision does not
        depend on it, but too small voxels hold too few points for a covariance).
    capacity : int
        Number of hash slots, a power of two (default :data:`DEFAULT_VOXEL_CAPACITY`, ``2**19``: 66 MiB).
    max_load : float
        Maximum fraction of occupied slots (default 0.75); beyond it new voxels are refused.
    min_sigma : float
        Added to every covariance as ``min_sigma^2 I`` (metres; default 0.05: LIDAR noise plus motion
        distortion). Sets how sharply the score peaks across a surface.
    m_max : float
        Truncation of the squared Mahalanobis distance (default 16, i.e. 4 sigma); the cost of a point in an
        empty voxel is ``-0.5 m_max``.

    Attributes
    ----------
    n_dropped : int
        Points refused so far (non-finite, outside the +-2**20-voxel range, or table full).
    max_probe : int
        Longest linear-probe distance of any stored key.
    frames : int
        Merges so far: the map's clock for :meth:`evict_transients`.
    """

    def __init__(
        self,
        voxel_size: float = 0.5,
        capacity: int = DEFAULT_VOXEL_CAPACITY,
        max_load: float = 0.75,
        min_sigma: float = 0.05,
        m_max: float = 16.0,
    ):
        capacity = int(capacity)
        if capacity < 16 or capacity & (capacity - 1):
            raise ValueError(f"capacity must be a power of two >= 16, got {capacity}")
        if (
            not voxel_size > 0
            or not 0 < max_load < 1
            or not min_sigma > 0
            or not m_max > 0
        ):
            raise ValueError(
                "voxel_size, min_sigma, m_max must be > 0 and 0 < max_load < 1"
            )
        self.voxel_size = float(voxel_size)
        self.capacity = capacity
        self.log2_capacity = capacity.bit_length() - 1
        self.max_load = float(max_load)
        self.max_voxels = int(max_load * capacity)
        self.min_sigma = float(min_sigma)
        self.m_max = float(m_max)
        self._keys = np.full(capacity, EMPTY_KEY, np.int64)
        self._count = np.zeros(capacity, np.int64)
        self._s1 = np.zeros((capacity, 3), np.float64)
        self._s2 = np.zeros((capacity, 6), np.float64)
        self._mean = np.zeros((capacity, 3), np.float32)
        self._icov = np.zeros((capacity, 6), np.float32)
        # frame of the merge that opened the voxel
        # frame of the last merge that hit it
        self._first = np.zeros(capacity, np.int32)
        self._last = np.zeros(capacity, np.int32)
        self.frames = 0
        self._state = np.zeros(3, np.int64)  # n_voxels, max_probe, n_dropped
        self._changed()

    # ------------------------------------------------------------------------------------------- interface
    def merge(self, points_world) -> None:
        """Add world points (N, 3) to the voxels' statistics and refresh the touched voxels' Gaussians (Numba)."""
        pts = as_points(points_world, "points_world")
        _merge_nb(
            pts,
            self._keys,
            self._count,
            self._s1,
            self._s2,
            self._mean,
            self._icov,
            self._first,
            self._last,
            np.int32(self.frames),
            self.voxel_size,
            self.log2_capacity,
            self.max_voxels,
            self.min_sigma**2,
            self._state,
        )
        self.frames += 1
        self._changed()

    def lookup(self) -> VoxelHashLookup:
        """The flat lookup tuple (views of the map's buffers; call again after each merge or prune)."""
        return VoxelHashLookup(
            KIND_VOXEL_HASH,
            self._keys,
            self._mean,
            self._icov,
            self.voxel_size,
            1.0 / self.voxel_size,
            self.log2_capacity,
            int(self._state[1]),
            self.m_max,
            self.version,
        )

    def points(self) -> np.ndarray:
        """Voxel means (M, 3) float32 of the occupied voxels, world frame (for plots and PLY export)."""
        return self._mean[self._keys != EMPTY_KEY].copy()

    def counts(self) -> np.ndarray:
        """Number of merged points (M,) of each occupied voxel, in the order of :meth:`points`."""
        return self._count[self._keys != EMPTY_KEY].copy()

    def seen(self) -> tuple[np.ndarray, np.ndarray]:
        """Frames ``(first, last)`` (M,) int32 that first and last hit each occupied voxel (order of :meth:`points`;
        frame ``k`` is the ``k``-th merge, counted from 0)."""
        occupied = self._keys != EMPTY_KEY
        return self._first[occupied].copy(), self._last[occupied].copy()

    def __len__(self) -> int:
        return int(self._state[0])

    def _buffers(self) -> tuple:
        return (
            self._keys,
            self._count,
            self._s1,
            self._s2,
            self._mean,
            self._icov,
            self._first,
            self._last,
        )

    def memory_bytes(self) -> int:
        return int(sum(a.nbytes for a in self._buffers()))

    @property
    def resolution(self) -> float:
        """The voxel's edge, metres (:meth:`Map3D.resolution`)."""
        return self.voxel_size

    @property
    def n_dropped(self) -> int:
        return int(self._state[2])

    @property
    def max_probe(self) -> int:
        return int(self._state[1])

    def prune(self, center, radius: float) -> int:
        """Evict voxels whose mean is farther than ``radius`` metres from ``center`` (3,); rebuild the table.

        Returns the number of voxels evicted. Costs O(capacity)."""
        c = np.asarray(center, dtype=np.float64).reshape(3)
        d2 = np.sum((self._mean.astype(np.float64) - c) ** 2, axis=1)
        return self._keep_only((self._keys != EMPTY_KEY) & (d2 <= float(radius) ** 2))

    def transients(self, span: int, center=None, radius: float = np.inf) -> np.ndarray:
        """Which occupied voxels (M,) bool, in the order of :meth:`points`, are transient with a ``span`` of frames:
        every hit fell within fewer than ``span`` consecutive frames (``last - first < span``), the last one is at
        least ``span`` frames old (``frames - 1 - last >= span``), so a surface still being hit is never one, and
        the voxel's mean lies within ``radius`` metres of ``center`` (3,) when given: near the sensor, where a
        static surface would still be seen, not at the edge of its range, which the car has left behind.
        ``span`` >= 1 (frames)."""
        occupied = self._keys != EMPTY_KEY
        return self._transient(occupied, int(span), center, radius)

    def _transient(self, slots, span, center, radius):
        if span < 1:
            raise ValueError(f"span must be >= 1 frame, got {span}")
        first, last = self._first[slots], self._last[slots]
        out = (last - first < span) & (self.frames - 1 - last >= span)
        if center is not None:
            d = self._mean[slots].astype(np.float64) - np.asarray(
                center, dtype=np.float64
            ).reshape(3)
            out &= np.sum(d * d, axis=1) <= float(radius) ** 2
        return out

    def evict_transients(self, span: int, center=None, radius: float = np.inf) -> int:
        """Evict the voxels :meth:`transients` names (the trails of movers, module docstring); rebuild the table.

        Returns the number of voxels evicted. Costs O(capacity)."""
        occupied = self._keys != EMPTY_KEY
        keep = occupied.copy()
        keep[occupied] = ~self._transient(occupied, int(span), center, radius)
        return self._keep_only(keep)

    def _keep_only(self, keep) -> int:
        """Rebuild the table with the slots ``keep`` (capacity,) bool; return how many occupied ones went."""
        evicted = int(np.count_nonzero(self._keys != EMPTY_KEY) - np.count_nonzero(keep))
        if evicted == 0:
            return 0
        new = tuple(
            np.full_like(a, EMPTY_KEY) if a is self._keys else np.zeros_like(a)
            for a in self._buffers()
        )
        max_probe = _reinsert_nb(
            self._keys, keep, *self._buffers()[1:], *new, self.log2_capacity
        )
        (
            self._keys,
            self._count,
            self._s1,
            self._s2,
            self._mean,
            self._icov,
            self._first,
            self._last,
        ) = new
        self._state[0] = int(np.count_nonzero(keep))
        self._state[1] = max_probe
        self._changed()
        return evicted

    def __repr__(self) -> str:
        return (
            f"VoxelHashMap(voxel_size={self.voxel_size}, capacity={self.capacity}, voxels={len(self)}, "
            f"dropped={self.n_dropped})"
        )
