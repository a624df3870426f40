"""The twelve steps of particle SLAM in one dimension, one pure function per step.

A particle is a hypothesis ``x_i`` (metres) of the vehicle's position; the set is an ``(P,)`` float64 array,
weighted by ``(P,)`` **log**-weights normalised to ``logsumexp = 0``. The map is a 1D **occupancy-count grid**
(:class:`OccupancyGrid1D`): cell ``c`` counts how many scan returns were merged into
``[origin + c r, origin + (c + 1) r)``. Names, leading parameters and results follow the step contract shared
with the 3D filter (:data:`slamlib.contract.STEPS`, checked by :func:`slamlib.contract.check_steps_module`);
what 1D needs beyond it comes after the shared parameters and has a default:

====  =================================================================  =============================================
step  function (the contract's parameters first)                         1D math
====  =================================================================  =============================================
1     ``initialise_particles(n_particles, pose0=0.0)``                   ``x_i = pose0``, ``log w_i = -log P``
2     ``read_scan(frame) -> points``                                     ``z`` (N,) offsets in the body frame
3     ``read_imu(frame) -> imu``                                         measured velocity ``u_k`` (m/s)
4     ``read_timing(frame) -> dt``                                       ``dt_k`` (s)
5     ``offset_by_motion(particles, imu, dt)``                           ``x_i <- x_i + u_k dt_k``
6     ``perturb_with_noise(particles, sigma, rng)``                      ``x_i <- x_i + sigma n_i``, ``n_i ~ N(0, 1)``
7     ``transform_scan(particles, points)``                              ``p_ij = x_i + z_j`` (pose = translation)
8     ``score_particles(particles, points, world_map, sigma, eps)``      ``s_i = sum_j log(F(p_ij) + eps)`` (7 + 8)
9     ``pick_best_particle(particles, log_weights) -> (pose, index)``    ``i = argmax log w``, ``pose = x_i``
10    ``merge_scan(world_map, pose, points) -> world_map``               a count at each ``pose + z_j``, in place
11    ``resample_particles(particles, log_weights, rng, ess_fraction)``  systematic, when the ESS drops
12    (the loop)                                                         ``ParticleSLAM1D.step(frame)``
====  =================================================================  =============================================

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

from slamlib.resampling import (
    DEFAULT_ESS_FRACTION,
    normalise_log_weights,
    resample_indexes,
    uniform_log_weights,
)
from slamlib.sim1d.world import Frame

__all__ = [
    "DEFAULT_EPS",
    "DEFAULT_RESOLUTION",
    "LANDMARK_MIN_COUNT",
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

#: Map cell size (m) when none is given (:meth:`OccupancyGrid1D.empty`, :func:`~slamlib.sim1d.run_slam_1d`).
DEFAULT_RESOLUTION = 0.05
#: Weight of the uniform "random return" term of the per-return likelihood ``F + eps`` (step 8) when none is given
#: (:func:`score_particles`, :class:`~slamlib.sim1d.ParticleSLAM1D`, :func:`~slamlib.sim1d.run_slam_1d`).
DEFAULT_EPS = 0.05
#: Fewest merged returns near a peak that :func:`extract_landmarks` reads as a landmark when none is given (and
#: :func:`~slamlib.sim1d.run_slam_1d`'s ``landmark_min_count``): fewer are clutter or stray returns.
LANDMARK_MIN_COUNT = 5


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
        Number of scan returns merged into each cell. The dataclass is frozen (origin and resolution never
        change) but ``counts`` is a mutable array: step 10 (:func:`merge_scan`) adds to it **in place**, so keep
        a :meth:`copy` of a grid whose state you want to look at later.
    """

    origin: float
    resolution: float
    counts: np.ndarray

    @classmethod
    def empty(
        cls, lo: float, hi: float, resolution: float = DEFAULT_RESOLUTION
    ) -> OccupancyGrid1D:
        """An all-zero grid covering ``[lo, hi]``."""
        if not resolution > 0 or not hi > lo:
            raise ValueError(
                f"need resolution > 0 and hi > lo, got {resolution}, [{lo}, {hi}]"
            )
        n = int(np.ceil((hi - lo) / resolution))
        return cls(
            origin=float(lo),
            resolution=float(resolution),
            counts=np.zeros(n, dtype=np.int64),
        )

    def copy(self) -> OccupancyGrid1D:
        """An independent grid with the same extent and a copy of the counts."""
        return OccupancyGrid1D(
            origin=self.origin, resolution=self.resolution, counts=self.counts.copy()
        )

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
        return np.floor(
            (np.asarray(x, dtype=np.float64) - self.origin) / self.resolution
        ).astype(np.int64)


def _gaussian_blur(counts: np.ndarray, sigma_cells: float) -> np.ndarray:
    """``sum_c n_c exp(-(i - c)^2 / (2 s^2))`` for every cell ``i`` (unnormalised kernel, peak 1), truncated at 4 s."""
    # Offsets beyond the grid never reach another cell: truncating there is exact and bounds the work by C^2 whatever
    # sigma is; the slice keeps the output (C,) (np.convolve "same" would return the longer of the two).
    half = min(max(1, int(np.ceil(4.0 * sigma_cells))), counts.size - 1)
    k = np.arange(-half, half + 1, dtype=np.float64)
    kernel = np.exp(-0.5 * (k / sigma_cells) ** 2)
    # = mode "same" for 2 half < C
    return np.convolve(counts.astype(np.float64), kernel)[half : half + counts.size]


def _running_max(values: np.ndarray, half: int) -> np.ndarray:
    """``max(values[i - half : i + half + 1])`` for every ``i`` (edges padded with -inf)."""
    padded = np.concatenate([np.full(half, -np.inf), values, np.full(half, -np.inf)])
    out = values.copy()
    for k in range(2 * half + 1):
        np.maximum(out, padded[k : k + values.size], out=out)
    return out


def likelihood_field(
    grid: OccupancyGrid1D, sigma: float, n_sat: float = 3.0
) -> np.ndarray:
    """The Gaussian-smoothed, peak-normalised likelihood field ``F`` at the cell centres, ``(C,)`` in ``[0, 1]``.

    .. math:: B = G_\\sigma * n, \\qquad
        F(x) = \\frac{B(x)}{\\max\\big(n_{sat},\\ \\max_{|y - x| \\le 3\\sigma} B(y)\\big)}

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
    # same: exact
    local_max = _running_max(
        blurred, min(max(1, int(np.ceil(3 * s_cells))), grid.counts.size)
    )
    return blurred / np.maximum(local_max, n_sat)


# ------------------------------------------------------------------------------------------- the twelve steps
def initialise_particles(
    n_particles: int, pose0: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Step 1: ``P`` particles all at ``pose0`` (default 0: the start pose defines the world frame).

    Returns
    -------
    (particles (P,) float64, log_weights (P,) float64 = ``-log P``, :func:`slamlib.resampling.uniform_log_weights`)
    """
    if n_particles < 1:
        raise ValueError(f"n_particles must be at least 1, got {n_particles}")
    return np.full(int(n_particles), float(pose0), dtype=np.float64), uniform_log_weights(
        n_particles
    )


def read_scan(frame: Frame) -> np.ndarray:
    """Step 2: the range scan, ``(N,)`` float64 signed offsets of returns in the body frame (m)."""
    return np.asarray(frame.scan, dtype=np.float64)


def read_imu(frame: Frame) -> float:
    """Step 3: the measured velocity ``u_k`` over ``[t_{k-1}, t_k]`` (m/s)."""
    return float(frame.velocity)


def read_timing(frame: Frame) -> float:
    """Step 4: the frame interval ``dt_k = t_k - t_{k-1}`` (s), 0 on the first frame."""
    return float(frame.dt)


def offset_by_motion(particles: np.ndarray, imu: float, dt: float) -> np.ndarray:
    """Step 5: dead-reckon every particle, ``x_i <- x_i + u dt`` with ``u = imu`` the velocity (a new ``(P,)`` array).

    Exact for the integral ``int v`` over the interval when ``u`` is the mean velocity over it (which the
    simulated velocity sensor measures, up to its noise and bias).
    """
    return np.asarray(particles, dtype=np.float64) + float(imu) * float(dt)


def perturb_with_noise(
    particles: np.ndarray, sigma: float, rng: np.random.Generator
) -> np.ndarray:
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


def transform_scan(particles, points: np.ndarray) -> np.ndarray:
    """Step 7: scan points in the world frame for every particle, ``p_ij = x_i + z_j``.

    Parameters
    ----------
    particles : float or array (P,)
        Particle positions (one pose, a scalar, gives the single-pose ``(N,)`` result).
    points : (N,) body-frame offsets.

    Returns
    -------
    ndarray (P, N) float64 (or (N,) for a scalar pose).
    """
    points = np.asarray(points, dtype=np.float64)
    x = np.asarray(particles, dtype=np.float64)
    return x[..., None] + points


def score_particles(
    particles,
    points: np.ndarray,
    world_map: OccupancyGrid1D,
    sigma: float | None = None,
    eps: float = DEFAULT_EPS,
    field: np.ndarray | None = None,
) -> np.ndarray:
    """Steps 7 + 8: log-likelihood of each particle's transformed scan against the map built so far.

    .. math:: s_i = \\sum_j \\log\\big(F(x_i + z_j) + \\varepsilon\\big)

    with ``x_i + z_j`` from :func:`transform_scan` and ``F`` the likelihood field of ``world_map``
    (:func:`likelihood_field`), linearly interpolated between cell centres and 0 outside the grid. On the
    **first frame** the map is empty, ``F = 0`` and every particle scores ``N log eps``; to keep the numbers
    readable an empty map or an empty scan scores all zeros (any constant gives the same normalised weights).

    Parameters
    ----------
    particles : (P,) float64 positions (or one pose, a float, for a ``(1,)`` result).
    points : (N,) body-frame offsets, from :func:`read_scan`.
    world_map : OccupancyGrid1D, the map before this frame is merged.
    sigma : float, optional
        Likelihood-field width (m). ``None``: two grid cells, ``2 * world_map.resolution`` (the floor of
        :func:`~slamlib.sim1d.run_slam_1d`'s ``max(sqrt(sigma_r^2 + resolution^2), 2 resolution)``, which needs
        the sensor's range noise ``sigma_r`` and so is chosen by the caller).
    eps : float, weight of the uniform "random return" term (> 0).
    field : (C,) float64, optional, a precomputed ``likelihood_field(world_map, sigma)``.

    Returns
    -------
    ndarray (P,) float64 log-likelihoods (all <= N log(1 + eps)).
    """
    world_points = np.atleast_2d(transform_scan(particles, points))
    if not eps > 0:
        raise ValueError(f"eps must be positive, got {eps}")
    if world_points.shape[1] == 0 or world_map.total == 0:
        return np.zeros(world_points.shape[0])
    if field is None:
        field = likelihood_field(
            world_map, 2.0 * world_map.resolution if sigma is None else sigma
        )
    f = np.interp(world_points, world_map.centres, field, left=0.0, right=0.0)
    return np.log(f + eps).sum(axis=1)


def pick_best_particle(
    particles: np.ndarray, log_weights: np.ndarray
) -> tuple[float, int]:
    """Step 9: the highest-weight particle, ``i* = argmax_i log w_i``, as ``(pose, index)``.

    ``pose = float(particles[i*])``. Ties go to the lowest index, so the choice is deterministic. Any
    increasing function of the weights (linear weights, raw scores) picks the same particle.
    """
    lw = np.asarray(log_weights, dtype=np.float64)
    x = np.asarray(particles, dtype=np.float64)
    if lw.ndim != 1 or lw.size == 0:
        raise ValueError(
            f"log_weights must be a non-empty (P,) array, got shape {lw.shape}"
        )
    if x.shape != lw.shape:
        raise ValueError(
            f"particles shape {x.shape} does not match log_weights shape {lw.shape}"
        )
    index = int(np.argmax(lw))
    return float(x[index]), index


def merge_scan(
    world_map: OccupancyGrid1D, pose: float, points: np.ndarray
) -> OccupancyGrid1D:
    """Step 10: add one count at the cell of each return placed by ``pose`` (``pose + z_j``), **in place**.

    ``world_map.counts`` is changed in place (as the 3D maps are, see :mod:`slamlib.contract`) and ``world_map``
    is returned; returns that fall off the grid are dropped. Copy the grid first (:meth:`OccupancyGrid1D.copy`)
    to keep the map as it was.
    """
    cells = world_map.cell_of(np.ravel(transform_scan(pose, points)))
    cells = cells[(cells >= 0) & (cells < world_map.counts.size)]
    np.add.at(world_map.counts, cells, 1)
    return world_map


def resample_particles(
    particles: np.ndarray,
    log_weights: np.ndarray,
    rng: np.random.Generator,
    ess_fraction: float | None = DEFAULT_ESS_FRACTION,
):
    """Step 11: systematic resampling when the effective sample size drops.

    :func:`slamlib.resampling.resample_indexes` decides and draws: when ``ess_fraction`` is ``None`` (always),
    or ``ESS = 1 / sum w_i^2 < ess_fraction * P`` for ``w = exp(log_weights)``, it draws ``u0 ~ U[0, 1)`` from
    ``rng`` and returns ``idx = systematic_resample(w, u0)``; this step then returns
    ``(particles[idx], uniform log-weights -log P, True)``. Otherwise nothing is drawn and it returns a copy of
    the particles, the normalised log-weights and ``False`` (the log-weights then keep accumulating scores:
    ``log w_i <- log w_i + s_i``).

    Returns
    -------
    (particles (P,), log_weights (P,) with logsumexp 0, resampled: bool)
    """
    particles = np.asarray(particles, dtype=np.float64)
    log_w = normalise_log_weights(log_weights)
    if log_w.shape != particles.shape:
        raise ValueError(
            f"log_weights shape {log_w.shape} does not match particles shape {particles.shape}"
        )
    idx = resample_indexes(log_w, rng, ess_fraction)
    if idx is None:
        return particles.copy(), log_w, False
    return particles[idx], uniform_log_weights(particles.size), True


# ----------------------------------------------------------------------------------------- reading the map
def extract_landmarks(
    grid: OccupancyGrid1D, sigma: float = 0.1, min_count: int = LANDMARK_MIN_COUNT
) -> np.ndarray:
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
    peaks = np.flatnonzero(
        (padded[1:-1] > padded[:-2]) & (padded[1:-1] >= padded[2:]) & (blurred > 0)
    )
    half = max(1, int(np.ceil(3 * s_cells)))
    centres = grid.centres
    found = []
    for c in peaks:
        lo, hi = max(0, c - half), min(counts.size, c + half + 1)
        mass = counts[lo:hi].sum()
        if mass >= min_count:
            found.append(float((counts[lo:hi] * centres[lo:hi]).sum() / mass))
    return np.unique(np.round(np.asarray(found), 9)) if found else np.zeros(0)
