"""The twelve steps of particle SLAM in the plane, one pure function per step.

A particle is a pose hypothesis ``(x, y, theta)`` (m, m, rad) of the vehicle body in the world frame (the pose
at the first frame); the set is a ``(P, 3)`` float64 array weighted by ``(P,)`` **log**-weights normalised to
``logsumexp = 0``. A pose maps body points ``q`` to the world: ``p = R(theta) q + (x, y)``. Names, leading
parameters and results follow :data:`slamlib.contract.STEPS`, shared with 1D and 3D; what 2D adds comes after
them and has a default.

====  =================================================================  ===============================================
step  function (the contract's parameters first)                         2D math
====  =================================================================  ===============================================
1     ``initialise_particles(n_particles, pose0=None)``                  ``(x, y, theta)_i = pose0`` (default 0)
2     ``read_scan(frame) -> points``                                     ``(N, 2)`` body-frame LIDAR points
3     ``read_imu(frame) -> imu``                                         ``(v, w)``: wheel speed, yaw rate
4     ``read_timing(frame) -> dt``                                       ``dt_k`` (s)
5     ``offset_by_motion(particles, imu, dt)``                           exact SE(2) arc (:func:`integrate_arc`)
6     ``perturb_with_noise(particles, sigma, rng)``                      body-frame ``sigma * n_i``, ``sigma (3,)``
7     ``transform_scan(particles, points)``                              ``p_ij = R(theta_i) q_j + t_i``
8     ``score_particles(particles, points, world_map)``                  ``s_i = sum_j l(p_ij)``, the map's term
9     ``pick_best_particle(particles, log_weights) -> (pose, index)``    ``i = argmax log w``
10    ``merge_scan(world_map, pose, points) -> world_map``               counts at the cells of ``R q + t``, in place
11    ``resample_particles(particles, log_weights, rng, ess_fraction)``  systematic, when the ESS drops (maps follow)
12    (the loop)                                                         :meth:`ParticleSLAM2D.step`
====  =================================================================  ===============================================

The map (:class:`OccupancyGrid2D`) counts scan returns per square cell; two ``kind``\\ s score a point differently:

* ``"density"``, the seed project's **2D density grid**: a point scores the (saturated) hit density of the cell
  it falls in, ``l(p) = min(n_c, n_sat) / n_sat`` in ``[0, 1]``; a particle's score ``s_i = sum_j l(p_ij)`` is
  read as a log-likelihood (a per-point likelihood ``exp(l)``). A point one cell off a wall scores 0, as much
  as a point in open space: the grid keeps no notion of "near".
* ``"likelihood"``, the **likelihood field** (Thrun, Burgard & Fox, *Probabilistic Robotics* 2005, sec. 6.4):
  ``F(p) = exp(-d(p)^2 / (2 sigma^2))`` with ``d`` the distance from ``p`` to the nearest merged return (each
  return's bump scaled to ``min(1, n_c / n_sat)``, the count of its cell when merged, so that a stray return
  merged once counts a third as much as a wall seen three times), read bilinearly between cell centres, and
  ``l(p) = log(F(p) + eps)`` (``eps`` the "random return" term ``z_rand / z_max``). Near misses still score well,
  so nearby particle poses are told apart by how near, not only
  by whether they hit.

References: Thrun et al. (2005) table 4.3 (particle filter), 5.4 (velocity motion model, exact arcs), 6.4
(likelihood field); Gothoskar & Tabrizi, CMU 15-418 project page (2017), the twelve steps and the density grid.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from slamlib.resampling import (
    DEFAULT_ESS_FRACTION,
    normalise_log_weights,
    resample_indexes,
    uniform_log_weights,
)
from slamlib.sim2d.world import Frame2D, integrate_arc, wrap_angle

__all__ = [
    "DEFAULT_MAP_KIND",
    "DEFAULT_RESOLUTION",
    "MAP_KINDS",
    "OccupancyGrid2D",
    "bilinear_taps",
    "field_bumps",
    "grid_cells",
    "initialise_particles",
    "merge_scan",
    "offset_by_motion",
    "perturb_with_noise",
    "pick_best_particle",
    "read_imu",
    "read_scan",
    "read_timing",
    "resample_particles",
    "score_particles",
    "transform_scan",
]

#: The two scoring rules of :class:`OccupancyGrid2D`.
MAP_KINDS = ("density", "likelihood")
#: The scoring rule when none is given (:class:`OccupancyGrid2D`, its :meth:`~OccupancyGrid2D.empty`,
#: :func:`~slamlib.sim2d.run_slam_2d`).
DEFAULT_MAP_KIND = "likelihood"
#: Cell size (m) when none is given (:meth:`OccupancyGrid2D.empty`, :func:`~slamlib.sim2d.run_slam_2d`).
DEFAULT_RESOLUTION = 0.05


# --------------------------------------------------------------------- grid math shared by every 2D map
def grid_cells(origin, resolution: float, shape, world_points):
    """``(row, col, inside)`` int64 cell indexes of world points ``(..., 2)`` in a grid of ``shape (H, W)`` whose
    cell ``(0, 0)`` has its lower-left corner at ``origin``, ``row = floor((y - origin_y) / res)``,
    ``col = floor((x - origin_x) / res)``, and whether they lie in it (indexes outside clamped to 0)."""
    p = np.asarray(world_points, dtype=np.float64)
    c = np.floor((p[..., 0] - origin[0]) / resolution).astype(np.int64)
    r = np.floor((p[..., 1] - origin[1]) / resolution).astype(np.int64)
    h, w = shape
    inside = (r >= 0) & (r < h) & (c >= 0) & (c < w)
    return np.where(inside, r, 0), np.where(inside, c, 0), inside


def field_bumps(
    origin, resolution: float, sigma: float, shape, world_points, heights=1.0
):
    """The likelihood field's bumps of world points ``p`` of ``(M, 2)``: ``h_p exp(-|x_c - p|^2 / 2 sigma^2)``
    at the centres ``x_c`` of the cells within ``3 sigma`` of ``p`` (``heights`` ``h_p``, scalar or ``(M,)``).

    Returns ``(rows, cols, values)``, flat arrays of the cells inside a grid of ``shape (H, W)`` whose cell
    ``(0, 0)`` has its lower-left corner at ``origin``; raising ``F <- max(F, value)`` at them adds the points
    to the field. Every 2D map (:class:`OccupancyGrid2D`, :class:`slamlib.sim2d.particle_maps.ParticleMaps2D`)
    raises its field with these bumps, so their fields agree to the bit.
    """
    rows, cols, vals, ok = _bumps(origin, resolution, sigma, shape, world_points, heights)
    return rows[ok], cols[ok], vals[ok]


def _bumps(origin, resolution, sigma, shape, world_points, heights):
    """:func:`field_bumps` before dropping the cells outside the grid: ``(rows, cols, values, ok)``, each
    ``(M, K)`` with ``K = (2 ceil(3 sigma / resolution) + 1)^2`` (so a caller can tell which point each is)."""
    p = np.asarray(world_points, dtype=np.float64).reshape(-1, 2)
    half = max(1, int(np.ceil(3 * sigma / resolution)))
    k = np.arange(-half, half + 1)
    dr, dc = (a.ravel() for a in np.meshgrid(k, k, indexing="ij"))
    r0 = np.floor((p[:, 1] - origin[1]) / resolution).astype(np.int64)
    c0 = np.floor((p[:, 0] - origin[0]) / resolution).astype(np.int64)
    rows = r0[:, None] + dr[None, :]
    cols = c0[:, None] + dc[None, :]
    cx = origin[0] + (cols + 0.5) * resolution
    cy = origin[1] + (rows + 0.5) * resolution
    vals = np.exp(-0.5 * ((cx - p[:, :1]) ** 2 + (cy - p[:, 1:]) ** 2) / sigma**2)
    vals = (
        vals * np.broadcast_to(np.asarray(heights, dtype=np.float64), (len(p),))[:, None]
    )
    h, w = shape
    ok = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    return rows, cols, vals, ok


def bilinear_taps(origin, resolution: float, shape, world_points):
    """The four cell-centre taps of bilinear interpolation at world points ``(..., 2)``.

    With ``u = (x - origin_x) / res - 1/2``, ``v = (y - origin_y) / res - 1/2``, ``c0 = floor(u)``,
    ``r0 = floor(v)``, ``f_u = u - c0``, ``f_v = v - r0``, the value is the sum of
    ``(1 - f_v)(1 - f_u) F[r0, c0]``, ``(1 - f_v) f_u F[r0, c0 + 1]``, ``f_v (1 - f_u) F[r0 + 1, c0]`` and
    ``f_v f_u F[r0 + 1, c0 + 1]``.
    Yields ``(rows, cols, weights)`` per tap, each shaped like the points' leading axes; a tap outside the grid
    ``shape (H, W)`` has weight 0 (and indexes clamped to cell ``(0, 0)``), so the field reads 0 outside.
    """
    p = np.asarray(world_points, dtype=np.float64)
    u = (p[..., 0] - origin[0]) / resolution - 0.5
    v = (p[..., 1] - origin[1]) / resolution - 0.5
    c0, r0 = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
    fu, fv = u - c0, v - r0
    h, w = shape
    for dr, dc, wt in (
        (0, 0, (1 - fv) * (1 - fu)),
        (0, 1, (1 - fv) * fu),
        (1, 0, fv * (1 - fu)),
        (1, 1, fv * fu),
    ):
        r, c = r0 + dr, c0 + dc
        ok = (r >= 0) & (r < h) & (c >= 0) & (c < w)
        yield np.where(ok, r, 0), np.where(ok, c, 0), np.where(ok, wt, 0.0)


# ------------------------------------------------------------------------------------------------- the map
@dataclass
class OccupancyGrid2D:
    """A 2D grid of hit counts with one of two scoring rules (``kind``), changed in place by step 10.

    Cell ``(r, c)`` covers ``x in [origin_x + c res, origin_x + (c + 1) res)`` and
    ``y in [origin_y + r res, origin_y + (r + 1) res)``; ``counts`` is ``(H, W)`` int64.

    The likelihood field ``F`` (at cell centres) is kept up to date **incrementally**: every merged point ``p``
    raises ``F <- max(F, h_p exp(-|x_c - p|^2 / 2 sigma^2))`` at the centres ``x_c`` within ``3 sigma`` of it,
    with ``h_p = min(1, n_c / n_sat)`` from the count of ``p``'s cell after merging. Since
    ``exp(-min d^2 / 2 sigma^2) = max exp(-d^2 / 2 sigma^2)``, once every cell holds ``n_sat`` returns this is the
    Gaussian of the distance to the nearest merged point (Thrun et al.'s distance-transform field), truncated at
    ``3 sigma``, with no cell quantisation; a return in a cell merged fewer times gets a lower bump.

    Attributes
    ----------
    origin : (2,) world position of the lower-left corner of cell (0, 0) (m).
    resolution : cell size (m).
    counts : (H, W) int64 returns merged into each cell.
    kind : ``"density"`` (the seed's density grid) or ``"likelihood"`` (the likelihood field), see the module.
    sigma : width of the likelihood field (m).
    n_sat : hits at which a density cell saturates.
    eps : random-return term of the likelihood field.
    """

    origin: np.ndarray
    resolution: float
    counts: np.ndarray
    kind: str = DEFAULT_MAP_KIND
    sigma: float = 0.1
    n_sat: int = 3
    eps: float = 0.05
    field: np.ndarray = field(default=None, repr=False)

    def __post_init__(self):
        if self.kind not in MAP_KINDS:
            raise ValueError(f"kind must be one of {MAP_KINDS}, got {self.kind!r}")
        if (
            not self.resolution > 0
            or not self.sigma > 0
            or not self.eps > 0
            or self.n_sat < 1
        ):
            raise ValueError("need resolution, sigma, eps > 0 and n_sat >= 1")
        self.origin = np.asarray(self.origin, dtype=np.float64).reshape(2)
        if self.field is None:
            self.field = np.zeros(self.counts.shape, dtype=np.float64)
            occupied = np.argwhere(self.counts > 0)
            # a grid given counts only: the field of its occupied cells' centres
            if len(occupied):
                self._raise_field(
                    self.origin + (occupied[:, ::-1] + 0.5) * self.resolution
                )

    @classmethod
    def empty(
        cls,
        lo,
        hi,
        resolution: float = DEFAULT_RESOLUTION,
        kind: str = DEFAULT_MAP_KIND,
        **kwargs,
    ) -> OccupancyGrid2D:
        """An all-zero grid covering the box ``lo (2,)`` to ``hi (2,)`` (m)."""
        lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
        if not resolution > 0 or not np.all(hi > lo):
            raise ValueError(
                f"need resolution > 0 and hi > lo, got {resolution}, {lo}, {hi}"
            )
        w, h = np.ceil((hi - lo) / resolution).astype(int)
        return cls(
            origin=lo,
            resolution=float(resolution),
            counts=np.zeros((h, w), dtype=np.int64),
            kind=kind,
            **kwargs,
        )

    def copy(self, kind: str | None = None) -> OccupancyGrid2D:
        """An independent grid with copies of the counts and field (optionally scoring with another ``kind``)."""
        return OccupancyGrid2D(
            origin=self.origin.copy(),
            resolution=self.resolution,
            counts=self.counts.copy(),
            kind=self.kind if kind is None else kind,
            sigma=self.sigma,
            n_sat=self.n_sat,
            eps=self.eps,
            field=self.field.copy(),
        )

    @property
    def total(self) -> int:
        """Returns merged so far."""
        return int(self.counts.sum())

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """``(x_min, x_max, y_min, y_max)`` (m), for ``imshow(..., origin="lower", extent=...)``."""
        h, w = self.counts.shape
        x0, y0 = self.origin
        return (x0, x0 + w * self.resolution, y0, y0 + h * self.resolution)

    def cells_of(self, world_points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(row, col, inside)`` int64 cell indexes of world points ``(..., 2)`` and whether they lie in the grid."""
        return grid_cells(self.origin, self.resolution, self.counts.shape, world_points)

    def _raise_field(self, world_points: np.ndarray, heights=1.0) -> None:
        """``F <- max(F, bump)`` with the bumps of :func:`field_bumps` (the field of the exact points, not of
        their cells' centres)."""
        rows, cols, vals = field_bumps(
            self.origin,
            self.resolution,
            self.sigma,
            self.counts.shape,
            world_points,
            heights,
        )
        np.maximum.at(self.field, (rows, cols), vals)

    def merge(self, world_points) -> OccupancyGrid2D:
        """Add one count per world point ``(N, 2)`` to its cell and raise the field around it; in place.

        Points outside the grid are dropped.
        """
        p = np.asarray(world_points, dtype=np.float64).reshape(-1, 2)
        r, c, inside = self.cells_of(p)
        r, c = r[inside], c[inside]
        np.add.at(self.counts, (r, c), 1)
        if len(r):
            self._raise_field(
                p[inside], np.minimum(self.counts[r, c], self.n_sat) / self.n_sat
            )
        return self

    def point_terms(self, world_points) -> np.ndarray:
        """Per-point log-likelihood terms ``l(p)`` of world points ``(..., 2)`` under this map's ``kind``.

        ``"density"``: ``min(n_c, n_sat) / n_sat`` (0 outside the grid); ``"likelihood"``: ``log(F + eps)``
        (``F`` bilinear between cell centres, :meth:`field_at`; ``log eps`` outside).
        """
        if self.kind == "density":
            r, c, inside = self.cells_of(world_points)
            return np.where(
                inside, np.minimum(self.counts[r, c], self.n_sat) / self.n_sat, 0.0
            )
        return np.log(self.field_at(world_points) + self.eps)

    def field_at(self, world_points) -> np.ndarray:
        """The likelihood field ``F`` at world points ``(..., 2)``, bilinear between cell centres (0 outside).

        The interpolation keeps sub-cell precision: ``F`` changes smoothly as a point moves across a cell, so
        poses a fraction of a cell apart still score differently (a nearest-cell lookup would not).
        """
        p = np.asarray(world_points, dtype=np.float64)
        out = np.zeros(p.shape[:-1])
        for r, c, wt in bilinear_taps(self.origin, self.resolution, self.counts.shape, p):
            out += wt * self.field[r, c]
        return out

    def density(self) -> np.ndarray:
        """(H, W) saturated hit density ``min(n, n_sat) / n_sat`` in [0, 1] (what the density grid scores)."""
        return np.minimum(self.counts, self.n_sat) / self.n_sat


# ------------------------------------------------------------------------------------------- the twelve steps
def initialise_particles(n_particles: int, pose0=None) -> tuple[np.ndarray, np.ndarray]:
    """Step 1: ``P`` particles at ``pose0 (3,)`` (default ``(0, 0, 0)``: the start defines the world frame).

    Returns ``(particles (P, 3) float64, log_weights (P,) = -log P)``.
    """
    if n_particles < 1:
        raise ValueError(f"n_particles must be at least 1, got {n_particles}")
    p0 = np.zeros(3) if pose0 is None else np.asarray(pose0, dtype=np.float64).reshape(3)
    return np.repeat(p0[None, :], int(n_particles), axis=0), uniform_log_weights(
        n_particles
    )


def read_scan(frame: Frame2D, max_points: int | None = None) -> np.ndarray:
    """Step 2: the LIDAR scan, ``(N, 2)`` float64 body-frame points (m): x forward, y left.

    ``max_points``: keep every ``ceil(N / max_points)``-th point (an even down-sampling over the beams).
    """
    pts = np.asarray(frame.scan, dtype=np.float64).reshape(-1, 2)
    if max_points is not None and len(pts) > max_points:
        pts = pts[:: int(np.ceil(len(pts) / max_points))]
    return pts


def read_imu(frame: Frame2D) -> tuple[float, float]:
    """Step 3: ``imu = (speed v (m/s), yaw_rate w (rad/s))``, the wheel odometry over ``[t_{k-1}, t_k]``."""
    return float(frame.speed), float(frame.yaw_rate)


def read_timing(frame: Frame2D) -> float:
    """Step 4: ``dt_k = t_k - t_{k-1}`` (s), 0 on the first frame."""
    dt = float(frame.dt)
    if not np.isfinite(dt) or dt < 0:
        raise ValueError(f"frame dt must be finite and >= 0, got {dt}")
    return dt


def offset_by_motion(particles: np.ndarray, imu, dt: float) -> np.ndarray:
    """Step 5: move every particle along the arc that ``imu = (v, w)`` held for ``dt`` describes (a new array).

    With ``d theta = w dt``: ``x += v dt sinc(d theta / 2) cos(theta + d theta / 2)``, ``y += ... sin(...)``,
    ``theta += d theta`` (:func:`slamlib.sim2d.world.integrate_arc`): the exact unicycle / SE(2) motion, in each
    particle's own heading. Particles ``(P, 3)`` (or one pose ``(3,)``).
    """
    v, w = imu
    return integrate_arc(particles, v, w, dt)


def perturb_with_noise(
    particles: np.ndarray, sigma, rng: np.random.Generator
) -> np.ndarray:
    """Step 6: ``T_i <- T_i [sigma * n_i]``: Gaussian noise in each particle's **body** frame (a new array).

    ``sigma = (sigma_forward (m), sigma_left (m), sigma_theta (rad))``, ``n_i ~ N(0, I_3)`` from ``rng``:
    ``x += c n_f - s n_l``, ``y += s n_f + c n_l`` (``c, s`` of the particle's heading), ``theta += sigma_theta n``
    (wrapped to ``[-pi, pi)``). All-zero ``sigma`` returns a copy and draws nothing.
    """
    particles = np.asarray(particles, dtype=np.float64)
    sigma = np.broadcast_to(np.asarray(sigma, dtype=np.float64), (3,))
    if np.any(sigma < 0):
        raise ValueError(f"sigma must be non-negative, got {sigma}")
    if not np.any(sigma > 0):
        return particles.copy()
    n = rng.standard_normal(particles.shape) * sigma
    c, s = np.cos(particles[..., 2]), np.sin(particles[..., 2])
    out = particles.copy()
    out[..., 0] += c * n[..., 0] - s * n[..., 1]
    out[..., 1] += s * n[..., 0] + c * n[..., 1]
    out[..., 2] = wrap_angle(out[..., 2] + n[..., 2])
    return out


def transform_scan(particles, points: np.ndarray) -> np.ndarray:
    """Step 7: body-frame ``points (N, 2)`` into the world, ``p_ij = R(theta_i) q_j + (x_i, y_i)``.

    ``particles (P, 3)`` gives ``(P, N, 2)``; one pose ``(3,)`` gives ``(N, 2)`` float64.
    """
    pose = np.asarray(particles, dtype=np.float64)
    q = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    c, s = np.cos(pose[..., 2])[..., None], np.sin(pose[..., 2])[..., None]
    x = c * q[:, 0] - s * q[:, 1] + pose[..., 0:1]
    y = s * q[:, 0] + c * q[:, 1] + pose[..., 1:2]
    return np.stack([x, y], axis=-1)


def score_particles(
    particles, points: np.ndarray, world_map: OccupancyGrid2D, tempering: float = 1.0
) -> np.ndarray:
    """Steps 7 + 8: ``s_i = beta sum_j l(R(theta_i) q_j + t_i)``, ``(P,)`` float64 log-likelihoods.

    ``l`` is the map's per-point term (:meth:`OccupancyGrid2D.point_terms`: the saturated hit density for
    ``kind="density"``, ``log(F + eps)`` for the likelihood field). An empty map or empty scan scores all zeros
    (every particle equally likely: the first frame). One pose ``(3,)`` gives a ``(1,)`` result.
    ``tempering`` ``beta`` in ``(0, 1]`` flattens the likelihood ``p(z | x)^beta``: the points of one scan are
    not independent (neighbouring beams hit the same wall, and the map's errors are shared), so the product of
    their terms is overconfident and collapses the weights every frame (Thrun et al. 2005, sec. 6.3.4).
    """
    if not 0 < tempering <= 1:
        raise ValueError(f"tempering must be in (0, 1], got {tempering}")
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    poses = np.atleast_2d(np.asarray(particles, dtype=np.float64))
    if len(pts) == 0 or world_map.total == 0:
        return np.zeros(len(poses))
    return tempering * world_map.point_terms(transform_scan(poses, pts)).sum(axis=-1)


def pick_best_particle(particles: np.ndarray, log_weights) -> tuple[np.ndarray, int]:
    """Step 9: ``(pose (3,), index)`` of the highest-weight particle (ties to the lowest index)."""
    i = int(np.argmax(np.asarray(log_weights, dtype=np.float64)))
    return np.array(particles[i], dtype=np.float64), i


def merge_scan(world_map, pose, points: np.ndarray):
    """Step 10: add the scan placed by ``pose`` (:func:`transform_scan`) to ``world_map``, **in place**.

    A shared :class:`OccupancyGrid2D` takes the best pose ``(3,)``; a
    :class:`~slamlib.sim2d.particle_maps.ParticleMaps2D` (one map per particle) takes every particle's pose
    ``(P, 3)`` and merges particle ``i``'s placement of the scan into particle ``i``'s map.
    """
    pose = np.asarray(pose, dtype=np.float64)
    if isinstance(world_map, OccupancyGrid2D):
        pose = pose.reshape(3)
    return world_map.merge(transform_scan(pose, points))


def resample_particles(
    particles: np.ndarray,
    log_weights,
    rng: np.random.Generator,
    ess_fraction: float | None = DEFAULT_ESS_FRACTION,
    maps=None,
) -> tuple[np.ndarray, np.ndarray, bool]:
    """Step 11: systematic resampling when ``ESS < ess_fraction * P`` (``None``: always).

    :func:`slamlib.resampling.resample_indexes` draws one offset ``u0`` from ``rng`` and returns the indexes;
    this step returns ``(particles[idx], -log P, True)``, or ``(a copy, normalised log-weights, False)``.
    ``maps``: the particles' own maps (:class:`~slamlib.sim2d.particle_maps.ParticleMaps2D`), which follow
    their particles (``maps.select(idx)``, in place); None for a shared map.
    """
    particles = np.asarray(particles, dtype=np.float64)
    log_w = normalise_log_weights(log_weights)
    if log_w.shape != particles.shape[:1]:
        raise ValueError(
            f"log_weights shape {log_w.shape} does not match particles {particles.shape}"
        )
    idx = resample_indexes(log_w, rng, ess_fraction)
    if idx is None:
        return particles.copy(), log_w, False
    if maps is not None:
        maps.select(idx)
    return particles[idx], uniform_log_weights(len(particles)), True
