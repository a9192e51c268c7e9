"""Per-plane homographies: align every view of one photograph of a textured planar target onto
a reference view (the first step of the variable-homography calibration).

The default method needs no features. Each view is brought to a common brightness scale
(divided by a flat field when one is given), a phase correlation of high-passed, windowed copies
finds the translation that brings it onto the reference (disparities are a hundred pixels and
more on the binned twin, far outside the basin of a local method), and a direct intensity
alignment (OpenCV's enhanced-correlation-coefficient maximisation, ``findTransformECCWithMask``)
refines a full homography coarse to fine over an image pyramid. A last full-resolution pass
removes the views' relative vignetting: the smooth gain between the aligned view and the
reference is estimated by local least squares and divided out before ECC runs once more. SIFT
features with RANSAC give an independent estimate (``method='sift'``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from lfring.core.lens import FLAT_FLOOR
from lfring.core.registry import Registry
from lfring.core.validate import check_choice, check_int, check_number, check_view_index
from lfring.errors import EstimationError, InvalidInputError
from lfring.core.records import record_repr

__all__ = [
    "METHODS",
    "MODELS",
    "PlaneHomographies",
    "check_flat_views",
    "estimate_plane_homographies",
    "local_shifts",
    "phase_correlation_translations",
]

MODELS = ("homography", "affine", "translation")

_ECC_MOTION = {"homography": cv2.MOTION_HOMOGRAPHY, "affine": cv2.MOTION_AFFINE, "translation": cv2.MOTION_TRANSLATION}

#: a pixel counts as clipped when its brightest channel reaches this fraction of full scale.
_CLIP_LEVEL = 0.995
#: refuse a view when more than this fraction of its valid pixels is clipped.
_MAX_CLIPPED_FRACTION = 0.5
#: a pixel counts as black below this fraction of full scale ...
_DARK_LEVEL = 0.01
#: ... and a view is refused when more than this fraction of its valid pixels is black.
_MAX_DARK_FRACTION = 0.9
#: RMS relative contrast of the (lightly smoothed) texture below which a view is textureless.
_MIN_CONTRAST = 0.01
#: phase-correlation peak strength (OpenCV's 'response', 0..1) below which no common shift exists.
_MIN_RESPONSE = 0.05
#: the ECC estimate may move the overlap's centre at most this far from the phase correlation.
_MAX_ECC_DRIFT_PX = 5.0
#: ECC's Gaussian prefilter (kernel size, px). Wider than OpenCV's default 5: bilinear
#: resampling shifts fine detail at sub-pixel offsets on sharp targets, and smoothing weights
#: the low frequencies, where it is exact (the wider kernel measured the smaller error).
_ECC_SMOOTHING = 9
#: default margins inside the valid disc, as fractions of its inscribed radius: the disc's rim
#: falls off over about a fifth of the radius on the twin and is kept out of the alignment
#: unless a flat field has divided it away.
_MARGIN_NO_FLAT = 0.18
_MARGIN_FLAT = 0.07


@dataclass(frozen=True, eq=False)
class PlaneHomographies:
    """The homographies of one plane, with diagnostics.

    Attributes
    ----------
    H_ref_from_view : ndarray, (V, 3, 3) float64
        View pixels -> reference-view pixels, each normalised so that H[2, 2] = 1; identity for
        the reference itself.
    reference : int
        The reference view.
    residual_px : ndarray, (V,)
        RMS misregistration that remains after the alignment, in pixels, measured locally: for
        ``'ecc'`` the overlap of the warped view and the reference is cut into square regions
        (about a tenth of the disc's diameter) and each region's remaining shift is solved by
        least squares (Lucas-Kanade with gain and offset); for ``'sift'`` it is the RMS
        reprojection error of the RANSAC inliers. Both are the scatter of local measurements
        about the fitted transform (noise plus whatever the model cannot represent), not the
        error of the transform itself, which averages many regions or matches and is smaller.
        0 for the reference.
    correlation : ndarray, (V,)
        ``'ecc'``: the final enhanced correlation coefficient (1 is a perfect match up to gain
        and offset); ``'sift'``: the fraction of the ratio-test matches that RANSAC kept. 1 for
        the reference.
    init_translation_px : ndarray, (V, 2)
        The phase correlation's translation (x, y) of each view onto the reference, the
        starting point of ECC (and the gate of SIFT matching).
    method, model : str
    """

    __repr__ = record_repr

    H_ref_from_view: np.ndarray
    reference: int
    residual_px: np.ndarray
    correlation: np.ndarray
    init_translation_px: np.ndarray
    method: str
    model: str

    @property
    def num_views(self) -> int:
        """Number of views V (one homography each)."""
        return len(self.H_ref_from_view)


# ------------------------------------------------------------------------------------------------
def estimate_plane_homographies(
    views,
    *,
    reference: int = 0,
    masks=None,
    method: str = "ecc",
    model: str = "homography",
    flat_views=None,
    pyramid_levels: int | None = None,
    margin_px: float | None = None,
) -> PlaneHomographies:
    """Homographies that map every view of a fronto-parallel textured plane onto a reference.

    Parameters
    ----------
    views : ndarray, (V, h, w, C) or (V, h, w), floating, in [0, 1]
        The sub-aperture views of one photograph of the target (``lfring.split_views``).
        Alignment runs on the luminance (mean of the channels).
    reference : int
        Index of the view the others are mapped into.
    masks : ndarray, (V, h, w) bool, optional
        Valid pixels of each view, e.g. ``Layout.masks()`` (the discs the mini-lenses light).
        Only valid pixels, less a margin (``margin_px``), take part. Default: every pixel.
    method : {'ecc', 'sift'}
        'ecc': phase correlation, then ECC coarse to fine, then a gain-compensated ECC pass
        (no features). 'sift': SIFT keypoints, ratio-test matches gated by the phase
        correlation, then RANSAC (MAGSAC++) and a least-squares fit on the inliers.
    model : {'homography', 'affine', 'translation'}
        The transform estimated. The twin's views are related by pure translations; a real ring
        has small tilts and distortion, hence the homography by default.
    flat_views : ndarray, same shape as ``views``, optional
        Views of a flat (uniformly lit white) frame cut with the same layout. The views are
        divided by it (where it exceeds a fifth of its bright level) before alignment, which
        removes each view's vignetting: the same target point sits at different places of
        each view's vignetted disc. Without a flat, a wider margin keeps the discs' dark rims
        out and the gain pass absorbs the remaining smooth brightness differences.
    pyramid_levels : int, optional
        Levels of the ECC pyramid (1 = full resolution only). Default: halve until the short
        side would drop below 128 px (3 levels for the binned twin's 704 px views).
    margin_px : float, optional
        Distance from the edge of each valid region within which pixels are not used. Default:
        0.07 (with a flat) or 0.18 (without) of the region's inscribed radius, 25 or 63 px on
        the binned twin.

    Returns
    -------
    PlaneHomographies

    Raises
    ------
    InvalidInputError
        Wrong shapes or dtypes, non-finite values, an unknown method or model.
    EstimationError
        A view is badly exposed (mostly clipped or black) or textureless, the views share no
        common shift (phase correlation finds no clear peak), ECC fails to converge or drifts
        away from the phase correlation, or SIFT finds too few consistent matches. The message
        names the view.

    Notes
    -----
    For a plane, view k and the reference see the same texture related by a homography
    ``x_ref ~ H x_k``. ECC maximises the correlation coefficient

        rho(H) = <T - mean T, I(H x) - mean I(H x)> / (|T - mean T| |I(H x) - mean I(H x)|)

    over the template T (view k) and the warped input I (the reference), which is invariant to
    a global gain and offset. A spatially varying gain (the views' relative vignetting when no
    flat is given) biases it; the final pass estimates ``G(x) = sum_w(I T_w) / sum_w(T_w^2)``
    over a Gaussian window w (T_w is view k warped by the current H) and aligns ``I / G``. At
    the true H, ``I / G`` is exactly ``T_w``, so the pass does not move a correct estimate.

    On the synthetic twin of the prototype (binned, with realistic noise) each view's homography
    is accurate to a small fraction of a pixel over the working range, a little better with a
    flat field than without; SIFT is several times less accurate and slower than ECC.

    Examples
    --------
    >>> from lfring.optics import load_device
    >>> from lfring.synth import render
    >>> from lfring.synth.presets import target_scene
    >>> dev = load_device("prototype")
    >>> r = render(dev, target_scene(dev, 1.0), binning=4)
    >>> est = estimate_plane_homographies(r.views, masks=r.layout.masks())
    >>> from lfring.core.geometry import homography_rms_px
    >>> bool(homography_rms_px(est.H_ref_from_view, r.homographies(1.0, reference=0), r.layout.view_shape).max() < 0.05)
    True
    """
    align = METHODS.lookup(method)
    check_choice(model, "model", MODELS)
    lum, valid, ref = _prepare(views, masks, flat_views, reference)
    num, h, w = lum.shape
    levels = _check_levels(pyramid_levels, h, w)
    margin = _margin(valid, margin_px, flat_views is not None)
    inner = np.stack([_erode(valid[k], margin) for k in range(num)])
    for k in range(num):
        if inner[k].sum() < 0.05 * h * w:
            raise InvalidInputError(
                f"view {k}: only {int(inner[k].sum())} usable pixels remain inside its valid region less a margin of "
                f"{margin:.0f} px; give masks that cover the target, or a smaller margin_px"
            )
    _check_texture(lum, inner)
    shifts, response = _phase_correlation(lum, valid, inner, ref, margin)
    for k in range(num):
        if k != ref and response[k] < _MIN_RESPONSE:
            raise EstimationError(
                f"view {k}: phase correlation with the reference view {ref} found no clear peak (strength "
                f"{response[k]:.3f}, expected > {_MIN_RESPONSE}); the views do not share the target's texture. Is "
                "the target textured, in the field of every view, and the frame not dominated by noise?"
            )
    H = np.tile(np.eye(3), (num, 1, 1))
    residual = np.zeros(num)
    corr = np.ones(num)
    for k in range(num):
        if k == ref:
            continue
        h0 = np.eye(3)
        h0[:2, 2] = shifts[k]
        H[k], corr[k], residual[k] = align(lum[k], lum[ref], inner[k], inner[ref], h0, model, levels, k, ref)
    return PlaneHomographies(
        H_ref_from_view=H, reference=ref, residual_px=residual, correlation=corr,
        init_translation_px=shifts, method=method, model=model,
    )


def phase_correlation_translations(views, *, reference: int = 0, masks=None, flat_views=None,
                                   margin_px: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Translation of every view onto the reference by phase correlation (the initialisation of
    :func:`estimate_plane_homographies`).

    Returns
    -------
    translation_px : ndarray, (V, 2)
        (x, y) to add to view pixels to land on the reference's; 0 for the reference.
    response : ndarray, (V,)
        Peak strength (0..1; OpenCV's ``phaseCorrelate`` response); 1 for the reference.

    Notes
    -----
    Each luminance image is divided by its local mean (a Gaussian of 6 px over the valid
    pixels) to remove vignetting and exposure, then multiplied by a window that rises smoothly
    from 0 at the margin to 1 at twice the margin inside the valid region, so that the discs'
    edges, which sit at the same place in every view, add no peak at zero shift. On the twin it
    lands within a fraction of a pixel at full resolution, inside ECC's basin.
    """
    lum, valid, ref = _prepare(views, masks, flat_views, reference)
    margin = _margin(valid, margin_px, flat_views is not None)
    inner = np.stack([_erode(valid[k], margin) for k in range(len(lum))])
    return _phase_correlation(lum, valid, inner, ref, margin)


# ------------------------------------------------------------------------------------------------
# Input preparation and checks
def _as_views(arr, name: str) -> np.ndarray:
    if isinstance(arr, (list, tuple)):
        shapes = {np.shape(a) for a in arr}
        if len(shapes) > 1:
            raise InvalidInputError(
                f"all {name} must have the same size, got shapes {sorted(shapes)}; cut them with one layout "
                "(lfring.split_views)"
            )
    a = np.asarray(arr)
    if a.ndim == 3:
        a = a[..., None]
    if a.ndim != 4:
        raise InvalidInputError(f"{name} must be an array (V, h, w, C) or (V, h, w), got shape {a.shape}")
    if not np.issubdtype(a.dtype, np.floating):
        raise InvalidInputError(
            f"{name} must be floating-point values in [0, 1], got {a.dtype}; normalise raw counts with explicit "
            "black and white levels (lfring.demosaic) first"
        )
    if not np.all(np.isfinite(a)):
        raise InvalidInputError(f"{name} contain NaN or infinite values")
    return a


def _prepare(views, masks, flat_views, reference):
    """Luminance (V, h, w) float32 (flat-fielded when a flat is given), valid masks (less the
    flat's dark rim) and the reference index, after validating everything."""
    v = _as_views(views, "views")
    num, h, w, _ = v.shape
    if num < 2:
        raise InvalidInputError(f"need two or more views to align, got {num}")
    if min(h, w) < 32:
        raise InvalidInputError(f"views must be at least 32 x 32 px, got {w} x {h}")
    check_view_index(reference, "reference", num, hint=" (for the virtual center view, re-express the result with "
                                                        "lfring.core.geometry.to_reference)")
    if masks is None:
        valid = np.ones((num, h, w), dtype=bool)
    else:
        valid = np.asarray(masks)
        if valid.shape != (num, h, w):
            raise InvalidInputError(f"masks must have shape (V, h, w) = {(num, h, w)}, got {valid.shape}")
        if valid.dtype != bool:
            raise InvalidInputError(f"masks must be boolean, got {valid.dtype}")
        valid = valid.copy()
    lum = v.mean(axis=3, dtype=np.float32)
    brightest = v.max(axis=3)
    # Partly clipped views are used whole: the clipped highlights sit at (nearly) the same
    # target points in every view and still align (partial clipping measured harmless), while
    # cutting them out of the masks riddles the masks with holes, which measurably throws ECC off.
    for k in range(num):
        n = int(valid[k].sum())
        if n == 0:
            raise InvalidInputError(f"view {k}: its mask selects no pixel")
        clipped = brightest[k][valid[k]] >= _CLIP_LEVEL
        if clipped.mean() > _MAX_CLIPPED_FRACTION:
            raise EstimationError(
                f"view {k} is overexposed: {100 * clipped.mean():.0f}% of its valid pixels are clipped at full scale "
                f"(at most {100 * _MAX_CLIPPED_FRACTION:.0f}% allowed); photograph the target with a shorter exposure"
            )
        dark = brightest[k][valid[k]] < _DARK_LEVEL
        if dark.mean() > _MAX_DARK_FRACTION:
            raise EstimationError(
                f"view {k} is underexposed: {100 * dark.mean():.0f}% of its valid pixels are below "
                f"{100 * _DARK_LEVEL:g}% of full scale; photograph the target with a longer exposure or more light"
            )
    if flat_views is not None:
        flat, brights = _flat_luminance(flat_views, valid)
        for k in range(num):
            ok = flat[k] > FLAT_FLOOR * brights[k]
            valid[k] &= ok
            lum[k] = np.where(ok, lum[k] / np.where(ok, flat[k], 1.0), 0.0)
    return lum, valid, int(reference)


def _flat_luminance(flat_views, valid: np.ndarray) -> tuple[np.ndarray, list]:
    """A flat frame's views' luminance (V, h, w) float32 and each view's bright level (its 95th
    percentile where ``valid``), refusing views that do not fit ``valid`` or are black or clipped."""
    num, h, w = valid.shape
    f = _as_views(flat_views, "flat_views")
    if f.shape[:3] != (num, h, w):
        raise InvalidInputError(
            f"flat_views must have the views' shape (V, h, w) = {(num, h, w)} (and any channel count), "
            f"got {f.shape[:3]}; cut the flat frame with the same layout"
        )
    flat = f.mean(axis=3, dtype=np.float32)
    brights = []
    for k in range(num):
        vals = flat[k][valid[k]]
        bright = float(np.percentile(vals, 95)) if vals.size else 0.0
        if not bright > _DARK_LEVEL:
            raise InvalidInputError(f"view {k} of the flat frame is black; is it a flat (white) frame?")
        if bright >= _CLIP_LEVEL:
            raise InvalidInputError(
                f"view {k} of the flat frame is clipped at full scale; take the flat with a shorter exposure"
            )
        brights.append(bright)
    return flat, brights


def check_flat_views(flat_views, masks) -> None:
    """Refuse a flat frame's views ((V, h, w[, C]), cut like the targets') that
    :func:`estimate_plane_homographies` cannot divide by: another shape than ``masks`` (V, h, w)
    bool, or a view black or clipped inside its mask. For a caller that aligns several targets
    with one flat: the flat is then judged once, as the flat, before any target."""
    _flat_luminance(flat_views, np.asarray(masks, dtype=bool))


def _check_levels(levels, h: int, w: int) -> int:
    if levels is None:
        n = 1
        while min(h, w) / 2**n >= 128:
            n += 1
        return n
    check_int(levels, "pyramid_levels", minimum=1)
    if min(h, w) / 2 ** (levels - 1) < 16:
        raise InvalidInputError(
            f"pyramid_levels={levels} would shrink the {w} x {h} px views below 16 px; use at most "
            f"{int(math.log2(min(h, w) / 16)) + 1}"
        )
    return int(levels)


def _margin(valid: np.ndarray, margin_px, have_flat: bool) -> float:
    if margin_px is not None:
        return check_number(margin_px, "margin_px", minimum=0.0)
    # The inscribed radius of the smallest valid region (the disc's radius for the ring).
    radius = min(float(cv2.distanceTransform(np.pad(m, 1).view(np.uint8), cv2.DIST_L2, 5).max()) for m in valid)
    return (_MARGIN_FLAT if have_flat else _MARGIN_NO_FLAT) * radius


def _erode(mask: np.ndarray, margin: float) -> np.ndarray:
    """Pixels farther than ``margin`` from the outside of ``mask`` (the image's border counts
    as outside)."""
    if margin <= 0:
        return mask.copy()
    dist = cv2.distanceTransform(np.pad(mask, 1).view(np.uint8), cv2.DIST_L2, 5)[1:-1, 1:-1]
    return dist > margin


def _local_mean(img: np.ndarray, weight: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian mean of ``img`` over the pixels where ``weight`` (float32) is 1."""
    num = cv2.GaussianBlur(img * weight, (0, 0), sigma)
    den = cv2.GaussianBlur(weight, (0, 0), sigma)
    return num / np.maximum(den, 1e-6)


def _check_texture(lum: np.ndarray, inner: np.ndarray) -> None:
    """Refuse views whose usable part has no texture to align on (a blank plane)."""
    for k in range(len(lum)):
        m = inner[k].astype(np.float32)
        # Light smoothing first: pixel noise alone must not count as texture.
        smooth = cv2.GaussianBlur(lum[k], (0, 0), 1.5)
        loc = _local_mean(smooth, m, 8.0)
        sel = inner[k] & (loc > 1e-6)
        level = float(np.median(loc[sel])) if sel.any() else 0.0
        if not level > 0:
            raise EstimationError(f"view {k} is black where it should show the target")
        contrast = float(np.sqrt(np.mean((smooth[sel] - loc[sel]) ** 2))) / level
        if contrast < _MIN_CONTRAST:
            raise EstimationError(
                f"view {k} shows no texture to align on (RMS local contrast {100 * contrast:.2f}%, at least "
                f"{100 * _MIN_CONTRAST:g}% needed); photograph a textured target (random speckle is best), in focus "
                "enough that its pattern survives"
            )


# ------------------------------------------------------------------------------------------------
# Phase correlation
def _pc_image(lum: np.ndarray, valid: np.ndarray, margin: float) -> np.ndarray:
    m = valid.astype(np.float32)
    hp = lum / np.maximum(_local_mean(lum, m, 6.0), 1e-6) - 1.0
    dist = cv2.distanceTransform(np.pad(valid, 1).view(np.uint8), cv2.DIST_L2, 5)[1:-1, 1:-1]
    ramp = max(margin, 4.0)
    t = np.clip((dist - margin) / ramp, 0.0, 1.0)
    win = (t * t * (3.0 - 2.0 * t)).astype(np.float32)
    if not win.sum() > 0:
        return np.zeros_like(lum)
    hp = np.where(win > 0, hp, 0.0).astype(np.float32)
    hp -= float((hp * win).sum() / win.sum())
    return hp * win


def _phase_correlation(lum, valid, inner, ref: int, margin: float):
    num, h, w = lum.shape
    # Large views are correlated at a reduced scale: the translation only needs to land ECC in
    # its basin, and a ~700 px transform is cheap.
    scale = 1
    while min(h, w) / scale > 1024:
        scale *= 2
    def down(img, mask):
        for _ in range(int(math.log2(scale))):
            img = cv2.pyrDown(img)
            mask = cv2.resize(mask.view(np.uint8), img.shape[::-1], interpolation=cv2.INTER_NEAREST).view(bool)
        return img, mask
    prepped = []
    for k in range(num):
        img, mask = down(lum[k], valid[k])
        prepped.append(_pc_image(img, mask, margin / scale))
    shifts = np.zeros((num, 2))
    response = np.ones(num)
    for k in range(num):
        if k == ref:
            continue
        (dx, dy), resp = cv2.phaseCorrelate(prepped[k], prepped[ref])
        shifts[k] = (dx * scale, dy * scale)
        response[k] = resp
    return shifts, response


# ------------------------------------------------------------------------------------------------
# ECC
def _mask_u8(mask: np.ndarray) -> np.ndarray:
    return mask.astype(np.uint8) * 255


def _ecc(template, image, t_mask, i_mask, H, motion, iters: int, eps: float, view: int, ref: int, what: str):
    warp = H.astype(np.float32) if motion == cv2.MOTION_HOMOGRAPHY else H[:2].astype(np.float32)
    try:
        cc, warp = cv2.findTransformECCWithMask(
            template, image, _mask_u8(t_mask), _mask_u8(i_mask), warp, motion,
            (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, iters, eps), _ECC_SMOOTHING,
        )
    except cv2.error as exc:
        msg = str(exc).strip().splitlines()[-1] if str(exc).strip() else "OpenCV error"
        raise EstimationError(
            f"view {view}: ECC alignment onto view {ref} did not converge ({what}; OpenCV: {msg}); check that the "
            "target is textured and fills the views, or try method='sift'"
        ) from None
    out = np.eye(3)
    out[: warp.shape[0]] = warp
    if not np.all(np.isfinite(out)) or abs(out[2, 2]) < 1e-12:
        raise EstimationError(f"view {view}: ECC alignment onto view {ref} diverged ({what})")
    return out / out[2, 2], float(cc)


def _align_ecc(tmpl, image, t_mask, i_mask, h0, model, levels, view, ref):
    """ECC of view ``tmpl`` onto reference ``image``: coarse to fine, then one gain-compensated
    pass at full resolution. Returns (H_ref_from_view, correlation, residual_px)."""
    motion = _ECC_MOTION[model]
    pyramid = [(tmpl, image, t_mask, i_mask)]
    for _ in range(1, levels):
        t, i, tm, im = pyramid[-1]
        # pyrDown keeps pixel centres at x_fine = 2 x_coarse, so H scales by diag(s, s, 1).
        pyramid.append((cv2.pyrDown(t), cv2.pyrDown(i), _down_mask(tm), _down_mask(im)))
    H = h0.copy()
    # The full-resolution level is left to the gain-compensated pass (a plain pass there first
    # changes nothing but the time), unless it is the only level.
    for lev in range(levels - 1, 0 if levels > 1 else -1, -1):
        s = 0.5**lev
        S, Si = np.diag([s, s, 1.0]), np.diag([1 / s, 1 / s, 1.0])
        t, i, tm, im = pyramid[lev]
        if tm.sum() < 64 or im.sum() < 64:
            continue  # too coarse a level for the masks: start finer
        Hl, _ = _ecc(t, i, tm, im, S @ H @ Si, motion, 50, 1e-6, view, ref, f"pyramid level {lev}")
        H = Si @ Hl @ S
        H /= H[2, 2]
    # Gain pass: divide the reference by its smooth gain relative to the aligned view.
    radius = float(cv2.distanceTransform(np.pad(i_mask, 1).view(np.uint8), cv2.DIST_L2, 5).max())
    sigma = max(4.0, radius / 22.0)
    warped, overlap = _warp_into(tmpl, t_mask, H, i_mask)
    _check_overlap(overlap, i_mask, view, ref)
    m = overlap.astype(np.float32)
    num = cv2.GaussianBlur(image * warped * m, (0, 0), sigma)
    den = cv2.GaussianBlur(warped * warped * m, (0, 0), sigma)
    ok = den > 1e-3 * float(den.max())
    gain = np.where(ok, num / np.where(ok, den, 1.0), 1.0)
    corrected = (image / np.clip(gain, 0.2, 5.0)).astype(np.float32)
    H, cc = _ecc(tmpl, corrected, t_mask, i_mask, H, motion, 20, 1e-7, view, ref, "gain-compensated pass")
    _check_drift(H, h0, t_mask, view, ref)
    warped, overlap = _warp_into(tmpl, t_mask, H, i_mask)
    _check_overlap(overlap, i_mask, view, ref)
    residual = _tile_residual(corrected, warped, overlap, radius)
    return H, cc, residual


def _down_mask(mask: np.ndarray) -> np.ndarray:
    """The coarse pixels whose whole pyrDown footprint is valid."""
    return cv2.pyrDown(mask.astype(np.float32)) > 0.999


def _warp_into(tmpl, t_mask, H, i_mask):
    """View ``tmpl`` resampled in the reference frame, and where that is valid in both."""
    h, w = i_mask.shape
    warped = cv2.warpPerspective(tmpl, H, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    wm = cv2.warpPerspective(_mask_u8(t_mask), H, (w, h), flags=cv2.INTER_NEAREST, borderValue=0) > 127
    return warped, wm & i_mask


def _check_overlap(overlap, i_mask, view, ref) -> None:
    if overlap.sum() < 0.05 * i_mask.sum() or overlap.sum() < 1024:
        raise EstimationError(
            f"view {view}: after alignment it overlaps view {ref} on only {int(overlap.sum())} px; the alignment "
            "failed or the views do not see the same part of the target"
        )


def _check_drift(H, h0, t_mask, view, ref) -> None:
    """ECC refines the phase correlation's translation; a result that moves the middle of the
    view far from it has run off to a wrong optimum."""
    ys, xs = np.nonzero(t_mask)
    c = np.array([xs.mean(), ys.mean(), 1.0])
    a, b = H @ c, h0 @ c
    drift = float(np.hypot(*(a[:2] / a[2] - b[:2] / b[2])))
    if drift > _MAX_ECC_DRIFT_PX:
        raise EstimationError(
            f"view {view}: ECC moved {drift:.1f} px away from the phase correlation's estimate (at most "
            f"{_MAX_ECC_DRIFT_PX:g} px expected); the alignment onto view {ref} is not trustworthy, try method='sift'"
        )


def _tile_residual(ref_img, warped, overlap, radius) -> float:
    """RMS over square regions of the overlap of the shift that still aligns ``warped`` onto
    ``ref_img`` best (one Lucas-Kanade step with gain and offset, which is exact to first
    order for the sub-pixel shifts left after ECC)."""
    a = cv2.GaussianBlur(ref_img, (0, 0), 1.0)
    b = cv2.GaussianBlur(warped, (0, 0), 1.0)
    gx = cv2.Sobel(b, cv2.CV_32F, 1, 0, ksize=3, scale=1 / 8)
    gy = cv2.Sobel(b, cv2.CV_32F, 0, 1, ksize=3, scale=1 / 8)
    valid = cv2.erode(overlap.view(np.uint8), np.ones((5, 5), np.uint8)).view(bool)
    tile = max(16, int(round(radius / 5)))
    h, w = overlap.shape
    shifts = []
    for y0 in range(0, h - tile + 1, tile):
        for x0 in range(0, w - tile + 1, tile):
            sl = np.s_[y0 : y0 + tile, x0 : x0 + tile]
            m = valid[sl]
            if m.mean() < 0.9:
                continue
            A = np.stack([b[sl][m], np.ones(int(m.sum()), np.float32), gx[sl][m], gy[sl][m]], axis=1).astype(np.float64)
            sol, *_ = np.linalg.lstsq(A, a[sl][m].astype(np.float64), rcond=None)
            if abs(sol[0]) < 1e-6:
                continue
            shifts.append(sol[2:] / sol[0])
    if len(shifts) < 4:
        return float("nan")
    d = np.asarray(shifts)
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


def local_shifts(reference, image, valid, *, tile_px: int, smoothing_px=(2.5, 1.0), iterations: int = 8):
    """Where each square tile of ``reference`` lies in ``image``: the shift d with
    ``reference(x) ~ g image(x + d) + o`` over the tile (Lucas-Kanade with gain and offset,
    iterated to convergence, coarse to fine over the smoothings).

    Parameters
    ----------
    reference, image : (h, w) float32
        Two images of one textured plane in one pixel frame (``image`` warped into the
        reference's frame by a near-correct transform).
    valid : (h, w) bool
        Where both are valid; only tiles entirely inside (after a 3 px erosion) are measured.
    tile_px : int
        Side of the tiles, which tile the image without overlap.
    smoothing_px : sequence of float
        Gaussian prefilters, widest first: the wide one widens the basin (shifts of a few
        pixels converge), the last sets the precision.
    iterations : int
        Most Gauss-Newton steps per smoothing.

    Returns
    -------
    centres : (N, 2) float64
        (x, y) of each measured tile's centre.
    shifts : (N, 2) float64
        Its shift d in pixels; where a tile did not converge (or ran more than a quarter of
        its side away) it is left out.
    """
    from scipy.ndimage import map_coordinates

    tile = check_int(tile_px, "tile_px", minimum=8)
    ok_mask = cv2.erode(valid.view(np.uint8), np.ones((7, 7), np.uint8)).view(bool)
    h, w = reference.shape
    starts = np.array([(x0, y0) for y0 in range(0, h - tile + 1, tile) for x0 in range(0, w - tile + 1, tile)
                       if ok_mask[y0 : y0 + tile, x0 : x0 + tile].all()], dtype=np.float64).reshape(-1, 2)
    n = len(starts)
    half = (tile - 1) / 2.0
    d = np.zeros((n, 2))
    good = np.ones(n, bool)
    # Every tile at once: a patch one pixel wider on each side (central differences) per tile.
    grid = np.arange(-1, tile + 1, dtype=np.float64)
    for sg in smoothing_px:
        a = cv2.GaussianBlur(reference, (0, 0), sg)
        b = cv2.GaussianBlur(image, (0, 0), sg).astype(np.float64)
        iy = starts[:, 1, None].astype(int) + np.arange(tile)[None, :]
        ix = starts[:, 0, None].astype(int) + np.arange(tile)[None, :]
        ref = a[iy[:, :, None], ix[:, None, :]].astype(np.float64).reshape(n, -1)
        active = good.copy()
        for _ in range(iterations):
            if not active.any():
                break
            idx = np.nonzero(active)[0]
            ys = starts[idx, 1, None, None] + d[idx, 1, None, None] + grid[None, :, None]
            xs = starts[idx, 0, None, None] + d[idx, 0, None, None] + grid[None, None, :]
            ys, xs = np.broadcast_arrays(ys, xs)
            p = map_coordinates(b, [ys.ravel(), xs.ravel()], order=1, mode="nearest").reshape(ys.shape)
            patch = p[:, 1:-1, 1:-1].reshape(len(idx), -1)
            gx = (0.5 * (p[:, 1:-1, 2:] - p[:, 1:-1, :-2])).reshape(len(idx), -1)
            gy = (0.5 * (p[:, 2:, 1:-1] - p[:, :-2, 1:-1])).reshape(len(idx), -1)
            A = np.stack([patch, np.ones_like(patch), gx, gy], axis=2)  # (m, T*T, 4)
            At = A.transpose(0, 2, 1)
            normal = At @ A
            rhs = (At @ ref[idx][..., None])[..., 0]
            ok = np.abs(np.linalg.det(normal)) > 1e-12
            sol = np.zeros((len(idx), 4))
            sol[ok] = np.linalg.solve(normal[ok], rhs[ok][..., None])[..., 0]
            ok &= np.abs(sol[:, 0]) > 1e-6
            step = np.zeros((len(idx), 2))
            step[ok] = sol[ok, 2:] / sol[ok, :1]
            d[idx] += step
            bad = ~ok | ~np.all(np.isfinite(d[idx]), axis=1) | (np.hypot(*d[idx].T) > tile / 4)
            good[idx[bad]] = False
            active[idx[bad | (np.hypot(*step.T) < 1e-4)]] = False
    centres = starts[good] + half
    return centres.reshape(-1, 2), d[good].reshape(-1, 2)


# ------------------------------------------------------------------------------------------------
# SIFT
_SIFT_MAX_FEATURES = 4000
_SIFT_RATIO = 0.8
_SIFT_RANSAC_PX = 1.0
_SIFT_MIN_INLIERS = 20


def _to_u8(img: np.ndarray, mask: np.ndarray) -> np.ndarray:
    lo, hi = np.percentile(img[mask], [0.5, 99.5])
    if not hi > lo:
        hi = lo + 1e-6
    return np.clip((img - lo) * (255.0 / (hi - lo)), 0, 255).astype(np.uint8)


def _align_sift(tmpl, image, t_mask, i_mask, h0, model, levels, view, ref):
    """SIFT matches of view ``tmpl`` onto reference ``image`` gated by the phase correlation, then
    RANSAC and least squares; at full resolution (``levels`` is ECC's alone). Returns
    (H_ref_from_view, inlier fraction, residual_px)."""
    sift = cv2.SIFT_create(nfeatures=_SIFT_MAX_FEATURES)
    kt, dt = sift.detectAndCompute(_to_u8(tmpl, t_mask), _mask_u8(t_mask))
    ki, di = sift.detectAndCompute(_to_u8(image, i_mask), _mask_u8(i_mask))
    if dt is None or di is None or len(kt) < _SIFT_MIN_INLIERS or len(ki) < _SIFT_MIN_INLIERS:
        raise EstimationError(
            f"view {view}: SIFT found too few keypoints ({0 if dt is None else len(kt)} and "
            f"{0 if di is None else len(ki)} in view {ref}); the target needs more texture, or use method='ecc'"
        )
    matches = cv2.BFMatcher(cv2.NORM_L2).knnMatch(dt, di, k=2)
    src, dst = [], []
    # Matches must agree with the phase correlation's translation to within a generous gate:
    # a random-speckle target repeats similar blobs, and the gate removes the far mismatches.
    gate = max(8.0, 0.02 * max(tmpl.shape))
    for pair in matches:
        if len(pair) < 2 or pair[0].distance >= _SIFT_RATIO * pair[1].distance:
            continue
        p = np.array(kt[pair[0].queryIdx].pt)
        q = np.array(ki[pair[0].trainIdx].pt)
        if np.hypot(*(p + h0[:2, 2] - q)) <= gate:
            src.append(p)
            dst.append(q)
    if len(src) < _SIFT_MIN_INLIERS:
        raise EstimationError(
            f"view {view}: only {len(src)} SIFT matches with view {ref} agree with the phase correlation "
            f"(at least {_SIFT_MIN_INLIERS} needed); the target needs more texture, or use method='ecc'"
        )
    src = np.asarray(src, np.float64)
    dst = np.asarray(dst, np.float64)
    if model == "homography":
        H, inl = cv2.findHomography(src, dst, cv2.USAC_MAGSAC, _SIFT_RANSAC_PX, maxIters=5000, confidence=0.9999)
        if H is not None:
            keep = inl.ravel().astype(bool)
            if keep.sum() >= _SIFT_MIN_INLIERS:
                # Least squares on the inliers (MAGSAC++ weights them by their residual).
                H2, _ = cv2.findHomography(src[keep], dst[keep], 0)
                H = H2 if H2 is not None else H
    elif model == "affine":
        A, inl = cv2.estimateAffine2D(src, dst, method=cv2.USAC_MAGSAC, ransacReprojThreshold=_SIFT_RANSAC_PX,
                                      maxIters=5000, confidence=0.9999)
        H = None if A is None else np.vstack([A, [0.0, 0.0, 1.0]])
        if H is not None:
            keep = inl.ravel().astype(bool)
            if keep.sum() >= _SIFT_MIN_INLIERS:
                sol, *_ = np.linalg.lstsq(np.column_stack([src[keep], np.ones(keep.sum())]), dst[keep], rcond=None)
                H = np.vstack([sol.T, [0.0, 0.0, 1.0]])
    else:
        d = dst - src
        med = np.median(d, axis=0)
        keep = np.hypot(*(d - med).T) <= _SIFT_RANSAC_PX
        inl = keep
        H = np.eye(3)
        H[:2, 2] = d[keep].mean(axis=0) if keep.any() else med
    if H is None:
        raise EstimationError(f"view {view}: RANSAC found no consistent transform onto view {ref} among {len(src)} SIFT matches")
    keep = np.asarray(inl).ravel().astype(bool)
    if keep.sum() < _SIFT_MIN_INLIERS:
        raise EstimationError(
            f"view {view}: only {int(keep.sum())} SIFT matches onto view {ref} are consistent (at least "
            f"{_SIFT_MIN_INLIERS} needed); the target needs more texture, or use method='ecc'"
        )
    H = np.asarray(H, np.float64)
    H /= H[2, 2]
    proj = np.column_stack([src[keep], np.ones(keep.sum())]) @ H.T
    err = proj[:, :2] / proj[:, 2:] - dst[keep]
    residual = float(np.sqrt(np.mean(np.sum(err * err, axis=1))))
    _check_drift(H, h0, t_mask, view, ref)
    return H, float(keep.sum() / len(src)), residual


#: The alignment methods by name, each ``(view, reference, view mask, reference mask, initial H,
#: model, pyramid levels, view index, reference index) -> (H_ref_from_view, correlation,
#: residual_px)``.
METHODS = Registry("method")
METHODS.register("ecc", _align_ecc)
METHODS.register("sift", _align_sift)
