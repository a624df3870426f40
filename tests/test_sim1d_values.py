"""Value tests for the 1D steps (slamlib.sim1d.steps), written for survivors of mutation testing.

Each test pins a formula or a documented behaviour on a tiny input whose expected value is worked out by hand (or by
brute force over all pairs of cells): the grid's extent and checks, the blur's truncation at 4 sigma and its window,
the likelihood field's local-maximum window and edges, the score outside the grid, the float64 results of steps fed
float32 (or wider) inputs, and extract_landmarks' peak test, centroid window, ``min_count`` and rounding.
Sharp blurs (``sigma`` of 0.02 cells: ``exp(-0.5 / 0.02^2)`` underflows to 0) make the blurred counts equal the
counts exactly, so plateaus and ties are exact.
"""

import re

import numpy as np
import pytest

from slamlib.sim1d import steps
from slamlib.sim1d.steps import OccupancyGrid1D
from slamlib.sim1d.world import Frame


def _grid(counts, origin=0.0, resolution=1.0):
    return OccupancyGrid1D(
        origin=origin, resolution=resolution, counts=np.asarray(counts, dtype=np.int64)
    )


def _field_by_definition(counts, s_cells, n_sat):
    """``B_i = sum_c n_c exp(-(i - c)^2 / (2 s^2))`` over ``|i - c| <= ceil(4 s)``, ``F_i = B_i / max(n_sat,
    max_{|j - i| <= ceil(3 s)} B_j)``, by double loops."""
    C = len(counts)
    blur_half, max_half = int(np.ceil(4 * s_cells)), int(np.ceil(3 * s_cells))
    B = np.array(
        [
            sum(
                counts[c] * np.exp(-0.5 * ((i - c) / s_cells) ** 2)
                for c in range(C)
                if abs(i - c) <= blur_half
            )
            for i in range(C)
        ]
    )
    local = np.array(
        [max(B[j] for j in range(C) if abs(j - i) <= max_half) for i in range(C)]
    )
    return B / np.maximum(local, n_sat)


# ------------------------------------------------------------------------------------------------------ the grid
def test_empty_grid_extent_default_resolution_and_int64_counts():
    """``empty(lo, hi)`` has the default resolution 0.05 m, ``ceil((hi - lo) / r)`` int64 zero counts from ``lo``."""
    g = OccupancyGrid1D.empty(-1.0, 0.0)
    assert g.origin == -1.0 and g.resolution == 0.05
    assert g.counts.shape == (20,) and g.counts.dtype == np.int64 and not g.counts.any()
    g = OccupancyGrid1D.empty(0.0, 1.0, 0.3)
    assert g.counts.shape == (4,) and g.counts.dtype == np.int64


@pytest.mark.parametrize(
    "lo, hi, resolution",
    [(0.0, 1.0, 0.0), (0.0, 1.0, -0.1), (1.0, 1.0, 0.1), (2.0, 1.0, 0.1)],
)
def test_empty_grid_rejects_a_zero_or_negative_resolution_and_an_empty_extent(
    lo, hi, resolution
):
    """A zero resolution (not a division by zero), a negative one, ``hi == lo`` (no zero-cell grid) and ``hi < lo``
    raise ValueError naming the values."""
    msg = f"need resolution > 0 and hi > lo, got {resolution}, [{lo}, {hi}]"
    with pytest.raises(ValueError, match=re.escape(msg)):
        OccupancyGrid1D.empty(lo, hi, resolution)


def test_cell_of_computes_in_float64():
    """float32(0.7) is 0.69999998..., in cell 6 of 0.1 m cells: the division is done in float64 (in float32 it
    rounds up to 7.0)."""
    g = _grid(np.zeros(10), origin=0.0, resolution=0.1)
    assert g.cell_of(np.float32(0.7)) == 6
    np.testing.assert_array_equal(
        g.cell_of(np.array([0.7, 0.35], dtype=np.float32)), [6, 3]
    )
    assert g.cell_of(np.array([0.7, 0.35], dtype=np.float32)).dtype == np.int64


# --------------------------------------------------------------------------------------------- blur and field
def test_gaussian_blur_is_truncated_at_four_sigma_on_both_sides():
    """``s = 0.25`` cells: the kernel spans ``ceil(4 s) = 1`` cell each side, so one count gives ``exp(-8)`` at its
    two neighbours and exactly 0 two cells away on either side (``exp(-32)`` would not be 0)."""
    counts = np.zeros(7, dtype=np.int64)
    counts[3] = 1
    e = np.exp(-0.5 * (1 / 0.25) ** 2)
    np.testing.assert_allclose(
        steps._gaussian_blur(counts, 0.25), [0, 0, e, 1, e, 0, 0], rtol=1e-15, atol=0
    )
    counts[3], counts[0] = 0, 2
    np.testing.assert_allclose(
        steps._gaussian_blur(counts, 0.25), [2, 2 * e, 0, 0, 0, 0, 0], rtol=1e-15, atol=0
    )


def test_gaussian_blur_reaches_across_the_whole_grid_when_sigma_is_wide():
    """``s = 1`` cell on 3 cells: the kernel is cut at ``C - 1 = 2`` cells, so a count in the first cell reaches the
    last one with ``exp(-2)`` (and one in the last cell the first)."""
    np.testing.assert_allclose(
        steps._gaussian_blur(np.array([1, 0, 0]), 1.0), np.exp([0, -0.5, -2]), rtol=1e-15
    )
    np.testing.assert_allclose(
        steps._gaussian_blur(np.array([0, 0, 3]), 1.0),
        3 * np.exp([-2, -0.5, 0]),
        rtol=1e-15,
    )


def test_running_max_pads_the_edges_with_minus_infinity():
    """``max(values[i - h : i + h + 1])`` clipped to the array at both ends."""
    np.testing.assert_array_equal(
        steps._running_max(np.array([1.0, 2.0, 3.0, 0.5]), 1), [2, 3, 3, 3]
    )
    np.testing.assert_array_equal(
        steps._running_max(np.array([4.0, 1.0, 0.0, 2.0, 0.0]), 2), [4, 4, 4, 2, 2]
    )


def test_likelihood_field_default_n_sat_and_landmarks_at_the_grid_edges():
    """One count in the first and one in the last cell, ``s = 0.3`` cells: the default ``n_sat = 3`` gives both
    peaks ``1 / 3`` (the local maximum near an edge is taken over the cells that exist), as by definition."""
    counts = np.array([1, 0, 0, 0, 0, 0, 0, 0, 1])
    f = steps.likelihood_field(_grid(counts, origin=-2.0, resolution=0.5), 0.15)
    assert f[0] == pytest.approx(1 / 3, rel=1e-12) and f[-1] == pytest.approx(
        1 / 3, rel=1e-12
    )
    np.testing.assert_allclose(
        f, _field_by_definition(counts, 0.3, 3.0), rtol=1e-12, atol=1e-300
    )


def test_likelihood_field_local_maximum_window_is_ceil_three_sigma():
    """``s = 0.3`` cells: the window of the local maximum is ``ceil(0.9) = 1`` cell each side, so a landmark of 3
    counts two cells from one of 6 is normalised by its own peak (``F = 1``), not by its neighbour's (``F = 1/2``)."""
    counts = np.array([0, 0, 6, 0, 3, 0, 0, 0, 0])
    f = steps.likelihood_field(_grid(counts, resolution=2.0), 0.6, n_sat=3.0)
    assert f[2] == pytest.approx(1.0, rel=1e-12) and f[4] == pytest.approx(1.0, rel=1e-12)
    np.testing.assert_allclose(
        f, _field_by_definition(counts, 0.3, 3.0), rtol=1e-12, atol=1e-300
    )


# ------------------------------------------------------------------------------------------------------ scoring
def _two_landmark_grid():
    """Cells of 1 m from 0, 3 counts in cells 0 and 4: with ``sigma = 0.3`` m ``F`` is exactly 1 at both."""
    return _grid([3, 0, 0, 0, 3])


def test_score_particles_is_log_eps_outside_the_grid_on_both_sides():
    """A return left of the first cell centre or right of the last scores ``log(0 + eps)`` with the default
    ``eps = 0.05`` (``F`` is 0 off the grid, not the edge value 1); one scan point is scored too."""
    g = _two_landmark_grid()
    for z in (-1.0, 0.2, 4.8, 7.0):
        np.testing.assert_allclose(
            steps.score_particles(0.0, [z], g, sigma=0.3), [np.log(0.05)], rtol=1e-15
        )
    np.testing.assert_allclose(
        steps.score_particles(np.array([0.0, 4.0]), [0.5, 4.5], g, sigma=0.3),
        [2 * np.log(1.05), np.log(0.05) + np.log(1.05)],
        rtol=1e-12,
    )


def test_score_particles_rejects_a_zero_eps():
    """``eps`` must be > 0 (``log(F + 0)`` is ``-inf`` off the structure): 0 raises ValueError naming it."""
    with pytest.raises(ValueError, match=re.escape("eps must be positive, got 0.0")):
        steps.score_particles(
            np.zeros(2), [0.5], _two_landmark_grid(), sigma=0.3, eps=0.0
        )


# --------------------------------------------------------------------------------- float64 results of the steps
def test_read_scan_returns_float64():
    """A float32 scan is read as float64 (same values)."""
    scan = np.array([-0.1, 0.7], dtype=np.float32)
    z = steps.read_scan(Frame(index=0, time=0.0, dt=0.0, velocity=0.0, scan=scan))
    assert z.dtype == np.float64
    np.testing.assert_array_equal(z, scan.astype(np.float64))


def test_offset_by_motion_adds_in_float64():
    """float32 particles are moved in float64: ``float64(x) + u dt`` exactly, not rounded to float32."""
    x = np.array([0.1, -2.3], dtype=np.float32)
    out = steps.offset_by_motion(x, 0.4, 0.5)
    assert out.dtype == np.float64
    np.testing.assert_array_equal(out, x.astype(np.float64) + 0.2)


def test_perturb_with_noise_returns_float64_with_and_without_noise():
    """float32 particles: ``sigma = 0`` returns a float64 copy, ``sigma > 0`` ``float64(x) + sigma n`` with the
    rng's standard normals."""
    x = np.array([0.1, -2.3, 5.0], dtype=np.float32)
    out = steps.perturb_with_noise(x, 0.0, np.random.default_rng(0))
    assert out.dtype == np.float64
    np.testing.assert_array_equal(out, x.astype(np.float64))
    out = steps.perturb_with_noise(x, 0.5, np.random.default_rng(1))
    assert out.dtype == np.float64
    np.testing.assert_array_equal(
        out, x.astype(np.float64) + 0.5 * np.random.default_rng(1).standard_normal(3)
    )


@pytest.mark.parametrize("wide", ["particles", "points"])
def test_transform_scan_returns_float64_for_wider_inputs(wide):
    """Particles or points in long double (wider than float64 on x86) still give float64 ``x_i + z_j``."""
    x, z = np.array([1.0, -0.5]), np.array([0.25, 2.0, -1.0])
    if wide == "particles":
        x = x.astype(np.longdouble)
    else:
        z = z.astype(np.longdouble)
    out = steps.transform_scan(x, z)
    assert out.dtype == np.float64 and out.shape == (2, 3)
    np.testing.assert_array_equal(out, [[1.25, 3.0, 0.0], [-0.25, 1.5, -1.5]])


def test_pick_best_particle_compares_log_weights_as_float64():
    """Log-weights 2^53 and 2^53 + 1 (Python ints) are the same float64: a tie, which goes to the lowest index."""
    assert steps.pick_best_particle([3.0, 4.0], [2**53, 2**53 + 1]) == (3.0, 0)
    assert steps.pick_best_particle([3.0, 4.0], [2**53, 2**53 + 2]) == (4.0, 1)


@pytest.mark.parametrize("ess_fraction", [None, 0.5])
def test_resample_particles_returns_float64_particles(ess_fraction):
    """float32 particles come back float64 whether resampled (``None``: always) or not (uniform weights, ESS = P)."""
    x = np.array([0.1, -2.3, 5.0, 7.0], dtype=np.float32)
    out, log_w, resampled = steps.resample_particles(
        x, np.zeros(4), np.random.default_rng(2), ess_fraction
    )
    assert resampled == (ess_fraction is None)
    assert out.dtype == np.float64
    assert set(out.tolist()) <= set(x.astype(np.float64).tolist())
    if not resampled:
        np.testing.assert_array_equal(out, x.astype(np.float64))


# ------------------------------------------------------------------------------------------------ the landmarks
def test_extract_landmarks_of_an_empty_grid_is_an_empty_float_array():
    """No counts: shape ``(0,)`` float64."""
    out = steps.extract_landmarks(OccupancyGrid1D.empty(0.0, 1.0, 0.1))
    assert out.shape == (0,) and out.dtype == np.float64


def test_extract_landmarks_single_return_with_min_count_one():
    """One return and ``min_count = 1``: one landmark at its cell centre (the blurred peak is exactly 1)."""
    np.testing.assert_array_equal(
        steps.extract_landmarks(_grid([0, 0, 1, 0]), sigma=0.02, min_count=1), [2.5]
    )


def test_extract_landmarks_defaults_sigma_and_min_count():
    """Defaults ``sigma = 0.1`` m, ``min_count = 5``: on 0.05 m cells two landmarks of exactly 5 returns 0.5 m apart
    are both kept (mass 5 >= 5) and told apart (a wider blur would merge them)."""
    counts = np.zeros(40, dtype=np.int64)
    counts[10] = counts[20] = 5
    out = steps.extract_landmarks(_grid(counts, resolution=0.05))
    np.testing.assert_allclose(out, [0.525, 1.025], rtol=0, atol=1e-15)
    counts[20] = 4
    np.testing.assert_allclose(
        steps.extract_landmarks(_grid(counts, resolution=0.05)),
        [0.525],
        rtol=0,
        atol=1e-15,
    )


def test_extract_landmarks_plateau_has_one_peak_its_left_cell():
    """Counts ``[0, 1, 5, 5, 1, 0, 0, 0]`` (a sharp blur: blurred = counts): the plateau 5, 5 is one peak, its left
    cell 2 (``> left``, ``>= right``), whose centroid over cells 1..3 (window ``max(1, ceil(3 s)) = 1``) is
    ``(1.5 + 5 * 2.5 + 5 * 3.5) / 11`` (rounded to 1e-9 m)."""
    out = steps.extract_landmarks(
        _grid([0, 1, 5, 5, 1, 0, 0, 0]), sigma=0.02, min_count=5
    )
    np.testing.assert_allclose(out, np.round([31.5 / 11], 9), rtol=0, atol=1e-15)


def test_extract_landmarks_peaks_at_both_edges():
    """Peaks in the first and the last cell count (the edges are padded with -inf); their windows are cut at the
    grid: centroids ``(5 * 0.5 + 1.5) / 6`` and ``(6.5 + 5 * 7.5) / 6`` (to 1e-9 m)."""
    out = steps.extract_landmarks(
        _grid([5, 1, 0, 0, 0, 0, 1, 5]), sigma=0.02, min_count=5
    )
    np.testing.assert_allclose(out, np.round([4 / 6, 44 / 6], 9), rtol=0, atol=1e-15)


def test_extract_landmarks_centroid_window_is_ceil_three_sigma_in_cells():
    """``sigma = 0.1`` m on 0.05 m cells is ``s = 2`` cells: one blurred peak at cell 10 (6 counts; 2 at cell 13, 1 at
    16 and 1 at 17), centroid over cells ``10 +- ceil(3 s) = 4..16``: cell 17 (7 away) is left out, cell 16 is in."""
    counts = np.zeros(30, dtype=np.int64)
    counts[[10, 13, 16, 17]] = [6, 2, 1, 1]
    g = _grid(counts, origin=1.0, resolution=0.05)
    blurred = steps._gaussian_blur(counts, 2.0)
    assert np.flatnonzero(
        (blurred[1:-1] > blurred[:-2]) & (blurred[1:-1] >= blurred[2:])
    ).tolist() == [9]
    centres = 1.0 + (np.array([10, 13, 16]) + 0.5) * 0.05
    expected = (6 * centres[0] + 2 * centres[1] + centres[2]) / 9
    np.testing.assert_allclose(
        steps.extract_landmarks(g, sigma=0.1, min_count=5),
        [round(expected, 9)],
        rtol=0,
        atol=1e-15,
    )


def test_extract_landmarks_min_count_zero_keeps_no_empty_cell():
    """``min_count = 0`` keeps every peak of the blurred counts but a cell with blurred 0 is no peak (an empty cell at
    the edge is not a landmark of mass 0)."""
    out = steps.extract_landmarks(_grid([0, 0, 0, 5, 0, 0, 0]), sigma=0.02, min_count=0)
    np.testing.assert_array_equal(out, [3.5])


def test_extract_landmarks_rounds_to_nine_decimals():
    """Positions are rounded to 1e-9 m: a landmark at 1.623456789123 reads 1.623456789."""
    out = steps.extract_landmarks(
        _grid([0, 5, 0], origin=0.123456789123), sigma=0.02, min_count=5
    )
    assert out.tolist() == [1.623456789]
