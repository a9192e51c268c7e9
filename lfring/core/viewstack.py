"""View stacks and their valid discs: the checks and weights every stage that compares or
averages views shares.

A stack of views is checked once (:func:`check_views`); each view pixel is weighed by its valid
disc (:func:`view_masks`, made once per calibration and view shape by :func:`cached_view_masks`,
in the one per-calibration cache :func:`calibration_cache`); sums of weights are inverted with
the one :data:`WEIGHT_FLOOR` (:func:`inverse_weight`).
"""

from __future__ import annotations

import math
import weakref

import cv2
import numpy as np

from lfring.errors import InvalidInputError

__all__ = ["COUNTS_MEDIAN", "TAPER", "WEIGHT_FLOOR", "all_finite", "cached_view_masks", "calibration_cache", "check_unit_range", "check_views", "inverse_weight", "unit_range_sample", "view_masks"]

# A reference pixel whose summed view weight is below this is seen by no view: it gets 0 (images)
# or NaN (depth), and divisions by a weight never divide by less.
WEIGHT_FLOOR = 1e-3
# Views whose values are mostly above this are counts (0..255, 0..65535) passed as float32, not
# images in [0, 1]: a flat-field-corrected view exceeds 1 only towards its rims. Judged on a
# strided sample of COUNTS_SAMPLE_PX x COUNTS_SAMPLE_PX pixels a view (a cheap look, every frame).
COUNTS_MEDIAN = 1.5
COUNTS_SAMPLE_PX = 32
# Fraction of a valid disc's radius over which a view's weight rises from 0 to 1 (view_masks).
TAPER = 0.15


def check_views(views, *, min_views: int = 1, images: bool = True) -> np.ndarray:
    """A view stack as a (V, h, w, C) float32 array, or a clear error.

    Parameters
    ----------
    views : array_like, (V, h, w) or (V, h, w, C) float32
        ``(V, h, w)`` is taken as one channel.
    min_views : int
        Fewest views the caller can work with.
    images : bool
        The views are images in [0, 1]: counts passed as float32 (most values above
        :data:`COUNTS_MEDIAN`) are refused. False for other per-view maps (a high-pass, a
        weight).

    Returns
    -------
    (V, h, w, C) float32 (a view of the input, not a copy; a native-order copy of big-endian
    floats)

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
    if arr.dtype.kind == "f" and not arr.dtype.isnative:  # big-endian floats: the same values, a copy
        arr = arr.astype(arr.dtype.newbyteorder("="))
    if arr.dtype != np.float32:
        raise InvalidInputError(f"views must be float32 in [0, 1] (lfring.split_views gives that), got {arr.dtype}")
    if arr.shape[0] < min_views or min(arr.shape[1:3]) < 2:
        raise InvalidInputError(f"views must hold at least {min_views} view(s) of 2 x 2 px, got shape {arr.shape}")
    if arr.shape[-1] > 4:
        raise InvalidInputError(f"views may have 1 to 4 channels, got {arr.shape[-1]}")
    if images:
        check_unit_range(arr, "views")
    return arr


def unit_range_sample(images):
    """The strided sample of ``images`` ((h, w) or (..., h, w, C)) that :func:`check_unit_range`
    judges, about :data:`COUNTS_SAMPLE_PX` pixels a side; any array that slices as NumPy's do
    (a torch tensor too: sample it on its device, then judge the sample on the host)."""
    rows, cols = (-2, -1) if images.ndim == 2 else (-3, -2)
    sy, sx = (max(1, images.shape[a] // COUNTS_SAMPLE_PX) for a in (rows, cols))
    index = [slice(None)] * images.ndim
    index[rows], index[cols] = slice(None, None, sy), slice(None, None, sx)
    return images[tuple(index)]


def check_unit_range(images: np.ndarray, what: str) -> None:
    """Refuse float ``images`` ((h, w) or (..., h, w, C)) whose values are mostly above
    :data:`COUNTS_MEDIAN`: counts (0..255, 0..65535), not images in [0, 1]. Judged on a strided
    sample, so it costs nothing per frame; ``what`` names them in the message."""
    arr = np.asarray(images)
    if arr.ndim < 2 or not np.issubdtype(arr.dtype, np.floating):
        return
    sample = unit_range_sample(arr)
    above = np.count_nonzero(sample > COUNTS_MEDIAN)
    if above * 2 > sample.size:
        raise InvalidInputError(
            f"{what} must be float in [0, 1], but {above / sample.size:.0%} of the values sampled are above "
            f"{COUNTS_MEDIAN:g} (largest {float(np.nanmax(sample)):g}): raw counts? Divide by the white level "
            "(255 for 8-bit images), or read frames with lfring.load_raw and lfring.demosaic")


def all_finite(image: np.ndarray) -> bool:
    """Whether an image (up to 4 channels) holds no NaN and no infinity: OpenCV's sum, one pass
    that lets other threads run meanwhile."""
    return math.isfinite(sum(cv2.sumElems(image)))


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
