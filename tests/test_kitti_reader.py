"""The KITTI raw reader (:mod:`slamlib.kitti.raw`) on the real shipped pieces and on tiny drives built from them
(vs pykitti); exact values and whole messages of its folder names, frame selection, opening and frames."""

import numpy as np
import pykitti
import pytest

from slamlib.errors import DataFormatError
from slamlib.geometry import invert_pose
from slamlib.kitti import (
    OXTS_FIELDS,
    KittiRawDrive,
    format_oxts_packet,
    format_timestamp_ns,
    load_T_velo_imu,
    parse_oxts_line,
    parse_timestamp_ns,
    read_oxts_packet,
    read_timestamps_ns,
    read_velodyne_scan,
    write_velodyne_scan,
)
from slamlib.kitti.raw import _normalise_frames, check_numbered_files, drive_folder_name
from slamlib.kitti.sample import (
    SAMPLE_DATE,
    SAMPLE_DRIVE,
    make_tiny_drive,
    sample_raw_paths,
)
from slamlib.kitti.timestamps import write_timestamps_ns

P = sample_raw_paths()


# ------------------------------------------------------------------ real shipped pieces
def test_real_calibration_T_velo_imu():
    T = load_T_velo_imu(P["date_dir"])
    # Values as printed in calib_imu_to_velo.txt (2011_09_26).
    assert T.shape == (4, 4)
    np.testing.assert_array_equal(
        T[0], [9.999976e-01, 7.553071e-04, -2.035826e-03, -8.086759e-01]
    )
    np.testing.assert_array_equal(
        T[1], [-7.854027e-04, 9.998898e-01, -1.482298e-02, 3.195559e-01]
    )
    np.testing.assert_array_equal(
        T[2], [2.024406e-03, 1.482454e-02, 9.998881e-01, -7.997231e-01]
    )
    np.testing.assert_array_equal(T[3], [0, 0, 0, 1])
    np.testing.assert_allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-6)


def test_real_oxts_packet_fields():
    p = read_oxts_packet(P["oxts_packet"])
    assert p._fields == OXTS_FIELDS and len(p) == 30
    assert (
        p.lat == 49.015003823272 and p.lon == 8.4342971002335 and p.alt == 116.43032836914
    )
    assert p.roll == 0.035752 and p.pitch == 0.00903 and p.yaw == -2.6087069803847
    assert (
        p.vf == 13.172716663769
        and p.vl == -0.12475264293164
        and p.vu == -0.032919903047354
    )
    assert p.af == -0.34030092211055 and p.au == 10.209117821189
    assert p.wf == 0.0089018002187228 and p.wu == -0.018809330937153
    assert (p.navstat, p.numsats, p.posmode, p.velmode, p.orimode) == (4, 11, 6, 6, 6)
    assert all(isinstance(v, int) for v in p[-5:])
    # forward speed from north/east velocities (the car is level): |vn, ve| ~ |vf, vl|
    assert np.hypot(p.vn, p.ve) == pytest.approx(np.hypot(p.vf, p.vl), rel=1e-3)


def test_oxts_format_round_trip():
    p = read_oxts_packet(P["oxts_packet"])
    assert parse_oxts_line(format_oxts_packet(p)) == p


def test_real_timestamps_nanoseconds_exact():
    ts = read_timestamps_ns(P["oxts_timestamps"])
    assert ts.dtype == np.int64 and ts.shape == (108,)
    assert ts[0] == parse_timestamp_ns("2011-09-26 13:02:25.964389445")
    assert ts[0] % 1_000_000_000 == 964389445 and ts[1] % 1_000_000_000 == 74347616
    assert format_timestamp_ns(ts[0]) == "2011-09-26 13:02:25.964389445"
    lines = P["oxts_timestamps"].read_text().split()
    assert format_timestamp_ns(ts[-1]) == " ".join(lines[-2:])
    dt = np.diff(ts) * 1e-9
    assert np.all(dt > 0.09) and np.all(dt < 0.12) and abs(dt.mean() - 0.1) < 0.005
    velo = read_timestamps_ns(P["velo_timestamps"])
    assert velo.shape == (108,) and velo[0] % 1_000_000_000 == 951199337


@pytest.mark.parametrize("name", ["scan0", "scan9"])
def test_real_scans(name):
    scan = read_velodyne_scan(P[name])
    n = P[name].stat().st_size // 16
    assert scan.shape == (n, 4) and scan.dtype == np.float32
    assert 100_000 < n < 130_000
    assert np.isfinite(scan).all()
    r = np.linalg.norm(scan[:, :3], axis=1)
    assert r.max() < 130 and np.median(r) > 2  # HDL-64E range
    assert scan[:, 3].min() >= 0 and scan[:, 3].max() <= 1
    np.testing.assert_array_equal(scan, pykitti.utils.load_velo_scan(str(P[name])))


def test_scan_write_read_round_trip(tmp_path):
    scan = read_velodyne_scan(P["scan0"])[::97]
    write_velodyne_scan(tmp_path / "a.bin", scan)
    np.testing.assert_array_equal(read_velodyne_scan(tmp_path / "a.bin"), scan)


# ------------------------------------------------------------------ tiny drives
@pytest.fixture
def tiny(tmp_path):
    make_tiny_drive(tmp_path, n_frames=6, point_stride=200)
    return tmp_path


def _pykitti_world_poses(basedir):
    pk = pykitti.raw(str(basedir), SAMPLE_DATE, SAMPLE_DRIVE)
    T0_inv = np.linalg.inv(pk.oxts[0].T_w_imu)
    return pk, np.stack([T0_inv @ o.T_w_imu for o in pk.oxts])


def test_drive_agrees_with_pykitti(tiny):
    drive = KittiRawDrive(tiny, SAMPLE_DATE, SAMPLE_DRIVE)
    pk, ref = _pykitti_world_poses(tiny)
    assert len(drive) == len(pk) == 6
    np.testing.assert_allclose(drive.T_velo_imu, pk.calib.T_velo_imu, atol=0)
    G = drive.ground_truth_poses("imu")
    np.testing.assert_allclose(G, ref, atol=1e-9)
    np.testing.assert_allclose(G[0], np.eye(4), atol=1e-12)
    assert np.linalg.norm(G[-1][:3, 3]) > 5  # the car moved ~13 m/s * 0.5 s
    Gv = drive.ground_truth_poses("velo")
    np.testing.assert_allclose(Gv, ref @ np.linalg.inv(pk.calib.T_velo_imu), atol=1e-9)
    for frame, pk_scan, pk_ts in zip(drive, pk.velo, pk.timestamps):
        np.testing.assert_array_equal(frame.scan, pk_scan)
        np.testing.assert_allclose(frame.T_w_imu, ref[frame.index], atol=1e-9)
        np.testing.assert_allclose(frame.T_w_velo, Gv[frame.index], atol=1e-12)
        assert frame.oxts == pk.oxts[frame.index].packet
        # pykitti keeps microseconds only (truncated): they agree with ours to the microsecond
        assert frame.timestamp_ns // 1000 % 1_000_000 == pk_ts.microsecond
        assert format_timestamp_ns(frame.timestamp_ns)[:19] == pk_ts.strftime(
            "%Y-%m-%d %H:%M:%S"
        )
    assert drive.calib.T_cam0_velo.shape == (4, 4)


def test_frame_fields_and_timing(tiny):
    drive = KittiRawDrive(tiny, SAMPLE_DATE, int(SAMPLE_DRIVE))
    ts = read_timestamps_ns(P["oxts_timestamps"])[:6]
    frames = list(drive)
    assert [f.index for f in frames] == list(range(6))
    assert [f.timestamp_ns for f in frames] == list(ts)
    assert frames[0].dt == 0.0 and frames[0].time_s == 0.0
    for k in range(1, 6):
        assert frames[k].dt == pytest.approx((ts[k] - ts[k - 1]) * 1e-9, abs=1e-15)
        assert frames[k].time_s == pytest.approx((ts[k] - ts[0]) * 1e-9, abs=1e-15)
    f = frames[2]
    np.testing.assert_array_equal(f.velocity, [f.oxts.vf, f.oxts.vl, f.oxts.vu])
    np.testing.assert_array_equal(f.angular_rate, [f.oxts.wf, f.oxts.wl, f.oxts.wu])
    np.testing.assert_array_equal(f.acceleration, [f.oxts.af, f.oxts.al, f.oxts.au])
    np.testing.assert_array_equal(f.specific_force, [f.oxts.ax, f.oxts.ay, f.oxts.az])
    np.testing.assert_allclose(f.T_w_velo, f.T_w_imu @ np.linalg.inv(drive.T_velo_imu))
    assert f.scan.dtype == np.float32 and f.scan.shape[1] == 4
    np.testing.assert_array_equal(drive.timestamps_ns, ts)
    assert drive.velo_timestamps_ns is not None and drive.velo_timestamps_ns.shape == (6,)


def test_scan_stamp_more_than_a_sweep_from_its_pose_names_the_file_and_line(tiny):
    from slamlib.errors import DataFormatError
    from slamlib.kitti.velodyne import SWEEP_PERIOD_S

    drive = KittiRawDrive(tiny, SAMPLE_DATE, int(SAMPLE_DRIVE))
    stamps = drive.path / "velodyne_points" / "timestamps.txt"
    lines = stamps.read_text().splitlines()
    # two sweeps after its pose
    late = int(drive.timestamps_ns[2]) + int(2 * SWEEP_PERIOD_S * 1e9)
    lines[2] = format_timestamp_ns(late)
    stamps.write_text("\n".join(lines) + "\n")
    drive = KittiRawDrive(tiny, SAMPLE_DATE, int(SAMPLE_DRIVE))
    assert drive[1].scan_time_offset_s == pytest.approx(
        (drive.velo_timestamps_ns[1] - drive.timestamps_ns[1]) * 1e-9
    )
    with pytest.raises(
        DataFormatError, match=r"velodyne_points/timestamps.txt:3: .*one sweep"
    ):
        drive[2]


def test_imu_arrays_match_frames(tiny):
    drive = KittiRawDrive(tiny, SAMPLE_DATE, SAMPLE_DRIVE, frames=range(1, 6))
    imu = drive.imu_arrays()
    frames = list(drive)
    np.testing.assert_array_equal(imu.index, [1, 2, 3, 4, 5])
    np.testing.assert_array_equal(imu.velocity, np.stack([f.velocity for f in frames]))
    np.testing.assert_array_equal(
        imu.angular_rate, np.stack([f.angular_rate for f in frames])
    )
    np.testing.assert_array_equal(
        imu.acceleration, np.stack([f.acceleration for f in frames])
    )
    np.testing.assert_array_equal(
        imu.specific_force, np.stack([f.specific_force for f in frames])
    )
    np.testing.assert_allclose(imu.dt, [f.dt for f in frames], atol=1e-15)
    np.testing.assert_allclose(imu.time_s, [f.time_s for f in frames], atol=1e-15)
    assert imu.dt[0] == 0.0 and imu.time_s[0] > 0.09  # time counts from drive frame 0


def test_frame_selection_keeps_world_and_dt(tiny):
    full = KittiRawDrive(tiny, SAMPLE_DATE, SAMPLE_DRIVE)
    sub = KittiRawDrive(tiny, SAMPLE_DATE, SAMPLE_DRIVE, frames=slice(1, 6, 2))
    assert len(sub) == 3
    G = full.ground_truth_poses()
    got = list(sub)
    assert [f.index for f in got] == [1, 3, 5]
    for f in got:
        np.testing.assert_allclose(f.T_w_imu, G[f.index], atol=1e-12)
    assert got[0].dt == 0.0
    assert got[1].dt == pytest.approx(
        (full.timestamps_ns[3] - full.timestamps_ns[1]) * 1e-9
    )
    assert sub[-1].index == 5 and sub[1].dt == got[1].dt
    np.testing.assert_allclose(sub.ground_truth_poses(), G[[1, 3, 5]], atol=1e-12)
    with pytest.raises(IndexError):
        sub[3]
    with pytest.raises(ValueError, match="out of range"):
        KittiRawDrive(tiny, SAMPLE_DATE, SAMPLE_DRIVE, frames=range(4, 8))


def test_iteration_is_lazy(tiny):
    """A broken scan in frame 4 does not stop frames 0-3 from being read: files are read frame by frame."""
    drive = KittiRawDrive(tiny, SAMPLE_DATE, SAMPLE_DRIVE)
    (drive.velodyne_path(4)).write_bytes(b"\0" * 17)
    it = iter(drive)
    assert [next(it).index for _ in range(4)] == [0, 1, 2, 3]
    from slamlib.errors import DataFormatError

    with pytest.raises(DataFormatError, match="0000000004.bin"):
        next(it)


def test_world_is_first_imu_pose_not_enu(tiny):
    """pykitti's T_w_imu keeps the absolute ENU rotation; slamlib's world is the frame-0 IMU pose."""
    drive = KittiRawDrive(tiny, SAMPLE_DATE, SAMPLE_DRIVE)
    pk, _ = _pykitti_world_poses(tiny)
    assert not np.allclose(pk.oxts[0].T_w_imu, np.eye(4), atol=1e-3)
    first = next(iter(drive))
    np.testing.assert_allclose(first.T_w_imu, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(first.T_w_velo, invert_pose(drive.T_velo_imu), atol=1e-6)
    # The car drives forward (IMU +x) at vf: displacement of frame 5 in world ~ vf * t along +x.
    G = drive.ground_truth_poses()
    t5 = (drive.timestamps_ns[5] - drive.timestamps_ns[0]) * 1e-9
    assert G[5, 0, 3] == pytest.approx(first.oxts.vf * t5, rel=0.02)


# ------------------------------------------------------------------ raw: names and frame selection
def test_drive_folder_name_keeps_string_drive_as_given():
    """A drive given as a string is used verbatim (only ints are zero-padded to 4 digits)."""
    assert drive_folder_name("2011_09_26", "1") == "2011_09_26_drive_1_sync"
    assert drive_folder_name("2011_09_26", 1) == "2011_09_26_drive_0001_sync"


def test_check_numbered_files_full_message(tmp_path):
    """The missing-file message names the count, the first missing file and that numbering starts at 0."""
    (tmp_path / "0000000000.txt").write_text("")
    with pytest.raises(DataFormatError) as info:
        check_numbered_files(tmp_path, ".txt", 3, "OXTS packets", "timestamps")
    assert info.value.message == (
        "fewer OXTS packets than the 3 timestamps: 2 of 3 missing "
        "(first: 0000000001.txt; files are numbered 0000000000.txt upwards)"
    )


N = 4  # frames in the drive that _normalise_frames is told about


def test_normalise_frames_values_and_dtype():
    """Every accepted form of ``frames`` gives int64 frame numbers, including floats, generators and lists."""
    cases = [
        (None, [0, 1, 2, 3]),
        (slice(1, None, 2), [1, 3]),
        (range(1, 3), [1, 2]),
        ([0.0, 2.0], [0, 2]),
        ((i for i in (0, 3)), [0, 3]),
        ([0], [0]),
        (np.array([3, 0]), [3, 0]),
    ]
    for frames, expected in cases:
        idx = _normalise_frames(frames, N)
        assert idx.dtype == np.int64
        assert idx.tolist() == expected


def test_normalise_frames_error_messages():
    """Full messages for a 0-d / 2-D selection, for frame numbers that are not whole numbers (0.5 was read as
    frame 0) and for frame numbers just past the last frame."""
    msg = "frames must be a range, a slice or a 1-D sequence of frame numbers"
    for bad in (np.array(2), np.zeros((2, 2), dtype=int)):
        with pytest.raises(ValueError) as info:
            _normalise_frames(bad, N)
        assert str(info.value) == msg
    for bad, shown in (([0, 0.5], "0.5"), ([np.inf], "inf"), (["1"], "'1'")):
        with pytest.raises(ValueError) as info:
            _normalise_frames(bad, N)
        assert str(info.value).startswith(
            "frames must be whole frame numbers, got "
        ) and shown in str(info.value)
    with pytest.raises(ValueError) as info:
        _normalise_frames([0, N], N)
    assert (
        str(info.value)
        == "frames out of range: the drive has frames 0..3, asked for 0..4"
    )
    assert _normalise_frames([N - 1], N).tolist() == [N - 1]


def test_normalise_frames_of_float32_whole_numbers():
    """float32 frame numbers are floats too: whole ones are frames, others an error (not "not whole" for all)."""
    assert _normalise_frames(np.array([0.0, 2.0], np.float32), N).tolist() == [0, 2]
    with pytest.raises(ValueError, match="^frames must be whole frame numbers, got "):
        _normalise_frames(np.array([1.5], np.float32), N)


# ------------------------------------------------------------------ raw: opening
def test_missing_drive_folder_full_message(tmp_path):
    """The folder-not-found message repeats basedir, date and drive exactly as the user passed them."""
    with pytest.raises(DataFormatError) as info:
        KittiRawDrive(tmp_path, "2011_09_26", 7)
    expected_path = tmp_path / "2011_09_26" / "2011_09_26_drive_0007_sync"
    assert info.value.path == str(expected_path)
    assert info.value.message == (
        "KITTI raw drive folder not found (expected basedir/DATE/DATE_drive_XXXX_sync with "
        f"basedir={str(tmp_path)!r}, date='2011_09_26', drive='0007')"
    )


def test_dataset_suffix_selects_folder(drive_dir, tiny_drive_frames):
    """``dataset='extract'`` opens ``DATE_drive_XXXX_extract`` (the suffix is not always ``sync``)."""
    other = drive_dir.with_name(drive_dir.name.replace("_sync", "_extract"))
    drive_dir.rename(other)
    drive = KittiRawDrive(
        other.parent.parent, SAMPLE_DATE, SAMPLE_DRIVE, dataset="extract"
    )
    assert drive.path == other
    assert len(drive) == tiny_drive_frames


def test_without_velodyne_timestamps(drive_dir, open_drive):
    """Without velodyne_points/timestamps.txt the drive opens and the scan times are None."""
    (drive_dir / "velodyne_points" / "timestamps.txt").unlink()
    drive = open_drive()
    assert drive.all_velo_timestamps_ns is None and drive.velo_timestamps_ns is None
    assert drive[1].scan_time_offset_s == 0.0


def test_frames_carry_the_scan_stamp_relative_to_the_pose(open_drive):
    """``Frame.scan_time_offset_s`` = Velodyne timestamp - OXTS timestamp (s) of the frame itself: 12-24 ms before
    the pose in the generator's drives, as on KITTI raw."""
    drive = open_drive(frames=[2, 0])
    for f, velo in zip(drive, drive.velo_timestamps_ns):
        assert f.scan_time_offset_s == (int(velo) - f.timestamp_ns) * 1e-9
        assert -0.0245 < f.scan_time_offset_s < -0.0115


def test_velodyne_timestamps_need_not_increase(drive_dir, open_drive):
    """Scan times out of order are accepted (informational) and returned as written, per selected frame."""
    f = drive_dir / "velodyne_points" / "timestamps.txt"
    ts = read_timestamps_ns(f)[::-1].copy()
    write_timestamps_ns(f, ts)
    drive = open_drive(frames=[2, 0])
    assert drive.velo_timestamps_ns.tolist() == [ts[2], ts[0]]


def test_repr_exact(drive_dir, open_drive):
    """``repr`` names the drive folder and the selection size."""
    drive = open_drive(frames=range(1, 3))
    assert repr(drive) == f"KittiRawDrive({str(drive_dir)!r}, 2 of 4 frames)"


# ------------------------------------------------------------------ raw: frames
def test_oxts_packets_are_cached(drive_dir, open_drive):
    """A packet is read once: a later change of its file does not change what the drive returns."""
    drive = open_drive()
    first = drive.oxts_packet(1)
    (drive_dir / "oxts" / "data" / "0000000001.txt").write_text("garbage\n")
    assert drive.oxts_packet(1) is first
    assert drive.oxts_packet(0) is drive.reference_packet


def test_getitem_bounds_dt_and_path(drive_dir, open_drive):
    """``drive[-n]`` is the first frame (dt 0.0), ``drive[n]`` raises with the full message; the path is kept."""
    drive = open_drive(frames=[1, 3])
    ts = drive.all_timestamps_ns
    first = drive[-2]
    assert first.index == 1 and first.dt == 0.0
    assert drive[0].dt == 0.0
    assert drive[1].dt == pytest.approx((ts[3] - ts[1]) * 1e-9, rel=1e-12)
    assert (
        drive[1].velodyne_path
        == drive_dir / "velodyne_points" / "data" / "0000000003.bin"
    )
    with pytest.raises(IndexError) as info:
        drive[2]
    assert str(info.value) == "frame position 2 out of range for 2 frames"
    with pytest.raises(IndexError):
        drive[-3]


def test_ground_truth_poses_bad_frame_message(drive_dir, open_drive):
    """The full message for an unknown pose frame."""
    with pytest.raises(ValueError) as info:
        open_drive().ground_truth_poses("cam")
    assert str(info.value) == "frame must be 'imu' or 'velo', got 'cam'"


def test_imu_arrays_two_frames(drive_dir, open_drive):
    """With two selected frames ``dt[1]`` is their time difference and the timestamps are the selected ones."""
    drive = open_drive(frames=[0, 2])
    ts = drive.all_timestamps_ns
    a = drive.imu_arrays()
    assert a.timestamps_ns.tolist() == [ts[0], ts[2]]
    assert a.dt[0] == 0.0
    assert a.dt[1] == pytest.approx((ts[2] - ts[0]) * 1e-9, rel=1e-12)


def test_progress_off_by_default(drive_dir, capsys, open_drive):
    """By default neither iterating nor reading the packets draws a progress bar."""
    drive = open_drive()
    list(drive)
    drive.imu_arrays()
    assert capsys.readouterr().err == ""


def test_progress_bars_labelled_and_cleared(drive_dir, capsys, open_drive):
    """``progress=True`` draws a 'frames' bar counting 'frame' and an 'OXTS' bar counting 'packet', both removed
    when done (no bar left behind: the output ends in a carriage return, not a newline)."""
    drive = open_drive(progress=True)
    list(drive)
    err = capsys.readouterr().err
    assert err.startswith("\rframes:   0%|") and "0/4 [00:00<?, ?frame/s]" in err
    assert "\n" not in err and err.endswith("\r")
    drive.imu_arrays()
    err = capsys.readouterr().err
    assert err.startswith("\rOXTS:   0%|") and "0/4 [00:00<?, ?packet/s]" in err
    assert "\n" not in err and err.endswith("\r")


# ------------------------------------------------------------------ drive.calib on what pykitti parses more strictly
def _replace_line(path, key, text):
    lines = [
        text if line.startswith(key) else line for line in path.read_text().splitlines()
    ]
    path.write_text("\n".join(lines) + "\n")


def _trailing_spaces(d):
    p = d / "oxts" / "timestamps.txt"
    p.write_text("".join(line + "  \n" for line in p.read_text().splitlines()))


def _blank_line_at_the_end(d):
    p = d / "oxts" / "timestamps.txt"
    p.write_text(p.read_text() + "\n")


def _non_utf8_byte(d):
    p = d.parent / "calib_cam_to_cam.txt"
    p.write_bytes(p.read_bytes().replace(b"calib_time: ", b"calib_time: \xff", 1))


def _blank_calib_line(d):
    p = d.parent / "calib_cam_to_cam.txt"
    p.write_text("\n" + p.read_text())


def _key_with_a_leading_space(d):
    p = d.parent / "calib_cam_to_cam.txt"
    p.write_text(p.read_text().replace("R_rect_00:", " R_rect_00:"))


def _blank_oxts_line(d):
    p = d / "oxts" / "data" / "0000000000.txt"
    p.write_text("\n" + p.read_text())


def _a_file_sorted_before_frame_0(d):
    (d / "oxts" / "data" / "0.txt").write_text("not a packet\n")


@pytest.mark.parametrize(
    "corrupt,where",
    [
        (
            _trailing_spaces,
            r"oxts/timestamps.txt:1: pykitti cannot parse timestamp line '2011-09-26 13:02:25.964389445  '",
        ),
        (
            _blank_line_at_the_end,
            r"oxts/timestamps.txt:4: pykitti cannot parse timestamp line ''",
        ),
        (_non_utf8_byte, r"calib_cam_to_cam.txt:1: byte b'\\xff' is not"),
        (_blank_calib_line, r"calib_cam_to_cam.txt:1: line without ':'"),
        (
            _key_with_a_leading_space,
            r"calib_cam_to_cam.txt:9: calibration key 'R_rect_00' has spaces around it",
        ),
        (
            _blank_oxts_line,
            r"oxts/data/0000000000.txt:1: blank line in an OXTS packet file",
        ),
        (
            _a_file_sorted_before_frame_0,
            r"oxts/data/0.txt: pykitti would read this file as frame 0's OXTS packet",
        ),
    ],
)
def test_drive_calib_on_what_pykitti_cannot_parse_is_a_data_format_error(
    tmp_path, corrupt, where
):
    """These drives open in slamlib; ``drive.calib`` is a DataFormatError naming the file, not pykitti's error."""
    from slamlib.kitti import KittiRawDrive
    from slamlib.kitti.sample import SAMPLE_DATE, SAMPLE_DRIVE, make_tiny_drive

    d = make_tiny_drive(tmp_path / "k", n_frames=3, point_stride=500)
    corrupt(d)
    drive = KittiRawDrive(tmp_path / "k", SAMPLE_DATE, SAMPLE_DRIVE)
    assert len(list(drive)) == 3  # slamlib itself reads it
    with pytest.raises(DataFormatError, match=where):
        _ = drive.calib  # the calibration is read on first use


@pytest.mark.parametrize(
    "key,value,where",
    [
        (
            "R_rect_00:",
            "R_rect_00: 0 0 0 0 0 0 0 0 0",
            r"calib_cam_to_cam.txt:9: calibration R_rect_00 is not a rotation",
        ),
        (
            "R_rect_02:",
            "R_rect_02: 1 0 0 0 1 0 0 0 -1",
            r"calib_cam_to_cam.txt:25: calibration R_rect_02 is not a rotation",
        ),
        (
            "P_rect_00:",
            "P_rect_00: 0 0 609 0 0 721 172 0 0 0 1 0",
            r"calib_cam_to_cam.txt:10: calibration P_rect_00 has focal length P\[0, 0\] = 0",
        ),
    ],
)
def test_camera_calibration_pykitti_cannot_use_is_refused_at_open(
    tmp_path, key, value, where
):
    """A singular R_rect_00 (pykitti's LinAlgError) or P_rect_00[0, 0] = 0 (NaN in drive.calib): refused at open."""
    from slamlib.kitti import KittiRawDrive
    from slamlib.kitti.sample import SAMPLE_DATE, SAMPLE_DRIVE, make_tiny_drive

    d = make_tiny_drive(tmp_path / "k", n_frames=3, point_stride=500)
    _replace_line(d.parent / "calib_cam_to_cam.txt", key, value)
    with pytest.raises(DataFormatError, match=where):
        KittiRawDrive(tmp_path / "k", SAMPLE_DATE, SAMPLE_DRIVE)


def test_drive_calib_of_a_clean_drive_still_matches_pykitti(tmp_path):
    import numpy as np
    import pykitti

    from slamlib.kitti import KittiRawDrive
    from slamlib.kitti.sample import SAMPLE_DATE, SAMPLE_DRIVE, make_tiny_drive

    make_tiny_drive(tmp_path / "k", n_frames=3, point_stride=500)
    mine = KittiRawDrive(tmp_path / "k", SAMPLE_DATE, SAMPLE_DRIVE).calib
    theirs = pykitti.raw(str(tmp_path / "k"), SAMPLE_DATE, SAMPLE_DRIVE).calib
    for name, value in theirs._asdict().items():
        np.testing.assert_array_equal(getattr(mine, name), value)


def test_raw_reader_refuses_incomplete_data_unless_allowed(
    drive_dir, open_drive, tiny_drive_frames
):
    """A drive with synth's in-progress marker or a scan beyond its OXTS timestamps: an error naming the file,
    unless ``allow_incomplete``."""
    import shutil

    from slamlib.kitti.velodyne import SYNTH_PARTIAL_MARKER

    n = tiny_drive_frames
    (drive_dir / SYNTH_PARTIAL_MARKER).write_text("{}")
    with pytest.raises(
        DataFormatError, match="left half written by an interrupted slamlib synth"
    ):
        open_drive()
    assert len(open_drive(allow_incomplete=True)) == n
    (drive_dir / SYNTH_PARTIAL_MARKER).unlink()
    velo = drive_dir / "velodyne_points" / "data"
    shutil.copyfile(velo / f"{0:010d}.bin", velo / f"{n:010d}.bin")
    with pytest.raises(DataFormatError) as err:
        open_drive()
    assert str(err.value).startswith(
        f"{drive_dir / 'oxts' / 'timestamps.txt'}: times {n} frames, but {velo} holds {n + 1} Velodyne "
        f"scans ({n:010d}.bin onwards have no time)"
    )
    assert len(open_drive(allow_incomplete=True)) == n
