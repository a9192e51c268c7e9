"""The strip sweep: the 'lcn' costs with box aggregation over every hypothesis, strip by strip.

Each strip of output rows (with the aggregation window's halo) is shifted, summed, box-filtered
and folded into the running minimum for all hypotheses before the next strip, so its buffers stay
in the cache, and strips are shared among threads. When every homography is a translation (the
optics model; :func:`lfring.core.warping.translations`) the views are shifted by the shared
:class:`lfring.core.shift.ShiftEngine`; otherwise ``cv2.warpPerspective`` renders the strip.
Memory holds a few strips per thread and ``exclude + 2`` aggregated slices of a strip, whatever
the number of hypotheses.
"""

from __future__ import annotations

import threading

import cv2
import numpy as np

from lfring.core.filters import box_filter
from lfring.core.shift import ShiftEngine
from lfring.core.threads import STRIP_PIXELS, run_threads
from lfring.core.viewstack import WEIGHT_FLOOR
from lfring.core.warping import translations
from lfring.depth.costs.lcn import weighted_square
from lfring.depth.costs.lcn_halves import checked_halves, half_aggregate
from lfring.depth.costs.lcn_occlusion import lcn_leave_one_out, leavable_views, occlusion_aggregate
from lfring.depth.selection import RunningMinimum

__all__ = ["sweep_strips"]


def sweep_strips(sources: np.ndarray, masks: np.ndarray, hs: np.ndarray, *, aggregate_px: int, exclude: int = 1,
                 threads: int = 1, on_strip=None, volume=None, occlusion: bool = False, on_rows=None, halves=None):
    """The 'lcn' cost with box aggregation over every hypothesis, strip by strip.

    Parameters
    ----------
    sources : (V, h, w) float32
        :func:`lfring.depth.costs.lcn.lcn_sources` of the views.
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
    volume : (N, h, w) float32, optional
        Filled with every hypothesis's aggregated cost (inf where fewer than 1.5 views see the
        pixel) instead of keeping a running minimum: for an optimisation over the whole volume
        (:mod:`lfring.depth.sgm`). Then ``on_strip`` is called as ``on_strip(r0, r1, nviews)``
        and, without it, ``nviews`` is returned.
    on_rows : callable, optional
        Called as ``on_rows(r0, r1)`` when the rows r0 to r1 are done (from the thread that swept
        them): for progress reports.
    occlusion : bool
        The 'lcn-occlusion' cost: over each window, the least of all views' cost and the costs
        without one view (:func:`lfring.depth.costs.lcn_occlusion.occlusion_aggregate`).
    halves : (N, h, w) float32, optional
        With ``volume``: filled with every hypothesis's least aggregated cost of a half of the
        views (:func:`lfring.depth.costs.lcn_halves.view_halves`, :func:`lfring.depth.costs.lcn_halves.half_aggregate`;
        inf where no half counts), for :func:`lfring.depth.costs.lcn_halves.take_halves`.

    Returns
    -------
    best_i : (h, w) int32
    c_best, c_prev, c_next, c_second, nviews : (h, w) float32
        As :func:`lfring.depth.sweep.slices.sweep_slices` defines them (c_second exact, see
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
    occlusion = occlusion and bool(leavable_views(hs))  # nothing to leave out of a pair
    halves_of = checked_halves(halves, volume, hs, (h, w))
    keep = occlusion or bool(halves_of)  # every view's rendering is kept for the other subsets
    shifts = translations(hs, (h, w))
    if shifts is not None:  # one engine per view, one slot per hypothesis, from padded copies
        engines = {k: ShiftEngine(shifts[:, k], (h, w)) for k in moving}
        padded = {k: (engines[k].padded(weighted[k], (k, 0)), engines[k].padded(masks[k], (k, 1))) for k in moving}
    else:
        inverse = np.linalg.inv(hs)  # view from reference
    # As many strips as fit STRIP_PIXELS, rounded up to a multiple of the threads, of equal height.
    threads = max(1, int(threads))
    most = max(8, STRIP_PIXELS // max(w, 1) - 2 * pad)
    count = threads * -(-h // (threads * most))
    rows = max(1, -(-h // count))
    strips = [(r0, min(h, r0 + rows)) for r0 in range(0, h, rows)]
    if volume is not None and (volume.shape != (n, h, w) or volume.dtype != np.float32):
        raise ValueError(f"volume must be float32 {(n, h, w)}, got {volume.dtype} {volume.shape}")
    nviews_all = None
    if on_strip is None and volume is not None:
        nviews_all = np.empty((h, w), np.float32)

        def on_strip(r0, r1, nviews):
            nviews_all[r0:r1] = nviews
        out = None
    elif on_strip is None:
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
        s1, s2, cnt, a_buf, wt_buf, t, agg, zeros, tmp, bad = (b[:big] for b in bufs[:10])
        per_view = [(b[0][:big], b[1][:big]) for b in bufs[10]]  # occlusion, halves: every view's rendering
        static = [k for k in range(v) if identity[k]]
        base = None
        if static:
            base = (sum(weighted[k][q0:q1] for k in static), sum(weighted_square(weighted[k][q0:q1], masks[k][q0:q1]) for k in static),
                    sum(masks[k][q0:q1] for k in static))
        run = RunningMinimum((m, w), exclude) if volume is None else None
        missing = np.full((m, w), np.inf, np.float32)
        nviews = np.zeros((m, w), np.float32)
        if shifts is None:
            shift_rows = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, q0], [0.0, 0.0, 1.0]])
        for i in range(n):
            first = True
            rendered = {} if keep else None  # the moving views' renderings, for the other subsets
            for j, k in enumerate(moving):
                if keep:
                    a_buf, wt_buf = per_view[j]
                if shifts is not None:
                    a = engines[k].render_padded(i, padded[k][0], q0, q1, a_buf, tmp)
                    wt = engines[k].render_padded(i, padded[k][1], q0, q1, wt_buf, tmp)
                else:
                    g = inverse[i, k] @ shift_rows
                    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
                    a = cv2.warpPerspective(weighted[k], g, (w, big), dst=a_buf, flags=flags, borderMode=cv2.BORDER_CONSTANT)
                    wt = cv2.warpPerspective(masks[k], g, (w, big), dst=wt_buf, flags=flags, borderMode=cv2.BORDER_CONSTANT)
                # S2's term a^2 / max(w, floor) (weighted_square), as a times a / max(w, floor):
                # t and agg are free until the sums are done.
                n_k = cv2.divide(a, cv2.max(wt, WEIGHT_FLOOR, dst=agg), dst=t)
                if first and base is not None:  # the views that do not move start the sums
                    cv2.add(base[0], a, dst=s1)
                    np.copyto(s2, base[1])
                    cv2.accumulateProduct(a, n_k, s2)
                    cv2.add(base[2], wt, dst=cnt)
                    first = False
                elif first:
                    np.copyto(s1, a)
                    cv2.multiply(a, n_k, dst=s2)
                    np.copyto(cnt, wt)
                    first = False
                else:
                    cv2.add(s1, a, dst=s1)
                    cv2.accumulateProduct(a, n_k, s2)
                    cv2.add(cnt, wt, dst=cnt)
                if keep:
                    rendered[k] = (a, wt)
            # c = (S2 - S1^2 / C) / (C - 1), aggregated over the pixels 1.5 views or more see.
            cv2.multiply(s1, s1, dst=t)
            cv2.divide(t, cnt, dst=t)
            cv2.subtract(s2, t, dst=t)
            cv2.subtract(cnt, 1.0, dst=tmp[:, :w])
            cv2.divide(t, tmp[:, :w], dst=t)  # C - 1 >= 0.5 wherever the result is kept:
            cv2.compare(cnt, 1.5, cv2.CMP_LT, dst=bad)
            box = lambda c, dst=None: box_filter(c, aggregate_px, dst=dst)
            support = None  # as costs.aggregate: the window's mean over the pixels 1.5 views see
            if cv2.countNonZero(bad):
                cv2.copyTo(zeros, bad, dst=t)
                support = box(cv2.bitwise_not(bad))  # 255 where seen
                cv2.max(support, 255.0 * WEIGHT_FLOOR, dst=support)
                cv2.multiply(support, 1.0 / 255.0, dst=support)
            box(t, dst=agg)
            if support is not None:
                cv2.divide(agg, support, dst=agg)
            if halves_of:
                least = bufs[12][:big]
                least.fill(np.inf)
                seen = bad == 0
                for half in halves_of:
                    parts = [rendered[k] if k in rendered else (weighted[k][q0:q1], masks[k][q0:q1]) for k in half]
                    half_aggregate(parts, seen, box, least, [b[:big] for b in bufs[13]])
                np.copyto(halves[i, r0:r1], least[o0:o0 + m])
            if occlusion:
                one = bufs[11][:big]

                def leave_out(a_k, w_k):
                    lcn_leave_one_out(s1, s2, cnt, a_k, w_k, out=one)
                    if support is not None:
                        cv2.copyTo(zeros, bad, dst=one)
                    return one, w_k

                seen_box = box if support is None else (lambda c: cv2.divide(box(c), support))
                occlusion_aggregate(agg, cnt, (leave_out(a_k, w_k) for a_k, w_k in rendered.values()), seen_box, box)
            cur = run.slot() if volume is None else volume[i, r0:r1]
            np.copyto(cur, agg[o0:o0 + m])
            cv2.copyTo(missing, bad[o0:o0 + m], dst=cur)
            cv2.max(nviews, cnt[o0:o0 + m], dst=nviews)
            if run is not None:
                run.push()
        if run is None:
            on_strip(r0, r1, nviews)
        else:
            on_strip(r0, r1, run.best_i, run.best, run.c_prev, run.c_next, run.second(), nviews)
        if on_rows is not None:
            on_rows(r0, r1)

    local = threading.local()

    def task(r0: int, r1: int) -> None:
        if not hasattr(local, "bufs"):  # this thread's strip buffers
            big = min(h, rows + 2 * pad)
            local.bufs = [np.empty((big, w), np.float32) for _ in range(7)]
            local.bufs += [np.zeros((big, w), np.float32), np.empty((big, w + 1), np.float32), np.empty((big, w), np.uint8)]
            local.bufs.append([(np.empty((big, w), np.float32), np.empty((big, w), np.float32)) for _ in moving]
                              if keep else [])
            local.bufs.append(np.empty((big, w), np.float32) if occlusion else None)
            local.bufs.append(np.empty((big, w), np.float32) if halves_of else None)
            local.bufs.append([np.empty((big, w), np.float32) for _ in range(5)] if halves_of else None)
        strip(r0, r1, local.bufs)

    run_threads([lambda s=s: task(*s) for s in strips], threads)
    if nviews_all is not None:
        return nviews_all
    if out is not None:
        return best_i, out["c_best"], out["c_prev"], out["c_next"], out["second"], out["nviews"]
    return None
