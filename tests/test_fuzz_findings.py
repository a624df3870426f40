"""Issue 13: regression tests for what tests/test_fuzz.py found (each failed before its fix)."""

from __future__ import annotations

import pytest

from slamlib.errors import DataFormatError


@pytest.mark.parametrize("stamp", ["0001-01-01 00:00:00.000000000", "9999-12-31 23:59:59.999999999",
                                   "2262-04-12 00:00:00.000000000", "1677-09-21 00:00:00.000000000"])
def test_timestamp_outside_int64_nanoseconds_is_a_data_format_error(tmp_path, stamp):
    from slamlib.kitti.timestamps import read_timestamps_ns

    path = tmp_path / "timestamps.txt"
    path.write_text(f"2011-09-26 13:02:25.964389445\n{stamp}\n")
    with pytest.raises(DataFormatError, match=r"timestamps.txt:2: bad timestamp .*1678-2262"):
        read_timestamps_ns(path, strictly_increasing=False)


def test_timestamps_at_the_int64_limits_still_parse():
    from slamlib.kitti.timestamps import format_timestamp_ns, parse_timestamp_ns

    for ns in (-(2**63) + 10**9, 2**63 - 1):
        text = format_timestamp_ns(ns)
        assert parse_timestamp_ns(text) == ns


@pytest.mark.parametrize("option,value", [("--points", "0"), ("--points", "-3"), ("--particles", "0"),
                                          ("--points", "100000000")])
def test_slamlib_run_count_error_names_the_option_given(tmp_path, monkeypatch, option, value):
    import slamlib.slam3d
    from slamlib.cli import main

    monkeypatch.setattr(slamlib.slam3d, "run_drive", lambda *a, **k: pytest.fail("the run started"))
    with pytest.raises(SystemExit) as exc:
        main(["run", "--no-progress", option, value, "--out", str(tmp_path / "o")])
    msg = str(exc.value)
    assert msg.startswith("slamlib run: ") and option in msg.split(":")[1] and "\n" not in msg, msg


@pytest.mark.parametrize("frames", ["1", "0:1", "2:"])
def test_slamlib_run_one_frame_selection_names_frames(tmp_path, monkeypatch, frames):
    import slamlib.slam3d
    from slamlib.cli import main
    from slamlib.kitti.sample import SAMPLE_DATE, SAMPLE_DRIVE, make_tiny_drive

    monkeypatch.setattr(slamlib.slam3d, "run_drive", lambda *a, **k: pytest.fail("the run started"))
    d = make_tiny_drive(tmp_path / "k", n_frames=3, point_stride=500)
    with pytest.raises(SystemExit) as exc:
        main(["run", "--basedir", str(d.parent.parent), "--date", SAMPLE_DATE, "--drive", SAMPLE_DRIVE,
              "--frames", frames, "--out", str(tmp_path / "o")])
    assert str(exc.value).startswith(f"slamlib run: --frames {frames!r} selects 1 frame"), str(exc.value)
