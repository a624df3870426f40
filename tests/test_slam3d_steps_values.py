"""Value tests of :mod:`slamlib.slam3d.steps` that pin what mutation testing found unpinned (steps 1-11).

Each test states the formula or rule it pins; expected values are computed by hand in the test.
"""

import dataclasses
import re
from types import SimpleNamespace

import numpy as np
import pytest

from slamlib import geometry
from slamlib.kernels import get_backend
from slamlib.slam3d import steps
from slamlib.slam3d.config import MotionConfig, ScanConfig
from slamlib.slam3d.preprocess import deskew, sweep_times


def test_one_particle_is_enough_and_zero_particles_is_an_error_naming_the_count():
    """Step 1 accepts ``n_particles = 1`` (identity pose, log-weight ``-log 1 = 0``) and rejects 0 with
    ``need at least one particle, got 0``."""
    particles, log_w = steps.initialise_particles(1)
    np.testing.assert_array_equal(particles.R, np.eye(3)[None])
    np.testing.assert_array_equal(particles.t, np.zeros((1, 3)))
    np.testing.assert_array_equal(log_w, [0.0])
    with pytest.raises(ValueError, match=r"^need at least one particle, got 0$"):
        steps.initialise_particles(0)


def test_an_integer_start_pose_gives_float64_particles():
    """Step 1 casts ``pose0`` to float64: an all-integer pose (a quarter turn about z at (1, 2, 3)) gives float64
    ``R`` and ``t`` with those values."""
    pose0 = [[0, -1, 0, 1], [1, 0, 0, 2], [0, 0, 1, 3], [0, 0, 0, 1]]
    particles, _ = steps.initialise_particles(2, pose0)
    assert particles.R.dtype == np.float64 and particles.t.dtype == np.float64
    np.testing.assert_array_equal(
        particles.R, [[[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]] * 2
    )
    np.testing.assert_array_equal(particles.t, [[1.0, 2.0, 3.0]] * 2)


_NO_CROP = ScanConfig(min_range=0.0, max_range=np.inf, downsample_voxel=0.0)


def test_read_scan_takes_a_plain_float64_n_by_3_array_and_returns_float32():
    """Step 2 accepts a bare (N, 3) array (no ``.scan`` attribute) and returns float32 points even for float64
    input when no ``T_body_velo`` is given (no crop, no down-sampling: the same points)."""
    pts = np.array(
        [[1.0, 2.0, 3.0], [-4.0, 5.0, 0.5], [10.25, -7.5, 1.0]], dtype=np.float64
    )
    got = steps.read_scan(pts, _NO_CROP)
    assert got.dtype == np.float32 and got.shape == (3, 3) and got.flags.c_contiguous
    np.testing.assert_array_equal(got, pts.astype(np.float32))


def test_read_scan_down_samples_with_the_configured_voxel():
    """Step 2 keeps the first point of each ``downsample_voxel`` voxel (here 0.5 m: six points in three voxels keep
    three), after the range crop; with no voxel every point in range is kept."""
    pts = np.array(
        [
            [5.0, 0.1, 0.1],
            [5.2, 0.2, 0.3],
            [5.1, 0.4, 0.2],
            [7.1, 0.1, 0.1],
            [7.3, 0.3, 0.4],
            [9.0, 0.1, 0.1],
        ],
        dtype=np.float32,
    )
    got = steps.read_scan(
        pts, ScanConfig(min_range=1.0, max_range=100.0, downsample_voxel=0.5)
    )
    np.testing.assert_array_equal(got, pts[[0, 3, 5]])
    assert (
        len(
            steps.read_scan(
                pts, ScanConfig(min_range=1.0, max_range=100.0, downsample_voxel=0.0)
            )
        )
        == 6
    )


def test_read_scan_rejects_a_scan_with_five_columns_naming_its_shape():
    """A 2-D scan whose second axis is neither 3 nor 4 is a ``ValueError`` with the full message."""
    msg = "scan must have shape (N, 3) or (N, 4), got (4, 5)"
    with pytest.raises(ValueError, match="^" + re.escape(msg) + "$"):
        steps.read_scan(np.ones((4, 5), np.float32), _NO_CROP)


def test_read_imu_reshapes_and_casts_integer_samples_of_a_frame_without_index():
    """Step 3 on a frame with no ``index`` attribute: ``velocity``/``angular_rate`` given as (1, 3) integer lists
    come back as (3,) float64 arrays with those values."""
    frame = SimpleNamespace(velocity=[[1, 2, 3]], angular_rate=[[0, 0, 1]])
    v, w = steps.read_imu(frame)
    assert v.shape == (3,) and w.shape == (3,)
    assert v.dtype == np.float64 and w.dtype == np.float64
    np.testing.assert_array_equal(v, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(w, [0.0, 0.0, 1.0])


def test_read_imu_accepts_values_exactly_at_the_oxts_limits():
    """The limits are inclusive: ``|v| = 150`` m/s and ``|w| = 50`` rad/s pass; just beyond is an error."""
    v, w = steps.read_imu(
        SimpleNamespace(velocity=[150.0, -150.0, 0.0], angular_rate=[0.0, 50.0, -50.0])
    )
    np.testing.assert_array_equal(v, [150.0, -150.0, 0.0])
    np.testing.assert_array_equal(w, [0.0, 50.0, -50.0])
    with pytest.raises(ValueError):
        steps.read_imu(
            SimpleNamespace(velocity=[150.001, 0.0, 0.0], angular_rate=[0.0, 0.0, 0.0])
        )


def test_read_imu_error_messages_name_the_quantity_limit_unit_and_where():
    """Full messages: ``IMU velocity must be finite and within +-150 m/s, got [...]`` (no frame index: nothing
    after the name), ``... angular_rate ... +-50 rad/s ...``, and for an indexed frame with an estimate the name
    is followed by `` (frame 3) (constant-velocity estimate)``."""
    with pytest.raises(
        ValueError,
        match="^"
        + re.escape(
            "IMU velocity must be finite and within +-150 m/s, got [151.0, 0.0, 0.0]"
        )
        + "$",
    ):
        steps.read_imu(
            SimpleNamespace(velocity=[151.0, 0.0, 0.0], angular_rate=[0.0, 0.0, 0.0])
        )
    with pytest.raises(
        ValueError,
        match="^"
        + re.escape(
            "IMU angular_rate must be finite and within +-50 rad/s, got [0.0, 0.0, -51.0]"
        )
        + "$",
    ):
        steps.read_imu(
            SimpleNamespace(velocity=[1.0, 0.0, 0.0], angular_rate=[0.0, 0.0, -51.0])
        )
    frame = SimpleNamespace(
        index=3, velocity=[1.0, 0.0, 0.0], angular_rate=[0.0, 0.0, 0.0]
    )
    with pytest.raises(
        ValueError,
        match="^"
        + re.escape(
            "IMU velocity (frame 3) (constant-velocity estimate) must be finite and within +-150 m/s, "
            "got [200.0, 0.0, 0.0]"
        )
        + "$",
    ):
        steps.check_twist(
            [200.0, 0.0, 0.0],
            [0.0, 0.0, 0.0],
            steps.frame_label(frame) + " (constant-velocity estimate)",
        )


def test_read_imu_without_either_imu_value_is_the_lidar_only_error():
    """A frame missing ``angular_rate`` (None or no attribute) or ``velocity`` (no attribute), with no estimate,
    is the ``has no IMU values`` error, not a failed cast or an ``AttributeError``."""
    msg = "frame (frame 4) has no IMU values: LIDAR-only step 3 needs the filter's own motion estimate"
    for frame in (
        SimpleNamespace(index=4, velocity=[1.0, 0.0, 0.0], angular_rate=None),
        SimpleNamespace(index=4, velocity=[1.0, 0.0, 0.0]),
        SimpleNamespace(index=4, angular_rate=[0.0, 0.0, 0.1]),
        SimpleNamespace(index=4),
    ):
        with pytest.raises(ValueError, match="^" + re.escape(msg) + "$"):
            steps.read_imu(frame)


def test_read_timing_rejects_a_negative_dt_naming_it():
    """Step 4: a negative ``dt`` is ``frame dt must be finite and >= 0, got -0.1``."""
    with pytest.raises(
        ValueError,
        match="^" + re.escape("frame dt must be finite and >= 0, got -0.1") + "$",
    ):
        steps.read_timing(SimpleNamespace(dt=-0.1))


def test_offset_by_motion_uses_a_given_increment_instead_of_the_imu():
    """Step 5 with ``increment=(rpy, dp)`` moves by that increment, whatever ``imu`` says: from the identity, a
    quarter turn about z and 1 m forward gives ``R = Rz(90 deg)``, ``t = (1, 0, 0)`` (``T [dR, dp]``)."""
    particles, _ = steps.initialise_particles(2)
    still = (np.zeros(3), np.zeros(3))
    moved = steps.offset_by_motion(
        particles,
        still,
        0.1,
        increment=(np.array([0.0, 0.0, np.pi / 2]), np.array([1.0, 0.0, 0.0])),
    )
    np.testing.assert_allclose(
        moved.R, [[[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]] * 2, atol=1e-12
    )
    np.testing.assert_allclose(moved.t, [[1.0, 0.0, 0.0]] * 2, atol=1e-12)


_SIMPLE_MOTION = MotionConfig(
    sigma_xyz_per_m=(1.0, 2.0, 3.0),
    sigma_xyz_per_s=(0.0, 0.0, 0.0),
    sigma_rpy_per_m=(0.1, 0.2, 0.3),
    sigma_rpy_per_s=(0.0, 0.0, 0.0),
    cv_accel=(100.0, 200.0, 300.0),
    cv_angular_accel=(10.0, 20.0, 30.0),
    cv_start_speed=(1.0, 2.0, 3.0, 4.0, 5.0, 6.0),
)


def test_motion_noise_sigma_passes_the_midpoint_distance_and_both_flags_to_the_config():
    """``sigma = per_m |dp| + per_s dt (+ cv dt^2 if constant_velocity) (+ start_speed dt if start)``, ``dp``
    the midpoint-twist translation: from rest to 4 m/s over 0.5 s (no rotation) ``|dp| = 2 * 0.5 = 1`` m
    (4 * 0.5 = 2 m without the previous sample). Hand values with per_s = 0:
    constant_velocity only -> per_m + cv * 0.25; start only -> per_m + start_speed * 0.5."""
    imu, prev = (np.array([4.0, 0.0, 0.0]), np.zeros(3)), (np.zeros(3), np.zeros(3))
    cv = steps.motion_noise_sigma(
        imu, 0.5, prev, _SIMPLE_MOTION, constant_velocity=True, start=False
    )
    np.testing.assert_allclose(cv, [26.0, 52.0, 78.0, 2.6, 5.2, 7.8], rtol=1e-12)
    start = steps.motion_noise_sigma(
        imu, 0.5, prev, _SIMPLE_MOTION, constant_velocity=False, start=True
    )
    np.testing.assert_allclose(start, [1.5, 3.0, 4.5, 2.1, 2.7, 3.3], rtol=1e-12)
    held = steps.motion_noise_sigma(imu, 0.5, None, _SIMPLE_MOTION)
    np.testing.assert_allclose(held, [2.0, 4.0, 6.0, 0.2, 0.4, 0.6], rtol=1e-12)


def test_project_to_rotation_flips_the_smallest_singular_direction_of_a_reflection():
    """``project(diag(3, 2, -1))``: ``det(U V^T) = -1``, so ``D = diag(1, 1, -1)`` and the closest rotation is the
    identity (not the reflection ``diag(1, 1, -1)``)."""
    got = steps.project_to_rotation(np.diag([3.0, 2.0, -1.0]))
    np.testing.assert_allclose(got, np.eye(3), atol=1e-12)
    assert np.linalg.det(got) == pytest.approx(1.0)


def test_mean_estimate_averages_the_particles_within_half_a_metre_of_the_best_and_ignores_a_log_weight_shift():
    """Step 9 ``estimate="mean"`` with the default radius 0.5 m: particles at distance 0.5 (on the sphere, kept),
    0.45 (kept) and 0.75 (dropped) behind/below the best one at the origin; weights ``exp(log_w - log_w_best)``
    = (1, e^-1, e^-2) so a common shift of -500 in the log-weights changes nothing (no underflow).
    ``t = (e^-1 (0, 0, 0.5) + e^-2 (0, -0.45, 0)) / (1 + e^-1 + e^-2)``."""
    t = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.5], [0.0, -0.45, 0.0], [-0.75, 0.0, 0.0]])
    particles = steps.Particles3D(np.repeat(np.eye(3)[None], 4, axis=0), t)
    log_w = np.array([0.0, -1.0, -2.0, -0.5]) - 500.0
    pose, best = steps.pick_best_particle(particles, log_w, "mean")
    assert best == 0
    w = np.exp([0.0, -1.0, -2.0])
    expected_t = (
        w[1] * np.array([0.0, 0.0, 0.5]) + w[2] * np.array([0.0, -0.45, 0.0])
    ) / w.sum()
    np.testing.assert_allclose(pose[:3, 3], expected_t, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(pose[:3, :3], np.eye(3), atol=1e-12)


def test_unknown_estimate_is_an_error_naming_it():
    """Step 9 with ``estimate="median"``: ``estimate must be 'best' or 'mean', got 'median'``."""
    particles, log_w = steps.initialise_particles(2)
    with pytest.raises(
        ValueError,
        match="^" + re.escape("estimate must be 'best' or 'mean', got 'median'") + "$",
    ):
        steps.pick_best_particle(particles, log_w, "median")


class _Map:
    """A map stub that records what step 10 merges."""

    def __init__(self):
        self.merged = []

    def merge(self, points):
        self.merged.append(points)


def test_merge_scan_uses_the_given_backend_object():
    """Step 10 moves the scan with the ``backend`` it is given: a backend object whose ``transform_points``
    records its calls (and delegates to the NumPy reference) is called once, and the map gets ``R p + t``."""
    ref = get_backend("numpy")
    calls = []

    def spy(T, pts, out=None):
        calls.append(T)
        return ref.transform_points(T, pts, out=out)

    backend = dataclasses.replace(ref, name="spy", transform_points=spy)
    pose = geometry.make_pose(
        geometry.rpy_to_matrix([0.0, 0.0, np.pi / 2]), [1.0, 2.0, 3.0]
    )
    world_map = _Map()
    assert (
        steps.merge_scan(
            world_map, pose, np.array([[1.0, 0.0, 0.0]], np.float32), backend
        )
        is world_map
    )
    assert len(calls) == 1
    np.testing.assert_allclose(world_map.merged[0], [[1.0, 3.0, 3.0]], atol=1e-6)


def test_resample_particles_draws_with_the_backends_systematic_resample():
    """Step 11 takes the indexes from the backend's ``systematic_resample``: a backend whose sampler returns
    (2, 2, 0) makes the particles (2, 2, 0) of the input, with uniform log-weights ``-log 3``."""
    calls = []

    def sampler(w, u0):
        calls.append(u0)
        return np.array([2, 2, 0])

    backend = dataclasses.replace(
        get_backend("numpy"), name="spy", systematic_resample=sampler
    )
    t = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    particles = steps.Particles3D(np.repeat(np.eye(3)[None], 3, axis=0), t)
    out, log_w, resampled = steps.resample_particles(
        particles, np.log([0.1, 0.1, 0.8]), np.random.default_rng(0), None, backend
    )
    assert resampled and len(calls) == 1
    np.testing.assert_array_equal(out.t, t[[2, 2, 0]])
    np.testing.assert_allclose(log_w, np.full(3, -np.log(3.0)), rtol=1e-12)


def test_default_ess_fraction_is_one_half():
    """Step 11's default threshold is ``ESS < 0.5 P``: weights (0.4, 0.2, 0.2, 0.2) have ``ESS = 1 / 0.28 = 3.57``,
    not below 2 -> no resampling, the log-weights come back normalised (``log w``) and the particles unchanged."""
    particles, _ = steps.initialise_particles(4)
    log_w = np.log([0.4, 0.2, 0.2, 0.2]) + 7.0
    out, new_log_w, resampled = steps.resample_particles(
        particles, log_w, np.random.default_rng(0)
    )
    assert resampled is False and out is particles
    np.testing.assert_allclose(new_log_w, np.log([0.4, 0.2, 0.2, 0.2]), rtol=1e-12)


def test_weighted_mean_pose_normalises_float32_weights_in_float64():
    """``weighted_mean_pose`` casts the weights to float64 before ``w / sum w``: float32 weights (1, 2) on
    positions 0 and 3 m give exactly ``t = 2`` m (float32 ``2/3`` would give 2.00000006)."""
    R = np.repeat(np.eye(3)[None], 2, axis=0)
    pose = steps.weighted_mean_pose(
        R, np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0]]), np.array([1, 2], np.float32)
    )
    np.testing.assert_allclose(pose[:3, 3], [2.0, 0.0, 0.0], rtol=1e-15, atol=0)


def test_mean_estimate_exponentiates_float32_log_weights_in_float64():
    """Step 9 casts the log-weights to float64: float32 log-weights (0, -1) give the mean
    ``0.3 e^-1 / (1 + e^-1)`` to float64 precision (a float32 ``exp`` is off by ~1e-8 relative)."""
    t = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0]])
    particles = steps.Particles3D(np.repeat(np.eye(3)[None], 2, axis=0), t)
    pose, best = steps.pick_best_particle(
        particles, np.array([0.0, -1.0], np.float32), "mean"
    )
    assert best == 0
    e = np.exp(-1.0)
    np.testing.assert_allclose(
        pose[:3, 3], [0.3 * e / (1.0 + e), 0.0, 0.0], rtol=1e-14, atol=0
    )


def test_deskew_scan_moves_a_one_point_scan_and_casts_an_empty_float64_scan():
    """``deskew_scan`` short-cuts only the empty scan: a single point 10 m to the left (azimuth 90 deg, fired a
    quarter sweep early) moves by ``deskew`` with its firing time ``sweep_times``; an empty float64 (0, 3) scan
    comes back as float32."""
    pts = np.array([[0.0, 10.0, 0.5]], np.float32)
    imu = (np.array([10.0, 0.0, 0.0]), np.zeros(3))
    times = sweep_times(pts, 0.1)
    assert times[0] == pytest.approx(-0.025)
    got = steps.deskew_scan(pts, imu, ScanConfig(sweep_period=0.1))
    np.testing.assert_array_equal(got, deskew(pts, *imu, times))
    np.testing.assert_allclose(
        got, [[-0.25, 10.0, 0.5]], atol=1e-5
    )  # 10 m/s * -0.025 s along x
    empty = steps.deskew_scan(np.zeros((0, 3)), imu, ScanConfig())
    assert empty.dtype == np.float32 and empty.shape == (0, 3)


def test_project_to_rotation_of_a_float32_matrix_is_computed_in_float64():
    """``project_to_rotation`` casts to float64 before the SVD: a float32 matrix gives the polar factor of its
    float64 copy (``scipy.linalg.polar``, the closest orthogonal matrix, here with det +1) to 1e-12, not the
    ~1e-7 of a float32 SVD."""
    from scipy.linalg import polar

    M = np.array([[0.9, -0.3, 0.1], [0.35, 0.8, -0.2], [-0.05, 0.25, 1.1]], np.float32)
    expected, _ = polar(M.astype(np.float64))
    assert np.linalg.det(expected) > 0
    got = steps.project_to_rotation(M)
    assert got.dtype == np.float64
    np.testing.assert_allclose(got, expected, atol=1e-12)


def test_read_scan_time_offset_reads_the_frame_or_zero_and_rejects_the_impossible():
    assert (
        steps.read_scan_time_offset(SimpleNamespace(scan_time_offset_s=-0.0171))
        == -0.0171
    )
    assert (
        steps.read_scan_time_offset(SimpleNamespace()) == 0.0
    )  # odometry layout, simulated frames
    for bad in (float("nan"), 0.2, -0.11):
        with pytest.raises(
            ValueError,
            match=r"scan time offset \(frame 3\) must be finite and within one sweep",
        ):
            steps.read_scan_time_offset(SimpleNamespace(scan_time_offset_s=bad, index=3))
    assert (
        steps.read_scan_time_offset(
            SimpleNamespace(scan_time_offset_s=0.15), ScanConfig(sweep_period=0.2)
        )
        == 0.15
    )
