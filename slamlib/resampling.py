"""Resampling for particle filters: pure functions, weights in, indexes out.

Step 11 of the twelve steps (see ``CONTRIBUTING.md``), shared by the 1D, 2D and 3D filters. Every sampler takes
normalised (or at least non-negative, positive-sum) weights ``w`` of shape ``(P,)`` and returns ``(P,)`` int64
indexes into the particle array; the caller then does ``particles = particles[indexes]`` and resets the weights to
``1 / P``. The style follows filterpy's ``filterpy/monte_carlo/resampling.py`` (R. Labbe), with the randomness
passed in explicitly (a ``numpy.random.Generator``, or the single offset ``u0`` for the systematic sampler) so
that results are reproducible and the Numba CPU / CUDA kernels (``slamlib.kernels``) can be compared bit for bit.

All four samplers are *unbiased*: the expected number of copies of particle ``i`` is ``P w_i``. They differ in
the variance of that count (Douc & Cappe 2005; Hol, Schon & Gustafsson 2006):

=============  =====================================================  ==========================
sampler        copies ``N_i`` of particle ``i``                       variance of ``N_i``
=============  =====================================================  ==========================
multinomial    ``Multinomial(P, w)``                                  ``P w_i (1 - w_i)``
residual       ``floor(P w_i)`` + multinomial on the remainders       smaller
stratified     one uniform draw in each stratum ``[k/P, (k+1)/P)``    smaller
systematic     one shared offset ``u0`` for all strata                ``N_i`` in {floor, ceil}
=============  =====================================================  ==========================

References
----------
* S. Thrun, W. Burgard, D. Fox, *Probabilistic Robotics*, MIT Press 2005, Table 4.4 (low-variance sampler).
* G. Kitagawa, "Monte Carlo filter and smoother for non-Gaussian nonlinear state space models", JCGS 5(1), 1996.
* R. Douc, O. Cappe, "Comparison of resampling schemes for particle filtering", ISPA 2005.
* J. Liu, R. Chen, "Sequential Monte Carlo methods for dynamic systems", JASA 93(443), 1998 (residual).
* A. Kong, J. Liu, W. Wong, "Sequential imputations and Bayesian missing data problems", JASA 1994 (ESS).
* R. Labbe, filterpy, ``filterpy/monte_carlo/resampling.py`` (MIT licence).
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "DEFAULT_ESS_FRACTION",
    "effective_sample_size",
    "multinomial_resample",
    "normalise_log_weights",
    "resample_indexes",
    "residual_resample",
    "stratified_resample",
    "systematic_resample",
    "uniform_log_weights",
    "weights_from_log_weights",
]

#: Step 11's default threshold, in every dimension: resample when the effective sample size falls below half the
#: particles, ``ESS < 0.5 P`` (Doucet, Godsill & Andrieu 2000). The 1D and 2D filters and
#: :class:`slamlib.slam3d.config.FilterConfig` take their default from here.
DEFAULT_ESS_FRACTION = 0.5


def _check_weights(weights) -> np.ndarray:
    """Return ``weights`` as a float64 ``(P,)`` array normalised to sum 1, or raise ``ValueError``.

    Weights must be a non-empty 1-D array of finite, non-negative numbers with a positive sum; they need not
    already sum to 1 (they are divided by their sum).
    """
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim != 1:
        raise ValueError(
            f"weights must be a 1-D array of shape (P,), got shape {w.shape}"
        )
    if w.size == 0:
        raise ValueError("weights is empty: need at least one particle")
    if np.isnan(w).any():
        raise ValueError(
            f"weights contain NaN at index {int(np.flatnonzero(np.isnan(w))[0])}"
        )
    if not np.isfinite(w).all():
        raise ValueError(
            f"weights contain inf at index {int(np.flatnonzero(~np.isfinite(w))[0])}; "
            "pass log-weights through weights_from_log_weights first"
        )
    if (w < 0).any():
        i = int(np.flatnonzero(w < 0)[0])
        raise ValueError(f"weights must be non-negative, got {w[i]!r} at index {i}")
    with np.errstate(over="ignore"):  # an overflowing sum is handled just below
        total = w.sum()
    # finite weights near 1e308 overflow their sum: divide by the largest first
    if not np.isfinite(total):
        w = w / w.max()
        total = w.sum()
    if not total > 0:
        raise ValueError("weights sum to zero: every particle has zero weight")
    return w / total


_BELOW_ONE = np.nextafter(1.0, 0.0)


def _cumulative(w: np.ndarray) -> np.ndarray:
    """Cumulative sum of normalised weights, exactly 1 from the last positive weight on (guards round-off).

    With ``c[j] = 1`` for ``j >= last positive index`` and every pointer ``u < 1``, ``searchsorted(c, u, "right")``
    (the first ``j`` with ``u < c[j]``) is always a particle with positive weight.
    """
    c = np.cumsum(w)
    c[np.flatnonzero(w > 0)[-1] :] = 1.0
    return c


def _pointers(positions: np.ndarray) -> np.ndarray:
    """Clamp pointers to ``[0, 1)``: ``(u0 + P - 1) / P`` can round up to exactly 1.0 when ``u0`` is just below 1."""
    return np.minimum(positions, _BELOW_ONE)


def _check_rng(rng) -> np.random.Generator:
    if not isinstance(rng, np.random.Generator):
        raise TypeError(
            f"rng must be a numpy.random.Generator (np.random.default_rng(seed)), got {type(rng)!r}"
        )
    return rng


def systematic_resample(weights, u0: float) -> np.ndarray:
    """Systematic (low-variance) resampling: ``(P,)`` int64 indexes from one offset ``u0`` in ``[0, 1)``.

    With normalised weights ``w`` and ``c = cumsum(w)`` (``c[P-1] = 1`` exactly), the ``P`` pointers are

    .. math:: u_k = (u_0 + k) / P, \\qquad k = 0, \\dots, P-1,

    and index ``k`` is the first ``j`` with ``u_k < c_j`` (pointers that round to 1.0 for ``u0`` just below 1 are
    clamped below 1, so the index never reaches ``P``). This is Thrun et al.'s *low variance sampler*
    (Probabilistic Robotics, Table 4.4, with ``r = u0 / P``) and Kitagawa's systematic resampling. The pointers
    are evenly spaced by ``1/P``, so particle ``i``, owning the interval ``[c_{i-1}, c_i)`` of length ``w_i``,
    receives either ``floor(P w_i)`` or ``ceil(P w_i)`` copies; the output is sorted (copies are contiguous).

    Passing ``u0`` (instead of an rng) makes the result a deterministic function of its inputs, so that the Numba
    CPU and CUDA kernels (:mod:`slamlib.kernels`) can be compared with it exactly. Draw it with
    ``u0 = rng.random()``.

    Parameters
    ----------
    weights : array_like, shape (P,)
        Non-negative finite weights with positive sum (normalised here).
    u0 : float
        Offset in ``[0, 1)``.

    Returns
    -------
    indexes : ndarray of int64, shape (P,)
        Sorted indexes of the particles to keep, in ``[0, P)``.
    """
    w = _check_weights(weights)
    u0 = float(u0)
    if not 0.0 <= u0 < 1.0:
        raise ValueError(f"u0 must be in [0, 1), got {u0!r}")
    positions = _pointers((u0 + np.arange(w.size)) / w.size)
    return np.searchsorted(_cumulative(w), positions, side="right").astype(np.int64)


def stratified_resample(weights, rng: np.random.Generator) -> np.ndarray:
    """Stratified resampling: one independent uniform pointer in each stratum ``[k/P, (k+1)/P)``.

    .. math:: u_k = (k + U_k) / P, \\quad U_k \\sim \\mathcal{U}[0, 1) \\text{ i.i.d.}, \\qquad
              \\text{index}_k = \\min\\{ j : u_k < c_j \\}

    Unbiased (``E[N_i] = P w_i``) with lower variance than multinomial resampling (Kitagawa 1996; Douc & Cappe
    2005). Output sorted.

    Parameters
    ----------
    weights : array_like, shape (P,)
        Non-negative finite weights with positive sum.
    rng : numpy.random.Generator
        Source of the ``P`` uniforms.

    Returns
    -------
    indexes : ndarray of int64, shape (P,)
    """
    w = _check_weights(weights)
    rng = _check_rng(rng)
    positions = _pointers((rng.random(w.size) + np.arange(w.size)) / w.size)
    return np.searchsorted(_cumulative(w), positions, side="right").astype(np.int64)


def multinomial_resample(weights, rng: np.random.Generator) -> np.ndarray:
    """Multinomial resampling: ``P`` independent draws from the categorical distribution ``w``.

    .. math:: \\text{index}_k = \\min\\{ j : U_k < c_j \\}, \\quad U_k \\sim \\mathcal{U}[0, 1) \\text{ i.i.d.}

    The counts ``(N_1, ..., N_P)`` are ``Multinomial(P, w)``: unbiased but the noisiest of the four samplers
    (``Var N_i = P w_i (1 - w_i)``). Output is in draw order (not sorted).

    Parameters
    ----------
    weights : array_like, shape (P,)
        Non-negative finite weights with positive sum.
    rng : numpy.random.Generator

    Returns
    -------
    indexes : ndarray of int64, shape (P,)
    """
    w = _check_weights(weights)
    rng = _check_rng(rng)
    return np.searchsorted(_cumulative(w), rng.random(w.size), side="right").astype(
        np.int64
    )


def residual_resample(weights, rng: np.random.Generator) -> np.ndarray:
    """Residual resampling (Liu & Chen 1998): deterministic copies first, multinomial for the rest.

    Particle ``i`` first gets ``floor(P w_i)`` copies; the remaining ``R = P - sum_i floor(P w_i)`` slots are
    filled by multinomial draws from the residual weights ``r_i = (P w_i - floor(P w_i)) / R``. Unbiased, and
    every particle with ``P w_i >= 1`` is guaranteed to survive.

    Parameters
    ----------
    weights : array_like, shape (P,)
        Non-negative finite weights with positive sum.
    rng : numpy.random.Generator

    Returns
    -------
    indexes : ndarray of int64, shape (P,)
    """
    w = _check_weights(weights)
    rng = _check_rng(rng)
    n = w.size
    scaled = n * w
    copies = np.floor(scaled).astype(np.int64)
    indexes = np.repeat(np.arange(n, dtype=np.int64), copies)
    remaining = n - indexes.size
    if remaining > 0:
        residual = scaled - copies
        residual_sum = residual.sum()
        if residual_sum > 0:
            c = _cumulative(residual / residual_sum)
            extra = np.searchsorted(c, rng.random(remaining), side="right").astype(
                np.int64
            )
        # round-off only: floor(P w) summed to P - tiny; fill from the weights themselves
        else:
            extra = np.searchsorted(
                _cumulative(w), rng.random(remaining), side="right"
            ).astype(np.int64)
        indexes = np.concatenate([indexes, extra])
    return indexes


def effective_sample_size(weights) -> float:
    """Effective sample size (Kong, Liu & Wong 1994): ``ESS = 1 / sum_i w_i^2`` for normalised ``w``.

    ``ESS = P`` when all weights are equal and ``1`` when one particle holds all the weight, so
    ``1 <= ESS <= P``. A common rule resamples only when ``ESS < P / 2`` (Doucet, Godsill & Andrieu 2000).

    Parameters
    ----------
    weights : array_like, shape (P,)
        Non-negative finite weights with positive sum (normalised here).

    Returns
    -------
    float
    """
    w = _check_weights(weights)
    ess = 1.0 / float(np.sum(w * w))
    return min(max(ess, 1.0), float(w.size))  # clip round-off just outside [1, P]


def _check_log_weights(log_weights) -> np.ndarray:
    """``log_weights`` as a float64 ``(P,)`` array, or a ``ValueError`` naming what is wrong with it."""
    lw = np.asarray(log_weights, dtype=np.float64)
    if lw.ndim != 1 or lw.size == 0:
        raise ValueError(
            f"log_weights must be a non-empty 1-D array of shape (P,), got shape {lw.shape}"
        )
    if np.isnan(lw).any():
        raise ValueError(
            f"log_weights contain NaN at index {int(np.flatnonzero(np.isnan(lw))[0])}"
        )
    if np.isposinf(lw).any():
        raise ValueError(
            f"log_weights contain +inf at index {int(np.flatnonzero(np.isposinf(lw))[0])}"
        )
    if np.isneginf(lw.max()):
        raise ValueError(
            "all log_weights are -inf: every particle has zero likelihood (the filter diverged)"
        )
    return lw


def weights_from_log_weights(log_weights) -> np.ndarray:
    """Normalised weights from log-weights (log-likelihood scores) by the log-sum-exp trick.

    .. math:: w_i = \\exp(\\ell_i - m) / \\sum_j \\exp(\\ell_j - m), \\qquad m = \\max_j \\ell_j

    Subtracting the maximum keeps every exponent ``<= 0``, so huge scores (``1e300``) do not overflow and very
    negative ones underflow harmlessly to 0. Entries equal to ``-inf`` (impossible particles) get weight 0.

    Parameters
    ----------
    log_weights : array_like, shape (P,)
        Log-weights; may contain ``-inf`` but not NaN or ``+inf``, and not all ``-inf``.

    Returns
    -------
    weights : ndarray of float64, shape (P,)
        Non-negative, summing to 1.

    Raises
    ------
    ValueError
        On NaN or ``+inf`` entries, an empty or non-1-D array, or when every entry is ``-inf`` (no particle is
        possible: the filter has diverged).
    """
    lw = _check_log_weights(log_weights)
    # e.g. -1e308 - 1e308 = -inf, whose exp is the right 0
    with np.errstate(over="ignore"):
        w = np.exp(lw - lw.max())
    return w / w.sum()


def normalise_log_weights(log_weights) -> np.ndarray:
    """Log-weights shifted so that ``logsumexp = 0`` (their ``exp`` sums to 1): ``l_i - m - log sum_j exp(l_j - m)``.

    The filters keep their weights in this form at every dimension (products of per-point likelihoods underflow
    as plain numbers). Same input rules and errors as :func:`weights_from_log_weights`; ``-inf`` stays ``-inf``.
    """
    lw = _check_log_weights(log_weights)
    m = lw.max()
    with np.errstate(over="ignore"):
        return lw - (m + np.log(np.sum(np.exp(lw - m))))


def uniform_log_weights(n: int) -> np.ndarray:
    """``(n,)`` log-weights ``-log n``: every particle equally likely (after step 1 and after resampling)."""
    return np.full(int(n), -np.log(int(n)))


def resample_indexes(
    log_weights,
    rng: np.random.Generator,
    ess_fraction: float | None = DEFAULT_ESS_FRACTION,
    sampler=systematic_resample,
) -> np.ndarray | None:
    """Step 11's decision and draw, shared by every dimension: indexes of the survivors, or ``None`` (keep all).

    Resample when ``ess_fraction`` is ``None`` (always) or when the effective sample size
    ``ESS = 1 / sum w_i^2`` of ``w = exp(normalise_log_weights(log_weights))`` is below ``ess_fraction * P``
    (Doucet, Godsill & Andrieu 2000 use ``P / 2``). Then one offset ``u0 ~ U[0, 1)`` is drawn from ``rng`` and
    ``sampler(w, u0)`` returns the ``(P,)`` int64 indexes: :func:`systematic_resample` by default, or a compute
    backend's ``systematic_resample`` (same signature). Nothing is drawn from ``rng`` when no resampling is due.
    """
    w = weights_from_log_weights(log_weights)
    if (
        ess_fraction is not None
        and not effective_sample_size(w) < float(ess_fraction) * w.size
    ):
        return None
    return np.asarray(sampler(w, float(rng.random())), dtype=np.int64)
