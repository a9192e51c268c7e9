"""Plane-sweep depth over the views (SPEC 6), streamed: memory does not grow with the number
of depth hypotheses.

For every hypothesis Z (evenly spaced in 1/(Z - z0), at most one pixel of view motion apart by
default) every view is warped into the reference frame with H_ref_from_view(Z), the warped
views are compared with their consensus, the cost is aggregated spatially, and each pixel keeps
its best hypothesis and the costs of its neighbours. A parabola through those three costs gives
the sub-hypothesis depth; the cost curve's distinctness gives the confidence.

The default cost ('lcn' with box aggregation) runs in :mod:`lfring.depth.stream`, strip by strip
on several threads; the other costs and the guided aggregation run here, a whole slice at a time.
"""

from __future__ import annotations

import warnings
import weakref
from dataclasses import dataclass

import cv2
import numpy as np

from lfring.depth.stream import (
    RunningMinimum,
    _luminance,
    _translations,
    lcn_cost,
    lcn_sources,
    sweep_strips,
)
from lfring.errors import InvalidInputError, LfringWarning
from lfring.geometry import check_reference
from lfring.refocus import (
    _check_views,
    _warp,
    depth_hypotheses,
    view_masks,
    view_motion_px,
)

__all__ = ["AGGREGATIONS", "COSTS", "DepthResult", "estimate_depth"]

COSTS = ("lcn", "zncc", "sad", "ssd", "sad-occlusion")
# The default aggregation window of the 'lcn' cost (the other costs aggregate over window_px).
LCN_AGGREGATE_PX = 15
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
    different vignetting and exposure, which would otherwise bias photo-consistency.

    The local mean varies slowly (sigma of tens of pixels), so it is computed on the image
    shrunk by up to sigma / 4 and enlarged back bilinearly: a few percent of the time of the
    full-size blur, and the same to a fraction of a percent."""
    v, h, w = views.shape[:3]
    f = int(max(1, min(sigma // 4, min(h, w) // 16)))
    small = (max(1, w // f), max(1, h // f))
    out = np.empty((v, h, w), np.float32)
    for k, lum in enumerate(_luminance(views)):
        num = cv2.GaussianBlur(cv2.resize(lum * masks[k], small, interpolation=cv2.INTER_AREA), (0, 0), sigma / f)
        den = cv2.GaussianBlur(cv2.resize(masks[k], small, interpolation=cv2.INTER_AREA), (0, 0), sigma / f)
        local = np.where(den > 1e-3, num / np.maximum(den, 1e-6), 0.0).astype(np.float32)
        local = cv2.resize(local, (w, h), interpolation=cv2.INTER_LINEAR)
        big = cv2.resize(den, (w, h), interpolation=cv2.INTER_LINEAR)
        out[k] = np.where(big > 1e-3, lum / np.maximum(local, 1e-4), 0.0)
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
    cost: str = "lcn",
    aggregation: str = "box",
    window_px: int = 9,
    aggregate_px: int | None = None,
    min_views: int = 2,
    coarse_to_fine: bool = False,
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
        :mod:`lfring.depth.stream`). The others compare the warped luminances divided by their
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
    coarse_to_fine : bool
        Sweep every other hypothesis at half resolution, then only the hypothesis nearest a
        smoothed copy of that coarse surface and its two neighbours at full resolution (about
        2.5x less work for the default spacing). Used when there are at least
        ``COARSE_MIN_PLANES`` hypotheses and the homographies are translations (the optics
        model); otherwise the full sweep runs. The confidence then comes from the coarse sweep.
        Off by default: on the twin it keeps the accuracy on pixels all four views see, but
        loses it on weakly textured, far, partly seen surfaces (see benchmarks/RESULTS.md).
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
    for name, value in (("window_px", window_px), ("aggregate_px", 1 if aggregate_px is None else aggregate_px)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1 or value % 2 == 0:
            raise InvalidInputError(f"{name} must be an odd positive integer, got {value!r}")
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1):
        raise InvalidInputError(f"threads must be a positive integer, got {threads!r}")
    if aggregate_px is None:
        aggregate_px = LCN_AGGREGATE_PX if cost == "lcn" else window_px
    arr = _check_views(views)
    calibration.check_views(arr.shape)
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
    h, w = arr.shape[1:3]
    masks = _masks(calibration, (h, w))
    step = view_motion_px(calibration, depths, (h, w))
    # The second minimum is looked for more than one pixel of motion away from the best.
    exclude = max(1, int(np.ceil(1.0 / max(step, 1e-6))))
    n = len(depths)
    use_coarse = coarse_to_fine and n >= COARSE_MIN_PLANES and min(h, w) >= COARSE_MIN_SIZE_PX and _is_translation(hs)
    threads = max(1, cv2.getNumThreads()) if threads is None else int(threads)
    if cost == "lcn" and aggregation == "box" and backend == "numpy" and not use_coarse:
        fin = _Finisher(depths, calibration.depth_origin_m, (h, w), min_views)
        sweep_strips(lcn_sources(arr, masks, window_px, threads=threads), masks, hs, aggregate_px=aggregate_px,
                     exclude=exclude, threads=threads, on_strip=fin)
        return fin.result(depths_m=depths, step_px=step, reference=ref, cost=cost, aggregation=aggregation)
    lum = None
    if cost != "lcn" or aggregation == "guided":
        lum = _normalised_luminance(arr, masks, sigma=max(8.0, min(h, w) / 40.0))
    guide_image = None
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
    if cost == "lcn":  # the sweep compares the locally normalised luminances instead
        lum = lcn_sources(arr, masks, window_px, threads=threads)
    if not use_coarse:
        out = _sweep(backend, device, lum, masks, hs, cost, aggregation, window_px, aggregate_px, guide_image, exclude)
        return _finish(*out, depths, calibration, ref, cost, aggregation, min_views, step)

    # Coarse: the whole sweep at half resolution over every other hypothesis.
    nc = n // 2 + 1
    depths_c = depth_hypotheses(calibration, float(depths[0]), float(depths[-1]), num=nc)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)
        hs_c = _HALF @ calibration.homographies(depths_c, reference=ref) @ _HALF_INV
    wh2 = (w // 2, h // 2)
    half = lambda x: cv2.resize(x, wh2, interpolation=cv2.INTER_AREA)
    lum_c = np.stack([half(x) for x in lum])
    masks_c = np.stack([half(x) for x in masks])
    guide_c = None if guide_image is None else half(guide_image)
    step_c = step * (n - 1) / (nc - 1)
    window_c = max(1, (window_px // 2) | 1)
    aggregate_c = max(1, (aggregate_px // 2) | 1)
    out_c = _sweep(backend, device, lum_c, masks_c, hs_c, cost, aggregation, window_c, aggregate_c, guide_c,
                   max(1, int(np.ceil(1.0 / max(step_c, 1e-6)))))
    coarse = _finish(*out_c, depths_c, calibration, ref, cost, aggregation, min_views, step_c)
    # Fine: at full resolution, the 2 * FINE_BAND + 1 hypotheses around each pixel's coarse one.
    idx_c = coarse.hypothesis_index * ((n - 1) / (nc - 1))
    idx_c = np.where(np.isfinite(idx_c), idx_c, np.nanmedian(idx_c) if np.isfinite(idx_c).any() else 0.0).astype(np.float32)
    # The band follows a smoothed coarse surface: the windowed cost at a pixel mixes its
    # neighbours' samples, so a jittery centre would pass its jitter into the result.
    idx_c = cv2.blur(idx_c, (3 * window_c, 3 * window_c))
    up = lambda x: cv2.warpAffine(x.astype(np.float32), _HALF[:2], (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                  borderMode=cv2.BORDER_REPLICATE)
    nb = 2 * FINE_BAND + 1
    center = np.clip(up(idx_c), FINE_BAND, n - 1 - FINE_BAND)
    maps = _FineMaps(hs, center, nb)
    if backend == "torch":
        from lfring.backends.torch_depth import fine_torch

        aggs, nviews = fine_torch(lum, masks, maps, cost=cost, aggregation=aggregation, window_px=window_px,
                                  aggregate_px=aggregate_px, guide=guide_image, device=device)
    else:
        aggs, nviews = _fine_numpy(lum, masks, maps, cost, aggregation, window_px, aggregate_px, guide_image)
    best_j, c_best, c_prev, c_next = _select(aggs)
    idx = center + (best_j - FINE_BAND) + _parabola(c_prev, c_best, c_next)
    # The confidence is the coarse cost curve's distinctness (the fine band is too narrow for it).
    fin = _Finisher(depths, calibration.depth_origin_m, (h, w), min_views)
    fin.rows(0, h, idx.astype(np.float32), np.clip(up(coarse.confidence), 0.0, 1.0), c_best, nviews)
    return fin.result(depths_m=depths, step_px=step, reference=ref, cost=cost, aggregation=aggregation)


# Coarse-to-fine (when asked for) runs when the sweep has at least this many hypotheses on views
# at least this large; the fine stage keeps the FINE_BAND hypotheses either side of the coarse one.
COARSE_MIN_PLANES = 6
COARSE_MIN_SIZE_PX = 64
FINE_BAND = 1
# Pixel (x, y) of a view is (x + 0.5) / 2 - 0.5 in the view halved (cv2.resize's convention).
_HALF = np.array([[0.5, 0.0, -0.25], [0.0, 0.5, -0.25], [0.0, 0.0, 1.0]])
_HALF_INV = np.linalg.inv(_HALF)
_MASKS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _masks(calibration, shape_hw) -> np.ndarray:
    """view_masks, made once per calibration and view shape (not to be written to)."""
    per = _MASKS.setdefault(calibration, {})
    if tuple(shape_hw) not in per:
        m = view_masks(calibration, shape_hw)
        per[tuple(shape_hw)] = m
    return per[tuple(shape_hw)]


def _sweep(backend, device, lum, masks, hs, cost, aggregation, window_px, aggregate_px, guide_image, exclude):
    if backend == "torch":
        from lfring.backends.torch_depth import sweep_torch

        return sweep_torch(lum, masks, hs, cost=cost, aggregation=aggregation, window_px=window_px,
                           aggregate_px=aggregate_px, guide=guide_image, exclude=exclude, device=device)
    guide = None if guide_image is None else cv2.ximgproc.createGuidedFilter(guide_image, aggregate_px // 2, 1e-3)
    return _sweep_numpy(lum, masks, hs, cost, window_px, guide, exclude, aggregate_px)


def _is_translation(hs) -> bool:
    """Whether every H_ref_from_view is a translation that is linear in the hypothesis index
    (the optics model, or any calibration whose views are parallel pinholes of equal focal length)."""
    t = _translations(hs)
    if t is None:
        return False
    i = np.arange(len(t), dtype=np.float64)[:, None, None]
    lin = t[:1] + i * (t[-1:] - t[:1]) / max(len(t) - 1, 1)
    return bool(np.all(np.abs(t - lin) < 1e-6))


class _FineMaps:
    """Per-pixel sampling maps of the fine stage: band slot j of pixel x is the (fractional)
    hypothesis ``center(x) + j - band``, and view k is sampled at ``x - t_k`` with t_k the
    view's translation there, linear in the hypothesis index (see :func:`_is_translation`)."""

    def __init__(self, hs, center, nb):
        hs = np.asarray(hs, np.float64)
        n = len(hs)
        self.t0 = hs[0, :, :2, 2]  # (V, 2)
        self.dt = (hs[-1, :, :2, 2] - self.t0) / max(n - 1, 1)
        self.center = center.astype(np.float32)
        self.nb = nb
        self.band = nb // 2
        self.num_views = hs.shape[1]
        h, w = center.shape
        self.shape = (h, w)
        self.xx = np.arange(w, dtype=np.float32)[None, :]
        self.yy = np.arange(h, dtype=np.float32)[:, None]

    def __call__(self, j: int, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(map_x, map_y), float32 (h, w): where reference pixels sample view k in slot j."""
        off = j - self.band
        tx0, ty0 = self.t0[k] + off * self.dt[k]
        dtx, dty = (np.float32(x) for x in self.dt[k])
        mx = self.center * -dtx
        mx += self.xx - np.float32(tx0)
        my = self.center * -dty
        my += self.yy - np.float32(ty0)
        return mx, my


def _fine_numpy(lum, masks, maps, cost, aggregation, window_px, aggregate_px, guide_image):
    """Aggregated costs (nb, h, w) of the band hypotheses and the most views seen."""
    v, h, w = lum.shape
    src = [np.ascontiguousarray(np.stack([lum[k] * masks[k], masks[k]], axis=-1)) for k in range(v)]
    guide = None if guide_image is None else cv2.ximgproc.createGuidedFilter(guide_image, aggregate_px // 2, 1e-3)
    aggs = np.empty((maps.nb, h, w), np.float32)
    nviews = np.zeros((h, w), np.float32)
    lum_w = np.empty((v, h, w), np.float32)
    wts = np.empty((v, h, w), np.float32)
    for j in range(maps.nb):
        for k in range(v):
            mx, my = maps(j, k)
            both = cv2.remap(src[k], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            lum_w[k] = both[..., 0]
            wts[k] = both[..., 1]
        aggs[j] = _aggregate(*slice_cost(lum_w, wts, cost, window_px), guide, aggregate_px)
        np.maximum(nviews, wts.sum(axis=0), out=nviews)
    return aggs, nviews


def _aggregate(c, nv, guide, window_px):
    finite = (nv >= 1.5) & np.isfinite(c)
    filled = np.where(finite, c, np.float32(1.0)).astype(np.float32)
    agg = guide.filter(filled) if guide is not None else _box(filled, window_px)
    agg[~finite] = np.inf
    return agg


def _select(aggs):
    """Best slot of the band (the first of equal minima), its cost and its neighbours' (inf at
    the band's ends, so that no parabola is fitted there)."""
    nb = len(aggs)
    best_j = np.argmin(aggs, axis=0).astype(np.int32)
    take = lambda j: np.take_along_axis(aggs, np.clip(j, 0, nb - 1)[None], axis=0)[0]
    c_best = take(best_j)
    c_prev = np.where(best_j > 0, take(best_j - 1), np.inf).astype(np.float32)
    c_next = np.where(best_j < nb - 1, take(best_j + 1), np.inf).astype(np.float32)
    return best_j, c_best, c_prev, c_next


def slice_cost(lum_w: np.ndarray, wts: np.ndarray, cost: str, window_px: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel cost of one hypothesis from warped luminances (V, h, w) premultiplied by their
    warped masks ``wts`` (V, h, w); returns (cost before aggregation, number of views)."""
    nview = wts.sum(axis=0)
    if cost == "zncc":
        return _zncc(lum_w, wts, nview, window_px), nview
    if cost == "lcn":  # lum_w: the warped locally normalised luminances (lcn_sources) times their masks
        return lcn_cost(lum_w.sum(axis=0), np.square(lum_w).sum(axis=0), nview), nview
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
    else:  # ssd
        c = ((vals - mean) ** 2 * valid).sum(axis=0) / np.maximum(valid.sum(axis=0), 1)
    return c.astype(np.float32), nview


def _box(src: np.ndarray, k: int, dst=None) -> np.ndarray:
    """Normalised k x k box filter, as cv2.boxFilter (BORDER_REFLECT_101) but as two separable
    passes, which OpenCV runs several times faster on float32 images."""
    kern = _BOX_KERNELS.get(k)
    if kern is None:
        kern = _BOX_KERNELS.setdefault(k, np.full(k, 1.0 / k, np.float32))
    return cv2.sepFilter2D(src, cv2.CV_32F, kern, kern, dst=dst, borderType=cv2.BORDER_REFLECT_101)


_BOX_KERNELS: dict = {}


def _zncc(lum_w: np.ndarray, wts: np.ndarray, nview: np.ndarray, window_px: int) -> np.ndarray:
    """One minus the mean, over the views valid at a pixel, of the zero-normalised
    cross-correlation over the window of each view with the views' weighted mean.

    The same numbers as the textbook expression (box means, variances clamped at 1e-8), computed
    with in-place float32 operations: a slice costs a few dozen passes over the image."""
    k = window_px
    mean = lum_w.sum(axis=0)
    np.divide(mean, np.maximum(nview, 1e-3), out=mean)
    mu_m = _box(mean, k)
    t = np.multiply(mean, mean)
    var_m = _box(t, k)
    var_m -= mu_m * mu_m
    np.maximum(var_m, 1e-8, out=var_m)
    np.sqrt(var_m, out=var_m)  # now the standard deviation of the mean
    acc = np.zeros_like(mean)
    nvalid = np.zeros_like(mean)
    vj = np.empty_like(mean)
    valid = np.empty_like(mean)
    mu_j = np.empty_like(mean)
    s2 = np.empty_like(mean)
    cov = np.empty_like(mean)
    for j in range(len(lum_w)):
        np.greater(wts[j], 0.5, out=valid, casting="unsafe")
        nvalid += valid
        np.maximum(wts[j], 1e-3, out=vj)
        np.divide(lum_w[j], vj, out=vj)
        vj *= valid
        _box(vj, k, dst=mu_j)
        np.multiply(vj, vj, out=t)
        _box(t, k, dst=s2)
        np.multiply(vj, mean, out=t)
        _box(t, k, dst=cov)
        # cov / sqrt(var_j var_m), var_j = max(E[v^2] - E[v]^2, 1e-8)
        np.multiply(mu_j, mu_m, out=t)
        cov -= t
        np.multiply(mu_j, mu_j, out=t)
        s2 -= t
        np.maximum(s2, 1e-8, out=s2)
        np.sqrt(s2, out=s2)
        s2 *= var_m
        cov /= s2
        cov *= valid
        acc += cov
    np.maximum(nvalid, 1.0, out=nvalid)
    acc /= nvalid
    np.subtract(1.0, acc, out=acc)
    return acc


def _sweep_numpy(lum, masks, hs, cost, window_px, guide, exclude=1, aggregate_px=None):
    n, v = hs.shape[:2]
    h, w = lum.shape[1:]
    aggregate_px = window_px if aggregate_px is None else aggregate_px
    run = RunningMinimum((h, w), exclude)
    nviews = np.zeros((h, w), np.float32)
    src = lum * masks
    lum_w = np.empty((v, h, w), np.float32)
    wts = np.empty((v, h, w), np.float32)
    for i in range(n):
        for k in range(v):
            _warp(src[k], hs[i, k], (w, h), dst=lum_w[k])
            _warp(masks[k], hs[i, k], (w, h), dst=wts[k])
        c, nv = slice_cost(lum_w, wts, cost, window_px)
        np.copyto(run.slot(), _aggregate(c, nv, guide, aggregate_px))
        run.push()
        np.maximum(nviews, nv, out=nviews)
    return run.best_i, run.best, run.c_prev, run.c_next, run.second(), nviews


def _parabola(a, b, c):
    """Offset of the minimum of the parabola through (-1, a), (0, b), (1, c), within +-0.5;
    0 where a neighbour is missing (inf) or the curve is not convex. float32."""
    a, b, c = (np.asarray(x, np.float32) for x in (a, b, c))
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        denom = a + c
        denom -= 2 * b  # inf or nan where a cost is missing
        delta = a - c
        delta *= 0.5
        delta /= denom
        ok = (denom > 1e-12) & np.isfinite(denom) & np.isfinite(delta)
    delta = np.where(ok, delta, np.float32(0.0))
    return np.clip(delta, -0.5, 0.5, out=delta)


def _refine(best_i, c_best, c_prev, c_next, c_second, n):
    """Fractional hypothesis index (parabola, none at the range's ends) and confidence
    ``1 - c_best / c_second`` (0 where c_second is missing or not positive), float32."""
    edge = (best_i <= 0) | (best_i >= n - 1)
    c_prev = np.where(edge, np.float32(np.inf), c_prev)
    idx = _parabola(c_prev, c_best, c_next)
    idx += best_i
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        conf = c_best / c_second
        np.subtract(np.float32(1.0), conf, out=conf)
    ok = np.isfinite(c_second) & (c_second > 0) & np.isfinite(conf)
    conf = np.where(ok, conf, np.float32(0.0))
    return idx, np.clip(conf, 0.0, 1.0, out=conf)


class _Finisher:
    """Depth, confidence and index rows from a sweep's strips (called from its threads)."""

    def __init__(self, depths, z0, shape, min_views):
        self.n = len(depths)
        self.inv = 1.0 / (np.asarray(depths, np.float64) - z0)
        self.z0 = z0
        # Hypotheses evenly spaced in 1/(Z - z0) (depth_hypotheses): interpolation is a line.
        step = (self.inv[-1] - self.inv[0]) / max(self.n - 1, 1)
        self.linear = bool(np.allclose(self.inv, self.inv[0] + step * np.arange(self.n), rtol=1e-9, atol=0))
        self.step = step
        self.min_views = min_views
        self.depth, self.conf, self.index = (np.empty(shape, np.float32) for _ in range(3))

    def __call__(self, r0, r1, best_i, c_best, c_prev, c_next, c_second, nviews):
        idx, conf = _refine(best_i, c_best, c_prev, c_next, c_second, self.n)
        self.rows(r0, r1, idx, conf, c_best, nviews)

    def rows(self, r0, r1, idx, conf, c_best, nviews):
        """Rows r0 to r1 from fractional hypothesis indices and confidences."""
        if self.linear:
            inv_at = idx * np.float32(self.step)
            inv_at += np.float32(self.inv[0])
        else:
            inv_at = np.interp(idx, np.arange(self.n), self.inv).astype(np.float32)
        depth = np.divide(np.float32(1.0), inv_at, out=inv_at)
        depth += np.float32(self.z0)
        seen = (nviews >= self.min_views - 0.5) & np.isfinite(c_best)
        self.depth[r0:r1] = np.where(seen, depth, np.float32(np.nan))
        self.conf[r0:r1] = np.where(seen, conf, np.float32(0.0))
        self.index[r0:r1] = np.where(seen, idx, np.float32(np.nan))

    def result(self, **record) -> DepthResult:
        return DepthResult(depth_m=self.depth, confidence=self.conf, hypothesis_index=self.index, **record)


def _finish(best_i, c_best, c_prev, c_next, c_second, nviews, depths, calibration, ref, cost, aggregation, min_views, step_px):
    fin = _Finisher(depths, calibration.depth_origin_m, c_best.shape, min_views)
    fin(0, c_best.shape[0], best_i, c_best, c_prev, c_next, c_second, nviews)
    return fin.result(depths_m=depths, step_px=step_px, reference=ref, cost=cost, aggregation=aggregation)
