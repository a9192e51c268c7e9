"""The warping core that refocusing, depth, inspection and their torch twins share.

Every stage that compares or averages views does the same few things: check a view stack, weigh
each view pixel by its valid disc (:func:`view_masks`, made once per calibration and view shape
by :func:`cached_view_masks`, in the one per-calibration cache :func:`calibration_cache`), bring the views into the reference frame (:func:`warp_views`, or
for pure translations the cheaper :class:`ShiftEngine`, chosen by the one translation test
:func:`translation_of`), normalise by the summed weights (:func:`inverse_weight` with the one
:data:`WEIGHT_FLOOR`), and work in row strips on several threads (:func:`run_threads`). The
photo-consistency measures also share :func:`luminance`, :func:`normalised_luminance` and
:func:`box_filter`. They live here, once, so that every stage answers each question the same way.
"""

from __future__ import annotations

import os
import threading
import weakref
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np

from lfring.errors import InvalidInputError

__all__ = [
    "DEFAULT_INTERPOLATION", "INTERPOLATIONS", "STRIP_BYTES", "TAPER", "TRANSLATION_TOL_PX", "WEIGHT_FLOOR", "ShiftEngine", "box_filter",
    "cached_view_masks", "calibration_cache", "check_views", "interpolation_flag", "inverse_weight", "luminance", "normalised_luminance",
    "check_threads", "run_threads", "translation_of", "translations", "view_masks", "warp_image", "warp_views",
]

# A reference pixel whose summed view weight is below this is seen by no view: it gets 0 (images)
# or NaN (depth), and divisions by a weight never divide by less.
WEIGHT_FLOOR = 1e-3
# Fraction of a valid disc's radius over which a view's weight rises from 0 to 1 (view_masks).
TAPER = 0.15
INTERPOLATIONS = {"linear": cv2.INTER_LINEAR, "cubic": cv2.INTER_CUBIC}
# The one default of the library, the CLI and batches: bilinear takes the shift engine (and the
# torch backend has it); bicubic keeps a little more detail at several times the cost.
DEFAULT_INTERPOLATION = "linear"
# A homography is treated as a translation when it is one to within this many pixels over the
# whole reference frame (translation_of proves the bound); refocusing and depth both ask this.
TRANSLATION_TOL_PX = 1e-3
# Rows per strip of the shift engine's accumulation: a strip's accumulator and two scratch buffers
# take about this many bytes, so they stay in the L3 cache (each view is read from memory once
# and the intermediate images of the bilinear stencil never go back to it), while every OpenCV
# call is long enough that two threads seldom wait for each other's Python in between (the GIL).
# On the benchmark machine (32 MiB L3) 2 to 6 MiB were best, 0.6 MiB (strips fit for L2) 1.8x slower.
STRIP_BYTES = 3 << 20


# -- view stacks ----------------------------------------------------------------------------------
def check_views(views, *, min_views: int = 1) -> np.ndarray:
    """A view stack as a (V, h, w, C) float32 array, or a clear error.

    Parameters
    ----------
    views : array_like, (V, h, w) or (V, h, w, C) float32
        ``(V, h, w)`` is taken as one channel.
    min_views : int
        Fewest views the caller can work with.

    Returns
    -------
    (V, h, w, C) float32 (a view of the input, not a copy)

    Examples
    --------
    >>> import numpy as np
    >>> check_views(np.zeros((4, 6, 5), np.float32)).shape
    (4, 6, 5, 1)
    """
    arr = np.asarray(views)
    if arr.ndim == 3:
        arr = arr[..., None]
    if arr.ndim != 4:
        raise InvalidInputError(f"views must be (V, h, w) or (V, h, w, C), got shape {np.shape(views)}")
    if arr.dtype != np.float32:
        raise InvalidInputError(f"views must be float32 in [0, 1] (lfring.split_views gives that), got {arr.dtype}")
    if arr.shape[0] < min_views or min(arr.shape[1:3]) < 2:
        raise InvalidInputError(f"views must hold at least {min_views} view(s) of 2 x 2 px, got shape {arr.shape}")
    if arr.shape[-1] > 4:
        raise InvalidInputError(f"views may have 1 to 4 channels, got {arr.shape[-1]}")
    return arr


def interpolation_flag(name: str) -> int:
    """The OpenCV flag of an interpolation name ('linear' or 'cubic')."""
    if name not in INTERPOLATIONS:
        raise InvalidInputError(f"interpolation must be one of {', '.join(INTERPOLATIONS)}, got {name!r}")
    return INTERPOLATIONS[name]


# -- masks ------------------------------------------------------------------------------------------
def view_masks(calibration, view_shape, *, taper: float = TAPER) -> np.ndarray:
    """(V, h, w) float32 weight of every view pixel: 0 outside the layout's valid disc, rising
    smoothly (raised cosine) over the outer ``taper`` fraction of its radius to 1 (all ones
    without discs). The taper hides the seams a hard edge would leave where the number of
    contributing views changes, since views are darkest (vignetted) at their edges.

    Examples
    --------
    >>> from lfring.calibration.defaults import default_calibration
    >>> cal, _ = default_calibration((2456, 1842))
    >>> m = view_masks(cal, cal.layout.view_shape)
    >>> m.shape, float(m[:, 352, 352].min())
    ((4, 705, 705), 1.0)
    """
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


# The one cache of what is derived from a calibration object (its view masks and what is made
# from them, its nearest renderable depth...): weakly held, it goes with the calibration.
_CALIBRATION_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def calibration_cache(calibration, key, make):
    """``make()`` computed once per calibration object and hashable ``key`` (calibrations are
    immutable: what is derived from one stays true while it lives).

    Examples
    --------
    >>> from lfring.calibration.defaults import default_calibration
    >>> cal, _ = default_calibration((2456, 1842))
    >>> calibration_cache(cal, "answer", lambda: 42), calibration_cache(cal, "answer", lambda: 0)
    (42, 42)
    """
    per_cal = _CALIBRATION_CACHE.setdefault(calibration, {})
    if key not in per_cal:
        per_cal[key] = make()
    return per_cal[key]


def cached_view_masks(calibration, view_shape, derived=None, make=None, *, taper: float = TAPER):
    """:func:`view_masks` (with ``taper``) made once per calibration object, view shape and taper
    (read-only), or with ``derived`` (a hashable key) and ``make`` (a function of the masks), what
    ``make`` derives from them, also made once (e.g. the masks repeated over channels, or their
    box sums).

    Examples
    --------
    >>> from lfring.calibration.defaults import default_calibration
    >>> cal, _ = default_calibration((2456, 1842))
    >>> cached_view_masks(cal, cal.layout.view_shape) is cached_view_masks(cal, cal.layout.view_shape)
    True
    """
    shape = tuple(int(n) for n in view_shape)
    taper = float(taper)

    def make_masks():
        masks = view_masks(calibration, shape, taper=taper)
        masks.setflags(write=False)
        return masks

    masks = calibration_cache(calibration, ("view_masks", shape, taper), make_masks)
    if derived is None:
        return masks
    return calibration_cache(calibration, ("view_masks", shape, taper, derived), lambda: make(masks))


def inverse_weight(weight: np.ndarray) -> np.ndarray:
    """1 / weight where some view is valid (weight > WEIGHT_FLOOR), else 0; float32."""
    weight = np.asarray(weight, dtype=np.float32)
    inv = np.zeros_like(weight)
    return np.divide(np.float32(1.0), weight, out=inv, where=weight > WEIGHT_FLOOR)


# -- warping ----------------------------------------------------------------------------------------
def warp_image(src: np.ndarray, H: np.ndarray, size_wh, dst=None, *, interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
    """Warp one image by ``H`` (view -> reference) into a frame of ``size_wh`` (width, height),
    zero outside; affine maps take ``cv2.warpAffine``, the others ``cv2.warpPerspective``."""
    if abs(H[2, 0]) < 1e-12 and abs(H[2, 1]) < 1e-12:
        return cv2.warpAffine(src, H[:2].astype(np.float64), size_wh, dst=dst, flags=interpolation, borderMode=cv2.BORDER_CONSTANT)
    return cv2.warpPerspective(src, H, size_wh, dst=dst, flags=interpolation, borderMode=cv2.BORDER_CONSTANT)


def warp_views(views, H_ref_from_view, *, masks=None, out_shape=None, interpolation: str = DEFAULT_INTERPOLATION):
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

    Examples
    --------
    >>> import numpy as np
    >>> views = np.ones((2, 4, 5, 1), np.float32)
    >>> H = np.stack([np.eye(3), [[1, 0, 1], [0, 1, 0], [0, 0, 1]]])  # the second moves 1 px right
    >>> warped, weights = warp_views(views, H)
    >>> weights[1, 0].tolist()
    [0.0, 1.0, 1.0, 1.0, 1.0]
    """
    arr = check_views(views)
    hs = np.asarray(H_ref_from_view, dtype=np.float64)
    if hs.shape != (arr.shape[0], 3, 3):
        raise InvalidInputError(f"need one 3 x 3 homography per view, got {hs.shape} for {arr.shape[0]} views")
    flag = interpolation_flag(interpolation)
    oh, ow = out_shape or arr.shape[1:3]
    warped = np.empty((arr.shape[0], oh, ow, arr.shape[3]), np.float32)
    weights = np.empty((arr.shape[0], oh, ow), np.float32)
    for k in range(arr.shape[0]):
        m = np.ones(arr.shape[1:3], np.float32) if masks is None else masks[k]
        warp_image(m, hs[k], (ow, oh), dst=weights[k])
        src = arr[k] if masks is None else arr[k] * m[..., None]
        out = warp_image(src, hs[k], (ow, oh), dst=warped[k], interpolation=flag)
        if out.ndim == 2:
            warped[k, ..., 0] = out
    return warped, weights


def translation_of(H: np.ndarray, out_shape, *, tol_px: float = TRANSLATION_TOL_PX):
    """The shift ``s`` (x, y) such that reference pixel ``x`` samples view pixel ``x + s`` to
    within ``tol_px`` everywhere in the reference frame of ``out_shape`` (h, w), or None.

    This is the one test of "is this homography a translation" that refocusing and depth share.

    Notes
    -----
    ``G = H^-1`` maps reference pixels to view pixels. With ``q(x) = g.x + 1`` its denominator
    (positive over the frame, else None), ``G(x) - x - s = (L(x) - x (g.x)) / q(x)`` where ``L``
    is affine, so ``|G(x) - x - s| <= (max|L| + max|x| max|g.x|) / min q`` with every maximum
    and minimum taken at the frame's corners: a rigorous bound, not a sample.

    Examples
    --------
    >>> import numpy as np
    >>> translation_of(np.array([[1.0, 0, 2.5], [0, 1, -1], [0, 0, 1]]), (10, 20)).tolist()
    [-2.5, 1.0]
    >>> translation_of(np.array([[1.01, 0, 2.5], [0, 1, -1], [0, 0, 1]]), (10, 20)) is None
    True
    """
    s = translations(np.asarray(H, dtype=np.float64)[None], out_shape, tol_px=tol_px)
    return None if s is None else s[0]


def translations(hs, out_shape, *, tol_px: float = TRANSLATION_TOL_PX):
    """(..., 2) sampling shifts of a stack of homographies (..., 3, 3), each as
    :func:`translation_of` defines it (the bound of its Notes, vectorised over the stack), or
    None when any of them is not a translation."""
    hs = np.asarray(hs, dtype=np.float64)
    lead = hs.shape[:-2]
    try:
        g = np.linalg.inv(hs.reshape(-1, 3, 3))
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(g)) or np.any(g[:, 2, 2] == 0):
        return None
    g = g / g[:, 2:3, 2:3]
    rows, cols = out_shape
    corners = np.array([[0, 0], [cols - 1, 0], [0, rows - 1], [cols - 1, rows - 1]], dtype=np.float64)
    gx = corners @ g[:, 2, :2].T  # (4, M)
    q = gx + 1.0
    if q.min() <= 0:
        return None
    centre = np.array([(cols - 1) / 2, (rows - 1) / 2])
    s = (g[:, :2, :2] @ centre + g[:, :2, 2]) / (g[:, 2, :2] @ centre + 1.0)[:, None] - centre  # (M, 2)
    lin_mat = g[:, :2, :2] - np.eye(2) - s[:, :, None] * g[:, None, 2, :2]  # (M, 2, 2)
    lin = np.einsum("cj,mij->mci", corners, lin_mat) + (g[:, :2, 2] - s)[:, None, :]  # (M, 4, 2)
    bound = (np.abs(lin).max(axis=1) + corners.max(axis=0) * np.abs(gx).max(axis=0)[:, None]) / q.min(axis=0)[:, None]
    if bound.max() > tol_px:
        return None
    return s.reshape(*lead, 2)


# -- threads ----------------------------------------------------------------------------------------
_POOL: tuple | None = None  # (pid, executor, workers)


def _pool(workers: int) -> ThreadPoolExecutor:
    """The worker threads, made anew in a forked child (which has none of them)."""
    global _POOL
    if _POOL is None or _POOL[0] != os.getpid() or _POOL[2] < workers:
        _POOL = (os.getpid(), ThreadPoolExecutor(max_workers=workers, thread_name_prefix="lfring"), workers)
    return _POOL[1]


def check_threads(threads, *, allow_none: bool = True):
    """``threads`` as an int >= 1 (None passes when ``allow_none``: the caller's default); anything
    else is refused with :class:`InvalidInputError`."""
    if threads is None and allow_none:
        return None
    if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1:
        raise InvalidInputError(f"threads must be an integer >= 1{' or None' if allow_none else ''}, got {threads!r}")
    return int(threads)


def run_threads(tasks, threads: int) -> None:
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


# -- photo-consistency helpers ----------------------------------------------------------------------
def luminance(views: np.ndarray) -> np.ndarray:
    """(V, h, w) float32 mean of the channels of (V, h, w, C) views."""
    v, h, w, c = views.shape
    if c == 1:
        return views[..., 0]
    mix = np.full((1, c), 1.0 / c, np.float32)
    return np.stack([cv2.transform(views[k], mix).reshape(h, w) for k in range(v)])


def normalised_luminance(views: np.ndarray, masks: np.ndarray, sigma: float) -> np.ndarray:
    """Luminance of every view divided by its local mean (Gaussian, masked): removes the views'
    different vignetting and exposure, which would otherwise bias photo-consistency.

    The local mean varies slowly (sigma of tens of pixels), so it is computed on the image
    shrunk by up to sigma / 4 and enlarged back bilinearly: a few percent of the time of the
    full-size blur, and the same to a fraction of a percent."""
    v, h, w = views.shape[:3]
    f = int(max(1, min(sigma // 4, min(h, w) // 16)))
    small = (max(1, w // f), max(1, h // f))
    out = np.empty((v, h, w), np.float32)
    for k, lum in enumerate(luminance(views)):
        num = cv2.GaussianBlur(cv2.resize(lum * masks[k], small, interpolation=cv2.INTER_AREA), (0, 0), sigma / f)
        den = cv2.GaussianBlur(cv2.resize(masks[k], small, interpolation=cv2.INTER_AREA), (0, 0), sigma / f)
        local = np.where(den > WEIGHT_FLOOR, num / np.maximum(den, 1e-6), 0.0).astype(np.float32)
        local = cv2.resize(local, (w, h), interpolation=cv2.INTER_LINEAR)
        big = cv2.resize(den, (w, h), interpolation=cv2.INTER_LINEAR)
        out[k] = np.where(big > WEIGHT_FLOOR, lum / np.maximum(local, 1e-4), 0.0)
    return out


_BOX_KERNELS: dict = {}


def box_filter(src: np.ndarray, k: int, dst=None) -> np.ndarray:
    """Normalised k x k box filter, as cv2.boxFilter (BORDER_REFLECT_101) but as two separable
    passes, which OpenCV runs several times faster on float32 images."""
    kern = _BOX_KERNELS.get(k)
    if kern is None:
        kern = _BOX_KERNELS.setdefault(k, np.full(k, 1.0 / k, np.float32))
    return cv2.sepFilter2D(src, cv2.CV_32F, kern, kern, dst=dst, borderType=cv2.BORDER_REFLECT_101)


# -- the shift engine -------------------------------------------------------------------------------
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

        run_threads([lambda c=c: work(c) for c in chunks], threads)
        return out
