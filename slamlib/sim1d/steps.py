"""The twelve steps of particle SLAM in one dimension, one pure function per step.

A particle is a hypothesis ``x_i`` (metres) of the vehicle's position; the set is an ``(P,)`` float64 array.
The map is a 1D **occupancy-count grid** (:class:`OccupancyGrid1D`): cell ``c`` counts how many scan returns
were merged into ``[origin + c r, origin + (c + 1) r)``. The step names are shared with the 3D filter
(``CONTRIBUTING.md``):

====  =======================  =============================================================================
step  function                 1D math
====  =======================  =============================================================================
1     initialise_particles     ``x_i = 0`` (the world frame is the start pose)
2     read_scan                ``z`` (N,) signed offsets in the body frame
3     read_imu                 measured velocity ``u_k`` (m/s)
4     read_timing              ``dt_k`` (s)
5     offset_by_motion         ``x_i <- x_i + u_k dt_k``
6     perturb_with_noise       ``x_i <- x_i + sigma n_i``, ``n_i ~ N(0, 1)``
7     transform_scan           ``p_ij = x_i + z_j`` (body -> world; a 1D pose is a translation)
8     score_particles          ``s_i = sum_j log(F(p_ij) + eps)`` against the likelihood field ``F`` of the map
9     pick_best_particle       ``argmax_i w_i``
10    merge_scan               add one count at each ``x_best + z_j``
11    resample_particles       systematic resampling (:mod:`slamlib.resampling`) when ESS drops
12    (the loop)               :meth:`slamlib.sim1d.ParticleSLAM1D.step` per frame
====  =======================  =============================================================================

The likelihood field (Thrun, Burgard & Fox, *Probabilistic Robotics* 2005, section 6.4) here is the grid of
counts blurred by a Gaussian and normalised so that each landmark's bump has height ``min(1, hits / n_sat)``
(:func:`likelihood_field`): near a well-observed landmark ``F -> 1``, near structure merged once ``F ~ 1/3``,
far from all structure ``F -> 0``. Each return then has the mixture likelihood ``F(p) + eps`` (a "hit" and a
uniform "random return" term, ``eps`` playing ``z_rand / z_max``), so clutter and not-yet-mapped structure cost
every particle the same ``log eps`` instead of dominating the score.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slamlib.resampling import effective_sample_size, systematic_resample
from slamlib.sim1d.world import Frame

__all__ = [
    "OccupancyGrid1D",
    "extract_landmarks",
    "initialise_particles",
    "likelihood_field",
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


# ---------------------------------------------------------------------------------------------------- the map
@dataclass(frozen=True)
class OccupancyGrid1D:
    """A 1D grid of hit counts: cell ``c`` covers ``[origin + c * resolution, origin + (c + 1) * resolution)``.

    Attributes
    ----------
    origin : float
        World position of the left edge of cell 0 (m).
    resolution : float
        Cell size (m).
    counts : ndarray (C,) int64
        Number of scan returns merged into each cell.
    """

    origin: float
    resolution: float
    counts: np.ndarray

    @classmethod
    def empty(cls, lo: float, hi: float, resolution: float = 0.05) -> "OccupancyGrid1D":
        """An all-zero grid covering ``[lo, hi]``."""
        if not resolution > 0 or not hi > lo:
            raise ValueError(f"need resolution > 0 and hi > lo, got {resolution}, [{lo}, {hi}]")
        n = int(np.ceil((hi - lo) / resolution))
        return cls(origin=float(lo), resolution=float(resolution), counts=np.zeros(n, dtype=np.int64))

    @property
    def centres(self) -> np.ndarray:
        """(C,) world positions of the cell centres."""
        return self.origin + (np.arange(self.counts.size) + 0.5) * self.resolution

    @property
    def total(self) -> int:
        """Number of returns merged so far."""
        return int(self.counts.sum())

    def cell_of(self, x) -> np.ndarray:
        """Cell index of world position(s) ``x`` (may be out of ``[0, C)``)."""
        return np.floor((np.asarray(x, dtype=np.float64) - self.origin) / self.resolution).astype(np.int64)


def _gaussian_blur(counts: np.ndarray, sigma_cells: float) -> np.ndarray:
    """``sum_c n_c exp(-(i - c)^2 / (2 s^2))`` for every cell ``i`` (unnormalised kernel, peak 1), truncated at 4 s."""
    half = max(1, int(np.ceil(4.0 * sigma_cells)))
    k = np.arange(-half, half + 1, dtype=np.float64)
    kernel = np.exp(-0.5 * (k / sigma_cells) ** 2)
    return np.convolve(counts.astype(np.float64), kernel, mode="same")


def _running_max(values: np.ndarray, half: int) -> np.ndarray:
    """``max(values[i - half : i + half + 1])`` for every ``i`` (edges padded with -inf)."""
    padded = np.concatenate([np.full(half, -np.inf), values, np.full(half, -np.inf)])
    out = values.copy()
    for k in range(2 * half + 1):
        np.maximum(out, padded[k:k + values.size], out=out)
    return out


def likelihood_field(grid: OccupancyGrid1D, sigma: float, n_sat: float = 3.0) -> np.ndarray:
    """The Gaussian-smoothed, peak-normalised likelihood field ``F`` at the cell centres, ``(C,)`` in ``[0, 1]``.

    .. math:: B = G_\\sigma * n, \\qquad F(x) = \\frac{B(x)}{\\max\\big(n_{sat},\\ \\max_{|y - x| \\le 3\\sigma} B(y)\\big)}

    ``G_sigma`` is an unnormalised Gaussian of standard deviation ``sigma`` metres (peak 1), so ``B`` is a sum of
    bumps, one per merged return. Dividing by the local maximum scales every landmark's bump to height
    ``min(1, B_peak / n_sat)``: a well-observed landmark gets a peak of 1 whatever its count (a landmark seen for
    100 frames must not be a wider or taller target than one seen for 10), structure merged fewer than ``n_sat``
    times (new landmarks, clutter) a lower one, and ``F -> 0`` far from all returns. The bump's width is that of
    the merged returns (range noise and the jitter of the merge poses) widened by ``sigma``; ``sigma`` of about
    the cell size (``sqrt(sigma_r^2 + resolution^2)`` by default in :func:`~slamlib.sim1d.run_slam_1d`) keeps it
    close to the sensor's own noise.
    """
    if not sigma > 0:
        raise ValueError(f"sigma must be positive, got {sigma}")
    if not n_sat > 0:
        raise ValueError(f"n_sat must be positive, got {n_sat}")
    s_cells = sigma / grid.resolution
    blurred = _gaussian_blur(grid.counts, s_cells)
    local_max = _running_max(blurred, max(1, int(np.ceil(3 * s_cells))))
    return blurred / np.maximum(local_max, n_sat)


# ------------------------------------------------------------------------------------------- the twelve steps
def initialise_particles(n_particles: int, x0: float = 0.0) -> np.ndarray:
    """Step 1: ``P`` particles all at ``x0`` (the start pose defines the world frame), ``(P,)`` float64."""
    if n_particles < 1:
        raise ValueError(f"n_particles must be at least 1, got {n_particles}")
    return np.full(int(n_particles), float(x0), dtype=np.float64)


def read_scan(frame: Frame) -> np.ndarray:
    """Step 2: the range scan, ``(N,)`` float64 signed offsets of returns in the body frame (m)."""
    return np.asarray(frame.scan, dtype=np.float64)


def read_imu(frame: Frame) -> float:
    """Step 3: the measured velocity ``u_k`` over ``[t_{k-1}, t_k]`` (m/s)."""
    return float(frame.velocity)


def read_timing(frame: Frame) -> float:
    """Step 4: the frame interval ``dt_k = t_k - t_{k-1}`` (s), 0 on the first frame."""
    return float(frame.dt)


def offset_by_motion(particles: np.ndarray, velocity: float, dt: float) -> np.ndarray:
    """Step 5: dead-reckon every particle, ``x_i <- x_i + u dt`` (a new ``(P,)`` array).

    Exact for the integral ``int v`` over the interval when ``u`` is the mean velocity over it (which the
    simulated velocity sensor measures, up to its noise and bias).
    """
    return np.asarray(particles, dtype=np.float64) + float(velocity) * float(dt)


def perturb_with_noise(particles: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """Step 6: ``x_i <- x_i + sigma n_i``, ``n_i ~ N(0, 1)`` i.i.d. from ``rng`` (a new ``(P,)`` array).

    The filter uses ``sigma = sigma_u dt``: a velocity error of ``sigma_u`` m/s held over the interval.
    ``sigma = 0`` returns a copy and draws nothing.
    """
    particles = np.asarray(particles, dtype=np.float64)
    if sigma < 0:
        raise ValueError(f"sigma must be non-negative, got {sigma}")
    if sigma == 0:
        return particles.copy()
    return particles + sigma * rng.standard_normal(particles.shape)


def transform_scan(particles, scan: np.ndarray) -> np.ndarray:
    """Step 7: scan points in the world frame for every particle, ``p_ij = x_i + z_j``.

    Parameters
    ----------
    particles : float or array (P,)
        Particle positions (a scalar gives the single-pose ``(N,)`` result).
    scan : (N,) body-frame offsets.

    Returns
    -------
    ndarray (P, N) float64 (or (N,) for a scalar pose).
    """
    scan = np.asarray(scan, dtype=np.float64)
    x = np.asarray(particles, dtype=np.float64)
    return x[..., None] + scan


def score_particles(world_points: np.ndarray, grid: OccupancyGrid1D, sigma: float, eps: float = 0.05,
                    field: np.ndarray | None = None) -> np.ndarray:
    """Step 8: log-likelihood of each particle's transformed scan against the map built so far.

    .. math:: s_i = \\sum_j \\log\\big(F(p_{ij}) + \\varepsilon\\big)

    with ``F`` the likelihood field of ``grid`` (:func:`likelihood_field`), linearly interpolated between cell
    centres and 0 outside the grid. On the **first frame** the map is empty, ``F = 0`` and every particle
    scores ``N log eps``; to keep the numbers readable an empty map or an empty scan scores all zeros (any
    constant gives the same normalised weights).

    Parameters
    ----------
    world_points : (P, N) float64, from :func:`transform_scan`.
    grid : OccupancyGrid1D, the map before this frame is merged.
    sigma : float, likelihood-field width (m).
    eps : float, weight of the uniform "random return" term (> 0).
    field : (C,) float64, optional, a precomputed ``likelihood_field(grid, sigma)``.

    Returns
    -------
    ndarray (P,) float64 log-likelihoods (all <= N log(1 + eps)).
    """
    points = np.atleast_2d(np.asarray(world_points, dtype=np.float64))
    if not eps > 0:
        raise ValueError(f"eps must be positive, got {eps}")
    if points.shape[1] == 0 or grid.total == 0:
        return np.zeros(points.shape[0])
    if field is None:
        field = likelihood_field(grid, sigma)
    f = np.interp(points, grid.centres, field, left=0.0, right=0.0)
    return np.log(f + eps).sum(axis=1)


def pick_best_particle(weights: np.ndarray) -> int:
    """Step 9: the index of the particle with the highest weight (or score), ``argmax_i w_i``.

    Ties go to the lowest index, so the choice is deterministic.
    """
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim != 1 or w.size == 0:
        raise ValueError(f"weights must be a non-empty (P,) array, got shape {w.shape}")
    return int(np.argmax(w))


def merge_scan(grid: OccupancyGrid1D, world_points: np.ndarray) -> OccupancyGrid1D:
    """Step 10: a new grid with one count added at the cell of each world point (points off the grid dropped).

    Call it with ``transform_scan(x_best, scan)``: the scan placed by the best particle's pose.
    """
    cells = grid.cell_of(np.ravel(world_points))
    cells = cells[(cells >= 0) & (cells < grid.counts.size)]
    counts = grid.counts + np.bincount(cells, minlength=grid.counts.size)
    return OccupancyGrid1D(origin=grid.origin, resolution=grid.resolution, counts=counts)


def resample_particles(particles: np.ndarray, weights: np.ndarray, rng: np.random.Generator,
                       ess_threshold: float | None = 0.5):
    """Step 11: systematic resampling when the effective sample size drops.

    When ``ess_threshold`` is ``None``, or ``ESS = 1 / sum w_i^2 < ess_threshold * P``, draw ``u0 ~ U[0, 1)``
    from ``rng``, pick ``idx = systematic_resample(w, u0)`` (:mod:`slamlib.resampling`) and return
    ``(particles[idx], uniform weights, True)``; otherwise return copies of the inputs and ``False`` (the
    weights then keep accumulating scores: ``w_i <- w_i exp(s_i)``).

    Returns
    -------
    (particles (P,), weights (P,) summing to 1, resampled: bool)
    """
    particles = np.asarray(particles, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != particles.shape:
        raise ValueError(f"weights shape {w.shape} does not match particles shape {particles.shape}")
    ess = effective_sample_size(w)
    n = particles.size
    if ess_threshold is None or ess < ess_threshold * n:
        idx = systematic_resample(w, rng.random())
        return particles[idx], np.full(n, 1.0 / n), True
    return particles.copy(), w / w.sum(), False


# ----------------------------------------------------------------------------------------- reading the map
def extract_landmarks(grid: OccupancyGrid1D, sigma: float = 0.1, min_count: int = 5) -> np.ndarray:
    """Landmark positions read off the map: peaks of the blurred counts, refined to a count-weighted centroid.

    A peak is a local maximum of ``G_sigma * n``; its landmark is the centroid of the raw counts within
    ``+- 3 sigma`` of the peak cell, kept when those counts add up to at least ``min_count`` (this drops clutter
    and stray returns merged once or twice).

    Returns
    -------
    ndarray (M,) float64, sorted world positions (m).
    """
    counts = grid.counts.astype(np.float64)
    if counts.sum() == 0:
        return np.zeros(0)
    s_cells = sigma / grid.resolution
    blurred = _gaussian_blur(grid.counts, s_cells)
    padded = np.concatenate([[-np.inf], blurred, [-np.inf]])
    peaks = np.flatnonzero((padded[1:-1] > padded[:-2]) & (padded[1:-1] >= padded[2:]) & (blurred > 0))
    half = max(1, int(np.ceil(3 * s_cells)))
    centres = grid.centres
    found = []
    for c in peaks:
        lo, hi = max(0, c - half), min(counts.size, c + half + 1)
        mass = counts[lo:hi].sum()
        if mass >= min_count:
            found.append(float((counts[lo:hi] * centres[lo:hi]).sum() / mass))
    return np.unique(np.round(np.asarray(found), 9)) if found else np.zeros(0)
