"""Edge-aware refinement and hole filling of a disparity-space map, guided by the reference image.

Two outputs, so that nothing guessed passes for measured:

* ``refined``: a weighted median (``cv2.ximgproc.weightedMedianFilter``, Zhang et al. 2014) of the
  confident pixels, weighted by their similarity to the centre in the guide image. It removes
  isolated outliers and snaps depth edges to image edges; pixels that were not confident stay NaN.
* ``filled``: ``refined`` where known, elsewhere a confidence-weighted edge-aware interpolation by
  the fast global smoother (``cv2.ximgproc.createFastGlobalSmootherFilter``, Min et al. 2014) used
  as a normalised convolution: ``FGS(c * d) / FGS(c)``. Holes take the values of the surface
  they share an image region with.

Both filters come from opencv-contrib's ximgproc; their guides are 8-bit, so the float guide
(values in [0, 1]) is quantised to 256 levels.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from lfring.errors import InvalidInputError

__all__ = ["MIN_CONFIDENCE", "refine_index"]

# Pixels below this confidence (1 - best / second best of the aggregated cost) are not trusted.
MIN_CONFIDENCE = 0.05
# Weighted median: radius (px) and guide range sigma (8-bit guide levels).
MEDIAN_RADIUS_PX = 3
MEDIAN_SIGMA = 25.5
# Fast global smoother for the holes: regularisation and guide range sigma (8-bit levels).
FGS_LAMBDA = 200.0
FGS_SIGMA = 8.0
# Normalised convolution: below this smoothed weight a pixel has no support at all.
_FILL_WEIGHT_FLOOR = 1e-6


def _guide8(guide, shape) -> np.ndarray:
    g = np.asarray(guide)
    if g.ndim == 3 and g.shape[2] == 1:
        g = g[..., 0]
    if g.shape[:2] != tuple(shape) or g.ndim not in (2, 3) or (g.ndim == 3 and g.shape[2] != 3):
        raise InvalidInputError(f"guide must be an (h, w) or (h, w, 3) image of the map's (h, w) = {tuple(shape)}, "
                                f"got shape {np.shape(guide)}")
    if g.dtype == np.uint8:
        return np.ascontiguousarray(g)
    if not np.issubdtype(g.dtype, np.floating) or not np.all(np.isfinite(g)):
        raise InvalidInputError(f"guide must be uint8 or finite floating point in [0, 1], got {g.dtype}")
    return np.ascontiguousarray(np.clip(np.rint(g * 255.0), 0, 255).astype(np.uint8))


def refine_index(index, confidence, guide, *, min_confidence: float = MIN_CONFIDENCE,
                 radius_px: int = MEDIAN_RADIUS_PX, sigma: float = MEDIAN_SIGMA, fill_lambda: float = FGS_LAMBDA,
                 fill_sigma: float = FGS_SIGMA) -> tuple[np.ndarray, np.ndarray]:
    """Edge-aware weighted median of the confident pixels, and a hole-filled copy.

    Parameters
    ----------
    index : (h, w) float array
        Fractional hypothesis index (or disparity in px); NaN where unknown.
    confidence : (h, w) float array in [0, 1]
        Per-pixel confidence (for example from :func:`lfring.depth.sgm.select`).
    guide : (h, w) or (h, w, 3) array
        Reference image, float in [0, 1] or uint8.
    min_confidence : float
        Pixels with lower confidence (or a NaN index) are holes.
    radius_px : int
        Radius of the weighted median window.
    sigma : float
        Guide range sigma of the weighted median, in 8-bit levels.
    fill_lambda, fill_sigma : float
        Regularisation and guide range sigma (8-bit levels) of the fast global smoother that
        fills the holes.

    Returns
    -------
    refined : (h, w) float32
        Weighted median over the confident pixels of the window, NaN at holes.
    filled : (h, w) float32
        ``refined`` where known; at holes ``FGS(w d) / FGS(w)`` with w = confidence at known
        pixels and 0 at holes; NaN only if no pixel at all is known.

    Notes
    -----
    The weighted median minimises ``sum_q w(p, q) |d - d_q|`` over the known pixels q of the
    window, with ``w = exp(-|I_p - I_q|^2 / (2 sigma^2))`` (``WMF_EXP``).

    Examples
    --------
    >>> import numpy as np
    >>> index = np.full((20, 30), 7.0, np.float32)
    >>> index[10, 15] = 30.0                                   # an outlier
    >>> confidence = np.full((20, 30), 0.5, np.float32)
    >>> confidence[5, 5] = 0.0                                 # a hole
    >>> refined, filled = refine_index(index, confidence, np.zeros((20, 30)))
    >>> float(refined[10, 15]), bool(np.isnan(refined[5, 5])), round(float(filled[5, 5]), 3)
    (7.0, True, 7.0)
    """
    d = np.asarray(index)
    if d.ndim != 2:
        raise InvalidInputError(f"index must be an (h, w) map, got shape {d.shape}")
    if not np.issubdtype(d.dtype, np.floating):
        raise InvalidInputError(f"index must be floating point (NaN where unknown), got {d.dtype}")
    c = np.asarray(confidence, np.float32)
    if c.shape != d.shape:
        raise InvalidInputError(f"confidence must have the index's shape {d.shape}, got {c.shape}")
    g8 = _guide8(guide, d.shape)
    for name, v in (("min_confidence", min_confidence), ("sigma", sigma), ("fill_lambda", fill_lambda),
                    ("fill_sigma", fill_sigma)):
        if not isinstance(v, (int, float, np.floating, np.integer)) or not math.isfinite(float(v)) or v < 0:
            raise InvalidInputError(f"{name} must be a finite number >= 0, got {v!r}")
    if isinstance(radius_px, bool) or not isinstance(radius_px, (int, np.integer)) or radius_px < 1:
        raise InvalidInputError(f"radius_px must be a positive integer, got {radius_px!r}")
    d = d.astype(np.float32)
    known = np.isfinite(d) & np.isfinite(c) & (c >= min_confidence)
    src = np.where(known, d, 0).astype(np.float32)
    refined = cv2.ximgproc.weightedMedianFilter(g8, src, int(radius_px), sigma=float(sigma),
                                                weightType=int(cv2.ximgproc.WMF_EXP), mask=known.astype(np.uint8))
    refined = np.where(known, refined, np.nan).astype(np.float32)
    if not known.any():
        return refined, refined.copy()
    weight = np.where(known, np.maximum(c, _FILL_WEIGHT_FLOOR), 0).astype(np.float32)
    fgs = cv2.ximgproc.createFastGlobalSmootherFilter(g8, float(fill_lambda), float(fill_sigma))
    num = fgs.filter(np.where(known, refined, 0).astype(np.float32) * weight)
    den = fgs.filter(weight)
    with np.errstate(invalid="ignore", divide="ignore"):
        interp = np.where(den > _FILL_WEIGHT_FLOOR, num / den, np.nan)
    filled = np.where(known, refined, interp).astype(np.float32)
    return refined, filled
