"""Defocus blur of a rendered layer: anti-aliased pillbox kernels, and the blur that varies with
depth across slanted and curved surfaces."""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

__all__ = ["disc_kernel", "blur", "convolve", "defocus_layer"]


def disc_kernel(diameter_px: float) -> np.ndarray | None:
    """Normalised pillbox of the given diameter, anti-aliased by 8 x 8 supersampling; None
    below 1 px (a blur smaller than a pixel is left to the pixel itself)."""
    if not diameter_px >= 1.0:
        return None
    r = diameter_px / 2.0
    half = int(np.ceil(r - 0.5))
    n = 2 * half + 1
    sub = (np.arange(n * 8) + 0.5) / 8.0 - n / 2.0
    inside = (sub[None, :] ** 2 + sub[:, None] ** 2) <= r * r
    k = inside.reshape(n, 8, n, 8).mean(axis=(1, 3)).astype(np.float32)
    return k / k.sum()


def blur(layer: np.ndarray, diameter_px: float) -> np.ndarray:
    """``layer`` blurred by the disc of ``diameter_px`` (:func:`disc_kernel`), zero outside it."""
    return convolve(layer, disc_kernel(diameter_px))


def convolve(layer: np.ndarray, k: np.ndarray | None) -> np.ndarray:
    """``layer`` convolved with the symmetric kernel ``k`` (zero outside the layer); ``layer``
    itself when ``k`` is None."""
    if k is None:
        return layer
    # filter2D correlates; the disc is symmetric, so this is the convolution. Zero outside.
    return cv2.filter2D(layer, -1, k, borderType=cv2.BORDER_CONSTANT)


def defocus_layer(rgba: np.ndarray, depth: np.ndarray, blur_px: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """A layer's premultiplied ``rgba`` (h, w, 4) blurred by the defocus disc of its ``depth``
    (h, w; inf where the layer does not cover), ``blur_px`` giving the disc diameter in pixels
    at a depth."""
    finite = np.isfinite(depth)
    if not finite.any():
        return rgba
    zs = depth[finite]
    zlo, zhi = zs.min(), zs.max()
    if zlo == zhi:  # one depth (a fronto-parallel plane): one disc, no per-pixel blur map
        return blur(rgba, float(blur_px(np.float64(zlo))))
    d = blur_px(np.where(finite, depth, np.nan).astype(np.float64))
    lo, hi = float(np.nanmin(d)), float(np.nanmax(d))
    if hi - lo < 0.5:
        return blur(rgba, 0.5 * (lo + hi))
    # Depth-varying blur: split the surface into bins of 0.5 px of blur diameter, blur each
    # with its own disc and add them (the bins tile the surface, so the sum is exact where
    # the blur is constant and smooth where it changes).
    edges = np.arange(lo, hi + 0.5, 0.5)
    idx = np.clip(np.digitize(np.nan_to_num(d, nan=lo), edges) - 1, 0, len(edges) - 1)
    # Pixels at the coverage fringe (no depth) follow their nearest bin: the lowest.
    rgba = np.ascontiguousarray(rgba)
    bits = rgba.view(np.uint64)  # two channels per word: nonzero where any bit is set
    nonzero = (bits[..., 0] | bits[..., 1]) != 0
    # Range of bins met on each row and column (pixels that are zero contribute nothing).
    n = len(edges)
    low, high = np.where(nonzero, idx, n), np.where(nonzero, idx, -1)
    row_lo, row_hi = low.min(axis=1), high.max(axis=1)
    col_lo, col_hi = low.min(axis=0), high.max(axis=0)
    out = np.zeros_like(rgba)
    h, w = idx.shape
    for i in range(n):
        rows = np.flatnonzero((row_lo <= i) & (i <= row_hi))
        cols = np.flatnonzero((col_lo <= i) & (i <= col_hi))
        if rows.size == 0 or cols.size == 0:
            continue
        k = disc_kernel(edges[i] + 0.25)
        half = 0 if k is None else k.shape[0] // 2
        # The bin's blur is zero farther than the disc radius from its pixels: convolve
        # only a box around them grown by that radius (same result, far fewer pixels).
        r0, r1 = max(0, rows[0] - half), min(h, rows[-1] + 1 + half)
        c0, c1 = max(0, cols[0] - half), min(w, cols[-1] + 1 + half)
        mask = (idx[r0:r1, c0:c1] == i).view(np.uint8)
        part = cv2.copyTo(rgba[r0:r1, c0:c1], mask)  # the bin's pixels, zero elsewhere
        out[r0:r1, c0:c1] += convolve(part, k)
    return out
