"""The compiled kernels of the 'lcn' sources and of the 'lcn-occlusion' and 'lcn-halves' costs:
numba, cached on disk.

Importing this module imports numba; the cost modules import it on first use only. The per-strip
kernels are one pass over their (h, w) arrays with no temporaries, and release the GIL, so the
sweep's strip threads run them side by side; the two over whole volumes (:func:`volume_minima`,
:func:`take_where`) run their rows in parallel.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from lfring.core.compiled import COMPILED as _JIT

__all__ = ["fold_half", "half_terms", "leave_one_out", "lcn_normalise", "pair_terms", "take_least",
           "take_where", "volume_minima"]


@njit(**_JIT)
def _weighted_square(a, w, floor):
    """A view's term of S2 (:func:`lfring.depth.costs.lcn.weighted_square`): ``a^2 / max(w, floor)``."""
    return (a * a) / (w if w > floor else floor)


@njit(**_JIT)
def lcn_normalise(x, mean, mean_sq, scale, eps, floor, out):
    """The 'lcn' normalisation of a strip (:func:`lfring.depth.costs.lcn.lcn_sources`), per
    pixel in float32: ``m = mean scale``, ``s = mean_sq scale``,
    ``out = (x - m) / sqrt(max(s - m^2, 0) + eps m^2 + floor)``, in one pass. The eps term is
    added as a fused multiply-add would (the float32 product exact in float64, the sum rounded
    to float64 and then to float32: a single rounding but in rare halfway cases), as OpenCV's
    ``scaleAdd`` adds it on a CPU with FMA; the numbers do not depend on the CPU."""
    h, w = out.shape
    zero = np.float32(0.0)
    e = np.float64(eps)
    for y in range(h):
        xr = x[y]
        mr = mean[y]
        sr = mean_sq[y]
        wr = scale[y]
        dr = out[y]
        for i in range(w):
            m = mr[i] * wr[i]
            sq = m * m
            var = sr[i] * wr[i] - sq
            var = var if var > zero else zero
            var = np.float32(np.float64(sq) * e + np.float64(var)) + floor
            dr[i] = (xr[i] - m) / np.sqrt(var)


@njit(**_JIT)
def leave_one_out(s1, s2, count, a_k, w_k, floor, out):
    """``out = lcn_cost(S1 - a_k, S2 - a_k^2 / max(w_k, floor), C - w_k)``, per pixel."""
    h, w = s1.shape
    floor = np.float32(floor)
    one = np.float32(1.0)
    half = np.float32(0.5)
    for y in range(h):
        for x in range(w):
            a = a_k[y, x]
            wk = w_k[y, x]
            rest = count[y, x] - wk
            sq = _weighted_square(a, wk, floor)
            s = s1[y, x] - a
            r = rest if rest > floor else floor
            d = rest - one
            d = d if d > half else half
            out[y, x] = ((s2[y, x] - sq) * r - s * s) / (r * d)


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


@njit(**_JIT)
def _lcn_term(s1, s2, count, seen, floor):
    """The 'lcn' cost of sums (S1, S2, C) where the pixel is ``seen`` and C >= 1.5, else 0, and
    whether it is (as :func:`lfring.depth.costs.lcn_cost`, in float32)."""
    r = count if count > floor else floor
    d = count - np.float32(1.0)
    d = d if d > np.float32(0.5) else np.float32(0.5)
    ok = seen & (count >= np.float32(1.5))
    return ((s2 - s1 * s1 / r) / d if ok else np.float32(0.0)), ok


@njit(**_JIT)
def _count_own(own):
    """The number of pixels ``own`` (> 0). A loop of its own: counted inside the terms' loop, the
    count kept that loop from vectorising (the pair's terms measured markedly slower)."""
    h, w = own.shape
    total = 0
    for y in range(h):
        for x in range(w):
            total += 1 if own[y, x] > np.float32(0.0) else 0
    return total


@njit(**_JIT)
def half_terms(s1, s2, count, seen, floor, cost, own):
    """A half's 'lcn' cost where the pixel is ``seen`` and two of the half's views see it (``own``
    = 1), else 0 and ``own`` = 0: the terms its seen-pixel mean over a window is made of.
    Returns the number of pixels ``own``."""
    h, w = s1.shape
    floor = np.float32(floor)
    for y in range(h):
        for x in range(w):
            c, ok = _lcn_term(s1[y, x], s2[y, x], count[y, x], seen[y, x], floor)
            cost[y, x] = c
            own[y, x] = np.float32(1.0) if ok else np.float32(0.0)
    return _count_own(own)


@njit(**_JIT)
def pair_terms(a0, w0, a1, w1, seen, floor, cost, own):
    """:func:`half_terms` of a half of two views, from their warped values (premultiplied by their
    masks) and masks, without forming the sums first (S2 from :func:`_weighted_square`)."""
    h, w = a0.shape
    floor = np.float32(floor)
    for y in range(h):
        for x in range(w):
            p = a0[y, x]
            q = a1[y, x]
            u = w0[y, x]
            v = w1[y, x]
            c, ok = _lcn_term(p + q, _weighted_square(p, u, floor) + _weighted_square(q, v, floor), u + v, seen[y, x], floor)
            cost[y, x] = c
            own[y, x] = np.float32(1.0) if ok else np.float32(0.0)
    return _count_own(own)


@njit(**_JIT)
def fold_half(box_cost, box_own, own, full, penalty, min_support, least):
    """``least = min(least, penalty * box_cost / box_own)`` at the pixels ``own`` whose window is
    ``own`` over at least ``min_support`` of its pixels, in place; with ``full`` (every pixel
    ``own``: each window's mean is its box) ``box_own`` is not read."""
    h, w = least.shape
    penalty = np.float32(penalty)
    min_support = np.float32(min_support)
    for y in range(h):
        for x in range(w):
            a = least[y, x]
            if full:
                c = penalty * box_cost[y, x]
                least[y, x] = c if c < a else a
            else:
                b = box_own[y, x]
                ok = (own[y, x] > 0) & (b >= min_support)
                c = penalty * box_cost[y, x] / (b if ok else np.float32(1.0))
                least[y, x] = c if ok & (c < a) else a


@njit(parallel=True, **_JIT)
def volume_minima(volume, halves, best, half_best):
    """Per pixel, the least cost over the hypotheses of ``volume`` and of ``halves`` (N, h, w)."""
    n, h, w = volume.shape
    for y in prange(h):
        for x in range(w):
            best[y, x] = volume[0, y, x]
            half_best[y, x] = halves[0, y, x]
        for d in range(1, n):
            for x in range(w):
                best[y, x] = min(best[y, x], volume[d, y, x])
                half_best[y, x] = min(half_best[y, x], halves[d, y, x])


@njit(parallel=True, **_JIT)
def take_where(volume, halves, take):
    """``volume = min(volume, halves)`` at the pixels ``take``, in place."""
    n, h, w = volume.shape
    for y in prange(h):
        for d in range(n):
            for x in range(w):
                if take[y, x]:
                    volume[d, y, x] = min(volume[d, y, x], halves[d, y, x])
