"""Timestamps files (:mod:`slamlib.kitti.timestamps`): parsing up to the int64-nanosecond limits, reading (order,
non-ASCII bytes), the check for what pykitti cannot parse, writing; messages compared whole."""

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

HINT = "expected 'YYYY-MM-DD HH:MM:SS.fffffffff' (KITTI raw format, 9 fractional digits)"
PYKITTI_HINT = (
    "it needs exactly 'YYYY-MM-DD HH:MM:SS.fffffffff' on every line (no trailing spaces, "
    "no blank lines)"
)
RANGE = "outside the years 1678-2262 that int64 nanoseconds since 1970 can hold"


def _raises(fn, exc=DataFormatError):
    with pytest.raises(exc) as info:
        fn()
    return info.value


def _write(path, text):
    path.write_text(text)
    return path


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


# ------------------------------------------------------------------ stamps beyond and at the int64-nanosecond limits
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


def test_a_byte_order_mark_is_named_as_such(tmp_path):
    from slamlib.kitti.timestamps import read_timestamps_ns

    path = tmp_path / "timestamps.txt"
    path.write_bytes(
        b"\xef\xbb\xbf2011-09-26 13:02:25.964389445\n2011-09-26 13:02:26.067702383\n"
    )
    with pytest.raises(DataFormatError) as err:
        read_timestamps_ns(path)
    assert str(err.value) == (
        f"{path}:1: starts with a UTF-8 byte-order mark (BOM, bytes EF BB BF), which KITTI's text files "
        "do not have (an editor added it?): save the file without a BOM"
    )
