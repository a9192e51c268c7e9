"""The compiled kernels of the fused semi-global engine (:mod:`lfring.depth.engines.semiglobal`):
numba, cached on disk, imported on first use.

The engine holds the cost volume in 16-bit integers, once, and never in float32:

1. :func:`sample_costs`: the aggregated cost of all views on a few rows, for the scale of the
   penalties and of the integer costs, and for the 'lcn-halves' threshold.
2. :func:`sweep_volume`: per strip of rows, every view shifted to every hypothesis and summed,
   the 'lcn' cost aggregated over the box and quantised into a (h, N, w) uint16 volume;
   :func:`sweep_halves` then, where no depth suits all views, the cost of the halves of the
   views, taken where a half agrees much better.
3. :func:`horizontal_paths`: per row, the volume eroded (shiftable windows) and the left-right
   and right-left scan paths, summed into a (h, N, w) uint16 accumulator.
4. :func:`vertical_paths`: per block of columns, the top-down path, then the bottom-up one, at
   whose every pixel the sum of the paths is complete: the winner, its parabola on the wider box
   of the cost and the confidence are taken there, and the sum is never written back.

Every step works on rows of one hypothesis at a time in small helpers whose loops run over
contiguous pixels, so that they vectorise; strips, rows and blocks of columns are the parallel
tasks. A cost is held in units of a fraction of the path penalty: a path's value exceeds its cost
by at most the large-jump penalty, so a sum of four paths fits in 16 bits when the cost is
clipped to :data:`COST_MAX` and the penalties stay below :data:`PENALTY_MAX`.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

__all__ = ["COST_MAX", "COST_ZERO", "PENALTY_MAX", "UNKNOWN", "horizontal_paths", "sample_costs", "sweep_halves", "sweep_volume",
           "vertical_paths"]

# Fast maths without "no infinities": unknown costs are inf until they are quantised.
_FAST = {"nsz", "arcp", "contract", "afn"}
_JIT = dict(cache=True, nogil=True, fastmath=_FAST, error_model="numpy")
_PAR = dict(_JIT, parallel=True)
# Small row helpers are inlined into their callers: a call per row and hypothesis costs more than
# the row itself on the short rows of a span or a block of columns.
_INLINE = dict(_JIT, inline="always")
# Side of the square tiles of a transposition.
_TILE = 16
# A cost that no two views saw: never a winner; the paths see the pixel's mean known cost there.
UNKNOWN = 65535
# The largest cost and penalty kept: 4 * (COST_MAX + PENALTY_MAX) < 2**16.
COST_MAX = 12000
PENALTY_MAX = 4000
# The integer that stands for a cost of 0: where the views agree, float rounding makes the cost
# slightly negative, and those values keep their place below the others. The paths' sums carry
# it once per path, the box means once; the distinctness measures take it off.
COST_ZERO = 1024


# -- small row helpers -------------------------------------------------------------------------
@njit(inline="always")
def _reflect(i, n):
    """Index i folded into [0, n) as OpenCV's BORDER_REFLECT_101."""
    if n == 1:
        return 0
    while i < 0 or i >= n:
        i = -i if i < 0 else 2 * n - 2 - i
    return i


@njit(**_INLINE)
def _lerp(s0, s1, p, q, t):
    """t = p s0 + q s1 (the vertical tap pair of a bilinear shift)."""
    for x in range(t.shape[0]):
        t[x] = p * s0[x] + q * s1[x]


@njit(**_INLINE)
def _shifted(t, a, b, out):
    """out = a t[x] + b t[x + 1] (the horizontal tap pair)."""
    for x in range(out.shape[0]):
        out[x] = a * t[x] + b * t[x + 1]


@njit(**_INLINE)
def _scaled(row, s, out):
    for x in range(out.shape[0]):
        out[x] = s * row[x]


@njit(**_INLINE)
def _sums_first(v, wt, s1, s2, cn):
    for x in range(v.shape[0]):
        s1[x] = v[x]
        s2[x] = v[x] * v[x]
        cn[x] = wt[x]


@njit(**_INLINE)
def _sums_add(v, wt, s1, s2, cn):
    for x in range(v.shape[0]):
        s1[x] += v[x]
        s2[x] += v[x] * v[x]
        cn[x] += wt[x]


@njit(**_INLINE)
def _lcn_row(s1, s2, cn, floor, seen_in, t, seen):
    """The 'lcn' cost of the sums where 1.5 views or more see the pixel (and ``seen_in``, when
    given), 0 elsewhere; ``seen`` 1 or 0."""
    one = np.float32(1.0)
    half = np.float32(0.5)
    lim = np.float32(1.5)
    for x in range(t.shape[0]):
        c = cn[x]
        ok = (c >= lim) & (seen_in[x] > half)
        r = c if c > floor else floor
        dd = c - one
        dd = dd if dd > half else half
        t[x] = (s2[x] - s1[x] * s1[x] / r) / dd if ok else np.float32(0.0)
        seen[x] = one if ok else np.float32(0.0)


@njit(**_INLINE)
def _vsum(rows, start, count, out):
    """out = sum of ``count`` rows of ``rows`` from index ``start`` (any order of rows)."""
    w = out.shape[0]
    for x in range(w):
        out[x] = rows[start, x]
    for k in range(start + 1, start + count):
        r = rows[k]
        for x in range(w):
            out[x] += r[x]


@njit(**_INLINE)
def _hsum(col, rad, tmp, out):
    """out[x] = sum of col over x - rad .. x + rad, reflected at the ends (BORDER_REFLECT_101)."""
    w = col.shape[0]
    for x in range(w):
        tmp[x + rad] = col[x]
    for x in range(rad):
        tmp[x] = col[_reflect(x - rad, w)]
        tmp[w + rad + x] = col[_reflect(w + x, w)]
    for x in range(w):
        s = tmp[x]
        for k in range(1, 2 * rad + 1):
            s += tmp[x + k]
        out[x] = s


# -- per-pixel terms of one row at one hypothesis ------------------------------------------------
@njit(**_INLINE)
def _weights(m0, m1, ones_lo, ones_hi, r, c0, p, q, a, b, t, out):
    """out[x] = the bilinear mask at padded columns c0 + x (+1) of padded rows r, r + 1 (``m0``,
    ``m1``: those rows from c0), 1 where all four taps lie in both rows' run of ones
    [ones_lo, ones_hi) (a disc's inside, where nothing needs computing)."""
    m = out.shape[0]
    lo = max(ones_lo[r], ones_lo[r + 1]) - c0
    hi = min(ones_hi[r], ones_hi[r + 1]) - c0 - 1  # x + 1 must be inside too
    lo = min(max(lo, 0), m)
    hi = min(max(hi, lo), m)
    if hi - lo < m:
        _lerp(m0, m1, p, q, t)
        for x in range(lo):
            out[x] = a * t[x] + b * t[x + 1]
        for x in range(hi, m):
            out[x] = a * t[x] + b * t[x + 1]
    for x in range(lo, hi):
        out[x] = np.float32(1.0)



@njit(**_JIT)
def _view_rows(src, msk, all_valid, edge_y, edge_x, iy, ix, fy, fx, pad, ones_lo, ones_hi, y, d, views, t, a_buf,
               w_buf):
    """Every view's value (premultiplied by its mask) and weight at row ``y`` shifted to
    hypothesis ``d`` (bilinear, zero outside the view)."""
    w = a_buf.shape[1]
    for j in range(views.shape[0]):
        k = views[j]
        r = y + iy[d, k] + pad
        c0 = ix[d, k] + pad
        q = np.float32(fy[d, k])
        p = np.float32(1.0) - q
        b = np.float32(fx[d, k])
        a = np.float32(1.0) - b
        _lerp(src[k, r, c0:c0 + w + 1], src[k, r + 1, c0:c0 + w + 1], p, q, t)
        _shifted(t, a, b, a_buf[j])
        if all_valid:
            _scaled(edge_x[d, k], edge_y[d, k, y], w_buf[j])
        else:
            _weights(msk[k, r, c0:c0 + w + 1], msk[k, r + 1, c0:c0 + w + 1], ones_lo[k], ones_hi[k], r, c0, p, q, a, b,
                     t, w_buf[j])


@njit(**_JIT)
def _all_terms(a_buf, w_buf, floor, ones, s1, s2, cn, t, seen):
    _sums_first(a_buf[0], w_buf[0], s1, s2, cn)
    for j in range(1, a_buf.shape[0]):
        _sums_add(a_buf[j], w_buf[j], s1, s2, cn)
    _lcn_row(s1, s2, cn, floor, ones, t, seen)


@njit(**_JIT)
def _half_terms(a_buf, w_buf, halves, half_ptr, h_i, floor, seen, s1, s2, cn, hc, ho):
    j0 = halves[half_ptr[h_i]]
    _sums_first(a_buf[j0], w_buf[j0], s1, s2, cn)
    for q_i in range(half_ptr[h_i] + 1, half_ptr[h_i + 1]):
        j = halves[q_i]
        _sums_add(a_buf[j], w_buf[j], s1, s2, cn)
    _lcn_row(s1, s2, cn, floor, seen, hc, ho)


@njit(**_INLINE)
def _all_set(row):
    """Whether every value of a row of 1 / 0 flags is 1."""
    for x in range(row.shape[0]):
        if row[x] < np.float32(0.5):
            return False
    return True


@njit(**_INLINE)
def _window_all_set(flags, q0, y, rad, h):
    """Whether the rows y - rad .. y + rad (reflected) all have their flag set."""
    for k in range(y - rad, y + rad + 1):
        if not flags[_reflect(k, h) - q0]:
            return False
    return True


@njit(**_INLINE)
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


@njit(**_INLINE)
def _fold_full(bt, scale, least):
    """least = min(least, scale * bt): a half whose every window is its own."""
    for x in range(least.shape[0]):
        c = scale * bt[x]
        least[x] = c if c < least[x] else least[x]


@njit(**_INLINE)
def _agg_row(bt, bs, seen_c, area, floor, out):
    """The seen-pixel mean of a box (sums ``bt`` of costs, ``bs`` of seen pixels); inf where the
    centre pixel is not seen."""
    inf = np.float32(np.inf)
    for x in range(out.shape[0]):
        sup = bs[x] / area
        sup = sup if sup > floor else floor
        out[x] = bt[x] / area / sup if seen_c[x] > np.float32(0.5) else inf


@njit(**_INLINE)
def _fold_half(bt, bs, own_c, area_support, penalty, least):
    """least = min(least, penalty * bt / bs) where the centre is the half's own and the window's
    own share reaches the support."""
    for x in range(least.shape[0]):
        ok = (own_c[x] > np.float32(0.5)) & (bs[x] >= area_support)
        c = penalty * bt[x] / (bs[x] if ok else np.float32(1.0))
        least[x] = c if ok & (c < least[x]) else least[x]


# -- pass 0: the scale and threshold from a sample of rows --------------------------------------
@njit(**_PAR)
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
        t = np.empty(w + 1, np.float32)
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
                yy = _reflect(y - rad + k, h)
                _view_rows(src, msk, all_valid, edge_y, edge_x, iy, ix, fy, fx, pad, ones_lo, ones_hi, yy, d, views, t, a_buf,
                           w_buf)
                _all_terms(a_buf, w_buf, floor, ones, s1, s2, cn, t_rows[k], seen_rows[k])
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
@njit(**_INLINE)
def _quantise(v, inv_unit, out):
    """Costs in integer units from COST_ZERO, rounded and clipped to [0, COST_MAX]; UNKNOWN where
    not finite."""
    cmax = np.float32(COST_MAX)
    inf = np.float32(np.inf)
    for x in range(out.shape[0]):
        q = v[x] * inv_unit + np.float32(COST_ZERO + 0.5)  # rounded
        q = q if q < cmax else cmax
        q = q if q > np.float32(0.0) else np.float32(0.0)
        out[x] = np.uint16(q) if v[x] < inf else np.uint16(UNKNOWN)


@njit(**_JIT)
def _box_row(rows, q0, y, rad, h, ordered, col, tmp, out):
    """The box sum at row ``y`` of a quantity whose rows from image row ``q0`` are ``rows``
    (reflected at the image's top and bottom; ``ordered`` a scratch of 2 rad + 1 rows)."""
    c = y - q0
    if y - rad >= 0 and y + rad < h:
        _vsum(rows, c - rad, 2 * rad + 1, col)
    else:
        for k in range(2 * rad + 1):
            ordered[k] = rows[_reflect(y - rad + k, h) - q0]
        _vsum(ordered, 0, 2 * rad + 1, col)
    _hsum(col, rad, tmp, out)


@njit(**_PAR)
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
        t = np.empty(w + 1, np.float32)
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
        col = np.empty(w, np.float32)
        bt = np.empty(w, np.float32)
        bs = np.empty(w, np.float32)
        tmp = np.empty(w + 2 * rad, np.float32)
        agg = np.empty(w, np.float32)
        for y in range(y0, y1):
            nviews[y] = 0.0
            best[y] = inf
            total[y] = 0.0
            count[y] = 0.0
        for d in range(n):
            for r in range(nq):
                _view_rows(src, msk, all_valid, edge_y, edge_x, iy, ix, fy, fx, pad, ones_lo, ones_hi, q0 + r, d, views, t,
                           a_buf, w_buf)
                _all_terms(a_buf, w_buf, floor, ones, s1, s2, cn, t_rows[r], seen_rows[r])
                if q0 + r >= y0 and q0 + r < y1:
                    nvr = nviews[q0 + r]
                    for x in range(w):
                        nvr[x] = max(nvr[x], cn[x])
            for r in range(nq):
                seen_all[r] = _all_set(seen_rows[r])
            for y in range(y0, y1):
                _box_row(t_rows, q0, y, rad, h, ordered, col, tmp, bt)
                if _window_all_set(seen_all, q0, y, rad, h):  # every window wholly seen
                    bs[:] = area
                else:
                    _box_row(seen_rows, q0, y, rad, h, ordered, col, tmp, bs)
                _agg_row(bt, bs, seen_rows[y - q0], area, floor, agg)
                _quantise(agg, inv_unit, out[y, d])
                b_row = best[y]
                t_row = total[y]
                c_row = count[y]
                for x in range(w):
                    b_row[x] = min(b_row[x], agg[x])
                    known = agg[x] < inf
                    t_row[x] += agg[x] if known else np.float32(0.0)
                    c_row[x] += np.float32(1.0) if known else np.float32(0.0)


@njit(**_PAR)
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
        x = 0
        while x < w:
            if not cols[x]:
                x += 1
                continue
            xa = x
            xb = x + 1
            last = x
            while xb < w and xb - last <= gap:
                if cols[xb]:
                    last = xb
                xb += 1
            xb = last + 1
            _halves_span(src, msk, all_valid, edge_y, edge_x, iy, ix, fy, fx, pad, ones_lo, ones_hi, views, halves, half_ptr, rad, floor,
                         penalty, min_support, gain, unit, poor, best, out, y0, y1, xa, xb)
            x = xb


@njit(**_JIT)
def _halves_span(src, msk, all_valid, edge_y, edge_x, iy, ix, fy, fx, pad, ones_lo, ones_hi, views, halves, half_ptr, rad, floor, penalty,
                 min_support, gain, unit, poor, best, out, y0, y1, xa, xb):
    """:func:`sweep_halves` for the rows y0..y1 and the output columns xa..xb."""
    h, n, w = out.shape
    n_views = views.shape[0]
    n_halves = half_ptr.shape[0] - 1
    inv_unit = np.float32(1.0 / unit)
    area = np.float32((2 * rad + 1) ** 2)
    inf = np.float32(np.inf)
    q0 = max(0, y0 - rad)
    q1 = min(h, y1 + rad)
    nq = q1 - q0
    m = y1 - y0
    # The terms over a span wider by the box's radius, so that its box sums are exact inside.
    ta = max(0, xa - rad)
    tb = min(w, xb + rad)
    sw = tb - ta
    t = np.empty(sw + 1, np.float32)
    a_buf = np.empty((n_views, sw), np.float32)
    w_buf = np.empty((n_views, sw), np.float32)
    s1 = np.empty(sw, np.float32)
    s2 = np.empty(sw, np.float32)
    cn = np.empty(sw, np.float32)
    seen_rows = np.empty((nq, sw), np.float32)
    hc_rows = np.empty((n_halves, nq, sw), np.float32)
    ho_rows = np.empty((n_halves, nq, sw), np.float32)
    ordered = np.empty((2 * rad + 1, sw), np.float32)
    col = np.empty(sw, np.float32)
    bt = np.empty(sw, np.float32)
    bs = np.empty(sw, np.float32)
    tmp = np.empty(sw + 2 * rad, np.float32)
    least = np.empty((m, n, sw), np.float32)
    hbest = np.full((m, sw), inf, np.float32)
    own_all = np.empty((n_halves, nq), np.bool_)
    for d in range(n):
        for r in range(nq):
            _view_span(src, msk, all_valid, edge_y, edge_x, iy, ix, fy, fx, pad, ones_lo, ones_hi, q0 + r, d, views, ta, t,
                       a_buf, w_buf)
            _seen_row(w_buf, seen_rows[r])
            for h_i in range(n_halves):
                _half_terms(a_buf, w_buf, halves, half_ptr, h_i, floor, seen_rows[r], s1, s2, cn, hc_rows[h_i, r],
                            ho_rows[h_i, r])
                own_all[h_i, r] = _all_set(ho_rows[h_i, r])
        for i in range(m):
            y = y0 + i
            l_row = least[i, d]
            for x in range(sw):
                l_row[x] = inf
            for h_i in range(n_halves):
                _box_span(hc_rows[h_i], q0, y, rad, h, ta, w, ordered, col, tmp, bt)
                if _window_all_set(own_all[h_i], q0, y, rad, h):  # every window the half's own
                    _fold_full(bt, penalty / area, l_row)
                    continue
                _box_span(ho_rows[h_i], q0, y, rad, h, ta, w, ordered, col, tmp, bs)
                _fold_half(bt, bs, ho_rows[h_i, y - q0], min_support * area, penalty, l_row)
            hb = hbest[i]
            for x in range(sw):
                hb[x] = min(hb[x], l_row[x])
    q = np.empty(sw, np.uint16)
    for i in range(m):
        y = y0 + i
        pr = poor[y]
        br = best[y]
        hb = hbest[i]
        for d in range(n):
            _quantise(least[i, d], inv_unit, q)
            o = out[y, d]
            for x in range(xa, xb):
                j = x - ta
                take = pr[x] & (hb[j] < gain * br[x])
                o[x] = min(o[x], q[j]) if take else o[x]


@njit(**_JIT)
def _view_span(src, msk, all_valid, edge_y, edge_x, iy, ix, fy, fx, pad, ones_lo, ones_hi, y, d, views, x0, t, a_buf,
               w_buf):
    """:func:`_view_rows` for the columns x0 .. x0 + a_buf.shape[1] of the row."""
    m = a_buf.shape[1]
    for j in range(views.shape[0]):
        k = views[j]
        r = y + iy[d, k] + pad
        c0 = ix[d, k] + pad + x0
        q = np.float32(fy[d, k])
        p = np.float32(1.0) - q
        b = np.float32(fx[d, k])
        a = np.float32(1.0) - b
        _lerp(src[k, r, c0:c0 + m + 1], src[k, r + 1, c0:c0 + m + 1], p, q, t)
        _shifted(t, a, b, a_buf[j])
        if all_valid:
            _scaled(edge_x[d, k, x0:x0 + m], edge_y[d, k, y], w_buf[j])
        else:
            _weights(msk[k, r, c0:c0 + m + 1], msk[k, r + 1, c0:c0 + m + 1], ones_lo[k], ones_hi[k], r, c0, p, q, a, b,
                     t, w_buf[j])


@njit(**_JIT)
def _box_span(rows, q0, y, rad, h, ta, w, ordered, col, tmp, out):
    """:func:`_box_row` over a span of columns from image column ``ta`` of an image ``w`` wide:
    reflected at the image's edges where the span reaches them; its own ends (inside the image)
    are wrong over ``rad`` columns, which the caller keeps out of use."""
    c = y - q0
    sw = col.shape[0]
    if y - rad >= 0 and y + rad < h:
        _vsum(rows, c - rad, 2 * rad + 1, col)
    else:
        for k in range(2 * rad + 1):
            ordered[k] = rows[_reflect(y - rad + k, h) - q0]
        _vsum(ordered, 0, 2 * rad + 1, col)
    if ta == 0 and sw == w:
        _hsum(col, rad, tmp, out)
        return
    # Pad: reflected where the span meets the image's edge, anything elsewhere (never used).
    for x in range(sw):
        tmp[x + rad] = col[x]
    for x in range(rad):
        tmp[x] = col[_reflect(x - rad, sw)] if ta == 0 else col[0]
        tmp[sw + rad + x] = col[_reflect(sw + x, sw)] if ta + sw == w else col[sw - 1]
    for x in range(sw):
        acc = tmp[x]
        for k in range(1, 2 * rad + 1):
            acc += tmp[x + k]
        out[x] = acc


# -- the scan paths ---------------------------------------------------------------------------------
@njit(**_INLINE)
def _min_into(row, out):
    for x in range(out.shape[0]):
        out[x] = min(out[x], row[x])


@njit(**_JIT)
def _eroded_rows(vol, y, rad, x0, x1, ext, out):
    """out (N, x1 - x0) = the least of ``vol`` (h, N, w) over rows y - rad .. y + rad and columns
    x - rad .. x + rad (clipped at the image's edges, as a replicated border), for columns x0..x1;
    ``ext`` a scratch row of x1 - x0 + 2 rad values."""
    h, n, w = vol.shape
    m = x1 - x0
    r0 = max(0, y - rad)
    r1 = min(h, y + rad + 1)
    c0 = max(0, x0 - rad)
    c1 = min(w, x1 + rad)
    lo = c0 - (x0 - rad)  # columns of ext before the image's first (replicated)
    for d in range(n):
        cm = ext[lo:lo + c1 - c0]
        cm[:] = vol[r0, d, c0:c1]
        for r in range(r0 + 1, r1):
            _min_into(vol[r, d, c0:c1], cm)
        for j in range(lo):
            ext[j] = ext[lo]
        for j in range(lo + c1 - c0, m + 2 * rad):
            ext[j] = ext[lo + c1 - c0 - 1]
        o = out[d]
        o[:] = ext[0:m]
        for k in range(1, 2 * rad + 1):
            _min_into(ext[k:k + m], o)


@njit(**_JIT)
def _fill_unknown(e, fill):
    """Each column's unknown costs replaced by the mean of its known ones (0 when none is)."""
    n, m = e.shape
    total = np.zeros(m, np.int64)
    count = np.zeros(m, np.int64)
    for d in range(n):
        row = e[d]
        for x in range(m):
            known = row[x] != UNKNOWN
            total[x] += np.int64(row[x]) if known else 0
            count[x] += 1 if known else 0
    missing = False
    for x in range(m):
        c = count[x]
        fill[x] = (total[x] + c // 2) // c if c > 0 else 0
        missing |= c < n
    if not missing:
        return
    for d in range(n):
        row = e[d]
        for x in range(m):
            row[x] = np.uint16(fill[x]) if row[x] == UNKNOWN else row[x]


@njit(**_INLINE)
def _p2_row(guide_a, guide_b, use_guide, p1, p2, edge_scale, out):
    """The large-jump penalty between neighbours with guide values a and b, as an integer."""
    for x in range(out.shape[0]):
        v = np.float32(p2)
        if use_guide:
            v = np.float32(p2) / (np.float32(1.0) + abs(guide_a[x] - guide_b[x]) / np.float32(edge_scale))
            v = v if v > np.float32(p1) else np.float32(p1)
        out[x] = np.int32(v + np.float32(0.5))


@njit(**_JIT)
def _step_line(e, prev, cur, pmin, cmin, p1, p2e):
    """One step of a path along a line of pixels processed side by side: ``e`` (N, m) costs,
    ``prev`` the previous pixels' path values (N, m), ``pmin`` their least, ``p2e`` the
    large-jump penalties; writes ``cur`` and its least ``cmin``."""
    n, m = e.shape
    for x in range(m):
        cmin[x] = 1 << 30
    for d in range(n):
        dm = d - 1 if d > 0 else d
        dp = d + 1 if d < n - 1 else d
        here = prev[d]
        below = prev[dm]
        above = prev[dp]
        cost = e[d]
        out = cur[d]
        least = cmin
        for x in range(m):
            best = here[x]
            t = below[x] + p1
            best = t if t < best else best
            t = above[x] + p1
            best = t if t < best else best
            t = pmin[x] + p2e[x]
            best = t if t < best else best
            v = np.int32(cost[x]) + best - pmin[x]
            out[x] = v
            least[x] = v if v < least[x] else least[x]


@njit(**_INLINE)
def _path_step(c, prev, cur, pmin, jump, p1):
    """One step of a path at one pixel: ``cur = c + min(prev, prev[d -+ 1] + p1, jump) - pmin``
    over the hypotheses (the ends' missing neighbour is the hypothesis itself); returns the least
    of ``cur``."""
    n = c.shape[0]
    if n == 1:
        cur[0] = c[0] + min(prev[0], jump) - pmin
        return cur[0]
    cur[0] = c[0] + min(min(prev[0], prev[1] + p1), jump) - pmin
    for d in range(1, n - 1):
        best = min(min(prev[d], prev[d - 1] + p1), min(prev[d + 1] + p1, jump))
        cur[d] = c[d] + best - pmin
    cur[n - 1] = c[n - 1] + min(min(prev[n - 1], prev[n - 2] + p1), jump) - pmin
    least = cur[0]
    for d in range(1, n):
        least = min(least, cur[d])
    return least


@njit(**_JIT)
def _horizontal_row(vol, y, guide, use_guide, p1, p2, edge_scale, erode_rad, total):
    """The two horizontal paths of row ``y`` (see :func:`horizontal_paths`)."""
    h, n, w = vol.shape
    e = np.empty((n, w), np.uint16)
    ext = np.empty(w + 2 * erode_rad, np.uint16)
    fill = np.empty(w, np.int64)
    _eroded_rows(vol, y, erode_rad, 0, w, ext, e)
    _fill_unknown(e, fill)
    # One pixel per step: its N costs side by side (transposed in tiles, which stay in the cache).
    c = np.empty((w, n), np.int32)
    for x0 in range(0, w, _TILE):
        x1 = min(w, x0 + _TILE)
        for d0 in range(0, n, _TILE):
            d1 = min(n, d0 + _TILE)
            for x in range(x0, x1):
                for d in range(d0, d1):
                    c[x, d] = e[d, x]
    acc = np.empty((w, n), np.int32)
    bufs = np.empty((2, n), np.int32)
    p2f = np.float32(p2)
    p1f = np.float32(p1)
    for direction in range(2):
        pmin = np.int32(0)
        for i in range(w):
            x = i if direction == 0 else w - 1 - i
            prev = bufs[(i + 1) % 2]
            cur = bufs[i % 2]
            cx = c[x]
            if i == 0:
                for d in range(n):
                    cur[d] = cx[d]
                pmin = cur[0]
                for d in range(1, n):
                    pmin = min(pmin, cur[d])
            else:
                xp = x - 1 if direction == 0 else x + 1
                p2e = np.int32(p2)
                if use_guide:
                    v = p2f / (np.float32(1.0) + abs(guide[y, x] - guide[y, xp]) / np.float32(edge_scale))
                    v = v if v > p1f else p1f
                    p2e = np.int32(v + np.float32(0.5))
                pmin = _path_step(cx, prev, cur, pmin, pmin + p2e, p1)
            ax = acc[x]
            if direction == 0:
                for d in range(n):
                    ax[d] = cur[d]
            else:
                for d in range(n):
                    ax[d] += cur[d]
    for d0 in range(0, n, _TILE):
        d1 = min(n, d0 + _TILE)
        for x0 in range(0, w, _TILE):
            x1 = min(w, x0 + _TILE)
            for d in range(d0, d1):
                row = total[y, d]
                for x in range(x0, x1):
                    row[x] = np.uint16(acc[x, d])


@njit(**_PAR)
def horizontal_paths(vol, guide, use_guide, p1, p2, edge_scale, erode_rad, total):
    """The left-right and right-left paths of every row of the eroded volume: ``total`` (h, N, w)
    uint16 = their sum."""
    for y in prange(vol.shape[0]):
        _horizontal_row(vol, y, guide, use_guide, p1, p2, edge_scale, erode_rad, total)


@njit(**_INLINE)
def _ext_row(row, x0, m, rad, out):
    """out[j] = row[reflect(x0 - rad + j)] for j < m + 2 rad (BORDER_REFLECT_101)."""
    w = row.shape[0]
    a = x0 - rad
    lo = max(0, -a)
    hi = min(m + 2 * rad, w - a)
    out[lo:hi] = row[a + lo:a + hi]
    for j in range(lo):
        out[j] = row[_reflect(a + j, w)]
    for j in range(hi, m + 2 * rad):
        out[j] = row[_reflect(a + j, w)]


@njit(**_INLINE)
def _raw_update(vol, r, d, x0, m, rad, sign, ext, col_sum, col_cnt):
    """col_sum, col_cnt += sign * (known cost, 1) of row ``r`` of hypothesis ``d``."""
    _ext_row(vol[r, d], x0, m, rad, ext)
    for j in range(m + 2 * rad):
        v = ext[j]
        known = v != UNKNOWN
        col_sum[j] += sign * (np.int32(v) if known else 0)
        col_cnt[j] += sign * (1 if known else 0)


@njit(**_INLINE)
def _parabola(cm, c0, cp):
    den = np.float64(cm) - 2.0 * np.float64(c0) + np.float64(cp)
    if den > 0.0:
        return min(0.5, max(-0.5, 0.5 * (np.float64(cm) - np.float64(cp)) / den))
    return 0.0


@njit(**_INLINE)
def _end_offset(c_end, c_next, c_after, inward):
    den = c_end - 2.0 * c_next + c_after
    if den > 0.0 and np.isfinite(den):
        return inward * min(0.5, max(0.0, 1.0 + 0.5 * (c_end - c_after) / den))
    return 0.0


@njit(**_INLINE)
def _distinctness(b, s):
    if np.isfinite(b) and np.isfinite(s) and s > 0.0:
        return np.float32(min(1.0, max(0.0, 1.0 - np.float64(b) / np.float64(s))))
    return np.float32(0.0)


@njit(**_JIT)
def _vertical_block(vol, total, guide, use_guide, p1, p2, edge_scale, erode_rad, raw_rad, exclude, floor, x0, x1,
                    index, conf):
    """The two vertical paths and the selection of columns x0..x1 (see :func:`vertical_paths`)."""
    h, n, w = vol.shape
    m = x1 - x0
    e = np.empty((n, m), np.uint16)
    ext = np.empty(m + 2 * max(erode_rad, raw_rad), np.uint16)
    fill = np.empty(m, np.int64)
    state = np.zeros((2, n, m), np.int32)
    mins = np.zeros((2, m), np.int32)
    p2e = np.zeros(m, np.int32)
    col_sum = np.zeros((n, m + 2 * raw_rad), np.int32)
    col_cnt = np.zeros((n, m + 2 * raw_rad), np.int32)
    raw = np.empty((n, m), np.float32)
    for direction in range(2):
        for i in range(h):
            y = i if direction == 0 else h - 1 - i
            prev = state[(i + 1) % 2]
            cur = state[i % 2]
            pmin = mins[(i + 1) % 2]
            cmin = mins[i % 2]
            _eroded_rows(vol, y, erode_rad, x0, x1, ext, e)
            _fill_unknown(e, fill)
            if i == 0:
                # Zero state: the first row takes its cost alone.
                prev[:] = 0
                pmin[:] = 0
                p2e[:] = 0
            else:
                yp = y - 1 if direction == 0 else y + 1
                _p2_row(guide[y, x0:x1], guide[yp, x0:x1], use_guide, p1, p2, edge_scale, p2e)
            _step_line(e, prev, cur, pmin, cmin, p1, p2e)
            if direction == 0:
                for d in range(n):
                    row = total[y, d, x0:x1]
                    cr = cur[d]
                    for x in range(m):
                        row[x] = np.uint16(np.int32(row[x]) + cr[x])
                continue
            # The wider box's column sums over rows y - raw_rad .. y + raw_rad (reflected), kept
            # running from row to row upwards.
            for d in range(n):
                if i == 0:
                    col_sum[d] = 0
                    col_cnt[d] = 0
                    for k in range(y - raw_rad, y + raw_rad + 1):
                        _raw_update(vol, _reflect(k, h), d, x0, m, raw_rad, 1, ext, col_sum[d], col_cnt[d])
                else:
                    _raw_update(vol, _reflect(y + raw_rad + 1, h), d, x0, m, raw_rad, -1, ext, col_sum[d], col_cnt[d])
                    _raw_update(vol, _reflect(y - raw_rad, h), d, x0, m, raw_rad, 1, ext, col_sum[d], col_cnt[d])
            _select_row(vol, total, cur, y, x0, x1, raw_rad, exclude, floor, col_sum, col_cnt, raw, index, conf)


@njit(**_PAR)
def vertical_paths(vol, total, guide, use_guide, p1, p2, edge_scale, erode_rad, raw_rad, exclude, block, floor,
                   index, conf):
    """The top-down and bottom-up paths of every block of ``block`` columns, added to the
    horizontal paths' ``total``; at every pixel of the bottom-up pass the winner of the sum, its
    sub-hypothesis offset from the parabola through the wider box's mean known cost ('raw') at
    the winner and its neighbours, and the confidence (the sum's distinctness times the raw
    curve's): ``index`` and ``conf`` (h, w) float32."""
    w = vol.shape[2]
    nblocks = (w + block - 1) // block
    for b in prange(nblocks):
        x0 = b * block
        _vertical_block(vol, total, guide, use_guide, p1, p2, edge_scale, erode_rad, raw_rad, exclude, floor, x0,
                        min(w, x0 + block), index, conf)


@njit(**_INLINE)
def _raw_row(col_sum, col_cnt, centre, rad, area, floor, out):
    """out[x] = the mean known cost of the box around x (its column sums ``col_sum``,
    ``col_cnt``), inf where the centre is unknown: the mean over the known pixels with the share
    of known pixels floored at ``floor``, as the seen-pixel mean of the reference."""
    m = out.shape[0]
    ssum = np.int32(0)
    csum = np.int32(0)
    for j in range(2 * rad):
        ssum += col_sum[j]
        csum += col_cnt[j]
    inv_area = np.float32(1.0 / area)
    for x in range(m):
        ssum += col_sum[x + 2 * rad]
        csum += col_cnt[x + 2 * rad]
        share = np.float32(csum) * inv_area
        share = share if share > floor else floor
        out[x] = np.float32(ssum) * inv_area / share if centre[x] != UNKNOWN else np.float32(np.inf)
        ssum -= col_sum[x]
        csum -= col_cnt[x]


@njit(**_JIT)
def _select_row(vol, total, cur, y, x0, x1, raw_rad, exclude, floor, col_sum, col_cnt, raw, index, conf):
    """Winner, offset and confidence of the pixels x0..x1 of row ``y`` from the complete sum
    (``total`` + the bottom-up path ``cur``) and the raw cost's box mean."""
    h, n, w = vol.shape
    m = x1 - x0
    area = (2 * raw_rad + 1) ** 2
    for d in range(n):
        _raw_row(col_sum[d], col_cnt[d], vol[y, d, x0:x1], raw_rad, area, np.float32(floor), raw[d])
    big = np.int32(1 << 30)
    best = np.full(m, big, np.int32)
    tie = np.full(m, np.inf, np.float32)
    arg = np.zeros(m, np.int64)
    for d in range(n):
        trow = total[y, d, x0:x1]
        cr = cur[d]
        rr = raw[d]
        for x in range(m):
            v = np.int32(trow[x]) + cr[x]
            # Integer sums tie where float ones would not: the raw cost breaks the tie.
            better = (v < best[x]) | ((v == best[x]) & (rr[x] < tie[x]))
            best[x] = v if better else best[x]
            tie[x] = rr[x] if better else tie[x]
            arg[x] = d if better else arg[x]
    # The second best of the sum away from the winner, and the raw curve's best and second.
    second = np.full(m, big, np.int32)
    rbest = np.full(m, np.inf, np.float32)
    rarg = np.zeros(m, np.int64)
    for d in range(n):
        trow = total[y, d, x0:x1]
        cr = cur[d]
        rr = raw[d]
        for x in range(m):
            v = np.int32(trow[x]) + cr[x]
            if abs(d - arg[x]) > exclude and v < second[x]:
                second[x] = v
            if rr[x] < rbest[x]:
                rbest[x] = rr[x]
                rarg[x] = d
    rsecond = np.full(m, np.inf, np.float32)
    for d in range(n):
        rr = raw[d]
        for x in range(m):
            if abs(d - rarg[x]) > exclude and rr[x] < rsecond[x]:
                rsecond[x] = rr[x]
    for x in range(m):
        k = arg[x]
        off = 0.0
        if 0 < k < n - 1:
            cm = np.float64(raw[k - 1, x])
            c0 = np.float64(raw[k, x])
            cp = np.float64(raw[k + 1, x])
            if not (np.isfinite(cm) and np.isfinite(c0) and np.isfinite(cp)):
                acc = 0.0
                cnt = 0
                for d in range(n):
                    if np.isfinite(raw[d, x]):
                        acc += raw[d, x]
                        cnt += 1
                f = acc / cnt if cnt > 0 else 0.0
                cm = cm if np.isfinite(cm) else f
                c0 = c0 if np.isfinite(c0) else f
                cp = cp if np.isfinite(cp) else f
            off = _parabola(cm, c0, cp)
        elif n >= 3:
            inward = 1 if k == 0 else -1
            off = _end_offset(np.float64(raw[k, x]), np.float64(raw[k + inward, x]), np.float64(raw[k + 2 * inward, x]),
                              inward)
        index[y, x0 + x] = np.float32(k + off)
        # The distinctness of costs counted from zero: each of the four paths carries COST_ZERO.
        s2 = np.float64(second[x] - 4 * COST_ZERO) if second[x] < big else np.inf
        conf[y, x0 + x] = _distinctness(np.float64(best[x] - 4 * COST_ZERO), s2) * \
            _distinctness(np.float64(rbest[x]) - COST_ZERO, np.float64(rsecond[x]) - COST_ZERO)
