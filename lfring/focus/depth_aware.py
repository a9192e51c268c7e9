"""Depth-aware refocusing: what the whole main-lens aperture would have recorded.

Shift-and-add shows every object away from the focus depth as V displaced copies of itself. A
lens whose aperture spans the views would show it as a smooth disc of blur instead. Given a
depth map in the reference frame, :class:`DepthOfField` renders that:

1. **The depth that was measured.** Where the depth is unknown, or fewer than
   :data:`MIN_DEPTH_VIEWS` views' worth see a pixel at its own depth (the views' disc rims, the
   frame's edge; :data:`MIN_ESTIMATED_VIEWS` for a map that depth estimation made, which says
   itself where it measured), that depth was not measured: the nearest measured pixel's surface
   is continued instead (its plane where one fits the measured depths around it,
   :mod:`lfring.focus.continuation`, else its depth), unless they agree anyway, feathered where
   two surfaces' nearest pixels meet (a step there would cut a seam across the rim).
2. **All-in-focus colour.** Every view is sampled at every reference pixel's own depth (one
   ``cv2.remap`` per view) and the views are averaged where they agree: a view whose luminance
   is far from the views' robust mean there (it sees an occluder, or a specular highlight) is
   left out (:data:`AGREE_TOL`). Every view counts by how much of it is valid there, so that a
   view fading out at its disc's rim fades out of every statistic: no seam follows the rims.
3. **The background under occlusion edges.** Where the depth map steps nearer by more than
   :data:`BACK_STEP_PX` of view motion, the farther surface is continued under the nearer one:
   its depth that of the nearest pixel across the step, its colour from the views that see it
   there (they look behind the edge from their places in the aperture), else extended from
   around. Steps 1 to 3 do not depend on the focus depth and are made once per depth map.
4. **In focus from shift-and-add.** Where the views refocused at the focus depth are aligned to
   within :data:`SHARP_PX` px and agree, the colour is the shift-and-add image itself, blending
   to the all-in-focus colour by :data:`SHARP_PX` + :data:`SHARP_RAMP_PX`: in-focus regions are
   what shift-and-add gives.
5. **Blur without layers to see.** Each pixel's signed circle-of-confusion radius
   ``rho = aperture * R * (x - x_f)``, with ``x = 1/(Z - z0)``, ``x_f`` the focus depth's and R
   from :func:`aperture_radius_px`, lies between two rungs of a ladder of radii
   (:mod:`lfring.focus.layers`). The pixel is shared between those two rungs, with weights that
   give the mixture of their blurs the second moment of its own disc (``rho^2 / 2``): the blur
   grows continuously with the depth, and no pixel is quantised to a rung. Every rung is one
   layer of premultiplied colour and coverage, blurred by its disc (on a reduced grid where the
   disc is large), and the layers are composited far to near: a layer covers ("over") what lies
   at least two rungs behind it, but adds to the rung just behind, because the two rungs around
   one pixel's radius are one surface, which does not hide itself; across a depth step of two
   rungs or more the nearer surface hides the farther one. The result is divided by the
   accumulated coverage, and where a nearer surface's soft edge leaves part of the aperture
   uncovered, the background of step 3, blurred by its own radius, fills it: through a near
   object's blurred edge the lens sees the background continue, not a hole, and what lies behind
   never covers a nearer object's sharp pixels.

The physics: view k's sampling shift at depth Z is (for the ring's translation model) affine in
x = 1/(Z - z0); a virtual viewpoint at aperture position u (the views sitting at their own
positions, u = 1) sees a point at depth Z moved by u (t_k(Z) - t_k(Z_f)) relative to the focus
plane, so a lens whose aperture is the disc through the views blurs it over a disc of radius
``R |x - x_f|`` px, R the views' mean distance (in px per unit x) from their centre. The
layers are :mod:`lfring.focus.layers`; the per-pixel passes are compiled
(:mod:`lfring.focus.depth_aware_kernels`).
"""

from __future__ import annotations

import math
import threading

import cv2
import numpy as np

from lfring.calibration.overlap import INFINITE_DEPTH_M
from lfring.calibration.ring import DEVICE_RECORD
from lfring.errors import InvalidInputError, warn_caller
from lfring.core.geometry import apply_homography, check_reference, to_reference
from lfring.core.viewstack import WEIGHT_FLOOR, cached_view_masks, check_views
from lfring.core.validate import check_number
from lfring.core.warping import translations
from lfring.depth.estimate import estimate_depth
from lfring.calibration.model import view_motion_px
from lfring.depth.selection import DepthResult
from lfring.focus.base import RefocusMethod
from lfring.focus.continuation import plane_continued
from lfring.focus.layers import COMPOSITE, NO_IMAGE, Grid, composite, ladder, sum_layers
from lfring.core.protocols import check_calibration

__all__ = [
    "AGREE_TOL", "BACK_EDGE_PX", "BACK_STEP_PX", "DEPTH_TOL_PX",
    "MIN_DEPTH_VIEWS", "MIN_ESTIMATED_VIEWS", "OCCLUSION_PX", "SHARP_PX", "SHARP_RAMP_PX", "SHARP_RESAMPLED_PX2", "SPREAD_TOL", "VISIBLE_VIEWS", "DepthOfField", "DEPTH_AWARE",
    "DERIVED_RANGE_MAX_MOTION", "FAR_MOTION_PX", "FEATHER_FLOOR", "FEATHER_PX", "MAX_BLUR_DIAGONALS", "FILL_SMOOTH_PX", "FILL_WINDOW_PX", "aperture_from_f_number", "aperture_radius_px", "check_aperture_options", "coc_radius_px", "depth_of_field", "depth_to_render", "known_depths",
    "estimation_range", "prepare_depth_aware", "resolve_aperture",
]

# Views aligned to within this many pixels of view motion at the focus depth are in focus: the
# shift-and-add image is used there, blending to the all-in-focus colour over SHARP_RAMP_PX more.
SHARP_PX = 0.5
SHARP_RAMP_PX = 1.0
# A view whose luminance at a pixel's own depth differs from the views' robust mean by more than
# AGREE_TOL (linear [0, 1] units) loses weight linearly, and none is left by twice that ...
AGREE_TOL = 0.04
# ... or by more than SPREAD_TOL times the views' rms spread about it, if that is larger: a view
# far out of a majority is left out, views that form no majority are averaged.
SPREAD_TOL = 1.0
# Views that a nearer surface hides at a pixel (by the depth map, uncertain near its steps) are
# left out of its colour once the visible views' summed weight there reaches VISIBLE_VIEWS (half
# a view); short of that they count in proportion: a view that only grazes the pixel with its
# disc's rim (where its values are darkened) does not outvote a whole view that is called hidden.
VISIBLE_VIEWS = 0.5
# A view is occluded at a reference pixel when the depth map puts a surface nearer by more than
# this many pixels of view motion onto the same view pixel.
OCCLUSION_PX = 1.0
# A step of the depth map nearer by more than BACK_STEP_PX pixels of view motion (at aperture 1)
# within BACK_EDGE_PX pixels is an occlusion edge: the farther surface is continued under the
# nearer one (the background layer). The edge is looked for over a few pixels because an
# estimated depth map's steps are not one pixel wide.
BACK_STEP_PX = 2.0
BACK_EDGE_PX = 2
# Depth estimated for a calibration without an upper bound reaches as far as the views still
# move by this many pixels from where they see infinity (estimation_range) ...
FAR_MOTION_PX = 0.5
# ... provided that, from the range's near end to there, no view moves by more than this fraction
# of the views' smaller side: the views then still share most of what they see at the near end,
# and the range is one of depths the calibration was made for. A view grid's open range starts
# where neighbouring views stop overlapping; closed that way it would hold every disparity the
# views can show (as many planes as the views are wide), not the scene's depths.
DERIVED_RANGE_MAX_MOTION = 0.5
# For calibrations that are not translations, view sampling positions are interpolated linearly
# in 1/(Z - z0) between knots this many pixels of view motion apart.
KNOT_STEP_PX = 0.25
# Pixel lists are sampled as images of this width (OpenCV's remap takes maps under 32767 wide).
LIST_ROW_PX = 1024
# The shift-and-add image is already spread by its views' bilinear resampling (second moment
# about this many px^2 besides its copies'): its share is blurred by that much less.
SHARP_RESAMPLED_PX2 = 0.08
# A depth that fewer than MIN_DEPTH_VIEWS views' worth see at a pixel was not measured there
# (depth estimation picks such depths at its range's end, where the views drift off their
# discs): the surface of the nearest pixel that enough views see is continued instead
# (lfring.focus.continuation), unless the two are within DEPTH_TOL_PX of view motion.
MIN_DEPTH_VIEWS = 2.0
DEPTH_TOL_PX = 0.5
# A depth map that depth estimation made (a DepthResult) says itself where its depth was measured
# (NaN elsewhere): there the renderer keeps it wherever this many views' worth, by the renderer's
# taper, see the pixel at that depth. The estimator counts a view by its own, wider taper, so a
# rim pixel it measured can fall short of MIN_DEPTH_VIEWS by the renderer's; a depth that few
# views see there (the views drifted off their discs at the range's end) is still continued from
# around. A renderer's rule, whatever min_views the estimate was made with (a DepthResult does not
# record it).
MIN_ESTIMATED_VIEWS = 1.5
# Where depth estimation was not confident of a pixel, the renderer takes its hole-filled depth
# if the confident depths within FILL_WINDOW_PX (an odd side, px) span at most FILL_SMOOTH_PX px
# of view motion (at aperture 1): a smooth surface, which the fill continues; elsewhere the
# estimate's own winner (at a depth edge the fill lies between the two surfaces).
FILL_SMOOTH_PX = 3.0
FILL_WINDOW_PX = 21
# The nearest measured pixel's plane (lfring.focus.continuation) is feathered by a Gaussian of
# this standard deviation (px), so that the depth continued into a rim changes smoothly where two
# surfaces' nearest pixels meet; the feathering is normalised by the continued pixels' share,
# floored at FEATHER_FLOOR.
FEATHER_PX = 8.0
FEATHER_FLOOR = 1e-3
# A render whose largest blur radius exceeds this many frame diagonals is refused: beyond the
# frame every pixel is the frame's mean, and the ladder's rungs (and their memory) go on growing
# (an aperture of 1e6 asked for 110 TB).
MAX_BLUR_DIAGONALS = 4.0


def _depth_at(x: np.ndarray, z0: float) -> np.ndarray:
    """Depths (metres) of the inverse depths ``x`` = 1 / (Z - z0); 0 (infinity, as a focus at
    --depth inf and float32 rounding of a far depth give it) is the model's limit, at the depth
    that stands for it (:data:`lfring.calibration.overlap.INFINITE_DEPTH_M`)."""
    return z0 + 1.0 / np.maximum(np.asarray(x, dtype=np.float64), 1.0 / INFINITE_DEPTH_M)


def _inverse_depth(depth_m, z0: float):
    return 1.0 / (np.asarray(depth_m, dtype=np.float64) - z0)


def aperture_radius_px(calibration, reference="center") -> float:
    """R: the views' mean distance from their centre in the aperture, in reference pixels of
    view motion per unit of 1/(Z - z0) (1/m).

    Derived from ``calibration.model`` (the motion of the reference frame's centre pixel in
    every view between two depths), so it holds for measured calibrations and view grids as
    well as for the optics model. A point at depth Z, seen by a lens focused at Z_f whose
    aperture is the disc through the views, is blurred over a disc of radius
    ``R |1/(Z - z0) - 1/(Z_f - z0)|`` px (:func:`coc_radius_px`).

    Examples
    --------
    >>> from lfring.calibration.defaults import default_calibration
    >>> cal, _ = default_calibration((2456, 1842))
    >>> round(aperture_radius_px(cal), 2)  # px of blur radius per unit of 1/(Z - z0) in 1/m
    2.2
    """
    ref = check_reference(reference, calibration.num_views)
    z0 = calibration.depth_origin_m
    x1 = 1.0 / (calibration.valid_depth_range_m[0] - z0)
    x2 = 0.5 * x1
    h, w = calibration.layout.view_shape
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    pos = []
    for x in (x1, x2):
        hs = to_reference(calibration.model(z0 + 1.0 / x), ref)
        pos.append(np.array([apply_homography(np.linalg.inv(hk), centre) for hk in hs]))
    motion = (pos[0] - pos[1]) / (x1 - x2)  # (V, 2) px per unit x
    motion -= motion.mean(axis=0)
    return float(np.linalg.norm(motion, axis=1).mean())


def coc_radius_px(calibration, depth_m, focus_m: float, *, aperture: float = 1.0, reference="center"):
    """Circle-of-confusion radius in px of points at ``depth_m`` for a lens focused at
    ``focus_m`` with ``aperture`` (1: the disc through the views): ``aperture R |x - x_f|``."""
    z0 = calibration.depth_origin_m
    r = aperture * aperture_radius_px(calibration, reference) * np.abs(_inverse_depth(depth_m, z0) - _inverse_depth(focus_m, z0))
    return float(r) if np.ndim(r) == 0 else r


def aperture_from_f_number(f_number: float, device) -> float:
    """The ``aperture`` (1 = the disc through the views) of a main lens stopped to ``f_number``.

    The main lens of focal length FL at f-number N has an entrance pupil of radius FL / (2 N).
    The views' projection centres are the images of the mini-lenses through the main lens: they
    lie at lateral distance ``|C_k|`` from the axis (:func:`lfring.optics.views.view_cameras`),
    the views' radius in the aperture. So ``aperture = FL / (2 N) / mean |C_k|``.

    Notes
    -----
    The views' centres lie at depth s (the depth origin z0), the main lens at 0; a lens aperture
    of radius A at 0 blurs a point at Z as a viewpoint disc of radius A (Z - s) / Z at s does,
    which is A to within s / Z (under 10 % beyond 10 s, 0.28 m for the prototype). The relation
    above neglects that factor. An f-number wider than the device's main lens opens (its iris,
    ``aperture_radius_m``, else its radius) is warned of: no such lens is on the camera.

    Examples
    --------
    >>> from lfring.optics import load_device
    >>> dev = load_device("prototype")
    >>> round(aperture_from_f_number(2.8, dev), 2)  # the views sit 1.1 mm from the axis, FL 16 mm
    2.57
    """
    from lfring.optics.paraxial import check_f_number
    from lfring.optics.views import view_cameras

    f_number = check_f_number(f_number)
    iris = device.aperture_radius_m if device.aperture_radius_m is not None else device.main_lens_radius_m
    own = device.main_focal_length_m / (2.0 * iris)
    if f_number < own:
        warn_caller(f"f/{f_number:g} is wider than the main lens of device '{device.name}' opens (f/{own:.2g}): the "
                    "image is of a lens this camera does not have, its blur extrapolated from the views")
    cams = view_cameras(device)
    radius = float(np.linalg.norm(cams.centres_m - cams.centres_m.mean(axis=0), axis=1).mean())
    return device.main_focal_length_m / (2.0 * float(f_number)) / radius


def _fill_from_around(planes: list, known: np.ndarray) -> list:
    """``planes`` (each (h, w) float32, valid where ``known`` > 0, ``known`` in [0, 1]) filled
    everywhere from the valid values around: a pyramid of normalised averages (push-pull),
    each level blended in where the finer one knows too little."""
    levels = [([p * known for p in planes], known)]
    while min(levels[-1][1].shape) > 2:
        prem, wt = levels[-1]
        h, w = wt.shape
        size = ((w + 1) // 2, (h + 1) // 2)
        levels.append(([cv2.resize(p, size, interpolation=cv2.INTER_AREA) for p in prem],
                       cv2.resize(wt, size, interpolation=cv2.INTER_AREA)))
    out = None
    for prem, wt in reversed(levels):
        inv = np.zeros_like(wt)
        np.divide(np.float32(1.0), wt, out=inv, where=wt > 1e-6)
        own = [p * inv for p in prem]
        if out is None:
            out = own
            continue
        h, w = wt.shape
        a = np.clip(wt, 0.0, 1.0)
        out = [o * a + cv2.resize(u, (w, h), interpolation=cv2.INTER_LINEAR) * (1.0 - a) for o, u in zip(own, out)]
    return out


def _feathered(image: np.ndarray, sigma_px: float) -> np.ndarray:
    """(h, w) float32 ``image`` blurred by a Gaussian of about ``sigma_px``: on a grid reduced so
    that the Gaussian there is about 2 px (area averaging down, bilinear up), which costs a
    fraction of the full-resolution blur and is as smooth."""
    h, w = image.shape
    f = int(sigma_px // 2)
    if f <= 1:
        return cv2.GaussianBlur(image, (0, 0), sigma_px)
    small = cv2.resize(image, (-(-w // f), -(-h // f)), interpolation=cv2.INTER_AREA)
    small = cv2.GaussianBlur(small, (0, 0), math.sqrt(max(sigma_px * sigma_px - f * f / 3.0, 0.25)) / f)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)


def _remap_masks(masks: np.ndarray, maps) -> np.ndarray:
    """(V, h, w) float32: every view's mask sampled (bilinearly, 0 outside) at its sampling map
    of ``maps`` ((V, h, w) map_x and map_y)."""
    map_x, map_y = maps
    out = np.empty(map_x.shape, np.float32)
    for k in range(len(map_x)):
        cv2.remap(masks[k], map_x[k], map_y[k], cv2.INTER_LINEAR, dst=out[k], borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out


def _remap_views(sources: list, maps) -> np.ndarray:
    """(V, h, w, C) float32: every view of ``sources`` ((h, w, C) each, premultiplied by its
    mask) sampled like :func:`_remap_masks`."""
    map_x, map_y = maps
    out = np.empty(map_x.shape + sources[0].shape[2:], np.float32)
    for k in range(len(map_x)):
        cv2.remap(sources[k], map_x[k], map_y[k], cv2.INTER_LINEAR, dst=out[k], borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out


class DepthOfField:
    """Render a lens of any aperture focused at any depth from views and a depth map.

    Parameters
    ----------
    views : (V, h, w, C) float32 in [0, 1]
    calibration : RingCalibration
    depth_map_m : (h, w) float
        Depth of every reference pixel in metres (NaN where unknown: the nearest known
        surface continued, as at a depth that too few views see).
    reference : 'center' or int
        The frame of the depth map and of the results.
    measured_views : float
        The views' worth that must see a pixel at its depth for that depth to count as measured
        (elsewhere it is continued from the nearest measured pixel): :data:`MIN_DEPTH_VIEWS`
        for a depth map of unknown origin, :data:`MIN_ESTIMATED_VIEWS` for one that depth
        estimation made (:func:`depth_of_field` chooses).

    Attributes
    ----------
    colour : (h, w, C) float32
        The all-in-focus colour (every pixel from the views that agree at its own depth).
    agree : (h, w) float32 in [0, 1]
        1 where every view that sees the pixel agrees with the others there.
    seen : (h, w) bool
        Whether any view sees the pixel at its depth.
    radius_px : float
        R of :func:`aperture_radius_px`.
    measured_views : float
        The parameter: the views' worth from which a depth counts as measured.
    depth_m : (h, w) float64
        The depth map it renders (for an estimate, :func:`depth_to_render`'s), NaN where it has no
        depth (:func:`known_depths`).

    Notes
    -----
    See the module's description. Memory: the views remapped once (V full-size images) while
    the colour is made; then, kept between renders, a few full-size buffers and the layers
    twice, as scattered and as blurred (each pixel in two of them, blurred layers on reduced
    grids). Renders share that memory, so one renderer used from several threads renders one
    image at a time (each render's passes use every core already).
    """

    def __init__(self, views, calibration, depth_map_m, *, reference="center", measured_views: float = MIN_DEPTH_VIEWS):
        check_calibration(calibration)
        arr = check_views(views)
        self.measured_views = check_number(measured_views, "measured_views", minimum=0.0, maximum=float(arr.shape[0]))
        h, w = arr.shape[1:3]
        dm = np.asarray(depth_map_m, dtype=np.float64)
        if dm.shape != (h, w):
            raise InvalidInputError(f"the depth map must be {h} x {w} px like the views, got shape {dm.shape}")
        z0 = calibration.depth_origin_m
        known = known_depths(dm, calibration)
        self.depth_m = np.where(known, dm, np.nan)
        self._views_sample = _views_sample(arr)
        if not np.all(known):
            dm = np.where(known, dm, float(np.median(dm[known])))
        self.reference = check_reference(reference, calibration.num_views)
        self.calibration = calibration
        self.view_shape = (h, w)
        self.x = _inverse_depth(dm, z0).astype(np.float32)
        self.radius_px = aperture_radius_px(calibration, self.reference)
        masks = cached_view_masks(calibration, (h, w))
        sources = [arr[k] if np.all(masks[k] == 1.0) else arr[k] * masks[k][..., None] for k in range(len(arr))]
        self.colour, self.agree, self.seen, nearest = self._all_in_focus(sources, masks, known)
        self._back = self._background(sources, masks, nearest)
        self._cover = self.seen.astype(np.float32)
        self._scratch: dict = {}
        self._rendering = threading.Lock()
        self._vmax = float(arr.max())  # every image rendered is a weighted average of the views
        self._x_range = (float(self.x[self.seen].min()), float(self.x[self.seen].max())) if self.seen.any() else (1.0, 1.0)

    def all_in_focus(self) -> tuple[np.ndarray, np.ndarray]:
        """The all-in-focus image: every pixel at its own depth (aperture 0), black where no view
        sees it; and that depth, (h, w) float32 metres, NaN where the map had none (the render
        continued the nearest measured surface there) or no view sees it. What
        :func:`lfring.all_in_focus` gives for this renderer's views and depth map."""
        out = self.render(float(np.nanmedian(self.depth_m)), 0.0)  # at aperture 0 any focus renders the same
        out[~self.seen] = 0.0
        return out, np.where(self.seen, self.depth_m, np.nan).astype(np.float32)

    def check_made_from(self, views, calibration, reference) -> None:
        """Raise :class:`InvalidInputError` unless this renderer was made from ``views`` (as many,
        of the same size and channels, the same values at a sample of their pixels) with
        ``calibration`` (the same object) in the frame of ``reference``: a prepared renderer passed
        where a depth map is taken is reused as it is."""
        arr = check_views(views)
        if arr.shape[1:] != self.colour.shape or arr.shape[0] != self._views_sample[0]:
            raise InvalidInputError(f"the depth-of-field renderer was made from {self._views_sample[0]} views of "
                                    f"{self.colour.shape} (h, w, C), these are {arr.shape[0]} of {arr.shape[1:]}")
        if _views_sample(arr) != self._views_sample:
            raise InvalidInputError("the depth-of-field renderer was made from other views (another frame, or "
                                    "views changed since): make it from these")
        if calibration is not self.calibration:
            raise InvalidInputError("the depth-of-field renderer was made with another calibration")
        ref = check_reference(reference, calibration.num_views)
        if ref != self.reference:
            raise InvalidInputError(f"the depth-of-field renderer is in the frame of reference {self.reference!r}, "
                                    f"the refocusing in {ref!r}")

    # -- sampling the views --------------------------------------------------------------------
    def _sampling_maps(self, k_views: int, x: np.ndarray, at=None):
        """(map_x, map_y), each (V, h, w) float32: the view pixel that every reference pixel
        samples in each view at the inverse depth ``x`` (h, w). With ``at`` ((rows, cols), each
        (n,)), only those pixels', each map (V, n): the same values as the whole grid's there."""
        from lfring.focus import depth_aware_kernels as kern

        cal, (h, w) = self.calibration, self.view_shape
        z0 = cal.depth_origin_m
        lo, hi = float(x.min()), float(x.max())
        if hi - lo < 1e-9:
            hi = lo + 1e-6
        ends = to_reference(cal.model(_depth_at(np.array([lo, hi]), z0)), self.reference)  # (2, V, 3, 3)
        shifts = translations(ends, (h, w))
        x = np.ascontiguousarray(x, dtype=np.float32)
        if at is not None:
            rows, cols = at
            x = np.ascontiguousarray(x[rows, cols])
        map_x = np.empty((k_views, *x.shape), np.float32)
        map_y = np.empty((k_views, *x.shape), np.float32)
        if shifts is not None:  # affine in x: exact from the two ends
            slope = (shifts[1] - shifts[0]) / (hi - lo)
            args = (x, np.float32(lo), np.ascontiguousarray(shifts[0, :k_views], np.float32),
                    np.ascontiguousarray(slope[:k_views], np.float32), map_x, map_y)
            if at is None:
                kern.shift_maps(*args)
            else:
                kern.shift_maps_at(rows, cols, *args)
            return map_x, map_y
        # General homographies: piecewise linear in x between knots.
        corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]], dtype=np.float64)
        inv_ends = np.linalg.inv(ends)
        motion = max(np.abs(apply_homography(inv_ends[0, k], corners) - apply_homography(inv_ends[1, k], corners)).max()
                     for k in range(k_views))
        knots = np.linspace(lo, hi, max(2, int(math.ceil(motion / KNOT_STEP_PX)) + 1))
        inv = np.ascontiguousarray(np.linalg.inv(to_reference(cal.model(_depth_at(knots, z0)), self.reference))[:, :k_views])
        if at is None:
            kern.knot_maps(x, knots, inv, map_x, map_y)
        else:
            kern.knot_maps_at(rows, cols, x, knots, inv, map_x, map_y)
        return map_x, map_y

    def _occluded(self, mx, my, x, nearest) -> np.ndarray:
        """(h, w) bool: whether a surface nearer than ``x`` by more than :data:`OCCLUSION_PX`
        of view motion lands on the view pixel (``mx``, ``my``) (``nearest``: the depth map
        splatted into the view)."""
        from lfring.focus import depth_aware_kernels as kern

        out = np.empty(mx.shape, bool)
        kern.occluded(mx, my, x, nearest, OCCLUSION_PX / max(self.radius_px, 1e-12), out)
        return out

    def _splat(self, maps) -> list:
        """Per view of ``maps`` (:meth:`_sampling_maps`), (h, w) float32: the largest inverse
        depth of the reference pixels that land on each view pixel (nearest wins, widened by one
        pixel), -inf where none does."""
        from lfring.focus import depth_aware_kernels as kern

        map_x, map_y = maps
        nearest = np.full((len(map_x), *self.view_shape), -np.inf, np.float32)
        kern.splat_max(map_x, map_y, self.x, nearest)
        return [cv2.dilate(nk, np.ones((3, 3), np.uint8)) for nk in nearest]

    def _measured(self, k_views: int, masks: np.ndarray, known: np.ndarray):
        """The depth map, continued from the nearest pixel that :attr:`measured_views` views'
        worth see at its own depth (along its plane,
        :func:`lfring.focus.continuation.plane_continued`; the planes feathered over
        :data:`FEATHER_PX`) where fewer do or the
        depth is unknown (a depth one view alone sees was not measured: estimation picks such
        depths at the range's end, where the views drift off their discs), unless it continues
        that pixel's depth anyway (``known``: where the given map had a depth); and the views'
        sampling maps at it, with the views' masks sampled there (V, h, w)."""
        maps = self._sampling_maps(k_views, self.x)
        weight = _remap_masks(masks, maps)
        trust = np.clip(weight.sum(axis=0) - (self.measured_views - 1.0), 0.0, 1.0).astype(np.float32)
        trust[~known] = 0.0  # an unknown depth (its stand-in the median) was not measured
        measured = trust >= 1.0
        if measured.all() or not measured.any():
            return maps, weight
        # The surface of the nearest measured pixel (not an average of all around, which would
        # invent depths between a nearer surface and a farther one), feathered over
        # FEATHER_PX: where the nearest measured pixels of two surfaces meet, a step would cut a
        # straight seam across the rim (the views sampled at one depth on one side, at the other
        # across it). The labels number the measured pixels in row-major order, as a boolean
        # index lists them.
        _, labels = cv2.distanceTransformWithLabels((~measured).view(np.uint8), cv2.DIST_L2, 5,
                                                    labelType=cv2.DIST_LABEL_PIXEL)
        # Feathered over the continued pixels only, so that the depths of measured pixels further
        # off (across a measured depth edge) do not leak in.
        # Each continued pixel's plane (the nearest measured pixel's surface, continued along it),
        # the planes feathered and each pixel's depth read off its feathered plane: a slope is
        # continued as it is, where a feathered depth would bend towards the measured side.
        planes = plane_continued(self.x, measured, labels, self.radius_px)
        share = (~measured).astype(np.float32)
        spread = np.maximum(_feathered(share, FEATHER_PX), np.float32(FEATHER_FLOOR))
        a, gu, gv = (_feathered(p * share, FEATHER_PX) / spread for p in planes)
        h, w = self.x.shape
        u = np.arange(w, dtype=np.float32)[None, :] - np.float32(0.5 * w)
        v = np.arange(h, dtype=np.float32)[:, None] - np.float32(0.5 * h)
        around = np.where(measured, self.x, np.maximum(a + gu * u + gv * v, np.float32(1.0 / INFINITE_DEPTH_M)))
        around = around.astype(np.float32)
        # A depth that continues its surroundings' (the feathered depth) is kept however few
        # views see it. (Also keeping a depth that continues the nearest pixel's brought the
        # misplaced wedges back beside a nearer surface's corners at the rims.)
        near = np.clip(2.0 - np.abs(self.x - around) * np.float32(self.radius_px / DEPTH_TOL_PX), 0.0, 1.0)
        near[~known] = 0.0
        trust = np.maximum(trust, near)
        self.x = (around + trust * (self.x - around)).astype(np.float32)
        maps = self._sampling_maps(k_views, self.x)
        return maps, _remap_masks(masks, maps)

    def _all_in_focus(self, sources: list, masks: np.ndarray, known: np.ndarray):
        from lfring.focus import depth_aware_kernels as kern

        v = len(sources)
        (h, w), c = self.view_shape, sources[0].shape[2]
        maps, weight = self._measured(v, masks, known)
        warped = _remap_views(sources, maps)
        nearest = self._splat(maps)
        visible = np.stack([~self._occluded(mx, my, self.x, nk) for mx, my, nk in zip(*maps, nearest)])
        colour = np.empty((h, w, c), np.float32)
        agree = np.empty((h, w), np.float32)
        seen = np.empty((h, w), bool)
        kern.robust_mean(warped, weight, visible, AGREE_TOL, SPREAD_TOL, VISIBLE_VIEWS, WEIGHT_FLOOR, colour, agree,
                         seen)
        return colour, agree, seen, nearest

    # -- the background under occlusion edges --------------------------------------------------
    def _background(self, sources: list, masks: np.ndarray, nearest: list):
        """The farther surface continued under nearer ones near occlusion edges: (distance_px,
        x_b, colour_b, row_min, col_min, x_b_range), or None where the depth map has no step of
        :data:`BACK_STEP_PX`.

        ``distance_px`` (h, w) is how far a pixel with a background lies from the step (inf
        where it has none); ``x_b`` its inverse depth (the nearest pixel across the step's);
        ``colour_b`` its colour, from the views that see it there (they look behind the edge
        from their places in the aperture), else extended from around; ``row_min`` and
        ``col_min`` the least distance of each row and column; ``x_b_range`` the least and
        largest ``x_b`` where there is a background."""
        from lfring.focus import depth_aware_kernels as kern

        x = self.x
        step = np.float32(BACK_STEP_PX / max(self.radius_px, 1e-12))
        k = 2 * BACK_EDGE_PX + 1
        nearer = cv2.dilate(x, np.ones((k, k), np.uint8))
        seeds = ((nearer - x) > step) & self.seen
        if not seeds.any():
            return None
        dist, labels = cv2.distanceTransformWithLabels((~seeds).astype(np.uint8), cv2.DIST_L2, 5,
                                                       labelType=cv2.DIST_LABEL_PIXEL)
        xb = x[seeds][labels - 1]  # the labels number the seeds in row-major order
        under = (x - xb) > step
        if not under.any():
            return None
        v = len(sources)
        (h, w), c = self.view_shape, sources[0].shape[2]
        # The views are sampled at the pixels with a background only: a list in rows of
        # LIST_ROW_PX, the last row filled up with the last pixel again.
        iy, ix = np.nonzero(under)
        n = iy.size
        pad = -n % LIST_ROW_PX
        at = (np.concatenate([iy, np.full(pad, iy[-1])]), np.concatenate([ix, np.full(pad, ix[-1])]))
        grid = (-(-n // LIST_ROW_PX), LIST_ROW_PX)
        maps = tuple(m.reshape(v, *grid) for m in self._sampling_maps(v, xb, at=at))
        xb_at = np.ascontiguousarray(xb[at]).reshape(grid)
        num = np.zeros((*grid, c), np.float32)
        den = np.zeros(grid, np.float32)
        for k, (val, wk) in enumerate(zip(_remap_views(sources, maps), _remap_masks(masks, maps))):
            kern.add_seen(val, wk, self._occluded(maps[0][k], maps[1][k], xb_at, nearest[k]), num, den)
        num, den = num.reshape(-1, c)[:n], den.reshape(-1)[:n]
        seen_at = den > WEIGHT_FLOOR
        known = np.zeros((h, w), bool)
        known[iy[seen_at], ix[seen_at]] = True
        colour = np.zeros((h, w, c), np.float32)
        colour[iy[seen_at], ix[seen_at]] = num[seen_at] / den[seen_at, None]
        # The seeds are the farther surface itself, as the reference sees it.
        colour[seeds] = self.colour[seeds]
        source = known | seeds
        # Filled from around over the box of what has or needs a background (nothing outside
        # it is a source), not the whole frame.
        involved = source | under
        rows, cols = np.flatnonzero(involved.any(axis=1)), np.flatnonzero(involved.any(axis=0))
        box = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
        colour[box] = np.stack(_fill_from_around([np.ascontiguousarray(colour[box + (i,)]) for i in range(c)],
                                                 source[box].astype(np.float32)), axis=2)
        dist_under = np.where(under, dist, np.inf).astype(np.float32)
        return (dist_under, xb.astype(np.float32), np.ascontiguousarray(colour, dtype=np.float32),
                dist_under.min(axis=1), dist_under.min(axis=0), (float(xb[under].min()), float(xb[under].max())))

    # -- rendering -------------------------------------------------------------------------------
    def signed_radius_px(self, focus_m: float) -> np.ndarray:
        """(h, w) float32 ``R (x - x_f)``: the signed circle-of-confusion radius at aperture 1
        (positive nearer than the focus), and the view motion of shift-and-add there."""
        xf = np.float32(1.0 / (focus_m - self.calibration.depth_origin_m))
        return np.float32(self.radius_px) * (self.x - xf)

    def render(self, focus_m: float, aperture: float, shift_and_add: np.ndarray | None = None) -> np.ndarray:
        """(h, w, C) float32: the lens of ``aperture`` focused at ``focus_m`` metres.

        ``shift_and_add`` is the views refocused at ``focus_m`` (:func:`lfring.refocus`): used
        where it is in focus. Without it, the all-in-focus colour is used everywhere."""
        z0 = self.calibration.depth_origin_m
        focus_m = check_number(focus_m, "focus_m", above=z0, finite=False, what="a depth in metres",
                               hint=" (beyond the calibration's depth origin; inf: focused at infinity)")
        aperture = check_number(aperture, "aperture", minimum=0.0)
        with self._rendering:
            return self._render(1.0 / (focus_m - z0), aperture, shift_and_add)

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_scratch"] = {}
        del state["_rendering"]
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._rendering = threading.Lock()

    def _render(self, xf: float, aperture: float, shift_and_add) -> np.ndarray:
        from lfring.focus import depth_aware_kernels as kern

        h, w, c = self.colour.shape
        motion = float(self.radius_px)
        sharp = NO_IMAGE
        if shift_and_add is not None:
            sharp = np.ascontiguousarray(np.asarray(shift_and_add, dtype=np.float32).reshape(self.colour.shape))
        # The largest blur radius, from the depth map's ends: the ladder reaches it.
        rmax = aperture * motion * max(abs(self._x_range[0] - xf), abs(self._x_range[1] - xf))
        diagonal = math.hypot(h, w)
        if rmax > MAX_BLUR_DIAGONALS * diagonal:  # its ladder of rungs grows without end, and shows only a mean
            raise InvalidInputError(
                f"aperture {aperture:g} blurs this depth map by up to {rmax:.0f} px at the focus "
                f"{_depth_at(xf, self.calibration.depth_origin_m):.4g} m, more than {MAX_BLUR_DIAGONALS:g} times the "
                f"frame's diagonal ({diagonal:.0f} px): give a smaller aperture (1 is the views' own)")
        window = None
        if self._back is not None:
            dist_under, x_b, colour_b, row_min, col_min, xb_range = self._back
            # Only as far from the edge as a nearer surface's blur can reach: the box of those
            # pixels from the rows' and columns' least distances.
            reach = rmax + 2.0
            rows, cols = np.flatnonzero(row_min <= reach), np.flatnonzero(col_min <= reach)
            if rows.size:
                window = (rows[0], rows[-1] + 1, cols[0], cols[-1] + 1)
                rmax = max(rmax, aperture * motion * max(abs(xb_range[0] - xf), abs(xb_range[1] - xf)))
        grid = Grid(ladder(rmax), (h, w), c, (xf, motion, aperture), self._scratch,
                    (SHARP_PX, SHARP_RAMP_PX, SHARP_RESAMPLED_PX2), self._vmax)
        acc = composite(grid.layers(kern, self.x, self.agree, self._cover, self.colour, sharp), grid, kern)
        by, bx, summed = 0, 0, NO_IMAGE
        if window is not None:
            # The background's cover in the window: 1 near the edge, 0 elsewhere (the passes read
            # only the window; outside it the kept scratch holds what an earlier render left).
            cover_b = grid.buffer("back cover", (h, w))
            box = (slice(window[0], window[1]), slice(window[2], window[3]))
            np.less_equal(dist_under[box], np.float32(reach), out=cover_b[box], casting="unsafe")
            by, bx, summed = sum_layers(grid.layers(kern, x_b, self.agree, cover_b, colour_b, NO_IMAGE, window, "back"),
                                         (h, w), c)
        out = np.empty((h, w, c), np.float32)
        kern.finish(acc, summed, by, bx, np.float32(WEIGHT_FLOOR), out, True)
        grid.left_zeros(COMPOSITE, acc.size)
        return out


def _views_sample(arr: np.ndarray) -> tuple[int, str]:
    """The number of views and a digest of their values on a sparse grid of pixels (every
    :data:`_SAMPLE_STEP_PX`-th row and column): enough to tell another frame from the one a
    renderer was made from, at a small fraction of the views' size."""
    import hashlib

    sample = np.ascontiguousarray(arr[:, ::_SAMPLE_STEP_PX, ::_SAMPLE_STEP_PX])
    return arr.shape[0], hashlib.blake2b(sample.tobytes(), digest_size=16).hexdigest()


_SAMPLE_STEP_PX = 7
"""Rows and columns between the pixels whose values identify a renderer's views."""


def check_aperture_options(aperture=None, f_number=None) -> None:
    """The depth of field's own options, before any frame or device is read: one of them at
    most, an ``aperture`` of at least 0 and an ``f_number`` a lens can have."""
    from lfring.optics.paraxial import check_f_number

    if aperture is not None and f_number is not None:
        raise InvalidInputError("give the depth of field as aperture or as f_number, not both")
    check_number(aperture, "aperture", minimum=0, allow_none=True, hint=" (1: the views' aperture, 0: a pinhole)")
    check_f_number(f_number, allow_none=True)


def resolve_aperture(calibration, aperture=None, f_number=None, ring_device=None) -> float:
    """The depth-aware ``aperture`` (1: the disc through the views, 0: a pinhole) from either
    ``aperture`` or ``f_number`` (1.0 when neither is given).

    ``f_number`` needs the device: ``ring_device`` (a :class:`lfring.optics.RingDevice` with
    its positions, a built-in device's name or a device file), or else the device the calibration was made with
    (:meth:`lfring.RingCalibration.device_optics`: its record, or the built-in device it names
    at the positions it records). See
    :func:`aperture_from_f_number` for the relation.
    """
    check_aperture_options(aperture, f_number)
    if f_number is None:
        return 1.0 if aperture is None else float(aperture)
    if ring_device is not None:
        from lfring.optics.device import load_device

        ring_device = load_device(ring_device)  # a RingDevice, a built-in name or a device file
    else:
        if calibration.device is None:
            raise InvalidInputError(
                "f_number needs the device (its main lens's focal length and where the views sit in its aperture): "
                "pass ring_device=, or use aperture= (1 is the aperture the views span)"
            )
        ring_device = calibration.device_optics()
        prov = calibration.provenance
        # A built-in device named without its record, at the positions the calibration was made at.
        if DEVICE_RECORD not in prov and prov.get("ring_distance_m") is not None and prov.get("sensor_distance_m") is not None:
            ring_device = ring_device.with_positions(prov["ring_distance_m"], prov["sensor_distance_m"])
    return aperture_from_f_number(f_number, ring_device)


def estimation_range(calibration, zmin_m=None, zmax_m=None, *, reference="center") -> tuple[float, float]:
    """The depth range (metres) over which depth-aware refocusing estimates its depth map, the
    one rule for every entry point (:func:`lfring.refocus`, ``lfring refocus``, ``lfring
    batch``, the viewer).

    ``zmin_m`` and ``zmax_m`` where given, else the calibration's valid range. A calibration
    without an upper bound gets a far end where the views still move by :data:`FAR_MOTION_PX`
    from where they see infinity (``1/(Z - z0) = FAR_MOTION_PX / R``, R of
    :func:`aperture_radius_px`), when that range is one of depths: when no view moves over it
    by more than :data:`DERIVED_RANGE_MAX_MOTION` of the views' smaller side. A calibration
    from the optics qualifies (its range starts at the device's nearest depth, and the views
    move by a small part of their size out to infinity); a view grid's by default does not
    (its range starts where neighbouring views stop overlapping, so closed at the far end it
    would hold every disparity the views can show): its scene's range must be given.

    Raises
    ------
    InvalidInputError
        The calibration has no upper bound and none can be derived: give ``zmax_m`` (or use
        shift-and-add, which needs no depth map).

    Examples
    --------
    >>> from lfring.calibration import RingCalibration
    >>> from lfring.optics import load_device
    >>> cal = RingCalibration.from_optics(load_device("prototype").binned(2))
    >>> lo, hi = estimation_range(cal)
    >>> round(lo, 3) == round(cal.valid_depth_range_m[0], 3), cal.valid_depth_range_m[1], round(hi, 1)
    (True, None, 4.4)
    >>> pair = RingCalibration.from_grid((64, 96), [(0, 0), (1, 0)], disparity_scale_px_m=120.0)
    >>> estimation_range(pair, zmax_m=20.0)
    (1.25, 20.0)
    >>> estimation_range(pair)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    lfring.errors.InvalidInputError: the calibration has no upper depth bound, and none follows from it: ... as zmax_m ...
    """
    zmin_m = check_number(zmin_m, "zmin_m", above=0.0, allow_none=True, what="a distance in metres")
    zmax_m = check_number(zmax_m, "zmax_m", above=0.0, allow_none=True, what="a distance in metres")
    lo, hi = calibration.valid_depth_range_m
    if zmax_m is not None and zmin_m is None and zmax_m <= lo:
        raise InvalidInputError(f"zmax_m ({zmax_m:g} m) must be farther than the calibration's nearest valid depth "
                                f"({lo:g} m), where the range starts when zmin_m is not given")
    lo = float(lo if zmin_m is None else zmin_m)
    if zmax_m is not None:
        return lo, float(zmax_m)
    if hi is not None:
        return lo, float(hi)
    hi = calibration.depth_origin_m + aperture_radius_px(calibration, reference) / FAR_MOTION_PX
    hi = max(hi, 2.0 * lo)
    view_shape = calibration.layout.view_shape
    move = view_motion_px(calibration, [lo, hi], view_shape)
    side = min(view_shape)
    if move > DERIVED_RANGE_MAX_MOTION * side:
        raise InvalidInputError(
            f"the calibration has no upper depth bound, and none follows from it: from its near end ({lo:g} m) to where "
            f"the views stop moving ({hi:.4g} m) they move by {move:.0f} px, more than {DERIVED_RANGE_MAX_MOTION:g} x "
            f"their size ({side} px), which is every disparity they can show rather than the scene's depths. Give the "
            f"scene's farthest depth as zmax_m (and its nearest as zmin_m); refocusing by method='shift-and-add' needs "
            f"no depth map"
        )
    return lo, float(hi)


def _estimated_depth(result: DepthResult, calibration, reference) -> np.ndarray:
    """(h, w) metres to render of a depth estimate: its depth, and at the pixels it was not
    confident of (under ``lfring.depth.refine.MIN_CONFIDENCE``, where ``depth_m`` keeps the
    unrefined winner) its hole-filled depth where the confident depths within
    :data:`FILL_WINDOW_PX` span at most :data:`FILL_SMOOTH_PX` px of view motion: on a smooth
    surface the fill continues it, at a depth edge it would lie between the two surfaces."""
    from lfring.depth.refine import MIN_CONFIDENCE

    d = np.asarray(result.depth_m, dtype=np.float64)
    filled = result.depth_filled_m
    if filled is None or np.shape(filled) != d.shape:
        return d
    z0 = calibration.depth_origin_m
    confident = known_depths(d, calibration, allow_none=True) & (np.asarray(result.confidence) >= MIN_CONFIDENCE)
    unsure = np.isfinite(d) & ~confident & np.isfinite(filled)
    if not unsure.any() or not confident.any():
        return d
    x = _inverse_depth(np.where(confident, d, np.inf), z0).astype(np.float32)  # 0 where not confident
    window = np.ones((FILL_WINDOW_PX, FILL_WINDOW_PX), np.uint8)
    top = cv2.dilate(np.where(confident, x, -np.inf).astype(np.float32), window)
    bottom = cv2.erode(np.where(confident, x, np.inf).astype(np.float32), window)
    # No confident depth within the window (top below bottom: the fill values, or the largest
    # float at the frame's border): not known to be smooth.
    some = top >= bottom
    span = np.subtract(top, bottom, out=np.zeros_like(top), where=some)
    smooth = some & (span * np.float32(aperture_radius_px(calibration, reference)) <= FILL_SMOOTH_PX)
    return np.where(unsure & smooth, np.asarray(filled, dtype=np.float64), d)


def known_depths(depth_map_m: np.ndarray, calibration, *, allow_none: bool = False) -> np.ndarray:
    """(h, w) bool: where ``depth_map_m`` holds a depth (finite, beyond the calibration's depth
    origin); elsewhere the renderer continues the nearest measured surface. A map that holds
    none is refused, unless ``allow_none``."""
    z0 = calibration.depth_origin_m
    known = np.isfinite(depth_map_m) & (depth_map_m > z0)
    if not allow_none and not np.any(known):
        raise InvalidInputError(f"the depth map holds no finite depth beyond the depth origin z0 = {z0:.4g} m")
    return known


def depth_to_render(depth, calibration, reference, shape) -> tuple[np.ndarray, float]:
    """A given depth map as the renderer takes it: (h, w) metres in the reference frame (NaN
    where unknown) and the views' worth from which its depths count as measured.

    ``depth`` is a :class:`lfring.DepthResult` (its depth, and where estimation was not
    confident its hole-filled depth on smooth surfaces, :data:`FILL_SMOOTH_PX`; measured
    wherever :data:`MIN_ESTIMATED_VIEWS` views' worth see it) or (h, w) metres of unknown
    origin (measured wherever :data:`MIN_DEPTH_VIEWS` do). ``shape`` is (h, w) of the views."""
    estimated = isinstance(depth, DepthResult)
    if estimated:
        if depth.reference != reference:
            raise InvalidInputError(f"the depth map is in the frame of reference {depth.reference!r}, the refocusing in {reference!r}")
        depth = _estimated_depth(depth, calibration, reference)
    try:
        dm = np.asarray(depth, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidInputError(f"the depth map must be (h, w) metres (NaN where unknown), got {type(depth).__name__}") from None
    if dm.shape != tuple(shape):
        raise InvalidInputError(f"the depth map must be (h, w) = ({shape[0]}, {shape[1]}) metres like the views, got shape {dm.shape}")
    if not estimated:
        known = known_depths(dm, calibration, allow_none=True)
        typical = float(np.median(dm[known])) if known.any() else math.nan
        # Only a range with a far end tells: open to infinity, a far scene is a scene.
        closed = calibration.valid_depth_range_m[1] is not None
        hint = calibration.millimetres_hint(typical) if closed and math.isfinite(typical) else ""
        if hint:  # a depth map of millimetres renders as a scene at hundreds of metres, without a word
            warn_caller(f"the depth map's depths lie beyond the calibration's range (median {typical:g} m){hint}")
        # NaN says unknown; 0 says it too for many depth sensors, but it may be a mistake: say so.
        z0 = calibration.depth_origin_m
        odd = ~np.isnan(dm) & ~known
        if odd.any():
            warn_caller(
                f"{int(odd.sum())} pixels of the depth map ({odd.mean():.1%}) are not depths beyond the depth origin "
                f"z0 = {z0:.4g} m (0, negative, nearer or infinite; e.g. {float(dm[odd][0]):g}): taken as unknown, "
                "as NaN is, and rendered by continuing the nearest known surface")
    return dm, MIN_ESTIMATED_VIEWS if estimated else MIN_DEPTH_VIEWS


def _depth_map(arr, calibration, depth, zmin_m, zmax_m, reference) -> tuple[np.ndarray, float]:
    """The depth map of the views in the reference frame, given or estimated (over ``zmin_m``..
    ``zmax_m``), and the views' worth from which its depths count as measured
    (:func:`depth_to_render`)."""
    if depth is None:
        zmin_m, zmax_m = estimation_range(calibration, zmin_m, zmax_m, reference=reference)
        depth = estimate_depth(arr, calibration, zmin_m=zmin_m, zmax_m=zmax_m, reference=reference)
    return depth_to_render(depth, calibration, reference, arr.shape[1:3])


def depth_of_field(views, calibration, *, depth=None, zmin_m=None, zmax_m=None, reference="center") -> DepthOfField:
    """A :class:`DepthOfField` renderer of the views: from a depth map (``depth``, a
    :class:`lfring.DepthResult` or (h, w) metres in the reference frame), or one estimated over
    ``zmin_m``..``zmax_m`` (by default the calibration's valid range). Reuse it to render many
    focus depths and apertures from one depth map; given as ``depth`` (here, and so to
    :func:`lfring.refocus`, :func:`lfring.focal_stack` and :func:`lfring.all_in_focus`), a renderer
    made from the same views is used as it is. An estimated map's depths count as measured
    wherever :data:`MIN_ESTIMATED_VIEWS` views' worth see them, a bare map's wherever
    :data:`MIN_DEPTH_VIEWS` do; where estimation was not confident, its hole-filled depth is
    rendered on smooth surfaces (:data:`FILL_SMOOTH_PX`)."""
    check_calibration(calibration)
    arr = check_views(views)
    ref = check_reference(reference, calibration.num_views)
    if depth is not None and (zmin_m is not None or zmax_m is not None):
        raise InvalidInputError("zmin_m/zmax_m set the range of the depth estimation: give them or a depth map, not both")
    if isinstance(depth, DepthOfField):
        depth.check_made_from(arr, calibration, ref)
        return depth
    dm, measured_views = _depth_map(arr, calibration, depth, zmin_m, zmax_m, ref)
    return DepthOfField(arr, calibration, dm, reference=ref, measured_views=measured_views)


def prepare_depth_aware(views, calibration, reference, *, aperture=None, f_number=None, ring_device=None, depth=None,
                        zmin_m=None, zmax_m=None):
    """The depth-aware method's ``finish(sharp, focus_m)`` for one frame (see
    :class:`lfring.focus.base.RefocusMethod`): the depth map (given or estimated) and the
    all-in-focus colour are made once, every focus depth reuses them."""
    a = resolve_aperture(calibration, aperture, f_number, ring_device)
    dof = depth_of_field(views, calibration, depth=depth, zmin_m=zmin_m, zmax_m=zmax_m, reference=reference)
    return lambda sharp, focus_m: dof.render(float(focus_m), a, sharp)


DEPTH_AWARE = RefocusMethod(
    name="depth-aware",
    summary="what a lens whose aperture spans the views records: in focus as shift-and-add, elsewhere a disc of blur",
    prepare=prepare_depth_aware,
    options=frozenset({"aperture", "f_number", "ring_device", "depth", "zmin_m", "zmax_m"}),
)

