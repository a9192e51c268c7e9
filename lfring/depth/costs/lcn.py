"""The 'lcn' cost: the variance across the views of their locally normalised luminances.

The 'lcn' cost of a hypothesis at a pixel is the variance across the views of their
locally normalised luminances, ``n = (L - mu) / sqrt(var + LCN_EPS mu^2 + LCN_FLOOR)`` with
``mu`` and ``var`` the masked local mean and variance of the luminance ``L`` over ``window_px``.
The normalisation is done once per view, before the sweep (:func:`lcn_sources`), so a hypothesis
only has to shift the views and sum. With a view's weight ``w`` (its warped mask) and its
warped value premultiplied by it, ``a = w n``, the sums over views are S1 = sum ``a``,
S2 = sum ``w n^2`` = sum ``a^2 / w`` (:func:`weighted_square`) and C = sum ``w``, and the cost is
their weighted variance ``c = (S2 - S1^2 / C) / max(C - 1, 0.5)`` (:func:`lcn_cost`). Dividing
by the local mean makes it blind to the views' different vignetting and exposure.

The local mean and variance are taken over the view's disc unweighted (its mask without the rim's
taper, :data:`LCN_STATS_TAPER`); the taper weighs only what each view adds to the sums. Weighted
by the taper, a window's mean near the rim leans to the side the view sees more of, so on a
sloped luminance each view's normalised image moves by a fraction of a pixel towards its disc's
centre, by an amount that depends on where the pixel lies in that view: where two views see a
pixel, the best depth moved with it (benchmarks/RESULTS.md, "The 'lcn' normalisation over the
whole disc").

S2 weighs each square by ``w``, as S1 and C weigh the values, so that a view that sees a pixel
only in part (the taper at its disc's rim, a frame edge) adds in part to every sum. Summing
``a^2`` instead (``w^2 n^2``) made the variance of views that agree negative wherever one
weighed less than 1, lowest for the hypotheses that put its strongest contrast there: a bias
along every rim (benchmarks/RESULTS.md, "The 'lcn' cost's squares weighted as its values").
"""

from __future__ import annotations

import cv2
import numpy as np

from lfring.core.filters import box_filter, luminance
from lfring.core.threads import STRIP_PIXELS, run_threads
from lfring.core.viewstack import WEIGHT_FLOOR, cached_view_masks
from lfring.depth.costs.base import DepthCost, compiled_kernels
from lfring.depth.plan import sweep_masks

__all__ = ["LCN", "LCN_AGGREGATE_PX", "LCN_EPS", "LCN_FLOOR", "LCN_STATS_TAPER", "lcn_cost", "lcn_cost_torch", "lcn_slice_cost",
           "lcn_slice_cost_torch", "lcn_sources", "weighted_square", "weighted_square_torch", "window_weights"]

# The default aggregation window of the 'lcn' cost (the other costs aggregate over window_px).
LCN_AGGREGATE_PX = 15
# Relative contrast floor of the normalisation (its variance term is LCN_EPS mu^2): texture
# fainter than 10 % of the local mean is compared unnormalised; LCN_FLOOR keeps black regions finite.
LCN_EPS = 1e-2
LCN_FLOOR = 1e-6
# The rim taper of the masks over which each view's local mean and variance are taken: none (the
# disc, its edge antialiased), whatever taper weighs the views in the cost.
LCN_STATS_TAPER = 0.0


def lcn_sources(views: np.ndarray, calibration, window_px: int, *, threads: int = 1) -> np.ndarray:
    """(V, h, w) float32 locally normalised luminance of every view (its statistics over the view's
    disc, :data:`LCN_STATS_TAPER`), to be multiplied by the sweep's mask before warping; views are
    shared among ``threads`` threads."""
    masks = sweep_masks(calibration, views.shape[1:3], LCN_STATS_TAPER)
    lum = luminance(views, threads)
    out = np.empty(lum.shape, np.float32)

    weights = window_weights(calibration, views.shape[1:3], window_px)
    v, h, w = lum.shape
    pad = window_px // 2
    rows = max(8, STRIP_PIXELS // (2 * max(w, 1)))  # row strips of every view, in the cache
    normalise = compiled_kernels().lcn_normalise
    eps, floor = np.float32(LCN_EPS), np.float32(LCN_FLOOR)

    def one(k: int, r0: int, r1: int) -> None:
        q0, q1 = max(0, r0 - pad), min(h, r1 + pad)
        inner = slice(r0 - q0, r1 - q0)
        m, x = masks[k][q0:q1], lum[k][q0:q1]
        a = cv2.multiply(x, m)
        mu = box_filter(a, window_px)[inner]
        cv2.multiply(a, x, dst=a)
        s2 = box_filter(a, window_px)[inner]
        # The means over the seen share of the window, and the normalisation (see the kernel).
        normalise(x[inner], mu, s2, weights[k][r0:r1], eps, floor, out[k][r0:r1])

    run_threads([lambda k=k, r=r: one(k, r, min(h, r + rows)) for k in range(v) for r in range(0, h, rows)], threads)
    return out


def window_weights(calibration, view_shape, window_px: int) -> np.ndarray:
    """(V, h, w) float32 ``1 / max(box(mask), WEIGHT_FLOOR)`` of every view's mask for the
    normalisation's statistics (:data:`LCN_STATS_TAPER`) over ``window_px``: made once per
    calibration, view shape and window."""
    return cached_view_masks(
        calibration, view_shape, ("window_weights", int(window_px)),
        taper=LCN_STATS_TAPER, make=lambda masks: np.stack([1.0 / np.maximum(box_filter(m, window_px), WEIGHT_FLOOR) for m in masks]).astype(np.float32),
    )


def weighted_square(a: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``w n^2`` of a view's warped value premultiplied by its weight (``a = w n``) and its weight
    ``w``: its term of S2 (see the module's docstring); 0 where ``w`` is 0.

    Examples
    --------
    >>> import numpy as np
    >>> weighted_square(np.array([0.5, 1.0, 0.0], np.float32), np.array([0.5, 1.0, 0.0], np.float32)).tolist()
    [0.5, 1.0, 0.0]
    """
    return np.square(a) / np.maximum(w, np.float32(WEIGHT_FLOOR))


def weighted_square_torch(a, w):
    """The torch twin of :func:`weighted_square`."""
    return a * a / w.clamp_min(WEIGHT_FLOOR)


def lcn_cost(s1: np.ndarray, s2: np.ndarray, count: np.ndarray) -> np.ndarray:
    """The 'lcn' cost from the sums over views (S1, S2, C; see the module's docstring)."""
    c = s2 - s1 * s1 / np.maximum(count, WEIGHT_FLOOR)
    c /= np.maximum(count - 1.0, 0.5)
    return c.astype(np.float32, copy=False)


def lcn_cost_torch(s1, s2, count):
    """The torch twin of :func:`lcn_cost`."""
    return (s2 - s1 * s1 / count.clamp_min(WEIGHT_FLOOR)) / (count - 1.0).clamp_min(0.5)


def lcn_slice_cost(lum_w: np.ndarray, wts: np.ndarray, nview: np.ndarray, window_px: int) -> np.ndarray:
    """The 'lcn' cost of one hypothesis from the warped :func:`lcn_sources` premultiplied by their
    warped masks (V, h, w) (see :class:`lfring.depth.costs.base.DepthCost`)."""
    return lcn_cost(lum_w.sum(axis=0), weighted_square(lum_w, wts).sum(axis=0), nview)


def lcn_slice_cost_torch(torch, lum_w, wts, nview, box):
    """The torch twin of :func:`lcn_slice_cost` on chunks (C, V, h, w) -> (C, h, w)."""
    return lcn_cost_torch(lum_w.sum(dim=1), weighted_square_torch(lum_w, wts).sum(dim=1), nview)


def _sources(views, calibration, plan, window_px: int, threads: int) -> np.ndarray:
    return lcn_sources(views, calibration, window_px, threads=threads)


LCN = DepthCost(
    name="lcn",
    summary="variance across views of the locally normalised luminances (fastest; blind to vignetting)",
    sources=_sources,
    slice_cost=lcn_slice_cost,
    slice_cost_torch=lcn_slice_cost_torch,
    lcn=True,
)
