"""The KITTI pieces the package ships and the tiny drives built from them (:mod:`slamlib.kitti.sample`): paths,
frame counts, OXTS packets and timestamps, the real scans."""

from __future__ import annotations

import lzma
import math

import numpy as np
import pytest

from slamlib.errors import DataFormatError
from slamlib.kitti import read_oxts_packet, read_timestamps_ns, read_velodyne_scan
from slamlib.kitti.sample import (
    NOMINAL_SCAN_PERIOD,
    REAL_SCANS,
    make_tiny_drive,
    real_scan_frames,
    real_scan_path,
    sample_raw_paths,
)
from slamlib.paths import kitti_sample_dir


def _err(fn, exc=DataFormatError):
    with pytest.raises(exc) as info:
        fn()
    return info.value


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
