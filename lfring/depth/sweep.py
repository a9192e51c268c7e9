"""Plane-sweep depth over the views (SPEC 6): the entry point, which checks the arguments, plans
the sweep and runs it.

For every hypothesis Z (evenly spaced in 1/(Z - z0), at most one pixel of view motion apart by
default; :mod:`lfring.depth.hypotheses`) every view is warped into the reference frame with
H_ref_from_view(Z), the warped views are compared with their consensus
(:mod:`lfring.depth.costs`), the cost is aggregated spatially, and each pixel keeps its best
hypothesis and the costs of its neighbours (:mod:`lfring.depth.selection`). A parabola through
those three costs gives the sub-hypothesis depth; the cost curve's distinctness gives the
confidence. The default cost ('lcn' with box aggregation) runs strip by strip on several threads
(:func:`lfring.depth.stream.sweep_strips`); the others a whole slice at a time
(:func:`lfring.depth.stream.sweep_slices`) or with the torch backend.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import cv2
import numpy as np

from lfring.depth.costs import AGGREGATIONS, COSTS, GUIDED_EPS, LCN_AGGREGATE_PX, lcn_sources
from lfring.depth.hypotheses import depth_hypotheses, view_motion_px
from lfring.depth.selection import DepthResult, Finisher
from lfring.depth.stream import sweep_slices, sweep_strips
from lfring.errors import InvalidInputError, LfringWarning
from lfring.geometry import check_reference
from lfring.warp import WEIGHT_FLOOR, cached_view_masks, check_views, normalised_luminance, warp_image

__all__ = ["AGGREGATIONS", "COSTS", "DepthResult", "estimate_depth"]


def _odd_positive(name: str, value) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1 or value % 2 == 0:
        raise InvalidInputError(f"{name} must be an odd positive integer, got {value!r}")


def _optional_count(name: str, value, least: int, meaning: str) -> None:
    if value is not None and (isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < least):
        raise InvalidInputError(f"{name} must be an integer >= {least}{meaning}, got {value!r}")


def estimate_depth(
    views,
    calibration,
    *,
    zmin_m: float,
    zmax_m: float,
    num_planes: int | None = None,
    reference="center",
    backend: str = "numpy",
    device=None,
    cost: str = "lcn",
    aggregation: str = "box",
    window_px: int = 9,
    aggregate_px: int | None = None,
    min_views: int = 2,
    threads: int | None = None,
) -> DepthResult:
    """Metric depth and confidence by plane sweep over the views.

    Parameters
    ----------
    views : (V, h, w, C) float32 in [0, 1]
        Cut with the calibration's layout (:func:`lfring.split_views`).
    calibration : RingCalibration
    zmin_m, zmax_m : float
        Depth range in metres from the main lens; zmin_m must lie beyond z0.
    num_planes : int, optional
        Number of hypotheses, evenly spaced in 1/(Z - z0). By default just enough that no view
        pixel moves more than one pixel between neighbours (``step_px`` reports it).
    reference : 'center' or int
        Frame of the depth map.
    backend : {'numpy', 'torch'}, device : str, optional
        The torch backend runs the same algorithm with kornia (GPU-ready).
    cost : {'lcn', 'zncc', 'sad', 'ssd', 'sad-occlusion'}
        Photo-consistency. 'lcn': the variance across views of their luminances normalised by
        the local mean and contrast over ``window_px`` (normalised once per view, before the
        sweep: the fastest, and the most accurate on the twin with box aggregation; see
        :mod:`lfring.depth.costs`). The others compare the warped luminances divided by their
        wide local mean: absolute or squared deviation from their mean, one minus their mean
        zero-normalised cross-correlation with the mean over ``window_px``, or the absolute
        deviation of the best subset (the view deviating most is left out, against occlusions).
    aggregation : {'box', 'guided'}
        Spatial aggregation of each cost slice over ``aggregate_px``: a box, or an edge-aware
        guided filter (guide: the reference view, or for 'center' the views' mean refocused at
        the middle hypothesis).
    window_px : int
        Odd window of the normalisation ('lcn') or of the correlation ('zncc').
    aggregate_px : int, optional
        Odd window of the aggregation: by default LCN_AGGREGATE_PX (15) for 'lcn' and
        ``window_px`` for the other costs.
    min_views : int
        Pixels seen by fewer views get NaN.
    threads : int, optional
        Threads of the default ('lcn', 'box', numpy) sweep; by default OpenCV's thread count.

    Returns
    -------
    DepthResult

    Notes
    -----
    With c(i) the aggregated cost, i* = argmin c and a parabola through c(i*-1), c(i*), c(i*+1),
    the refined index is ``i* + (c(i*-1) - c(i*+1)) / (2 (c(i*-1) - 2 c(i*) + c(i*+1)))``; the
    depth follows from linear interpolation in 1/(Z - z0). The confidence is
    ``1 - c(i*) / c2`` with c2 the lowest cost more than one pixel of view motion from i*.
    """
    from lfring.backends import BACKENDS

    if backend not in BACKENDS:
        raise InvalidInputError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    if cost not in COSTS:
        raise InvalidInputError(f"cost must be one of {', '.join(COSTS)}, got {cost!r}")
    if aggregation not in AGGREGATIONS:
        raise InvalidInputError(f"aggregation must be one of {', '.join(AGGREGATIONS)}, got {aggregation!r}")
    _odd_positive("window_px", window_px)
    if aggregate_px is not None:
        _odd_positive("aggregate_px", aggregate_px)
    _optional_count("threads", threads, 1, "")
    _optional_count("num_planes", num_planes, 2, " (or None for the default spacing)")
    arr = check_views(views)
    calibration.check_fits(arr.shape)
    if not np.all(np.isfinite(arr)):
        raise InvalidInputError("views contain NaN or infinite values")
    plan = _plan(arr, calibration, zmin_m, zmax_m, num_planes, reference)
    if aggregate_px is None:
        aggregate_px = LCN_AGGREGATE_PX if cost == "lcn" else window_px
    threads = max(1, cv2.getNumThreads()) if threads is None else int(threads)
    fin = Finisher(plan.depths, calibration.depth_origin_m, arr.shape[1:3], min_views)
    if cost == "lcn" and aggregation == "box" and backend == "numpy":
        sweep_strips(lcn_sources(arr, calibration, window_px, threads=threads), plan.masks, plan.hs,
                     aggregate_px=aggregate_px, exclude=plan.exclude, threads=threads, on_strip=fin)
    else:
        out = _sweep_whole(arr, calibration, plan, backend, device, cost, aggregation, window_px, aggregate_px, threads)
        fin(0, arr.shape[1], *out)
    return fin.result(depths_m=plan.depths, step_px=plan.step_px, reference=plan.reference, cost=cost, aggregation=aggregation)


@dataclass(frozen=True)
class _Plan:
    """What a sweep needs besides the views: hypotheses, homographies, masks and spacing."""

    depths: np.ndarray  # (N,) metres
    hs: np.ndarray  # (N, V, 3, 3) H_ref_from_view
    masks: np.ndarray  # (V, h, w)
    reference: object
    step_px: float  # largest view motion between neighbouring hypotheses
    exclude: int  # the second minimum is looked for more than this many hypotheses away


def _plan(views, calibration, zmin_m, zmax_m, num_planes, reference) -> _Plan:
    ref = check_reference(reference, calibration.num_views)
    depths = depth_hypotheses(calibration, zmin_m, zmax_m, num=num_planes)
    calibration.check_depth(np.array([zmin_m, zmax_m]))  # warns once if outside the calibrated range
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)
        hs = calibration.homographies(depths, reference=ref)  # (N, V, 3, 3)
    shape = views.shape[1:3]
    step = view_motion_px(calibration, depths, shape)
    # The second minimum is looked for more than one pixel of motion away from the best.
    exclude = max(1, int(np.ceil(1.0 / max(step, 1e-6))))
    return _Plan(depths, hs, cached_view_masks(calibration, shape), ref, step, exclude)


def _sweep_whole(views, calibration, plan, backend, device, cost, aggregation, window_px, aggregate_px, threads):
    """The sweep for the other costs, the guided aggregation and the torch backend."""
    h, w = views.shape[1:3]
    masks, hs = plan.masks, plan.hs
    lum = None
    if cost != "lcn" or aggregation == "guided":
        lum = normalised_luminance(views, masks, sigma=max(8.0, min(h, w) / 40.0))
    guide_image = None
    if aggregation == "guided":
        if plan.reference == "center":
            mid = len(plan.depths) // 2
            acc = np.zeros((h, w), np.float32)
            wsum = np.zeros((h, w), np.float32)
            for k in range(len(lum)):
                acc += warp_image(lum[k] * masks[k], hs[mid, k], (w, h))
                wsum += warp_image(masks[k], hs[mid, k], (w, h))
            g = acc / np.maximum(wsum, WEIGHT_FLOOR)
        else:
            g = lum[plan.reference]
        guide_image = np.clip(g / max(float(g.max()), 1e-6), 0, 1).astype(np.float32)
    if cost == "lcn":  # the sweep compares the locally normalised luminances instead
        lum = lcn_sources(views, calibration, window_px, threads=threads)
    if backend == "torch":
        from lfring.backends.torch_depth import sweep_torch

        return sweep_torch(lum, masks, hs, cost=cost, aggregation=aggregation, window_px=window_px,
                           aggregate_px=aggregate_px, guide=guide_image, exclude=plan.exclude, device=device)
    guide = None if guide_image is None else cv2.ximgproc.createGuidedFilter(guide_image, aggregate_px // 2, GUIDED_EPS)
    return sweep_slices(lum, masks, hs, cost, window_px, guide, plan.exclude, aggregate_px)
