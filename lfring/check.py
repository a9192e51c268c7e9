"""Is this a ring frame for this calibration? A cheap check before refocusing or depth.

A frame of the ring camera holds four views of one scene: warped into the reference frame at
the depth of the scene they agree. An ordinary photograph at the sensor's size, a frame of
another camera or binning, or a frame read with the wrong layout has four unrelated quadrants
that agree at no depth. :func:`check_frame` measures that agreement on downsampled views at a
few depths, with the frame's exposure and how well the layout's discs fit its light. A frame
whose discs are largely clipped at the white level is over-exposed: a warning names it, and past
a larger share it is refused, whatever else the check finds, since clipped light hides the
texture that the other measures read. On the binned twin the check takes about as long as one
refocus at one depth, a fraction of the time that reading and demosaicing the frame takes.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, field

import cv2
import numpy as np

from lfring.calibration.overlap import nearest_renderable_depth_m
from lfring.core.validate import check_int, check_number
from lfring.errors import InvalidInputError, LfringWarning, warn_caller
from lfring.core.filters import luminance
from lfring.core.protocols import check_calibration

__all__ = ["AGREEMENT_THRESHOLD", "CHECK_DOWNSAMPLE", "CLIPPED_REFUSE", "CLIPPED_WARN", "DIM_LEVEL", "FLAT_TEXTURE", "MIN_DISC_CONTRAST",
           "PROCESS_ANYWAY", "ExposureWarning", "FrameCheck", "OverExposureWarning", "UnderExposureWarning", "check_frame", "draw_layout"]

AGREEMENT_THRESHOLD = 0.3
"""Smallest view agreement (the least, over the pairs of views, ZNCC of their high-passed
luminance, warped at the best of the depths tried) of a frame that is taken as a ring frame.

Chosen with the built-in calibration (tests/test_check.py asserts the separation): every
bundled frame of the twin scores well above it; ordinary RGB photographs scaled to the sensor's
size, the untextured flat frame, and the scene with its views in the wrong places (exchanged,
transposed, or each turned by 180 degrees) score near zero, well below it, so the threshold
leaves a wide margin on both sides. (A whole frame turned by 180 degrees scores as the upright
one on the twin: its ring is symmetric, so the turned views agree as well and refocus to the
turned image.)"""

CHECK_DOWNSAMPLE = 4
"""Views are reduced by this factor (area averaging) before the check."""

CHECK_MIN_SIDE_PX = 16
"""The reduced views keep at least this many pixels a side (a larger ``downsample`` is refused):
fewer hold no texture to compare."""

MIN_DISC_CONTRAST = 0.5
"""Smallest disc contrast (:attr:`FrameCheck.disc_contrast`) of a frame that is taken as a ring
frame: the ring's views are discs of light with dark between them. Every bundled frame of the
twin scores near 0.9; an image that fills the sensor (a photograph, a gradient) scores near 0,
so a frame whose views happen to agree (a smooth gradient does) is still refused."""

PROCESS_ANYWAY = "check it with 'lfring check', or pass --no-check to process it anyway"
"""What a refusal of the processing commands tells the user to do (ends the message of a frame
that is not a ring frame)."""

FLAT_TEXTURE = 0.12
"""Largest texture (:attr:`FrameCheck.texture`) of a flat field: the RMS of the views'
high-passed luminance (at the check's downsampled scale) over their mean luminance, inside the
discs. Flat frames of the twin score at most about 0.05 (noise and the falloff of the light
inside the discs, at every noise preset and binning), its scenes, targets and parts at least
about 0.25, so the threshold leaves a margin of two on each side."""

CLIPPED_LEVEL = 0.99
"""Brightness (linear luminance, white level 1) from which a pixel counts as clipped."""

DARK_LEVEL = 0.01

DIM_LEVEL = 0.1
"""99th percentile of the luminance inside the views' discs (white level 1) below which a frame
passes with an under-exposure warning (:class:`UnderExposureWarning`): depth from views that dim
reads farther than the scene by a few % (the noise, not the scene, decides between hypotheses
near the best; benchmarks/RESULTS.md, "Depth from dim frames")."""

CLIPPED_WARN = 0.05
"""Share of the views' discs clipped (:attr:`FrameCheck.clipped_fraction`) from which a frame is
over-exposed: a warning (:class:`OverExposureWarning`) says so, and the frame is still processed.
Clipped light holds no texture, so refocused images are flat white there and depth is not
measured there. Well-exposed frames clip none of their discs, or only the small highlights and
light sources of their scene, so the warning is for a frame that lost a visible part of its scene
to the exposure."""

CLIPPED_REFUSE = 0.4
"""Share of the views' discs clipped from which a frame is refused as over-exposed (reason
``'over_exposed'``, processed only with --no-check), before the check's other verdicts: as the
clipped areas spread, the views lose the texture that tells a scene from a flat field and, where
light spills between the discs, the contrast that tells discs from an image that fills the
sensor. The share is below the one where those measures start to misread an over-exposed frame
of the twin, so such a frame is refused for its exposure and not for a cause it does not have."""

MIN_TEXTURE = 1e-4
"""RMS of a view's high-passed luminance (linear, full scale 1) below which it has no texture:
well below the noise of any real frame (1e-4 is 0.4 counts of 12 bits)."""
_HIGHPASS_SIGMA_PX = 3.0  # at the downsampled scale
_MIN_SAMPLES = 200


@dataclass(frozen=True)
class FrameCheck:
    """The outcome of :func:`check_frame`.

    Attributes
    ----------
    ok : bool
        A ring frame to process: discs of light (``disc_contrast`` at least
        :data:`MIN_DISC_CONTRAST`, when measured), with texture (not a flat field), not
        over-exposed (less than :data:`CLIPPED_REFUSE` of the discs clipped), whose views agree
        as a ring frame's do (``agreement >= threshold``).
    agreement : float
        The least pairwise ZNCC of the views' high-passed luminance at ``best_depth_m``, in
        [-1, 1]: every pair of views must agree (two pairs that do, such as the columns of a
        layout read mirrored, are not enough).
    best_depth_m : float or None
        The depth tried (metres) where the views agree best.
    agreement_by_depth : dict of float to float
        Agreement at every depth tried.
    threshold : float
    size_px : (width, height)
    clipped_fraction, dark_fraction : float
        Fractions of the pixels inside the views' discs at or above 99 % of the white level, and
        at or below 1 %.
    disc_contrast : float
        ``(inside - outside) / (inside + outside)`` of the mean brightness inside the layout's
        discs and outside them: near 1 for a ring frame (dark between the discs), near 0 for
        an image that fills the sensor. NaN when the layout leaves nothing outside.
    message : str
        One line that says what was found and, when not ok, what to do.
    raw : dict
        Pattern, levels and bit depth when the check was given a RawFrame.
    reason : str
        Why the frame is not a ring frame to process: ``'no_discs'`` (the disc contrast is
        below :data:`MIN_DISC_CONTRAST`), ``'flat_field'`` (a flat (white) frame of the camera:
        discs without texture, see :data:`FLAT_TEXTURE`; told only of a whole frame, whose
        discs are seen), ``'over_exposed'`` (at least :data:`CLIPPED_REFUSE` of the discs
        clipped, or a flat field with at least :data:`CLIPPED_WARN` that shows discs: told before
        the others, which clipping misleads) or ``'views_disagree'``; ``''`` when ``ok``.
    texture : float
        The least, over the views, RMS of the high-passed luminance over the mean luminance
        inside the discs (near 0 for a flat field); NaN for a frame without light.
    fit_px, fit_depth_m : float
        How well the frame fits the calibration (``check_frame(..., measure_fit=True)``): the
        median over square tiles of the views (corrected as the calibration says) of how far each
        tile of a view still lies from its place in view 0 at the one depth that fits them best
        (``fit_depth_m``, metres), in pixels. On a frame of a plane at one depth (a target) it
        is the calibration's error there (hundredths of a pixel when the calibration fits the
        camera, tenths when it misses the lenses' distortion); on a scene it also holds the
        scene's departures from that depth. NaN when not measured.
    warning : str
        Over-exposure short of a refusal (at least :data:`CLIPPED_WARN` of the discs clipped,
        below :data:`CLIPPED_REFUSE`): what is lost and what to do, also at the end of
        ``message``; ``''`` when none.
    """

    ok: bool
    agreement: float
    best_depth_m: float | None
    agreement_by_depth: dict
    threshold: float
    size_px: tuple[int, int]
    clipped_fraction: float
    dark_fraction: float
    disc_contrast: float
    message: str
    raw: dict = field(default_factory=dict)
    reason: str = ""
    texture: float = float("nan")
    fit_px: float = float("nan")
    fit_depth_m: float = float("nan")

    warning: str = ""

    @property
    def flat_field(self) -> bool:
        """The frame is a flat (white) frame of this camera: good for a calibration's or a
        layout's flat, with no scene to refocus or measure."""
        return self.reason == "flat_field"


class ExposureWarning(LfringWarning):
    """:func:`check_frame` passed a frame whose exposure costs its results (the subclasses say how)."""


class OverExposureWarning(ExposureWarning):
    """:func:`check_frame` passed a frame with at least :data:`CLIPPED_WARN` of its discs clipped:
    the frame is processed, but its clipped areas are lost to refocusing and depth."""


class UnderExposureWarning(ExposureWarning):
    """:func:`check_frame` passed a frame whose discs' brightest pixels stay below
    :data:`DIM_LEVEL` of the white level: the frame is processed, but its noise biases depth."""


def _image_of(frame):
    """(float image (H, W, C) or None, views (V, h, w, C) or None, raw info)."""
    from lfring.io.raw import RawFrame

    if isinstance(frame, RawFrame):
        from lfring.io.demosaic import demosaic

        info = {"pattern": frame.pattern, "black_level": frame.black_level, "white_level": frame.white_level,
                "bit_depth": frame.bit_depth}
        return demosaic(frame, method="bilinear"), None, info
    if isinstance(frame, (str, os.PathLike)):
        raise InvalidInputError(f"check_frame takes the frame, not a path: lfring.load_raw({str(frame)!r})")
    arr = np.asarray(frame)
    if not np.issubdtype(arr.dtype, np.floating):
        raise InvalidInputError(f"check_frame takes a RawFrame, a float image (H, W[, C]) or views (V, h, w, C), got {arr.dtype}")
    if not np.isfinite(arr).all():
        raise InvalidInputError("check_frame: the frame contains NaN or infinite values")
    if arr.ndim == 2:
        arr = arr[..., None]
    if arr.ndim == 3:
        return arr.astype(np.float32, copy=False), None, {}
    if arr.ndim == 4:
        return None, arr.astype(np.float32, copy=False), {}
    raise InvalidInputError(f"check_frame takes (H, W[, C]) images or (V, h, w, C) views, got shape {arr.shape}")


def _small(lum: np.ndarray, f: int) -> np.ndarray:
    h, w = lum.shape[1:3]
    return np.stack([cv2.resize(x, (w // f, h // f), interpolation=cv2.INTER_AREA) for x in lum])


def _agreement(hp: np.ndarray, masks: np.ndarray, h_small: np.ndarray) -> float:
    from lfring.core.warping import warp_views

    warped, weights = warp_views(hp[..., None], h_small, masks=masks)
    common = (weights > 0.99).all(axis=0)
    if common.sum() < _MIN_SAMPLES:
        return float("nan")
    x = warped[..., 0][:, common].astype(np.float64)
    x -= x.mean(axis=1, keepdims=True)
    norm = np.linalg.norm(x, axis=1, keepdims=True)
    if np.any(norm < MIN_TEXTURE * np.sqrt(x.shape[1])):
        return 0.0  # a view without texture: nothing to agree on (rounding patterns would)
    c = (x / norm) @ (x / norm).T
    iu = np.triu_indices(len(x), 1)
    return float(c[iu].min())


def _discs(layout, f: int) -> np.ndarray:
    """(V, h // f, w // f) bool: pixels inside each view's valid disc (all True without discs)."""
    h, w = layout.view_shape
    hs, ws = h // f, w // f
    if layout.circles is None:
        return np.ones((layout.num_views, hs, ws), bool)
    yy, xx = np.mgrid[0:hs, 0:ws].astype(np.float32)
    yy, xx = (yy + 0.5) * f - 0.5, (xx + 0.5) * f - 0.5  # centres of the reduced pixels, in view pixels
    return np.stack([(xx - cx) ** 2 + (yy - cy) ** 2 <= r * r for cx, cy, r in layout.circles])


def _soft_discs(layout, f: int) -> np.ndarray:
    """Reduced valid weights: the discs shrunk by the taper of :func:`lfring.core.viewstack.view_masks`
    (its weight is 1 only there), as float32."""
    from lfring.core.viewstack import TAPER

    if layout.circles is None:
        return _discs(layout, f).astype(np.float32)
    shrunk = type(layout)(raw_width_px=layout.raw_width_px, raw_height_px=layout.raw_height_px, rects=layout.rects,
                          rotate180=layout.rotate180,
                          circles=tuple((cx, cy, r * (1 - TAPER)) for cx, cy, r in layout.circles))
    return _discs(shrunk, f).astype(np.float32)


def check_frame(frame, calibration, *, threshold: float = AGREEMENT_THRESHOLD, downsample: int | None = None,
                measure_fit: bool = False) -> FrameCheck:
    """Check that ``frame`` is a ring frame of the camera ``calibration`` describes.

    Parameters
    ----------
    frame : RawFrame, float image (H, W[, C]) in [0, 1], or views (V, h, w, C)
        A whole frame (its size is checked against the calibration, its exposure and disc fit
        measured) or views already split with the calibration's layout.
    calibration : RingCalibration
    threshold : float
        Agreement below it makes ``ok`` False (see :data:`AGREEMENT_THRESHOLD`).
    downsample : int, optional
        Views are reduced by this factor first: by default :data:`CHECK_DOWNSAMPLE`, less for
        views too small to keep :data:`CHECK_MIN_SIDE_PX` a side; a factor that keeps fewer is
        refused.
    measure_fit : bool
        Also measure how well the views fit the calibration at the best depth (``fit_px``), at
        full resolution (about as long again as the check).

    Returns
    -------
    FrameCheck

    Raises
    ------
    InvalidInputError
        The frame's size is not the calibration's, the views are not as many or as large as the
        layout cuts, the frame holds NaN or infinite values, a path was given for the frame, or
        ``downsample`` leaves the views too small.

    Warns
    -----
    OverExposureWarning
        The frame passes, but at least :data:`CLIPPED_WARN` of its discs are clipped.
    UnderExposureWarning
        The frame passes, but its discs' brightest pixels (99th percentile) stay below
        :data:`DIM_LEVEL` of the white level: its noise biases depth.

    Notes
    -----
    The depths tried are evenly spaced in disparity from half the calibration's nearest valid
    depth (no nearer than where the views stop overlapping) to twice its farthest, about
    ``downsample`` pixels of view motion apart: 7 depths for the built-in calibration.
    """
    from lfring.depth.hypotheses import depth_hypotheses
    from lfring.views import correct_views, split_views

    check_calibration(calibration)
    layout = calibration.layout
    most = max(1, min(layout.view_shape) // CHECK_MIN_SIDE_PX)
    downsample = min(CHECK_DOWNSAMPLE, most) if downsample is None else check_int(downsample, "downsample", minimum=1,
                                                                                 maximum=most)
    threshold = check_number(threshold, "threshold", minimum=-1.0, maximum=1.0, what="a ZNCC")
    image, views, info = _image_of(frame)
    if image is not None:
        calibration.check_frame(image.shape)
        lum_img = luminance(np.ascontiguousarray(np.atleast_3d(image), dtype=np.float32)[None])[0]
        lum = split_views(lum_img[..., None], layout)[..., 0]
        size = (int(image.shape[1]), int(image.shape[0]))
    else:
        calibration.check_fits(views.shape)
        size = calibration.raw_size
        lum = luminance(np.ascontiguousarray(views, dtype=np.float32))
    inside = layout.masks()
    n_in = int(np.count_nonzero(inside))
    clipped = np.count_nonzero((lum >= CLIPPED_LEVEL) & inside) / n_in if n_in else float("nan")
    sample = lum[:, ::4, ::4][inside[:, ::4, ::4]]  # the discs' brightest pixels, as recorded
    bright = float(np.percentile(sample, 99)) if sample.size else float("nan")
    dark = np.count_nonzero((lum <= DARK_LEVEL) & inside) / n_in if n_in else float("nan")
    contrast = float("nan")
    if image is not None:
        total = float(lum_img.sum(dtype=np.float64))
        n_out = image.shape[0] * image.shape[1] - n_in
        if n_in and n_out > 0:
            a = float(lum[inside].sum(dtype=np.float64))
            mean_in, mean_out = a / n_in, max(total - a, 0.0) / n_out
            contrast = (mean_in - mean_out) / (mean_in + mean_out) if mean_in + mean_out > 0 else 0.0

    if image is not None:
        # Exposure is judged on the views as recorded; agreement on the views the calibration's
        # homographies relate (its lens distortion undone, its flat field divided out).
        lum = correct_views(lum[..., None], calibration)[..., 0]
    f = downsample
    h, w = layout.view_shape
    small = _small(lum, f)
    hp = np.stack([s - cv2.GaussianBlur(s, (0, 0), _HIGHPASS_SIGMA_PX) for s in small]).astype(np.float32)
    masks = _soft_discs(layout, f)
    texture = _texture(small, hp, masks)
    scale = np.diag([(w // f) / w, (h // f) / h, 1.0])
    lo, hi = calibration.valid_depth_range_m
    hi = 4 * lo if hi is None else hi
    nearest = nearest_renderable_depth_m(calibration)
    zmin = max(lo / 2, nearest * 1.2)
    zmax = max(hi * 2, zmin * 1.5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)
        zs = depth_hypotheses(calibration, zmin, zmax, max_step_px=float(f))
        by_depth = {}
        for z in zs:
            hz = calibration.homographies(float(z), reference="center")
            by_depth[float(z)] = _agreement(hp, masks, scale @ hz @ np.linalg.inv(scale))
    finite = {z: a for z, a in by_depth.items() if np.isfinite(a)}
    if finite:
        best_z = max(finite, key=finite.get)
        agreement = finite[best_z]
    else:
        best_z, agreement = None, float("nan")
    agree = bool(np.isfinite(agreement) and agreement >= threshold)
    disagree = (f"the views do not agree at any depth from {zmin:.3g} to {zmax:.3g} m (ZNCC {agreement:.2f}, a ring "
                f"frame scores above {threshold:g})")
    how = PROCESS_ANYWAY
    clipped_share = f"{clipped:.2%} of the views' discs are clipped at the white level"
    exposure_lost = f"{clipped_share}, with no texture left there to refocus or measure depth on"
    exposure_fix = "reduce the exposure, or check the white level the frame is read with"
    warning = ""
    flat_like = np.isfinite(texture) and texture < FLAT_TEXTURE and np.isfinite(contrast)  # discs seen, without texture
    no_discs = bool(np.isfinite(contrast) and contrast < MIN_DISC_CONTRAST)
    # No discs outranks a clipped part: a photograph with a clipped sky is not a ring frame, and
    # the exposure is not what to change.
    if clipped >= CLIPPED_REFUSE or (flat_like and clipped >= CLIPPED_WARN and not no_discs):
        reason = "over_exposed"
        if clipped >= CLIPPED_REFUSE:
            message = f"over-exposed: {exposure_lost} (refused from {CLIPPED_REFUSE:.0%}); {exposure_fix}; {how}"
        else:  # what the clipping left has no texture either: a flat (white) frame, or a scene washed out
            message = (f"over-exposed: {clipped_share} (over-exposed from {CLIPPED_WARN:.0%}) and the rest of them has "
                       "no texture either: an over-exposed flat (white) frame, of no use as a flat, or a scene washed "
                       f"out by the exposure; {exposure_fix}")
    elif no_discs:
        reason = "no_discs"
        dark_too = " (or too dark to show them)" if dark > 0.9 else ""
        message = (f"no discs of light{dark_too}: the frame is as bright between the views' discs as inside them (disc "
                   f"contrast {contrast:.2f}, a ring frame's is above {MIN_DISC_CONTRAST:g}), so it is an image that "
                   "fills the sensor (an ordinary photograph, a gradient, another camera), not a frame of this ring "
                   f"camera and layout{'' if agree else '; and ' + disagree}; {how}")
    elif flat_like:
        reason = "flat_field"
        message = (f"a flat field: the views are discs of light without texture ({texture:.3f} of their mean, a scene's is "
                   f"above {FLAT_TEXTURE:g}), a flat (white) frame of this camera with no scene to refocus or measure; "
                   "use it as the flat of a calibration or a layout detection")
    elif not agree:
        reason = "views_disagree"
        message = (f"{disagree}: not a frame of this ring camera and layout (an ordinary photograph, another camera or "
                   f"binning, or a frame without texture); {how}")
    else:
        reason = ""
        message = f"the views agree (ZNCC {agreement:.2f} at {best_z:.3g} m, threshold {threshold:g}): a ring frame for this calibration"
    if reason not in ("over_exposed", "no_discs") and clipped >= CLIPPED_WARN:
        warning = f"over-exposed: {exposure_lost} (over-exposed from {CLIPPED_WARN:.0%}); {exposure_fix}"
        if message.endswith("; " + how):
            message = f"{message[:-len(how) - 2]}; and {warning}; {how}"
        else:
            message = f"{message}; but {warning}"
    ok = not reason
    dim = ok and not warning and bright < DIM_LEVEL
    if dim:
        warning = (f"under-exposed: the brightest pixels of the views' discs (99th percentile) reach {bright:.1%} of the "
                   f"white level (under-exposed below {DIM_LEVEL:.0%}): depth from views this noisy reads too far by a "
                   "few %; expose longer, or check the white level the frame is read with")
        message = f"{message}; but {warning}"
    if ok and warning:
        warn_caller(warning, UnderExposureWarning if dim else OverExposureWarning)
    fit, fit_z = _fit_px(lum, calibration, best_z) if measure_fit and ok else (float("nan"), float("nan"))
    return FrameCheck(ok=ok, agreement=agreement, best_depth_m=best_z, agreement_by_depth=by_depth,
                      threshold=threshold, size_px=size, clipped_fraction=clipped, dark_fraction=dark, disc_contrast=contrast,
                      message=message, raw=info, reason=reason, texture=texture, fit_px=fit, fit_depth_m=fit_z,
                      warning=warning)


def _texture(small: np.ndarray, hp: np.ndarray, masks: np.ndarray) -> float:
    """The least, over the views, RMS of ``hp`` over the mean of ``small`` where ``masks`` is 1."""
    out = []
    for s, h, m in zip(small, hp, masks):
        inside = m >= 1.0
        if np.count_nonzero(inside) < _MIN_SAMPLES:
            continue
        mean = float(s[inside].mean(dtype=np.float64))
        if mean <= MIN_TEXTURE:
            continue  # no light: no texture to speak of
        out.append(float(np.sqrt(np.mean(np.square(h[inside], dtype=np.float64)))) / mean)
    return min(out) if out else float("nan")


def _fit_px(lum: np.ndarray, calibration, depth_m: float) -> tuple[float, float]:
    """Median over the tiles of every view (onto view 0) of their remaining shift at the single
    depth that fits them best: measured at ``depth_m`` (a depth tried), then the depth refined
    by least squares along the views' motion with depth."""
    from lfring.calibration.planes import local_shifts

    masks = calibration.layout.masks()
    h, w = calibration.layout.view_shape
    z0 = calibration.depth_origin_m
    x = 1.0 / (depth_m - z0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)
        hs = calibration.homographies(depth_m, reference=0)
        hs2 = calibration.homographies(z0 + 1.0 / (x * 1.01), reference=0)
    centre = np.array([w / 2.0, h / 2.0])
    tile = max(16, round(min(h, w) / 22))
    shifts, motion = [], []
    for k in range(1, len(lum)):
        warped = cv2.warpPerspective(lum[k], hs[k], (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        seen = cv2.warpPerspective(masks[k].view(np.uint8), hs[k], (w, h), flags=cv2.INTER_NEAREST) > 0
        _, d = local_shifts(lum[0], warped, seen & masks[0], tile_px=tile)
        ck = np.linalg.solve(hs[k], np.append(centre, 1.0))
        a, b = hs[k] @ ck, hs2[k] @ ck
        shifts.append(d)
        motion.append(np.broadcast_to((b[:2] / b[2] - a[:2] / a[2]) / (0.01 * x), d.shape))
    if not shifts or not sum(len(d) for d in shifts):
        return float("nan"), float("nan")
    d, g = np.concatenate(shifts), np.concatenate(motion)
    # Moving the depth by dx moves view k's content by g_k dx: the dx that cancels the shifts best.
    dx = -float(np.sum(g * d)) / max(float(np.sum(g * g)), 1e-12)
    return float(np.median(np.hypot(*(d + g * dx).T))), float(z0 + 1.0 / (x + dx))


def draw_layout(image: np.ndarray, layout) -> np.ndarray:
    """The frame (float (H, W[, C]) linear light) as 8-bit sRGB with the layout drawn on it:
    each view's rectangle in yellow, its valid disc in green, its index in the corner. A layout
    that turns the frame by 180 degrees (``rotate180``) is drawn on the frame turned, as it cuts
    the views (its rectangles and view numbers are in that frame).

    Returns
    -------
    (H, W, 3) uint8 RGB
    """
    from lfring.io.writers import encode_image

    img = np.asarray(image, dtype=np.float32)
    if img.ndim == 2:
        img = img[..., None]
    if img.shape[2] == 1:
        img = np.repeat(img, 3, axis=2)
    if layout.rotate180:
        img = img[::-1, ::-1]
    out = np.ascontiguousarray(encode_image(img[..., :3], 8, "srgb"))
    thick = max(1, round(min(out.shape[:2]) / 400))
    for k, (x, y, w, h) in enumerate(layout.rects):
        cv2.rectangle(out, (x, y), (x + w - 1, y + h - 1), (255, 220, 0), thick)
        if layout.circles is not None:
            cx, cy, r = layout.circles[k]
            cv2.circle(out, (round(x + cx), round(y + cy)), round(r), (0, 255, 0), thick)
        cv2.putText(out, str(k), (x + 6 * thick, y + 30 * thick), cv2.FONT_HERSHEY_SIMPLEX, thick, (255, 220, 0), thick)
    return out
