"""Every kind of bad KITTI raw input raises DataFormatError naming the file (and line where there is one)."""

import re
import shutil

import numpy as np
import pytest

from slamlib.errors import DataFormatError
from slamlib.kitti import (
    KittiRawDrive,
    read_calib_file,
    read_oxts_packet,
    read_timestamps_ns,
    read_velodyne_scan,
)
from slamlib.kitti.sample import (
    SAMPLE_DATE,
    SAMPLE_DRIVE,
    make_tiny_drive,
    sample_raw_paths,
)


def _read_all(open_drive):
    return [f.index for f in open_drive()]


def _expect(fn, filename, line=None, match=None):
    with pytest.raises(DataFormatError) as info:
        fn()
    err = info.value
    assert filename in str(err), str(err)
    assert err.path.endswith(filename), err.path
    if line is not None:
        assert err.line == line and f":{line}:" in str(err), str(err)
    if match is not None:
        assert re.search(match, str(err)), str(err)
    return err


# ------------------------------------------------------------------ OXTS packets (read lazily)
def _set_oxts(drive_dir, index, text):
    (drive_dir / "oxts" / "data" / f"{index:010d}.txt").write_text(text)


def _good_line():
    return sample_raw_paths()["oxts_packet"].read_text().strip()


def test_oxts_wrong_field_count(drive_dir, open_drive):
    _set_oxts(drive_dir, 2, " ".join(_good_line().split()[:29]) + "\n")
    open_drive()  # opening is fine: frame 2 is only read when reached
    _expect(
        lambda: _read_all(open_drive),
        "0000000002.txt",
        line=1,
        match="29 fields, expected 30",
    )


def test_oxts_non_numeric_field(drive_dir, open_drive):
    parts = _good_line().split()
    parts[7] = "abc"
    _set_oxts(drive_dir, 1, "\n" + " ".join(parts) + "\n")
    _expect(
        lambda: _read_all(open_drive),
        "0000000001.txt",
        line=2,
        match=r"field 8 \(ve\).*'abc'",
    )


@pytest.mark.parametrize("bad", ["nan", "inf"])
def test_oxts_non_finite_field(drive_dir, bad, open_drive):
    parts = _good_line().split()
    parts[8] = bad
    _set_oxts(drive_dir, 3, " ".join(parts))
    _expect(lambda: _read_all(open_drive), "0000000003.txt", line=1, match="vf")


def test_oxts_first_packet_checked_at_open(drive_dir, open_drive):
    _set_oxts(drive_dir, 0, "")
    _expect(lambda: open_drive(), "0000000000.txt", match="empty")


def test_oxts_two_lines(drive_dir):
    _set_oxts(drive_dir, 0, _good_line() + "\n" + _good_line() + "\n")
    _expect(
        lambda: read_oxts_packet(drive_dir / "oxts" / "data" / "0000000000.txt"),
        "0000000000.txt",
        line=2,
    )


def test_oxts_fractional_integer_field(drive_dir, open_drive):
    parts = _good_line().split()
    parts[-1] = "6.5"
    _set_oxts(drive_dir, 1, " ".join(parts))
    _expect(lambda: _read_all(open_drive), "0000000001.txt", line=1, match="orimode")


def test_imu_arrays_validates_every_packet(drive_dir, open_drive):
    _set_oxts(drive_dir, 3, "1 2 3")
    drive = open_drive()
    _expect(drive.imu_arrays, "0000000003.txt", line=1)
    _expect(drive.ground_truth_poses, "0000000003.txt", line=1)


# ------------------------------------------------------------------ timestamps (at open)
def _ts_path(drive_dir):
    return drive_dir / "oxts" / "timestamps.txt"


def _ts_lines(drive_dir):
    return _ts_path(drive_dir).read_text().splitlines()


@pytest.mark.parametrize(
    "bad",
    [
        "2011-09-26 13:02:26.174598",  # 6 digits (microseconds)
        "2011-09-26T13:02:26.174598199",  # ISO 'T'
        "2011-09-26 13:02:26",  # no fraction
        "2011-13-26 13:02:26.174598199",  # month 13
        "hello",
    ],
)
def test_timestamp_wrong_format(drive_dir, bad, open_drive):
    lines = _ts_lines(drive_dir)
    lines[2] = bad
    _ts_path(drive_dir).write_text("\n".join(lines) + "\n")
    _expect(lambda: open_drive(), "timestamps.txt", line=3)


@pytest.mark.parametrize("swap_to", ["equal", "earlier"])
def test_timestamps_not_strictly_increasing(drive_dir, swap_to, open_drive):
    lines = _ts_lines(drive_dir)
    lines[3] = lines[2] if swap_to == "equal" else lines[1]
    _ts_path(drive_dir).write_text("\n".join(lines) + "\n")
    _expect(lambda: open_drive(), "timestamps.txt", line=4, match="strictly increasing")


def test_timestamps_empty_or_missing(drive_dir, open_drive):
    _ts_path(drive_dir).write_text("\n\n")
    _expect(lambda: open_drive(), "timestamps.txt", match="empty")
    _ts_path(drive_dir).unlink()
    _expect(
        lambda: read_timestamps_ns(_ts_path(drive_dir)),
        "timestamps.txt",
        match="not found",
    )
    _expect(lambda: open_drive(), "timestamps.txt", match="not found")


def test_timestamps_without_final_newline_read(drive_dir, open_drive, tiny_drive_frames):
    text = _ts_path(drive_dir).read_text()
    _ts_path(drive_dir).write_text(text.rstrip("\n"))
    assert len(open_drive()) == tiny_drive_frames


def test_more_timestamps_than_packets(drive_dir, open_drive):
    lines = _ts_lines(drive_dir)
    lines.append("2011-09-26 13:02:29.000000000")
    _ts_path(drive_dir).write_text("\n".join(lines) + "\n")
    _expect(
        lambda: open_drive(),
        "data",
        match=r"fewer OXTS packets than the 5 timestamps.*first: 0000000004.txt",
    )


# ------------------------------------------------------------------ velodyne scans
def _scan_path(drive_dir, i):
    return drive_dir / "velodyne_points" / "data" / f"{i:010d}.bin"


def test_scan_size_not_multiple_of_16(drive_dir, open_drive):
    p = _scan_path(drive_dir, 1)
    p.write_bytes(p.read_bytes() + b"\0\0\0\0")
    _expect(lambda: _read_all(open_drive), "0000000001.bin", match="not a multiple of 16")


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_scan_non_finite_points(drive_dir, bad, open_drive):
    p = _scan_path(drive_dir, 2)
    scan = np.fromfile(p, dtype="<f4").reshape(-1, 4)
    scan[5, 1] = bad
    scan.tofile(p)
    err = _expect(lambda: _read_all(open_drive), "0000000002.bin", match="nan/inf")
    assert "point index 5" in str(err)


def test_scan_non_finite_points_are_counted_by_point(drive_dir, open_drive):
    """Three bad values in two points: the message counts points, and names the first."""
    p = _scan_path(drive_dir, 2)
    scan = np.fromfile(p, dtype="<f4").reshape(-1, 4)
    scan[7, 0], scan[7, 3], scan[9, 2] = np.nan, np.inf, -np.inf
    scan.tofile(p)
    err = _expect(lambda: _read_all(open_drive), "0000000002.bin", match="nan/inf")
    assert "2 point(s)" in str(err) and "point index 7" in str(err)


def test_fewer_scans_than_packets(drive_dir, open_drive):
    _scan_path(drive_dir, 3).unlink()
    match = r"fewer Velodyne scans than the 4 OXTS packets.*first: 0000000003.bin"
    _expect(lambda: open_drive(), "data", match=match)


def test_no_velodyne_folder(drive_dir, open_drive):
    shutil.rmtree(drive_dir / "velodyne_points" / "data")
    _expect(lambda: open_drive(), "data", match="folder of Velodyne scans not found")


def test_missing_scan_file_direct(tmp_path):
    _expect(
        lambda: read_velodyne_scan(tmp_path / "0000000007.bin"),
        "0000000007.bin",
        match="not found",
    )


# ------------------------------------------------------------------ calibration (at open)
@pytest.mark.parametrize(
    "name", ["calib_imu_to_velo.txt", "calib_velo_to_cam.txt", "calib_cam_to_cam.txt"]
)
def test_missing_calibration_file(drive_dir, name, open_drive):
    (drive_dir.parent / name).unlink()
    _expect(lambda: open_drive(), name, match="not found")


@pytest.mark.parametrize(
    "name,key",
    [
        ("calib_imu_to_velo.txt", "R"),
        ("calib_imu_to_velo.txt", "T"),
        ("calib_velo_to_cam.txt", "T"),
        ("calib_cam_to_cam.txt", "P_rect_02"),
        ("calib_cam_to_cam.txt", "R_rect_00"),
    ],
)
def test_missing_calibration_key(drive_dir, name, key, open_drive):
    p = drive_dir.parent / name
    lines = [s for s in p.read_text().splitlines() if not s.startswith(key + ":")]
    p.write_text("\n".join(lines) + "\n")
    _expect(lambda: open_drive(), name, match=f"missing: {key}")


def test_calibration_key_wrong_count_and_non_numeric(drive_dir, open_drive):
    p = drive_dir.parent / "calib_imu_to_velo.txt"
    original = p.read_text().splitlines()
    lines = list(original)
    lines[2] = "T: 1.0 2.0"
    p.write_text("\n".join(lines) + "\n")
    _expect(
        lambda: open_drive(),
        "calib_imu_to_velo.txt",
        line=3,
        match="2 numbers, expected 3",
    )
    lines[2] = "T: 1.0 2.0 x"
    p.write_text("\n".join(lines) + "\n")
    _expect(lambda: open_drive(), "calib_imu_to_velo.txt", line=3, match="non-numeric")
    lines = list(original)
    lines[1] = "R: " + " ".join(["2"] * 9)
    p.write_text("\n".join(lines) + "\n")
    _expect(lambda: open_drive(), "calib_imu_to_velo.txt", match="not a rotation")


def test_calibration_line_without_colon(tmp_path):
    p = tmp_path / "calib_x.txt"
    p.write_text("R: 1 0 0 0 1 0 0 0 1\nT 0 0 0\n")
    _expect(lambda: read_calib_file(p, {"R": 9, "T": 3}), "calib_x.txt", line=2)


# ------------------------------------------------------------------ folders
def test_missing_drive_folder_names_expected_path(tmp_path):
    make_tiny_drive(tmp_path, n_frames=2, point_stride=1000)
    err = _expect(
        lambda: KittiRawDrive(tmp_path, SAMPLE_DATE, "0002"), "2011_09_26_drive_0002_sync"
    )
    assert str(tmp_path / SAMPLE_DATE / "2011_09_26_drive_0002_sync") in str(err)
    _expect(
        lambda: KittiRawDrive(tmp_path / "nope", SAMPLE_DATE, SAMPLE_DRIVE),
        "2011_09_26_drive_0001_sync",
    )


def test_velodyne_timestamps_checked_at_open(drive_dir, open_drive):
    p = drive_dir / "velodyne_points" / "timestamps.txt"
    lines = p.read_text().splitlines()
    p.write_text("\n".join(lines[:2]) + "\n")
    _expect(lambda: open_drive(), "timestamps.txt", match="fewer than the 4 OXTS packets")
    lines[1] = lines[1][:-3]  # 6 fractional digits
    p.write_text("\n".join(lines) + "\n")
    err = _expect(lambda: open_drive(), "timestamps.txt", line=2)
    assert "velodyne_points" in err.path
