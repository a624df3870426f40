"""The 1D steps called as the contract of :mod:`slamlib.contract` says (tests/test_contract.py checks the
signatures)."""

import numpy as np

import slamlib.sim1d.steps as s
from slamlib.contract import STEPS
from slamlib.sim1d import OccupancyGrid1D, make_world, simulate


def test_every_step_is_exported_by_sim1d():
    import slamlib.sim1d as pkg

    for spec in STEPS:
        assert getattr(pkg, spec.name) is getattr(s, spec.name)
        assert spec.name in s.__all__


def test_shared_parameter_calls_work():
    """Each step called with the contract's parameters alone (extras left at their defaults) gives its result."""
    rec = simulate(make_world(seed=0), n_frames=3, seed=0)
    frame = rec.frames[1]
    p, lw = s.initialise_particles(5)  # 1
    assert p.shape == lw.shape == (5,) and abs(np.logaddexp.reduce(lw)) < 1e-12
    p0, _ = s.initialise_particles(5, 1.5)
    np.testing.assert_array_equal(p0, 1.5)
    points = s.read_scan(frame)  # 2
    imu = s.read_imu(frame)  # 3
    dt = s.read_timing(frame)  # 4
    assert points.ndim == 1 and isinstance(imu, float) and isinstance(dt, float)
    moved = s.offset_by_motion(p, 1.0, 0.1)  # 5
    np.testing.assert_allclose(moved, 0.1)
    moved = s.perturb_with_noise(moved, 0.01, np.random.default_rng(0))  # 6
    assert moved.shape == (5,)
    assert s.transform_scan(moved, points).shape == (5, points.size)  # 7
    assert s.transform_scan(float(moved[0]), points).shape == (points.size,)
    world_map = OccupancyGrid1D.empty(-20.0, 20.0, 0.05)
    assert s.merge_scan(world_map, 0.0, points) is world_map  # 10
    assert world_map.total > 0
    scores = s.score_particles(moved, points, world_map)  # 8
    assert scores.shape == (5,) and np.all(np.isfinite(scores))
    pose, index = s.pick_best_particle(p, lw)  # 9, shared parameters only
    assert (
        (pose, index) == (0.0, 0) and isinstance(pose, float) and isinstance(index, int)
    )
    pose, index = s.pick_best_particle(moved, lw + scores)
    assert isinstance(pose, float) and isinstance(index, int) and pose == moved[index]
    out = s.resample_particles(moved, lw + scores, np.random.default_rng(0))  # 11
    particles, log_weights, resampled = out
    assert particles.shape == log_weights.shape == (5,) and isinstance(resampled, bool)
    assert abs(np.logaddexp.reduce(log_weights)) < 1e-12
