"""The Triton kernels of the GPU engine (:mod:`lfring.depth.engines.gpu`): compiled for the GPU,
or interpreted on CPU tensors where the process sees no CUDA device
(:mod:`lfring.core.triton_kernels`). Importing this module imports torch and Triton; the engine
imports it on first use only.

- :func:`warp_kernel`: every view warped to every hypothesis of a chunk (bilinear, zero
  outside), with its mask: the general sweep and the guide of the 'center' frame.
- :func:`lcn_kernel`: the 'lcn' cost of a set of views (all, or a half) at a chunk of
  hypotheses, straight from the views (the warp is fused in), and where it counts.
- :func:`box_columns_kernel`, :func:`box_ratio_kernel`: the sweep's box means (OpenCV's
  BORDER_REFLECT_101 borders, summed in ``avg_pool2d``'s order: each column's k rows over k,
  then k columns over k) with the ratio that uses them, two passes over a chunk instead of a
  padded copy, four pooling passes and the element-wise operations between them.
- :func:`fill_kernel`: unknown costs replaced by their pixel's mean known cost.
- :func:`path_kernel`: one scan path of the semi-global aggregation, one program per block of
  lines that walks them step by step with their running state on chip; the paths add up in
  the aggregated volume.
- :func:`select_kernel`: the winner of the aggregated volume, its sub-hypothesis parabola on the
  raw cost's box mean and the two distinctness measures, one pass over both volumes.
- :func:`median_kernel`: the edge-aware weighted median of the refinement.
- :func:`fgs_kernel`: one pass of the fast global smoother (Min et al. 2014): a tridiagonal
  solve along every row or column (the Thomas algorithm).

Every float operation is spelled out in the order of the NumPy/numba/OpenCV reference and the
kernels are launched without fused multiply-adds, so that with the same inputs the paths, the
selection and the smoother give the reference's numbers (to the order of float sums).
"""

from __future__ import annotations

from lfring.core.triton_kernels import device_function, jit, project, reduce_min, reduce_sum, sample, taps, tl

__all__ = ["BOX_FINITE", "BOX_HALF", "BOX_MEAN", "box_columns_kernel", "box_ratio_kernel", "fgs_kernel", "fill_kernel", "lcn_kernel", "median_kernel", "path_kernel", "select_kernel", "warp_kernel"]

# A cost that can never win: the padded hypotheses of a block (a constant the kernels can read).
_BIG = tl.constexpr(1e30) if tl is not None else 1e30


# -- the sweep -----------------------------------------------------------------------------------
@jit
def warp_kernel(src_ptr, msk_ptr, hinv_ptr, out_ptr, wts_ptr, n_views, h, w, d0, BLOCK: tl.constexpr):
    """Per hypothesis ``d0 + program_id(1)`` and view: the view's source (premultiplied by its
    mask) and its mask warped into the reference frame, into ``out`` and ``wts`` (C, V, h, w).
    ``hinv`` (N, V, 9): the maps from reference pixels to view pixels."""
    pid = tl.program_id(0)
    c = tl.program_id(1)
    hw = h * w
    p = pid * BLOCK + tl.arange(0, BLOCK)
    inside = p < hw
    yf = (p // w).to(tl.float32)
    xf = (p % w).to(tl.float32)
    for k in range(0, n_views):
        u, v = project(hinv_ptr + ((d0 + c) * n_views + k) * 9, xf, yf)
        o00, m00, m01, m10, m11, fx, fy = taps(u, v, h, w)
        a = sample(src_ptr + tl.cast(k, tl.int64) * hw, o00, m00, m01, m10, m11, fx, fy, w)
        m = sample(msk_ptr + tl.cast(k, tl.int64) * hw, o00, m00, m01, m10, m11, fx, fy, w)
        o = (tl.cast(c, tl.int64) * n_views + k) * hw + p
        tl.store(out_ptr + o, a, mask=inside)
        tl.store(wts_ptr + o, m, mask=inside)


@jit
def lcn_kernel(src_ptr, msk_ptr, hinv_ptr, cost_ptr, seen_ptr, nv_ptr, n_views, members, h, w, d0, n_chunk, floor,
               WRITE_NV: tl.constexpr, BLOCK: tl.constexpr):
    """The 'lcn' cost of the views in ``members`` (a bit per view) at hypotheses ``d0`` ..
    ``d0 + n_chunk``: ``(S2 - S1^2 / C) / max(C - 1, 0.5)`` of their warped sources and masks
    (:func:`lfring.depth.costs.lcn.lcn_cost`) into ``cost`` (n_chunk, h, w), where all views
    together weigh 1.5 or more and so do the members (``seen`` 1, else 0 and a cost of 0); S2 sums
    each member's square over its weight (:func:`lfring.depth.costs.lcn.weighted_square`). With
    ``WRITE_NV``: ``nv`` (h, w) = the most the views weigh over these hypotheses and ``nv``'s
    value before."""
    pid = tl.program_id(0)
    hw = h * w
    p = pid * BLOCK + tl.arange(0, BLOCK)
    inside = p < hw
    yf = (p // w).to(tl.float32)
    xf = (p % w).to(tl.float32)
    if WRITE_NV:
        nv = tl.load(nv_ptr + p, mask=inside, other=0.0)
    for c in range(0, n_chunk):
        s1 = tl.zeros([BLOCK], tl.float32)
        s2 = tl.zeros([BLOCK], tl.float32)
        cn = tl.zeros([BLOCK], tl.float32)
        cn_all = tl.zeros([BLOCK], tl.float32)
        for k in range(0, n_views):
            u, v = project(hinv_ptr + ((d0 + c) * n_views + k) * 9, xf, yf)
            o00, m00, m01, m10, m11, fx, fy = taps(u, v, h, w)
            m = sample(msk_ptr + tl.cast(k, tl.int64) * hw, o00, m00, m01, m10, m11, fx, fy, w)
            cn_all += m
            if ((members >> k) & 1) != 0:
                a = sample(src_ptr + tl.cast(k, tl.int64) * hw, o00, m00, m01, m10, m11, fx, fy, w)
                s1 += a
                s2 += a * a / tl.maximum(m, floor)  # w n^2 (lfring.depth.costs.lcn.weighted_square)
                cn += m
        cost = s2 - s1 * s1 / tl.maximum(cn, floor)
        cost = cost / tl.maximum(cn - 1.0, 0.5)
        ok = (cn_all >= 1.5) & (cn >= 1.5) & (cost == cost) & (tl.abs(cost) < float("inf"))
        o = tl.cast(c, tl.int64) * hw + p
        tl.store(cost_ptr + o, tl.where(ok, cost, 0.0), mask=inside)
        tl.store(seen_ptr + o, tl.where(ok, 1.0, 0.0), mask=inside)
        if WRITE_NV:
            nv = tl.maximum(nv, cn_all)
    if WRITE_NV:
        tl.store(nv_ptr + p, nv, mask=inside)


# What box_ratio_kernel makes of the box means (its MODE).
BOX_MEAN = 0  # mean(num) / max(mean(den), floor) where den > 0.5 at the pixel, inf elsewhere
BOX_HALF = 1  # a half's candidate scale * mean(num) / mean(den), kept where it counts and is less
BOX_FINITE = 2  # the mean of num's finite values where num is finite, inf elsewhere (den = finite)


@device_function
def _reflect(i, n):
    """OpenCV's BORDER_REFLECT_101 index of ``i`` along an axis of ``n``, however far outside
    (reflected again and again: periodic in 2 n - 2; 0 where n is 1)."""
    period = tl.maximum(2 * n - 2, 1)
    i = tl.abs(i) % period
    return tl.where(i >= n, period - i, i)


@device_function
def _slice_pixels(h, w, BLOCK: tl.constexpr):
    """This program's block of pixels in slice ``program_id(1)`` of a (C, h, w) tensor: their
    flat index in the slice, which lie inside it, their row and column, and the slice's
    offset."""
    hw = h * w
    p = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
    return p, p < hw, p // w, p % w, tl.cast(tl.program_id(1), tl.int64) * hw


@jit
def box_columns_kernel(num_ptr, den_ptr, col_num_ptr, col_den_ptr, h, w, FINITE: tl.constexpr, K: tl.constexpr,
                       BLOCK: tl.constexpr):
    """The first pass of the box means of slice ``program_id(1)`` of ``num`` and ``den`` (C, h,
    w): each pixel's sum over the K rows centred on it, over K, into ``col_num`` and ``col_den``.
    With ``FINITE``: of num's finite values and of their count (``den`` is not read)."""
    p, inside, y, x, base = _slice_pixels(h, w, BLOCK)
    s_num = tl.zeros([BLOCK], tl.float32)
    s_den = tl.zeros([BLOCK], tl.float32)
    for dy in tl.static_range(K):
        o = base + _reflect(y + (dy - K // 2), h) * w + x
        a = tl.load(num_ptr + o, mask=inside, other=0.0)
        if FINITE:
            known = tl.abs(a) < float("inf")
            s_num += tl.where(known, a, 0.0)
            s_den += tl.where(known, 1.0, 0.0)
        else:
            s_num += a
            s_den += tl.load(den_ptr + o, mask=inside, other=0.0)
    tl.store(col_num_ptr + base + p, s_num / K, mask=inside)
    tl.store(col_den_ptr + base + p, s_den / K, mask=inside)


@jit
def box_ratio_kernel(num_ptr, den_ptr, col_num_ptr, col_den_ptr, out_ptr, h, w, floor, scale, min_support,
                     MODE: tl.constexpr, K: tl.constexpr, BLOCK: tl.constexpr):
    """The second pass: the box means of slice ``program_id(1)`` (the K column sums centred on
    each pixel, over K) and what MODE makes of them into ``out`` (C, h, w): BOX_MEAN
    ``mean(num) / max(mean(den), floor)`` where ``den`` > 0.5 at the pixel, inf elsewhere;
    BOX_HALF ``scale * mean(num) / mean(den)`` where ``den`` > 0.5 at the pixel and
    ``mean(den) >= min_support``, stored where less than ``out``; BOX_FINITE
    ``mean(num) / max(mean(den), floor)`` where ``num`` is finite at the pixel, inf elsewhere
    (``out`` may be ``num``: each pixel reads only itself there)."""
    p, inside, y, x, base = _slice_pixels(h, w, BLOCK)
    s_num = tl.zeros([BLOCK], tl.float32)
    s_den = tl.zeros([BLOCK], tl.float32)
    for dx in tl.static_range(K):
        o = base + y * w + _reflect(x + (dx - K // 2), w)
        s_num += tl.load(col_num_ptr + o, mask=inside, other=0.0)
        s_den += tl.load(col_den_ptr + o, mask=inside, other=0.0)
    m_num = s_num / K
    m_den = s_den / K
    o = base + p
    if MODE == 1:
        counts = (tl.load(den_ptr + o, mask=inside, other=0.0) > 0.5) & (m_den >= min_support)
        cand = scale * m_num / tl.where(counts, m_den, 1.0)
        least = tl.load(out_ptr + o, mask=inside, other=0.0)
        tl.store(out_ptr + o, cand, mask=inside & counts & (cand < least))
    else:
        if MODE == 2:
            own = tl.abs(tl.load(num_ptr + o, mask=inside, other=0.0)) < float("inf")
        else:
            own = tl.load(den_ptr + o, mask=inside, other=0.0) > 0.5
        tl.store(out_ptr + o, tl.where(own, m_num / tl.maximum(m_den, floor), float("inf")), mask=inside)


# -- the semi-global paths -----------------------------------------------------------------------
@jit
def fill_kernel(vol_ptr, n, hw, N_PAD: tl.constexpr, P: tl.constexpr):
    """Unknown (not finite) costs of the (n, h, w) volume replaced, in place, by the mean of
    their pixel's known costs (float64 sums; 0 where none is known), as
    :func:`lfring.depth.sgm_kernels.fill_values`."""
    pid = tl.program_id(0)
    d = tl.arange(0, N_PAD)[:, None]
    p = pid * P + tl.arange(0, P)[None, :]
    m = (d < n) & (p < hw)
    offs = d.to(tl.int64) * hw + p
    c = tl.load(vol_ptr + offs, mask=m, other=0.0)
    known = m & (tl.abs(c) < float("inf"))
    total = reduce_sum(tl.where(known, c.to(tl.float64), 0.0), 0)
    count = reduce_sum(known.to(tl.int32), 0)
    mean = tl.where(count > 0, total / tl.maximum(count, 1).to(tl.float64), 0.0).to(tl.float32)
    tl.store(vol_ptr + offs, tl.where(known, c, mean[None, :]), mask=m & ~known)


@jit
def path_kernel(cost_ptr, total_ptr, pen_ptr, p1_ptr, scratch_ptr, n, h, w, line0, n_lines, n_steps,
                HORIZONTAL: tl.constexpr, REVERSE: tl.constexpr, SLOPE: tl.constexpr, FIRST: tl.constexpr,
                N_PAD: tl.constexpr, LINES: tl.constexpr):
    """One scan path of the semi-global aggregation over the (n, h, w) ``cost`` (finite), added
    into ``total`` (written with ``FIRST``).

    A program walks ``LINES`` lines side by side, step by step, with their (N_PAD, LINES) state on
    chip. Horizontal lines are rows, stepping along x (right to left with ``REVERSE``); the others
    step along y (bottom-up with ``REVERSE``) on the lines x = k + SLOPE * y, k from ``line0``
    (SLOPE 0: the columns; +-1: the diagonals). ``pen`` (h, w): each pixel's large-jump penalty
    towards its predecessor on the path; ``p1``: a one-element tensor. A line's state is zero
    until it enters the image, so its first pixel takes its cost alone, as in
    :mod:`lfring.depth.sgm_kernels`. ``scratch``: (programs, N_PAD, LINES) float32, through which
    the neighbouring hypotheses of the state are exchanged. The next step's costs, penalties and
    sums are loaded while the current step is computed.
    """
    pid = tl.program_id(0)
    d = tl.arange(0, N_PAD)[:, None]
    j = tl.arange(0, LINES)[None, :]
    # 64-bit index arithmetic: no overflow, and no overflow checks when interpreted.
    k = (pid * LINES + j).to(tl.int64) + line0
    line_ok = k < line0 + n_lines
    d_ok = d < n
    hw = tl.cast(h, tl.int64) * w
    d_off = d.to(tl.int64) * hw
    p1 = tl.load(p1_ptr)
    base = scratch_ptr + pid.to(tl.int64) * (N_PAD * LINES)
    here = base + d * LINES + j
    below = base + tl.maximum(d - 1, 0) * LINES + j  # the ends' missing neighbour is the hypothesis itself
    above = base + tl.minimum(d + 1, n - 1) * LINES + j
    # The pixel of every line at the first step, and the offset of one step along the path.
    if REVERSE:
        s0 = tl.cast(n_steps - 1, tl.int64)
    else:
        s0 = tl.cast(0, tl.int64)
    if HORIZONTAL:
        pix = k * w + s0
        delta = tl.cast(1, tl.int64)
    else:
        pix = s0 * w + k + SLOPE * s0
        delta = tl.cast(w + SLOPE, tl.int64)
    if REVERSE:
        delta = -delta
    x = k + SLOPE * s0  # the diagonals' column
    if SLOPE != 0:
        valid = line_ok & (x >= 0) & (x < w)
    else:
        valid = line_ok
    ok = valid & d_ok
    c_next = tl.load(cost_ptr + (d_off + pix), mask=ok, other=_BIG)
    pen_next = tl.load(pen_ptr + pix, mask=valid, other=0.0)
    if not FIRST:
        sum_next = tl.load(total_ptr + (d_off + pix), mask=ok, other=0.0)
    prev = tl.zeros([N_PAD, LINES], tl.float32)
    pmin = tl.zeros([1, LINES], tl.float32)
    step_of = j * 0  # the step as a (1, LINES) tensor: a mask of a scalar and a tensor fails interpreted
    for i in range(0, n_steps):
        c = c_next
        pen = pen_next
        if not FIRST:
            acc = sum_next
        at = pix
        at_ok = valid
        # The next step's loads, issued before this step's arithmetic (only the lines' pixels are
        # carried from step to step: whole tiles of addresses would not fit in registers).
        more = step_of + i < n_steps - 1
        pix += delta
        if SLOPE != 0:
            x += -SLOPE if REVERSE else SLOPE
            valid_next = line_ok & (x >= 0) & (x < w)
            ok = valid_next & d_ok
        else:
            valid_next = valid
        c_next = tl.load(cost_ptr + (d_off + pix), mask=ok & more, other=_BIG)
        pen_next = tl.load(pen_ptr + pix, mask=valid_next & more, other=0.0)
        if not FIRST:
            sum_next = tl.load(total_ptr + (d_off + pix), mask=ok & more, other=0.0)
        tl.store(here, prev)
        tl.debug_barrier()
        lower = tl.load(below)
        upper = tl.load(above)
        tl.debug_barrier()
        best = tl.minimum(prev, lower + p1)
        best = tl.minimum(best, upper + p1)
        best = tl.minimum(best, pmin + pen)
        cur = c + (best - pmin)
        if SLOPE != 0:
            cur = tl.where(valid, cur, 0.0)  # a line outside the image keeps its zero state
            valid = valid_next
        # The padded hypotheses cost _BIG and more: never the least.
        pmin = reduce_min(cur, 0)[None, :]
        if FIRST:
            tl.store(total_ptr + (d_off + at), cur, mask=at_ok & d_ok)
        else:
            tl.store(total_ptr + (d_off + at), acc + cur, mask=at_ok & d_ok)
        prev = cur


@jit
def select_kernel(total_ptr, raw_ptr, index_ptr, conf_ptr, n, hw, exclude, N_PAD: tl.constexpr, P: tl.constexpr):
    """Winner-take-all on ``total`` (n, h, w) with the sub-hypothesis parabola on ``raw`` at the
    winner and its neighbours, and the confidence: the distinctness of ``total`` times that of
    ``raw``'s own curve, as :func:`lfring.depth.sgm_kernels.select_index_both` computes them
    (a non-finite raw cost at the parabola's points takes the pixel's mean finite raw cost)."""
    pid = tl.program_id(0)
    d = tl.arange(0, N_PAD)[:, None]
    p = pid * P + tl.arange(0, P)
    inside = p < hw
    m = (d < n) & inside[None, :]
    offs = d.to(tl.int64) * hw + p[None, :]
    inf = float("inf")
    s = tl.load(total_ptr + offs, mask=m, other=inf)
    r = tl.load(raw_ptr + offs, mask=m, other=inf)
    best = reduce_min(s, 0)
    arg = reduce_min(tl.where(m & (s == best[None, :]), d, N_PAD), 0)
    away = m & (tl.abs(d - arg[None, :]) > exclude)
    second = reduce_min(tl.where(away, s, inf), 0)
    rbest = reduce_min(r, 0)
    # The first least raw cost (the first hypothesis where none is finite, as the reference).
    rarg = reduce_min(tl.where(m & (r == rbest[None, :]), d, N_PAD), 0)
    raway = m & (tl.abs(d - rarg[None, :]) > exclude)
    rsecond = reduce_min(tl.where(raway, r, inf), 0)
    finite = m & (tl.abs(r) < inf)
    count = reduce_sum(finite.to(tl.int32), 0)
    fill = reduce_sum(tl.where(finite, r.to(tl.float64), 0.0), 0)
    fill = tl.where(count > 0, fill / tl.maximum(count, 1).to(tl.float64), 0.0).to(tl.float32)
    # The raw costs at the winner and the two on either side of it.
    cm = reduce_min(tl.where(m & (d == arg[None, :] - 1), r, inf), 0)
    c0 = reduce_min(tl.where(m & (d == arg[None, :]), r, inf), 0)
    cp = reduce_min(tl.where(m & (d == arg[None, :] + 1), r, inf), 0)
    c2m = reduce_min(tl.where(m & (d == arg[None, :] - 2), r, inf), 0)
    c2p = reduce_min(tl.where(m & (d == arg[None, :] + 2), r, inf), 0)
    # Inside the range: the parabola through the three (unknown ones take the pixel's mean).
    fm = tl.where(tl.abs(cm) < inf, cm, fill).to(tl.float64)
    f0 = tl.where(tl.abs(c0) < inf, c0, fill).to(tl.float64)
    fp = tl.where(tl.abs(cp) < inf, cp, fill).to(tl.float64)
    den = fm - 2.0 * f0 + fp
    mid = tl.where(den > 0.0, tl.minimum(0.5, tl.maximum(-0.5, 0.5 * (fm - fp) / tl.where(den > 0.0, den, 1.0))), 0.0)
    # At an end: the vertex of the parabola through it and the next two inwards, at most 0.5
    # inwards (0 unless it curves up and all three are known).
    first = arg == 0
    inward = tl.where(first, 1.0, -1.0).to(tl.float64)
    e_end = c0.to(tl.float64)
    e_next = tl.where(first, cp, cm).to(tl.float64)
    e_after = tl.where(first, c2p, c2m).to(tl.float64)
    eden = e_end - 2.0 * e_next + e_after
    eok = (eden > 0.0) & (tl.abs(eden) < inf)
    e_off = inward * tl.minimum(0.5, tl.maximum(0.0, 1.0 + 0.5 * (e_end - e_after) / tl.where(eok, eden, 1.0)))
    end = tl.where(eok, e_off, 0.0)
    off = tl.where((arg > 0) & (arg < n - 1), mid, tl.where(arg * 0 + n >= 3, end, 0.0))
    index = (arg.to(tl.float64) + off).to(tl.float32)
    # The distinctness 1 - best / second of both curves (0 where undefined).
    sok = (tl.abs(best) < inf) & (tl.abs(second) < inf) & (second > 0.0)
    dist = tl.minimum(1.0, tl.maximum(0.0, 1.0 - best.to(tl.float64) / tl.where(sok, second, 1.0).to(tl.float64)))
    dist = tl.where(sok, dist, 0.0).to(tl.float32)
    rok = (tl.abs(rbest) < inf) & (tl.abs(rsecond) < inf) & (rsecond > 0.0)
    rdist = tl.minimum(1.0, tl.maximum(0.0, 1.0 - rbest.to(tl.float64) / tl.where(rok, rsecond, 1.0).to(tl.float64)))
    rdist = tl.where(rok, rdist, 0.0).to(tl.float32)
    known = tl.abs(best) < inf
    tl.store(index_ptr + p, tl.where(known, index, float("nan")), mask=inside)
    tl.store(conf_ptr + p, tl.where(known, dist * rdist, 0.0), mask=inside)


# -- the refinement ------------------------------------------------------------------------------
@jit
def median_kernel(values_ptr, bins_ptr, guide_ptr, lut_ptr, out_ptr, h, w, RADIUS: tl.constexpr, WIN: tl.constexpr,
                  P: tl.constexpr):
    """The weighted median of :func:`lfring.depth.refine_kernels.weighted_median`: per pixel with
    a bin (``bins >= 0``), of the known values of its (2 RADIUS + 1)^2 window (clipped at the
    image's edges), weighted by ``lut[|guide_p - guide_q|]``: the lowest bin of the window whose
    cumulative weight reaches half the window's, and the weighted mean of the values in it; NaN
    where the pixel has no bin. Sums in float32 (the reference's sums, float32 for windows of at most
    two adjacent bins and float64 for the others, decide the same bin but where the weights below
    it make half to within float32 rounding). ``WIN`` >= (2 RADIUS + 1)^2, a power of two."""
    pid = tl.program_id(0)
    hw = h * w
    p = pid * P + tl.arange(0, P)
    inside = p < hw
    y = p // w
    x = p % w
    side = 2 * RADIUS + 1
    q = tl.arange(0, WIN)[None, :]
    qy = y[:, None] + q // side - RADIUS
    qx = x[:, None] + q % side - RADIUS
    qok = inside[:, None] & (q < side * side) & (qy >= 0) & (qy < h) & (qx >= 0) & (qx < w)
    qoff = qy * w + qx
    qbin = tl.load(bins_ptr + qoff, mask=qok, other=-1)
    qval = tl.load(values_ptr + qoff, mask=qok, other=0.0)
    gq = tl.load(guide_ptr + qoff, mask=qok, other=0).to(tl.int32)
    pbin = tl.load(bins_ptr + p, mask=inside, other=-1)
    gp = tl.load(guide_ptr + p, mask=inside, other=0).to(tl.int32)
    known = qok & (qbin >= 0)
    wq = tl.load(lut_ptr + tl.abs(gq - gp[:, None]), mask=known, other=0.0)
    half = 0.5 * reduce_sum(wq, 1)
    # The median's bin: the least window bin whose cumulative weight reaches half.
    pick = tl.full([P], 2147483647, tl.int32)
    for t in range(0, side * side):
        ty = y + t // side - RADIUS
        tx = x + t % side - RADIUS
        tok = inside & (ty >= 0) & (ty < h) & (tx >= 0) & (tx < w)
        tbin = tl.load(bins_ptr + ty * w + tx, mask=tok, other=-1)
        below = reduce_sum(tl.where(qbin <= tbin[:, None], wq, 0.0), 1)
        take = tok & (tbin >= 0) & (below >= half)
        pick = tl.where(take, tl.minimum(pick, tbin), pick)
    inbin = known & (qbin == pick[:, None])
    hf = reduce_sum(tl.where(inbin, wq, 0.0), 1)
    hv = reduce_sum(tl.where(inbin, wq * qval, 0.0), 1)
    own = tl.load(values_ptr + p, mask=inside, other=0.0)
    out = tl.where(hf > 0.0, hv / tl.where(hf > 0.0, hf, 1.0), own)
    tl.store(out_ptr + p, tl.where(pbin >= 0, out, float("nan")), mask=inside)


@jit
def fgs_kernel(coef_ptr, x_ptr, inter_ptr, n_lines, n_steps, stride_line, stride_step, image_stride,
               IMAGES: tl.constexpr, COLUMNS: tl.constexpr, LINES: tl.constexpr):
    """One pass of OpenCV's fast global smoother (``cv2.ximgproc.createFastGlobalSmootherFilter``)
    over ``IMAGES`` (a power of two) images at ``x`` (``image_stride`` apart), in place: along each
    line (a row or a column, ``stride_line`` apart, ``stride_step`` between neighbours) the
    tridiagonal system with off-diagonals ``coef`` (lambda times the negative weight towards the
    next pixel, 0 at the line's end) and diagonal ``1 - coef_prev - coef``, solved by the Thomas
    algorithm; ``inter`` holds the elimination's factors (the images share them). ``COLUMNS``:
    the lines are columns, whose pivots OpenCV sums in another order than the rows'. Every buffer
    has a line of slack before and after it: the next step's values are loaded (unmasked) while
    the current one is computed."""
    pid = tl.program_id(0)
    line = pid * LINES + tl.arange(0, LINES)[None, :]
    ok = line < n_lines
    at = line.to(tl.int64) * stride_line
    # Pointers carried from step to step (one add each per step).
    cp = coef_ptr + at
    ip = inter_ptr + at
    xp = x_ptr + tl.arange(0, IMAGES)[:, None].to(tl.int64) * image_stride + at
    a_prev = tl.load(cp, mask=ok, other=0.0)
    inter = a_prev / (1.0 - a_prev)
    tl.store(ip, inter, mask=ok)
    x = tl.load(xp, mask=ok, other=0.0) / (1.0 - a_prev)
    tl.store(xp, x, mask=ok)
    cp += stride_step
    ip += stride_step
    xp += stride_step
    a_next = tl.load(cp, mask=ok, other=0.0)
    x_next = tl.load(xp, mask=ok, other=0.0)
    for s in range(1, n_steps):
        a_cur = a_next
        v = x_next
        i_here = ip
        x_here = xp
        cp += stride_step
        ip += stride_step
        xp += stride_step
        a_next = tl.load(cp, mask=ok, other=0.0)  # the next step's (slack past the line's end)
        x_next = tl.load(xp, mask=ok, other=0.0)
        if COLUMNS:
            denom = 1.0 - ((a_prev + a_cur) + inter * a_prev)
        else:
            denom = (1.0 - (a_cur + a_prev)) - inter * a_prev
        inter = a_cur / denom
        tl.store(i_here, inter, mask=ok)
        x = (v - x * a_prev) / denom
        tl.store(x_here, x, mask=ok)
        a_prev = a_cur
    ip -= 2 * stride_step
    xp -= 2 * stride_step
    f_next = tl.load(ip, mask=ok, other=0.0)
    v_next = tl.load(xp, mask=ok, other=0.0)
    for s in range(1, n_steps):
        f = f_next
        v = v_next
        x_here = xp
        ip -= stride_step
        xp -= stride_step
        f_next = tl.load(ip, mask=ok, other=0.0)  # the next step's (slack before the line's start)
        v_next = tl.load(xp, mask=ok, other=0.0)
        x = v - f * x
        tl.store(x_here, x, mask=ok)
