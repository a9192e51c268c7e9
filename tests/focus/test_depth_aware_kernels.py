"""The depth-aware renderer's compiled passes against plain NumPy versions of the same rules."""

import numpy as np
import pytest

from lfring.core.viewstack import WEIGHT_FLOOR
from lfring.focus import depth_aware_kernels as kern
from lfring.focus.depth_aware import AGREE_TOL, SPREAD_TOL


def _robust_mean_numpy(warped, weight, visible):
    """The views' robust mean, written array by array (the rules of ``kern.robust_mean``)."""
    present = weight > WEIGHT_FLOOR
    visible = visible & present
    visible |= present & ~visible.any(axis=0)
    lum = np.divide(warped.mean(axis=3), weight, out=np.zeros(weight.shape), where=present)
    wv = np.where(visible, weight, 0.0)
    close = np.exp(-0.5 * ((lum[:, None] - lum[None, :]) / AGREE_TOL) ** 2)
    support = np.einsum("jvhw,jhw->vhw", close, wv) ** 4 * wv
    total = support.sum(axis=0)
    mean_lum = (wv * lum).sum(axis=0) / np.maximum(wv.sum(axis=0), WEIGHT_FLOOR)
    med = np.where(total > 0, (support * lum).sum(axis=0) / np.maximum(total, 1e-30), mean_lum)
    dev = np.abs(lum - med)
    spread = np.sqrt((wv * dev * dev).sum(axis=0) / np.maximum(wv.sum(axis=0), WEIGHT_FLOOR))
    tol = np.maximum(AGREE_TOL, SPREAD_TOL * spread)
    phi = np.where(visible, np.clip(2.0 - dev / tol, 0.0, 1.0), 0.0)
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
    kern.robust_mean(warped, weight, visible, AGREE_TOL, SPREAD_TOL, WEIGHT_FLOOR, colour, agree, seen)
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
