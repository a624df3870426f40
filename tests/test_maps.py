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

REF = get_backend("numpy")
CPU = get_backend("cpu")


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
    # frames 0..19 of the mover: 0.6 m apart, one 0.5 m voxel each; 20..29 are too recent
    assert trail == 20
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
    # every occupied voxel represented
    assert set(np.unique(morton_codes(u_all) >> 9)) == set(dedup)
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
    # the buffers' bytes: a voxel hash slot holds a key and a count (int64), sums (3 + 6 float64), a mean and an
    # inverse covariance (3 + 6 float32) and two frame numbers (int32); the Morton map a code (int64) and xyz
    # (3 float32) a point, a code and a start (int64) and a box (2 x 3 float32) a cell, and one more start
    if kind == "voxel_hash":
        per_slot = 8 + 8 + 3 * 8 + 6 * 8 + 3 * 4 + 6 * 4 + 2 * 4
        assert m.memory_bytes() == per_slot * m.capacity
    else:
        assert m.memory_bytes() == 8  # no point, no cell: cell_start = [0]
        m.merge(np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [5.0, 5.0, 5.0]], np.float32))
        cells = len(m.lookup().cell_codes)
        assert len(m) == 3 and m.memory_bytes() == 20 * 3 + 40 * cells + 8
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


# ------------------------------------------------------------------ prune, merge, parameters and layouts, by value
def _voxel_stats(m):
    """``{key: (count, mean, icov)}`` of every occupied voxel of a VoxelHashMap."""
    lk = m.lookup()
    occ = np.flatnonzero(lk.keys != -1)
    return {
        int(lk.keys[s]): (int(m._count[s]), lk.mean[s].copy(), lk.icov[s].copy())
        for s in occ
    }


def _probe_distances(lk):
    """Linear-probe distance of every stored key from its home slot (the documented hash)."""
    from slamlib.maps.codes import hash_slots

    occ = np.flatnonzero(lk.keys != -1)
    home = hash_slots(lk.keys[occ], lk.log2_capacity)
    return (occ - home) % (1 << lk.log2_capacity)


def test_voxel_hash_prune_keeps_exactly_the_near_voxels_with_their_statistics():
    """``prune(c, r)`` keeps the voxels whose mean is within ``r`` of ``c`` (a mean at exactly ``r`` is kept), each
    with its count, mean, inverse covariance and sums (merging more points later equals a map built from the kept
    points); the rebuilt table (small: keys collide and probes wrap around the end) finds every key, ``max_probe``
    is the longest probe of the new layout, the buffers keep their dtypes and ``n_dropped`` is unchanged. Returns the
    number evicted; nothing to evict changes nothing; ``center`` may be any shape of 3 values."""
    from slamlib.maps.codes import hash_slots, pack_keys

    rng = np.random.default_rng(21)
    centres = (
        np.array([[x, y, 0.0] for x in range(-3, 4) for y in range(-3, 4)], np.float64)[
            :40
        ]
        + 0.5
    )
    # three more near voxels whose home slots are the last ones (62, 63; found by search): reinserted after the
    # grid's keys, one of them wraps around the end of the table
    last = np.array([[-1, 0, 1], [0, 1, 2], [1, 2, -3]])
    assert hash_slots(pack_keys(last + 2**20), 6).tolist() == [63, 62, 63]
    centres = np.vstack([centres, last + [0.5, 0.5, 0.5]])
    pts = np.vstack([c + rng.uniform(-0.4, 0.4, (5, 3)) * [1, 1, 0.5] for c in centres])
    c0 = np.array([0.5, 0.5, 0.0])
    # alone in its voxel: mean at distance 4.0
    pts = np.vstack([pts, [c0 + [0.0, 4.0, 0.0]]]).astype(np.float32)
    m = VoxelHashMap(voxel_size=1.0, capacity=64, max_load=0.7)
    m.merge(pts)
    assert m.n_dropped == 0 and len(m) == 44
    before = _voxel_stats(m)
    version = m.version
    assert (
        m.prune(c0, 100.0) == 0
        and m.version == version
        and _voxel_stats(m).keys() == before.keys()
    )
    means = {k: v[1].astype(np.float64) for k, v in before.items()}
    near = {k for k, mu in means.items() if np.sum((mu - c0) ** 2) <= 16.0}
    assert (
        any(np.sum((mu - c0) ** 2) == 16.0 for mu in means.values())
        and 0 < len(near) < 44
    )
    assert {pack_key_of(p) for p in last + 0.5} <= near
    evicted = m.prune(c0.reshape(3, 1), 4.0)  # a column is fine too
    assert (
        evicted == 44 - len(near)
        and len(m) == len(near)
        and m.version != version
        and m.n_dropped == 0
    )
    after = _voxel_stats(m)
    assert after.keys() == near
    for k in near:
        assert after[k][0] == before[k][0]
        np.testing.assert_array_equal(after[k][1], before[k][1])
        np.testing.assert_array_equal(after[k][2], before[k][2])
    lk = m.lookup()
    assert (lk.keys.dtype, lk.mean.dtype, lk.icov.dtype, m.counts().dtype) == (
        np.int64,
        np.float32,
        np.float32,
        np.int64,
    )
    for s in np.flatnonzero(lk.keys != -1):
        assert _find(lk.keys, int(lk.keys[s]), lk.log2_capacity, lk.max_probe) == s
    assert lk.max_probe == _probe_distances(lk).max() > 0
    occ = np.flatnonzero(lk.keys != -1)
    assert np.any(hash_slots(lk.keys[occ], 6) > occ)  # a probe wrapped around the end
    # the sums travelled too: more points into the kept voxels == a fresh map of all the kept points
    keep_pts = np.array([p for p in pts if pack_key_of(p) in near], np.float32)
    extra = (keep_pts[:7] + 0.01).astype(np.float32)
    fresh = VoxelHashMap(voxel_size=1.0, capacity=64, max_load=0.7)
    fresh.merge(np.vstack([keep_pts, extra]))
    m.merge(extra)
    got, want = _voxel_stats(m), _voxel_stats(fresh)
    assert got.keys() == want.keys()
    for k in want:
        assert got[k][0] == want[k][0]
        np.testing.assert_allclose(got[k][1], want[k][1], atol=1e-6)
        np.testing.assert_allclose(got[k][2], want[k][2], rtol=1e-4, atol=1e-2)
    # down to one voxel: no probe at all
    assert m.prune(c0 + [0.0, 4.0, 0.0], 0.1) == len(near) - 1 and len(m) == 1
    assert m.max_probe == 0 and m.lookup().max_probe == 0


def pack_key_of(p, h=1.0):
    from slamlib.maps.codes import axis_indices, pack_keys

    u, ok = axis_indices(np.asarray(p, np.float64)[None], 1.0 / h)
    return int(pack_keys(u)[0])


def test_morton_prune_keeps_exactly_the_points_within_the_radius():
    """``prune(c, r)`` keeps the points within ``r`` of ``c`` (a point at exactly ``r`` is kept), and the map is then
    the map built from those points alone (codes, points, cells, boxes); nothing to drop changes nothing."""
    rng = np.random.default_rng(22)
    pts = np.vstack(
        [rng.uniform(-6, 6, (400, 3)), [[3.0, 4.0, 3.0], [1.0, 2.0, 2.0]]]
    ).astype(np.float32)
    m = MortonBVHMap(radius=0.3, dedup_level=0)
    m.merge(pts)
    version = m.version
    assert m.prune([1.0, 2.0, 2.0], 100.0) == 0 and m.version == version and len(m) == 402
    c = np.array([1.0, 2.0, 2.0])
    d2 = np.sum((pts.astype(np.float64) - c) ** 2, axis=1)
    keep = d2 <= 9.0
    assert keep[-2] and d2[-2] == 9.0 and 0 < keep.sum() < 402
    assert (
        m.prune(c.reshape(3, 1), 3.0) == 402 - keep.sum()
        and len(m) == keep.sum()
        and m.version != version
    )
    fresh = MortonBVHMap(radius=0.3, dedup_level=0)
    fresh.merge(pts[keep])
    a, b = m.lookup(), fresh.lookup()
    for name in ("codes", "points", "cell_codes", "cell_start", "cell_lo", "cell_hi"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_make_map_by_name():
    from slamlib.maps import make_map

    assert type(make_map()) is VoxelHashMap
    m = make_map("morton_bvh", radius=0.5, sigma=0.2)
    assert type(m) is MortonBVHMap and (m.radius, m.sigma) == (0.5, 0.2)
    assert make_map("voxel_hash", voxel_size=2.0).voxel_size == 2.0
    with pytest.raises(
        ValueError,
        match=r"^unknown map kind 'octree'; choose one of voxel_hash, morton_bvh$",
    ):
        make_map("octree")


def test_fresh_code_functions_follow_the_formulas():
    """A fresh identity build of ``make_code_functions`` (the source of every build): ``axis_index``, ``in_range``
    at its bounds, and ``find_slot`` on a hand-made table whose probe wraps around the end."""
    from slamlib.maps.codes import make_code_functions

    f = make_code_functions()
    for x, inv_h in ((0.0, 2.0), (-0.1, 2.0), (3.7, 2.0), (-1e5, 10.0), (0.49999, 2.0)):
        assert f["axis_index"](x, inv_h) == np.floor(x * inv_h) + 2**20
    assert [bool(f["in_range"](np.int64(u))) for u in (-1, 0, 2**21 - 1, 2**21)] == [
        False,
        True,
        True,
        False,
    ]
    log2c = 4
    keys = np.full(16, -1, np.int64)
    # three keys with the home slot 15: stored at 15, 0, 1 (linear probing wraps around)
    homes = [
        k for k in range(1, 5000) if f["hash_slot"](np.int64(k), np.int64(log2c)) == 15
    ][:3]
    for slot, k in zip((15, 0, 1), homes):
        keys[slot] = k
    for slot, k in zip((15, 0, 1), homes):
        assert f["find_slot"](keys, np.int64(k), np.int64(log2c), np.int64(2)) == slot
    # beyond max_probe
    assert f["find_slot"](keys, np.int64(homes[2]), np.int64(log2c), np.int64(1)) == -1
    other = next(
        k
        for k in range(5000, 10000)
        if f["hash_slot"](np.int64(k), np.int64(log2c)) == 15
    )
    # stops at the empty slot 2
    assert f["find_slot"](keys, np.int64(other), np.int64(log2c), np.int64(5)) == -1
    # a full table without the key: gives up after max_probe + 1
    full = np.arange(16, dtype=np.int64) + 100
    assert f["find_slot"](full, np.int64(7), np.int64(log2c), np.int64(15)) == -1
    # masked to 21 bits
    assert (
        f["part1by2"](np.int64(0b1011)) == 0b1000001001
        and f["part1by2"](np.int64(2**21)) == 0
    )


def test_pack_keys_of_unsigned_or_narrow_indices():
    """``pack_keys`` converts its indices to int64 first: uint64 or int32 input gives the same keys."""
    from slamlib.maps.codes import pack_keys

    u = np.array([[5, 2**20, 2**21 - 1], [0, 1, 2]])
    want = u[:, 0] | u[:, 1] << 21 | u[:, 2] << 42
    for dtype in (np.int64, np.uint64, np.uint32):
        got = pack_keys(u.astype(dtype))
        assert got.dtype == np.int64 and got.tolist() == want.tolist()


def test_morton_map_of_one_point_and_pruned_to_nothing():
    """One point: one cell, ``cell_start = [0, 1]``, its box the point. Pruned to nothing: the empty layout (shapes
    (0,), (1,) = [0], (0, 3)) and every query costs ``-0.5 r^2 / sigma^2``."""
    m = MortonBVHMap(radius=0.5, sigma=0.25)
    p = np.array([[1.0, -2.0, 0.5]], np.float32)
    m.merge(p)
    lk = m.lookup()
    assert (
        lk.codes.shape == (1,)
        and lk.cell_codes.shape == (1,)
        and lk.cell_start.tolist() == [0, 1]
    )
    assert lk.cell_codes[0] == lk.codes[0] >> (3 * lk.cell_level)
    np.testing.assert_array_equal(lk.cell_lo, p)
    np.testing.assert_array_equal(lk.cell_hi, p)
    q = np.array([[1.1, -2.0, 0.5], [3.0, 3.0, 3.0]], np.float32)
    I, z = np.eye(3)[None], np.zeros((1, 3))
    floor = -0.5 * 0.5**2 / 0.25**2
    for backend in (REF, CPU):
        np.testing.assert_allclose(
            backend.score_particles(I, z, q[:1], lk), -0.5 * 0.1**2 / 0.25**2, rtol=1e-5
        )
    assert m.prune([0.0, 0.0, 0.0], 1.0) == 1 and len(m) == 0
    lk = m.lookup()
    assert lk.codes.shape == (0,) and lk.points.shape == (0, 3)
    assert lk.cell_codes.shape == (0,) and lk.cell_codes.dtype == np.int64
    assert lk.cell_start.tolist() == [0] and lk.cell_start.dtype == np.int64
    assert (
        lk.cell_lo.shape == lk.cell_hi.shape == (0, 3)
        and lk.cell_lo.dtype == lk.cell_hi.dtype == np.float32
    )
    for backend in (REF, CPU):
        np.testing.assert_allclose(backend.score_particles(I, z, q, lk), 2 * floor)


def test_morton_parameters_defaults_and_limits():
    m = MortonBVHMap()
    assert (m.radius, m.sigma, m.quantum, m.dedup_level, m.max_points) == (
        0.3,
        0.1,
        0.01,
        3,
        4_000_000,
    )
    msg = r"^radius, sigma, quantum, max_points must be > 0 and 0 <= dedup_level <= 20$"
    for bad in (
        {"radius": 0.0},
        {"sigma": 0.0},
        {"quantum": 0.0},
        {"max_points": 0},
        {"dedup_level": -1},
        {"dedup_level": 21},
        {"radius": -1.0, "sigma": 1.0},
    ):
        with pytest.raises(ValueError, match=msg):
            MortonBVHMap(**bad)
    for ok in ({"dedup_level": 0}, {"dedup_level": 20}, {"max_points": 1}):
        MortonBVHMap(**ok)
    # 2 r < quantum: cells of one quantum
    assert MortonBVHMap(radius=0.004, quantum=0.01).cell_level == 0
    assert MortonBVHMap(radius=0.01 * 2**19, quantum=0.01).cell_level == 20
    with pytest.raises(
        ValueError,
        match=r"^radius too large for quantum: cells would exceed the 21-bit range$",
    ):
        MortonBVHMap(radius=0.01 * 2**19 * 1.01, quantum=0.01)


def test_morton_merge_counts_drops_and_dedups_against_the_map():
    """Dropped points add up over merges (non-finite ones, and those beyond ``max_points``); merging the same
    points again adds nothing (each, including the one with the highest code, is already there); points stay
    float32; a bad shape names ``points_world``."""
    rng = np.random.default_rng(23)
    m = MortonBVHMap(max_points=10, dedup_level=0)
    a = rng.uniform(-2, 2, (6, 3)).astype(np.float32)
    m.merge(np.vstack([a, [[np.nan, 0, 0]]]))
    assert len(m) == 6 and m.n_dropped == 1
    m.merge(a)  # all already there
    assert len(m) == 6 and m.n_dropped == 1
    m.merge(rng.uniform(-2, 2, (6, 3)).astype(np.float32))
    assert len(m) == 10 and m.n_dropped == 3
    m.merge(np.array([[np.inf, 0, 0]], np.float32))
    assert m.n_dropped == 4
    assert m.lookup().points.dtype == np.float32
    with pytest.raises(ValueError, match=r"^points_world must have shape \(N, 3\)"):
        m.merge(np.zeros((3, 2)))
    v = VoxelHashMap()
    with pytest.raises(ValueError, match=r"^points_world must have shape \(N, 3\)"):
        v.merge(np.zeros(3))


@pytest.mark.parametrize("kind", [VoxelHashMap, MortonBVHMap])
def test_lookup_carries_the_map_version(kind):
    """The lookup's ``version`` is the map's stamp (the CUDA backend re-uses its device copy while it is equal):
    non-zero, new after each merge."""
    m = kind()
    v0 = m.lookup().version
    assert v0 == m.version != 0
    m.merge(np.ones((2, 3), np.float32))
    assert m.lookup().version == m.version not in (0, v0)


def test_voxel_hash_merge_drops_out_of_range_points_and_counts_them():
    """Non-finite points and points outside the +-2**20-voxel range on any one axis are dropped and counted (over
    merges); points far out but in range (1000 voxels up) are merged; with a tiny voxel the overflow guard drops a
    point whose index would not fit in int64. Slots that no point reached keep their zeros (no statistics
    refreshed from an empty slot)."""
    m = VoxelHashMap(voxel_size=1.0, capacity=2**10)
    out = 1.5 * 2**20  # index + 2**20 beyond 21 bits
    bad = np.array(
        [[np.nan, 0, 0], [0, np.inf, 0], [out, 0, 0], [0, -out, 0], [0, 0, out]],
        np.float32,
    )
    m.merge(bad)
    assert len(m) == 0 and m.n_dropped == 5
    lk = m.lookup()
    assert not lk.mean.any() and not lk.icov.any()
    good = np.array(
        [[0.5, 0.5, 1000.5], [1000.5, 0.5, 0.5], [0.5, -1000.5, 0.5], [0.2, 0.3, 0.4]],
        np.float32,
    )
    m.merge(np.vstack([bad[:2], good]))
    assert len(m) == 4 and m.n_dropped == 7
    np.testing.assert_allclose(np.sort(m.points(), axis=0), np.sort(good, axis=0))
    lk = m.lookup()
    empty = lk.keys == -1
    assert (
        not lk.mean[empty].any()
        and not lk.icov[empty].any()
        and np.isfinite(lk.icov).all()
    )
    tiny = VoxelHashMap(voxel_size=1e-10, capacity=2**4)
    tiny.merge(np.array([[1e9, 0, 0], [0, 1e9, 0], [0, 0, -1e9], [0, 0, 0]], np.float32))
    assert len(tiny) == 1 and tiny.n_dropped == 3


def test_voxel_hash_max_probe_is_the_longest_probe():
    """``max_probe`` is the longest linear-probe distance of any stored key: 0 for one voxel, and exactly the
    layout's longest after many colliding inserts (lookups give up after ``max_probe + 1`` slots)."""
    m = VoxelHashMap(voxel_size=1.0, capacity=16)
    m.merge(np.array([[0.5, 0.5, 0.5], [0.6, 0.5, 0.5]], np.float32))
    assert m.max_probe == 0 == m.lookup().max_probe
    rng = np.random.default_rng(24)
    m = VoxelHashMap(voxel_size=1.0, capacity=64, max_load=0.7)
    m.merge(rng.uniform(-4, 4, (300, 3)).astype(np.float32))
    lk = m.lookup()
    assert len(m) == 44 and lk.max_probe == _probe_distances(lk).max() >= 2


def test_voxel_hash_parameters_defaults_and_limits():
    m = VoxelHashMap()
    assert (m.voxel_size, m.capacity, m.max_load, m.min_sigma, m.m_max) == (
        0.5,
        2**19,
        0.75,
        0.05,
        16.0,
    )
    assert m.max_voxels == int(0.75 * 2**19) and m.log2_capacity == 19
    for cap in (8, 24, 15, 2**10 + 2):
        with pytest.raises(
            ValueError, match=rf"^capacity must be a power of two >= 16, got {cap}$"
        ):
            VoxelHashMap(capacity=cap)
    assert VoxelHashMap(capacity=16).capacity == 16
    msg = r"^voxel_size, min_sigma, m_max must be > 0 and 0 < max_load < 1$"
    for bad in (
        {"voxel_size": 0.0},
        {"max_load": 0.0},
        {"max_load": 1.0},
        {"max_load": 1.5},
        {"min_sigma": 0.0},
        {"m_max": 0.0},
    ):
        with pytest.raises(ValueError, match=msg):
            VoxelHashMap(capacity=16, **bad)


def test_as_points_names_the_argument_and_converts():
    from slamlib.maps.base import as_points

    with pytest.raises(
        ValueError, match=r"^points must have shape \(N, 3\), got \(3,\)$"
    ):
        as_points(np.zeros(3))
    with pytest.raises(
        ValueError, match=r"^scan must have shape \(N, 3\), got \(2, 4\)$"
    ):
        as_points(np.zeros((2, 4)), "scan")
    a = as_points(np.arange(12, dtype=np.float64).reshape(3, 4)[:, :3])
    assert (
        a.dtype == np.float32
        and a.flags.c_contiguous
        and a.tolist() == [[0, 1, 2], [4, 5, 6], [8, 9, 10]]
    )


def test_axis_indices_in_float64_at_the_range_ends():
    """``axis_indices``: float32 points are offset in float64 (``70.1f * 10`` is 700.99998..., index 700, while a
    float32 product rounds to 701); int64 result; the valid range is exactly ``[-2**20, 2**20)`` voxels."""
    from slamlib.maps.codes import axis_indices

    u, ok = axis_indices(np.array([[70.1, 27.3, -91.9]], np.float32), 10.0)
    assert u.dtype == np.int64 and ok.tolist() == [True]
    assert (u[0] - 2**20).tolist() == [700, 272, -920]
    h = 0.5
    pts = np.array(
        [
            [-(2**20) * h, 0, 0],
            [(2**20 - 1) * h, 0, 0],
            [0, -(2**20) * h - h, 0],
            [0, 0, 2**20 * h],
            [np.nan, 0, 0],
        ]
    )
    u, ok = axis_indices(pts, 1.0 / h)
    assert ok.tolist() == [True, True, False, False, False]
    assert u[0, 0] == 0 and u[1, 0] == 2**21 - 1


def test_voxel_in_slot_zero_is_refreshed():
    """The voxel whose home slot is 0 gets its statistics like any other (the refresh loop includes slot 0)."""
    from slamlib.maps.codes import hash_slots, pack_keys

    r = np.arange(-4, 5)
    u = np.stack(np.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3)
    home0 = u[hash_slots(pack_keys(u + 2**20), 4) == 0][0]
    p = (home0 + [0.2, 0.3, 0.4]).astype(np.float32)[None]
    # m_max may be below 1
    m = VoxelHashMap(voxel_size=1.0, capacity=16, min_sigma=0.05, m_max=0.5)
    m.merge(p)
    lk = m.lookup()
    assert lk.keys[0] != -1 and lk.voxel_size == 1.0 and lk.m_max == 0.5
    np.testing.assert_allclose(lk.mean[0], p[0], atol=1e-6)
    np.testing.assert_allclose(lk.icov[0], [400, 0, 0, 400, 0, 400], rtol=1e-5, atol=1e-3)
    assert m.counts().dtype == np.int64 and m.counts().tolist() == [1]


def test_fresh_morton_map_layout():
    """Before any merge the lookup is the empty layout with the documented dtypes (and scores the floor)."""
    lk = MortonBVHMap(radius=0.5, sigma=0.25).lookup()
    assert (lk.codes.shape, lk.codes.dtype) == ((0,), np.int64)
    assert (lk.points.shape, lk.points.dtype) == ((0, 3), np.float32)
    assert (lk.cell_codes.shape, lk.cell_codes.dtype) == ((0,), np.int64)
    assert lk.cell_start.tolist() == [0] and lk.cell_start.dtype == np.int64
    for box in (lk.cell_lo, lk.cell_hi):
        assert (box.shape, box.dtype) == ((0, 3), np.float32)
    I, z = np.eye(3)[None], np.zeros((1, 3))
    np.testing.assert_allclose(
        CPU.score_particles(I, z, np.zeros((3, 3), np.float32), lk),
        -1.5 * 0.5**2 / 0.25**2,
    )


def test_a_maps_resolution_is_its_voxel_edge_or_its_lookup_radius():
    """:attr:`Map3D.resolution`: the scale below which two poses score against the same elements, a voxel hash's
    edge and a Morton BVH's lookup radius, as configured (the start search's line uses it,
    :mod:`slamlib.slam3d.stages.search`)."""
    assert make_map("voxel_hash", voxel_size=0.4).resolution == 0.4
    assert make_map("morton_bvh", radius=0.25).resolution == 0.25
