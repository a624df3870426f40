"""The KITTI calibration files (:mod:`slamlib.kitti.calib`): exact values, whole messages (``path:line: message``)
and limits tested exactly at the bound, on tiny hand-written KITTI-style files; the checks that stand in for
pykitti's stricter parsing. Expected values are written by hand from the file format, never copied from the
code's output."""

import locale

import numpy as np
import pytest

from slamlib.errors import DataFormatError
from slamlib.kitti import calib as kcalib
from slamlib.kitti.calib import (
    CAM_TO_CAM,
    IMU_TO_VELO,
    VELO_TO_CAM,
    check_calibration_for_pykitti,
    check_cam_to_cam,
    read_calib_file,
    rigid_transform,
)

IDENTITY_9 = "1 0 0 0 1 0 0 0 1"
P_RECT = "721.5 0 609.5 0 0 721.5 172.8 0 0 0 1 0"


def _raises(fn) -> DataFormatError:
    with pytest.raises(DataFormatError) as info:
        fn()
    return info.value


def _write(path, text):
    path.write_bytes(text.encode("ascii") if isinstance(text, str) else text)
    return path


def _cam_to_cam_text(r_rect_00=IDENTITY_9, p_rect_00=P_RECT, before=""):
    lines = [before] if before else []
    lines.append("calib_time: 09-Jan-2012 13:57:47")
    for k in range(4):
        lines.append(f"P_rect_0{k}: {p_rect_00 if k == 0 else P_RECT}")
        lines.append(f"R_rect_0{k}: {r_rect_00 if k == 0 else IDENTITY_9}")
    return "\n".join(lines) + "\n"


def _date_dir(tmp_path):
    """A ``basedir/DATE`` folder with three minimal valid calibration files."""
    d = tmp_path / "2011_09_26"
    d.mkdir()
    rigid = f"calib_time: 25-May-2012 16:47:16\nR: {IDENTITY_9}\nT: 0.5 0 -1\n"
    _write(d / IMU_TO_VELO, rigid)
    _write(d / VELO_TO_CAM, rigid)
    _write(d / CAM_TO_CAM, _cam_to_cam_text())
    return d


# ------------------------------------------------------------------ read_calib_file
def test_read_calib_file_missing_file_message(tmp_path):
    """A missing calibration file: ``path: calibration file not found``, no line."""
    path = str(tmp_path / "nope.txt")
    err = _raises(lambda: read_calib_file(path))
    assert str(err) == f"{path}: calibration file not found"
    assert err.path == path and err.line is None


def test_read_calib_file_splits_key_at_first_colon(tmp_path):
    """``calib_time: 25-May-2012 16:47:16`` is split at its first ``:``: the non-numeric value is skipped, so the
    dict holds exactly the numeric keys (splitting at the last ``:`` would keep a numeric key ``calib_time: ...``)."""
    path = _write(tmp_path / "c.txt", "calib_time: 25-May-2012 16:47:16\nR: 1 2\nT: 3\n")
    data = read_calib_file(path)
    assert sorted(data) == ["R", "T"]
    np.testing.assert_array_equal(data["R"], [1.0, 2.0])
    assert data["R"].dtype == np.float64


def test_read_calib_file_line_without_colon_message(tmp_path):
    """A line without ``:`` is named with its line and its stripped text."""
    path = _write(tmp_path / "c.txt", "R: 1\n  garbage here  \n")
    err = _raises(lambda: read_calib_file(path))
    assert str(err) == f"{path}:2: calibration line is not 'key: values': 'garbage here'"
    assert err.line == 2


def test_read_calib_file_non_finite_message(tmp_path):
    """A required key with ``inf``: ``path:line: calibration key 'T' has a non-finite value``."""
    path = _write(tmp_path / "c.txt", "R: 1 2 3\n\nT: 0 inf 0\n")
    err = _raises(lambda: read_calib_file(path, {"R": 3, "T": 3}))
    assert str(err) == f"{path}:3: calibration key 'T' has a non-finite value"
    assert (
        err.path == str(path)
        and err.line == 3
        and err.message == "calibration key 'T' has a non-finite value"
    )


def test_read_calib_file_missing_keys_listed_comma_separated(tmp_path):
    """Several missing keys are listed in ``required`` order, separated by ``, ``."""
    path = _write(tmp_path / "c.txt", "S: 1\n")
    err = _raises(lambda: read_calib_file(path, {"R": 9, "T": 3}))
    assert str(err) == f"{path}: calibration key(s) missing: R, T"


def test_read_calib_file_is_ascii_and_counts_only_newlines(tmp_path):
    """Files are read as ASCII: a UTF-8 NEL (``\\xc2\\x85``, a line break to Python's str.splitlines) in a comment
    does not shift line numbers, and a UTF-8 no-break space between numbers is not a separator."""
    path = _write(
        tmp_path / "c.txt", b"calib_time: a\xc2\x85b\nR: 1 2 3\nT: 1\xc2\xa02 3\n"
    )
    err = _raises(lambda: read_calib_file(path, {"R": 3, "T": 3}))
    assert err.line == 3
    assert str(err) == f"{path}:3: calibration key 'T' has a non-numeric value"


# ------------------------------------------------------------------ rigid_transform / read_rigid
def test_rigid_transform_default_names_in_messages(tmp_path):
    """Default names: the messages call the blocks ``R`` and ``T``, and quote T in metres with the 100 m limit."""
    err = _raises(
        lambda: rigid_transform("f.txt", np.diag([1.0, 1.0, -1.0]), [0.0, 0.0, 0.0])
    )
    assert (
        str(err)
        == "f.txt: calibration R is not a rotation matrix (R^T R != I or det R < 0)"
    )
    err = _raises(lambda: rigid_transform("f.txt", np.eye(3), [100, 0, 1]))
    assert str(err) == (
        "f.txt: calibration T = [100.0, 0.0, 1.0] m is farther than 100 m: not an offset between two "
        "sensors of one vehicle"
    )


def test_rigid_transform_offset_limit_is_inclusive():
    """``|T|`` exactly 100 m is allowed (the limit is "more than 100 m"); the 4x4 holds R and T."""
    T = rigid_transform("f.txt", np.eye(3), [0.0, 100.0, 0.0])
    expected = np.eye(4)
    expected[1, 3] = 100.0
    np.testing.assert_array_equal(T, expected)


def test_rigid_transform_rotation_tolerance_is_inclusive():
    """``max |R^T R - I|`` exactly 1e-3 is allowed: for R = I + 1e-3 e_01 the (0, 1) entry of R^T R - I is exactly
    1e-3 (the (1, 1) entry is 1e-6)."""
    R = np.eye(3)
    R[0, 1] = 1e-3
    T = rigid_transform("f.txt", R, [0.0, 0.0, 0.0])
    np.testing.assert_array_equal(T[:3, :3], R)


def test_rigid_transform_integer_input_does_not_overflow():
    """Integer arrays are checked in float64: diag(2**63 - 1, 1, 1) is not a rotation, although its int64 square
    wraps around to 1."""
    R = np.diag(np.array([2**63 - 1, 1, 1], dtype=np.int64))
    err = _raises(lambda: rigid_transform("f.txt", R, [0, 0, 0]))
    assert "is not a rotation matrix" in err.message


# ------------------------------------------------------------------ check_cam_to_cam
def test_cam_to_cam_rotation_tolerance_is_inclusive(tmp_path):
    """``R_rect_00`` with ``max |R^T R - I|`` exactly 1e-3 passes (pykitti can still invert it)."""
    path = _write(
        tmp_path / CAM_TO_CAM, _cam_to_cam_text(r_rect_00="1 0.001 0 0 1 0 0 0 1")
    )
    d = check_cam_to_cam(path)
    np.testing.assert_array_equal(d["R_rect_00"], [1, 0.001, 0, 0, 1, 0, 0, 0, 1])


def test_cam_to_cam_small_positive_focal_length_passes(tmp_path):
    """Any positive focal length is accepted, also one below 1 pixel."""
    path = _write(
        tmp_path / CAM_TO_CAM, _cam_to_cam_text(p_rect_00="0.5 0 0 0 0 0.5 0 0 0 0 1 0")
    )
    assert check_cam_to_cam(path)["P_rect_00"][0] == 0.5


def test_cam_to_cam_focal_length_message(tmp_path):
    """A zero focal length: the message quotes ``P[0, 0] = 0`` and names the ``P_rect_00`` line (line 2)."""
    path = _write(
        tmp_path / CAM_TO_CAM, _cam_to_cam_text(p_rect_00="0 0 0 0 0 1 0 0 0 0 1 0")
    )
    err = _raises(lambda: check_cam_to_cam(path))
    assert (
        str(err)
        == f"{path}:2: calibration P_rect_00 has focal length P[0, 0] = 0: it must be positive"
    )


def test_cam_to_cam_line_of_bad_rotation_counts_newlines_only(tmp_path):
    """The line named for a bad ``R_rect_00`` counts ``\\n`` only: non-ASCII bytes before it (a UTF-8 NEL, an
    invalid byte) neither shift it nor make the check fail."""
    path = _write(
        tmp_path / CAM_TO_CAM,
        _cam_to_cam_text(r_rect_00="1 0 0 0 1 0 0 0 -1")
        .encode("ascii")
        .replace(b"calib_time: ", b"calib_time: \xc2\x85\xff "),
    )
    err = _raises(lambda: check_cam_to_cam(path))
    assert str(err) == (
        f"{path}:3: calibration R_rect_00 is not a rotation matrix (R^T R != I or det R < 0)"
    )


# ------------------------------------------------------------------ check_calibration_for_pykitti
def test_pykitti_check_accepts_valid_files(tmp_path):
    """Three well-formed files pass the pykitti check."""
    assert check_calibration_for_pykitti(_date_dir(tmp_path)) is None


def test_pykitti_check_undecodable_byte_message_and_line(tmp_path):
    """A byte the locale encoding cannot decode: the message quotes the byte and the encoding, and the line is the
    1-based line holding it (line 3 here)."""
    d = _date_dir(tmp_path)
    path = d / IMU_TO_VELO
    _write(path, b"calib_time: x\nR: 1 0 0 0 1 0 0 0 1\nT: 0 0 0 \xff\n")
    encoding = locale.getpreferredencoding(False)
    err = _raises(lambda: check_calibration_for_pykitti(d))
    assert str(err) == (
        f"{path}:3: byte b'\\xff' is not {encoding} text: pykitti cannot read the file (KITTI "
        "calibration files are ASCII)"
    )


def test_pykitti_check_unknown_encoding_names_first_byte(tmp_path, monkeypatch):
    """A locale encoding Python does not know (LookupError, no byte offset): the first byte and line 1 are named."""
    d = _date_dir(tmp_path)
    monkeypatch.setattr(kcalib.locale, "getpreferredencoding", lambda *a: "no-such-codec")
    err = _raises(lambda: check_calibration_for_pykitti(d))
    assert str(err) == (
        f"{d / IMU_TO_VELO}:1: byte b'c' is not no-such-codec text: pykitti cannot read the file "
        "(KITTI calibration files are ASCII)"
    )


def test_pykitti_check_blank_line_message(tmp_path):
    """A blank line (which slamlib skips) is named with its line: pykitti splits every line at ``:``."""
    d = _date_dir(tmp_path)
    path = d / VELO_TO_CAM
    _write(path, f"R: {IDENTITY_9}\n\nT: 0 0 0\n")
    err = _raises(lambda: check_calibration_for_pykitti(d))
    assert (
        str(err)
        == f"{path}:2: line without ':' (a blank line too): pykitti reads every line as 'key: values'"
    )


def test_pykitti_check_absent_key_is_a_data_format_error_without_line(tmp_path):
    """A required key pykitti does not find and no line holds (check run without check_calibration) is a
    DataFormatError naming the file, with no line, saying the key is missing."""
    d = _date_dir(tmp_path)
    path = d / IMU_TO_VELO
    _write(path, f"R: {IDENTITY_9}\n")
    err = _raises(lambda: check_calibration_for_pykitti(d))
    assert err.path == str(path) and err.line is None
    assert (
        err.message
        == "calibration key 'T' is missing: pykitti needs 'T:' at the start of a line"
    )


def test_pykitti_check_key_line_splits_at_first_colon(tmp_path):
    """The line named for a key pykitti skips is found by splitting at the first ``:`` (``R: 1:2`` is key ``R``)."""
    d = _date_dir(tmp_path)
    path = d / IMU_TO_VELO
    _write(path, "T: 0 0 0\nR: 1:2\n")
    err = _raises(lambda: check_calibration_for_pykitti(d))
    assert err.path == str(path) and err.line == 2 and "'R'" in err.message


# ------------------------------------------------------------------ a calibration offset farther than a vehicle
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
