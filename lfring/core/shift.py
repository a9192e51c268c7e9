"""The shift engine: bilinear resampling by pure shifts in cache-sized row strips, the one
resampler of refocusing and of the depth sweep when every homography is a translation."""

from __future__ import annotations

import threading

import cv2
import numpy as np

from lfring.core.threads import run_threads
from lfring.core.viewstack import all_finite, inverse_weight
from lfring.errors import InvalidInputError

__all__ = ["STRIP_BYTES", "ShiftEngine"]

# Rows per strip of the shift engine's accumulation: a strip's accumulator and two scratch buffers
# take about this many bytes, so they stay in the L3 cache (each view is read from memory once
# and the intermediate images of the bilinear stencil never go back to it), while every OpenCV
# call is long enough that two threads seldom wait for each other's Python in between (the GIL).
# Strips of a few MiB measured best; strips sized for L2 were much slower, their threads mostly
# waiting on each other's Python between short calls (benchmarks/RESULTS.md, "Refocusing").
STRIP_BYTES = 3 << 20


_SCRATCH = threading.local()


def _scratch(rows: int, w: int, tail: tuple):
    """This thread's scratch strips of the shift engine, reused from frame to frame (fresh ones
    would cost page faults every frame): the padded vertical pass (its two pad columns are
    never written, so stay zero), the horizontal pass, masked rows and spread channels."""
    key = (rows, w, tail)
    if getattr(_SCRATCH, "key", None) != key:
        _SCRATCH.key = key
        _SCRATCH.bufs = (np.zeros((rows, w + 2, *tail), np.float32), np.empty((rows, w, *tail), np.float32),
                         np.empty((rows + 1, w, *tail), np.float32), np.empty((rows + 1, w, *tail), np.float32))
    return _SCRATCH.bufs


def _edge_weights(shift: float, n: int) -> np.ndarray:
    """(n,) bilinear weight of a zero-padded line of ones shifted by ``shift``: what warping an
    all-valid view gives along one axis (1 inside, the fraction at the two edge pixels)."""
    i = int(np.floor(shift))
    f = shift - i
    pos = np.arange(n) + i  # the line's pixel under the first tap
    return (np.where((pos >= 0) & (pos < n), 1.0 - f, 0.0) + np.where((pos + 1 >= 0) & (pos + 1 < n), f, 0.0))


def _vertical(src, tv, zeros, top, both, bottom) -> None:
    """The vertical two-tap pass of a strip into ``tv`` (see :class:`ShiftEngine`)."""
    for z in zeros:
        tv[z] = 0
    if top is not None:
        np.multiply(src[top[0]], top[1], out=tv[top[2]])
    if both is not None:
        if both[3] == 0.0:  # a whole-row shift: a copy
            np.copyto(tv[both[4]], src[both[0]])
        else:
            cv2.addWeighted(src[both[0]], both[1], src[both[2]], both[3], 0.0, dst=tv[both[4]])
    if bottom is not None:
        np.multiply(src[bottom[0]], bottom[1], out=tv[bottom[2]])


class ShiftEngine:
    """Bilinear resampling by pure shifts with constant weights, in row strips: the one shift
    engine of refocusing and depth.

    Slot k has the shift ``shifts[k] = (sx, sy)``: reference pixel (x, y) samples its source at
    (x + sx, y + sy), i.e. ``(1-fy) [(1-fx) v(y', x') + fx v(y', x'+1)] + fy [... row y'+1 ...]``
    with ``x' = x + ix``, ``y' = y + iy`` (``ix = floor(sx)``, ``fx = sx - ix``) and the source
    zero outside, exactly as ``cv2.warpAffine`` with a constant border. A strip of output rows
    takes one vertical two-tap pass that reads the source's rows into a cache-resident buffer
    with a zero column on either side (so the horizontal edges need no special case), then one
    horizontal two-tap pass.

    Two uses:

    - :meth:`run` accumulates slot k of a view stack ``views[k]`` strip by strip and normalises
      the sum (refocusing: one slot per view); strips are shared among threads.
    - :meth:`render_padded` draws rows of one source shifted by one slot's shift, from a
      zero-padded copy made once by :meth:`padded` (the depth sweep: one engine per view, one
      slot per hypothesis).

    Parameters
    ----------
    shifts : (K, 2) float
        Sampling shift of every slot, as :func:`translation_of` gives it.
    view_shape : (h, w)
        Shape of the sources and of the output frame.
    masks : (K, h, w) float32, optional
        For :meth:`run`: every view is multiplied by its mask first; None when every view is
        valid everywhere.
    """

    def __init__(self, shifts: np.ndarray, view_shape, masks=None):
        h, w = view_shape
        self.view_shape = (int(h), int(w))
        self.masks = masks
        self.shifts = np.asarray(shifts, dtype=np.float64).reshape(-1, 2)
        ints = np.floor(self.shifts).astype(int)
        self.geometry = [(int(ix), int(iy), float(sx - ix), float(sy - iy))
                         for (sx, sy), (ix, iy) in zip(self.shifts, ints)]
        self._columns = [self._column_plan(*g) for g in self.geometry]
        self._strips: dict[int, list] = {}
        self._inv_bands = None

    # -- geometry ------------------------------------------------------------------------
    def _column_plan(self, ix: int, iy: int, fx: float, fy: float):
        """What does not depend on the rows: the view columns read (c0, c1), the vertical pass's
        columns in the padded buffer, the horizontal taps' columns, the output columns written
        and those left zero; None when no output pixel touches the view."""
        w = self.view_shape[1]
        # Output pixels whose taps touch the view: x + ix in [-1, w - 1].
        x0, x1 = max(0, -ix - 1), min(w, w - ix)
        if x0 >= x1:
            return None
        c0, c1 = max(0, x0 + ix), min(w, x1 + ix + 1)  # view columns read
        a, m = x0 + ix + 1, x1 - x0
        clear = [slice(0, x0)] * (x0 > 0) + [slice(x1, w)] * (x1 < w)
        return c0, c1, slice(c0 + 1, c1 + 1), slice(a, a + m), slice(a + 1, a + 1 + m), m, slice(x0, x1), clear

    def _row_plan(self, k: int, s0: int, s1: int, masked: bool):
        """The vertical pass of slot k for output rows [s0, s1): the source rows read (r0, r1)
        and the (zeros, top, both, bottom) steps of :func:`_vertical`, with the source's rows
        counted from r0 when ``masked`` (a masked copy of those rows) and columns from c0;
        None when no output row of the strip touches the view."""
        ix, iy, fx, fy = self.geometry[k]
        c0, c1, cols = self._columns[k][:3]
        h = self.view_shape[0]
        n = s1 - s0
        y0, y1 = max(s0, -iy - 1), min(s1, h - iy)
        if y0 >= y1:
            return None
        r0, r1 = max(0, y0 + iy), min(h, y1 + iy + 1)  # view rows read
        b0, b1 = max(y0, -iy), min(y1, h - 1 - iy)  # output rows with both taps inside
        ro = r0 if masked else 0  # the source's first row
        cs = slice(0, c1 - c0) if masked else slice(c0, c1)
        zeros = [(slice(0, y0 - s0), cols)] if y0 > s0 else []
        if y1 < s1:
            zeros.append((slice(y1 - s0, n), cols))
        # The view's first row under the second tap only; its last under the first only.
        top = ((0 - ro, cs), np.float32(fy), (y0 - s0, cols)) if b0 > y0 else None
        bottom = ((h - 1 - ro, cs), np.float32(1.0 - fy), (b1 - s0, cols)) if y1 > b1 else None
        both = (((slice(b0 + iy - ro, b1 + iy - ro), cs), 1.0 - fy, (slice(b0 + iy + 1 - ro, b1 + iy + 1 - ro), cs),
                 float(fy), (slice(b0 - s0, b1 - s0), cols)) if b1 > b0 else None)
        return r0, r1, zeros, top, both, bottom

    def strips(self, rows: int) -> list:
        """Per strip of ``rows`` output rows: (s0, s1, steps, bands), ``steps`` per slot
        touching the strip (its slices made here, once, so a frame only applies them) and
        ``bands`` the row bands of the all-valid normalisation within the strip."""
        if rows not in self._strips:
            h, w = self.view_shape
            masked = self.masks is not None
            bands = self.inv_bands() if not masked else []
            plan = []
            for s0 in range(0, h, rows):
                s1 = min(s0 + rows, h)
                out_rows, strip_rows = slice(s0, s1), slice(0, s1 - s0)
                steps = []
                for k, (ix, iy, fx, fy) in enumerate(self.geometry):
                    if self._columns[k] is None:
                        continue
                    c0, c1, _, ha, hb, m, dcols, clear = self._columns[k]
                    vertical = self._row_plan(k, s0, s1, masked)
                    if vertical is None:
                        continue
                    r0, r1, zeros, top, both, bottom = vertical
                    steps.append((k, (slice(r0, r1), slice(c0, c1)), (slice(0, r1 - r0), slice(0, c1 - c0)), zeros, top, both,
                                  bottom, ((strip_rows, ha), 1.0 - fx, (strip_rows, hb), fx), (strip_rows, slice(0, m)),
                                  (out_rows, dcols), [(out_rows, c) for c in clear]))
                strip_bands = [(slice(max(y0, s0), min(y1, s1)), i) for i, (y0, y1, _, _) in enumerate(bands) if y0 < s1 and s0 < y1]
                plan.append((s0, s1, steps, strip_bands))
            self._strips[rows] = plan
        return self._strips[rows]

    def inv_bands(self):
        """Normalisation of an all-valid plan: the weight is ``sum_k wy_k(y) wx_k(x)``, so rows
        fall into bands with one (w,) row each: [(y0, y1, weight_row, inverse_row)]."""
        if self._inv_bands is None:
            h, w = self.view_shape
            wy = np.array([_edge_weights(iy + fy, h) for ix, iy, fx, fy in self.geometry])
            wx = np.array([_edge_weights(ix + fx, w) for ix, iy, fx, fy in self.geometry])
            starts = [0, *(np.flatnonzero(np.any(wy[:, 1:] != wy[:, :-1], axis=0)) + 1), h]
            bands = []
            for y0, y1 in zip(starts[:-1], starts[1:]):
                weight = (wy[:, y0] @ wx).astype(np.float32)
                bands.append((y0, y1, weight, inverse_weight(weight)))
            self._inv_bands = bands
        return self._inv_bands

    # -- rendering -----------------------------------------------------------------------
    def padded(self, src: np.ndarray, slot) -> tuple[np.ndarray, int]:
        """``src`` (h, w) copied into this thread's zero-padded buffer ``slot`` (reused from call
        to call: fresh pages every frame cost more than the copy), with a margin wider than
        every slot's shift; for :meth:`render_padded`, which then needs no edge cases."""
        h, w = self.view_shape
        p = int(np.ceil(np.abs(self.shifts).max(initial=0.0))) + 2
        cache = getattr(_SCRATCH, "padded", None)
        if cache is None:
            cache = _SCRATCH.padded = {}
        buf = cache.get(slot)
        if buf is None or buf.shape != (h + 2 * p, w + 2 * p):
            buf = cache[slot] = np.zeros((h + 2 * p, w + 2 * p), np.float32)
        buf[:p] = 0
        buf[p + h:] = 0
        buf[p:p + h, :p] = 0
        buf[p:p + h, p + w:] = 0
        buf[p:p + h, p:p + w] = src
        return buf, p

    def render_padded(self, k: int, padded, s0: int, s1: int, out: np.ndarray, tmp: np.ndarray) -> np.ndarray:
        """Rows [s0, s1) of the source shifted by slot k's shift, written to and returned as
        ``out[:s1 - s0]`` (a view of the copy for a whole-pixel shift), from :meth:`padded`'s
        copy: two weighted adds (one for a whole-row or whole-column shift). The sweep renders
        every hypothesis of a view from one copy, so the copy pays for itself; ``tmp`` is a
        scratch of at least (s1 - s0, w + 1)."""
        buf, p = padded
        ix, iy, fx, fy = self.geometry[k]
        rows, w = s1 - s0, self.view_shape[1]
        r, c0 = s0 + iy + p, ix + p
        cols = w if fx == 0.0 else w + 1
        if fy == 0.0:
            t = buf[r:r + rows, c0:c0 + cols]
        else:
            t = tmp[:rows, :cols] if fx != 0.0 else out[:rows]
            cv2.addWeighted(buf[r:r + rows, c0:c0 + cols], 1.0 - fy, buf[r + 1:r + 1 + rows, c0:c0 + cols], fy, 0.0, dst=t)
        if fx == 0.0:
            return t
        return cv2.addWeighted(t[:, :w], 1.0 - fx, t[:, 1:], fx, 0.0, dst=out[:rows])

    def run(self, views: np.ndarray, out: np.ndarray, *, masks=None, inv=None, inv_rows=None, threads: int = 1):
        """Accumulate the shifted views (V, h, w[, C]) into ``out`` (h, w[, C]) and normalise it
        by ``inv`` ((h, w) map) or, for an all-valid plan, ``inv_rows`` (the inverse row of every
        band of :meth:`inv_bands`, shaped (w[, C])), if given. Views holding NaN or infinite
        values raise :class:`lfring.errors.InvalidInputError`. A plan with masks multiplies
        every view by its mask first. Single-channel masks and ``inv`` are spread over the
        channels strip by strip, in the cache: memory traffic, not arithmetic, bounds this."""
        h, w = self.view_shape
        tail = out.shape[2:]
        rows = max(8, min(h, STRIP_BYTES // (3 * (w + 2) * out.itemsize * max(1, int(np.prod(tail))))))
        plan = self.strips(rows)
        threads = max(1, min(threads, len(plan)))
        chunks = [plan[i * len(plan) // threads:(i + 1) * len(plan) // threads] for i in range(threads)]
        add, weighted, multiply, merge = cv2.add, cv2.addWeighted, cv2.multiply, cv2.merge
        masks, nc = self.masks if masks is None else masks, (tail or (1,))[0]

        def work(chunk):
            tv, th, tm, spread = _scratch(rows, w, tail)
            for s0, s1, steps, bands in chunk:
                acc = out[s0:s1]
                for i, (k, vsl, tsl, zeros, top, both, bottom, hz, hsl, dst, clear) in enumerate(steps):
                    if masks is None:
                        src = views[k]
                    else:
                        src = tm[tsl]
                        m = masks[k][vsl]
                        if nc > 1 and m.ndim == 2:
                            m = merge([m] * nc, dst=spread[tsl])
                        multiply(views[k][vsl], m, dst=src)
                    _vertical(src, tv, zeros, top, both, bottom)
                    if i == 0:  # the first view goes straight into the result
                        for c in clear:
                            out[c] = 0
                        weighted(tv[hz[0]], hz[1], tv[hz[2]], hz[3], 0.0, dst=out[dst])
                    else:
                        t = th[hsl]
                        weighted(tv[hz[0]], hz[1], tv[hz[2]], hz[3], 0.0, dst=t)
                        d = out[dst]
                        add(d, t, dst=d)
                if not steps:
                    acc[...] = 0
                if inv is not None:
                    m = inv[s0:s1]
                    if nc > 1 and m.ndim == 2:
                        m = merge([m] * nc, dst=spread[: s1 - s0])
                    multiply(acc, m, dst=acc)
                elif inv_rows is not None:
                    for sl, i in bands:
                        np.multiply(out[sl], inv_rows[i], out=out[sl])
                if not all_finite(acc):  # the strip is in the cache: caught here cheaply
                    finite[0] = False

        finite = [True]
        run_threads([lambda c=c: work(c) for c in chunks], threads)
        if not finite[0]:
            raise InvalidInputError("views contain NaN or infinite values")
        return out
