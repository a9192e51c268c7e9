"""The compiled kernels of the 'lcn-occlusion' cost (:mod:`lfring.depth.costs`): numba, cached on disk.

Importing this module imports numba; :mod:`lfring.depth.costs` imports it on first use only.
Each kernel is one pass over its (h, w) arrays with no temporaries, and releases the GIL, so the
sweep's strip threads run them side by side.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["leave_one_out", "take_least"]

_JIT = dict(cache=True, nogil=True, fastmath=False, error_model="numpy")  # numpy: no zero-division checks, so loops vectorise


@njit(**_JIT)
def leave_one_out(s1, s2, count, a_k, w_k, floor, out):
    """``out = lcn_cost(S1 - a_k, S2 - a_k^2, C - w_k)``, per pixel."""
    h, w = s1.shape
    floor = np.float32(floor)
    one = np.float32(1.0)
    half = np.float32(0.5)
    for y in range(h):
        for x in range(w):
            a = a_k[y, x]
            rest = count[y, x] - w_k[y, x]
            s = s1[y, x] - a
            r = rest if rest > floor else floor
            d = rest - one
            d = d if d > half else half
            out[y, x] = ((s2[y, x] - a * a) * r - s * s) / (r * d)


@njit(**_JIT)
def take_least(agg, candidate, penalty, agg_count, agg_w, least_rest):
    """``agg = min(agg, penalty * candidate)`` where ``agg_count - agg_w > least_rest``, in place."""
    h, w = agg.shape
    penalty = np.float32(penalty)
    least_rest = np.float32(least_rest)
    for y in range(h):
        for x in range(w):
            c = penalty * candidate[y, x]
            a = agg[y, x]
            agg[y, x] = c if (agg_count[y, x] - agg_w[y, x] > least_rest) & (c < a) else a  # selects vectorise
