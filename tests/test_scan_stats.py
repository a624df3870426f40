"""slamlib.kitti.scan_stats: angles, ring recovery, elevation shares, front view, range image, ICP."""

import numpy as np
import pytest

from slamlib.geometry import invert_pose, make_pose, rot_z, transform_points
from slamlib.kitti import read_velodyne_scan
from slamlib.kitti.scan_stats import (
    ELEVATION_BINS_DEG,
    azimuth,
    elevation,
    elevation_fractions,
    front_view,
    icp_align,
    range_image,
    ranges,
    ring_counts,
    ring_index,
)
from slamlib.paths import kitti_sample_dir
from slamlib.synth import Hdl64, hdl64_elevations, ray_directions


@pytest.fixture(scope="module")
def real_scan():
    return read_velodyne_scan(kitti_sample_dir() / "velodyne_sample" / "0000000000.bin")


def _grid_scan(columns=100, r=10.0, occlusion=False):
    """Every ray of an HDL-64E model at range r, beam-major like slamlib.synth writes scans."""
    d = ray_directions(Hdl64(columns=columns, ego_occlusion=occlusion))
    return np.c_[d * r, np.full(len(d), 0.5, np.float32)].astype(np.float32)


def test_angles_and_ranges_of_known_points():
    p = np.array(
        [[1, 0, 0], [0, 2, 0], [0, -1, 0], [-1, 0, 0], [1, 0, 1], [3, 4, -12]],
        dtype=np.float32,
    )
    assert np.allclose(
        azimuth(p), [0, np.pi / 2, 3 * np.pi / 2, np.pi, 0, np.arctan2(4, 3)]
    )
    assert np.all((azimuth(p) >= 0) & (azimuth(p) < 2 * np.pi))
    assert np.allclose(elevation(p), [0, 0, 0, 0, np.pi / 4, -np.arctan2(12, 5)])
    assert np.allclose(ranges(p), [1, 2, 1, 1, np.sqrt(2), 13])
    with pytest.raises(ValueError):
        azimuth(np.zeros((4, 2)))


def test_ring_index_splits_a_beam_major_scan_into_its_rings():
    scan = _grid_scan(columns=100)
    idx = ring_index(scan)
    assert np.array_equal(idx, np.repeat(np.arange(64), 100))
    assert np.array_equal(ring_counts(scan), np.full(64, 100))
    # each recovered ring has a single elevation, the beams' own, top first
    e = np.array([np.degrees(elevation(scan[idx == k])).mean() for k in range(64)])
    assert np.allclose(e, np.degrees(hdl64_elevations()), atol=1e-3)


def test_ring_index_with_gaps_and_a_missing_ring():
    scan = _grid_scan(columns=100)
    idx0 = np.repeat(np.arange(64), 100)
    holes = scan[
        (np.arange(len(scan)) % 7 != 3)
    ]  # returns missing inside rings: still 64 rings
    assert ring_index(holes).max() == 63
    no_ring_5 = scan[idx0 != 5]  # a ring without any return cannot be seen
    assert ring_index(no_ring_5).max() == 62
    assert len(ring_counts(no_ring_5)) == 64 and ring_counts(no_ring_5)[63] == 0
    assert (
        len(ring_counts(scan, n_rings=10)) == 64
    )  # more rings than asked: the result grows


def test_real_scan_has_64_rings_top_first(real_scan):
    idx = ring_index(real_scan)
    counts = ring_counts(real_scan)
    assert idx.max() == 63 and counts.sum() == len(real_scan) and len(counts) == 64
    assert np.all(np.diff(idx) >= 0)
    med = np.array(
        [np.median(np.degrees(elevation(real_scan[idx == k]))) for k in range(64)]
    )
    assert med[0] > 0 > med[31] > med[63] and med[63] < -20
    assert np.corrcoef(np.arange(64), med)[0, 1] < -0.99  # rings ordered top to bottom
    # no point steps back in azimuth inside a ring by more than a hair
    a = np.degrees(azimuth(real_scan))
    same = idx[1:] == idx[:-1]
    assert np.all(np.diff(a)[same] > -0.05)


def test_elevation_fractions():
    e = np.radians(
        [-25.0, -22.0, -17.0, -12.0, -7.0, -2.0, 1.0, 1.5, 30.0]
    )  # 30 deg: outside the bins
    p = np.c_[np.cos(e), np.zeros_like(e), np.sin(e)]
    f = elevation_fractions(p)
    assert np.allclose(f, np.array([2, 1, 1, 1, 1, 2]) / 8) and np.isclose(f.sum(), 1.0)
    assert np.allclose(elevation_fractions(p, edges_deg=(-30, 0, 40)), [6 / 9, 3 / 9])
    assert np.all(np.isnan(elevation_fractions(p[-1:])))
    assert len(ELEVATION_BINS_DEG) == 7


def test_elevation_fractions_of_real_scans_match_a_direct_histogram(real_scan):
    e = np.degrees(np.arctan2(real_scan[:, 2], np.linalg.norm(real_scan[:, :2], axis=1)))
    h = np.histogram(e, bins=ELEVATION_BINS_DEG)[0]
    assert np.allclose(elevation_fractions(real_scan), h / h.sum())


def test_front_view_keeps_the_front_sorted_far_to_near():
    p = np.array(
        [[10, 0, 0], [1, 1, 0], [1, -1, 0], [-5, 0, 0], [0, 5, 1], [50, 0, 5]],
        dtype=np.float32,
    )
    az, el, r = front_view(p, (-60, 60))
    assert np.allclose(r, [np.hypot(50, 5), 10, np.sqrt(2), np.sqrt(2)])
    assert np.allclose(sorted(az), [-45, 0, 0, 45])
    assert np.isclose(el[0], np.degrees(np.arctan2(5, 50)))
    az, el, r = front_view(p, (-180, 180), max_range=20)
    assert len(r) == 5 and np.all(np.diff(r) <= 0)


def test_range_image_layout():
    # ring 0: one point behind (az ~180 deg); ring 1 (the azimuth drops): ahead at 10 m and 9 m, then left at 5.1 m
    p = np.array([[-7, 0.01, 0], [10, 0, 0], [9, 0.001, 0], [0, 5, -1]], dtype=np.float32)
    assert np.array_equal(ring_index(p), [0, 1, 1, 1])
    img = range_image(p, (-90, 90), columns=360, n_rings=3)
    assert img.shape == (3, 180)
    assert np.isclose(
        img[1, 90], 9.0
    )  # straight ahead: the middle column, the nearest point
    assert np.isclose(img[1, 0], np.sqrt(26))  # +90 deg (left) is column 0
    assert (
        np.isfinite(img).sum() == 2
    )  # behind (ring 0) is outside the limits; ring 2 empty
    with pytest.raises(ValueError):
        range_image(p, (10, -10))


def test_range_image_of_a_grid_scan_fills_every_pixel():
    scan = _grid_scan(columns=400, r=12.0)
    img = range_image(scan, columns=400)
    assert img.shape == (64, 400) and np.isfinite(img).all() and np.allclose(img, 12.0)


@pytest.fixture(scope="module")
def moved(real_scan):
    T_true = make_pose(
        rot_z(np.radians(2.0)), [0.6, -0.2, 0.05]
    )  # the scan seen from a sensor moved by T_true
    source = transform_points(invert_pose(T_true), real_scan[::2, :3])
    return T_true, source


def test_icp_recovers_a_known_motion(real_scan, moved):
    T_true, source = moved
    res = icp_align(source, real_scan[::2])  # T_target_source = T_true
    assert np.abs(res.T[:3, 3] - T_true[:3, 3]).max() < 0.02
    assert np.abs(res.T[:3, :3] - T_true[:3, :3]).max() < 1e-3
    assert (
        res.fitness > 0.8
        and res.fitness > res.fitness_init
        and res.inlier_rmse < res.max_distance
    )
    assert res.max_distance == 0.25 and res.n_source > 1000 and res.n_target > 1000


def test_icp_starting_at_the_answer_stays_there(real_scan, moved):
    T_true, source = moved
    res = icp_align(source, real_scan[::2], init=T_true, max_distances=(0.25,))
    assert np.abs(res.T[:3, 3] - T_true[:3, 3]).max() < 0.02
    assert res.fitness_init > 0.8


def test_icp_needs_points():
    with pytest.raises(ValueError):
        icp_align(np.zeros((2, 3)), np.zeros((2, 3)))
