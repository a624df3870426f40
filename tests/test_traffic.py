"""Moving traffic in the synthetic drives (slamlib.synth.traffic): layout of the movers, and the scans seeing them."""

import hashlib
from pathlib import Path

import numpy as np
import pytest

from slamlib.synth import (
    Hdl64,
    drive_traffic,
    loop_route,
    simulate_scan,
    straight_route,
    write_drive,
    write_sequence,
)
from slamlib.synth.drive import _streams, resolve_route
from slamlib.synth.lidar import (
    MOVER_BLOCKS,
    SCAN_PERIOD_S,
    _sweep_blocks,
    column_time_offsets,
    ray_columns,
)
from slamlib.synth.traffic import (
    CYCLE_LANE,
    CYCLIST_SPEED,
    FOLLOW_GAP_S,
    FOLLOW_MIN_DIST,
    KEEP_RIGHT,
    KINDS,
    LEFT_LANE,
    ONCOMING_SPEED,
    OVERTAKE_EXCESS,
    PEDESTRIAN_SPEED,
    SIDEWALK,
    SIDEWALK_JITTER,
    TrafficConfig,
    build_traffic,
    points_in_boxes,
)
from slamlib.synth.writer import drive_dir, read_marker

TINY = Hdl64(columns=64, beam_stride=4)
SMALL = Hdl64(columns=360, beam_stride=2)
AHEAD, BEHIND, ONCOMING, OVERTAKING, CYCLIST, PEDESTRIAN = range(len(KINDS))
#: SHA-256 of the files of small drives written before traffic existed (commit 33dd4d1, seed 5, 3 frames of the
#: straight route, ``TINY`` LIDAR): traffic=None must keep them byte for byte. Tied to the numpy / open3d versions
#: of the project's environment, like every byte-level check of the generator, and to the CPU's instruction set
#: (numpy's vectorised sin / cos differ in the last bit between AVX2 and AVX-512), so each case holds one digest
#: per machine family, each recorded by running that commit's own code on such a machine.
#: The swept ones re-recorded for synth-4 (the first scan's sweep continues the route's motion before its start,
#: :meth:`Route.pose_extended`; tests/test_sweep_distortion.py checks that change by itself), from commit 99bf131.
GOLDEN = {
    ("drive", False): {
        "4644ac3449cce5c9447507f2f29e793a4e08dcd5fb0d06d01d79a2c0b019b1b0",  # AMD EPYC, AVX2
        "4a04125b7a857a99adba0617861ad3e9852f9043d0ee0031ddd61ac1e24f92b6",
    },  # Xeon, AVX-512
    ("drive", True): {
        "110f60d5ef61b199fbe9662c729850905be60384c1b8f4665459a44e40960ab1",
        "f37d8a373ce6e914e2f82f9fd1f00902039e86f08021bc309bc56edc1f5e6830",
    },
    ("sequence", False): {
        "6789b46f8c6512dbf8739bb47aa548346345ad211e6d930c557d5b467ca49920",
        "37d5187cffac43c4cbf84dc51a4e59754e66e560038030d8a4cde6c6643df2b0",
    },
    ("sequence", True): {
        "f16fe11e9fcae77d499e2f416fab1ccde334885736e9f7c239b17c3eaf3fc12b",
        "a0804e149aeb19131be33168a11d104bcbd4c11d284d34a5cedbf2d3bd95a3c5",
    },
}


def _digest(root: Path) -> str:
    """SHA-256 over every file's relative path and bytes, the generator's markers left out."""
    h = hashlib.sha256()
    for p in sorted(Path(root).rglob("*")):
        if p.is_file() and not p.name.startswith(".slamlib"):
            h.update(str(p.relative_to(root)).encode())
            h.update(p.read_bytes())
    return h.hexdigest()


def _traffic(route, duration, config=TrafficConfig(), seed=1):
    return build_traffic(
        route, route.t0, route.t0 + duration, config, np.random.default_rng(seed)
    )


def _arrays(tr):
    return [
        tr.kind,
        tr.lateral,
        tr.heading,
        tr.size,
        tr.albedo,
        tr.b,
        tr.c,
        tr.t_ref,
        tr.gap,
        tr.t_on,
        tr.t_off,
    ]


def test_deterministic_by_seed():
    r = straight_route()
    a, b, c = _traffic(r, 30, seed=4), _traffic(r, 30, seed=4), _traffic(r, 30, seed=5)
    assert len(a) > 10
    assert all(np.array_equal(x, y) for x, y in zip(_arrays(a), _arrays(b)))
    assert len(a) != len(c) or not np.array_equal(a.b, c.b)
    va, vb = a.mesh(r.t0 + 7.3)[0], b.mesh(r.t0 + 7.3)[0]
    assert va.shape[0] > 0 and np.array_equal(va, vb)


def test_counts_scale_with_density():
    r = straight_route()  # 600 m
    base = TrafficConfig()
    one = np.bincount(_traffic(r, 60, base).kind, minlength=len(KINDS))
    three = np.bincount(_traffic(r, 60, base.scaled(3)).kind, minlength=len(KINDS))
    # a kind's street is the extended centre line (plus speed x duration): never shorter than the route
    assert np.all(one >= np.round(base.per_km() * r.length() / 1000) - 1)
    # every kind but the overtaking cars, which fit only into gaps of the oncoming lane, keeps its rate
    rest = np.arange(len(KINDS)) != OVERTAKING
    assert np.all(one > 0) and np.all(
        np.abs(three[rest] - 3 * one[rest]) <= 0.1 * 3 * one[rest] + 1
    )
    assert len(_traffic(r, 60, base.scaled(0))) == 0
    assert (
        base.scaled(2).density == 2.0
        and base.scaled(2).per_km()[ONCOMING] == 2 * base.oncoming
    )
    with pytest.raises(ValueError):
        TrafficConfig(density=-1.0)


def _tracks(tr, times):
    """Per time: the box dict; and per mover index, its (time, centre, yaw) samples."""
    tracks = {}
    for t in times:
        bx = tr.boxes(t)
        for j, i in enumerate(bx["index"]):
            tracks.setdefault(int(i), []).append((t, bx["centre"][j], bx["yaw"][j]))
    return tracks


def test_lanes_directions_and_speeds_on_a_straight_route():
    """Straight route along +x at 10 m/s: a mover's y is its lateral offset, its yaw 0 (with) or pi (against)."""
    r = straight_route()
    tr = _traffic(r, 60, TrafficConfig(oncoming=8.0, overtaking=5.0).scaled(2))
    times = np.arange(0.0, 60.0, 0.5)
    tracks = _tracks(tr, times)
    seen = set()
    for i, samples in tracks.items():
        if len(samples) < 3:
            continue
        kind = tr.kind[i]
        seen.add(int(kind))
        t = np.array([s[0] for s in samples])
        c = np.array([s[1] for s in samples])
        yaw = np.array([s[2] for s in samples])
        vx = np.diff(c[:, 0]) / np.diff(t)
        ego_x = 10.0 * t
        assert np.allclose(c[:, 2], c[0, 2], atol=1e-6)  # level road
        along = np.cos(yaw) > 0
        if kind in (AHEAD, BEHIND):
            sign = 1 if kind == AHEAD else -1
            assert np.allclose(c[:, 1], 0.0, atol=1e-9) and along.all()
            gap = sign * (c[:, 0] - ego_x)
            assert (
                gap.min() >= FOLLOW_MIN_DIST and gap.max() <= 10.0 * FOLLOW_GAP_S[1] + 1.0
            )
            assert np.allclose(vx, 10.0, atol=0.05)
        elif kind == ONCOMING:
            assert np.allclose(c[:, 1], LEFT_LANE) and not along.any()
            assert np.all(
                (-vx >= ONCOMING_SPEED[0] - 1e-6) & (-vx <= ONCOMING_SPEED[1] + 1e-6)
            )
        elif kind == OVERTAKING:
            assert np.allclose(c[:, 1], LEFT_LANE) and along.all()
            assert np.all(
                (vx - 10.0 >= OVERTAKE_EXCESS[0] - 1e-6)
                & (vx - 10.0 <= OVERTAKE_EXCESS[1] + 1e-6)
            )
        elif kind == CYCLIST:
            assert np.allclose(c[:, 1], CYCLE_LANE) and along.all()
            assert np.all(
                (vx >= CYCLIST_SPEED[0] - 1e-6) & (vx <= CYCLIST_SPEED[1] + 1e-6)
            )
        else:
            speed = np.abs(vx)
            assert np.all(
                (speed >= PEDESTRIAN_SPEED[0] - 1e-6)
                & (speed <= PEDESTRIAN_SPEED[1] + 1e-6)
            )
            # walks the way it faces
            assert np.all(np.sign(vx) == np.where(along[1:], 1, -1))
            # on a sidewalk, keeping to its right: -y of the sidewalk's middle walking along +x, +y walking back
            middle = np.sign(c[:, 1]) * SIDEWALK
            keep = np.where(along, -KEEP_RIGHT, KEEP_RIGHT)
            assert np.all(np.abs(c[:, 1] - middle - keep) <= SIDEWALK_JITTER + 1e-9)
    assert seen == set(range(len(KINDS)))


def test_lanes_follow_a_curved_route():
    """Loop of radius 60 m turning left around (0, 60): a mover ``y`` m to the left is ``60 - y`` m from the centre,
    and its yaw is the circle's tangent (reversed for oncoming cars)."""
    r = loop_route()
    tr = _traffic(r, 40, TrafficConfig().scaled(2))
    checked = 0
    for t in np.arange(1.0, 40.0, 1.0):
        bx = tr.boxes(t)
        rel = bx["centre"][:, :2] - [0.0, 60.0]
        radius = np.linalg.norm(rel, axis=1)
        on_circle = (
            np.abs(tr.line.ego_s(t) - tr.arc_length(t)[bx["index"]])
            < r.length() - tr.line.length
        )
        lateral = tr.lateral[bx["index"]]
        # not on the straight extensions
        keep = on_circle & (np.arctan2(rel[:, 1], rel[:, 0]) > -np.pi / 2 + 0.1)
        assert np.allclose(radius[keep], 60.0 - lateral[keep], atol=0.05)
        tangent = np.arctan2(rel[:, 1], rel[:, 0]) + np.pi / 2
        dyaw = np.angle(np.exp(1j * (bx["yaw"] - tangent)))
        expect = np.where(tr.heading[bx["index"]] > 0, 0.0, np.pi)
        assert np.all(np.abs(np.angle(np.exp(1j * (dyaw - expect))))[keep] < 0.05)
        checked += keep.sum()
    assert checked > 50


#: The ego car's footprint around its IMU, ``(x_min, x_max, half width)`` m, generous: a 4.8 x 1.8 m estate car with
#: the IMU over its rear axle (Geiger et al. IJRR 2013, Fig. 3).
EGO_FOOTPRINT = (-1.5, 3.5, 1.0)


def _corners(centre_xy, yaw, length, width):
    """Footprint corners ``(M, 4, 2)`` of boxes centred at ``centre_xy (M, 2)`` with yaws ``(M,)``."""
    u = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]]) / 2
    local = u[None] * np.stack([length, width], axis=1)[:, None, :]
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    return (
        np.stack(
            [
                c * local[..., 0] - s * local[..., 1],
                s * local[..., 0] + c * local[..., 1],
            ],
            -1,
        )
        + centre_xy[:, None, :]
    )


def _gap(a, b):
    """Distance (m) between convex quadrilaterals ``a (M, 4, 2)`` and ``b (M, 4, 2)``, 0 where they overlap
    (separating axis test over the edge normals; else the least vertex-to-edge distance)."""

    def edges(q):
        return q, np.roll(q, -1, axis=1) - q

    def separated(p, q):
        _, e = edges(p)
        n = np.stack([-e[..., 1], e[..., 0]], -1)  # (M, 4, 2)
        pp = np.einsum("mkd,mjd->mkj", n, p)
        qq = np.einsum("mkd,mjd->mkj", n, q)
        return np.any((pp.max(2) < qq.min(2)) | (qq.max(2) < pp.min(2)), axis=1)

    def vertex_edge(p, q):
        o, e = edges(q)
        d = p[:, :, None, :] - o[:, None, :, :]  # (M, 4 vertices, 4 edges, 2)
        t = np.clip(
            np.einsum("mved,med->mve", d, e) / np.einsum("med,med->me", e, e)[:, None, :],
            0.0,
            1.0,
        )
        return np.linalg.norm(d - t[..., None] * e[:, None], axis=-1).min(axis=(1, 2))

    apart = separated(a, b) | separated(b, a)
    return np.where(apart, np.minimum(vertex_edge(a, b), vertex_edge(b, a)), 0.0)


@pytest.mark.parametrize("route", ["07", "loop", "straight"])
def test_movers_keep_away_from_the_ego_car(route):
    """At every instant of the drive, at three times the default density: every box centre is more than 3 m from the
    ego car (its IMU) and every box's footprint more than 0.5 m from the ego car's (:data:`EGO_FOOTPRINT`); the cars
    in its lane keep at least FOLLOW_MIN_DIST along the route (a chord across a corner can be shorter)."""
    r, n = resolve_route(route, (0, 300) if route == "07" else 300)
    duration = (n - 1) * 0.1
    tr = _traffic(r, duration, TrafficConfig().scaled(3), seed=2)
    x0, x1, half = EGO_FOOTPRINT
    nearest, lane_nearest, gap_nearest = np.inf, np.inf, np.inf
    for t in np.arange(r.t0 - SCAN_PERIOD_S, r.t0 + duration + SCAN_PERIOD_S, 0.02):
        bx = tr.boxes(t)
        if len(bx["index"]) == 0:
            continue
        T = r.pose(t)[0]
        d = np.linalg.norm(bx["centre"][:, :2] - T[:2, 3], axis=1)
        nearest = min(nearest, d.min())
        ego_yaw = np.arctan2(T[1, 0], T[0, 0])
        ego_centre = T[:2, 3] + (x0 + x1) / 2 * np.array(
            [np.cos(ego_yaw), np.sin(ego_yaw)]
        )
        m = len(d)
        ego = _corners(
            np.tile(ego_centre, (m, 1)),
            np.full(m, ego_yaw),
            np.full(m, x1 - x0),
            np.full(m, 2 * half),
        )
        boxes = _corners(
            bx["centre"][:, :2], bx["yaw"], bx["size"][:, 0], bx["size"][:, 1]
        )
        gap_nearest = min(gap_nearest, _gap(ego, boxes).min())
        lane = np.isin(bx["kind"], (AHEAD, BEHIND))
        if lane.any():
            gap = np.abs(tr.arc_length(t)[bx["index"][lane]] - tr.line.ego_s(t))
            lane_nearest = min(lane_nearest, gap.min())
    assert 3.0 < nearest < 4.0  # cyclists ride 3.2 m from the ego lane and are passed
    # an oncoming car on a corner of 07 swings to 0.9 m of the (generous) footprint
    assert 0.5 < gap_nearest < 2.5
    assert lane_nearest >= FOLLOW_MIN_DIST


def test_footprint_gap_helper():
    """_gap on known cases: apart along x by 1 m, touching diagonally at sqrt(2), overlapping."""
    one = np.ones(1)
    a = _corners(np.zeros((1, 2)), np.zeros(1), 2 * one, 2 * one)
    for centre, yaw, expected in [
        ((3.0, 0.0), 0.0, 1.0),
        ((3.0, 3.0), 0.0, np.sqrt(2)),
        ((1.5, 0.5), 0.3, 0.0),
        ((0.0, 1.0 + np.sqrt(2)), np.pi / 4, 0.0),
        ((0.0, 1.5 + np.sqrt(2)), np.pi / 4, 0.5),
    ]:
        b = _corners(np.array([centre]), np.array([yaw]), 2 * one, 2 * one)
        assert _gap(a, b)[0] == pytest.approx(expected, abs=1e-9)


def test_movers_of_one_lane_never_overlap():
    r = straight_route()
    tr = _traffic(r, 60, TrafficConfig().scaled(3), seed=3)
    for t in np.arange(0.0, 60.0, 0.05):
        bx = tr.boxes(t)
        c, size = bx["centre"], bx["size"]
        dx = (
            np.abs(c[:, None, 0] - c[None, :, 0])
            < (size[:, None, 0] + size[None, :, 0]) / 2
        )
        dy = (
            np.abs(c[:, None, 1] - c[None, :, 1])
            < (size[:, None, 1] + size[None, :, 1]) / 2
        )
        overlap = dx & dy
        np.fill_diagonal(overlap, False)
        assert not overlap.any(), f"boxes overlap at t = {t}"


def test_sweep_blocks_bound_the_mover_time_error():
    model = Hdl64(columns=400, beam_stride=8)
    cols = ray_columns(model)
    offsets = column_time_offsets(model)
    seen = np.zeros(len(cols), dtype=int)
    for dt, sel, _ in _sweep_blocks(cols, model, np.zeros((model.columns, 3))):
        assert np.all(
            np.abs(offsets[cols[sel]] - dt) <= SCAN_PERIOD_S / (2 * MOVER_BLOCKS) + 1e-12
        )
        seen[sel] += 1
    assert np.all(seen == 1)


def test_first_four_random_streams_unchanged():
    for seed in (0, 7):
        old = [
            np.random.default_rng(s).integers(2**63, size=3)
            for s in np.random.SeedSequence(seed).spawn(4)
        ]
        new = _streams(seed)
        assert len(new) == 5
        assert all(np.array_equal(o, g.integers(2**63, size=3)) for o, g in zip(old, new))


@pytest.mark.parametrize("layout", ["drive", "sequence"])
@pytest.mark.parametrize("distortion", [False, True])
def test_no_traffic_output_unchanged(tmp_path, layout, distortion):
    if layout == "drive":
        base = write_drive(
            tmp_path,
            "straight",
            frames=3,
            seed=5,
            lidar=TINY,
            progress=False,
            distortion=distortion,
            traffic=None,
        )[0]
    else:
        base = write_sequence(
            tmp_path,
            "straight",
            3,
            frames=3,
            seed=5,
            lidar=TINY,
            progress=False,
            distortion=distortion,
        )[0]
    digest = _digest(base)
    assert digest in GOLDEN[(layout, distortion)], (
        f"{digest}: not the no-traffic output recorded on AMD EPYC / Intel Xeon; on another kind of CPU, record "
        "the digest of commit 33dd4d1's (swept: 99bf131's) code on it before trusting this test"
    )


def test_traffic_without_movers_casts_the_same_scans(tmp_path):
    """Density 0 with the left parking kept: the mover path runs with no movers and must change no byte."""
    off = write_drive(
        tmp_path / "off",
        "straight",
        frames=3,
        seed=5,
        lidar=TINY,
        progress=False,
        distortion=True,
    )[0]
    empty = TrafficConfig(density=0.0, clear_left_parking=False)
    on = write_drive(
        tmp_path / "on",
        "straight",
        frames=3,
        seed=5,
        lidar=TINY,
        progress=False,
        distortion=True,
        traffic=empty,
    )[0]
    assert _digest(off) == _digest(on)
    assert "traffic" not in read_marker(drive_dir(off, "2011_09_26", 1))
    assert read_marker(drive_dir(on, "2011_09_26", 1))["traffic"] == empty.as_dict()


def test_scans_see_the_movers_where_they_are(tmp_path):
    """A straight drive at 3x density without sweep distortion: each scan, put in the world frame with the true
    Velodyne pose, has points inside the cars near the road at that frame's time; the same drive with density 0
    (the same town, no movers) has none there."""
    from slamlib.geometry import invert_pose
    from slamlib.kitti.calib import load_T_velo_imu
    from slamlib.paths import kitti_sample_dir

    cfg, seed, n = TrafficConfig().scaled(3), 11, 4
    on = write_drive(
        tmp_path / "on",
        "straight",
        frames=n,
        seed=seed,
        lidar=SMALL,
        progress=False,
        traffic=cfg,
    )[0]
    off = write_drive(
        tmp_path / "off",
        "straight",
        frames=n,
        seed=seed,
        lidar=SMALL,
        progress=False,
        traffic=TrafficConfig(density=0.0),
    )[0]
    r, t_route, movers = drive_traffic("straight", n, seed, cfg)
    T_imu_velo = invert_pose(load_T_velo_imu(kitti_sample_dir() / "raw" / "2011_09_26"))
    near_cars = 0
    for k in range(n):
        T = r.pose(t_route[k])[0] @ T_imu_velo
        counts = {}
        for name, base in (("on", on), ("off", off)):
            rel = (
                f"2011_09_26/2011_09_26_drive_0001_sync/velodyne_points/data/{k:010d}.bin"
            )
            p = (
                np.fromfile(base / rel, np.float32)
                .reshape(-1, 4)[:, :3]
                .astype(np.float64)
            )
            # points above 0.3 m over each box's base: the road under a (sunk) box does not count
            inside = points_in_boxes(
                p @ T[:3, :3].T + T[:3, 3],
                movers.boxes(t_route[k]),
                margin=0.05,
                lift=0.3,
            )
            counts[name] = inside.sum(axis=1)
        bx = movers.boxes(t_route[k])
        dist = np.linalg.norm(bx["centre"][:, :2] - T[:2, 3], axis=1)
        cars = np.isin(bx["kind"], (AHEAD, BEHIND, ONCOMING, OVERTAKING)) & (dist < 30.0)
        near_cars += cars.sum()
        assert np.all(counts["on"][cars] >= 5), (k, counts["on"][cars])
        assert np.all(counts["off"][cars] == 0)
    assert near_cars >= 2


def test_command_traffic_option(tmp_path):
    """``slamlib synth --traffic [SCALE]``: recorded in the marker with its density; absent without the option."""
    from slamlib.cli import main

    tiny = ["--route", "straight", "--columns", "64", "--frames", "2", "--no-progress"]
    assert main(["synth", "--out", str(tmp_path / "a"), "--traffic", "2.5", *tiny]) == 0
    assert main(["synth", "--out", str(tmp_path / "b"), "--traffic", *tiny]) == 0
    assert main(["synth", "--out", str(tmp_path / "c"), *tiny]) == 0
    markers = [read_marker(drive_dir(tmp_path / x, "2011_09_26", 1)) for x in "abc"]
    assert markers[0]["traffic"] == TrafficConfig().scaled(2.5).as_dict()
    assert markers[1]["traffic"] == TrafficConfig().as_dict()
    assert "traffic" not in markers[2]
    assert (
        main(
            [
                "synth",
                "--out",
                str(tmp_path / "d"),
                "--layout",
                "odometry",
                "--traffic",
                "0.5",
                *tiny,
            ]
        )
        == 0
    )
    assert read_marker(tmp_path / "d" / "sequences" / "00")["traffic"]["density"] == 0.5


@pytest.mark.parametrize("value", ["0", "-1", "11", "nan", "inf"])
def test_command_rejects_a_bad_traffic_scale(tmp_path, capsys, value):
    from slamlib.cli import main

    with pytest.raises(SystemExit) as err:
        main(["synth", "--out", str(tmp_path), "--traffic", value, "--no-progress"])
    assert str(err.value).startswith("slamlib synth: --traffic must be") and value in str(
        err.value
    )
    assert not any(tmp_path.iterdir())


def _box_mesh(centre, size):
    """A yaw-0 box (base centre ``centre``) as ``(vertices, triangles, albedo)`` for ``simulate_scan(movers=...)``."""
    from slamlib.synth.scene import _BOX

    v, f = _BOX
    return (
        (v * size + centre).astype(np.float32),
        f.astype(np.uint32),
        np.full(len(f), 0.5, np.float32),
    )


def _outside(points, centre, size):
    """Distance (m) of each point ``(N, 3)`` outside a yaw-0 box with base centre ``centre``: 0 on or inside it."""
    half = np.asarray(size) / 2
    d = np.abs(points - (np.asarray(centre) + [0.0, 0.0, half[2]])) - half
    return np.linalg.norm(np.clip(d, 0.0, None), axis=1)


def test_swept_scan_sees_a_mover_where_it_is_when_each_column_fires():
    """The sensor drives along x at 10 m/s, a car drives beside it at 14 m/s; with sweep distortion, each point put
    back in the world with its own column's pose lies on the car where the car is at that column's firing time, to
    within the block bound v T / (2 MOVER_BLOCKS) (no range noise); against the car at the frame's instant the
    points lie up to v x 26 ms off (the car is seen a quarter turn before mid-sweep)."""
    import open3d as o3d

    model = Hdl64(columns=720, beam_stride=2, sigma_range=0.0, dropout=0.0)
    # the static world: one triangle far out of range
    far = o3d.t.geometry.RaycastingScene()
    far.add_triangles(
        o3d.core.Tensor(np.array([[500, 0, 0], [500, 1, 0], [500, 0, 1]], np.float32)),
        o3d.core.Tensor(np.array([[0, 1, 2]], np.uint32)),
    )
    ego_v, car_v, size = 10.0, 14.0, np.array([4.2, 1.8, 1.5])
    offsets = column_time_offsets(model)
    poses = np.tile(np.eye(4), (model.columns, 1, 1))
    poses[:, 0, 3] = ego_v * offsets

    def car_at(dt):
        return np.array([car_v * dt, 5.0, -1.73])

    scan = simulate_scan(
        far,
        np.zeros(1, np.float32),
        np.eye(4),
        np.random.default_rng(0),
        model,
        column_poses=poses,
        movers=lambda dts: [_box_mesh(car_at(dt), size) for dt in dts],
    )
    assert len(scan) > 100
    az = np.arctan2(scan[:, 1], scan[:, 0]) % (2 * np.pi)
    col = np.rint(az / (2 * np.pi) * model.columns).astype(int) % model.columns
    world = scan[:, :3].astype(np.float64) + poses[col, :3, 3]
    bound = car_v * SCAN_PERIOD_S / (2 * MOVER_BLOCKS)
    true_time = np.array(
        [
            _outside(world[i : i + 1], car_at(offsets[c]), size)[0]
            for i, c in enumerate(col)
        ]
    )
    assert true_time.max() <= bound + 1e-3
    assert _outside(world, car_at(0.0), size).max() > 0.2


def test_a_one_frame_drive_has_traffic(tmp_path):
    """One frame spans no time: the centre line still covers a second of the route, so movers have a direction."""
    tr = build_traffic(
        straight_route(), 5.0, 5.0, TrafficConfig(), np.random.default_rng(0)
    )
    assert len(tr) > 0 and np.all(np.isfinite(tr.arc_length(5.0)))
    bx = tr.boxes(5.0)
    assert (
        len(bx["index"]) > 0
        and np.all(np.isfinite(bx["centre"]))
        and np.all(np.isfinite(bx["speed"]))
    )
    write_drive(
        tmp_path,
        "straight",
        frames=1,
        seed=1,
        lidar=TINY,
        progress=False,
        traffic=TrafficConfig(),
    )


@pytest.mark.parametrize("distortion", [False, True])
def test_azimuth_culling_changes_no_hit(tmp_path, monkeypatch, distortion):
    """Only the rays within the movers' azimuth spans are cast against them: the same mover hits (every ray's range,
    normal and albedo) and the same bytes as casting every ray."""
    from slamlib.synth import lidar

    cast = lidar._cast_movers
    hits = {"culled": [], "every": []}
    kw = dict(
        frames=2,
        seed=4,
        lidar=Hdl64(columns=2000, beam_stride=4),
        progress=False,
        distortion=distortion,
        traffic=TrafficConfig().scaled(3),
    )
    for name in hits:
        if name == "every":
            monkeypatch.setattr(
                lidar,
                "_azimuth_mask",
                lambda o, spread, azimuth, v, f: np.ones(len(azimuth), bool),
            )
        monkeypatch.setattr(
            lidar,
            "_cast_movers",
            lambda *a, out=hits[name]: out.append(cast(*a)) or out[-1],
        )
        write_drive(tmp_path / name, "07", **kw)
    assert _digest(tmp_path / "culled") == _digest(tmp_path / "every")
    for a, b in zip(hits["culled"], hits["every"]):
        assert np.isfinite(a[0]).sum() > 500
        assert all(np.array_equal(x, y) for x, y in zip(a, b))


def test_left_parking_cleared_and_nothing_else_changed():
    """``parking_sides=(-1,)``: the parked cars on the left (+y of a route along +x) are gone, every other triangle
    of the town is the same (the layout's random draws do not depend on the sides)."""
    from slamlib.synth.scene import build_scene

    p = straight_route().position(np.linspace(0.0, 20.0, 401))
    both, right = build_scene(p, seed=1), build_scene(p, seed=1, parking_sides=(-1,))
    car = 3

    def triangles(scene, keep):
        return scene.vertices[scene.triangles[keep]]

    y_both = triangles(both, both.kind == car)[..., 1].mean(1)
    y_right = triangles(right, right.kind == car)[..., 1].mean(1)
    assert (y_both > 0).sum() > 10 and (y_both < 0).sum() > 10
    assert np.all(y_right < 0) and np.array_equal(
        np.sort(y_right), np.sort(y_both[y_both < 0])
    )
    assert np.array_equal(
        triangles(both, both.kind != car), triangles(right, right.kind != car)
    )


def test_movers_move_smoothly_along_a_kitti_route():
    """The whole 07 route (stops, corners, a standstill at its end where the ground truth jitters): per 0.1 s no mover
    jumps more than 2.5 m (14 m/s on the outside of a corner is ~1.7 m) nor turns more than 0.5 rad."""
    r, _ = resolve_route("07", (0, None))
    tr = build_traffic(r, r.t0, r.t1, TrafficConfig(), np.random.default_rng(0))
    prev, steps = None, 0
    for t in np.arange(r.t0, r.t1, 0.1):
        bx = tr.boxes(t)
        cur = dict(zip(bx["index"], zip(bx["centre"], bx["yaw"])))
        for i in cur.keys() & (prev or {}).keys():
            assert np.linalg.norm(cur[i][0][:2] - prev[i][0][:2]) < 2.5, (
                KINDS[tr.kind[i]],
                t,
            )
            assert abs(np.angle(np.exp(1j * (cur[i][1] - prev[i][1])))) < 0.5, (
                KINDS[tr.kind[i]],
                t,
            )
            steps += 1
        prev = cur
    assert steps > 10000


def test_a_drive_with_traffic_is_deterministic_by_seed(tmp_path):
    kw = dict(
        frames=3,
        lidar=TINY,
        progress=False,
        distortion=True,
        traffic=TrafficConfig().scaled(2),
    )
    a = write_drive(tmp_path / "a", "straight", seed=6, **kw)[0]
    b = write_drive(tmp_path / "b", "straight", seed=6, **kw)[0]
    c = write_drive(tmp_path / "c", "straight", seed=7, **kw)[0]
    assert _digest(a) == _digest(b) != _digest(c)
    d = write_sequence(tmp_path / "d", "straight", 3, seed=6, **kw)[0]
    e = write_sequence(tmp_path / "e", "straight", 3, seed=6, **kw)[0]
    assert _digest(d) == _digest(e)


def test_drive_traffic_gives_the_movers_the_scans_hold(tmp_path):
    """``drive_traffic`` rebuilds the movers a drive's scans were cast with: many scan points lie inside its boxes
    (``Traffic.inside``) at each frame's time; the same drive without movers has only the road under the (sunk)
    boxes there."""
    from slamlib.kitti import KittiRawDrive

    cfg, seed, n = TrafficConfig().scaled(3), 11, 3
    route, t_route, movers = drive_traffic("straight", n, seed, cfg)
    counts = {}
    for name, config in (("on", cfg), ("off", TrafficConfig(density=0.0))):
        drive = KittiRawDrive(
            write_drive(
                tmp_path / name,
                "straight",
                frames=n,
                seed=seed,
                lidar=SMALL,
                progress=False,
                traffic=config,
            )[0],
            "2011_09_26",
            1,
        )
        T0 = route.pose(t_route[0])[
            0
        ]  # the drive's world (the IMU at frame 0) in the route's
        counts[name] = []
        for k, f in enumerate(drive):
            T = T0 @ f.T_w_velo
            p = f.scan[:, :3].astype(np.float64) @ T[:3, :3].T + T[:3, 3]
            # above the road (the IMU is 0.93 m up)
            above = p[:, 2] > route.pose(t_route[k])[0][2, 3] - 0.5
            counts[name].append(int(movers.inside(p[above], t_route[k]).sum()))
    assert min(counts["on"]) > 200 and max(counts["off"]) < 0.05 * min(counts["on"]), (
        counts
    )
