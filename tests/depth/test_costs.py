"""The 'lcn' cost's sources and terms, and the occlusion-aware costs: leaving one view out, and
the halves of the views."""


import numpy as np
import pytest
from sgm_scenes import disparity

from lfring.depth import estimate_depth
from lfring.errors import InvalidInputError, LfringWarning


def test_occlusion_aware_cost_leaves_out_the_view_that_disagrees():
    """Three views agree and one (occluded) does not: over the window, 'lcn-occlusion' takes the
    three's variance (0) where 'lcn' is high; where only two views see the window, or the view
    left out would leave fewer than two, nothing is left out."""
    from lfring.core.filters import box_filter
    from lfring.depth.costs.lcn import lcn_cost
    from lfring.depth.costs.lcn_occlusion import (
        OCCLUSION_PENALTY,
        lcn_leave_one_out,
        occlusion_aggregate,
    )

    rng = np.random.default_rng(1)
    x = np.broadcast_to(rng.random((1, 12, 16), dtype=np.float32), (4, 12, 16)).copy()
    x[3] += 1.0  # view 3 sees something else
    wts = np.ones_like(x)
    box = lambda c: box_filter(np.ascontiguousarray(c, np.float32), 5)

    def cost(wts):
        a = x * wts
        s1, s2, cnt = a.sum(0), (a * a).sum(0), wts.sum(0)
        full = box(lcn_cost(s1, s2, cnt))
        outs = [(lcn_leave_one_out(s1, s2, cnt, a[k], wts[k]), wts[k]) for k in (1, 2, 3)]  # view 0: the reference
        return full.copy(), occlusion_aggregate(full, cnt, outs, box, box)

    full, occ = cost(wts)
    assert np.all(full > 0.15)
    np.testing.assert_allclose(occ, 0.0, atol=1e-5)
    wts[2:] = 0.0  # only views 0 and 1 see it: nothing to leave out
    full, occ = cost(wts)
    np.testing.assert_array_equal(occ, full)
    wts[2:] = 1.0
    wts[1:3, :, :8] = 0.0  # left half: views 0 and 3 only; right half: all four
    full, occ = cost(wts)
    np.testing.assert_array_equal(occ[:, :4], full[:, :4])  # whole window in the left half
    np.testing.assert_allclose(occ[:, 11:], 0.0, atol=1e-5)  # whole window in the right half
    assert np.all(occ <= full) and OCCLUSION_PENALTY >= 1.0


def test_occlusion_aware_costs_beat_all_views_on_the_hard_scene(hard_twin):
    """The hard scene (4 x 4 binned) against its exact ground truth on every pixel of view 0's
    disc: the two occlusion-aware costs have fewer pixels off by more than 0.5 px of disparity
    than 'lcn' (measured: 'lcn' 19.3 %, 'lcn-occlusion' 17.6 %, the default 'lcn-halves' 18.0 %),
    and 'lcn-occlusion' fewer off by more than 1 px (10.1, 9.7 and 11.3 %; before the 'lcn'
    statistics stopped leaning with the rim taper 10.4, 9.6 and 11.0 %, and 'lcn' gained most).
    Since the optimisation takes the shiftable windows' cost, the halves no longer win at 1 px on
    this coarse frame; on the 2 x 2 binned frame of benchmarks/bench_depth_real.py they still do
    (every pixel two views see). The costs are compared under one engine, the float32 reference
    of the semi-global method ('lcn-occlusion' has no 16-bit passes)."""
    r, cal = hard_twin
    gt = r.depth_m[0]
    m = np.isfinite(gt) & (r.layout.masks()[0] > 0)
    bad, bad1 = {}, {}
    for cost in ("lcn", "lcn-occlusion", None):
        res = estimate_depth(r.views, cal, zmin_m=0.27, zmax_m=1.1, reference=0, cost=cost, method="sgm-reference")
        d = res.depth_filled_m[m]
        err = np.abs(disparity(cal, np.where(np.isfinite(d), d, 1.0)) - disparity(cal, gt[m]))
        bad[res.cost], bad1[res.cost] = np.mean(~(err <= 0.5)), np.mean(~(err <= 1.0))
    assert bad["lcn-occlusion"] <= 0.19 and bad["lcn-occlusion"] <= 0.93 * bad["lcn"], bad
    assert bad["lcn-halves"] <= 0.19 and bad["lcn-halves"] <= 0.95 * bad["lcn"], bad
    assert bad1["lcn-occlusion"] <= 0.97 * bad1["lcn"] and max(bad1.values()) <= 0.12, bad1


def test_the_halves_volume_needs_the_whole_volume_and_an_lcn_cost(twin):
    import warnings

    from lfring.depth.sweep.slices import sweep_slices
    from lfring.depth.sweep.strips import sweep_strips

    r, cal, views, *_ = twin
    h, w = views.shape[1:3]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)
        hs = cal.homographies(np.array([0.3, 0.5, 1.0]), reference=0)
    lum = np.zeros((4, h, w), np.float32)
    masks = np.ones((4, h, w), np.float32)
    vol = np.zeros((3, h, w), np.float32)  # not empty: a signalling NaN in it would warn on the cast below
    with pytest.raises(ValueError, match="halves needs a volume"):
        sweep_strips(lum, masks, hs, aggregate_px=5, halves=vol)
    with pytest.raises(ValueError, match="halves needs a volume"):
        sweep_strips(lum, masks, hs, aggregate_px=5, volume=vol, halves=np.empty((2, h, w), np.float32))
    with pytest.raises(ValueError, match="an 'lcn' cost"):
        sweep_slices(lum, masks, hs, "zncc", 9, None, volume=vol, halves=np.empty_like(vol))
    from lfring.depth.costs.lcn_halves import take_halves

    with pytest.raises(InvalidInputError, match="halves must have the volume's shape"):
        take_halves(vol, np.empty((2, h, w), np.float32))
    with pytest.raises(InvalidInputError, match="volume must be a C-contiguous float32"):
        take_halves(vol.astype(np.float64), vol)


def test_a_pixel_without_a_cost_of_all_views_takes_no_halves_cost():
    """Where no hypothesis has a cost of all views (best inf: too few views see the pixel), the
    halves' cost is not taken, even a finite one; a poor finite pixel still takes it."""
    from lfring.depth.costs.lcn_halves import HALVES_POOR, halves_poor, take_halves

    volume = np.full((2, 1, 6), 0.1, np.float32)
    volume[:, 0, 4] = np.inf   # no cost of all views at any hypothesis
    volume[:, 0, 5] = 4.0      # poor: 40 times the median best
    halves = np.full((2, 1, 6), 0.1, np.float32)
    halves[:, 0, 4:] = 0.2
    assert take_halves(volume, halves) == pytest.approx(1 / 6)
    np.testing.assert_array_equal(volume[:, 0, 4], [np.inf, np.inf])
    np.testing.assert_array_equal(volume[:, 0, 5], [np.float32(0.2)] * 2)
    best = np.array([1.0, HALVES_POOR * 2.0, np.inf], np.float32)
    assert halves_poor(best, 1.0).tolist() == [False, True, False]


def test_view_halves_follow_the_rows_and_columns_of_the_ring(twin):
    """Reference 0 (top left): its column and its row; 'center': the four sides of the square;
    the pair and a single line of views: none; the cost is 'lcn' there."""
    import warnings

    from lfring.depth.costs.lcn_halves import view_halves

    r, cal, views, *_ = twin
    shape = views.shape[1:3]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)
        hs = lambda c, ref: c.homographies(np.array([0.3, 1.0]), reference=ref)
        assert view_halves(hs(cal, 0), shape) == [(0, 2), (0, 1)]
        assert view_halves(hs(cal, 3), shape) == [(1, 3), (2, 3)]
        assert sorted(view_halves(hs(cal, "center"), shape)) == [(0, 1), (0, 2), (1, 3), (2, 3)]
        pair = cal.select_views([0, 1])
        assert view_halves(hs(pair, 0), shape) == [] and view_halves(hs(pair, "center"), shape) == []
        a = estimate_depth(views[:2], pair, zmin_m=0.3, zmax_m=1.0, reference=0)
        b = estimate_depth(views[:2], pair, zmin_m=0.3, zmax_m=1.0, reference=0, cost="lcn")
    assert a.cost == "lcn-halves"
    np.testing.assert_array_equal(a.depth_m, b.depth_m)


def test_a_view_that_weighs_less_than_one_adds_its_square_in_part_as_its_value():
    """The 'lcn' cost is the weighted variance of the views' normalised values: views that agree
    cost nothing whatever their weights (a view at its disc's rim weighs less than 1), and two
    values 1 and 3 weighing 1 and 0.5 give sum w (n - mean)^2 / max(C - 1, 0.5) = (4/9 + 8/9) / 0.5.
    The slice cost, the leave-one-out and pair kernels, and the fused engine's four-view and pair
    terms (the fused engine's four-view row kernels against its general one: the next test)."""
    from lfring.core.viewstack import WEIGHT_FLOOR
    from lfring.depth.costs.base import compiled_kernels
    from lfring.depth.costs.lcn import lcn_slice_cost, weighted_square
    from lfring.depth.costs.lcn_occlusion import lcn_leave_one_out
    from lfring.depth.engines import fused_volume

    floor = np.float32(WEIGHT_FLOOR)

    def stack(values):
        return np.array(values, np.float32)[:, None, None] * np.ones((1, 1, 3), np.float32)

    w = stack([1.0, 1.0, 0.5, 0.25])
    agree = 2.0 * w  # every view sees n = 2, premultiplied by its weight
    np.testing.assert_allclose(lcn_slice_cost(agree, w, w.sum(axis=0), 9), 0.0, atol=1e-6)
    two_w, two = stack([1.0, 0.5]), stack([1.0, 1.5])  # n = 1 and 3
    np.testing.assert_allclose(lcn_slice_cost(two, two_w, two_w.sum(axis=0), 9), (4 / 9 + 8 / 9) / 0.5, rtol=1e-6)
    # Leave the one that disagrees (n = 5, at weight 0.5) out of three that agree, one at weight 0.5.
    w4 = stack([1.0, 1.0, 0.5, 0.5])
    a4 = np.concatenate([2.0 * w4[:3], 5.0 * w4[3:]])
    s2 = weighted_square(a4, w4).sum(axis=0)
    np.testing.assert_allclose(lcn_leave_one_out(a4.sum(axis=0), s2, w4.sum(axis=0), a4[3], w4[3]), 0.0, atol=1e-6)
    cost, own = np.empty((1, 3), np.float32), np.empty((1, 3), np.float32)
    seen = np.ones((1, 3), bool)
    compiled_kernels().pair_terms(two[0], two_w[0], two[1], two_w[1], seen, floor, cost, own)
    np.testing.assert_allclose(cost, (4 / 9 + 8 / 9) / 0.5, rtol=1e-6)
    g = [np.float32(x) for x in (1.0, 1.0, 0.5, 0.25)]
    c, ok = fused_volume._lcn_of_four(*(np.float32(2.0) * x for x in g), *g, np.float32(sum(g)), floor, np.float32(1.0))
    assert ok == 1.0 and abs(c) < 1e-6, c
    t, flags, cn = (np.empty(3, np.float32) for _ in range(3))
    fused_volume._lcn_two(two[0, 0], two[1, 0], two_w[0, 0], two_w[1, 0], floor, np.ones(3, np.float32), cn, t, flags)
    np.testing.assert_allclose(t, (4 / 9 + 8 / 9) / 0.5, rtol=1e-6)


def test_the_torch_twin_weighs_the_squares_as_the_numpy_cost():
    torch = pytest.importorskip("torch", reason="the torch extra is not installed")
    from lfring.depth.costs.lcn import lcn_slice_cost, lcn_slice_cost_torch

    rng = np.random.default_rng(3)
    w = rng.random((4, 5, 6)).astype(np.float32)
    a = (w * rng.normal(size=(4, 5, 6))).astype(np.float32)
    want = lcn_slice_cost(a, w, w.sum(axis=0), 9)
    got = lcn_slice_cost_torch(torch, torch.from_numpy(a)[None], torch.from_numpy(w)[None], torch.from_numpy(w.sum(axis=0))[None], None)
    np.testing.assert_allclose(got[0].numpy(), want, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("all_valid", [True, False])
def test_the_four_view_row_kernels_sum_as_the_general_one(all_valid):
    """The fused engine's four-view row kernels skip the divisions where every view weighs 1 (and,
    for all-valid views, 0) and divide only elsewhere: their costs, flags and weights' sums are
    the general kernel's (every view's row sampled, then summed one view at a time, every square
    divided by its weight) up to rounding, on random shifts that put views partly outside the
    frame, and masks whose runs of ones start at the first column, end at the last, are empty or
    do not overlap, with tapered rims."""
    from lfring.core.viewstack import WEIGHT_FLOOR
    from lfring.depth.engines import fused, fused_volume

    rng = np.random.default_rng(11)
    v, h, w, n, pad = 4, 24, 300, 5, 12
    hp, wp = h + 2 * pad + 1, w + 2 * pad + 1
    src = np.zeros((v, hp, wp), np.float32)
    src[:, pad:pad + h, pad:pad + w] = rng.normal(size=(v, h, w)).astype(np.float32)
    shifts = rng.uniform(-pad + 1.5, pad - 1.5, (n, v, 2))
    shifts[0, :, :] = np.round(shifts[0])  # whole-pixel shifts too
    iy = np.floor(shifts[..., 1]).astype(np.int64)
    ix = np.floor(shifts[..., 0]).astype(np.int64)
    fy = (shifts[..., 1] - iy).astype(np.float32)
    fx = (shifts[..., 0] - ix).astype(np.float32)
    if all_valid:
        msk = src
        edge_y, edge_x = fused._edges(shifts[..., 1], h), fused._edges(shifts[..., 0], w)
        ones_lo, ones_hi = fused._runs_of_ones(edge_x)
    else:
        msk = np.zeros((v, hp, wp), np.float32)
        for k in range(v):
            for r in range(pad, pad + h):
                lo, hi = sorted(rng.integers(pad - 3, pad + w + 3, 2))
                kind = rng.integers(5)
                if kind == 0:
                    lo = pad  # the run from the first column
                elif kind == 1:
                    hi = pad + w  # to the last
                elif kind == 2:
                    hi = lo  # none
                msk[k, r, lo:hi] = 1.0
                for j in range(1, 4):  # tapered rims
                    if lo - j >= 0:
                        msk[k, r, lo - j] = 1.0 - j / 4
                    if hi - 1 + j < wp:
                        msk[k, r, hi - 1 + j] = 1.0 - j / 4
            msk[k, :, :pad] = msk[k, :, pad + w:] = 0.0
        src = src * msk
        edge_y = edge_x = np.zeros((1, 1, 1), np.float32)
        ones_lo, ones_hi = fused._runs_of_ones(msk)
    views = np.arange(v, dtype=np.int64)
    floor = np.float32(WEIGHT_FLOOR)
    ones = np.ones(w, np.float32)
    a_buf, w_buf = np.empty((v, w), np.float32), np.empty((v, w), np.float32)
    s1, s2, cn = (np.empty(w, np.float32) for _ in range(3))
    kernel = fused_volume._all_terms_valid_four if all_valid else fused_volume._all_terms_masked_four
    tested = 0
    for d in range(n):
        for y in range(h):
            want_t, want_seen = np.empty(w, np.float32), np.empty(w, np.float32)
            fused_volume._view_span(src, msk, all_valid, edge_y, edge_x, iy, ix, fy, fx, pad, ones_lo, ones_hi, y, d, views,
                                    0, w, 0, a_buf, w_buf)
            # The general kernel's samples and weights: bilinear shifts of the padded rows.
            for k in range(v):
                r, c = y + iy[d, k] + pad, ix[d, k] + pad + np.arange(w)
                a, b = np.float64(fx[d, k]), np.float64(fy[d, k])

                def bilinear(img):
                    img = img.astype(np.float64)
                    return ((1 - b) * ((1 - a) * img[r, c] + a * img[r, c + 1])
                            + b * ((1 - a) * img[r + 1, c] + a * img[r + 1, c + 1]))

                np.testing.assert_allclose(a_buf[k], bilinear(src[k]), rtol=1e-5, atol=1e-5)
                weight = edge_y[d, k, y] * edge_x[d, k, :w] if all_valid else bilinear(msk[k])
                np.testing.assert_allclose(w_buf[k], weight, rtol=1e-5, atol=1e-6)
            fused_volume._all_terms(a_buf, w_buf, floor, ones, s1, s2, cn, want_t, want_seen)
            want_cn = cn.copy()
            got_t, got_seen, got_cn = (np.full(w, np.nan, np.float32) for _ in range(3))
            if all_valid:
                kernel(src, edge_y, edge_x, iy, ix, fy, fx, pad, ones_lo, ones_hi, y, d, views, floor, ones, got_cn, got_t,
                       got_seen)
            else:
                kernel(src, msk, ones_lo, ones_hi, iy, ix, fy, fx, pad, y, d, views, floor, ones, got_cn, got_t, got_seen)
            np.testing.assert_array_equal(got_seen, want_seen)
            np.testing.assert_array_equal(got_cn, want_cn)
            np.testing.assert_allclose(got_t, want_t, rtol=1e-5, atol=1e-5)
            tested += int((want_seen > 0).sum())
    assert tested > 0.3 * n * h * w  # most columns carry a cost: the comparison means something


def test_lcn_sources_are_the_locally_normalised_luminance(monkeypatch):
    """Each view's 'lcn' source against its definition written in NumPy (float64): the masked
    luminance's window mean and mean square over the window's seen share of the disc (its mask
    without the rim's taper; reflected at the borders), n = (L - mu) / sqrt(max(E[L^2] - mu^2, 0)
    + eps mu^2 + floor), on disc views (their rims seen in part), with a flat patch (where eps mu^2 is the whole variance) and a dark one
    of faint texture (where the floor is a fifth of it), in strips of 8 rows with their halos."""
    from lfring.calibration import RingCalibration
    from lfring.depth.costs import lcn as lcn_module
    from lfring.depth.costs.lcn import LCN_EPS, LCN_FLOOR, LCN_STATS_TAPER, lcn_sources
    from lfring.depth.plan import sweep_masks
    from lfring.optics import load_device
    from lfring.views import layout_from_circles

    dev = load_device("prototype")
    w, h = dev.sensor_width_px, dev.sensor_height_px
    side = 64
    circles = [(200.0 + dx, 150.0 + dy, side / 2) for dy in (0, h / 2) for dx in (0, w / 2)]
    cal = RingCalibration.from_optics(dev, layout=layout_from_circles(circles, w, h))
    rng = np.random.default_rng(5)
    views = rng.random((4, side, side, 3)).astype(np.float32)
    views[:, 16:30, 20:40] = 0.25  # flat
    views[:, 40:52, 14:30] = 0.02 + 0.0005 * rng.random((4, 12, 16, 3))  # dark, faint texture
    window = 9
    monkeypatch.setattr(lcn_module, "STRIP_PIXELS", 16 * side)  # strips of 8 rows
    got = lcn_sources(views, cal, window, threads=2)

    masks = sweep_masks(cal, (side, side), LCN_STATS_TAPER).astype(np.float64)
    lum = views.astype(np.float64).mean(axis=3)
    pad = window // 2

    def box(img):  # the window's sum, reflected at the borders as OpenCV's BORDER_REFLECT_101
        p = np.pad(img, pad, mode="reflect")
        return sum(p[i:i + side, j:j + side] for i in range(window) for j in range(window))

    for k in range(4):
        seen = box(masks[k])
        mu = np.where(seen > 0, box(lum[k] * masks[k]) / np.maximum(seen, 1e-300), 0.0)
        msq = np.where(seen > 0, box(lum[k] ** 2 * masks[k]) / np.maximum(seen, 1e-300), 0.0)
        want = (lum[k] - mu) / np.sqrt(np.maximum(msq - mu ** 2, 0.0) + LCN_EPS * mu ** 2 + LCN_FLOOR)
        inside = seen > 1.0  # a pixel's worth of the window seen: above the weights' floor
        assert inside.mean() > 0.7
        np.testing.assert_allclose(got[k][inside], want[inside], rtol=2e-4, atol=2e-4)


def test_lcn_sources_do_not_lean_with_the_rim_taper():
    """Inside a view's rim taper, where a pixel's whole window lies in the disc, its 'lcn' source
    is the plain local normalisation, as anywhere inside. Statistics weighted by the taper leaned
    towards the disc's centre, so that on a sloped luminance each view's image moved by a
    fraction of a pixel near its rim, and where two views saw a slant the best depth with it."""
    import cv2

    from lfring.calibration import RingCalibration
    from lfring.depth.costs.lcn import LCN_EPS, LCN_FLOOR, lcn_sources
    from lfring.depth.plan import DEPTH_TAPER
    from lfring.optics import load_device
    from lfring.views import layout_from_circles

    dev = load_device("prototype")
    w, h = dev.sensor_width_px, dev.sensor_height_px
    r = 202.0
    side = int(2 * r)
    circles = [(260.0 + dx, 260.0 + dy, r) for dy in (0, h / 2) for dx in (0, w / 2)]
    cal = RingCalibration.from_optics(dev, layout=layout_from_circles(circles, w, h))
    rng = np.random.default_rng(11)
    yy, xx = np.mgrid[0:side, 0:side].astype(np.float32)
    ramp = 0.1 + 0.8 * (xx + 0.5 * yy) / (1.5 * side)  # a slope, and texture on it
    views = np.repeat((ramp + 0.03 * rng.random((4, side, side)).astype(np.float32))[..., None], 3, axis=3)
    window = 9
    got = lcn_sources(views, cal, window, threads=2)

    lum = views.astype(np.float64).mean(axis=3)
    cx = cy = (side - 1) / 2.0  # each view cut centred on its disc
    dist = np.hypot(xx - cx, yy - cy)
    # In the taper and the window inside the disc (its mask 1 to half a pixel of the rim).
    ring = (dist > r - DEPTH_TAPER * r) & (dist < r - 0.5 - np.sqrt(2) * (window // 2) - 1)
    assert ring.sum() > 1000
    for k in range(4):
        mu = cv2.blur(lum[k], (window, window))
        msq = cv2.blur(lum[k] ** 2, (window, window))
        want = (lum[k] - mu) / np.sqrt(np.maximum(msq - mu ** 2, 0.0) + LCN_EPS * mu ** 2 + LCN_FLOOR)
        np.testing.assert_allclose(got[k][ring], want[ring], rtol=1e-4, atol=1e-4)
