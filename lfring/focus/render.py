"""Refocusing at metric depth, focal stacks and all-in-focus images: the entry points, which look
the method up in :data:`lfring.focus.methods.METHODS`.

Refocusing at depth Z warps every view into the reference frame with ``H_ref_from_view(Z)``
and averages them, each pixel weighted by how many views are valid there, so the borders are
not darkened. Objects at Z line up and are sharp; others appear as displaced copies
(``method='shift-and-add'``). With a depth map, ``method='depth-aware'`` renders what a lens
whose aperture spans the views would record instead: smooth, occlusion-correct blur of any
aperture (:mod:`lfring.focus.depth_aware`).
"""

from __future__ import annotations

import warnings

import cv2
import numpy as np

from lfring.calibration.overlap import check_renderable
from lfring.core.backend import check_backend
from lfring.core.geometry import check_reference
from lfring.core.viewstack import WEIGHT_FLOOR, cached_view_masks, check_views
from lfring.core.warping import DEFAULT_INTERPOLATION, warp_views
from lfring.depth.hypotheses import depth_hypotheses
from lfring.errors import InvalidInputError, LfringWarning
from lfring.focus.depth_aware import MIN_DEPTH_VIEWS, DepthOfField, depth_to_render, estimation_range, known_depths
from lfring.focus.methods import METHODS
from lfring.focus.shift_and_add import Refocuser, refocus_torch
from lfring.core.protocols import check_calibration
from lfring.core.memory import check_free_memory, memory_words
from lfring.core.validate import check_odd_px

__all__ = ["all_in_focus", "focal_stack", "refocus"]


def _given(**options) -> dict:
    return {k: v for k, v in options.items() if v is not None}


def _method(name, backend, options):
    """The method ``name`` after checking that it runs on ``backend`` and takes the options given."""
    m = METHODS.lookup(name)
    check_backend(backend)
    if backend not in m.backends:
        raise InvalidInputError(f"method={m.name!r} runs on the {' or '.join(m.backends)} backend only")
    extra = sorted(set(_given(**options)) - m.options)
    if extra:
        owners = ", ".join(f"method={o.name!r}" for o in METHODS.values() if set(extra) <= o.options)
        raise InvalidInputError(f"{', '.join(extra)} {'is' if len(extra) == 1 else 'are'} for {owners or 'no method'}, "
                                f"not method={m.name!r}")
    return m


def refocus(views, calibration, depth_m: float, *, reference="center", interpolation: str = DEFAULT_INTERPOLATION,
            backend: str = "numpy", device=None, levels=None, method: str = "shift-and-add", aperture=None,
            f_number=None, ring_device=None, depth=None, zmin_m=None, zmax_m=None) -> np.ndarray:
    """Refocus the views at ``depth_m`` metres from the main lens.

    Parameters
    ----------
    views : (V, h, w, C) float32 in [0, 1]
        From :func:`lfring.split_views` with the calibration's layout.
    calibration : RingCalibration
    depth_m : float
        Metres, finite, beyond the calibration's depth origin; outside its valid range it
        warns (:class:`lfring.LfringWarning`). Nearer than where every view still covers part
        of the reference frame (``calibration.overlap_depth_range``) it is refused. For focus
        at infinity (the command line's ``--depth inf``) give a depth far enough that the
        model has reached its limit, ``lfring.calibration.overlap.INFINITE_DEPTH_M``.
    reference : 'center' or int
        Frame of the result: the virtual central view (default) or a view index.
    interpolation : {'linear', 'cubic'}
    backend : {'numpy', 'torch'}
        'torch' is the GPU path: it runs on ``device`` (CUDA when present by default, one
        Triton kernel there; kornia on a CPU) and also takes batches (B, V, h, w, C), torch
        tensors (a tensor in, a tensor out, on the device) and raw counts (uint8, uint16,
        normalised on the device with ``levels``); see
        :func:`lfring.focus.shift_and_add.refocus_torch`.
    device : str, optional
        For the torch backend, e.g. 'cuda' or 'cpu'.
    levels : (black, white), optional
        For raw-count views on the torch backend: the counts of black and white (by default 0
        and the dtype's largest count).
    method : str
        One of :data:`lfring.focus.methods.METHODS`. 'shift-and-add' averages the views aligned at ``depth_m``: objects elsewhere appear as V
        displaced copies. 'depth-aware' renders what a lens whose aperture spans the views
        would record (numpy backend): in focus as shift-and-add where the views agree (their
        robust mean where one sees an occluder), elsewhere a disc of blur of the
        circle-of-confusion radius, occlusion-correct (:mod:`lfring.focus.depth_aware`).
    aperture : float, optional
        'depth-aware': the lens's aperture radius in units of the views' distance from their
        centre: 1 (default) the aperture the views span, 0 a pinhole (all in focus); any value
        >= 0 scales the blur.
    f_number : float, optional
        'depth-aware': instead of ``aperture``, the main lens's f-number (needs the device:
        ``ring_device`` or a calibration made from a built-in device; see
        :func:`lfring.focus.depth_aware.resolve_aperture`).
    ring_device : RingDevice, optional
    depth : DepthResult, (h, w) array of metres or DepthOfField, optional
        'depth-aware': the depth map in the reference frame (e.g. from
        :func:`lfring.estimate_depth`); estimated over ``zmin_m``..``zmax_m`` when not given.
        A renderer made from these views (:func:`lfring.focus.depth_aware.depth_of_field`) is
        used as it is: its preparation is not repeated.
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
    the calibration's model (:func:`lfring.focus.depth_aware.aperture_radius_px`); for many
    depths from one depth map use :func:`focal_stack` or :func:`lfring.focus.depth_aware.depth_of_field`.

    Examples
    --------
    The bundled scene refocused on the book (0.5 m): the book is sharper than when refocused on
    the cup (0.3 m).

    >>> import cv2, lfring
    >>> cal = lfring.RingCalibration.load("twin_binned2")
    >>> views = lfring.split_views(lfring.demosaic(lfring.load_raw("data/synthetic/scene.png")), cal)
    >>> sharpness = lambda img: cv2.Laplacian(img.mean(axis=2), cv2.CV_32F).var()
    >>> book = (slice(250, 450), slice(420, 600))  # rows, columns of the book in the centre frame
    >>> at_book, at_cup = lfring.refocus(views, cal, 0.5), lfring.refocus(views, cal, 0.3)
    >>> at_book.shape, bool(sharpness(at_book[book]) > 3 * sharpness(at_cup[book]))
    ((705, 705, 3), True)
    """
    check_calibration(calibration)
    m = _method(method, backend, dict(aperture=aperture, f_number=f_number, ring_device=ring_device, depth=depth,
                                      zmin_m=zmin_m, zmax_m=zmax_m))
    if backend == "torch":
        check_renderable(calibration, depth_m, reference=reference)  # as the Refocuser does
        return refocus_torch(views, calibration, depth_m, reference=reference, device=device, interpolation=interpolation,
                             levels=levels)
    if levels is not None:
        raise InvalidInputError("levels are the black and white counts of integer views on the torch backend")
    arr = check_views(views)
    sharp = Refocuser(calibration, depth_m, reference=reference, view_shape=arr.shape[1:3], interpolation=interpolation)(arr)
    if m.prepare is None:
        return sharp
    finish = m.prepare(arr, calibration, reference, **_given(aperture=aperture, f_number=f_number, ring_device=ring_device,
                                                            depth=depth, zmin_m=zmin_m, zmax_m=zmax_m))
    return finish(sharp, float(depth_m))



def focal_stack(views, calibration, depths_m, *, reference="center", interpolation: str = DEFAULT_INTERPOLATION,
                method: str = "shift-and-add", aperture=None, f_number=None, ring_device=None, depth=None,
                zmin_m=None, zmax_m=None) -> np.ndarray:
    """Refocus at every depth of ``depths_m``: (N, h, w, C) float32.

    The arguments are :func:`refocus`'s; a method's per-frame preparation (for 'depth-aware'
    the depth map, given or estimated, and the all-in-focus colour) is made once for the whole stack.

    Examples
    --------
    >>> import cv2, numpy as np, lfring
    >>> cal = lfring.RingCalibration.load("twin_binned2")
    >>> views = lfring.split_views(lfring.demosaic(lfring.load_raw("data/synthetic/scene.png")), cal)
    >>> stack = lfring.focal_stack(views, cal, [0.3, 0.5, 1.0])
    >>> book = (slice(250, 450), slice(420, 600))
    >>> stack.shape, int(np.argmax([cv2.Laplacian(s[book].mean(axis=2), cv2.CV_32F).var() for s in stack]))
    ((3, 705, 705, 3), 1)
    """
    check_calibration(calibration)
    m = _method(method, "numpy", dict(aperture=aperture, f_number=f_number, ring_device=ring_device, depth=depth,
                                      zmin_m=zmin_m, zmax_m=zmax_m))
    z = np.atleast_1d(calibration.check_depth(depths_m, name="depths_m"))  # validates and warns once for the stack
    if z.ndim != 1 or z.size == 0:
        raise InvalidInputError(f"depths_m must be a non-empty list of depths, got {depths_m!r}")
    arr = check_views(views)
    check_renderable(calibration, z, reference=reference)
    # The stack is one image per depth, kept at once (twice while np.stack joins them).
    need = 2 * z.size * arr[0].nbytes
    check_free_memory(need, f"a focal stack of {z.size} depths ({memory_words(need)} while it is made: its images twice)",
                      "give fewer depths_m, or refocus them a few at a time")
    finish = None
    if m.prepare is not None:
        finish = m.prepare(arr, calibration, reference, **_given(aperture=aperture, f_number=f_number,
                                                                ring_device=ring_device, depth=depth, zmin_m=zmin_m,
                                                                zmax_m=zmax_m))
    out = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)
        for d in z:
            img = refocus(arr, calibration, float(d), reference=reference, interpolation=interpolation)
            out.append(img if finish is None else finish(img, float(d)))
    return np.stack(out)



def all_in_focus(views, calibration, depths_m=None, *, depth_map_m=None, reference="center", window_px: int = 7):
    """An all-in-focus image: every pixel from the views aligned at the depth where it is sharpest
    (the depth-aware renderer at aperture 0).

    Parameters
    ----------
    views : (V, h, w, C) float32
    calibration : RingCalibration
    depths_m : sequence of float, optional
        Depths to choose from (default: depth-aware refocusing's range,
        :func:`lfring.focus.depth_aware.estimation_range`, evenly in disparity, one pixel
        apart; with ``depth_map_m``, the map's own depths).
    depth_map_m : DepthResult, (h, w) float or DepthOfField, optional
        Depth of every reference pixel (a :class:`lfring.DepthResult` from
        :func:`lfring.estimate_depth`, or metres; NaN where unknown; or a renderer made from these
        views, :func:`lfring.focus.depth_aware.depth_of_field`, whose map and preparation are
        used as they are): each pixel is then
        refocused at its own depth (the nearest of ``depths_m`` when they are given), as
        depth-aware refocusing renders the same map at aperture 0: where the depth is unknown,
        or too few views see it, the nearest measured surface is continued
        (:func:`lfring.focus.depth_aware.depth_to_render`).
    window_px : int
        Side of the box over which the photo-consistency is averaged (odd, a centred box).

    Returns
    -------
    image : (h, w, C) float32
    depth_m : (h, w) float32
        The depth each pixel was taken from (of ``depths_m``, or the map's own); NaN where no
        view sees it, and where the given depth map has no depth.

    Raises
    ------
    InvalidInputError
        A depth map of another shape or (a :class:`lfring.DepthResult`) another reference frame,
        or one that holds no depth beyond the calibration's depth origin.

    Notes
    -----
    Without a depth map, the focus measure is photo-consistency: at the right depth the
    warped views agree, so their weighted variance, averaged over a small window, is least.
    The sweep is streamed: memory does not grow with the number of depths. The image is then
    the depth-aware renderer's at aperture 0 (:class:`lfring.focus.depth_aware.DepthOfField`) with the
    chosen depths: every pixel from the views that see it at its depth, occluded views left
    out.

    Examples
    --------
    Each pixel comes from the depth where the views agree: the book at 0.5 m, the cup at 0.3 m.

    >>> import numpy as np, lfring
    >>> cal = lfring.RingCalibration.load("twin_binned2")
    >>> views = lfring.split_views(lfring.demosaic(lfring.load_raw("data/synthetic/scene.png")), cal)
    >>> image, depth_m = lfring.all_in_focus(views, cal)
    >>> book, cup = (slice(250, 450), slice(420, 600)), (slice(150, 350), slice(80, 280))
    >>> round(float(np.nanmedian(depth_m[book])), 1), round(float(np.nanmedian(depth_m[cup])), 1)
    (0.5, 0.3)
    """
    check_calibration(calibration)
    arr = check_views(views)
    if not isinstance(depth_map_m, DepthOfField):  # a renderer says what it was made from
        calibration.check_fits(arr.shape)
    window_px = check_odd_px(window_px, "window_px", within=arr.shape[1:3])
    h, w = arr.shape[1:3]
    measured_views = MIN_DEPTH_VIEWS
    if isinstance(depth_map_m, DepthOfField):
        depth_map_m.check_made_from(arr, calibration, reference)
        if depths_m is None:
            return depth_map_m.all_in_focus()
        dm, measured_views = depth_map_m.depth_m, depth_map_m.measured_views
    elif depth_map_m is not None:
        dm, measured_views = depth_to_render(depth_map_m, calibration, check_reference(reference, calibration.num_views),
                                             (h, w))
        if depths_m is None:  # every pixel at its own depth
            return DepthOfField(arr, calibration, dm, reference=reference, measured_views=measured_views).all_in_focus()
    if depth_map_m is not None:
        known = known_depths(dm, calibration)
    if depths_m is None:
        # Depth-aware refocusing's range, by its one rule (a calibration open to infinity ends
        # where the views stop moving, when that is a range of depths at all).
        try:
            lo, hi = estimation_range(calibration, reference=reference)
        except InvalidInputError:
            raise InvalidInputError("give depths_m: the calibration has no upper depth bound, and none follows from "
                                    "it (see lfring.focus.depth_aware.estimation_range)") from None
        depths_m = depth_hypotheses(calibration, lo, hi)
    z = np.atleast_1d(calibration.check_depth(depths_m, name="depths_m"))
    if z.ndim != 1 or z.size == 0:
        raise InvalidInputError(f"depths_m must be a non-empty list of depths (or None: the calibration's range), got "
                                f"{depths_m!r}")
    masks = cached_view_masks(calibration, (h, w))
    if depth_map_m is not None:
        target = np.where(known, dm, z[0])
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
    covered = np.isfinite(chosen)
    if depth_map_m is not None:
        chosen[~known] = np.nan  # the renderer continues the nearest measured surface there
    if not covered.any():
        return out, chosen
    out = DepthOfField(arr, calibration, chosen, reference=reference, measured_views=measured_views).render(float(z[0]), 0.0)
    out[~covered] = 0.0
    return out, chosen
