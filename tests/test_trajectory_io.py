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
