"""Lookup-table Gaussian noise (slamlib.noise): tables, equality of the numpy / Numba / CUDA builds, moments,
and the absence of correlation across frames and threads (and its presence in the seed project's variant)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slamlib import noise as N


@pytest.fixture(scope="module")
def tables():
    return N.make_tables(seed=2017)


def _check_uncorrelated(series, limit):
    """The property the filter needs: lag-1 correlation over frames (axis 0) and threads (axis 1) below limit."""
    r_steps = N.lag_correlation(series, 1, axis=0)
    r_threads = N.lag_correlation(series, 1, axis=1)
    assert abs(r_steps) < limit, f"consecutive frames correlated: r = {r_steps:.3f}"
    assert abs(r_threads) < limit, f"neighbouring threads correlated: r = {r_threads:.3f}"


def test_tables_are_normal_quantiles_and_permutations(tables):
    T = 1 << tables.bits
    assert tables.normal.shape == (T,) and tables.perm.shape == (6, T)
    assert abs(tables.normal.astype(np.float64).mean()) < 1e-6
    assert abs(tables.normal.astype(np.float64).var() - 1.0) < 1e-5
    for k in range(6):
        assert np.array_equal(np.sort(tables.perm[k]), np.arange(T))
    assert not np.array_equal(tables.perm[0], tables.perm[1])
    drawn = N.make_tables(seed=1, bits=10, exact=False)
    assert drawn.normal.shape == (1024,) and abs(drawn.normal.mean()) < 0.15
    with pytest.raises(ValueError):
        N.make_tables(seed=1, bits=17)


def test_numpy_numba_and_cuda_builds_agree_bit_for_bit(tables):
    from slamlib.kernels import cuda as kc

    a = N.lut_normal(tables, 257, step=9, seed=4)
    assert np.array_equal(a, N.lut_normal_nb(tables, 257, step=9, seed=4))
    assert np.array_equal(
        a, kc.lut_normal_device(N.LutNoise(tables, 9, 4), 257).copy_to_host()
    )
    assert np.array_equal(a, N.LutNoise(tables, 9, 4).draw(257))


@settings(max_examples=60, deadline=None)
@given(
    thread=st.integers(0, 2**32 - 1),
    step=st.integers(0, 2**32 - 1),
    seed=st.integers(0, 2**32 - 1),
    k=st.integers(0, 5),
)
def test_index_in_range_and_numba_matches_numpy(thread, step, seed, k):
    tables = N.make_tables(seed=0, bits=8)
    nb = N.numba_functions()
    i_np = int(N.lut_index(np.uint64(thread), step, seed, k, tables.perm, tables.bits))
    i_nb = int(
        nb["lut_index"](
            np.uint64(thread),
            np.uint64(step),
            np.uint64(seed),
            k,
            tables.perm,
            tables.bits,
        )
    )
    assert i_np == i_nb and 0 <= i_np < 256
    assert int(
        nb["counter_hash"](np.uint64(thread), np.uint64(step), np.uint64(seed))
    ) == int(N.counter_hash(np.uint64(thread), step, seed))


def test_fmix32_is_a_bijection_on_a_range():
    h = N.fmix32(np.arange(1 << 16, dtype=np.uint64))
    assert np.unique(h).size == 1 << 16 and h.max() < 2**32


def test_moments_and_ks(tables):
    s = N.noise_statistics(N.lut_normal(tables, 20000, step=3, seed=1))
    assert abs(s["mean"]) < 0.02
    assert abs(s["var"] - 1.0) < 0.03
    assert abs(s["kurtosis"] - 3.0) < 0.1
    assert s["ks"] < 0.01


def test_components_uncorrelated(tables):
    c = np.corrcoef(N.lut_normal(tables, 20000, step=0, seed=5).T)
    off = c[~np.eye(6, dtype=bool)]
    assert np.max(np.abs(off)) < 0.04


def test_noise_changes_every_frame_and_across_threads(tables):
    # (steps, threads)
    series = np.stack(
        [N.lut_normal(tables, 256, step=s, seed=7)[:, 0] for s in range(200)]
    )
    _check_uncorrelated(series, 0.05)
    one = np.array(
        [N.lut_normal(tables, 1, step=s, seed=7, start=3)[0, 3] for s in range(2000)]
    )
    # one particle over 2000 frames (sd of r ~ 0.022)
    assert abs(N.lag_correlation(one, 1)) < 0.07
    wide = N.lut_normal(tables, 4096, step=1, seed=7)[:, 0]
    # no period of 256 threads
    assert abs(np.corrcoef(wide[:-256], wide[256:])[0, 1]) < 0.05
    # seeds differ
    assert not np.array_equal(
        N.lut_normal(tables, 64, 1, 7), N.lut_normal(tables, 64, 1, 8)
    )


def test_particles_rarely_share_their_six_draws(tables):
    # Two particles share all six draws only when 2 log2(T) = 24 hash bits agree: P^2 / 2 / 2^24 = 0.75 pairs
    # expected for P = 5000 (birthday bound); the seed variant has only 256 distinct rows.
    dup = [
        5000 - np.unique(N.lut_normal(tables, 5000, step=s, seed=3), axis=0).shape[0]
        for s in range(10)
    ]
    assert np.mean(dup) < 3.0
    t8 = N.make_tables(seed=2017, bits=N.SEED_BITS)
    assert np.unique(N.seed_lut_normal(t8, 5000), axis=0).shape[0] == 256


def test_seed_variant_fails_the_same_check():
    t8 = N.make_tables(seed=2017, bits=N.SEED_BITS)
    series = np.stack([N.seed_lut_normal(t8, 512, step=s)[:, 0] for s in range(20)])
    # same noise at every frame
    assert N.lag_correlation(series, 1, axis=0) == pytest.approx(1.0)
    assert np.array_equal(series[0, :256], series[0, 256:])  # repeats every 256 threads
    with pytest.raises(AssertionError, match="consecutive frames correlated"):
        _check_uncorrelated(series, 0.05)


def test_statistics_helpers_on_known_input():
    rng = np.random.default_rng(0)
    s = N.noise_statistics(rng.standard_normal(50000))
    assert abs(s["kurtosis"] - 3) < 0.1 and s["ks"] < 0.01
    assert N.noise_statistics(rng.random(50000))["ks"] > 0.1  # uniform is not normal
    x = np.arange(100.0)
    assert N.lag_correlation(x, 1) == pytest.approx(1.0)
    with pytest.raises(ValueError):
        N.lut_normal(N.make_tables(0, bits=8), 4, step=-1, seed=0)


@settings(max_examples=40, deadline=None)
@given(
    thread=st.integers(0, 2**32 - 1),
    step=st.integers(0, 2**32 - 1),
    seed=st.integers(0, 2**32 - 1),
)
def test_hash_once_then_six_indexes_is_lut_index(thread, step, seed):
    """The pieces a fused kernel uses (frame_key once per frame, thread_hash once per particle, hash_index per
    component) give lut_index's values, in numpy and in Numba, and frame_key is the documented nesting."""
    tables = N.make_tables(seed=3, bits=10)
    nb = N.numba_functions()
    key = N.frame_key(np.uint64(step), np.uint64(seed))
    assert int(key) == int(
        N.fmix32(np.uint64(step) ^ N.fmix32(np.uint64(seed) ^ np.uint64(0x9E3779B9)))
    )
    assert int(nb["frame_key"](np.uint64(step), np.uint64(seed))) == int(key)
    h = N._NP["thread_hash"](np.uint64(thread), key)
    assert int(h) == int(N.counter_hash(np.uint64(thread), step, seed))
    for k in range(6):
        i = int(N._NP["hash_index"](h, k, tables.perm, tables.bits))
        assert i == int(
            N.lut_index(np.uint64(thread), step, seed, k, tables.perm, tables.bits)
        )
        assert i == int(
            nb["hash_index"](
                nb["thread_hash"](np.uint64(thread), key), k, tables.perm, tables.bits
            )
        )


# ------------------------------------------------------------------ the formulas, value by value
def _fmix32_ref(h):
    """MurmurHash3's fmix32 on Python ints (Appleby)."""
    h &= 0xFFFFFFFF
    h ^= h >> 16
    h = (h * 0x85EBCA6B) & 0xFFFFFFFF
    h ^= h >> 13
    h = (h * 0xC2B2AE35) & 0xFFFFFFFF
    h ^= h >> 16
    return h


def _lut_index_ref(thread, step, seed, k, perm, bits):
    key = _fmix32_ref((step & 0xFFFFFFFF) ^ _fmix32_ref((seed & 0xFFFFFFFF) ^ 0x9E3779B9))
    h = _fmix32_ref((thread & 0xFFFFFFFF) ^ key)
    mask = (1 << bits) - 1
    return int(perm[k, h & mask]) ^ ((h >> (32 - bits)) & mask)


def test_fresh_lut_functions_match_a_plain_integer_reference():
    # make_lut_functions() is also run at import; calling it here tests a fresh build of every function
    fns = N.make_lut_functions()
    assert int(fns["fmix32"](np.uint64(1))) == _fmix32_ref(1) == 0x514E28B7
    assert int(fns["fmix32"](np.uint64(0))) == 0
    tables = N.make_tables(seed=11, bits=7)
    rng = np.random.default_rng(4)
    for thread, step, seed in rng.integers(
        0, 2**33, size=(30, 3)
    ):  # beyond 2**32: inputs are taken mod 2**32
        thread, step, seed = int(thread), int(step), int(seed)
        key = fns["frame_key"](np.uint64(step), np.uint64(seed))
        assert int(key) == _fmix32_ref(
            (step & 0xFFFFFFFF) ^ _fmix32_ref((seed & 0xFFFFFFFF) ^ 0x9E3779B9)
        )
        h = fns["thread_hash"](np.uint64(thread), key)
        assert int(h) == int(
            fns["counter_hash"](np.uint64(thread), np.uint64(step), np.uint64(seed))
        )
        for k in range(6):
            ref = _lut_index_ref(thread, step, seed, k, tables.perm, 7)
            assert 0 <= ref < 128
            assert int(fns["hash_index"](h, k, tables.perm, 7)) == ref
            assert (
                int(
                    fns["lut_index"](
                        np.uint64(thread),
                        np.uint64(step),
                        np.uint64(seed),
                        k,
                        tables.perm,
                        7,
                    )
                )
                == ref
            )
            assert (
                fns["lut_draw"](
                    np.uint64(thread),
                    np.uint64(step),
                    np.uint64(seed),
                    k,
                    tables.normal,
                    tables.perm,
                    7,
                )
                == tables.normal[ref]
            )


def test_make_tables_values_and_bounds():
    from scipy.stats import norm

    t = N.make_tables(seed=5, bits=4)
    q = norm.ppf((np.arange(16) + 0.5) / 16)
    q = (q - q.mean()) / np.sqrt(np.mean((q - q.mean()) ** 2))
    np.testing.assert_array_equal(t.normal, q.astype(np.float32))
    assert (
        t.normal.dtype == np.float32
        and t.perm.dtype == np.int32
        and t.bits == 4
        and type(t.bits) is int
    )
    rng = np.random.default_rng(5)
    np.testing.assert_array_equal(t.perm, [rng.permutation(16) for _ in range(6)])
    d = N.make_tables(seed=5, bits=4, exact=False)
    rng = np.random.default_rng(5)
    np.testing.assert_array_equal(d.normal, rng.standard_normal(16).astype(np.float32))
    np.testing.assert_array_equal(d.perm, [rng.permutation(16) for _ in range(6)])
    assert N.make_tables(0, bits=1).normal.shape == (2,)
    assert N.make_tables(0, bits=16).perm.shape == (6, 65536)
    assert N.make_tables(0, bits=4.0).bits == 4
    for bad in (0, 17, -1):
        with pytest.raises(ValueError, match=rf"bits must be in \[1, 16\], got {bad}"):
            N.make_tables(0, bits=bad)
    assert N.make_tables(0).bits == N.DEFAULT_BITS == 12


def test_lut_normal_rows_are_threads_from_start():
    t = N.make_tables(seed=2, bits=6)
    full = N.lut_normal(t, 12, step=4, seed=9)
    assert full.shape == (12, 6) and full.dtype == np.float32
    np.testing.assert_array_equal(N.lut_normal(t, 5, step=4, seed=9, start=3), full[3:8])
    for i in (0, 7):
        for k in range(6):
            assert full[i, k] == t.normal[_lut_index_ref(i, 4, 9, k, t.perm, 6)]
    assert N.lut_normal(t, 0, step=0, seed=0).shape == (0, 6)  # n = 0 is allowed
    np.testing.assert_array_equal(N.LutNoise(t, 4, 9).draw(12), full)


def test_check_rejects_negative_inputs_and_bad_tables():
    t = N.make_tables(seed=2, bits=6)
    for n, step, seed in [(-1, 0, 0), (1, -1, 0), (1, 0, -1)]:
        with pytest.raises(ValueError, match=r"n, step and seed must be >= 0, got "):
            N.lut_normal(t, n, step, seed)
    N.lut_normal(t, 0, 0, 0)
    bad_tables = (
        r"^tables.perm must be \(6, T\) and tables.normal \(T,\) with T = 2\*\*bits$"
    )
    with pytest.raises(ValueError, match=bad_tables):
        N.lut_normal(N.NoiseTables(t.normal, t.perm[:5], 6), 1, 0, 0)
    with pytest.raises(ValueError, match=bad_tables):
        N.lut_normal(N.NoiseTables(t.normal[:-1], t.perm, 6), 1, 0, 0)
    with pytest.raises(ValueError, match=bad_tables):
        N.lut_normal(N.NoiseTables(t.normal, t.perm, 5), 1, 0, 0)


def test_seed_variant_values_and_bounds():
    t9 = N.make_tables(seed=2, bits=9)
    s = N.seed_lut_normal(t9, 600, step=3, seed=1)
    assert s.shape == (600, 6) and s.dtype == np.float32
    for i in (0, 5, 300, 599):
        for k in range(6):
            assert s[i, k] == t9.normal[t9.perm[k, i & 0xFF]]
    np.testing.assert_array_equal(N.seed_lut_normal(t9, 10), s[:10])  # step, seed ignored
    N.seed_lut_normal(N.make_tables(0, bits=8), 3)
    with pytest.raises(
        ValueError,
        match=(
            r"^the seed variant needs tables with at least 256 entries \(bits >= 8\)$"
        ),
    ):
        N.seed_lut_normal(N.make_tables(0, bits=7), 3)


def test_noise_statistics_and_lag_correlation_values():
    from scipy import stats

    x = np.array([[0.0, 1.0], [2.0, 3.0]])
    s = N.noise_statistics(x)
    assert s["n"] == 4 and type(s["n"]) is int
    assert s["mean"] == 1.5 and s["var"] == 1.25
    assert s["kurtosis"] == pytest.approx(
        (2 * 1.5**4 + 2 * 0.5**4) / 4 / 1.25**2, rel=1e-15
    )
    assert s["ks"] == stats.kstest(x.ravel(), "norm").statistic
    assert N.noise_statistics([1, 2, 3, 4])["var"] == 1.25  # ints are read as float64
    alt = np.array([1.0, 2.0, 1.0, 2.0, 1.0, 2.0])
    assert N.lag_correlation(alt, 1) == pytest.approx(-1.0)
    assert N.lag_correlation(alt, 2) == pytest.approx(1.0)
    assert N.lag_correlation(alt) == pytest.approx(-1.0)  # lag 1 by default
    y = np.random.default_rng(1).normal(size=(7, 5))
    a, b = y[:-2].ravel(), y[2:].ravel()
    assert N.lag_correlation(y, 2, axis=0) == pytest.approx(
        np.corrcoef(a, b)[0, 1], rel=1e-12
    )
    a, b = y.T[:-1].ravel(), y.T[1:].ravel()  # axis 1 moved first, pooled over the rows
    assert N.lag_correlation(y, 1, axis=1) == pytest.approx(
        np.corrcoef(a, b)[0, 1], rel=1e-12
    )
    # no variance: NaN, not a division error
    assert np.isnan(N.lag_correlation(np.ones(5), 1))


def test_float32_and_degenerate_inputs_of_the_helpers():
    import warnings

    # float32 sums would round
    x32 = (1e4 + np.random.default_rng(6).normal(size=1001)).astype(np.float32)
    s32, s64 = N.noise_statistics(x32), N.noise_statistics(x32.astype(np.float64))
    for key in ("mean", "var", "kurtosis"):
        assert s32[key] == pytest.approx(s64[key], rel=1e-12, abs=0)
    y32 = x32.reshape(7, 143)
    assert N.lag_correlation(y32, 1, axis=1) == pytest.approx(
        N.lag_correlation(y32.astype(np.float64), 1, axis=1), rel=1e-12, abs=0
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # zero variance: NaN without computing 0/0
        assert np.isnan(N.lag_correlation(np.full(6, 2.0), 2))
    t = N.make_tables(seed=2, bits=6)
    assert N.lut_normal_nb(t, 5, step=1, seed=1).dtype == np.float32


# ------------------------------------------------------------------ the fill kernel, built afresh
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
