"""LIDAR-only slamlib on the ten real KITTI scans the package ships, beside a direct registration and
KISS-ICP (installed by ``make setup``: the ``peers`` extra)."""

from __future__ import annotations

import lzma

import numpy as np
import pytest

from slamlib.errors import DataFormatError
from slamlib.kitti import read_velodyne_scan
from slamlib.kitti.sample import REAL_SCANS, real_scan_frames, real_scan_path
from slamlib.kitti.scan_stats import icp_align
from slamlib.peers import kiss_icp_poses
from slamlib.slam3d import SLAM3DConfig, run_drive

#: The settings the book's real-scan section uses (more particles and points than the defaults: ten frames only).
REAL_SCAN_SETTINGS = dict(particles=600, scored_points=2000)


@pytest.fixture(scope="module")
def frames():
    return real_scan_frames()


def test_the_ten_real_scans_ship_and_read(frames):
    assert len(frames) == REAL_SCANS
    assert all(100_000 < len(f.scan) < 130_000 for f in frames)
    assert (
        frames[0].dt == 0.0
        and all(f.dt > 0 for f in frames[1:])
        and frames[4].velocity is None
    )
    assert str(real_scan_path(4)).endswith(".bin.xz") and str(real_scan_path(9)).endswith(
        ".bin"
    )
    with pytest.raises(ValueError, match="0..9"):
        real_scan_path(10)


def test_compressed_scans_decompress_to_kitti_bytes_and_bad_ones_name_the_file(
    tmp_path, frames
):
    raw = tmp_path / "scan.bin"
    frames[3].scan.astype("<f4").tofile(raw)
    packed = tmp_path / "scan.bin.xz"
    packed.write_bytes(lzma.compress(raw.read_bytes()))
    np.testing.assert_array_equal(read_velodyne_scan(packed), read_velodyne_scan(raw))
    # same either way
    assert (
        read_velodyne_scan(packed).flags.writeable
        and read_velodyne_scan(raw).flags.writeable
    )
    packed.write_bytes(packed.read_bytes()[:1000])
    with pytest.raises(DataFormatError, match=r"scan\.bin\.xz: not a readable xz file"):
        read_velodyne_scan(packed)
    packed.write_bytes(lzma.compress(b"\0" * 20))
    with pytest.raises(
        DataFormatError, match=r"scan\.bin\.xz: .*20 bytes, not a multiple of 16"
    ):
        read_velodyne_scan(packed)


def test_lidar_only_motion_over_the_real_scans_matches_the_direct_registration(frames):
    """The car crept ~2.2 m forward from scan 0 to scan 9: LIDAR-only slamlib, chaining nine frames, must end within
    10 cm of one direct point-to-plane ICP of scan 9 onto scan 0, and closer to it than KISS-ICP's chain."""
    direct = icp_align(frames[9].scan, frames[0].scan).T[:3, 3]
    assert 2.0 < direct[0] < 2.4, direct
    run = run_drive(frames, SLAM3DConfig.of(**REAL_SCAN_SETTINGS), progress=False)
    assert run.slam.lidar_only
    ours = np.linalg.norm(run.poses[-1][:3, 3] - direct)
    kiss, _ = kiss_icp_poses(frames)
    theirs = np.linalg.norm(kiss[-1][:3, 3] - direct)
    assert ours < 0.10 and ours < theirs, (ours, theirs)
