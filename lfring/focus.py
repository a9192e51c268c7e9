"""Refocusing at metric depth, focal stacks and all-in-focus images (SPEC 5).

Refocusing at depth Z warps every view into the reference frame with ``H_ref_from_view(Z)``
and averages them, each pixel weighted by how many views are valid there, so the borders are
not darkened. Objects at Z line up and are sharp; others appear as displaced copies
(``method='shift-and-add'``). With a depth map, ``method='depth-aware'`` renders what a lens
whose aperture spans the views would record instead: smooth, occlusion-correct blur of any
aperture (:mod:`lfring.dof`).
"""

from __future__ import annotations

import warnings

import cv2
import numpy as np

from lfring.calibration.overlap import check_renderable
from lfring.depth.hypotheses import depth_hypotheses
from lfring.depth.selection import DepthResult
from lfring.dof import DepthOfField, aperture_from_f_number
from lfring.errors import InvalidInputError, LfringWarning
from lfring.core.geometry import check_reference
from lfring.core.warping import DEFAULT_INTERPOLATION, interpolation_flag, translation_of, warp_image, warp_views
from lfring.core.viewstack import WEIGHT_FLOOR, cached_view_masks, check_views, inverse_weight
from lfring.core.shift import ShiftEngine

__all__ = ["METHODS", "Refocuser", "refocus", "focal_stack", "all_in_focus", "depth_of_field", "resolve_aperture"]

# Refocusing methods: the views' plain average at the focus depth, or a lens's blur from a depth map.
METHODS = ("shift-and-add", "depth-aware")


def _all_valid(masks) -> bool:
    return bool(np.all(masks == 1.0))


def _channel_masks(channels: int):
    """The masks shaped like a view of ``channels`` channels (made once per calibration)."""
    return lambda masks: [m if channels == 1 else np.repeat(m[..., None], channels, axis=2) for m in masks]


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

    def __init__(self, calibration, depth_m: float, *, reference="center", view_shape=None, interpolation: str = DEFAULT_INTERPOLATION,
                 threads: int | None = None):
        if np.ndim(depth_m) != 0:
            raise InvalidInputError("Refocuser takes one depth; use focal_stack for several")
        if threads is not None and (isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1):
            raise InvalidInputError(f"threads must be a positive integer or None, got {threads!r}")
        self.depth_m = float(depth_m)
        self.reference = reference
        self._flag = interpolation_flag(interpolation)
        check_renderable(calibration, self.depth_m, reference=reference)
        self.view_shape = tuple(view_shape or calibration.layout.view_shape)
        self.threads = threads
        self.H = calibration.homographies(self.depth_m, reference=reference)
        self._calibration = calibration
        self.masks = cached_view_masks(calibration, self.view_shape)
        self._all_valid = cached_view_masks(calibration, self.view_shape, "all_valid", _all_valid)
        self._shift = None
        if self._flag == cv2.INTER_LINEAR:
            shifts = [translation_of(hk, self.view_shape) for hk in self.H]
            if all(s is not None for s in shifts):
                self._shift = ShiftEngine(np.array(shifts), self.view_shape, None if self._all_valid else self.masks)
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
                ShiftEngine(self._shift.shifts, self.view_shape).run(self.masks, weight)
            else:
                for k in range(len(self.H)):
                    weight += warp_image(self.masks[k], self.H[k], (w, h))
            self._weight = weight
        return self._weight

    def _inverse(self) -> np.ndarray:
        if self._inv is None:
            self._inv = inverse_weight(self.weight)
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
            masks = None if self._all_valid else cached_view_masks(self._calibration, self.view_shape, ("channels", c), _channel_masks(c))
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
        arr = check_views(views)
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
                acc = warp_image(s_k, self.H[k], (w, h), interpolation=self._flag)
            else:
                warp_image(s_k, self.H[k], (w, h), dst=tmp, interpolation=self._flag)
                cv2.add(acc, tmp, dst=acc)
        cv2.multiply(acc, inv, dst=acc)
        if self._flag != cv2.INTER_LINEAR:
            np.clip(acc, 0.0, None, out=acc)  # bicubic overshoots below zero at dark edges
        return acc[..., None] if c == 1 else acc


def _check_method(method: str) -> None:
    if method not in METHODS:
        raise InvalidInputError(f"method must be one of {', '.join(METHODS)}, got {method!r}")


def resolve_aperture(calibration, aperture=None, f_number=None, ring_device=None) -> float:
    """The depth-aware ``aperture`` (1: the disc through the views, 0: a pinhole) from either
    ``aperture`` or ``f_number`` (1.0 when neither is given).

    ``f_number`` needs the device: ``ring_device`` (a :class:`lfring.optics.RingDevice` with
    its positions), or else the built-in device the calibration was made from (calibrations
    from the optics name it), set to the positions the calibration records. See
    :func:`lfring.dof.aperture_from_f_number` for the relation.
    """
    if aperture is not None and f_number is not None:
        raise InvalidInputError("give the depth of field as aperture or as f_number, not both")
    if f_number is None:
        a = 1.0 if aperture is None else aperture
        if isinstance(a, bool) or not isinstance(a, (int, float, np.integer, np.floating)) or not (np.isfinite(a) and a >= 0):
            raise InvalidInputError(f"aperture must be a finite number >= 0 (1: the views' aperture, 0: a pinhole), got {aperture!r}")
        return float(a)
    if ring_device is None:
        if calibration.device is None:
            raise InvalidInputError(
                "f_number needs the device (its main lens's focal length and where the views sit in its aperture): "
                "pass ring_device=, or use aperture= (1 is the aperture the views span)"
            )
        from lfring.optics.device import load_device

        ring_device = load_device(calibration.device)
        prov = calibration.provenance
        if prov.get("ring_distance_m") is not None and prov.get("sensor_distance_m") is not None:
            ring_device = ring_device.with_positions(prov["ring_distance_m"], prov["sensor_distance_m"])
    return aperture_from_f_number(f_number, ring_device)


def _depth_map(arr, calibration, depth, zmin_m, zmax_m, reference) -> np.ndarray:
    """The depth map of the views in the reference frame: given, or estimated."""
    from lfring.depth.sweep import estimate_depth

    h, w = arr.shape[1:3]
    if depth is None:
        lo, hi = calibration.valid_depth_range_m
        zmin_m = lo if zmin_m is None else zmin_m
        zmax_m = hi if zmax_m is None else zmax_m
        if zmax_m is None:
            raise InvalidInputError("the calibration has no upper depth bound: give zmax_m (or a depth map as depth=)")
        depth = estimate_depth(arr, calibration, zmin_m=float(zmin_m), zmax_m=float(zmax_m), reference=reference)
    elif zmin_m is not None or zmax_m is not None:
        raise InvalidInputError("zmin_m/zmax_m set the range of the depth estimation: give them or a depth map, not both")
    if isinstance(depth, DepthResult):
        if depth.reference != reference:
            raise InvalidInputError(f"the depth map is in the frame of reference {depth.reference!r}, the refocusing in {reference!r}")
        depth = depth.depth_m
    dm = np.asarray(depth, dtype=np.float64)
    if dm.shape != (h, w):
        raise InvalidInputError(f"the depth map must be (h, w) = ({h}, {w}) metres like the views, got shape {dm.shape}")
    return dm


def depth_of_field(views, calibration, *, depth=None, zmin_m=None, zmax_m=None, reference="center") -> DepthOfField:
    """A :class:`lfring.dof.DepthOfField` renderer of the views: from a depth map (``depth``, a
    :class:`lfring.DepthResult` or (h, w) metres in the reference frame), or one estimated over
    ``zmin_m``..``zmax_m`` (by default the calibration's valid range). Reuse it to render many
    focus depths and apertures from one depth map."""
    arr = check_views(views)
    ref = check_reference(reference, calibration.num_views)
    return DepthOfField(arr, calibration, _depth_map(arr, calibration, depth, zmin_m, zmax_m, ref), reference=ref)


def refocus(views, calibration, depth_m: float, *, reference="center", interpolation: str = DEFAULT_INTERPOLATION,
            backend: str = "numpy", device=None, method: str = "shift-and-add", aperture=None, f_number=None,
            ring_device=None, depth=None, zmin_m=None, zmax_m=None) -> np.ndarray:
    """Refocus the views at ``depth_m`` metres from the main lens.

    Parameters
    ----------
    views : (V, h, w, C) float32 in [0, 1]
        From :func:`lfring.split_views` with the calibration's layout.
    calibration : RingCalibration
    depth_m : float
        Must be positive and beyond the calibration's depth origin; outside its valid range it
        warns (:class:`lfring.LfringWarning`). Nearer than where every view still covers part
        of the reference frame (``calibration.overlap_depth_range``) it is refused.
    reference : 'center' or int
        Frame of the result: the virtual central view (default) or a view index.
    interpolation : {'linear', 'cubic'}
    backend : {'numpy', 'torch'}
        'torch' runs on ``device`` (CUDA when present by default) through kornia, and also
        takes batches (B, V, h, w, C); see :func:`lfring.backends.torch_refocus.refocus_torch`.
    device : str, optional
        For the torch backend, e.g. 'cuda' or 'cpu'.
    method : {'shift-and-add', 'depth-aware'}
        'shift-and-add' averages the views aligned at ``depth_m``: objects elsewhere appear as V
        displaced copies. 'depth-aware' renders what a lens whose aperture spans the views
        would record (numpy backend): in focus as shift-and-add, elsewhere a disc of blur of the
        circle-of-confusion radius, occlusion-correct (:mod:`lfring.dof`).
    aperture : float, optional
        'depth-aware': the lens's aperture radius in units of the views' distance from their
        centre: 1 (default) the aperture the views span, 0 a pinhole (all in focus); any value
        >= 0 scales the blur.
    f_number : float, optional
        'depth-aware': instead of ``aperture``, the main lens's f-number (needs the device:
        ``ring_device`` or a calibration made from a built-in device; see
        :func:`resolve_aperture`).
    ring_device : RingDevice, optional
    depth : DepthResult or (h, w) array of metres, optional
        'depth-aware': the depth map in the reference frame (e.g. from
        :func:`lfring.estimate_depth`); estimated over ``zmin_m``..``zmax_m`` when not given.
    zmin_m, zmax_m : float, optional
        'depth-aware': the range of the depth estimation (default: the calibration's valid range).

    Returns
    -------
    (h, w, C) float32

    Notes
    -----
    Shift-and-add: ``out(x) = sum_k m_k(H_k^-1 x) v_k(H_k^-1 x) / sum_k m_k(H_k^-1 x)`` with
    ``H_k = H_ref_from_k(Z)`` and ``m_k`` the valid disc of view k, bilinear interpolation.
    For many frames at one depth, build a :class:`Refocuser` once. Depth-aware: the circle of
    confusion of a point at depth Z is ``aperture * R * |1/(Z - z0) - 1/(Z_f - z0)|`` px, R from
    the calibration's model (:func:`lfring.dof.aperture_radius_px`); for many depths from one
    depth map use :func:`focal_stack` or :func:`depth_of_field`.

    Examples
    --------
    The bundled scene refocused on the book (0.5 m): the book is sharper than when refocused on
    the cup (0.3 m).

    >>> import cv2, lfring
    >>> cal = lfring.RingCalibration.load("twin_binned2")
    >>> views = lfring.split_views(lfring.demosaic(lfring.load_raw("data/synthetic/scene.png")), cal.layout)
    >>> sharpness = lambda img: cv2.Laplacian(img.mean(axis=2), cv2.CV_32F).var()
    >>> book = (slice(250, 450), slice(420, 600))  # rows, columns of the book in the centre frame
    >>> at_book, at_cup = refocus(views, cal, 0.5), refocus(views, cal, 0.3)
    >>> at_book.shape, bool(sharpness(at_book[book]) > 3 * sharpness(at_cup[book]))
    ((705, 705, 3), True)
    """
    from lfring.core.backend import BACKENDS

    _check_method(method)
    if backend not in BACKENDS:
        raise InvalidInputError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    if method == "depth-aware":
        if backend != "numpy":
            raise InvalidInputError("method='depth-aware' runs on the numpy backend only")
        a = resolve_aperture(calibration, aperture, f_number, ring_device)
        arr = check_views(views)
        sharp = Refocuser(calibration, depth_m, reference=reference, view_shape=arr.shape[1:3], interpolation=interpolation)(arr)
        dof = depth_of_field(arr, calibration, depth=depth, zmin_m=zmin_m, zmax_m=zmax_m, reference=reference)
        return dof.render(float(depth_m), a, sharp)
    if any(v is not None for v in (aperture, f_number, ring_device, depth, zmin_m, zmax_m)):
        raise InvalidInputError("aperture, f_number, ring_device, depth, zmin_m and zmax_m are for method='depth-aware'")
    if backend == "torch":
        from lfring.backends.torch_refocus import refocus_torch

        check_renderable(calibration, depth_m, reference=reference)  # as the Refocuser does
        return refocus_torch(views, calibration, depth_m, reference=reference, device=device, interpolation=interpolation)
    arr = check_views(views)
    return Refocuser(calibration, depth_m, reference=reference, view_shape=arr.shape[1:3], interpolation=interpolation)(arr)


def focal_stack(views, calibration, depths_m, *, reference="center", interpolation: str = DEFAULT_INTERPOLATION,
                method: str = "shift-and-add", aperture=None, f_number=None, ring_device=None, depth=None,
                zmin_m=None, zmax_m=None) -> np.ndarray:
    """Refocus at every depth of ``depths_m``: (N, h, w, C) float32.

    The arguments are :func:`refocus`'s; with ``method='depth-aware'`` the depth map (given or
    estimated) and the all-in-focus colour are made once for the whole stack.

    Examples
    --------
    >>> import cv2, numpy as np, lfring
    >>> cal = lfring.RingCalibration.load("twin_binned2")
    >>> views = lfring.split_views(lfring.demosaic(lfring.load_raw("data/synthetic/scene.png")), cal.layout)
    >>> stack = focal_stack(views, cal, [0.3, 0.5, 1.0])
    >>> book = (slice(250, 450), slice(420, 600))
    >>> stack.shape, int(np.argmax([cv2.Laplacian(s[book].mean(axis=2), cv2.CV_32F).var() for s in stack]))
    ((3, 705, 705, 3), 1)
    """
    _check_method(method)
    z = np.atleast_1d(np.asarray(depths_m, dtype=np.float64))
    if z.ndim != 1 or z.size == 0:
        raise InvalidInputError(f"depths_m must be a non-empty list of depths, got {depths_m!r}")
    arr = check_views(views)
    calibration.check_depth(z)  # validates and warns once for the whole stack
    check_renderable(calibration, z, reference=reference)
    dof, a = None, None
    if method == "depth-aware":
        a = resolve_aperture(calibration, aperture, f_number, ring_device)
        dof = depth_of_field(arr, calibration, depth=depth, zmin_m=zmin_m, zmax_m=zmax_m, reference=reference)
    elif any(v is not None for v in (aperture, f_number, ring_device, depth, zmin_m, zmax_m)):
        raise InvalidInputError("aperture, f_number, ring_device, depth, zmin_m and zmax_m are for method='depth-aware'")
    out = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)
        for d in z:
            img = refocus(arr, calibration, float(d), reference=reference, interpolation=interpolation)
            out.append(img if dof is None else dof.render(float(d), a, img))
    return np.stack(out)


def all_in_focus(views, calibration, depths_m=None, *, depth_map_m=None, reference="center", window_px: int = 7):
    """An all-in-focus image: every pixel from the views aligned at the depth where it is sharpest
    (the depth-aware renderer at aperture 0).

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
    The sweep is streamed: memory does not grow with the number of depths. The image is then
    the depth-aware renderer's at aperture 0 (:class:`lfring.dof.DepthOfField`) with the
    chosen depths: every pixel from the views that see it at its depth, occluded views left
    out.

    Examples
    --------
    Each pixel comes from the depth where the views agree: the book at 0.5 m, the cup at 0.3 m.

    >>> import numpy as np, lfring
    >>> cal = lfring.RingCalibration.load("twin_binned2")
    >>> views = lfring.split_views(lfring.demosaic(lfring.load_raw("data/synthetic/scene.png")), cal.layout)
    >>> image, depth_m = all_in_focus(views, cal)
    >>> book, cup = (slice(250, 450), slice(420, 600)), (slice(150, 350), slice(80, 280))
    >>> round(float(np.nanmedian(depth_m[book])), 1), round(float(np.nanmedian(depth_m[cup])), 1)
    (0.5, 0.3)
    """
    arr = check_views(views)
    h, w = arr.shape[1:3]
    if depths_m is None:
        lo, hi = calibration.valid_depth_range_m
        if hi is None:
            raise InvalidInputError("give depths_m: the calibration has no upper depth bound")
        depths_m = depth_hypotheses(calibration, lo, hi)
    z = np.atleast_1d(np.asarray(depths_m, dtype=np.float64))
    calibration.check_depth(z)
    masks = cached_view_masks(calibration, (h, w))
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
        ok = wsum > WEIGHT_FLOOR
        if depth_map_m is not None:
            cost = np.abs(1.0 / (target - calibration.depth_origin_m) - 1.0 / (d - calibration.depth_origin_m)).astype(np.float32)
        else:
            mean = warped.sum(axis=0) / np.where(ok, wsum, 1.0)[..., None]
            # Weighted variance across views (warped values are premultiplied by the weights).
            second = (warped**2 / np.maximum(weights, WEIGHT_FLOOR)[..., None]).sum(axis=0) / np.where(ok, wsum, 1.0)[..., None]
            var = np.maximum(second - mean**2, 0).mean(axis=2)
            var = np.where(wsum >= 1.5, var, np.inf).astype(np.float32)  # one view alone proves nothing
            cost = cv2.boxFilter(np.where(np.isfinite(var), var, 1e3).astype(np.float32), -1, (window_px, window_px))
        better = (cost < best_cost) & ok
        best_cost[better] = cost[better]
        chosen[better] = d
    if np.all(np.isnan(chosen)):
        return out, chosen
    out = DepthOfField(arr, calibration, chosen, reference=reference).render(float(z[0]), 0.0)
    out[np.isnan(chosen)] = 0.0
    return out, chosen
