"""The cost volume of the fused semi-global passes, in 16-bit integers (see
:mod:`lfring.depth.engines.fused`):

1. :func:`sample_costs`: the aggregated cost of all views on a few rows, for a first estimate of
   the cost's scale, which sets the integer unit.
2. :func:`sweep_volume`: per strip of rows, every view shifted to every hypothesis and summed,
   the 'lcn' cost aggregated over the box and quantised into a (h, N, w) uint16 volume.
3. :func:`sweep_halves`: where no depth suits all views, the cost of the halves of the views,
   taken where a half agrees much better.

Each step works on rows of one hypothesis at a time in small helpers whose loops run over
contiguous pixels from index 0 (an index that might be negative is wrapped around by numba,
which keeps a loop from vectorising), so that they vectorise; strips of rows are the parallel
tasks.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from lfring.depth.aggregation_kernels import reflect
from lfring.depth.engines.fused_common import COST_MAX, COST_ZERO, INLINE, JIT, ONE_PASS_MIN_WIDTH, PARALLEL, UNKNOWN

__all__ = ["HALVES_GROUP_COLUMNS", "sample_costs", "sweep_halves", "sweep_volume"]

# The halves pass computes a strip's runs of poor columns side by side, up to this many columns
# of terms at once (runs are often a few pixels wide, where per-run steps cost more than the
# pixels; at this width a group's 16-bit least costs still fit a core's L2 cache).
HALVES_GROUP_COLUMNS = 512


@njit(**INLINE)
def _weighted_square(v, g, floor):
    """A view's term of the sum of squares: its value ``v`` (premultiplied by its weight ``g``)
    squared over ``g`` (:func:`lfring.depth.costs.lcn.weighted_square`)."""
    return (v * v) / (g if g > floor else floor)


@njit(**INLINE)
def _sums_first(v, wt, floor, s1, s2, cn):
    for x in range(v.shape[0]):
        s1[x] = v[x]
        s2[x] = _weighted_square(v[x], wt[x], floor)
        cn[x] = wt[x]


@njit(**INLINE)
def _sums_add(v, wt, floor, s1, s2, cn):
    for x in range(v.shape[0]):
        s1[x] += v[x]
        s2[x] += _weighted_square(v[x], wt[x], floor)
        cn[x] += wt[x]


@njit(**INLINE)
def _lcn(s1, s2, c, floor, seen_in):
    """The 'lcn' cost of one pixel's sums of values ``s1``, squares ``s2`` and weights ``c``,
    and 1.0 where 1.5 views or more see the pixel (and ``seen_in`` > 0.5); (0.0, 0.0) elsewhere."""
    one = np.float32(1.0)
    half = np.float32(0.5)
    ok = (c >= np.float32(1.5)) & (seen_in > half)
    r = c if c > floor else floor
    dd = c - one
    dd = dd if dd > half else half
    return ((s2 - s1 * s1 / r) / dd if ok else np.float32(0.0)), (one if ok else np.float32(0.0))


@njit(**INLINE)
def _lcn_row(s1, s2, cn, floor, seen_in, t, seen):
    """:func:`_lcn` of every pixel of the sums: ``t`` the costs, ``seen`` 1 or 0."""
    for x in range(t.shape[0]):
        t[x], seen[x] = _lcn(s1[x], s2[x], cn[x], floor, seen_in[x])


@njit(**INLINE)
def _rounded(product):
    """A product that is never negative (a square, weights) as it is when stored. Allowed to
    contract, the compiler may fuse a product into the sum it enters; its absolute value (the
    same number) keeps it rounded, as the sums of rows of products had it."""
    return abs(product)


@njit(**JIT)
def _lcn_two(a0, a1, w0, w1, floor, seen_in, cn, t, seen):
    """:func:`_lcn_row` of the sums of two views' values and weights, in one pass (the sums of
    :func:`_sums_first` and :func:`_sums_add` up to rounding: the squares over one common
    denominator, as :func:`_lcn_of_four`); ``cn`` receives the weights' sums."""
    for x in range(t.shape[0]):
        v0 = a0[x]
        v1 = a1[x]
        g0 = w0[x]
        g1 = w1[x]
        c = g0 + g1
        cn[x] = c
        h0, h1 = (g0 if g0 > floor else floor), (g1 if g1 > floor else floor)
        t[x], seen[x] = _lcn(v0 + v1, ((v0 * v0) * h1 + (v1 * v1) * h0) / (h0 * h1), c, floor, seen_in[x])


@njit(**INLINE)
def _lcn_of_four(v0, v1, v2, v3, g0, g1, g2, g3, c, floor, seen_in):
    """:func:`_lcn` of four views' values at a pixel (weights ``g0`` .. ``g3``, their sum ``c``):
    the sums of :func:`_sums_first` and :func:`_sums_add`, up to rounding."""
    # sum v^2 / g over one division: the squares over the common denominator of the weights (each
    # at least the floor), which on two cores cost a sixth of the row's terms as four divisions.
    h0, h1 = (g0 if g0 > floor else floor), (g1 if g1 > floor else floor)
    h2, h3 = (g2 if g2 > floor else floor), (g3 if g3 > floor else floor)
    p01, p23 = h0 * h1, h2 * h3
    s2 = ((v0 * v0) * h1 + (v1 * v1) * h0) * p23 + ((v2 * v2) * h3 + (v3 * v3) * h2) * p01
    return _lcn(v0 + v1 + v2 + v3, s2 / (p01 * p23), c, floor, seen_in)


@njit(**INLINE)
def _vsum(rows, start, count, out):
    """out = sum of ``count`` rows of ``rows`` from index ``start`` (any order of rows), added
    in row order. Five rows (the default box) in one pass, in the same order: one store a value
    instead of five."""
    w = out.shape[0]
    if count == 5 and w >= ONE_PASS_MIN_WIDTH:
        r0, r1, r2, r3, r4 = rows[start], rows[start + 1], rows[start + 2], rows[start + 3], rows[start + 4]
        for x in range(w):
            out[x] = (((r0[x] + r1[x]) + r2[x]) + r3[x]) + r4[x]
        return
    for x in range(w):
        out[x] = rows[start, x]
    for k in range(start + 1, start + count):
        r = rows[k]
        for x in range(w):
            out[x] += r[x]


@njit(**INLINE)
def _hsum(col, rad, tmp, out):
    """out[x] = sum of col over x - rad .. x + rad, reflected at the ends (BORDER_REFLECT_101)."""
    w = col.shape[0]
    for x in range(w):
        tmp[x + rad] = col[x]
    _hsum_in_place(tmp, rad, out)


@njit(**INLINE)
def _hsum_in_place(tmp, rad, out):
    """:func:`_hsum` of the row that ``tmp`` holds from its column ``rad`` (its ends are filled
    here)."""
    w = out.shape[0]
    for x in range(rad):
        tmp[x] = tmp[rad + reflect(x - rad, w)]
        tmp[w + rad + x] = tmp[rad + reflect(w + x, w)]
    _shifted_sum(tmp, rad, out)


@njit(**INLINE)
def _shifted_sum(padded, rad, out):
    """out[x] = sum of padded[x .. x + 2 rad]. One shifted row at a time, in the order of
    additions of a sum per pixel (so the same floats), with indices from 0 (numba wraps an
    index that may be negative around): the loops vectorise, where a sum per pixel did not."""
    m = out.shape[0]
    if rad == 2 and m >= ONE_PASS_MIN_WIDTH:  # the default box, in one pass (the same order of additions)
        for x in range(m):
            out[x] = (((padded[x] + padded[x + 1]) + padded[x + 2]) + padded[x + 3]) + padded[x + 4]
        return
    for x in range(m):
        out[x] = padded[x]
    for k in range(1, 2 * rad + 1):
        for x in range(m):
            out[x] += padded[x + k]


@njit(**INLINE)
def _vbox(rows, q0, y, rad, h, ordered, col):
    """col = the sum over image rows y - rad .. y + rad (reflected at the image's top and
    bottom) of a quantity whose rows from image row ``q0`` are ``rows`` (``ordered``: a scratch
    of 2 rad + 1 rows)."""
    if y - rad >= 0 and y + rad < h:
        _vsum(rows, y - rad - q0, 2 * rad + 1, col)
    else:
        for k in range(2 * rad + 1):
            ordered[k] = rows[reflect(y - rad + k, h) - q0]
        _vsum(ordered, 0, 2 * rad + 1, col)


# -- per-pixel terms of one row at one hypothesis ------------------------------------------------
@njit(**INLINE)
def _ones_run(ones_lo, ones_hi, r, c0, m):
    """The columns lo..hi of ``m`` from padded column c0 whose bilinear mask over padded rows r,
    r + 1 is 1 for certain: all four taps in both rows' run of ones [ones_lo, ones_hi)."""
    lo = max(ones_lo[r], ones_lo[r + 1]) - c0
    hi = min(ones_hi[r], ones_hi[r + 1]) - c0 - 1  # x + 1 must be inside too
    lo = min(max(lo, 0), m)
    return lo, min(max(hi, lo), m)


@njit(**INLINE)
def _view_taps(src, iy, ix, fy, fx, pad, y, d, k, x0, m):
    """View ``k``'s bilinear taps for ``m`` columns from x0 of row ``y`` at hypothesis ``d``: its
    two padded rows of ``src`` from column c0 (m + 1 values each), r and c0, and the weights p,
    q (down) and a, b (across)."""
    r = y + iy[d, k] + pad
    c0 = ix[d, k] + pad + x0
    q = np.float32(fy[d, k])
    b = np.float32(fx[d, k])
    return (src[k, r, c0:c0 + m + 1], src[k, r + 1, c0:c0 + m + 1], r, c0, np.float32(1.0) - q, q,
            np.float32(1.0) - b, b)


@njit(**INLINE)
def _sample(s0, s1, p, q, a, b, x):
    """The bilinear sample between columns x, x + 1 of rows ``s0``, ``s1`` (weights p, q down,
    a, b across): the vertical pairs first, then across."""
    return a * (p * s0[x] + q * s1[x]) + b * (p * s0[x + 1] + q * s1[x + 1])


@njit(**INLINE)
def _lcn_of_four_whole(v0, v1, v2, v3, c, floor, seen_in):
    """:func:`_lcn_of_four` where every weight is 1 or 0 (weights' sum ``c``): a square over a
    weight of 1 is the square, and a view of weight 0 has the value 0 (its taps all in the
    zero padding). The first square rounded, the others fused into the sum."""
    s2 = _rounded(v0 * v0) + v1 * v1 + v2 * v2 + v3 * v3
    return _lcn(v0 + v1 + v2 + v3, s2, c, floor, seen_in)


@njit(**INLINE)
def _taps_from(tap, o, e):
    """A view's taps (:func:`_view_taps`' rows and weights) for the columns o..e."""
    u, l, p, q, a, b = tap
    return u[o:e + 1], l[o:e + 1], p, q, a, b


@njit(**INLINE)
def _sample_tap(tap, x):
    u, l, p, q, a, b = tap
    return _sample(u, l, p, q, a, b, x)


@njit(**INLINE)
def _whole_four(t0, t1, t2, t3, floor, ones, cn, t, seen):
    """The terms of four views (taps ``t0`` .. ``t3``) that all weigh 1 at every column of these
    (sliced) rows."""
    for x in range(t.shape[0]):
        cn[x] = np.float32(4.0)
        t[x], seen[x] = _lcn_of_four_whole(_sample_tap(t0, x), _sample_tap(t1, x), _sample_tap(t2, x),
                                           _sample_tap(t3, x), np.float32(4.0), floor, ones[x])


@njit(**INLINE)
def _valid_four_span(t0, t1, t2, t3, es, xs, floor, ones, cn, t, seen, whole):
    """The terms of four all-valid views over these (sliced) rows, each weight its edge weight:
    ``es`` the four row weights, ``xs`` the four column weights' rows. With ``whole`` every
    weight is 1 or 0 and none is divided by (:func:`_lcn_of_four_whole`)."""
    e0, e1, e2, e3 = es
    x0, x1, x2, x3 = xs
    if whole:  # a loop of its own: a test inside kept the loop from vectorising
        for x in range(t.shape[0]):
            c = ((_rounded(e0 * x0[x]) + _rounded(e1 * x1[x])) + _rounded(e2 * x2[x])) + _rounded(e3 * x3[x])
            cn[x] = c
            t[x], seen[x] = _lcn_of_four_whole(_sample_tap(t0, x), _sample_tap(t1, x), _sample_tap(t2, x),
                                               _sample_tap(t3, x), c, floor, ones[x])
        return
    for x in range(t.shape[0]):
        g0 = _rounded(e0 * x0[x])
        g1 = _rounded(e1 * x1[x])
        g2 = _rounded(e2 * x2[x])
        g3 = _rounded(e3 * x3[x])
        c = g0 + g1 + g2 + g3
        cn[x] = c
        t[x], seen[x] = _lcn_of_four(_sample_tap(t0, x), _sample_tap(t1, x), _sample_tap(t2, x), _sample_tap(t3, x),
                                     g0, g1, g2, g3, c, floor, ones[x])


@njit(**INLINE)
def _whole_weight(e):
    return (e == np.float32(0.0)) | (e == np.float32(1.0))


@njit(**JIT)
def _all_terms_valid_four(src, edge_y, edge_x, iy, ix, fy, fx, pad, ones_lo, ones_hi, y, d, views, floor, ones, cn, t, seen):
    """:func:`_view_span` and :func:`_all_terms` of four all-valid views in one pass: each view's
    sample and edge weight made where the sums take them rather than written to rows first (the
    same sums, up to rounding). An all-valid view weighs 1 inside the frame and 0 outside but
    for a column or a row at each edge: the row is summed with no weight divided by, and those
    columns again with the weights. ``ones_lo``, ``ones_hi``: (N, V) the run of ones of each
    hypothesis's and view's ``edge_x`` (lo = hi where there is none)."""
    w = t.shape[0]
    k0, k1, k2, k3 = views[0], views[1], views[2], views[3]
    u0, l0, _, _, p0, q0, a0, b0 = _view_taps(src, iy, ix, fy, fx, pad, y, d, k0, 0, w)
    u1, l1, _, _, p1, q1, a1, b1 = _view_taps(src, iy, ix, fy, fx, pad, y, d, k1, 0, w)
    u2, l2, _, _, p2, q2, a2, b2 = _view_taps(src, iy, ix, fy, fx, pad, y, d, k2, 0, w)
    u3, l3, _, _, p3, q3, a3, b3 = _view_taps(src, iy, ix, fy, fx, pad, y, d, k3, 0, w)
    taps = ((u0, l0, p0, q0, a0, b0), (u1, l1, p1, q1, a1, b1), (u2, l2, p2, q2, a2, b2), (u3, l3, p3, q3, a3, b3))
    es = (edge_y[d, k0, y], edge_y[d, k1, y], edge_y[d, k2, y], edge_y[d, k3, y])
    xs = (edge_x[d, k0], edge_x[d, k1], edge_x[d, k2], edge_x[d, k3])
    whole = _whole_weight(es[0]) & _whole_weight(es[1]) & _whole_weight(es[2]) & _whole_weight(es[3])
    if whole:  # each view's run of ones, and zeros beyond the fractional columns at its ends
        for k in range(4):
            whole = whole & (ones_hi[d, views[k]] > ones_lo[d, views[k]])
    _valid_four_span(taps[0], taps[1], taps[2], taps[3], es, xs, floor, ones, cn, t, seen, whole)
    if not whole:
        return
    for k in range(4):  # the columns where a view weighs neither 0 nor 1, with the weights
        row = xs[k]
        lo, hi = ones_lo[d, views[k]], ones_hi[d, views[k]]
        for side in range(2):
            c, step = (lo - 1, -1) if side == 0 else (hi, 1)
            while (c >= 0) & (c < w):
                if row[c] == np.float32(0.0):
                    break
                _valid_four_span(_taps_from(taps[0], c, c + 1), _taps_from(taps[1], c, c + 1),
                                 _taps_from(taps[2], c, c + 1), _taps_from(taps[3], c, c + 1), es,
                                 (xs[0][c:c + 1], xs[1][c:c + 1], xs[2][c:c + 1], xs[3][c:c + 1]), floor, ones[c:c + 1],
                                 cn[c:c + 1], t[c:c + 1], seen[c:c + 1], False)
                c += step


@njit(**INLINE)
def _mask_taps(msk, ones_lo, ones_hi, k, r, c0, m):
    """View ``k``'s mask rows at its taps (:func:`_view_taps`' r, c0) and the columns lo..hi
    where its bilinear mask is 1 for certain (:func:`_ones_run`)."""
    lo, hi = _ones_run(ones_lo[k], ones_hi[k], r, c0, m)
    return msk[k, r, c0:c0 + m + 1], msk[k, r + 1, c0:c0 + m + 1], lo, hi


@njit(**INLINE)
def _mask_weight(mu, ml, lo, hi, p, q, a, b, x):
    """A view's weight at column x: its bilinear mask, 1 inside its run of ones (lo..hi,
    :func:`_ones_run`), where all four taps weigh 1 for certain."""
    return np.float32(1.0) if lo <= x < hi else _sample(mu, ml, p, q, a, b, x)


@njit(**INLINE)
def _mask_weight_of(mask, x):
    """:func:`_mask_weight` of a view's mask taps (rows, run of ones lo..hi) and tap weights."""
    mu, ml, lo, hi, p, q, a, b = mask
    return _mask_weight(mu, ml, lo, hi, p, q, a, b, x)


@njit(**INLINE)
def _masks_from(mask, o, e):
    """A view's mask taps for the columns o..e (its run of ones counted from o)."""
    mu, ml, lo, hi, p, q, a, b = mask
    return mu[o:e + 1], ml[o:e + 1], lo - o, hi - o, p, q, a, b


@njit(**INLINE)
def _masked_four_span(t0, t1, t2, t3, m0, m1, m2, m3, floor, ones, cn, t, seen):
    """The terms of four views with masks over these (sliced) rows, each weight its bilinear mask
    (``m0`` .. ``m3``: 1 inside its run of ones)."""
    for x in range(t.shape[0]):
        g0 = _mask_weight_of(m0, x)
        g1 = _mask_weight_of(m1, x)
        g2 = _mask_weight_of(m2, x)
        g3 = _mask_weight_of(m3, x)
        c = g0 + g1 + g2 + g3
        cn[x] = c
        t[x], seen[x] = _lcn_of_four(_sample_tap(t0, x), _sample_tap(t1, x), _sample_tap(t2, x), _sample_tap(t3, x),
                                     g0, g1, g2, g3, c, floor, ones[x])


@njit(**JIT)
def _all_terms_masked_four(src, msk, ones_lo, ones_hi, iy, ix, fy, fx, pad, y, d, views, floor, ones, cn, t, seen):
    """:func:`_all_terms_valid_four` for four views with masks: each view's weight its bilinear
    mask (:func:`_mask_weight`), made where the sums take it (the same sums, up to rounding). Where
    all four runs of ones overlap no weight is divided by."""
    w = t.shape[0]
    u0, l0, r0, c0, p0, q0, a0, b0 = _view_taps(src, iy, ix, fy, fx, pad, y, d, views[0], 0, w)
    u1, l1, r1, c1, p1, q1, a1, b1 = _view_taps(src, iy, ix, fy, fx, pad, y, d, views[1], 0, w)
    u2, l2, r2, c2, p2, q2, a2, b2 = _view_taps(src, iy, ix, fy, fx, pad, y, d, views[2], 0, w)
    u3, l3, r3, c3, p3, q3, a3, b3 = _view_taps(src, iy, ix, fy, fx, pad, y, d, views[3], 0, w)
    mu0, ml0, lo0, hi0 = _mask_taps(msk, ones_lo, ones_hi, views[0], r0, c0, w)
    mu1, ml1, lo1, hi1 = _mask_taps(msk, ones_lo, ones_hi, views[1], r1, c1, w)
    mu2, ml2, lo2, hi2 = _mask_taps(msk, ones_lo, ones_hi, views[2], r2, c2, w)
    mu3, ml3, lo3, hi3 = _mask_taps(msk, ones_lo, ones_hi, views[3], r3, c3, w)
    taps = ((u0, l0, p0, q0, a0, b0), (u1, l1, p1, q1, a1, b1), (u2, l2, p2, q2, a2, b2), (u3, l3, p3, q3, a3, b3))
    masks = ((mu0, ml0, lo0, hi0, p0, q0, a0, b0), (mu1, ml1, lo1, hi1, p1, q1, a1, b1),
             (mu2, ml2, lo2, hi2, p2, q2, a2, b2), (mu3, ml3, lo3, hi3, p3, q3, a3, b3))
    lo = max(max(lo0, lo1), max(lo2, lo3))
    hi = max(min(min(hi0, hi1), min(hi2, hi3)), lo)
    for part in range(2):  # the columns before the run and after it
        o, e = (0, lo) if part == 0 else (hi, w)
        if e > o:
            _masked_four_span(_taps_from(taps[0], o, e), _taps_from(taps[1], o, e), _taps_from(taps[2], o, e),
                              _taps_from(taps[3], o, e), _masks_from(masks[0], o, e), _masks_from(masks[1], o, e),
                              _masks_from(masks[2], o, e), _masks_from(masks[3], o, e), floor, ones[o:e], cn[o:e],
                              t[o:e], seen[o:e])
    if hi > lo:
        _whole_four(_taps_from(taps[0], lo, hi), _taps_from(taps[1], lo, hi), _taps_from(taps[2], lo, hi),
                    _taps_from(taps[3], lo, hi), floor, ones[lo:hi], cn[lo:hi], t[lo:hi], seen[lo:hi])


@njit(**JIT)
def _all_terms(a_buf, w_buf, floor, ones, s1, s2, cn, t, seen):
    """The 'lcn' cost ``t`` of all views' rows, its ``seen`` flags and the views' weights' sum
    ``cn``. A pair is summed in one pass rather than a pass per view (four views take
    :func:`_row_terms`' sampled kernels)."""
    if a_buf.shape[0] == 2:
        _lcn_two(a_buf[0], a_buf[1], w_buf[0], w_buf[1], floor, ones, cn, t, seen)
        return
    _sums_first(a_buf[0], w_buf[0], floor, s1, s2, cn)
    for j in range(1, a_buf.shape[0]):
        _sums_add(a_buf[j], w_buf[j], floor, s1, s2, cn)
    _lcn_row(s1, s2, cn, floor, ones, t, seen)


@njit(**INLINE)
def _row_terms(src, msk, all_valid, edge_y, edge_x, iy, ix, fy, fx, pad, ones_lo, ones_hi, y, d, views, floor, ones, a_buf,
               w_buf, s1, s2, cn, t_row, seen_row):
    """The 'lcn' cost of all views at row ``y`` and hypothesis ``d`` (``t_row``), its seen flags
    and the views' weights' sum ``cn``: four views sampled where the sums take them
    (:func:`_all_terms_valid_four`, :func:`_all_terms_masked_four`), other numbers of views
    through rows of samples (:func:`_view_span`)."""
    if all_valid and views.shape[0] == 4:
        _all_terms_valid_four(src, edge_y, edge_x, iy, ix, fy, fx, pad, ones_lo, ones_hi, y, d, views, floor, ones, cn,
                              t_row, seen_row)
    elif views.shape[0] == 4:
        _all_terms_masked_four(src, msk, ones_lo, ones_hi, iy, ix, fy, fx, pad, y, d, views, floor, ones, cn, t_row,
                               seen_row)
    else:
        _view_span(src, msk, all_valid, edge_y, edge_x, iy, ix, fy, fx, pad, ones_lo, ones_hi, y, d, views, 0,
                   t_row.shape[0], 0, a_buf, w_buf)
        _all_terms(a_buf, w_buf, floor, ones, s1, s2, cn, t_row, seen_row)


@njit(**INLINE)
def _half_terms(a_buf, w_buf, halves, half_ptr, h_i, floor, seen, s1, s2, cn, hc, ho):
    """The 'lcn' cost ``hc`` of the half ``h_i`` of the views and its flags ``ho`` (where
    ``seen`` too), one view at a time."""
    j0 = halves[half_ptr[h_i]]
    _sums_first(a_buf[j0], w_buf[j0], floor, s1, s2, cn)
    for q_i in range(half_ptr[h_i] + 1, half_ptr[h_i + 1]):
        j = halves[q_i]
        _sums_add(a_buf[j], w_buf[j], floor, s1, s2, cn)
    _lcn_row(s1, s2, cn, floor, seen, hc, ho)


@njit(**INLINE)
def _all_set(row):
    """Whether every value of a row of 1 / 0 flags is 1."""
    for x in range(row.shape[0]):
        if row[x] < np.float32(0.5):
            return False
    return True


@njit(**INLINE)
def _window_all_set(flags, q0, y, rad, h):
    """Whether the rows y - rad .. y + rad (reflected) all have their flag set."""
    for k in range(y - rad, y + rad + 1):
        if not flags[reflect(k, h) - q0]:
            return False
    return True


@njit(**INLINE)
def _seen_row(w_buf, seen):
    """seen = 1 where the views' weights add up to 1.5 or more, else 0."""
    m = seen.shape[0]
    for x in range(m):
        seen[x] = w_buf[0, x]
    for j in range(1, w_buf.shape[0]):
        wr = w_buf[j]
        for x in range(m):
            seen[x] += wr[x]
    for x in range(m):
        seen[x] = np.float32(1.0) if seen[x] >= np.float32(1.5) else np.float32(0.0)


@njit(**INLINE)
def _fold_full(bt, scale, least):
    """least = min(least, scale * bt): a half whose every window is its own."""
    for x in range(least.shape[0]):
        c = scale * bt[x]
        least[x] = c if c < least[x] else least[x]


@njit(**INLINE)
def _agg(bt, bs, seen_c, area, floor):
    """The seen-pixel mean of a box (sum ``bt`` of costs, ``bs`` of seen pixels); inf where the
    centre pixel is not seen (``seen_c`` 0)."""
    sup = bs / area
    sup = sup if sup > floor else floor
    return bt / area / sup if seen_c > np.float32(0.5) else np.float32(np.inf)


@njit(**INLINE)
def _agg_row(bt, bs, seen_c, area, floor, out):
    """:func:`_agg` of every pixel of a row."""
    for x in range(out.shape[0]):
        out[x] = _agg(bt[x], bs[x], seen_c[x], area, floor)


@njit(**INLINE)
def _fold_half(bt, bs, own_c, area_support, penalty, least):
    """least = min(least, penalty * bt / bs) where the centre is the half's own and the window's
    own share reaches the support."""
    for x in range(least.shape[0]):
        ok = (own_c[x] > np.float32(0.5)) & (bs[x] >= area_support)
        c = penalty * bt[x] / (bs[x] if ok else np.float32(1.0))
        least[x] = c if ok & (c < least[x]) else least[x]


# -- pass 0: the scale and threshold from a sample of rows --------------------------------------
@njit(**PARALLEL)
def sample_costs(src, msk, all_valid, edge_y, edge_x, iy, ix, fy, fx, pad, ones_lo, ones_hi, views, sample_rows, stride, rad, floor,
                 best_out, spread_out):
    """Per sampled pixel (rows ``sample_rows``, every ``stride``-th column): the least aggregated
    cost of all views over the hypotheses (``best_out``) and the mean of its finite costs minus
    that least (``spread_out``); inf and NaN where fewer than two hypotheses are finite."""
    n = iy.shape[0]
    h = src.shape[1] - 2 * pad - 1
    w = src.shape[2] - 2 * pad - 1
    n_views = views.shape[0]
    area = np.float32((2 * rad + 1) ** 2)
    ncol = best_out.shape[1]
    for i in prange(sample_rows.shape[0]):
        y = sample_rows[i]
        a_buf = np.empty((n_views, w), np.float32)
        w_buf = np.empty((n_views, w), np.float32)
        ones = np.ones(w, np.float32)
        s1 = np.empty(w, np.float32)
        s2 = np.empty(w, np.float32)
        cn = np.empty(w, np.float32)
        t_rows = np.empty((2 * rad + 1, w), np.float32)
        seen_rows = np.empty((2 * rad + 1, w), np.float32)
        col = np.empty(w, np.float32)
        bt = np.empty(w, np.float32)
        bs = np.empty(w, np.float32)
        tmp = np.empty(w + 2 * rad, np.float32)
        agg = np.empty(w, np.float32)
        best = np.full(ncol, np.inf, np.float32)
        total = np.zeros(ncol, np.float64)
        count = np.zeros(ncol, np.int64)
        for d in range(n):
            for k in range(2 * rad + 1):
                yy = reflect(y - rad + k, h)
                _row_terms(src, msk, all_valid, edge_y, edge_x, iy, ix, fy, fx, pad, ones_lo, ones_hi, yy, d, views, floor, ones,
                           a_buf, w_buf, s1, s2, cn, t_rows[k], seen_rows[k])
            _vsum(t_rows, 0, 2 * rad + 1, col)
            _hsum(col, rad, tmp, bt)
            _vsum(seen_rows, 0, 2 * rad + 1, col)
            _hsum(col, rad, tmp, bs)
            _agg_row(bt, bs, seen_rows[rad], area, floor, agg)
            for c in range(ncol):
                v = agg[c * stride]
                if v < np.float32(np.inf):
                    best[c] = min(best[c], v)
                    total[c] += v
                    count[c] += 1
        for c in range(ncol):
            if count[c] >= 2:
                best_out[i, c] = best[c]
                spread_out[i, c] = np.float32(total[c] / count[c]) - best[c]
            else:
                best_out[i, c] = np.inf
                spread_out[i, c] = np.nan


# -- pass 1: the quantised cost volume ------------------------------------------------------------
@njit(**INLINE)
def _quantised(v, inv_unit):
    """A cost in integer units from COST_ZERO, rounded and clipped to [0, COST_MAX]; UNKNOWN
    where not finite."""
    q = v * inv_unit + np.float32(COST_ZERO + 0.5)  # rounded
    q = q if q < np.float32(COST_MAX) else np.float32(COST_MAX)
    q = q if q > np.float32(0.0) else np.float32(0.0)
    return np.uint16(q) if v < np.float32(np.inf) else np.uint16(UNKNOWN)


@njit(**INLINE)
def _quantise(v, inv_unit, out):
    """:func:`_quantised` of every cost of a row."""
    for x in range(out.shape[0]):
        out[x] = _quantised(v[x], inv_unit)


@njit(**INLINE)
def _take_row(bt, bs, seen_c, area, floor, inv_unit, out, b_row, t_row, c_row):
    """One row of a hypothesis from its box sums: its :func:`_agg` costs quantised into ``out``,
    and each pixel's least cost ``b_row``, sum ``t_row`` and number ``c_row`` of finite ones
    updated, in one pass."""
    inf = np.float32(np.inf)
    for x in range(out.shape[0]):
        v = _agg(bt[x], bs[x], seen_c[x], area, floor)
        out[x] = _quantised(v, inv_unit)
        b_row[x] = min(b_row[x], v)
        known = v < inf
        t_row[x] += v if known else np.float32(0.0)
        c_row[x] += np.float32(1.0) if known else np.float32(0.0)


@njit(**JIT)
def _box_row(rows, q0, y, rad, h, ordered, tmp, out):
    """The box sum at row ``y`` of a quantity whose rows from image row ``q0`` are ``rows``
    (reflected at the image's top and bottom; ``ordered`` a scratch of 2 rad + 1 rows, ``tmp``
    one of w + 2 rad values, where the column sums are made)."""
    _vbox(rows, q0, y, rad, h, ordered, tmp[rad:rad + out.shape[0]])
    _hsum_in_place(tmp, rad, out)


@njit(**PARALLEL)
def sweep_volume(src, msk, all_valid, edge_y, edge_x, iy, ix, fy, fx, pad, ones_lo, ones_hi, views, rad, rows, floor, unit, out, best,
                 total, count, nviews):
    """The quantised cost volume of all views ``out`` (h, N, w) uint16, each pixel's least cost
    ``best`` (h, w) float32 (inf where none), the sum and number of its finite costs ``total``
    and ``count`` (h, w) float32 (before quantisation: for the scale of the penalties) and
    ``nviews`` (h, w) float32.

    ``src``, ``msk``: (V, h + 2 pad + 1, w + 2 pad + 1) zero-padded sources (premultiplied by
    their masks) and masks; ``iy, ix, fy, fx``: (N, V) integer and fractional sampling shifts;
    ``edge_y``, ``edge_x``: (N, V, h) and (N, V, w) weights of an all-valid view's edges
    (``all_valid``); ``views``: the views that enter the cost; ``rad``: the aggregation box's
    radius; ``rows``: output rows per strip; ``unit``: the cost of one integer step."""
    h, n, w = out.shape
    n_views = views.shape[0]
    n_strips = (h + rows - 1) // rows
    inv_unit = np.float32(1.0 / unit)
    area = np.float32((2 * rad + 1) ** 2)
    inf = np.float32(np.inf)
    for s in prange(n_strips):
        y0 = s * rows
        y1 = min(h, y0 + rows)
        q0 = max(0, y0 - rad)
        q1 = min(h, y1 + rad)
        nq = q1 - q0
        a_buf = np.empty((n_views, w), np.float32)
        w_buf = np.empty((n_views, w), np.float32)
        ones = np.ones(w, np.float32)
        s1 = np.empty(w, np.float32)
        s2 = np.empty(w, np.float32)
        cn = np.empty(w, np.float32)
        t_rows = np.empty((nq, w), np.float32)
        seen_rows = np.empty((nq, w), np.float32)
        seen_all = np.empty(nq, np.bool_)
        ordered = np.empty((2 * rad + 1, w), np.float32)
        bt = np.empty(w, np.float32)
        bs = np.empty(w, np.float32)
        tmp = np.empty(w + 2 * rad, np.float32)
        for y in range(y0, y1):
            nviews[y] = 0.0
            best[y] = inf
            total[y] = 0.0
            count[y] = 0.0
        for d in range(n):
            for r in range(nq):
                _row_terms(src, msk, all_valid, edge_y, edge_x, iy, ix, fy, fx, pad, ones_lo, ones_hi, q0 + r, d, views, floor,
                           ones, a_buf, w_buf, s1, s2, cn, t_rows[r], seen_rows[r])
                if q0 + r >= y0 and q0 + r < y1:
                    nvr = nviews[q0 + r]
                    for x in range(w):
                        nvr[x] = max(nvr[x], cn[x])
            for r in range(nq):
                seen_all[r] = _all_set(seen_rows[r])
            for y in range(y0, y1):
                _box_row(t_rows, q0, y, rad, h, ordered, tmp, bt)
                if _window_all_set(seen_all, q0, y, rad, h):  # every window wholly seen
                    bs[:] = area
                else:
                    _box_row(seen_rows, q0, y, rad, h, ordered, tmp, bs)
                _take_row(bt, bs, seen_rows[y - q0], area, floor, inv_unit, out[y, d], best[y], total[y], count[y])


@njit(**PARALLEL)
def sweep_halves(src, msk, all_valid, edge_y, edge_x, iy, ix, fy, fx, pad, ones_lo, ones_hi, views, halves, half_ptr, rad, rows, floor,
                 penalty, min_support, gain, unit, poor, best, out):
    """'lcn-halves': at the ``poor`` pixels (no depth suits all views), the least cost of a half
    of the views, aggregated over the box; where its best is under ``gain`` times the pixel's
    ``best`` of all views, ``out`` (the all views' volume, h, N, w uint16) becomes the least of
    the two. Only the runs of columns of each strip that hold poor pixels (with the box's reach)
    are computed. Arguments as :func:`sweep_volume`; ``halves`` with ``half_ptr``: each half's
    positions in ``views``, flattened; ``penalty`` and ``min_support`` as
    :func:`lfring.depth.costs.lcn_halves.half_aggregate`."""
    h, n, w = out.shape
    n_strips = (h + rows - 1) // rows
    # Runs closer than this share one span: their terms' reach would overlap anyway.
    gap = 4 * rad + 8
    for s in prange(n_strips):
        y0 = s * rows
        y1 = min(h, y0 + rows)
        cols = np.zeros(w, np.bool_)
        for y in range(y0, y1):
            pr = poor[y]
            for x in range(w):
                cols[x] |= pr[x]
        span_a = np.empty(w, np.int64)
        span_b = np.empty(w, np.int64)
        n_spans = 0
        x = 0
        while x < w:
            if not cols[x]:
                x += 1
                continue
            xb = x + 1
            last = x
            while xb < w and xb - last <= gap:
                if cols[xb]:
                    last = xb
                xb += 1
            span_a[n_spans] = x
            span_b[n_spans] = last + 1
            n_spans += 1
            x = last + 1
        # Each span only over the rows that hold its poor pixels (with the box's reach): a few
        # scattered poor pixels would otherwise cost the strip's every row. Neighbouring spans
        # over the same rows are computed together up to HALVES_GROUP_COLUMNS columns of terms:
        # fewer, longer row steps, and a working set that stays in the core's cache.
        span_y0 = np.empty(n_spans, np.int64)
        span_y1 = np.empty(n_spans, np.int64)
        for i in range(n_spans):
            span_y0[i], span_y1[i] = _poor_rows(poor, y0, y1, span_a[i], span_b[i])
        i = 0
        while i < n_spans:
            k = i + 1
            width = span_b[i] - span_a[i] + 4 * rad
            while (k < n_spans and span_y0[k] == span_y0[i] and span_y1[k] == span_y1[i]
                   and width + span_b[k] - span_a[k] + 4 * rad <= HALVES_GROUP_COLUMNS):
                width += span_b[k] - span_a[k] + 4 * rad
                k += 1
            _halves_strip(src, msk, all_valid, edge_y, edge_x, iy, ix, fy, fx, pad, ones_lo, ones_hi, views, halves, half_ptr, rad,
                          floor, penalty, min_support, gain, unit, poor, best, out, span_y0[i], span_y1[i], span_a[i:k],
                          span_b[i:k])
            i = k


@njit(**INLINE)
def _poor_rows(poor, y0, y1, xa, xb):
    """The first and one past the last row of y0..y1 with a ``poor`` pixel in columns xa..xb."""
    ya = y1
    yb = y0
    for y in range(y0, y1):
        hit = False
        pr = poor[y]
        for x in range(xa, xb):
            hit |= pr[x]
        if hit:
            ya = min(ya, y)
            yb = y + 1
    return ya, yb


@njit(**JIT)
def _halves_strip(src, msk, all_valid, edge_y, edge_x, iy, ix, fy, fx, pad, ones_lo, ones_hi, views, halves, half_ptr, rad, floor,
                  penalty, min_support, gain, unit, poor, best, out, y0, y1, span_a, span_b):
    """:func:`sweep_halves` for the rows y0..y1 and the output columns of its spans
    (``span_a``..``span_b``). The spans' terms lie side by side in one row, each over its span
    wider by the box's radius (so that its box sums are exact inside) with ``rad`` columns of
    its own padding either side: every row-wide step runs once for all the spans, not once per
    span (a strip's spans are often a few pixels wide, where the steps' fixed costs dominate)."""
    h, n, w = out.shape
    n_views = views.shape[0]
    n_halves = half_ptr.shape[0] - 1
    n_spans = span_a.shape[0]
    inv_unit = np.float32(1.0 / unit)
    area = np.float32((2 * rad + 1) ** 2)
    inf = np.float32(np.inf)
    q0 = max(0, y0 - rad)
    q1 = min(h, y1 + rad)
    nq = q1 - q0
    m = y1 - y0
    # Span i: image columns ta..tb at row positions base..base + (tb - ta).
    ta = np.empty(n_spans, np.int64)
    sw = np.empty(n_spans, np.int64)
    base = np.empty(n_spans, np.int64)
    total = 0
    for i in range(n_spans):
        ta[i] = max(0, span_a[i] - rad)
        sw[i] = min(w, span_b[i] + rad) - ta[i]
        base[i] = total + rad
        total += sw[i] + 2 * rad
    # Zeros in the padding: no terms are made there, and its box sums are never used.
    a_buf = np.zeros((n_views, total), np.float32)
    w_buf = np.zeros((n_views, total), np.float32)
    s1 = np.empty(total, np.float32)
    s2 = np.empty(total, np.float32)
    cn = np.empty(total, np.float32)
    seen_rows = np.zeros((nq, total), np.float32)
    hc_rows = np.zeros((n_halves, nq, total), np.float32)
    ho_rows = np.zeros((n_halves, nq, total), np.float32)
    ordered = np.empty((2 * rad + 1, total), np.float32)
    col = np.empty(total, np.float32)
    bt = np.empty(total, np.float32)
    bs = np.empty(total, np.float32)
    # Each row's least cost of a half is quantised as soon as it is complete (only its float
    # minimum over the hypotheses is needed later): 16 bits a value keep the strip in cache.
    least = np.empty((m, n, total), np.uint16)
    l_row = np.empty(total, np.float32)
    hbest = np.full((m, total), inf, np.float32)
    # Per half, span and row: whether the half sees every pixel of the span's row as its own.
    own_all = np.empty((n_halves, n_spans, nq), np.bool_)
    full = np.empty(n_spans, np.bool_)
    for d in range(n):
        for r in range(nq):
            for i in range(n_spans):
                _view_span(src, msk, all_valid, edge_y, edge_x, iy, ix, fy, fx, pad, ones_lo, ones_hi, q0 + r, d, views, ta[i],
                           sw[i], base[i], a_buf, w_buf)
            _seen_row(w_buf, seen_rows[r])
            for h_i in range(n_halves):
                _half_terms(a_buf, w_buf, halves, half_ptr, h_i, floor, seen_rows[r], s1, s2, cn, hc_rows[h_i, r],
                            ho_rows[h_i, r])
                for i in range(n_spans):
                    own_all[h_i, i, r] = _all_set(ho_rows[h_i, r, base[i]:base[i] + sw[i]])
        for j in range(m):
            y = y0 + j
            for x in range(total):
                l_row[x] = inf
            for h_i in range(n_halves):
                _box_spans(hc_rows[h_i], q0, y, rad, h, w, ta, sw, base, ordered, col, bt)
                all_full = True
                for i in range(n_spans):
                    full[i] = _window_all_set(own_all[h_i, i], q0, y, rad, h)  # every window the half's own
                    all_full &= full[i]
                if all_full:
                    _fold_full(bt, penalty / area, l_row)
                    continue
                _box_spans(ho_rows[h_i], q0, y, rad, h, w, ta, sw, base, ordered, col, bs)
                for i in range(n_spans):
                    a, b = base[i], base[i] + sw[i]
                    if full[i]:
                        _fold_full(bt[a:b], penalty / area, l_row[a:b])
                    else:
                        _fold_half(bt[a:b], bs[a:b], ho_rows[h_i, y - q0, a:b], min_support * area, penalty, l_row[a:b])
            hb = hbest[j]
            for x in range(total):
                hb[x] = min(hb[x], l_row[x])
            _quantise(l_row, inv_unit, least[j, d])
    for j in range(m):
        y = y0 + j
        pr = poor[y]
        br = best[y]
        hb = hbest[j]
        for d in range(n):
            q = least[j, d]
            o = out[y, d]
            for i in range(n_spans):
                xa, xb = span_a[i], span_b[i]
                at = base[i] + xa - ta[i]
                qs, hs = q[at:at + xb - xa], hb[at:at + xb - xa]
                ps, bs_, os_ = pr[xa:xb], br[xa:xb], o[xa:xb]
                for x in range(xb - xa):
                    take = ps[x] & (hs[x] < gain * bs_[x])
                    os_[x] = min(os_[x], qs[x]) if take else os_[x]


@njit(**JIT)
def _view_span(src, msk, all_valid, edge_y, edge_x, iy, ix, fy, fx, pad, ones_lo, ones_hi, y, d, views, x0, m, at, a_buf,
               w_buf):
    """Every view's value (premultiplied by its mask) and weight at the ``m`` columns from x0 of
    row ``y`` shifted to hypothesis ``d`` (bilinear, zero outside the view), into ``a_buf`` and
    ``w_buf`` from their column ``at``: one pass a view, each sample and weight made where it is
    written (:func:`_sample`, :func:`_mask_weight`)."""
    for j in range(views.shape[0]):
        k = views[j]
        upper, lower, r, c0, p, q, a, b = _view_taps(src, iy, ix, fy, fx, pad, y, d, k, x0, m)
        out_a = a_buf[j, at:at + m]
        out_w = w_buf[j, at:at + m]
        if all_valid:
            e = edge_y[d, k, y]
            ex = edge_x[d, k, x0:x0 + m]
            for x in range(m):
                out_a[x] = _sample(upper, lower, p, q, a, b, x)
                out_w[x] = e * ex[x]
        else:
            mu, ml, lo, hi = _mask_taps(msk, ones_lo, ones_hi, k, r, c0, m)
            for x in range(m):
                out_a[x] = _sample(upper, lower, p, q, a, b, x)
                out_w[x] = _mask_weight(mu, ml, lo, hi, p, q, a, b, x)


@njit(**INLINE)
def _box_spans(rows, q0, y, rad, h, w, ta, sw, base, ordered, col, out):
    """The box sums at row ``y`` of every span laid out by :func:`_halves_strip` (``rows``: its
    rows of a quantity from image row ``q0``, reflected at the image's top and bottom): exact
    over each span's columns but its ``rad`` outermost at a side inside the image, which the
    caller keeps out of use. Where a span meets the image's side, its padding is the span's
    columns reflected there."""
    total = col.shape[0]
    _vbox(rows, q0, y, rad, h, ordered, col)
    for i in range(ta.shape[0]):
        b, n_i = base[i], sw[i]
        if ta[i] == 0:
            for x in range(rad):
                col[b - rad + x] = col[b + reflect(x - rad, n_i)]
        if ta[i] + n_i == w:
            for x in range(rad):
                col[b + n_i + x] = col[b + reflect(n_i + x, n_i)]
    # As _hsum (the first and last rad columns, padding, are left as they are).
    _shifted_sum(col, rad, out[rad:total - rad])
