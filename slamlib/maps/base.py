"""The map interface shared by every 3D map structure, and the flat lookup tuples the kernels read.

A map lives in the **world frame** (metres; the IMU pose at the first frame, see CONTRIBUTING.md). The
3D pipeline uses it in two of the twelve steps:

* step 8 (``score_particles``): ``backend.score_particles(R, t, points_body, map.lookup())`` transforms each
  scan point by each particle's pose ``T_world_body = [R_i, t_i]`` and looks it up in the map, summing a
  robust per-point log-likelihood per particle (never materialising the ``P x N`` transformed points);
* step 10 (``merge_scan``): ``map.merge(points_world)`` adds the best particle's transformed scan.

``lookup()`` returns a :class:`typing.NamedTuple` of numpy arrays and scalars only (no Python objects), so
that Numba CPU kernels and CUDA kernels can implement the same lookup from the fields documented on
:class:`VoxelHashLookup` and :class:`MortonLookup`. Each tuple starts with an integer ``kind`` field
(:data:`KIND_VOXEL_HASH`, :data:`KIND_MORTON`) so a backend can dispatch on it. The arrays are the map's own
buffers (no copy): call ``lookup()`` again after every ``merge`` (scalars such as ``max_probe`` or the number of
points change, and the Morton arrays are replaced). Its last field, ``version``, is the map's
:attr:`Map3D.version` stamp of that content: a backend that keeps copies of the arrays elsewhere (the CUDA
backend keeps them on the device between frames) re-uses them while the stamp is unchanged.

Per-point score terms (both maps) are truncated ("robust") negative squared distances, so points that hit
structure that is not in the map yet (or outliers) cost a bounded constant instead of dominating:

* voxel hash (NDT, Biber & Strasser 2003; Magnusson 2009): for voxel ``v``, ``d = p - mu_v``,
  ``m = d^T Sigma_v^-1 d`` with ``Sigma_v`` the voxel's point covariance plus ``min_sigma^2 I``;
  ``T_v(p) = -0.5 min(m, m_max)``, and ``-0.5 m_max`` where the voxel is empty; the point's term is the
  trilinear interpolation of ``T_v(p)`` over the 8 voxels whose centres surround ``p``.
* Morton BVH (likelihood field from nearest neighbours, Thrun et al., *Probabilistic Robotics* 6.4):
  ``d`` = distance to the nearest stored map point within ``radius``; term ``= -0.5 min(d, radius)^2 / sigma^2``.

Both are continuous in the pose wherever the structure is continuous (plane fits / exact LIDAR points, not
cell centres), which is what lets the filter tell apart particles a few centimetres and a fraction of a degree
apart (the seed project's 2D density grid lost that precision). The score of a particle is the **sum** over
the ``N`` points (a log-likelihood up to a constant); differences between particles scale with ``N``, so a
pipeline may temper it (divide by a temperature) before exponentiating.
"""

from __future__ import annotations

import itertools
from abc import ABC, abstractmethod
from typing import NamedTuple

import numpy as np

#: ``lookup.kind`` of :class:`VoxelHashLookup`.
KIND_VOXEL_HASH = 1
#: ``lookup.kind`` of :class:`MortonLookup`.
KIND_MORTON = 2

#: Empty slot marker in :attr:`VoxelHashLookup.keys`.
EMPTY_KEY = -1
#: Bits per axis in packed voxel keys and Morton codes; indices are offset by ``2**20`` so they are >= 0.
BITS_PER_AXIS = 21
#: Offset added to signed integer indices before packing (valid signed range ``[-2**20, 2**20)``).
AXIS_OFFSET = 1 << 20
#: Fibonacci multiplicative hash constant ``2**64 / golden ratio`` (Knuth, TAOCP vol. 3, 6.4).
HASH_MULTIPLIER = 0x9E3779B97F4A7C15


class VoxelHashLookup(NamedTuple):
    """Flat lookup structure of :class:`slamlib.maps.VoxelHashMap` (open addressing, linear probing).

    Finding the slot of voxel index ``i = (ix, iy, iz)`` (int64 per axis, valid in ``[-2**20, 2**20)``)::

        key = (ix + 2**20) | (iy + 2**20) << 21 | (iz + 2**20) << 42      # packed int64, >= 0
        h = ((uint64(key) * 0x9E3779B97F4A7C15) mod 2**64) >> (64 - log2_capacity)
        for j in 0 .. max_probe:                           # inclusive
            s = (h + j) & (capacity - 1)
            if keys[s] == key: found slot s
            if keys[s] == -1: not found (stop)
        not found after max_probe + 1 probes; an index outside [-2**20, 2**20) on any axis is not found

    Voxel ``i`` holds the points with ``floor(p / voxel_size) = i``; its centre is ``(i + 0.5) voxel_size``.
    Its term at world point ``p`` (float64): found -> ``d = p - mean[s]``, ``m = d^T A d`` with ``A`` the
    symmetric matrix ``[[a0, a1, a2], [a1, a3, a4], [a2, a4, a5]]`` from ``icov[s] = (a0..a5)``, term
    ``T_i(p) = -0.5 * min(m, m_max)``; not found -> ``T_i(p) = -0.5 * m_max``.

    The per-point score **interpolates trilinearly** between the 8 voxels whose centres surround ``p``, so
    that it is continuous in ``p`` (a single-voxel NDT jumps when points cross voxel faces, which made the
    score landscape jagged at the 1-2 cm scale)::

        g = p * inv_voxel_size - 0.5;  b = floor(g);  f = g - b          # per axis, f in [0, 1)
        term(p) = sum over (dx, dy, dz) in {0,1}^3 of
                  wx * wy * wz * T_(b + (dx, dy, dz))(p),   wx = f_x if dx else 1 - f_x  (same for y, z)

    Fields
    ------
    kind : int
        :data:`KIND_VOXEL_HASH` (= 1).
    keys : (C,) int64
        Packed voxel key per slot, :data:`EMPTY_KEY` (-1) for empty slots. ``C = capacity`` (a power of 2).
    mean : (C, 3) float32
        Mean of the points merged into the voxel, world frame, metres (garbage in empty slots).
    icov : (C, 6) float32
        Upper triangle ``(xx, xy, xz, yy, yz, zz)`` of ``(Sigma + min_sigma^2 I)^-1`` in 1/m^2, ``Sigma`` the
        (biased, 1/n) covariance of the voxel's points.
    voxel_size : float
        Voxel edge in metres.
    inv_voxel_size : float
        ``1 / voxel_size`` (multiply, then floor, to get voxel indices).
    log2_capacity : int
        ``C = 2**log2_capacity``.
    max_probe : int
        The longest probe distance any stored key needed; lookups give up after ``max_probe + 1`` slots.
    m_max : float
        Truncation of the squared Mahalanobis distance (robust term; also the cost of a miss).
    version : int
        :attr:`Map3D.version` of the map when the tuple was made: equal stamps mean equal array contents, so the
        CUDA backend re-uses its device copy while it is unchanged. 0 (the default, e.g. for a hand-made tuple)
        means unknown: nothing is cached.
    """

    kind: int
    keys: np.ndarray
    mean: np.ndarray
    icov: np.ndarray
    voxel_size: float
    inv_voxel_size: float
    log2_capacity: int
    max_probe: int
    m_max: float
    version: int = 0


class MortonLookup(NamedTuple):
    """Flat lookup structure of :class:`slamlib.maps.MortonBVHMap` (sorted Morton codes, implicit octree).

    Points are quantised to integer coordinates ``u = floor(p / quantum) + 2**20`` (21 bits per axis) and
    sorted by their 63-bit Morton code ``morton(u) = sum_b x_b 2^(3b) + y_b 2^(3b+1) + z_b 2^(3b+2)``.
    A Morton code shifted right by ``3 L`` is the Morton code of the octree cell of edge ``quantum * 2**L``
    that holds the point, so every cell at level ``L = cell_level`` is one contiguous run of the sorted array
    (the implicit tree of a linear BVH, Karras 2012 / Lauterbach et al. 2009). ``cell_codes`` lists the
    non-empty cells, ``cell_start`` where their runs start.

    Nearest-neighbour query for world point ``q`` (float64 arithmetic)::

        s = 2**cell_level                                   # cell edge in quanta; radius <= quantum * s / 2
        c0 = floor((q / quantum + 2**20) / s - 0.5)         # per axis: the 2x2x2 block of cells nearest q
        best = radius**2
        for each (dx, dy, dz) in {0,1}^3:
            c = c0 + (dx, dy, dz);  skip if any component outside [0, 2**(21 - cell_level))
            k = binary search of morton(c) in cell_codes;  skip if absent
            skip if the squared distance from q to the box [cell_lo[k], cell_hi[k]] >= best   (optional pruning)
            for j in cell_start[k] .. cell_start[k+1]-1:  best = min(best, |q - points[j]|^2)
        term = -0.5 * best / sigma**2

    Because ``radius <= quantum * s / 2``, the ball of radius ``radius`` around ``q`` lies inside those 8 cells,
    so ``best`` is exactly ``min(d_nn, radius)^2``. Any exact search gives the same result: the CPU kernel
    also starts ``best`` from the previous particle's neighbour and descends into sub-cells of large runs.

    Fields
    ------
    kind : int
        :data:`KIND_MORTON` (= 2).
    codes : (M,) int64
        Sorted Morton codes of the stored points (for insertion, and for descending inside a cell's run: the
        sub-cells of any level are contiguous sub-runs, found by binary search on ``codes >> 3 level``).
    points : (M, 3) float32
        The stored points in the same order, world frame, metres (exact positions, not quantised).
    cell_codes : (K,) int64
        Sorted distinct ``codes >> (3 * cell_level)``.
    cell_start : (K + 1,) int64
        Points of cell ``cell_codes[k]`` are ``points[cell_start[k]:cell_start[k+1]]``; ``cell_start[K] = M``.
    cell_lo, cell_hi : (K, 3) float32
        Tight axis-aligned bounding box of each cell's points (world, metres): the leaves' boxes of the BVH.
        On a wall or the ground they are thin, so they prune most cells a query must otherwise scan.
    quantum : float
        Quantisation step in metres.
    cell_level : int
        Octree level ``L`` of the cells searched; cell edge ``quantum * 2**L`` metres.
    radius : float
        Search radius and truncation distance in metres.
    sigma : float
        Standard deviation of the Gaussian point likelihood, metres.
    version : int
        The map's content stamp (:attr:`Map3D.version`), as in :class:`VoxelHashLookup`.
    """

    kind: int
    codes: np.ndarray
    points: np.ndarray
    cell_codes: np.ndarray
    cell_start: np.ndarray
    cell_lo: np.ndarray
    cell_hi: np.ndarray
    quantum: float
    cell_level: int
    radius: float
    sigma: float
    version: int = 0


# Source of Map3D.version stamps: one counter for the whole process, so a stamp names one content of one map.
_VERSIONS = itertools.count(1)


class Map3D(ABC):
    """A point map in the world frame with a flat lookup structure for scoring (steps 8 and 10).

    Implementations call :meth:`_changed` in ``__init__`` and after every change of the arrays behind
    :meth:`lookup` (``merge``, ``prune``), and pass :attr:`version` as the lookup's ``version`` field.
    """

    _version = 0

    @property
    def version(self) -> int:
        """Stamp of the map's current content: unique in the process, drawn anew by every change (``merge``,
        ``prune``); 0 for a map that does not keep stamps. Equal stamps mean equal lookup arrays, so copies of
        them (the CUDA backend's device arrays) can be re-used while it is unchanged."""
        return self._version

    def _changed(self) -> None:
        """Draw a new :attr:`version` (the arrays behind :meth:`lookup` changed)."""
        self._version = next(_VERSIONS)

    @property
    @abstractmethod
    def resolution(self) -> float:
        """Metres: the scale below which two poses score against the same map elements (a voxel's edge, a
        lookup radius); optima of the score closer than this are one structure, seen from about the same pose."""

    @abstractmethod
    def merge(self, points_world: np.ndarray) -> None:
        """Add ``points_world`` (N, 3) float32, world frame, metres, to the map (step 10)."""

    @abstractmethod
    def lookup(self) -> NamedTuple:
        """The flat lookup structure (numpy arrays + scalars) for ``backend.score_particles`` (step 8)."""

    @abstractmethod
    def points(self) -> np.ndarray:
        """Representative map points (M, 3) float32, world frame, for plotting and PLY export."""

    @abstractmethod
    def __len__(self) -> int:
        """Number of map elements (occupied voxels or stored points)."""

    @abstractmethod
    def memory_bytes(self) -> int:
        """Bytes held by the map's numpy buffers."""

    @abstractmethod
    def prune(self, center, radius: float) -> int:
        """Drop the elements farther than ``radius`` metres from ``center`` (3,); return how many were dropped.

        Keeps memory bounded on long drives (call it with the vehicle position)."""


def as_points(points, name: str = "points") -> np.ndarray:
    """Validate and convert to a C-contiguous (N, 3) float32 array; raise ``ValueError`` on bad shapes."""
    arr = np.asarray(points)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {arr.shape}")
    return np.ascontiguousarray(arr, dtype=np.float32)
