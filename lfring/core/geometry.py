"""Homography helpers shared by the optics model, calibration, refocusing and depth.

Transforms are named by their frames: ``H_ref_from_view`` takes view pixels to reference
pixels (the convention of ``cv2.warpPerspective`` and kornia), composed as
``H_a_from_c = H_a_from_b @ H_b_from_c``.
"""

from __future__ import annotations

import math

import numpy as np

from lfring.core.validate import check_view_index
from lfring.errors import InvalidInputError

__all__ = ["normalize_homographies", "to_reference", "check_reference", "apply_homography", "homography_rms_px"]


def normalize_homographies(h: np.ndarray) -> np.ndarray:
    """Scale each (..., 3, 3) homography so that H[2, 2] = 1."""
    h = np.asarray(h, dtype=np.float64)
    if h.shape[-2:] != (3, 3):
        raise InvalidInputError(f"homographies must have shape (..., 3, 3), got {h.shape}")
    return h / h[..., 2:3, 2:3]


def check_reference(reference, num_views: int):
    """Validate a reference: 'center' or a view index in [0, num_views)."""
    if isinstance(reference, str) and reference.isdigit():  # a view index typed on a command line
        reference = int(reference)
    return check_view_index(reference, "reference", num_views, allow_center=True)


def to_reference(H_r_from_view: np.ndarray, reference) -> np.ndarray:
    """Re-express (V, 3, 3) homographies into another reference frame.

    Parameters
    ----------
    H_r_from_view : ndarray, (V, 3, 3) or (N, V, 3, 3)
        Maps of every view into some common frame r.
    reference : 'center' or int
        A view index j gives ``H_j_from_k = inv(H_r_from_j) @ H_r_from_k``. ``'center'`` gives the
        virtual central view: with ``M = mean_k H_r_from_k`` (each normalised),
        ``H_center_from_k = inv(M) @ H_r_from_k`` (the source paper's central view); for pure translations this is the
        translation minus its mean.

    Returns
    -------
    ndarray, same shape, each normalised so that H[2, 2] = 1.
    """
    h = normalize_homographies(H_r_from_view)
    ref = check_reference(reference, h.shape[-3])
    if ref == "center":
        m = h.mean(axis=-3, keepdims=True)
    else:
        m = h[..., ref : ref + 1, :, :]
    return normalize_homographies(np.linalg.inv(m) @ h)


def apply_homography(h: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Map points (..., 2) by a (3, 3) homography."""
    xy = np.asarray(xy, dtype=np.float64)
    p = xy @ h[:2, :2].T + h[:2, 2]
    w = xy @ h[2, :2] + h[2, 2]
    return p / w[..., None]


def homography_rms_px(H_a, H_b, shape_hw: tuple[int, int], mask=None, *, step: int = 1) -> np.ndarray | float:
    """RMS distance in pixels between where two homographies send the pixels of a view.

    Parameters
    ----------
    H_a, H_b : ndarray, (..., 3, 3)
        Broadcast against each other, e.g. (V, 3, 3) estimates against (V, 3, 3) truths.
    shape_hw : (h, w)
        The view's size; every pixel centre (x, y) = (column, row) is used.
    mask : ndarray of bool, (h, w) or (..., h, w), optional
        Only these pixels (e.g. the valid disc of each view).
    step : int
        Use every ``step``-th row and column (1: every pixel centre).

    Returns
    -------
    float for single homographies, else ndarray of the broadcast leading shape.

    Notes
    -----
    ``sqrt(mean_p |pi(H_a p) - pi(H_b p)|^2)`` with pi the perspective division.
    """
    ha = np.asarray(H_a, dtype=np.float64)
    hb = np.asarray(H_b, dtype=np.float64)
    if ha.shape[-2:] != (3, 3) or hb.shape[-2:] != (3, 3):
        raise InvalidInputError(f"homographies must have shape (..., 3, 3), got {ha.shape} and {hb.shape}")
    try:
        ha, hb = np.broadcast_arrays(ha, hb)
    except ValueError:
        raise InvalidInputError(f"cannot compare homographies of shapes {ha.shape} and {hb.shape}") from None
    h, w = (int(v) for v in shape_hw)
    if h < 1 or w < 1:
        raise InvalidInputError(f"shape_hw must be a positive (h, w), got {shape_hw!r}")
    lead = ha.shape[:-2]
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape[-2:] != (h, w):
            raise InvalidInputError(f"mask must have shape (..., {h}, {w}), got {mask.shape}")
        mask = np.broadcast_to(mask, lead + (h, w)) if mask.ndim > 2 else mask
    ys, xs = np.mgrid[0:h:step, 0:w:step]
    if mask is not None:
        mask = mask[..., ::step, ::step]
    pts = np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)]).astype(np.float64)  # (3, N)
    flat_a, flat_b = ha.reshape(-1, 3, 3), hb.reshape(-1, 3, 3)
    out = np.empty(len(flat_a))
    for i in range(len(flat_a)):
        pa, pb = flat_a[i] @ pts, flat_b[i] @ pts
        d2 = ((pa[:2] / pa[2] - pb[:2] / pb[2]) ** 2).sum(axis=0)
        if mask is not None:
            m = (mask if mask.ndim == 2 else mask.reshape(-1, h, w)[i]).ravel()
            if not m.any():
                raise InvalidInputError("mask selects no pixel")
            d2 = d2[m]
        out[i] = math.sqrt(float(d2.mean()))
    return float(out[0]) if lead == () else out.reshape(lead)

