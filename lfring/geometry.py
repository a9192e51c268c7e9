"""Homography helpers shared by the optics model, calibration, refocusing and depth.

Transforms are named by their frames: ``H_ref_from_view`` takes view pixels to reference
pixels (the convention of ``cv2.warpPerspective`` and kornia), composed as
``H_a_from_c = H_a_from_b @ H_b_from_c``.
"""

from __future__ import annotations

import numpy as np

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
    if isinstance(reference, str):
        if reference == "center":
            return reference
        if reference.isdigit():
            reference = int(reference)
        else:
            raise InvalidInputError(f"reference must be 'center' or a view index 0..{num_views - 1}, got {reference!r}")
    if isinstance(reference, bool) or not isinstance(reference, (int, np.integer)) or not 0 <= reference < num_views:
        raise InvalidInputError(f"reference must be 'center' or a view index 0..{num_views - 1}, got {reference!r}")
    return int(reference)


def to_reference(H_r_from_view: np.ndarray, reference) -> np.ndarray:
    """Re-express (V, 3, 3) homographies into another reference frame.

    Parameters
    ----------
    H_r_from_view : ndarray, (V, 3, 3) or (N, V, 3, 3)
        Maps of every view into some common frame r.
    reference : 'center' or int
        A view index j gives ``H_j_from_k = inv(H_r_from_j) @ H_r_from_k``. ``'center'`` gives the
        virtual central view: with ``M = mean_k H_r_from_k`` (each normalised),
        ``H_center_from_k = inv(M) @ H_r_from_k`` (SPEC 4); for pure translations this is the
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


def homography_rms_px(h_a: np.ndarray, h_b: np.ndarray, shape_hw: tuple[int, int], *, step: int = 8) -> float:
    """RMS distance in pixels between where two homographies send the pixels of a view.

    Parameters
    ----------
    h_a, h_b : (3, 3)
    shape_hw : (h, w) of the view; the pixel grid is sampled every ``step`` pixels.
    """
    h, w = shape_hw
    ys, xs = np.mgrid[0:h:step, 0:w:step]
    xy = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float64)
    d = apply_homography(np.asarray(h_a, dtype=np.float64), xy) - apply_homography(np.asarray(h_b, dtype=np.float64), xy)
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))
