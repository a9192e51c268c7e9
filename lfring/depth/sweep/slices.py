"""The whole-slice sweep: any cost and aggregation, a whole slice of every hypothesis at a time.

:func:`sweep_slices` is the NumPy/OpenCV reference; :func:`sweep_slices_torch` its torch twin,
which processes chunks of hypotheses at once on a GPU or the CPU (chunks sized so that their
tensors stay under about ``_CHUNK_BYTES``: memory does not grow with the number of hypotheses).
Tests hold the two together.
"""

from __future__ import annotations

import numpy as np

from lfring.core.backend import require_torch, resolve_device
from lfring.core.filters import BoxTorch
from lfring.core.validate import check_choice
from lfring.core.viewstack import WEIGHT_FLOOR
from lfring.core.warping import warp_image
from lfring.depth.aggregation import AGGREGATIONS, GUIDED_EPS, GuidedTorch, aggregate, aggregation_window
from lfring.depth.costs import as_cost
from lfring.depth.costs.lcn import weighted_square
from lfring.depth.costs.lcn_halves import checked_halves, half_aggregate, halves_least_torch
from lfring.depth.costs.lcn_occlusion import lcn_leave_one_out, leavable_views, occlusion_aggregate, occlusion_aggregate_torch
from lfring.depth.selection import RunningMinimum, RunningMinimumTorch
from lfring.errors import InvalidInputError

__all__ = ["sweep_slices", "sweep_slices_torch"]

_CHUNK_BYTES = 1 << 30
# Float32 images of the (V, h, w) size alive at once per hypothesis in the worst case (zncc):
# the repeated sources and their warps (2 channels each), the cost's per-view terms and the
# three padded window statistics per view.
_IMAGES_PER_HYPOTHESIS = 24


def sweep_slices(lum, masks, hs, cost, window_px, guide, exclude=1, aggregate_px=None, volume=None, halves=None):
    """Any cost and aggregation over every hypothesis, a whole slice at a time.

    Parameters
    ----------
    lum : (V, h, w) float32
        The views' luminances as the cost compares them (its :attr:`~lfring.depth.costs.base.DepthCost.sources`).
    masks : (V, h, w) float32
    hs : (N, V, 3, 3)
    cost : str or DepthCost
        The cost, by name or record (:data:`lfring.depth.costs.COSTS`).
    window_px : int
    guide : cv2.ximgproc.GuidedFilter or None
        The guided aggregation, or None for a box over ``aggregate_px``.
    exclude : int
        As :class:`lfring.depth.selection.RunningMinimum`.
    volume : (N, h, w) float32, optional
        As in :func:`sweep_strips`: filled with every aggregated slice; then only ``nviews``
        is returned.
    halves : (N, h, w) float32, optional
        As in :func:`sweep_strips` (with ``volume``; the 'lcn' costs).

    Returns
    -------
    best_i : (h, w) int32
        The best hypothesis.
    c_best, c_prev, c_next, c_second, nviews : (h, w) float32
        Its aggregated cost, its neighbours' (inf at the ends), the best cost more than
        ``exclude`` hypotheses away, and the most views that saw the pixel.
    """
    cost = as_cost(cost)
    n, v = hs.shape[:2]
    h, w = lum.shape[1:]
    aggregate_px = window_px if aggregate_px is None else aggregate_px
    run = RunningMinimum((h, w), exclude) if volume is None else None
    nviews = np.zeros((h, w), np.float32)
    src = lum * masks
    lum_w = np.empty((v, h, w), np.float32)
    wts = np.empty((v, h, w), np.float32)
    leavable = leavable_views(hs) if cost.leave_one_out else []
    halves_of = checked_halves(halves, volume, hs, (h, w), cost)
    window = aggregation_window(guide, aggregate_px)
    for i in range(n):
        for k in range(v):
            warp_image(src[k], hs[i, k], (w, h), dst=lum_w[k])
            warp_image(masks[k], hs[i, k], (w, h), dst=wts[k])
        nv = wts.sum(axis=0)
        c = cost.slice_cost(lum_w, wts, nv, window_px)
        agg = aggregate(c, nv, guide, aggregate_px)
        if leavable:
            s1, s2 = lum_w.sum(axis=0), weighted_square(lum_w, wts).sum(axis=0)
            occlusion_aggregate(agg, nv, ((lcn_leave_one_out(s1, s2, nv, lum_w[k], wts[k]), wts[k]) for k in leavable),
                                lambda one: aggregate(one, nv, guide, aggregate_px), window)
        if halves_of:
            least = np.full((h, w), np.inf, np.float32)
            for half in halves_of:
                half_aggregate([(lum_w[k], wts[k]) for k in half], nv >= 1.5, window, least)
            halves[i] = least
        np.copyto(run.slot() if run is not None else volume[i], agg)
        if run is not None:
            run.push()
        np.maximum(nviews, nv, out=nviews)
    if run is None:
        return nviews
    return run.best_i, run.best, run.c_prev, run.c_next, run.second(), nviews


def _checked_inputs(lum, masks, aggregation: str, guide):
    """The torch sweep's argument checks: the aggregation's name, float32 (V, h, w) luminances and
    masks, and a guide of the views' size for the guided aggregation."""
    check_choice(aggregation, "aggregation", AGGREGATIONS)
    lum = np.asarray(lum)
    masks = np.asarray(masks)
    if lum.dtype != np.float32 or masks.dtype != np.float32 or lum.ndim != 3 or masks.shape != lum.shape:
        raise InvalidInputError(
            f"need float32 (V, h, w) luminances and masks, got {lum.dtype} {lum.shape} and {masks.dtype} {masks.shape}"
        )
    h, w = lum.shape[1:]
    if aggregation == "guided" and (guide is None or np.shape(guide) != (h, w)):
        got = None if guide is None else np.shape(guide)
        raise InvalidInputError(f"the guided aggregation needs a ({h}, {w}) guide image, got {got}")
    return lum, masks


def _chunk_size(n: int, v: int, h: int, w: int) -> int:
    per = _IMAGES_PER_HYPOTHESIS * v * h * w * 4
    return int(max(1, min(n, _CHUNK_BYTES // max(per, 1))))


def sweep_slices_torch(lum, masks, hs, *, cost, aggregation, window_px, guide, exclude=1, device=None, aggregate_px=None,
                volume=None, halves=None):
    """Same contract as :func:`lfring.depth.stream.sweep_slices`, with kornia.

    Parameters
    ----------
    lum : (V, h, w) float32
        Normalised luminances.
    masks : (V, h, w) float32
        Valid weight of every view pixel.
    hs : (N, V, 3, 3) float64
        H_ref_from_view for every hypothesis and view.
    cost : str or DepthCost
        The cost, by name or record; ``lum`` holds its sources.
    aggregation : {'box', 'guided'}
    window_px : int
        Odd window of the cost ('zncc').
    aggregate_px : int, optional
        Odd window of the aggregation (guided: radius ``aggregate_px // 2``); ``window_px`` by default.
    guide : (h, w) float32 in [0, 1] or None
        The guided filter's guide image (required for 'guided').
    exclude : int
        The second minimum is looked for more than ``exclude`` hypotheses from the best.
    device : str or torch.device, optional
    volume : (N, h, w) float32 ndarray, optional
        Filled with every aggregated slice instead of keeping a running minimum; then only
        ``nviews`` is returned (as :func:`lfring.depth.stream.sweep_slices`).
    halves : (N, h, w) float32 ndarray, optional
        With ``volume``: every hypothesis's least cost of a half of the views, as
        :func:`lfring.depth.stream.sweep_slices` fills it.

    Returns
    -------
    best_i : (h, w) int32
    c_best, c_prev, c_next, c_second, nviews : (h, w) float32
        As the NumPy sweep defines them.
    """
    torch = require_torch()
    from kornia.geometry.transform import warp_perspective

    cost = as_cost(cost)
    lum, masks = _checked_inputs(lum, masks, aggregation, guide)
    v, h, w = lum.shape
    hs = np.asarray(hs, dtype=np.float64)
    if hs.ndim != 4 or hs.shape[1:] != (v, 3, 3):
        raise InvalidInputError(f"need (N, {v}, 3, 3) homographies, got {hs.shape}")
    dev = resolve_device(device)
    n = hs.shape[0]

    aggregate_px = window_px if aggregate_px is None else aggregate_px
    box_cost = BoxTorch(torch, (h, w), window_px, 1, dev)  # cv2.boxFilter: BORDER_REFLECT_101
    box_agg = box_cost if aggregate_px == window_px else BoxTorch(torch, (h, w), aggregate_px, 1, dev)
    guided = GuidedTorch(torch, guide, aggregate_px, GUIDED_EPS, dev) if aggregation == "guided" else None
    lum_t = torch.from_numpy(np.ascontiguousarray(lum)).to(dev)
    masks_t = torch.from_numpy(np.array(masks, dtype=np.float32)).to(dev)  # a writable copy: the cached masks are read-only
    src = torch.stack([lum_t * masks_t, masks_t], dim=1)  # (V, 2, h, w): each view warps with its mask
    hs_t = torch.from_numpy(hs).to(dev, torch.float32)

    def full(value):
        return torch.full((h, w), value, dtype=torch.float32, device=dev)

    run = RunningMinimumTorch(torch, (h, w), exclude, dev)
    nviews = full(0.0)
    leavable = leavable_views(hs) if cost.leave_one_out else []
    halves_of = checked_halves(halves, volume, hs, (h, w), cost)
    chunk = _chunk_size(n, v, h, w)
    with torch.no_grad():
        for i0 in range(0, n, chunk):
            i1 = min(n, i0 + chunk)
            c = i1 - i0
            warped = warp_perspective(src.repeat(c, 1, 1, 1), hs_t[i0:i1].reshape(c * v, 3, 3), (h, w),
                                      mode="bilinear", padding_mode="zeros", align_corners=True)
            warped = warped.reshape(c, v, 2, h, w)
            lum_w, wts = warped[:, :, 0], warped[:, :, 1]
            nv = wts.sum(dim=1)
            cst = cost.slice_cost_torch(torch, lum_w, wts, nv, box_cost)
            finite = (nv >= 1.5) & torch.isfinite(cst)
            plain = lambda x: guided(torch, x) if guided is not None else box_agg(x[:, None])[:, 0]
            support = plain(finite.to(cst.dtype)).clamp_min(WEIGHT_FLOOR)  # as lfring.depth.aggregation.aggregate
            aggregate = lambda x: plain(torch.where(finite, x, 0.0)) / support
            agg = occlusion_aggregate_torch(torch, aggregate(cst), lum_w, wts, nv, leavable, plain, aggregate)
            if halves_of:
                halves[i0:i1] = halves_least_torch(torch, lum_w, wts, nv, halves_of, plain).cpu().numpy()
            del warped
            agg = torch.where(finite, agg, float("inf"))
            if volume is None:
                run.push_chunk(agg)
            else:
                volume[i0:i1] = agg.cpu().numpy()
            torch.maximum(nviews, nv.amax(dim=0), out=nviews)
    if volume is not None:
        return nviews.cpu().numpy()
    out = (run.best, run.c_prev, run.c_next, run.second(), nviews)
    return (run.best_i.to(torch.int32).cpu().numpy(), *(x.cpu().numpy() for x in out))
