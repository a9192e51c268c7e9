"""The compiled kernels of :mod:`lfring.depth.refine`: numba, cached on disk after the first compile.

Besides the weighted median, the refinement's per-pixel steps around it (which pixels are known,
their range and bins, the smoother's inputs and the filled map) run here row-parallel, in float32
as NumPy computes them: in NumPy they were serial passes that bound the call on many cores.

Importing this module imports numba; :mod:`lfring.depth.refine` imports it on first use only.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

__all__ = ["bin_values", "fill_inputs", "filled_map", "known_pixels", "value_range", "weighted_median"]


KERNEL = dict(parallel=True, cache=True, nogil=True, fastmath=False, error_model="numpy")


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
def weighted_median(values, bins, guide, radius, lut, fine_bins, out):
    """Per pixel with a bin (``bins >= 0``; -1: unknown, NaN out), the weighted median of the
    known values in its (2 radius + 1)^2 window, weighted by ``lut[|guide_p - guide_q|]``.

    ``bins`` holds each known value's bin, of ``fine_bins``. A window's values span few bins and
    neighbours mostly share one, so each run of consecutive entries of one bin is summed in
    registers and added to the histogram once (adding every entry to memory chains each add to
    the last one's store). The median's bin is found by one cumulative scan from the window's
    lowest bin to its highest (a coarse histogram beside it measured slower on the twin and on
    real stereo pairs, for the same answers); the answer is the weighted mean of the values in
    that bin. One row per parallel task; each task keeps its own histograms and clears only the
    range of bins it touched.
    """
    h, w = values.shape
    for y in prange(h):
        hf = np.zeros(fine_bins, np.float64)
        hv = np.zeros(fine_bins, np.float64)
        y0 = max(0, y - radius)
        y1 = min(h, y + radius + 1)
        for x in range(w):
            if bins[y, x] < 0:
                out[y, x] = np.nan
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
