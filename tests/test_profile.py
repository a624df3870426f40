"""The per-stage profile of a frame (slamlib.slam3d.profile): every stage timed by its own time, the times adding
up to the frames' wall time, the filter left as it was."""

import time

import numpy as np
import pytest
from world3d import simulate, tiny_config

from slamlib.slam3d import ParticleSLAM3D, steps
from slamlib.slam3d.profile import STAGES, STEP_FUNCTIONS, StageProfile


def _profiled(config, frames, lidar_only=False):
    slam = ParticleSLAM3D(config)
    slam.register_frame(frames[0])
    profile = StageProfile()
    t0 = time.perf_counter()
    with profile.attached(slam):
        poses = [slam.register_frame(f) for f in frames[1:]]
    return slam, profile, poses, time.perf_counter() - t0


@pytest.mark.parametrize(
    "settings, timed, untimed",
    [
        ({}, {"read_motion", "weigh", "merge", "learn", "resample"}, {"anneal"}),
        (
            {"anneal_rounds": 2, "model": "constant_velocity"},
            {"anneal", "scan_match", "perturb", "weigh"},
            set(),
        ),
    ],
)
def test_every_stage_is_timed_by_its_own_time(settings, timed, untimed):
    """Over 7 frames: the stages the mode runs each have calls; the weighing runs once per frame plus once
    per annealing round (inside ``anneal``, counted under ``weigh``; LIDAR-only the start search's rounds too, and
    the start line's first weighing);
    the stages' own times add up to the frames' wall time (less the profile's overhead outside the frames)."""
    frames, _ = simulate(8)
    slam, profile, _, wall = _profiled(tiny_config(**settings), frames)
    assert profile.frames == 7
    assert set(profile.ms_per_frame()) == set(STAGES)
    for name in timed:
        assert profile.calls[name] >= 7, (name, profile.calls)
    for name in untimed:  # called each frame, with no round to run
        assert profile.calls[name] == 7
    # every annealing round weighs once (LIDAR-only, the start search's rounds too)
    rounds = settings.get("anneal_rounds", 0)
    assert slam.search.n_rounds >= 7 * rounds
    lines = slam.search.n_line_searches
    assert lines == int("model" in settings)  # LIDAR-only, one start
    assert profile.calls["weigh"] == 7 + slam.search.n_rounds + lines
    assert profile.calls["bookkeeping"] == 7
    assert all(s >= 0 for s in profile.seconds.values()), profile.seconds
    total = sum(profile.seconds.values())
    # all of the frames' time, less the loop's own around them (a wide margin: a shared machine may pause it)
    assert 0.8 * wall <= total <= wall
    assert sum(profile.ms_per_frame().values()) == pytest.approx(1e3 * total / 7)


def test_the_profile_changes_nothing_and_is_removed_after():
    """The profiled run gives the same poses as an unprofiled one with the same seed, and on leaving, the filter's
    methods and the step functions are the originals again."""
    frames, _ = simulate(6)
    originals = {name: getattr(steps, name) for name in STEP_FUNCTIONS}
    slam, _, poses, _ = _profiled(tiny_config(), frames)
    plain = ParticleSLAM3D(tiny_config())
    expected = [plain.register_frame(f) for f in frames][1:]
    np.testing.assert_array_equal(np.array(poses), np.array(expected))
    assert {name: getattr(steps, name) for name in STEP_FUNCTIONS} == originals
    for obj in (slam, slam.motion, slam.scan, slam.prior, slam.search):
        assert not any(getattr(v, "__wrapped__", None) for v in vars(obj).values())
    assert "register_frame" not in vars(slam) and "weigh" not in vars(slam)


def test_the_profile_needs_the_first_frame():
    """The stages that depend on the data exist only after the first frame: attaching before says so."""
    slam = ParticleSLAM3D(tiny_config())
    with pytest.raises(ValueError, match="first frame"):
        with StageProfile().attached(slam):
            pass


def test_an_attached_loop_closer_is_timed_as_its_own_stage():
    """With a loop closer attached, its frames and its final optimisation are ``loop_closure``'s calls, and the
    closer's methods are its own again after the block; without one, the stage stays at zero."""
    from slamlib.loops import LoopCloser

    frames, _ = simulate(6)
    slam = ParticleSLAM3D(tiny_config())
    closer = LoopCloser()
    closer.add_frame(0, slam.register_frame(frames[0]), slam.last["points"])
    profile = StageProfile()
    with profile.attached(slam, closer):
        for k, f in enumerate(frames[1:], start=1):
            closer.add_frame(k, slam.register_frame(f), slam.last["points"])
        closer.finish()
    assert profile.calls["loop_closure"] == 6  # 5 frames and the finish
    assert profile.seconds["loop_closure"] > 0
    assert profile.calls["bookkeeping"] == 5
    assert not any(getattr(v, "__wrapped__", None) for v in vars(closer).values())
    _, plain, _, _ = _profiled(tiny_config(), frames)
    assert plain.ms_per_frame()["loop_closure"] == 0.0
