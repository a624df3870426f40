"""KITTI / TUM trajectory files and times files: round trips (hypothesis), real files, clear errors."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from slamlib.errors import DataFormatError
from slamlib.kitti import (
    read_kitti_poses,
    read_times,
    read_tum,
    write_kitti_poses,
    write_times,
    write_tum,
)
from slamlib.paths import kitti_sample_dir

finite = st.floats(min_value=-1e4, max_value=1e4, allow_nan=False, allow_infinity=False)


def _poses(quats, trans):
    T = np.zeros((len(quats), 4, 4))
    T[:, 3, 3] = 1
    T[:, :3, :3] = Rotation.from_quat(quats).as_matrix()
    T[:, :3, 3] = trans
    return T


pose_batches = st.integers(1, 8).flatmap(
    lambda n: st.tuples(
        arrays(np.float64, (n, 4), elements=st.floats(-1, 1, allow_nan=False)).filter(
            lambda q: np.all(np.linalg.norm(q, axis=1) > 0.1)
        ),
        arrays(np.float64, (n, 3), elements=finite),
    )
)


@settings(max_examples=40, deadline=None)
@given(pose_batches)
def test_kitti_round_trip_exact(tmp_path_factory, qt):
    T = _poses(*qt)
    path = tmp_path_factory.mktemp("k") / "poses.txt"
    write_kitti_poses(path, T)
    back = read_kitti_poses(path, check_rotation=True)
    np.testing.assert_array_equal(back, T)
    assert all(len(line.split()) == 12 for line in path.read_text().splitlines())


@settings(max_examples=40, deadline=None)
@given(pose_batches, st.floats(0, 1e9, allow_nan=False))
def test_tum_round_trip(tmp_path_factory, qt, t0):
    T = _poses(*qt)
    times = t0 + 0.1 * np.arange(len(T))
    path = tmp_path_factory.mktemp("t") / "traj.txt"
    write_tum(path, times, T, header=True)
    t_back, T_back = read_tum(path)
    np.testing.assert_array_equal(t_back, times)
    np.testing.assert_array_equal(T_back[:, :3, 3], T[:, :3, 3])
    np.testing.assert_allclose(T_back[:, :3, :3], T[:, :3, :3], atol=1e-12)
    # quaternions are written scalar-last, unit norm
    q = np.array(
        [
            [float(v) for v in line.split()[4:]]
            for line in path.read_text().splitlines()[1:]
        ]
    )
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1, atol=1e-12)


def test_tum_quaternion_convention(tmp_path):
    """A 90 deg yaw is written as qz = qw = sqrt(1/2) (TUM: qx qy qz qw, scalar last)."""
    T = np.eye(4)[None].copy()
    T[0, :3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    T[0, :3, 3] = [1, 2, 3]
    write_tum(tmp_path / "a.txt", [5.0], T)
    vals = [float(v) for v in (tmp_path / "a.txt").read_text().split()]
    np.testing.assert_allclose(vals[:4], [5, 1, 2, 3])
    np.testing.assert_allclose(
        np.abs(vals[4:]), [0, 0, np.sqrt(0.5), np.sqrt(0.5)], atol=1e-12
    )
    assert vals[6] * vals[7] > 0


@settings(max_examples=30, deadline=None)
@given(
    arrays(np.float64, st.integers(0, 20), elements=st.floats(0, 1e6, allow_nan=False))
)
def test_times_round_trip(tmp_path_factory, t):
    path = tmp_path_factory.mktemp("s") / "times.txt"
    write_times(path, t)
    np.testing.assert_array_equal(read_times(path), t)


def test_real_kitti_files():
    root = kitti_sample_dir() / "odometry"
    g = read_kitti_poses(root / "poses" / "00.txt", check_rotation=True)
    assert g.shape == (4541, 4, 4)
    np.testing.assert_allclose(g[0], np.eye(4), atol=1e-6)
    np.testing.assert_array_equal(g[:, 3], np.tile([0, 0, 0, 1.0], (4541, 1)))
    assert g[1, 2, 3] == 8.586941e-01
    t = read_times(root / "times" / "00.txt", strictly_increasing=True)
    assert t.shape == (4541,) and t[0] == 0 and t[1] == 1.037359e-01
    assert read_kitti_poses(root / "results" / "00_orb_slam2.txt").shape == (4541, 4, 4)


def _bad(path, text, line, match, reader):
    path.write_text(text)
    with pytest.raises(DataFormatError) as info:
        reader(path)
    msg = str(info.value)
    assert path.name in msg and info.value.line == line and f":{line}:" in msg, msg
    assert match in msg, msg


def test_kitti_bad_lines(tmp_path):
    good = " ".join(["1", "0", "0", "0", "0", "1", "0", "0", "0", "0", "1", "0"])
    p = tmp_path / "bad_poses.txt"
    _bad(p, good + "\n" + "1 2 3\n", 2, "3 numbers, expected 12", read_kitti_poses)
    _bad(
        p,
        good + "\n\n" + good.replace("0", "x", 1) + "\n",
        3,
        "not a number",
        read_kitti_poses,
    )
    _bad(p, good.replace("1", "nan", 1) + "\n", 1, "not finite", read_kitti_poses)
    _bad(
        p,
        good + "\n" + good.replace("1", "2", 1) + "\n",
        2,
        "not a rotation",
        lambda q: read_kitti_poses(q, check_rotation=True),
    )


def test_tum_bad_lines(tmp_path):
    p = tmp_path / "bad_tum.txt"
    _bad(
        p,
        "# header\n0 1 2 3 0 0 0 1\n1 1 2 3 0 0 1\n",
        3,
        "7 numbers, expected 8",
        read_tum,
    )
    _bad(p, "0 1 2 3 0 0 0 0\n", 1, "zero norm", read_tum)
    _bad(p, "0 1 2 3 0 0 0 one\n", 1, "not a number", read_tum)


def test_times_bad_lines(tmp_path):
    p = tmp_path / "bad_times.txt"
    _bad(p, "0.0\n0.1 0.2\n", 2, "2 numbers, expected 1", read_times)
    _bad(
        p,
        "0.0\n0.1\n0.1\n",
        3,
        "not later",
        lambda q: read_times(q, strictly_increasing=True),
    )


def test_missing_file(tmp_path):
    for reader in (read_kitti_poses, read_tum, read_times):
        with pytest.raises(
            DataFormatError, match="nofile.txt: trajectory file not found"
        ):
            reader(tmp_path / "nofile.txt")


def test_write_rejects_bad_shapes(tmp_path):
    with pytest.raises(ValueError):
        write_kitti_poses(tmp_path / "a.txt", np.zeros((3, 4)))
    with pytest.raises(ValueError):
        write_tum(tmp_path / "a.txt", [0.0, 1.0], np.tile(np.eye(4), (3, 1, 1)))


def test_empty_trajectories_round_trip(tmp_path):
    """An empty trajectory (a run with no poses) is written as empty KITTI and TUM files and read back as
    ``(0, 4, 4)`` poses (and no timestamps), as the readers return for an empty file."""
    empty = np.zeros((0, 4, 4))
    write_kitti_poses(tmp_path / "p.txt", empty)
    assert (tmp_path / "p.txt").read_text() == ""
    assert read_kitti_poses(tmp_path / "p.txt").shape == (0, 4, 4)
    write_tum(tmp_path / "t.txt", np.zeros(0), empty, header=False)
    assert (tmp_path / "t.txt").read_text() == ""
    t, T = read_tum(tmp_path / "t.txt")
    assert t.shape == (0,) and T.shape == (0, 4, 4)


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


# ------------------------------------------------------------------ the writers' input types
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


# ------------------------------------------------------------------ the writers refuse non-finite poses and times
@pytest.mark.parametrize("writer", ["kitti", "tum", "times"])
def test_trajectory_writers_refuse_nan(tmp_path, writer):
    from slamlib.kitti.trajectory_io import write_kitti_poses, write_times, write_tum

    T = np.tile(np.eye(4), (3, 1, 1))
    T[1, 0, 3] = np.nan
    path = tmp_path / "t.txt"
    with pytest.raises(ValueError, match="non-finite"):
        {
            "kitti": lambda: write_kitti_poses(path, T),
            "tum": lambda: write_tum(path, [0, 1, 2], T),
            "times": lambda: write_times(path, [0.0, np.nan, 1.0]),
        }[writer]()
    assert not path.exists()


def test_a_byte_order_mark_in_times_or_poses_is_named_as_such(tmp_path):
    from slamlib.kitti.trajectory_io import read_kitti_poses, read_times

    times = tmp_path / "times.txt"
    times.write_bytes("\ufeff0.0\n0.1\n".encode())
    with pytest.raises(
        DataFormatError, match=r"times\.txt:1: starts with a UTF-8 byte-order mark \(BOM"
    ):
        read_times(times)
    poses = tmp_path / "poses.txt"
    poses.write_bytes("\ufeff1 0 0 0 0 1 0 0 0 0 1 0\n".encode())
    with pytest.raises(
        DataFormatError, match=r"poses\.txt:1: starts with a UTF-8 byte-order mark"
    ):
        read_kitti_poses(poses)
