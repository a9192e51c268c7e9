"""Refocusing at metric depth, focal stacks and all-in-focus images (SPEC 5).

Refocusing at depth Z warps every view into the reference frame with ``H_ref_from_view(Z)``
and averages them, each pixel weighted by how many views are valid there, so the borders are
not darkened. Objects at Z line up and are sharp; others appear as displaced copies.
"""

from __future__ import annotations

import warnings
import weakref

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
    """(V, h, w) masks and the same repeated over ``channels`` (a list of (h, w[, C]))."""
    per_cal = _MASK_CACHE.setdefault(calibration, {})
    key = (tuple(view_shape), channels)
    if key not in per_cal:
        base = per_cal[(tuple(view_shape), 1)][0] if (tuple(view_shape), 1) in per_cal else view_masks(calibration, view_shape)
        rep = [m if channels == 1 else np.repeat(m[..., None], channels, axis=2) for m in base]
        per_cal[key] = (base, rep)
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


class Refocuser:
    """Refocus many frames at one depth: warps, masks and normalisation are computed once.

    An inspection line refocuses thousands of frames at one depth; this does the geometry
    once and leaves each frame with one masking multiply, one warp and one add per view.

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

    def __init__(self, calibration, depth_m: float, *, reference="center", view_shape=None, interpolation: str = "linear"):
        if np.ndim(depth_m) != 0:
            raise InvalidInputError("Refocuser takes one depth; use focal_stack for several")
        self.depth_m = float(depth_m)
        self.reference = reference
        self._flag = _interp(interpolation)
        self.view_shape = tuple(view_shape or calibration.layout.view_shape)
        self.H = calibration.homographies(self.depth_m, reference=reference)
        self._calibration = calibration
        self.masks = _cached_masks(calibration, self.view_shape, 1)[0]
        self._all_valid = bool(np.all(self.masks == 1.0))
        h, w = self.view_shape
        weight = np.zeros((h, w), np.float32)
        for k in range(len(self.H)):
            weight += _warp(self.masks[k], self.H[k], (w, h))
        #: (h, w) number of views that see each reference pixel (fractional at edges).
        self.weight = weight
        self._inv = np.where(weight > 1e-3, 1.0 / np.maximum(weight, 1e-3), 0.0).astype(np.float32)
        self._cache: dict[int, tuple] = {}

    def _buffers(self, c: int):
        """Per channel count: the normalisation and masks shaped like a view, and two scratch
        buffers, made once and reused for every frame."""
        if c not in self._cache:
            h, w = self.view_shape
            shape = (h, w) if c == 1 else (h, w, c)
            inv = self._inv if c == 1 else cv2.merge([self._inv] * c)
            masks = None if self._all_valid else _cached_masks(self._calibration, self.view_shape, c)[1]
            self._cache[c] = (inv, masks, np.empty(shape, np.float32), np.empty(shape, np.float32))
        return self._cache[c]

    def __call__(self, views) -> np.ndarray:
        """The refocused image, (h, w, C) float32, of one frame's views (V, h, w, C)."""
        arr = _check_views(views)
        if arr.shape[1:3] != self.view_shape or arr.shape[0] != len(self.H):
            raise InvalidInputError(f"expected {len(self.H)} views of {self.view_shape[1]} x {self.view_shape[0]} px, got shape {arr.shape}")
        c = arr.shape[3]
        inv, masks, tmp, masked = self._buffers(c)
        h, w = self.view_shape
        src = arr[..., 0] if c == 1 else arr
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
