"""Edge-aware refinement and hole filling of a disparity-space map, guided by the reference image.

Two outputs, so that nothing guessed passes for measured:

* ``refined``: a weighted median of the confident pixels over a small window, weighted by their
  similarity to the centre in the guide image (as ``cv2.ximgproc.weightedMedianFilter``, Zhang et
  al. 2014, with its exponential weight; :mod:`lfring.depth.refine_kernels`: sums along the row
  for windows on one surface, a histogram per pixel for the others). It removes isolated outliers and snaps depth edges to image
  edges; pixels that were not confident stay NaN.
* ``filled``: ``refined`` where known, elsewhere a confidence-weighted edge-aware interpolation by
  the fast global smoother (``cv2.ximgproc.createFastGlobalSmootherFilter``, Min et al. 2014) used
  as a normalised convolution: ``FGS(c * d) / FGS(c)``. Holes take the values of the surface
  they share an image region with.

The fast global smoother comes from opencv-contrib's ximgproc. Both guides are 8-bit: the float
guide (values in [0, 1]) is quantised to 256 levels.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from lfring.core.validate import check_int, check_number
from lfring.errors import InvalidInputError

__all__ = ["FGS_ATTENUATION", "FGS_ITERATIONS", "FILL_WEIGHT_FLOOR", "MIN_CONFIDENCE", "fill_from_farther_side", "refine_index"]

# Pixels below this confidence (1 - best / second best of the aggregated cost) are not trusted.
MIN_CONFIDENCE = 0.05
# Weighted median: radius (px) and guide range sigma (8-bit guide levels).
MEDIAN_RADIUS_PX = 3
MEDIAN_SIGMA = 25.5
# Fast global smoother for the holes: regularisation and guide range sigma (8-bit levels).
FGS_LAMBDA = 200.0
FGS_SIGMA = 8.0
# OpenCV's defaults of the smoother, which refine_index keeps: each of its iterations is a pass
# along the rows and one along the columns, with the regularisation cut by this factor after it.
FGS_ATTENUATION = 0.25
FGS_ITERATIONS = 3
# Normalised convolution: below this smoothed weight a pixel has no support at all.
FILL_WEIGHT_FLOOR = 1e-6
# The weighted median bins the values: their range is cut into at most this many units (one per
# hypothesis when the range allows), each split into MEDIAN_FINE_BINS bins; the answer is the
# weighted mean of the values in the median's bin.
MEDIAN_COARSE_BINS = 256
MEDIAN_FINE_BINS = 8


def weighted_median(values: np.ndarray, known: np.ndarray, guide8: np.ndarray, radius_px: int, sigma: float) -> np.ndarray:
    """(h, w) float32 weighted median of the ``known`` ``values`` over (2 radius + 1)^2 windows,
    weighted by ``exp(-|I_p - I_q|^2 / (2 sigma^2))`` of the uint8 guide; NaN where not known
    (the values there are never read)."""
    from lfring.depth import refine_kernels

    v = np.ascontiguousarray(values, np.float32)
    k = np.ascontiguousarray(known, np.bool_)
    lo, hi = refine_kernels.value_range(v, k)
    return _median(v, k, float(lo), float(hi), guide8, radius_px, sigma)


def _median(v, k, lo: float, hi: float, guide8, radius_px: int, sigma: float) -> np.ndarray:
    """:func:`weighted_median` of float32 values with their known mask and its range."""
    from lfring.depth import refine_kernels

    out = np.empty(v.shape, np.float32)
    if lo > hi:  # nothing is known
        out.fill(np.nan)
        return out
    coarse = int(min(MEDIAN_COARSE_BINS, math.ceil(hi - lo) + 1))
    fine_width = max((hi - lo) / max(coarse - 1, 1), 1e-6) / MEDIAN_FINE_BINS
    fine = coarse * MEDIAN_FINE_BINS
    bins = np.empty(v.shape, np.int32)
    refine_kernels.bin_values(v, k, np.float32(lo), np.float32(fine_width), fine, bins)
    lut = np.exp(-np.arange(256, dtype=np.float64) ** 2 / (2.0 * max(float(sigma), 1e-6) ** 2))
    refine_kernels.weighted_median(v, bins, np.ascontiguousarray(guide8, np.uint8), int(radius_px), lut, fine, out)
    return out


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
        pixels and 0 at holes; NaN where that weight vanishes (below 1e-6: strong edges of the
        guide cut the hole off from every known pixel; a nearest-value fill there was measured
        and judged not worth its time) and where no pixel at all is known.

    Notes
    -----
    The weighted median minimises ``sum_q w(p, q) |d - d_q|`` over the known pixels q of the
    window, with ``w = exp(-|I_p - I_q|^2 / (2 sigma^2))`` (OpenCV's ``WMF_EXP``; a colour guide
    is turned grey first), to the resolution of :data:`MEDIAN_FINE_BINS` bins per unit of the
    values; within that bin the answer is the bin's weighted mean.

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
    try:
        c = np.asarray(confidence, np.float32)
    except (TypeError, ValueError):
        raise InvalidInputError(f"confidence must be a float (h, w) map, got {type(confidence).__name__}") from None
    if c.shape != d.shape:
        raise InvalidInputError(f"confidence must have the index's shape {d.shape}, got {c.shape}")
    g8 = _guide8(guide, d.shape)
    check_number(min_confidence, "min_confidence", minimum=0.0, maximum=1.0)
    for name, v in (("sigma", sigma), ("fill_lambda", fill_lambda), ("fill_sigma", fill_sigma)):
        check_number(v, name, minimum=0.0)
    check_int(radius_px, "radius_px", minimum=1)
    radius_px = min(int(radius_px), max(d.shape))  # a wider window covers the same pixels
    from lfring.depth import refine_kernels

    d = np.ascontiguousarray(d, np.float32)
    c = np.ascontiguousarray(c)
    known = np.empty(d.shape, np.bool_)
    refine_kernels.known_pixels(d, c, np.float32(min_confidence), known)
    lo, hi = refine_kernels.value_range(d, known)
    refined = _median(d, known, float(lo), float(hi), g8 if g8.ndim == 2 else cv2.cvtColor(g8, cv2.COLOR_RGB2GRAY),
                      radius_px, sigma)
    if lo > hi:  # nothing is known
        return refined, refined.copy()
    weight = np.empty(d.shape, np.float32)
    weighted = np.empty(d.shape, np.float32)
    refine_kernels.fill_inputs(known, refined, c, np.float32(FILL_WEIGHT_FLOOR), weight, weighted)
    fgs = cv2.ximgproc.createFastGlobalSmootherFilter(g8, float(fill_lambda), float(fill_sigma), FGS_ATTENUATION,
                                                     FGS_ITERATIONS)
    filled = np.empty(d.shape, np.float32)
    refine_kernels.filled_map(known, refined, fgs.filter(weighted), fgs.filter(weight), np.float32(FILL_WEIGHT_FLOOR),
                              filled)
    return refined, filled


def fill_from_farther_side(index, holes, *, axis: int = 1) -> np.ndarray:
    """``index`` with its ``holes`` filled along ``axis`` from the farther side.

    A hole takes the higher (the hypotheses run from near to far) of the nearest known values
    before and after it on its row (``axis=1``) or column (``axis=0``); the one there is where
    only one side has any; it stays NaN where its line has none. The holes of the left-right
    check are mostly occlusions: background beside a nearer surface, which the other view
    cannot see. They belong to the farther side, and the Middlebury SDK fills them so.

    Parameters
    ----------
    index : (h, w) float array
        Hypothesis index (or any value that grows with depth); NaN where unknown. Known: finite
        and not a hole.
    holes : (h, w) bool array
    axis : {0, 1}
        Along the baseline: 1 for a horizontal pair, 0 for a vertical one.

    Returns
    -------
    (h, w) float32

    Examples
    --------
    >>> import numpy as np
    >>> index = np.array([[2.0, 9.0, 1.0, 1.0, 5.0, np.nan]], np.float32)
    >>> holes = np.array([[False, False, True, True, False, True]])
    >>> fill_from_farther_side(index, holes).tolist()
    [[2.0, 9.0, 9.0, 9.0, 5.0, 5.0]]
    """
    d = np.asarray(index)
    if d.ndim != 2 or not np.issubdtype(d.dtype, np.floating):
        raise InvalidInputError(f"index must be a floating-point (h, w) map, got {d.dtype} {d.shape}")
    holes = np.asarray(holes)
    if holes.shape != d.shape or holes.dtype != bool:
        raise InvalidInputError(f"holes must be a bool map of the index's shape {d.shape}, got {holes.dtype} {holes.shape}")
    check_int(axis, "axis", minimum=0, maximum=1, hint=" (0 along columns, 1 along rows)")
    v = np.asarray(d, np.float32)
    if axis == 0:
        v, holes = v.T, holes.T
    h, w = v.shape
    known = np.isfinite(v) & ~holes
    cols = np.broadcast_to(np.arange(w), (h, w))
    before = np.maximum.accumulate(np.where(known, cols, -1), axis=1)  # nearest known at or before
    after = np.minimum.accumulate(np.where(known, cols, w)[:, ::-1], axis=1)[:, ::-1]
    rows = np.arange(h)[:, None]
    vb = np.where(before >= 0, v[rows, np.clip(before, 0, w - 1)], -np.inf)
    va = np.where(after < w, v[rows, np.clip(after, 0, w - 1)], -np.inf)
    far = np.maximum(vb, va)
    out = np.where(holes, np.where(np.isfinite(far), far, np.nan), v).astype(np.float32)
    return out.T.copy() if axis == 0 else out
