"""Gaps in time: where a drive's frames jump by more than a few frame periods, the run starts a new segment.

A sensor dropout (a USB hiccup, a full disk on the logging PC, a drive cut and glued) leaves a drive whose frames
jump by seconds: ``dt`` between two frames is tens of sweep periods. Steps 5 and 6 would carry the particles over
that time with one IMU sample (or the held constant velocity), metres off wherever the car turned or braked, and
step 10 would merge the next scan into the old map at that wrong pose: the whole rest of the drive inherits the
error (a 10-second gap cost 33 m of ATE on a drive that otherwise had 0.09 m).

So a gap is detected from the frame intervals, ``dt_k > GAP_PERIODS * median(dt_1..dt_{k-1})`` (the median of the
intervals seen before, gaps excluded: robust to the jitter of KITTI's 10 Hz timing and to a drive read with a
frame stride), and the run starts a **segment** there (:func:`slamlib.slam3d.run.run_drive`): a fresh filter
(step 1 again, a new map), its start pose the old filter's motion prediction across the gap (steps 3-5 without
noise: :meth:`slamlib.slam3d.ParticleSLAM3D.predicted_pose`). The poses stay one trajectory; the metrics evaluate
each segment from its own first pose (:func:`stitch_segments`), so that a segment is charged its own drift and
not the prediction across the gap, which no scan could check. The run says so: a warning naming the frames and the
gap, and ``segments`` in its metrics.
"""

from __future__ import annotations

import numpy as np

from slamlib.geometry import invert_pose

__all__ = ["GAP_PERIODS", "MIN_INTERVALS", "is_gap", "gap_warning", "stitch_segments"]

#: A frame interval longer than this many typical intervals is a gap ("more than a few frame periods").
GAP_PERIODS = 5.0
#: Intervals to have seen before a gap can be told from the typical interval.
MIN_INTERVALS = 2


def is_gap(dt: float, seen) -> bool:
    """Whether the interval ``dt`` (s) is a gap after the intervals ``seen`` (s, gaps excluded):
    ``dt > GAP_PERIODS * median(seen)``, judged once :data:`MIN_INTERVALS` are known."""
    if len(seen) < MIN_INTERVALS:
        return False
    return bool(dt > GAP_PERIODS * float(np.median(seen)))


def gap_warning(before: int, after: int, dt: float, typical: float) -> str:
    """The warning for a gap between drive frames ``before`` and ``after``."""
    return (
        f"a {dt:.2f} s gap in time between frames {before} and {after} ({dt / typical:.0f} frame "
        "periods): a new segment starts there (new map, start pose predicted across the gap); "
        "the metrics evaluate each segment from its own first pose"
    )


def stitch_segments(poses, ground_truth, starts) -> np.ndarray:
    """The poses ``(F, 4, 4)`` with each segment (frames ``starts[i]`` up to the next start) moved rigidly so that
    its first pose is the ground truth's there: ``P'_k = G_s inv(P_s) P_k`` for ``k`` in the segment starting at
    ``s``. Any metric of the result charges each segment its own drift only. ``starts`` begins with 0; one segment
    returns the poses unchanged (both start at the identity)."""
    P = np.asarray(poses, dtype=np.float64)
    G = np.asarray(ground_truth, dtype=np.float64)
    out = P.copy()
    bounds = list(starts) + [len(P)]
    for a, b in zip(bounds[:-1], bounds[1:]):
        if a > 0:
            out[a:b] = (G[a] @ invert_pose(P[a]))[None] @ P[a:b]
    return out
