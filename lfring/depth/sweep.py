"""Plane-sweep depth over the views (SPEC 6), streamed: memory does not grow with the number
of depth hypotheses.

For every hypothesis Z (evenly spaced in 1/(Z - z0), at most one pixel of view motion apart by
default) every view is warped into the reference frame with H_ref_from_view(Z), the warped
views are compared with their consensus, the cost is aggregated spatially, and each pixel keeps
its best hypothesis and the costs of its neighbours. A parabola through those three costs gives
the sub-hypothesis depth; the cost curve's distinctness gives the confidence.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import cv2
import numpy as np

from lfring.errors import InvalidInputError, LfringWarning
from lfring.geometry import check_reference
from lfring.refocus import _check_views, _warp, depth_hypotheses, view_masks, view_motion_px

__all__ = ["DepthResult", "estimate_depth", "COSTS", "AGGREGATIONS"]

COSTS = ("sad", "ssd", "zncc", "sad-occlusion")
AGGREGATIONS = ("box", "guided")


@dataclass(frozen=True, eq=False)
class DepthResult:
    """A depth map in the reference frame.

    Attributes
    ----------
    depth_m : (h, w) float32
        Distance from the main lens in metres; NaN where fewer than two views see the pixel.
    confidence : (h, w) float32 in [0, 1]
        How distinct the best hypothesis is: 1 - best cost / best cost away from it.
    hypothesis_index : (h, w) float32
        The disparity-space result: the refined (fractional) index into ``depths_m``, which are
        evenly spaced in 1/(Z - z0), i.e. in disparity.
    depths_m : (N,) float64
        The hypotheses.
    step_px : float
        Largest motion of any view pixel between neighbouring hypotheses.
    reference : 'center' or int
    """

    depth_m: np.ndarray
    confidence: np.ndarray
    hypothesis_index: np.ndarray
    depths_m: np.ndarray
    step_px: float
    reference: object
    cost: str
    aggregation: str


def _normalised_luminance(views: np.ndarray, masks: np.ndarray, sigma: float) -> np.ndarray:
    """Luminance of every view divided by its local mean (Gaussian, masked): removes the views'
    different vignetting and exposure, which would otherwise bias photo-consistency."""
    v = views.mean(axis=3) if views.shape[3] > 1 else views[..., 0]
    out = np.empty(v.shape, np.float32)
    for k in range(len(v)):
        num = cv2.GaussianBlur(v[k] * masks[k], (0, 0), sigma)
        den = cv2.GaussianBlur(masks[k], (0, 0), sigma)
        out[k] = np.where(den > 1e-3, v[k] / np.maximum(num / np.maximum(den, 1e-6), 1e-4), 0.0)
    return out


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
    cost: str = "zncc",
    aggregation: str = "guided",
    window_px: int = 9,
    min_views: int = 2,
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
    cost : {'sad', 'ssd', 'zncc', 'sad-occlusion'}
        Photo-consistency of the warped, locally normalised luminances: absolute or squared
        deviation from their mean, one minus their mean zero-normalised cross-correlation with
        the mean over the window, or the absolute deviation of the best subset (the view
        deviating most is left out, against occlusions).
    aggregation : {'box', 'guided'}
        Spatial aggregation of each cost slice over ``window_px``: a box, or an edge-aware
        guided filter (guide: the reference view, or for 'center' the views' mean refocused at
        the middle hypothesis).
    min_views : int
        Pixels seen by fewer views get NaN.

    Returns
    -------
    DepthResult

    Notes
    -----
    With c(i) the aggregated cost, i* = argmin c and a parabola through c(i*-1), c(i*), c(i*+1),
    the refined index is ``i* + (c(i*-1) - c(i*+1)) / (2 (c(i*-1) - 2 c(i*) + c(i*+1)))``; the
    depth follows from linear interpolation in 1/(Z - z0). The confidence is
    ``1 - c(i*) / c2`` with c2 the best cost at least one pixel of view motion away.
    """
    from lfring.backends import BACKENDS

    if backend not in BACKENDS:
        raise InvalidInputError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    if cost not in COSTS:
        raise InvalidInputError(f"cost must be one of {', '.join(COSTS)}, got {cost!r}")
    if aggregation not in AGGREGATIONS:
        raise InvalidInputError(f"aggregation must be one of {', '.join(AGGREGATIONS)}, got {aggregation!r}")
    if isinstance(window_px, bool) or not isinstance(window_px, (int, np.integer)) or window_px < 1 or window_px % 2 == 0:
        raise InvalidInputError(f"window_px must be an odd positive integer, got {window_px!r}")
    arr = _check_views(views)
    if not np.all(np.isfinite(arr)):
        raise InvalidInputError("views contain NaN or infinite values")
    if num_planes is not None and (isinstance(num_planes, bool) or not isinstance(num_planes, (int, np.integer)) or num_planes < 2):
        raise InvalidInputError(f"num_planes must be an integer >= 2 (or None for the default spacing), got {num_planes!r}")
    ref = check_reference(reference, calibration.num_views)
    depths = depth_hypotheses(calibration, zmin_m, zmax_m, num=num_planes)
    calibration.check_depth(np.array([zmin_m, zmax_m]))  # warns once if outside the calibrated range
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)
        hs = calibration.homographies(depths, reference=ref)  # (N, V, 3, 3)
    masks = view_masks(calibration, arr.shape[1:3])
    h, w = arr.shape[1:3]
    lum = _normalised_luminance(arr, masks, sigma=max(8.0, min(h, w) / 40.0))
    guide = guide_image = None
    if aggregation == "guided":
        if ref == "center":
            mid = len(depths) // 2
            acc = np.zeros((h, w), np.float32)
            wsum = np.zeros((h, w), np.float32)
            for k in range(len(lum)):
                acc += _warp(lum[k] * masks[k], hs[mid, k], (w, h))
                wsum += _warp(masks[k], hs[mid, k], (w, h))
            g = acc / np.maximum(wsum, 1e-3)
        else:
            g = lum[ref]
        guide_image = np.clip(g / max(float(g.max()), 1e-6), 0, 1).astype(np.float32)
        guide = cv2.ximgproc.createGuidedFilter(guide_image, window_px // 2, 1e-3)
    step = view_motion_px(calibration, depths, (h, w))
    # The second minimum is looked for at least one pixel of motion away from the best.
    exclude = max(1, int(np.ceil(1.0 / max(step, 1e-6))))
    if backend == "torch":
        from lfring.backends.torch_depth import sweep_torch

        best_i, c_best, c_prev, c_next, c_second, nviews = sweep_torch(lum, masks, hs, cost=cost, aggregation=aggregation,
                                                                       window_px=window_px, guide=guide_image, exclude=exclude, device=device)
    else:
        best_i, c_best, c_prev, c_next, c_second, nviews = _sweep_numpy(lum, masks, hs, cost, window_px, guide, exclude)
    return _finish(best_i, c_best, c_prev, c_next, c_second, nviews, depths, calibration, ref, cost, aggregation, min_views, step)


def slice_cost(lum_w: np.ndarray, wts: np.ndarray, cost: str, window_px: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel cost of one hypothesis from warped luminances (V, h, w) premultiplied by their
    warped masks ``wts`` (V, h, w); returns (cost before aggregation, number of views)."""
    nview = wts.sum(axis=0)
    safe = np.maximum(nview, 1e-3)
    vals = lum_w / np.maximum(wts, 1e-3)
    valid = wts > 0.5
    mean = (lum_w.sum(axis=0)) / safe
    if cost in ("sad", "sad-occlusion"):
        dev = np.abs(vals - mean) * valid
        if cost == "sad-occlusion":
            worst = dev.max(axis=0)
            n = valid.sum(axis=0)
            c = (dev.sum(axis=0) - np.where(n > 2, worst, 0.0)) / np.maximum(n - (n > 2), 1)
        else:
            c = dev.sum(axis=0) / np.maximum(valid.sum(axis=0), 1)
    elif cost == "ssd":
        c = ((vals - mean) ** 2 * valid).sum(axis=0) / np.maximum(valid.sum(axis=0), 1)
    else:  # zncc of every view with the mean, over the window
        k = (window_px, window_px)
        mu_m = cv2.boxFilter(mean, -1, k)
        var_m = np.maximum(cv2.boxFilter(mean * mean, -1, k) - mu_m**2, 1e-8)
        acc = np.zeros_like(mean)
        for j in range(len(vals)):
            vj = vals[j] * valid[j]
            mu_j = cv2.boxFilter(vj, -1, k)
            var_j = np.maximum(cv2.boxFilter(vj * vj, -1, k) - mu_j**2, 1e-8)
            cov = cv2.boxFilter(vj * mean, -1, k) - mu_j * mu_m
            acc += (cov / np.sqrt(var_j * var_m)) * valid[j]
        c = 1.0 - acc / np.maximum(valid.sum(axis=0), 1)
    return c.astype(np.float32), nview


def _sweep_numpy(lum, masks, hs, cost, window_px, guide, exclude=1):
    n, v = hs.shape[:2]
    h, w = lum.shape[1:]
    best = np.full((h, w), np.inf, np.float32)
    best_i = np.zeros((h, w), np.int32)
    c_prev = np.full((h, w), np.inf, np.float32)
    c_next = np.full((h, w), np.inf, np.float32)
    second = np.full((h, w), np.inf, np.float32)
    nviews = np.zeros((h, w), np.float32)
    last = np.full((h, w), np.inf, np.float32)
    src = lum * masks
    lum_w = np.empty((v, h, w), np.float32)
    wts = np.empty((v, h, w), np.float32)
    for i in range(n):
        for k in range(v):
            _warp(src[k], hs[i, k], (w, h), dst=lum_w[k])
            _warp(masks[k], hs[i, k], (w, h), dst=wts[k])
        c, nv = slice_cost(lum_w, wts, cost, window_px)
        c = np.where(nv >= 1.5, c, np.inf).astype(np.float32)
        finite = np.isfinite(c)
        agg = guide.filter(np.where(finite, c, 1.0)) if guide is not None else cv2.boxFilter(np.where(finite, c, 1.0), -1, (window_px, window_px))
        agg = np.where(finite, agg, np.inf).astype(np.float32)
        _update(i, agg, last, best, best_i, c_prev, c_next, second, exclude)
        np.maximum(nviews, nv, out=nviews)
        last = agg
    return best_i, best, c_prev, c_next, second, nviews


def _update(i, agg, last, best, best_i, c_prev, c_next, second, exclude=1):
    """Streamed argmin with the neighbours' costs and the best cost at least ``exclude``
    hypotheses away from the minimum (an approximation when the minimum moves later)."""
    # The slice right after the current best gives its right neighbour.
    after = best_i == i - 1
    c_next[after] = agg[after]
    new = agg < best
    far = np.abs(i - best_i) > exclude
    # The old best becomes a candidate for the second minimum when the new best is far from it.
    np.minimum(second, np.where(new & far, best, np.inf), out=second)
    # A slice that is not the new best and is far from the best is a candidate too.
    np.minimum(second, np.where(~new & far, agg, np.inf), out=second)
    c_prev[new] = last[new]
    c_next[new] = np.inf
    best[new] = agg[new]
    best_i[new] = i


def _finish(best_i, c_best, c_prev, c_next, c_second, nviews, depths, calibration, ref, cost, aggregation, min_views, step_px):
    n = len(depths)
    a, b, c = c_prev.astype(np.float64), c_best.astype(np.float64), c_next.astype(np.float64)
    inner = np.isfinite(a) & np.isfinite(b) & np.isfinite(c) & (best_i > 0) & (best_i < n - 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        denom = np.where(inner, a - 2 * b + c, 0.0)
        delta = np.where(inner & (denom > 1e-12), 0.5 * (a - c) / np.where(denom > 1e-12, denom, 1.0), 0.0)
    idx = best_i + np.clip(delta, -0.5, 0.5)
    z0 = calibration.depth_origin_m
    inv = 1.0 / (depths - z0)
    inv_at = np.interp(idx, np.arange(n), inv)
    depth = (z0 + 1.0 / inv_at).astype(np.float32)
    with np.errstate(invalid="ignore", divide="ignore"):
        conf = np.where(np.isfinite(c_second) & (c_second > 0), 1.0 - b / c_second, 0.0)
    conf = np.clip(np.nan_to_num(conf, nan=0.0), 0.0, 1.0).astype(np.float32)
    seen = (nviews >= min_views - 0.5) & np.isfinite(c_best)
    depth[~seen] = np.nan
    conf[~seen] = 0.0
    return DepthResult(depth_m=depth, confidence=conf, hypothesis_index=np.where(seen, idx, np.nan).astype(np.float32),
                       depths_m=depths, step_px=step_px, reference=ref, cost=cost, aggregation=aggregation)
