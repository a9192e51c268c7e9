"""The compiled per-pixel passes of the depth-aware renderer (:mod:`lfring.focus.depth_aware`):
numba, cached on disk, imported on first use.

A render makes three passes over the pixels: :func:`rungs` (every pixel's blur radius and its
place between two rungs of the ladder, and every rung's bounding box), :func:`scatter` (every
pixel's premultiplied colour and coverage shared between its two rungs, each rung on its own
grid) and :func:`finish` (the composite divided by its coverage, the background filling what
the surfaces leave uncovered); between them, OpenCV blurs every rung's layer and :func:`over`
and :func:`merge` composite the layers. Rows run in parallel stripes; a stripe's height is a
multiple of every rung's grid factor, so no two stripes write the same cell. Colour and
coverage are interleaved (C + 1 values per pixel), one cache line for all of a pixel.

The renderer's all-in-focus colour, made once per depth map, has its own: :func:`shift_maps`
and :func:`knot_maps` (where each view sees every pixel at its depth, for calibrations whose
views move by translations and for the others),
:func:`splat_max` (the depth map seen from each view), :func:`occluded` (which views a nearer
surface hides a pixel from), :func:`add_seen` (the background's samples) and
:func:`robust_mean` (the views' robust mean: one pass over the pixels, not a dozen whole-frame
arrays).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

__all__ = ["add_seen", "finish", "knot_maps", "merge", "occluded", "over", "robust_mean", "rungs", "scatter",
           "shift_maps", "splat_max"]

_JIT = dict(cache=True, nogil=True, fastmath=False, error_model="numpy")


@njit(parallel=True, **_JIT)
def rungs(x, agree, cover, sharp, window, x_f, motion, aperture, sharp_px, ramp_px, share_px2, moments, stripe,
          q, s, boxes):
    """Per pixel of inverse depth ``x`` (h, w), where ``cover`` > 0: ``s`` the share of the
    shift-and-add image ``sharp`` (h, w, C; 0 where it is empty, or 0 in every channel: there
    no view covered it) and ``q`` the signed fractional rung of its
    blur radius (between the rungs whose blurs' second ``moments`` enclose its disc's, linear in
    that moment; negative behind the focus); ``boxes`` (stripes, 2 n + 1, 4)
    receives per stripe and signed rung (index + n) the least and largest row and column of its
    pixels (rows, then columns; unset boxes keep their values). Only the pixels of ``window``
    (row0, row1, col0, col1) are visited (``q`` and ``s`` are left as they are elsewhere).

    ``motion`` is R (px of view motion per unit x at aperture 1); the radius is ``aperture *
    motion * (x - x_f)``, less the share ``s`` that shift-and-add's copies already spread
    (their second moment ``d^2`` plus ``share_px2``, d the view motion)."""
    r0, r1, c0, c1 = window[0], window[1], window[2], window[3]
    n = moments.shape[0] - 1
    with_sharp = sharp.shape[0] == x.shape[0]
    n_stripes = (r1 + stripe - 1) // stripe
    for b in prange(r0 // stripe, n_stripes):
        for y in range(max(r0, b * stripe), min(r1, (b + 1) * stripe)):
            # Neighbours mostly share their rungs: the search for a pixel's rung starts from the
            # last pixel's, and a row's run of pixels between the same rungs enters the boxes once.
            i = 1
            run_k = -1
            run_k2 = -1
            run_x0 = 0
            run_x1 = 0
            for xx in range(c0, c1):
                if cover[y, xx] <= 0.0:
                    q[y, xx] = 0.0
                    s[y, xx] = 0.0
                    continue
                d = motion * (x[y, xx] - x_f)
                rho = aperture * d
                share = 0.0
                if with_sharp:
                    for ch in range(sharp.shape[2]):
                        if sharp[y, xx, ch] != 0.0:
                            share = min(max((sharp_px + ramp_px - abs(d)) / ramp_px, 0.0), 1.0) * agree[y, xx]
                            break
                m = max(0.5 * rho * rho - share * (d * d + share_px2), 0.0)
                # The fractional index of m in the increasing moments (np.interp's): the first i
                # with m <= moments[i]; the top rung past the last (or for a NaN).
                frac = float(n)
                if n > 0 and m <= moments[n]:
                    while i > 1 and m <= moments[i - 1]:
                        i -= 1
                    while m > moments[i]:
                        i += 1
                    frac = (i - 1) + (m - moments[i - 1]) / (moments[i] - moments[i - 1])
                sign = -1 if rho < 0.0 else 1
                q[y, xx] = sign * frac
                s[y, xx] = share
                lo = int(frac)
                k = n + sign * lo
                k2 = -1 if frac <= lo or lo >= n else n + sign * (lo + 1)  # -1: the pixel has one rung
                if k != run_k or k2 != run_k2:
                    _box_add(boxes, b, run_k, y, run_x0, run_x1)
                    _box_add(boxes, b, run_k2, y, run_x0, run_x1)
                    run_k, run_k2, run_x0 = k, k2, xx
                run_x1 = xx
            _box_add(boxes, b, run_k, y, run_x0, run_x1)
            _box_add(boxes, b, run_k2, y, run_x0, run_x1)


@njit(inline="always")
def _box_add(boxes, b, k, y, xa, xb):
    """Stripe ``b``'s box of rung ``k`` grown to hold row ``y``'s columns xa..xb (none: k < 0)."""
    if k < 0:
        return
    if boxes[b, k, 0] > y:
        boxes[b, k, 0] = y
    if boxes[b, k, 1] < y:
        boxes[b, k, 1] = y
    if boxes[b, k, 2] > xa:
        boxes[b, k, 2] = xa
    if boxes[b, k, 3] < xb:
        boxes[b, k, 3] = xb


@njit(parallel=True, **_JIT)
def scatter(colour, sharp, s, cover, q, window, n, shift, y0, x0, rows, cols, offset, stripe, buf):
    """Add every pixel's premultiplied colour ``colour + s (sharp - colour)`` times ``cover``, and
    ``cover``, to the two rungs around its fractional rung ``q`` (weights ``1 - t`` and ``t``),
    each rung ``k`` (signed rung + ``n``) on its grid reduced ``2 ** shift[k]`` times (area
    averaging) within its box (origin ``y0[k]``, ``x0[k]`` in full-resolution pixels, multiples
    of the factor; ``rows[k]`` x ``cols[k]`` cells of C + 1 values) at ``buf[offset[k]:]``;
    the pixels of ``window`` (row0, row1, col0, col1). ``sharp`` may be empty (no shift-and-add
    image).

    A full-resolution rung's cell takes one pixel at most, so its box is written whole, zeros
    where no pixel of the rung lies (its part of ``buf`` need not be cleared first); the reduced
    grids' cells sum several pixels, and their parts of ``buf`` must hold zeros."""
    h, _, c = colour.shape
    c1 = c + 1
    with_sharp = sharp.shape[0] == h
    r0, r1, col0, col1 = window[0], window[1], window[2], window[3]
    # The rows to visit: the window's and every full-resolution box's.
    lo_row, hi_row = r0, r1
    for k in range(2 * n + 1):
        if rows[k] > 0 and shift[k] == 0:
            lo_row = min(lo_row, y0[k])
            hi_row = max(hi_row, y0[k] + rows[k])
    # A cell's share of a pixel, 4 ** -f (exact: the same numbers as a division).
    area_inv = np.empty(64, np.float64)
    for f in range(64):
        area_inv[f] = 0.25 ** f
    n_stripes = (hi_row + stripe - 1) // stripe
    for b in prange(lo_row // stripe, n_stripes):
        v = np.empty(c1, np.float32)
        for y in range(max(lo_row, b * stripe), min(hi_row, (b + 1) * stripe)):
            # Every full-resolution box's row is cleared first, then each pixel writes its value
            # into the one or two boxes of its rungs (the row is in cache by then).
            for k in range(2 * n + 1):
                if rows[k] == 0 or shift[k] != 0 or not (y0[k] <= y < y0[k] + rows[k]):
                    continue
                base = offset[k] + (y - y0[k]) * cols[k] * c1
                for i in range(base, base + cols[k] * c1):
                    buf[i] = np.float32(0.0)
            if not r0 <= y < r1:
                continue
            for xx in range(col0, col1):
                cv = cover[y, xx]
                if cv <= 0.0:
                    continue
                sh = s[y, xx]
                for ch in range(c):
                    col = colour[y, xx, ch]
                    if with_sharp and sh > 0.0:
                        col += sh * (sharp[y, xx, ch] - col)
                    v[ch] = col * cv
                v[c] = cv
                sq = q[y, xx]
                frac = abs(sq)
                lo = int(frac)
                t = frac - lo
                sign = -1 if sq < 0.0 else 1
                for m in range(2):
                    if m == 1 and (t <= 0.0 or lo >= n):
                        break
                    k = n + sign * (lo + m)
                    f = shift[k]
                    scale = np.float32((t if m == 1 else 1.0 - t) * area_inv[f])
                    if f == 0:
                        cell = offset[k] + ((y - y0[k]) * cols[k] + xx - x0[k]) * c1
                        for ch in range(c1):
                            buf[cell + ch] = np.float32(0.0) + scale * v[ch]
                        continue
                    cy = (y >> f) - (y0[k] >> f)
                    cx = (xx >> f) - (x0[k] >> f)
                    base = offset[k] + (cy * cols[k] + cx) * c1
                    for ch in range(c1):
                        buf[base + ch] += scale * v[ch]


@njit(parallel=True, **_JIT)
def over(acc, oy, ox, layer, prev, py, px, trans, skip, first):
    """Composite ``layer`` (rows, cols, C + 1: premultiplied colour and coverage a), placed at
    (``oy``, ``ox``) of ``acc``, over it: ``acc = (1 - a) acc + layer + a prev``, where ``prev``
    (placed at ``py``, ``px``; zero outside it, or empty) is the layer of the rung just behind,
    which ``layer`` does not cover. ``trans`` (``acc``'s rows and columns, or empty) is
    multiplied by ``1 - a``; ``skip`` (or empty) is set to ``a`` (``first``) or multiplied by
    ``1 - a``."""
    rows, cols, c1 = layer.shape
    ph, pw = prev.shape[0], prev.shape[1]
    with_trans = trans.shape[0] > 0
    with_skip = skip.shape[0] > 0
    for i in prange(rows):
        y = oy + i
        for j in range(cols):
            x = ox + j
            a = layer[i, j, c1 - 1]
            keep = np.float32(1.0) - a
            for ch in range(c1):
                acc[y, x, ch] = acc[y, x, ch] * keep + layer[i, j, ch]
            pi, pj = y - py, x - px
            if 0 <= pi < ph and 0 <= pj < pw:
                for ch in range(c1):
                    acc[y, x, ch] += a * prev[pi, pj, ch]
            if with_trans:
                trans[y, x] *= keep
            if with_skip:
                if first:
                    skip[y, x] = a
                else:
                    skip[y, x] *= keep


@njit(parallel=True, **_JIT)
def merge(acc, oy, ox, group, trans, skip, prev, py, px):
    """A group of layers composited on their own (``group``: premultiplied, ``trans``: their
    transmission, ``skip``: the first one's coverage times the later ones' transmission, or
    empty), placed at (``oy``, ``ox``), over ``acc``: ``acc = trans acc + group + skip prev``
    (``prev`` as in :func:`over`); cells past ``acc``'s edge are left out."""
    h, w, c1 = acc.shape
    rows, cols = group.shape[0], group.shape[1]
    ph, pw = prev.shape[0], prev.shape[1]
    with_skip = skip.shape[0] > 0
    for i in prange(max(0, -oy), min(rows, h - oy)):
        y = oy + i
        for j in range(max(0, -ox), min(cols, w - ox)):
            x = ox + j
            t = trans[i, j]
            for ch in range(c1):
                acc[y, x, ch] = acc[y, x, ch] * t + group[i, j, ch]
            if with_skip:
                pi, pj = y - py, x - px
                if 0 <= pi < ph and 0 <= pj < pw:
                    sk = skip[i, j]
                    for ch in range(c1):
                        acc[y, x, ch] += sk * prev[pi, pj, ch]


@njit(parallel=True, **_JIT)
def finish(acc, back, by, bx, floor, out):
    """``out`` (h, w, C) = the composite ``acc`` (h, w, C + 1: premultiplied colour and
    coverage) with the background ``back`` (same layout, summed, placed at (``by``, ``bx``), or
    empty) filling the coverage it lacks, divided by the coverage; 0 where the coverage is at
    most ``floor``."""
    h, w, c1 = acc.shape
    c = c1 - 1
    bh, bw = back.shape[0], back.shape[1]
    for y in prange(h):
        for xx in range(w):
            alpha = acc[y, xx, c]
            den = alpha
            fill = np.float32(0.0)
            bi, bj = y - by, xx - bx
            with_back = 0 <= bi < bh and 0 <= bj < bw
            if with_back:
                fill = min(max(np.float32(1.0) - alpha, np.float32(0.0)), np.float32(1.0))
                den += fill * back[bi, bj, c]
            if den > floor:
                inv = np.float32(1.0) / den
                for ch in range(c):
                    num = acc[y, xx, ch]
                    if with_back:
                        num += fill * back[bi, bj, ch]
                    out[y, xx, ch] = num * inv
            else:
                for ch in range(c):
                    out[y, xx, ch] = 0.0


@njit(inline="always")
def _view_pixel(mx, my, vh, vw):
    """The view pixel (column, row) nearest the sampling position (``mx``, ``my``) in a view of
    ``vh`` x ``vw``, or (-1, -1) where it lies outside or is not finite."""
    if not (np.isfinite(mx) and np.isfinite(my)):
        return -1, -1
    u = int(np.rint(mx))
    v = int(np.rint(my))
    if 0 <= u < vw and 0 <= v < vh:
        return u, v
    return -1, -1


@njit(parallel=True, **_JIT)
def occluded(mx, my, x, nearest, tol, out):
    """``out`` (h, w) bool: whether the view pixel (``mx``, ``my``) (rounded) that a reference
    pixel of inverse depth ``x`` samples holds a surface nearer by more than ``tol`` (in x):
    ``nearest`` is the depth map splatted into the view; False outside the view."""
    h, w = out.shape
    vh, vw = nearest.shape
    for y in prange(h):
        for xx in range(w):
            u, v = _view_pixel(mx[y, xx], my[y, xx], vh, vw)
            out[y, xx] = u >= 0 and nearest[v, u] > x[y, xx] + tol


@njit(parallel=True, **_JIT)
def robust_mean(warped, weight, visible, agree_tol, spread_tol, floor, colour, agree, seen):
    """The views' robust mean at every pixel (the all-in-focus colour of
    :class:`lfring.focus.depth_aware.DepthOfField`), from the views sampled there ``warped`` (V,
    h, w, C; premultiplied by ``weight`` (V, h, w), how much of each view is valid there) and
    ``visible`` (V, h, w; no nearer surface hides the pixel from the view).

    Every statistic weighs a view by its weight, so that a view fading out at its disc's rim
    fades out of it. The centre is robust: each view's luminance (mean of the channels)
    weighted by the summed weight of the views within about ``agree_tol`` of it, to the fourth
    power, so three agreeing views outweigh a fourth; a view whose luminance is off the centre
    by more than ``tol = max(agree_tol, spread_tol * spread)`` (spread: the views' rms deviation
    about it) loses weight linearly, none left at twice that. Where no view is visible, those
    that are present (weight > ``floor``) count. Writes ``colour`` (h, w, C; 0 where not
    ``seen``), ``agree`` (h, w: 1 less the worst view's excess deviation over ``agree_tol``,
    every present view by its weight, occluded or not; 0 where none is present) and ``seen``
    (h, w: the views' weight in the mean exceeds ``floor``)."""
    v, h, w, c = warped.shape
    inv_c = 1.0 / c
    inv_tol = 1.0 / agree_tol
    for y in prange(h):
        lum = np.empty(v)
        wv = np.empty(v)
        support = np.empty(v)
        phi = np.empty(v)
        for xx in range(w):
            any_present = False
            any_visible = False
            for k in range(v):
                present = weight[k, y, xx] > floor
                any_present = any_present or present
                any_visible = any_visible or (present and visible[k, y, xx])
            for k in range(v):
                wk = weight[k, y, xx]
                present = wk > floor
                s = 0.0
                for ch in range(c):
                    s += warped[k, y, xx, ch]
                lum[k] = s * inv_c / wk if present else 0.0
                sees = present and (visible[k, y, xx] or not any_visible)
                wv[k] = wk if sees else 0.0
            # Each view's support: the weight of the views close to it (itself included), the
            # closeness of a pair computed once.
            for k in range(v):
                support[k] = wv[k]
            for k in range(v):
                if wv[k] <= 0.0:
                    continue
                for j in range(k + 1, v):
                    if wv[j] > 0.0:
                        dl = np.float32((lum[j] - lum[k]) * inv_tol)
                        close = np.exp(np.float32(-0.5) * dl * dl)  # float32: a closeness
                        support[k] += close * wv[j]
                        support[j] += close * wv[k]
            total = 0.0
            sum_wv = 0.0
            sum_wl = 0.0
            for k in range(v):
                acc = support[k] * support[k]
                support[k] = acc * acc * wv[k]
                total += support[k]
                sum_wv += wv[k]
                sum_wl += wv[k] * lum[k]
            if total > 0.0:
                med = 0.0
                for k in range(v):
                    med += support[k] * lum[k]
                med /= max(total, 1e-30)
            else:
                med = sum_wl / max(sum_wv, floor)
            var = 0.0
            for k in range(v):
                dev = lum[k] - med
                var += wv[k] * dev * dev
            tol = max(agree_tol, spread_tol * np.sqrt(var / max(sum_wv, floor)))
            worst = 1.0
            den = 0.0
            for k in range(v):
                dev = abs(lum[k] - med)
                phi[k] = min(max(2.0 - dev / tol, 0.0), 1.0) if wv[k] > 0.0 else 0.0
                wk = weight[k, y, xx]
                if wk > floor:
                    dis = min(max(dev / agree_tol - 1.0, 0.0), 1.0) * min(max(wk, 0.0), 1.0)
                    worst = min(worst, 1.0 - dis)
                den += phi[k] * wk
            agree[y, xx] = worst if any_present else 0.0
            seen[y, xx] = den > floor
            for ch in range(c):
                num = 0.0
                if den > floor:
                    for k in range(v):
                        num += phi[k] * warped[k, y, xx, ch]
                    num /= den
                colour[y, xx, ch] = num


@njit(parallel=True, **_JIT)
def splat_max(mx, my, x, out):
    """``out`` (V, view rows, cols; filled by the caller) = per view, the largest ``x`` (h, w)
    of the reference pixels whose view pixel (``mx``, ``my``: (V, h, w)), rounded, it is. The
    views in parallel, each one's pixels in order: they land on one another."""
    h, w = x.shape
    vh, vw = out.shape[1], out.shape[2]
    for k in prange(out.shape[0]):
        for y in range(h):
            for xx in range(w):
                u, v = _view_pixel(mx[k, y, xx], my[k, y, xx], vh, vw)
                if u >= 0 and x[y, xx] > out[k, v, u]:
                    out[k, v, u] = x[y, xx]


@njit(parallel=True, **_JIT)
def shift_maps(x, x0, shift, slope, map_x, map_y):
    """``map_x``, ``map_y`` (V, h, w): the view pixel that every reference pixel samples at its
    inverse depth ``x`` (h, w) where the views move by translations affine in x: view k's
    shift ``shift[k]`` (x, y) at ``x0`` and ``slope[k]`` per unit x beyond it (float32
    throughout, the column or row index plus the shift plus the slope times ``x - x0``)."""
    h, w = x.shape
    for y in prange(h):
        fy = np.float32(y)
        for k in range(shift.shape[0]):
            sx, sy = shift[k, 0], shift[k, 1]
            gx, gy = slope[k, 0], slope[k, 1]
            for xx in range(w):
                dx = x[y, xx] - x0
                map_x[k, y, xx] = np.float32(xx) + sx + dx * gx
                map_y[k, y, xx] = fy + sy + dx * gy


@njit(parallel=True, **_JIT)
def add_seen(val, weight, wanted, hidden, num, den):
    """``num += val`` (h, w, C) and ``den += weight`` (h, w) where ``wanted`` and not ``hidden``
    (a view's samples of the background that it sees)."""
    h, w, c = val.shape
    for y in prange(h):
        for xx in range(w):
            if wanted[y, xx] and not hidden[y, xx]:
                for ch in range(c):
                    num[y, xx, ch] += val[y, xx, ch]
                den[y, xx] += weight[y, xx]


@njit(parallel=True, **_JIT)
def knot_maps(x, knots, inv, map_x, map_y):
    """``map_x``, ``map_y`` (V, h, w): the view pixel that every reference pixel samples at its
    inverse depth ``x`` (h, w), linear in x between the increasing ``knots`` (K) where ``inv``
    (K, V, 3, 3) maps reference pixels into each view (a homography per knot and view)."""
    h, w = x.shape
    n_knots = knots.shape[0]
    v = inv.shape[1]
    for y in prange(h):
        for xx in range(w):
            xv = x[y, xx]
            # The segment, as np.searchsorted(knots, xv, side="right") - 1 clipped to 0..K-2.
            j = 0
            hi = n_knots - 1
            while hi - j > 1:
                mid = (j + hi) // 2
                if knots[mid] <= xv:
                    j = mid
                else:
                    hi = mid
            t = (xv - knots[j]) / (knots[j + 1] - knots[j])
            for k in range(v):
                a = inv[j, k]
                b = inv[j + 1, k]
                wa = a[2, 0] * xx + a[2, 1] * y + a[2, 2]
                wb = b[2, 0] * xx + b[2, 1] * y + b[2, 2]
                ax = (a[0, 0] * xx + a[0, 1] * y + a[0, 2]) / wa
                ay = (a[1, 0] * xx + a[1, 1] * y + a[1, 2]) / wa
                bx = (b[0, 0] * xx + b[0, 1] * y + b[0, 2]) / wb
                by = (b[1, 0] * xx + b[1, 1] * y + b[1, 2]) / wb
                map_x[k, y, xx] = ax + t * (bx - ax)
                map_y[k, y, xx] = ay + t * (by - ay)
