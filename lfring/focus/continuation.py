"""Continuing a depth map where it was not measured: along the surface of the nearest measured
pixel (:func:`plane_continued`), as depth-aware refocusing does at the frame's edges and the
views' disc rims (:mod:`lfring.focus.depth_aware`, step 1)."""

from __future__ import annotations

import math

import cv2
import numpy as np

from lfring.calibration.overlap import INFINITE_DEPTH_M

__all__ = ["PLANE_FIT_PX", "PLANE_PX", "PLANE_REACH", "plane_continued"]

# The depth is continued along the surface of the nearest measured pixel: the plane fitted to the
# measured depths in a Gaussian window of PLANE_PX (standard deviation, px) around it, where it
# fits them to PLANE_FIT_PX of view motion (rms; none of its slope is kept from twice that), for at
# most PLANE_REACH windows from that pixel (the continued depth is constant beyond).
PLANE_PX = 32.0
PLANE_FIT_PX = 0.25
PLANE_REACH = 2.0


def plane_continued(x: np.ndarray, measured: np.ndarray, labels: np.ndarray, radius_px: float):
    """Every pixel's plane of inverse depth ``(a, gu, gv)``, each (h, w) float32, the plane
    ``a + gu u + gv v`` in the frame's pixel coordinates centred on the frame (``u`` the column
    less half the width, ``v`` the row less half the height): where ``measured``, the constant
    ``x``; elsewhere the surface of the nearest measured pixel (``labels``, of
    ``cv2.distanceTransformWithLabels`` over the pixels not measured): the plane fitted to the
    measured depths around it (weighted least squares in a Gaussian window of :data:`PLANE_PX`)
    through that pixel, where it fits them to :data:`PLANE_FIT_PX` of view motion (rms; the
    slope fading out by twice that, at depth edges and on curved surfaces), else that pixel's
    own depth; beyond :data:`PLANE_REACH` windows from it, its slope lessened so that the pixel
    lies at what that reach gives.

    A slant seen by fewer views at the frame's edge continues as a slant rather than as the
    depth of its last measured pixel, and a window that wide averages out the estimate's own
    error where the views drop out."""
    h, w = x.shape
    f = max(int(PLANE_PX // 2), 1)
    hb, wb = -(-h // f), -(-w // f)
    # The measured depths (0 elsewhere) and their weight, padded with unmeasured pixels to whole
    # blocks of f x f; coordinates centred on the frame keep the moments' sums precise.
    wt = np.zeros((hb * f, wb * f), np.float64)
    wt[:h, :w] = measured
    xm = np.zeros_like(wt)
    xm[:h, :w] = np.where(measured, x, 0.0)
    u = np.arange(wb * f, dtype=np.float64) - 0.5 * w
    v = np.arange(hb * f, dtype=np.float64) - 0.5 * h
    # Every block's sums of w, w u, w v, w u^2, w u v, w v^2, x, x u, x v, x^2 (x = 0 where w is):
    # the rows' powers of v applied to each block's rows, then the columns' powers of u (matrix
    # products over the blocks, not ten full-size products).
    pv = np.stack([np.ones_like(v), v, v * v]).reshape(3, hb, f).transpose(1, 0, 2)  # (hb, 3, f)
    pu = np.stack([np.ones_like(u), u, u * u]).reshape(3, wb, f).transpose(1, 2, 0)  # (wb, f, 3)

    def block_sums(img, powers_v):
        rows = np.matmul(pv[:, :powers_v], img.reshape(hb, f, wb * f))  # (hb, powers_v, wb f)
        return np.matmul(rows.reshape(hb, powers_v, wb, f)[:, :, :, None, :], pu[None, None])[..., 0, :]  # (hb, pv, wb, 3)

    bw = block_sums(wt, 3)
    bx = block_sums(xm, 2)
    bxx = block_sums(xm * xm, 1)
    sigma = math.sqrt(max(PLANE_PX * PLANE_PX - f * f / 3.0, 0.25)) / f
    blocks = (bw[:, 0, :, 0], bw[:, 0, :, 1], bw[:, 1, :, 0], bx[:, 0, :, 0], bw[:, 0, :, 2], bw[:, 1, :, 1],
              bw[:, 2, :, 0], bx[:, 0, :, 1], bx[:, 1, :, 0], bxx[:, 0, :, 0])
    # Gaussian-weighted sums over the blocks: smooth, and cheap at this width.
    s0, su, sv, sx, suu, suv, svv, sxu, sxv, sxx = (cv2.GaussianBlur(np.ascontiguousarray(a), (0, 0), sigma)
                                                   for a in blocks)
    some = s0 > 1e-6
    inv = np.divide(1.0, s0, out=np.zeros_like(s0), where=some)
    mu_u, mu_v, mu_x = su * inv, sv * inv, sx * inv
    cuu = suu * inv - mu_u * mu_u
    cuv = suv * inv - mu_u * mu_v
    cvv = svv * inv - mu_v * mu_v
    cxu = sxu * inv - mu_x * mu_u
    cxv = sxv * inv - mu_x * mu_v
    cxx = sxx * inv - mu_x * mu_x
    det = cuu * cvv - cuv * cuv
    solvable = some & (det > (0.25 * PLANE_PX * PLANE_PX) ** 2)  # measured pixels spread both ways
    det = np.where(solvable, det, 1.0)
    gu = np.where(solvable, (cxu * cvv - cxv * cuv) / det, 0.0)
    gv = np.where(solvable, (cxv * cuu - cxu * cuv) / det, 0.0)
    misfit_px = radius_px * np.sqrt(np.maximum(cxx - gu * cxu - gv * cxv, 0.0))
    fits = np.clip(2.0 - misfit_px / PLANE_FIT_PX, 0.0, 1.0) * solvable
    gu, gv = gu * fits, gv * fits
    intercept = mu_x - gu * mu_u - gv * mu_v  # each block's plane at u = v = 0
    # Back to full resolution, each block's plane at its centre and between them interpolated (a
    # padded frame's blocks are whole); beyond the outermost centres the outermost plane holds.
    # (The plane's value itself, interpolated, would be held constant there instead.)
    full = [cv2.resize(a.astype(np.float32), (wb * f, hb * f), interpolation=cv2.INTER_LINEAR)[:h, :w].ravel()
            for a in (intercept, gu, gv, fits)]
    # Only the continued pixels are computed; each from its nearest measured pixel (flat index n).
    a_out = x.astype(np.float32, copy=True)
    gu_out = np.zeros((h, w), np.float32)
    gv_out = np.zeros((h, w), np.float32)
    at = np.flatnonzero(~measured)
    n = np.flatnonzero(measured)[labels.ravel()[at] - 1]
    xn = x.ravel()[n]
    un, vn = (n % w - np.float32(0.5 * w)).astype(np.float32), (n // w - np.float32(0.5 * h)).astype(np.float32)
    plane_n = full[0][n] + full[1][n] * un + full[2][n] * vn
    base = xn + full[3][n] * (plane_n - xn)  # the plane where it fits there, else the pixel's own depth
    dy = (at // w - n // w).astype(np.float32)
    dx = (at % w - n % w).astype(np.float32)
    scale = np.minimum(np.float32(1.0), np.float32(PLANE_REACH * PLANE_PX) / np.maximum(np.hypot(dx, dy), np.float32(1e-6)))
    su, sv = scale * full[1][n], scale * full[2][n]
    value = np.maximum(base + su * dx + sv * dy, np.float32(1.0 / INFINITE_DEPTH_M))  # beyond infinity is infinity
    a_out.ravel()[at] = value - su * (at % w - np.float32(0.5 * w)) - sv * (at // w - np.float32(0.5 * h))
    gu_out.ravel()[at] = su
    gv_out.ravel()[at] = sv
    return a_out, gu_out, gv_out
