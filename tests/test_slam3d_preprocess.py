"""Step 2's point preparation (:mod:`slamlib.slam3d.preprocess`): the range crop, voxel down-sampling (the fused
Numba pass against the two numpy functions) and the scoring sample."""

import numpy as np

from slamlib.slam3d import crop_range, sample_points, voxel_downsample


# ------------------------------------------------------------------------------------------ preprocessing
def test_crop_range_keeps_the_annulus():
    pts = np.array([[1, 0, 0], [0, 3, 0], [0, 0, 10], [20, 0, 0]], np.float32)
    assert np.array_equal(crop_range(pts, 2.0, 15.0), pts[1:3])


def test_voxel_downsample_one_exact_point_per_voxel():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-3, 3, (5000, 3)).astype(np.float32)
    out = voxel_downsample(pts, 1.0)
    keys = np.floor(out / 1.0).astype(int)
    assert (
        len(np.unique(keys, axis=0))
        == len(out)
        == len(np.unique(np.floor(pts).astype(int), axis=0))
    )
    # kept points are input points (the first of each voxel, in input order)
    first = {}
    for i, k in enumerate(map(tuple, np.floor(pts).astype(int))):
        first.setdefault(k, i)
    assert np.array_equal(out, pts[sorted(first.values())])


def test_sample_points_is_seeded_and_distinct():
    pts = np.arange(3000, dtype=np.float32).reshape(1000, 3)
    a = sample_points(pts, 100, np.random.default_rng(5))
    b = sample_points(pts, 100, np.random.default_rng(5))
    c = sample_points(pts, 100, np.random.default_rng(6))
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert len(np.unique(a[:, 0])) == 100
    assert len(sample_points(pts, 5000, np.random.default_rng(0))) == 1000


def test_crop_and_downsample_equals_crop_then_downsample():
    """The fused Numba pass of step 2 against the two numpy reference functions: same points, same order."""
    from slamlib.kitti.sample import real_scan_frames
    from slamlib.slam3d.preprocess import (
        crop_and_downsample,
        crop_range,
        voxel_downsample,
    )

    real = real_scan_frames(range(1))[0].scan
    cases = [
        (real[:, :3], 3.0, 60.0, 0.25),
        (real, 0.0, np.inf, 0.5),
        (real[:, :3], 3.0, 60.0, 0.0),
    ]
    rng = np.random.default_rng(7)
    for _ in range(30):
        scale = rng.choice([0.01, 1.0, 30.0, 1e3])
        pts = (rng.standard_normal((int(rng.integers(0, 2000)), 3)) * scale).astype(
            np.float32
        )
        cases.append(
            (
                pts,
                float(rng.uniform(0, 1)),
                float(rng.uniform(1, 50)),
                float(rng.choice([0, 0.05, 0.3])),
            )
        )
    # far out
    cases.append(
        (
            np.array([[1e7, 0, 0], [1, 1, 1], [1.01, 1.01, 1.01]], np.float32),
            0.0,
            np.inf,
            0.25,
        )
    )
    for pts, lo, hi, h in cases:
        np.testing.assert_array_equal(
            crop_and_downsample(pts, lo, hi, h),
            voxel_downsample(crop_range(pts, lo, hi), h),
        )


def test_a_scan_and_the_matchers_points_load_one_crop_kernel():
    """Step 2 crops a scan's (N, 4) rows and the matcher thins step 2's (M, 3) points: both reach the kernel as the
    same array type (float32, C order), so a LIDAR-only run loads one compiled kernel, not two."""
    from slamlib.slam3d.preprocess import _crop_keys_nb, crop_and_downsample
    from slamlib.slam3d.steps import read_scan

    rng = np.random.default_rng(3)
    scan = np.hstack(
        [rng.uniform(-30, 30, (5000, 3)), rng.uniform(0, 1, (5000, 1))]
    ).astype(np.float32)
    points = read_scan(scan)
    assert points.shape[1] == 3 and points.flags.c_contiguous
    before = set(_crop_keys_nb.signatures)
    thinned = crop_and_downsample(points, voxel_size=0.5)
    assert set(_crop_keys_nb.signatures) == before
    np.testing.assert_array_equal(thinned, voxel_downsample(points, 0.5))


def test_crop_and_downsample_grows_its_hash_set_when_most_points_are_distinct(
    monkeypatch,
):
    """The hash set starts sized for a quarter of the points to be distinct; where nearly all are (a voxel far
    smaller than their spacing) it fills, grows fourfold until they fit, and the result is still the reference's."""
    import slamlib.slam3d.preprocess as pre

    rng = np.random.default_rng(5)
    pts = rng.uniform(-10, 10, (5000, 3)).astype(np.float32)
    sizes = []
    inner = pre._first_of_each_key_nb
    monkeypatch.setattr(
        pre,
        "_first_of_each_key_nb",
        lambda key_of, log2, dedupe: sizes.append(log2) or inner(key_of, log2, dedupe),
    )
    got = pre.crop_and_downsample(pts, 0.0, np.inf, 1e-3)
    np.testing.assert_array_equal(got, pre.voxel_downsample(pts, 1e-3))
    assert len(got) == len(pts)
    # 2**12 slots hold 2048 keys at half load, too few for 5000; 2**14 hold 8192
    assert sizes == [12, 14]
    sizes.clear()
    pre.crop_and_downsample(
        pts, 0.0, np.inf, 2.0
    )  # 1000 voxels of 2 m: the first size holds them
    assert sizes == [12]


def test_crop_and_downsample_keeps_the_first_columns_when_asked():
    """``columns=3``: the same rows as without, x, y, z only; on the kernel's path, the reference path (a voxel
    index beyond the packed range) and an empty input alike."""
    from slamlib.slam3d.preprocess import crop_and_downsample

    rng = np.random.default_rng(4)
    scan = rng.uniform(-40, 40, (3000, 4)).astype(np.float32)
    far = scan.copy()
    far[7, :3] = 1e7  # 1e7 voxels of 1 m: beyond the 2**20 of a packed key
    for points, voxel in ((scan, 0.5), (far, 1.0), (scan[:0], 0.5)):
        whole = crop_and_downsample(points, 2.0, 1e8, voxel)
        xyz = crop_and_downsample(points, 2.0, 1e8, voxel, columns=3)
        assert xyz.shape == (len(whole), 3)
        np.testing.assert_array_equal(xyz, whole[:, :3])
    assert len(crop_and_downsample(far, 2.0, 1e8, 1.0)) > 0


def _road_and_walls(rng, n_road=300, n_above=100):
    road = np.c_[rng.uniform(-20, 20, (n_road, 2)), np.full(n_road, -1.7)]
    above = np.c_[rng.uniform(-20, 20, (n_above, 2)), rng.uniform(0.0, 3.0, n_above)]
    return np.r_[road, above].astype(np.float32), n_road


def test_sample_thinned_draws_as_thinning_then_sampling_does():
    """``sample_thinned`` is ``sample_points(thin_ground(...))`` in distribution: over many draws each point above
    the road is chosen with probability n / (A + k), each road point with n / (A + k) * k / G, for both; every
    draw is n distinct points of the scan."""
    from slamlib.slam3d.preprocess import sample_thinned, thin_ground

    rng = np.random.default_rng(8)
    pts, n_road = _road_and_walls(rng)
    share, n, draws = 0.2, 60, 4000
    n_above = len(pts) - n_road
    k = int(share / (1 - share) * n_above)
    want = np.r_[
        np.full(n_road, n / (n_above + k) * k / n_road),
        np.full(n_above, n / (n_above + k)),
    ]
    index = {tuple(p): i for i, p in enumerate(pts)}
    for draw in (
        lambda r: sample_thinned(pts, share, n, r),
        lambda r: sample_points(thin_ground(pts, share, r), n, r),
    ):
        counts = np.zeros(len(pts))
        r = np.random.default_rng(9)
        for _ in range(draws):
            chosen = [index[tuple(p)] for p in draw(r)]
            assert len(chosen) == n == len(set(chosen))
            counts[chosen] += 1
        freq = counts / draws
        # group means against the exact inclusion probabilities (binomial standard errors, 4 sigma)
        for group in (slice(0, n_road), slice(n_road, None)):
            p, m = want[group][0], len(freq[group])
            assert abs(freq[group].mean() - p) < 4 * np.sqrt(p * (1 - p) / (draws * m))
        assert np.corrcoef(freq, want)[0, 1] > 0.9


def test_sample_thinned_edge_cases_are_thin_ground_and_sample_points():
    """The whole pool when ``n`` reaches it, the plain sample for ``share >= 1`` or too few points above the road:
    the very arrays ``thin_ground`` / ``sample_points`` give from the same generator state."""
    from slamlib.slam3d.preprocess import sample_thinned, thin_ground

    rng = np.random.default_rng(10)
    pts, n_road = _road_and_walls(rng)
    few_above = pts[: n_road + 5]
    for args, reference in (
        ((pts, 0.2, 10_000), lambda r: thin_ground(pts, 0.2, r)),
        ((pts, 1.0, 50), lambda r: sample_points(pts, 50, r)),
        ((few_above, 0.2, 50), lambda r: sample_points(few_above, 50, r)),
        ((pts[:0], 0.2, 50), lambda r: pts[:0]),
    ):
        got = sample_thinned(*args, np.random.default_rng(11))
        np.testing.assert_array_equal(got, reference(np.random.default_rng(11)))
