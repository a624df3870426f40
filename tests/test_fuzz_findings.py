"""Issue 13: regression tests for what tests/test_fuzz.py found (each failed before its fix)."""

from __future__ import annotations

import pytest

from slamlib.errors import DataFormatError


@pytest.mark.parametrize(
    "stamp",
    [
        "0001-01-01 00:00:00.000000000",
        "9999-12-31 23:59:59.999999999",
        "2262-04-12 00:00:00.000000000",
        "1677-09-21 00:00:00.000000000",
    ],
)
def test_timestamp_outside_int64_nanoseconds_is_a_data_format_error(tmp_path, stamp):
    from slamlib.kitti.timestamps import read_timestamps_ns

    path = tmp_path / "timestamps.txt"
    path.write_text(f"2011-09-26 13:02:25.964389445\n{stamp}\n")
    with pytest.raises(
        DataFormatError, match=r"timestamps.txt:2: bad timestamp .*1678-2262"
    ):
        read_timestamps_ns(path, strictly_increasing=False)


def test_timestamps_at_the_int64_limits_still_parse():
    from slamlib.kitti.timestamps import format_timestamp_ns, parse_timestamp_ns

    for ns in (-(2**63) + 10**9, 2**63 - 1):
        text = format_timestamp_ns(ns)
        assert parse_timestamp_ns(text) == ns


@pytest.mark.parametrize(
    "option,value",
    [
        ("--points", "0"),
        ("--points", "-3"),
        ("--particles", "0"),
        ("--points", "100000000"),
    ],
)
def test_slamlib_run_count_error_names_the_option_given(
    tmp_path, monkeypatch, option, value
):
    import slamlib.slam3d
    from slamlib.cli import main

    monkeypatch.setattr(
        slamlib.slam3d, "run_drive", lambda *a, **k: pytest.fail("the run started")
    )
    with pytest.raises(SystemExit) as exc:
        main(["run", "--no-progress", option, value, "--out", str(tmp_path / "o")])
    msg = str(exc.value)
    assert (
        msg.startswith("slamlib run: ")
        and option in msg.split(":")[1]
        and "\n" not in msg
    ), msg


@pytest.mark.parametrize("frames", ["1", "0:1", "2:"])
def test_slamlib_run_one_frame_selection_names_frames(tmp_path, monkeypatch, frames):
    import slamlib.slam3d
    from slamlib.cli import main
    from slamlib.kitti.sample import SAMPLE_DATE, SAMPLE_DRIVE, make_tiny_drive

    monkeypatch.setattr(
        slamlib.slam3d, "run_drive", lambda *a, **k: pytest.fail("the run started")
    )
    d = make_tiny_drive(tmp_path / "k", n_frames=3, point_stride=500)
    with pytest.raises(SystemExit) as exc:
        main(
            [
                "run",
                "--basedir",
                str(d.parent.parent),
                "--date",
                SAMPLE_DATE,
                "--drive",
                SAMPLE_DRIVE,
                "--frames",
                frames,
                "--out",
                str(tmp_path / "o"),
            ]
        )
    assert str(exc.value).startswith(
        f"slamlib run: --frames {frames!r} selects 1 frame"
    ), str(exc.value)


def test_calibration_offset_farther_than_a_vehicle_is_a_data_format_error(tmp_path):
    from slamlib.kitti.calib import read_rigid

    path = tmp_path / "calib_imu_to_velo.txt"
    path.write_text("R: 1 0 0 0 1 0 0 0 1\nT: -0.8 0.3 524348\n")
    with pytest.raises(
        DataFormatError,
        match=r"calib_imu_to_velo.txt: calibration T .* farther than 100 m",
    ):
        read_rigid(path)
    path.write_text("R: 1 0 0 0 1 0 0 0 1\nT: -0.8 0.3 -1.2\n")
    assert read_rigid(path)[2, 3] == -1.2


@pytest.mark.parametrize("fmt", ["ply", "pcd"])
def test_slamlib_run_with_every_scan_empty_writes_an_empty_map(tmp_path, fmt):
    import json

    import open3d as o3d

    from slamlib.cli import main
    from slamlib.kitti.sample import SAMPLE_DATE, SAMPLE_DRIVE, make_tiny_drive

    d = make_tiny_drive(tmp_path / "k", n_frames=3, point_stride=500)
    for p in (d / "velodyne_points" / "data").iterdir():
        p.write_bytes(b"")
    out = tmp_path / "o"
    assert (
        main(
            [
                "run",
                "--basedir",
                str(d.parent.parent),
                "--date",
                SAMPLE_DATE,
                "--drive",
                SAMPLE_DRIVE,
                "--no-progress",
                "--no-plots",
                "--particles",
                "8",
                "--points",
                "30",
                "--backend",
                "numpy",
                "--map-format",
                fmt,
                "--out",
                str(out),
            ]
        )
        == 0
    )
    assert len(o3d.io.read_point_cloud(str(out / f"map.{fmt}")).points) == 0
    info = json.loads((out / "metrics.json").read_text())
    assert info["map_points_written"] == 0 and info["n_skipped_frames"] == 3


def test_synth_frames_beyond_the_route_names_frames(tmp_path):
    from slamlib.cli import main

    with pytest.raises(SystemExit) as exc:
        main(
            [
                "synth",
                "--out",
                str(tmp_path / "s"),
                "--route",
                "straight",
                "--frames",
                "583",
                "--no-progress",
            ]
        )
    assert str(exc.value).startswith(
        "slamlib synth: --frames '583': route 'straight' spans at most"
    ), str(exc.value)
    assert not (tmp_path / "s").exists()


@pytest.mark.parametrize(
    "command,option", [("synth", "--drive"), ("sim2d", "--particles")]
)
def test_option_equals_double_dash_is_a_one_line_error(tmp_path, capsys, command, option):
    from slamlib.cli import main

    argv = [command, f"{option}=--"] + (
        ["--out", str(tmp_path / "s")] if command == "synth" else []
    )
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2 and option in capsys.readouterr().err


# ------------------------------------------------------------------ drive.calib: what pykitti parses more strictly
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
    """Issue 13 item 3: these drives open in slamlib, and ``drive.calib`` raised from inside pykitti."""
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
    """A singular R_rect_00 made pykitti raise LinAlgError; P_rect_00[0, 0] = 0 gave NaN in drive.calib."""
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
