"""The 'lcn-occlusion' cost: the 'lcn' cost with one view left out where that is cheaper over
the aggregation window (:func:`occlusion_aggregate`).

Next to a depth edge a view that sees the occluding surface no longer spoils the true depth's
cost.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from lfring.core.viewstack import WEIGHT_FLOOR
from lfring.depth.costs.base import compiled_kernels
from lfring.depth.costs.lcn import LCN, lcn_cost_torch, weighted_square_torch

__all__ = ["LCN_OCCLUSION", "MIN_VIEWS_TO_LEAVE_ONE_OUT", "OCCLUSION_PENALTY", "lcn_leave_one_out", "leavable_views",
           "occlusion_aggregate", "occlusion_aggregate_torch"]

# A view may be left out of a window where on average at least this many views see its pixels
# (with two, neither can be told to be the occluded one). Judged over the window, not per pixel: a
# per-pixel rule switches the candidates on and off as the views' edges move with the hypothesis,
# and measured worse than no leaving out at all on the twin's three-depth scene.
MIN_VIEWS_TO_LEAVE_ONE_OUT = 3
# 'lcn-occlusion': the aggregated cost of the views without one competes with all views' cost
# after this factor. Fewer samples give a noisier variance, and the least of several noisy
# candidates is biased low. On the twin's hard scene 1.0 and 1.15 measured the same, on the
# three-depth scene 1.15 slightly better.
OCCLUSION_PENALTY = 1.15


def lcn_leave_one_out(s1: np.ndarray, s2: np.ndarray, count: np.ndarray, a_k: np.ndarray, w_k: np.ndarray,
                      out: np.ndarray | None = None) -> np.ndarray:
    """The 'lcn' cost of the views without view k (:func:`lcn_cost`), from all views' sums (S1,
    S2, C; :mod:`lfring.depth.costs.lcn`) and view k's warped value ``a_k`` (premultiplied by its
    warped mask) and mask ``w_k``,
    all (h, w) float32; written into ``out`` when given. The views that remain are ``count - w_k``.

    Examples
    --------
    >>> import numpy as np
    >>> x = np.array([0.3, 0.3, 0.3, 2.0], np.float32)[:, None, None] * np.ones((4, 1, 2), np.float32)
    >>> ones = np.ones_like(x)
    >>> cost = lcn_leave_one_out(x.sum(0), (x * x).sum(0), ones.sum(0), x[3], ones[3])
    >>> np.allclose(cost, 0.0, atol=1e-6)        # the three that agree
    True
    """
    out = np.empty(np.shape(s1), np.float32) if out is None else out
    compiled_kernels().leave_one_out(s1, s2, count, a_k, w_k, WEIGHT_FLOOR, out)
    return out


def leavable_views(hs: np.ndarray) -> list[int]:
    """The views 'lcn-occlusion' may leave out: all but the reference view (whose homography is
    the identity at every hypothesis; it sees its own pixel by definition), for the 'center'
    reference every view; none with fewer than :data:`MIN_VIEWS_TO_LEAVE_ONE_OUT` views."""
    hs = np.asarray(hs)
    if hs.shape[1] < MIN_VIEWS_TO_LEAVE_ONE_OUT:
        return []
    return [k for k in range(hs.shape[1]) if not np.all(hs[:, k] == np.eye(3))]


def occlusion_aggregate(agg_all: np.ndarray, count: np.ndarray, leave_outs, aggregate_cost, aggregate_count) -> np.ndarray:
    """The 'lcn-occlusion' cost of one hypothesis, in place in ``agg_all``.

    Next to a depth edge, some views see the occluding surface instead of the reference's pixel,
    and at the rim of a view's disc its few, dark, tapered pixels are noisy: at the true depth
    such a view disagrees with the others and the variance over all views is high. Over a window,
    the cost is therefore the least of all views' aggregated cost and, for every view k that may
    be left out, :data:`OCCLUSION_PENALTY` times the aggregated cost of the views without k
    (:func:`lcn_leave_one_out`), where the window's aggregated count of the views that remain
    reaches :data:`MIN_VIEWS_TO_LEAVE_ONE_OUT` - 1. The choice is made per window, after the
    aggregation, so one noisy pixel does not drop a view.

    Parameters
    ----------
    agg_all : (h, w) float32
        The aggregated 'lcn' cost of all views.
    count : (h, w) float32
        The views that see each pixel (the sum of their warped masks).
    leave_outs : iterable of ((h, w), (h, w)) float32
        Per view that may be left out, its per-pixel :func:`lcn_leave_one_out` cost and warped
        mask ``w_k`` (the cost may share a buffer: each is aggregated before the next is made).
    aggregate_cost, aggregate_count : callable
        ``agg_all``'s spatial aggregation, (h, w) -> (h, w), for the costs (over the same pixels
        as ``agg_all``'s, :func:`aggregate`) and, plain, for the counts.
    """
    agg_count = aggregate_count(count)
    least_rest = MIN_VIEWS_TO_LEAVE_ONE_OUT - 1.5
    # An aggregated mask lies in [0, 1]: only where the count is within 1 of the bound does the
    # left-out view's own share decide (the rims of the views' discs); elsewhere the count alone.
    rim = bool(np.any((agg_count > least_rest) & (agg_count <= least_rest + 1.0)))
    whole = None if rim else np.ones_like(agg_count)  # the most a view's aggregated mask can be
    for c, w_k in leave_outs:
        agg_w = aggregate_count(w_k) if rim else whole
        compiled_kernels().take_least(agg_all, aggregate_cost(c), OCCLUSION_PENALTY, agg_count, agg_w, least_rest)
    return agg_all


def occlusion_aggregate_torch(torch, agg, lum_w, wts, nview, leavable, window, aggregate_cost):
    """The torch twin of :func:`occlusion_aggregate` on chunks: ``agg`` (C, h, w) all views'
    aggregated cost, ``lum_w``, ``wts`` (C, V, h, w) the warped sources and masks, ``nview`` their
    sum, ``leavable`` the views that may be left out, ``window`` the plain aggregation and
    ``aggregate_cost`` the aggregation over the seen pixels. Returns the new ``agg``."""
    if not leavable:
        return agg
    agg_count = window(nview)
    s1, s2 = lum_w.sum(dim=1), weighted_square_torch(lum_w, wts).sum(dim=1)
    for k in leavable:
        a_k = lum_w[:, k]
        allowed = agg_count - window(wts[:, k]) > MIN_VIEWS_TO_LEAVE_ONE_OUT - 1.5
        one = aggregate_cost(lcn_cost_torch(s1 - a_k, s2 - weighted_square_torch(a_k, wts[:, k]), nview - wts[:, k]))
        agg = torch.where(allowed, torch.minimum(agg, OCCLUSION_PENALTY * one), agg)
    return agg


LCN_OCCLUSION = dataclasses.replace(
    LCN, name="lcn-occlusion", leave_one_out=True,
    summary="'lcn', over each window the least of all views' cost and the costs without one view")
