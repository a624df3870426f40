"""Value tests of ``ParticleSLAM3D.register_frame`` that pin what mutation testing of slamlib.slam3d left unpinned.

Each test builds a tiny filter (20 particles, a few hundred points) and compares against values computed
independently with the step functions or by hand.
"""

from types import SimpleNamespace

import numpy as np

from slamlib import geometry
from slamlib.slam3d import steps
from slamlib.slam3d.config import FilterConfig, MotionConfig, ScanConfig, SLAM3DConfig
from slamlib.slam3d.pipeline import MIN_SCAN_POINTS, ParticleSLAM3D


def _scan(n=300, seed=0):
    rng = np.random.default_rng(seed)
    az = rng.uniform(-np.pi, np.pi, n)
    r = rng.uniform(5.0, 30.0, n)
    xyz = np.column_stack([r * np.cos(az), r * np.sin(az), rng.uniform(-1.5, 1.0, n)])
    return np.column_stack([xyz, np.zeros(n)]).astype(np.float32)


def _frame(scan, v=(10.0, 0.0, 0.0), w=(0.0, 0.0, 0.1), dt=0.1):
    return SimpleNamespace(
        scan=scan, velocity=np.array(v, float), angular_rate=np.array(w, float), dt=dt
    )


def _config(**kw):
    return SLAM3DConfig(filter=FilterConfig(particles=20, scored_points=100), **kw)


def _sorted(points):
    p = np.asarray(points, dtype=np.float64)
    return p[np.lexsort(p.T[::-1])]


def _map_of(config, points):
    m = config.map.make()
    steps.merge_scan(m, np.eye(4), points, "cpu")
    return _sorted(m.points())


def test_constant_velocity_model_is_lidar_only_even_when_the_frame_has_an_imu():
    """``MotionConfig(model="constant_velocity")``: a frame WITH IMU values still makes the filter LIDAR-only (no
    dead-reckoning twin, ``lidar_only`` True); the default model with IMU values is not LIDAR-only."""
    scan = _scan()
    cv = ParticleSLAM3D(_config(motion=MotionConfig(model="constant_velocity")))
    cv.register_frame(_frame(scan))
    assert cv.lidar_only is True and cv.dead_reckoning is None
    imu = ParticleSLAM3D(_config())
    imu.register_frame(_frame(scan))
    assert imu.lidar_only is False and imu.dead_reckoning.shape == (1, 4, 4)


def test_a_frame_without_a_velocity_attribute_makes_the_filter_lidar_only():
    """A first frame object that has no ``velocity`` attribute at all (KITTI odometry layout) is LIDAR-only."""
    slam = ParticleSLAM3D(_config())
    slam.register_frame(SimpleNamespace(scan=_scan(), dt=0.1))
    assert slam.lidar_only is True and slam.dead_reckoning is None


def test_first_frame_merges_the_scan_moved_into_the_body_frame():
    """``read_scan`` gets ``T_body_velo = inv(T_velo_imu)``: the first frame's map is the cropped scan moved by
    ``T_body_velo`` (written out here: ``R p + t``), merged at the identity start pose."""
    scan = _scan()
    T_velo_imu = geometry.make_pose(
        geometry.rpy_to_matrix([0.0, 0.0, 0.7]), [2.0, -1.0, 0.5]
    )
    config = SLAM3DConfig(
        filter=FilterConfig(particles=20), scan=ScanConfig(downsample_voxel=0.0)
    )
    slam = ParticleSLAM3D(config, T_velo_imu=T_velo_imu)
    slam.register_frame(_frame(scan))
    T = np.linalg.inv(T_velo_imu)
    body = (scan[:, :3].astype(np.float64) @ T[:3, :3].T + T[:3, 3]).astype(np.float32)
    expected = _map_of(config, body)
    np.testing.assert_array_equal(_sorted(slam.map_points()), expected)
    unmoved = _map_of(config, scan[:, :3])
    assert expected.shape != unmoved.shape or np.abs(expected - unmoved).max() > 0.5


def test_deskew_config_deskews_the_scan_with_the_frames_imu_before_merging():
    """``ScanConfig(deskew=True)``: the first frame merges ``steps.deskew_scan(points, (v, w), cfg.scan,
    T_body_velo)`` of the body-frame points, with the frame's own velocity and angular rate."""
    scan = _scan()
    T_velo_imu = geometry.make_pose(
        geometry.rpy_to_matrix([0.0, 0.0, 1.2]), [0.8, -0.3, 1.7]
    )
    T = np.linalg.inv(T_velo_imu)
    sc = ScanConfig(downsample_voxel=0.0, deskew=True, sweep_period=0.1)
    config = SLAM3DConfig(filter=FilterConfig(particles=20), scan=sc)
    frame = _frame(scan, v=(12.0, 0.5, 0.0), w=(0.0, 0.0, 0.3))
    slam = ParticleSLAM3D(config, T_velo_imu=T_velo_imu)
    slam.register_frame(frame)
    body = steps.read_scan(frame, sc, T)
    expected = steps.deskew_scan(body, (frame.velocity, frame.angular_rate), sc, T)
    np.testing.assert_array_equal(_sorted(slam.map_points()), _map_of(config, expected))
    assert (
        np.abs(_sorted(expected) - _sorted(body)).max() > 0.05
    )  # de-skewing moved the points
    no_t = steps.deskew_scan(body, (frame.velocity, frame.angular_rate), sc)
    assert np.abs(no_t - expected).max() > 1e-3  # the mounting matters


def test_default_deskew_follows_the_frames_sweep():
    """``ScanConfig.deskew`` None (the default) de-skews a frame whose ``swept`` is true, as ``deskew=True`` does,
    and merges a frame with ``swept`` false (or none) as ``deskew=False``; ``n_deskewed`` counts the frames."""
    scan = _scan()
    frame = _frame(scan, v=(12.0, 0.5, 0.0), w=(0.0, 0.0, 0.3))
    maps = {}
    for name, deskew, swept in (
        ("auto swept", None, True),
        ("on", True, False),
        ("auto still", None, False),
        ("off", False, True),
    ):
        config = SLAM3DConfig(
            filter=FilterConfig(particles=20),
            scan=ScanConfig(downsample_voxel=0.0, deskew=deskew),
        )
        slam = ParticleSLAM3D(config)
        frame.swept = swept
        slam.register_frame(frame)
        maps[name] = (_sorted(slam.map_points()), slam.n_deskewed)
    np.testing.assert_array_equal(maps["auto swept"][0], maps["on"][0])
    np.testing.assert_array_equal(maps["auto still"][0], maps["off"][0])
    assert (
        maps["on"][0].shape != maps["off"][0].shape
        or np.abs(maps["on"][0] - maps["off"][0]).max() > 0.05
    )
    assert [maps[k][1] for k in ("auto swept", "on", "auto still", "off")] == [1, 1, 0, 0]


def test_deskew_goes_to_the_pose_time_of_the_frame():
    """A frame with ``scan_time_offset_s`` (its scan stamped before its pose, as KITTI raw frames are) is de-skewed to
    the pose's time: the first frame merges ``deskew_scan(..., time_offset=frame.scan_time_offset_s)``."""
    scan = _scan()
    sc = ScanConfig(downsample_voxel=0.0, deskew=True, sweep_period=0.1)
    config = SLAM3DConfig(filter=FilterConfig(particles=20), scan=sc)
    frame = _frame(scan, v=(12.0, 0.5, 0.0), w=(0.0, 0.0, 0.3))
    frame.scan_time_offset_s = -0.02
    slam = ParticleSLAM3D(config)
    slam.register_frame(frame)
    body = steps.read_scan(frame, sc, None)
    expected = steps.deskew_scan(
        body, (frame.velocity, frame.angular_rate), sc, None, -0.02
    )
    np.testing.assert_array_equal(_sorted(slam.map_points()), _map_of(config, expected))
    at_stamp = steps.deskew_scan(body, (frame.velocity, frame.angular_rate), sc)
    assert np.abs(_sorted(expected) - _sorted(at_stamp)).max() > 0.2  # 12 m/s x 20 ms


def test_second_imu_frame_gets_the_ordinary_sigma_not_the_lidar_only_start_search():
    """In IMU mode the second frame's step-6 spread is ``motion.sigma(increment[1], dt, False, False)``
    (``start = lidar_only and len(poses) == 1`` is False), not the wide constant-velocity start spread."""
    scan = _scan()
    config = _config()
    slam = ParticleSLAM3D(config)
    f1, f2 = _frame(scan), _frame(scan, v=(11.0, 0.2, 0.0), w=(0.0, 0.01, 0.12), dt=0.1)
    slam.register_frame(f1)
    slam.register_frame(f2)
    imu1 = (f1.velocity, f1.angular_rate)
    inc = steps.motion_increment((f2.velocity, f2.angular_rate), 0.1, imu1)
    np.testing.assert_array_equal(
        slam.last["sigma"], config.motion.sigma(inc[1], 0.1, False, False)
    )
    assert not np.allclose(
        slam.last["sigma"], config.motion.sigma(inc[1], 0.1, False, True)
    )


def test_a_scan_of_exactly_min_scan_points_is_merged_and_scored():
    """A scan of exactly ``MIN_SCAN_POINTS`` points (after the crop) is not degenerate: the first frame merges it
    and the second frame is scored (``last['scores']`` has one score per particle), none skipped."""
    n = MIN_SCAN_POINTS
    ang = np.arange(n) * 2 * np.pi / n
    scan = np.column_stack(
        [10 * np.cos(ang), 10 * np.sin(ang), np.zeros(n), np.zeros(n)]
    ).astype(np.float32)
    config = SLAM3DConfig(
        filter=FilterConfig(particles=20), scan=ScanConfig(downsample_voxel=0.0)
    )
    slam = ParticleSLAM3D(config)
    slam.register_frame(_frame(scan))
    assert slam.n_skipped_frames == 0 and len(slam.map_points()) == n
    slam.register_frame(_frame(scan))
    assert slam.n_skipped_frames == 0 and slam.last["scores"].shape == (20,)
    assert len(slam.last["sample"]) == n
    short = ParticleSLAM3D(config)
    short.register_frame(_frame(scan[: n - 1]))
    assert short.n_skipped_frames == 1 and len(short.map_points()) == 0


def test_lidar_only_second_frame_sigma_is_the_constant_velocity_start_spread():
    """LIDAR-only the second frame's spread is ``motion.sigma(increment[1], dt, True, True)`` with the increment of
    the zero own motion (``constant_velocity`` is passed as True, the start search is on)."""
    scan = _scan()
    config = _config(motion=MotionConfig(model="constant_velocity"))
    slam = ParticleSLAM3D(config)
    slam.register_frame(_frame(scan))
    slam.register_frame(_frame(scan))
    inc = steps.motion_increment((np.zeros(3), np.zeros(3)), 0.1, None)
    np.testing.assert_array_equal(
        slam.last["sigma"], config.motion.sigma(inc[1], 0.1, True, True)
    )
    assert not np.allclose(
        slam.last["sigma"], config.motion.sigma(inc[1], 0.1, False, True)
    )


def test_a_map_of_one_voxel_is_scored_against():
    """Only an EMPTY map skips scoring: a first scan of ``MIN_SCAN_POINTS`` points inside one voxel makes a map of
    one element, and the second frame is scored (one score per particle) and not skipped."""
    rng = np.random.default_rng(3)
    n = MIN_SCAN_POINTS
    scan = np.column_stack([10.05 + rng.uniform(0, 0.01, (n, 3)), np.zeros(n)]).astype(
        np.float32
    )
    config = SLAM3DConfig(
        filter=FilterConfig(particles=20), scan=ScanConfig(downsample_voxel=0.0)
    )
    slam = ParticleSLAM3D(config)
    slam.register_frame(_frame(scan, v=(0, 0, 0), w=(0, 0, 0)))
    assert len(slam.map) == 1
    slam.register_frame(_frame(scan, v=(0, 0, 0), w=(0, 0, 0)))
    assert (
        slam.n_skipped_frames == 0
        and slam.last["scores"].shape == (20,)
        and slam.last["best"] is not None
    )


def test_a_skipped_frame_keeps_its_imu_sample_and_sigma():
    """A degenerate (empty) second frame still records its IMU sample as ``imu_prev`` (the next frame's increment
    starts from it) and its step-6 ``sigma`` in ``last``; the third frame is then not taken for a first frame."""
    scan = _scan()
    config = _config()
    slam = ParticleSLAM3D(config)
    f1 = _frame(scan)
    f2 = _frame(np.zeros((0, 4), np.float32), v=(9.0, 0.1, 0.0), w=(0.0, 0.0, 0.2))
    slam.register_frame(f1)
    slam.register_frame(f2)
    assert slam.n_skipped_frames == 1
    np.testing.assert_array_equal(slam.imu_prev[0], f2.velocity)
    np.testing.assert_array_equal(slam.imu_prev[1], f2.angular_rate)
    inc = steps.motion_increment(
        (f2.velocity, f2.angular_rate), 0.1, (f1.velocity, f1.angular_rate)
    )
    np.testing.assert_array_equal(
        slam.last["sigma"], config.motion.sigma(inc[1], 0.1, False, False)
    )
    slam.register_frame(_frame(scan))
    assert len(slam.poses) == 3 and len(slam.dead_reckoning) == 3


def test_imu_mode_scores_every_point_without_ground_thinning():
    """With an IMU the pool is the whole scan (no ``thin_ground``): ``scored_points`` above the scan size samples
    every point in input order, so ``last['sample']`` and ``last['points']`` are the step-2 points."""
    scan = _scan()
    scan[:150, 2] = -1.7  # a flat road for thin_ground to thin
    config = SLAM3DConfig(
        filter=FilterConfig(particles=20, scored_points=10_000),
        scan=ScanConfig(downsample_voxel=0),
    )
    slam = ParticleSLAM3D(config)
    slam.register_frame(_frame(scan))
    slam.register_frame(_frame(scan))
    points = steps.read_scan(scan, config.scan)
    np.testing.assert_array_equal(slam.last["points"], points)
    np.testing.assert_array_equal(slam.last["sample"], points)


def test_configured_mean_estimate_is_used_for_the_pose():
    """``FilterConfig(estimate="mean")`` reaches step 9: the pose is ``pick_best_particle(moved, log_w, "mean")``,
    not the best particle's pose (checked with ``ess_fraction=0``: no resampling, ``particles`` are the moved)."""
    scan = _scan()
    for estimate in ("best", "mean"):
        config = SLAM3DConfig(
            filter=FilterConfig(particles=20, estimate=estimate, ess_fraction=0.0)
        )
        slam = ParticleSLAM3D(config)
        slam.register_frame(_frame(scan))
        pose = slam.register_frame(_frame(scan))
        p, i = slam.particles, slam.last["best"]
        expected, _ = steps.pick_best_particle(p, slam.log_weights, estimate)
        np.testing.assert_allclose(pose, expected, atol=1e-12)
        best_pose = geometry.make_pose(p.R[i], p.t[i])
        assert np.allclose(pose, best_pose) == (estimate == "best")


def test_step_11_counts_resamplings_with_the_configured_ess_fraction():
    """Step 11 uses ``FilterConfig.ess_fraction`` and ``n_resampled`` accumulates: ``ess_fraction=1`` resamples
    whenever ESS < P (at least 2 of the 3 scored frames; a non-accumulating count would be at most 1),
    ``ess_fraction=0`` never (0)."""
    scan = _scan()
    for frac, at_least, at_most in ((1.0, 2, 3), (0.0, 0, 0)):
        slam = ParticleSLAM3D(
            SLAM3DConfig(filter=FilterConfig(particles=20, ess_fraction=frac))
        )
        for _ in range(4):
            slam.register_frame(_frame(scan))
        assert at_least <= slam.n_resampled <= at_most


# ------------------------------------------------------------------ pipeline survivors, second pass
def _ten_points():
    """Exactly MIN_SCAN_POINTS returns, each in its own voxel and inside [min_range, max_range]."""
    x = 5.0 + 2.0 * np.arange(MIN_SCAN_POINTS)
    return np.column_stack(
        [x, np.zeros_like(x), np.zeros_like(x), np.zeros_like(x)]
    ).astype(np.float32)


def test_a_fresh_filter_has_default_config_zero_counters_and_the_model_lidar_only_flag():
    """``ParticleSLAM3D()`` builds with the default config; counters start at 0; ``lidar_only`` is set from
    ``MotionConfig.model`` already at construction (True for constant velocity, False for the IMU model)."""
    slam = ParticleSLAM3D()
    assert slam.config == SLAM3DConfig()
    assert slam.n_resampled == 0 and slam.n_skipped_frames == 0
    assert slam.lidar_only is False
    assert (
        ParticleSLAM3D(_config(motion=MotionConfig(model="constant_velocity"))).lidar_only
        is True
    )


def test_given_T0_and_calibration_are_stored_and_place_the_particles():
    """``T0`` (given as integers) is stored as float64 and every particle starts there; ``T_velo_imu`` is stored
    inverted as ``T_body_velo``."""
    T0 = np.eye(4, dtype=np.int64)
    T0[:3, 3] = [3, -2, 1]
    T_velo_imu = geometry.make_pose(
        geometry.rpy_to_matrix([0.0, 0.0, 0.7]), [2.0, -1.0, 0.5]
    )
    slam = ParticleSLAM3D(_config(), T_velo_imu=T_velo_imu, T0=T0)
    assert slam.T0.dtype == np.float64
    np.testing.assert_array_equal(slam.T0, T0.astype(np.float64))
    np.testing.assert_array_equal(slam.particles.t, np.tile([3.0, -2.0, 1.0], (20, 1)))
    np.testing.assert_array_equal(slam.particles.R, np.tile(np.eye(3), (20, 1, 1)))
    np.testing.assert_allclose(slam.T_body_velo, np.linalg.inv(T_velo_imu), atol=1e-12)


def test_weigh_adds_tempered_scores_and_stores_them():
    """``weigh``: ``normalise(log_w + score / (N * temperature))`` with ``score = steps.score_particles`` (computed
    here independently), and the raw scores land in ``last["scores"]``."""
    scan = _scan()
    config = _config()
    slam = ParticleSLAM3D(config)
    slam.register_frame(_frame(scan))
    parts = steps.perturb_with_noise(
        slam.particles, np.full(6, 0.05), np.random.default_rng(3)
    )
    sample = scan[:40, :3].astype(np.float64)  # N * temperature = 0.8, not 1
    log_w = np.log(np.linspace(1.0, 2.0, 20) / np.linspace(1.0, 2.0, 20).sum())
    got = slam.weigh(parts, log_w, sample)
    scores = steps.score_particles(parts, sample, slam.map)
    raw = log_w + scores / (40 * config.filter.temperature)
    expected = raw - np.log(np.exp(raw - raw.max()).sum()) - raw.max()
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(slam.last["scores"], scores)
    assert np.ptp(scores) > 0


def test_refine_rounds_each_resample_once():
    """``FilterConfig(refine=3)`` with step 11 off (``ess_fraction=0``): 3 annealing rounds a frame, each
    resampling (``ess_fraction=1``), so ``n_annealed`` is 3 after the second frame and 6 after the third, and
    ``n_resampled`` (frames whose step 11 resampled) stays 0."""
    scan = _scan()
    slam = ParticleSLAM3D(
        SLAM3DConfig(
            filter=FilterConfig(
                particles=20, scored_points=100, refine=3, ess_fraction=0.0
            )
        )
    )
    slam.register_frame(_frame(scan, v=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0)))
    slam.register_frame(_frame(scan, v=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0)))
    assert slam.n_annealed == 3 and slam.n_resampled == 0
    slam.register_frame(_frame(scan, v=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0)))
    assert slam.n_annealed == 6 and slam.n_resampled == 0


def test_lidar_only_start_frame_runs_cv_start_rounds_rounds():
    """LIDAR-only, the second frame adds ``cv_start_rounds`` halving rounds (here 2, refine 0, step 11 off):
    ``n_annealed`` is 2; the third frame (not a start) adds none."""
    scan = _scan()
    slam = ParticleSLAM3D(
        SLAM3DConfig(
            filter=FilterConfig(particles=20, scored_points=100, ess_fraction=0.0),
            motion=MotionConfig(model="constant_velocity", cv_start_rounds=2),
        )
    )
    slam.register_frame(_frame(scan, v=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0)))
    slam.register_frame(_frame(scan, v=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0)))
    assert slam.n_annealed == 2
    slam.register_frame(_frame(scan, v=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0)))
    assert slam.n_annealed == 2 and slam.n_resampled == 0


def test_first_frame_of_exactly_min_scan_points_starts_the_map_and_records_its_points():
    """A first frame with exactly ``MIN_SCAN_POINTS`` points is merged (map of 10 points, nothing skipped) and
    ``last["points"]`` is its body-frame scan."""
    slam = ParticleSLAM3D(_config())
    slam.register_frame(_frame(_ten_points()))
    assert slam.n_skipped_frames == 0 and len(slam.map_points()) == MIN_SCAN_POINTS
    np.testing.assert_array_equal(
        _sorted(slam.last["points"]), _sorted(_ten_points()[:, :3])
    )


def test_empty_first_then_min_scan_points_frame_starts_the_map_at_the_predicted_pose():
    """Empty first frame (skipped), then exactly ``MIN_SCAN_POINTS`` points: ``_skip`` starts the map with them
    (10 points), ``n_skipped_frames`` stays 1; ``last`` holds these points, an empty (0, 3) sample, the sigma and
    ``best=None``."""
    config = _config()
    slam = ParticleSLAM3D(config)
    slam.register_frame(_frame(np.zeros((0, 4), np.float32)))
    slam.register_frame(_frame(_ten_points()))
    assert slam.n_skipped_frames == 1 and len(slam.map_points()) == MIN_SCAN_POINTS
    assert len(slam.last["points"]) == MIN_SCAN_POINTS and slam.last["sample"].shape == (
        0,
        3,
    )
    assert slam.last["sigma"] is not None and slam.last["best"] is None


def test_a_skipped_frame_after_a_scored_one_clears_best_and_sample():
    """Frame 3 empty after a scored frame 2: ``last["best"]`` is None (not frame 2's index), ``last["sample"]`` is
    empty (0, 3), ``last["points"]`` the empty scan, ``imu_prev`` frame 3's IMU."""
    scan = _scan()
    slam = ParticleSLAM3D(_config())
    slam.register_frame(_frame(scan))
    slam.register_frame(_frame(scan))
    assert slam.last["best"] is not None and len(slam.last["sample"]) == 100
    f3 = _frame(np.zeros((0, 4), np.float32), v=(8.0, 0.0, 0.0))
    slam.register_frame(f3)
    assert (
        slam.last["best"] is None
        and slam.last["sample"].shape == (0, 3)
        and len(slam.last["points"]) == 0
    )
    np.testing.assert_array_equal(slam.imu_prev[0], f3.velocity)


def test_prune_every_zero_never_prunes():
    """``MapConfig(prune_every=0)`` turns pruning off: frames register (no ``% 0``) and nothing is archived."""
    from slamlib.slam3d.config import MapConfig

    slam = ParticleSLAM3D(_config(map=MapConfig(prune_every=0, prune_radius=1.0)))
    slam.register_frame(_frame(_scan()))
    slam.register_frame(_frame(_scan()))
    assert slam.archive == [] and len(slam.poses) == 2


def test_a_map_point_exactly_at_prune_radius_stays_live_and_is_not_archived():
    """``_prune`` archives only points strictly farther than ``prune_radius`` (the maps' own ``>`` rule): with
    returns at x = 5, 7, ..., 23 and radius 9 around the start pose, x = 5, 7, 9 stay live, x = 11..23 are archived,
    and the point at exactly 9 is not also in the archive (``map_points`` has each point once)."""
    from slamlib.slam3d.config import MapConfig

    config = SLAM3DConfig(
        filter=FilterConfig(particles=20),
        scan=ScanConfig(downsample_voxel=0.0),
        map=MapConfig(prune_every=1, prune_radius=9.0),
    )
    slam = ParticleSLAM3D(config)
    slam.register_frame(_frame(_ten_points()))
    np.testing.assert_array_equal(_sorted(slam.map.points())[:, 0], [5.0, 7.0, 9.0])
    np.testing.assert_array_equal(
        _sorted(np.concatenate(slam.archive))[:, 0], 11.0 + 2.0 * np.arange(7)
    )
    np.testing.assert_array_equal(
        _sorted(slam.map_points())[:, 0], 5.0 + 2.0 * np.arange(10)
    )


def test_refine_does_not_resample_when_all_weights_are_equal():
    """Annealing rounds resample only when ``ESS < 1.0 * P``: a second frame 1 m off the map scores every particle
    the same truncated value, the weights stay exactly uniform (ESS = P), so ``refine=2`` with step 11 off
    resamples 0 times (not "always", not ``ESS < 2 P``)."""
    scan = _scan()
    slam = ParticleSLAM3D(
        SLAM3DConfig(
            filter=FilterConfig(
                particles=20, scored_points=100, refine=2, ess_fraction=0.0
            )
        )
    )
    slam.register_frame(_frame(scan))
    slam.register_frame(_frame(scan))
    assert np.ptp(slam.last["scores"]) == 0
    assert slam.n_resampled == 0


def test_a_float32_calibration_is_inverted_in_float64():
    """``T_velo_imu`` given as float32 is cast to float64 before inverting: ``T_body_velo`` is float64 and equals
    the float64 inverse of the float64 cast exactly."""
    T = geometry.make_pose(
        geometry.rpy_to_matrix([0.1, -0.2, 0.7]), [2.0, -1.0, 0.5]
    ).astype(np.float32)
    slam = ParticleSLAM3D(_config(), T_velo_imu=T)
    assert slam.T_body_velo.dtype == np.float64
    np.testing.assert_array_equal(slam.T_body_velo, np.linalg.inv(T.astype(np.float64)))


def test_the_configured_backend_runs_every_step(monkeypatch):
    """``SLAM3DConfig(backend=...)`` reaches every step that takes a backend (steps 5, 6, 8, 10, 11, the annealing
    rounds, the first frame's merge and the merge of a frame that starts the map late): with ``backend="numpy"``
    no step may fall back to its default (``steps.DEFAULT_BACKEND``, resolved by name through ``get_backend``)."""

    def no_default(name):
        raise AssertionError(
            f"a step used its default backend {name!r}, not the configured one"
        )

    monkeypatch.setattr(steps, "get_backend", no_default)
    scan = _scan()
    config = SLAM3DConfig(
        filter=FilterConfig(particles=20, scored_points=100, refine=2, ess_fraction=1.0),
        backend="numpy",
    )
    started = ParticleSLAM3D(config)
    still = dict(v=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0))
    started.register_frame(_frame(scan, **still))  # _start merges
    started.register_frame(_frame(scan, **still))  # 5-11 with two annealing rounds
    assert started.n_annealed == 2 and len(started.poses) == 2
    late = ParticleSLAM3D(config)
    late.register_frame(_frame(np.zeros((0, 4), np.float32)))  # nothing to merge
    late.register_frame(_frame(scan))  # _skip starts the map
    assert late.n_skipped_frames == 1 and len(late.map_points()) > 0
    with (
        monkeypatch.context() as m
    ):  # the check itself works: a step given no backend reaches the patched lookup
        m.setattr(steps, "get_backend", no_default)
        try:
            steps.merge_scan(late.map, np.eye(4), scan[:, :3])
        except AssertionError as exc:
            assert "default backend 'cpu'" in str(exc)
        else:
            raise AssertionError(
                "merge_scan without a backend did not look up the default"
            )


def test_lidar_only_holds_the_twist_and_imu_mode_averages_two_samples(monkeypatch):
    """Step 5's increment: LIDAR-only, ``motion_increment(imu, dt, None)`` (the held twist over ``dt``, no previous
    sample); with an IMU, the previous frame's sample is passed (the two samples are averaged)."""
    seen = []
    real = steps.motion_increment
    monkeypatch.setattr(
        steps,
        "motion_increment",
        lambda imu, dt, prev=None: seen.append(prev) or real(imu, dt, prev),
    )
    scan = _scan()
    cv = ParticleSLAM3D(
        _config(motion=MotionConfig(model="constant_velocity", cv_start_rounds=0))
    )
    for _ in range(3):
        cv.register_frame(_frame(scan))
    assert seen == [None, None]
    seen.clear()
    imu = ParticleSLAM3D(_config())
    f1, f2 = _frame(scan), _frame(scan, v=(9.0, 0.0, 0.0))
    imu.register_frame(f1)
    imu.register_frame(f2)
    assert len(seen) == 1
    np.testing.assert_array_equal(seen[0][0], f1.velocity)
    np.testing.assert_array_equal(seen[0][1], f1.angular_rate)


def test_lidar_only_scores_a_sample_with_the_road_thinned():
    """LIDAR-only, the scored sample is drawn from ``thin_ground(points, lidar_only_ground_share)``: on a scan that
    is 80 % road, with a share of 0.2, at most a fifth of the 100 scored points are road points (drawn from all
    points, about 80 would be)."""
    rng = np.random.default_rng(3)
    n_road, n_wall = 800, 200
    az = rng.uniform(-np.pi, np.pi, n_road)
    r = rng.uniform(4.0, 25.0, n_road)
    road = np.column_stack([r * np.cos(az), r * np.sin(az), np.full(n_road, -1.73)])
    wall = np.column_stack(
        [
            rng.uniform(-20, 20, n_wall),
            np.full(n_wall, 8.0),
            rng.uniform(-1.0, 3.0, n_wall),
        ]
    )
    scan = np.column_stack(
        [np.concatenate([road, wall]), np.zeros(n_road + n_wall)]
    ).astype(np.float32)
    config = SLAM3DConfig(
        filter=FilterConfig(particles=20, scored_points=100, lidar_only_ground_share=0.2),
        motion=MotionConfig(model="constant_velocity", cv_start_rounds=0),
        scan=ScanConfig(downsample_voxel=0.0),
    )
    slam = ParticleSLAM3D(config)
    slam.register_frame(_frame(scan))
    slam.register_frame(_frame(scan))
    sample = np.asarray(slam.last["sample"])
    assert len(sample) == 100
    assert np.sum(sample[:, 2] < sample[:, 2].min() + 0.1) <= 25


def test_lidar_only_start_rounds_halve_the_spread(monkeypatch):
    """The LIDAR-only start frame's annealing rounds perturb with ``sigma / 2, sigma / 4, ...`` (``0.5**k``) after
    step 6's ``sigma``; refine rounds then use ``refine_shrink``."""
    sigmas = []
    real = steps.perturb_with_noise
    monkeypatch.setattr(
        steps,
        "perturb_with_noise",
        lambda p, sigma, rng, backend: (
            sigmas.append(np.array(sigma)) or real(p, sigma, rng, backend=backend)
        ),
    )
    scan = _scan()
    slam = ParticleSLAM3D(
        SLAM3DConfig(
            filter=FilterConfig(
                particles=20, scored_points=100, refine=1, refine_shrink=0.3
            ),
            motion=MotionConfig(model="constant_velocity", cv_start_rounds=3),
        )
    )
    still = dict(v=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0))
    slam.register_frame(_frame(scan, **still))
    slam.register_frame(_frame(scan, **still))
    assert len(sigmas) == 5
    for got, k in zip(sigmas[1:], (0.5, 0.25, 0.125, 0.3)):
        np.testing.assert_allclose(got, sigmas[0] * k, rtol=1e-15)
