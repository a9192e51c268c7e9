"""Edge-aware refinement and hole filling against constructions with known disparity."""

import numpy as np
import pytest
from sgm_scenes import FAR_INDEX, NEAR_INDEX, STEP_COLUMN

from lfring.depth.refine import refine_index
from lfring.errors import InvalidInputError


def _two_planes(seed=0, h=40, w=64):
    rng = np.random.default_rng(seed)
    x = np.arange(w)[None, :].repeat(h, 0)
    truth = np.where(x < STEP_COLUMN, FAR_INDEX, NEAR_INDEX).astype(np.float32)
    guide = np.where(x < STEP_COLUMN, 0.3, 0.7) + 0.01 * rng.standard_normal((h, w))
    return truth, np.clip(guide, 0, 1).astype(np.float32), rng


def test_weighted_median_removes_outliers_and_keeps_the_edge():
    truth, guide, rng = _two_planes()
    index = truth + 0.05 * rng.standard_normal(truth.shape).astype(np.float32)
    outliers = rng.random(truth.shape) < 0.05
    index[outliers] = rng.uniform(0, 31, outliers.sum())
    confidence = np.full(truth.shape, 0.5, np.float32)
    refined, filled = refine_index(index, confidence, guide)
    assert np.mean(np.abs(index - truth) > 1) > 0.04
    assert np.mean(np.abs(refined - truth) > 1) < 0.002  # outliers gone, edge columns included
    edge = np.abs(refined - truth)[:, STEP_COLUMN - 2:STEP_COLUMN + 2]
    assert edge.max() < 0.5  # the step stays within the guide's edge, no blur
    np.testing.assert_array_equal(filled, refined)  # nothing to fill


def test_holes_stay_nan_in_refined_and_are_filled_from_their_region():
    truth, guide, rng = _two_planes(seed=1)
    index = truth.copy()
    confidence = np.full(truth.shape, 0.8, np.float32)
    holes = np.zeros(truth.shape, bool)
    holes[10:30, 24:31] = True  # a hole on the far side of the edge, touching it
    holes[5:15, 40:50] = True  # a hole inside the near plane
    confidence[holes] = 0.01
    index[holes] = 0.0  # garbage where not confident
    index[0, 0] = np.nan
    refined, filled = refine_index(index, confidence, guide, min_confidence=0.05)
    assert np.all(np.isnan(refined[holes])) and np.isnan(refined[0, 0])
    assert np.all(np.isfinite(filled))
    err = np.abs(filled - truth)[holes]
    assert err.max() < 1.0  # every hole pixel takes its own surface's value
    assert np.abs(filled[0, 0] - FAR_INDEX) < 0.5


def test_no_confident_pixel_gives_all_nan():
    truth, guide, _ = _two_planes()
    refined, filled = refine_index(truth, np.zeros_like(truth), guide)
    assert np.all(np.isnan(refined)) and np.all(np.isnan(filled))


def test_accepts_uint8_and_colour_guides():
    truth, guide, _ = _two_planes()
    conf = np.ones_like(truth)
    a = refine_index(truth, conf, guide)[0]
    b = refine_index(truth, conf, (guide * 255).round().astype(np.uint8))[0]
    c = refine_index(truth, conf, np.repeat(guide[..., None], 3, axis=2))[0]
    np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(c, truth, atol=1e-6)


@pytest.mark.parametrize(
    "args, kwargs, match",
    [
        ((np.zeros((3, 4, 5)), np.zeros((3, 4)), np.zeros((3, 4))), {}, "index must be an"),
        ((np.zeros((3, 4), np.int32), np.zeros((3, 4)), np.zeros((3, 4))), {}, "floating point"),
        ((np.zeros((3, 4)), np.zeros((3, 5)), np.zeros((3, 4))), {}, "confidence must have"),
        ((np.zeros((3, 4)), np.zeros((3, 4)), np.zeros((4, 3))), {}, "guide must be an"),
        ((np.zeros((3, 4)), np.zeros((3, 4)), np.zeros((3, 4))), {"radius_px": 0}, "radius_px"),
        ((np.zeros((3, 4)), np.zeros((3, 4)), np.zeros((3, 4))), {"min_confidence": -1}, "min_confidence"),
        ((np.zeros((3, 4)), np.zeros((3, 4)), np.zeros((3, 4))), {"min_confidence": 5}, "min_confidence"),  # all holes
        ((np.zeros((3, 4)), np.zeros((3, 4)), np.zeros((3, 4))), {"min_confidence": True}, "min_confidence"),
        ((np.zeros((3, 4)), "a", np.zeros((3, 4))), {}, "confidence must be"),
    ],
)
def test_errors(args, kwargs, match):
    with pytest.raises(InvalidInputError, match=match):
        refine_index(*args, **kwargs)


def test_fill_from_farther_side_takes_the_higher_neighbour_along_rows_or_columns():
    from lfring.depth.refine import fill_from_farther_side

    rng = np.random.default_rng(2)
    index = rng.random((6, 9)).astype(np.float32) * 10
    holes = rng.random((6, 9)) < 0.4
    holes[3] = True  # a row with nothing known
    index[0, 4] = np.nan  # unknown but no hole: stays unknown, and is no neighbour
    got = fill_from_farther_side(index, holes)
    for y in range(6):
        for x in range(9):
            if not holes[y, x]:
                assert got[y, x] == index[y, x] or (np.isnan(got[y, x]) and np.isnan(index[y, x]))
                continue
            known = [i for i in range(9) if not holes[y, i] and np.isfinite(index[y, i])]
            left = [index[y, i] for i in known if i < x][-1:]
            right = [index[y, i] for i in known if i > x][:1]
            want = max(left + right) if left + right else np.nan
            np.testing.assert_equal(got[y, x], np.float32(want))
    np.testing.assert_array_equal(fill_from_farther_side(index.T, holes.T, axis=0), got.T)


@pytest.mark.parametrize("args, kwargs, match", [
    ((np.zeros((3, 3), np.int32), np.zeros((3, 3), bool)), {}, "floating-point"),
    ((np.zeros(3, np.float32), np.zeros(3, bool)), {}, r"\(h, w\)"),
    ((np.zeros((3, 3), np.float32), np.zeros((3, 4), bool)), {}, "holes must"),
    ((np.zeros((3, 3), np.float32), np.zeros((3, 3))), {}, "holes must"),
    ((np.zeros((3, 3), np.float32), np.zeros((3, 3), bool)), {"axis": 2}, "axis"),
    ((np.zeros((3, 3), np.float32), np.zeros((3, 3), bool)), {"axis": True}, "axis"),
    ((np.zeros((3, 3), np.float32), np.zeros((3, 3), bool)), {"axis": 1.0}, "axis"),
    ((np.zeros((3, 3), np.float32), np.zeros((3, 3), bool)), {"axis": np.array([1, 1])}, "axis")])
def test_fill_from_farther_side_refuses_bad_inputs(args, kwargs, match):
    from lfring.depth.refine import fill_from_farther_side

    with pytest.raises(InvalidInputError, match=match):
        fill_from_farther_side(*args, **kwargs)


def test_filled_is_nan_only_where_the_smoother_brings_no_weight():
    """One known pixel: the smoother carries its value over its own image region; a region behind
    a guide edge of the full range gets no weight and stays NaN, as documented (the sweep then
    falls back on the optimisation's answer: test_filled_map_is_known_wherever_the_depth_is)."""
    index = np.full((60, 80), 5.0, np.float32)
    conf = np.zeros((60, 80), np.float32)
    conf[10, 10] = 1.0
    guide = np.zeros((60, 80), np.float32)
    guide[:, 40:] = 1.0
    refined, filled = refine_index(index, conf, guide)
    reached = np.isfinite(filled)
    assert reached[:, :40].all()
    np.testing.assert_allclose(filled[reached], 5.0, atol=1e-4)
    assert np.isnan(refined).sum() == index.size - 1
    assert np.isnan(refine_index(index, np.zeros_like(conf), guide)[1]).all()


def test_the_compiled_steps_around_the_median_are_numpy_s_to_the_bit():
    """The known mask, the bins, the smoother's inputs and the filled map run as compiled
    row-parallel passes: on values and confidences with NaN, infinities and pixels under the
    threshold, both maps equal those of the same steps written in float32 NumPy (around the same
    median kernel and smoother)."""
    import cv2

    from lfring.depth import refine as refine_module
    from lfring.depth import refine_kernels

    rng = np.random.default_rng(3)
    h, w = 47, 53
    index = rng.uniform(2.0, 9.0, (h, w)).astype(np.float32)
    index[rng.random((h, w)) < 0.05] = np.nan
    confidence = rng.uniform(0.0, 0.3, (h, w)).astype(np.float32)
    confidence[rng.random((h, w)) < 0.05] = np.inf
    confidence[rng.random((h, w)) < 0.05] = np.nan
    guide = rng.random((h, w)).astype(np.float32)
    refined, filled = refine_index(index, confidence, guide)

    g8 = np.clip(np.rint(guide * 255.0), 0, 255).astype(np.uint8)
    known = np.isfinite(index) & np.isfinite(confidence) & (confidence >= np.float32(refine_module.MIN_CONFIDENCE))
    assert 0.2 < known.mean() < 0.9
    lo, hi = float(index[known].min()), float(index[known].max())
    coarse = int(min(refine_module.MEDIAN_COARSE_BINS, np.ceil(hi - lo) + 1))
    width = max((hi - lo) / max(coarse - 1, 1), 1e-6) / refine_module.MEDIAN_FINE_BINS
    fine = coarse * refine_module.MEDIAN_FINE_BINS
    # NumPy casts a Python float to the array's float32 here (NumPy 1 by value, 2 as a weak scalar).
    bins = np.clip(np.floor((np.where(known, index, np.float32(lo)) - np.float32(lo)) / np.float32(width)), 0,
                   fine - 1).astype(np.int32)
    bins[~known] = -1
    lut = np.exp(-np.arange(256, dtype=np.float64) ** 2 / (2.0 * refine_module.MEDIAN_SIGMA ** 2))
    want_refined = np.empty((h, w), np.float32)
    refine_kernels.weighted_median(index, bins, g8, refine_module.MEDIAN_RADIUS_PX, lut, fine, want_refined)
    floor = np.float32(refine_module.FILL_WEIGHT_FLOOR)
    weight = np.where(known, np.maximum(confidence, floor), np.float32(0)).astype(np.float32)
    fgs = cv2.ximgproc.createFastGlobalSmootherFilter(g8, refine_module.FGS_LAMBDA, refine_module.FGS_SIGMA,
                                                     refine_module.FGS_ATTENUATION, refine_module.FGS_ITERATIONS)
    num = fgs.filter(np.where(known, want_refined, np.float32(0)) * weight)
    den = fgs.filter(weight)
    with np.errstate(invalid="ignore", divide="ignore"):
        want_filled = np.where(known, want_refined, np.where(den > floor, num / den, np.float32(np.nan)))
    np.testing.assert_array_equal(refined, want_refined)
    np.testing.assert_array_equal(filled, want_filled)
    assert np.isnan(refined[~known]).all() and np.isfinite(refined[known]).all()
    # An empty map has no known pixel and no range.
    empty = refine_index(np.zeros((0, 5), np.float32), np.zeros((0, 5), np.float32), np.zeros((0, 5)))
    assert all(m.shape == (0, 5) for m in empty)


@pytest.mark.parametrize("use_index", [True, False])
def test_the_compiled_depth_maps_are_the_finishers_to_the_bit(use_index):
    """The semi-global engine's last step (index maps to depth, confidence, index and filled
    depth) in one compiled pass equals :class:`Finisher`'s NumPy steps on the whole frame, on
    maps with NaN and infinities, views seen by too few, and the fallback to the unrefined index
    with and without it (``use_index``: without the left-right check)."""
    from lfring.calibration import RingCalibration
    from lfring.depth import refine_kernels
    from lfring.depth.hypotheses import depth_hypotheses
    from lfring.depth.selection import Finisher

    cal = RingCalibration.load("twin_binned2")
    depths = depth_hypotheses(cal, 0.3, 1.1)
    rng = np.random.default_rng(7)
    h, w = 41, 59
    n = len(depths)

    def holes(a, nan_share):
        """NaN at a share of the pixels, +inf and -inf at a few."""
        for value, share in ((np.nan, nan_share), (np.inf, 0.02), (-np.inf, 0.02)):
            a[rng.random((h, w)) < share] = value
        return a

    refined = holes(rng.uniform(0, n - 1, (h, w)).astype(np.float32), 0.2)
    index = holes(rng.uniform(0, n - 1, (h, w)).astype(np.float32), 0.1)
    filled = holes(rng.uniform(0, n - 1, (h, w)).astype(np.float32), 0.1)
    confidence = holes(rng.uniform(0, 1, (h, w)).astype(np.float32), 0.02)
    nviews = holes(rng.choice(np.float32([0.0, 1.2, 1.5, 2.0, 3.7, 4.0]), (h, w)), 0.02)

    want = Finisher(depths, cal.depth_origin_m, (h, w), 2)
    assert want.linear
    idx = np.where(np.isfinite(refined), refined, index if use_index else np.nan).astype(np.float32)
    fills = np.where(np.isfinite(filled), filled, idx).astype(np.float32)
    missing = np.where(np.isfinite(idx), np.float32(0.0), np.float32(np.inf))
    want.rows(0, h, np.nan_to_num(idx), confidence, missing, nviews)
    want_filled = want.depth_of(fills, nviews)

    got = Finisher(depths, cal.depth_origin_m, (h, w), 2)
    got_filled = np.empty((h, w), np.float32)
    refine_kernels.depth_maps(refined, index, filled, confidence, nviews, use_index, np.float32(got.step),
                              np.float32(got.inv[0]), np.float32(got.z0), np.float32(got.seen_views), got.depth, got.conf,
                              got.index, got_filled)
    for a, b in ((got.depth, want.depth), (got.conf, want.conf), (got.index, want.index), (got_filled, want_filled)):
        np.testing.assert_array_equal(a, b)
    seen = (nviews >= want.seen_views) & np.isfinite(idx)
    assert 0.3 < seen.mean() < 0.8 and np.isnan(got.depth[~seen]).all() and np.isfinite(got.depth[seen]).all()
    assert np.isnan(got_filled[~(nviews >= want.seen_views)]).all()


def _window_median(values, bins, guide8, lut, radius):
    """The weighted median written plainly: per known pixel, its window's known entries sorted by
    bin, the lowest bin whose cumulative weight reaches half the total, the weighted mean of the
    values in it (float64); also how far that bin's cumulative weight below it lies from half
    (near 0: a tie that float32 sums may decide the other way)."""
    h, w = values.shape
    out = np.full((h, w), np.nan)
    margin = np.full((h, w), np.inf)
    for y in range(h):
        for x in range(w):
            if bins[y, x] < 0:
                continue
            ys, xs = slice(max(0, y - radius), y + radius + 1), slice(max(0, x - radius), x + radius + 1)
            b, v = bins[ys, xs].ravel(), values[ys, xs].ravel().astype(np.float64)
            wt = lut[np.abs(guide8[ys, xs].ravel().astype(int) - int(guide8[y, x]))]
            keep = b >= 0
            b, v, wt = b[keep], v[keep], wt[keep]
            half = 0.5 * wt.sum()
            below = 0.0
            for f in np.unique(b):
                here = wt[b == f].sum()
                margin[y, x] = min(margin[y, x], abs(below + here - half))
                if below + here >= half:
                    out[y, x] = np.sum(wt[b == f] * v[b == f]) / here
                    break
                below += here
    return out, margin


@pytest.mark.parametrize("mirrored", [False, True])
def test_the_weighted_median_kernel_is_the_plain_median(mirrored):
    """The compiled median against the plain one on a map whose windows span one bin, two
    adjacent bins (a slow ramp, and values jittered within a bin: the rows' sums) and many
    (noise: a histogram per pixel), on rows where most pixels are known and rows where few are
    (too few for the sums); the unknown pixels' values are NaN. Mirrored, the ramp meets the
    other side of the image. Equal to float32 rounding except where the half falls within
    rounding of a bin's edge."""
    from lfring.depth import refine as refine_module
    from lfring.depth import refine_kernels

    rng = np.random.default_rng(7)
    h, w = 40, 90
    index = np.empty((h, w), np.float32)
    index[:, :30] = 4.3 + 0.05 * rng.random((h, 30))  # one bin (width 1/8)
    index[:, 30:60] = 4.0 + np.linspace(0.0, 0.5, 30)[None, :] + 0.02 * np.arange(h)[:, None]  # a ramp
    index[:, 60:] = rng.uniform(0.0, 9.0, (h, 30))  # noise
    share = np.where(np.arange(h) % 10 < 7, 0.9, 0.15)[:, None]  # dense rows, and sparse ones
    known = rng.random((h, w)) < share
    if mirrored:
        index, known = index[:, ::-1].copy(), known[:, ::-1].copy()
    guide8 = rng.integers(0, 256, (h, w)).astype(np.uint8)
    fine_width = np.float32(1.0 / refine_module.MEDIAN_FINE_BINS)
    fine = 10 * refine_module.MEDIAN_FINE_BINS
    bins = np.empty((h, w), np.int32)
    refine_kernels.bin_values(index, known, np.float32(0.0), fine_width, fine, bins)
    index[~known] = np.nan  # never read
    lut = np.exp(-np.arange(256, dtype=np.float64) ** 2 / (2.0 * refine_module.MEDIAN_SIGMA ** 2))
    radius = refine_module.MEDIAN_RADIUS_PX
    got = np.empty((h, w), np.float32)
    refine_kernels.weighted_median(index, bins, guide8, radius, lut, fine, got)
    want, margin = _window_median(index, bins, guide8, lut, radius)
    np.testing.assert_array_equal(np.isnan(got), ~known)
    clear = known & (margin > 1e-4)
    assert clear.sum() > 0.95 * known.sum()
    np.testing.assert_allclose(got[clear], want[clear], rtol=2e-6, atol=0)
    # Every kind of window was there, on the dense rows.
    from scipy.ndimage import maximum_filter, minimum_filter
    size = 2 * radius + 1
    span = (maximum_filter(np.where(known, bins, -1), size, mode="constant", cval=-1)
            - minimum_filter(np.where(known, bins, 10**6), size, mode="constant", cval=10**6))
    dense = known & (share > 0.5)
    assert (span[dense] == 0).sum() > 50 and (span[dense] == 1).sum() > 50 and (span[dense] > 1).sum() > 50
