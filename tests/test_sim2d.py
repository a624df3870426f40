"""The 2D particle SLAM: world and ray caster, each step alone, the two maps, and the filter over whole runs."""

import numpy as np
import pytest

import slamlib.sim2d.steps as steps_2d
from slamlib.contract import check_steps_module
from slamlib.resampling import uniform_log_weights
from slamlib.sim2d import (
    OccupancyGrid2D,
    SensorModel2D,
    World2D,
    cast_rays,
    dead_reckon_2d,
    initialise_particles,
    make_world,
    merge_scan,
    offset_by_motion,
    perturb_with_noise,
    pick_best_particle,
    read_imu,
    read_scan,
    read_timing,
    resample_particles,
    run_slam_2d,
    scan_at,
    score_particles,
    simulate,
    transform_scan,
    wrap_angle,
)


@pytest.fixture(scope="module")
def world():
    return make_world(seed=0)


@pytest.fixture(scope="module")
def recording(world):
    return simulate(world, seed=0, laps=0.35)


def test_steps_module_keeps_the_contract():
    assert check_steps_module(steps_2d) == []


# ------------------------------------------------------------------------------------------ world and sensor
def test_ray_caster_hits_a_known_wall_and_a_known_pillar():
    w = World2D(
        segments=np.array([[[5.0, -10.0], [5.0, 10.0]]]),
        circles=np.array([[0.0, 3.0, 0.5]]),
    )
    r = cast_rays(
        w, (1.0, 0.0), np.array([0.0, np.pi / 4, np.pi / 2, np.pi]), max_range=20.0
    )
    assert r[0] == pytest.approx(4.0)  # straight at the wall
    assert r[1] == pytest.approx(4.0 * np.sqrt(2))  # 45 degrees
    assert r[3] == np.inf  # nothing behind
    r2 = cast_rays(w, (0.0, 0.0), np.array([np.pi / 2]), max_range=20.0)
    assert r2[0] == pytest.approx(2.5)  # pillar at 3 m, radius 0.5
    # beyond max range
    assert cast_rays(w, (1.0, 0.0), np.array([0.0]), max_range=3.0)[0] == np.inf


def test_scan_points_lie_on_the_structure(world):
    pose = np.array([0.0, 0.0, 0.3])
    pts = transform_scan(pose, scan_at(world, pose, SensorModel2D()))  # noise-free
    a, b = world.segments[:, 0], world.segments[:, 1]
    e = b - a
    u = np.clip(
        np.einsum("nsk,sk->ns", pts[:, None] - a[None], e) / np.sum(e**2, 1), 0, 1
    )
    d_seg = np.linalg.norm(
        pts[:, None] - (a[None] + u[..., None] * e[None]), axis=-1
    ).min(axis=1)
    d_circ = np.abs(
        np.linalg.norm(pts[:, None] - world.circles[None, :, :2], axis=-1)
        - world.circles[:, 2]
    ).min(1)
    assert len(pts) > 100 and np.all(np.minimum(d_seg, d_circ) < 1e-6)


def test_simulation_is_deterministic_and_closes_the_loop(world):
    a, b = simulate(world, seed=3, laps=0.2), simulate(world, seed=3, laps=0.2)
    assert np.array_equal(a.true_poses, b.true_poses)
    assert all(
        np.array_equal(f.scan, g.scan) and f.speed == g.speed
        for f, g in zip(a.frames, b.frames)
    )
    c = simulate(world, seed=4, laps=0.2)
    assert not np.array_equal(a.frames[5].scan, c.frames[5].scan)
    full = simulate(world, seed=0, sensors=SensorModel2D(n_beams=8))
    assert (
        np.hypot(*full.true_poses[-1, :2]) < 0.3
        and abs(wrap_angle(full.true_poses[-1, 2])) < 0.05
    )


# ------------------------------------------------------------------------------------------------- steps
def test_initialise_and_read(recording):
    p, lw = initialise_particles(7, pose0=(1.0, 2.0, 0.5))
    assert (
        p.shape == (7, 3) and np.all(p == [1.0, 2.0, 0.5]) and np.allclose(lw, -np.log(7))
    )
    f = recording.frames[3]
    assert (
        read_scan(f).shape == f.scan.shape
        and read_imu(f) == (f.speed, f.yaw_rate)
        and read_timing(f) == f.dt
    )
    assert len(read_scan(f, max_points=50)) <= 50


def test_offset_by_motion_is_the_exact_arc():
    p0 = np.array([[1.0, -2.0, 0.7], [0.0, 0.0, -3.0]])
    v, w, dt = 2.0, 0.8, 0.5
    moved = offset_by_motion(p0, (v, w), dt)
    # fine Euler integration of the unicycle converges to the arc
    x = p0.copy()
    n = 20000
    for _ in range(n):
        x[:, 0] += v * dt / n * np.cos(x[:, 2] + w * dt / n / 2)
        x[:, 1] += v * dt / n * np.sin(x[:, 2] + w * dt / n / 2)
        x[:, 2] += w * dt / n
    assert np.allclose(moved[:, :2], x[:, :2], atol=1e-7)
    assert np.allclose(wrap_angle(moved[:, 2] - x[:, 2]), 0, atol=1e-9)
    straight = offset_by_motion(np.array([0.0, 0.0, np.pi / 2]), (3.0, 0.0), 2.0)
    assert np.allclose(straight, [0.0, 6.0, np.pi / 2])


def test_noise_free_odometry_reproduces_the_ground_truth(world):
    rec = simulate(
        world,
        seed=1,
        laps=0.3,
        sensors=SensorModel2D(
            speed_noise=0, speed_bias=0, yaw_rate_noise=0, yaw_rate_bias=0, n_beams=4
        ),
    )
    assert np.allclose(dead_reckon_2d(rec), rec.true_poses, atol=1e-9)


def test_perturb_with_noise_has_the_requested_spread_in_the_body_frame():
    rng = np.random.default_rng(0)
    p = np.tile([0.0, 0.0, np.pi / 2], (20000, 1))  # heading +y: forward is world y
    out = perturb_with_noise(p, (0.3, 0.1, 0.02), rng)
    # forward noise along world y
    assert np.std(out[:, 1]) == pytest.approx(0.3, rel=0.03)
    assert np.std(out[:, 0]) == pytest.approx(0.1, rel=0.03)
    assert np.std(out[:, 2]) == pytest.approx(0.02, rel=0.03)
    assert np.array_equal(perturb_with_noise(p, (0, 0, 0), rng), p)


def test_transform_scan_is_the_rigid_transform():
    q = np.array([[1.0, 0.0], [0.0, 2.0], [3.0, -1.0]])
    pose = np.array([1.0, 2.0, np.pi / 2])
    assert np.allclose(transform_scan(pose, q), [[1.0, 3.0], [-1.0, 2.0], [2.0, 5.0]])
    many = transform_scan(np.stack([pose, np.zeros(3)]), q)
    assert (
        many.shape == (2, 3, 2)
        and np.allclose(many[1], q)
        and np.allclose(many[0], transform_scan(pose, q))
    )
    # distances between points are kept
    assert np.allclose(
        np.linalg.norm(many[0, 0] - many[0, 2]), np.linalg.norm(q[0] - q[2])
    )


@pytest.mark.parametrize("kind", ["density", "likelihood"])
def test_score_prefers_the_true_pose(world, kind):
    sensors = SensorModel2D()
    grid = OccupancyGrid2D.empty((-12, -8), (32, 24), 0.05, kind=kind)
    rng = np.random.default_rng(0)
    for x in np.linspace(0.0, 1.2, 7):  # a map from seven scans along the route
        pose = np.array([x, 0.0, 0.0])
        merge_scan(grid, pose, scan_at(world, pose, sensors, rng))
    truth = np.array([0.7, 0.05, 0.02])
    scan = scan_at(world, truth, sensors, rng)
    offsets = np.array(
        [
            [0, 0, 0],
            [0.1, 0, 0],
            [0.2, 0, 0],
            [0, 0.1, 0],
            [0, 0, 0.02],
            [-0.1, 0.1, -0.02],
        ]
    )
    s = score_particles(truth + offsets, scan, grid)
    assert s.shape == (6,) and np.argmax(s) == 0 and np.all(s[1:] < s[0] - 5.0), s
    assert np.array_equal(
        score_particles(truth, scan, OccupancyGrid2D.empty((0, 0), (1, 1), 0.1)), [0.0]
    )


def test_merge_scan_changes_the_map_in_place_and_raises_the_field():
    grid = OccupancyGrid2D.empty(
        (-5, -5), (5, 5), 0.1, kind="likelihood", sigma=0.1, n_sat=1
    )
    # world point (1, 2)
    same = merge_scan(grid, np.array([1.0, 0.0, np.pi / 2]), np.array([[2.0, 0.0]]))
    assert same is grid and grid.total == 1
    r, c, inside = grid.cells_of(np.array([1.0, 2.0]))
    assert inside and grid.counts[r, c] == 1
    assert (
        grid.field_at(np.array([1.0, 2.0])) > 0.7
        and grid.field_at(np.array([1.0, 2.5])) < 0.01
    )
    assert (
        grid.point_terms(np.array([[1.0, 2.0]]))[0]
        > grid.point_terms(np.array([[3.0, 2.0]]))[0]
    )
    merge_scan(grid, np.zeros(3), np.array([[100.0, 0.0]]))  # outside the grid: dropped
    assert grid.total == 1


def test_pick_best_and_resample_via_resample_indexes():
    particles = np.arange(12, dtype=float).reshape(4, 3)
    log_w = np.log(np.array([0.1, 0.6, 0.2, 0.1]))
    pose, i = pick_best_particle(particles, log_w)
    assert i == 1 and np.array_equal(pose, particles[1])
    pose[0] = -1.0
    assert particles[1, 0] == 3.0  # a copy, not a view
    out, lw, done = resample_particles(
        particles, log_w, np.random.default_rng(0), ess_fraction=None
    )
    assert done and out.shape == (4, 3) and np.allclose(lw, uniform_log_weights(4))
    assert (
        set(map(tuple, out)) <= set(map(tuple, particles))
        and (out == particles[1]).all(1).sum() >= 2
    )
    kept, lw2, done2 = resample_particles(
        particles, uniform_log_weights(4), np.random.default_rng(0)
    )
    assert not done2 and np.array_equal(kept, particles)


# -------------------------------------------------------------------------------------------------- the filter
@pytest.mark.parametrize("kind", ["density", "likelihood"])
def test_filter_beats_dead_reckoning(world, kind):
    for seed in (0, 1):
        rec = simulate(make_world(seed), seed=seed, laps=0.5)
        res = run_slam_2d(rec, n_particles=100, seed=seed, map_kind=kind)
        assert res.ate < 0.1 and res.ate < res.ate_dead_reckoning / 10, (
            kind,
            seed,
            res.summary(),
        )
        assert res.slam_heading_error.max() < np.radians(2)


def test_run_is_deterministic_by_seed(recording):
    a = run_slam_2d(recording, n_particles=50, seed=7, max_points=60, keep_history=True)
    b = run_slam_2d(recording, n_particles=50, seed=7, max_points=60, keep_history=True)
    c = run_slam_2d(recording, n_particles=50, seed=8, max_points=60)
    assert np.array_equal(a.estimated, b.estimated) and np.array_equal(
        a.world_map.counts, b.world_map.counts
    )
    assert not np.array_equal(a.estimated, c.estimated)
    assert a.particle_history.shape == (len(recording), 50, 3)


def test_bad_input_is_refused():
    with pytest.raises(ValueError):
        OccupancyGrid2D.empty((0, 0), (1, 1), 0.1, kind="voxels")
    with pytest.raises(ValueError):
        initialise_particles(0)
    with pytest.raises(ValueError):
        perturb_with_noise(np.zeros((2, 3)), (-1, 0, 0), np.random.default_rng(0))
    with pytest.raises(ValueError):
        simulate(make_world(0), laps=0)


def test_sim2d_command_prints_both_maps_and_dead_reckoning(capsys):
    from slamlib.cli import main

    assert main(["sim2d", "--laps", "0.15", "--particles", "30", "--beams", "60"]) == 0
    out = capsys.readouterr().out
    assert (
        "SLAM, density" in out and "SLAM, likelihood" in out and "dead reckoning" in out
    )


# ------------------------------------------------------------------ bad options, refused before the run
@pytest.mark.parametrize(
    "option,value",
    [
        ("--laps", "inf"),
        ("--laps", "nan"),
        ("--laps", "0"),
        ("--laps", "1e9"),
        ("--resolution", "nan"),
        ("--resolution", "1e-9"),
        ("--beams", "0"),
        ("--beams", "1000000000"),
        ("--particles", "1000000000"),
        ("--seed", "-1"),
        ("--plot", "FILE/fig.png"),
    ],
)
def test_sim2d_bad_option_is_refused_before_the_run(tmp_path, monkeypatch, option, value):
    import slamlib.sim2d
    from slamlib.cli import main

    monkeypatch.setattr(
        slamlib.sim2d, "run_slam_2d", lambda *a, **k: pytest.fail("the run started")
    )
    monkeypatch.setattr(
        slamlib.sim2d, "simulate", lambda *a, **k: pytest.fail("the simulation started")
    )
    (tmp_path / "FILE").write_text("")
    if option == "--plot":
        value = str(tmp_path / value)
    with pytest.raises(SystemExit) as exc:
        main(["sim2d", option, value])
    assert str(exc.value).startswith(f"slamlib sim2d: {option}"), str(exc.value)


# ------------------------------------------------------------------------------------- a map per particle
def _scans(recording, n):
    return [read_scan(f, max_points=40) for f in recording.frames[1 : n + 1]]


@pytest.mark.parametrize("kind", ["density", "likelihood"])
def test_each_particle_map_is_the_grid_its_own_scans_build(recording, kind):
    """Particle i's map, merged scan by scan at particle i's poses, equals an OccupancyGrid2D merged with the
    same points (counts and field to the bit), scores the same, and is untouched by the other particles'
    merges even where they share tiles."""
    from slamlib.sim2d import ParticleMaps2D

    lo, hi = recording.world.bounds
    template = OccupancyGrid2D.empty(np.subtract(lo, 13), np.add(hi, 13), 0.1, kind=kind)
    maps = ParticleMaps2D(template, 3, tile=8)
    dense = [template.copy() for _ in range(3)]
    offsets = np.array([[0.0, 0.0, 0.0], [0.3, -0.1, 0.02], [0.0, 0.0, 0.0]])
    for k, pts in enumerate(_scans(recording, 6)):
        poses = recording.true_poses[k + 1] + offsets
        poses[2, 0] += 0.05 * k  # particle 2 drifts
        merge_scan(maps, poses, pts)
        for i in range(3):
            merge_scan(dense[i], poses[i], pts)
    probe = transform_scan(recording.true_poses[3] + offsets, _scans(recording, 3)[-1])
    terms = maps.point_terms(probe)
    for i in range(3):
        grid = maps.grid(i)
        assert np.array_equal(grid.counts, dense[i].counts)
        assert np.array_equal(grid.field, dense[i].field)
        assert np.array_equal(terms[i], dense[i].point_terms(probe[i]))
    assert maps.totals.tolist() == [d.total for d in dense]


def test_resampled_maps_share_tiles_and_copy_only_what_they_write(recording):
    """Resampling copies tables, not tiles; a merge copies a shared tile before writing it (the others keep the
    original), tiles nobody holds are recycled, and reference counts always equal the tables' holdings."""
    from slamlib.sim2d import ParticleMaps2D
    from slamlib.sim2d.particle_maps import EMPTY_TILE

    lo, hi = recording.world.bounds
    template = OccupancyGrid2D.empty(np.subtract(lo, 13), np.add(hi, 13), 0.1)
    maps = ParticleMaps2D(template, 4)

    def check_counts():
        held = maps.tables[maps.tables != EMPTY_TILE]
        assert np.array_equal(
            np.bincount(held, minlength=len(maps.refcount)), maps.refcount
        )

    scans = _scans(recording, 3)
    pose = recording.true_poses[1]
    merge_scan(
        maps,
        np.repeat(pose[None], 4, axis=0) + [[0.2 * i, 0, 0] for i in range(4)],
        scans[0],
    )
    check_counts()
    assert maps.distinct_maps() == 4 and maps.disputed_tiles() > 0
    maps.select([1, 1, 1, 1])
    check_counts()
    own = np.count_nonzero(maps.tables[0] != EMPTY_TILE)
    assert (
        maps.live_tiles == own and maps.distinct_maps() == 1
    )  # the others' tiles recycled
    before = [maps.grid(i) for i in range(4)]
    maps.merge(np.zeros((4, 0, 2)))  # an empty scan writes nothing and copies nothing
    assert maps.live_tiles == own
    # only particle 3 merges (the others' points fall outside the grid)...
    outside = np.full((3, len(scans[1]), 2), -1e6)
    placed = transform_scan(recording.true_poses[2] + [0.0, 0.5, 0.0], scans[1])
    maps.merge(np.concatenate([outside, placed[None]]))
    check_counts()
    for i in range(3):  # ...and the maps it shared with the others are unchanged
        assert np.array_equal(maps.grid(i).counts, before[i].counts)
        assert np.array_equal(maps.grid(i).field, before[i].field)
    assert maps.grid(3).total == before[3].total + len(scans[1])
    copied = maps.live_tiles - own
    assert 0 < copied <= np.count_nonzero(maps.tables[3] != EMPTY_TILE)
    assert maps.memory_bytes() < maps.full_copy_bytes() / 4


def test_one_particle_with_its_own_map_is_the_shared_map_filter(recording):
    """With one particle its map is the shared map: both filters give the same estimates and the same map."""
    runs = [
        run_slam_2d(
            recording, n_particles=1, seed=3, max_points=40, per_particle_maps=per
        )
        for per in (False, True)
    ]
    assert np.array_equal(runs[0].estimated, runs[1].estimated)
    assert np.array_equal(runs[0].world_map.counts, runs[1].world_map.counts)
    assert np.array_equal(runs[0].world_map.field, runs[1].world_map.field)


def test_per_particle_maps_beat_dead_reckoning_in_a_fraction_of_full_copies(recording):
    res = run_slam_2d(
        recording, n_particles=20, seed=0, max_points=60, per_particle_maps=True
    )
    assert res.ate < 0.25 * res.ate_dead_reckoning
    assert res.map_bytes.max() < 0.2 * res.particle_maps.full_copy_bytes()
    live = res.particle_maps.live_tiles
    assert 0 <= res.disputed_tiles.min() and res.disputed_tiles.max() <= live


def test_tempering_scales_the_scores(recording):
    lo, hi = recording.world.bounds
    grid = OccupancyGrid2D.empty(np.subtract(lo, 13), np.add(hi, 13), 0.1)
    pts = read_scan(recording.frames[1])
    merge_scan(grid, recording.true_poses[1], pts)
    poses = recording.true_poses[1] + np.array([[0, 0, 0], [0.05, 0, 0], [0, 0.1, 0.01]])
    full = score_particles(poses, pts, grid)
    assert np.allclose(score_particles(poses, pts, grid, tempering=0.25), 0.25 * full)
    with pytest.raises(ValueError, match="tempering"):
        score_particles(poses, pts, grid, tempering=0.0)


def test_the_chapters_figures_keep_their_legends_off_the_data(recording):
    """The world with its scan and the heading lever fill their axes with walls, route and returns: their
    legends hang below the axes, covering no data vertex."""
    import matplotlib.pyplot as plt

    from slamlib.plotstyle import data_under_legend
    from slamlib.sim2d.plot import plot_heading_lever, plot_world

    for fig in (plot_world(recording, frame=5), plot_heading_lever(recording, 5)):
        legends = [ax for ax in fig.axes if ax.get_legend() is not None]
        assert legends and all(data_under_legend(ax) == 0 for ax in legends), fig
        plt.close(fig)
