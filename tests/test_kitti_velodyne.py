"""Velodyne scan files (:mod:`slamlib.kitti.velodyne`): reading ``.bin`` and ``.bin.xz``, writing, and whole
messages naming the file."""

from __future__ import annotations

import lzma

import numpy as np
import pytest

from slamlib.errors import DataFormatError
from slamlib.kitti import read_velodyne_scan
from slamlib.kitti.velodyne import write_velodyne_scan


def _err(fn, exc=DataFormatError):
    with pytest.raises(exc) as info:
        fn()
    return info.value


# ------------------------------------------------------------------ velodyne
def test_missing_scan_file_message(tmp_path):
    """A missing scan: the whole message, naming the file."""
    err = _err(lambda: read_velodyne_scan(tmp_path / "a.bin"))
    assert str(err) == f"{tmp_path / 'a.bin'}: Velodyne scan file not found"


def test_xz_scan_reads_the_same_values(tmp_path):
    """A ``.bin.xz`` file holds the little-endian float32 bytes of a ``.bin``: read back exactly."""
    pts = np.array(
        [[1.5, -2.25, 3.0, 0.5], [4.0, 5.0, -6.5, 1.0], [0.1, 0.2, 0.3, 0.0]],
        dtype=np.float32,
    )
    f = tmp_path / "000000.bin.xz"
    f.write_bytes(lzma.compress(pts.astype("<f4").tobytes()))
    got = read_velodyne_scan(f)
    assert got.dtype == np.float32 and got.shape == (3, 4)
    np.testing.assert_array_equal(got, pts)


def test_xz_scan_size_is_the_decompressed_size(tmp_path):
    """The 16-byte check counts the decompressed bytes (20 here), not the compressed file size."""
    f = tmp_path / "s.bin.xz"
    f.write_bytes(lzma.compress(bytes(20)))
    err = _err(lambda: read_velodyne_scan(f))
    assert (
        str(err)
        == f"{f}: Velodyne scan has 20 bytes, not a multiple of 16 (4 float32 per point)"
    )


def test_unreadable_xz_message(tmp_path):
    """A ``.xz`` name holding no xz data: DataFormatError naming the file, with lzma's reason."""
    f = tmp_path / "s.bin.xz"
    f.write_bytes(bytes(32))
    err = _err(lambda: read_velodyne_scan(f))
    assert err.path == str(f)
    assert str(err).startswith(f"{f}: not a readable xz file: ") and len(
        err.message
    ) > len("not a readable xz file: ")


def test_write_three_columns_adds_zero_reflectance(tmp_path):
    """An (N, 3) scan is written as x, y, z, 0 little-endian float32, 16 bytes a point."""
    xyz = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    f = tmp_path / "s.bin"
    write_velodyne_scan(f, xyz)
    expected = np.array([[1, 2, 3, 0], [4, 5, 6, 0]], dtype="<f4").tobytes()
    assert f.read_bytes() == expected


def test_write_float64_is_stored_as_float32(tmp_path):
    """A float64 (N, 4) array is written as float32: 16 bytes a point."""
    pts = np.array([[1.0, 2.0, 3.0, 0.25]])
    f = tmp_path / "s.bin"
    write_velodyne_scan(f, pts)
    assert f.read_bytes() == pts.astype("<f4").tobytes()


@pytest.mark.parametrize("shape", [(4,), (2, 4, 4), (2, 5), (2, 2)])
def test_write_refuses_bad_shapes(tmp_path, shape):
    """Only (N, 4) or (N, 3) are written; the message gives the shape."""
    err = _err(
        lambda: write_velodyne_scan(tmp_path / "s.bin", np.zeros(shape)), ValueError
    )
    assert str(err) == f"scan must be (N, 4) or (N, 3), got {shape}"
    assert not (tmp_path / "s.bin").exists()
