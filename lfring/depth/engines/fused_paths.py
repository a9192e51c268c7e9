"""The scan paths and the selection of the fused semi-global passes (see
:mod:`lfring.depth.engines.fused`):

1. :func:`horizontal_paths`: per row (or block of rows side by side, for few hypotheses), the
   volume eroded (shiftable windows) and the left-right and right-left scan paths, summed into
   a uint16 accumulator in tiles of columns (:func:`tile_shape`); the eroded volume is kept, in
   the same tiles, for the next pass where the caller gives it a buffer.
2. :func:`vertical_paths`: per tile of columns, the top-down path, then the bottom-up one, at
   whose every pixel the sum of the paths is complete: the winner, its parabola on the wider box
   of the cost and the confidence are taken there, and the sum is never written back. Without
   the kept eroded volume each direction erodes its rows again.

The vertical pass runs a block of columns per thread, row after row. In the (h, N, w) layout of
the cost volume a block's part of a row is N pieces scattered over the row's N * w values, and
streaming such pieces from memory ran several times slower than whole rows (see
benchmarks/RESULTS.md). The horizontal paths' sums and the eroded volume, which that pass reads at
every row, are therefore laid out (h, tiles, N, block): a block's part of a row is one contiguous
run.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from lfring.depth.aggregation_kernels import reflect
from lfring.depth.engines.fused_common import COST_ZERO, INLINE, JIT, ONE_PASS_MIN_WIDTH, PARALLEL, PENALTY_MAX, UNKNOWN

__all__ = ["horizontal_paths", "tile_shape", "untiled", "vertical_paths"]

# The horizontal paths of a few hypotheses run rows side by side: a pixel's step over its own
# hypotheses is too short to vectorise, and its least is a serial reduction per pixel. Reordering
# the costs pixel-outermost costs a scattered copy per cost, which pays up to about 16
# hypotheses (see benchmarks/RESULTS.md); blocks of 32 rows, 32 columns of costs at a time.
SIDE_BY_SIDE_HYPOTHESES = 16
SIDE_BY_SIDE_ROWS = 32
SIDE_BY_SIDE_COLUMNS = 32
# The ends of a padded path state (:func:`_chain_step`): with p1 added it stays above any jump
# (a path's least plus a penalty, fused_common) and within int16.
PAD = 32767 - PENALTY_MAX
# The widest box of the selection's raw cost whose column sums are summed from sums over 2 and 4
# columns (:func:`_raw_rows`): three sums of 4, one of 2 and one column.
QUAD_WINDOW_MAX_PX = 15


def tile_shape(h: int, n: int, w: int, block: int) -> tuple:
    """The shape (h, tiles, N, block) of a volume of h rows, N hypotheses and w columns laid out in
    tiles of ``block`` columns (the last one may reach past the image; its extra columns are never
    read)."""
    return (h, -(-w // block), n, block)


@njit(**INLINE)
def _check_tiles(total, vol):
    """Raise unless ``total`` is laid out as :func:`tile_shape` lays out a volume of ``vol``'s
    shape (the passes index it unchecked)."""
    h, n, w = vol.shape
    t, b = total.shape[1], total.shape[3]
    if not (total.shape[0] == h and total.shape[2] == n and b > 0 and (t - 1) * b < w <= t * b):
        raise ValueError("the paths' sums are not in tiles of the cost volume's shape (fused_paths.tile_shape)")


def untiled(tiles: np.ndarray, w: int) -> np.ndarray:
    """The (h, N, w) volume of ``tiles`` (:func:`tile_shape`), a copy."""
    h, t, n, b = tiles.shape
    return np.ascontiguousarray(tiles.transpose(0, 2, 1, 3).reshape(h, n, t * b)[:, :, :w])


@njit(**INLINE)
def _copy(row, out):
    """out = row, by a loop: numba's slice assignment first checks the two for overlap and runs
    several times slower on these short rows."""
    for x in range(out.shape[0]):
        out[x] = row[x]


@njit(**INLINE)
def _min_into(row, out):
    for x in range(out.shape[0]):
        out[x] = min(out[x], row[x])


@njit(**JIT)
def _eroded_rows(vol, y, rad, x0, x1, ext, out):
    """out (N, x1 - x0) = the least of ``vol`` (h, N, w) over rows y - rad .. y + rad and columns
    x - rad .. x + rad (clipped at the image's edges, as a replicated border), for columns x0..x1;
    ``ext`` a scratch row of x1 - x0 + 2 rad values."""
    h, n, w = vol.shape
    m = x1 - x0
    r0 = max(0, y - rad)
    r1 = min(h, y + rad + 1)
    c0 = max(0, x0 - rad)
    c1 = min(w, x1 + rad)
    lo = c0 - (x0 - rad)  # columns of ext before the image's first (replicated)
    # The default 5-pixel window in one pass a direction (the least of five values: the same
    # in any order), one store a value instead of five.
    five = rad == 2 and m >= ONE_PASS_MIN_WIDTH
    for d in range(n):
        cm = ext[lo:lo + c1 - c0]
        if five and r1 - r0 == 5:
            _min_of_five(vol[r0, d, c0:c1], vol[r0 + 1, d, c0:c1], vol[r0 + 2, d, c0:c1], vol[r0 + 3, d, c0:c1],
                         vol[r0 + 4, d, c0:c1], cm)
        else:
            _copy(vol[r0, d, c0:c1], cm)
            for r in range(r0 + 1, r1):
                _min_into(vol[r, d, c0:c1], cm)
        for j in range(lo):
            ext[j] = ext[lo]
        for j in range(lo + c1 - c0, m + 2 * rad):
            ext[j] = ext[lo + c1 - c0 - 1]
        o = out[d]
        if five:
            _min_of_five(ext[0:m], ext[1:m + 1], ext[2:m + 2], ext[3:m + 3], ext[4:m + 4], o)
            continue
        _copy(ext[0:m], o)
        for k in range(1, 2 * rad + 1):
            _min_into(ext[k:k + m], o)


@njit(**INLINE)
def _min_of_five(a, b, c, d, e, out):
    """out = the least of five rows, value by value."""
    for x in range(out.shape[0]):
        out[x] = min(min(min(a[x], b[x]), min(c[x], d[x])), e[x])


@njit(**JIT)
def _fill_unknown(e, fill):
    """Each column's unknown costs replaced by the mean of its known ones (0 when none is)."""
    n, m = e.shape
    # int32 sums (N uint16 costs fit while N < 32768): int64 would halve the vectors' lanes.
    total = np.zeros(m, np.int32)
    count = np.zeros(m, np.int32)
    for d in range(n):
        row = e[d]
        for x in range(m):
            known = row[x] != UNKNOWN
            total[x] = np.int32(total[x] + (np.int32(row[x]) if known else np.int32(0)))
            count[x] = np.int32(count[x] + (np.int32(1) if known else np.int32(0)))
    missing = False
    for x in range(m):
        c = count[x]
        fill[x] = (total[x] + c // 2) // c if c > 0 else 0
        missing |= c < n
    if not missing:
        return
    for d in range(n):
        row = e[d]
        for x in range(m):
            row[x] = np.uint16(fill[x]) if row[x] == UNKNOWN else row[x]


@njit(**INLINE)
def _p2_between(a, b, use_guide, p1, p2, edge_scale):
    """The large-jump penalty between neighbours with guide values a and b, as an integer: ``p2``
    cut by the guide's step (never below ``p1``), rounded."""
    v = np.float32(p2)
    if use_guide:
        v = np.float32(p2) / (np.float32(1.0) + abs(a - b) / np.float32(edge_scale))
        v = v if v > np.float32(p1) else np.float32(p1)
    return np.int32(v + np.float32(0.5))


@njit(**INLINE)
def _p2_row(guide_a, guide_b, use_guide, p1, p2, edge_scale, out):
    """:func:`_p2_between` of every pair of neighbours ``guide_a[x]``, ``guide_b[x]``."""
    for x in range(out.shape[0]):
        out[x] = _p2_between(guide_a[x], guide_b[x], use_guide, p1, p2, edge_scale)


@njit(**INLINE)
def _step_line(src, k, x0, prev, cur, pmin, cmin, p1, p2e):
    """One step of a path along a line of pixels processed side by side: the costs (N, m) are
    ``src[k, :, x0:x0 + m]`` (read in place: a copy first cost as much as the step), ``prev``
    the previous pixels' path values (N, m), ``pmin`` their least, ``p2e`` the large-jump
    penalties; writes ``cur`` and its least ``cmin``."""
    n, m = prev.shape
    p1s = np.int16(p1)
    for x in range(m):
        cmin[x] = 32767  # int16's largest
    for d in range(n):
        dm = d - 1 if d > 0 else d
        dp = d + 1 if d < n - 1 else d
        here = prev[d]
        below = prev[dm]
        above = prev[dp]
        cost = src[k, d, x0:x0 + m]
        out = cur[d]
        least = cmin
        # int16 path values (fused_common: they stay below 2**15), every sum cast back: numba
        # widens integer arithmetic to int64, which would cut the vectorised loop's lanes.
        for x in range(m):
            best = here[x]
            t = np.int16(below[x] + p1s)
            best = t if t < best else best
            t = np.int16(above[x] + p1s)
            best = t if t < best else best
            t = np.int16(pmin[x] + p2e[x])
            best = t if t < best else best
            v = np.int16(np.int16(cost[x]) + best - pmin[x])
            out[x] = v
            least[x] = v if v < least[x] else least[x]


@njit(**INLINE)
def _next_step(src, k, x0, state, mins, p2e, i, p1):
    """Step ``i`` of lines of paths side by side (:func:`_step_line` on the costs
    ``src[k, :, x0:x0 + m]``), their values and least ping-ponging in ``state`` (2, N, m) and
    ``mins`` (2, m) by the step's parity; ``p2e`` holds the step's large-jump penalties, except
    at the first step, which takes its cost alone (zero state and penalties). Returns the step's
    values (N, m)."""
    prev = state[(i + 1) % 2]
    cur = state[i % 2]
    pmin = mins[(i + 1) % 2]
    if i == 0:
        prev[:] = 0
        pmin[:] = 0
        p2e[:] = 0
    _step_line(src, k, x0, prev, cur, pmin, mins[i % 2], p1, p2e)
    return cur


@njit(**INLINE)
def _chain_step(c, prev, cur, pmin, jump, p1):
    """One step of a path at one pixel: ``cur = c + min(prev, prev[d -+ 1] + p1, jump) - pmin``
    over the hypotheses; returns the least of ``cur``. ``prev`` and ``cur`` hold hypothesis d at
    d + 1, between two :data:`PAD` ends: the ends' missing neighbour never wins, as if it were
    the hypothesis itself. int16 throughout, as in :func:`_step_line`."""
    least = np.int16(32767)
    for d in range(c.shape[0]):
        best = min(min(prev[d + 1], np.int16(prev[d] + p1)), min(np.int16(prev[d + 2] + p1), jump))
        v = np.int16(c[d] + best - pmin)
        cur[d + 1] = v
        least = min(least, v)
    return least


@njit(**INLINE)
def _kept(eroded, total):
    """Whether ``eroded`` is a volume in the tiles of ``total`` (not the empty stand-in)."""
    return eroded.shape == total.shape


@njit(**INLINE)
def _put_tiles(row, out):
    """out (tiles, N, block) = row (N, w) cut into its tiles."""
    t, n, b = out.shape
    w = row.shape[1]
    for k in range(t):
        x0 = k * b
        m = min(w, x0 + b) - x0
        for d in range(n):
            _copy(row[d, x0:x0 + m], out[k, d, :m])


@njit(**INLINE)
def _start_chain(cx, cur):
    """The first step of a path: its cost alone (``cur`` padded as in :func:`_chain_step`);
    returns its least."""
    least = np.int16(32767)
    for d in range(cx.shape[0]):
        cur[d + 1] = cx[d]
        least = min(least, cx[d])
    return least


@njit(**INLINE)
def _into_sums(acc, cur, add):
    """acc = cur (its padded hypotheses), or acc += cur where ``add``."""
    if add:
        for d in range(acc.shape[0]):
            acc[d] += cur[d + 1]
    else:
        for d in range(acc.shape[0]):
            acc[d] = cur[d + 1]


@njit(**JIT)
def _horizontal_rows(vol, y, y2, guide, use_guide, p1, p2, edge_scale, erode_rad, total, eroded):
    """The two horizontal paths of rows ``y`` and ``y2`` (``y2 == y``: row ``y`` alone; see
    :func:`horizontal_paths`)."""
    h, n, w = vol.shape
    pair = y2 != y
    ext = np.empty(w + 2 * erode_rad, np.uint16)
    fill = np.empty(w, np.int64)
    # One pixel per step: its N costs side by side, gathered pixel by pixel (about twice as fast
    # as numba's copy of the transposed view, and faster than 8 x 8 tiles: benchmarks/RESULTS.md).
    c = np.empty((2, w, n), np.int16)
    e = np.empty((n, w), np.uint16)
    kept = _kept(eroded, total)
    for r in range(2 if pair else 1):
        yy = y if r == 0 else y2
        _eroded_rows(vol, yy, erode_rad, 0, w, ext, e)
        _fill_unknown(e, fill)
        cr = c[r]
        for x in range(w):
            px = cr[x]
            for d in range(n):
                px[d] = np.int16(e[d, x])
        if kept:
            _put_tiles(e, eroded[yy])
    # A step's least over the hypotheses is a serial chain from one pixel to the next: the
    # left-right and right-left paths of both rows (four independent chains) run step by step
    # together, so that one chain's reduction overlaps the others' arithmetic.
    acc = np.empty((2, w, n), np.int16)
    state = np.full((2, 4, n + 2), PAD, np.int16)
    p1 = np.int16(p1)
    m0 = m1 = m2 = m3 = np.int16(0)
    gy2 = guide[y2]
    for i in range(w):
        xa = i
        xb = w - 1 - i
        prev = state[(i + 1) % 2]
        cur = state[i % 2]
        if i == 0:
            m0 = _start_chain(c[0, xa], cur[0])
            m1 = _start_chain(c[0, xb], cur[1])
            if pair:
                m2 = _start_chain(c[1, xa], cur[2])
                m3 = _start_chain(c[1, xb], cur[3])
        else:
            ea = _p2_between(guide[y, xa], guide[y, xa - 1], use_guide, p1, p2, edge_scale)
            eb = _p2_between(guide[y, xb], guide[y, xb + 1], use_guide, p1, p2, edge_scale)
            m0, m1 = (_chain_step(c[0, xa], prev[0], cur[0], m0, np.int16(m0 + ea), p1),
                      _chain_step(c[0, xb], prev[1], cur[1], m1, np.int16(m1 + eb), p1))
            if pair:
                ea = _p2_between(gy2[xa], gy2[xa - 1], use_guide, p1, p2, edge_scale)
                eb = _p2_between(gy2[xb], gy2[xb + 1], use_guide, p1, p2, edge_scale)
                m2, m3 = (_chain_step(c[1, xa], prev[2], cur[2], m2, np.int16(m2 + ea), p1),
                          _chain_step(c[1, xb], prev[3], cur[3], m3, np.int16(m3 + eb), p1))
        # The first path to reach a pixel writes its sum, the second adds to it (in the middle
        # of an odd row both reach it at once: left-right first).
        later = 2 * i > w - 1
        _into_sums(acc[0, xa], cur[0], later)
        _into_sums(acc[0, xb], cur[1], later or 2 * i == w - 1)
        if pair:
            _into_sums(acc[1, xa], cur[2], later)
            _into_sums(acc[1, xb], cur[3], later or 2 * i == w - 1)
    _put_sums(acc[0], total[y])
    if pair:
        _put_sums(acc[1], total[y2])


@njit(**INLINE)
def _put_sums(acc, out):
    """out (tiles, N, block) uint16 = acc (w, N) int16 transposed into its tiles: the sums fit in
    16 bits (fused_common). An explicit loop, a row of a tile at a time: numba's assignment of a
    transposed view runs several times slower."""
    w, n = acc.shape
    t, _, b = out.shape
    for k in range(t):
        x0 = k * b
        part = acc[x0:min(w, x0 + b)]  # sliced first: an index x0 + x would not vectorise
        for d in range(n):
            row = out[k, d]
            for x in range(part.shape[0]):
                row[x] = np.uint16(part[x, d])


@njit(**JIT)
def _horizontal_block(vol, y0, y1, guide, use_guide, p1, p2, edge_scale, erode_rad, total, eroded, chunk):
    """The two horizontal paths of rows y0..y1 side by side, as the vertical pass runs its
    columns (see :func:`horizontal_paths`), ``chunk`` columns of costs at a time."""
    _, n, w = vol.shape
    b = y1 - y0
    tw = total.shape[3]
    kept = _kept(eroded, total)
    block = np.empty((b, n, w), np.uint16)
    ext = np.empty(w + 2 * erode_rad, np.uint16)
    fill = np.empty(w, np.int64)
    for r in range(b):
        _eroded_rows(vol, y0 + r, erode_rad, 0, w, ext, block[r])
        _fill_unknown(block[r], fill)
        if kept:
            _put_tiles(block[r], eroded[y0 + r])
    # A chunk of the rows' costs with the pixel outermost: t[j] (N, b) is one step of the b
    # paths; acc the chunk's path values, in the same order.
    t = np.empty((chunk, n, b), np.int16)
    acc = np.empty((chunk, n, b), np.int16)
    state = np.empty((2, n, b), np.int16)  # zeroed by the first step (_next_step), as mins and p2e
    mins = np.empty((2, b), np.int16)
    p2e = np.empty(b, np.int16)
    ga = np.empty(b, np.float32)
    gb = np.empty(b, np.float32)
    n_chunks = (w + chunk - 1) // chunk
    for direction in range(2):
        i = 0
        for kc in range(n_chunks):
            c = kc if direction == 0 else n_chunks - 1 - kc
            c0 = c * chunk
            m = min(w, c0 + chunk) - c0
            for r in range(b):
                for d in range(n):
                    src = block[r, d, c0:c0 + m]
                    for j in range(m):
                        t[j, d, r] = src[j]
            for jj in range(m):
                j = jj if direction == 0 else m - 1 - jj
                x = c0 + j
                if i > 0:
                    xp = x - 1 if direction == 0 else x + 1
                    for r in range(b):
                        ga[r] = guide[y0 + r, x]
                        gb[r] = guide[y0 + r, xp]
                    _p2_row(ga, gb, use_guide, p1, p2, edge_scale, p2e)
                acc[j] = _next_step(t, j, 0, state, mins, p2e, i, p1)
                i += 1
            # The chunk's columns by the tiles they lie in (a chunk may straddle two).
            xs = c0
            while xs < c0 + m:
                k = xs // tw
                xe = min(c0 + m, (k + 1) * tw)
                for r in range(b):
                    for d in range(n):
                        out = total[y0 + r, k, d, xs - k * tw:xe - k * tw]
                        a = acc[xs - c0:xe - c0, d, r]
                        if direction == 0:
                            for j in range(xe - xs):
                                out[j] = np.uint16(a[j])
                        else:
                            for j in range(xe - xs):
                                out[j] = np.uint16(np.int32(out[j]) + np.int32(a[j]))  # fits (fused_common)
                xs = xe


@njit(**PARALLEL)
def horizontal_paths(vol, guide, use_guide, p1, p2, edge_scale, erode_rad, total, eroded):
    """The left-right and right-left paths of every row of the eroded volume: ``total`` uint16 in
    tiles (:func:`tile_shape`; they set the blocks of :func:`vertical_paths`) = their sum.
    ``eroded``: a uint16 buffer in the same tiles that receives the eroded volume (its unknown
    costs filled) for :func:`vertical_paths`, or an empty 4-d array.

    Up to :data:`SIDE_BY_SIDE_HYPOTHESES` hypotheses, blocks of :data:`SIDE_BY_SIDE_ROWS` rows
    run side by side (one step of all their paths at a time, vectorised across the rows, after
    the costs are reordered pixel-outermost); with more, rows run in pairs (the four paths' steps
    interleaved), a step vectorised across its hypotheses."""
    h, n, _ = vol.shape
    _check_tiles(total, vol)
    if n <= SIDE_BY_SIDE_HYPOTHESES:
        for k in prange((h + SIDE_BY_SIDE_ROWS - 1) // SIDE_BY_SIDE_ROWS):
            _horizontal_block(vol, k * SIDE_BY_SIDE_ROWS, min(h, (k + 1) * SIDE_BY_SIDE_ROWS), guide, use_guide, p1, p2,
                              edge_scale, erode_rad, total, eroded, SIDE_BY_SIDE_COLUMNS)
    else:
        for k in prange((h + 1) // 2):
            _horizontal_rows(vol, 2 * k, min(2 * k + 1, h - 1), guide, use_guide, p1, p2, edge_scale, erode_rad, total,
                             eroded)


@njit(**INLINE)
def _inside(x0, m, rad, w):
    """For the columns x0 - rad .. x0 + m + rad of a row of ``w``: the first one ``a`` and the
    positions lo..hi among them that lie inside the row (the others are reflected)."""
    a = x0 - rad
    return a, max(0, -a), min(m + 2 * rad, w - a)


@njit(**INLINE)
def _ext_row(row, x0, m, rad, out):
    """out[j] = row[reflect(x0 - rad + j)] for j < m + 2 rad (BORDER_REFLECT_101)."""
    w = row.shape[0]
    a, lo, hi = _inside(x0, m, rad, w)
    _copy(row[a + lo:a + hi], out[lo:hi])
    for j in range(lo):
        out[j] = row[reflect(a + j, w)]
    for j in range(hi, m + 2 * rad):
        out[j] = row[reflect(a + j, w)]


@njit(**INLINE)
def _raw_update(vol, r, d, x0, m, rad, ext, col_sum, col_cnt):
    """col_sum, col_cnt += (known cost, 1) of row ``r`` of hypothesis ``d``."""
    _ext_row(vol[r, d], x0, m, rad, ext)
    for j in range(m + 2 * rad):
        v, k = _known_cost(ext[j])
        col_sum[j] = np.int32(col_sum[j] + v)
        col_cnt[j] = np.int32(col_cnt[j] + k)


@njit(**INLINE)
def _parabola(cm, c0, cp):
    den = np.float64(cm) - 2.0 * np.float64(c0) + np.float64(cp)
    if den > 0.0:
        return min(0.5, max(-0.5, 0.5 * (np.float64(cm) - np.float64(cp)) / den))
    return 0.0


@njit(**INLINE)
def _end_offset(c_end, c_next, c_after, inward):
    den = c_end - 2.0 * c_next + c_after
    if den > 0.0 and np.isfinite(den):
        return inward * min(0.5, max(0.0, 1.0 + 0.5 * (c_end - c_after) / den))
    return 0.0


@njit(**INLINE)
def _distinctness(b, s):
    if np.isfinite(b) and np.isfinite(s) and s > 0.0:
        return np.float32(min(1.0, max(0.0, 1.0 - np.float64(b) / np.float64(s))))
    return np.float32(0.0)


@njit(**JIT)
def _vertical_block(vol, eroded, total, guide, use_guide, p1, p2, edge_scale, erode_rad, raw_rad, exclude, floor, tile,
                    index, conf):
    """The two vertical paths and the selection of the columns of tile ``tile`` (see
    :func:`vertical_paths`)."""
    h, n, w = vol.shape
    tw = total.shape[3]
    kept = _kept(eroded, total)
    x0 = tile * tw
    x1 = min(w, x0 + tw)
    m = x1 - x0
    e = np.empty((1, n, m), np.uint16)  # the eroded row where it is not kept
    ext = np.empty(m + 2 * max(erode_rad, raw_rad), np.uint16)
    fill = np.empty(m, np.int64)
    state = np.empty((2, n, m), np.int16)  # zeroed by the first step (_next_step), as mins and p2e
    mins = np.empty((2, m), np.int16)
    p2e = np.empty(m, np.int16)
    col_sum = np.zeros((n, m + 2 * raw_rad), np.int32)
    col_cnt = np.zeros((n, m + 2 * raw_rad), np.int32)
    raw = np.empty((n, m), np.float32)
    box_scratch = np.zeros((5, m + 2 * raw_rad), np.int32)
    for direction in range(2):
        for i in range(h):
            y = i if direction == 0 else h - 1 - i
            if not kept:
                _eroded_rows(vol, y, erode_rad, x0, x1, ext, e[0])
                _fill_unknown(e[0], fill)
            if i > 0:
                yp = y - 1 if direction == 0 else y + 1
                _p2_row(guide[y, x0:x1], guide[yp, x0:x1], use_guide, p1, p2, edge_scale, p2e)
            if kept:
                cur = _next_step(eroded[y], tile, 0, state, mins, p2e, i, p1)
            else:
                cur = _next_step(e, 0, 0, state, mins, p2e, i, p1)
            if direction == 0:
                for d in range(n):
                    row = total[y, tile, d, :m]
                    cr = cur[d]
                    for x in range(m):
                        row[x] = np.uint16(np.int32(row[x]) + cr[x])
                continue
            # The wider box's column sums over rows y - raw_rad .. y + raw_rad (reflected), kept
            # running from row to row upwards.
            for d in range(n):
                if i == 0:
                    col_sum[d] = 0
                    col_cnt[d] = 0
                    for k in range(y - raw_rad, y + raw_rad + 1):
                        _raw_update(vol, reflect(k, h), d, x0, m, raw_rad, ext, col_sum[d], col_cnt[d])
                else:
                    _raw_move(vol, reflect(y - raw_rad, h), reflect(y + raw_rad + 1, h), d, x0, m, raw_rad, col_sum[d],
                              col_cnt[d])
            _select_row(vol, total[y, tile], cur, y, x0, x1, raw_rad, exclude, floor, col_sum, col_cnt, box_scratch, raw,
                        index, conf)


@njit(**PARALLEL)
def vertical_paths(vol, eroded, total, guide, use_guide, p1, p2, edge_scale, erode_rad, raw_rad, exclude, floor, index,
                   conf):
    """The top-down and bottom-up paths of every tile of columns of the horizontal paths' ``total``
    (:func:`tile_shape`; one tile per parallel task), added to it; at every pixel of the bottom-up
    pass the winner of the sum, its sub-hypothesis offset from the parabola through the wider
    box's mean known cost ('raw') at the winner and its neighbours, and the confidence (the sum's
    distinctness times the raw curve's): ``index`` and ``conf`` (h, w) float32. ``eroded``: the eroded volume
    :func:`horizontal_paths` kept (in ``total``'s tiles), or an empty 4-d array (each row is
    eroded again)."""
    _check_tiles(total, vol)
    for k in prange(total.shape[1]):
        _vertical_block(vol, eroded, total, guide, use_guide, p1, p2, edge_scale, erode_rad, raw_rad, exclude, floor, k,
                        index, conf)


@njit(**INLINE)
def _known_cost(v):
    """(cost, 1) as int32 where ``v`` is known, (0, 0) where it is UNKNOWN."""
    known = v != UNKNOWN
    return (np.int32(v) if known else np.int32(0)), (np.int32(1) if known else np.int32(0))


@njit(**INLINE)
def _raw_move(vol, r_in, r_out, d, x0, m, rad, col_sum, col_cnt):
    """col_sum, col_cnt += the (known cost, 1) of row ``r_in`` minus those of row ``r_out``, of
    hypothesis ``d`` over the columns x0 - rad .. x0 + m + rad (reflected at the image's sides):
    the window's step down one row in one pass over the sums, reading the rows in place."""
    w = vol.shape[2]
    a, lo, hi = _inside(x0, m, rad, w)
    new = vol[r_in, d]
    old = vol[r_out, d]
    ni = new[a + lo:a + hi]
    oi = old[a + lo:a + hi]
    cs = col_sum[lo:hi]
    cc = col_cnt[lo:hi]
    for j in range(hi - lo):
        _move_column(ni, oi, j, j, cs, cc)
    for j in range(lo):
        _move_column(new, old, reflect(a + j, w), j, col_sum, col_cnt)
    for j in range(hi, m + 2 * rad):
        _move_column(new, old, reflect(a + j, w), j, col_sum, col_cnt)


@njit(**INLINE)
def _move_column(new, old, x, j, col_sum, col_cnt):
    """col_sum[j], col_cnt[j] += the (known cost, 1) of new[x] minus those of old[x]."""
    vn, kn = _known_cost(new[x])
    vo, ko = _known_cost(old[x])
    col_sum[j] = np.int32(col_sum[j] + vn - vo)
    col_cnt[j] = np.int32(col_cnt[j] + kn - ko)


@njit(**INLINE)
def _pair_sums(src, span, dst):
    """dst[x] = src[x] + src[x + span] wherever both lie in ``src`` (a pass that vectorises)."""
    n_out = src.shape[0] - span
    a = src[:n_out]
    b = src[span:span + n_out]
    for x in range(n_out):
        dst[x] = np.int32(a[x] + b[x])


@njit(**INLINE)
def _window_terms(col, width, m, two, four, zero):
    """Five rows whose sum at x < m is col[x] + ... + col[x + width - 1] (``width`` at most
    :data:`QUAD_WINDOW_MAX_PX`, col's length m + width - 1): up to three sums over 4 columns, one
    over 2 and one column, ``zero`` for each that the width leaves out. ``two`` and ``four``
    receive col's sums over 2 and 4 consecutive columns."""
    n = col.shape[0]
    _pair_sums(col, 1, two)
    _pair_sums(two[:n - 1], 2, four)
    q = width // 4
    o2 = 4 * q
    o1 = o2 + (2 if width & 2 else 0)
    return (four[0:m] if q > 0 else zero[:m], four[4:4 + m] if q > 1 else zero[:m], four[8:8 + m] if q > 2 else zero[:m],
            two[o2:o2 + m] if width & 2 else zero[:m], col[o1:o1 + m] if width & 1 else zero[:m])


@njit(**INLINE)
def _box_mean(total, known, centre, inv_area, floor):
    """The mean known cost of a box (``total`` over ``known`` pixels), inf where the ``centre`` is
    unknown: the share of known pixels floored at ``floor``, as the seen-pixel mean of the
    reference."""
    share = np.float32(known) * inv_area
    share = share if share > floor else floor
    return np.float32(total) * inv_area / share if centre != UNKNOWN else np.float32(np.inf)


@njit(**JIT)
def _raw_rows(col_sum, col_cnt, vol, y, x0, rad, floor, scratch, sums, counts, raw):
    """raw[d, x] = :func:`_box_mean` of the box around column x0 + x of row ``y`` for hypothesis d
    (its column sums ``col_sum[d]``, ``col_cnt[d]``; the centre ``vol[y, d, x0 + x]``).
    ``sums``, ``counts``: int32 scratch rows of raw's width; ``scratch`` (5, the column sums'
    length) int32, its last row zeros.

    A box up to :data:`QUAD_WINDOW_MAX_PX` wide sums its columns from their sums over 2 and 4
    (passes that vectorise, and one loop over the five terms and the divisions); a wider one by a
    running sum along the row, a serial chain of integer adds that does not vectorise. Integer
    sums: the same values either way. (One call a row: a call per hypothesis costs more than
    the sums.)"""
    n, m = raw.shape
    width = 2 * rad + 1
    inv_area = np.float32(1.0 / (width * width))
    for d in range(n):
        centre = vol[y, d, x0:x0 + m]
        out = raw[d]
        if width <= QUAD_WINDOW_MAX_PX:
            s0, s1, s2, s3, s4 = _window_terms(col_sum[d], width, m, scratch[0], scratch[1], scratch[4])
            c0, c1, c2, c3, c4 = _window_terms(col_cnt[d], width, m, scratch[2], scratch[3], scratch[4])
            for x in range(m):
                total = np.int32(s0[x] + s1[x] + s2[x] + s3[x] + s4[x])
                known = np.int32(c0[x] + c1[x] + c2[x] + c3[x] + c4[x])
                out[x] = _box_mean(total, known, centre[x], inv_area, floor)
            continue
        cs = col_sum[d]
        cc = col_cnt[d]
        ssum = np.int32(0)
        csum = np.int32(0)
        for j in range(2 * rad):
            ssum = np.int32(ssum + cs[j])
            csum = np.int32(csum + cc[j])
        for x in range(m):
            ssum = np.int32(ssum + cs[x + 2 * rad])
            csum = np.int32(csum + cc[x + 2 * rad])
            sums[x] = ssum
            counts[x] = csum
            ssum = np.int32(ssum - cs[x])
            csum = np.int32(csum - cc[x])
        for x in range(m):
            out[x] = _box_mean(sums[x], counts[x], centre[x], inv_area, floor)


@njit(**INLINE)
def _select_row(vol, sums_row, cur, y, x0, x1, raw_rad, exclude, floor, col_sum, col_cnt, scratch, raw, index, conf):
    """Winner, offset and confidence of the pixels x0..x1 of row ``y`` from the complete sum
    (``sums_row``, (N, tile width), the other paths' sum there, + the bottom-up path ``cur``) and
    the raw cost's box mean."""
    h, n, w = vol.shape
    m = x1 - x0
    sums = np.empty(m, np.int32)
    counts = np.empty(m, np.int32)
    _raw_rows(col_sum, col_cnt, vol, y, x0, raw_rad, np.float32(floor), scratch, sums, counts, raw)
    # The loops over the columns are branch-free selects on int32 (the winners' indices too):
    # a branch or an int64 lane keeps them from vectorising.
    big = np.int32(1 << 30)
    best = np.full(m, big, np.int32)
    tie = np.full(m, np.inf, np.float32)
    arg = np.zeros(m, np.int32)
    for d in range(n):
        trow = sums_row[d, :m]
        cr = cur[d]
        rr = raw[d]
        di = np.int32(d)
        for x in range(m):
            v = np.int32(np.int32(trow[x]) + np.int32(cr[x]))
            b = best[x]
            # Integer sums tie where float ones would not: the raw cost breaks the tie.
            better = (v < b) | ((v == b) & (rr[x] < tie[x]))
            best[x] = v if better else b
            tie[x] = rr[x] if better else tie[x]
            arg[x] = di if better else arg[x]
    # The second best of the sum away from the winner, and the raw curve's best and second.
    second = np.full(m, big, np.int32)
    rbest = np.full(m, np.inf, np.float32)
    rarg = np.zeros(m, np.int32)
    ex = np.int32(exclude)
    for d in range(n):
        trow = sums_row[d, :m]
        cr = cur[d]
        rr = raw[d]
        di = np.int32(d)
        for x in range(m):
            v = np.int32(np.int32(trow[x]) + np.int32(cr[x]))
            away = np.int32(abs(np.int32(di - arg[x]))) > ex
            second[x] = v if away & (v < second[x]) else second[x]
            lower = rr[x] < rbest[x]
            rbest[x] = rr[x] if lower else rbest[x]
            rarg[x] = di if lower else rarg[x]
    rsecond = np.full(m, np.inf, np.float32)
    for d in range(n):
        rr = raw[d]
        di = np.int32(d)
        for x in range(m):
            away = np.int32(abs(np.int32(di - rarg[x]))) > ex
            rsecond[x] = rr[x] if away & (rr[x] < rsecond[x]) else rsecond[x]
    for x in range(m):
        k = arg[x]
        off = 0.0
        if 0 < k < n - 1:
            cm = np.float64(raw[k - 1, x])
            c0 = np.float64(raw[k, x])
            cp = np.float64(raw[k + 1, x])
            if not (np.isfinite(cm) and np.isfinite(c0) and np.isfinite(cp)):
                acc = 0.0
                cnt = 0
                for d in range(n):
                    if np.isfinite(raw[d, x]):
                        acc += raw[d, x]
                        cnt += 1
                f = acc / cnt if cnt > 0 else 0.0
                cm = cm if np.isfinite(cm) else f
                c0 = c0 if np.isfinite(c0) else f
                cp = cp if np.isfinite(cp) else f
            off = _parabola(cm, c0, cp)
        elif n >= 3:
            inward = 1 if k == 0 else -1
            off = _end_offset(np.float64(raw[k, x]), np.float64(raw[k + inward, x]), np.float64(raw[k + 2 * inward, x]),
                              inward)
        index[y, x0 + x] = np.float32(k + off)
        # The distinctness of costs counted from zero: each of the four paths carries COST_ZERO.
        s2 = np.float64(second[x] - 4 * COST_ZERO) if second[x] < big else np.inf
        conf[y, x0 + x] = _distinctness(np.float64(best[x] - 4 * COST_ZERO), s2) * \
            _distinctness(np.float64(rbest[x]) - COST_ZERO, np.float64(rsecond[x]) - COST_ZERO)
