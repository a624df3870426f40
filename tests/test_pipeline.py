"""The 3D filter (:mod:`slamlib.slam3d.pipeline`): its per-frame method as the design states it (the numbered steps
in order, stages chosen once), and what ``ParticleSLAM3D.register_frame`` does with whole drives and frame by frame.

``ParticleSLAM3D.register_frame`` must stay as brief as KISS-ICP's ``register_frame``: at most
:data:`MAX_CODE_LINES` lines of code (docstring, comments and blank lines aside), no setting that chooses a mode
read in it (the stages are chosen once, :mod:`slamlib.slam3d.stages`), and no branch but the data's own: the
first frame and a degenerate frame.
"""

from __future__ import annotations

import ast
import inspect
import os
import textwrap
from dataclasses import dataclass, fields, is_dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from world3d import tiny_config

from slamlib import geometry
from slamlib.geometry import make_pose, rpy_to_matrix
from slamlib.metrics import absolute_trajectory_error
from slamlib.odometry import dead_reckon
from slamlib.slam3d import ParticleSLAM3D, SLAM3DConfig, steps
from slamlib.slam3d.config import (
    AnnealConfig,
    ConstantVelocityConfig,
    FilterConfig,
    MotionConfig,
    ScanConfig,
)
from slamlib.slam3d.pipeline import MIN_SCAN_POINTS
from slamlib.slam3d.stages import (
    Annealing,
    ConstantVelocity,
    ImuMotion,
    NoPolish,
    NoPrior,
    ScanMatch,
    TiltPrior,
)


def _cv(**changes) -> ConstantVelocityConfig:
    """The LIDAR-only motion source's settings with ``changes``."""
    return ConstantVelocityConfig(**changes)


#: The design's bound: KISS-ICP's register_frame is 33 lines with its docstring; ours at most 25 of code.
MAX_CODE_LINES = 25
#: Settings the per-frame method may pass on as arguments (not modes): step 9's estimate.
PASSED_ON = {"pose_estimate"}
#: Pipeline state whose name is also a setting's: the particle set itself.
STATE = {"particles"}
#: Names that may appear in a branch's condition: the data (poses so far, the scan, the map).
DATA_NAMES = {"poses", "points", "self", "map", "len", "MIN_SCAN_POINTS"}


def method_problems(source: str) -> list[str]:
    """Where the function in ``source`` breaks the per-frame method's rules (module docstring); empty when it
    keeps them."""
    src = textwrap.dedent(source)
    body = ast.parse(src).body[0].body
    if isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
        body = body[1:]  # the docstring
    lines = src.splitlines()
    code = [
        n
        for n in range(body[0].lineno, body[-1].end_lineno + 1)
        if lines[n - 1].strip() and not lines[n - 1].strip().startswith("#")
    ]
    problems = []
    if len(code) > MAX_CODE_LINES:
        problems.append(f"{len(code)} code lines, more than {MAX_CODE_LINES}")
    config = SLAM3DConfig()
    groups = [getattr(config, g.name) for g in fields(config)]
    groups = [g for g in groups if is_dataclass(g)]
    settings = {
        f.name for g in groups for f in fields(g) if not is_dataclass(getattr(g, f.name))
    }
    modes = (settings - PASSED_ON - STATE) | {"lidar_only"}
    seen, branches = set(), set()
    for node in (n for stmt in body for n in ast.walk(stmt)):
        if isinstance(node, ast.Attribute):
            seen.add(node.attr)
        elif isinstance(node, ast.Name):
            seen.add(node.id)
        if isinstance(node, (ast.If, ast.IfExp)):
            names = {n.id for n in ast.walk(node.test) if isinstance(n, ast.Name)}
            names |= {n.attr for n in ast.walk(node.test) if isinstance(n, ast.Attribute)}
            if names - DATA_NAMES:
                problems.append(f"branches on {sorted(names - DATA_NAMES)}")
            branches.add(ast.unparse(node.test))
    problems += [f"reads the setting {name!r}" for name in sorted(seen & modes)]
    if len(branches) > 2:
        problems.append(f"{len(branches)} distinct branch conditions: {sorted(branches)}")
    return problems


def test_register_frame_is_the_steps_in_order_with_no_mode_read():
    assert method_problems(inspect.getsource(ParticleSLAM3D.register_frame)) == []


def test_the_method_check_finds_a_mode_flag_a_branch_and_length():
    planted = """
    def register_frame(self, frame):
        \"\"\"A per-frame method that decides its modes per frame.\"\"\"
        points = self.scan.read(frame)
        if self.config.filter.tilt_sigma:
            points = points[:10]
        return points[:5] if self.lidar_only else points
    """
    assert method_problems(planted) == [
        "branches on ['config', 'filter', 'tilt_sigma']",
        "branches on ['lidar_only']",
        "reads the setting 'lidar_only'",
        "reads the setting 'tilt_sigma'",
    ]
    three = """
    def register_frame(self, frame):
        if not poses:
            return 1
        if len(points) < 3:
            return 2
        if len(self.map) == 0:
            return 3
    """
    assert method_problems(three) == [
        "3 distinct branch conditions: ['len(points) < 3', 'len(self.map) == 0', 'not poses']"
    ]
    body = "\n".join(f"    x{k} = {k}  # a comment" for k in range(MAX_CODE_LINES + 1))
    long = f"def register_frame(self, frame):\n    # not code\n\n{body}\n"
    assert method_problems(long) == [
        f"{MAX_CODE_LINES + 1} code lines, more than {MAX_CODE_LINES}"
    ]
    short = f"def register_frame(self, frame):\n{body.split(chr(10), 1)[1]}\n"
    assert method_problems(short) == []


def _frame(scan, v=(1.0, 0.0, 0.0), w=(0.0, 0.0, 0.0), **extra):
    from types import SimpleNamespace

    return SimpleNamespace(
        scan=scan,
        velocity=None if v is None else np.array(v),
        angular_rate=np.array(w),
        dt=0.1,
        **extra,
    )


def _scan(n=600, seed=0):
    rng = np.random.default_rng(seed)
    pts = np.column_stack(
        [rng.uniform(-20, 20, n), rng.uniform(-20, 20, n), rng.uniform(-1.5, 3.0, n)]
    )
    return np.column_stack([pts, np.zeros(n)]).astype(np.float32)


def test_stages_are_chosen_once_from_the_settings_and_the_first_frame():
    scan = _scan()
    config = SLAM3DConfig.of(particles=20, scored_points=100)
    imu = ParticleSLAM3D(config)
    # nothing chosen before the data is seen
    assert imu.motion is None and not imu.lidar_only
    imu.register_frame(_frame(scan))
    chosen = (imu.motion, imu.prior, imu.polish)
    assert isinstance(imu.motion, ImuMotion)
    # the tilt prior on by default with an IMU (this frame has no accelerometer: nothing measured yet)
    assert isinstance(imu.prior, TiltPrior) and imu.prior.up is None
    assert imu.prior.sigma == config.prior.tilt_sigma > 0
    # scan matching on by default with an IMU too, the road's points not held, the prior in its cost
    assert isinstance(imu.polish, ScanMatch) and not imu.polish.road
    assert imu.polish.prior is imu.prior
    # the tilt prior that weighs itself; a frame without an accelerometer leaves it nothing to hold to
    auto = ParticleSLAM3D(config.with_(tilt_sigma="auto"))
    auto.register_frame(_frame(scan))
    assert isinstance(auto.prior, TiltPrior) and auto.prior.auto and auto.prior.up is None
    assert imu.polish.gate == config.polish.match_gate > 0  # the gate is on by default
    imu.register_frame(_frame(scan))
    assert (imu.motion, imu.prior, imu.polish) == chosen  # the same objects: chosen once
    # the polish measured the match against the frame's spread (the gate's distance)
    assert np.isfinite(imu.polish.last_distance)
    assert isinstance(imu.search, Annealing) and imu.search.rounds == 0

    lidar = ParticleSLAM3D(config)
    lidar.register_frame(_frame(scan, v=None))  # no IMU in the data: LIDAR-only
    assert isinstance(lidar.motion, ConstantVelocity) and lidar.lidar_only
    assert isinstance(lidar.prior, NoPrior)  # no accelerometer to hold the tilt to
    assert isinstance(lidar.polish, ScanMatch) and lidar.polish.road

    tilted = ParticleSLAM3D(
        config.with_(tilt_sigma=0.003, anneal_rounds=2, scan_match=True)
    )
    tilted.register_frame(_frame(scan, specific_force=np.array([0.0, 0.0, 9.81])))
    assert isinstance(tilted.prior, TiltPrior) and tilted.prior.sigma == 0.003
    assert isinstance(tilted.polish, ScanMatch) and not tilted.polish.road  # forced
    # left to "auto" with match_tilt off, the tilt prior turns scan matching off: a matcher on the map score
    # alone would undo its pull
    prior_only = ParticleSLAM3D(config.with_(tilt_sigma=0.003, match_tilt=False))
    prior_only.register_frame(_frame(scan, specific_force=np.array([0.0, 0.0, 9.81])))
    assert isinstance(prior_only.prior, TiltPrior)
    assert isinstance(prior_only.polish, NoPolish)
    assert (
        tilted.search.rounds == 2 and tilted.search.shrink == AnnealConfig().anneal_shrink
    )
    off = ParticleSLAM3D(config.with_(tilt_sigma=0.003, scan_match=False))
    # LIDAR-only: the prior is off whatever tilt_sigma says
    off.register_frame(_frame(scan, v=None))
    assert isinstance(off.prior, NoPrior) and isinstance(off.polish, NoPolish)


def test_the_start_line_setting_reaches_the_search_stage():
    """``ConstantVelocityConfig.start_line`` is the search stage's ``start_line`` (on by default), with the filter's
    score and its map's resolution."""
    off = SLAM3DConfig.of(**{"constant_velocity.start_line": False})
    assert ParticleSLAM3D(off).search.start_line is False
    on = SLAM3DConfig()
    slam = ParticleSLAM3D(on)
    assert slam.search.start_line is True
    # the line's search is kept only beyond the map's resolution, by the filter's last scores
    assert slam.search.resolution == slam.map.resolution == on.map.params["voxel_size"]
    assert slam.search.last is slam.last


def test_resampling_and_annealing_are_counted_apart():
    scan = _scan()
    slam = ParticleSLAM3D(
        SLAM3DConfig.of(
            particles=20, scored_points=100, anneal_rounds=2, ess_fraction=1.0
        )
    )
    for _ in range(3):
        slam.register_frame(_frame(scan))
    assert slam.n_annealed == 4  # two rounds in each of the two frames after the first
    assert slam.n_resampled == 2  # step 11 in each of them (ESS below P after scoring)


def test_step_reports_a_degenerate_frame_as_unscored_and_register_frame_its_pose():
    scan = _scan()
    config = SLAM3DConfig.of(particles=20, scored_points=100)
    slam = ParticleSLAM3D(config)
    first = slam.step(_frame(scan))
    assert first.resampled is False and np.all(first.scores == 0)
    np.testing.assert_array_equal(first.estimate, np.eye(4))
    before = slam.log_weights
    empty = slam.step(_frame(np.zeros((0, 4), np.float32)))
    assert empty.resampled is False and np.all(empty.scores == 0)
    np.testing.assert_array_equal(empty.log_weights, before)
    assert empty.moved is slam.particles and slam.n_skipped_frames == 1
    scored = slam.step(_frame(scan))
    assert np.ptp(scored.scores) > 0 and scored.resampled == (slam.n_resampled == 1)
    twin = ParticleSLAM3D(config)
    poses = [
        twin.register_frame(f) for f in (_frame(scan), _frame(scan[:0]), _frame(scan))
    ]
    # step() adds a report, not a change
    np.testing.assert_array_equal(poses[-1], scored.estimate)


# ------------------------------------------------------------------ step 12 over whole drives of the tiny world
def test_register_frame_beats_dead_reckoning(drive):
    frames, gt = drive
    slam = ParticleSLAM3D(tiny_config())
    for f in frames:
        slam.register_frame(f)
    ate_slam = absolute_trajectory_error(slam.trajectory, gt).rmse
    ate_dr = absolute_trajectory_error(slam.dead_reckoning, gt).rmse
    assert ate_dr > 0.3  # the IMU alone drifts
    assert ate_slam < ate_dr / 4
    assert slam.n_resampled > 0 and len(slam.poses) == len(frames)


def test_dead_reckoning_twin_is_the_imu_integral(drive):
    frames, _ = drive
    slam = ParticleSLAM3D(tiny_config(particles=5, scored_points=50))
    for f in frames[:6]:
        slam.register_frame(f)
    v = np.array([f.velocity for f in frames[:6]])
    w = np.array([f.angular_rate for f in frames[:6]])
    assert np.allclose(
        slam.dead_reckoning, dead_reckon(v, w, [f.dt for f in frames[:6]]), atol=1e-12
    )


def test_same_seed_same_trajectory_other_seed_differs(drive):
    frames, _ = drive

    def traj(seed):
        slam = ParticleSLAM3D(tiny_config(particles=50, scored_points=200, seed=seed))
        for f in frames[:8]:
            slam.register_frame(f)
        return slam.trajectory

    a, b, c = traj(1), traj(1), traj(2)
    assert np.array_equal(a, b)
    assert not np.allclose(a[1:], c[1:])


def test_numpy_and_cpu_backends_give_the_same_trajectory(drive):
    frames, _ = drive

    def traj(backend):
        slam = ParticleSLAM3D(
            tiny_config(particles=16, scored_points=100, backend=backend, seed=7)
        )
        for f in frames[:4]:
            slam.register_frame(f)
        return slam.trajectory

    assert np.allclose(traj("numpy"), traj("cpu"), atol=1e-9)


def test_cuda_backend_gives_the_cpu_trajectory(drive):
    """In Numba's CUDA simulator (tests/conftest.py) unless SLAMLIB_REAL_CUDA=1: tiny sizes."""
    frames, _ = drive

    def traj(backend):
        slam = ParticleSLAM3D(
            tiny_config(
                particles=8,
                scored_points=30,
                backend=backend,
                seed=7,
                downsample_voxel=1.5,
            )
        )
        for f in frames[:3]:
            slam.register_frame(f)
        return slam.trajectory

    assert np.allclose(traj("cuda"), traj("cpu"), atol=1e-6)


def test_pruned_map_points_are_kept_for_export(drive):
    frames, _ = drive
    slam = ParticleSLAM3D(
        tiny_config(particles=10, scored_points=50, prune_every=5, prune_radius=12.0)
    )
    for f in frames[:10]:  # pruned after frames 5 and 10
        slam.register_frame(f)
    assert slam.archive and len(slam.map_points()) == len(slam.map) + sum(
        len(a) for a in slam.archive
    )
    assert (
        np.linalg.norm(slam.map.points() - slam.poses[-1][:3, 3], axis=1).max()
        <= 12.0 + 1e-4
    )
    assert (
        np.linalg.norm(slam.archive[-1] - slam.poses[-1][:3, 3], axis=1).min()
        > 12.0 - 1e-4
    )


def test_transient_voxels_are_evicted_every_span_frames(drive):
    frames, _ = drive
    span = 4
    slam = ParticleSLAM3D(
        tiny_config(particles=10, scored_points=50, transient_span=span, prune_every=0)
    )
    plain = ParticleSLAM3D(tiny_config(particles=10, scored_points=50, prune_every=0))
    for k, f in enumerate(frames[: 2 * span]):
        slam.register_frame(f)
        plain.register_frame(f)
        if (k + 1) % span == 0:
            assert not slam.map.transients(span).any()
    assert slam.map.frames == plain.map.frames == 2 * span
    assert len(slam.map) < len(plain.map) and plain.map.transients(span).any()


def test_tilt_prior_pulls_a_tilted_start_back_to_gravity(drive):
    """Started with a 40 mrad pitch error (the map is built tilted), the map alone keeps the filter tilted; the
    accelerometer's up (step 3) in step 8 pulls it back toward level against that map (2 mrad: a strong prior; a
    0.5 s window, the up from the IMU's velocities, near exact on this IMU, so that it holds from the sixth of the
    30 frames; the up from the filter's positions over so short a window is not). A pose's up in its body is its
    rotation's third row. The spread is held fixed: how fast the pull acts depends on step 6's
    spread in pitch, which self-tuning would narrow to the drive's own small pitch innovations (the pull per frame
    is at most about that spread)."""
    frames, gt = drive
    T0 = make_pose(rpy_to_matrix([0.0, 0.04, 0.0]), [0.0, 0.0, 0.0])

    def run(**kw):
        slam = ParticleSLAM3D(tiny_config(self_tuning=False, **kw), T0=T0)
        for f in frames:
            slam.register_frame(f)
        return np.linalg.norm(slam.poses[-1][2, :3] - gt[-1][2, :3]), slam

    without, plain = run(tilt_sigma=0.0)
    # level world, no bias
    with_prior, slam = run(
        tilt_sigma=0.002,
        tilt_window=0.5,
        tilt_world_sigma=0.0,
        tilt_bias_sigma=0.0,
        tilt_up="velocity",
    )
    assert without > 0.03 and plain.prior.up is None  # the map holds the start's tilt
    assert with_prior < without / 2, (with_prior, without)
    # the measured up is the true one
    np.testing.assert_allclose(slam.prior.up, gt[-1][2, :3], atol=0.01)


# ------------------------------------------------------------------ register_frame value by value
# A tiny filter (20 particles, a few hundred points) against values computed with the step functions or by hand.
def _ring_scan(n=300, seed=0):
    rng = np.random.default_rng(seed)
    az = rng.uniform(-np.pi, np.pi, n)
    r = rng.uniform(5.0, 30.0, n)
    xyz = np.column_stack([r * np.cos(az), r * np.sin(az), rng.uniform(-1.5, 1.0, n)])
    return np.column_stack([xyz, np.zeros(n)]).astype(np.float32)


def _imu_frame(scan, v=(10.0, 0.0, 0.0), w=(0.0, 0.0, 0.1), dt=0.1):
    return SimpleNamespace(
        scan=scan, velocity=np.array(v, float), angular_rate=np.array(w, float), dt=dt
    )


def _config(**kw):
    return SLAM3DConfig(filter=FilterConfig(particles=20, scored_points=100), **kw)


def test_constant_velocity_model_is_lidar_only_even_when_the_frame_has_an_imu():
    """``MotionConfig(model="constant_velocity")``: a frame WITH IMU values still makes the filter LIDAR-only (no
    dead-reckoning twin, ``lidar_only`` True); the default model with IMU values is not LIDAR-only."""
    scan = _ring_scan()
    cv = ParticleSLAM3D(_config(motion=MotionConfig(model="constant_velocity")))
    cv.register_frame(_imu_frame(scan))
    assert cv.lidar_only is True and cv.dead_reckoning is None
    imu = ParticleSLAM3D(_config())
    imu.register_frame(_imu_frame(scan))
    assert imu.lidar_only is False and imu.dead_reckoning.shape == (1, 4, 4)


def test_a_frame_without_a_velocity_attribute_makes_the_filter_lidar_only():
    """A first frame object that has no ``velocity`` attribute at all (KITTI odometry layout) is LIDAR-only."""
    slam = ParticleSLAM3D(_config())
    slam.register_frame(SimpleNamespace(scan=_ring_scan(), dt=0.1))
    assert slam.lidar_only is True and slam.dead_reckoning is None


def test_the_particle_count_follows_the_mode_unless_given():
    """``particles="auto"`` (default): 300 particles with an IMU, 100 LIDAR-only (set at the first frame, when the
    data tell the mode, even where the settings did not ask for LIDAR-only); a number holds in either mode."""
    scan = _ring_scan()
    counts = {}
    for name, frame in (
        ("imu", _imu_frame(scan)),
        ("lidar_only", SimpleNamespace(scan=scan, dt=0.1)),
    ):
        for particles in ("auto", 40):
            slam = ParticleSLAM3D(SLAM3DConfig.of(particles=particles))
            slam.register_frame(frame)
            slam.register_frame(frame)
            counts[name, particles] = (len(slam.particles), len(slam.last["moved"]))
    assert counts == {
        ("imu", "auto"): (300, 300),
        ("imu", 40): (40, 40),
        ("lidar_only", "auto"): (100, 100),
        ("lidar_only", 40): (40, 40),
    }


def _sorted(points):
    p = np.asarray(points, dtype=np.float64)
    return p[np.lexsort(p.T[::-1])]


def _map_of(config, points):
    m = config.map.make()
    steps.merge_scan(m, np.eye(4), points, "cpu")
    return _sorted(m.points())


def test_first_frame_merges_the_scan_moved_into_the_body_frame():
    """``read_scan`` gets ``T_body_velo = inv(T_velo_imu)``: the first frame's map is the cropped scan moved by
    ``T_body_velo`` (written out here: ``R p + t``), merged at the identity start pose."""
    scan = _ring_scan()
    T_velo_imu = geometry.make_pose(
        geometry.rpy_to_matrix([0.0, 0.0, 0.7]), [2.0, -1.0, 0.5]
    )
    config = SLAM3DConfig(
        filter=FilterConfig(particles=20), scan=ScanConfig(downsample_voxel=0.0)
    )
    slam = ParticleSLAM3D(config, T_velo_imu=T_velo_imu)
    slam.register_frame(_imu_frame(scan))
    T = np.linalg.inv(T_velo_imu)
    body = (scan[:, :3].astype(np.float64) @ T[:3, :3].T + T[:3, 3]).astype(np.float32)
    expected = _map_of(config, body)
    np.testing.assert_array_equal(_sorted(slam.map_points()), expected)
    unmoved = _map_of(config, scan[:, :3])
    assert expected.shape != unmoved.shape or np.abs(expected - unmoved).max() > 0.5


def test_deskew_config_deskews_the_scan_with_the_frames_imu_before_merging():
    """``ScanConfig(deskew=True)``: the first frame merges ``steps.deskew_scan(points, (v, w), cfg.scan,
    T_body_velo)`` of the body-frame points, with the frame's own velocity and angular rate."""
    scan = _ring_scan()
    T_velo_imu = geometry.make_pose(
        geometry.rpy_to_matrix([0.0, 0.0, 1.2]), [0.8, -0.3, 1.7]
    )
    T = np.linalg.inv(T_velo_imu)
    sc = ScanConfig(downsample_voxel=0.0, deskew=True, sweep_period=0.1)
    config = SLAM3DConfig(filter=FilterConfig(particles=20), scan=sc)
    frame = _imu_frame(scan, v=(12.0, 0.5, 0.0), w=(0.0, 0.0, 0.3))
    slam = ParticleSLAM3D(config, T_velo_imu=T_velo_imu)
    slam.register_frame(frame)
    body = steps.read_scan(frame, sc, T)
    expected = steps.deskew_scan(body, (frame.velocity, frame.angular_rate), sc, T)
    np.testing.assert_array_equal(_sorted(slam.map_points()), _map_of(config, expected))
    # de-skewing moved the points
    assert np.abs(_sorted(expected) - _sorted(body)).max() > 0.05
    no_t = steps.deskew_scan(body, (frame.velocity, frame.angular_rate), sc)
    assert np.abs(no_t - expected).max() > 1e-3  # the mounting matters


def test_default_deskew_follows_the_frames_sweep():
    """``ScanConfig.deskew`` "auto" (the default) de-skews a frame whose ``swept`` is true, as ``deskew=True`` does,
    and merges a frame with ``swept`` false (or none) as ``deskew=False``; ``n_deskewed`` counts the frames."""
    scan = _ring_scan()
    frame = _imu_frame(scan, v=(12.0, 0.5, 0.0), w=(0.0, 0.0, 0.3))
    maps = {}
    for name, deskew, swept in (
        ("auto swept", "auto", True),
        ("on", True, False),
        ("auto still", "auto", False),
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
    scan = _ring_scan()
    sc = ScanConfig(downsample_voxel=0.0, deskew=True, sweep_period=0.1)
    config = SLAM3DConfig(filter=FilterConfig(particles=20), scan=sc)
    frame = _imu_frame(scan, v=(12.0, 0.5, 0.0), w=(0.0, 0.0, 0.3))
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
    scan = _ring_scan()
    config = _config()
    slam = ParticleSLAM3D(config)
    f1, f2 = (
        _imu_frame(scan),
        _imu_frame(scan, v=(11.0, 0.2, 0.0), w=(0.0, 0.01, 0.12), dt=0.1),
    )
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
    slam.register_frame(_imu_frame(scan))
    assert slam.n_skipped_frames == 0 and len(slam.map_points()) == n
    slam.register_frame(_imu_frame(scan))
    assert slam.n_skipped_frames == 0 and slam.last["scores"].shape == (20,)
    assert len(slam.last["sample"]) == n
    short = ParticleSLAM3D(config)
    short.register_frame(_imu_frame(scan[: n - 1]))
    assert short.n_skipped_frames == 1 and len(short.map_points()) == 0


def test_lidar_only_second_frame_sigma_is_the_constant_velocity_start_spread():
    """LIDAR-only the second frame's spread is ``motion.sigma(increment[1], dt, True, True)`` with the increment of
    the zero own motion (``constant_velocity`` is passed as True, the start search is on)."""
    scan = _ring_scan()
    config = _config(motion=MotionConfig(model="constant_velocity"))
    slam = ParticleSLAM3D(config)
    slam.register_frame(_imu_frame(scan))
    slam.register_frame(_imu_frame(scan))
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
    slam.register_frame(_imu_frame(scan, v=(0, 0, 0), w=(0, 0, 0)))
    assert len(slam.map) == 1
    slam.register_frame(_imu_frame(scan, v=(0, 0, 0), w=(0, 0, 0)))
    assert (
        slam.n_skipped_frames == 0
        and slam.last["scores"].shape == (20,)
        and slam.last["best"] is not None
    )


def test_a_skipped_frame_keeps_its_imu_sample_and_sigma():
    """A degenerate (empty) second frame still records its IMU sample as ``imu_prev`` (the next frame's increment
    starts from it) and its step-6 ``sigma`` in ``last``; the third frame is then not taken for a first frame."""
    scan = _ring_scan()
    config = _config()
    slam = ParticleSLAM3D(config)
    f1 = _imu_frame(scan)
    f2 = _imu_frame(np.zeros((0, 4), np.float32), v=(9.0, 0.1, 0.0), w=(0.0, 0.0, 0.2))
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
    slam.register_frame(_imu_frame(scan))
    assert len(slam.poses) == 3 and len(slam.dead_reckoning) == 3


def test_imu_mode_scores_every_point_without_ground_thinning():
    """With an IMU the pool is the whole scan (no ``thin_ground``): ``scored_points`` above the scan size samples
    every point in input order, so ``last['sample']`` and ``last['points']`` are the step-2 points."""
    scan = _ring_scan()
    scan[:150, 2] = -1.7  # a flat road for thin_ground to thin
    config = SLAM3DConfig(
        filter=FilterConfig(particles=20, scored_points=10_000),
        scan=ScanConfig(downsample_voxel=0),
    )
    slam = ParticleSLAM3D(config)
    slam.register_frame(_imu_frame(scan))
    slam.register_frame(_imu_frame(scan))
    points = steps.read_scan(scan, config.scan)
    np.testing.assert_array_equal(slam.last["points"], points)
    np.testing.assert_array_equal(slam.last["sample"], points)


def test_configured_mean_estimate_is_used_for_the_pose():
    """``FilterConfig(pose_estimate="mean")`` reaches step 9: the pose is ``pick_best_particle(moved, log_w, "mean")``,
    not the best particle's pose (checked with ``ess_fraction=0``: no resampling, ``particles`` are the moved)."""
    scan = _ring_scan()
    for estimate in ("best", "mean"):
        config = SLAM3DConfig(
            filter=FilterConfig(particles=20, pose_estimate=estimate, ess_fraction=0.0)
        )
        slam = ParticleSLAM3D(config)
        slam.register_frame(_imu_frame(scan))
        pose = slam.register_frame(_imu_frame(scan))
        p, i = slam.particles, slam.last["best"]
        expected, _ = steps.pick_best_particle(p, slam.log_weights, estimate)
        np.testing.assert_allclose(pose, expected, atol=1e-12)
        best_pose = geometry.make_pose(p.R[i], p.t[i])
        assert np.allclose(pose, best_pose) == (estimate == "best")


def test_step_11_counts_resamplings_with_the_configured_ess_fraction():
    """Step 11 uses ``FilterConfig.ess_fraction`` and ``n_resampled`` accumulates: ``ess_fraction=1`` resamples
    whenever ESS < P (at least 2 of the 3 scored frames; a non-accumulating count would be at most 1),
    ``ess_fraction=0`` never (0)."""
    scan = _ring_scan()
    for frac, at_least, at_most in ((1.0, 2, 3), (0.0, 0, 0)):
        slam = ParticleSLAM3D(
            SLAM3DConfig(filter=FilterConfig(particles=20, ess_fraction=frac))
        )
        for _ in range(4):
            slam.register_frame(_imu_frame(scan))
        assert at_least <= slam.n_resampled <= at_most


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
    scan = _ring_scan()
    config = _config()
    slam = ParticleSLAM3D(config)
    slam.register_frame(_imu_frame(scan))
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


def test_anneal_rounds_each_resample_once():
    """``AnnealConfig(anneal_rounds=3)`` with step 11 off (``ess_fraction=0``): 3 annealing rounds a frame, each
    resampling (``ess_fraction=1``), so ``n_annealed`` is 3 after the second frame and 6 after the third, and
    ``n_resampled`` (frames whose step 11 resampled) stays 0."""
    scan = _ring_scan()
    slam = ParticleSLAM3D(
        SLAM3DConfig(
            filter=FilterConfig(particles=20, scored_points=100, ess_fraction=0.0),
            search=AnnealConfig(anneal_rounds=3),
        )
    )
    slam.register_frame(_imu_frame(scan, v=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0)))
    slam.register_frame(_imu_frame(scan, v=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0)))
    assert slam.n_annealed == 3 and slam.n_resampled == 0
    slam.register_frame(_imu_frame(scan, v=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0)))
    assert slam.n_annealed == 6 and slam.n_resampled == 0


@pytest.mark.parametrize("start_line, rounds", [(False, 2), (True, 2 + 2)])
def test_lidar_only_start_frame_runs_the_start_rounds(start_line, rounds):
    """LIDAR-only, the second frame adds ``start_rounds`` halving rounds (here 2, no annealing, step 11 off), and
    with the start line as many again for the search from the line: ``n_annealed`` is 2 or 4; the third frame (not
    a start) adds none."""
    scan = _ring_scan()
    slam = ParticleSLAM3D(
        SLAM3DConfig(
            filter=FilterConfig(particles=20, scored_points=100, ess_fraction=0.0),
            motion=MotionConfig(
                model="constant_velocity",
                constant_velocity=_cv(start_rounds=2, start_line=start_line),
            ),
        )
    )
    slam.register_frame(_imu_frame(scan, v=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0)))
    slam.register_frame(_imu_frame(scan, v=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0)))
    assert slam.n_annealed == rounds
    slam.register_frame(_imu_frame(scan, v=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0)))
    assert slam.n_annealed == rounds and slam.n_resampled == 0


# ------------------------------------------------------------------ construction, counters, the first frames, pruning
def _ten_points():
    """Exactly MIN_SCAN_POINTS returns, each in its own voxel and inside [min_range, max_range]."""
    x = 5.0 + 2.0 * np.arange(MIN_SCAN_POINTS)
    return np.column_stack(
        [x, np.zeros_like(x), np.zeros_like(x), np.zeros_like(x)]
    ).astype(np.float32)


def test_first_frame_of_exactly_min_scan_points_starts_the_map_and_records_its_points():
    """A first frame with exactly ``MIN_SCAN_POINTS`` points is merged (map of 10 points, nothing skipped) and
    ``last["points"]`` is its body-frame scan."""
    slam = ParticleSLAM3D(_config())
    slam.register_frame(_imu_frame(_ten_points()))
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
    slam.register_frame(_imu_frame(np.zeros((0, 4), np.float32)))
    slam.register_frame(_imu_frame(_ten_points()))
    assert slam.n_skipped_frames == 1 and len(slam.map_points()) == MIN_SCAN_POINTS
    assert len(slam.last["points"]) == MIN_SCAN_POINTS and slam.last["sample"].shape == (
        0,
        3,
    )
    assert slam.last["sigma"] is not None and slam.last["best"] is None


def test_a_skipped_frame_after_a_scored_one_clears_best_and_sample():
    """Frame 3 empty after a scored frame 2: ``last["best"]`` is None (not frame 2's index), ``last["sample"]`` is
    empty (0, 3), ``last["points"]`` the empty scan, ``imu_prev`` frame 3's IMU."""
    scan = _ring_scan()
    slam = ParticleSLAM3D(_config())
    slam.register_frame(_imu_frame(scan))
    slam.register_frame(_imu_frame(scan))
    assert slam.last["best"] is not None and len(slam.last["sample"]) == 100
    f3 = _imu_frame(np.zeros((0, 4), np.float32), v=(8.0, 0.0, 0.0))
    slam.register_frame(f3)
    assert (
        slam.last["best"] is None
        and slam.last["sample"].shape == (0, 3)
        and len(slam.last["points"]) == 0
    )
    np.testing.assert_array_equal(slam.imu_prev[0], f3.velocity)


def test_prune_every_zero_never_prunes():
    """``UpkeepConfig(prune_every=0)`` turns pruning off: frames register (no ``% 0``) and nothing is archived."""
    from slamlib.slam3d.config import UpkeepConfig

    slam = ParticleSLAM3D(_config(upkeep=UpkeepConfig(prune_every=0, prune_radius=1.0)))
    slam.register_frame(_imu_frame(_ring_scan()))
    slam.register_frame(_imu_frame(_ring_scan()))
    assert slam.archive == [] and len(slam.poses) == 2


def test_a_map_point_exactly_at_prune_radius_stays_live_and_is_not_archived():
    """``_prune`` archives only points strictly farther than ``prune_radius`` (the maps' own ``>`` rule): with
    returns at x = 5, 7, ..., 23 and radius 9 around the start pose, x = 5, 7, 9 stay live, x = 11..23 are archived,
    and the point at exactly 9 is not also in the archive (``map_points`` has each point once)."""
    from slamlib.slam3d.config import UpkeepConfig

    config = SLAM3DConfig(
        filter=FilterConfig(particles=20),
        scan=ScanConfig(downsample_voxel=0.0),
        upkeep=UpkeepConfig(prune_every=1, prune_radius=9.0),
    )
    slam = ParticleSLAM3D(config)
    slam.register_frame(_imu_frame(_ten_points()))
    np.testing.assert_array_equal(_sorted(slam.map.points())[:, 0], [5.0, 7.0, 9.0])
    np.testing.assert_array_equal(
        _sorted(np.concatenate(slam.archive))[:, 0], 11.0 + 2.0 * np.arange(7)
    )
    np.testing.assert_array_equal(
        _sorted(slam.map_points())[:, 0], 5.0 + 2.0 * np.arange(10)
    )


def test_annealing_does_not_resample_when_all_weights_are_equal():
    """Annealing rounds resample only when ``ESS < 1.0 * P``: a second frame 1 m off the map scores every particle
    the same truncated value, the weights stay exactly uniform (ESS = P), so ``anneal_rounds=2`` with step 11 off
    resamples 0 times (not "always", not ``ESS < 2 P``)."""
    scan = _ring_scan()
    slam = ParticleSLAM3D(
        SLAM3DConfig(
            filter=FilterConfig(particles=20, scored_points=100, ess_fraction=0.0),
            search=AnnealConfig(anneal_rounds=2),
        )
    )
    slam.register_frame(_imu_frame(scan))
    slam.register_frame(_imu_frame(scan))
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
    scan = _ring_scan()
    config = SLAM3DConfig(
        filter=FilterConfig(particles=20, scored_points=100, ess_fraction=1.0),
        search=AnnealConfig(anneal_rounds=2),
        backend="numpy",
    )
    started = ParticleSLAM3D(config)
    still = dict(v=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0))
    started.register_frame(_imu_frame(scan, **still))  # _start merges
    started.register_frame(_imu_frame(scan, **still))  # 5-11 with two annealing rounds
    assert started.n_annealed == 2 and len(started.poses) == 2
    late = ParticleSLAM3D(config)
    late.register_frame(_imu_frame(np.zeros((0, 4), np.float32)))  # nothing to merge
    late.register_frame(_imu_frame(scan))  # _skip starts the map
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
    scan = _ring_scan()
    cv = ParticleSLAM3D(
        _config(
            motion=MotionConfig(
                model="constant_velocity", constant_velocity=_cv(start_rounds=0)
            )
        )
    )
    for _ in range(3):
        cv.register_frame(_imu_frame(scan))
    assert seen == [None, None]
    seen.clear()
    imu = ParticleSLAM3D(_config())
    f1, f2 = _imu_frame(scan), _imu_frame(scan, v=(9.0, 0.0, 0.0))
    imu.register_frame(f1)
    imu.register_frame(f2)
    assert len(seen) == 1
    np.testing.assert_array_equal(seen[0][0], f1.velocity)
    np.testing.assert_array_equal(seen[0][1], f1.angular_rate)


def test_lidar_only_scores_a_sample_with_the_road_thinned():
    """LIDAR-only, the scored sample is drawn from ``thin_ground(points, ground_share)``: on a scan that
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
        filter=FilterConfig(particles=20, scored_points=100),
        motion=MotionConfig(
            model="constant_velocity",
            constant_velocity=_cv(start_rounds=0, ground_share=0.2),
        ),
        scan=ScanConfig(downsample_voxel=0.0),
    )
    slam = ParticleSLAM3D(config)
    slam.register_frame(_imu_frame(scan))
    slam.register_frame(_imu_frame(scan))
    sample = np.asarray(slam.last["sample"])
    assert len(sample) == 100
    assert np.sum(sample[:, 2] < sample[:, 2].min() + 0.1) <= 25


def test_lidar_only_start_rounds_halve_the_spread(monkeypatch):
    """The LIDAR-only start frame's annealing rounds (without the line's search) perturb with ``sigma / 2,
    sigma / 4, ...`` (``0.5**k``) after step 6's ``sigma``; the frame's annealing round then shrinks on from the
    last of them by ``anneal_shrink``."""
    sigmas = []
    real = steps.perturb_with_noise
    monkeypatch.setattr(
        steps,
        "perturb_with_noise",
        lambda p, sigma, rng, backend: (
            sigmas.append(np.array(sigma)) or real(p, sigma, rng, backend=backend)
        ),
    )
    scan = _ring_scan()
    slam = ParticleSLAM3D(
        SLAM3DConfig(
            filter=FilterConfig(particles=20, scored_points=100),
            search=AnnealConfig(anneal_rounds=1, anneal_shrink=0.3),
            motion=MotionConfig(
                model="constant_velocity",
                constant_velocity=_cv(start_rounds=3, start_line=False),
            ),
        )
    )
    still = dict(v=(0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0))
    slam.register_frame(_imu_frame(scan, **still))
    slam.register_frame(_imu_frame(scan, **still))
    assert len(sigmas) == 5
    for got, k in zip(sigmas[1:], (0.5, 0.25, 0.125, 0.125 * 0.3)):
        np.testing.assert_allclose(got, sigmas[0] * k, rtol=1e-15)


# ------------------------------------------------------------------ degenerate frames and bad IMU values
@dataclass
class Frame:
    scan: np.ndarray
    velocity: np.ndarray
    angular_rate: np.ndarray
    dt: float
    index: int = 0


def _box_scan(rng, n=3000):
    """Points on the walls of a 40 x 30 x 6 m box around the sensor (a static world seen from its centre)."""
    u = rng.uniform(-1, 1, (n, 3)) * [20.0, 15.0, 3.0]
    axis = rng.integers(0, 2, n)
    u[np.arange(n), axis] = np.sign(u[np.arange(n), axis]) * np.array([20.0, 15.0])[axis]
    return np.c_[u, np.full(n, 0.5)].astype(np.float32)


def _frames(n=6, empty=(), seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        scan = np.zeros((0, 4), np.float32) if k in empty else _box_scan(rng)
        out.append(
            Frame(
                scan,
                np.array([1.0, 0.0, 0.0]),
                np.array([0.0, 0.0, 0.02]),
                0.0 if k == 0 else 0.1,
                k,
            )
        )
    return out


def _slam(**kw):
    base = dict(
        particles=30,
        scored_points=200,
        min_range=1.0,
        max_range=40.0,
        downsample_voxel=0.5,
        capacity=2**12,
        seed=1,
    )
    base.update(kw)
    return ParticleSLAM3D(SLAM3DConfig.of(backend="numpy", **base))


@pytest.mark.parametrize("scan", ["empty", "zeros", "far", "few"])
def test_degenerate_frame_skips_scoring_and_keeps_the_motion_prediction(scan):
    frames = _frames()
    n = {"empty": 0, "zeros": 500, "far": 500, "few": MIN_SCAN_POINTS - 1}[scan]
    bad = {
        "empty": np.zeros((0, 4)),
        "zeros": np.zeros((n, 4)),
        "far": np.c_[np.full((n, 3), 1e10), np.ones(n)],
        "few": frames[3].scan[:n],
    }[scan]
    frames[3].scan = bad.astype(np.float32)
    slam = _slam()
    for f in frames[:3]:
        slam.register_frame(f)
    before, map_size = slam.poses[-1].copy(), len(slam.map)
    weights = slam.log_weights.copy()
    pose = slam.register_frame(frames[3])
    assert slam.n_skipped_frames == 1
    assert len(slam.map) == map_size  # nothing merged
    np.testing.assert_array_equal(slam.log_weights, weights)  # not scored
    expected = before @ np.linalg.inv(slam.dr_poses[-2]) @ slam.dr_poses[-1]
    # the motion prediction (the dead-reckoning increment)
    np.testing.assert_allclose(pose, expected, atol=1e-9)
    for f in frames[4:]:
        slam.register_frame(f)
    assert slam.n_skipped_frames == 1
    assert np.all(np.isfinite(slam.trajectory)) and np.all(np.isfinite(slam.log_weights))


def test_degenerate_first_frame_waits_for_a_scan_to_start_the_map():
    slam = _slam()
    for f in _frames(empty=(0, 1)):
        slam.register_frame(f)
    assert slam.n_skipped_frames == 2 and len(slam.map) > 0
    assert np.all(np.isfinite(slam.trajectory))


@pytest.mark.parametrize(
    "field,value",
    [
        ("velocity", np.nan),
        ("velocity", np.inf),
        ("velocity", 1e300),
        ("angular_rate", np.nan),
        ("angular_rate", -np.inf),
        ("angular_rate", 1e3),
    ],
)
def test_register_frame_rejects_non_finite_or_impossible_imu(field, value):
    frames = _frames(n=3)
    getattr(frames[2], field)[0] = value
    slam = _slam()
    slam.register_frame(frames[0])
    slam.register_frame(frames[1])
    with pytest.raises(
        ValueError, match=f"IMU {field} \\(frame 2\\) must be finite and within"
    ):
        slam.register_frame(frames[2])


# ------------------------------------------------------------------------------------------------ hard roads
@pytest.fixture(scope="module")
def hard_drive(tmp_path_factory):
    """:func:`slamlib.synth.roads.hard_road` as a KITTI raw drive: a swept LIDAR (1,000 columns), wandering IMU
    biases."""
    from slamlib.kitti.raw import KittiRawDrive
    from slamlib.synth import WANDERING_BIASES, Hdl64, write_drive
    from slamlib.synth.roads import hard_road

    base = tmp_path_factory.mktemp("hard")
    write_drive(
        base,
        hard_road(),
        frames=None,
        seed=1,
        progress=False,
        distortion=True,
        noise=WANDERING_BIASES,
        lidar=Hdl64(columns=1000),
    )
    return KittiRawDrive(base, "2011_09_26", 1)


def _tilt_errors_deg(frames, T_velo_imu):
    """The default filter run on ``frames``: each frame's roll-and-pitch error (degrees) and the run."""
    from slamlib.metrics import tilt_errors
    from slamlib.slam3d.run import run_drive

    run = run_drive(frames, None, T_velo_imu=T_velo_imu, progress=False)
    return np.degrees(tilt_errors(run.poses, run.ground_truth)), run


def test_the_default_holds_roll_and_pitch_through_braking_a_hairpin_and_a_climb(
    hard_drive,
):
    """The default filter on :func:`slamlib.synth.roads.hard_road`: no frame's roll or pitch is more than 1 degree
    off the truth, and the guard never steps the prior back."""
    from slamlib.synth.roads import hard_road, road_statistics

    s = road_statistics(hard_road())
    assert s["longitudinal"].min() < -6.0  # hard braking
    assert np.degrees(np.abs(s["roll"]).max()) > 6.0  # the hairpin's body roll
    assert np.abs(s["grade"]).max() > 0.115  # a 12 % climb
    assert hard_road().velocity_body(0.0)[0, 0] == pytest.approx(
        7.5, abs=0.05
    )  # moving at once
    error, run = _tilt_errors_deg(hard_drive, hard_drive.T_velo_imu)
    assert len(error) > 300
    assert error.max() < 1.0, (
        f"roll/pitch {error.max():.2f} deg off at frame {error.argmax()}"
    )
    assert run.slam.prior.n_stepped_back == 0


def test_the_guard_lets_the_scan_decide_while_the_accelerometer_reads_a_wrong_up(
    hard_drive,
):
    """Four seconds (frames 100-139, the climb) of an accelerometer that reads its specific force turned 5 degrees
    in roll, as an acceleration read as tilt would: the guard steps the prior back within a few frames of the
    window filling with it and holds it back while it lasts, every frame's roll and pitch stay within 1 degree,
    and the prior holds again after. (Without the guard the filter followed the wrong up to 5.7 degrees, and,
    the calibration having taken it for bias and the world's tilt, on to 22 degrees after it had ended.)"""
    import dataclasses

    wrong = rpy_to_matrix([np.radians(5.0), 0.0, 0.0])
    bad = range(100, 140)

    def frames():
        for k, frame in enumerate(hard_drive):
            if k in bad:
                frame = dataclasses.replace(
                    frame, specific_force=wrong @ frame.specific_force
                )
            yield frame

    error, run = _tilt_errors_deg(list(frames()), hard_drive.T_velo_imu)
    prior = run.slam.prior
    assert error.max() < 1.0, (
        f"roll/pitch {error.max():.2f} deg off at frame {error.argmax()}"
    )
    assert (
        len(bad) // 2 < prior.n_stepped_back < len(bad) + 40
    )  # the window's 2 s drain the bad samples
    assert not prior.stepped_back and prior.held_up() is not None


# The default filter's trajectories, committed (tests/golden/): any change to the code that moves the default by one
# bit fails here. A deliberate change of the default regenerates them (SLAMLIB_WRITE_GOLDEN=1) and says why.
GOLDEN = Path(__file__).parent / "golden" / "default_trajectories.npz"
GOLDEN_LIDAR_FRAMES = 150  # LIDAR-only: the hard road's first 15 s


def _golden_runs(hard_drive):
    """The default on the hard road with its IMU, and LIDAR-only (its swept scans as odometry-layout frames, no
    IMU) on its first :data:`GOLDEN_LIDAR_FRAMES` frames: ``{name: poses (N, 4, 4)}``."""
    from slamlib.kitti.sequence import OdometryFrame
    from slamlib.slam3d.run import run_drive

    frames = list(hard_drive)
    scans = [
        OdometryFrame(
            f.index, f.time_s, f.dt, f.scan, f.T_w_velo, f.velodyne_path, swept=f.swept
        )
        for f in frames[:GOLDEN_LIDAR_FRAMES]
    ]
    return {
        "imu": run_drive(
            frames, None, T_velo_imu=hard_drive.T_velo_imu, progress=False
        ).poses,
        "lidar_only": run_drive(scans, None, progress=False).poses,
    }


def test_the_default_reproduces_its_committed_trajectories_to_the_last_bit(hard_drive):
    runs = _golden_runs(hard_drive)
    if os.environ.get("SLAMLIB_WRITE_GOLDEN") == "1":
        GOLDEN.parent.mkdir(exist_ok=True)
        np.savez_compressed(GOLDEN, **runs)
    golden = np.load(GOLDEN)
    assert set(golden.files) == set(runs)
    for name, poses in runs.items():
        np.testing.assert_array_equal(poses, golden[name], err_msg=name)
