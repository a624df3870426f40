"""Gaps in time (:mod:`slamlib.slam3d.segments`): detected from the frame intervals, a new segment each, reported,
and evaluated from each segment's own first pose."""

import re

import numpy as np
import pytest

from slamlib.geometry import make_pose, rpy_to_matrix
from slamlib.slam3d.segments import GAP_PERIODS, is_gap, stitch_segments


def test_a_gap_is_an_interval_over_a_few_typical_ones():
    period = 0.10315
    seen = [period, period * 1.01, period * 0.99]
    assert not is_gap(GAP_PERIODS * period * 0.99, seen)
    assert is_gap(GAP_PERIODS * period * 1.01, seen)
    assert is_gap(10.3, seen)
    # a stride of 10 frames is the typical interval of its own drive, not a gap
    assert not is_gap(1.03, [1.03, 1.04])
    # too few intervals to tell what is typical; two are enough
    assert not is_gap(10.3, [period])
    assert is_gap(10.3, [period, period])
    # exactly five typical intervals is not yet a gap
    assert not is_gap(GAP_PERIODS * 0.125, [0.125, 0.125, 0.125])


def test_stitching_moves_each_segment_onto_the_ground_truth_at_its_start():
    rng = np.random.default_rng(3)
    G = np.array(
        [
            make_pose(rpy_to_matrix(rng.normal(0, 0.2, 3)), rng.normal(0, 5, 3))
            for _ in range(9)
        ]
    )
    G[0] = np.eye(4)
    P = G.copy()
    P[4:] = (
        make_pose(rpy_to_matrix([0, 0, 0.5]), [7.0, -2.0, 0.3]) @ G[4:]
    )  # off after the gap
    P[6] = P[6] @ make_pose(np.eye(3), [0.1, 0, 0])  # the segment's own drift
    S = stitch_segments(P, G, [0, 4])
    np.testing.assert_allclose(S[:4], P[:4])
    np.testing.assert_allclose(S[[4, 5, 7, 8]], G[[4, 5, 7, 8]], atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(S[6, :3, 3] - G[6, :3, 3]), 0.1, rtol=1e-9)
    np.testing.assert_allclose(stitch_segments(P, G, [0]), P)
    # the first segment is never moved, even when it does not start at the ground truth's first pose
    P0 = P.copy()
    P0[:4] = make_pose(rpy_to_matrix([0.1, 0, 0]), [1.0, 0, 0]) @ P[:4]
    np.testing.assert_allclose(stitch_segments(P0, G, [0, 4])[:4], P0[:4])
    # a segment from the second frame on; integer poses are computed in float64
    S1 = stitch_segments(np.broadcast_to(np.eye(4, dtype=int), (9, 4, 4)), G, [0, 1])
    np.testing.assert_allclose(S1[1:], np.broadcast_to(G[1], (8, 4, 4)), atol=1e-12)


@pytest.fixture(scope="module")
def drives(tmp_path_factory):
    """A 120-frame synthetic drive, and the same drive with frames 10-109 cut out (a 10.3-second dropout)."""
    from drive_edits import cut_frames

    from slamlib.synth import Hdl64, write_drive
    from slamlib.synth.writer import drive_dir

    base = tmp_path_factory.mktemp("gap")
    write_drive(
        base / "full",
        "07",
        frames=(0, 120),
        seed=2,
        lidar=Hdl64(columns=500, beam_stride=2),
        progress=False,
    )
    full = drive_dir(base / "full", "2011_09_26", 1)
    keep = list(range(10)) + list(range(110, 120))
    cut_frames(full, drive_dir(base / "gap", "2011_09_26", 1), keep)
    return base


def test_a_ten_second_gap_is_reported_and_costs_no_more_than_the_segments_own_drift(
    drives,
):
    """The reproducer of a 10-second dropout (frames 0-9, then 110-119): a warning naming the frames, two
    segments, and an ATE at most twice the uncut drive's (before: 33.5 m against 0.09 m)."""
    from slamlib.kitti import KittiRawDrive
    from slamlib.slam3d import SLAM3DConfig, evaluate, run_drive

    cfg = SLAM3DConfig.of(particles=100, seed=0)
    full = run_drive(KittiRawDrive(drives / "full", "2011_09_26", 1), cfg, progress=False)
    with pytest.warns(UserWarning) as record:
        gap = run_drive(
            KittiRawDrive(drives / "gap", "2011_09_26", 1), cfg, progress=False
        )
    (w,) = [r for r in record if "gap in time" in str(r.message)]
    assert re.fullmatch(
        r"a 10\.\d\d s gap in time between frames 9 and 10 \(10\d frame periods\): a new segment starts "
        r"there \(new map, start pose predicted across the gap\); the metrics evaluate each segment from "
        r"its own first pose",
        str(w.message),
    )
    assert list(gap.segment_starts) == [0, 10] and len(gap.filters()) == 2
    m_full, m_gap = evaluate(full), evaluate(gap)
    assert m_gap["segments"] == [{"frames": [0, 9]}, {"frames": [10, 19]}]
    assert m_full.get("segments") is None
    ate_full, ate_gap = m_full["slam"]["ate_rmse_m"], m_gap["slam"]["ate_rmse_m"]
    assert ate_gap <= 2 * ate_full, (ate_gap, ate_full)
    # without segments (the old behaviour) the prediction across the gap would be charged
    ate_bridged = np.sqrt(
        np.mean(np.sum((gap.poses[:, :3, 3] - gap.ground_truth[:, :3, 3]) ** 2, axis=1))
    )
    assert ate_bridged > ate_gap
    assert len(gap.poses) == 20 and len(gap.map_points()) > len(gap.slam.map_points())
