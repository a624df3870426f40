"""Tests of the synthetic KITTI drive generator (slamlib.synth): layout, ground truth, sensor statistics, noise,
and writing over existing folders."""

import json

import numpy as np
import pykitti
import pytest

from slamlib.kitti.oxts import OxtsPacket, poses_from_packets
from slamlib.kitti.scan_stats import elevation_fractions
from slamlib.kitti.timestamps import read_timestamps_ns
from slamlib.odometry import dead_reckon
from slamlib.paths import kitti_sample_dir
from slamlib.synth import (
    WANDERING_BIASES,
    ZERO_NOISE,
    Hdl64,
    ImuNoise,
    hdl64_elevations,
    kitti_route,
    loop_route,
    oxts_packets,
    ray_directions,
    resolve_route,
    simulate_scan,
    write_drive,
)
from slamlib.synth.writer import drive_dir

FAST_LIDAR = Hdl64(columns=500)


@pytest.fixture(scope="module")
def tiny_drive(tmp_path_factory):
    base = tmp_path_factory.mktemp("synth")
    write_drive(base, "07", frames=(0, 5), seed=3, progress=False)
    return base


def test_layout_is_kitti_raw(tiny_drive):
    d = drive_dir(tiny_drive, "2011_09_26", 1)
    for name in (
        "calib_imu_to_velo.txt",
        "calib_velo_to_cam.txt",
        "calib_cam_to_cam.txt",
    ):
        assert (tiny_drive / "2011_09_26" / name).read_bytes() == (
            kitti_sample_dir() / "raw" / "2011_09_26" / name
        ).read_bytes()
    assert sorted(p.name for p in (d / "oxts" / "data").iterdir()) == [
        f"{i:010d}.txt" for i in range(5)
    ]
    assert sorted(p.name for p in (d / "velodyne_points" / "data").iterdir()) == [
        f"{i:010d}.bin" for i in range(5)
    ]
    for name in ("timestamps.txt", "timestamps_start.txt", "timestamps_end.txt"):
        lines = (d / "velodyne_points" / name).read_text().splitlines()
        assert len(lines) == 5 and all(
            len(x) == 29 and x.startswith("2011-09-26 ") for x in lines
        )
    assert (d / "oxts" / "dataformat.txt").exists()


def test_pykitti_loads_and_ground_truth_matches_route(tiny_drive):
    data = pykitti.raw(str(tiny_drive), "2011_09_26", "0001")
    assert len(data.oxts) == 5 and len(data.velo_files) == 5
    scan = data.get_velo(2)
    assert scan.shape[1] == 4 and scan.dtype == np.float32 and len(scan) > 50000
    route, _ = resolve_route("07", (0, 5))
    ns = read_timestamps_ns(
        drive_dir(tiny_drive, "2011_09_26", 1) / "oxts" / "timestamps.txt"
    )
    truth = route.pose(route.t0 + (ns - ns[0]) * 1e-9)
    T0 = data.oxts[0].T_w_imu
    for k, o in enumerate(data.oxts):
        T = np.linalg.inv(T0) @ o.T_w_imu
        assert np.abs(T[:3, 3] - truth[k, :3, 3]).max() < 1e-3
        assert np.abs(T[:3, :3] - truth[k, :3, :3]).max() < 1e-6


def test_deterministic_from_seed(tmp_path):
    a = write_drive(
        tmp_path / "a", "loop", frames=3, seed=7, lidar=FAST_LIDAR, progress=False
    )[0]
    b = write_drive(
        tmp_path / "b", "loop", frames=3, seed=7, lidar=FAST_LIDAR, progress=False
    )[0]
    c = write_drive(
        tmp_path / "c", "loop", frames=3, seed=8, lidar=FAST_LIDAR, progress=False
    )[0]
    rel = "2011_09_26/2011_09_26_drive_0001_sync/velodyne_points/data/0000000002.bin"
    assert (a / rel).read_bytes() == (b / rel).read_bytes()
    assert (a / rel).read_bytes() != (c / rel).read_bytes()


#: Five places along the default route (KITTI 07 key frames), each written into its own folder with seed 3.
PLACES = [(0, 5), (50, 55), (100, 105), (200, 205), (250, 255)]


def test_scan_statistics_close_to_real(tiny_drive, tmp_path):
    """Points per scan and the elevation histogram, averaged along the route, within 20 % of the real scans'.

    The real sample is one place (stop-and-go traffic); a single synthetic place differs more, mostly in the
    top bin (sky or facade at the horizon), so the statistic is taken over five places of the route.
    """
    real = [
        np.fromfile(p, np.float32).reshape(-1, 4)
        for p in sorted((kitti_sample_dir() / "velodyne_sample").glob("*.bin"))
    ]
    syn = []
    for k, frames in enumerate(PLACES):
        base = (
            tiny_drive
            if frames == (0, 5)
            else write_drive(
                tmp_path / str(k), "07", frames=frames, seed=3, progress=False
            )[0]
        )
        data = pykitti.raw(str(base), "2011_09_26", "0001")
        syn += [data.get_velo(k) for k in range(5)]
    n_real = np.mean([len(s) for s in real])
    n_syn = np.mean([len(s) for s in syn])
    assert abs(n_syn - n_real) < 0.2 * n_real
    f_real = np.mean([elevation_fractions(s) for s in real], axis=0)
    f_syn = np.mean([elevation_fractions(s) for s in syn], axis=0)
    assert np.all(np.abs(f_syn - f_real) < 0.2 * f_real), (f_syn, f_real)
    assert 0 <= syn[0][:, 3].min() and syn[0][:, 3].max() < 1


def test_ego_vehicle_hides_only_the_lowest_rings():
    """As in the real scans: the upper block and the upper lower-block rings see all round (the real rings above
    -19 deg lose under 10 %, the model under 15 %); the lowest rings lose about half their points behind the car
    (real: 41-46 %)."""
    d = ray_directions(Hdl64())
    elevation = np.degrees(np.arcsin(d[:, 2]))
    e = np.degrees(hdl64_elevations())
    kept = np.array([(np.abs(elevation - x) < 1e-3).sum() for x in e]) / Hdl64().columns
    assert np.all(kept[e > -19] > 0.85)
    assert np.all(kept[:32] == 1.0)
    assert 0.3 < kept[-1] < 0.7


def test_timestamps_like_kitti(tiny_drive):
    d = drive_dir(tiny_drive, "2011_09_26", 1)
    v = read_timestamps_ns(d / "velodyne_points" / "timestamps.txt")
    o = read_timestamps_ns(d / "oxts" / "timestamps.txt")
    s = read_timestamps_ns(d / "velodyne_points" / "timestamps_start.txt")
    e = read_timestamps_ns(d / "velodyne_points" / "timestamps_end.txt")
    dt = np.diff(v) * 1e-9
    assert np.all((dt > 0.1025) & (dt < 0.1038)) and np.std(dt) > 0
    assert np.all((o - v > 10e6) & (o - v < 22e6))
    assert np.all(s < v) and np.all(v < e) and np.all(s[1:] == e[:-1])


def _drift(noise, seed=0):
    route = kitti_route("07", (0, 400))
    t = np.arange(0, route.t1, 0.10315)
    o = oxts_packets(route, t, noise, seed=seed)
    D = dead_reckon(o[:, 8:11], o[:, 20:23], np.r_[0, np.diff(t)])
    T = route.pose(t)
    length = np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=1).sum()
    return np.linalg.norm(D[-1, :3, 3] - T[-1, :3, 3]) / length


def test_dead_reckoning_drift_default_noise_several_percent():
    assert 0.02 < _drift(ImuNoise()) < 0.2


def test_dead_reckoning_drift_zero_noise_tiny():
    assert _drift(ZERO_NOISE) < 1e-3


def test_oxts_pose_fields_exact_on_loop():
    r = loop_route()
    t = np.linspace(0, r.t1, 200)
    o = oxts_packets(r, t, ImuNoise(), seed=1, enu_yaw0=0.0)
    P = poses_from_packets([OxtsPacket(*x) for x in o])
    T = r.pose(t)
    assert np.abs(P[:, :3, 3] - T[:, :3, 3]).max() < 1e-3
    assert np.abs(P[:, :3, :3] - T[:, :3, :3]).max() < 1e-6
    assert np.all(o[:, 25] == 4) and o.shape == (200, 30)


def test_route_07_is_planar_z_up():
    r = kitti_route("07")
    p = r.position(np.linspace(r.t0, r.t1, 1000))
    assert 650 < r.length() < 740  # KITTI reports 694.7 m for sequence 07
    assert np.ptp(p[:, 2]) < 0.05 * np.ptp(p[:, :2], axis=0).max()
    f = r.specific_force_body(np.linspace(r.t0, r.t1, 200))
    assert abs(np.median(f[:, 2]) - 9.81) < 0.3


def test_kitti_route_rejects_an_empty_selection_clearly():
    with pytest.raises(ValueError, match="key frames 0..1100"):
        kitti_route("07", (2000, 2100))


def test_bias_walk_is_a_wiener_process_sampled_at_the_times():
    """``bias_walk``: zero at the first time; increments ``q sqrt(dt) N(0, 1)`` per axis, independent (over 4,000
    walks on uneven times, the variance at each time is ``q^2 (t - t_0)`` within sampling error and successive
    increments are uncorrelated); ``q = 0`` draws nothing."""
    from slamlib.synth.oxts import bias_walk

    t = np.array([0.0, 0.1, 0.35, 1.0, 3.0])
    rng = np.random.default_rng(40)
    walks = np.stack([bias_walk(t, 0.2, rng) for _ in range(4000)])  # (4000, 5, 3)
    assert np.all(walks[:, 0] == 0.0)
    # per time, averaged over the 3 axes
    var = walks.reshape(4000, 5, 3).var(axis=0).mean(axis=1)
    np.testing.assert_allclose(var[1:], 0.04 * t[1:], rtol=0.06)
    inc = np.diff(walks, axis=1)
    r = np.corrcoef(inc[:, 1, 0], inc[:, 2, 0])[0, 1]
    assert abs(r) < 0.05
    state = rng.bit_generator.state
    assert np.all(bias_walk(t, 0.0, rng) == 0.0) and rng.bit_generator.state == state


def test_wandering_biases_change_only_velocity_and_gyro_fields():
    """With :data:`WANDERING_BIASES` the packets equal the default noise's in every field but the velocities and
    the two gyro groups, which both carry the same walk; the walk's spread after 600 s is ``q sqrt(600)``."""
    r = kitti_route("07", (0, 60))
    t = np.linspace(r.t0, r.t1, 60)
    base, walk = (
        oxts_packets(r, t, ImuNoise(), seed=3),
        oxts_packets(r, t, WANDERING_BIASES, seed=3),
    )
    same = np.r_[0:8, 11:17, 23:30]
    np.testing.assert_array_equal(walk[:, same], base[:, same])
    d_xyz, d_flu = walk[:, 17:20] - base[:, 17:20], walk[:, 20:23] - base[:, 20:23]
    np.testing.assert_allclose(d_xyz, d_flu, atol=1e-15)
    assert np.all(d_xyz[0] == 0) and np.all(np.abs(d_xyz[1:]).max(axis=0) > 0)
    assert (
        np.all(walk[0, 8:11] == base[0, 8:11])
        and np.abs(walk[1:, 8:11] - base[1:, 8:11]).max() > 0
    )
    ends = np.array(
        [
            oxts_packets(r, np.array([0.0, 600.0]), WANDERING_BIASES, seed=s)[1, 20:23]
            - oxts_packets(r, np.array([0.0, 600.0]), ImuNoise(), seed=s)[1, 20:23]
            for s in range(400)
        ]
    )
    assert ends.std() == pytest.approx(
        WANDERING_BIASES.gyro_bias_walk * np.sqrt(600.0), rel=0.1
    )


def test_oxts_stamps_follow_the_real_sawtooth():
    """The synthetic OXTS stamps are matched to the scans as in real drive 0001: on a 10 ms grid (every interval
    within 0.5 ms of 100 or 110 ms, about 31.5 % = 3.15 / 10 of them 110 ms), 11.5-24.5 ms after the scan stamp,
    the delay shrinking by 3.15 ms a frame between 10 ms jumps; the real drive's stamps pass the same checks."""
    from slamlib.synth.writer import frame_timestamps_ns

    real = kitti_sample_dir() / "raw" / "2011_09_26" / "2011_09_26_drive_0001_sync"
    real_o = read_timestamps_ns(real / "oxts" / "timestamps.txt")
    real_v = read_timestamps_ns(real / "velodyne_points" / "timestamps.txt")
    syn = frame_timestamps_ns(300, "2011_09_26", np.random.default_rng(7))
    for o, v in ((real_o, real_v), (syn["oxts"], syn["velo"])):
        do, delay = np.diff(o) * 1e-6, (o - v) * 1e-6
        assert np.all(np.minimum(np.abs(do - 100), np.abs(do - 110)) < 0.5)
        assert 0.25 < np.mean(do > 105) < 0.4
        assert np.all((delay > 11.5) & (delay < 24.5))
        steps = np.diff(delay)
        assert np.all((np.abs(steps + 3.15) < 0.6) | (np.abs(steps - 6.85) < 0.6))


def test_a_scene_of_boxes_is_hit_where_its_faces_are():
    from slamlib.synth import Scene

    scene = Scene.from_boxes(
        [((10.0, -2.0, 0.0), (10.5, 2.0, 3.0)), ((-8.0, -1.0, 0.0), (-7.0, 1.0, 1.0))]
    )
    assert scene.n_triangles == 24 and set(scene.kind) == {Scene.KINDS.index("wall")}
    lidar = Hdl64(columns=360, beam_stride=4, sigma_range=0.0, dropout=0.0)
    origin = np.eye(4)
    origin[2, 3] = 0.5
    scan = simulate_scan(
        scene.raycasting_scene(), scene.albedo, origin, np.random.default_rng(0), lidar
    )
    ahead = scan[(np.abs(scan[:, 1]) < 1.5) & (scan[:, 0] > 0)]
    behind = scan[(np.abs(scan[:, 1]) < 0.5) & (scan[:, 0] < 0)]
    np.testing.assert_allclose(ahead[:, 0], 10.0, atol=1e-4)  # the near face of each box
    np.testing.assert_allclose(behind[:, 0], -7.0, atol=1e-4)
    with pytest.raises(ValueError, match="hi > lo"):
        Scene.from_boxes([((0, 0, 0), (1, 0, 1))])


def test_default_drive_is_realistic_unless_asked_for_the_still_one(tmp_path, monkeypatch):
    """``default_drive()`` writes swept scans, KITTI-city traffic and wandering biases; ``realism=False`` none of
    them, into its own cache folder; a ``noise`` given wins over either default."""
    from slamlib.synth import KITTI_CITY
    from slamlib.synth import drive as drive_module

    monkeypatch.setenv("SLAMLIB_CACHE", str(tmp_path))
    calls = []
    monkeypatch.setattr(
        drive_module, "write_drive", lambda basedir, *a, **kw: calls.append((basedir, kw))
    )
    drive_module.default_drive(progress=False)
    drive_module.default_drive(progress=False, realism=False)
    drive_module.default_drive(progress=False, noise=ZERO_NOISE)
    (real_dir, real), (still_dir, still), (_, quiet) = calls
    assert (
        real["distortion"] is True
        and real["traffic"] == KITTI_CITY
        and real["noise"] == WANDERING_BIASES
    )
    assert (
        still["distortion"] is False
        and still["traffic"] is None
        and still["noise"] == ImuNoise()
    )
    assert quiet["distortion"] is True and quiet["noise"] == ZERO_NOISE
    assert len({real_dir, still_dir, calls[2][0]}) == 3


# ------------------------------------------- writing over existing folders: the user's files kept, stale frames dropped


def _write(base, frames=3, seed=0, **kw):
    from slamlib.synth import Hdl64, write_drive

    return write_drive(
        base,
        "loop",
        frames=frames,
        seed=seed,
        lidar=Hdl64(columns=100),
        progress=False,
        **kw,
    )


def _drive_files(ddir):
    return {
        str(p.relative_to(ddir)): p.read_bytes()
        for p in sorted(ddir.rglob("*"))
        if p.is_file()
    }


def test_write_drive_refuses_a_folder_that_is_not_synthetic(tmp_path):
    from slamlib.synth.writer import drive_dir

    ddir = drive_dir(tmp_path, "2011_09_26", 1)
    ddir.mkdir(parents=True)
    (ddir / "real.bin").write_bytes(b"real data")
    with pytest.raises(FileExistsError, match="not a slamlib synthetic drive"):
        _write(tmp_path)
    assert [p.name for p in ddir.iterdir()] == ["real.bin"] and not (
        tmp_path / "2011_09_26" / "calib_imu_to_velo.txt"
    ).exists()


def test_write_drive_refuses_differing_calibration_before_writing(tmp_path):
    from slamlib.synth.writer import drive_dir

    (tmp_path / "2011_09_26").mkdir()
    calib = tmp_path / "2011_09_26" / "calib_imu_to_velo.txt"
    calib.write_text("R: 1 0 0 0 1 0 0 0 1\nT: 0 0 0\n")
    with pytest.raises(FileExistsError, match="differs"):
        _write(tmp_path)
    assert (
        calib.read_text().startswith("R: 1 0 0")
        and not drive_dir(tmp_path, "2011_09_26", 1).exists()
    )


def test_write_drive_into_an_empty_folder(tmp_path):
    from slamlib.synth.writer import MARKER, drive_dir

    drive_dir(tmp_path, "2011_09_26", 1).mkdir(parents=True)
    _write(tmp_path)
    assert (drive_dir(tmp_path, "2011_09_26", 1) / MARKER).is_file()


def test_rewriting_a_synthetic_drive_keeps_the_users_files_and_drops_stale_frames(
    tmp_path,
):
    from slamlib.kitti import KittiRawDrive
    from slamlib.synth.writer import MARKER, PARTIAL_MARKER, drive_dir

    _write(tmp_path, frames=5)
    ddir = drive_dir(tmp_path, "2011_09_26", 1)
    (ddir / "notes.txt").write_text("my notes")
    (ddir / "out").mkdir()
    (ddir / "out" / "slam_poses.txt").write_text("my run")
    (ddir / "oxts" / "README").write_text("mine too")
    _write(tmp_path, frames=3, seed=1)
    assert (ddir / "notes.txt").read_text() == "my notes" and (
        ddir / "out" / "slam_poses.txt"
    ).read_text() == "my run"
    assert (ddir / "oxts" / "README").read_text() == "mine too"
    assert (
        json.loads((ddir / MARKER).read_text())["seed"] == 1
        and not (ddir / PARTIAL_MARKER).exists()
    )
    # frames 3 and 4 of the first drive are gone
    assert len(KittiRawDrive(tmp_path, "2011_09_26", 1)) == 3
    fresh = tmp_path / "fresh"
    _write(fresh, frames=3, seed=1)
    mine = {
        k: v
        for k, v in _drive_files(ddir).items()
        if k not in ("notes.txt", "out/slam_poses.txt", "oxts/README")
    }
    assert mine == _drive_files(drive_dir(fresh, "2011_09_26", 1))


class _Interrupt(BaseException):
    pass


def test_an_interrupted_drive_is_redone_by_the_next_synth(tmp_path, monkeypatch):
    import slamlib.synth.drive
    from slamlib.cli import main
    from slamlib.synth.writer import MARKER, PARTIAL_MARKER, drive_dir, write_scan

    calls = []

    def write_two_then_stop(*a, **k):
        if len(calls) == 2:
            raise _Interrupt
        calls.append(1)
        write_scan(*a, **k)

    args = [
        "synth",
        "--out",
        str(tmp_path / "o"),
        "--route",
        "loop",
        "--frames",
        "4",
        "--columns",
        "100",
        "--no-progress",
    ]
    with monkeypatch.context() as mp:
        mp.setattr(slamlib.synth.drive, "write_scan", write_two_then_stop)
        with pytest.raises(_Interrupt):
            main(args)
    ddir = drive_dir(tmp_path / "o", "2011_09_26", 1)
    # nothing of the interrupted drive: no folder, no temporary, no lock
    assert sorted(p.name for p in ddir.parent.iterdir()) == [
        "calib_cam_to_cam.txt",
        "calib_imu_to_velo.txt",
        "calib_velo_to_cam.txt",
    ]
    assert main(args) == 0
    # a drive left half written by an older slamlib: its partial marker makes it the generator's
    (ddir / MARKER).rename(ddir / PARTIAL_MARKER)
    (ddir / "velodyne_points" / "data" / "0000000003.bin").unlink()
    (ddir / "notes.txt").write_text("my notes")
    assert main(args) == 0  # before: "not a slamlib synthetic drive"
    assert (ddir / MARKER).is_file() and not (ddir / PARTIAL_MARKER).exists()
    assert (ddir / "notes.txt").read_text() == "my notes"
    assert main(args[:2] + [str(tmp_path / "fresh")] + args[3:]) == 0
    mine = _drive_files(ddir)
    del mine["notes.txt"]
    assert mine == _drive_files(drive_dir(tmp_path / "fresh", "2011_09_26", 1))
