"""Exact values and full error messages of the KITTI odometry sequence reader, the Velodyne scan reader / writer
and the shipped sample pieces (``slamlib.kitti.sequence``, ``slamlib.kitti.velodyne``, ``slamlib.kitti.sample``).

Expected values are computed independently in each test (by hand on tiny inputs, or with numpy / lzma from the
files), error messages are compared whole: slamlib promises errors that name the file and say what is wrong.
"""

from __future__ import annotations

import lzma
import math

import numpy as np
import pytest

from slamlib.errors import DataFormatError
from slamlib.kitti import (
    KittiOdometrySequence,
    read_oxts_packet,
    read_timestamps_ns,
    read_velodyne_scan,
)
from slamlib.kitti.sample import (
    NOMINAL_SCAN_PERIOD,
    REAL_SCANS,
    make_tiny_drive,
    real_scan_frames,
    real_scan_path,
    sample_raw_paths,
)
from slamlib.kitti.sequence import sequence_name
from slamlib.kitti.velodyne import write_velodyne_scan
from slamlib.paths import kitti_sample_dir

# A rotation of 90 degrees about z and a 1 m / 2 m / 3 m offset: a valid, non-trivial calibration Tr.
TR = np.array([[0.0, -1.0, 0.0, 1.0], [1.0, 0.0, 0.0, 2.0], [0.0, 0.0, 1.0, 3.0]])
TIMES = [0.0, 0.25, 0.75]


def _line(values):
    return " ".join(repr(float(v)) for v in np.ravel(values))


def _scan(i):
    """Two points whose values encode the frame number ``i``."""
    return (np.arange(8, dtype=np.float32).reshape(2, 4) + 10 * i).astype(np.float32)


def _pose(k):
    """Camera pose ``k``: a turn of ``0.1 k`` rad about z and a translation ``(k, k / 2, 0)`` m."""
    c, s = math.cos(0.1 * k), math.sin(0.1 * k)
    return np.array([[c, -s, 0.0, float(k)], [s, c, 0.0, 0.5 * k], [0.0, 0.0, 1.0, 0.0]])


def _make_sequence(base, seq="04", times=TIMES, tr=TR, poses=True, scans=None):
    """Write ``base/sequences/<seq>`` by hand: calib.txt (P0..P3, Tr), times.txt, velodyne/*.bin, poses."""
    d = base / "sequences" / seq
    (d / "velodyne").mkdir(parents=True)
    p = _line(np.hstack([np.eye(3), np.zeros((3, 1))]))
    (d / "calib.txt").write_text(
        "".join(f"P{i}: {p}\n" for i in range(4)) + f"Tr: {_line(tr)}\n"
    )
    (d / "times.txt").write_text("".join(f"{t!r}\n" for t in times))
    for i in range(len(times) if scans is None else scans):
        _scan(i).astype("<f4").tofile(d / "velodyne" / f"{i:06d}.bin")
    if poses:
        (base / "poses").mkdir(exist_ok=True)
        (base / "poses" / f"{seq}.txt").write_text(
            "".join(_line(_pose(k)) + "\n" for k in range(len(times)))
        )
    return d


def _tr4():
    T = np.eye(4)
    T[:3] = TR
    return T


@pytest.fixture
def base(tmp_path):
    _make_sequence(tmp_path)
    return tmp_path


def _err(fn, exc=DataFormatError):
    with pytest.raises(exc) as info:
        fn()
    return info.value


# ------------------------------------------------------------------ sequence_name
def test_sequence_name_error_message_is_whole():
    """A non-numeric sequence is refused with the message naming the value (repr)."""
    assert (
        str(_err(lambda: sequence_name("x7"), ValueError))
        == "sequence must be a number like 07, got 'x7'"
    )


# ------------------------------------------------------------------ opening
def test_values_read_at_open(base):
    """calib, Tr (4x4), times and the ground truth inv(Tr) P_k Tr of a hand-written sequence."""
    seq = KittiOdometrySequence(base, 4)
    np.testing.assert_array_equal(seq.calib["Tr"], TR.ravel())
    np.testing.assert_array_equal(seq.Tr, _tr4())
    np.testing.assert_array_equal(seq.times, TIMES)
    assert seq.poses_path == base / "poses" / "04.txt"
    for k in range(3):
        P = np.eye(4)
        P[:3] = _pose(k)
        np.testing.assert_allclose(
            seq.ground_truth[k], np.linalg.inv(_tr4()) @ P @ _tr4(), atol=1e-12
        )


def test_missing_sequence_folder_lists_the_sequences_there(tmp_path):
    """The message lists only the numbered folders under sequences/ (not files, not other names), sorted."""
    for name in ("11", "03", "abc"):
        (tmp_path / "sequences" / name).mkdir(parents=True)
    (tmp_path / "sequences" / "05").write_text("")
    err = _err(lambda: KittiOdometrySequence(tmp_path, 7))
    path = tmp_path / "sequences" / "07"
    assert str(err) == (
        f"{path}: KITTI odometry sequence folder not found (expected basedir/sequences/NN); "
        "sequences there: 03, 11"
    )
    assert err.path == str(path)


def test_missing_sequences_folder_says_none(tmp_path):
    """Without a sequences/ folder the list reads ``none``."""
    err = _err(lambda: KittiOdometrySequence(tmp_path, "00"))
    assert str(err) == (
        f"{tmp_path / 'sequences' / '00'}: KITTI odometry sequence folder not found (expected "
        "basedir/sequences/NN); sequences there: none"
    )


def test_tr_offset_too_far_names_tr_offset(tmp_path):
    """A Tr translation over 100 m is refused, the message calling it Tr's offset."""
    tr = TR.copy()
    tr[:, 3] = [200.0, 0.0, 0.0]
    d = _make_sequence(tmp_path, tr=tr)
    err = _err(lambda: KittiOdometrySequence(tmp_path, 4))
    assert str(err) == (
        f"{d / 'calib.txt'}: calibration Tr's offset = [200.0, 0.0, 0.0] m is farther than 100 m: "
        "not an offset between two sensors of one vehicle"
    )


def test_missing_times_file_message(base):
    """No times.txt: the whole message, naming the file."""
    times = base / "sequences" / "04" / "times.txt"
    times.unlink()
    assert str(_err(lambda: KittiOdometrySequence(base, 4))) == (
        f"{times}: times file not found (one time in seconds per frame; the odometry layout needs it for the "
        "frame intervals)"
    )


def test_empty_times_file_has_no_frames(base):
    """An empty times.txt: DataFormatError naming it (path attribute too), no line."""
    times = base / "sequences" / "04" / "times.txt"
    times.write_text("")
    err = _err(lambda: KittiOdometrySequence(base, 4))
    assert str(err) == f"{times}: holds no times: the sequence has no frames"
    assert err.path == str(times) and err.line is None


def test_one_frame_sequence_opens(tmp_path):
    """One time, one scan, one pose: a valid 1-frame sequence (the lower bound)."""
    _make_sequence(tmp_path, times=[0.5])
    seq = KittiOdometrySequence(tmp_path, 4)
    assert len(seq) == 1 and seq[0].time_s == 0.5 and seq[0].dt == 0.0
    np.testing.assert_array_equal(seq[0].scan, _scan(0))


def test_missing_scan_message(tmp_path):
    """Fewer scans than times: the message says what is missing against what."""
    d = _make_sequence(tmp_path, scans=2)
    assert str(_err(lambda: KittiOdometrySequence(tmp_path, 4))) == (
        f"{d / 'velodyne'}: fewer Velodyne scans than the 3 times in times.txt: 1 of 3 missing "
        "(first: 000002.bin; files are numbered 000000.bin upwards)"
    )


def test_missing_velodyne_folder_message(base):
    """No velodyne/ folder: the message names the folder and what it should hold."""
    d = base / "sequences" / "04" / "velodyne"
    for f in d.iterdir():
        f.unlink()
    d.rmdir()
    assert str(_err(lambda: KittiOdometrySequence(base, 4))) == (
        f"{d}: folder of Velodyne scans not found (needed for 3 frames)"
    )


def test_explicit_poses_file_is_read(base, tmp_path):
    """``poses=`` reads that file, not basedir/poses/NN.txt."""
    other = tmp_path / "gt.txt"
    P = np.eye(4)
    P[:3, 3] = [5.0, 6.0, 7.0]
    other.write_text("".join(_line(P[:3]) + "\n" for _ in range(3)))
    seq = KittiOdometrySequence(base, 4, poses=other)
    assert seq.poses_path == other
    np.testing.assert_allclose(
        seq.ground_truth[1], np.linalg.inv(_tr4()) @ P @ _tr4(), atol=1e-12
    )


def test_explicit_missing_poses_file_is_an_error(base, tmp_path):
    """An explicit poses file that does not exist is an error naming it, not silently no ground truth."""
    err = _err(lambda: KittiOdometrySequence(base, 4, poses=tmp_path / "nope.txt"))
    assert err.path == str(tmp_path / "nope.txt")


def test_poses_rotation_is_checked(base):
    """A pose whose 3x3 block is not a rotation is refused at open (check_rotation)."""
    bad = _pose(1)
    bad[0, 0] = 2.0
    f = base / "poses" / "04.txt"
    f.write_text(_line(_pose(0)) + "\n" + _line(bad) + "\n" + _line(_pose(2)) + "\n")
    err = _err(lambda: KittiOdometrySequence(base, 4))
    assert err.path == str(f) and err.line == 2


def test_no_poses_file_means_no_ground_truth(tmp_path):
    """Without poses/NN.txt: poses_path and ground_truth None, frames without T_w_body, a clear ValueError."""
    _make_sequence(tmp_path, poses=False)
    seq = KittiOdometrySequence(tmp_path, 4)
    assert seq.poses_path is None and seq.ground_truth is None
    assert seq[1].T_w_body is None
    err = _err(seq.ground_truth_poses, ValueError)
    assert (
        str(err)
        == f"{tmp_path / 'sequences' / '04'} has no ground truth ({tmp_path / 'poses' / '04'}.txt)"
    )


# ------------------------------------------------------------------ frames
def test_frame_values(base):
    """index, time_s, dt against the previous selected frame, scan, T_w_body and the scan path."""
    seq = KittiOdometrySequence(base, 4, frames=[0, 2])
    f = seq[1]
    assert f.index == 2 and f.time_s == 0.75 and f.dt == 0.75
    assert f.velodyne_path == base / "sequences" / "04" / "velodyne" / "000002.bin"
    np.testing.assert_array_equal(f.scan, _scan(2))
    np.testing.assert_array_equal(f.T_w_body, seq.ground_truth[2])
    assert (
        repr(seq)
        == f"KittiOdometrySequence({str(base / 'sequences' / '04')!r}, 2 of 3 frames)"
    )


def test_getitem_bounds(base):
    """Positions -n..n-1 are valid (-n is the first), n and -n-1 raise IndexError with the whole message."""
    seq = KittiOdometrySequence(base, 4)
    assert seq[-3].index == 0 and seq[2].index == 2
    assert (
        str(_err(lambda: seq[3], IndexError))
        == "frame position 3 out of range for 3 frames"
    )
    assert (
        str(_err(lambda: seq[-4], IndexError))
        == "frame position -4 out of range for 3 frames"
    )


def test_progress_bar_only_when_asked(base, capsys):
    """progress=True draws a transient 'frames' bar counting 'frame' units on stderr; the default draws none."""
    assert [f.index for f in KittiOdometrySequence(base, 4)] == [0, 1, 2]
    assert capsys.readouterr().err == ""
    assert [f.index for f in KittiOdometrySequence(base, 4, progress=True)] == [0, 1, 2]
    err = capsys.readouterr().err
    assert err.startswith("\rframes:   0%|") and " 0/3 " in err and "frame/s]" in err
    assert not err.endswith(
        "\n"
    )  # leave=False: the bar is cleared, not left on its own line


# ------------------------------------------------------------------ velodyne
def test_missing_scan_file_message(tmp_path):
    """A missing scan: the whole message, naming the file."""
    err = _err(lambda: read_velodyne_scan(tmp_path / "a.bin"))
    assert str(err) == f"{tmp_path / 'a.bin'}: Velodyne scan file not found"


def test_xz_scan_reads_the_same_values(tmp_path):
    """A ``.bin.xz`` file holds the little-endian float32 bytes of a ``.bin``: read back exactly."""
    pts = np.array(
        [[1.5, -2.25, 3.0, 0.5], [4.0, 5.0, -6.5, 1.0], [0.1, 0.2, 0.3, 0.0]],
        dtype=np.float32,
    )
    f = tmp_path / "000000.bin.xz"
    f.write_bytes(lzma.compress(pts.astype("<f4").tobytes()))
    got = read_velodyne_scan(f)
    assert got.dtype == np.float32 and got.shape == (3, 4)
    np.testing.assert_array_equal(got, pts)


def test_xz_scan_size_is_the_decompressed_size(tmp_path):
    """The 16-byte check counts the decompressed bytes (20 here), not the compressed file size."""
    f = tmp_path / "s.bin.xz"
    f.write_bytes(lzma.compress(bytes(20)))
    err = _err(lambda: read_velodyne_scan(f))
    assert (
        str(err)
        == f"{f}: Velodyne scan has 20 bytes, not a multiple of 16 (4 float32 per point)"
    )


def test_unreadable_xz_message(tmp_path):
    """A ``.xz`` name holding no xz data: DataFormatError naming the file, with lzma's reason."""
    f = tmp_path / "s.bin.xz"
    f.write_bytes(bytes(32))
    err = _err(lambda: read_velodyne_scan(f))
    assert err.path == str(f)
    assert str(err).startswith(f"{f}: not a readable xz file: ") and len(
        err.message
    ) > len("not a readable xz file: ")


def test_write_three_columns_adds_zero_reflectance(tmp_path):
    """An (N, 3) scan is written as x, y, z, 0 little-endian float32, 16 bytes a point."""
    xyz = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    f = tmp_path / "s.bin"
    write_velodyne_scan(f, xyz)
    expected = np.array([[1, 2, 3, 0], [4, 5, 6, 0]], dtype="<f4").tobytes()
    assert f.read_bytes() == expected


def test_write_float64_is_stored_as_float32(tmp_path):
    """A float64 (N, 4) array is written as float32: 16 bytes a point."""
    pts = np.array([[1.0, 2.0, 3.0, 0.25]])
    f = tmp_path / "s.bin"
    write_velodyne_scan(f, pts)
    assert f.read_bytes() == pts.astype("<f4").tobytes()


@pytest.mark.parametrize("shape", [(4,), (2, 4, 4), (2, 5), (2, 2)])
def test_write_refuses_bad_shapes(tmp_path, shape):
    """Only (N, 4) or (N, 3) are written; the message gives the shape."""
    err = _err(
        lambda: write_velodyne_scan(tmp_path / "s.bin", np.zeros(shape)), ValueError
    )
    assert str(err) == f"scan must be (N, 4) or (N, 3), got {shape}"
    assert not (tmp_path / "s.bin").exists()


# ------------------------------------------------------------------ sample pieces
def test_sample_raw_paths_values():
    """The shipped pieces: folders and files under the package's sample dir, all present."""
    root = kitti_sample_dir()
    p = sample_raw_paths()
    assert p["date_dir"] == root / "raw" / "2011_09_26"
    assert p["drive_dir"] == root / "raw" / "2011_09_26" / "2011_09_26_drive_0001_sync"
    assert p["scan0"] == root / "velodyne_sample" / "0000000000.bin"
    assert all(v.exists() for v in p.values())


def _n_real_timestamps():
    return len(sample_raw_paths()["oxts_timestamps"].read_text().split("\n")) - 1


def test_make_tiny_drive_defaults(tmp_path):
    """Defaults: 5 frames; scans alternate the two real scans keeping every 50th point; dataformat.txt copied."""
    d = make_tiny_drive(tmp_path)
    p = sample_raw_paths()
    assert sorted(f.name for f in (d / "oxts" / "data").iterdir()) == [
        f"{i:010d}.txt" for i in range(5)
    ]
    assert len(list((d / "velodyne_points" / "data").iterdir())) == 5
    np.testing.assert_array_equal(
        read_velodyne_scan(d / "velodyne_points" / "data" / "0000000003.bin"),
        np.fromfile(p["scan9"], dtype="<f4").reshape(-1, 4)[::50],
    )
    assert (d / "oxts" / "dataformat.txt").read_bytes() == (
        p["drive_dir"] / "oxts" / "dataformat.txt"
    ).read_bytes()


def test_make_tiny_drive_twice_in_the_same_place(tmp_path):
    """Writing a drive over an existing one is allowed (folders may exist)."""
    make_tiny_drive(tmp_path, n_frames=2, point_stride=5000)
    d = make_tiny_drive(tmp_path, n_frames=3, point_stride=5000)
    assert len(list((d / "oxts" / "data").iterdir())) == 3


def test_make_tiny_drive_frame_count_bounds(tmp_path):
    """1 and all the real timestamps are allowed; 0 and one more are refused with the range in the message."""
    n = _n_real_timestamps()
    d = make_tiny_drive(tmp_path / "a", n_frames=1, point_stride=5000)
    assert len(list((d / "oxts" / "data").iterdir())) == 1
    d = make_tiny_drive(tmp_path / "b", n_frames=n, point_stride=100000)
    assert len(list((d / "velodyne_points" / "data").iterdir())) == n
    for bad in (0, n + 1):
        err = _err(lambda: make_tiny_drive(tmp_path / "c", n_frames=bad), ValueError)
        assert str(err) == f"n_frames must be in 1..{n}"


def test_make_tiny_drive_packets(tmp_path):
    """Packet 0 is the real one (wu = yaw_rate); packet k moved along the heading on a 6378137 m sphere, yaw turned."""
    rate = 0.2
    d = make_tiny_drive(tmp_path, n_frames=3, point_stride=5000, yaw_rate=rate)
    base = read_oxts_packet(sample_raw_paths()["oxts_packet"])
    ts = read_timestamps_ns(sample_raw_paths()["oxts_timestamps"])
    pk = [read_oxts_packet(d / "oxts" / "data" / f"{i:010d}.txt") for i in range(3)]
    assert (pk[0].lat, pk[0].lon, pk[0].yaw, pk[0].wu) == (
        base.lat,
        base.lon,
        base.yaw,
        rate,
    )
    assert pk[0]._replace(wu=base.wu) == base
    dt = (ts[1] - ts[0]) * 1e-9
    step = base.vf * dt
    r = 6378137.0
    assert pk[1].lat - base.lat == pytest.approx(
        math.degrees(step * math.sin(base.yaw) / r), rel=1e-9
    )
    assert pk[1].lon - base.lon == pytest.approx(
        math.degrees(step * math.cos(base.yaw) / (r * math.cos(math.radians(pk[1].lat)))),
        rel=1e-9,
    )
    assert pk[2].yaw == pytest.approx(base.yaw + rate * (ts[2] - ts[0]) * 1e-9, abs=1e-12)
    assert pk[2].wu == rate


def test_real_scan_path_values_and_bounds():
    """Scans 0 and 9 ship as .bin, 1..8 as .bin.xz; -1 and 10 are refused with the whole message."""
    root = kitti_sample_dir() / "velodyne_sample"
    assert REAL_SCANS == 10
    assert (
        real_scan_path(0) == root / "0000000000.bin"
        and real_scan_path(9) == root / "0000000009.bin"
    )
    assert real_scan_path("4") == root / "0000000004.bin.xz"
    for bad in (-1, 10):
        err = _err(lambda: real_scan_path(bad), ValueError)
        assert str(err) == f"the package ships real scans 0..9, asked for {bad}"


def test_real_scan_frames_selected():
    """Selected frames: index, time k * period, dt from the previous selected, scan = the file, no ground truth."""
    frames = real_scan_frames([1, 4], period=0.5)
    assert [f.index for f in frames] == [1, 4]
    assert [f.time_s for f in frames] == [0.5, 2.0] and [f.dt for f in frames] == [
        0.0,
        1.5,
    ]
    for f, k in zip(frames, [1, 4]):
        assert (
            f.velodyne_path == kitti_sample_dir() / "velodyne_sample" / f"{k:010d}.bin.xz"
        )
        raw = np.frombuffer(
            lzma.decompress(f.velodyne_path.read_bytes()), dtype="<f4"
        ).reshape(-1, 4)
        np.testing.assert_array_equal(f.scan, raw)
        assert f.T_w_body is None and f.velocity is None and f.angular_rate is None


def test_real_scan_frames_defaults():
    """Default: all 10 shipped scans at the nominal period 0.10315 s."""
    frames = real_scan_frames()
    assert [f.index for f in frames] == list(range(10))
    assert NOMINAL_SCAN_PERIOD == 0.10315
    assert frames[9].time_s == pytest.approx(9 * 0.10315, abs=1e-12)
    assert frames[3].dt == pytest.approx(0.10315, abs=1e-12)
    np.testing.assert_array_equal(
        frames[9].scan, np.fromfile(real_scan_path(9), dtype="<f4").reshape(-1, 4)
    )
