"""The compiled kernels of :mod:`lfring.depth.refine`: numba, cached on disk after the first compile.

Besides the weighted median, the refinement's per-pixel steps around it (which pixels are known,
their range and bins, the smoother's inputs and the filled map) run here row-parallel, in float32
as NumPy computes them: in NumPy they were serial passes that bound the call on many cores. So
does the semi-global engine's last step, from the refined and filled index maps to the depth maps
(:func:`depth_maps`).

Importing this module imports numba; :mod:`lfring.depth.refine` imports it on first use only.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from lfring.core.compiled import COMPILED as SERIAL
from lfring.core.compiled import COMPILED_PARALLEL as KERNEL

__all__ = ["bin_values", "depth_maps", "fill_inputs", "filled_map", "known_pixels", "value_range", "weighted_median"]


@njit(**KERNEL)
def known_pixels(values, confidence, min_confidence, known):
    """known = a finite value with a finite confidence of at least ``min_confidence`` (float32)."""
    h, w = values.shape
    for y in prange(h):
        for x in range(w):
            c = confidence[y, x]
            known[y, x] = np.isfinite(values[y, x]) and np.isfinite(c) and c >= min_confidence


@njit(**KERNEL)
def value_range(values, known):
    """(least, largest) of the known values; (inf, -inf) where none is."""
    h, w = values.shape
    lows = np.full(h, np.inf, np.float32)
    highs = np.full(h, -np.inf, np.float32)
    for y in prange(h):
        lo = np.float32(np.inf)
        hi = np.float32(-np.inf)
        for x in range(w):
            if known[y, x]:
                lo = min(lo, values[y, x])
                hi = max(hi, values[y, x])
        lows[y] = lo
        highs[y] = hi
    lo = np.float32(np.inf)
    hi = np.float32(-np.inf)
    for y in range(h):
        lo = min(lo, lows[y])
        hi = max(hi, highs[y])
    return lo, hi


@njit(**KERNEL)
def bin_values(values, known, lo, width, count, bins):
    """bins = floor((value - lo) / width) clipped to [0, count - 1] (float32 steps) where known,
    -1 elsewhere."""
    h, w = values.shape
    top = np.float32(count - 1)
    for y in prange(h):
        for x in range(w):
            if known[y, x]:
                q = np.floor((values[y, x] - lo) / width)
                bins[y, x] = np.int32(min(max(q, np.float32(0.0)), top))
            else:
                bins[y, x] = -1


@njit(**KERNEL)
def fill_inputs(known, refined, confidence, floor, weight, weighted):
    """The smoother's inputs: ``weight`` = the confidence floored at ``floor`` where known, 0
    elsewhere; ``weighted`` = the refined value times it (0 where not known)."""
    h, w = known.shape
    zero = np.float32(0.0)
    for y in prange(h):
        for x in range(w):
            k = known[y, x]
            wt = max(confidence[y, x], floor) if k else zero
            weight[y, x] = wt
            weighted[y, x] = (refined[y, x] if k else zero) * wt


@njit(**KERNEL)
def filled_map(known, refined, num, den, floor, out):
    """out = refined where known, else num / den where den > floor, else NaN."""
    h, w = known.shape
    for y in prange(h):
        for x in range(w):
            if known[y, x]:
                out[y, x] = refined[y, x]
            else:
                out[y, x] = num[y, x] / den[y, x] if den[y, x] > floor else np.float32(np.nan)


@njit(**KERNEL)
def depth_maps(refined, index, filled, confidence, nviews, use_index, step, inv0, z0, seen_views, depth, conf_out,
               index_out, filled_depth):
    """The semi-global engine's maps from its index maps, for hypotheses evenly spaced in
    1 / (Z - z0), in one pass with :class:`lfring.depth.selection.Finisher`'s floats.

    A pixel's index is ``refined`` where finite, else ``index`` with ``use_index`` (NaN without).
    Where ``nviews`` reaches ``seen_views`` and that index is finite: ``depth`` = 1 / (index
    times ``step`` + ``inv0``) + ``z0``, ``conf_out`` the confidence, ``index_out`` the index; elsewhere
    NaN, 0 and NaN. ``filled_depth``: the depth of ``filled`` where finite, else of that index,
    wherever ``nviews`` reaches ``seen_views``; NaN elsewhere."""
    h, w = refined.shape
    nan = np.float32(np.nan)
    one = np.float32(1.0)
    for y in prange(h):
        for x in range(w):
            r = refined[y, x]
            i = r if np.isfinite(r) else (index[y, x] if use_index else nan)
            f = filled[y, x]
            f = f if np.isfinite(f) else i
            views_ok = nviews[y, x] >= seen_views
            seen = views_ok and np.isfinite(i)
            depth[y, x] = one / (i * step + inv0) + z0 if seen else nan
            conf_out[y, x] = confidence[y, x] if seen else np.float32(0.0)
            index_out[y, x] = i if seen else nan
            filled_depth[y, x] = one / (f * step + inv0) + z0 if views_ok else nan


# A row's pixels whose window spans one bin or two adjacent ones take the median from four sums
# a pixel, accumulated offset by offset along the row in float32 loops; the others
# (and rows where they are too few) take a histogram each. The sums cost every column between the
# row's first and last such pixel, a histogram only its own pixel: the sums are used where those
# pixels make at least this share of the columns they span (about the ratio of the two costs per
# window entry).
MEDIAN_SUMS_MIN_SHARE = 0.25
# The sums serve windows whose known bins lie within this many of their least (two adjacent bins).
MEDIAN_SUMS_SPAN = 1
_NO_BIN = 2**30  # a window's least bin where it holds no known value


@njit(**SERIAL)
def _enough(n, first, end):
    """Whether ``n`` pixels over the columns first..end are worth the row's sums
    (:data:`MEDIAN_SUMS_MIN_SHARE`)."""
    return n > 0 and n >= MEDIAN_SUMS_MIN_SHARE * (end - first)


@njit(**KERNEL)
def weighted_median(values, bins, guide, radius, lut, fine_bins, out):
    """Per pixel with a bin (``bins >= 0``; -1: unknown, NaN out), the weighted median of the
    known values in its (2 radius + 1)^2 window, weighted by ``lut[|guide_p - guide_q|]``: the
    lowest bin whose cumulative weight reaches half the window's, and the weighted mean of the
    values in it.

    ``bins`` holds each known value's bin, of ``fine_bins``. Most windows span one bin or two
    adjacent ones (a smooth surface): for those, :func:`_two_bin_sums` sums each pixel's weight
    and weighted value in its window's lowest bin and in the one above, in float32 loops over the
    row (:data:`MEDIAN_SUMS_MIN_SHARE`); the median is the lower bin where its weight reaches
    half the window's, else the upper. Other pixels take a histogram of their window in float64:
    each run of consecutive entries of one bin is summed in registers and added to the histogram
    once, and the median's bin is found by one cumulative scan from the window's lowest bin to
    its highest. The two ways decide the same bin but where the weights below it make half to
    within float32 rounding. One row per parallel task; each task keeps its own histograms and
    clears only the range of bins it touched.
    """
    h, w = values.shape
    lut32 = lut.astype(np.float32)
    for y in prange(h):
        y0 = max(0, y - radius)
        y1 = min(h, y + radius + 1)
        # The known pixels first: where they are too few, their windows' bins are not worth
        # finding.
        ka = w
        kb = 0
        n = 0
        for x in range(w):
            if bins[y, x] >= 0:
                ka = min(ka, x)
                kb = x + 1
                n += 1
        dense = _enough(n, ka, kb)
        if dense:
            xa, take, sums = _two_bin_sums(values, bins, guide, y, radius, lut32)
        else:
            xa, take, sums = 0, np.zeros(0, np.bool_), np.zeros((4, 0), np.float32)
        hf = np.zeros(fine_bins, np.float64)
        hv = np.zeros(fine_bins, np.float64)
        for x in range(w):
            if bins[y, x] < 0:
                out[y, x] = np.nan
                continue
            if dense and take[x]:
                i = x - xa
                w_lo = sums[0, i]
                w_hi = sums[2, i]
                own = values[y, x]
                if w_lo >= w_hi:  # the lower bin holds half the window's weight
                    out[y, x] = own + sums[1, i] / w_lo if w_lo > 0.0 else own
                else:
                    out[y, x] = own + sums[3, i] / w_hi if w_hi > 0.0 else own
                continue
            gp = np.int32(guide[y, x])
            x0 = max(0, x - radius)
            x1 = min(w, x + radius + 1)
            fmin = fine_bins
            fmax = 0
            run = -1  # the bin of the run being summed
            run_w = 0.0
            run_v = 0.0
            for yy in range(y0, y1):
                br = bins[yy, x0:x1]
                gr = guide[yy, x0:x1]
                vr = values[yy, x0:x1]
                for j in range(x1 - x0):
                    f = br[j]
                    if f >= 0:
                        wq = lut[abs(np.int32(gr[j]) - gp)]
                        if f != run:
                            if run >= 0:
                                hf[run] += run_w
                                hv[run] += run_v
                            run = f
                            run_w = 0.0
                            run_v = 0.0
                            fmin = min(fmin, f)
                            fmax = max(fmax, f)
                        run_w += wq
                        run_v += wq * np.float64(vr[j])
            if run >= 0:
                hf[run] += run_w
                hv[run] += run_v
            total = 0.0
            for f in range(fmin, fmax + 1):
                total += hf[f]
            half = 0.5 * total
            acc = 0.0
            f = fmin
            # Stops on a filled bin: an empty one cannot take the sum from below half to half.
            while f < fmax and acc + hf[f] < half:
                acc += hf[f]
                f += 1
            out[y, x] = np.float32(hv[f] / hf[f]) if hf[f] > 0.0 else values[y, x]
            hf[fmin:fmax + 1] = 0.0  # the touched range only
            hv[fmin:fmax + 1] = 0.0


@njit(**SERIAL)
def _two_bin_sums(values, bins, guide, y, radius, lut32):
    """For row y of :func:`weighted_median`, ``(xa, take, sums)``: ``take``, (w,) bool, the pixels
    that take their median from the sums (known, their window's known bins at most
    :data:`MEDIAN_SUMS_SPAN` from its least); ``sums``, (4, xb - xa) float32 for the columns
    xa..xb that hold them: the weight and the weighted value of each window's known entries in its
    least bin (rows 0 and 1), and of the others (rows 2 and 3). No pixel takes them where too few
    would (:func:`_enough`; the caller calls this only for rows whose known pixels are not too
    few). The values are summed less the pixel's own: a window of equal values sums to 0 exactly,
    and the float32 sums of values that differ little keep their precision. An unknown entry's
    value (it may be NaN) enters no sum; an unknown pixel's own value may spoil its own column's
    sums, which no pixel takes."""
    h, w = bins.shape
    y0 = max(0, y - radius)
    y1 = min(h, y + radius + 1)
    take = np.zeros(w, np.bool_)
    br = bins[y]
    # Each window's least known bin (_NO_BIN where none is known) and largest (-1): the columns'
    # extremes over the rows first, then along the row.
    cmin = np.full(w, _NO_BIN, np.int32)
    cmax = np.full(w, -1, np.int32)
    for yy in range(y0, y1):
        bq = bins[yy]
        for x in range(w):
            b = bq[x]
            cmax[x] = max(cmax[x], b)
            cmin[x] = min(cmin[x], b if b >= 0 else _NO_BIN)
    lo = np.full(w, _NO_BIN, np.int32)
    hi = np.full(w, -1, np.int32)
    for dx in range(-radius, radius + 1):
        xs = max(0, -dx)
        xe = min(w, w - dx)
        if xe <= xs:
            continue
        lo_s = lo[xs:xe]
        hi_s = hi[xs:xe]
        cmn = cmin[xs + dx:xe + dx]
        cmx = cmax[xs + dx:xe + dx]
        for i in range(xe - xs):
            lo_s[i] = min(lo_s[i], cmn[i])
            hi_s[i] = max(hi_s[i], cmx[i])
    xa = w
    xb = 0
    n = 0
    for x in range(w):
        take[x] = br[x] >= 0 and hi[x] - lo[x] <= MEDIAN_SUMS_SPAN
        if take[x]:
            xa = min(xa, x)
            xb = x + 1
            n += 1
    if not _enough(n, xa, xb):
        take[:] = False
        return 0, take, np.zeros((4, 0), np.float32)
    m = xb - xa
    sums = np.zeros((4, m), np.float32)
    weight = np.empty(m, np.float32)
    zero = np.float32(0.0)
    gc = guide[y, xa:xb]
    vc = values[y, xa:xb]
    lo_c = lo[xa:xb]
    w_0 = sums[0]
    v_0 = sums[1]
    w_1 = sums[2]
    v_1 = sums[3]
    for yy in range(y0, y1):
        bq_row = bins[yy]
        gq_row = guide[yy]
        vq_row = values[yy]
        for dx in range(-radius, radius + 1):
            xs = max(xa, -dx)  # the output columns xs..xe whose neighbour x + dx lies in the image
            xe = min(xb, w - dx)
            if xe <= xs:
                continue
            k = xe - xs
            bq = bq_row[xs + dx:xe + dx]
            gq = gq_row[xs + dx:xe + dx]
            vq = vq_row[xs + dx:xe + dx]
            gp = gc[xs - xa:xe - xa]
            vp = vc[xs - xa:xe - xa]
            # The table's lookups in a loop of their own, which keeps the sums' loop free of
            # them (benchmarks/RESULTS.md).
            for i in range(k):
                weight[i] = lut32[abs(np.int32(gq[i]) - np.int32(gp[i]))]
            lo_s = lo_c[xs - xa:xe - xa]
            w0 = w_0[xs - xa:xe - xa]
            v0 = v_0[xs - xa:xe - xa]
            w1 = w_1[xs - xa:xe - xa]
            v1 = v_1[xs - xa:xe - xa]
            for i in range(k):
                b = bq[i]
                wq = weight[i] if b >= 0 else zero
                wv = wq * (vq[i] - vp[i]) if b >= 0 else zero  # 0 times an unknown NaN is NaN
                low = b == lo_s[i]
                w0[i] += wq if low else zero
                v0[i] += wv if low else zero
                w1[i] += zero if low else wq
                v1[i] += zero if low else wv
    return xa, take, sums
