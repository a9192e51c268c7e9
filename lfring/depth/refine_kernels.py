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

    ``bins`` holds each known value's bin, of ``fine_bins``. The median's bin is found by one
    cumulative scan from the window's lowest bin to its highest (a window's values span few
    bins: a coarse histogram beside it measured slower on the twin and on real stereo pairs,
    for the same answers); the answer is the weighted mean of the values in that bin. One row per
    parallel task; each task keeps its own histograms and clears only the range of bins it
    touched.
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
            total = 0.0
            fmin = fine_bins
            fmax = 0
            for yy in range(y0, y1):
                for xx in range(x0, x1):
                    f = bins[yy, xx]
                    if f >= 0:
                        wq = lut[abs(np.int32(guide[yy, xx]) - gp)]
                        hf[f] += wq
                        hv[f] += wq * np.float64(values[yy, xx])
                        total += wq
                        fmin = min(fmin, f)
                        fmax = max(fmax, f)
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
