"""The strip sweep against the whole-slice sweep."""


import numpy as np
import pytest

from lfring.calibration import RingCalibration
from lfring.errors import LfringWarning
from lfring.synth import render
from lfring.synth.presets import three_depth_scene


@pytest.mark.parametrize("cost", ["lcn", "lcn-occlusion", "lcn-halves"])
@pytest.mark.parametrize("reference", [0, "center"])
@pytest.mark.parametrize("warp", ["translation", "perspective"])
def test_strips_equal_whole_slices(prototype, reference, warp, cost):
    """The default sweep, strip by strip on threads (two weighted adds per shift, or
    warpPerspective per strip), gives what the whole-slice sweep gives for the same cost.

    With perspective warps the strips' and the slices' bilinear taps differ in OpenCV's
    fixed-point rounding. A view that weighs a few hundredths at its disc's rim adds its square
    divided by that weight to the sum of squares, which magnifies the difference: there, at a
    pixel or so in 10^4, the aggregated costs may differ by more than the tolerance."""
    import warnings

    from lfring.core.viewstack import cached_view_masks
    from lfring.depth.costs.lcn import lcn_sources
    from lfring.depth.hypotheses import depth_hypotheses
    from lfring.depth.sweep.slices import sweep_slices
    from lfring.depth.sweep.strips import sweep_strips

    r = render(prototype, three_depth_scene(), binning=4)
    cal = RingCalibration.from_optics(r.device, layout=r.layout)
    h, w = r.views.shape[1:3]
    masks = cached_view_masks(cal, (h, w))
    src = lcn_sources(r.views, cal, 9, threads=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)
        hs = cal.homographies(depth_hypotheses(cal, 0.28, 1.1), reference=reference)
    if warp == "perspective":  # a slight tilt: no longer translations
        tilt = np.array([[1.0, 0.002, 0.3], [-0.001, 1.0, -0.2], [2e-6, -1e-6, 1.0]])
        hs = np.where(np.all(hs == np.eye(3), axis=(-2, -1))[..., None, None], hs, tilt @ hs)
    if cost == "lcn-halves":  # a volume beside the volume: both sweeps fill the same numbers
        n = len(hs)
        want_v, want_h, got_v, got_h = (np.empty((n, h, w), np.float32) for _ in range(4))
        sweep_slices(src, masks, hs, cost, 9, None, 2, 15, volume=want_v, halves=want_h)
        sweep_strips(src, masks, hs, aggregate_px=15, exclude=2, threads=3, volume=got_v, halves=got_h)
        for got, want in ((got_v, want_v), (got_h, want_h)):
            np.testing.assert_array_equal(np.isfinite(got), np.isfinite(want))
            fin = np.isfinite(want)
            np.testing.assert_allclose(got[fin], want[fin], rtol=1e-3, atol=1e-4)
        assert 0.3 < np.isfinite(want_h).mean() < np.isfinite(want_v).mean()  # the halves see less
        return
    want = sweep_slices(src, masks, hs, cost, 9, None, 2, 15)
    occlusion = cost == "lcn-occlusion"
    for threads in (1, 3):
        got = sweep_strips(src, masks, hs, aggregate_px=15, exclude=2, threads=threads, occlusion=occlusion)
        ok = np.isfinite(want[1])
        np.testing.assert_array_equal(np.isfinite(got[1]), ok)
        assert np.mean(got[0][ok] == want[0][ok]) > 0.999
        same = ok & (got[0] == want[0])
        for g, x in zip(got[1:5], want[1:5]):
            fin = same & np.isfinite(x)
            if warp == "translation":
                np.testing.assert_allclose(g[fin], x[fin], rtol=1e-3, atol=1e-4)
            else:  # see the docstring: a pixel or so at a rim may differ more, but not by half
                close = np.abs(g[fin] - x[fin]) <= 1e-4 + 1e-3 * np.abs(x[fin])
                assert close.mean() >= 0.9999, (close.mean(), (~close).sum())
                np.testing.assert_allclose(g[fin], x[fin], rtol=0.5, atol=1e-4)
        np.testing.assert_allclose(got[5], want[5], atol=1e-4)
    # The whole volume instead of the running minimum: the same best hypothesis and costs.
    volume = np.empty((len(hs), h, w), np.float32)
    nviews = sweep_strips(src, masks, hs, aggregate_px=15, exclude=2, threads=3, volume=volume, occlusion=occlusion)
    np.testing.assert_allclose(nviews, want[5], atol=1e-4)
    ok = np.isfinite(want[1])
    np.testing.assert_array_equal(np.isfinite(volume).any(axis=0), ok)
    best = np.argmin(np.where(np.isfinite(volume), volume, np.inf), axis=0)
    assert np.mean(best[ok] == want[0][ok]) > 0.999
    g, x = np.take_along_axis(volume, best[None], 0)[0][ok], want[1][ok]
    close = np.abs(g - x) <= 1e-4 + 1e-3 * np.abs(x)
    assert close.mean() >= (1.0 if warp == "translation" else 0.9999), (close.mean(), (~close).sum())
    np.testing.assert_allclose(g, x, rtol=0.5, atol=1e-4)


def test_the_reference_frame_image_is_the_views_warped_mean_on_any_number_of_threads():
    """'center': each view's image times its mask, warped at the middle hypothesis, summed in the
    views' order and divided by the warped masks' sum: the same numbers on one thread or three,
    and the formula written out with the warping core; a view as reference: its own image."""
    from lfring.calibration import RingCalibration
    from lfring.core.warping import warp_image
    from lfring.depth.plan import DEPTH_TAPER, in_reference_frame, plan_sweep

    cal = RingCalibration.load("twin_binned2")
    h, w = cal.layout.view_shape
    views = np.random.default_rng(5).random((4, h, w, 1)).astype(np.float32)
    plan = plan_sweep(views, cal, 0.3, 1.0, 8, "center", DEPTH_TAPER)
    lum = views[..., 0]
    one = in_reference_frame(lum, plan)
    np.testing.assert_array_equal(in_reference_frame(lum, plan, threads=3), one)
    mid = len(plan.depths) // 2
    num = sum(warp_image(lum[k] * plan.masks[k], plan.hs[mid, k], (w, h)).astype(np.float64) for k in range(4))
    den = sum(warp_image(plan.masks[k], plan.hs[mid, k], (w, h)).astype(np.float64) for k in range(4))
    inside = den > 0.5
    assert inside.mean() > 0.5
    np.testing.assert_allclose(one[inside], num[inside] / den[inside], rtol=1e-5)
    np.testing.assert_array_equal(in_reference_frame(lum, plan_sweep(views, cal, 0.3, 1.0, 8, 2, DEPTH_TAPER)), lum[2])


@pytest.fixture
def percentile_calls(monkeypatch):
    """``np.percentile`` as it was, and the list of calls made to it from now on (its stand-in
    counts them): whether :func:`lfring.depth.plan.high_percentile` handed a question to NumPy."""
    real = np.percentile
    calls = []

    def counted(*args, **kwargs):
        calls.append(args)
        return real(*args, **kwargs)

    monkeypatch.setattr(np, "percentile", counted)
    return real, calls


@pytest.mark.parametrize("seed, kind", list(enumerate(["uniform", "ties", "normal", "constant", "sorted", "skewed",
                                                           "sampled top"])))
def test_the_high_percentile_is_numpys_to_the_bit(seed, kind, percentile_calls):
    """The guide's white (:func:`lfring.depth.plan.high_percentile`) is ``np.percentile``'s value
    and type for float32 and float64 values of many sizes and kinds, high percentiles between
    ranks and on them; it answers itself wherever it should (large arrays, high percentiles, a
    NumPy that interpolates as it does) and hands the question to NumPy elsewhere (low or top
    percentiles, small arrays, a sample that leaves too few values above its threshold)."""
    from lfring.depth import plan

    real, calls = percentile_calls
    rng = np.random.default_rng(seed)
    for size in (7, 1000, 40_000, 123_457, 495_616, 1_123_600):
        x = {"uniform": lambda: rng.random(size),
             "ties": lambda: rng.integers(0, 20, size).astype(np.float64),
             "normal": lambda: rng.normal(size=size) * 3,
             "constant": lambda: np.full(size, 0.25),
             "sorted": lambda: np.sort(rng.random(size)),
             "skewed": lambda: rng.random(size) ** 8,
             # the largest values just where the sample looks: its threshold leaves too few above
             "sampled top": lambda: np.where(np.arange(size) % max(1, size // plan.PERCENTILE_SAMPLE) == 0, 5.0, 0.0)
             + rng.random(size)}[kind]()
        for dtype in (np.float32, np.float64):
            a = x.astype(dtype).reshape(-1, 1) if size % 2 else x.astype(dtype)
            for q in (99.5, 90.0, 99.0, 99.99, 99.999, 100.0, 50.0):
                want = real(a, q)
                calls.clear()
                got = plan.high_percentile(a, q)
                assert got == want and type(got) is type(want), (kind, size, dtype, q, got, want)
                itself = (plan.NUMPY_INTERPOLATION_MATCHED and size >= plan.PERCENTILE_MIN_VALUES
                          and plan.PERCENTILE_MIN_Q <= q < 100.0)
                if kind != "sampled top":
                    assert (not calls) == itself, (kind, size, dtype, q, len(calls))
                elif itself and q == 99.5:  # most of the largest values are in the sample: too few above
                    assert calls, (size, dtype)


def test_the_high_percentile_interpolates_and_hands_over_as_numpy(percentile_calls):
    """Where NumPy's interpolation between two ranks takes its second form (a weight of one half
    included), where exactly one value too few lies above the sample's threshold, and for
    integer, NaN-holding values and a percentile that is not a Python number,
    :func:`lfring.depth.plan.high_percentile` gives NumPy's answer."""
    from lfring.depth.plan import NUMPY_INTERPOLATION_MATCHED, high_percentile

    real, calls = percentile_calls
    rng = np.random.default_rng(11)
    # The 99.5th percentile of 200 003 values lies 0.99 of the way from rank 199 001 to 199 002,
    # the 93.75th of 40 009 values half way from rank 37 507 to 37 508: NumPy takes the upper
    # value less the rest of the step, which differs in float32 from the lower value plus the
    # step's part for these pairs.
    for n, q, t, below, above in ((200_003, 99.5, 0.99, np.float32(0.391619), np.float32(0.89027435)),
                                  (40_009, 93.75, 0.5, np.float32(0.08564917), np.float32(0.2368105))):
        rank = int((n - 1) * (q / 100.0))
        x = np.concatenate([rng.random(rank).astype(np.float32) * below, [below, above],
                            above + rng.random(n - rank - 2).astype(np.float32)])
        rng.shuffle(x)
        want = real(x, q)
        calls.clear()
        assert want != below + (above - below) * t and high_percentile(x, q) == want
        assert (not calls) == NUMPY_INTERPOLATION_MATCHED
    # 100 000 values, the 99.5th percentile needs the 501 from rank 99 499 up; 500 equal largest
    # values where the sample looks put its threshold on them, one value too few above it.
    x = rng.random(100_000)
    x[::12][:500] = 5.0
    assert high_percentile(x, 99.5) == real(x, 99.5) < 5.0
    ints = rng.integers(0, 1000, 200_000)
    assert high_percentile(ints, 99.5) == real(ints, 99.5)
    holed = rng.random(200_000).astype(np.float32)
    holed[12345] = np.nan
    assert np.isnan(high_percentile(holed, 99.5))
    whole = rng.random(200_000).astype(np.float32)
    for q in (np.float64(99.5), np.array(99.5), np.int64(99)):  # NumPy works these in float64
        got, want = high_percentile(whole, q), real(whole, q)
        assert got == want and type(got) is type(want), (q, got, want)
