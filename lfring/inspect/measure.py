"""The check at a working plane: which pixels lie on it, which regions leave it, and the verdict.

An inspection line images parts at a known distance. :func:`inspect_frame` takes the views of
one frame and

* highlights the **working plane**: pixels that are photo-consistent when the views are warped
  to the plane's depth (their spread across the views is small next to the local contrast,
  :func:`photo_consistency`);
* measures the **deviation** of every confident pixel from the plane (or from a reference depth
  map) with a plane sweep over a narrow band of depths around it (:func:`default_depth_band`),
  and flags connected regions of confident pixels deviating by more than the tolerance as
  **defects**;
* finds the **part** (the pixels whose surface lies near the plane, confident or not) and the
  **coverage**, the fraction of it actually checked with confident depth;
* returns an :class:`~lfring.inspect.records.InspectionResult` (the verdict 'pass', 'fail' or
  'cannot_judge' with its reason, the coverage, the :class:`~lfring.inspect.records.Defect`
  records, the masks and maps behind them, the refocused image): nothing passes that was not
  checked. :mod:`lfring.inspect.draw` draws it, :mod:`lfring.inspect.reporting` reports it.

Sign convention: a deviation is the **target depth minus the measured depth**, so it is
positive towards the camera (a bump, like :class:`lfring.synth.Bump` heights) and negative
away from it (a dent).

Physics: the ring's baseline is small. At 0.3 m on the 2 x 2 binned prototype one pixel of
disparity between neighbouring views is about 24 mm of depth, so a 10 mm tolerance is about
0.4 px: the sweep is sampled at :data:`STEP_PX` of view motion and refined to sub-pixel, and
only confident pixels (textured, seen alike by the views) can raise an alarm.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import cv2
import numpy as np

from lfring.errors import InvalidInputError, LfringError, LfringWarning, warn_caller
from lfring.depth.costs.lcn import LCN_AGGREGATE_PX
from lfring.depth.plan import sweep_masks
from lfring.depth.selection import DepthResult
from lfring.calibration.model import view_motion_px
from lfring.depth.hypotheses import check_depth_range, depth_hypotheses
from lfring.core.geometry import check_reference
from lfring.core.validate import check_fraction, check_int, check_number, is_integer
from lfring.core.viewstack import TAPER, WEIGHT_FLOOR, check_views
from lfring.core.filters import normalised_luminance
from lfring.core.warping import warp_views
from lfring.inspect.records import Defect, InspectionResult
from lfring.core.protocols import check_calibration

__all__ = [
    "DARK_LEVEL", "MARGIN_PX", "MIN_CONFIDENCE_TWO_VIEWS", "MIN_COVERAGE", "MIN_PART_FRACTION", "MIN_TEXTURED_FRACTION",
    "OFF_PLANE_SHARE", "PART_OPENING_PX", "PART_RIM_PX", "PHOTO_MIN_CONTRAST", "BAND_END_REACH_PX", "MIN_TOLERANCE_PX", "STEP_PX", "VERDICTS", "default_depth_band", "inspect_frame",
    "photo_consistency",
]

#: Spacing of the depth hypotheses, in pixels of view motion (the sweep refines below it).
STEP_PX = 0.25
#: Half-width of the default band beyond the deviations it must see, in pixels of view motion:
#: the sweep's confidence compares the best cost with the best one at least 1 px away, which
#: needs hypotheses on both sides of every depth of interest.
MARGIN_PX = 1.5
#: A defect whose region (its holes filled), grown by this many pixels, holds pixels at its side's
#: end of the band reaches beyond it: the depths there are the band's end, not the surface's. One
#: pixel: a far surface beside a part's edge (the belt) must not mark a dent at that edge.
BAND_END_REACH_PX = 1
#: A tolerance below this many pixels of view motion at the plane draws a warning: the twin's flat
#: targets, judged on their own plane, raise false defects from about 0.1-0.2 px (their depth noise
#: at the views' rims), and pass from about 0.4 px.
MIN_TOLERANCE_PX = 0.25


# -- validation -----------------------------------------------------------------------------------
def _positive(value, name: str, what: str = "a positive distance in metres") -> float:
    """``value`` as a float > 0 (finite), else an error naming ``name``."""
    return check_number(value, name, above=0.0, what=what)


def _check_roi(roi, shape_hw) -> tuple[int, int, int, int] | None:
    if roi is None:
        return None
    h, w = shape_hw
    try:
        vals = tuple(roi)
    except TypeError:
        raise InvalidInputError(f"roi must be (x, y, w, h) in pixels of the reference frame, got {roi!r}") from None
    if len(vals) != 4 or not all(is_integer(v) for v in vals):
        raise InvalidInputError(f"roi must be four integers (x, y, w, h) in pixels of the reference frame, got {roi!r}")
    x, y, rw, rh = (int(v) for v in vals)
    if rw < 1 or rh < 1:
        raise InvalidInputError(f"roi width and height must be at least 1 px, got {rw} x {rh}")
    if x < 0 or y < 0 or x + rw > w or y + rh > h:
        raise InvalidInputError(
            f"roi (x={x}, y={y}, w={rw}, h={rh}) does not fit inside the {w} x {h} px reference frame; "
            f"x + w must be <= {w} and y + h <= {h}"
        )
    return x, y, rw, rh


def _check_reference_depth(ref_depth, shape_hw, z0: float) -> np.ndarray:
    arr = np.asarray(ref_depth)
    if not np.issubdtype(arr.dtype, np.floating):
        raise InvalidInputError(f"reference_depth_m must be a float map in metres (NaN where unknown), got dtype {arr.dtype}")
    if arr.shape != tuple(shape_hw):
        raise InvalidInputError(
            f"reference_depth_m must have the reference frame's shape (h, w) = {tuple(shape_hw)}, got {arr.shape}; "
            "it must be a depth map in the same frame (reference view) as the inspection"
        )
    finite = np.isfinite(arr)
    if not finite.any():
        raise InvalidInputError("reference_depth_m has no finite depth")
    if np.any(arr[finite] <= z0):
        raise InvalidInputError(
            f"reference_depth_m must lie beyond the calibration's depth origin z0 = {z0:.4g} m (metres, not mm?); "
            f"got a minimum of {float(arr[finite].min()):.4g}"
        )
    return arr.astype(np.float32)


# -- band -----------------------------------------------------------------------------------------
def _motion_per_inv(calibration, depth_m: float) -> float:
    """View motion in pixels per unit of 1/(Z - z0) near ``depth_m`` (the maps are affine in it)."""
    z0 = calibration.depth_origin_m
    z1, z2 = depth_m * 0.98, depth_m * 1.02
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)
        move = view_motion_px(calibration, [z1, z2], calibration.layout.view_shape)
    return move / abs(1.0 / (z1 - z0) - 1.0 / (z2 - z0))


def _tolerance_inv(z0: float, depth_m: float, tolerance_m: float) -> float:
    """A tolerance at ``depth_m`` in disparity: the change of 1/(Z - z0) it makes there."""
    return abs(1.0 / (depth_m - z0) - 1.0 / (depth_m + tolerance_m - z0))


def default_depth_band(calibration, near_m: float, far_m: float, tolerance_m: float) -> tuple[float, float]:
    """The depths a sweep searches to judge surfaces between ``near_m`` and ``far_m``.

    The band reaches, on either side, four tolerances or one pixel of view motion (whichever
    is larger) plus :data:`MARGIN_PX` pixels of view motion, measured in disparity
    (1/(Z - z0)), so that deviations well beyond the tolerance are measured, not clipped, and
    the sweep's confidence has hypotheses on both sides to compare with.

    Returns
    -------
    (zmin_m, zmax_m) : floats, metres
    """
    z0 = calibration.depth_origin_m
    k = _motion_per_inv(calibration, 0.5 * (near_m + far_m))
    if not k > 0.0:  # so far that the views do not move at all around it (in float)
        raise InvalidInputError(f"the views do not move at all between depths around {far_m:g} m: no depth can be told "
                                f"there{calibration.millimetres_hint(near_m, far_m)}")
    inv_near, inv_far = 1.0 / (near_m - z0), 1.0 / (far_m - z0)
    tol_inv = _tolerance_inv(z0, near_m, tolerance_m)
    reach = max(4.0 * tol_inv, 1.0 / k) + MARGIN_PX / k
    inv_lo = inv_far - reach
    if inv_lo <= 0 and inv_far - (1.0 + MARGIN_PX) / k > 0:  # the tolerance's reach alone passes infinity
        raise InvalidInputError(
            f"tolerance_m {tolerance_m:g} m is too large for a surface at {far_m:g} m: the band searched reaches four "
            f"tolerances beyond it, past infinity; give a smaller tolerance_m (in metres)")
    if inv_lo <= 0:
        words = (f"the depth band around {far_m:g} m reaches infinity: the views move {k * inv_far:.2g} px between "
                 f"{far_m:g} m and infinity, and the search needs {k * reach:.2g} px of motion on either side of a surface")
        hint = calibration.millimetres_hint(far_m)
        if hint:
            words += hint
        else:
            words += "; this calibration cannot judge a surface that far (a nearer plane or a finer binning can)"
        raise InvalidInputError(words + "; for very far surfaces give zmin_m and zmax_m explicitly")
    return float(z0 + 1.0 / (inv_near + reach)), float(z0 + 1.0 / inv_lo)


def _aligned_band(calibration, near_m, far_m, tolerance_m, num_planes=None) -> tuple[float, float, int]:
    """The default band with its hypotheses placed so that one falls on the middle of
    [near_m, far_m] in disparity (on the plane itself for a plane): a good part then sits on
    a hypothesis instead of between two, where the sweep's sub-hypothesis refinement is
    weakest. Returns (zmin_m, zmax_m, number of hypotheses)."""
    z0 = calibration.depth_origin_m
    lo, hi = default_depth_band(calibration, near_m, far_m, tolerance_m)
    inv_lo, inv_hi = 1.0 / (hi - z0), 1.0 / (lo - z0)
    inv_mid = 0.5 * (1.0 / (near_m - z0) + 1.0 / (far_m - z0))
    k = _motion_per_inv(calibration, 0.5 * (near_m + far_m))
    if num_planes is None:
        half = int(np.ceil(max(inv_hi - inv_mid, inv_mid - inv_lo) * k / STEP_PX))
    else:
        num_planes = check_int(num_planes, "num_planes", minimum=3, hint=" (or None for the default spacing)")
        half = (num_planes - 1) // 2
    step = max(inv_hi - inv_mid, inv_mid - inv_lo) / half
    return float(z0 + 1.0 / (inv_mid + half * step)), float(z0 + 1.0 / (inv_mid - half * step)), 2 * half + 1


# -- core -----------------------------------------------------------------------------------------
#: Below this local variance of the locally normalised luminance a pixel is untextured
#: (:func:`photo_consistency`'s default ``min_contrast``).
PHOTO_MIN_CONTRAST = 1e-3


def photo_consistency(views, calibration, depth_m: float, *, reference="center", window_px: int = 9,
                      min_contrast: float = PHOTO_MIN_CONTRAST) -> np.ndarray:
    """Spread of the views warped to ``depth_m`` relative to the local contrast.

    Parameters
    ----------
    views : (V, h, w, C) float32
    calibration : RingCalibration
    depth_m : float
    reference : 'center' or int
    window_px : int
        Side of the box over which spread and contrast are averaged.
    min_contrast : float
        Below this local variance of the (locally normalised) luminance a pixel is untextured
        and gets NaN: its consistency says nothing about its depth.

    Returns
    -------
    (h, w) float32
        ``box(var_k L_k) / box_var(mean_k L_k)``, with ``L_k`` the warped, locally normalised
        luminances; NaN where fewer than two views see the pixel or it is untextured.
    """
    return _consistency(views, calibration, depth_m, reference=reference, window_px=window_px,
                        min_contrast=min_contrast)[0]


def _consistency(views, calibration, depth_m: float, *, reference="center", window_px: int = 9,
                 min_contrast: float = PHOTO_MIN_CONTRAST) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`photo_consistency`, the local contrast ((h, w) float32) and the number of views
    that see each pixel at ``depth_m`` ((h, w) int)."""
    arr = np.asarray(views)
    masks = sweep_masks(calibration, arr.shape[1:3], SWEEP_RIM_TAPER)  # the views that see a pixel, as the sweep counts them
    lum = normalised_luminance(arr, masks)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)
        hs = calibration.homographies(depth_m, reference=reference)
    warped, wts = warp_views(lum[..., None], hs, masks=masks)
    warped = warped[..., 0]
    valid = wts > 0.5
    n = valid.sum(axis=0)
    vals = warped / np.maximum(wts, WEIGHT_FLOOR)
    mean = (vals * valid).sum(axis=0) / np.maximum(n, 1)
    spread = (((vals - mean) ** 2) * valid).sum(axis=0) / np.maximum(n - 1, 1)
    k = (window_px, window_px)
    spread = cv2.boxFilter(spread.astype(np.float32), -1, k)
    mean = mean.astype(np.float32)
    contrast = cv2.boxFilter(mean * mean, -1, k) - cv2.boxFilter(mean, -1, k) ** 2
    out = spread / np.maximum(contrast, 1e-12)
    out[(n < 2) | (contrast < min_contrast)] = np.nan
    return out.astype(np.float32), contrast.astype(np.float32), n


def _target(plane_m: float, reference_depth) -> np.ndarray | float:
    return plane_m if reference_depth is None else reference_depth


# The plane sweep's settings here, chosen on benchmarks/bench_inspect.py's parts (the figures are
# in benchmarks/RESULTS.md, "Inspection"). Pixels seen by only two views form a ring around the
# part: judged like the others they gave confident false defects near the frame's edges, and none
# once they must be more confident (MIN_CONFIDENCE_TWO_VIEWS), and judging them checks much more
# of a good part. ZNCC with guided aggregation found the same defects, several times slower.
SWEEP_COST = "lcn"
SWEEP_AGGREGATION = "box"
# The local sweep (winner-take-all per pixel): what these figures were measured with, and faster
# than the semi-global engine on frames of this size; its confidence says where a pixel's own cost
# curve is distinct.
SWEEP_METHOD = "local"
SWEEP_MIN_VIEWS = 2
# Each view's weight rises over the refocusing taper (TAPER, the outer part of its disc), not the
# depth default's narrower rim: with the narrower one, the dark, noisy periphery of the frame gave
# confident false defects on good parts (none with TAPER), for little more of the plate checked.
SWEEP_RIM_TAPER = TAPER
# The local sweep's aggregation window: only pixels whose whole window two views see are checked.
# Near the edge of what two views see, the window's mean over its few seen pixels gave a confident
# false dent on a good part (a test renders it); with the rule none.
SWEEP_WINDOW_PX = LCN_AGGREGATE_PX
#: Smallest sweep confidence of a pixel that only two views see for it to be checked (pixels
#: that three views or more see need ``min_confidence``).
MIN_CONFIDENCE_TWO_VIEWS = 0.9

#: Default smallest fraction of the part that must be checked with confident depth for a pass.
MIN_COVERAGE = 0.8
#: A frame whose views' 99th percentile of luminance is below this (fraction of the white
#: level) is too dark to judge: lens cap, no light, or wrong black/white levels.
DARK_LEVEL = 0.01
#: A frame whose textured pixels (see :func:`photo_consistency`'s ``min_contrast``) cover less
#: than this fraction of the region seen by two views or more is too flat to judge.
MIN_TEXTURED_FRACTION = 0.02
#: The part must cover at least this fraction of the inspected region (frame or ROI).
MIN_PART_FRACTION = 0.02
#: Radius of the opening that removes specks from the part's evidence before its holes are filled.
PART_OPENING_PX = 3
#: A defect over at least this share of the part's checked area is the part off the plane (not
#: seated, or the plane given wrong), and is said to be.
OFF_PLANE_SHARE = 0.5
#: Within this many pixels of the rim of what two views see, the evidence that finds the part
#: fades (the sweep's window and the views' taper reach past the rim; benchmarks/RESULTS.md,
#: "Inspection: the part beyond the views' common sight"): the part is continued across that
#: band from farther in, and on into what one view alone sees.
PART_RIM_PX = 16

#: The verdicts of :func:`inspect_frame`, in :attr:`InspectionResult.verdict`.
VERDICTS = ("pass", "fail", "cannot_judge")


@dataclass(frozen=True, eq=False)
class _Checked:
    """The validated arguments of :func:`inspect_frame`."""

    views: np.ndarray
    plane_m: float
    tolerance_m: float
    reference: object
    box: tuple[int, int, int, int] | None
    target: np.ndarray | None
    consistency_threshold: float
    min_coverage: float


def _check_inputs(views, calibration, *, plane_m, tolerance_m, roi, reference_depth_m, reference, min_area_px,
                  min_confidence, percentile, opening_px, consistency_threshold, min_coverage) -> _Checked:
    """Validation step of :func:`inspect_frame`: every argument checked, the bad one named."""
    arr = check_views(views, min_views=2)
    plane = _positive(plane_m, "plane_m")
    tol = _positive(tolerance_m, "tolerance_m")
    z0 = calibration.depth_origin_m
    if plane <= z0:
        raise InvalidInputError(f"plane_m ({plane:g} m) must lie beyond the calibration's depth origin z0 = {z0:.4g} m")
    if tol >= plane - z0:
        raise InvalidInputError(f"tolerance_m ({tol:g} m) must be smaller than the plane's distance from the depth origin "
                                f"z0 ({plane - z0:.4g} m, the plane at {plane:g} m): tolerances are in metres (was {tol:g} "
                                "given in mm?)")
    check_int(min_area_px, "min_area_px", minimum=1, maximum=arr.shape[1] * arr.shape[2],
              hint=f" (a defect's least area; the views hold {arr.shape[1] * arr.shape[2]} px)")
    check_fraction(min_confidence, "min_confidence")
    coverage = check_fraction(min_coverage, "min_coverage")
    check_number(percentile, "percentile", above=0.0, maximum=100.0)
    check_int(opening_px, "opening_px", minimum=0, maximum=max(arr.shape[1:3]),
              hint=" (the radius of the defects' opening, px; at most the views' larger side)")
    threshold = _positive(consistency_threshold, "consistency_threshold", "a positive ratio (spread over contrast)")
    ref = check_reference(reference, calibration.num_views)
    shape = arr.shape[1:3]
    if shape != tuple(calibration.layout.view_shape):
        raise InvalidInputError(
            f"views are {shape[1]} x {shape[0]} px but the calibration's layout cuts "
            f"{calibration.layout.view_shape[1]} x {calibration.layout.view_shape[0]} px views"
        )
    box = _check_roi(roi, shape)
    if isinstance(reference_depth_m, DepthResult):  # a golden part's estimate: its measured depths
        if reference_depth_m.reference != ref:
            raise InvalidInputError(f"reference_depth_m is a depth map in the frame of reference "
                                    f"{reference_depth_m.reference!r}, the inspection in {ref!r}")
        reference_depth_m = reference_depth_m.depth_m
    target = None if reference_depth_m is None else _check_reference_depth(reference_depth_m, shape, z0)
    return _Checked(arr, plane, tol, ref, box, target, threshold, coverage)


def _target_near_plane(calibration, chk: _Checked, zmin_m, zmax_m) -> _Checked:
    """A golden part's depth map judged where it shows the part: its depths in the band around
    the working plane (the given band, else :func:`default_depth_band`), the rest (the belt
    behind the part, the frame's corners) left out as a plane's out-of-band surfaces are."""
    if chk.target is None:
        return chk
    auto_lo, auto_hi = default_depth_band(calibration, chk.plane_m, chk.plane_m, chk.tolerance_m)
    lo = auto_lo if zmin_m is None else _positive(zmin_m, "zmin_m")
    hi = auto_hi if zmax_m is None else _positive(zmax_m, "zmax_m")
    with np.errstate(invalid="ignore"):
        near = (chk.target > lo) & (chk.target < hi)
    if not near.any():  # a map of another plane, or in mm: the band's own checks say so
        return chk
    return replace(chk, target=np.where(near, chk.target, np.float32(np.nan)).astype(np.float32))


def _plan_band(calibration, chk: _Checked, zmin_m, zmax_m, num_planes) -> tuple[float, float, int]:
    """Band-planning step of :func:`inspect_frame`: the sweep's depths (zmin_m, zmax_m, count)."""
    plane, tol, target = chk.plane_m, chk.tolerance_m, chk.target
    z0 = calibration.depth_origin_m
    calibration.check_depth(plane)  # warns when the plane is outside the calibrated range
    if target is None:
        near = far = plane
    else:
        near, far = float(np.nanmin(target)), float(np.nanmax(target))
        # A golden part's map at a plane on the range's edge straddles it by noise: only a
        # typical depth beyond the tolerance from the range is worth a warning.
        typical = float(np.nanmedian(target))
        lo, hi = calibration.valid_depth_range_m
        if typical < lo - tol or (hi is not None and typical > hi + tol):
            calibration.check_depth(typical)
    if zmin_m is not None and zmax_m is not None:
        check_depth_range(zmin_m, zmax_m)
    try:
        if zmin_m is None and zmax_m is None:
            zlo, zhi, num = _aligned_band(calibration, near, far, tol, num_planes)
            num_planes = num_planes or num
        else:
            auto_lo, auto_hi = default_depth_band(calibration, near, far, tol)
            zlo = auto_lo if zmin_m is None else _positive(zmin_m, "zmin_m")
            zhi = auto_hi if zmax_m is None else _positive(zmax_m, "zmax_m")
    except InvalidInputError as exc:
        if target is None:
            raise
        held = f"{near:g} to {far:g} m" if near != far else f"{near:g} m"
        raise InvalidInputError(f"reference_depth_m holds depths of {held}: {exc}") from None
    if not zlo < near <= far < zhi:
        what = f"the plane ({plane:g} m)" if target is None else f"the reference depths ({near:g} to {far:g} m)"
        raise InvalidInputError(f"the depth band {zlo:g} to {zhi:g} m (zmin_m, zmax_m) must contain {what} strictly")
    if zlo <= z0:
        raise InvalidInputError(f"zmin_m ({zlo:g} m) must lie beyond the calibration's depth origin z0 = {z0:.4g} m")
    if num_planes is None:
        num_planes = len(depth_hypotheses(calibration, zlo, zhi, max_step_px=STEP_PX))
    tol_px = _motion_per_inv(calibration, far) * _tolerance_inv(z0, far, tol)
    if tol_px < MIN_TOLERANCE_PX:
        warn_caller(f"tolerance_m {tol:g} m is {tol_px:.2g} px of view motion at {far:g} m, below {MIN_TOLERANCE_PX} px: "
                      "depth noise of that size (most at the views' rims) may be taken for defects; a tolerance of "
                      f"{tol * MIN_TOLERANCE_PX / tol_px:.2g} m or more is safer there")
    return zlo, zhi, int(num_planes)


def _roi_mask(box, shape_hw) -> np.ndarray:
    in_roi = np.zeros(shape_hw, bool)
    if box is None:
        in_roi[:] = True
    else:
        x, y, rw, rh = box
        in_roi[y:y + rh, x:x + rw] = True
    return in_roi


def _measure(chk: _Checked, calibration, zmin_m: float, zmax_m: float, num_planes: int, backend: str):
    """Depth step of :func:`inspect_frame`: the sweep over the band, the views refocused at the
    plane, and the photo-consistency there (with the local contrast and the views that see each
    pixel)."""
    from lfring.depth import estimate_depth
    from lfring.focus import Refocuser

    arr, ref = chk.views, chk.reference
    # The band may reach past the calibrated range around a plane at its edge: a small, smooth
    # extrapolation of the model, not worth a warning of its own (the plane's was given).
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)
        depth = estimate_depth(arr, calibration, zmin_m=zmin_m, zmax_m=zmax_m, num_planes=num_planes, reference=ref,
                               method=SWEEP_METHOD, backend=backend, cost=SWEEP_COST, aggregation=SWEEP_AGGREGATION,
                               min_views=SWEEP_MIN_VIEWS, rim_taper=SWEEP_RIM_TAPER)
        refocused = Refocuser(calibration, chk.plane_m, reference=ref, view_shape=arr.shape[1:3])(arr)
    consistency, contrast, num_views = _consistency(arr, calibration, chk.plane_m, reference=ref)
    return depth, refocused, consistency, contrast, num_views


def _checked_pixels(depth, ends, num_views, in_roi, target, *, min_confidence: float):
    """The deviation from the target (NaN out of band), the in-band pixels (a depth, at neither
    of the band's ``ends``: :func:`_band_ends`), and the reliable (checked) ones, as
    :func:`inspect_frame`'s Notes define them."""
    in_band = np.isfinite(depth.depth_m) & ~(ends[1.0] | ends[-1.0])
    dev = (target - depth.depth_m).astype(np.float32)
    dev[~in_band] = np.nan
    confident = np.where(num_views >= 3, depth.confidence >= min_confidence,
                         (num_views == 2) & (depth.confidence >= max(min_confidence, MIN_CONFIDENCE_TWO_VIEWS)))
    # The sweep aggregates over the pixels of its window that two views see: where the window
    # reaches past them, its few pixels make a distinct but unreliable cost curve.
    window = np.ones((SWEEP_WINDOW_PX, SWEEP_WINDOW_PX), np.uint8)
    whole = cv2.erode((num_views >= 2).astype(np.uint8), window, borderType=cv2.BORDER_REPLICATE).astype(bool)
    return dev, in_band, in_band & confident & whole & in_roi & np.isfinite(dev)


def _band_ends(depth) -> dict[float, np.ndarray]:
    """Per side (+1 nearer than the target, as a bump; -1 farther, a dent) the pixels whose depth
    the sweep put at that end of its band: their surface lies there or beyond."""
    n = len(depth.depths_m)
    idx = depth.hypothesis_index
    with np.errstate(invalid="ignore"):
        first, last = np.isfinite(depth.depth_m) & (idx <= 1.0), np.isfinite(depth.depth_m) & (idx >= n - 2.0)
    near_first = depth.depths_m[0] < depth.depths_m[-1]
    return {1.0: first if near_first else last, -1.0: last if near_first else first}


def _find_defects(dev, reliable, confidence, *, tol, min_area_px, opening_px, percentile,
                  footprint_mm, band_ends) -> tuple[list, np.ndarray]:
    """Deviation step of :func:`inspect_frame`: the defects (largest deviation first) and their
    pixels. A defect whose region (its holes filled, grown by :data:`BAND_END_REACH_PX`) holds at
    least ``min_area_px`` pixels at its side's end of the band (:func:`_band_ends`) reaches
    beyond the band: its deviation is a lower bound."""
    smooth = cv2.medianBlur(np.where(reliable, dev, 0.0).astype(np.float32), 5)
    deviating = np.zeros(dev.shape, bool)
    defects = []
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * opening_px + 1,) * 2) if opening_px else None
    reach = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * BAND_END_REACH_PX + 1,) * 2)
    for sign in (1.0, -1.0):
        m = (reliable & (sign * smooth > tol)).astype(np.uint8)
        if kernel is not None:
            m = cv2.morphologyEx(cv2.morphologyEx(m, cv2.MORPH_OPEN, kernel), cv2.MORPH_CLOSE, kernel)
        count, labels, stats, cents = cv2.connectedComponentsWithStats(m, connectivity=8)
        for j in range(1, count):
            area = int(stats[j, cv2.CC_STAT_AREA])
            if area < min_area_px:
                continue
            comp = labels == j
            deviating |= comp
            around = cv2.dilate(_fill_holes(comp).astype(np.uint8), reach).astype(bool)
            beyond = int((around & band_ends[sign]).sum()) >= min_area_px
            px = comp & reliable
            vals = dev[px] if px.any() else smooth[comp]
            d = float(np.percentile(np.abs(vals), percentile))
            defects.append(Defect(
                bbox_px=tuple(int(v) for v in stats[j, :4]),
                centroid_px=(float(cents[j, 0]), float(cents[j, 1])),
                area_px=area,
                area_mm2=None if footprint_mm is None else area * footprint_mm**2,
                deviation_m=sign * d,
                kind="bump" if sign > 0 else "dent",
                mean_confidence=float(confidence[comp].mean()),
                beyond_band=beyond,
            ))
    defects.sort(key=lambda dd: -abs(dd.deviation_m))
    return defects, deviating


def _fill_holes(mask: np.ndarray) -> np.ndarray:
    """``mask`` with every region of False not connected to the array's border set True."""
    from scipy import ndimage

    return ndimage.binary_fill_holes(mask)


def _find_part(plane_mask, reliable, box, *, min_area_px: int) -> np.ndarray:
    """The part: pixels whose surface lies near the working plane (see :func:`inspect_frame`'s Notes)."""
    evidence = (plane_mask | reliable).astype(np.uint8)
    if box is not None:
        x, y, rw, rh = box
        crop = np.zeros_like(evidence)
        crop[y:y + rh, x:x + rw] = evidence[y:y + rh, x:x + rw]
        evidence = crop
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * PART_OPENING_PX + 1,) * 2)
    evidence = cv2.morphologyEx(evidence, cv2.MORPH_OPEN, disc)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(evidence, connectivity=8)
    keep = np.zeros(count, bool)
    keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= min_area_px
    part = keep[labels]
    if box is None:
        return _fill_holes(part)
    x, y, rw, rh = box
    out = np.zeros_like(part)
    out[y:y + rh, x:x + rw] = _fill_holes(part[y:y + rh, x:x + rw])
    return out


def _part_beyond_sight(part, num_views, in_roi) -> np.ndarray:
    """Where the part may run on beyond what two views see: the pixels of the region of interest
    near the rim of what two views see, and beyond it those that one view alone sees, whose
    nearest pixel :data:`PART_RIM_PX` or more inside that rim is part (and that are not part
    already). No depth is measured beyond the rim and little evidence is left near it: whether
    the part covers them is not known, and nothing there was checked."""
    seen = (num_views >= 2).astype(np.uint8)
    inner = cv2.distanceTransform(seen, cv2.DIST_L2, 5) >= PART_RIM_PX
    rim = (num_views >= 1) & ~inner & in_roi & ~part
    if not (rim.any() and inner.any() and part.any()):
        return np.zeros_like(part)
    # Labels number the inner pixels in row-major order, as a boolean index lists them.
    _, labels = cv2.distanceTransformWithLabels((~inner).view(np.uint8), cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
    return rim & part[inner][labels - 1]


def _judge(views, *, in_roi, seen, textured, part, reliable, num_defects, min_coverage,
           beyond_band) -> tuple[str, float, str | None, dict]:
    """Coverage and verdict step of :func:`inspect_frame`: (verdict, coverage, reason, statistics).
    ``beyond_band``: the pixels whose depth the sweep put at an end of its band."""
    lum = views[:, ::4, ::4].mean(axis=-1)
    bright = float(np.percentile(lum, 99)) if lum.size else 0.0
    region = max(int(in_roi.sum()), 1)
    seen_px = int((seen & in_roi).sum())
    textured_fraction = float((textured & seen & in_roi).sum() / max(seen_px, 1))
    part_px = int(part.sum())
    stats = {"coverage": 0.0, "part_fraction": part_px / region, "textured_fraction": textured_fraction,
             "luminance_p99": bright}
    where = "the region of interest" if not in_roi.all() else "the frame"
    # Until a part is found, none of it is checked: the coverage is 0.
    if bright < DARK_LEVEL:
        return "cannot_judge", 0.0, (
            f"frame too dark: the views' 99th percentile of luminance is {bright:.4f} of the white level "
            f"(at least {DARK_LEVEL} needed); is the lens cap on, the light off, or are the black and white "
            "levels wrong?"), stats
    if textured_fraction < MIN_TEXTURED_FRACTION:
        return "cannot_judge", 0.0, (
            f"frame too flat: {textured_fraction:.1%} of {where} has texture (at least {MIN_TEXTURED_FRACTION:.0%} "
            "needed); depth cannot be measured on a uniform surface"), stats
    if part_px < MIN_PART_FRACTION * region:
        return "cannot_judge", 0.0, (
            f"no surface found at the working plane: {part_px / region:.1%} of {where} lies near it (at least "
            f"{MIN_PART_FRACTION:.0%} needed); check the plane's distance, the calibration and that a part is in view"), stats
    coverage = stats["coverage"] = float((reliable & part).sum() / part_px)
    if num_defects:
        return "fail", coverage, None, stats
    if coverage < min_coverage:
        far_off = stats["beyond_band_fraction"] = float((beyond_band & seen & in_roi).sum() / max(seen_px, 1))
        why = ("the rest is untextured, occluded, seen by too few views or beyond the depth band" if far_off < 0.5 else
               f"{far_off:.0%} of {where} lies beyond the depth band searched around the plane: is the part at the "
               "working plane (its distance, the calibration), or does it leave it by more than the band (zmin_m, zmax_m)?")
        return "cannot_judge", coverage, (
            f"too few confident pixels: checked {coverage:.1%} of the part, at least {min_coverage:.0%} needed "
            f"(min_coverage); {why}"), stats
    return "pass", coverage, None, stats


def inspect_frame(
    views,
    calibration,
    *,
    plane_m: float,
    tolerance_m: float,
    roi=None,
    reference_depth_m=None,
    reference="center",
    min_area_px: int = 150,
    min_confidence: float = 0.6,
    min_coverage: float = MIN_COVERAGE,
    percentile: float = 90.0,
    zmin_m: float | None = None,
    zmax_m: float | None = None,
    num_planes: int | None = None,
    opening_px: int = 2,
    consistency_threshold: float = 0.02,
    device=None,
    backend: str = "numpy",
) -> InspectionResult:
    """Check that the surface seen by the views lies on the working plane within a tolerance.

    Three verdicts: ``'pass'`` (the part was found, at least ``min_coverage`` of it checked,
    no defect), ``'fail'`` (defects) and ``'cannot_judge'`` (the frame is too dark or too flat,
    no surface lies near the plane, or too little of the part was checked): nothing passes
    unchecked.

    Parameters
    ----------
    views : (V, h, w, C) float32 in [0, 1]
        From :func:`lfring.split_views` with the calibration's layout.
    calibration : RingCalibration
    plane_m : float
        Distance of the working plane from the main lens, metres. Outside the calibrated
        range it warns (:class:`lfring.errors.LfringWarning`).
    tolerance_m : float
        Largest accepted deviation from the plane (or the reference depth), metres, > 0.
    roi : (x, y, w, h) ints, optional
        Region of interest in pixels of the reference frame; only it can raise alarms, and
        the part is looked for inside it.
    reference_depth_m : (h, w) float or DepthResult, optional
        Expected depth of every reference pixel in metres (a golden part's depth map, NaN
        where unknown; of a :class:`lfring.DepthResult`, its ``depth_m``) instead of the plane. The plane still sets the refocused image and
        the highlighted working plane.
    reference : 'center' or int
        Frame of every map and of the defects' boxes.
    min_area_px : int
        Smallest region reported as a defect (and smallest piece of the part), pixels.
    min_confidence : float in [0, 1]
        Pixels whose sweep confidence is lower (untextured, occluded, noisy) never raise an
        alarm and do not count as checked.
    min_coverage : float in [0, 1]
        Smallest fraction of the part that must be checked for a pass (default
        :data:`MIN_COVERAGE`); below it a frame without defects cannot be judged.
    percentile : float in (0, 100]
        A defect's deviation is this percentile of the absolute deviations of its pixels: a
        maximum that one noisy pixel cannot make.
    zmin_m, zmax_m : float, optional
        Depth band of the sweep; by default :func:`default_depth_band` around the plane (or
        the reference depth's range). Surfaces beyond the band (the belt behind a part, say)
        are out of band and left out: use ``roi`` and a wider band to judge them.
    num_planes : int, optional
        Hypotheses in the band (default: :data:`STEP_PX` pixels of view motion apart).
    opening_px : int
        Radius of the morphological opening (then closing) of the deviating pixels, which
        removes isolated noisy pixels and fills pinholes; 0 turns it off.
    consistency_threshold : float
        Pixels whose :func:`photo_consistency` at the plane is below it form ``plane_mask``.
    device : RingDevice, str or path, optional
        The optics (binned to the frame), for defect areas in mm^2; a built-in name or a device
        file is binned to the calibration's frames. By default the device the calibration names,
        binned to its frames (areas in pixels only when it names none, or one that does not fit
        them).
    backend : {'numpy', 'torch'}
        Of the plane sweep (:func:`lfring.estimate_depth`).

    Returns
    -------
    InspectionResult
        With ``verdict``, ``coverage`` and, when the frame cannot be judged, ``reason``.

    Raises
    ------
    InvalidInputError
        A bad value, named in the message.

    Notes
    -----
    With ``Z(x)`` the swept depth, ``c(x)`` its confidence and ``T(x)`` the target (the plane
    or ``reference_depth_m``), the deviation is ``d(x) = T(x) - Z(x)``. A pixel is reliable
    (checked), ``R(x)``, when at least three views see it and ``c >= min_confidence``, or two
    views see it and ``c >= max(min_confidence, MIN_CONFIDENCE_TWO_VIEWS)`` (two views leave
    the depth along their baseline less constrained), its depth lies strictly inside the band
    (not on its first or last hypothesis) and it is in the ROI.
    The deviation is median-filtered (5 x 5, unreliable pixels counting as 0), thresholded
    at ``+-tolerance_m`` on reliable pixels, opened and closed with a disc of radius
    ``opening_px``, and split into 8-connected components; those of at least ``min_area_px``
    pixels are defects, their deviation the ``percentile`` of ``|d|`` over their reliable
    pixels with the sign of their median. Areas in mm^2 use the pixel footprint at the plane,
    ``pitch (Z - s) / f``.

    The part is found from two kinds of evidence that the surface lies near the plane,
    confident depth or not: photo-consistency at the plane, ``q(x) < consistency_threshold``
    (the views agree there, whatever the sweep's confidence), or a reliable depth in the band
    (which reaches four tolerances and more beyond the plane, so a part off the plane is still
    found and fails)::

        E = open((q < consistency_threshold) | R) & ROI      (disc of PART_OPENING_PX)
        P = fill_holes(components of E of at least min_area_px pixels)
        coverage = |R & P| / |P|

    Holes are filled inside the frame (or the ROI): untextured patches, deep dents or holes
    beyond the band inside the part count as part and as unchecked. Pixels seen by fewer than
    two views carry no evidence and are never part of P. Where P reaches the rim of what two
    views see, it may run on beyond: the result's ``beyond_sight`` marks the pixels near that
    rim and beyond it (one view alone seeing them) that P would continue into, unchecked, and
    ``stats['beyond_sight_fraction']`` their area over P's; the verdict is P's. The verdict, in order: the frame is
    too dark (99th percentile of the views' luminance below :data:`DARK_LEVEL`), too flat
    (textured pixels on less than :data:`MIN_TEXTURED_FRACTION` of the pixels two views see)
    or ``|P|`` is below :data:`MIN_PART_FRACTION` of the region: ``'cannot_judge'`` with coverage
    0 (no part was found, and no defect is reported: there is no part it could belong to); else defects give ``'fail'``;
    else ``coverage < min_coverage`` gives ``'cannot_judge'``; else ``'pass'``.

    Examples
    --------
    The twin's parts in data/synthetic (paths relative to the repository root), a plate at
    0.3 m: ``part_defects`` carries a 15 mm bump and a 15 mm dent, ``part_good`` none:

    >>> import lfring
    >>> cal = lfring.RingCalibration.load("twin_binned2")
    >>> def views_of(path):
    ...     return lfring.split_views(lfring.demosaic(lfring.load_raw(path)), cal)
    >>> result = lfring.inspect_frame(views_of("data/synthetic/part_defects.png"), cal, plane_m=0.3, tolerance_m=0.008)
    >>> result.verdict, result.coverage > 0.9
    ('fail', True)
    >>> [(d.kind, round(d.deviation_m * 1000)) for d in result.defects]  # deviation in mm
    [('bump', 14), ('dent', -13)]
    >>> lfring.inspect_frame(views_of("data/synthetic/part_good.png"), cal, plane_m=0.3, tolerance_m=0.008).verdict
    'pass'
    """
    check_calibration(calibration)
    chk = _check_inputs(views, calibration, plane_m=plane_m, tolerance_m=tolerance_m, roi=roi,
                        reference_depth_m=reference_depth_m, reference=reference, min_area_px=min_area_px,
                        min_confidence=min_confidence, percentile=percentile, opening_px=opening_px,
                        consistency_threshold=consistency_threshold, min_coverage=min_coverage)
    chk = _target_near_plane(calibration, chk, zmin_m, zmax_m)
    zlo, zhi, num_planes = _plan_band(calibration, chk, zmin_m, zmax_m, num_planes)
    from lfring.depth.io import device_for
    from lfring.optics import RingDevice

    if device is None and calibration.device:
        try:
            device = device_for(calibration)
        except LfringError:  # an unknown device, or one of another sensor: areas in pixels
            device = None
    elif device is not None and not isinstance(device, RingDevice):
        device = device_for(calibration, device)
    footprint_mm = _footprint_mm(device, calibration, chk.plane_m)  # checks the device before the work

    depth, refocused, consistency, contrast, num_views = _measure(chk, calibration, zlo, zhi, num_planes, backend)
    with np.errstate(invalid="ignore"):
        plane_mask = consistency < chk.consistency_threshold

    # Deviation step.
    shape = chk.views.shape[1:3]
    in_roi = _roi_mask(chk.box, shape)
    ends = _band_ends(depth)
    dev, in_band, reliable = _checked_pixels(depth, ends, num_views, in_roi, _target(chk.plane_m, chk.target),
                                             min_confidence=min_confidence)
    defects, deviating = _find_defects(dev, reliable, depth.confidence, tol=chk.tolerance_m,
                                       min_area_px=min_area_px, opening_px=opening_px, percentile=percentile,
                                       footprint_mm=footprint_mm, band_ends=ends)

    # Coverage and verdict step.
    part = _find_part(plane_mask, reliable, chk.box, min_area_px=int(min_area_px))
    beyond_sight = _part_beyond_sight(part, num_views, in_roi)
    verdict, coverage, reason, judged = _judge(
        chk.views, in_roi=in_roi, seen=num_views >= 2, textured=contrast >= PHOTO_MIN_CONTRAST, part=part, reliable=reliable,
        num_defects=len(defects), min_coverage=chk.min_coverage, beyond_band=np.isfinite(depth.depth_m) & ~in_band)
    if verdict == "cannot_judge" and defects:  # no part they could belong to
        defects, deviating = [], np.zeros(shape, bool)
    checked_px = max(int((part & reliable).sum()), 1)
    whole = [d for d in defects if d.area_px >= OFF_PLANE_SHARE * checked_px]
    if whole:
        d = whole[0]
        warn_caller(f"a {d.kind} of {d.deviation_m * 1e3:+.1f} mm covers {d.area_px / checked_px:.0%} "
                      "of the part's checked area: the part itself lies off the plane (is it seated, is plane_m its "
                      "depth?), which fails it as a whole rather than as a local defect")

    # Report step.
    roi_px = max(int(in_roi.sum()), 1)
    settings = {
        "plane_m": chk.plane_m, "tolerance_m": chk.tolerance_m, "roi_px": None if chk.box is None else list(chk.box),
        "reference_depth": chk.target is not None, "reference": chk.reference, "zmin_m": zlo, "zmax_m": zhi,
        "num_planes": len(depth.depths_m), "step_px": depth.step_px, "min_area_px": int(min_area_px), "min_confidence": float(min_confidence),
        "min_coverage": chk.min_coverage, "percentile": float(percentile), "opening_px": int(opening_px),
        "consistency_threshold": chk.consistency_threshold, "pixel_footprint_mm": footprint_mm, "backend": backend,
    }
    stats = {
        "reliable_fraction": float(reliable.sum() / roi_px),
        "plane_fraction": float((plane_mask & in_roi).sum() / roi_px),
        "out_of_band_fraction": float((~in_band & in_roi).sum() / roi_px),
        "median_abs_deviation_m": float(np.median(np.abs(dev[reliable]))) if reliable.any() else None,
        **judged,
        "beyond_sight_fraction": float(beyond_sight.sum() / max(int(part.sum()), 1)),
    }
    return InspectionResult(
        verdict=verdict, coverage=coverage, reason=reason, defects=tuple(defects), plane_mask=plane_mask,
        consistency=consistency, deviation_m=dev, reliable=reliable, deviating=deviating, part=part, depth=depth,
        refocused=refocused, settings=settings, stats=stats, beyond_sight=beyond_sight,
    )


def _footprint_mm(device, calibration, depth_m: float) -> float | None:
    """Side of one reference pixel on the plane at ``depth_m`` in mm, when the optics are known."""
    if device is None:
        return None
    from lfring.optics.views import view_cameras

    if (device.sensor_width_px, device.sensor_height_px) != tuple(calibration.raw_size):
        raise InvalidInputError(
            f"device is {device.sensor_width_px} x {device.sensor_height_px} px but the calibration is for "
            f"{calibration.raw_size[0]} x {calibration.raw_size[1]} px frames; bin it to match (device.binned(k))"
        )
    cams = view_cameras(device)
    return float(device.pixel_pitch_m * (depth_m - cams.depth_origin_m) / cams.focal_m * 1e3)
