"""Image filters the photo-consistency measures and the checks share: luminance, the
luminance normalised by its local mean, and a fast box filter."""

from __future__ import annotations

import cv2
import numpy as np

from lfring.core.viewstack import WEIGHT_FLOOR

__all__ = ["box_filter", "luminance", "normalised_luminance"]


def luminance(views: np.ndarray) -> np.ndarray:
    """(V, h, w) float32 mean of the channels of (V, h, w, C) views."""
    v, h, w, c = views.shape
    if c == 1:
        return views[..., 0]
    mix = np.full((1, c), 1.0 / c, np.float32)
    return np.stack([cv2.transform(views[k], mix).reshape(h, w) for k in range(v)])


def normalised_luminance(views: np.ndarray, masks: np.ndarray, sigma: float) -> np.ndarray:
    """Luminance of every view divided by its local mean (Gaussian, masked): removes the views'
    different vignetting and exposure, which would otherwise bias photo-consistency.

    The local mean varies slowly (sigma of tens of pixels), so it is computed on the image
    shrunk by up to sigma / 4 and enlarged back bilinearly: a few percent of the time of the
    full-size blur, and the same to a fraction of a percent."""
    v, h, w = views.shape[:3]
    f = int(max(1, min(sigma // 4, min(h, w) // 16)))
    small = (max(1, w // f), max(1, h // f))
    out = np.empty((v, h, w), np.float32)
    for k, lum in enumerate(luminance(views)):
        num = cv2.GaussianBlur(cv2.resize(lum * masks[k], small, interpolation=cv2.INTER_AREA), (0, 0), sigma / f)
        den = cv2.GaussianBlur(cv2.resize(masks[k], small, interpolation=cv2.INTER_AREA), (0, 0), sigma / f)
        local = np.where(den > WEIGHT_FLOOR, num / np.maximum(den, 1e-6), 0.0).astype(np.float32)
        local = cv2.resize(local, (w, h), interpolation=cv2.INTER_LINEAR)
        big = cv2.resize(den, (w, h), interpolation=cv2.INTER_LINEAR)
        out[k] = np.where(big > WEIGHT_FLOOR, lum / np.maximum(local, 1e-4), 0.0)
    return out


_BOX_KERNELS: dict = {}


def box_filter(src: np.ndarray, k: int, dst=None) -> np.ndarray:
    """Normalised k x k box filter, as cv2.boxFilter (BORDER_REFLECT_101) but as two separable
    passes, which OpenCV runs several times faster on float32 images."""
    kern = _BOX_KERNELS.get(k)
    if kern is None:
        kern = _BOX_KERNELS.setdefault(k, np.full(k, 1.0 / k, np.float32))
    return cv2.sepFilter2D(src, cv2.CV_32F, kern, kern, dst=dst, borderType=cv2.BORDER_REFLECT_101)
