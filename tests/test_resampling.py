"""Tests for slamlib.resampling: invariants (hypothesis), unbiasedness (fixed-seed statistics), bad input."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from slamlib.resampling import (
    effective_sample_size,
    multinomial_resample,
    normalise_log_weights,
    resample_indexes,
    residual_resample,
    stratified_resample,
    systematic_resample,
    uniform_log_weights,
    weights_from_log_weights,
)

weights_strategy = arrays(
    np.float64,
    st.integers(1, 60),
    elements=st.floats(0.0, 1e3, allow_nan=False, allow_infinity=False),
).filter(lambda w: w.sum() > 0)
u0_strategy = st.floats(0.0, 1.0, exclude_max=True)

RNG_SAMPLERS = [stratified_resample, multinomial_resample, residual_resample]


def _all_samplers(u0=0.5, seed=0):
    """(name, callable(weights)) pairs covering the four samplers."""
    return [("systematic", lambda w: systematic_resample(w, u0))] + [
        (f.__name__, lambda w, f=f: f(w, np.random.default_rng(seed)))
        for f in RNG_SAMPLERS
    ]


@settings(max_examples=60, deadline=None)
@given(w=weights_strategy, u0=u0_strategy, seed=st.integers(0, 2**32 - 1))
def test_count_preserved_and_indexes_in_range(w, u0, seed):
    for name, sampler in _all_samplers(u0, seed):
        idx = sampler(w)
        assert idx.shape == w.shape, name
        assert idx.dtype == np.int64, name
        assert idx.min() >= 0 and idx.max() < w.size, name
        assert np.all(w[idx] > 0), f"{name} picked a zero-weight particle"


@settings(max_examples=100, deadline=None)
@given(w=weights_strategy, u0=u0_strategy)
def test_systematic_gives_floor_or_ceil_copies(w, u0):
    p = w.size
    expected = p * w / w.sum()
    counts = np.bincount(systematic_resample(w, u0), minlength=p)
    # one pointer per 1/P interval: copies within floor/ceil of P w_i (tiny slack for round-off at boundaries)
    assert np.all(counts >= np.floor(expected - 1e-9))
    assert np.all(counts <= np.ceil(expected + 1e-9))


@settings(max_examples=60, deadline=None)
@given(w=weights_strategy, seed=st.integers(0, 2**32 - 1))
def test_residual_keeps_the_deterministic_copies(w, seed):
    expected = w.size * w / w.sum()
    counts = np.bincount(
        residual_resample(w, np.random.default_rng(seed)), minlength=w.size
    )
    assert np.all(counts >= np.floor(expected - 1e-9))


def test_systematic_matches_the_low_variance_sampler_by_hand():
    # Probabilistic Robotics Table 4.4 written out as a loop: r = u0 / P, U = r + k / P, advance while U > c.
    w = np.array([0.1, 0.4, 0.05, 0.25, 0.2])
    for u0 in (0.0, 0.13, 0.5, 0.99):
        p = w.size
        c, i, want = w[0], 0, []
        for k in range(p):
            u = (u0 + k) / p
            while u >= c:
                i += 1
                c += w[i]
            want.append(i)
        np.testing.assert_array_equal(systematic_resample(w, u0), want)
        # scale-free
        np.testing.assert_array_equal(systematic_resample(w * 13.0, u0), want)


@pytest.mark.parametrize(
    "name",
    ["systematic", "stratified_resample", "multinomial_resample", "residual_resample"],
)
def test_unbiased_and_higher_weight_never_fewer_copies_in_expectation(name):
    """Mean copies over many fixed-seed runs approach P w_i and are ordered like the weights."""
    rng = np.random.default_rng(1234)
    w = np.array([0.02, 0.05, 0.08, 0.13, 0.22, 0.5])
    p, runs = w.size, 3000
    total = np.zeros(p)
    for _ in range(runs):
        if name == "systematic":
            idx = systematic_resample(w, rng.random())
        else:
            idx = globals()[name](w, rng)
        total += np.bincount(idx, minlength=p)
    mean = total / runs
    # standard error of a mean count is at most sqrt(P w (1 - w) / runs) < 0.03; allow 5 of them
    np.testing.assert_allclose(mean, p * w, atol=0.15)
    assert np.all(np.diff(mean) > 0), mean


@settings(max_examples=100, deadline=None)
@given(w=weights_strategy)
def test_effective_sample_size_bounds(w):
    ess = effective_sample_size(w)
    assert 1.0 <= ess <= w.size
    # never more than the particles that carry weight
    assert ess <= np.count_nonzero(w) + 1e-9


def test_effective_sample_size_extremes():
    assert effective_sample_size(np.ones(50)) == pytest.approx(50.0)
    assert effective_sample_size(np.eye(1, 50, 7).ravel()) == pytest.approx(1.0)
    assert effective_sample_size([0.5, 0.5, 0.0, 0.0]) == pytest.approx(2.0)


@settings(max_examples=100, deadline=None)
@given(
    lw=arrays(
        np.float64,
        st.integers(1, 40),
        elements=st.one_of(st.floats(-1e300, 1e300), st.just(-np.inf)),
    ).filter(lambda a: np.isfinite(a).any())
)
def test_weights_from_log_weights_sums_to_one(lw):
    w = weights_from_log_weights(lw)
    assert np.all(np.isfinite(w)) and np.all(w >= 0)
    assert w.sum() == pytest.approx(1.0)
    assert np.all(w[np.isneginf(lw)] == 0)
    assert w[np.argmax(lw)] == w.max()


def test_weights_from_log_weights_matches_softmax_and_survives_huge_values():
    lw = np.array([0.0, np.log(2.0), np.log(5.0)])
    np.testing.assert_allclose(weights_from_log_weights(lw), [1 / 8, 2 / 8, 5 / 8])
    np.testing.assert_allclose(weights_from_log_weights(lw + 1e6), [1 / 8, 2 / 8, 5 / 8])
    np.testing.assert_allclose(weights_from_log_weights(lw - 1e6), [1 / 8, 2 / 8, 5 / 8])
    np.testing.assert_allclose(
        weights_from_log_weights([-np.inf, 3.0, -np.inf]), [0, 1, 0]
    )


@pytest.mark.parametrize(
    "bad, message",
    [
        ([-np.inf, -np.inf], "all log_weights are -inf"),
        ([0.0, np.nan], "NaN"),
        ([0.0, np.inf], r"\+inf"),
        ([], "non-empty"),
    ],
)
def test_log_weight_functions_reject_bad_input(bad, message):
    for fn in (weights_from_log_weights, normalise_log_weights):
        with pytest.raises(ValueError, match=message):
            fn(np.asarray(bad, dtype=float))


@settings(max_examples=100, deadline=None)
@given(lw=arrays(np.float64, st.integers(1, 40), elements=st.floats(-1e6, 1e6)))
def test_normalise_log_weights_returns_log_weights_of_the_same_distribution(lw):
    out = normalise_log_weights(lw)
    assert np.exp(out).sum() == pytest.approx(1.0)
    np.testing.assert_allclose(
        np.exp(out), weights_from_log_weights(lw), rtol=1e-9, atol=1e-300
    )
    # a shift, nothing else
    np.testing.assert_allclose(out - out.max(), lw - lw.max(), rtol=0, atol=1e-6)


def test_resample_indexes_follows_the_ess_rule_and_draws_only_when_due():
    P = 100
    flat = uniform_log_weights(P)
    assert np.allclose(np.exp(flat).sum(), 1.0)
    rng = np.random.default_rng(0)
    state = rng.bit_generator.state
    assert resample_indexes(flat, rng, ess_fraction=0.5) is None  # ESS = P: nothing to do
    assert rng.bit_generator.state == state  # and nothing drawn
    peaked = np.log(np.r_[np.full(10, 1.0), np.full(P - 10, 1e-6)])  # ESS ~ 10 < 50
    idx = resample_indexes(peaked, np.random.default_rng(1), ess_fraction=0.5)
    assert idx.shape == (P,) and set(np.unique(idx)) <= set(range(10))
    u0 = np.random.default_rng(1).random()
    np.testing.assert_array_equal(
        idx, systematic_resample(weights_from_log_weights(peaked), u0)
    )
    # None: always
    assert resample_indexes(flat, np.random.default_rng(2), ess_fraction=None) is not None
    calls = []
    resample_indexes(
        peaked,
        np.random.default_rng(3),
        0.5,
        sampler=lambda w, u: calls.append(u) or np.arange(P),
    )
    assert len(calls) == 1 and 0 <= calls[0] < 1


@pytest.mark.parametrize(
    "bad, message",
    [
        ([0.5, -0.1, 0.6], "non-negative"),
        ([0.5, np.nan], "NaN"),
        ([0.5, np.inf], "inf"),
        ([0.0, 0.0], "sum to zero"),
        ([], "empty"),
        ([[0.5, 0.5]], "1-D"),
    ],
)
def test_samplers_reject_bad_weights(bad, message):
    w = np.asarray(bad, dtype=float)
    with pytest.raises(ValueError, match=message):
        systematic_resample(w, 0.5)
    for f in RNG_SAMPLERS:
        with pytest.raises(ValueError, match=message):
            f(w, np.random.default_rng(0))
    with pytest.raises(ValueError, match=message):
        effective_sample_size(w)


def test_bad_offset_and_rng():
    for u0 in (-0.1, 1.0, np.nan):
        with pytest.raises(ValueError, match="u0"):
            systematic_resample([0.5, 0.5], u0)
    with pytest.raises(TypeError, match="Generator"):
        stratified_resample([0.5, 0.5], 3)


def test_seeded_samplers_are_deterministic():
    w = np.random.default_rng(5).random(40)
    for f in RNG_SAMPLERS:
        a = f(w, np.random.default_rng(11))
        b = f(w, np.random.default_rng(11))
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("p", [1, 3, 7, 49, 1000])
def test_offset_just_below_one_stays_in_range(p):
    """(u0 + P - 1) / P rounds to exactly 1.0 for u0 = 1 - 2**-52 and some P; the index must stay below P."""
    u0 = np.nextafter(1.0, 0.0)
    for w in (np.ones(p), np.r_[np.ones(p - 1), 0.0] if p > 1 else np.ones(1)):
        idx = systematic_resample(w, u0)
        assert idx.max() < p and np.all(w[idx] > 0)


def test_trailing_zero_weights_are_never_picked():
    w = np.array([0.3, 0.7, 0.0, 0.0])
    for u0 in (0.0, 0.5, np.nextafter(1.0, 0.0)):
        assert set(systematic_resample(w, u0)) <= {0, 1}
    rng = np.random.default_rng(0)
    for f in RNG_SAMPLERS:
        assert set(f(np.tile(w, 50), rng) % 4) <= {0, 1}


def test_effective_sample_size_on_uneven_weights_is_one_over_sum_of_squares():
    # 1 / sum w^2 pinned on weights where it differs from 1 / max w (2.0) and from the count of non-zeros (3)
    assert effective_sample_size([0.5, 0.25, 0.25]) == pytest.approx(1 / 0.375, rel=1e-12)
    # normalised first
    assert effective_sample_size([2.0, 1.0, 1.0]) == pytest.approx(8 / 3, rel=1e-12)
    w = np.array([0.4, 0.3, 0.2, 0.1])
    assert effective_sample_size(w) == pytest.approx(1 / 0.3, rel=1e-12)
    # the resampling decision follows it: ESS = 3.33 is above 0.8 * 4 = 3.2 (1 / max w = 2.5 would be below)
    assert resample_indexes(np.log(w), np.random.default_rng(0), ess_fraction=0.8) is None
    assert (
        resample_indexes(np.log(w), np.random.default_rng(0), ess_fraction=0.85)
        is not None
    )


def test_stratified_and_multinomial_pointers_by_value():
    """Stratified: one uniform per stratum, ``u_k = (k + U_k) / P``; multinomial: ``u_k = U_k``; index = first
    ``j`` with ``u_k < c_j`` (pinned against the draws of a same-seeded generator, not just their statistics)."""
    w = np.array([0.1, 0.0, 0.35, 0.05, 0.5])
    c = np.cumsum(w)
    for seed in range(5):
        u = np.random.default_rng(seed).random(w.size)
        want = np.searchsorted(c, (np.arange(w.size) + u) / w.size, side="right")
        np.testing.assert_array_equal(
            stratified_resample(w, np.random.default_rng(seed)), want
        )
        np.testing.assert_array_equal(
            multinomial_resample(w, np.random.default_rng(seed)),
            np.searchsorted(c, u, side="right"),
        )


def test_residual_draws_the_remainder_from_the_residual_weights():
    """P = 2, w = (0.7, 0.3): one deterministic copy of particle 0, then one draw from the residuals
    (0.4, 0.6) / 1, so the extra index is 1 exactly when the draw u >= 0.4 (from w itself it would need u >= 0.7)."""
    seen = set()
    for seed in range(30):
        u = np.random.default_rng(seed).random()
        idx = residual_resample([0.7, 0.3], np.random.default_rng(seed))
        assert idx.dtype == np.int64
        np.testing.assert_array_equal(idx, [0, int(u >= 0.4)])
        seen.add((u >= 0.4, u >= 0.7))
    # a draw in [0.4, 0.7) was tried: it tells the two rules apart
    assert (
        True,
        False,
    ) in seen
    # no draw
    np.testing.assert_array_equal(
        residual_resample([0.5, 0.5], np.random.default_rng(0)), [0, 1]
    )


def test_resample_indexes_default_threshold_is_half_the_particles():
    w = np.array([0.4, 0.3, 0.2, 0.1])  # ESS = 3.33 >= 0.5 * 4: no resampling by default
    assert resample_indexes(np.log(w), np.random.default_rng(0)) is None
    w = np.array([0.85, 0.05, 0.05, 0.05])  # ESS = 1.37 < 2
    idx = resample_indexes(np.log(w), np.random.default_rng(0))
    np.testing.assert_array_equal(
        idx, systematic_resample(w, np.random.default_rng(0).random())
    )


def test_bad_rng_message_names_the_type_given():
    with pytest.raises(TypeError, match="RandomState"):
        multinomial_resample([0.5, 0.5], np.random.RandomState(0))


def test_weight_checks_name_the_problem_exactly():
    cases = [
        ([], r"^weights is empty: need at least one particle$"),
        (
            [0.5, np.inf],
            r"^weights contain inf at index 1; pass log-weights through weights_from_log_weights first$",
        ),
        (
            [0.0, -0.1, 0.5],
            r"^weights must be non-negative, got (np.float64\()?-0.1\)? at index 1$",
        ),
        ([0.0, 0.0], r"^weights sum to zero: every particle has zero weight$"),
    ]
    for bad, message in cases:
        with pytest.raises(ValueError, match=message):
            effective_sample_size(np.asarray(bad, dtype=float))
    with pytest.raises(
        ValueError, match=r"^all log_weights are -inf: every particle has zero likelihood"
    ):
        weights_from_log_weights([-np.inf, -np.inf])


def test_weights_are_computed_in_float64_and_extremes_raise_no_warning():
    import warnings

    w32 = np.array([0.1, 0.2, 0.7], np.float32)
    w64 = w32.astype(np.float64)
    assert (
        effective_sample_size(w32)
        == effective_sample_size(w64)
        == 1.0 / np.sum((w64 / w64.sum()) ** 2)
    )
    lw32 = np.log(w32)
    assert weights_from_log_weights(lw32).dtype == np.float64
    np.testing.assert_array_equal(
        weights_from_log_weights(lw32), weights_from_log_weights(lw32.astype(np.float64))
    )
    np.testing.assert_array_equal(
        normalise_log_weights(lw32), normalise_log_weights(lw32.astype(np.float64))
    )
    with warnings.catch_warnings():
        # -1e308 - 1e308 overflows to -inf: expected, silenced
        warnings.simplefilter("error")
        np.testing.assert_array_equal(
            weights_from_log_weights([-1e308, 1e308]), [0.0, 1.0]
        )
        np.testing.assert_array_equal(
            normalise_log_weights([-1e308, 1e308]), [-np.inf, 0.0]
        )
        # their sum overflows: handled, silently
        assert effective_sample_size([1e308, 1e308]) == 2.0


def test_resample_indexes_threshold_is_strict_and_indexes_are_int64():
    flat = uniform_log_weights(4)  # ESS = 4 exactly: not below 1.0 * 4
    assert resample_indexes(flat, np.random.default_rng(0), ess_fraction=1.0) is None
    idx = resample_indexes(
        flat,
        np.random.default_rng(0),
        ess_fraction=None,
        sampler=lambda w, u: np.arange(w.size, dtype=np.int32),
    )
    assert idx.dtype == np.int64


# ------------------------------------------------------------------ huge finite weights
@pytest.mark.parametrize(
    "name", ["systematic", "stratified", "multinomial", "residual", "ess"]
)
def test_resampling_huge_finite_weights(name):
    from slamlib import resampling as rs

    w, rng = np.array([1e308, 1e308]), np.random.default_rng(0)
    if name == "ess":
        assert rs.effective_sample_size(w) == 2.0
        return
    fn = {
        "systematic": lambda: rs.systematic_resample(w, 0.3),
        "stratified": lambda: rs.stratified_resample(w, rng),
        "multinomial": lambda: rs.multinomial_resample(w, rng),
        "residual": lambda: rs.residual_resample(w, rng),
    }
    assert set(fn[name]().tolist()) <= {0, 1}
