"""The compiled per-pixel passes of the depth-aware renderer (:mod:`lfring.focus.depth_aware`):
numba, cached on disk, imported on first use.

A render makes three passes over the pixels: :func:`rungs` (every pixel's blur radius and its
place between two rungs of the ladder, and every rung's bounding box), :func:`scatter` (every
pixel's premultiplied colour and coverage shared between its two rungs, each rung on its own
grid) and :func:`finish` (the composite divided by its coverage, the background filling what
the surfaces leave uncovered); between them, :func:`disc_blur` blurs every rung's layer and
:func:`over` and :func:`merge` composite the layers. Rows run in parallel stripes; a stripe's height is a
multiple of every rung's grid factor, so no two stripes write the same cell. Colour and
coverage are interleaved (C + 1 values per pixel), one cache line for all of a pixel.

The per-cell loops run over flat rows, and each is an inlined helper called with the cell's size
given as 4 (RGB and coverage), which compiles a copy whose loops are unrolled and vectorise, and
again with the size of the call for any other channel count. Indexed as (row, column,
value), or with a size known only at run time, the same loops compile to scalar code; so do
loops whose index is a signed product or sum such as ``c1 * j + ch`` (numba checks a signed
index for a negative value): those indices are unsigned.

The renderer's all-in-focus colour, made once per depth map, has its own: :func:`shift_maps`
and :func:`knot_maps` (where each view sees every pixel at its depth, for calibrations whose
views move by translations and for the others; ``*_at`` for a list of pixels),
:func:`splat_max` (the depth map seen from each view), :func:`occluded` (which views a nearer
surface hides a pixel from), :func:`add_seen` (the background's samples) and
:func:`robust_mean` (the views' robust mean: row by row, not a dozen whole-frame arrays).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from lfring.core.compiled import COMPILED as _JIT

__all__ = ["BLUR_TASK_ROWS", "add_seen", "clamp_cells", "disc_blur", "finish", "knot_maps", "knot_maps_at", "merge", "occluded", "over",
           "robust_mean", "rungs", "scatter", "shift_maps", "shift_maps_at", "splat_max"]


@njit(inline="always")
def _moment_row(xr, ar, cr, sr, n_px, c, x_f, motion, aperture, sharp_px, ramp_px, share_px2, with_sharp, m_out, s_out):
    """Per pixel of a row of :func:`rungs` (inverse depth ``xr``, agreement ``ar``, cover ``cr``,
    ``sr`` the shift-and-add image's ``c`` values a pixel, flat): ``m_out`` the second moment
    its rungs' blurs make up, -1 where it is not covered; ``s_out`` the share of shift-and-add."""
    for j in range(n_px):
        d = motion * (xr[j] - x_f)
        rho = aperture * d
        share = 0.0
        if with_sharp:
            filled = False
            for ch in range(c):
                filled = filled | (sr[c * j + ch] != 0.0)
            share = min(max((sharp_px + ramp_px - abs(d)) / ramp_px, 0.0), 1.0) * ar[j] if filled else 0.0
        m = max(0.5 * rho * rho - share * (d * d + share_px2), 0.0)
        covered = cr[j] > 0.0
        m_out[j] = m if covered else -1.0
        s_out[j] = share if covered else 0.0


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
    (their second moment ``d^2`` plus ``share_px2``, d the view motion).

    A row's moments are computed first, in a loop that vectorises (RGB's compiled for exactly 3
    channels, as :func:`over`), then their rungs."""
    r0, r1, c0, c1 = window[0], window[1], window[2], window[3]
    moments32 = moments.astype(np.float32)
    n = moments.shape[0] - 1
    top = moments32[n]
    nn = np.int32(n)
    nf = np.float32(n)
    span = np.int32(2 * n + 2)  # a pixel's key: its rung times span, plus its second rung + 1
    w = x.shape[1]
    with_sharp = sharp.shape[0] == x.shape[0]
    c = sharp.shape[2]
    flat = sharp.reshape(sharp.size)
    n_stripes = (r1 + stripe - 1) // stripe
    for b in prange(r0 // stripe, n_stripes):
        m_row = np.empty(c1 - c0, np.float32)
        lo_m = np.empty(c1 - c0, np.float32)
        hi_m = np.empty(c1 - c0, np.float32)
        i_row = np.empty(c1 - c0, np.int32)
        key = np.empty(c1 - c0, np.int32)
        for y in range(max(r0, b * stripe), min(r1, (b + 1) * stripe)):
            sr = flat[(y * w + c0) * c:(y * w + c1) * c] if with_sharp else flat[0:0]
            xr, ar, cr, s_row = x[y, c0:c1], agree[y, c0:c1], cover[y, c0:c1], s[y, c0:c1]
            # Whether there is a shift-and-add image given as a literal too: a flag known only at
            # run time inside the loop keeps it from vectorising.
            if not with_sharp:
                _moment_row(xr, ar, cr, sr, c1 - c0, 0, x_f, motion, aperture, sharp_px, ramp_px, share_px2,
                            False, m_row, s_row)
            elif c == 3:
                _moment_row(xr, ar, cr, sr, c1 - c0, 3, x_f, motion, aperture, sharp_px, ramp_px, share_px2,
                            True, m_row, s_row)
            else:
                _moment_row(xr, ar, cr, sr, c1 - c0, c, x_f, motion, aperture, sharp_px, ramp_px, share_px2,
                            True, m_row, s_row)
            # The fractional index of m in the increasing moments (np.interp's): i - 1 and m's place
            # between moments[i - 1] and moments[i], i the first index from 1 with m <= moments[i]
            # (1 and the number of moments below m from index 1), found in passes over the row
            # per rung (which vectorise); the top rung past the last (or for a NaN).
            nj = c1 - c0
            for j in range(nj):
                i_row[j] = 1
                lo_m[j] = moments32[0]
                hi_m[j] = moments32[n]
            for rung in range(1, n):
                mr = moments32[rung]
                for j in range(nj):
                    below = mr < m_row[j]
                    i_row[j] += 1 if below else 0
                    lo_m[j] = mr if below else lo_m[j]
                    hi_m[j] = min(hi_m[j], mr) if mr >= m_row[j] else hi_m[j]
            # Each pixel's rungs in two passes that vectorise: its fractional rung (kept in
            # lo_m), then its rungs packed in one key, -1 where it is not covered.
            q_row = q[y, c0:c1]
            for j in range(nj):
                m = m_row[j]
                inside = (n > 0) & (m <= top)
                frac = np.float32(i_row[j] - 1) + (m - lo_m[j]) / (hi_m[j] - lo_m[j]) if inside else nf
                neg = aperture * (motion * (xr[j] - x_f)) < np.float32(0.0)
                covered = not m < np.float32(0.0)  # a NaN moment is covered (the top rung)
                q_row[j] = (-frac if neg else frac) if covered else np.float32(0.0)
                lo_m[j] = frac
            for j in range(nj):
                frac = lo_m[j]
                lo = np.int32(frac)
                step = np.int32(-1) if q_row[j] < np.float32(0.0) else np.int32(1)
                k = nn + step * lo
                k2 = np.int32(-1) if (frac <= np.float32(lo)) | (lo >= nn) else k + step  # -1: one rung
                key[j] = k * span + k2 + np.int32(1) if not m_row[j] < np.float32(0.0) else np.int32(-1)
            # Neighbours mostly share their rungs: a row's run of pixels between the same rungs
            # enters the boxes once (the pixels not covered make runs of their own, which enter
            # none: a rung's box is the same whether or not its runs are cut by them).
            run = np.int32(-1)
            run_x0 = 0
            for j in range(nj + 1):
                if j < nj and key[j] == run:
                    continue
                if run >= 0:
                    _box_add(boxes, b, run // span, y, c0 + run_x0, c0 + j - 1)
                    _box_add(boxes, b, run % span - 1, y, c0 + run_x0, c0 + j - 1)
                if j < nj:
                    run, run_x0 = key[j], j


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


@njit(inline="always")
def _row_values(colour, sharp, s, cover, q, y, col0, col1, n, c, vr, ka, kb, wa, wb):
    """Row ``y``'s pixels col0 .. col1 - 1 of :func:`scatter`, the i-th pixel of the row at i:
    ``vr`` (flat, c + 1 values a pixel) its premultiplied colour and coverage, zeros where it is
    not covered; ``ka``, ``kb`` the rung below its fractional rung and the one above where it
    lies between them (-1: none, or not covered); ``wa``, ``wb`` their shares 1 - t and t.
    Returns whether every value is finite. Loops without branches or signed indices (each
    selects instead), which vectorise."""
    c1 = c + 1
    m = col1 - col0
    zero = np.float32(0.0)
    one = np.float32(1.0)
    cr = cover[y, col0:col1]
    colr = colour[y, col0:col1].reshape(m * c)
    if sharp.shape[0] == colour.shape[0]:
        sr = s[y, col0:col1]
        shr = sharp[y, col0:col1].reshape(m * c)
        for j in range(m):
            cv = cr[j]
            sh = sr[j]
            covered = cv > zero
            mix = sh > zero
            for ch in range(c):
                col = colr[np.uintp(j * c + ch)]
                mixed = col + sh * (shr[np.uintp(j * c + ch)] - col)
                vr[np.uintp(j * c1 + ch)] = (mixed if mix else col) * cv if covered else zero
            vr[np.uintp(j * c1 + c)] = cv if covered else zero
    else:
        for j in range(m):
            cv = cr[j]
            covered = cv > zero
            for ch in range(c):
                vr[np.uintp(j * c1 + ch)] = colr[np.uintp(j * c + ch)] * cv if covered else zero
            vr[np.uintp(j * c1 + c)] = cv if covered else zero
    qr = q[y, col0:col1]
    nn = np.int32(n)
    for j in range(m):
        sq = qr[j]
        neg = sq < zero
        frac = abs(sq)
        lo = np.int32(frac)
        t = frac - np.float32(lo)  # exact
        second = (t > zero) & (lo < nn)
        k = nn + (-lo if neg else lo)
        covered = cr[j] > zero
        ka[j] = k if covered else np.int32(-1)
        kb[j] = k + (np.int32(-1) if neg else np.int32(1)) if covered & second else np.int32(-1)
        wa[j] = one - t
        wb[j] = t if second else zero
    # Whether any value is infinite or NaN: all of its exponent's bits set (integer operations,
    # which vectorise).
    bits = vr[:m * c1].view(np.uint32)
    exponent = np.uint32(0x7F800000)
    bad = np.uint32(0)
    for i in range(m * c1):
        bad |= np.uint32((bits[i] & exponent) == exponent)
    return bad == 0


@njit(inline="always")
def _full_row(buf, base, k, xa, xb, col0, vr, ka, kb, wa, wb, c1, finite):
    """The cells of columns xa .. xb - 1 of full-resolution rung ``k``'s row at ``buf[base:]``:
    each pixel's values times its share of the rung, 0 where the rung is not one of its two.
    Where every value is ``finite`` that 0 is a product with a share of 0; otherwise it is
    selected, so that an infinite or NaN value stays out of the other rungs."""
    zero = np.float32(0.0)
    if finite:
        for x in range(xa, xb):
            j = np.uintp(x - col0)
            w = wa[j] if ka[j] == k else (wb[j] if kb[j] == k else zero)
            for ch in range(c1):
                buf[np.uintp(base + (x - xa) * c1 + ch)] = zero + w * vr[np.uintp(j * c1 + ch)]
        return
    for x in range(xa, xb):
        j = np.uintp(x - col0)
        mine = (ka[j] == k) | (kb[j] == k)
        w = wa[j] if ka[j] == k else wb[j]
        for ch in range(c1):
            buf[np.uintp(base + (x - xa) * c1 + ch)] = zero + w * vr[np.uintp(j * c1 + ch)] if mine else zero


@njit(inline="always")
def _whole_cells(buf, rb, cx0, cx1, npx, col0, share, vr, c1):
    """Cells cx0 .. cx1 - 1 of a reduced row at ``buf[rb:]`` (of :func:`scatter`), each of
    ``npx`` pixels of the row's values, all finite: each pixel's share times its values added
    in order, as :func:`_cells` adds them."""
    for cx in range(cx0, cx1):
        cell = np.uintp(rb + cx * c1)
        j0 = np.uintp(cx * npx - col0)
        for ch in range(c1):
            acc = buf[cell + np.uintp(ch)]
            for i in range(npx):
                j = j0 + np.uintp(i)
                acc += share[j] * vr[j * np.uintp(c1) + np.uintp(ch)]
            buf[cell + np.uintp(ch)] = acc


@njit(inline="always")
def _cells(buf, rb, cx0, cx1, f, xa, xb, col0, share, vr, c1, finite):
    """Cells cx0 .. cx1 - 1 of a reduced row (grid factor ``2 ** f``) at ``buf[rb:]``: each adds
    its pixels within xa .. xb, pixel by pixel (where not every value is ``finite``, only the
    pixels with a share)."""
    for cx in range(cx0, cx1):
        cell = rb + cx * c1  # unsigned below: see disc_blur
        pa = max(xa, cx << f)
        pb = min(xb, (cx + 1) << f)
        for ch in range(c1):
            acc = buf[np.uintp(cell + ch)]
            if finite:
                for x in range(pa, pb):
                    j = np.uintp(x - col0)
                    acc += share[j] * vr[np.uintp(j * c1 + ch)]
            else:
                for x in range(pa, pb):
                    j = np.uintp(x - col0)
                    if share[j] > np.float32(0.0):
                        acc += share[j] * vr[np.uintp(j * c1 + ch)]
            buf[np.uintp(cell + ch)] = acc


@njit(parallel=True, **_JIT)
def scatter(colour, sharp, s, cover, q, window, n, shift, y0, x0, rows, cols, offset, stripe, buf):
    """Add every pixel's premultiplied colour ``colour + s (sharp - colour)`` times ``cover``, and
    ``cover``, to the two rungs around its fractional rung ``q`` (weights ``1 - t`` and ``t``),
    each rung ``k`` (signed rung + ``n``) on its grid reduced ``2 ** shift[k]`` times (area
    averaging) within its box (origin ``y0[k]``, ``x0[k]`` in full-resolution pixels, multiples
    of the factor; ``rows[k]`` x ``cols[k]`` cells of C + 1 values) at ``buf[offset[k]:]``;
    the pixels of ``window`` (row0, row1, col0, col1). ``sharp`` may be empty (no shift-and-add
    image).

    A full-resolution rung's cell takes one pixel at most, so its box is written whole, once,
    zeros where no pixel of the rung lies (its part of ``buf`` need not be cleared first): per
    row, the rung's cells are one pass over the row's values, which vectorises. The reduced
    grids' cells sum several pixels, and their parts of ``buf`` must hold zeros; each cell adds
    its pixels in order, row by row. A pixel enters no rung but its two, whatever its values
    (an infinite or NaN one too). The rows' values and the full-resolution rows run loops
    compiled for exactly 4 values for RGB (C + 1 = 4 values a cell), as :func:`over`."""
    c = colour.shape[2]
    c1 = c + 1
    r0, r1, col0, col1 = window[0], window[1], window[2], window[3]
    nk = 2 * n + 1
    # The rows to visit: the window's and every full-resolution box's.
    lo_row, hi_row = r0, r1
    reduced = False
    for k in range(nk):
        if rows[k] > 0 and shift[k] == 0:
            lo_row = min(lo_row, y0[k])
            hi_row = max(hi_row, y0[k] + rows[k])
        reduced = reduced or (rows[k] > 0 and shift[k] > 0)
    m = max(col1 - col0, 0)
    n_stripes = (hi_row + stripe - 1) // stripe
    for b in prange(lo_row // stripe, n_stripes):
        vr = np.zeros(m * c1, np.float32)
        ka = np.full(m, -1, np.int32)
        kb = np.full(m, -1, np.int32)
        wa = np.zeros(m, np.float32)
        wb = np.zeros(m, np.float32)
        share = np.zeros(m, np.float32)
        for y in range(max(lo_row, b * stripe), min(hi_row, (b + 1) * stripe)):
            inside = r0 <= y < r1
            finite = True
            if inside:
                if c1 == 4:
                    finite = _row_values(colour, sharp, s, cover, q, y, col0, col1, n, 3, vr, ka, kb, wa, wb)
                else:
                    finite = _row_values(colour, sharp, s, cover, q, y, col0, col1, n, c, vr, ka, kb, wa, wb)
            for k in range(nk):
                if rows[k] == 0 or shift[k] != 0 or not y0[k] <= y < y0[k] + rows[k]:
                    continue
                base = offset[k] + (y - y0[k]) * cols[k] * c1
                xa, xb = x0[k], x0[k] + cols[k]
                # The window's columns take its pixels; the rest of the box's row is zeros.
                ia = min(max(xa, col0), xb) if inside else xb
                ib = max(min(xb, col1), ia) if inside else xb
                if ia > xa:
                    buf[base:base + (ia - xa) * c1] = np.float32(0.0)
                if c1 == 4:
                    _full_row(buf, base + (ia - xa) * c1, k, ia, ib, col0, vr, ka, kb, wa, wb, 4, finite)
                else:
                    _full_row(buf, base + (ia - xa) * c1, k, ia, ib, col0, vr, ka, kb, wa, wb, c1, finite)
                if xb > ib:
                    buf[base + (ib - xa) * c1:base + cols[k] * c1] = np.float32(0.0)
            if not (reduced and inside):
                continue
            for k in range(nk):
                f = shift[k]
                if rows[k] == 0 or f == 0 or y < y0[k] or (y >> f) - (y0[k] >> f) >= rows[k]:
                    continue
                rb = offset[k] + (((y >> f) - (y0[k] >> f)) * cols[k] - (x0[k] >> f)) * c1
                area = np.float32(0.25 ** f)  # a cell's share of a pixel (exact)
                xa = max(col0, x0[k])
                xb = min(col1, x0[k] + (cols[k] << f))
                if xb <= xa:
                    continue
                # Each pixel's share of the rung, 0 where the rung is not one of its two (every
                # share of a pixel of the rung is above 0): such a pixel adds a product with 0
                # where every value is finite, and nothing otherwise.
                for x in range(xa, xb):
                    j = np.uintp(x - col0)
                    share[j] = wa[j] * area if ka[j] == k else (wb[j] * area if kb[j] == k else np.float32(0.0))
                # Cells wholly inside xa..xb of finite values add their 2 or 4 pixels in loops
                # compiled for that count (and RGB's 4 values), which unroll; the others, and
                # cells of wider grids, pixel by pixel.
                ca, cb = xa >> f, ((xb - 1) >> f) + 1
                whole_a, whole_b = cb, cb  # the whole cells: whole_a .. whole_b - 1
                if finite and c1 == 4 and f <= 2:
                    whole_a = min((xa + (1 << f) - 1) >> f, cb)  # xa rounded up to a cell: never below ca
                    whole_b = max(xb >> f, whole_a)
                    if f == 1:
                        _whole_cells(buf, rb, whole_a, whole_b, 2, col0, share, vr, 4)
                    else:
                        _whole_cells(buf, rb, whole_a, whole_b, 4, col0, share, vr, 4)
                for e0, e1 in ((ca, whole_a), (whole_b, cb)):
                    _cells(buf, rb, e0, e1, f, xa, xb, col0, share, vr, c1, finite)


@njit(inline="always")
def _keep_add(ar, wr, ws, wo, complement, gr, n, c1):
    """``ar = k ar + gr`` over ``n`` cells of ``c1`` values (flat rows), each cell's ``k`` =
    ``wr[ws j + wo]`` (one minus it where ``complement``): a layer's own coverage (``over``) or
    a group's transmission (``merge``)."""
    for j in range(n):
        w = wr[np.uintp(ws * j + wo)]
        keep = np.float32(1.0) - w if complement else w
        for ch in range(c1):
            e = np.uintp(c1 * j + ch)
            ar[e] = ar[e] * keep + gr[e]


@njit(inline="always")
def _add_scaled(ar, wr, ws, wo, pr, n, c1):
    """``ar += w pr`` over ``n`` cells of ``c1`` values, each cell's ``w`` = ``wr[ws j + wo]``:
    the layer behind, under a layer's coverage (``over``) or a group's skip term (``merge``)."""
    for j in range(n):
        w = wr[np.uintp(ws * j + wo)]
        for ch in range(c1):
            e = np.uintp(c1 * j + ch)
            ar[e] += w * pr[e]


@njit(inline="always")
def _keep_add_behind(ar, lr, pr, n, c1):
    """:func:`_keep_add` with the layer's own coverage, then :func:`_add_scaled` of ``pr`` under
    it, in one pass over ``n`` cells (the same sums in the same order)."""
    for j in range(n):
        a = lr[np.uintp(c1 * j + c1 - 1)]
        keep = np.float32(1.0) - a
        for ch in range(c1):
            e = np.uintp(c1 * j + ch)
            ar[e] = (ar[e] * keep + lr[e]) + a * pr[e]


@njit(inline="always")
def _overlap(y, x0, n, oy, ox, hh, ww):
    """The row ``y - oy`` of an array of ``hh`` x ``ww`` placed at (``oy``, ``ox``), and the span
    [ja, jb) of the cells x0 .. x0 + n - 1 that it covers (ja = jb where it covers none)."""
    i = y - oy
    if i < 0 or i >= hh:
        return i, 0, 0
    ja = min(n, max(0, ox - x0))
    return i, ja, max(ja, min(n, ox + ww - x0))


@njit(parallel=True, **_JIT)
def over(acc, oy, ox, layer, prev, py, px, trans, skip, first):
    """Composite ``layer`` (rows, cols, C + 1: premultiplied colour and coverage a), placed at
    (``oy``, ``ox``) of ``acc``, over it: ``acc = (1 - a) acc + layer + a prev``, where ``prev``
    (placed at ``py``, ``px``; zero outside it, or empty) is the layer of the rung just behind,
    which ``layer`` does not cover. ``trans`` (``acc``'s rows and columns, or empty) is
    multiplied by ``1 - a``; ``skip`` (or empty) is set to ``a`` (``first``) or multiplied by
    ``1 - a``. ``oy``, ``ox`` are at least 0; cells past ``acc``'s bottom or right edge are left
    out (a reduced grid's last cells may reach past the frame). Every array C-contiguous.

    The rows are flat runs of cells; colour and coverage (C + 1 = 4 values a cell) run loops
    compiled for exactly 4 values, which vectorise, other channel counts the same loops for any
    count."""
    rows, cols, c1 = layer.shape
    h, w = acc.shape[0], acc.shape[1]
    n = max(0, min(cols, w - ox))  # the cells of a row inside acc
    ph, pw = prev.shape[0], prev.shape[1]
    af = acc.reshape(acc.size)
    lf = layer.reshape(layer.size)
    pf = prev.reshape(prev.size)
    with_trans = trans.shape[0] > 0
    with_skip = skip.shape[0] > 0
    for i in prange(max(0, min(rows, h - oy))):
        y = oy + i
        a0 = (y * w + ox) * c1
        ar = af[a0:a0 + n * c1]
        lr = lf[i * cols * c1:(i * cols + n) * c1]
        pi, ja, jb = _overlap(y, ox, n, py, px, ph, pw)
        # The cells before the layer behind, over it (one pass for both terms), and after it.
        for s0, s1 in ((0, ja), (jb, n)):
            if s1 > s0:
                a_s, l_s = ar[c1 * s0:c1 * s1], lr[c1 * s0:c1 * s1]
                if c1 == 4:
                    _keep_add(a_s, l_s, 4, 3, True, l_s, s1 - s0, 4)
                else:
                    _keep_add(a_s, l_s, c1, c1 - 1, True, l_s, s1 - s0, c1)
        if jb > ja:
            p0 = (pi * pw + ox + ja - px) * c1
            pr = pf[p0:p0 + (jb - ja) * c1]
            ab, lb = ar[c1 * ja:c1 * jb], lr[c1 * ja:c1 * jb]
            if c1 == 4:
                _keep_add_behind(ab, lb, pr, jb - ja, 4)
            else:
                _keep_add_behind(ab, lb, pr, jb - ja, c1)
        if with_trans:
            tr = trans[y, ox:ox + n]
            for j in range(n):
                tr[j] *= np.float32(1.0) - lr[np.uintp(c1 * j + c1 - 1)]
        if with_skip:
            sr = skip[y, ox:ox + n]
            for j in range(n):
                a = lr[np.uintp(c1 * j + c1 - 1)]
                sr[j] = a if first else sr[j] * (np.float32(1.0) - a)


@njit(parallel=True, **_JIT)
def merge(acc, oy, ox, group, trans, skip, prev, py, px):
    """A group of layers composited on their own (``group``: premultiplied, ``trans``: their
    transmission, ``skip``: the first one's coverage times the later ones' transmission, or
    empty), placed at (``oy``, ``ox``), over ``acc``: ``acc = trans acc + group + skip prev``
    (``prev`` as in :func:`over`); cells past ``acc``'s edge are left out. Every array
    C-contiguous; the rows' loops as in :func:`over`."""
    h, w, c1 = acc.shape
    rows, cols = group.shape[0], group.shape[1]
    ph, pw = prev.shape[0], prev.shape[1]
    af = acc.reshape(acc.size)
    gf = group.reshape(group.size)
    pf = prev.reshape(prev.size)
    with_skip = skip.shape[0] > 0
    ja = max(0, -ox)
    jb = min(cols, w - ox)
    if jb <= ja:
        return
    n = jb - ja
    for i in prange(max(0, -oy), min(rows, h - oy)):
        y = oy + i
        a0 = (y * w + ox + ja) * c1
        ar = af[a0:a0 + n * c1]
        gr = gf[(i * cols + ja) * c1:(i * cols + jb) * c1]
        tr = trans[i, ja:jb]
        if c1 == 4:
            _keep_add(ar, tr, 1, 0, False, gr, n, 4)
        else:
            _keep_add(ar, tr, 1, 0, False, gr, n, c1)
        if not with_skip:
            continue
        pi, ka, kb = _overlap(y, ox + ja, n, py, px, ph, pw)
        if kb > ka:
            p0 = (pi * pw + ox + ja + ka - px) * c1
            pr = pf[p0:p0 + (kb - ka) * c1]
            sr = skip[i, ja + ka:ja + kb]
            ab = ar[c1 * ka:c1 * kb]
            if c1 == 4:
                _add_scaled(ab, sr, 1, 0, pr, kb - ka, 4)
            else:
                _add_scaled(ab, sr, 1, 0, pr, kb - ka, c1)


@njit(inline="always")
def _divided(ar, orow, n, c1, floor):
    """``orow`` (n cells of c1 - 1 values) = the cells of ``ar`` divided by their last value, 0
    where that is at most ``floor``."""
    c = c1 - 1
    for j in range(n):
        den = ar[np.uintp(c1 * j + c)]
        inv = np.float32(1.0) / den
        for ch in range(c):
            orow[np.uintp(c * j + ch)] = ar[np.uintp(c1 * j + ch)] * inv if den > floor else np.float32(0.0)


@njit(inline="always")
def _divided_filled(ar, br, orow, n, c1, floor):
    """:func:`_divided` with the cells of ``br`` filling the coverage ``ar`` lacks: ``ar + f br``,
    f = 1 - the coverage, clipped to [0, 1]."""
    c = c1 - 1
    for j in range(n):
        alpha = ar[np.uintp(c1 * j + c)]
        fill = min(max(np.float32(1.0) - alpha, np.float32(0.0)), np.float32(1.0))
        den = alpha + fill * br[np.uintp(c1 * j + c)]
        inv = np.float32(1.0) / den
        for ch in range(c):
            num = ar[np.uintp(c1 * j + ch)] + fill * br[np.uintp(c1 * j + ch)]
            orow[np.uintp(c * j + ch)] = num * inv if den > floor else np.float32(0.0)


@njit(parallel=True, **_JIT)
def finish(acc, back, by, bx, floor, out, clear):
    """``out`` (h, w, C) = the composite ``acc`` (h, w, C + 1: premultiplied colour and
    coverage) with the background ``back`` (same layout, summed, placed at (``by``, ``bx``), or
    empty) filling the coverage it lacks, divided by the coverage; 0 where the coverage is at
    most ``floor``. Where ``clear``, each row of ``acc`` is set to zeros once read (the next
    render's composite starts from zeros, and the row is in cache here). Every array
    C-contiguous; the rows' loops as in :func:`over`."""
    h, w, c1 = acc.shape
    c = c1 - 1
    bh, bw = back.shape[0], back.shape[1]
    af = acc.reshape(acc.size)
    bf = back.reshape(back.size)
    of = out.reshape(out.size)
    for y in prange(h):
        ar = af[y * w * c1:(y + 1) * w * c1]
        orow = of[y * w * c:(y + 1) * w * c]
        bi, ja, jb = _overlap(y, 0, w, by, bx, bh, bw)
        # The cells before the background's, under it, and after it.
        for s0, s1 in ((0, ja), (jb, w)):
            if s1 > s0:
                a_s, o_s = ar[c1 * s0:c1 * s1], orow[c * s0:c * s1]
                if c1 == 4:
                    _divided(a_s, o_s, s1 - s0, 4, floor)
                else:
                    _divided(a_s, o_s, s1 - s0, c1, floor)
        if jb > ja:
            b0 = (bi * bw + ja - bx) * c1
            br = bf[b0:b0 + (jb - ja) * c1]
            a_s, o_s = ar[c1 * ja:c1 * jb], orow[c * ja:c * jb]
            if c1 == 4:
                _divided_filled(a_s, br, o_s, jb - ja, 4, floor)
            else:
                _divided_filled(a_s, br, o_s, jb - ja, c1, floor)
        if clear:
            ar[:] = np.float32(0.0)


@njit(inline="always")
def _clamp_row(r, cols, c1, zero, top):
    """A row of :func:`clamp_cells`' cells of ``c1`` values (RGB's compiled for exactly 4)."""
    for j in range(cols):
        a = max(r[np.uintp(j * c1 + c1 - 1)], zero)
        r[np.uintp(j * c1 + c1 - 1)] = a
        cap = a * top
        for ch in range(c1 - 1):
            e = np.uintp(j * c1 + ch)
            r[e] = min(max(r[e], zero), cap)


@njit(parallel=True, **_JIT)
def clamp_cells(cells, vmax):
    """Clamp ``cells`` (rows, cols, C + 1: premultiplied colour and coverage, C-contiguous) in
    place to what they can hold: the coverage at least 0, each colour in [0, coverage *
    ``vmax``]; a map (rows, cols, 1) to [0, 1] when ``vmax`` is negative."""
    rows, cols, c1 = cells.shape
    flat = cells.reshape(rows, cols * c1)
    zero = np.float32(0.0)
    top = np.float32(vmax)
    for y in prange(rows):
        r = flat[y]
        if vmax < 0.0:
            for e in range(cols * c1):
                r[e] = min(max(r[e], zero), np.float32(1.0))
            continue
        if c1 == 4:
            _clamp_row(r, cols, 4, zero, top)
        else:
            _clamp_row(r, cols, c1, zero, top)


# Rows of a disc blur per parallel task (they share the task's scratch rows).
BLUR_TASK_ROWS = 16


@njit(inline="always")
def _fold_rows(rows_of, y, rows, length, n, pad, stride, zero, fold):
    """``fold`` row i (i = 0 .. n, each ``stride`` long, ``pad`` zeros on either side) = row
    y + i plus row y - i of ``rows_of`` (rows, length), rows past either end and the second
    row y taken from ``zero`` (one loop a row: the code stays small)."""
    for i in range(n + 1):
        base = i * stride + pad
        ra = rows_of[y + i] if y + i < rows else zero
        rb = rows_of[y - i] if i > 0 and y - i >= 0 else zero
        for e in range(length):
            fold[np.uintp(base + e)] = ra[e] + rb[e]


@njit(inline="always")
def _disc_row(rows_of, y, rows, length, quarter, n, c1, zero, fold, cols, out):
    """Row ``y`` of :func:`disc_blur`, ``n`` (the disc's reach) a literal: the loops over the taps
    unroll, and each value's sums stay in registers."""
    pad = n * c1
    stride = length + 2 * pad
    _fold_rows(rows_of, y, rows, length, n, pad, stride, zero, fold)
    # Columns j of the quarter applied to the folded rows, over the padded row, three columns a
    # pass (each folded value loaded once for the three; more sums than three spill registers) ...
    j = 0
    while j + 3 <= n + 1:
        for e in range(stride):
            f0 = fold[np.uintp(e)]
            a0 = quarter[0, j] * f0
            a1 = quarter[0, j + 1] * f0
            a2 = quarter[0, j + 2] * f0
            for i in range(1, n + 1):
                fi = fold[np.uintp(i * stride + e)]
                a0 += quarter[i, j] * fi
                a1 += quarter[i, j + 1] * fi
                a2 += quarter[i, j + 2] * fi
            cols[np.uintp(j * stride + e)] = a0
            cols[np.uintp((j + 1) * stride + e)] = a1
            cols[np.uintp((j + 2) * stride + e)] = a2
        j += 3
    if j + 2 == n + 1:
        for e in range(stride):
            f0 = fold[np.uintp(e)]
            a0 = quarter[0, j] * f0
            a1 = quarter[0, j + 1] * f0
            for i in range(1, n + 1):
                fi = fold[np.uintp(i * stride + e)]
                a0 += quarter[i, j] * fi
                a1 += quarter[i, j + 1] * fi
            cols[np.uintp(j * stride + e)] = a0
            cols[np.uintp((j + 1) * stride + e)] = a1
    elif j + 1 == n + 1:
        for e in range(stride):
            a0 = quarter[0, j] * fold[np.uintp(e)]
            for i in range(1, n + 1):
                a0 += quarter[i, j] * fold[np.uintp(i * stride + e)]
            cols[np.uintp(j * stride + e)] = a0
    # ... and shifted by j cells to either side.
    for e in range(length):
        acc = cols[np.uintp(pad + e)]
        for j in range(1, n + 1):
            acc += cols[np.uintp(j * stride + pad + e - c1 * j)] + cols[np.uintp(j * stride + pad + e + c1 * j)]
        out[e] = acc


@njit(inline="always")
def _first_taps(col, fold, stride, quarter, j, m):
    """``col`` = taps 0 .. ``m`` - 1 of column ``j`` of the quarter times their folded rows, in
    that order, in one pass (``m`` a literal, 1 to 4)."""
    k0 = quarter[0, j]
    if m == 1:
        for e in range(stride):
            col[e] = k0 * fold[np.uintp(e)]
        return
    k1 = quarter[1, j]
    b1 = np.uintp(stride)
    if m == 2:
        for e in range(stride):
            u = np.uintp(e)
            col[e] = k0 * fold[u] + k1 * fold[b1 + u]
        return
    k2 = quarter[2, j]
    b2 = b1 + np.uintp(stride)
    if m == 3:
        for e in range(stride):
            u = np.uintp(e)
            col[e] = (k0 * fold[u] + k1 * fold[b1 + u]) + k2 * fold[b2 + u]
        return
    k3 = quarter[3, j]
    b3 = b2 + np.uintp(stride)
    for e in range(stride):
        u = np.uintp(e)
        col[e] = ((k0 * fold[u] + k1 * fold[b1 + u]) + k2 * fold[b2 + u]) + k3 * fold[b3 + u]


@njit(inline="always")
def _disc_row_any(rows_of, y, rows, length, quarter, n, c1, zero, fold, cols, out):
    """:func:`_disc_row` for a reach known at run time: the same taps in the same order (to
    float32 rounding: which products are fused into additions is the compiler's choice). Each
    column of the quarter is a pass over the row (in cache) for its first four taps, then one
    more per tap: loops that vectorise without unrolling over the taps (reaches past 3, which
    have more than four, are rare here: 4 and 5 have loops of their own)."""
    pad = n * c1
    stride = length + 2 * pad
    _fold_rows(rows_of, y, rows, length, n, pad, stride, zero, fold)
    col = cols[:stride]
    for j in range(n + 1):
        if n >= 3:
            _first_taps(col, fold, stride, quarter, j, 4)
        elif n == 2:
            _first_taps(col, fold, stride, quarter, j, 3)
        elif n == 1:
            _first_taps(col, fold, stride, quarter, j, 2)
        else:
            _first_taps(col, fold, stride, quarter, j, 1)
        for i in range(4, n + 1):
            k = quarter[i, j]
            fi = fold[i * stride:(i + 1) * stride]
            for e in range(stride):
                col[e] += k * fi[e]
        if j == 0:
            for e in range(length):
                out[e] = col[np.uintp(pad + e)]
        else:
            lo = col[pad - c1 * j:pad - c1 * j + length]
            hi = col[pad + c1 * j:pad + c1 * j + length]
            for e in range(length):
                out[e] += lo[e] + hi[e]


@njit(parallel=True, **dict(_JIT, fastmath={"contract"}))
def disc_blur(cells, quarter, out):
    """``out`` (rows, cols, m) = ``cells`` (the same shape, C-contiguous) convolved with a disc
    symmetric about both axes, zero outside: ``quarter`` ((n + 1) x (n + 1)) is its taps at row
    and column offsets 0 .. n (as ``cv2.filter2D`` with ``BORDER_CONSTANT``, to float32 rounding).

    The rows at +i and -i share every tap, so they are added first (n + 1 folded rows); each
    column of the quarter is applied to them, and the columns are added shifted by their offset
    to either side: about (n + 1)^2 + 3 n operations a value instead of (2 n + 1)^2. The reaches
    that carry most of a render's blurs, 4 and 5, run loops compiled for them, which unroll over
    the taps and keep each value's sums in registers, three columns of the quarter at a time
    (each folded value is loaded once for the three); the others (each such copy would lengthen
    the first compile) pass over the row once per column for its first four taps, and once per
    further tap. Indices are unsigned: numba checks a signed one for a negative value, which
    keeps a loop from vectorising."""
    rows, width, c1 = cells.shape
    length = width * c1
    n = quarter.shape[0] - 1
    rows_of = cells.reshape(rows, length)
    out_of = out.reshape(rows, length)
    stride = length + 2 * n * c1
    for b in prange((rows + BLUR_TASK_ROWS - 1) // BLUR_TASK_ROWS):
        fold = np.zeros((n + 1) * stride, np.float32)
        cols = np.empty((n + 1) * stride, np.float32)
        zero = np.zeros(length, np.float32)
        for y in range(b * BLUR_TASK_ROWS, min(rows, (b + 1) * BLUR_TASK_ROWS)):
            o = out_of[y]
            if n == 5:
                _disc_row(rows_of, y, rows, length, quarter, 5, c1, zero, fold, cols, o)
            elif n == 4:
                _disc_row(rows_of, y, rows, length, quarter, 4, c1, zero, fold, cols, o)
            else:
                _disc_row_any(rows_of, y, rows, length, quarter, n, c1, zero, fold, cols, o)


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
def robust_mean(warped, weight, visible, agree_tol, spread_tol, full_visible, floor, colour, agree, seen):
    """The views' robust mean at every pixel (the all-in-focus colour of
    :class:`lfring.focus.depth_aware.DepthOfField`), from the views sampled there ``warped`` (V,
    h, w, C; premultiplied by ``weight`` (V, h, w), how much of each view is valid there) and
    ``visible`` (V, h, w; no nearer surface hides the pixel from the view).

    Every statistic weighs a view by its weight, so that a view fading out at its disc's rim
    fades out of it. The centre is robust: each view's luminance (mean of the channels)
    weighted by the summed weight of the views within about ``agree_tol`` of it, to the fourth
    power, so three agreeing views outweigh a fourth; a view whose luminance is off the centre
    by more than ``tol = max(agree_tol, spread_tol * spread)`` (spread: the views' rms deviation
    about it) loses weight linearly, none left at twice that. The present views (weight >
    ``floor``) that are not visible count by ``1 - (visible views' weight) / full_visible``
    (none from there on): all of them where no view is visible, and a view that only grazes
    the pixel with its disc's rim does not outvote a whole one that is hidden. Writes ``colour`` (h, w, C; 0 where not
    ``seen``), ``agree`` (h, w: 1 less the worst view's excess deviation over ``agree_tol``,
    every present view by its weight, occluded or not; 0 where none is present) and ``seen``
    (h, w: the views' weight in the mean exceeds ``floor``)."""
    v, h, w, c = warped.shape
    inv_c = 1.0 / c
    inv_tol = 1.0 / agree_tol
    for y in prange(h):
        # A row at a time, each step a loop over the row per view: such loops vectorise (the
        # selects have no branches), where a loop over the views per pixel stays scalar. Every
        # pixel's sums still add the views in order, so the results are those of a per-pixel loop.
        lum = np.empty((v, w))
        wv = np.empty((v, w))
        support = np.empty((v, w))
        scale = np.empty((v, w))
        hidden = np.zeros(w)  # the visible views' weight, then what a hidden view counts by
        any_present = np.zeros(w, np.uint8)
        for k in range(v):
            wrow = weight[k, y]
            vrow = visible[k, y].view(np.uint8)
            for xx in range(w):
                wk = wrow[xx]
                present = wk > floor
                any_present[xx] |= np.uint8(present)
                hidden[xx] += wk if (present & (vrow[xx] != 0)) else 0.0
        for xx in range(w):
            hidden[xx] = max(1.0 - hidden[xx] / full_visible, 0.0)
        for k in range(v):
            wrow = weight[k, y]
            vrow = visible[k, y].view(np.uint8)
            src = warped[k, y].reshape(w * c)
            lum_k, scale_k, wv_k, support_k = lum[k], scale[k], wv[k], support[k]
            for xx in range(w):
                wk = wrow[xx]
                present = wk > floor
                s = 0.0
                for ch in range(c):
                    s += src[xx * c + ch]
                lum_k[xx] = s * inv_c / wk if present else 0.0
                sc = (1.0 if vrow[xx] != 0 else hidden[xx]) if present else 0.0
                scale_k[xx] = sc
                wv_k[xx] = wk * sc
                support_k[xx] = wk * sc
        # Each view's support: the weight of the views close to it (itself included), the
        # closeness of a pair computed once (float32: a closeness; the exponential is a call
        # per pixel, in a loop of its own so that the others vectorise).
        close = np.empty(w, np.float32)
        for k in range(v):
            for j in range(k + 1, v):
                lum_k, lum_j = lum[k], lum[j]
                for xx in range(w):
                    dl = np.float32((lum_j[xx] - lum_k[xx]) * inv_tol)
                    close[xx] = np.float32(-0.5) * dl * dl
                for xx in range(w):
                    close[xx] = np.exp(close[xx])
                wv_k, wv_j, support_k, support_j = wv[k], wv[j], support[k], support[j]
                for xx in range(w):
                    both = (wv_k[xx] > 0.0) & (wv_j[xx] > 0.0)
                    support_k[xx] += close[xx] * wv_j[xx] if both else 0.0
                    support_j[xx] += close[xx] * wv_k[xx] if both else 0.0
        # The centre: the views' luminance weighted by support^4 (support now holds that
        # weight), or by their weights where no view has support.
        total = np.zeros(w)
        sum_wv = np.zeros(w)
        sum_wl = np.zeros(w)
        centre = np.zeros(w)
        for k in range(v):
            support_k, wv_k, lum_k = support[k], wv[k], lum[k]
            for xx in range(w):
                acc = support_k[xx] * support_k[xx]
                sk = acc * acc * wv_k[xx]
                support_k[xx] = sk
                total[xx] += sk
                sum_wv[xx] += wv_k[xx]
                sum_wl[xx] += wv_k[xx] * lum_k[xx]
                centre[xx] += sk * lum_k[xx]
        for xx in range(w):
            centre[xx] = centre[xx] / max(total[xx], 1e-30) if total[xx] > 0.0 else sum_wl[xx] / max(sum_wv[xx], floor)
        tol = np.zeros(w)  # the views' weighted variance about the centre, then the tolerance
        for k in range(v):
            wv_k, lum_k = wv[k], lum[k]
            for xx in range(w):
                dev = lum_k[xx] - centre[xx]
                tol[xx] += wv_k[xx] * dev * dev
        for xx in range(w):
            tol[xx] = max(agree_tol, spread_tol * np.sqrt(tol[xx] / max(sum_wv[xx], floor)))
        # Each view's share phi (support now holds it), the worst agreement and phi's sum.
        worst = np.ones(w)
        den = np.zeros(w)
        for k in range(v):
            wv_k, lum_k, scale_k, support_k = wv[k], lum[k], scale[k], support[k]
            wrow = weight[k, y]
            for xx in range(w):
                dev = abs(lum_k[xx] - centre[xx])
                phi = min(max(2.0 - dev / tol[xx], 0.0), 1.0) * scale_k[xx] if wv_k[xx] > 0.0 else 0.0
                wk = wrow[xx]
                dis = min(max(dev / agree_tol - 1.0, 0.0), 1.0) * min(max(wk, 0.0), 1.0)
                worst[xx] = min(worst[xx], 1.0 - dis) if wk > floor else worst[xx]
                den[xx] += phi * wk
                support_k[xx] = phi
        agree_row = agree[y]
        seen_row = seen[y].view(np.uint8)
        for xx in range(w):
            agree_row[xx] = worst[xx] if any_present[xx] != 0 else 0.0
            seen_row[xx] = np.uint8(den[xx] > floor)
        num = total  # reused
        out = colour[y].reshape(w * c)
        for ch in range(c):
            num[:] = 0.0
            for k in range(v):
                support_k = support[k]
                src = warped[k, y].reshape(w * c)
                for xx in range(w):
                    num[xx] += support_k[xx] * src[xx * c + ch]
            for xx in range(w):
                out[xx * c + ch] = num[xx] / den[xx] if den[xx] > floor else 0.0


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
def shift_maps_at(rows, cols, x, x0, shift, slope, map_x, map_y):
    """:func:`shift_maps` for the listed pixels only: ``rows``, ``cols`` and ``x`` (n,) each, the
    maps (V, n); the same values as at those pixels of the whole grid."""
    n = x.shape[0]
    for k in prange(shift.shape[0]):
        sx, sy = shift[k, 0], shift[k, 1]
        gx, gy = slope[k, 0], slope[k, 1]
        for i in range(n):
            dx = x[i] - x0
            map_x[k, i] = np.float32(cols[i]) + sx + dx * gx
            map_y[k, i] = np.float32(rows[i]) + sy + dx * gy


@njit(parallel=True, **_JIT)
def add_seen(val, weight, hidden, num, den):
    """``num += val`` (h, w, C) and ``den += weight`` (h, w) where not ``hidden`` (a view's
    samples of the background that it sees)."""
    h, w, c = val.shape
    for y in prange(h):
        for xx in range(w):
            if not hidden[y, xx]:
                for ch in range(c):
                    num[y, xx, ch] += val[y, xx, ch]
                den[y, xx] += weight[y, xx]


@njit(inline="always")
def _knot_segment(xv, knots):
    """(j, t): the segment of the increasing ``knots`` that holds ``xv``, as
    np.searchsorted(knots, xv, side="right") - 1 clipped to 0..K-2, and where in it (0 .. 1)."""
    j = 0
    hi = knots.shape[0] - 1
    while hi - j > 1:
        mid = (j + hi) // 2
        if knots[mid] <= xv:
            j = mid
        else:
            hi = mid
    return j, (xv - knots[j]) / (knots[j + 1] - knots[j])


@njit(inline="always")
def _knot_point(inv, j, t, k, row, col):
    """View k's pixel (x, y) for the reference pixel (``col``, ``row``): its homographies at
    knots j and j + 1 of ``inv`` applied, and interpolated at ``t``."""
    a = inv[j, k]
    b = inv[j + 1, k]
    wa = a[2, 0] * col + a[2, 1] * row + a[2, 2]
    wb = b[2, 0] * col + b[2, 1] * row + b[2, 2]
    ax = (a[0, 0] * col + a[0, 1] * row + a[0, 2]) / wa
    ay = (a[1, 0] * col + a[1, 1] * row + a[1, 2]) / wa
    bx = (b[0, 0] * col + b[0, 1] * row + b[0, 2]) / wb
    by = (b[1, 0] * col + b[1, 1] * row + b[1, 2]) / wb
    return ax + t * (bx - ax), ay + t * (by - ay)


@njit(parallel=True, **_JIT)
def knot_maps(x, knots, inv, map_x, map_y):
    """``map_x``, ``map_y`` (V, h, w): the view pixel that every reference pixel samples at its
    inverse depth ``x`` (h, w), linear in x between the increasing ``knots`` (K) where ``inv``
    (K, V, 3, 3) maps reference pixels into each view (a homography per knot and view)."""
    h, w = x.shape
    v = inv.shape[1]
    for y in prange(h):
        for xx in range(w):
            j, t = _knot_segment(x[y, xx], knots)
            for k in range(v):
                map_x[k, y, xx], map_y[k, y, xx] = _knot_point(inv, j, t, k, y, xx)


@njit(parallel=True, **_JIT)
def knot_maps_at(rows, cols, x, knots, inv, map_x, map_y):
    """:func:`knot_maps` for the listed pixels only: ``rows``, ``cols`` and ``x`` (n,) each, the
    maps (V, n); the same values as at those pixels of the whole grid."""
    n = x.shape[0]
    v = inv.shape[1]
    for i in prange(n):
        j, t = _knot_segment(x[i], knots)
        for k in range(v):
            map_x[k, i], map_y[k, i] = _knot_point(inv, j, t, k, rows[i], cols[i])
