"""Self-tuning motion (slamlib.slam3d.stages.tuning): the innovation, the fit of scale errors and biases, the spread."""

import numpy as np
import pytest

from slamlib.geometry import matrix_to_rpy, rpy_to_matrix
from slamlib.slam3d.stages.tuning import (
    FixedSpread,
    SelfTuning,
    innovation_model,
    innovation_update,
    motion_innovation,
)

DT = 0.1


def test_the_innovation_is_zero_for_the_predicted_motion_and_the_offset_otherwise():
    rpy, dp = np.array([0.01, -0.02, 0.3]), np.array([1.2, 0.1, -0.05])
    assert np.allclose(motion_innovation((rpy, dp), (rpy, dp)), 0.0, atol=1e-15)
    # a measured motion that turned 2 mrad more in yaw after the predicted rotation, and moved 3 cm farther
    extra = np.array([0.0, 0.0, 0.002])
    R_m = rpy_to_matrix(rpy) @ rpy_to_matrix(extra)
    e = motion_innovation((matrix_to_rpy(R_m), dp + [0.03, 0, 0]), (rpy, dp))
    assert np.allclose(e, [0.03, 0, 0, 0, 0, 0.002], atol=1e-12)


def test_the_update_adds_each_axis_row_with_forgetting():
    info, eta = np.zeros((6, 2, 2)), np.zeros((6, 2))
    H = innovation_model(np.arange(6.0), DT)
    assert np.allclose(H[:, 1], DT) and np.allclose(H[:, 0], np.arange(6.0))
    e = np.ones(6)
    info, eta = innovation_update(info, eta, H, e, 0.5)
    info, eta = innovation_update(info, eta, H, e, 0.5)
    # 0.5 * (h h^T) + h h^T
    assert np.allclose(info[3], 1.5 * np.outer(H[3], H[3]))
    assert np.allclose(eta[3], 1.5 * H[3])


def _planted(rng, n, scale, bias, scatter):
    """``n`` frames of increments ``u`` (a car at 5-15 m/s turning a little) and innovations
    ``e = scale u + bias dt + N(0, scatter^2)``."""
    for _ in range(n):
        u = np.concatenate(
            [
                [rng.uniform(0.5, 1.5), rng.normal(0, 0.02), rng.normal(0, 0.01)],
                rng.normal(0, [0.002, 0.002, 0.02]),
            ]
        )
        e = scale * u + bias * DT + rng.normal(0, scatter)
        yield u, e


def _learn(tuning, frames):
    for u, e in frames:
        predicted = (u[3:], u[:3])
        # the measured increment that has this innovation against the prediction
        R_m = rpy_to_matrix(u[3:]) @ rpy_to_matrix(e[3:])
        tuning.learn(predicted, (matrix_to_rpy(R_m), u[:3] + e[:3]), DT)


def test_a_planted_scale_error_bias_and_scatter_are_learnt():
    """The forward scale error (1.5 %), the lateral velocity bias (3 cm/s) and the yaw-rate bias (3 mrad/s) of
    the synthetic IMU, and a scatter of 5 mm / 0.2 mrad per frame: recovered from 600 frames."""
    rng = np.random.default_rng(3)
    scale = np.array([-0.015, 0, 0, 0, 0, 0])
    bias = np.array([0, -0.03, 0, 0, 0, -0.003])
    scatter = np.array([0.005, 0.005, 0.005, 2e-4, 2e-4, 2e-4])
    # a long noise memory (20 s), so that the scatter is measured to ~10 %
    tuning = SelfTuning(
        memory=30.0, noise_memory=20.0, gain=2.0, floor=np.zeros(6), warmup=20
    )
    _learn(tuning, _planted(rng, 600, scale, bias, scatter))
    assert tuning.ready and tuning.frames == 600
    assert tuning.scale[0] == pytest.approx(-0.015, abs=0.003)
    assert tuning.bias[1] == pytest.approx(-0.03, abs=0.005)
    assert tuning.bias[5] == pytest.approx(-0.003, abs=3e-4)
    # the spread is the gain times the residual scatter, within the sampling error of ~200 frames
    assert np.allclose(tuning.spread(np.ones(6)), 2 * scatter, rtol=0.3)
    # the correction moves the increment by the learnt errors
    u = np.array([1.0, 0, 0, 0, 0, 0.01])
    rpy, dp = tuning.correct((u[3:], u[:3]), DT)
    assert dp[0] == pytest.approx(1.0 - 0.015, abs=0.003)
    assert rpy[2] == pytest.approx(0.01 - 0.0003, abs=3e-5)


def test_the_filters_own_jitter_is_taken_out_of_the_sources_scatter():
    """Innovations ``e_k = n_k + eps_k - eps_{k-1}``: the source's white noise ``n`` (1 cm) and a pose jitter ``eps``
    (1 cm) that enters each frame's increment twice. The residuals' mean square holds both, ``1 + 2`` cm^2; the
    source's variance, with the product of consecutive residuals, only the source's."""
    rng = np.random.default_rng(4)
    n, eps = rng.normal(0, 0.01, (3000, 6)), rng.normal(0, 0.01, (3001, 6))
    innovations = n + eps[1:] - eps[:-1]
    tuning = SelfTuning(30.0, 60.0, 1.0, np.zeros(6), warmup=1)
    _learn(
        tuning,
        ((np.zeros(6), e) for e in innovations),
    )
    assert np.allclose(tuning.mean_square[:3], 3 * 0.01**2, rtol=0.2)
    assert np.allclose(tuning.source_variance[:3], 0.01**2, rtol=0.4)
    assert np.all(tuning.source_variance[:3] < 0.5 * tuning.mean_square[:3])


def test_before_the_warm_up_the_configured_spread_and_the_raw_increment_stand():
    rng = np.random.default_rng(0)
    tuning = SelfTuning(30.0, 5.0, 2.0, np.full(6, 1e-3), warmup=20)
    _learn(tuning, _planted(rng, 19, np.zeros(6), np.full(6, 0.1), np.full(6, 0.01)))
    configured = np.arange(1.0, 7.0)
    assert not tuning.ready
    assert np.array_equal(tuning.spread(configured), configured)
    inc = (np.zeros(3), np.ones(3))
    assert tuning.correct(inc, DT) is inc
    _learn(tuning, _planted(rng, 1, np.zeros(6), np.full(6, 0.1), np.full(6, 0.01)))
    assert tuning.ready and not np.array_equal(tuning.spread(configured), configured)


def test_an_exact_source_keeps_the_floor_and_a_worse_one_widens_the_spread():
    rng = np.random.default_rng(1)
    floor = np.array([0.005, 0.005, 0.005, 3e-4, 3e-4, 5e-4])
    exact = SelfTuning(30.0, 5.0, 2.0, floor, warmup=20)
    _learn(exact, _planted(rng, 100, np.zeros(6), np.zeros(6), np.zeros(6)))
    assert np.allclose(exact.spread(np.ones(6)), floor)
    noisy = SelfTuning(30.0, 5.0, 2.0, floor, warmup=20)
    _learn(noisy, _planted(rng, 100, np.zeros(6), np.zeros(6), 10 * floor))
    late = noisy.spread(np.ones(6))
    assert np.all(late > 10 * floor)
    # the errors grow fourfold: within the noise memory (5 s = 50 frames) the spread follows
    _learn(noisy, _planted(rng, 100, np.zeros(6), np.zeros(6), 40 * floor))
    assert np.all(noisy.spread(np.ones(6)) > 2 * late)


def test_the_bias_is_not_corrected_where_the_source_has_none():
    rng = np.random.default_rng(2)
    held = SelfTuning(30.0, 5.0, 2.0, np.zeros(6), warmup=5, correct_bias=False)
    _learn(held, _planted(rng, 50, np.zeros(6), np.full(6, 0.05), np.full(6, 0.01)))
    inc = (np.zeros(3), np.ones(3))
    assert held.correct(inc, DT) is inc and held.ready


def test_fixed_spread_is_the_null_form():
    fixed = FixedSpread()
    inc = (np.zeros(3), np.ones(3))
    assert fixed.correct(inc, DT) is inc
    assert np.array_equal(fixed.spread([1, 2, 3, 4, 5, 6]), [1, 2, 3, 4, 5, 6])
    fixed.learn(inc, inc, DT)
    assert not fixed.ready


def test_the_filter_learns_its_imus_scale_error_and_yaw_rate_bias():
    """The small test drive's IMU reads the speed 6 % high and the yaw rate 0.06 rad/s high: after 80 frames the
    motion stage's fit corrects the forward and the yaw increments by those errors, and the filter with
    self-tuning off learns nothing. The drive keeps one speed and one yaw rate, so the fit cannot tell a scale
    error from a bias (``s u + b dt`` with ``u`` constant): only their sum at that speed is fixed."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from world3d import simulate, tiny_config

    from slamlib.slam3d import ParticleSLAM3D

    frames, _ = simulate(80, yaw_rate=0.3)
    slam = ParticleSLAM3D(tiny_config())
    for f in frames:
        slam.register_frame(f)
    tuning = slam.motion.tuning
    assert (
        tuning.frames == len(frames) - 1
    )  # every frame but the first, which only starts the map
    # -0.06 / 1.06 of the measured 5.3 m/s over 0.1 s: -0.028 m per frame; -0.06 rad/s of the measured 0.36
    # rad/s: -0.006 rad per frame
    u, w = 5.0 * 1.06 * 0.1, (0.3 + 0.06) * 0.1
    assert -0.04 < tuning.scale[0] * u + tuning.bias[0] * 0.1 < -0.02
    assert -0.0075 < tuning.scale[5] * w + tuning.bias[5] * 0.1 < -0.0045
    fixed = ParticleSLAM3D(tiny_config(self_tuning=False))
    for f in frames:
        fixed.register_frame(f)
    assert isinstance(fixed.motion.tuning, FixedSpread)
    # dead reckoning stays the IMU's own: the corrections are the filter's, not the baseline's
    np.testing.assert_array_equal(slam.dead_reckoning, fixed.dead_reckoning)
