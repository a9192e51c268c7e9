"""The compiled kernels of :mod:`lfring.depth.sgm`: numba, cached on disk after the first compile.

Importing this module imports numba (the functions compile on their first call, then load from
numba's cache in later processes); :mod:`lfring.depth.sgm` imports it on first use only, so
importing lfring does neither. Each kernel is self-contained.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

# NumPy's error model (every division here is guarded): the paths' loops vectorise, with the same
# sums. The pieces the kernels share run inside their parallel loops: compiled alike, without
# parallel.
from lfring.core.compiled import COMPILED as _PIECE
from lfring.core.compiled import COMPILED_PARALLEL as _JIT

__all__ = ["fill_values", "horizontal", "lines", "select_index", "select_index_both"]


@njit(**_JIT)
def fill_values(cost, out):
    """Per pixel, the mean of its finite costs (0 where none is finite)."""
    n, h, w = cost.shape
    for y in prange(h):
        acc = np.zeros(w, np.float64)
        cnt = np.zeros(w, np.int64)
        for d in range(n):
            for x in range(w):
                v = cost[d, y, x]
                if np.isfinite(v):
                    acc[x] += v
                    cnt[x] += 1
        for x in range(w):
            out[y, x] = np.float32(acc[x] / cnt[x]) if cnt[x] > 0 else np.float32(0.0)


@njit(**_JIT)
def horizontal(cost, fill, guide, use_guide, p1, p2, edge_scale, out, do_lr, do_rl):
    """Left-right and right-left paths, one row per parallel task; adds them into ``out``."""
    n, h, w = cost.shape
    for y in prange(h):
        c = np.empty((w, n), np.float32)
        for d in range(n):
            for x in range(w):
                v = cost[d, y, x]
                c[x, d] = v if np.isfinite(v) else fill[y, x]
        s = np.zeros((w, n), np.float32)
        prev = np.empty(n, np.float32)
        cur = np.empty(n, np.float32)
        for pass_ in range(2):
            if (pass_ == 0 and not do_lr) or (pass_ == 1 and not do_rl):
                continue
            pmin = np.float32(0.0)
            for i in range(w):
                x = i if pass_ == 0 else w - 1 - i
                cmin = np.float32(np.inf)
                if i == 0:
                    for d in range(n):
                        cur[d] = c[x, d]
                        cmin = min(cmin, cur[d])
                else:
                    xp = x - 1 if pass_ == 0 else x + 1
                    p2e = p2
                    if use_guide:
                        p2e = max(p1, np.float32(p2 / (np.float32(1.0) + abs(guide[y, x] - guide[y, xp]) / edge_scale)))
                    jump = pmin + p2e
                    # The ends' missing neighbour is the hypothesis itself: min(a, a + p1) = a.
                    cur[0] = c[x, 0] + (min(prev[0], prev[min(1, n - 1)] + p1, jump) - pmin)
                    cmin = min(cmin, cur[0])
                    for d in range(1, n - 1):
                        cur[d] = c[x, d] + (min(prev[d], prev[d - 1] + p1, prev[d + 1] + p1, jump) - pmin)
                        cmin = min(cmin, cur[d])
                    if n > 1:
                        cur[n - 1] = c[x, n - 1] + (min(prev[n - 1], prev[n - 2] + p1, jump) - pmin)
                        cmin = min(cmin, cur[n - 1])
                for d in range(n):
                    s[x, d] += cur[d]
                pmin = cmin
                prev, cur = cur, prev
        for d in range(n):
            for x in range(w):
                out[d, y, x] += s[x, d]


@njit(**_JIT)
def lines(cost, fill, guide, use_guide, p1, p2, edge_scale, out, dy, dx, block):
    """One path with dy = +-1 (vertical or diagonal), one block of parallel lines per task.

    The lines of a path (columns, or diagonals x -+ y = const) are independent; a block of
    ``block`` neighbouring lines covers a contiguous run of columns on every row, so the task
    reads the cost row by row and keeps its lines' state in (N, block) buffers.
    """
    n, h, w = cost.shape
    big = np.float32(np.inf)
    s = dx * dy  # on a line, x = k + s * y
    if s == 0:
        kmin, kmax = 0, w - 1
    elif s == 1:
        kmin, kmax = -(h - 1), w - 1
    else:
        kmin, kmax = 0, w + h - 2
    nblocks = (kmax - kmin + block) // block
    for b in prange(nblocks):
        k0 = kmin + b * block
        nb = min(block, kmax + 1 - k0)
        # Zero state makes a line's first pixel take its cost alone (best = 0 = pmin below),
        # so the recursion needs no branch for it: a line's columns stay zero until it starts.
        prev = np.zeros((n, block), np.float32)
        cur = np.zeros((n, block), np.float32)
        pmin = np.zeros(block, np.float32)
        cmin = np.zeros(block, np.float32)
        jump = np.empty(block, np.float32)
        started = np.zeros(block, np.bool_)
        for i in range(h):
            y = i if dy > 0 else h - 1 - i
            xb = k0 + s * y
            j0 = max(0, -xb)
            j1 = min(nb, w - xb)
            if j0 >= j1:
                continue
            for j in range(j0, j1):
                x = xb + j
                cmin[j] = np.float32(np.inf)
                p2e = p2
                if use_guide and started[j]:
                    p2e = max(p1, np.float32(p2 / (np.float32(1.0) + abs(guide[y, x] - guide[y - dy, x - dx]) / edge_scale)))
                jump[j] = pmin[j] + p2e
            fill_row = fill[y, xb + j0:xb + j1]
            m = j1 - j0
            for d in range(n):
                # At the ends the missing neighbour is the hypothesis itself: min(a, a + p1) = a.
                dm = d - 1 if d > 0 else d
                dp = d + 1 if d < n - 1 else d
                # Row slices, and two loops of few arrays each: with every array in one loop,
                # LLVM's aliasing checks gave up and the loop ran scalar, markedly slower.
                cost_row = cost[d, y, xb + j0:xb + j1]
                here, below, above = prev[d, j0:j1], prev[dm, j0:j1], prev[dp, j0:j1]
                jumps, base, new = jump[j0:j1], pmin[j0:j1], cur[d, j0:j1]
                for j in range(m):  # selects, not branches: the loops vectorise
                    v = cost_row[j]
                    v = v if abs(v) < big else fill_row[j]  # NaN fails the test too
                    best = here[j]
                    t = below[j] + p1
                    best = t if t < best else best
                    t = above[j] + p1
                    best = t if t < best else best
                    t = jumps[j]
                    best = t if t < best else best
                    new[j] = v + (best - base[j])
                least, total = cmin[j0:j1], out[d, y, xb + j0:xb + j1]
                for j in range(m):
                    L = new[j]
                    c = least[j]
                    least[j] = L if L < c else c
                    total[j] += L
            for j in range(j0, j1):
                started[j] = True
            # A line inside the image on this row was inside on the previous one (lines are
            # contiguous), so swapping whole buffers never hands a line stale state.
            prev, cur = cur, prev
            pmin, cmin = cmin, pmin


@njit(**_PIECE)
def _row_minima(vol, y, exclude, best, arg, second):
    """Row y of a volume: per pixel the least cost, its (first) hypothesis, and the least cost
    more than ``exclude`` hypotheses from it."""
    n, h, w = vol.shape
    best[:] = np.inf
    arg[:] = 0
    second[:] = np.inf
    for d in range(n):
        for x in range(w):
            v = vol[d, y, x]
            if v < best[x]:
                best[x] = v
                arg[x] = d
    for d in range(n):
        for x in range(w):
            if abs(d - arg[x]) > exclude:
                second[x] = min(second[x], vol[d, y, x])


@njit(**_PIECE)
def _parabola(cm, c0, cp):
    """Sub-hypothesis offset in [-0.5, 0.5] of the parabola through three costs (0 unless it
    curves up)."""
    den = np.float64(cm) - 2.0 * np.float64(c0) + np.float64(cp)
    if den > 0.0:
        return min(0.5, max(-0.5, 0.5 * (np.float64(cm) - np.float64(cp)) / den))
    return 0.0


@njit(**_PIECE)
def _end_offset(vol, k, y, x):
    """Sub-hypothesis offset, at most 0.5 inwards, of a winner ``k`` at the first or last
    hypothesis of ``vol``: the vertex of the parabola through the end's cost and the next two
    inwards, clamped (0 unless it curves up or a cost is not finite); ``vol`` holds three
    hypotheses or more. A surface within half a step inside the range's end otherwise comes out
    at the end."""
    inward = 1 if k == 0 else -1
    c_end = np.float64(vol[k, y, x])
    c_after = np.float64(vol[k + 2 * inward, y, x])
    den = c_end - 2.0 * np.float64(vol[k + inward, y, x]) + c_after
    if den > 0.0 and np.isfinite(den):
        return inward * min(0.5, max(0.0, 1.0 + 0.5 * (c_end - c_after) / den))
    return 0.0


@njit(**_PIECE)
def _distinctness(b, s):
    """1 - best / second in [0, 1] (float32), 0 where either is not finite or second <= 0."""
    if np.isfinite(b) and np.isfinite(s) and s > 0.0:
        return np.float32(min(1.0, max(0.0, 1.0 - np.float64(b) / np.float64(s))))
    return np.float32(0.0)


@njit(**_JIT)
def select_index(agg, raw, fill, use_raw, exclude, index, conf):
    """Winner-take-all, parabola sub-hypothesis offset, distinctness 1 - best / second."""
    n, h, w = agg.shape
    for y in prange(h):
        best = np.empty(w, np.float32)
        arg = np.empty(w, np.int64)
        second = np.empty(w, np.float32)
        _row_minima(agg, y, exclude, best, arg, second)
        for x in range(w):
            k = arg[x]
            b = best[x]
            if not np.isfinite(b):
                index[y, x] = np.nan
                conf[y, x] = 0.0
                continue
            off = 0.0
            if 0 < k < n - 1:
                if use_raw:
                    cm = raw[k - 1, y, x]
                    c0 = raw[k, y, x]
                    cp = raw[k + 1, y, x]
                    cm = cm if np.isfinite(cm) else fill[y, x]
                    c0 = c0 if np.isfinite(c0) else fill[y, x]
                    cp = cp if np.isfinite(cp) else fill[y, x]
                else:
                    cm = agg[k - 1, y, x]
                    c0 = b
                    cp = agg[k + 1, y, x]
                off = _parabola(cm, c0, cp)
            elif n >= 3:
                off = _end_offset(raw if use_raw else agg, k, y, x)
            index[y, x] = np.float32(k + off)
            conf[y, x] = _distinctness(b, second[x])


@njit(**_JIT)
def select_index_both(agg, raw, exclude, index, conf):
    """:func:`select_index` of ``agg`` with the parabola on ``raw``, its confidence times the
    distinctness of ``raw``'s own curve (as :func:`select_index` of ``raw`` alone), in one task
    per row; a non-finite ``raw`` cost at the parabola's points takes the pixel's mean finite raw
    cost (as :func:`fill_values`), computed only there."""
    n, h, w = agg.shape
    for y in prange(h):
        best = np.empty(w, np.float32)
        arg = np.empty(w, np.int64)
        second = np.empty(w, np.float32)
        rbest = np.empty(w, np.float32)
        rarg = np.empty(w, np.int64)
        rsecond = np.empty(w, np.float32)
        _row_minima(agg, y, exclude, best, arg, second)
        _row_minima(raw, y, exclude, rbest, rarg, rsecond)
        for x in range(w):
            k = arg[x]
            b = best[x]
            if not np.isfinite(b):
                index[y, x] = np.nan
                conf[y, x] = 0.0
                continue
            off = 0.0
            if 0 < k < n - 1:
                cm = raw[k - 1, y, x]
                c0 = raw[k, y, x]
                cp = raw[k + 1, y, x]
                if not (np.isfinite(cm) and np.isfinite(c0) and np.isfinite(cp)):
                    acc = 0.0
                    cnt = 0
                    for d in range(n):
                        r = raw[d, y, x]
                        if np.isfinite(r):
                            acc += r
                            cnt += 1
                    f = np.float32(acc / cnt) if cnt > 0 else np.float32(0.0)
                    cm = cm if np.isfinite(cm) else f
                    c0 = c0 if np.isfinite(c0) else f
                    cp = cp if np.isfinite(cp) else f
                off = _parabola(cm, c0, cp)
            elif n >= 3:
                off = _end_offset(raw, k, y, x)
            index[y, x] = np.float32(k + off)
            conf[y, x] = _distinctness(b, second[x]) * _distinctness(rbest[x], rsecond[x])
