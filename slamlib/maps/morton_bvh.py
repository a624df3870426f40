"""A point map sorted by 3D Morton code: an implicit linear BVH queried for nearest neighbours from Numba.

Points are quantised to ``quantum``-metre integer coordinates (21 bits per axis, offset by ``2**20``, so the map
spans +-``2**20 * quantum`` metres, +-10.5 km at 1 cm) and kept sorted by their Morton (Z-order) code. Sorted
Morton codes are the leaves of a linear BVH (Lauterbach et al., *Fast BVH construction on GPUs*, 2009; Karras,
*Maximizing parallelism in the construction of BVHs, octrees and k-d trees*, HPG 2012): every octree cell is a
contiguous run of the array, found by binary search, so no pointer tree has to be built, updated or traversed.
The map keeps the runs of the cells at level ``cell_level`` (edge ``quantum * 2**cell_level >= 2 radius``) and
the tight bounding box of each cell's points (the BVH's leaf boxes); a nearest-neighbour query within ``radius``
visits the 2x2x2 block of cells nearest the query point, skipping cells whose box is too far (exact, see
:class:`~slamlib.maps.base.MortonLookup`). The stored points are the exact LIDAR points, not cell centres.

Memory is bounded by voxel de-duplication: of the points falling in one de-duplication voxel (edge
``quantum * 2**dedup_level``, default 8 cm) only the first one merged is kept; and by ``max_points``: when the map
is full, new points are dropped (counted in :attr:`MortonBVHMap.n_dropped`); :meth:`MortonBVHMap.prune` evicts
far points. The score is ``-0.5 min(d_nn, radius)^2 / sigma^2`` per point (likelihood field, Thrun et al.,
*Probabilistic Robotics*, sec. 6.4).
"""

from __future__ import annotations

import numpy as np

from slamlib.maps.base import KIND_MORTON, Map3D, MortonLookup, as_points
from slamlib.maps.codes import axis_indices, morton_codes


class MortonBVHMap(Map3D):
    """Point map as sorted Morton codes with nearest-neighbour lookup.

    The cell level is the smallest ``L`` with ``quantum * 2**L >= 2 * radius``.

    Parameters
    ----------
    radius : float
        Nearest-neighbour search radius and truncation distance, metres (default 0.3).
    sigma : float
        Standard deviation of the point likelihood, metres (default 0.1).
    quantum : float
        Quantisation step of the codes, metres (default 0.01).
    dedup_level : int
        Keep one point per voxel of edge ``quantum * 2**dedup_level`` (default 3: 8 cm); 0 keeps one per quantum.
    max_points : int
        Maximum number of stored points (default 4,000,000); new points beyond it are dropped.
    """

    def __init__(
        self,
        radius: float = 0.3,
        sigma: float = 0.1,
        quantum: float = 0.01,
        dedup_level: int = 3,
        max_points: int = 4_000_000,
    ):
        if not (
            radius > 0
            and sigma > 0
            and quantum > 0
            and max_points > 0
            and 0 <= dedup_level <= 20
        ):
            raise ValueError(
                "radius, sigma, quantum, max_points must be > 0 and 0 <= dedup_level <= 20"
            )
        self.radius = float(radius)
        self.sigma = float(sigma)
        self.quantum = float(quantum)
        self.dedup_level = int(dedup_level)
        self.max_points = int(max_points)
        self.cell_level = int(np.ceil(np.log2(2.0 * self.radius / self.quantum)))
        self.cell_level = max(self.cell_level, 0)
        if self.cell_level > 20:
            raise ValueError(
                "radius too large for quantum: cells would exceed the 21-bit range"
            )
        self._codes = np.zeros(0, np.int64)
        self._points = np.zeros((0, 3), np.float32)
        self._cell_codes = np.zeros(0, np.int64)
        self._cell_start = np.zeros(1, np.int64)
        self._cell_lo = np.zeros((0, 3), np.float32)
        self._cell_hi = np.zeros((0, 3), np.float32)
        self.n_dropped = 0
        self._changed()

    def _rebuild_cells(self) -> None:
        cells = self._codes >> (3 * self.cell_level)
        if cells.size == 0:
            self._cell_codes = np.zeros(0, np.int64)
            self._cell_start = np.zeros(1, np.int64)
            self._cell_lo = np.zeros((0, 3), np.float32)
            self._cell_hi = np.zeros((0, 3), np.float32)
            return
        first = np.flatnonzero(np.r_[True, cells[1:] != cells[:-1]])
        self._cell_codes = cells[first]
        self._cell_start = np.r_[first, cells.size].astype(np.int64)
        self._cell_lo = np.minimum.reduceat(self._points, first, axis=0)
        self._cell_hi = np.maximum.reduceat(self._points, first, axis=0)

    def merge(self, points_world) -> None:
        """Insert world points (N, 3): quantise, sort, de-duplicate against themselves and the map, merge runs.

        Costs O(N log N + M) (a sorted merge of the new run into the stored arrays)."""
        pts = as_points(points_world, "points_world")
        u, ok = axis_indices(pts, 1.0 / self.quantum)
        self.n_dropped += int((~ok).sum())
        pts, u = pts[ok], u[ok]
        codes = morton_codes(u)
        shift = 3 * self.dedup_level
        # stable sort by de-duplication voxel: the first point merged into a voxel is the one kept; with one
        # point per voxel left, this order is also the order of the full codes
        order = np.argsort(codes >> shift, kind="stable")
        codes, pts = codes[order], pts[order]
        dedup = codes >> shift
        first = np.r_[True, dedup[1:] != dedup[:-1]] if dedup.size else np.zeros(0, bool)
        codes, pts, dedup = codes[first], pts[first], dedup[first]
        if self._codes.size:
            old = self._codes >> shift
            pos = np.searchsorted(old, dedup)
            hit = (pos < old.size) & (old[np.minimum(pos, old.size - 1)] == dedup)
            codes, pts = codes[~hit], pts[~hit]
        room = self.max_points - self._codes.size
        if codes.size > room:
            self.n_dropped += int(codes.size - room)
            # keeps the lowest codes; documented as "dropped"
            codes, pts = codes[:room], pts[:room]
        if codes.size == 0:
            return
        ins = np.searchsorted(self._codes, codes) + np.arange(codes.size)
        total = self._codes.size + codes.size
        is_new = np.zeros(total, bool)
        is_new[ins] = True
        new_codes = np.empty(total, np.int64)
        new_points = np.empty((total, 3), np.float32)
        new_codes[ins], new_points[ins] = codes, pts
        new_codes[~is_new], new_points[~is_new] = self._codes, self._points
        self._codes, self._points = new_codes, new_points
        self._rebuild_cells()
        self._changed()

    def lookup(self) -> MortonLookup:
        """The flat lookup tuple (the map's arrays, replaced by each merge: call again after merging)."""
        return MortonLookup(
            KIND_MORTON,
            self._codes,
            self._points,
            self._cell_codes,
            self._cell_start,
            self._cell_lo,
            self._cell_hi,
            self.quantum,
            self.cell_level,
            self.radius,
            self.sigma,
            self.version,
        )

    def points(self) -> np.ndarray:
        """The stored points (M, 3) float32 in Morton order, world frame."""
        return self._points.copy()

    @property
    def resolution(self) -> float:
        """The lookup radius, metres (:meth:`Map3D.resolution`)."""
        return self.radius

    def __len__(self) -> int:
        return int(self._codes.size)

    def memory_bytes(self) -> int:
        return int(
            sum(
                a.nbytes
                for a in (
                    self._codes,
                    self._points,
                    self._cell_codes,
                    self._cell_start,
                    self._cell_lo,
                    self._cell_hi,
                )
            )
        )

    def prune(self, center, radius: float) -> int:
        """Drop the points farther than ``radius`` metres from ``center`` (3,); return how many were dropped."""
        c = np.asarray(center, dtype=np.float64).reshape(3)
        keep = (
            np.sum((self._points.astype(np.float64) - c) ** 2, axis=1)
            <= float(radius) ** 2
        )
        dropped = int((~keep).sum())
        if dropped:
            self._codes, self._points = self._codes[keep], self._points[keep]
            self._rebuild_cells()
            self._changed()
        return dropped

    def __repr__(self) -> str:
        return (
            f"MortonBVHMap(radius={self.radius}, sigma={self.sigma}, quantum={self.quantum}, "
            f"points={len(self)}, dropped={self.n_dropped})"
        )
