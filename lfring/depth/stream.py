"""The default plane sweep: locally normalised luminances compared across views, box-aggregated,
swept in row strips that stay in the cache and are shared among threads.

The cost ('lcn') of a hypothesis at a pixel is the variance across the views of their locally
normalised luminances, ``n = (L - mu) / sqrt(var + LCN_EPS mu^2 + LCN_FLOOR)`` with ``mu`` and
``var`` the masked local mean and variance of the luminance ``L`` over ``window_px``. The
normalisation is done once per view, before the sweep, so a hypothesis only has to shift the
views and sum: with S1, S2 the sums over views of the (mask-weighted) normalised values and
their squares and C the sum of the views' weights, ``c = (S2 - S1^2 / C) / max(C - 1, 0.5)``.
Dividing by the local mean makes it blind to the views' different vignetting and exposure.

:func:`sweep_strips` evaluates it for every hypothesis strip by strip: each strip of output rows
(with the aggregation window's halo) is shifted, summed, box-filtered and folded into the
running minimum for all hypotheses before the next strip, so its buffers stay in the cache. When
every homography is a translation (the optics model) the shift is two weighted adds of a
zero-padded copy of the view; otherwise ``cv2.warpPerspective`` renders the strip. Memory holds
a few strips per thread and ``exclude + 2`` aggregated slices of a strip, whatever the number
of hypotheses.
"""

from __future__ import annotations

import threading

import cv2
import numpy as np

from lfring.refocus import _run_threads

__all__ = ["LCN_EPS", "LCN_FLOOR", "RunningMinimum", "lcn_cost", "lcn_sources", "sweep_strips"]

# Relative contrast floor of the normalisation (its variance term is LCN_EPS mu^2): texture
# fainter than 10 % of the local mean is compared unnormalised; LCN_FLOOR keeps black regions finite.
LCN_EPS = 1e-2
LCN_FLOOR = 1e-6
# Pixels per strip (rows times width, with the halo): about 0.4 MiB a buffer, so a thread's dozen
# buffers stay in its L2 and L3 share; larger strips measured no faster, smaller ones slower.
STRIP_PIXELS = 1 << 17


def _luminance(views: np.ndarray) -> np.ndarray:
    v, h, w, c = views.shape
    if c == 1:
        return views[..., 0]
    mix = np.full((1, c), 1.0 / c, np.float32)
    return np.stack([cv2.transform(views[k], mix).reshape(h, w) for k in range(v)])


def lcn_sources(views: np.ndarray, masks: np.ndarray, window_px: int, *, threads: int = 1) -> np.ndarray:
    """(V, h, w) float32 locally normalised luminance of every view, to be multiplied by the
    mask before warping; views are shared among ``threads`` threads."""
    from lfring.depth.sweep import _box

    lum = _luminance(views)
    out = np.empty(lum.shape, np.float32)

    weights = _window_weights(masks, window_px)
    v, h, w = lum.shape
    pad = window_px // 2
    rows = max(8, STRIP_PIXELS // (2 * max(w, 1)))  # row strips of every view, in the cache

    def one(k: int, r0: int, r1: int) -> None:
        q0, q1 = max(0, r0 - pad), min(h, r1 + pad)
        inner = slice(r0 - q0, r1 - q0)
        m, x = masks[k][q0:q1], lum[k][q0:q1]
        a = cv2.multiply(x, m)
        mu = _box(a, window_px)[inner]
        cv2.multiply(a, x, dst=a)
        s2 = _box(a, window_px)[inner]
        wk = weights[k][r0:r1]
        cv2.multiply(mu, wk, dst=mu)
        cv2.multiply(s2, wk, dst=s2)
        # sqrt(max(E[x^2] - mu^2, 0) + eps mu^2 + floor)
        sq = cv2.multiply(mu, mu)
        var = cv2.subtract(s2, sq)
        cv2.max(var, 0.0, dst=var)
        cv2.scaleAdd(sq, LCN_EPS, var, dst=var)
        cv2.add(var, LCN_FLOOR, dst=var)
        cv2.sqrt(var, dst=var)
        dst = out[k][r0:r1]
        cv2.subtract(x[inner], mu, dst=dst)
        cv2.divide(dst, var, dst=dst)

    _run_threads([lambda k=k, r=r: one(k, r, min(h, r + rows)) for k in range(v) for r in range(0, h, rows)], threads)
    return out


_WEIGHTS: dict = {}


def _window_weights(masks: np.ndarray, window_px: int) -> np.ndarray:
    """1 / (box of every mask, at least 1e-3), kept for the last few mask arrays (the masks
    are made once per calibration and view shape and never written to)."""
    from lfring.depth.sweep import _box

    key = (id(masks), masks.shape, window_px)
    hit = _WEIGHTS.get(key)
    if hit is not None and hit[0] is masks:
        return hit[1]
    inv = np.stack([1.0 / np.maximum(_box(m, window_px), 1e-3) for m in masks]).astype(np.float32)
    if len(_WEIGHTS) >= 8:
        _WEIGHTS.clear()
    _WEIGHTS[key] = (masks, inv)
    return inv


def lcn_cost(s1: np.ndarray, s2: np.ndarray, count: np.ndarray) -> np.ndarray:
    """The 'lcn' cost from the sums over views (S1, S2, C; see the module's docstring)."""
    c = s2 - s1 * s1 / np.maximum(count, 1e-3)
    c /= np.maximum(count - 1.0, 0.5)
    return c.astype(np.float32, copy=False)


class RunningMinimum:
    """Streamed argmin over hypotheses with what refinement and confidence need, per pixel:
    the best cost and its (first) index, its neighbours' costs, and the best cost more than
    ``exclude`` hypotheses away from the final best. That last one is exact: the minimum over
    the slices before the best (a prefix minimum lagging ``exclude + 1`` slices, copied when
    the best moves) and over the slices after it (restarted when the best moves); the tracker
    keeps the last ``exclude + 2`` slices for it. OpenCV masked copies throughout: NumPy's
    masked assignments are 40x slower on these arrays."""

    def __init__(self, shape, exclude: int = 1):
        self.exclude = e = max(1, int(exclude))
        inf = lambda: np.full(shape, np.inf, np.float32)
        self.best, self.c_prev, self.c_next, self.far_lo, self.far_hi, self.prefix = (inf() for _ in range(6))
        self.best_i = np.zeros(shape, np.int32)
        self.ring = [np.empty(shape, np.float32) for _ in range(e + 2)]  # slices i - e - 1 .. i
        self._inf = inf()
        self._idx = np.empty(shape, np.int32)
        self._tmp = np.empty(shape, np.float32)
        self._mask = np.empty(shape, np.uint8)
        self._new = np.empty(shape, np.uint8)
        self.i = 0

    def slot(self) -> np.ndarray:
        """The buffer to write the next slice into (then call :meth:`push`)."""
        return self.ring[self.i % len(self.ring)]

    def push(self) -> None:
        i, e, ring = self.i, self.exclude, self.ring
        cur = ring[i % len(ring)]
        if i >= e + 1:
            cv2.min(self.prefix, ring[(i - e - 1) % len(ring)], dst=self.prefix)  # min over slices <= i - e - 1
        if i >= 1:
            cv2.compare(self.best_i, i - 1, cv2.CMP_EQ, dst=self._mask)
            cv2.copyTo(cur, self._mask, dst=self.c_next)
            cv2.compare(self.best_i, i - e, cv2.CMP_LT, dst=self._mask)  # slice i is far after the best
            cv2.min(self.far_hi, cur, dst=self._tmp)
            cv2.copyTo(self._tmp, self._mask, dst=self.far_hi)
        new = cv2.compare(cur, self.best, cv2.CMP_LT, dst=self._new)
        cv2.copyTo(cur, new, dst=self.best)
        self._idx.fill(i)
        cv2.copyTo(self._idx, new, dst=self.best_i)
        if i >= 1:
            cv2.copyTo(ring[(i - 1) % len(ring)], new, dst=self.c_prev)
            cv2.copyTo(self._inf, new, dst=self.c_next)
            cv2.copyTo(self._inf, new, dst=self.far_hi)
        if i >= e + 1:
            cv2.copyTo(self.prefix, new, dst=self.far_lo)
        self.i += 1

    def second(self) -> np.ndarray:
        return np.minimum(self.far_lo, self.far_hi)


def _translations(hs: np.ndarray):
    """(N, V, 2) translation (tx, ty) of every H_ref_from_view, or None if any is not one."""
    hs = np.asarray(hs, np.float64)
    if not (np.all(np.abs(hs[..., :2, :2] - np.eye(2)) < 1e-12) and np.all(np.abs(hs[..., 2, :2]) < 1e-15)
            and np.all(hs[..., 2, 2] == 1.0)):
        return None
    return hs[..., :2, 2]


_BUFFERS = threading.local()


def _padded_buffer(slot, shape) -> np.ndarray:
    """This thread's padded copy number ``slot``, kept from call to call: fresh memory for
    every frame costs more in page faults than the copy itself."""
    cache = getattr(_BUFFERS, "arrays", None)
    if cache is None:
        cache = _BUFFERS.arrays = {}
    buf = cache.get(slot)
    if buf is None or buf.shape != shape:
        buf = cache[slot] = np.empty(shape, np.float32)
    return buf


class _Shifter:
    """Renders rows [q0, q1) of a view shifted by a translation: reference pixel x samples the
    view at x - t, bilinearly, zero outside; a vertical then a horizontal two-tap pass over a
    copy of the view padded with zeros far enough for every hypothesis."""

    def __init__(self, src: np.ndarray, shifts: np.ndarray, slot):
        h, w = src.shape
        s = -np.asarray(shifts, np.float64)  # (N, 2): sample offsets
        self.pad = p = int(np.ceil(np.abs(s).max())) + 2
        self.src = _padded_buffer(slot, (h + 2 * p, w + 2 * p))
        self.src[:p] = 0
        self.src[p + h:] = 0
        self.src[p:p + h, :p] = 0
        self.src[p:p + h, p + w:] = 0
        self.src[p:p + h, p:p + w] = src
        ints = np.floor(s).astype(int)
        self.plan = [(int(ix), int(iy), float(sx - ix), float(sy - iy)) for (sx, sy), (ix, iy) in zip(s, ints)]
        self.w = w

    def render(self, i: int, q0: int, rows: int, tmp: np.ndarray, out: np.ndarray) -> np.ndarray:
        ix, iy, fx, fy = self.plan[i]
        p, w = self.pad, self.w
        r = q0 + iy + p
        c0 = ix + p
        src = self.src
        # A whole-row shift needs no vertical pass, a whole-column one no horizontal pass.
        cols = w if fx == 0.0 else w + 1
        if fy == 0.0:
            t = src[r:r + rows, c0:c0 + cols]
        else:
            t = tmp[:rows, :cols] if fx != 0.0 else out[:rows]
            cv2.addWeighted(src[r:r + rows, c0:c0 + cols], 1.0 - fy, src[r + 1:r + 1 + rows, c0:c0 + cols], fy, 0.0, dst=t)
        if fx == 0.0:
            return t
        return cv2.addWeighted(t[:, :w], 1.0 - fx, t[:, 1:], fx, 0.0, dst=out[:rows])


def sweep_strips(sources: np.ndarray, masks: np.ndarray, hs: np.ndarray, *, aggregate_px: int, exclude: int = 1,
                 threads: int = 1, on_strip=None):
    """The 'lcn' cost with box aggregation over every hypothesis, strip by strip.

    Parameters
    ----------
    sources : (V, h, w) float32
        :func:`lcn_sources` of the views.
    masks : (V, h, w) float32
        Valid weight of every view pixel.
    hs : (N, V, 3, 3)
        H_ref_from_view per hypothesis and view.
    aggregate_px : int
        Odd side of the box.
    exclude : int
        As :class:`RunningMinimum`.
    threads : int
        Strips are shared among this many threads (OpenCV and NumPy release the GIL).
    on_strip : callable, optional
        Called, in the thread that swept it, as ``on_strip(r0, r1, best_i, c_best, c_prev,
        c_next, c_second, nviews)`` with the results for rows r0 to r1 of each strip; then
        nothing is returned.

    Returns
    -------
    best_i : (h, w) int32
    c_best, c_prev, c_next, c_second, nviews : (h, w) float32
        As :func:`lfring.depth.sweep._sweep_numpy` defines them (c_second exact, see
        :class:`RunningMinimum`).
    """
    v, h, w = sources.shape
    hs = np.asarray(hs, np.float64)
    n = hs.shape[0]
    pad = aggregate_px // 2
    weighted = np.ascontiguousarray(sources * masks, dtype=np.float32)
    masks = np.ascontiguousarray(masks, dtype=np.float32)
    identity = [bool(np.all(hs[:, k] == np.eye(3))) for k in range(v)]
    moving = [k for k in range(v) if not identity[k]]
    shifts = _translations(hs)
    if shifts is not None:
        shifters = {k: (_Shifter(weighted[k], shifts[:, k], (k, 0)), _Shifter(masks[k], shifts[:, k], (k, 1))) for k in moving}
    else:
        inverse = np.linalg.inv(hs)  # view from reference
    # As many strips as fit STRIP_PIXELS, rounded up to a multiple of the threads, of equal height.
    threads = max(1, int(threads))
    most = max(8, STRIP_PIXELS // max(w, 1) - 2 * pad)
    count = threads * -(-h // (threads * most))
    rows = max(1, -(-h // count))
    strips = [(r0, min(h, r0 + rows)) for r0 in range(0, h, rows)]
    if on_strip is None:
        out = {name: np.empty((h, w), np.float32) for name in ("c_best", "c_prev", "c_next", "second", "nviews")}
        best_i = np.empty((h, w), np.int32)

        def on_strip(r0, r1, *arrays):
            for dst, src in zip((best_i, *out.values()), arrays):
                dst[r0:r1] = src
    else:
        out = None

    def strip(r0: int, r1: int, bufs) -> None:
        q0, q1 = max(0, r0 - pad), min(h, r1 + pad)
        big = q1 - q0
        o0, m = r0 - q0, r1 - r0
        s1, s2, cnt, a_buf, wt_buf, t, agg, ones, tmp, bad = (b[:big] for b in bufs)
        static = [k for k in range(v) if identity[k]]
        base = None
        if static:
            base = (sum(weighted[k][q0:q1] for k in static), sum(weighted[k][q0:q1] ** 2 for k in static),
                    sum(masks[k][q0:q1] for k in static))
        run = RunningMinimum((m, w), exclude)
        nviews = np.zeros((m, w), np.float32)
        if shifts is None:
            shift_rows = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, q0], [0.0, 0.0, 1.0]])
        for i in range(n):
            first = True
            for k in moving:
                if shifts is not None:
                    sa, sm = shifters[k]
                    a = sa.render(i, q0, big, tmp, a_buf)
                    wt = sm.render(i, q0, big, tmp, wt_buf)
                else:
                    g = inverse[i, k] @ shift_rows
                    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
                    a = cv2.warpPerspective(weighted[k], g, (w, big), dst=a_buf, flags=flags, borderMode=cv2.BORDER_CONSTANT)
                    wt = cv2.warpPerspective(masks[k], g, (w, big), dst=wt_buf, flags=flags, borderMode=cv2.BORDER_CONSTANT)
                if first and base is not None:  # the views that do not move start the sums
                    cv2.add(base[0], a, dst=s1)
                    cv2.add(base[1], cv2.multiply(a, a, dst=s2), dst=s2)
                    cv2.add(base[2], wt, dst=cnt)
                    first = False
                elif first:
                    np.copyto(s1, a)
                    cv2.multiply(a, a, dst=s2)
                    np.copyto(cnt, wt)
                    first = False
                else:
                    cv2.add(s1, a, dst=s1)
                    cv2.accumulateSquare(a, s2)
                    cv2.add(cnt, wt, dst=cnt)
            # c = (S2 - S1^2 / C) / (C - 1); 1 where fewer than 1.5 views are valid.
            cv2.multiply(s1, s1, dst=t)
            cv2.divide(t, cnt, dst=t)
            cv2.subtract(s2, t, dst=t)
            cv2.subtract(cnt, 1.0, dst=tmp[:, :w])
            cv2.divide(t, tmp[:, :w], dst=t)  # C - 1 >= 0.5 wherever the result is kept:
            cv2.compare(cnt, 1.5, cv2.CMP_LT, dst=bad)
            cv2.copyTo(ones, bad, dst=t)
            cv2.boxFilter(t, cv2.CV_32F, (aggregate_px, aggregate_px), dst=agg, borderType=cv2.BORDER_REFLECT_101)
            cur = run.slot()
            np.copyto(cur, agg[o0:o0 + m])
            cv2.copyTo(run._inf, bad[o0:o0 + m], dst=cur)
            cv2.max(nviews, cnt[o0:o0 + m], dst=nviews)
            run.push()
        on_strip(r0, r1, run.best_i, run.best, run.c_prev, run.c_next, run.second(), nviews)

    local = threading.local()

    def task(r0: int, r1: int) -> None:
        if not hasattr(local, "bufs"):  # this thread's strip buffers
            big = min(h, rows + 2 * pad)
            local.bufs = [np.empty((big, w), np.float32) for _ in range(7)]
            local.bufs += [np.ones((big, w), np.float32), np.empty((big, w + 1), np.float32), np.empty((big, w), np.uint8)]
        strip(r0, r1, local.bufs)

    _run_threads([lambda s=s: task(*s) for s in strips], threads)
    if out is not None:
        return best_i, out["c_best"], out["c_prev"], out["c_next"], out["second"], out["nviews"]
    return None
