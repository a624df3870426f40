"""Exact values of slamlib.kitti.raw (drive reader) and slamlib.kitti.scan_stats (scan statistics).

Pins full error messages, boundary inputs exactly at the limits, caching, progress bars and values computed by
hand on tiny inputs.
"""

import warnings

import numpy as np
import pytest

from slamlib.errors import DataFormatError
from slamlib.kitti import KittiRawDrive
from slamlib.kitti import scan_stats as ss
from slamlib.kitti.raw import _normalise_frames, check_numbered_files, drive_folder_name
from slamlib.kitti.sample import SAMPLE_DATE, SAMPLE_DRIVE
from slamlib.kitti.timestamps import read_timestamps_ns, write_timestamps_ns


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


# ------------------------------------------------------------------ scan_stats
def test_xyz_shape_message():
    """The full message for points of the wrong shape."""
    with pytest.raises(ValueError) as info:
        ss.azimuth(np.zeros((3, 2)))
    assert str(info.value) == "points must be (N, 3) or (N, 4), got shape (3, 2)"


def test_ring_index_two_points_and_exact_drop():
    """Two points: a drop of more than min_drop starts ring 1; a drop of exactly min_drop does not."""
    assert ss.ring_index([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]).tolist() == [
        0,
        0,
    ]  # drop pi/2 == min_drop
    assert ss.ring_index([[-1.0, 1.0, 0.0], [1.0, 0.0, 0.0]]).tolist() == [
        0,
        1,
    ]  # drop 3 pi / 4


def test_ring_counts_uses_min_drop_and_int64():
    """ring_counts passes min_drop on (a 45-degree drop splits only with min_drop < pi/4) and returns int64."""
    pts = [[1.0, 1.0, 0.0], [1.0, 0.0, 0.0]]
    c = ss.ring_counts(pts, n_rings=2, min_drop=0.5)
    assert c.dtype == np.int64 and c.tolist() == [1, 1]
    assert ss.ring_counts(pts, n_rings=2).tolist() == [2, 0]


def test_elevation_fractions_no_point_inside_is_silent_nan():
    """No point inside the edges: all-NaN fractions, without a division-by-zero warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        f = ss.elevation_fractions([[1.0, 0.0, 10.0]])
    assert len(f) == len(ss.ELEVATION_BINS_DEG) - 1 and np.isnan(f).all()


def test_front_view_limits_inclusive_and_short_range():
    """A point at exactly the lower azimuth limit and one at exactly max_range are kept; elevation of a point
    nearer than 1 m is asin(z / r) (0.3, 0, 0.4): r = 0.5, el = asin(0.8))."""
    az, el, r = ss.front_view(
        [[3.0, 4.0, 0.0], [0.3, 0.0, 0.4], [1.0, -1.0, 0.0]],
        az_limits_deg=(0.0, 90.0),
        max_range=5.0,
    )
    assert r.tolist() == [5.0, 0.5]
    assert az[1] == 0.0
    assert el[1] == pytest.approx(np.degrees(np.arcsin(0.8)), abs=1e-12)


def test_front_view_ties_keep_input_order():
    """Points at equal range keep their input order (stable far-to-near sort)."""
    dirs = np.array(
        [
            [5, 0, 0],
            [4, 3, 0],
            [4, -3, 0],
            [3, 4, 0],
            [3, -4, 0],
            [4, 0, 3],
            [4, 0, -3],
            [3, 0, 4],
        ]
    )
    rng = np.random.default_rng(0)
    k = rng.integers(1, 4, 200)
    pts = (dirs[rng.integers(0, len(dirs), 200)] * k[:, None]).astype(
        float
    )  # ranges exactly 5 k
    order = sorted(range(200), key=lambda i: -k[i])  # Python's sort is stable
    az, el, r = ss.front_view(pts)
    assert r.tolist() == [5.0 * k[i] for i in order]
    np.testing.assert_allclose(
        az, np.degrees(np.arctan2(pts[order, 1], pts[order, 0])), atol=1e-12
    )
    np.testing.assert_allclose(el, np.degrees(np.arcsin(pts[order, 2] / r)), atol=1e-12)


def test_range_image_shapes_and_errors():
    """Default width 2000 columns; one column allowed; a width rounding to 0 gives 1; bad limits raise."""
    one = [[1.0, 0.0, 0.0]]
    assert ss.range_image(one).shape == (64, 2000)
    assert ss.range_image(one, columns=1, n_rings=1).tolist() == [[1.0]]
    assert ss.range_image(one, az_limits_deg=(0.0, 0.01), n_rings=1).tolist() == [[1.0]]
    for kw in ({"az_limits_deg": (10.0, 10.0)}, {"columns": 0}):
        with pytest.raises(ValueError) as info:
            ss.range_image(one, **kw)
        assert (
            str(info.value) == "need az_limits_deg[0] < az_limits_deg[1] and columns >= 1"
        )


def test_range_image_drops_out_of_grid_points():
    """Rings beyond n_rings and a point one column past the right edge are dropped; min_drop is passed on.

    Limits (-90, 90) with columns=4: step 90 deg, width 2 (az 90 -> column 0, az 0 -> column 1, az -90 -> 2)."""
    pts = [
        [0.0, 2.0, 0.0],
        [3.0, 0.0, 0.0],
        [0.0, -4.0, 0.0],
    ]  # az 90, 0, -90: no drop, one ring
    img = ss.range_image(pts, az_limits_deg=(-90.0, 90.0), columns=4, n_rings=2)
    np.testing.assert_array_equal(img, [[2.0, 3.0], [np.nan, np.nan]])
    two_rings = [
        [5.0, -0.1, 0.0],
        [3.0, 0.1, 0.0],
    ]  # az ~358.9 then ~1.9 deg: the wrap starts ring 1
    img = ss.range_image(two_rings, az_limits_deg=(-90.0, 90.0), columns=4, n_rings=1)
    np.testing.assert_array_equal(img, [[np.nan, np.hypot(5.0, 0.1)]])
    spread = [
        [0.0, 2.0, 0.0],
        [1.0, 1.0, 0.0],
    ]  # az 90 then 45: drop pi/4 splits only with min_drop < pi/4
    img = ss.range_image(
        spread, az_limits_deg=(-90.0, 90.0), columns=8, n_rings=2, min_drop=0.5
    )
    np.testing.assert_allclose(
        img, [[2.0, np.nan, np.nan, np.nan], [np.nan, np.sqrt(2.0), np.nan, np.nan]]
    )


# ------------------------------------------------------------------ icp_align
def _plane_grid(n=20, spacing=1.0):
    g = np.arange(n) * spacing
    x, y = np.meshgrid(g + 5.0, g - n * spacing / 2)
    floor = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, -1.5)])
    wall = np.column_stack([np.full(x.size, 25.0), y.ravel(), x.ravel() - 10.0])
    side = np.column_stack([x.ravel(), np.full(x.size, 12.0), y.ravel() + 10.0])
    return np.vstack([floor, wall, side])


def test_icp_crop_bounds_inclusive():
    """Points at exactly min_range (3 m) and max_range (80 m) are kept; nearer / farther ones (2.9, 80.5 m) not."""
    src = np.array(
        [
            [3.0, 0, 0],
            [0, 3.0, 0],
            [0, 0, 3.0],
            [80.0, 0, 0],
            [0, 80.0, 0],
            [2.9, 0, 0],
            [80.5, 0, 0],
            [0, 0, 1.0],
        ]
    )
    res = ss.icp_align(src, _plane_grid())
    assert res.n_source == 5


def test_icp_three_points_enough_and_message():
    """Three points left in each scan are enough; fewer in either raises with the full message."""
    three = np.array([[10.0, 0, 0], [0, 10.0, 0], [0, 0, 10.0]])
    res = ss.icp_align(three, _plane_grid())
    assert res.n_source == 3
    res = ss.icp_align(_plane_grid(), three)
    assert res.n_target == 3
    for src, tgt in ((three[:2], _plane_grid()), (_plane_grid(), three[:2])):
        with pytest.raises(ValueError) as info:
            ss.icp_align(src, tgt)
        assert (
            str(info.value)
            == "icp_align: fewer than 3 points left in a scan after cropping and down-sampling"
        )


def test_icp_initial_rmse_reported():
    """``inlier_rmse_init`` is the RMS pair distance at the initial guess: 0.1 m when it is off by 0.1 m along x
    (each source point lands 0.1 m from its own copy in the target, grid spacing 0.25 m)."""
    pts = _plane_grid(40, 0.25)
    init = np.eye(4)
    init[0, 3] = 0.1
    res = ss.icp_align(pts, pts, init=init)
    assert isinstance(res.inlier_rmse_init, float)
    assert res.inlier_rmse_init == pytest.approx(0.1, abs=0.02)


def test_icp_settings_reach_open3d(monkeypatch):
    """The documented settings reach open3d: every ICP round stops after ``max_iteration`` iterations (default 60,
    not open3d's 30), and the normals come from at most 30 neighbours within ``3 voxel_size``."""
    import open3d as o3d

    reg, geo = o3d.pipelines.registration, o3d.geometry
    rounds, searches = [], []
    real_icp, real_search = reg.registration_icp, geo.KDTreeSearchParamHybrid

    def icp(src, tgt, d, T, est, criteria=None):
        rounds.append(None if criteria is None else criteria.max_iteration)
        return (
            real_icp(src, tgt, d, T, est)
            if criteria is None
            else real_icp(src, tgt, d, T, est, criteria)
        )

    def search(radius, max_nn):
        searches.append((radius, max_nn))
        return real_search(radius=radius, max_nn=max_nn)

    monkeypatch.setattr(reg, "registration_icp", icp)
    monkeypatch.setattr(geo, "KDTreeSearchParamHybrid", search)
    pts = _plane_grid(12, 0.5)
    ss.icp_align(pts, pts, voxel_size=0.3)
    assert rounds == [60, 60, 60] and searches == [(pytest.approx(0.9), 30)] * 2
    rounds.clear()
    ss.icp_align(pts, pts, voxel_size=0.3, max_iteration=7, max_distances=(0.5, 0.2))
    assert rounds == [7, 7]
