"""Refocusing at metric depth, focal stacks and all-in-focus images (SPEC 5).

Refocusing at depth Z warps every view into the reference frame with ``H_ref_from_view(Z)``
and averages them, each pixel weighted by how many views are valid there, so the borders are
not darkened. Objects at Z line up and are sharp; others appear as displaced copies.
"""

from __future__ import annotations

import os
import threading
import warnings
import weakref
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np

from lfring.errors import InvalidInputError, LfringWarning

__all__ = ["Refocuser", "refocus", "focal_stack", "all_in_focus", "warp_views", "view_masks", "depth_hypotheses", "view_motion_px"]


def _check_views(views) -> np.ndarray:
    arr = np.asarray(views)
    if arr.ndim == 3:
        arr = arr[..., None]
    if arr.ndim != 4:
        raise InvalidInputError(f"views must be (V, h, w) or (V, h, w, C), got shape {np.shape(views)}")
    if arr.dtype != np.float32:
        raise InvalidInputError(f"views must be float32 in [0, 1] (lfring.split_views gives that), got {arr.dtype}")
    if arr.shape[0] < 1 or min(arr.shape[1:3]) < 2:
        raise InvalidInputError(f"views must hold at least one view of 2 x 2 px, got shape {arr.shape}")
    if arr.shape[-1] > 4:
        raise InvalidInputError(f"views may have 1 to 4 channels, got {arr.shape[-1]}")
    return arr


TAPER = 0.15
INTERPOLATIONS = {"linear": cv2.INTER_LINEAR, "cubic": cv2.INTER_CUBIC}


def _interp(name: str) -> int:
    if name not in INTERPOLATIONS:
        raise InvalidInputError(f"interpolation must be one of {', '.join(INTERPOLATIONS)}, got {name!r}")
    return INTERPOLATIONS[name]


# Masks depend only on the calibration and the view shape: made once per calibration object.
_MASK_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _cached_masks(calibration, view_shape, channels: int):
    """(V, h, w) masks, the same repeated over ``channels`` (a list of (h, w[, C])) and whether
    every view is valid everywhere (all ones)."""
    per_cal = _MASK_CACHE.setdefault(calibration, {})
    key = (tuple(view_shape), channels)
    if key not in per_cal:
        one = (tuple(view_shape), 1)
        if one in per_cal:
            base, _, all_valid = per_cal[one]
        else:
            base = view_masks(calibration, view_shape)
            all_valid = bool(np.all(base == 1.0))
        rep = [m if channels == 1 else np.repeat(m[..., None], channels, axis=2) for m in base]
        per_cal[key] = (base, rep, all_valid)
    return per_cal[key]


def view_masks(calibration, view_shape, *, taper: float = TAPER) -> np.ndarray:
    """(V, h, w) float32 weight of every view pixel: 0 outside the layout's valid disc, rising
    smoothly (raised cosine) over the outer ``taper`` fraction of its radius to 1 (all ones
    without discs). The taper hides the seams a hard edge would leave where the number of
    contributing views changes, since views are darkest (vignetted) at their edges."""
    layout = calibration.layout
    if tuple(view_shape) != layout.view_shape:
        raise InvalidInputError(
            f"views are {view_shape[1]} x {view_shape[0]} px but the calibration's layout cuts "
            f"{layout.view_shape[1]} x {layout.view_shape[0]} px views"
        )
    h, w = view_shape
    if layout.circles is None:
        return np.ones((layout.num_views, h, w), np.float32)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    out = []
    for cx, cy, r in layout.circles:
        t = np.clip((r + 0.5 - np.sqrt((xx - cx) ** 2 + (yy - cy) ** 2)) / max(taper * r, 1.0), 0.0, 1.0)
        out.append(0.5 - 0.5 * np.cos(np.pi * t))
    return np.stack(out).astype(np.float32)


def _inverse_weight(weight: np.ndarray) -> np.ndarray:
    """1 / weight where some view is valid (weight > 1e-3), else 0; float32."""
    weight = np.asarray(weight, dtype=np.float32)
    inv = np.zeros_like(weight)
    return np.divide(np.float32(1.0), weight, out=inv, where=weight > 1e-3)


def _warp(src: np.ndarray, h: np.ndarray, size_wh, dst=None, *, interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
    """Warp by H (view -> reference); pure translations and affine maps take the cheaper path."""
    if abs(h[2, 0]) < 1e-12 and abs(h[2, 1]) < 1e-12:
        return cv2.warpAffine(src, h[:2].astype(np.float64), size_wh, dst=dst, flags=interpolation, borderMode=cv2.BORDER_CONSTANT)
    return cv2.warpPerspective(src, h, size_wh, dst=dst, flags=interpolation, borderMode=cv2.BORDER_CONSTANT)


def warp_views(views, H_ref_from_view, *, masks=None, out_shape=None, interpolation: str = "linear"):
    """Warp every view into the reference frame.

    Parameters
    ----------
    views : (V, h, w, C) float32
    H_ref_from_view : (V, 3, 3)
    masks : (V, h, w) float32, optional
        Valid weight of every view pixel (see :func:`view_masks`); ones when None.
    out_shape : (h, w), optional
        Size of the reference frame (the views' size by default).
    interpolation : {'linear', 'cubic'}

    Returns
    -------
    warped : (V, H, W, C) float32
        Each view warped and multiplied by its warped mask (zero where it is not valid).
    weights : (V, H, W) float32
        The warped masks.
    """
    arr = _check_views(views)
    hs = np.asarray(H_ref_from_view, dtype=np.float64)
    if hs.shape != (arr.shape[0], 3, 3):
        raise InvalidInputError(f"need one 3 x 3 homography per view, got {hs.shape} for {arr.shape[0]} views")
    flag = _interp(interpolation)
    oh, ow = out_shape or arr.shape[1:3]
    warped = np.empty((arr.shape[0], oh, ow, arr.shape[3]), np.float32)
    weights = np.empty((arr.shape[0], oh, ow), np.float32)
    for k in range(arr.shape[0]):
        m = np.ones(arr.shape[1:3], np.float32) if masks is None else masks[k]
        _warp(m, hs[k], (ow, oh), dst=weights[k])
        src = arr[k] if masks is None else arr[k] * m[..., None]
        out = _warp(src, hs[k], (ow, oh), dst=warped[k], interpolation=flag)
        if out.ndim == 2:
            warped[k, ..., 0] = out
    return warped, weights


# Views whose homography is a translation to within this many pixels over the whole reference
# frame take the shift path (constant bilinear weights); others take the general warp.
TRANSLATION_TOL_PX = 1e-3
# Rows per strip of the shift path: a strip's accumulator and two scratch buffers take about
# this many bytes, so they stay in the L3 cache (each view is read from memory once and the
# intermediate images of the bilinear stencil never go back to it), while every OpenCV call is
# long enough that two threads seldom wait for each other's Python in between (the GIL). On the
# benchmark machine (32 MiB L3) 2 to 6 MiB were best, 0.6 MiB (strips fit for L2) 1.8x slower.
STRIP_BYTES = 3 << 20

_POOL: tuple | None = None  # (pid, executor, workers)


def _pool(workers: int) -> ThreadPoolExecutor:
    """The shift path's worker threads, made anew in a forked child (which has none of them)."""
    global _POOL
    if _POOL is None or _POOL[0] != os.getpid() or _POOL[2] < workers:
        _POOL = (os.getpid(), ThreadPoolExecutor(max_workers=workers, thread_name_prefix="lfring-refocus"), workers)
    return _POOL[1]


def _run_threads(tasks, threads: int) -> None:
    """Run the callables, shared among ``threads`` threads: this one and the pool's (which take
    the next task as they free up; OpenCV and NumPy release the GIL)."""
    lock = threading.Lock()
    todo = iter(tasks)

    def worker() -> None:
        while True:
            with lock:
                task = next(todo, None)
            if task is None:
                return
            task()

    threads = max(1, min(int(threads), len(tasks)))
    if threads == 1:
        worker()
        return
    futures = [_pool(threads - 1).submit(worker) for _ in range(threads - 1)]
    try:
        worker()
    finally:
        for f in futures:
            f.result()


_SCRATCH = threading.local()


def _scratch(rows: int, w: int, tail: tuple):
    """This thread's scratch strips of the shift path, reused from frame to frame (fresh ones
    would cost page faults every frame): the padded vertical pass (its two pad columns are
    never written, so stay zero), the horizontal pass, masked rows and spread channels."""
    key = (rows, w, tail)
    if getattr(_SCRATCH, "key", None) != key:
        _SCRATCH.key = key
        _SCRATCH.bufs = (np.zeros((rows, w + 2, *tail), np.float32), np.empty((rows, w, *tail), np.float32),
                         np.empty((rows + 1, w, *tail), np.float32), np.empty((rows + 1, w, *tail), np.float32))
    return _SCRATCH.bufs


def _translation_of(h: np.ndarray, out_shape, *, tol_px: float = TRANSLATION_TOL_PX):
    """The shift ``s`` (x, y) such that reference pixel ``x`` samples view pixel ``x + s`` to
    within ``tol_px`` everywhere in the reference frame of ``out_shape``, or None.

    ``G = H^-1`` maps reference pixels to view pixels. With ``q(x) = g.x + 1`` its denominator
    (positive over the frame, else None), ``G(x) - x - s = (L(x) - x (g.x)) / q(x)`` where ``L``
    is affine, so ``|G(x) - x - s| <= (max|L| + max|x| max|g.x|) / min q`` with every maximum
    and minimum taken at the frame's corners: a rigorous bound, not a sample.
    """
    try:
        g = np.linalg.inv(np.asarray(h, dtype=np.float64))
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(g)) or g[2, 2] == 0:
        return None
    g = g / g[2, 2]
    rows, cols = out_shape
    corners = np.array([[0, 0], [cols - 1, 0], [0, rows - 1], [cols - 1, rows - 1]], dtype=np.float64)
    gx = corners @ g[2, :2]
    q = gx + 1.0
    if q.min() <= 0:
        return None
    centre = np.array([(cols - 1) / 2, (rows - 1) / 2])
    s = (g[:2, :2] @ centre + g[:2, 2]) / (g[2, :2] @ centre + 1.0) - centre
    lin = corners @ (g[:2, :2] - np.eye(2) - np.outer(s, g[2, :2])).T + (g[:2, 2] - s)
    bound = (np.abs(lin).max(axis=0) + corners.max(axis=0) * np.abs(gx).max()) / q.min()
    return s if bound.max() <= tol_px else None


def _edge_weights(shift: float, n: int) -> np.ndarray:
    """(n,) bilinear weight of a zero-padded line of ones shifted by ``shift``: what warping an
    all-valid view gives along one axis (1 inside, the fraction at the two edge pixels)."""
    i = int(np.floor(shift))
    f = shift - i
    pos = np.arange(n) + i  # the line's pixel under the first tap
    return (np.where((pos >= 0) & (pos < n), 1.0 - f, 0.0) + np.where((pos + 1 >= 0) & (pos + 1 < n), f, 0.0))


class _ShiftPlan:
    """Refocus by pure shifts: bilinear resampling with constant weights, fused in row strips.

    Reference pixel (x, y) of view k is ``(1-fy) [(1-fx) v(y', x') + fx v(y', x'+1)] + fy [...
    row y'+1 ...]`` with ``x' = x + ix``, ``y' = y + iy`` and the views zero outside (as
    ``cv2.warpAffine`` with a constant border). Per strip of output rows and per view: one
    vertical two-tap pass reads the view's rows from memory into a cache-resident buffer (with
    a zero column on either side, so the horizontal edges need no special case), one
    horizontal two-tap pass and one add accumulate it; then the strip is normalised. Strips
    are shared among OpenCV's number of threads (the calls release the GIL).
    """

    def __init__(self, shifts: np.ndarray, view_shape, masks=None):
        h, w = view_shape
        self.view_shape = (h, w)
        self.masks = masks  # (V, h, w) or None when every view is valid everywhere
        self.shifts = np.asarray(shifts, dtype=np.float64)
        ints = np.floor(shifts).astype(int)
        self.geometry = [(int(ix), int(iy), float(sx - ix), float(sy - iy))
                         for (sx, sy), (ix, iy) in zip(shifts, ints)]
        self._strips: dict[int, list] = {}
        self._inv_bands = None

    # -- geometry ------------------------------------------------------------------------
    def strips(self, rows: int) -> list:
        """Per strip of ``rows`` output rows: (s0, s1, steps, bands), ``steps`` per view
        touching the strip (its slices made here, once, so a frame only applies them) and
        ``bands`` the row bands of the all-valid normalisation within the strip."""
        if rows not in self._strips:
            h, w = self.view_shape
            masked = self.masks is not None
            per_view = []  # what does not depend on the strip
            for k, (ix, iy, fx, fy) in enumerate(self.geometry):
                # Output pixels whose taps touch the view: x + ix in [-1, w - 1].
                x0, x1 = max(0, -ix - 1), min(w, w - ix)
                if x0 >= x1:
                    continue
                c0, c1 = max(0, x0 + ix), min(w, x1 + ix + 1)  # view columns read
                a, m = x0 + ix + 1, x1 - x0
                # Columns of the source: the view itself, or its masked rows in scratch.
                cs = slice(0, c1 - c0) if masked else slice(c0, c1)
                per_view.append((k, ix, iy, np.float32(fy), np.float32(1.0 - fy), fx, c0, c1, slice(c0, c1), slice(0, c1 - c0),
                                 cs, slice(c0 + 1, c1 + 1), slice(a, a + m), slice(a + 1, a + 1 + m), slice(0, m), slice(x0, x1),
                                 [slice(0, x0)] * (x0 > 0) + [slice(x1, w)] * (x1 < w)))
            bands = self.inv_bands() if not masked else []
            plan = []
            for s0 in range(0, h, rows):
                s1 = min(s0 + rows, h)
                n = s1 - s0
                out_rows, strip_rows = slice(s0, s1), slice(0, n)
                steps = []
                for k, ix, iy, fy, gy, fx, c0, c1, vcols, tcols, cs, cols, ha, hb, hm, dcols, clear in per_view:
                    y0, y1 = max(s0, -iy - 1), min(s1, h - iy)
                    if y0 >= y1:
                        continue
                    r0, r1 = max(0, y0 + iy), min(h, y1 + iy + 1)  # view rows read
                    b0, b1 = max(y0, -iy), min(y1, h - 1 - iy)  # output rows with both taps inside
                    ro = r0 if masked else 0  # the source's first row
                    zeros = [(slice(0, y0 - s0), cols)] if y0 > s0 else []
                    if y1 < s1:
                        zeros.append((slice(y1 - s0, n), cols))
                    # The view's first row under the second tap only; its last under the first only.
                    top = ((0 - ro, cs), fy, (y0 - s0, cols)) if b0 > y0 else None
                    bottom = ((h - 1 - ro, cs), gy, (b1 - s0, cols)) if y1 > b1 else None
                    both = (((slice(b0 + iy - ro, b1 + iy - ro), cs), 1.0 - fy, (slice(b0 + iy + 1 - ro, b1 + iy + 1 - ro), cs),
                             float(fy), (slice(b0 - s0, b1 - s0), cols)) if b1 > b0 else None)
                    steps.append((k, (slice(r0, r1), vcols), (slice(0, r1 - r0), tcols), zeros, top, both, bottom,
                                  ((strip_rows, ha), 1.0 - fx, (strip_rows, hb), fx), (strip_rows, hm), (out_rows, dcols),
                                  [(out_rows, c) for c in clear]))
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
                bands.append((y0, y1, weight, _inverse_weight(weight)))
            self._inv_bands = bands
        return self._inv_bands

    # -- per frame -----------------------------------------------------------------------
    def run(self, views: np.ndarray, out: np.ndarray, *, masks=None, inv=None, inv_rows=None, threads: int = 1):
        """Accumulate the shifted views (V, h, w[, C]) into ``out`` (h, w[, C]) and normalise it
        by ``inv`` ((h, w) map) or, for an all-valid plan, ``inv_rows`` (the inverse row of every
        band of :meth:`inv_bands`, shaped (w[, C])), if given. A plan with masks multiplies
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
                    for z in zeros:
                        tv[z] = 0
                    if top is not None:
                        np.multiply(src[top[0]], top[1], out=tv[top[2]])
                    if both is not None:
                        weighted(src[both[0]], both[1], src[both[2]], both[3], 0.0, dst=tv[both[4]])
                    if bottom is not None:
                        np.multiply(src[bottom[0]], bottom[1], out=tv[bottom[2]])
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

        _run_threads([lambda c=c: work(c) for c in chunks], threads)
        return out


class Refocuser:
    """Refocus many frames at one depth: warps, masks and normalisation are computed once.

    An inspection line refocuses thousands of frames at one depth; this does the geometry
    once and leaves each frame with the resampling and one normalisation.

    Parameters
    ----------
    calibration : RingCalibration
    depth_m : float
        Distance from the main lens, metres.
    reference : 'center' or int
    view_shape : (h, w), optional
        Size of the views (the calibration's layout's by default).
    interpolation : {'linear', 'cubic'}
        Bilinear is fastest; bicubic keeps more detail and its smoothing depends less on the
        sub-pixel phase of each view's shift.
    threads : int, optional
        Threads for the shift path (default: OpenCV's, ``cv2.getNumThreads()``).

    Notes
    -----
    When every view's ``H_ref_from_view`` is a translation to within ``TRANSLATION_TOL_PX``
    (1e-3 px) over the whole reference frame, as for a ring whose views are parallel pinhole
    cameras of one focal length, bilinear resampling has the same four weights at every pixel:
    the views are then shifted and accumulated strip by strip in the cache (``shift_path`` is
    True). Otherwise every view goes through ``cv2.warpAffine`` / ``cv2.warpPerspective``.
    Both give the same image to float32 rounding.

    Examples
    --------
    >>> from lfring.calibration.defaults import default_calibration
    >>> cal, _ = default_calibration((2456, 1842))
    >>> r = Refocuser(cal, 0.5)
    >>> import numpy as np
    >>> views = np.full((4, *cal.layout.view_shape, 3), 0.5, np.float32)
    >>> out = r(views)
    >>> out.shape, float(round(out[352, 352, 0], 6))
    ((705, 705, 3), 0.5)
    """

    def __init__(self, calibration, depth_m: float, *, reference="center", view_shape=None, interpolation: str = "linear",
                 threads: int | None = None):
        if np.ndim(depth_m) != 0:
            raise InvalidInputError("Refocuser takes one depth; use focal_stack for several")
        if threads is not None and (isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1):
            raise InvalidInputError(f"threads must be a positive integer or None, got {threads!r}")
        self.depth_m = float(depth_m)
        self.reference = reference
        self._flag = _interp(interpolation)
        self.view_shape = tuple(view_shape or calibration.layout.view_shape)
        self.threads = threads
        self.H = calibration.homographies(self.depth_m, reference=reference)
        self._calibration = calibration
        self.masks, _, self._all_valid = _cached_masks(calibration, self.view_shape, 1)
        self._shift = None
        if self._flag == cv2.INTER_LINEAR:
            shifts = [_translation_of(hk, self.view_shape) for hk in self.H]
            if all(s is not None for s in shifts):
                self._shift = _ShiftPlan(np.array(shifts), self.view_shape, None if self._all_valid else self.masks)
        self._weight = None
        self._inv = None
        self._cache: dict[int, tuple] = {}

    @property
    def shift_path(self) -> bool:
        """Whether frames take the shift path (every homography a translation)."""
        return self._shift is not None

    @property
    def weight(self) -> np.ndarray:
        """(h, w) number of views that see each reference pixel (fractional at edges)."""
        if self._weight is None:
            h, w = self.view_shape
            weight = np.zeros((h, w), np.float32)
            if self._shift is not None and self._all_valid:
                for y0, y1, row, _ in self._shift.inv_bands():
                    weight[y0:y1] = row
            elif self._shift is not None:  # the masks shifted like the views (not masked again)
                _ShiftPlan(self._shift.shifts, self.view_shape).run(self.masks, weight)
            else:
                for k in range(len(self.H)):
                    weight += _warp(self.masks[k], self.H[k], (w, h))
            self._weight = weight
        return self._weight

    def _inverse(self) -> np.ndarray:
        if self._inv is None:
            self._inv = _inverse_weight(self.weight)
        return self._inv

    def _buffers(self, c: int):
        """Per channel count: the normalisation (a map like the result, or per band of rows one
        row) and the masks shaped like a view, made once and reused for every frame.

        With masks on the shift path, a Refocuser's first frame (all that a one-shot
        :func:`refocus` makes) takes the single-channel masks and inverse weight, spread over
        the channels strip by strip in the cache, rather than first writing a full-size
        per-depth map; later frames read the maps shaped like a view, which is faster per
        frame. Both give the same bits."""
        first = c not in self._cache
        if first or self._cache[c] is None:
            masks = None if self._all_valid else _cached_masks(self._calibration, self.view_shape, c)[1]
            if self._shift is not None and self._all_valid:
                inv = [row if c == 1 else np.repeat(row[:, None], c, axis=1) for _, _, _, row in self._shift.inv_bands()]
            elif self._shift is not None and first:
                self._cache[c] = None
                return self._inverse(), self.masks
            else:
                inv = self._inverse() if c == 1 else cv2.merge([self._inverse()] * c)
            self._cache[c] = (inv, masks)
        return self._cache[c]

    def __call__(self, views) -> np.ndarray:
        """The refocused image, (h, w, C) float32, of one frame's views (V, h, w, C)."""
        arr = _check_views(views)
        if arr.shape[1:3] != self.view_shape or arr.shape[0] != len(self.H):
            raise InvalidInputError(f"expected {len(self.H)} views of {self.view_shape[1]} x {self.view_shape[0]} px, got shape {arr.shape}")
        c = arr.shape[3]
        inv, masks = self._buffers(c)
        h, w = self.view_shape
        src = np.ascontiguousarray(arr[..., 0] if c == 1 else arr)
        if self._shift is not None:
            out = np.empty((h, w) if c == 1 else (h, w, c), np.float32)
            threads = cv2.getNumThreads() if self.threads is None else self.threads
            if self._all_valid:
                self._shift.run(src, out, inv_rows=inv, threads=threads)
            else:
                self._shift.run(src, out, masks=masks, inv=inv, threads=threads)
            return out[..., None] if c == 1 else out
        shape = (h, w) if c == 1 else (h, w, c)
        tmp, masked = np.empty(shape, np.float32), np.empty(shape, np.float32)
        acc = None
        for k in range(len(self.H)):
            if masks is None:
                s_k = src[k]
            else:
                s_k = cv2.multiply(src[k], masks[k], dst=masked)
            if acc is None:  # the first view is warped straight into the result
                acc = _warp(s_k, self.H[k], (w, h), interpolation=self._flag)
            else:
                _warp(s_k, self.H[k], (w, h), dst=tmp, interpolation=self._flag)
                cv2.add(acc, tmp, dst=acc)
        cv2.multiply(acc, inv, dst=acc)
        if self._flag != cv2.INTER_LINEAR:
            np.clip(acc, 0.0, None, out=acc)  # bicubic overshoots below zero at dark edges
        return acc[..., None] if c == 1 else acc


def refocus(views, calibration, depth_m: float, *, reference="center", interpolation: str = "linear",
            backend: str = "numpy", device=None) -> np.ndarray:
    """Refocus the views at ``depth_m`` metres from the main lens.

    Parameters
    ----------
    views : (V, h, w, C) float32 in [0, 1]
        From :func:`lfring.split_views` with the calibration's layout.
    calibration : RingCalibration
    depth_m : float
        Must be positive and beyond the calibration's depth origin; outside its valid range it
        warns (:class:`lfring.LfringWarning`).
    reference : 'center' or int
        Frame of the result: the virtual central view (default) or a view index.
    interpolation : {'linear', 'cubic'}
    backend : {'numpy', 'torch'}
        'torch' runs on ``device`` (CUDA when present by default) through kornia, and also
        takes batches (B, V, h, w, C); see :func:`lfring.backends.torch_refocus.refocus_torch`.
    device : str, optional
        For the torch backend, e.g. 'cuda' or 'cpu'.

    Returns
    -------
    (h, w, C) float32

    Notes
    -----
    ``out(x) = sum_k m_k(H_k^-1 x) v_k(H_k^-1 x) / sum_k m_k(H_k^-1 x)`` with ``H_k =
    H_ref_from_k(Z)`` and ``m_k`` the valid disc of view k, bilinear interpolation.
    For many frames at one depth, build a :class:`Refocuser` once.
    """
    from lfring.backends import BACKENDS

    if backend not in BACKENDS:
        raise InvalidInputError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    if backend == "torch":
        from lfring.backends.torch_refocus import refocus_torch

        return refocus_torch(views, calibration, depth_m, reference=reference, device=device, interpolation=interpolation)
    arr = _check_views(views)
    return Refocuser(calibration, depth_m, reference=reference, view_shape=arr.shape[1:3], interpolation=interpolation)(arr)


def focal_stack(views, calibration, depths_m, *, reference="center", interpolation: str = "linear") -> np.ndarray:
    """Refocus at every depth of ``depths_m``: (N, h, w, C) float32."""
    z = np.atleast_1d(np.asarray(depths_m, dtype=np.float64))
    if z.ndim != 1 or z.size == 0:
        raise InvalidInputError(f"depths_m must be a non-empty list of depths, got {depths_m!r}")
    arr = _check_views(views)
    calibration.check_depth(z)  # validates and warns once for the whole stack
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)
        return np.stack([refocus(arr, calibration, float(d), reference=reference, interpolation=interpolation) for d in z])


def view_motion_px(calibration, depths_m, view_shape) -> float:
    """Largest distance any view pixel moves in the reference frame between consecutive depths
    of ``depths_m`` (its corners bound it: the maps are affine, or nearly so)."""
    from lfring.geometry import apply_homography

    h, w = view_shape
    corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]], dtype=np.float64)
    hs = calibration.model(np.asarray(depths_m, dtype=np.float64))
    steps = [np.abs(apply_homography(hs[i, k], corners) - apply_homography(hs[i + 1, k], corners)).max()
             for i in range(len(hs) - 1) for k in range(hs.shape[1])]
    return float(max(steps)) if steps else 0.0


def depth_hypotheses(calibration, zmin_m: float, zmax_m: float, *, num=None, max_step_px: float = 1.0) -> np.ndarray:
    """Depths between ``zmin_m`` and ``zmax_m`` evenly spaced in 1/(Z - z0) (evenly in disparity),
    by default close enough that no view moves more than ``max_step_px`` between neighbours."""
    z0 = calibration.depth_origin_m
    for name, v in (("zmin_m", zmin_m), ("zmax_m", zmax_m)):
        if not (isinstance(v, (int, float, np.floating)) and np.isfinite(v) and v > 0):
            raise InvalidInputError(f"{name} must be a positive number of metres, got {v!r}")
    if not zmin_m < zmax_m:
        raise InvalidInputError(f"zmin_m ({zmin_m}) must be smaller than zmax_m ({zmax_m})")
    if zmin_m <= z0:
        raise InvalidInputError(f"zmin_m ({zmin_m}) must lie beyond the depth origin z0 = {z0:.4g} m")
    if num is None:
        move = view_motion_px(calibration, [zmin_m, zmax_m], calibration.layout.view_shape)
        num = max(2, int(np.ceil(move / max_step_px)) + 1)
    if isinstance(num, bool) or not isinstance(num, (int, np.integer)) or num < 2:
        raise InvalidInputError(f"the number of depths must be an integer >= 2, got {num!r}")
    inv = np.linspace(1.0 / (zmin_m - z0), 1.0 / (zmax_m - z0), int(num))
    return z0 + 1.0 / inv


def all_in_focus(views, calibration, depths_m=None, *, depth_map_m=None, reference="center", window_px: int = 7):
    """An all-in-focus image: every pixel from the refocused image where it is sharpest.

    Parameters
    ----------
    views : (V, h, w, C) float32
    calibration : RingCalibration
    depths_m : sequence of float, optional
        Depths to choose from (default: the calibration's valid range, evenly in disparity,
        one pixel apart).
    depth_map_m : (h, w) float, optional
        Depth of every reference pixel (from :func:`lfring.estimate_depth`, say): each pixel is
        then refocused at its own depth, taken from the nearest of ``depths_m``.
    window_px : int
        Side of the box over which the photo-consistency is averaged.

    Returns
    -------
    image : (h, w, C) float32
    depth_m : (h, w) float32
        The depth each pixel was taken from.

    Notes
    -----
    Without a depth map, the focus measure is photo-consistency: at the right depth the
    warped views agree, so their weighted variance, averaged over a small window, is least.
    The sweep is streamed: memory does not grow with the number of depths.
    """
    arr = _check_views(views)
    h, w = arr.shape[1:3]
    if depths_m is None:
        lo, hi = calibration.valid_depth_range_m
        if hi is None:
            raise InvalidInputError("give depths_m: the calibration has no upper depth bound")
        depths_m = depth_hypotheses(calibration, lo, hi)
    z = np.atleast_1d(np.asarray(depths_m, dtype=np.float64))
    calibration.check_depth(z)
    masks = view_masks(calibration, (h, w))
    if depth_map_m is not None:
        dm = np.asarray(depth_map_m, dtype=np.float64)
        if dm.shape != (h, w):
            raise InvalidInputError(f"depth_map_m must be {h} x {w}, got {dm.shape}")
        target = np.where(np.isfinite(dm), dm, z[0])
    best_cost = np.full((h, w), np.inf, np.float32)
    out = np.zeros((h, w, arr.shape[3]), np.float32)
    chosen = np.full((h, w), np.nan, np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)  # checked once above
        hs = [calibration.homographies(float(d), reference=reference) for d in z]
    for d, hd in zip(z, hs):
        warped, weights = warp_views(arr, hd, masks=masks)
        wsum = weights.sum(axis=0)
        ok = wsum > 1e-3
        mean = warped.sum(axis=0) / np.where(ok, wsum, 1.0)[..., None]
        if depth_map_m is not None:
            cost = np.abs(1.0 / (target - calibration.depth_origin_m) - 1.0 / (d - calibration.depth_origin_m)).astype(np.float32)
        else:
            # Weighted variance across views (warped values are premultiplied by the weights).
            second = (warped**2 / np.maximum(weights, 1e-3)[..., None]).sum(axis=0) / np.where(ok, wsum, 1.0)[..., None]
            var = np.maximum(second - mean**2, 0).mean(axis=2)
            var = np.where(wsum >= 1.5, var, np.inf).astype(np.float32)  # one view alone proves nothing
            cost = cv2.boxFilter(np.where(np.isfinite(var), var, 1e3).astype(np.float32), -1, (window_px, window_px))
        better = (cost < best_cost) & ok
        best_cost[better] = cost[better]
        out[better] = mean[better]
        chosen[better] = d
    return out, chosen
