"""The 1D world: structure on a line, a moving vehicle, a velocity sensor and a 1D range sensor.

Everything lives on one axis ``x`` (metres). The **world** is a set of point landmarks ("walls", "pillars")
at positions unknown to the filter: irregularly spaced stretches and a **colonnade** of evenly spaced pillars,
whose repetition makes scans at shifts of one spacing look alike (a 1D version of a corridor with identical
doors). The **vehicle** starts at ``x = 0`` at ``t = 0`` and follows a smooth velocity profile

.. math:: v(t) &= \\bar v + \\sum_m a_m \\sin(2 \\pi t / T_m + \\varphi_m), \\\\
          x(t) &= \\bar v t
          + \\sum_m \\frac{a_m T_m}{2\\pi} \\left[\\cos\\varphi_m - \\cos(2\\pi t / T_m + \\varphi_m)\\right]

(the position is the exact integral, so no integration error enters the ground truth).

Sensors, sampled in **frames** ``k = 0..K-1`` at a jittered ~10 Hz (KITTI's rate): ``t_0 = 0`` and
``dt_k = t_k - t_{k-1} = period (1 + j_k)``, ``j_k ~ U(-jitter, jitter)``.

* **Velocity sensor** (the IMU / wheel-odometer analogue): the mean velocity over the last interval plus a
  constant bias and white noise, ``u_k = (x_k - x_{k-1}) / dt_k + b + sigma_v n_k``, ``n_k ~ N(0, 1)``
  (``u_0 = 0``). Integrating it (dead reckoning) drifts like ``b t`` plus a random walk
  ``sigma_v sqrt(sum dt^2)``.
* **Range sensor** (the "1D LIDAR"): the signed offsets ``z = l - x_k + sigma_r n`` of every landmark ``l`` with
  ``|l - x_k| <= max_range``, each dropped independently with probability ``dropout``, plus optional clutter
  (``Poisson(clutter_rate)`` spurious returns uniform in ``[-max_range, max_range]``); a noisy return beyond
  ``max_range`` is not reported. Offsets are in the
  **body frame** (origin at the vehicle), sorted.

All randomness comes from ``numpy.random.Generator`` objects built from explicit seeds.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np

__all__ = [
    "Frame",
    "Recording1D",
    "SensorModel1D",
    "VelocityProfile",
    "World1D",
    "make_world",
    "scan_landmarks",
    "simulate",
]


@dataclass(frozen=True)
class World1D:
    """Landmark positions on the line.

    Attributes
    ----------
    landmarks : ndarray (L,) float64
        Sorted world positions of the structure (metres).
    colonnade : tuple (start, end, spacing)
        Where the evenly spaced section lies (for plots; the filter never sees it).
    """

    landmarks: np.ndarray
    colonnade: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def extent(self) -> tuple[float, float]:
        """``(min, max)`` landmark position."""
        return float(self.landmarks[0]), float(self.landmarks[-1])


def make_world(
    seed: int = 0,
    start: float = -12.0,
    end: float = 75.0,
    gap: tuple[float, float] = (1.2, 4.0),
    colonnade: tuple[float, float, float] = (20.0, 36.0, 2.0),
) -> World1D:
    """A random world: irregular landmarks with gaps ``U(gap)`` on ``[start, end]``, and a colonnade.

    Parameters
    ----------
    seed : int
        Seed of the generator placing the irregular landmarks.
    start, end : float
        Extent of the structure (metres). The vehicle starts at 0, so ``start < 0`` gives structure behind it.
    gap : (float, float)
        Range of the uniformly drawn gaps between irregular landmarks (metres).
    colonnade : (start, end, spacing)
        Evenly spaced pillars ``start, start + spacing, ...`` up to ``end``; no irregular landmark is placed in
        ``(start - spacing, end + spacing)``. Use ``spacing = 0`` for none.
    """
    lo, hi = gap
    if not 0 < lo <= hi:
        raise ValueError(f"gap must be 0 < min <= max, got {gap}")
    if not start < end:
        raise ValueError(f"start must be below end, got {start} >= {end}")
    rng = np.random.default_rng(seed)
    c0, c1, spacing = colonnade
    positions = []
    x = start
    while x <= end:
        if not (spacing > 0 and c0 - spacing < x < c1 + spacing):
            positions.append(x)
        x += rng.uniform(lo, hi)
    if spacing > 0:
        positions.extend(np.arange(c0, c1 + 1e-9, spacing))
    return World1D(
        landmarks=np.sort(np.asarray(positions, dtype=np.float64)),
        colonnade=(c0, c1, spacing),
    )


@dataclass(frozen=True)
class VelocityProfile:
    """``v(t) = mean + sum_m a_m sin(2 pi t / T_m + phi_m)`` (m/s) and its exact integral ``x(t)``, ``x(0) = 0``.

    ``components`` holds ``(a_m, T_m, phi_m)`` triples (m/s, s, rad).
    """

    mean: float = 1.5
    components: tuple[tuple[float, float, float], ...] = (
        (0.8, 12.0, 0.0),
        (0.3, 4.7, 1.0),
    )

    def velocity(self, t) -> np.ndarray:
        """``v(t)`` in m/s, for scalar or array ``t`` (s)."""
        t = np.asarray(t, dtype=np.float64)
        v = np.full_like(t, self.mean)
        for a, period, phase in self.components:
            v = v + a * np.sin(2 * np.pi * t / period + phase)
        return v

    def position(self, t) -> np.ndarray:
        """``x(t) = integral_0^t v``, in metres."""
        t = np.asarray(t, dtype=np.float64)
        x = self.mean * t
        for a, period, phase in self.components:
            w = 2 * np.pi / period
            x = x + a / w * (np.cos(phase) - np.cos(w * t + phase))
        return x


#: Most spurious returns per scan (the Poisson mean of ``clutter_rate``): each costs memory and scoring time every
#: frame; 1,000 is already 50 times the landmarks a scan sees.
MAX_CLUTTER_RATE = 1000.0


@dataclass(frozen=True)
class SensorModel1D:
    """Sensor and timing parameters of the simulation (the filter may use them as a datasheet).

    Attributes
    ----------
    period, jitter : frame period (s) and relative jitter: ``dt = period (1 + U(-jitter, jitter))``.
    velocity_noise : ``sigma_v`` (m/s), white noise on each velocity reading.
    velocity_bias : ``b`` (m/s), constant bias of the velocity sensor (dead reckoning drifts by ``b t``).
    range_noise : ``sigma_r`` (m), Gaussian noise on each range return.
    max_range : metres; landmarks with ``|l - x| <= max_range`` can be returned (in front and behind).
    dropout : probability that a landmark in range gives no return.
    clutter_rate : expected number of spurious returns per scan (Poisson), uniform within range.
    """

    period: float = 0.1
    jitter: float = 0.1
    velocity_noise: float = 0.2
    velocity_bias: float = 0.1
    range_noise: float = 0.05
    max_range: float = 8.0
    dropout: float = 0.15
    clutter_rate: float = 0.2

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if not np.isfinite(v):
                raise ValueError(f"{f.name} must be finite, got {v!r}")
        if self.clutter_rate > MAX_CLUTTER_RATE:
            raise ValueError(
                f"clutter_rate must be at most {MAX_CLUTTER_RATE:g} returns per scan, got "
                f"{self.clutter_rate!r}"
            )
        if not self.period > 0 or not 0 <= self.jitter < 1:
            raise ValueError(
                f"need period > 0 and 0 <= jitter < 1, got {self.period}, {self.jitter}"
            )
        if self.velocity_noise < 0 or self.range_noise < 0 or self.clutter_rate < 0:
            raise ValueError("noise levels and clutter_rate must be non-negative")
        if not 0 <= self.dropout < 1 or not self.max_range > 0:
            raise ValueError(
                f"need 0 <= dropout < 1 and max_range > 0, got {self.dropout}, {self.max_range}"
            )


@dataclass(frozen=True)
class Frame:
    """One sensor frame, what the filter reads at step ``k``.

    Attributes
    ----------
    index : k.
    time : t_k (s).
    dt : t_k - t_{k-1} (s); 0 for the first frame.
    velocity : measured velocity u_k (m/s) over [t_{k-1}, t_k]; 0 for the first frame.
    scan : ndarray (N,) float64, signed offsets of returns in the body frame (m), sorted.
    """

    index: int
    time: float
    dt: float
    velocity: float
    scan: np.ndarray


@dataclass(frozen=True)
class Recording1D:
    """A simulated run: the world, the ground truth and the frames the filter reads.

    Attributes
    ----------
    world : World1D
    profile : VelocityProfile
    sensors : SensorModel1D
    times : ndarray (K,) float64, t_k.
    true_positions : ndarray (K,) float64, x(t_k).
    frames : list[Frame], K frames.
    true_offsets : list of ndarray, the noise-free offsets of the landmarks actually returned (for plots/tests).
    landmark_returns : ndarray (L,) int64, how many frames returned each landmark of ``world.landmarks``.
    """

    world: World1D
    profile: VelocityProfile
    sensors: SensorModel1D
    times: np.ndarray
    true_positions: np.ndarray
    frames: list = field(repr=False)
    true_offsets: list = field(repr=False)
    landmark_returns: np.ndarray = field(repr=False, default=None)

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def measured_velocities(self) -> np.ndarray:
        """(K,) measured velocities u_k."""
        return np.array([f.velocity for f in self.frames])

    @property
    def dts(self) -> np.ndarray:
        """(K,) frame intervals dt_k."""
        return np.array([f.dt for f in self.frames])


def scan_landmarks(
    world: World1D, x: float, sensors: SensorModel1D, rng: np.random.Generator
):
    """Simulate one range scan at vehicle position ``x``: returns ``(scan, true_offsets, returned)``.

    ``returned`` are the indexes (into ``world.landmarks``) of the landmarks that gave a return, ``true_offsets``
    their noise-free ``l - x`` (clutter excluded); ``scan`` is sorted and holds their noisy versions plus clutter.
    """
    offsets = world.landmarks - x
    in_range = np.flatnonzero(np.abs(offsets) <= sensors.max_range)
    returned = in_range[rng.random(in_range.size) >= sensors.dropout]
    noisy = offsets[returned] + sensors.range_noise * rng.standard_normal(returned.size)
    # the sensor reports nothing beyond its range
    gate = np.abs(noisy) <= sensors.max_range
    returned, noisy = returned[gate], noisy[gate]
    kept = offsets[returned]
    clutter = rng.uniform(
        -sensors.max_range, sensors.max_range, rng.poisson(sensors.clutter_rate)
    )
    return np.sort(np.concatenate([noisy, clutter])), kept, returned


def simulate(
    world: World1D,
    n_frames: int = 300,
    seed: int = 0,
    profile: VelocityProfile | None = None,
    sensors: SensorModel1D | None = None,
) -> Recording1D:
    """Drive the vehicle through ``world`` for ``n_frames`` frames and record its sensors.

    Parameters
    ----------
    world : World1D
    n_frames : int
        Number of frames K (the first at ``t = 0``).
    seed : int
        Seed for timing jitter, velocity-sensor noise and range-sensor noise/dropouts/clutter.
    profile : VelocityProfile, optional
        Defaults to ``VelocityProfile()`` (0.4 to 2.6 m/s, about 45 m in 30 s).
    sensors : SensorModel1D, optional
        Defaults to ``SensorModel1D()``.

    Returns
    -------
    Recording1D
    """
    if n_frames < 1:
        raise ValueError(f"n_frames must be at least 1, got {n_frames}")
    profile = profile or VelocityProfile()
    sensors = sensors or SensorModel1D()
    rng = np.random.default_rng(seed)
    dts = sensors.period * (1.0 + rng.uniform(-sensors.jitter, sensors.jitter, n_frames))
    dts[0] = 0.0
    times = np.cumsum(dts)
    x = profile.position(times)
    frames, true_offsets = [], []
    landmark_returns = np.zeros(world.landmarks.size, dtype=np.int64)
    for k in range(n_frames):
        if k == 0:
            u = 0.0
        else:
            u = (
                (x[k] - x[k - 1]) / dts[k]
                + sensors.velocity_bias
                + sensors.velocity_noise * rng.standard_normal()
            )
        scan, kept, returned = scan_landmarks(world, x[k], sensors, rng)
        landmark_returns[returned] += 1
        frames.append(
            Frame(
                index=k,
                time=float(times[k]),
                dt=float(dts[k]),
                velocity=float(u),
                scan=scan,
            )
        )
        true_offsets.append(kept)
    return Recording1D(
        world=world,
        profile=profile,
        sensors=sensors,
        times=times,
        true_positions=x,
        frames=frames,
        true_offsets=true_offsets,
        landmark_returns=landmark_returns,
    )
