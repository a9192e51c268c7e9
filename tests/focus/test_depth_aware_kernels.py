"""The depth-aware renderer's compiled passes against plain NumPy versions of the same rules."""

import cv2
import numpy as np
import pytest

from lfring.core.viewstack import WEIGHT_FLOOR
from lfring.focus import depth_aware_kernels as kern
from lfring.focus.depth_aware import AGREE_TOL, SPREAD_TOL, VISIBLE_VIEWS


def _robust_mean_numpy(warped, weight, visible):
    """The views' robust mean, written array by array (the rules of ``kern.robust_mean``)."""
    present = weight > WEIGHT_FLOOR
    visible = visible & present
    hidden = np.clip(1.0 - (weight * visible).sum(axis=0) / VISIBLE_VIEWS, 0.0, 1.0)
    scale = np.where(visible, 1.0, np.where(present, hidden, 0.0))
    lum = np.divide(warped.mean(axis=3), weight, out=np.zeros(weight.shape), where=present)
    wv = weight * scale
    close = np.exp(-0.5 * ((lum[:, None] - lum[None, :]) / AGREE_TOL) ** 2)
    support = np.einsum("jvhw,jhw->vhw", close, wv) ** 4 * wv
    total = support.sum(axis=0)
    mean_lum = (wv * lum).sum(axis=0) / np.maximum(wv.sum(axis=0), WEIGHT_FLOOR)
    med = np.where(total > 0, (support * lum).sum(axis=0) / np.maximum(total, 1e-30), mean_lum)
    dev = np.abs(lum - med)
    spread = np.sqrt((wv * dev * dev).sum(axis=0) / np.maximum(wv.sum(axis=0), WEIGHT_FLOOR))
    tol = np.maximum(AGREE_TOL, SPREAD_TOL * spread)
    phi = np.where(wv > 0, np.clip(2.0 - dev / tol, 0.0, 1.0) * scale, 0.0)
    dis = np.clip(dev / AGREE_TOL - 1.0, 0.0, 1.0) * np.clip(weight, 0.0, 1.0)
    agree = np.where(present.any(axis=0), np.where(present, 1.0 - dis, 1.0).min(axis=0), 0.0)
    num = np.einsum("vhw,vhwc->hwc", phi, warped)
    den = (phi * weight).sum(axis=0)
    seen = den > WEIGHT_FLOOR
    colour = np.where(seen[..., None], num / np.where(seen, den, 1.0)[..., None], 0.0)
    return colour, agree, seen


@pytest.mark.parametrize("channels", [1, 3])
def test_robust_mean_matches_the_array_rules(channels):
    rng = np.random.default_rng(7)
    v, h, w = 4, 24, 32
    base = rng.random((1, h, w, channels))
    # Views that agree up to noise, one that sees something else on a third of the pixels, a
    # weight that fades at a rim and is zero in a corner, and occlusions.
    views = base + 0.01 * rng.standard_normal((v, h, w, channels))
    views[2, :, : w // 3] += 0.5
    weight = np.clip(rng.random((v, h, w)) * 3.0, 0.0, 1.0)
    weight[:, :4, :4] = 0.0
    weight[1, :, -5:] = np.linspace(1.0, 0.0, 5)
    visible = rng.random((v, h, w)) > 0.1
    visible[:, 5, :] = False  # no view visible: the present ones count
    warped = (views * weight[..., None]).astype(np.float32)
    weight = weight.astype(np.float32)
    colour = np.empty((h, w, channels), np.float32)
    agree = np.empty((h, w), np.float32)
    seen = np.empty((h, w), bool)
    kern.robust_mean(warped, weight, visible, AGREE_TOL, SPREAD_TOL, VISIBLE_VIEWS, WEIGHT_FLOOR, colour, agree, seen)
    want_colour, want_agree, want_seen = _robust_mean_numpy(warped.astype(np.float64), weight.astype(np.float64), visible)
    assert np.array_equal(seen, want_seen) and seen.mean() > 0.9 and not seen[:4, :4].any()
    np.testing.assert_allclose(colour, want_colour, atol=1e-5)
    np.testing.assert_allclose(agree, want_agree, atol=1e-5)
    # Where all four views see the pixel well, the odd one is left out: the colour is the
    # others' (the base), and the views do not agree.
    clear = (visible & (weight > 0.9)).all(axis=0)
    odd, rest = clear.copy(), clear.copy()
    odd[:, w // 3:] = False
    rest[:, : w // 3] = False
    assert odd.sum() > 20 and rest.sum() > 20
    assert np.abs(colour[odd] - base[0][odd]).max() < 0.05
    assert agree[odd].max() < 0.15 and agree[rest].min() > 0.9


def test_robust_mean_a_view_grazing_with_its_rim_does_not_outvote_a_hidden_one():
    # A whole view that the depth map calls hidden, and another that sees the pixel only with the
    # darkened rim of its disc (weight w): the hidden one counts by 1 - w / VISIBLE_VIEWS, so the
    # colour is the whole view's while w is small; from w = VISIBLE_VIEWS on it is left out.
    c = 3
    rim = np.array([0.01, 0.02, 0.1, 0.4, 0.6, 0.99, 1.0]) * VISIBLE_VIEWS  # the least well above WEIGHT_FLOOR
    rim[-1] = 1.0
    n = rim.size
    weight = np.zeros((4, 1, n), np.float32)
    weight[0, 0] = 1.0
    weight[1, 0] = rim
    value = np.zeros((4, 1, n, c))
    value[0], value[1] = 0.7, 0.35
    visible = np.ones((4, 1, n), bool)
    visible[0] = False
    warped = (value * weight[..., None]).astype(np.float32)
    colour = np.empty((1, n, c), np.float32)
    agree = np.empty((1, n), np.float32)
    seen = np.empty((1, n), bool)
    kern.robust_mean(warped, weight, visible, AGREE_TOL, SPREAD_TOL, VISIBLE_VIEWS, WEIGHT_FLOOR, colour, agree, seen)
    assert seen.all()
    np.testing.assert_allclose(colour, _robust_mean_numpy(warped.astype(np.float64), weight.astype(np.float64), visible)[0],
                               atol=1e-5)
    got = colour[0, :, 0]
    # Up to a tenth of VISIBLE_VIEWS at the rim, the colour stays within 0.01 of the whole view's.
    assert np.abs(got[:3] - 0.7).max() < 0.01
    # With VISIBLE_VIEWS visible (or all but), the hidden one is left out.
    np.testing.assert_allclose(got[-1], 0.35, atol=1e-6)
    assert abs(got[-2] - 0.35) < 0.01
    # In between, the colour moves from the whole view's to the rim view's, never back, and not
    # in one jump.
    assert np.all(np.diff(got) <= 1e-6) and np.any((got > 0.4) & (got < 0.65))

def test_occluded_is_a_nearer_surface_at_the_rounded_view_pixel():
    rng = np.random.default_rng(3)
    h, w = 20, 30
    x = rng.random((h, w)).astype(np.float32)
    nearest = rng.random((h, w)).astype(np.float32)
    my, mx = np.mgrid[0:h, 0:w].astype(np.float32)
    mx = mx + rng.uniform(-3.0, 3.0, (h, w)).astype(np.float32)
    my = my + rng.uniform(-3.0, 3.0, (h, w)).astype(np.float32)
    out = np.empty((h, w), bool)
    kern.occluded(mx, my, x, nearest, 0.1, out)
    u, vv = np.rint(mx).astype(int), np.rint(my).astype(int)
    inside = (u >= 0) & (u < w) & (vv >= 0) & (vv < h)
    want = np.zeros((h, w), bool)
    want[inside] = nearest[vv[inside], u[inside]] > x[inside] + 0.1
    assert np.array_equal(out, want) and want.any() and (~inside).any() and not out[~inside].any()


def test_splat_max_keeps_the_nearest_of_the_pixels_that_land_together():
    """Every view on its own (they run in parallel), each the largest x of the pixels that land
    on a view pixel, as np.maximum.at gives it."""
    rng = np.random.default_rng(5)
    h, w = 20, 30
    x = rng.random((h, w)).astype(np.float32)
    my, mx = np.mgrid[0:h, 0:w].astype(np.float32)
    mx = np.stack([mx * 0.5 + rng.uniform(-2.0, 2.0, (h, w)),  # about two pixels on each view pixel
                   mx + rng.uniform(-1.0, 1.0, (h, w))]).astype(np.float32)
    my = np.stack([my + rng.uniform(-2.0, 2.0, (h, w)), my - 3.0]).astype(np.float32)
    out = np.full((2, h, w), -np.inf, np.float32)
    kern.splat_max(mx, my, x, out)
    for k in range(2):
        u, vv = np.rint(mx[k]).astype(int).ravel(), np.rint(my[k]).astype(int).ravel()
        inside = (u >= 0) & (u < w) & (vv >= 0) & (vv < h)
        want = np.full(h * w, -np.inf, np.float32)
        np.maximum.at(want, (vv * w + u)[inside], x.ravel()[inside])
        assert np.array_equal(out[k].ravel(), want)
    assert np.isinf(out[0, :, -5:]).all() and np.isfinite(out[0, :, 5:10]).mean() > 0.8
    assert np.isinf(out[1, -3:]).all() and np.isfinite(out[1, :-3]).mean() > 0.6


def test_shift_maps_are_the_index_plus_the_shift_plus_the_slope_times_x():
    """The translation case of the renderer's sampling maps, against its NumPy formula in
    float32, to the bit."""
    rng = np.random.default_rng(8)
    h, w, v = 9, 14, 3
    x = rng.uniform(0.5, 3.0, (h, w)).astype(np.float32)
    shift = rng.uniform(-5.0, 5.0, (v, 2)).astype(np.float32)
    slope = rng.uniform(-4.0, 4.0, (v, 2)).astype(np.float32)
    x0 = np.float32(0.5)
    map_x = np.empty((v, h, w), np.float32)
    map_y = np.empty((v, h, w), np.float32)
    kern.shift_maps(x, x0, shift, slope, map_x, map_y)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    dx = x - x0
    for k in range(v):
        assert np.array_equal(map_x[k], xx + shift[k, 0] + dx * slope[k, 0])
        assert np.array_equal(map_y[k], yy + shift[k, 1] + dx * slope[k, 1])


def test_knot_maps_interpolate_the_knots_homographies_linearly_in_x():
    from lfring.core.geometry import apply_homography

    rng = np.random.default_rng(11)
    h, w, v = 12, 17, 3
    knots = np.linspace(0.5, 2.0, 5)
    inv = np.tile(np.eye(3), (5, v, 1, 1))
    inv[:, :, :2, 2] = knots[:, None, None] * rng.uniform(-3.0, 3.0, (1, v, 2))  # shifts growing with x
    inv[:, :, 2, :2] = rng.uniform(-1e-3, 1e-3, (5, v, 2))  # and a little perspective
    x = rng.uniform(0.5, 2.0, (h, w)).astype(np.float32)
    x[0, :5] = knots[:5]  # on the knots themselves
    map_x = np.empty((v, h, w), np.float32)
    map_y = np.empty((v, h, w), np.float32)
    kern.knot_maps(x, knots, inv, map_x, map_y)
    yy, xx = np.mgrid[0:h, 0:w]
    pts = np.stack([xx.ravel(), yy.ravel()], axis=1).astype(np.float64)
    seg = np.clip(np.searchsorted(knots, x.ravel(), side="right") - 1, 0, len(knots) - 2)
    t = ((x.ravel() - knots[seg]) / (knots[seg + 1] - knots[seg]))[:, None]
    for k in range(v):
        a = np.array([apply_homography(inv[j, k], p) for j, p in zip(seg, pts)])
        b = np.array([apply_homography(inv[j + 1, k], p) for j, p in zip(seg, pts)])
        want = a + t * (b - a)
        np.testing.assert_allclose(map_x[k].ravel(), want[:, 0], atol=1e-4)
        np.testing.assert_allclose(map_y[k].ravel(), want[:, 1], atol=1e-4)


@pytest.mark.parametrize("channels", [1, 3])
@pytest.mark.parametrize("n", [0, 1, 8])
def test_rungs_are_np_interp_of_the_moments_and_boxes_of_their_pixels(n, channels):
    """Every pixel's signed fractional rung is ``np.interp`` of its blur's second moment in the
    ladder's moments (the top rung past the last, and for a NaN depth), its share of the
    shift-and-add image the ramp where that image has a colour; each stripe's box of a signed rung
    holds exactly the pixels of the window that go to that rung. Smooth depth (long runs of the same
    rungs), jumps, NaN, uncovered pixels and pixels without a shift-and-add colour."""
    rng = np.random.default_rng(3 + n)
    h, w, stripe = 70, 90, 16
    xx = np.linspace(-1.0, 3.0, w)[None, :] + np.zeros((h, 1))
    x = np.where(rng.random((h, w)) < 0.1, rng.uniform(-1.0, 3.0, (h, w)), xx).astype(np.float32)
    x[rng.random((h, w)) < 0.02] = np.nan
    agree = rng.random((h, w)).astype(np.float32)
    cover = rng.random((h, w)).astype(np.float32)
    cover[cover < 0.15] = 0.0
    sharp = rng.random((h, w, channels)).astype(np.float32)
    sharp[rng.random((h, w)) < 0.3] = 0.0
    moments = np.cumsum(np.r_[0.0, rng.uniform(0.2, 1.5, n)])
    window = np.array([3, h - 5, 4, w - 2], np.int64)
    x_f, motion, aperture, sharp_px, ramp_px, share_px2 = 1.1, 1.7, 0.8, 0.5, 1.0, 0.08
    if n > 1:  # pixels whose moment is exactly one of the moments (a whole rung)
        d = motion * (np.float64(x[10, 20]) - x_f)
        moments[1] = 0.5 * (aperture * d) ** 2
        cover[10, 20], sharp[10, 20] = 1.0, 0.0
        moments = np.sort(moments)
    q = np.full((h, w), -7.0, np.float32)
    s = np.full((h, w), -7.0, np.float32)
    boxes = np.empty(((h + stripe - 1) // stripe, 2 * n + 1, 4), np.int64)
    boxes[..., 0::2] = np.iinfo(np.int64).max
    boxes[..., 1::2] = -1
    kern.rungs(x, agree, cover, sharp, window, x_f, motion, aperture, sharp_px, ramp_px, share_px2, moments, stripe, q, s,
               boxes)

    r0, r1, c0, c1 = window
    inside = np.zeros((h, w), bool)
    inside[r0:r1, c0:c1] = True
    on = inside & (cover > 0)
    d = motion * (x.astype(np.float64) - x_f)
    rho = aperture * d
    has = (sharp != 0).any(axis=2)
    share = np.where(has, np.clip((sharp_px + ramp_px - np.abs(d)) / ramp_px, 0, 1) * agree, 0.0)
    m = np.maximum(0.5 * rho * rho - share * (d * d + share_px2), 0.0)
    frac = np.where(np.isnan(m) | (m > moments[-1]), float(n), np.interp(np.nan_to_num(m), moments, np.arange(n + 1.0)))
    want_q = np.where(rho < 0, -frac, frac)
    np.testing.assert_allclose(q[on], want_q[on], rtol=0, atol=1e-5)
    np.testing.assert_array_equal(s[on], share[on].astype(np.float32))
    assert (q[inside & ~on] == 0).all() and (s[inside & ~on] == 0).all() and (q[~inside] == -7).all()
    # Each pixel goes to the rung below its fraction, and to the next one up where it lies between.
    qa = np.abs(q.astype(np.float64))
    lo = np.floor(qa).astype(int)
    sign = np.where(q < 0, -1, 1)
    two = (qa > lo) & (lo < n)
    for b in range(boxes.shape[0]):
        band = np.zeros((h, w), bool)
        band[b * stripe:(b + 1) * stripe] = True
        for k in range(2 * n + 1):
            mine = on & band & ((n + sign * lo == k) | (two & (n + sign * (lo + 1) == k)))
            if not mine.any():
                assert boxes[b, k, 1] == -1 and boxes[b, k, 3] == -1
                continue
            rows, cols = np.nonzero(mine)
            assert tuple(boxes[b, k]) == (rows.min(), rows.max(), cols.min(), cols.max())


def _scatter_numpy(colour, sharp, s, cover, q, window, n, shift, y0, x0, rows, cols):
    """Each rung's cells (rows, cols, C + 1) by the array rules in float32, a reduced cell's
    pixels added one by one, row by row and left to right, as the scatter adds them."""
    h, w, c = colour.shape
    r0, r1, c0, c1 = window
    share_s = s[..., None]
    mixed = np.where(share_s > 0, colour + share_s * (sharp - colour), colour) if sharp.size else colour
    v = np.concatenate([mixed * cover[..., None], cover[..., None]], axis=2)
    qa = np.abs(q)
    lo = np.floor(qa).astype(int)
    t = qa - lo.astype(np.float32)  # exact
    sign = np.where(q < 0, -1, 1)
    out = [np.zeros((rows[k], cols[k], c + 1), np.float32) for k in range(2 * n + 1)]
    for y in range(r0, r1):
        for x in range(c0, c1):
            if not cover[y, x] > 0:
                continue
            pairs = [(n + sign[y, x] * lo[y, x], np.float32(1) - t[y, x])]
            if t[y, x] > 0 and lo[y, x] < n:
                pairs.append((n + sign[y, x] * (lo[y, x] + 1), t[y, x]))
            for k, share in pairs:
                f = shift[k]
                cell = (y >> f) - (y0[k] >> f), (x >> f) - (x0[k] >> f)
                if f == 0:
                    out[k][cell] = np.float32(0) + share * v[y, x]
                else:
                    out[k][cell] = out[k][cell] + (share * np.float32(0.25 ** f)) * v[y, x]
    return out


# RGB's cells (4 values) and a single channel's (2) run loops compiled apart.
@pytest.mark.parametrize("channels", [1, 3])
@pytest.mark.parametrize("with_sharp", [True, False])
@pytest.mark.parametrize("n", [0, 4])
def test_scatter_shares_every_pixel_between_its_two_rungs_on_their_grids(channels, with_sharp, n):
    """Every covered pixel of the window adds its premultiplied colour (mixed with the
    shift-and-add image by its share) and its coverage to the rung below its fractional rung
    (1 - t) and the one above (t), on each rung's grid (full resolution, reduced 2, 4 and 8 times:
    area averages, a cell's pixels added in order); a full-resolution box is written whole (its
    cells no pixel reaches are zeros though ``buf`` held NaN there, its rows outside the window
    too), a reduced one adds to the zeros it holds. Equal to the bit to the same float32 sums.
    Rungs on either side of the focus, integer rungs (one rung), the top rung, a single rung,
    pixels not covered (cover 0 or below), an infinite and a NaN value (they stay in their own
    pixel's rungs), boxes reaching past the window."""
    rng = np.random.default_rng(17 + channels + 2 * with_sharp + n)
    h, w, stripe = 50, 70, 16
    colour = rng.random((h, w, channels)).astype(np.float32)
    sharp = rng.random((h, w, channels)).astype(np.float32) if with_sharp else np.zeros((0, 0, 0), np.float32)
    s = np.where(rng.random((h, w)) < 0.5, rng.random((h, w)), 0.0).astype(np.float32)
    cover = rng.random((h, w)).astype(np.float32)
    cover[cover < 0.15] = 0.0
    cover[rng.random((h, w)) < 0.03] = -0.5
    # Smooth rungs (long runs) with jumps, whole numbers and the top rung.
    q = (np.linspace(-n, n, w)[None, :] + np.zeros((h, 1))).astype(np.float32)
    jump = rng.random((h, w)) < 0.1
    q[jump] = rng.uniform(-n, n, jump.sum()).astype(np.float32)
    whole = rng.random((h, w)) < 0.1
    q[whole] = np.round(q[whole])
    q[:, :3] = -n
    window = np.array([5, h - 7, 3, w - 4], np.int64)
    r0, r1, c0, c1 = window
    # Values that must not spread: an infinite colour at a covered pixel on a whole rung (one
    # rung), a NaN shift-and-add mixed in by a share above 0; an infinite colour where nothing
    # covers and a NaN shift-and-add with a share of 0 (not mixed in) must not appear at all.
    colour[20, 30, 0], cover[20, 30], q[20, 30] = np.inf, 0.7, 0.0
    if with_sharp:
        sharp[25, 10, -1] = np.nan
        cover[25, 10], s[25, 10] = 0.6, 0.5
        sharp[26, 12, 0] = np.nan
        cover[26, 12], s[26, 12] = 0.6, 0.0
    colour[30, 40, 0], cover[30, 40] = np.inf, 0.0
    shift = np.array([3, 2, 1, 0, 0, 0, 1, 2, 3], np.int64)[4 - n:5 + n]
    nk = 2 * n + 1
    y0, x0, rows, cols, offset = (np.zeros(nk, np.int64) for _ in range(5))
    qa = np.abs(q.astype(np.float64))
    lo = np.floor(qa).astype(int)
    sign = np.where(q < 0, -1, 1)
    on = np.zeros((h, w), bool)
    on[r0:r1, c0:c1] = cover[r0:r1, c0:c1] > 0
    total = 0
    for k in range(nk):
        mine = on & ((n + sign * lo == k) | ((qa > lo) & (lo < n) & (n + sign * (lo + 1) == k)))
        if not mine.any():
            continue
        ys, xs = np.nonzero(mine)
        f = 1 << shift[k]
        pad = 2  # boxes reach past the window's rows and columns
        ya, yb = max(0, ys.min() - pad) // f * f, -(-(ys.max() + pad + 1) // f) * f
        xa, xb = max(0, xs.min() - pad) // f * f, -(-(xs.max() + pad + 1) // f) * f
        y0[k], x0[k], rows[k], cols[k], offset[k] = ya, xa, (yb - ya) // f, (xb - xa) // f, total
        total += (channels + 1) * rows[k] * cols[k]
    assert set(shift[rows > 0]) == ({0} if n == 0 else {0, 1, 2, 3})
    buf = np.full(total + 8, np.nan, np.float32)  # 8 past the end: left as they are
    for k in range(nk):
        if shift[k] > 0:
            buf[offset[k]:offset[k] + (channels + 1) * rows[k] * cols[k]] = 0.0
    kern.scatter(colour, sharp, s, cover, q, window, n, shift, y0, x0, rows, cols, offset, stripe, buf)
    with np.errstate(invalid="ignore"):  # the infinite colour times a cover of 0
        want = _scatter_numpy(colour, sharp, s, cover, q, window, n, shift, y0, x0, rows, cols)
    for k in range(nk):
        got = buf[offset[k]:offset[k] + (channels + 1) * rows[k] * cols[k]].reshape(rows[k], cols[k], channels + 1)
        np.testing.assert_array_equal(got, want[k], err_msg=f"rung {k}")
    assert np.isnan(buf[total:]).all()
    # The infinite value reached its pixel's one rung, the mixed NaN its pixel's rungs (one
    # value a cell), nothing else.
    assert 1 <= (~np.isfinite(buf[:total])).sum() <= (3 if with_sharp else 1)


def _placed(shape, arr, y0, x0):
    """``arr`` placed at (y0, x0) of a zero array of ``shape`` (the part inside it), and where."""
    out = np.zeros(shape + arr.shape[2:], arr.dtype)
    inside = np.zeros(shape, bool)
    ya, yb = max(0, y0), min(shape[0], y0 + arr.shape[0])
    xa, xb = max(0, x0), min(shape[1], x0 + arr.shape[1])
    out[ya:yb, xa:xb] = arr[ya - y0:yb - y0, xa - x0:xb - x0]
    inside[ya:yb, xa:xb] = True
    return out, inside


def test_the_maps_at_listed_pixels_are_the_whole_grids_there():
    """``shift_maps_at`` and ``knot_maps_at`` (the background's samples) give, to the bit, the
    values of ``shift_maps`` and ``knot_maps`` at the listed pixels, in any order, repeated."""
    rng = np.random.default_rng(12)
    h, w, v = 23, 31, 4
    x = rng.uniform(0.5, 2.0, (h, w)).astype(np.float32)
    rows = rng.integers(0, h, 300)
    cols = rng.integers(0, w, 300)
    rows[:3], cols[:3] = (0, h - 1, h - 1), (0, w - 1, 0)  # the corners, and a pixel twice
    rows[3], cols[3] = rows[4], cols[4]
    xs = np.ascontiguousarray(x[rows, cols])
    shift = rng.uniform(-5.0, 5.0, (v, 2)).astype(np.float32)
    slope = rng.uniform(-4.0, 4.0, (v, 2)).astype(np.float32)
    knots = np.linspace(0.5, 2.0, 7)
    inv = np.tile(np.eye(3), (7, v, 1, 1))
    inv[:, :, :2, 2] = knots[:, None, None] * rng.uniform(-3.0, 3.0, (1, v, 2))
    inv[:, :, 2, :2] = rng.uniform(-1e-3, 1e-3, (7, v, 2))
    inv[:, :, :2, :2] += rng.uniform(-0.01, 0.01, (7, v, 2, 2))
    grid_x, grid_y = np.empty((v, h, w), np.float32), np.empty((v, h, w), np.float32)
    at_x, at_y = np.empty((v, rows.size), np.float32), np.empty((v, rows.size), np.float32)
    kern.shift_maps(x, np.float32(0.5), shift, slope, grid_x, grid_y)
    kern.shift_maps_at(rows, cols, xs, np.float32(0.5), shift, slope, at_x, at_y)
    assert np.array_equal(at_x, grid_x[:, rows, cols]) and np.array_equal(at_y, grid_y[:, rows, cols])
    kern.knot_maps(x, knots, inv, grid_x, grid_y)
    kern.knot_maps_at(rows, cols, xs, knots, inv, at_x, at_y)
    assert np.array_equal(at_x, grid_x[:, rows, cols]) and np.array_equal(at_y, grid_y[:, rows, cols])
    # And the grid's are not all alike: the test would see a pixel taken for another.
    assert np.unique(grid_x[0]).size > 0.9 * h * w


# RGB's cells (4 values) and a single channel's (2) run loops compiled apart.
@pytest.mark.parametrize("channels", [1, 3])
def test_over_and_merge_composite_as_the_array_rules(channels):
    rng = np.random.default_rng(11 + channels)
    h, w, c1 = 30, 40, channels + 1
    acc0 = rng.random((h, w, c1)).astype(np.float32)
    layer = rng.random((12, 25, c1)).astype(np.float32)
    prev = rng.random((9, 14, c1)).astype(np.float32)
    oy, ox, py, px = 5, 7, 8, 20  # prev overlaps the layer's lower right part and reaches past it
    for first in (True, False):
        acc = acc0.copy()
        trans = rng.random((h, w)).astype(np.float32)
        skip = rng.random((h, w)).astype(np.float32)
        trans0, skip0 = trans.copy(), skip.copy()
        kern.over(acc, oy, ox, layer, prev, py, px, trans, skip, first)
        a = _placed((h, w), layer[..., -1:], oy, ox)[0]
        lay, on = _placed((h, w), layer, oy, ox)
        behind = _placed((h, w), prev, py, px)[0]
        want = np.where(on[..., None], (acc0 * (1 - a) + lay) + a * behind, acc0)
        np.testing.assert_allclose(acc, want, rtol=0, atol=1e-6)
        np.testing.assert_allclose(trans, np.where(on, trans0 * (1 - a[..., 0]), trans0), rtol=0, atol=1e-7)
        want_skip = a[..., 0] if first else skip0 * (1 - a[..., 0])
        np.testing.assert_allclose(skip, np.where(on, want_skip, skip0), rtol=0, atol=1e-7)
    # A layer reaching past the composite's bottom right corner (a reduced grid's last cells):
    # the cells inside composited, none written past the edge (a column past it would land in
    # the next row, a row past it in the memory after the composite, kept here to check).
    no_map = np.zeros((0, 0), np.float32)
    edge = rng.random((12, 25, c1)).astype(np.float32)
    memory = np.full(h * w * c1 + 40 * 40 * c1, -9.0, np.float32)
    acc = memory[:h * w * c1].reshape(h, w, c1)
    acc[:] = acc0
    kern.over(acc, h - 7, w - 10, edge, prev, py, px, no_map, no_map, False)
    a = _placed((h, w), edge[..., -1:], h - 7, w - 10)[0]
    lay, on = _placed((h, w), edge, h - 7, w - 10)
    behind = _placed((h, w), prev, py, px)[0]
    np.testing.assert_allclose(acc, np.where(on[..., None], (acc0 * (1 - a) + lay) + a * behind, acc0), rtol=0, atol=1e-6)
    assert (memory[h * w * c1:] == -9.0).all()
    # A group reaching past the composite's top left corner, with and without the skip term.
    group = rng.random((14, 20, c1)).astype(np.float32)
    trans_g = rng.random((14, 20)).astype(np.float32)
    skip_g = rng.random((14, 20)).astype(np.float32)
    for with_skip in (True, False):
        acc = acc0.copy()
        kern.merge(acc, -3, -4, group, trans_g, skip_g if with_skip else np.zeros((0, 0), np.float32), prev, py - 6, px - 12)
        g, on = _placed((h, w), group, -3, -4)
        t = _placed((h, w), trans_g[..., None], -3, -4)[0]
        sk = _placed((h, w), skip_g[..., None], -3, -4)[0] if with_skip else 0.0
        behind = _placed((h, w), prev, py - 6, px - 12)[0]
        want = np.where(on[..., None], (acc0 * t + g) + sk * behind, acc0)
        np.testing.assert_allclose(acc, want, rtol=0, atol=1e-6)


@pytest.mark.parametrize("channels", [1, 3])
def test_finish_divides_by_the_coverage_with_the_background_filling_it_and_clears_it_if_asked(channels):
    rng = np.random.default_rng(5 + channels)
    h, w, c1 = 20, 30, channels + 1
    acc = rng.random((h, w, c1)).astype(np.float32)
    acc[..., -1] = rng.uniform(-0.2, 1.3, (h, w))  # coverage past 0 and 1 on either side
    acc[2, :5, -1] = 0.0
    back = rng.random((8, 12, c1)).astype(np.float32)
    floor = np.float32(1e-3)
    for placed, clear in ((back, False), (np.zeros((0, 0, 0), np.float32), False), (back, True)):
        out = np.full((h, w, channels), -5.0, np.float32)
        mine = acc.copy()
        kern.finish(mine, placed, 1, 22, floor, out, clear)  # the background reaches past the right edge
        assert not mine.any() if clear else np.array_equal(mine, acc)  # cleared once read, or left
        alpha = acc[..., -1:]
        b, on = _placed((h, w), placed, 1, 22) if placed.size else (np.zeros_like(acc), np.zeros((h, w), bool))
        fill = np.where(on[..., None], np.clip(1 - alpha, 0, 1), 0)
        den = alpha + fill * b[..., -1:]
        want = np.where(den > floor, (acc[..., :-1] + fill * b[..., :-1]) / np.where(den > floor, den, 1), 0)
        np.testing.assert_allclose(out, want, rtol=1e-6, atol=1e-6)
        assert (out[2, :5] == 0).all() and (on.any() or not placed.size)


@pytest.mark.parametrize("radius_px, shape", [(1.0, (40, 50, 4)), (2.5, (33, 21, 2)), (4.0, (30, 40, 4)),
                                              (5.0, (64, 70, 4)), (5.54, (25, 30, 4)), (8.0, (30, 35, 5)),
                                              (5.0, (7, 3, 4)), (3.0, (2, 60, 4))])
def test_disc_blur_is_the_disc_kernel_convolved_zero_outside(radius_px, shape):
    """As ``cv2.filter2D`` with the disc and zeros outside, to float32 rounding: every reach the
    renderer compiles apart (1 to 6) and one past them, RGB's cells and others, layers narrower
    or shorter than the disc."""
    from lfring.focus.layers import disc_kernel

    rng = np.random.default_rng(int(radius_px * 10) + shape[0])
    cells = rng.random(shape).astype(np.float32)
    kernel = disc_kernel(radius_px)
    reach = kernel.shape[0] // 2
    out = np.full_like(cells, np.nan)
    kern.disc_blur(cells, np.ascontiguousarray(kernel[reach:, reach:]), out)
    want = np.stack([cv2.filter2D(np.ascontiguousarray(cells[..., i]), -1, kernel, borderType=cv2.BORDER_CONSTANT)
                     for i in range(shape[2])], axis=2)
    np.testing.assert_allclose(out, want, rtol=0, atol=2e-6)
    assert np.abs(out - cells).max() > 0.05  # it blurred
