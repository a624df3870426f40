"""Value tests written for survivors of mutation testing (issue 15, tests/mutation/REPORT.md).

Small and fast on purpose: ``make mutate`` runs the kernels as plain Python (``NUMBA_DISABLE_JIT=1``), and mutmut
runs the fastest covering test first, so these kill most mutants of the Numba kernels and the maps in well under a
second each. The Numba CPU backend is checked against the numpy reference (independent: sorted-key search, k-d tree)
and against the definitions, on sizes that cross every chunk boundary of its loops.
"""

import re

import numba
import numpy as np
import pytest

from slamlib import geometry
from slamlib.kernels import cpu, get_backend, reference
from slamlib.maps import MortonBVHMap, VoxelHashMap

REF = get_backend("numpy")
CPU = get_backend("cpu")


def _world(rng, n=900):
    """Points on the faces of two boxes and a slab, plus clutter, around the origin (float32, metres)."""
    out = []
    for c, size in (
        ([1.0, 0.5, 0.0], [2.0, 1.0, 1.5]),
        ([-1.5, -1.0, 0.5], [1.0, 2.5, 1.0]),
    ):
        p = rng.uniform(-0.5, 0.5, (n // 3, 3))
        ax = rng.integers(0, 3, n // 3)
        p[np.arange(n // 3), ax] = np.sign(p[np.arange(n // 3), ax]) * 0.5
        out.append(np.asarray(c) + p * size)
    out.append(rng.uniform(-3, 3, (n // 3, 3)) * [1, 1, 0.05])
    return np.vstack(out).astype(np.float32)


def _maps(rng):
    world = _world(rng)
    maps = [
        VoxelHashMap(voxel_size=0.5, capacity=2**11),
        MortonBVHMap(radius=0.3, sigma=0.15, dedup_level=2),
        MortonBVHMap(radius=0.8, sigma=0.3, quantum=0.02, dedup_level=0),
    ]
    for m in maps:
        m.merge(world)
    return maps


def _particles(rng, P, spread=0.05, shift=0.2):
    R = geometry.rpy_to_matrix(rng.uniform(-np.pi, np.pi, (P, 3)) * spread)
    t = rng.normal(0.0, shift, (P, 3))
    return R, t


@pytest.fixture(scope="module")
def small_maps():
    return _maps(np.random.default_rng(11))


@pytest.mark.parametrize(
    "chunks", [None, (5, 3, 4, 2)], ids=["default-chunks", "small-chunks"]
)
def test_score_particles_cpu_equals_reference_across_chunks(
    small_maps, monkeypatch, chunks
):
    """Per-particle scores of the fused kernel == the reference, with point and particle counts that are not
    multiples of the chunk sizes (several chunks each way, a partial last one), a small Morton leaf (the octree
    descent runs) and a tiny cell cache (collisions), and with the default constants."""
    if chunks:
        for name, v in zip(
            ("POINT_CHUNK", "PARTICLE_CHUNK", "MORTON_LEAF", "CELL_CACHE_BITS"), chunks
        ):
            monkeypatch.setattr(cpu, name, v)
    rng = np.random.default_rng(12)
    P, N = (7, 23) if chunks else (3, 70)
    R, t = _particles(rng, P)
    pts = np.vstack(
        [
            rng.uniform(-3, 3, (N - 3, 3)),
            [[1.0, 1.0, 0.75], [20.0, 0.0, 0.0], [-2.0, -1.0, 0.0]],
        ]
    ).astype(np.float32)
    for m in small_maps:
        lk = m.lookup()
        ref = REF.score_particles(R, t, pts, lk)
        got = CPU.score_particles(R, t, pts, lk)
        assert got.shape == (P,) and got.dtype == np.float64
        np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-9)
        assert (
            np.ptp(ref) > 1.0
        )  # the particles are told apart: a mixed-up particle index shows


def test_score_particles_per_point_terms_by_definition(small_maps):
    """One particle at the identity, one point at a time: the CPU score is the reference's per-point term, and
    for the Morton maps it is ``-0.5 min(d_nn, r)^2 / sigma^2`` by brute force; the sum over points adds up."""
    rng = np.random.default_rng(13)
    I, z = np.eye(3)[None], np.zeros((1, 3))
    queries = np.vstack(
        [rng.uniform(-3, 3, (25, 3)), _world(rng)[:15] + rng.normal(0, 0.05, (15, 3))]
    )
    queries = queries.astype(np.float32)
    for m in small_maps:
        lk = m.lookup()
        terms = reference.point_terms(queries.astype(np.float64), lk)
        got = np.array([CPU.score_particles(I, z, q[None], lk)[0] for q in queries])
        np.testing.assert_allclose(got, terms, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(
            CPU.score_particles(I, z, queries, lk)[0], terms.sum(), rtol=1e-9
        )
        if isinstance(m, MortonBVHMap):
            stored = m.points().astype(np.float64)
            d2 = np.min(
                np.sum((stored[None] - queries.astype(np.float64)[:, None]) ** 2, axis=2),
                axis=1,
            )
            np.testing.assert_allclose(
                got,
                -0.5 * np.minimum(d2, m.radius**2) / m.sigma**2,
                rtol=1e-9,
                atol=1e-12,
            )
            assert np.any(d2 < m.radius**2) and np.any(d2 > m.radius**2)


def _garbage_stack(cell_level):
    """``morton_nn_nb``'s scratch stack filled with an entry it must never read: a node that covers everything
    (level 62) holding the run ``[10**6, 10**6 + 1)`` past the end of the points (read as Python: IndexError)."""
    stack = np.empty((8 * (cell_level + 2), 6), np.int64)
    stack[:] = [10**6, 10**6 + 1, 62, 0, 0, 0]
    return stack


def test_morton_nn_is_exact_with_warm_starts_and_a_small_leaf(small_maps):
    """``morton_nn_nb`` returns ``(min(d_nn^2, best), index of that point)`` by brute force, cold and warm started
    from another point, with leaves of 1, 4 and 64 points (deep and shallow descent)."""
    m = small_maps[1]
    lk = m.lookup()
    stored = lk.points.astype(np.float64)
    rng = np.random.default_rng(14)
    queries = np.vstack(
        [
            stored[rng.integers(0, len(stored), 20)] + rng.normal(0, 0.1, (20, 3)),
            rng.uniform(-3, 3, (20, 3)),
        ]
    )
    r2 = lk.radius**2
    for leaf in (1, 4, 64):
        stack = _garbage_stack(lk.cell_level)
        cache_code = np.full(1 << 3, -1, np.int64)
        cache_k = np.empty(1 << 3, np.int64)
        for q in queries:
            d2 = np.sum((stored - q) ** 2, axis=1)
            j = int(np.argmin(d2))
            args = (
                lk.codes,
                lk.points,
                lk.cell_codes,
                lk.cell_start,
                lk.cell_lo,
                lk.cell_hi,
                lk.quantum,
                lk.cell_level,
            )
            best, best_j = cpu.morton_nn_nb(
                *q, *args, r2, -1, stack, leaf, cache_code, cache_k, 3
            )
            if d2[j] < r2:
                assert best_j == j and best == pytest.approx(d2[j], rel=1e-12)
            else:
                assert best_j == -1 and best == r2
            k = int(
                np.argsort(d2)[1]
            )  # warm start from the second-nearest point, at its distance
            if d2[k] < r2:
                best, best_j = cpu.morton_nn_nb(
                    *q, *args, d2[k], k, stack, leaf, cache_code, cache_k, 3
                )
                assert best == pytest.approx(d2[j], rel=1e-12) and d2[
                    best_j
                ] == pytest.approx(best, rel=1e-12)


def test_move_particles_cpu_equals_reference_on_two_blocks(monkeypatch):
    """The particle loop in blocks: with a block of 4, 10 particles take three blocks (the last partial)."""
    from slamlib.noise import LutNoise, make_tables

    monkeypatch.setattr(cpu, "PARTICLE_BLOCK", 4)
    rng = np.random.default_rng(15)
    R, t = _particles(rng, 10, spread=0.3, shift=3.0)
    sigma = rng.uniform(0.05, 0.3, 6)
    args = ([0.02, -0.01, 0.3], [1.1, 0.2, -0.1])
    noise = rng.normal(size=(10, 6))
    for nz in (
        noise,
        LutNoise(make_tables(5, bits=2), 3, 4),
        LutNoise(make_tables(5, bits=6), 3, 4),
    ):
        R_c, t_c = CPU.move_particles(R, t, *args, nz, sigma)
        R_r, t_r = REF.move_particles(R, t, *args, nz, sigma)
        np.testing.assert_allclose(R_c, R_r, atol=1e-12)
        np.testing.assert_allclose(t_c, t_r, atol=1e-12)


def test_transform_points_cpu_in_spans(monkeypatch):
    """The transform loop in spans: 11 points in spans of 4, allocating and in place, against float64 maths."""
    monkeypatch.setattr(cpu, "TRANSFORM_CHUNK", 4)
    rng = np.random.default_rng(16)
    T = np.eye(4)
    T[:3, :3] = geometry.rpy_to_matrix(np.array([0.3, -0.2, 1.1]))
    T[:3, 3] = [1.0, -2.0, 0.5]
    pts = rng.uniform(-5, 5, (11, 3)).astype(np.float32)
    want = pts.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    np.testing.assert_allclose(CPU.transform_points(T, pts), want, rtol=1e-5, atol=1e-5)
    x = pts.copy()
    assert CPU.transform_points(T, x, out=x) is x
    np.testing.assert_allclose(x, want, rtol=1e-5, atol=1e-5)


# ------------------------------------------------------------------------------------------------------- maps
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
    pts = np.vstack([pts, [c0 + [0.0, 4.0, 0.0]]]).astype(
        np.float32
    )  # alone in its voxel: mean at distance 4.0
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


def _find(keys, key, log2c, max_probe):
    """The documented lookup in plain Python (``VoxelHashLookup``)."""
    from slamlib.maps.base import HASH_MULTIPLIER

    s = ((key * HASH_MULTIPLIER) % 2**64) >> (64 - log2c)
    for _ in range(max_probe + 1):
        if keys[s] == key:
            return s
        if keys[s] == -1:
            return -1
        s = (s + 1) % (1 << log2c)
    return -1


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
    assert (
        f["find_slot"](keys, np.int64(homes[2]), np.int64(log2c), np.int64(1)) == -1
    )  # beyond max_probe
    other = next(
        k
        for k in range(5000, 10000)
        if f["hash_slot"](np.int64(k), np.int64(log2c)) == 15
    )
    assert (
        f["find_slot"](keys, np.int64(other), np.int64(log2c), np.int64(5)) == -1
    )  # stops at the empty slot 2
    full = (
        np.arange(16, dtype=np.int64) + 100
    )  # a full table without the key: gives up after max_probe + 1
    assert f["find_slot"](full, np.int64(7), np.int64(log2c), np.int64(15)) == -1
    assert (
        f["part1by2"](np.int64(0b1011)) == 0b1000001001
        and f["part1by2"](np.int64(2**21)) == 0
    )  # masked to 21 bits


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
    assert (
        MortonBVHMap(radius=0.004, quantum=0.01).cell_level == 0
    )  # 2 r < quantum: cells of one quantum
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
    m = VoxelHashMap(
        voxel_size=1.0, capacity=16, min_sigma=0.05, m_max=0.5
    )  # m_max may be below 1
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


# ---------------------------------------------------------------------------------------------------- kernels
@pytest.mark.parametrize("backend", [REF, CPU], ids=["numpy", "cpu"])
def test_systematic_resample_checks_and_messages(backend):
    """Each bad input alone is refused with the documented message (infinite weights, 2-D weights, empty, negative,
    zero sum, ``u0`` outside [0, 1)); the result is int64."""
    msg = r"^weights must be a non-empty 1-D array of finite non-negative numbers with positive sum$"
    for w in (
        [np.inf, 1.0],
        [[0.5, 0.5], [0.5, 0.5]],
        [],
        [1.0, -0.5],
        [0.0, 0.0],
        [np.nan, 1.0],
    ):
        with pytest.raises(ValueError, match=msg):
            backend.systematic_resample(np.asarray(w, float), 0.5)
    for u0 in (1.0, -0.1):
        with pytest.raises(ValueError, match=rf"^u0 must be in \[0, 1\), got {u0}$"):
            backend.systematic_resample(np.ones(3), u0)
    idx = backend.systematic_resample([1, 0, 3], 0.0)
    assert idx.dtype == np.int64 and idx.tolist() == [0, 2, 2]


def test_reference_scores_every_voxel_and_rounds_points_to_float32():
    """The reference's sorted-key search finds every stored voxel, the one with the largest key too (per-point
    terms at each voxel's mean == the CPU kernel's); float64 points are scored as their float32 values."""
    rng = np.random.default_rng(25)
    m = VoxelHashMap(voxel_size=1.0, capacity=64)
    m.merge(
        (rng.integers(-3, 3, (6, 3)) + rng.uniform(0.3, 0.7, (30, 6, 3)))
        .reshape(-1, 3)
        .astype(np.float32)
    )
    lk = m.lookup()
    occ = np.flatnonzero(lk.keys != -1)
    q = lk.mean[occ]
    I, z = np.eye(3)[None], np.zeros((1, 3))
    ref = np.array([REF.score_particles(I, z, p[None], lk)[0] for p in q])
    cpu_ = np.array([CPU.score_particles(I, z, p[None], lk)[0] for p in q])
    np.testing.assert_allclose(ref, cpu_, rtol=1e-9, atol=1e-9)
    assert np.all(ref > -0.5 * lk.m_max)
    p64 = rng.uniform(-3, 3, (40, 3))
    R, t = _particles(rng, 3)
    for backend in (REF, CPU):
        for mm in (m, MortonBVHMap(radius=0.5)):
            if isinstance(mm, MortonBVHMap):
                mm.merge(q)
            np.testing.assert_array_equal(
                backend.score_particles(R, t, p64, mm.lookup()),
                backend.score_particles(R, t, p64.astype(np.float32), mm.lookup()),
            )


def test_reference_at_the_far_corner_of_the_key_range():
    """The voxel with packed key 0 (index -2**20 on every axis) is a stored voxel like any other, and points whose
    interpolation corners leave the key range are scored without error: the reference equals the CPU kernel."""
    h = 0.001
    corner = np.float32(-(2**20) * h + 0.0004)
    m = VoxelHashMap(voxel_size=h, capacity=16, min_sigma=0.001)
    m.merge(
        np.array(
            [[corner, corner, corner], [corner + 0.0001, corner, corner]], np.float32
        )
    )
    lk = m.lookup()
    assert 0 in lk.keys.tolist()
    q = np.array(
        [
            [corner, corner, corner],
            [corner + 0.0002, corner + 0.0001, corner],
            [1e4, 0, 0],
        ],
        np.float32,
    )
    I, z = np.eye(3)[None], np.zeros((1, 3))
    ref = np.array([REF.score_particles(I, z, p[None], lk)[0] for p in q])
    np.testing.assert_allclose(
        ref, [CPU.score_particles(I, z, p[None], lk)[0] for p in q], rtol=1e-9, atol=1e-9
    )
    assert ref[0] > -0.5 * lk.m_max and ref[2] == -0.5 * lk.m_max


def test_point_terms_work_in_float64_and_name_an_unknown_kind(small_maps):
    rng = np.random.default_rng(26)
    w = rng.uniform(-3, 3, (30, 3)).astype(np.float32)
    for m in small_maps:
        np.testing.assert_array_equal(
            reference.point_terms(w, m.lookup()),
            reference.point_terms(w.astype(np.float64), m.lookup()),
        )
    bad = small_maps[0].lookup()._replace(kind=7)
    for fn in (
        lambda: reference.point_terms(w, bad),
        lambda: CPU.score_particles(np.eye(3)[None], np.zeros((1, 3)), w, bad),
    ):
        with pytest.raises(ValueError, match=r"^unknown lookup kind 7$"):
            fn()


def test_out_may_be_another_view_of_the_input():
    """``out=`` given as a different view object of the same memory counts as in place (not as an overlap)."""
    rng = np.random.default_rng(27)
    T = np.eye(4)
    T[:3, 3] = [1.0, 2.0, 3.0]
    x = rng.uniform(-1, 1, (5, 3)).astype(np.float32)
    want = x + np.float32([1, 2, 3])
    assert np.shares_memory(CPU.transform_points(T, x, out=x.view()), x)
    np.testing.assert_allclose(x, want, rtol=1e-6)
    R, t = _particles(rng, 4)
    R_ref, t_ref = CPU.move_particles(
        R, t, [0.1, 0, 0], [1, 0, 0], np.zeros((4, 6)), np.zeros(6)
    )
    CPU.move_particles(
        R,
        t,
        [0.1, 0, 0],
        [1, 0, 0],
        np.zeros((4, 6)),
        np.zeros(6),
        out=(R.view(), t.view()),
    )
    np.testing.assert_array_equal(R, R_ref)
    np.testing.assert_array_equal(t, t_ref)


def test_reference_transform_points_dtype_and_out_checks():
    """float64 points are transformed as their float32 values; the result is float32; ``out`` must be a float32
    array of the result's shape (each condition alone), with the documented message."""
    rng = np.random.default_rng(28)
    T = np.eye(4)
    T[:3, :3] = geometry.rpy_to_matrix(np.array([0.3, -0.2, 1.1]))
    T[:3, 3] = [100.3, -20.7, 3.1]
    p64 = rng.uniform(-50, 50, (20, 3))
    got = REF.transform_points(T, p64)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, REF.transform_points(T, p64.astype(np.float32)))
    with pytest.raises(
        ValueError,
        match=r"^out must be a float32 array of shape \(20, 3\), got float64 \(20, 3\)$",
    ):
        REF.transform_points(T, p64, out=np.empty((20, 3)))
    with pytest.raises(
        ValueError,
        match=r"^out must be a float32 array of shape \(20, 3\), got float32 \(19, 3\)$",
    ):
        REF.transform_points(T, p64, out=np.empty((19, 3), np.float32))


@pytest.mark.parametrize("quantum, leaf", [(0.1, 1), (0.05, 4)])
def test_morton_nn_exact_on_coarse_quanta(quantum, leaf):
    """With coarse quanta (a node's gap of one quantum is 5-10 cm) and deep descent, queries a centimetre from
    stored points still find the true nearest one: the node holding the query is never pruned."""
    rng = np.random.default_rng(29)
    m = MortonBVHMap(radius=0.3, sigma=0.1, quantum=quantum, dedup_level=0)
    m.merge(rng.uniform(-1, 1, (3000, 3)).astype(np.float32))
    lk = m.lookup()
    stored = lk.points.astype(np.float64)
    stack = _garbage_stack(lk.cell_level)
    cache_code, cache_k = np.full(8, -1, np.int64), np.empty(8, np.int64)
    for q in stored[rng.integers(0, len(stored), 60)] + rng.normal(0, 0.01, (60, 3)):
        d2 = np.sum((stored - q) ** 2, axis=1)
        best, best_j = cpu.morton_nn_nb(
            *q,
            lk.codes,
            lk.points,
            lk.cell_codes,
            lk.cell_start,
            lk.cell_lo,
            lk.cell_hi,
            lk.quantum,
            lk.cell_level,
            lk.radius**2,
            -1,
            stack,
            leaf,
            cache_code,
            cache_k,
            3,
        )
        assert best_j == int(np.argmin(d2)) and best == pytest.approx(d2.min(), rel=1e-12)


@pytest.mark.parametrize("quantum", [0.6, 0.3, 0.2])
def test_morton_scoring_exact_when_the_cells_are_one_to_four_quanta(quantum):
    """Quanta so coarse that ``cell_level`` (edge ``quantum 2**cell_level >= 2 radius``) is 0, 1 or 2: the scoring
    kernel's search stack (``8 (cell_level + 2)`` rows) is at its smallest and the scores are still exact."""
    rng = np.random.default_rng(35)
    m = MortonBVHMap(radius=0.3, sigma=0.1, quantum=quantum, dedup_level=0)
    m.merge(rng.uniform(-2, 2, (2000, 3)).astype(np.float32))
    lk = m.lookup()
    assert lk.cell_level == {0.6: 0, 0.3: 1, 0.2: 2}[quantum]
    stored = lk.points.astype(np.float64)
    q = stored[rng.integers(0, len(stored), 30)] + rng.normal(0, 0.05, (30, 3))
    R, t = (
        np.repeat(np.eye(3)[None], 2, axis=0),
        np.array([[0.0, 0.0, 0.0], [0.05, -0.02, 0.01]]),
    )
    got = CPU.score_particles(R, t, q.astype(np.float32), lk)
    for i in range(2):
        w = q.astype(np.float32).astype(np.float64) + t[i]
        d2 = np.minimum(((w[:, None, :] - stored[None]) ** 2).sum(-1).min(1), 0.3**2)
        assert got[i] == pytest.approx(np.sum(-0.5 * d2 / 0.1**2), rel=1e-6)


def test_cpu_transform_points_dtype_and_messages():
    """float64 points give a float32 result (the points are converted first); bad shapes and a bad ``out`` are
    refused with the documented messages, naming ``out``."""
    T = np.eye(4)
    T[:3, 3] = [1.0, 2.0, 3.0]
    p64 = np.arange(12, dtype=np.float64).reshape(4, 3) * 0.1
    got = CPU.transform_points(T, p64)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, CPU.transform_points(T, p64.astype(np.float32)))
    with pytest.raises(
        ValueError,
        match=r"^need T \(4, 4\) and points \(N, 3\), got \(3, 3\) and \(4, 3\)$",
    ):
        CPU.transform_points(np.eye(3), p64)
    pts = p64.astype(np.float32)
    for out in (np.empty((4, 3)), pts[::-1]):
        with pytest.raises(
            ValueError,
            match=r"^out must be a writeable C-contiguous float32 array of shape \(4, 3\)$",
        ):
            CPU.transform_points(T, pts, out=out)


def test_cpu_move_and_score_refuse_bad_input_with_messages():
    """Each check of the CPU backend alone, with its message: particle shapes, ``out`` arrays (named), LUT noise
    step / seed (0 allowed) and tables, the noise shape, scan point shapes."""
    from slamlib.noise import LutNoise, make_tables

    rng = np.random.default_rng(30)
    R, t = _particles(rng, 4)
    args = ([0.0, 0.0, 0.1], [1.0, 0.0, 0.0])
    noise, sigma = np.zeros((4, 6)), np.full(6, 0.1)
    with pytest.raises(
        ValueError,
        match=r"^particles need R \(P, 3, 3\) and t \(P, 3\), got \(4, 3, 3\) and \(3, 3\)$",
    ):
        CPU.move_particles(R, t[:3], *args, noise, sigma)
    with pytest.raises(
        ValueError,
        match=r"^particles need R \(P, 3, 3\) and t \(P, 3\), got \(4, 3, 2\) and \(4, 3\)$",
    ):
        CPU.move_particles(R[:, :, :2], t, *args, noise, sigma)
    with pytest.raises(
        ValueError,
        match=r"^out\[0\] must be a writeable C-contiguous float64 array of shape \(4, 3, 3\)$",
    ):
        CPU.move_particles(
            R, t, *args, noise, sigma, out=(R.astype(np.float32), t.copy())
        )
    with pytest.raises(
        ValueError,
        match=r"^out\[1\] must be a writeable C-contiguous float64 array of shape \(4, 3\)$",
    ):
        CPU.move_particles(R, t, *args, noise, sigma, out=(R.copy(), t[:, :2].copy()))
    tables = make_tables(5, bits=4)
    for step, seed in ((-1, 0), (0, -1)):
        with pytest.raises(ValueError, match=r"^LutNoise step and seed must be >= 0$"):
            CPU.move_particles(R, t, *args, LutNoise(tables, step, seed), sigma)
    CPU.move_particles(R, t, *args, LutNoise(tables, 0, 0), sigma)
    bad = LutNoise(tables._replace(perm=tables.perm[:, :8]), 1, 1)
    with pytest.raises(
        ValueError,
        match=r"^LutNoise tables need normal \(T,\) and perm \(6, T\) with T = 2\*\*bits$",
    ):
        CPU.move_particles(R, t, *args, bad, sigma)
    with pytest.raises(
        ValueError, match=r"^noise must have shape \(P, 6\) = \(4, 6\), got \(4, 5\)$"
    ):
        CPU.move_particles(R, t, *args, noise[:, :5], sigma)
    lk = VoxelHashMap(capacity=16).lookup()
    for pts in (np.zeros(3, np.float32), np.zeros((4, 2), np.float32)):
        with pytest.raises(
            ValueError,
            match=rf"^points must have shape \(N, 3\), got {re.escape(str(pts.shape))}$",
        ):
            CPU.score_particles(R, t, pts, lk)
    with pytest.raises(ValueError, match=r"^particles need R"):
        CPU.score_particles(R, t[:3], np.zeros((2, 3), np.float32), lk)


def test_cpu_transform_in_place_refuses_a_read_only_array():
    x = np.ones((4, 3), np.float32)
    x.setflags(write=False)
    with pytest.raises(
        ValueError,
        match=r"^out must be a writeable C-contiguous float32 array of shape \(4, 3\)$",
    ):
        CPU.transform_points(np.eye(4), x, out=x)


def test_reference_move_particles_returns_the_out_arrays():
    rng = np.random.default_rng(31)
    R, t = _particles(rng, 3)
    R_o, t_o = np.empty_like(R), np.empty_like(t)
    res = REF.move_particles(
        R, t, [0.1, 0, 0], [1, 0, 0], np.zeros((3, 6)), np.zeros(6), out=(R_o, t_o)
    )
    assert res[0] is R_o and res[1] is t_o


def test_morton_search_at_the_low_corner_of_the_range():
    """Points in the first cells of the 21-bit range (-10,485.76 m at 1 cm quanta): the query's 2x2x2 block includes
    cells at index -1 (skipped) and 0 on each axis, and the ones at 0 are searched: exact nearest neighbours."""
    rng = np.random.default_rng(32)
    lo = -(2**20) * 0.01
    pts = (lo + rng.uniform(0.0, 0.5, (300, 3))).astype(np.float32)
    m = MortonBVHMap(radius=0.3, sigma=0.1, quantum=0.01, dedup_level=0)
    m.merge(pts)
    lk = m.lookup()
    assert len(m) > 200 and np.any(lk.cell_codes == 0)
    stored = lk.points.astype(np.float64)
    I = np.eye(3)[None]
    for q in stored[:40] + rng.normal(0, 0.02, (40, 3)):
        d2 = min(np.min(np.sum((stored - q) ** 2, axis=1)), 0.3**2)
        got = CPU.score_particles(I, q[None], np.zeros((1, 3), np.float32), lk)[0]
        assert got == pytest.approx(-0.5 * d2 / 0.1**2, rel=1e-9, abs=1e-12)


def test_morton_search_finds_the_cell_whose_code_is_one():
    """Points in the first two cells along x of the 21-bit range: cell (1, 0, 0) has Morton code 1, the one code
    next to the cell cache's "empty" marker (-1); queries there, made first in a fresh kernel call, find their exact
    nearest neighbours in that cell (a cache whose empty entries read as code 1 would hand back an unset index)."""
    rng = np.random.default_rng(34)
    lo = -(2**20) * 0.01
    m = MortonBVHMap(radius=0.3, sigma=0.1, quantum=0.01, dedup_level=0)
    edge = 0.01 * 2**m.cell_level  # 0.64 m
    near = rng.uniform(0.0, 0.3, (100, 3))
    far = near + [edge + 0.3, 0.0, 0.0]  # x in [0.94, 1.24): cell 1
    m.merge((lo + np.concatenate([near, far])).astype(np.float32))
    lk = m.lookup()
    assert lk.cell_codes.tolist() == [0, 1]
    stored = lk.points.astype(np.float64)
    I = np.eye(3)[None]
    for q in lo + far[:20] + rng.normal(0, 0.02, (20, 3)):
        d2 = min(np.min(np.sum((stored - q) ** 2, axis=1)), 0.3**2)
        assert d2 < 0.01
        got = CPU.score_particles(I, q[None], np.zeros((1, 3), np.float32), lk)[0]
        assert got == pytest.approx(-0.5 * d2 / 0.1**2, rel=1e-9, abs=1e-12)


def test_morton_warm_start_from_the_last_stored_point():
    """Two particles at the same pose and a scan point whose nearest neighbour is the last stored point (in Morton
    order): the second particle warm-starts from that point alone and both score the same."""
    rng = np.random.default_rng(33)
    m = MortonBVHMap(radius=0.3, sigma=0.1, dedup_level=0)
    m.merge(rng.uniform(-1, 1, (200, 3)).astype(np.float32))
    last = m.lookup().points[-1]
    R, t = np.repeat(np.eye(3)[None], 2, axis=0), np.zeros((2, 3))
    s = CPU.score_particles(R, t, (last + 0.001).astype(np.float32)[None], m.lookup())
    assert s[0] == s[1] == pytest.approx(-0.5 * 3e-6 / 0.01, rel=1e-3)


# ------------------------------------------------------------------------------------------------------ sim1d
def test_sim1d_steps_checks_and_edge_values():
    """Each check of the 1D steps alone with its message, and the smallest valid values (one particle, ``n_sat``
    below 1); step 6 adds ``sigma n`` (not subtracts), also for ``sigma = 1``; resampling's default ESS fraction is
    one half."""
    from slamlib.sim1d import steps

    grid = steps.OccupancyGrid1D.empty(-2.0, 2.0, 0.05)
    with pytest.raises(ValueError, match=r"^sigma must be positive, got 0.0$"):
        steps.likelihood_field(grid, 0.0)
    with pytest.raises(ValueError, match=r"^n_sat must be positive, got 0.0$"):
        steps.likelihood_field(grid, 0.1, 0.0)
    assert steps.likelihood_field(grid, 0.1, 0.5).shape == grid.counts.shape
    x, lw = steps.initialise_particles(1, 2.0)
    assert x.tolist() == [2.0] and lw.tolist() == [0.0]
    assert steps.pick_best_particle(x, lw) == (2.0, 0)
    p = np.array([0.0, 1.0, 2.0])
    for sigma in (1.0, 0.3):
        want = p + sigma * np.random.default_rng(5).standard_normal(3)
        np.testing.assert_array_equal(
            steps.perturb_with_noise(p, sigma, np.random.default_rng(5)), want
        )
    with pytest.raises(ValueError, match=r"^sigma must be non-negative, got -1.0$"):
        steps.perturb_with_noise(p, -1.0, np.random.default_rng(5))
    with pytest.raises(
        ValueError,
        match=r"^log_weights must be a non-empty \(P,\) array, got shape \(1, 3\)$",
    ):
        steps.pick_best_particle(p, np.zeros((1, 3)))
    with pytest.raises(
        ValueError,
        match=r"^particles shape \(2,\) does not match log_weights shape \(3,\)$",
    ):
        steps.pick_best_particle(p[:2], np.zeros(3))
    with pytest.raises(
        ValueError,
        match=r"^log_weights shape \(3,\) does not match particles shape \(2,\)$",
    ):
        steps.resample_particles(p[:2], np.zeros(3), np.random.default_rng(5))
    # ESS of weights (0.8, 0.1, 0.1) is 1 / 0.66 = 1.52 >= 0.5 * 3: no resampling by default, but below 0.6 * 3
    lw3 = np.log([0.8, 0.1, 0.1])
    assert steps.resample_particles(p, lw3, np.random.default_rng(5))[2] is False
    assert (
        steps.resample_particles(p, lw3, np.random.default_rng(5), ess_fraction=0.6)[2]
        is True
    )


def test_reference_transform_is_float64_arithmetic_rounded_once():
    """The numpy reference of transform_points: float32 points, float64 arithmetic, one rounding to float32
    (float32 arithmetic differs by an ulp on about half the coordinates of a typical pose)."""
    from slamlib.geometry import make_pose, rpy_to_matrix
    from slamlib.kernels import reference

    rng = np.random.default_rng(11)
    pts = rng.uniform(-80, 80, (10_000, 3)).astype(np.float32)
    T = make_pose(
        rpy_to_matrix(np.array([0.01, -0.02, 1.3])), np.array([123.4, -56.7, 1.9])
    )
    exact = (pts.astype(np.float64) @ T[:3, :3].T + T[:3, 3]).astype(np.float32)
    np.testing.assert_array_equal(reference.transform_points(T, pts), exact)


def test_launch_runs_one_task_on_one_thread_and_restores_the_thread_count():
    """``kernels.cpu._launch(kernel, n, chunk, *args)`` calls ``kernel(*args, chunk)``: on one thread when
    ``n <= chunk`` (a single task), on the pool's threads otherwise, and leaves the thread count as it found it."""
    threads = numba.get_num_threads()
    seen = []

    def spy(a, chunk):
        seen.append((a, chunk, numba.get_num_threads()))
        return a + chunk

    assert cpu._launch(spy, 5, 5, 10) == 15
    assert numba.get_num_threads() == threads
    assert cpu._launch(spy, 6, 5, 20) == 25
    assert seen == [(10, 5, 1), (20, 5, threads)]
    assert numba.get_num_threads() == threads


def test_ceil_div_counts_the_tasks_that_cover_n_items():
    """``kernels.cpu._ceil_div(n, chunk) = ceil(n / chunk)``: the task count of every ``prange`` in the CPU backend."""
    for n, chunk in [
        (0, 4),
        (1, 4),
        (3, 4),
        (4, 4),
        (5, 4),
        (8, 4),
        (9, 4),
        (7, 1),
        (1, 1),
        (100, 64),
    ]:
        assert cpu._ceil_div(n, chunk) == -(-n // chunk), (n, chunk)


def test_move_particles_takes_float32_particles_and_returns_float64():
    """``move_particles`` converts ``R``, ``t`` to float64 before the kernel (its documented ``(P, 3, 3) f8`` result):
    float32 particles give the float64 result of the same poses, not a float32 one."""
    rng = np.random.default_rng(4)
    P = 5
    R = np.stack(
        [geometry.rpy_to_matrix(a) for a in rng.uniform(-0.5, 0.5, (P, 3))]
    ).astype(np.float32)
    t = rng.normal(size=(P, 3)).astype(np.float32)
    noise = rng.normal(size=(P, 6))
    sigma = np.array([0.1, 0.2, 0.05, 0.01, 0.02, 0.03])
    args = ([0.01, -0.02, 0.03], [1.0, 0.1, 0.0], noise, sigma)
    R_new, t_new = cpu.move_particles(R, t, *args)
    R_ref, t_ref = cpu.move_particles(R.astype(np.float64), t.astype(np.float64), *args)
    assert R_new.dtype == t_new.dtype == np.float64
    np.testing.assert_array_equal(R_new, R_ref)
    np.testing.assert_array_equal(t_new, t_ref)


@pytest.mark.parametrize("which", ["rpy_delta", "trans_delta", "sigma"])
def test_move_particles_names_a_vector_of_the_wrong_length(which):
    """``move_particles`` needs 3 (``rpy_delta``, ``trans_delta``) and 6 (``sigma``) values: one more is an error
    naming the argument, not silently ignored (the kernels read only the first 3 or 6)."""
    P = 2
    R, t = np.tile(np.eye(3), (P, 1, 1)), np.zeros((P, 3))
    args = {"rpy_delta": np.zeros(3), "trans_delta": np.zeros(3), "sigma": np.ones(6)}
    args[which] = np.zeros(args[which].size + 1)
    with pytest.raises(
        ValueError, match=rf"{which} must have {args[which].size - 1} values"
    ):
        cpu.move_particles(
            R, t, args["rpy_delta"], args["trans_delta"], np.zeros((P, 6)), args["sigma"]
        )


def test_systematic_resample_normalises_float32_weights_in_float64():
    """``systematic_resample`` accumulates the weights in float64 whatever their dtype: on a pointer that falls
    between the float32 and the float64 cumulative sums of the same weights, float32 weights pick the index the
    reference picks from their float64 values."""
    P = 10
    w32 = np.full(P, 0.1, np.float32)
    w64 = w32.astype(np.float64)
    c32 = np.cumsum(w32 / w32.sum())
    c64 = np.cumsum(w64 / w64.sum())
    u0s = np.linspace(0.0, 0.999, 99901)
    pointers = (u0s[:, None] + np.arange(P)) / P
    differ = np.any(
        np.searchsorted(c32, pointers, side="right")
        != np.searchsorted(c64, pointers, side="right"),
        1,
    )
    assert differ.any(), (
        "no pointer separates the float32 and float64 sums: the test needs another weight"
    )
    u0 = u0s[np.argmax(differ)]
    np.testing.assert_array_equal(
        cpu.systematic_resample(w32, u0), reference.systematic_resample(w64, u0)
    )


def test_fill_kernel_built_afresh_draws_what_lut_normal_draws():
    """``noise._make_fill(lut_draw)`` (the ``prange`` kernel behind ``lut_normal_nb``, built once per process by
    ``numba_functions``) fills row ``i``, column ``k`` with draw ``k`` of thread ``i``: a fresh build (so that
    mutation runs see its body) gives :func:`slamlib.noise.lut_normal` bit for bit on every row of a 37 x 6 array."""
    from numba import njit

    from slamlib.noise import _make_fill, lut_normal, make_lut_functions, make_tables

    tables = make_tables(seed=3, bits=8)
    fill = _make_fill(make_lut_functions(njit(inline="always"))["lut_draw"])
    out = np.full((37, 6), np.nan, np.float32)
    fill(tables.normal, tables.perm, np.int64(tables.bits), np.int64(4), np.int64(9), out)
    np.testing.assert_array_equal(out, lut_normal(tables, 37, 4, 9))
