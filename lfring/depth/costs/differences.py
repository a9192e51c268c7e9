"""The direct comparisons of luminances divided by their wide local mean: the absolute ('sad')
or squared ('ssd') deviation of every valid view from the views' mean, and 'sad-occlusion', the
absolute deviation without the view that deviates most at each pixel."""

from __future__ import annotations

import numpy as np

from lfring.depth.costs.base import DepthCost, wide_sources, wide_terms, wide_terms_torch

__all__ = ["SAD", "SAD_OCCLUSION", "SSD", "sad_cost", "sad_cost_torch", "sad_occlusion_cost", "sad_occlusion_cost_torch",
           "ssd_cost", "ssd_cost_torch"]


def sad_cost(lum_w: np.ndarray, wts: np.ndarray, nview: np.ndarray, window_px: int) -> np.ndarray:
    """Mean absolute deviation of the valid views from the views' mean, per pixel, (h, w) float32."""
    vals, valid, mean = wide_terms(lum_w, wts, nview)
    dev = np.abs(vals - mean) * valid
    return (dev.sum(axis=0) / np.maximum(valid.sum(axis=0), 1)).astype(np.float32)


def sad_occlusion_cost(lum_w: np.ndarray, wts: np.ndarray, nview: np.ndarray, window_px: int) -> np.ndarray:
    """:func:`sad_cost` without the view that deviates most, where more than two views are valid."""
    vals, valid, mean = wide_terms(lum_w, wts, nview)
    dev = np.abs(vals - mean) * valid
    worst = dev.max(axis=0)
    n = valid.sum(axis=0)
    return ((dev.sum(axis=0) - np.where(n > 2, worst, 0.0)) / np.maximum(n - (n > 2), 1)).astype(np.float32)


def ssd_cost(lum_w: np.ndarray, wts: np.ndarray, nview: np.ndarray, window_px: int) -> np.ndarray:
    """Mean squared deviation of the valid views from the views' mean, per pixel, (h, w) float32."""
    vals, valid, mean = wide_terms(lum_w, wts, nview)
    return (((vals - mean) ** 2 * valid).sum(axis=0) / np.maximum(valid.sum(axis=0), 1)).astype(np.float32)


def sad_cost_torch(torch, lum_w, wts, nview, box):
    """The torch twin of :func:`sad_cost` on chunks (C, V, h, w) -> (C, h, w)."""
    vals, valid, nvalid, mean = wide_terms_torch(lum_w, wts, nview)
    return ((vals - mean[:, None]).abs() * valid).sum(dim=1) / nvalid.clamp_min(1)


def sad_occlusion_cost_torch(torch, lum_w, wts, nview, box):
    """The torch twin of :func:`sad_occlusion_cost`."""
    vals, valid, nvalid, mean = wide_terms_torch(lum_w, wts, nview)
    dev = (vals - mean[:, None]).abs() * valid
    more = nvalid > 2
    return (dev.sum(dim=1) - torch.where(more, dev.amax(dim=1), 0.0)) / (nvalid - more.to(nvalid.dtype)).clamp_min(1)


def ssd_cost_torch(torch, lum_w, wts, nview, box):
    """The torch twin of :func:`ssd_cost`."""
    vals, valid, nvalid, mean = wide_terms_torch(lum_w, wts, nview)
    return ((vals - mean[:, None]) ** 2 * valid).sum(dim=1) / nvalid.clamp_min(1)


SAD = DepthCost("sad", "mean absolute deviation of the views from their mean", wide_sources, sad_cost, sad_cost_torch)
SSD = DepthCost("ssd", "mean squared deviation of the views from their mean", wide_sources, ssd_cost, ssd_cost_torch)
SAD_OCCLUSION = DepthCost("sad-occlusion", "'sad' without the view that deviates most at each pixel", wide_sources,
                          sad_occlusion_cost, sad_occlusion_cost_torch)
