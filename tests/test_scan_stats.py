"""slamlib.kitti.scan_stats: angles, ring recovery, elevation shares, front view, range image, ICP."""

import warnings

import numpy as np
import pytest

from slamlib.geometry import invert_pose, make_pose, rot_z, transform_points
from slamlib.kitti import read_velodyne_scan
from slamlib.kitti import scan_stats as ss
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
    # more rings than asked: the result grows
    assert len(ring_counts(scan, n_rings=10)) == 64


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
    # 30 deg: outside the bins
    e = np.radians([-25.0, -22.0, -17.0, -12.0, -7.0, -2.0, 1.0, 1.5, 30.0])
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
    # straight ahead: the middle column, the nearest point
    assert np.isclose(img[1, 90], 9.0)
    assert np.isclose(img[1, 0], np.sqrt(26))  # +90 deg (left) is column 0
    # behind (ring 0) is outside the limits; ring 2 empty
    assert np.isfinite(img).sum() == 2
    with pytest.raises(ValueError):
        range_image(p, (10, -10))


def test_range_image_of_a_grid_scan_fills_every_pixel():
    scan = _grid_scan(columns=400, r=12.0)
    img = range_image(scan, columns=400)
    assert img.shape == (64, 400) and np.isfinite(img).all() and np.allclose(img, 12.0)


@pytest.fixture(scope="module")
def moved(real_scan):
    # the scan seen from a sensor moved by T_true
    T_true = make_pose(rot_z(np.radians(2.0)), [0.6, -0.2, 0.05])
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


# ------------------------------------------------------------------ messages, limits and ties, value by value
def test_xyz_shape_message():
    """The full message for points of the wrong shape."""
    with pytest.raises(ValueError) as info:
        ss.azimuth(np.zeros((3, 2)))
    assert str(info.value) == "points must be (N, 3) or (N, 4), got shape (3, 2)"


def test_ring_index_two_points_and_exact_drop():
    """Two points: a drop of more than min_drop starts ring 1; a drop of exactly min_drop does not."""
    assert ss.ring_index([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]).tolist() == [
        0,
        0,
    ]  # drop pi/2 == min_drop
    assert ss.ring_index([[-1.0, 1.0, 0.0], [1.0, 0.0, 0.0]]).tolist() == [
        0,
        1,
    ]  # drop 3 pi / 4


def test_ring_counts_uses_min_drop_and_int64():
    """ring_counts passes min_drop on (a 45-degree drop splits only with min_drop < pi/4) and returns int64."""
    pts = [[1.0, 1.0, 0.0], [1.0, 0.0, 0.0]]
    c = ss.ring_counts(pts, n_rings=2, min_drop=0.5)
    assert c.dtype == np.int64 and c.tolist() == [1, 1]
    assert ss.ring_counts(pts, n_rings=2).tolist() == [2, 0]


def test_elevation_fractions_no_point_inside_is_silent_nan():
    """No point inside the edges: all-NaN fractions, without a division-by-zero warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        f = ss.elevation_fractions([[1.0, 0.0, 10.0]])
    assert len(f) == len(ss.ELEVATION_BINS_DEG) - 1 and np.isnan(f).all()


def test_front_view_limits_inclusive_and_short_range():
    """A point at exactly the lower azimuth limit and one at exactly max_range are kept; elevation of a point
    nearer than 1 m is asin(z / r) (0.3, 0, 0.4): r = 0.5, el = asin(0.8))."""
    az, el, r = ss.front_view(
        [[3.0, 4.0, 0.0], [0.3, 0.0, 0.4], [1.0, -1.0, 0.0]],
        az_limits_deg=(0.0, 90.0),
        max_range=5.0,
    )
    assert r.tolist() == [5.0, 0.5]
    assert az[1] == 0.0
    assert el[1] == pytest.approx(np.degrees(np.arcsin(0.8)), abs=1e-12)


def test_front_view_ties_keep_input_order():
    """Points at equal range keep their input order (stable far-to-near sort)."""
    dirs = np.array(
        [
            [5, 0, 0],
            [4, 3, 0],
            [4, -3, 0],
            [3, 4, 0],
            [3, -4, 0],
            [4, 0, 3],
            [4, 0, -3],
            [3, 0, 4],
        ]
    )
    rng = np.random.default_rng(0)
    k = rng.integers(1, 4, 200)
    # ranges exactly 5 k
    pts = (dirs[rng.integers(0, len(dirs), 200)] * k[:, None]).astype(float)
    order = sorted(range(200), key=lambda i: -k[i])  # Python's sort is stable
    az, el, r = ss.front_view(pts)
    assert r.tolist() == [5.0 * k[i] for i in order]
    np.testing.assert_allclose(
        az, np.degrees(np.arctan2(pts[order, 1], pts[order, 0])), atol=1e-12
    )
    np.testing.assert_allclose(el, np.degrees(np.arcsin(pts[order, 2] / r)), atol=1e-12)


def test_range_image_shapes_and_errors():
    """Default width 2000 columns; one column allowed; a width rounding to 0 gives 1; bad limits raise."""
    one = [[1.0, 0.0, 0.0]]
    assert ss.range_image(one).shape == (64, 2000)
    assert ss.range_image(one, columns=1, n_rings=1).tolist() == [[1.0]]
    assert ss.range_image(one, az_limits_deg=(0.0, 0.01), n_rings=1).tolist() == [[1.0]]
    for kw in ({"az_limits_deg": (10.0, 10.0)}, {"columns": 0}):
        with pytest.raises(ValueError) as info:
            ss.range_image(one, **kw)
        assert (
            str(info.value) == "need az_limits_deg[0] < az_limits_deg[1] and columns >= 1"
        )


def test_range_image_drops_out_of_grid_points():
    """Rings beyond n_rings and a point one column past the right edge are dropped; min_drop is passed on.

    Limits (-90, 90) with columns=4: step 90 deg, width 2 (az 90 -> column 0, az 0 -> column 1, az -90 -> 2)."""
    pts = [
        [0.0, 2.0, 0.0],
        [3.0, 0.0, 0.0],
        [0.0, -4.0, 0.0],
    ]  # az 90, 0, -90: no drop, one ring
    img = ss.range_image(pts, az_limits_deg=(-90.0, 90.0), columns=4, n_rings=2)
    np.testing.assert_array_equal(img, [[2.0, 3.0], [np.nan, np.nan]])
    two_rings = [
        [5.0, -0.1, 0.0],
        [3.0, 0.1, 0.0],
    ]  # az ~358.9 then ~1.9 deg: the wrap starts ring 1
    img = ss.range_image(two_rings, az_limits_deg=(-90.0, 90.0), columns=4, n_rings=1)
    np.testing.assert_array_equal(img, [[np.nan, np.hypot(5.0, 0.1)]])
    spread = [
        [0.0, 2.0, 0.0],
        [1.0, 1.0, 0.0],
    ]  # az 90 then 45: drop pi/4 splits only with min_drop < pi/4
    img = ss.range_image(
        spread, az_limits_deg=(-90.0, 90.0), columns=8, n_rings=2, min_drop=0.5
    )
    np.testing.assert_allclose(
        img, [[2.0, np.nan, np.nan, np.nan], [np.nan, np.sqrt(2.0), np.nan, np.nan]]
    )


# ------------------------------------------------------------------ icp_align
def _plane_grid(n=20, spacing=1.0):
    g = np.arange(n) * spacing
    x, y = np.meshgrid(g + 5.0, g - n * spacing / 2)
    floor = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, -1.5)])
    wall = np.column_stack([np.full(x.size, 25.0), y.ravel(), x.ravel() - 10.0])
    side = np.column_stack([x.ravel(), np.full(x.size, 12.0), y.ravel() + 10.0])
    return np.vstack([floor, wall, side])


def test_icp_crop_bounds_inclusive():
    """Points at exactly min_range (3 m) and max_range (80 m) are kept; nearer / farther ones (2.9, 80.5 m) not."""
    src = np.array(
        [
            [3.0, 0, 0],
            [0, 3.0, 0],
            [0, 0, 3.0],
            [80.0, 0, 0],
            [0, 80.0, 0],
            [2.9, 0, 0],
            [80.5, 0, 0],
            [0, 0, 1.0],
        ]
    )
    res = ss.icp_align(src, _plane_grid())
    assert res.n_source == 5


def test_icp_three_points_enough_and_message():
    """Three points left in each scan are enough; fewer in either raises with the full message."""
    three = np.array([[10.0, 0, 0], [0, 10.0, 0], [0, 0, 10.0]])
    res = ss.icp_align(three, _plane_grid())
    assert res.n_source == 3
    res = ss.icp_align(_plane_grid(), three)
    assert res.n_target == 3
    for src, tgt in ((three[:2], _plane_grid()), (_plane_grid(), three[:2])):
        with pytest.raises(ValueError) as info:
            ss.icp_align(src, tgt)
        assert (
            str(info.value)
            == "icp_align: fewer than 3 points left in a scan after cropping and down-sampling"
        )


def test_icp_initial_rmse_reported():
    """``inlier_rmse_init`` is the RMS pair distance at the initial guess: 0.1 m when it is off by 0.1 m along x
    (each source point lands 0.1 m from its own copy in the target, grid spacing 0.25 m)."""
    pts = _plane_grid(40, 0.25)
    init = np.eye(4)
    init[0, 3] = 0.1
    res = ss.icp_align(pts, pts, init=init)
    assert isinstance(res.inlier_rmse_init, float)
    assert res.inlier_rmse_init == pytest.approx(0.1, abs=0.02)


def test_icp_settings_reach_open3d(monkeypatch):
    """The documented settings reach open3d: every ICP round stops after ``max_iteration`` iterations (default 60,
    not open3d's 30), and the normals come from at most 30 neighbours within ``3 voxel_size``."""
    import open3d as o3d

    reg, geo = o3d.pipelines.registration, o3d.geometry
    rounds, searches = [], []
    real_icp, real_search = reg.registration_icp, geo.KDTreeSearchParamHybrid

    def icp(src, tgt, d, T, est, criteria=None):
        rounds.append(None if criteria is None else criteria.max_iteration)
        return (
            real_icp(src, tgt, d, T, est)
            if criteria is None
            else real_icp(src, tgt, d, T, est, criteria)
        )

    def search(radius, max_nn):
        searches.append((radius, max_nn))
        return real_search(radius=radius, max_nn=max_nn)

    monkeypatch.setattr(reg, "registration_icp", icp)
    monkeypatch.setattr(geo, "KDTreeSearchParamHybrid", search)
    pts = _plane_grid(12, 0.5)
    ss.icp_align(pts, pts, voxel_size=0.3)
    assert rounds == [60, 60, 60] and searches == [(pytest.approx(0.9), 30)] * 2
    rounds.clear()
    ss.icp_align(pts, pts, voxel_size=0.3, max_iteration=7, max_distances=(0.5, 0.2))
    assert rounds == [7, 7]
