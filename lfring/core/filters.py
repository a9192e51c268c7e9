"""Image filters the photo-consistency measures and the checks share: luminance, the
luminance normalised by its local mean, and a fast box filter."""

from __future__ import annotations

import cv2
import numpy as np

from lfring.core.threads import run_threads
from lfring.core.viewstack import WEIGHT_FLOOR

__all__ = ["BoxTorch", "box_filter", "local_mean_sigma_px", "luminance", "normalised_luminance"]


def luminance(views: np.ndarray, threads: int = 1) -> np.ndarray:
    """(V, h, w) float32 mean of the channels of (V, h, w, C) views; the views shared among
    ``threads`` threads."""
    v, h, w, c = views.shape
    if c == 1:
        return views[..., 0]
    views = np.asarray(views, np.float32)  # transform writes into out only from float32
    mix = np.full((1, c), 1.0 / c, np.float32)
    out = np.empty((v, h, w), np.float32)
    # Into the output: no per-view copies stacked afterwards.
    run_threads([lambda k=k: cv2.transform(views[k], mix, dst=out[k]) for k in range(v)], threads)
    return out


def local_mean_sigma_px(view_shape) -> float:
    """The Gaussian sigma of :func:`normalised_luminance`'s local mean for views of ``view_shape``
    (h, w): a fortieth of the shorter side, at least 8 px (wide enough to hold no texture)."""
    return max(8.0, min(view_shape) / 40.0)


def normalised_luminance(views: np.ndarray, masks: np.ndarray, sigma: float | None = None) -> np.ndarray:
    """Luminance of every view divided by its local mean (Gaussian of ``sigma`` px, masked; by
    default :func:`local_mean_sigma_px`): removes the views' different vignetting and exposure,
    which would otherwise bias photo-consistency.

    The local mean varies slowly (sigma of tens of pixels), so it is computed on the image
    shrunk by up to sigma / 4 and enlarged back bilinearly: a small fraction of the time of the
    full-size blur, and the same to a fraction of a percent."""
    if sigma is None:
        sigma = local_mean_sigma_px(views.shape[1:3])
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


def _border_index(n: int, pad: int, delta: int) -> np.ndarray:
    """Source index of every padded position, as cv2.borderInterpolate: ``delta`` 1 for
    BORDER_REFLECT_101 (cv2.boxFilter's default), 0 for BORDER_REFLECT (the ximgproc guided filter)."""
    idx = np.arange(-pad, n + pad)
    if n == 1:
        return np.zeros_like(idx)
    out = idx.copy()
    for _ in range(4 * (pad // max(n, 1) + 1)):
        lo, hi = out < 0, out >= n
        if not (lo.any() or hi.any()):
            break
        out = np.where(lo, -out - 1 + delta, np.where(hi, 2 * n - 1 - out - delta, out))
    return out


class BoxTorch:
    """The torch twin of :func:`box_filter`: a normalised k x k box filter of (B, C, h, w) tensors
    with OpenCV's border handling (``delta`` 1: BORDER_REFLECT_101, 0: BORDER_REFLECT)."""

    def __init__(self, torch, shape_hw, k: int, delta: int, device):
        self.torch = torch
        self.k = k
        self.pad = k // 2
        self.delta = delta
        # Windows wider than the image reflect more than once: gather by cv2.borderInterpolate's indices.
        self.general = self.pad >= min(shape_hw)
        if self.general:
            self.rows = torch.from_numpy(_border_index(shape_hw[0], self.pad, delta)).to(device)
            self.cols = torch.from_numpy(_border_index(shape_hw[1], self.pad, delta)).to(device)

    def _padded(self, x):
        p = self.pad
        if self.general:
            return x.index_select(-2, self.rows).index_select(-1, self.cols)
        if self.delta == 1:
            return self.torch.nn.functional.pad(x, (p, p, p, p), mode="reflect")
        cat = self.torch.cat
        x = cat([x[..., :p, :].flip(-2), x, x[..., -p:, :].flip(-2)], dim=-2)
        return cat([x[..., :p].flip(-1), x, x[..., -p:].flip(-1)], dim=-1)

    def __call__(self, x):
        if self.k == 1:
            return x
        x = self._padded(x)
        # The vertical pass as k shifted adds: avg_pool2d over columns is several times slower on the CPU.
        h = x.shape[-2] - self.k + 1
        y = x[..., :h, :].clone()
        for i in range(1, self.k):
            y += x[..., i:i + h, :]
        return self.torch.nn.functional.avg_pool2d(y, (1, self.k), stride=1).mul_(1.0 / self.k)
