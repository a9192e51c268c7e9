"""Depth and disparity metrics, as the HCI 4D light-field benchmark reports them.

Pure functions over arrays of any (equal) shape, with an optional boolean ``mask`` of the pixels
to evaluate. The ground truth decides which pixels count; the estimate never does:

* a pixel is **evaluated** when it is in the mask (all pixels without one) and its ground truth
  is finite (the synthetic twin has NaN where no surface is seen);
* an estimate that is not finite there (NaN: no depth, or +-inf) is a **missing** estimate.
  :func:`badpix` counts it as a bad pixel (a method cannot improve its score by abstaining);
  the error means (:func:`mse_x100`, :func:`mae`, :func:`median_relative_error`) leave it out,
  and :func:`summary` reports how many were left out (``n_missing``). When every evaluated
  estimate is missing the means are NaN (no warning);
* a mask or a ground truth that leaves no pixel to evaluate is an error.

HCI states BadPix as a percentage; here it is a fraction in [0, 1]. HCI's disparities are
between neighbouring views of its 9 x 9 grid; here they are between two views of the ring
(:func:`depth_to_disparity_px`), by default the horizontal neighbours 0 and 1.
"""

from __future__ import annotations

import numpy as np

from lfring.core.validate import check_number, check_view_index
from lfring.errors import InvalidInputError

__all__ = [
    "DEFAULT_TAUS_PX", "badpix", "depth_to_disparity_px", "evaluation_mask", "mae", "median_relative_error", "mse_x100",
    "summary",
]

#: BadPix thresholds in disparity pixels between neighbouring views.
DEFAULT_TAUS_PX = (0.07, 0.3, 1.0)


# -- validation --------------------------------------------------------------------------------
def _float_array(a, name: str) -> np.ndarray:
    arr = np.asarray(a)
    if not np.issubdtype(arr.dtype, np.floating):
        raise InvalidInputError(
            f"{name} must be a floating-point array (float32 or float64, NaN where unknown), got dtype {arr.dtype}; "
            "convert it explicitly, e.g. with .astype(np.float32)"
        )
    if arr.ndim < 1 or arr.size == 0:
        raise InvalidInputError(f"{name} must be a non-empty array, got shape {arr.shape}")
    return arr


def _evaluated(estimate, truth, mask, *, names=("estimate", "truth")) -> tuple[np.ndarray, np.ndarray]:
    """The estimate and truth (float64, 1-D) at the evaluated pixels: in the mask, truth finite."""
    e = _float_array(estimate, names[0])
    t = _float_array(truth, names[1])
    if e.shape != t.shape:
        raise InvalidInputError(f"{names[0]} and {names[1]} must have the same shape, got {e.shape} and {t.shape}")
    sel = np.isfinite(t)
    if mask is not None:
        m = np.asarray(mask)
        if m.dtype != np.bool_:
            raise InvalidInputError(f"mask must be a boolean array, got dtype {m.dtype}; build it with a comparison, e.g. depth > 0")
        if m.shape != t.shape:
            raise InvalidInputError(f"mask must have the shape of the maps {t.shape}, got {m.shape}")
        if not m.any():
            raise InvalidInputError("the mask selects no pixel; there is nothing to evaluate")
        sel &= m
    if not sel.any():
        where = " inside the mask" if mask is not None else ""
        raise InvalidInputError(f"{names[1]} has no finite value{where}; there is nothing to evaluate")
    return e[sel].astype(np.float64), t[sel].astype(np.float64)


def _finite_pairs(e: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ok = np.isfinite(e)
    return e[ok], t[ok]


# -- metrics -----------------------------------------------------------------------------------
def badpix(estimate, truth, tau: float, mask=None) -> float:
    """Fraction of evaluated pixels whose error exceeds ``tau`` (HCI BadPix, as a fraction).

    Parameters
    ----------
    estimate, truth : ndarray, floating, same shape
        Disparity maps in pixels (or any maps in the unit of ``tau``).
    tau : float
        Threshold, > 0, in the unit of the maps (HCI reports 0.07, 0.03 and 0.01 px).
    mask : ndarray of bool, optional
        Pixels to evaluate (also limited to those with finite truth).

    Returns
    -------
    float in [0, 1]

    Notes
    -----
    ``badpix = #{|estimate - truth| > tau or estimate not finite} / #evaluated``.

    Examples
    --------
    >>> import numpy as np
    >>> badpix(np.array([1.0, 2.0, np.nan, 4.0]), np.array([1.0, 2.5, 3.0, 4.05]), 0.07)
    0.5
    """
    check_number(tau, "tau", above=0.0, what="a positive number of pixels")
    e, t = _evaluated(estimate, truth, mask)
    with np.errstate(invalid="ignore"):
        good = np.abs(e - t) <= tau  # NaN compares False: a missing estimate is bad
    return float(1.0 - np.count_nonzero(good) / e.size)


def mse_x100(estimate, truth, mask=None) -> float:
    """100 times the mean squared error (HCI's MSE * 100; disparity px^2).

    Missing (non-finite) estimates are left out; NaN when every evaluated estimate is missing.

    Examples
    --------
    >>> import numpy as np
    >>> mse_x100(np.array([1.0, 2.0, np.nan]), np.array([1.0, 2.5, 3.0]))
    12.5
    """
    e, t = _finite_pairs(*_evaluated(estimate, truth, mask))
    return float(100.0 * np.mean((e - t) ** 2)) if e.size else float("nan")


def mae(estimate, truth, mask=None) -> float:
    """Mean absolute error, in the unit of the maps (metres for depth, pixels for disparity).

    Missing (non-finite) estimates are left out; NaN when every evaluated estimate is missing.

    Examples
    --------
    >>> import numpy as np
    >>> mae(np.array([1.0, 2.0, np.nan]), np.array([1.5, 2.5, 3.0]))
    0.5
    """
    e, t = _finite_pairs(*_evaluated(estimate, truth, mask))
    return float(np.mean(np.abs(e - t))) if e.size else float("nan")


def median_relative_error(estimate_m, truth_m, mask=None) -> float:
    """Median of ``|estimate - truth| / truth`` over the evaluated pixels (depths, > 0).

    Missing (non-finite) estimates are left out; NaN when every evaluated estimate is missing.

    Examples
    --------
    >>> import numpy as np
    >>> median_relative_error(np.array([0.75, 1.0, 3.0]), np.array([0.5, 1.0, 2.0]))
    0.5
    """
    e, t = _evaluated(estimate_m, truth_m, mask, names=("estimate_m", "truth_m"))
    if np.any(t <= 0):
        raise InvalidInputError(f"truth_m must be positive depths where evaluated, got a minimum of {t.min()!r}")
    e, t = _finite_pairs(e, t)
    return float(np.median(np.abs(e - t) / t)) if e.size else float("nan")


# -- depth to disparity -----------------------------------------------------------------------
def _model_of(calibration):
    model = getattr(calibration, "model", calibration)
    if not all(hasattr(model, k) for k in ("A", "B", "depth_origin_m")):
        raise InvalidInputError(
            f"calibration must be a RingCalibration or a VariableHomography, got {type(calibration).__name__}"
        )
    return model


def depth_to_disparity_px(depth_m, calibration, view_a: int = 0, view_b: int = 1, *, signed: bool = False) -> np.ndarray:
    """The disparity between two views that a depth map implies, in pixels.

    Parameters
    ----------
    depth_m : ndarray, floating, any shape
        Distances Z from the main lens, metres; non-finite values give NaN.
    calibration : RingCalibration or VariableHomography
        Its model ``H_r_from_k(Z) = A_k + B_k / (Z - z0)`` (normalised to ``H[2, 2] = 1``).
    view_a, view_b : int
        Two different views: 0 and 1 are horizontal neighbours, 0 and 2 vertical ones.
    signed : bool
        False (default): the length of the disparity vector. True: its component along the
        baseline direction, growing as the point comes nearer (see Notes).

    Returns
    -------
    ndarray, float64, shape of ``depth_m``

    Raises
    ------
    InvalidInputError
        A finite depth at or in front of the depth origin z0, equal or invalid views.

    Notes
    -----
    With ``t_k(Z) = H_r_from_k(Z)[:2, 2]`` (the translation of ``calibration.model(Z)``; exact
    for the ring, whose homographies are translations), a point seen at pixel ``p_a`` of view a
    is seen at ``p_b = p_a - d`` in view b, with the disparity vector

        d(Z) = t_b(Z) - t_a(Z) = dA + dB / (Z - z0)        (pure translations),

    and the disparity is ``|d(Z)|``. It does not depend on the calibration's reference view.
    The signed disparity is ``d(Z) . u`` with ``u = dB / |dB|``, which is affine in
    ``1 / (Z - z0)`` and increasing towards the viewer. Prefer it for errors: the two agree
    up to a constant sign unless ``d`` passes through zero within the depths at hand (views cut
    so that they align at some finite depth), where ``|d|`` folds two depths onto one value.

    Examples
    --------
    >>> import numpy as np
    >>> from lfring.calibration.model import VariableHomography
    >>> eye = np.eye(3)
    >>> b = np.zeros((2, 3, 3)); b[1, 0, 2] = -2.0             # view 1 moves 2 px / (Z - z0)
    >>> a = np.stack([eye, eye]); a[1, 0, 2] = 10.0
    >>> depth_to_disparity_px(np.array([1.0, 2.0, np.nan]), VariableHomography(a, b, 0.0, 0), 0, 1)
    array([ 8.,  9., nan])
    """
    model = _model_of(calibration)
    v = model.A.shape[0]
    a = check_view_index(view_a, "view_a", v)
    b = check_view_index(view_b, "view_b", v)
    if a == b:
        raise InvalidInputError(f"view_a and view_b must be two different views, got {a} twice")
    z = _float_array(depth_m, "depth_m").astype(np.float64)
    z0 = float(model.depth_origin_m)
    finite = np.isfinite(z)
    if np.any(z[finite] <= z0):
        raise InvalidInputError(
            f"depth_m must lie beyond the calibration's depth origin z0 = {z0:.4g} m (or be NaN where unknown); "
            f"got a minimum of {float(np.min(z[finite])):.4g} m"
        )
    x = np.full(z.shape, np.nan)
    x[finite] = 1.0 / (z[finite] - z0)
    aa, bb = model.A, model.B

    # calibration.model(Z)[k, :2, 2] in closed form: no (N, V, 3, 3) stack for a whole map.
    def translation(k: int) -> np.ndarray:
        num = aa[k, :2, 2] + bb[k, :2, 2] * x[..., None]
        return num / (aa[k, 2, 2] + bb[k, 2, 2] * x)[..., None]

    d = translation(b) - translation(a)
    if not signed:
        return np.hypot(d[..., 0], d[..., 1])
    db = bb[b, :2, 2] - bb[a, :2, 2]
    norm = float(np.hypot(*db))
    if not norm > 0:
        raise InvalidInputError(f"views {a} and {b} do not move relative to each other with depth; no baseline direction")
    return d @ (db / norm)


# -- summary -----------------------------------------------------------------------------------
def summary(
    estimate_m,
    truth_m,
    calibration,
    mask=None,
    *,
    view_a: int = 0,
    view_b: int = 1,
    taus=DEFAULT_TAUS_PX,
) -> dict:
    """The benchmark numbers of a depth map against its ground truth.

    Parameters
    ----------
    estimate_m, truth_m : ndarray, floating, same shape
        Depth maps in metres, NaN where unknown.
    calibration : RingCalibration or VariableHomography
        Converts depths into disparities between ``view_a`` and ``view_b``.
    mask : ndarray of bool, optional
    view_a, view_b : int
        The disparity pair (default 0, 1: horizontal neighbours).
    taus : sequence of float
        BadPix thresholds in disparity pixels.

    Returns
    -------
    dict
        ``badpix_{tau:g}px`` (fraction of bad pixels, one key per tau, e.g. ``badpix_0.07px``),
        ``mse_x100`` (disparity px^2), ``mae_m``, ``mae_px``, ``median_relative_error``,
        ``n_pixels`` (evaluated: in the mask with finite truth), ``n_missing`` (of those, the
        pixels without a finite estimate: bad for BadPix, left out of the means), ``view_a``
        and ``view_b``.

    Notes
    -----
    Disparity errors use the signed disparity of :func:`depth_to_disparity_px`, so an error
    in pixels is exactly ``|dB| |1/(Ze - z0) - 1/(Zt - z0)|`` however the views were cut.
    """
    try:
        taus = tuple(taus)
    except TypeError:
        raise InvalidInputError(f"taus must be a sequence of thresholds in pixels, got {taus!r}") from None
    if not taus:
        raise InvalidInputError("taus must hold at least one threshold in pixels")
    e_m = _float_array(estimate_m, "estimate_m")
    t_m = _float_array(truth_m, "truth_m")
    e_sel, _ = _evaluated(e_m, t_m, mask, names=("estimate_m", "truth_m"))  # validates shapes and mask first
    d_e = depth_to_disparity_px(e_m, calibration, view_a, view_b, signed=True)
    d_t = depth_to_disparity_px(t_m, calibration, view_a, view_b, signed=True)
    out = {f"badpix_{float(tau):g}px": badpix(d_e, d_t, tau, mask) for tau in taus}
    out.update(
        mse_x100=mse_x100(d_e, d_t, mask),
        mae_m=mae(e_m, t_m, mask),
        mae_px=mae(d_e, d_t, mask),
        median_relative_error=median_relative_error(e_m, t_m, mask),
        n_pixels=int(e_sel.size),
        n_missing=int(np.count_nonzero(~np.isfinite(e_sel))),
        view_a=int(view_a),
        view_b=int(view_b),
    )
    return out


def evaluation_mask(truth_m, image, *, min_variance: float = 1e-4, edge_m: float = 0.01, margin_px: int = 31,
                    window_px: int = 9) -> np.ndarray:
    """Pixels where a depth estimate can be judged: textured (local variance of ``image``'s
    luminance over ``window_px`` above ``min_variance``) and at least ``margin_px // 2`` px away
    from any depth edge (a jump of more than ``edge_m`` metres between neighbours), where
    occlusions and defocus spill make the ground truth ambiguous.

    Parameters
    ----------
    truth_m : (h, w) float
        Ground-truth depth in metres.
    image : (h, w) or (h, w, 3) float
        The reference view, in [0, 1].
    """
    import cv2

    t = np.asarray(truth_m, dtype=np.float64)
    img = np.asarray(image, dtype=np.float32)
    if img.ndim == 3:
        img = img.mean(axis=2)
    if t.ndim != 2 or img.shape != t.shape:
        raise InvalidInputError(f"truth_m and image must share one (h, w) shape, got {t.shape} and {img.shape}")
    k = (window_px, window_px)
    textured = cv2.boxFilter(img * img, -1, k) - cv2.boxFilter(img, -1, k) ** 2 > min_variance
    with np.errstate(invalid="ignore"):
        jump = (np.abs(np.diff(t, axis=0, prepend=t[:1])) + np.abs(np.diff(t, axis=1, prepend=t[:, :1]))) > edge_m
    near = cv2.dilate(jump.astype(np.uint8), np.ones((margin_px, margin_px), np.uint8)).astype(bool)
    return textured & ~near & np.isfinite(t)
