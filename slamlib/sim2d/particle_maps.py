"""One map per particle in 2D, in shared tiles copied on write (Rao-Blackwellised particle SLAM).

FastSLAM (Montemerlo et al. 2002) and GMapping (Grisetti et al. 2007) factor the SLAM posterior as
``p(x_{1:k}, m | z, u) = p(x_{1:k} | z, u) p(m | x_{1:k}, z)``: the particles sample trajectories, and given a
trajectory the map follows in closed form, so **each particle carries the map its own trajectory built**
(Rao-Blackwellisation). A particle scores a scan against its own map (step 8) and merges the scan into it at
its own pose (step 10); resampling (step 11) copies maps along with their particles. When the vehicle returns
to a place it mapped long ago, a particle whose trajectory drifted holds a map that disagrees with itself
there (the old walls where they were, the new ones where the drift put them) and loses weight: the loop
closes by selection, with no loop detector.

Stored naively that is ``P`` whole grids, copied at every resampling. Here a map is a table of **tiles**
(``T x T`` cells, default 16 x 16) in one shared pool: resampling copies only the tables (an int per tile)
and bumps reference counts; step 10 copies a tile only when a particle writes to one it shares (copy on
write, as DP-SLAM's ancestry trees and GMapping's reference-counted maps do). Tiles nobody references are
recycled. Memory is therefore ``live tiles x tile size`` plus the tables, and grows with what the particles
changed since their ancestry split, not with ``P x map size`` (:meth:`ParticleMaps2D.memory_bytes` against
:meth:`ParticleMaps2D.full_copy_bytes`).

Each particle's map scores and merges exactly as an :class:`~slamlib.sim2d.steps.OccupancyGrid2D` of the same
settings would (the same :func:`~slamlib.sim2d.steps.field_bumps` and
:func:`~slamlib.sim2d.steps.bilinear_taps`); :meth:`ParticleMaps2D.grid` gives one as a dense grid.

References: Montemerlo, Thrun, Koller & Wegbreit, *FastSLAM* (AAAI 2002); Eliazar & Parr, *DP-SLAM* (IJCAI
2003); Grisetti, Stachniss & Burgard, *Improved techniques for grid mapping with Rao-Blackwellized particle
filters* (IEEE T-RO 2007).
"""

from __future__ import annotations

import numpy as np

from slamlib.sim2d.steps import (
    MAP_KINDS,
    OccupancyGrid2D,
    _bumps,
    bilinear_taps,
    grid_cells,
)

__all__ = ["DEFAULT_TILE", "EMPTY_TILE", "ParticleMaps2D"]

#: Tile side (cells) when none is given: 16 x 16 cells, 0.8 m at 5 cm, about a scan's footprint on a wall.
DEFAULT_TILE = 16
#: A table entry for a tile the particle never wrote: all counts and field values 0, stored nowhere.
EMPTY_TILE = -1
#: Bytes per tile entry in a particle's table (int32 tile ids).
_TABLE_ITEM = np.dtype(np.int32).itemsize


class ParticleMaps2D:
    """``P`` occupancy grids of one shape and settings, one per particle, in copy-on-write tiles.

    Particle ``i``'s map is ``tables[i] (TH, TW)``: tile ids into the pool ``counts_pool (capacity, T, T)``
    int32 and ``field_pool (capacity, T, T)`` float64, or :data:`EMPTY_TILE`. Grid cell ``(r, c)`` is cell
    ``(r mod T, c mod T)`` of tile ``(r // T, c // T)``. ``refcount[j]`` is how many table entries hold tile
    ``j``; a tile with more than one holder is never written (step 10 copies it first). ``ancestors (P,)``: the
    particle each descends from, counted from the last :meth:`tag` (or the start).

    Parameters
    ----------
    template : OccupancyGrid2D
        Gives the grid (origin, resolution, shape) and the scoring settings (kind, sigma, n_sat, eps); its
        counts are every particle's starting map (usually empty).
    n_particles : int, P.
    tile : int, tile side ``T`` in cells.
    """

    def __init__(
        self, template: OccupancyGrid2D, n_particles: int, tile: int = DEFAULT_TILE
    ):
        if n_particles < 1 or tile < 1:
            raise ValueError(
                f"need n_particles >= 1 and tile >= 1, got {n_particles}, {tile}"
            )
        if template.kind not in MAP_KINDS:
            raise ValueError(f"kind must be one of {MAP_KINDS}, got {template.kind!r}")
        self.origin = template.origin.copy()
        self.resolution = template.resolution
        self.shape = template.counts.shape
        self.kind, self.sigma = template.kind, template.sigma
        self.n_sat, self.eps = template.n_sat, template.eps
        self.tile = int(tile)
        h, w = self.shape
        self.tiles_shape = (-(-h // self.tile), -(-w // self.tile))
        self.counts_pool = np.zeros((0, self.tile, self.tile), np.int32)
        self.field_pool = np.zeros((0, self.tile, self.tile), np.float64)
        self.refcount = np.zeros(0, np.int64)
        self._free = np.zeros(0, np.int64)
        # the template's non-empty tiles, shared by every particle from the start
        table = np.full(self.tiles_shape, EMPTY_TILE, np.int32)
        counts = self._blocks(self._padded(template.counts))
        fld = self._blocks(self._padded(template.field))
        for tr, tc in np.argwhere(counts.any(axis=(2, 3))):
            (j,) = self._allocate(1)
            self.counts_pool[j] = counts[tr, tc]
            self.field_pool[j] = fld[tr, tc]
            table[tr, tc] = j
        self.tables = np.repeat(table[None], int(n_particles), axis=0)
        self.totals = np.full(int(n_particles), template.total, np.int64)
        self.ancestors = np.arange(int(n_particles))
        self._recount()

    def tag(self) -> None:
        """Name the current particles ``0 .. P-1`` as ancestors: after later resamplings, ``ancestors[k]`` is the
        particle, at the time of the tag, that particle ``k`` (and its map) descends from."""
        self.ancestors = np.arange(self.n_particles)

    def copy(self) -> ParticleMaps2D:
        """An independent copy (the pool, tables and counts copied): a snapshot the filter will not change."""
        out = object.__new__(ParticleMaps2D)
        out.__dict__.update(
            {
                k: v.copy() if isinstance(v, np.ndarray) else v
                for k, v in self.__dict__.items()
            }
        )
        return out

    # ------------------------------------------------------------------------------------------- bookkeeping
    def _padded(self, a):
        th, tw = self.tiles_shape
        out = np.zeros((th * self.tile, tw * self.tile), a.dtype)
        out[: a.shape[0], : a.shape[1]] = a
        return out

    def _blocks(self, a):
        """``(TH, TW, T, T)`` view of a padded ``(TH T, TW T)`` array."""
        th, tw = self.tiles_shape
        return a.reshape(th, self.tile, tw, self.tile).swapaxes(1, 2)

    def _allocate(self, n: int) -> np.ndarray:
        """``n`` unused tile ids (the pool doubles when it runs out); their contents are the caller's to set."""
        if n > len(self._free):
            old = len(self.refcount)
            new = max(2 * old, old + n - len(self._free), 64)
            grow = new - old
            self.counts_pool = np.concatenate(
                [self.counts_pool, np.zeros((grow, self.tile, self.tile), np.int32)]
            )
            self.field_pool = np.concatenate(
                [self.field_pool, np.zeros((grow, self.tile, self.tile), np.float64)]
            )
            self.refcount = np.concatenate([self.refcount, np.zeros(grow, np.int64)])
            self._free = np.concatenate([np.arange(new - 1, old - 1, -1), self._free])
        ids, self._free = (
            self._free[len(self._free) - n :],
            self._free[: len(self._free) - n],
        )
        self.refcount[ids] = 1
        return ids

    def _recount(self) -> None:
        """Reference counts from the tables; tiles nobody holds go back to the free list."""
        held = self.tables[self.tables != EMPTY_TILE]
        self.refcount = np.bincount(held, minlength=len(self.refcount)).astype(np.int64)
        self._free = np.flatnonzero(self.refcount == 0)[::-1].copy()

    @property
    def n_particles(self) -> int:
        """P."""
        return len(self.tables)

    @property
    def total(self) -> int:
        """The most returns any particle's map holds (0: every map empty, step 8 scores all zeros)."""
        return int(self.totals.max())

    @property
    def live_tiles(self) -> int:
        """Tiles held by at least one particle."""
        return int(np.count_nonzero(self.refcount))

    def memory_bytes(self) -> int:
        """Bytes the maps need: live tiles (counts + field) plus every particle's table."""
        per_tile = self.tile**2 * (self.counts_pool.itemsize + self.field_pool.itemsize)
        return self.live_tiles * per_tile + self.tables.size * _TABLE_ITEM

    def full_copy_bytes(self) -> int:
        """Bytes ``P`` whole grids of the same cells and types would need (what copying maps would cost)."""
        h, w = self.shape
        return (
            self.n_particles
            * h
            * w
            * (self.counts_pool.itemsize + self.field_pool.itemsize)
        )

    def disputed_tiles(self) -> int:
        """Tile positions where the particles do not all hold the same tile: how much of the map is still a
        matter of hypothesis (the rest, every particle inherited from a common ancestor)."""
        flat = self.tables.reshape(self.n_particles, -1)
        return int(np.count_nonzero((flat != flat[:1]).any(axis=0)))

    def distinct_maps(self) -> int:
        """How many different maps the particles hold (particles sharing every tile count once)."""
        return len({row.tobytes() for row in self.tables.reshape(self.n_particles, -1)})

    # ------------------------------------------------------------------------------------------------ lookup
    def _lookup(self, particle, rows, cols):
        """Tile ids and in-tile cells of grid cells ``(rows, cols)`` in the maps of ``particle`` (broadcast)."""
        ids = self.tables[particle, rows // self.tile, cols // self.tile]
        return ids, rows % self.tile, cols % self.tile

    def _read(self, pool, particle, rows, cols):
        ids, ir, ic = self._lookup(particle, rows, cols)
        return np.where(ids != EMPTY_TILE, pool[np.maximum(ids, 0), ir, ic], 0)

    def _particle_axis(self, world_points):
        p = np.asarray(world_points, dtype=np.float64)
        if p.ndim != 3 or p.shape[0] != self.n_particles or p.shape[2] != 2:
            raise ValueError(
                f"world points must be (P={self.n_particles}, N, 2), one scan per particle, got {p.shape}"
            )
        return p, np.arange(self.n_particles)[:, None]

    def point_terms(self, world_points) -> np.ndarray:
        """Per-point terms ``l(p_ij)`` of particle ``i``'s points ``(P, N, 2)`` under particle ``i``'s own map.

        The same rule as :meth:`OccupancyGrid2D.point_terms`: ``min(n_c, n_sat) / n_sat`` for ``"density"``,
        ``log(F + eps)`` with ``F`` bilinear between cell centres for ``"likelihood"``. Returns ``(P, N)``.
        """
        p, who = self._particle_axis(world_points)
        if self.kind == "density":
            r, c, inside = grid_cells(self.origin, self.resolution, self.shape, p)
            n = self._read(self.counts_pool, who, r, c)
            return np.where(inside, np.minimum(n, self.n_sat) / self.n_sat, 0.0)
        f = np.zeros(p.shape[:-1])
        for r, c, wt in bilinear_taps(self.origin, self.resolution, self.shape, p):
            f += wt * self._read(self.field_pool, who, r, c)
        return np.log(f + self.eps)

    # ------------------------------------------------------------------------------------------------ writes
    def _make_writable(self, particle, tile_flat) -> None:
        """Give each ``(particle, tile)`` pair (unique) a tile of its own: empty ones get a zero tile, shared
        ones a copy, except that when every holder of a shared tile writes to it, one of them keeps it."""
        flat_tables = self.tables.reshape(self.n_particles, -1)
        ids = flat_tables[particle, tile_flat].astype(np.int64)
        fresh = ids == EMPTY_TILE
        held = np.flatnonzero(~fresh)
        copy = np.zeros(len(ids), bool)
        if len(held):
            uniq, first, inv, writers = np.unique(
                ids[held], return_index=True, return_inverse=True, return_counts=True
            )
            shared = self.refcount[uniq] > 1
            copy[held] = shared[inv]
            # all holders write: the first keeps the tile
            keeper = held[first[shared & (writers == self.refcount[uniq])]]
            copy[keeper] = False
        need = np.flatnonzero(fresh | copy)
        if not len(need):
            return
        new = self._allocate(len(need))
        src = ids[need]
        was_copy = src != EMPTY_TILE
        self.counts_pool[new] = 0
        self.field_pool[new] = 0.0
        self.counts_pool[new[was_copy]] = self.counts_pool[src[was_copy]]
        self.field_pool[new[was_copy]] = self.field_pool[src[was_copy]]
        np.subtract.at(self.refcount, src[was_copy], 1)
        flat_tables[particle[need], tile_flat[need]] = new

    def merge(self, world_points) -> ParticleMaps2D:
        """Particle ``i``'s scan ``world_points[i]`` (``(P, N, 2)``) into particle ``i``'s map; in place.

        As :meth:`OccupancyGrid2D.merge` per particle: one count per point in its cell, then the field raised
        by each point's bump with height ``min(1, n_c / n_sat)``. Points outside the grid are dropped. Only the
        tiles a particle writes are copied, and only when it shares them.
        """
        p, who = self._particle_axis(world_points)
        flat = p.reshape(-1, 2)
        owner = np.broadcast_to(who, p.shape[:2]).reshape(-1)
        rows, cols, vals, ok = _bumps(
            self.origin, self.resolution, self.sigma, self.shape, flat, 1.0
        )
        r0, c0, inside = grid_cells(self.origin, self.resolution, self.shape, flat)
        # every bump cell (the point's own cell among them) needs a writable tile
        bump_owner = np.broadcast_to(owner[:, None], rows.shape)[ok]
        br, bc = rows[ok], cols[ok]
        n_tiles = self.tiles_shape[0] * self.tiles_shape[1]
        touched = np.zeros(self.n_particles * n_tiles, bool)
        touched[
            bump_owner * n_tiles
            + (br // self.tile) * self.tiles_shape[1]
            + bc // self.tile
        ] = True
        self._make_writable(*np.divmod(np.flatnonzero(touched), n_tiles))
        # counts, then each point's height from its cell's count after merging
        ids, ir, ic = self._lookup(owner[inside], r0[inside], c0[inside])
        np.add.at(self.counts_pool, (ids, ir, ic), 1)
        np.add.at(self.totals, owner[inside], 1)
        heights = np.zeros(len(flat))
        heights[inside] = (
            np.minimum(self.counts_pool[ids, ir, ic], self.n_sat) / self.n_sat
        )
        heights = np.broadcast_to(heights[:, None], rows.shape)[ok]
        ids, ir, ic = self._lookup(bump_owner, br, bc)
        np.maximum.at(self.field_pool, (ids, ir, ic), vals[ok] * heights)
        return self

    def select(self, indexes) -> ParticleMaps2D:
        """Resampling: particle ``k`` takes the map of particle ``indexes[k]`` (tables copied, tiles shared);
        tiles no particle holds any more are recycled. In place."""
        idx = np.asarray(indexes, dtype=np.int64)
        if idx.shape != (self.n_particles,):
            raise ValueError(f"indexes must be ({self.n_particles},), got {idx.shape}")
        self.tables = self.tables[idx]
        self.totals = self.totals[idx]
        self.ancestors = self.ancestors[idx]
        self._recount()
        return self

    def grid(self, particle: int) -> OccupancyGrid2D:
        """Particle ``particle``'s map as a dense :class:`OccupancyGrid2D` (a copy, for plots and checks)."""
        th, tw = self.tiles_shape
        counts = np.zeros((th * self.tile, tw * self.tile), np.int64)
        fld = np.zeros(counts.shape)
        cb, fb = self._blocks(counts), self._blocks(fld)
        for tr, tc in np.argwhere(self.tables[particle] != EMPTY_TILE):
            j = self.tables[particle, tr, tc]
            cb[tr, tc] = self.counts_pool[j]
            fb[tr, tc] = self.field_pool[j]
        h, w = self.shape
        return OccupancyGrid2D(
            origin=self.origin.copy(),
            resolution=self.resolution,
            counts=counts[:h, :w].copy(),
            kind=self.kind,
            sigma=self.sigma,
            n_sat=self.n_sat,
            eps=self.eps,
            field=fld[:h, :w].copy(),
        )
