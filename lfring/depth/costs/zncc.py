"""The 'zncc' cost: one minus the mean zero-normalised cross-correlation of every view with the
views' mean over a window, on luminances divided by their wide local mean."""

from __future__ import annotations

import numpy as np

from lfring.core.filters import box_filter
from lfring.core.viewstack import WEIGHT_FLOOR
from lfring.depth.costs.base import DepthCost, wide_sources, wide_terms_torch

__all__ = ["ZNCC", "zncc_cost", "zncc_slice_cost_torch"]


def zncc_cost(lum_w: np.ndarray, wts: np.ndarray, nview: np.ndarray, window_px: int) -> np.ndarray:
    """One minus the mean, over the views valid at a pixel, of the zero-normalised
    cross-correlation over the window of each view with the views' weighted mean.

    The same numbers as the textbook expression (box means, variances clamped at 1e-8), computed
    with in-place float32 operations: a slice costs a few dozen passes over the image."""
    k = window_px
    mean = lum_w.sum(axis=0)
    np.divide(mean, np.maximum(nview, WEIGHT_FLOOR), out=mean)
    mu_m = box_filter(mean, k)
    t = np.multiply(mean, mean)
    var_m = box_filter(t, k)
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
        np.maximum(wts[j], WEIGHT_FLOOR, out=vj)
        np.divide(lum_w[j], vj, out=vj)
        vj *= valid
        box_filter(vj, k, dst=mu_j)
        np.multiply(vj, vj, out=t)
        box_filter(t, k, dst=s2)
        np.multiply(vj, mean, out=t)
        box_filter(t, k, dst=cov)
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


def zncc_slice_cost_torch(torch, lum_w, wts, nview, box):
    """The torch twin of :func:`zncc_cost` on chunks (C, V, h, w) -> (C, h, w)."""
    vals, valid, nvalid, mean = wide_terms_torch(lum_w, wts, nview)
    cc, v, h, w = vals.shape
    stats_m = box(torch.stack([mean, mean * mean], dim=1))  # (C, 2, h, w)
    mu_m = stats_m[:, 0]
    var_m = (stats_m[:, 1] - mu_m**2).clamp_min(1e-8)
    vj = vals * valid
    stats = box(torch.stack([vj, vj * vj, vj * mean[:, None]], dim=2).reshape(cc, v * 3, h, w)).reshape(cc, v, 3, h, w)
    mu_j = stats[:, :, 0]
    var_j = (stats[:, :, 1] - mu_j**2).clamp_min(1e-8)
    cov = stats[:, :, 2] - mu_j * mu_m[:, None]
    acc = (cov / torch.sqrt(var_j * var_m[:, None]) * valid).sum(dim=1)
    return 1.0 - acc / nvalid.clamp_min(1)


ZNCC = DepthCost(
    name="zncc",
    summary="one minus the views' zero-normalised cross-correlation with their mean over window_px",
    sources=wide_sources,
    slice_cost=zncc_cost,
    slice_cost_torch=zncc_slice_cost_torch,
)
