"""Whole drives and their results (:mod:`slamlib.slam3d.run`): ``run_drive``, the frame selection of ``--frames``."""

import numpy as np
import pytest
from world3d import tiny_config

from slamlib.metrics import absolute_trajectory_error
from slamlib.slam3d import parse_frames, run_drive


def test_refine_and_bvh_map_also_track(drive):
    frames, gt = drive
    run = run_drive(
        frames[:15],
        tiny_config(kind="morton_bvh", params={}, refine=1, estimate="mean"),
        progress=False,
    )
    assert run.ground_truth is not None and np.allclose(run.ground_truth, gt[:15])
    ate_slam = absolute_trajectory_error(run.poses, run.ground_truth).rmse
    ate_dr = absolute_trajectory_error(run.dead_reckoning, run.ground_truth).rmse
    assert ate_slam < ate_dr / 2


def test_parse_frames():
    assert parse_frames("10:20") == slice(10, 20)
    assert parse_frames("5:") == slice(5, None)
    assert parse_frames("30") == slice(0, 30)
    assert parse_frames(None) is None
    for bad in ("a:b", "20:10", "-3:5"):
        with pytest.raises(ValueError):
            parse_frames(bad)
    with pytest.raises(ValueError):
        parse_frames("100:200", n=50)
