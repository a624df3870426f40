"""OXTS packets (:mod:`slamlib.kitti.oxts`): physical ranges, parsing, packet files, writing and poses from packets,
with whole messages and limits exactly at the bound; expected values written by hand from the file format (or
pykitti's formulas), on hand-written lines and on tiny drives."""

import math

import numpy as np
import pytest
from drive_edits import set_oxts_field

from slamlib.errors import DataFormatError
from slamlib.kitti.oxts import (
    OxtsPacket,
    check_oxts_for_pykitti,
    format_oxts_packet,
    oxts_range_problem,
    parse_oxts_line,
    poses_from_packets,
    read_oxts_packet,
    write_oxts_packet,
)
from slamlib.kitti.sample import SAMPLE_DATE, SAMPLE_DRIVE


def _raises(fn) -> DataFormatError:
    with pytest.raises(DataFormatError) as info:
        fn()
    return info.value


def _write(path, text):
    path.write_bytes(text.encode("ascii") if isinstance(text, str) else text)
    return path


# ------------------------------------------------------------------ OXTS: ranges and parsing
GOOD = [49.0, 8.4, 110.0, 0.01, -0.02, 1.5] + [0.0] * 17 + [0.1, 0.2] + [4, 10, 4, 4, 4]


def _line(**changes):
    vals = list(GOOD)
    for name, v in changes.items():
        vals[OxtsPacket._fields.index(name)] = v
    return " ".join(str(v) for v in vals)


def test_oxts_range_problem_message_and_unknown_field():
    """Out of range: the message quotes the value with repr and the closed range with %g; fields without a range
    (the integer flags) have no problem."""
    assert (
        oxts_range_problem("lat", 90.0)
        == "OXTS field lat = 90.0 is outside its physical range [-89, 89]"
    )
    assert oxts_range_problem("alt", -1000.5) == (
        "OXTS field alt = -1000.5 is outside its physical range [-1000, 20000]"
    )
    assert oxts_range_problem("navstat", 1e9) is None


def test_oxts_range_bounds_are_inclusive():
    """The ranges are closed: exactly -89 / +89 degrees latitude and 0 accuracy are allowed."""
    assert oxts_range_problem("lat", -89.0) is None
    assert oxts_range_problem("lat", 89.0) is None
    assert oxts_range_problem("pos_accuracy", 0.0) is None
    assert oxts_range_problem("lon", math.nextafter(180.0, math.inf)) is not None


def test_parse_oxts_line_defaults_name_string_line_1():
    """Without path/line, errors read ``<string>:1: ...``."""
    err = _raises(lambda: parse_oxts_line("1 2 3"))
    assert (
        str(err)
        == "<string>:1: OXTS line has 3 fields, expected 30 (see oxts/dataformat.txt)"
    )


def test_parse_oxts_line_non_finite_message():
    """A nan latitude is field 1: ``OXTS field 1 (lat) is not finite: 'nan'``."""
    err = _raises(lambda: parse_oxts_line(_line(lat="nan"), "p.txt", 7))
    assert str(err) == "p.txt:7: OXTS field 1 (lat) is not finite: 'nan'"


def test_parse_oxts_line_fractional_integer_message():
    """A fractional navstat is field 26: ``OXTS field 26 (navstat) must be an integer, got '4.5'``."""
    err = _raises(lambda: parse_oxts_line(_line(navstat="4.5"), "p.txt", 2))
    assert str(err) == "p.txt:2: OXTS field 26 (navstat) must be an integer, got '4.5'"


def test_parse_oxts_line_range_message():
    """A latitude of 90 degrees is field 1 and outside [-89, 89]; path, line and message are all given."""
    err = _raises(lambda: parse_oxts_line(_line(lat=90.0), "p.txt", 3))
    assert (
        str(err)
        == "p.txt:3: field 1: OXTS field lat = 90.0 is outside its physical range [-89, 89]"
    )
    assert err.path == "p.txt" and err.line == 3


def test_parse_oxts_line_values_and_types():
    """A valid line gives the floats and five ints, in field order."""
    pkt = parse_oxts_line(_line())
    assert list(pkt) == GOOD
    assert [type(v) for v in pkt[-5:]] == [int] * 5 and type(pkt.lat) is float


# ------------------------------------------------------------------ OXTS: packet files
def test_read_oxts_packet_missing_file_message(tmp_path):
    """A missing packet file: ``path: OXTS packet file not found``, no line."""
    path = str(tmp_path / "0000000000.txt")
    err = _raises(lambda: read_oxts_packet(path))
    assert str(err) == f"{path}: OXTS packet file not found"
    assert err.path == path and err.line is None


def test_read_oxts_packet_empty_message(tmp_path):
    """A file of blank lines: ``path: OXTS packet file is empty (expected one line of 30 numbers)``."""
    path = _write(tmp_path / "0000000000.txt", "\n  \n")
    assert str(_raises(lambda: read_oxts_packet(path))) == (
        f"{path}: OXTS packet file is empty (expected one line of 30 numbers)"
    )


def test_read_oxts_packet_two_lines_message(tmp_path):
    """Two data lines: the second one's line (3, after a blank line) is named."""
    path = _write(tmp_path / "0000000000.txt", f"{_line()}\n\n{_line()}\n")
    assert str(_raises(lambda: read_oxts_packet(path))) == (
        f"{path}:3: OXTS packet file has more than one data line (expected exactly one)"
    )


def test_read_oxts_packet_reads_ascii_with_replacement(tmp_path):
    """Non-ASCII bytes become U+FFFD (one per byte) and are quoted in the error; a UTF-8 NEL is not a line break."""
    path = _write(
        tmp_path / "0000000000.txt", _line(alt="1\xc2\x85").encode("latin-1") + b"\n"
    )
    assert str(_raises(lambda: read_oxts_packet(path))) == (
        f"{path}:1: OXTS field 3 (alt) is not a number: '1\ufffd\ufffd'"
    )


def test_check_oxts_for_pykitti_blank_line_message(tmp_path):
    """A blank second line is named: pykitti would read it as a packet."""
    path = _write(tmp_path / "0000000000.txt", f"{_line()}\n\n")
    assert str(_raises(lambda: check_oxts_for_pykitti(path))) == (
        f"{path}:2: blank line in an OXTS packet file: pykitti reads every line as a packet (expected exactly one "
        "line of 30 numbers)"
    )


def test_check_oxts_for_pykitti_reads_ascii_with_replacement(tmp_path):
    """The file is read as ASCII with replacement: an invalid byte does not raise, and a line holding only a UTF-8
    no-break space (``\\xc2\\xa0``) is not blank."""
    path = _write(
        tmp_path / "0000000000.txt", _line().encode("ascii") + b" \xff\n\xc2\xa0\n"
    )
    assert check_oxts_for_pykitti(path) is None


# ------------------------------------------------------------------ OXTS: writing
def test_format_oxts_packet_exact_text():
    """25 floats with repr, then 5 plain integers, single-space separated."""
    text = format_oxts_packet(GOOD)
    assert text == ("49.0 8.4 110.0 0.01 -0.02 1.5 " + "0.0 " * 17 + "0.1 0.2 4 10 4 4 4")


def test_format_oxts_packet_wrong_length_message():
    """A packet of 29 values: ``an OXTS packet has 30 values, got 29``."""
    with pytest.raises(ValueError) as info:
        format_oxts_packet(GOOD[:29])
    assert str(info.value) == "an OXTS packet has 30 values, got 29"


def test_write_oxts_packet_round_trip(tmp_path):
    """A written packet file is the formatted line plus ``\\n`` and reads back equal."""
    path = tmp_path / "0000000000.txt"
    write_oxts_packet(path, GOOD)
    assert (
        path.read_bytes()
        == (
            "49.0 8.4 110.0 0.01 -0.02 1.5 " + "0.0 " * 17 + "0.1 0.2 4 10 4 4 4\n"
        ).encode()
    )
    assert list(read_oxts_packet(path)) == GOOD


# ------------------------------------------------------------------ OXTS: poses
def test_poses_from_packets_empty():
    """No packets: an empty (0, 4, 4) array."""
    out = poses_from_packets([])
    assert out.shape == (0, 4, 4)


def test_poses_from_packets_default_reference_is_first_packet():
    """World = first packet's IMU pose: a second packet 3 m higher and turned by yaw +90 degrees (same lat/lon, zero
    roll and pitch) is ``[[Rz(90), (0, 0, 3)], [0, 1]]``, and the first pose is the identity."""
    p0 = parse_oxts_line(_line(roll=0.0, pitch=0.0, yaw=0.0))
    p1 = parse_oxts_line(_line(roll=0.0, pitch=0.0, yaw=math.pi / 2, alt=113.0))
    out = poses_from_packets([p0, p1])
    expected1 = np.array(
        [
            [0.0, -1.0, 0.0, 0.0],
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 3.0],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )
    np.testing.assert_allclose(out[0], np.eye(4), atol=1e-12)
    np.testing.assert_allclose(out[1], expected1, atol=1e-9)


# ------------------------------------------------------------------ physical ranges, read through a tiny drive
def _read_all(drive_dir):
    from slamlib.kitti import KittiRawDrive

    return [
        f.T_w_imu
        for f in KittiRawDrive(drive_dir.parent.parent, SAMPLE_DATE, SAMPLE_DRIVE)
    ]


@pytest.mark.parametrize(
    "name,value",
    [
        ("lat", "91"),
        ("lat", "-90"),
        ("lat", "90"),
        ("lon", "1e308"),
        ("lon", "-180.5"),
        ("alt", "1e9"),
        ("vf", "1e300"),
        ("vn", "-200"),
        ("wz", "1e6"),
        ("ax", "5e4"),
        ("yaw", "100"),
        ("pos_accuracy", "-1"),
    ],
)
def test_oxts_value_outside_its_physical_range_names_file_line_and_field(
    drive_dir, name, value
):
    _read_all(drive_dir)  # the drive is fine before
    set_oxts_field(drive_dir, 2, name, value)
    with pytest.raises(DataFormatError) as info:
        _read_all(drive_dir)
    err = info.value
    assert err.path.endswith("0000000002.txt") and err.line == 1
    assert f"{name} = " in str(err) and "physical range" in str(err), str(err)


def test_oxts_latitude_out_of_range_in_packet_0_fails_at_open(drive_dir):
    from slamlib.kitti import KittiRawDrive

    set_oxts_field(drive_dir, 0, "lat", "91")
    with pytest.raises(DataFormatError, match="0000000000.txt:1: .*lat = 91.0"):
        KittiRawDrive(drive_dir.parent.parent, SAMPLE_DATE, SAMPLE_DRIVE)


def test_real_oxts_sample_is_within_the_ranges():
    from slamlib.kitti import read_oxts_packet
    from slamlib.kitti.sample import sample_raw_paths

    p = read_oxts_packet(sample_raw_paths()["oxts_packet"])
    assert 48 < p.lat < 50


# ------------------------------------------------------------------ the packet type and projection, against pykitti
def test_packet_type_and_pose_are_pykittis():
    """slamlib writes pykitti's ``OxtsPacket`` and ``pose_from_oxts_packet`` itself (pykitti's package import
    costs start-up): the same fields in the same order, and the same poses on packets over the whole globe."""
    import pykitti.utils as pk

    from slamlib.kitti.oxts import OxtsPacket, enu_pose_from_packet, mercator_scale

    assert OxtsPacket._fields == pk.OxtsPacket._fields
    rng = np.random.default_rng(11)
    for _ in range(200):
        values = rng.uniform(-1.0, 1.0, 30)
        values[0] = rng.uniform(-85.0, 85.0)  # lat
        values[1] = rng.uniform(-180.0, 180.0)  # lon
        values[2] = rng.uniform(-100.0, 3000.0)  # alt
        values[3:6] = rng.uniform(-math.pi, math.pi, 3)  # roll, pitch, yaw
        ours, theirs = OxtsPacket(*values), pk.OxtsPacket(*values)
        scale = mercator_scale(rng.uniform(-85.0, 85.0))
        R, t = pk.pose_from_oxts_packet(theirs, scale)
        expected = pk.transform_from_rot_trans(R, t)
        got = enu_pose_from_packet(ours, scale)
        np.testing.assert_allclose(got[:3, :3], expected[:3, :3], rtol=0, atol=1e-15)
        # metres from the Mercator origin, up to 2e7: equal to a few ulp
        np.testing.assert_allclose(got[:3, 3], expected[:3, 3], rtol=1e-14, atol=1e-9)
        np.testing.assert_array_equal(got[3], [0.0, 0.0, 0.0, 1.0])
