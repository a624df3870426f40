"""Tests of slamlib.maps: hash/Morton codes, VoxelHashMap and MortonBVHMap invariants, and score precision."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numba import njit

from slamlib.geometry import rpy_to_matrix
from slamlib.kernels import get_backend
from slamlib.maps import MortonBVHMap, VoxelHashMap, make_map
from slamlib.maps.base import EMPTY_KEY, HASH_MULTIPLIER
from slamlib.maps.codes import (
    axis_indices,
    find_cell_nb,
    find_slot_nb,
    hash_slot_nb,
    hash_slots,
    make_code_functions,
    morton_codes,
    morton_nb,
    pack_key_nb,
    pack_keys,
)
from slamlib.synth.street import street_scan, street_scene


@njit(cache=True)
def _codes_nb(u, log2c):
    m = np.empty(u.shape[0], np.int64)
    h = np.empty(u.shape[0], np.int64)
    for i in range(u.shape[0]):
        m[i] = morton_nb(u[i, 0], u[i, 1], u[i, 2])
        h[i] = hash_slot_nb(pack_key_nb(u[i, 0], u[i, 1], u[i, 2]), log2c)
    return m, h


def _bit_interleave(ux, uy, uz):
    """Morton code by the definition, one bit at a time (independent of the magic-number version)."""
    code = 0
    for b in range(21):
        code |= (
            ((ux >> b) & 1) << (3 * b)
            | ((uy >> b) & 1) << (3 * b + 1)
            | ((uz >> b) & 1) << (3 * b + 2)
        )
    return code


coord = st.integers(0, 2**21 - 1)


@settings(max_examples=50, deadline=None)
@given(
    st.lists(st.tuples(coord, coord, coord), min_size=1, max_size=20), st.integers(4, 30)
)
def test_codes_numpy_numba_and_definition_agree(triples, log2c):
    u = np.array(triples, dtype=np.int64)
    m_nb, h_nb = _codes_nb(u, log2c)
    m_np = morton_codes(u)
    np.testing.assert_array_equal(m_nb, m_np)
    np.testing.assert_array_equal(h_nb, hash_slots(pack_keys(u), log2c))
    for (x, y, z), code in zip(triples, m_np):
        assert code == _bit_interleave(x, y, z)
        key = x | y << 21 | z << 42
        assert hash_slots(np.array([key]), log2c)[0] == (
            (key * HASH_MULTIPLIER) % 2**64
        ) >> (64 - log2c)
    assert np.all(m_np >= 0)


@settings(max_examples=30, deadline=None)
@given(
    st.lists(st.tuples(coord, coord, coord), min_size=1, max_size=10), st.integers(0, 20)
)
def test_morton_prefix_is_the_parent_cell_code(triples, level):
    u = np.array(triples, dtype=np.int64)
    np.testing.assert_array_equal(
        morton_codes(u) >> (3 * level), morton_codes(u >> level)
    )


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.tuples(coord, coord, coord), min_size=1, max_size=10), st.integers(1, 63)
)
def test_codes_scalar_builds_agree_without_overflow(triples, log2c):
    """The plain build on numpy scalars (how the CUDA simulator runs the device build) equals the njit and the
    array builds, and never overflows (the hash product is formed from 32-bit halves)."""
    import warnings

    py = make_code_functions()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for x, y, z in triples:
            ux, uy, uz = np.int64(x), np.int64(y), np.int64(z)
            key = py["pack_key"](ux, uy, uz)
            assert key == pack_key_nb(x, y, z) == pack_keys(np.array([[x, y, z]]))[0]
            h = py["hash_slot"](key, np.int64(log2c))
            assert h == hash_slot_nb(key, log2c) == hash_slots(np.array([key]), log2c)[0]
            assert h == ((int(key) * HASH_MULTIPLIER) % 2**64) >> (64 - log2c)
            assert (
                py["morton"](ux, uy, uz) == morton_nb(x, y, z) == _bit_interleave(x, y, z)
            )


def test_find_slot_and_find_cell_builds_agree_with_the_tables():
    rng = np.random.default_rng(3)
    py = make_code_functions()
    m = VoxelHashMap(voxel_size=0.5, capacity=2**10)
    m.merge(_random_points(rng, 3000, scale=3.0))
    lk = m.lookup()
    occupied = np.flatnonzero(lk.keys != EMPTY_KEY)
    for s in occupied[:200]:
        key = lk.keys[s]
        assert (
            py["find_slot"](
                lk.keys, key, np.int64(lk.log2_capacity), np.int64(lk.max_probe)
            )
            == s
        )
        assert find_slot_nb(lk.keys, key, lk.log2_capacity, lk.max_probe) == s
    stored = set(lk.keys[occupied].tolist())
    missing = [k for k in rng.integers(0, 2**62, 50) if int(k) not in stored]
    for key in missing:
        assert (
            py["find_slot"](
                lk.keys, np.int64(key), np.int64(lk.log2_capacity), np.int64(lk.max_probe)
            )
            == -1
        )
        assert find_slot_nb(lk.keys, key, lk.log2_capacity, lk.max_probe) == -1
    mm = MortonBVHMap(radius=0.3)
    mm.merge(_random_points(rng, 2000, scale=2.0))
    cells = mm.lookup().cell_codes
    for k in range(0, cells.size, 7):
        assert py["find_cell"](cells, cells[k]) == find_cell_nb(cells, cells[k]) == k
    for code in (cells[0] - 1, cells[-1] + 1, np.int64(0)):
        assert (
            py["find_cell"](cells, code)
            == find_cell_nb(cells, code)
            == (0 if code == cells[0] else -1)
        )


def _random_points(rng, n, scale=6.0):
    return (rng.normal(0.0, scale, (n, 3)) + [100.0, -40.0, 2.0]).astype(np.float32)


def _find(keys, key, log2c, max_probe):
    """The documented lookup, in plain Python."""
    s = ((key * HASH_MULTIPLIER) % 2**64) >> (64 - log2c)
    for _ in range(max_probe + 1):
        if keys[s] == key:
            return s
        if keys[s] == EMPTY_KEY:
            return -1
        s = (s + 1) % (1 << log2c)
    return -1


def test_voxel_hash_statistics_match_numpy_groupby():
    rng = np.random.default_rng(0)
    pts = _random_points(rng, 5000)
    m = VoxelHashMap(voxel_size=0.7, capacity=2**14, min_sigma=0.05)
    for chunk in np.array_split(pts, 3):  # merging in pieces must equal merging at once
        m.merge(chunk)
    u, ok = axis_indices(pts, 1.0 / 0.7)
    assert ok.all()
    keys = pack_keys(u)
    uniq, inv = np.unique(keys, return_inverse=True)
    assert len(m) == len(uniq)
    lk = m.lookup()
    for v in rng.choice(len(uniq), size=40, replace=False):
        s = _find(lk.keys, int(uniq[v]), lk.log2_capacity, lk.max_probe)
        assert s >= 0
        p = pts[inv == v].astype(np.float64)
        np.testing.assert_allclose(lk.mean[s], p.mean(axis=0), atol=2e-5)
        cov = np.cov(p.T, bias=True).reshape(3, 3) + 0.05**2 * np.eye(3)
        a = np.linalg.inv(cov)
        got = lk.icov[s]
        np.testing.assert_allclose(
            got, a[[0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]], rtol=2e-3, atol=1e-2
        )
    # every stored key is reachable from its home slot within max_probe
    occupied = np.flatnonzero(lk.keys != EMPTY_KEY)
    assert len(occupied) == len(uniq)
    for s in occupied[:500]:
        assert _find(lk.keys, int(lk.keys[s]), lk.log2_capacity, lk.max_probe) == s
    np.testing.assert_array_equal(np.sort(m.counts()), np.sort(np.bincount(inv)))
    assert m.points().shape == (len(uniq), 3)


def test_voxel_hash_refuses_new_voxels_beyond_load_factor():
    m = VoxelHashMap(voxel_size=1.0, capacity=64, max_load=0.5)
    pts = (
        np.stack(
            np.meshgrid(np.arange(10), np.arange(10), [0.5], indexing="ij"), -1
        ).reshape(-1, 3)
        + 0.5
    )
    m.merge(pts.astype(np.float32))
    assert len(m) == 32
    assert m.n_dropped == 100 - 32
    m.merge(pts[:1].astype(np.float32))  # a point in an existing voxel is still merged
    assert m.n_dropped == 68
    assert m.counts().sum() == 33


def test_voxel_hash_prune_keeps_near_voxels_reachable():
    rng = np.random.default_rng(1)
    pts = (rng.uniform(-20, 20, (4000, 3))).astype(np.float32)
    m = VoxelHashMap(voxel_size=1.0, capacity=2**16)
    m.merge(pts)
    before = len(m)
    score_pts = np.array([[1.0, 2.0, 3.0], [-2.0, 0.5, 1.0]], np.float32)
    cpu = get_backend("cpu")
    I, z = np.eye(3)[None], np.zeros((1, 3))
    s_before = cpu.score_particles(I, z, score_pts, m.lookup())
    dropped = m.prune([0.0, 0.0, 0.0], 10.0)
    assert dropped > 0 and len(m) == before - dropped
    assert np.all(np.linalg.norm(m.points(), axis=1) <= 10.0)
    lk = m.lookup()
    for s in np.flatnonzero(lk.keys != EMPTY_KEY):
        assert _find(lk.keys, int(lk.keys[s]), lk.log2_capacity, lk.max_probe) == s
    # points well inside the kept ball score the same before and after
    np.testing.assert_allclose(
        cpu.score_particles(I, z, score_pts, lk), s_before, rtol=1e-6
    )


def _wall_and_mover(frames: int, speed: float = 0.6):
    """A static wall hit every frame, and a one-point mover ``speed`` m along y per frame (a trail of voxels)."""
    wall = np.stack(
        np.meshgrid([5.2], np.arange(0, 2, 0.1), np.arange(0, 1, 0.1), indexing="ij"), -1
    )
    wall = wall.reshape(-1, 3).astype(np.float32)
    return [
        np.concatenate([wall, np.float32([[1.0, -10.0 + speed * k, 0.5]])])
        for k in range(frames)
    ]


def test_voxel_hash_remembers_when_each_voxel_was_hit():
    m = VoxelHashMap(voxel_size=1.0, capacity=1024)
    for pts in _wall_and_mover(5):
        m.merge(pts)
    first, last = m.seen()
    wall = m.points()[:, 0] > 5.0
    assert m.frames == 5 and np.all(first[wall] == 0) and np.all(last[wall] == 4)
    # the mover opens a voxel every frame or two (0.6 m per frame, 1 m voxels); each is hit only in its span
    assert sorted(first[~wall]) == [0, 2, 4] and np.all(last[~wall] - first[~wall] <= 1)


def test_voxel_hash_evicts_the_trail_of_a_mover_and_keeps_static_surfaces():
    m = VoxelHashMap(voxel_size=0.5, capacity=1024)
    for pts in _wall_and_mover(30):
        m.merge(pts)
    first, last = m.seen()
    transient = m.transients(10)
    # by the rule: hit within < 10 frames, the last hit >= 10 frames before the last merge (frame 29)
    assert np.array_equal(transient, (last - first < 10) & (29 - last >= 10))
    wall_before = np.sort(m.points()[m.points()[:, 0] > 5.0], axis=0)
    trail = int(transient.sum())
    assert (
        trail == 20
    )  # frames 0..19 of the mover: 0.6 m apart, one 0.5 m voxel each; 20..29 are too recent
    # only near a centre: the trail's first five voxels (0.6 m apart) lie within 2.9 m of its start
    near = m.transients(10, center=[1.0, -10.0, 0.5], radius=2.9)
    assert near.sum() == 5 and np.all(near <= transient)
    assert m.evict_transients(10) == trail and len(m) == len(transient) - trail
    assert np.array_equal(
        np.sort(m.points()[m.points()[:, 0] > 5.0], axis=0), wall_before
    )
    assert not m.transients(10).any() and m.evict_transients(10) == 0
    lk = m.lookup()  # the rebuilt table still finds every kept key
    for s in np.flatnonzero(lk.keys != EMPTY_KEY):
        assert _find(lk.keys, int(lk.keys[s]), lk.log2_capacity, lk.max_probe) == s
    # a surface hit for a long span is kept however old its last hit, and the clock survives a prune
    m.prune([5.0, 0.0, 0.0], 3.0)
    assert m.frames == 30 and np.all(m.seen()[0] == 0)
    with pytest.raises(ValueError, match="span must be >= 1"):
        m.transients(0)


def test_morton_map_layout_and_dedup():
    rng = np.random.default_rng(2)
    pts = _random_points(rng, 6000, scale=2.0)
    pts = np.vstack([pts, pts[:500] + 1e-3])  # near-duplicates must be dropped
    m = MortonBVHMap(radius=0.3, quantum=0.01, dedup_level=3)
    m.merge(pts)
    lk = m.lookup()
    assert np.all(np.diff(lk.codes) >= 0)
    u, ok = axis_indices(lk.points, 1.0 / 0.01)
    np.testing.assert_array_equal(morton_codes(u), lk.codes)
    dedup = lk.codes >> 9
    assert np.all(np.diff(dedup) > 0)  # one point per 8 cm voxel
    u_all, _ = axis_indices(pts, 100.0)
    assert set(np.unique(morton_codes(u_all) >> 9)) == set(
        dedup
    )  # every occupied voxel represented
    cells = lk.codes >> (3 * lk.cell_level)
    np.testing.assert_array_equal(np.unique(cells), lk.cell_codes)
    for k in range(len(lk.cell_codes)):
        assert np.all(cells[lk.cell_start[k] : lk.cell_start[k + 1]] == lk.cell_codes[k])
    assert lk.cell_start[-1] == len(m)
    for k in rng.choice(len(lk.cell_codes), size=50, replace=False):
        run = lk.points[lk.cell_start[k] : lk.cell_start[k + 1]]
        np.testing.assert_array_equal(lk.cell_lo[k], run.min(axis=0))
        np.testing.assert_array_equal(lk.cell_hi[k], run.max(axis=0))
    assert 0.01 * 2**lk.cell_level >= 2 * 0.3 > 0.01 * 2 ** (lk.cell_level - 1)


def test_morton_merge_in_pieces_equals_merge_at_once():
    rng = np.random.default_rng(3)
    pts = _random_points(rng, 5000, scale=1.5)
    a, b = MortonBVHMap(), MortonBVHMap()
    a.merge(pts)
    for chunk in np.array_split(pts, 4):
        b.merge(chunk)
    np.testing.assert_array_equal(a.lookup().codes, b.lookup().codes)
    np.testing.assert_array_equal(a.points(), b.points())


def test_morton_max_points_and_prune():
    rng = np.random.default_rng(4)
    pts = rng.uniform(-10, 10, (3000, 3)).astype(np.float32)
    m = MortonBVHMap(max_points=1000, dedup_level=0)
    m.merge(pts)
    assert len(m) == 1000 and m.n_dropped == 2000
    dropped = m.prune([0, 0, 0], 8.0)
    assert len(m) == 1000 - dropped
    assert np.all(np.linalg.norm(m.points(), axis=1) <= 8.0)
    lk = m.lookup()
    assert lk.cell_start[-1] == len(m) and np.all(np.diff(lk.codes) >= 0)


@pytest.mark.parametrize("kind", ["voxel_hash", "morton_bvh"])
def test_maps_reject_bad_shapes_and_report_memory(kind):
    m = make_map(kind)
    with pytest.raises(ValueError):
        m.merge(np.zeros((5, 4), np.float32))
    m.merge(np.zeros((0, 3), np.float32))
    assert len(m) == 0
    assert m.memory_bytes() >= 0
    with pytest.raises(ValueError):
        make_map("octomap")


def test_out_of_range_and_nonfinite_points_are_dropped():
    pts = np.array([[1e9, 0, 0], [np.nan, 0, 0], [1.0, 1.0, 1.0]], np.float32)
    v = VoxelHashMap()
    v.merge(pts)
    assert len(v) == 1 and v.n_dropped == 2
    m = MortonBVHMap()
    m.merge(pts)
    assert len(m) == 1 and m.n_dropped == 2


# ------------------------------------------------------------------------------------- score precision
TRUE_RPY = np.array([0.01, -0.02, 0.05])
TRUE_T = np.array([1.0, 0.3, 1.73])


@pytest.fixture(scope="module")
def street():
    rng = np.random.default_rng(7)
    world = street_scene(rng, 200_000)
    scan = street_scan(rng, rpy_to_matrix(TRUE_RPY), TRUE_T, 1000)
    return world, scan


def _sweep(lookup, scan, axis, offsets):
    """Scores of poses offset from the true one along one axis (0-2: x, y, z metres; 3-5: rpy radians)."""
    P = len(offsets)
    t = np.tile(TRUE_T, (P, 1))
    rpy = np.tile(TRUE_RPY, (P, 1))
    if axis < 3:
        t[:, axis] += offsets
    else:
        rpy[:, axis - 3] += offsets
    return get_backend("cpu").score_particles(rpy_to_matrix(rpy), t, scan, lookup)


@pytest.mark.parametrize("kind", ["voxel_hash", "morton_bvh"])
def test_score_peaks_at_the_true_pose(street, kind):
    """The score is maximised within 5 cm / 0.2 deg of the true pose, and 5 cm / 0.3 deg off scores lower."""
    world, scan = street
    m = make_map(kind)
    for chunk in np.array_split(world, 10):
        m.merge(chunk)
    lookup = m.lookup()
    shifts = np.linspace(-0.2, 0.2, 41)  # 1 cm steps
    angles = np.deg2rad(np.linspace(-2.0, 2.0, 41))  # 0.1 deg steps
    for axis in range(6):
        offs = shifts if axis < 3 else angles
        s = _sweep(lookup, scan, axis, offs)
        best = offs[np.argmax(s)]
        if axis < 3:
            assert abs(best) <= 0.05 + 1e-9, (kind, axis, best)
        else:
            assert abs(np.rad2deg(best)) <= 0.2 + 1e-9, (kind, axis, np.rad2deg(best))
        near = np.array([-0.05, 0.0, 0.05]) if axis < 3 else np.deg2rad([-0.3, 0.0, 0.3])
        s_near = _sweep(lookup, scan, axis, near)
        assert s_near[1] > s_near[0] and s_near[1] > s_near[2], (kind, axis, s_near)


def test_score_is_continuous_in_the_pose(street):
    """Trilinear interpolation: a 1 mm shift changes the voxel-hash score by little (no jumps at voxel faces)."""
    world, scan = street
    m = VoxelHashMap()
    m.merge(world)
    s = _sweep(m.lookup(), scan, 0, np.arange(-0.1, 0.1, 0.001))
    # a jump J (a point changing voxel) shows in both the first and the second difference with size ~J; a
    # continuous, piecewise smooth score has second differences far below its first differences
    d1, d2 = np.abs(np.diff(s)), np.abs(np.diff(s, 2))
    assert d2.max() < 0.25 * d1.max(), (d1.max(), d2.max())


@pytest.mark.parametrize("kind", ["voxel_hash", "morton_bvh"])
def test_score_peaks_on_a_real_kitti_scan(kind):
    """Real HDL-64E points (KITTI 2011_09_26 drive 1, frame 0): a map from a random half of the scan scores
    1000 points of the other half best within 5 cm / 0.2 deg of the identity pose."""
    from slamlib.paths import kitti_sample_dir

    path = kitti_sample_dir() / "velodyne_sample" / "0000000000.bin"
    scan = np.fromfile(path, np.float32).reshape(-1, 4)[:, :3]
    rng = np.random.default_rng(0)
    idx = rng.permutation(len(scan))
    m = make_map(kind)
    m.merge(scan[idx[: len(scan) // 2]])
    query = scan[idx[len(scan) // 2 :]]
    query = query[np.linalg.norm(query, axis=1) > 3.0][:1000]
    cpu = get_backend("cpu")
    for axis in range(6):
        offs = (
            np.linspace(-0.2, 0.2, 41)
            if axis < 3
            else np.deg2rad(np.linspace(-2.0, 2.0, 41))
        )
        t, rpy = np.zeros((41, 3)), np.zeros((41, 3))
        (t if axis < 3 else rpy)[:, axis % 3] = offs
        best = offs[
            np.argmax(cpu.score_particles(rpy_to_matrix(rpy), t, query, m.lookup()))
        ]
        assert abs(best) <= (0.05 if axis < 3 else np.deg2rad(0.2)) + 1e-9, (
            kind,
            axis,
            best,
        )


def test_voxel_hash_statistics_after_merging_one_point():
    """One point: its voxel's mean is the point and its inverse covariance ``(0 + min_sigma^2 I)^-1 = 400 I``;
    the voxel's centre (0.25, 0.25, 0.25), where the trilinear score reads that voxel alone, is
    ``d = (0.15, 0.05, -0.05)`` from the mean and costs ``-0.5 * 400 * |d|^2 = -5.5``, not the best possible 0."""
    m = VoxelHashMap(voxel_size=0.5, capacity=2**6, min_sigma=0.05)
    m.merge(np.array([[0.1, 0.2, 0.3]], np.float32))
    assert len(m) == 1 and m.counts().tolist() == [1]
    np.testing.assert_allclose(m.points(), [[0.1, 0.2, 0.3]], atol=1e-7)
    lk = m.lookup()
    s = int(np.flatnonzero(lk.keys != EMPTY_KEY)[0])
    np.testing.assert_allclose(
        lk.icov[s], [400.0, 0.0, 0.0, 400.0, 0.0, 400.0], rtol=1e-5, atol=1e-3
    )
    score = get_backend("numpy").score_particles(
        np.eye(3)[None], np.zeros((1, 3)), np.array([[0.25, 0.25, 0.25]], np.float32), lk
    )
    assert score[0] == pytest.approx(-5.5, rel=1e-4)


def test_voxel_hash_merge_in_pieces_equals_merge_at_once():
    """Every voxel's statistics (not a sample of them) are the same whether the points come at once or in
    pieces of uneven sizes, including single points (so the last voxel of each merge is refreshed)."""
    rng = np.random.default_rng(5)
    pts = _random_points(rng, 3000, scale=2.0)
    a, b = (
        VoxelHashMap(voxel_size=0.7, capacity=2**13),
        VoxelHashMap(voxel_size=0.7, capacity=2**13),
    )
    a.merge(pts)
    for chunk in np.split(pts, [1, 2, 700, 701, 2999]):
        b.merge(chunk)
    la, lb = a.lookup(), b.lookup()
    np.testing.assert_array_equal(la.keys, lb.keys)
    np.testing.assert_array_equal(la.mean, lb.mean)
    np.testing.assert_array_equal(la.icov, lb.icov)
    np.testing.assert_array_equal(a.counts(), b.counts())
    # and each is the numpy group-by over the whole array: every occupied voxel's mean
    u, _ = axis_indices(pts, 1.0 / 0.7)
    uniq, inv = np.unique(pack_keys(u), return_inverse=True)
    occupied = np.flatnonzero(la.keys != EMPTY_KEY)
    assert occupied.size == uniq.size
    for s in occupied:
        p = pts[inv == np.searchsorted(uniq, la.keys[s])].astype(np.float64)
        np.testing.assert_allclose(la.mean[s], p.mean(axis=0), atol=2e-5)
