"""KITTI raw timestamp files, parsed to integer nanoseconds (no precision lost).

KITTI raw writes one timestamp per line, ``YYYY-MM-DD HH:MM:SS.fffffffff`` (exactly nine fractional
digits, local time of the recording, no zone), e.g. ``2011-09-26 13:02:25.964389445``. Files:
``oxts/timestamps.txt`` (one per OXTS packet) and ``velodyne_points/timestamps{,_start,_end}.txt``.

Python's ``datetime`` (and therefore ``pykitti.raw.timestamps``) keeps only microseconds; here each line
becomes an ``int`` number of nanoseconds since 1970-01-01 00:00:00, treating the wall-clock time as UTC
(the zone does not matter for differences):

    ns = (days_since_epoch * 86400 + HH * 3600 + MM * 60 + SS) * 10**9 + fffffffff

``int64`` nanoseconds cover the years 1678-2262, which holds every KITTI recording.
"""

from __future__ import annotations

import codecs
import datetime as _dt
import os
import re
from collections.abc import Iterable

import numpy as np

from slamlib.errors import DataFormatError, bom_error

__all__ = [
    "parse_timestamp_ns",
    "format_timestamp_ns",
    "read_timestamps_ns",
    "write_timestamps_ns",
    "check_timestamps_for_pykitti",
]

_PATTERN = re.compile(r"^(\d{4})-(\d{2})-(\d{2}) (\d{2}):(\d{2}):(\d{2})\.(\d{9})$")
_EPOCH = _dt.datetime(1970, 1, 1)
_INT64_MIN, _INT64_MAX = -(2**63), 2**63 - 1
_FORMAT_HINT = (
    "expected 'YYYY-MM-DD HH:MM:SS.fffffffff' (KITTI raw format, 9 fractional digits)"
)


def parse_timestamp_ns(
    text: str, path: str | os.PathLike = "<string>", line: int | None = None
) -> int:
    """Parse one KITTI timestamp ``YYYY-MM-DD HH:MM:SS.fffffffff`` to integer nanoseconds since 1970 (UTC).

    Parameters
    ----------
    text : str
        The timestamp; surrounding whitespace is ignored.
    path, line :
        Where the text came from, only used in the error message.

    Raises
    ------
    DataFormatError
        If the text does not match the format exactly (e.g. 6 fractional digits) or the date/time is invalid
        (month 13, second 61, ...).
    """
    s = text.strip()
    m = _PATTERN.match(s)
    if m is None:
        raise DataFormatError(path, f"bad timestamp {s!r}: {_FORMAT_HINT}", line)
    y, mo, d, hh, mm, ss, frac = m.groups()
    try:
        whole = _dt.datetime(int(y), int(mo), int(d), int(hh), int(mm), int(ss))
    except ValueError as exc:
        raise DataFormatError(path, f"bad timestamp {s!r}: {exc}", line) from None
    seconds = (whole - _EPOCH) // _dt.timedelta(seconds=1)
    ns = seconds * 1_000_000_000 + int(frac)
    if not _INT64_MIN <= ns <= _INT64_MAX:
        raise DataFormatError(
            path,
            f"bad timestamp {s!r}: outside the years 1678-2262 that int64 nanoseconds "
            "since 1970 can hold",
            line,
        )
    return ns


def format_timestamp_ns(ns: int) -> str:
    """Inverse of :func:`parse_timestamp_ns`: integer nanoseconds since 1970 -> ``YYYY-MM-DD HH:MM:SS.fffffffff``."""
    ns = int(ns)
    seconds, frac = divmod(ns, 1_000_000_000)
    whole = _EPOCH + _dt.timedelta(seconds=seconds)
    return f"{whole:%Y-%m-%d %H:%M:%S}.{frac:09d}"


def read_timestamps_ns(
    path: str | os.PathLike, strictly_increasing: bool = True
) -> np.ndarray:
    """Read a KITTI timestamps file: one ``YYYY-MM-DD HH:MM:SS.fffffffff`` per line -> ``(N,)`` int64 ns.

    Blank lines at the end of the file are ignored; a blank line in the middle is an error.

    Raises
    ------
    DataFormatError
        File missing, empty, a line in the wrong format (file and 1-based line named), or (with
        ``strictly_increasing``) a timestamp not later than the one before it.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise DataFormatError(path, "timestamps file not found")
    with open(path, "rb") as f:
        raw = f.read()
    if raw.startswith(codecs.BOM_UTF8):
        raise bom_error(path)
    lines = raw.decode("ascii", errors="replace").splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines:
        raise DataFormatError(path, "timestamps file is empty")
    out = np.empty(len(lines), dtype=np.int64)
    for i, text in enumerate(lines):
        out[i] = parse_timestamp_ns(text, path, i + 1)
        if strictly_increasing and i > 0 and out[i] <= out[i - 1]:
            raise DataFormatError(
                path,
                f"timestamp {text.strip()!r} is not later than the previous line's "
                f"({format_timestamp_ns(out[i - 1])}); timestamps must be strictly increasing",
                i + 1,
            )
    return out


def check_timestamps_for_pykitti(path: str | os.PathLike) -> None:
    """Check that ``pykitti.raw`` can parse ``oxts/timestamps.txt`` (slamlib reads it first and allows more).

    pykitti parses every line as ``datetime.strptime(line[:-4], '%Y-%m-%d %H:%M:%S.%f')``: it drops the newline and
    the last three digits by position, so trailing spaces, a blank line (also at the end) or a line of another
    length make it raise. This replays that parse line by line.

    Raises
    ------
    DataFormatError
        The first line pykitti could not parse (file and 1-based line named).
    """
    path = os.fspath(path)
    with open(path, encoding="ascii", errors="replace") as f:
        lines = f.readlines()
    for i, text in enumerate(lines, start=1):
        try:
            _dt.datetime.strptime(text[:-4], "%Y-%m-%d %H:%M:%S.%f")
        except ValueError:
            raise DataFormatError(
                path,
                f"pykitti cannot parse timestamp line {text.rstrip(chr(10))!r}: it needs exactly "
                "'YYYY-MM-DD HH:MM:SS.fffffffff' on every line (no trailing spaces, no blank lines)",
                i,
            ) from None


def write_timestamps_ns(path: str | os.PathLike, timestamps_ns: Iterable[int]) -> None:
    """Write integer nanosecond timestamps in the KITTI raw format, one per line (newline-terminated)."""
    with open(path, "w", encoding="ascii") as f:
        for ns in timestamps_ns:
            f.write(format_timestamp_ns(int(ns)) + "\n")
