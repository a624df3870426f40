"""The 1D particle SLAM filter: a thin object whose :meth:`ParticleSLAM1D.step` is the twelve steps.

State per frame: particle positions ``x (P,)``, their normalised **log**-weights ``log w (P,)`` (``logsumexp = 0``,
as at every dimension, :mod:`slamlib.contract`) and the map (:class:`~slamlib.sim1d.steps.OccupancyGrid1D`,
changed in place by step 10). Between resamplings the log-weights carry the sum of all scores since the last one
(``log w_i <- log w_i + s_i``, normalised by :func:`slamlib.resampling.normalise_log_weights`), which is the
sequential importance sampling update (Doucet, Godsill & Andrieu 2000); resampling is triggered when the
effective sample size falls below ``ess_fraction * P``. The estimate is the best particle (step 9, as in the seed
project), and the weighted mean is recorded beside it.

The per-frame loop is not written here: :class:`ParticleSLAM1D` is a :class:`slamlib.contract.StepsFilter` over
:mod:`slamlib.sim1d.steps`, whose ``step(frame)`` is the one loop that 1D and 2D share; this class adds step 8's
likelihood width and ``eps`` and the weighted mean ``sum_i w_i x_i``.

This is the "map from the best particle" simplification of particle SLAM: one shared map, built from the best
pose of each frame (the seed project's scheme), rather than a map per particle as in FastSLAM / Rao-Blackwellised
grid SLAM (Montemerlo et al. 2002; Grisetti, Stachniss & Burgard 2007).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

import slamlib.sim1d.steps as steps_1d
from slamlib.contract import StepInfo, StepsFilter
from slamlib.resampling import DEFAULT_ESS_FRACTION
from slamlib.sim1d.steps import (
    DEFAULT_EPS,
    DEFAULT_RESOLUTION,
    LANDMARK_MIN_COUNT,
    OccupancyGrid1D,
    extract_landmarks,
)
from slamlib.sim1d.world import Recording1D

__all__ = ["ParticleSLAM1D", "SLAM1DResult", "StepInfo", "dead_reckon", "run_slam_1d"]


def _grid_is_world_map(init):
    """Let ``__init__`` take the map as ``grid=`` too, its name before the constructors were made alike."""

    @functools.wraps(init)
    def wrapper(self, *args, **kwargs):
        if "grid" in kwargs:
            if "world_map" in kwargs or len(args) >= 2:
                raise TypeError("ParticleSLAM1D got the map twice (world_map and grid)")
            kwargs["world_map"] = kwargs.pop("grid")
        init(self, *args, **kwargs)

    return wrapper


def _scoring_settings(likelihood_sigma, eps) -> tuple[float | None, float]:
    """Step 8's settings checked (finite and >= 0; ``likelihood_sigma`` may be None: step 8's default) and as
    floats. Kept out of the decorated ``__init__``, which mutation testing skips."""
    settings = {"likelihood_sigma": likelihood_sigma, "eps": eps}
    if likelihood_sigma is None:
        del settings["likelihood_sigma"]
    for name, value in settings.items():
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
    return (None if likelihood_sigma is None else float(likelihood_sigma)), float(eps)


class ParticleSLAM1D(StepsFilter):
    """Particle SLAM on a line, one :meth:`step` per frame (:class:`slamlib.contract.StepsFilter`).

    The first four parameters and ``ess_fraction`` are the same, in the same order, as
    :class:`slamlib.sim2d.ParticleSLAM2D`'s; what 1D adds (step 8's settings) comes after them with defaults.

    Parameters
    ----------
    n_particles : int
        P.
    world_map : OccupancyGrid1D
        The (usually empty) map to start from; its extent bounds the map (not the landmarks' positions).
        :meth:`step` adds to it in place (step 10): pass ``world_map.copy()`` to keep the original. Also accepted
        as ``grid=``, its earlier name.
    motion_noise : float
        ``sigma_u`` (m/s): step 6 spreads the particles by ``sigma_u dt``. Use at least the velocity sensor's
        noise; larger values let the filter absorb an unknown bias.
    rng : numpy.random.Generator
        Source of the motion noise and the resampling offsets.
    ess_fraction : float or None
        Resample when ``ESS < ess_fraction * P``; ``None`` resamples every frame.
    likelihood_sigma : float, optional
        Width of the likelihood field (m), e.g. ``sqrt(sigma_r^2 + resolution^2)`` (what
        :func:`run_slam_1d` passes); ``None``: step 8's default, two grid cells.
    eps : float
        Random-return term of the per-return likelihood ``F + eps``.

    Attributes
    ----------
    particles : (P,) float64 positions.
    log_weights : (P,) float64 log-weights (logsumexp 0).
    world_map : the map, changed in place by every :meth:`step` (also :attr:`grid`).
    """

    #: The step functions the filter runs (:mod:`slamlib.sim1d.steps`).
    #:
    #: :meta hide-value:
    steps = steps_1d

    @_grid_is_world_map
    def __init__(
        self,
        n_particles: int,
        world_map: OccupancyGrid1D,
        motion_noise: float,
        rng: np.random.Generator,
        ess_fraction: float | None = DEFAULT_ESS_FRACTION,
        likelihood_sigma: float | None = None,
        eps: float = DEFAULT_EPS,
    ):
        super().__init__(n_particles, world_map, float(motion_noise), rng, ess_fraction)
        self.likelihood_sigma, self.eps = _scoring_settings(likelihood_sigma, eps)

    @property
    def grid(self) -> OccupancyGrid1D:
        """The map (:attr:`world_map`), by its earlier name."""
        return self.world_map

    def score_options(self) -> dict:
        """Step 8's likelihood width and random-return term."""
        return {"sigma": self.likelihood_sigma, "eps": self.eps}

    def mean_pose(self, moved, weights) -> float:
        """The weighted mean position ``sum_i w_i x_i`` (m)."""
        return float(np.dot(weights, moved))


def dead_reckon(recording: Recording1D, x0: float = 0.0) -> np.ndarray:
    """Velocity-only positions ``x_k = x_{k-1} + u_k dt_k`` (steps 3-5 alone), ``(K,)`` float64."""
    return x0 + np.cumsum(recording.measured_velocities * recording.dts)


#: Frames in which the range sensor must have returned a true landmark for it to count as observed (enough to be
#: mapped) when none is given (:meth:`SLAM1DResult.observed_landmarks`, :meth:`SLAM1DResult.landmark_errors`).
DEFAULT_MIN_RETURNS = 5


@dataclass
class SLAM1DResult:
    """Everything a run produced, for plots, tests and the book.

    Attributes
    ----------
    times, true_positions, estimated, mean_estimated, dead_reckoned : ndarray (K,) float64
        Time (s) and positions (m): truth, best particle, weighted mean, velocity integration.
    ess : (K,) effective sample size after scoring; resampled : (K,) bool.
    grid : OccupancyGrid1D, the final map.
    landmarks_true : (L,) the world's landmarks; landmark_returns : (L,) how many frames returned each one;
    landmarks_estimated : (M,) read off the map.
    particle_history, weight_history : (K, P) float32, particles after steps 5-6 and their weights, or None.
    map_history : (K, C) int32 counts after each merge, or None.
    """

    times: np.ndarray
    true_positions: np.ndarray
    estimated: np.ndarray
    mean_estimated: np.ndarray
    dead_reckoned: np.ndarray
    ess: np.ndarray
    resampled: np.ndarray
    grid: OccupancyGrid1D
    landmarks_true: np.ndarray
    landmark_returns: np.ndarray
    landmarks_estimated: np.ndarray
    particle_history: np.ndarray | None = None
    weight_history: np.ndarray | None = None
    map_history: np.ndarray | None = None

    @property
    def slam_error(self) -> np.ndarray:
        """(K,) ``|estimated - true|`` (m)."""
        return np.abs(self.estimated - self.true_positions)

    @property
    def dead_reckoning_error(self) -> np.ndarray:
        """(K,) ``|dead reckoned - true|`` (m)."""
        return np.abs(self.dead_reckoned - self.true_positions)

    def observed_landmarks(self, min_returns: int = DEFAULT_MIN_RETURNS) -> np.ndarray:
        """True landmarks the range sensor returned in at least ``min_returns`` frames (enough to be mapped)."""
        return self.landmarks_true[self.landmark_returns >= min_returns]

    def landmark_errors(self, min_returns: int = DEFAULT_MIN_RETURNS) -> np.ndarray:
        """For each observed true landmark, the distance to the nearest landmark read off the map (m)."""
        seen = self.observed_landmarks(min_returns)
        est = self.landmarks_estimated
        if est.size == 0:
            return np.full(seen.size, np.inf)
        return np.abs(seen[:, None] - est[None, :]).min(axis=1)

    def summary(self) -> dict:
        """Final and mean absolute errors of SLAM and dead reckoning (m), and the number of resamplings."""
        return {
            "frames": int(self.times.size),
            "slam_final_error_m": float(self.slam_error[-1]),
            "slam_mean_error_m": float(self.slam_error.mean()),
            "dead_reckoning_final_error_m": float(self.dead_reckoning_error[-1]),
            "dead_reckoning_mean_error_m": float(self.dead_reckoning_error.mean()),
            "resamplings": int(self.resampled.sum()),
        }


#: Most map cells :func:`run_slam_1d` allocates: 4 million cells (100 km at 5 cm) keep memory (~100 MB with the
#: likelihood field) and time per frame bounded; a huge velocity bias would otherwise ask for billions (a hang).
MAX_GRID_CELLS = 4_000_000
#: Most multiply-adds per frame of the likelihood field's blur (cells x kernel cells): ~1 s a frame in numpy.
MAX_FIELD_WORK = 1e9


def run_slam_1d(
    recording: Recording1D,
    n_particles: int = 200,
    seed: int = 0,
    motion_noise: float | None = None,
    likelihood_sigma: float | None = None,
    resolution: float = DEFAULT_RESOLUTION,
    eps: float = DEFAULT_EPS,
    ess_fraction: float | None = DEFAULT_ESS_FRACTION,
    keep_history: bool = True,
    landmark_min_count: int = LANDMARK_MIN_COUNT,
    progress: bool = False,
) -> SLAM1DResult:
    """Run :class:`ParticleSLAM1D` over every frame of ``recording`` (step 12, the loop).

    Parameters
    ----------
    recording : Recording1D, from :func:`slamlib.sim1d.simulate`.
    n_particles : int, P.
    seed : int, seed of the filter's generator (motion noise, resampling).
    motion_noise : float, optional
        ``sigma_u`` (m/s); defaults to ``1.5 * max(sigma_v, 0.05)`` plus ``|b|``, the datasheet noise inflated
        to cover the unknown bias.
    likelihood_sigma : float, optional
        Defaults to ``sqrt(sigma_r^2 + resolution^2)`` (at least 2 cells).
    resolution : float, map cell size (m). The map spans the landmark-free bounds ``[x_0 - D - R, x_0 + D + R]``
        with ``D`` the distance that ``v_max`` covers in the run's duration and ``R`` the sensor range; ValueError
        when that is more than :data:`MAX_GRID_CELLS` cells, or when the likelihood field's blur would cost more
        than :data:`MAX_FIELD_WORK` operations a frame (a huge range noise on a large map).
    eps, ess_fraction : see :class:`ParticleSLAM1D`.
    keep_history : keep particles, weights and map counts of every frame (K x P and K x C).
    landmark_min_count : passed to :func:`~slamlib.sim1d.steps.extract_landmarks`.
    progress : show a tqdm progress bar.
    """
    from tqdm.auto import tqdm

    sensors = recording.sensors
    if motion_noise is None:
        motion_noise = 1.5 * max(sensors.velocity_noise, 0.05) + abs(
            sensors.velocity_bias
        )
    if likelihood_sigma is None:
        likelihood_sigma = max(
            float(np.hypot(sensors.range_noise, resolution)), 2 * resolution
        )
    if not (np.isfinite(resolution) and resolution > 0):
        raise ValueError(f"resolution must be finite and > 0, got {resolution!r}")
    reach = np.abs(recording.measured_velocities).max() * recording.times[-1] + 1.0
    cells = 2.0 * (reach + sensors.max_range) / resolution
    if not cells <= MAX_GRID_CELLS:
        raise ValueError(
            f"the map would need {cells:.3g} cells of {resolution:g} m to cover the +-{reach:.3g} m the "
            f"measured velocities (bias included) can reach in {recording.times[-1]:.3g} s, more than "
            f"{MAX_GRID_CELLS:,}; use a smaller velocity bias, fewer frames or a coarser resolution"
        )
    # the blur's width in cells (at most the grid)
    kernel = min(cells, 8.0 * likelihood_sigma / resolution)
    if not cells * kernel <= MAX_FIELD_WORK:
        raise ValueError(
            f"a likelihood field {likelihood_sigma:.3g} m wide over {cells:.3g} cells of {resolution:g} m "
            f"costs {cells * kernel:.3g} operations per frame, more than {MAX_FIELD_WORK:.0e}; use a "
            f"smaller range noise or likelihood_sigma, or a coarser resolution"
        )
    grid = OccupancyGrid1D.empty(
        -reach - sensors.max_range, reach + sensors.max_range, resolution
    )
    slam = ParticleSLAM1D(
        n_particles,
        grid,
        motion_noise,
        np.random.default_rng(seed),
        ess_fraction=ess_fraction,
        likelihood_sigma=likelihood_sigma,
        eps=eps,
    )
    k_frames = len(recording)
    estimated, mean_est, ess, resampled = (np.zeros(k_frames) for _ in range(4))
    resampled = resampled.astype(bool)
    particle_history = (
        np.zeros((k_frames, n_particles), np.float32) if keep_history else None
    )
    weight_history = (
        np.zeros((k_frames, n_particles), np.float32) if keep_history else None
    )
    map_history = (
        np.zeros((k_frames, grid.counts.size), np.int32) if keep_history else None
    )
    for k, frame in enumerate(
        tqdm(recording.frames, desc="sim1d SLAM", unit="frame", disable=not progress)
    ):
        info = slam.step(frame)
        estimated[k], mean_est[k], ess[k], resampled[k] = (
            info.estimate,
            info.mean,
            info.ess,
            info.resampled,
        )
        if keep_history:
            particle_history[k] = info.moved
            weight_history[k] = info.weights
            # a copy (into the int32 row): the grid changes in place
            map_history[k] = slam.world_map.counts
    return SLAM1DResult(
        times=recording.times.copy(),
        true_positions=recording.true_positions.copy(),
        estimated=estimated,
        mean_estimated=mean_est,
        dead_reckoned=dead_reckon(recording),
        ess=ess,
        resampled=resampled,
        grid=slam.world_map,
        landmarks_true=recording.world.landmarks.copy(),
        landmark_returns=recording.landmark_returns.copy(),
        landmarks_estimated=extract_landmarks(
            slam.world_map, likelihood_sigma, landmark_min_count
        ),
        particle_history=particle_history,
        weight_history=weight_history,
        map_history=map_history,
    )
