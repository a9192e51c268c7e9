"""The compiled kernel of :mod:`lfring.depth.refine`: numba, cached on disk after the first compile.

Importing this module imports numba; :mod:`lfring.depth.refine` imports it on first use only.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

__all__ = ["weighted_median"]


@njit(parallel=True, cache=True, nogil=True, fastmath=False, error_model="numpy")
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
