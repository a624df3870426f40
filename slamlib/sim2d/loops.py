"""Closing a loop in 2D: one shared map against a map per particle, on a route long enough to drift.

The courtyard of :func:`~slamlib.sim2d.world.make_world` grown to a 40 m x 20 m loop (:data:`LOOP_ROUTE`, 139 m a
lap), seen by a short-range LIDAR (:data:`LOOP_SENSORS`: 6 m, 90 beams), driven :data:`LOOP_LAPS` laps so that the
vehicle comes back to where it started and drives on through the place it mapped first. Sixteen pillars
and two wall stubs are the landmarks along the way. Dead reckoning is off
by about 10 m by then; a filter is off by what it drifted on the way round, and the question is whether it
takes that back when it sees the start again.

* **Shared map** (:class:`~slamlib.sim2d.filter.ParticleSLAM2D`, the seed's scheme): one map, grown from the best
  particle of each frame. Whatever the best particle got wrong is in the map for good, and every particle is
  scored against it.
* **A map per particle** (:class:`~slamlib.sim2d.filter.ParticleMapsSLAM2D`, FastSLAM's scheme): each particle is
  scored against the map its own past built; at the loop, the particles whose past drifted see the old walls in
  one place and the new ones in another, and lose weight.

:func:`compare_loop_closure` runs both on one seeded world and drive (the world, the drive and the filters all
seeded by ``seed``) and measures the position error in :data:`LOOP_WINDOW` metres of driving before and after
the vehicle passes its start again (:func:`loop_windows`), and the per-particle maps' memory against full copies.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slamlib.sim2d.filter import SLAM2DResult, run_slam_2d
from slamlib.sim2d.world import Recording2D, Route2D, SensorModel2D, make_world, simulate

__all__ = [
    "LOOP_LAPS",
    "LOOP_PARTICLES",
    "LOOP_RESOLUTION",
    "LOOP_ROUTE",
    "LOOP_SENSORS",
    "LOOP_WINDOW",
    "LoopComparison",
    "compare_loop_closure",
    "loop_recording",
    "loop_windows",
    "travelled",
]

#: The loop: 40 m x 20 m straights, 3 m turns (138.8 m a lap).
LOOP_ROUTE = Route2D(length=40.0, width=20.0, turn_radius=3.0)
#: A short-range LIDAR (6 m, 90 beams): along the long walls a scan pins the heading and the distance to the wall,
#: but little of how far the vehicle has come.
LOOP_SENSORS = SensorModel2D(max_range=6.0, n_beams=90)
#: Laps driven: the whole loop and 30 % of it again, through the place mapped first.
LOOP_LAPS = 1.3
#: Pillars and wall stubs of the loop world (:func:`~slamlib.sim2d.world.make_world`).
LOOP_PILLARS, LOOP_STUBS = 16, 2
#: Particles and cell size (m) of both filters.
LOOP_PARTICLES = 50
LOOP_RESOLUTION = 0.1
#: Metres of driving before and after the vehicle passes its start again over which the error is averaged.
LOOP_WINDOW = 15.0


def loop_recording(seed: int, laps: float = LOOP_LAPS) -> Recording2D:
    """The loop world of ``seed`` and ``laps`` laps driven through it (drive seeded by ``seed`` too)."""
    world = make_world(
        seed=seed, route=LOOP_ROUTE, n_pillars=LOOP_PILLARS, n_stubs=LOOP_STUBS
    )
    return simulate(world, route=LOOP_ROUTE, laps=laps, seed=seed, sensors=LOOP_SENSORS)


def travelled(recording: Recording2D) -> np.ndarray:
    """``(K,)`` true distance driven up to each frame (m), summed over the frames' chords."""
    steps = np.hypot(*np.diff(recording.true_poses[:, :2], axis=0).T)
    return np.concatenate([[0.0], np.cumsum(steps)])


def loop_windows(recording: Recording2D, metres: float = LOOP_WINDOW):
    """``(before, after)`` boolean ``(K,)`` masks: the frames in the last ``metres`` of driving before the
    vehicle has covered one lap, and in the first ``metres`` after it (when it is back where it started)."""
    d = travelled(recording)
    lap = recording.route.perimeter
    return (d > lap - metres) & (d <= lap), (d > lap) & (d <= lap + metres)


@dataclass
class LoopComparison:
    """Both filters on one loop drive: ``shared`` and ``per_particle`` :class:`SLAM2DResult`\\ s, the drive's
    ``recording`` and the ``before`` / ``after`` masks of :func:`loop_windows`."""

    seed: int
    recording: Recording2D
    shared: SLAM2DResult
    per_particle: SLAM2DResult
    before: np.ndarray
    after: np.ndarray

    def error(self, result: SLAM2DResult, window: np.ndarray) -> float:
        """Mean position error (m) of ``result``'s estimate over the frames of ``window``."""
        return float(result.slam_error[window].mean())

    def summary(self) -> dict:
        """The numbers a table needs: errors before and after the loop (m), the after-loop ratio shared over
        per-particle, final errors, dead reckoning's after-loop error, and the maps' memory (bytes) at its
        peak against full per-particle copies."""
        per, shared = self.per_particle, self.shared
        peak = int(per.map_bytes.max())
        full = per.particle_maps.full_copy_bytes()
        return {
            "seed": self.seed,
            "frames": len(self.recording),
            "shared_before_m": self.error(shared, self.before),
            "shared_after_m": self.error(shared, self.after),
            "per_particle_before_m": self.error(per, self.before),
            "per_particle_after_m": self.error(per, self.after),
            "after_ratio_shared_over_per_particle": self.error(shared, self.after)
            / self.error(per, self.after),
            "shared_final_m": float(shared.slam_error[-1]),
            "per_particle_final_m": float(per.slam_error[-1]),
            "dead_reckoning_after_m": float(per.dead_reckoning_error[self.after].mean()),
            "map_bytes_peak": peak,
            "full_copy_bytes": int(full),
            "memory_share": peak / full,
        }


def compare_loop_closure(
    seed: int,
    n_particles: int = LOOP_PARTICLES,
    laps: float = LOOP_LAPS,
    keep_history: bool = False,
    progress: bool = False,
    snapshots: tuple = (),
) -> LoopComparison:
    """The shared map and a map per particle on the loop drive of ``seed`` (:func:`loop_recording`), each
    filter seeded by ``seed``, with :data:`LOOP_RESOLUTION` cells; see the module. ``keep_history``, ``progress``
    and (the per-particle run's) ``snapshots`` as :func:`~slamlib.sim2d.filter.run_slam_2d`'s."""
    recording = loop_recording(seed, laps)
    runs = {
        per: run_slam_2d(
            recording,
            n_particles=n_particles,
            seed=seed,
            resolution=LOOP_RESOLUTION,
            keep_history=keep_history,
            progress=progress,
            per_particle_maps=per,
            snapshots=snapshots if per else (),
        )
        for per in (False, True)
    }
    before, after = loop_windows(recording)
    return LoopComparison(seed, recording, runs[False], runs[True], before, after)
