"""Exact values of the trajectory and timestamp readers / writers: full error messages, limits, file contents.

The messages are the contract (slamlib promises errors naming file, line and what is wrong), so they are
compared whole with ``str(err)``; the numbers are computed by hand on tiny inputs.
"""

import datetime as dt

import numpy as np
import pytest

from slamlib.errors import DataFormatError
from slamlib.kitti.timestamps import (
    check_timestamps_for_pykitti,
    format_timestamp_ns,
    parse_timestamp_ns,
    read_timestamps_ns,
    write_timestamps_ns,
)
from slamlib.kitti.trajectory_io import (
    read_kitti_poses,
    read_times,
    read_tum,
    write_kitti_poses,
    write_times,
    write_tum,
)

HINT = "expected 'YYYY-MM-DD HH:MM:SS.fffffffff' (KITTI raw format, 9 fractional digits)"
PYKITTI_HINT = (
    "it needs exactly 'YYYY-MM-DD HH:MM:SS.fffffffff' on every line (no trailing spaces, "
    "no blank lines)"
)
RANGE = "outside the years 1678-2262 that int64 nanoseconds since 1970 can hold"
IDENTITY_ROW = "1 0 0 0 0 1 0 0 0 0 1 0"


def _raises(fn, exc=DataFormatError):
    with pytest.raises(exc) as info:
        fn()
    return info.value


def _write(path, text):
    path.write_text(text)
    return path


# ------------------------------------------------------------------ trajectory_io: KITTI poses
def test_kitti_pose_not_a_number_names_value_position(tmp_path):
    """A non-number names its 1-based position inside the line, the kind of file and the token."""
    p = _write(tmp_path / "poses.txt", IDENTITY_ROW + "\n" + "1 0 x 0 0 1 0 0 0 0 1 0\n")
    err = _raises(lambda: read_kitti_poses(p))
    assert str(err) == f"{p}:2: KITTI pose value 3 is not a number: 'x'"
    assert (err.path, err.line) == (str(p), 2)


def test_kitti_pose_not_finite_names_value_position(tmp_path):
    """inf at the 4th place reads 'KITTI pose value 4 is not finite'."""
    p = _write(tmp_path / "poses.txt", "1 0 0 inf 0 1 0 0 0 0 1 0\n")
    assert (
        str(_raises(lambda: read_kitti_poses(p)))
        == f"{p}:1: KITTI pose value 4 is not finite: 'inf'"
    )


def test_kitti_pose_wrong_count_message(tmp_path):
    """Eleven numbers: 'KITTI pose line has 11 numbers, expected 12'."""
    p = _write(tmp_path / "poses.txt", "1 0 0 0 0 1 0 0 0 0 1\n")
    assert (
        str(_raises(lambda: read_kitti_poses(p)))
        == f"{p}:1: KITTI pose line has 11 numbers, expected 12"
    )


def test_kitti_pose_hash_is_not_a_comment(tmp_path):
    """KITTI pose files have no comments: a '#' line is a bad line (TUM and times files skip it)."""
    p = _write(tmp_path / "poses.txt", "# header\n" + IDENTITY_ROW + "\n")
    assert (
        str(_raises(lambda: read_kitti_poses(p)))
        == f"{p}:1: KITTI pose line has 2 numbers, expected 12"
    )


def test_kitti_pose_rotation_unchecked_by_default(tmp_path):
    """Without check_rotation a non-rotation block is read as written; with it, the line is named."""
    p = _write(tmp_path / "poses.txt", IDENTITY_ROW + "\n" + "2 0 0 1 0 2 0 2 0 0 2 3\n")
    T = read_kitti_poses(p)
    expected = np.array(
        [[2, 0, 0, 1], [0, 2, 0, 2], [0, 0, 2, 3], [0, 0, 0, 1]], dtype=float
    )
    np.testing.assert_array_equal(T[1], expected)
    err = _raises(lambda: read_kitti_poses(p, check_rotation=True))
    assert str(err) == f"{p}:2: KITTI pose rotation block is not a rotation matrix"


def test_kitti_pose_rotation_tolerance_is_inclusive(tmp_path):
    """|R^T R - I| exactly 1e-4 (r12 = 1e-4, computed exactly) passes; 0.5 fails."""
    p = _write(tmp_path / "poses.txt", "1 0.0001 0 0 0 1 0 0 0 0 1 0\n")
    assert read_kitti_poses(p, check_rotation=True)[0, 0, 1] == 1e-4
    q = _write(tmp_path / "poses2.txt", "1 0.5 0 0 0 1 0 0 0 0 1 0\n")
    assert str(_raises(lambda: read_kitti_poses(q, check_rotation=True))).startswith(
        f"{q}:1: KITTI pose rotation"
    )


def test_kitti_poses_values_and_shape(tmp_path):
    """Two lines -> (2, 4, 4), the 12 numbers row-major in the top 3x4, bottom row 0 0 0 1."""
    p = _write(
        tmp_path / "poses.txt", IDENTITY_ROW + "\n\n" + "0 -1 0 5 1 0 0 6 0 0 1 7\n"
    )
    T = read_kitti_poses(p, check_rotation=True)
    assert T.shape == (2, 4, 4) and T.dtype == np.float64
    np.testing.assert_array_equal(
        T[1], [[0, -1, 0, 5], [1, 0, 0, 6], [0, 0, 1, 7], [0, 0, 0, 1]]
    )


def test_write_kitti_poses_golden_text(tmp_path):
    """(N, 3, 4) poses are accepted and written as repr floats, 12 per line."""
    P = np.zeros((2, 3, 4))
    P[:, :, :3] = np.eye(3)
    P[1, :, 3] = [0.1, -2.0, 3.5]
    write_kitti_poses(tmp_path / "p.txt", P)
    assert (tmp_path / "p.txt").read_text() == (
        "1.0 0.0 0.0 0.0 0.0 1.0 0.0 0.0 0.0 0.0 1.0 0.0\n"
        "1.0 0.0 0.0 0.1 0.0 1.0 0.0 -2.0 0.0 0.0 1.0 3.5\n"
    )


def test_write_poses_rejects_3d_wrong_shape(tmp_path):
    """A 3-D array that is neither (N, 4, 4) nor (N, 3, 4) is refused, naming the shape; nothing is written."""
    err = _raises(
        lambda: write_kitti_poses(tmp_path / "p.txt", np.zeros((2, 4, 3))), ValueError
    )
    assert str(err) == "poses must be (N, 4, 4) or (N, 3, 4), got (2, 4, 3)"
    assert not (tmp_path / "p.txt").exists()


def test_write_poses_non_finite_message_counts(tmp_path):
    """Three poses, the 2nd and 3rd with NaN / inf (each pose checked whole, bottom row included): '2 of 3, the
    first at index 1'; nothing is written."""
    T = np.tile(np.eye(4), (3, 1, 1))
    T[1, 3, 3] = np.nan
    T[2, 2, 2] = np.inf
    msg = "refusing to write a trajectory with non-finite (NaN / inf) poses: 2 of 3, the first at index 1"
    assert (
        str(_raises(lambda: write_kitti_poses(tmp_path / "p.txt", T), ValueError)) == msg
    )
    assert (
        str(_raises(lambda: write_tum(tmp_path / "t.txt", [0, 1, 2], T), ValueError))
        == msg
    )
    assert not (tmp_path / "p.txt").exists() and not (tmp_path / "t.txt").exists()


# ------------------------------------------------------------------ trajectory_io: TUM
def test_tum_values_by_hand(tmp_path):
    """qx = 1 is a half turn about x (diag 1 -1 -1); a comment line is skipped; times and translation kept."""
    p = _write(
        tmp_path / "t.txt",
        "# timestamp tx ty tz qx qy qz qw\n0.5 1 2 3 1 0 0 0\n1.5 4 5 6 0 0 0 2\n",
    )
    t, T = read_tum(p)
    np.testing.assert_array_equal(t, [0.5, 1.5])
    assert T.shape == (2, 4, 4)
    np.testing.assert_allclose(
        T[0], [[1, 0, 0, 1], [0, -1, 0, 2], [0, 0, -1, 3], [0, 0, 0, 1]], atol=1e-15
    )
    np.testing.assert_allclose(
        T[1], [[1, 0, 0, 4], [0, 1, 0, 5], [0, 0, 1, 6], [0, 0, 0, 1]], atol=1e-15
    )


def test_tum_empty_file(tmp_path):
    """A TUM file of comments only reads as 0 timestamps and (0, 4, 4) poses."""
    t, T = read_tum(_write(tmp_path / "t.txt", "# nothing\n"))
    assert t.shape == (0,) and T.shape == (0, 4, 4)


def test_tum_tiny_quaternion_is_normalised(tmp_path):
    """A quaternion of norm exactly 1e-12 is not 'zero' (the limit is exclusive): it reads as the identity."""
    p = _write(tmp_path / "t.txt", "0 0 0 0 0 0 0 1e-12\n")
    np.testing.assert_allclose(read_tum(p)[1][0], np.eye(4), atol=1e-15)
    q = _write(tmp_path / "t2.txt", "0 0 0 0 0 0 0 0\n")
    assert (
        str(_raises(lambda: read_tum(q)))
        == f"{q}:1: TUM quaternion (qx qy qz qw) has zero norm"
    )


def test_tum_bad_line_messages(tmp_path):
    """TUM messages name the kind 'TUM', the count, or the value position."""
    p = _write(tmp_path / "t.txt", "0 1 2 3 0 0 0\n")
    assert (
        str(_raises(lambda: read_tum(p))) == f"{p}:1: TUM line has 7 numbers, expected 8"
    )
    q = _write(tmp_path / "t2.txt", "0 1 2 3 0 0 0 nan\n")
    assert str(_raises(lambda: read_tum(q))) == f"{q}:1: TUM value 8 is not finite: 'nan'"


def test_tum_invalid_utf8_is_replaced(tmp_path):
    """Bytes that are not UTF-8 become U+FFFD and give a DataFormatError (not UnicodeDecodeError)."""
    p = tmp_path / "t.txt"
    p.write_bytes(b"0 1 2 3 0 0 0 1\xff\n")
    assert (
        str(_raises(lambda: read_tum(p)))
        == f"{p}:1: TUM value 8 is not a number: '1\ufffd'"
    )


def test_write_tum_golden_text_with_header(tmp_path):
    """header=True writes the evo comment; timestamps of shape (1, N) are flattened; identity -> 0 0 0 1."""
    T = np.tile(np.eye(4), (2, 1, 1))
    T[:, :3, 3] = [[1, 2, 3], [4, 5, 6]]
    write_tum(tmp_path / "t.txt", np.array([[0.5, 1.25]]), T, header=True)
    assert (tmp_path / "t.txt").read_text() == (
        "# timestamp tx ty tz qx qy qz qw\n0.5 1.0 2.0 3.0 0.0 0.0 0.0 1.0\n1.25 4.0 5.0 6.0 0.0 0.0 0.0 1.0\n"
    )


def test_write_tum_errors(tmp_path):
    """Wrong number of timestamps and non-finite timestamps give these exact messages."""
    T = np.tile(np.eye(4), (3, 1, 1))
    err = _raises(lambda: write_tum(tmp_path / "t.txt", [0.0, 1.0], T), ValueError)
    assert str(err) == "2 timestamps for 3 poses"
    err = _raises(
        lambda: write_tum(tmp_path / "t.txt", [0.0, np.inf, 2.0], T), ValueError
    )
    assert (
        str(err)
        == "refusing to write a trajectory with non-finite (NaN / inf) timestamps"
    )


# ------------------------------------------------------------------ trajectory_io: times
def test_times_comments_and_values(tmp_path):
    """times files skip '#' comments and blank lines."""
    p = _write(tmp_path / "times.txt", "# seconds\n0.0\n\n0.103\n")
    t = read_times(p)
    assert t.dtype == np.float64
    np.testing.assert_array_equal(t, [0.0, 0.103])


def test_times_not_increasing_names_previous_value(tmp_path):
    """The message names the value just before (3.0), not an earlier one."""
    p = _write(tmp_path / "times.txt", "1.0\n2.0\n3.0\n2.5\n")
    err = _raises(lambda: read_times(p, strictly_increasing=True))
    assert str(err) == f"{p}:4: time 2.5 is not later than the previous 3.0"


def test_times_bad_line_messages(tmp_path):
    """A times line with two numbers, or a word, names the kind 'time'."""
    p = _write(tmp_path / "times.txt", "0.0\n1 2\n")
    assert (
        str(_raises(lambda: read_times(p)))
        == f"{p}:2: time line has 2 numbers, expected 1"
    )
    q = _write(tmp_path / "times2.txt", "abc\n")
    assert (
        str(_raises(lambda: read_times(q)))
        == f"{q}:1: time value 1 is not a number: 'abc'"
    )


def test_write_times_golden_and_flattened(tmp_path):
    """A (2, 2) array is written flattened, one repr float per line."""
    write_times(tmp_path / "t.txt", np.array([[0.0, 0.1], [1.0, 2.5]]))
    assert (tmp_path / "t.txt").read_text() == "0.0\n0.1\n1.0\n2.5\n"


def test_write_times_non_finite_message(tmp_path):
    """NaN times: the exact message, nothing written."""
    err = _raises(lambda: write_times(tmp_path / "t.txt", [0.0, np.nan]), ValueError)
    assert str(err) == "refusing to write non-finite (NaN / inf) times"
    assert not (tmp_path / "t.txt").exists()


# ------------------------------------------------------------------ timestamps
def test_parse_default_path_in_message():
    """Without a path the message starts with '<string>' and has no line."""
    err = _raises(lambda: parse_timestamp_ns("2011-09-26 13:02:25.964389"))
    assert str(err) == f"<string>: bad timestamp '2011-09-26 13:02:25.964389': {HINT}"
    assert err.line is None


def test_parse_invalid_date_message_is_datetimes():
    """Month 13: the message ends with datetime's own reason (computed here from datetime)."""
    with pytest.raises(ValueError) as ref:
        dt.datetime(2011, 13, 26, 13, 2, 25)
    text = "2011-13-26 13:02:25.000000000"
    err = _raises(lambda: parse_timestamp_ns(text, "ts.txt", 3))
    assert str(err) == f"ts.txt:3: bad timestamp {text!r}: {ref.value}"


def test_parse_int64_limits_inclusive():
    """-2**63 and 2**63 - 1 ns (pandas' 1677-09-21 00:12:43.145224192 / 2262-04-11 23:47:16.854775807) parse;
    one nanosecond beyond either is refused with the range message."""
    lo, hi = "1677-09-21 00:12:43.145224192", "2262-04-11 23:47:16.854775807"
    assert parse_timestamp_ns(lo) == -(2**63)
    assert parse_timestamp_ns(hi) == 2**63 - 1
    for text in ("1677-09-21 00:12:43.145224191", "2262-04-11 23:47:16.854775808"):
        err = _raises(lambda: parse_timestamp_ns(text, "f.txt", 1))
        assert str(err) == f"f.txt:1: bad timestamp {text!r}: {RANGE}"


def test_read_timestamps_missing_and_empty(tmp_path):
    """Missing and blank-only files: exact messages without a line."""
    p = tmp_path / "timestamps.txt"
    assert (
        str(_raises(lambda: read_timestamps_ns(p))) == f"{p}: timestamps file not found"
    )
    _write(p, "\n  \n")
    assert str(_raises(lambda: read_timestamps_ns(p))) == f"{p}: timestamps file is empty"


def test_read_timestamps_second_line_not_later(tmp_path):
    """Line 2 equal to line 1 is refused at line 2 (the first comparison is checked)."""
    a = "2011-09-26 13:02:25.000000001"
    p = _write(tmp_path / "timestamps.txt", f"{a}\n{a}\n")
    err = _raises(lambda: read_timestamps_ns(p))
    assert str(err) == (
        f"{p}:2: timestamp {a!r} is not later than the previous line's ({a}); "
        "timestamps must be strictly increasing"
    )
    np.testing.assert_array_equal(
        read_timestamps_ns(p, strictly_increasing=False), [1317042145000000001] * 2
    )


def test_read_timestamps_third_line_names_second(tmp_path):
    """Line 3 earlier than line 2: the message quotes line 2's time, not line 1's."""
    lines = [
        "2011-09-26 13:02:25.000000000",
        "2011-09-26 13:02:27.000000000",
        "2011-09-26 13:02:26.000000000",
    ]
    p = _write(tmp_path / "timestamps.txt", "\n".join(lines) + "\n")
    err = _raises(lambda: read_timestamps_ns(p))
    assert str(err) == (
        f"{p}:3: timestamp {lines[2]!r} is not later than the previous line's ({lines[1]}); "
        "timestamps must be strictly increasing"
    )


def test_read_timestamps_non_ascii_replaced(tmp_path):
    """Read as ASCII with replacement: the two UTF-8 bytes of 'é' become two U+FFFD in the message."""
    p = tmp_path / "timestamps.txt"
    p.write_bytes("2011-09-26 13:02:25.96438944é\n".encode())
    bad = "2011-09-26 13:02:25.96438944\ufffd\ufffd"
    assert (
        str(_raises(lambda: read_timestamps_ns(p)))
        == f"{p}:1: bad timestamp {bad!r}: {HINT}"
    )


def test_pykitti_check_non_ascii_replaced(tmp_path):
    """The pykitti check reads ASCII with replacement too, and quotes the line without its newline."""
    p = tmp_path / "timestamps.txt"
    p.write_bytes(
        "2011-09-26 13:02:25.964389445\n2011-09-26 13:02:26.96438944é\n".encode()
    )
    bad = "2011-09-26 13:02:26.96438944\ufffd\ufffd"
    err = _raises(lambda: check_timestamps_for_pykitti(p))
    assert (
        str(err) == f"{p}:2: pykitti cannot parse timestamp line {bad!r}: {PYKITTI_HINT}"
    )


def test_pykitti_check_cuts_four_characters(tmp_path):
    """pykitti cuts 4 characters: 4 fractional digits + newline leave 1 digit (fine); 10 digits leave 7 (%f takes
    at most 6), so that line is refused."""
    ok = _write(tmp_path / "ok.txt", "2011-09-26 13:02:25.1234\n")
    check_timestamps_for_pykitti(ok)
    line = "2011-09-26 13:02:25.1234567890"
    bad = _write(tmp_path / "bad.txt", line + "\n")
    assert str(_raises(lambda: check_timestamps_for_pykitti(bad))) == (
        f"{bad}:1: pykitti cannot parse timestamp line {line!r}: {PYKITTI_HINT}"
    )


def test_write_timestamps_round_trip(tmp_path):
    """Written lines are the KITTI format; reading them back gives the same integers."""
    ns = [0, 1317042145964389445, -(2**63)]
    write_timestamps_ns(tmp_path / "ts.txt", ns)
    assert (tmp_path / "ts.txt").read_text() == (
        "1970-01-01 00:00:00.000000000\n2011-09-26 13:02:25.964389445\n1677-09-21 00:12:43.145224192\n"
    )
    np.testing.assert_array_equal(
        read_timestamps_ns(tmp_path / "ts.txt", strictly_increasing=False), ns
    )
    assert format_timestamp_ns(ns[1]) == "2011-09-26 13:02:25.964389445"


def test_writers_convert_object_arrays_to_float(tmp_path):
    """Object arrays (e.g. a pandas object column's ``.values``) are converted to float64 like any array: the
    files are identical to those written from float arrays."""
    T = np.tile(np.eye(4), (2, 1, 1))
    T[1, :3, 3] = [0.1, 0.2, 0.3]
    t = np.array([0.5, 1.5])
    write_kitti_poses(tmp_path / "a.txt", T)
    write_kitti_poses(tmp_path / "b.txt", T.astype(object))
    write_tum(tmp_path / "c.txt", t, T)
    write_tum(tmp_path / "d.txt", t.astype(object), T.astype(object))
    write_times(tmp_path / "e.txt", t)
    write_times(tmp_path / "f.txt", t.astype(object))
    for x, y in ("ab", "cd", "ef"):
        assert (tmp_path / f"{x}.txt").read_text() == (tmp_path / f"{y}.txt").read_text()
    assert (tmp_path / "f.txt").read_text() == "0.5\n1.5\n"
