"""The compiled kernel of the seen-pixel box mean (:func:`lfring.depth.aggregation.box_mean_of_finite`):
numba, cached on disk, imported on first use."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from lfring.core.compiled import COMPILED as _JIT

__all__ = ["finite_box_mean", "reflect"]


@njit(inline="always")
def reflect(i, n):
    """Index i folded into [0, n) as OpenCV's BORDER_REFLECT_101 (gfedcb|abcdefgh|gfedcba)."""
    if n == 1:
        return 0
    while i < 0 or i >= n:
        i = -i if i < 0 else 2 * n - 2 - i
    return i


@njit(parallel=True, **_JIT)
def finite_box_mean(c, radius, floor, blocks, out):
    """``out`` = the mean of ``c`` over the finite pixels of each (2 radius + 1)^2 box (borders
    reflected as BORDER_REFLECT_101), ``box(c) / max(box(finite), floor)`` with both boxes
    normalised; inf where ``c`` is not finite. Sums in float64: running column sums, then each
    row's box from its prefix sums; ``blocks`` of rows in parallel. ``out`` must not be ``c``."""
    h, w = c.shape
    big = np.float32(np.inf)
    size = 2 * radius + 1
    norm = 1.0 / (size * size)
    floor = np.float64(floor)
    blocks = max(1, min(h, blocks))
    rows = (h + blocks - 1) // blocks
    for b in prange(blocks):
        y0 = b * rows
        y1 = min(h, y0 + rows)
        if y0 >= y1:
            continue
        col_v = np.zeros(w, np.float64)  # the column sums over the box's rows
        col_n = np.zeros(w, np.float64)
        pre_v = np.empty(w + size, np.float64)  # prefix sums along the reflected row
        pre_n = np.empty(w + size, np.float64)
        fold = np.empty(w + 2 * radius, np.int64)
        for j in range(w + 2 * radius):
            fold[j] = reflect(j - radius, w)
        for k in range(y0 - radius, y0 + radius + 1):
            r = reflect(k, h)
            for x in range(w):
                v = c[r, x]
                ok = abs(v) < big
                col_v[x] += v if ok else 0.0
                col_n[x] += 1.0 if ok else 0.0
        for y in range(y0, y1):
            if y > y0:
                r_in = reflect(y + radius, h)
                r_out = reflect(y - radius - 1, h)
                for x in range(w):
                    v = c[r_in, x]
                    u = c[r_out, x]
                    ok = abs(v) < big
                    gone = abs(u) < big
                    col_v[x] += (v if ok else 0.0) - (u if gone else 0.0)
                    col_n[x] += (1.0 if ok else 0.0) - (1.0 if gone else 0.0)
            sv = 0.0
            sn = 0.0
            pre_v[0] = 0.0
            pre_n[0] = 0.0
            for j in range(w + 2 * radius):
                sv += col_v[fold[j]]
                sn += col_n[fold[j]]
                pre_v[j + 1] = sv
                pre_n[j + 1] = sn
            for x in range(w):
                mean_n = (pre_n[x + size] - pre_n[x]) * norm
                mean_v = (pre_v[x + size] - pre_v[x]) * norm
                out[y, x] = np.float32(mean_v / (mean_n if mean_n > floor else floor)) if abs(c[y, x]) < big else big
