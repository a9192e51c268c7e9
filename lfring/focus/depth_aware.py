"""Depth-aware refocusing: what the whole main-lens aperture would have recorded.

Shift-and-add shows every object away from the focus depth as V displaced copies of itself. A
lens whose aperture spans the views would show it as a smooth disc of blur instead. Given a
depth map in the reference frame, :class:`DepthOfField` renders that:

1. **All-in-focus colour.** Every view is sampled at every reference pixel's own depth (one
   ``cv2.remap`` per view) and the views are averaged where they agree: a view whose luminance
   is far from the views' median there (it sees an occluder, or a specular highlight) is left
   out (:data:`AGREE_TOL`). This does not depend on the focus depth and is made once per depth
   map.
2. **In focus from shift-and-add.** Where the views refocused at the focus depth are aligned to
   within :data:`SHARP_PX` px and agree, the colour is the shift-and-add image itself, blending
   to the all-in-focus colour by :data:`SHARP_PX` + :data:`SHARP_RAMP_PX`: in-focus regions are
   what shift-and-add gives.
3. **Layers.** Each pixel's signed circle-of-confusion radius ``rho = aperture * R * (x - x_f)``,
   with ``x = 1/(Z - z0)``, ``x_f`` the focus depth's and R from :func:`aperture_radius_px`, goes
   to the nearest of a ladder of radii (0.5 px apart up to 2 px, 1 px apart up to
   :data:`LINEAR_UNTIL_PX`, then growing by :data:`GEOMETRIC_STEP`). Every rung is one layer of
   premultiplied colour and coverage, blurred by a disc of its radius (large radii on a grid
   reduced so that the disc is at most :data:`FULL_RES_BLUR_PX` px) and composited far to near
   with the "over" operator; the result is divided by the accumulated coverage. Before a
   blurred layer is composited, what lies behind is extended under it and under every nearer
   pixel (a normalised blur of the farther layers, out to the layer's radius): through a near
   object's soft edge the lens sees the background continue, not a hole. A near object's blur
   therefore spreads symmetrically over its edge and what lies behind it, and what lies behind
   never covers a nearer object's sharp pixels.

The physics: view k's sampling shift at depth Z is (for the ring's translation model) affine in
x = 1/(Z - z0); a virtual viewpoint at aperture position u (the views sitting at their own
positions, u = 1) sees a point at depth Z moved by u (t_k(Z) - t_k(Z_f)) relative to the focus
plane, so a lens whose aperture is the disc through the views blurs it over a disc of radius
``R |x - x_f|`` px, R the views' mean distance (in px per unit x) from their centre.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from lfring.errors import InvalidInputError
from lfring.core.geometry import apply_homography, check_reference, to_reference
from lfring.core.viewstack import WEIGHT_FLOOR, cached_view_masks, check_views
from lfring.core.filters import luminance
from lfring.core.threads import run_threads
from lfring.core.validate import check_number
from lfring.core.warping import translations
from lfring.depth.estimate import estimate_depth
from lfring.depth.selection import DepthResult
from lfring.focus.base import RefocusMethod

__all__ = [
    "AGREE_TOL", "FULL_RES_BLUR_PX", "GEOMETRIC_STEP", "LINEAR_UNTIL_PX", "OCCLUSION_PX", "SHARP_PX", "SHARP_RAMP_PX", "DepthOfField",
    "DEPTH_AWARE", "aperture_from_f_number", "aperture_radius_px", "coc_radius_px", "depth_of_field", "disc_kernel",
    "prepare_depth_aware", "resolve_aperture",
]

# Views aligned to within this many pixels of view motion at the focus depth are in focus: the
# shift-and-add image is used there, blending to the all-in-focus colour over SHARP_RAMP_PX more.
SHARP_PX = 0.5
SHARP_RAMP_PX = 1.0
# A view whose luminance at a pixel's own depth differs from the views' median by more than
# AGREE_TOL (linear [0, 1] units) loses weight linearly, and none is left by twice that.
AGREE_TOL = 0.04
# The ladder of blur radii of the layers: 0.5 px apart up to 2 px, 1 px apart up to LINEAR_UNTIL_PX, then each
# GEOMETRIC_STEP times the last (the eye does not tell a disc of radius r from one of 1.2 r).
LINEAR_UNTIL_PX = 6.0
GEOMETRIC_STEP = 1.2
# Discs larger than this radius are applied on a grid reduced by an integer factor (INTER_AREA
# down, bilinear up) so that the disc there is at most this radius.
FULL_RES_BLUR_PX = 4.0
# A view is occluded at a reference pixel when the depth map puts a surface nearer by more than
# this many pixels of view motion onto the same view pixel.
OCCLUSION_PX = 1.0
# For calibrations that are not translations, view sampling positions are interpolated linearly
# in 1/(Z - z0) between knots this many pixels of view motion apart.
KNOT_STEP_PX = 0.25


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
    above neglects that factor.

    Examples
    --------
    >>> from lfring.optics import load_device
    >>> dev = load_device("prototype")
    >>> round(aperture_from_f_number(2.8, dev), 2)  # the views sit 1.1 mm from the axis, FL 16 mm
    2.57
    """
    from lfring.optics.views import view_cameras

    f_number = check_number(f_number, "f_number", above=0.0, what="a positive number")
    cams = view_cameras(device)
    radius = float(np.linalg.norm(cams.centres_m - cams.centres_m.mean(axis=0), axis=1).mean())
    return device.main_focal_length_m / (2.0 * float(f_number)) / radius


_DISCS: dict = {}


def disc_kernel(radius_px: float) -> np.ndarray:
    """(2n+1, 2n+1) float32 disc of ``radius_px``, each tap the fraction of its pixel inside the
    disc (8 x 8 samples), normalised to sum 1."""
    key = round(float(radius_px), 3)
    kern = _DISCS.get(key)
    if kern is None:
        n = int(math.ceil(key - 0.5)) if key > 0.5 else 0
        sub = (np.arange(8) + 0.5) / 8 - 0.5
        grid = np.arange(-n, n + 1)
        xs = (grid[:, None] + sub[None, :]).ravel()
        inside = (xs[:, None] ** 2 + xs[None, :] ** 2) <= key * key
        cover = inside.reshape(2 * n + 1, 8, 2 * n + 1, 8).mean(axis=(1, 3))
        if cover.sum() == 0:
            cover[n, n] = 1.0
        kern = _DISCS.setdefault(key, (cover / cover.sum()).astype(np.float32))
    return kern


def _blur(layer: np.ndarray, radius_px: float) -> np.ndarray:
    """``layer`` (h, w, C) convolved with a disc of ``radius_px``, zero outside."""
    if radius_px < 0.5:
        return layer
    if radius_px <= FULL_RES_BLUR_PX:
        return cv2.filter2D(layer, -1, disc_kernel(radius_px), borderType=cv2.BORDER_CONSTANT)
    f = int(math.ceil(radius_px / FULL_RES_BLUR_PX))
    h, w = layer.shape[:2]
    hp, wp = -(-h // f) * f, -(-w // f) * f
    if (hp, wp) != (h, w):
        layer = cv2.copyMakeBorder(layer, 0, hp - h, 0, wp - w, cv2.BORDER_CONSTANT, value=0)
    small = cv2.resize(layer, (wp // f, hp // f), interpolation=cv2.INTER_AREA)
    # Area averaging down and bilinear up blur by f^2 / 4 px^2 per axis; a disc of radius r by r^2 / 4.
    small = cv2.filter2D(small, -1, disc_kernel(math.sqrt(radius_px**2 - f * f) / f), borderType=cv2.BORDER_CONSTANT)
    big = cv2.resize(small, (wp, hp), interpolation=cv2.INTER_LINEAR)
    return big[:h, :w]


def _extend_under(region: np.ndarray, nearer: np.ndarray, radius_px: float, threads: int = 1) -> None:
    """Fill the holes of premultiplied planes (C + 1, h, w) where ``nearer`` surfaces sit
    (coverage below 1 there) with the colour around them, out to about ``radius_px``: a blurred
    layer composited next shows, through its soft edge, the surface behind extended under it,
    as a lens looking past the edge sees it."""
    alpha = region[-1]
    hole = np.float32(1.0) - alpha
    np.maximum(hole, 0.0, out=hole)
    hole *= nearer
    if float(hole.max()) < 1e-3:
        return
    h, w = alpha.shape
    f = max(1, int(radius_px // 2))
    size = (max(1, w // f), max(1, h // f))
    k = 2 * int(math.ceil(radius_px / f)) + 1

    def spread(plane):
        return cv2.blur(cv2.resize(plane, size, interpolation=cv2.INTER_AREA), (k, k), borderType=cv2.BORDER_CONSTANT)

    weight = spread(alpha)
    inv = np.zeros_like(weight)
    np.divide(np.float32(1.0), weight, out=inv, where=weight > WEIGHT_FLOOR)
    hole *= cv2.resize((weight > WEIGHT_FLOOR).astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR)

    def fill(i):
        region[i] += hole * cv2.resize(spread(region[i]) * inv, (w, h), interpolation=cv2.INTER_LINEAR)

    run_threads([lambda i=i: fill(i) for i in range(len(region) - 1)], threads)
    region[-1] += hole


def _radius_ladder(max_px: float) -> np.ndarray:
    """Signed layer radii, ascending (far to near): 0, +-0.5, +-1, +-1.5, +-2, +-3, ...
    +-LINEAR_UNTIL_PX, then geometric."""
    r = [0.5]
    while r[-1] < max_px:
        r.append(r[-1] * GEOMETRIC_STEP if r[-1] >= LINEAR_UNTIL_PX else r[-1] + (0.5 if r[-1] < 2.0 else 1.0))
    r = np.array(r)
    return np.concatenate([-r[::-1], [0.0], r])


class DepthOfField:
    """Render a lens of any aperture focused at any depth from views and a depth map.

    Parameters
    ----------
    views : (V, h, w, C) float32 in [0, 1]
    calibration : RingCalibration
    depth_map_m : (h, w) float
        Depth of every reference pixel in metres (NaN where unknown: filled with the median
        of the known depths).
    reference : 'center' or int
        The frame of the depth map and of the results.

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

    Notes
    -----
    See the module's description. Memory: the views remapped once (V full-size images) while
    the colour is made; then a few full-size buffers per render.
    """

    def __init__(self, views, calibration, depth_map_m, *, reference="center"):
        arr = check_views(views)
        h, w = arr.shape[1:3]
        dm = np.asarray(depth_map_m, dtype=np.float64)
        if dm.shape != (h, w):
            raise InvalidInputError(f"the depth map must be {h} x {w} px like the views, got shape {dm.shape}")
        z0 = calibration.depth_origin_m
        known = np.isfinite(dm) & (dm > z0)
        if not np.any(known):
            raise InvalidInputError(f"the depth map holds no finite depth beyond the depth origin z0 = {z0:.4g} m")
        if not np.all(known):
            dm = np.where(known, dm, float(np.median(dm[known])))
        self.reference = check_reference(reference, calibration.num_views)
        self.calibration = calibration
        self.view_shape = (h, w)
        self.x = _inverse_depth(dm, z0).astype(np.float32)
        self.radius_px = aperture_radius_px(calibration, self.reference)
        masks = cached_view_masks(calibration, (h, w))
        self.colour, self.agree, self.seen = self._all_in_focus(arr, masks)

    # -- the all-in-focus colour -----------------------------------------------------------------
    def _sampling_maps(self, k_views: int):
        """Per view, the (mapx, mapy) float32 view pixel that every reference pixel samples at
        its own depth."""
        cal, (h, w), x = self.calibration, self.view_shape, self.x
        z0 = cal.depth_origin_m
        lo, hi = float(x.min()), float(x.max())
        if hi - lo < 1e-9:
            hi = lo + 1e-6
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        ends = to_reference(cal.model(z0 + 1.0 / np.array([lo, hi])), self.reference)  # (2, V, 3, 3)
        shifts = translations(ends, (h, w))
        if shifts is not None:  # affine in x: exact from the two ends
            slope = (shifts[1] - shifts[0]) / (hi - lo)
            dx = (x - np.float32(lo))
            return [(xx + np.float32(shifts[0, k, 0]) + dx * np.float32(slope[k, 0]),
                     yy + np.float32(shifts[0, k, 1]) + dx * np.float32(slope[k, 1])) for k in range(k_views)]
        # General homographies: piecewise linear in x between knots.
        corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]], dtype=np.float64)
        inv_ends = np.linalg.inv(ends)
        motion = max(np.abs(apply_homography(inv_ends[0, k], corners) - apply_homography(inv_ends[1, k], corners)).max()
                     for k in range(k_views))
        knots = np.linspace(lo, hi, max(2, int(math.ceil(motion / KNOT_STEP_PX)) + 1))
        inv = np.linalg.inv(to_reference(cal.model(z0 + 1.0 / knots), self.reference))  # (K, V, 3, 3)
        seg = np.clip(np.searchsorted(knots, x.ravel(), side="right") - 1, 0, len(knots) - 2)
        pts = np.stack([xx.ravel(), yy.ravel()], axis=1).astype(np.float64)
        out = [np.empty((h * w, 2), np.float32) for _ in range(k_views)]
        order = np.argsort(seg, kind="stable")
        bounds = np.searchsorted(seg[order], np.arange(len(knots)))
        for j in range(len(knots) - 1):
            idx = order[bounds[j]:bounds[j + 1]]
            if idx.size == 0:
                continue
            t = ((x.ravel()[idx] - knots[j]) / (knots[j + 1] - knots[j]))[:, None]
            for k in range(k_views):
                a = apply_homography(inv[j, k], pts[idx])
                b = apply_homography(inv[j + 1, k], pts[idx])
                out[k][idx] = a + t * (b - a)
        return [(o[:, 0].reshape(h, w), o[:, 1].reshape(h, w)) for o in out]

    def _visible(self, maps) -> list:
        """Per view, (h, w) bool: whether the view sees the reference pixel's own surface, i.e.
        no reference pixel nearer by more than :data:`OCCLUSION_PX` of view motion lands on
        the same view pixel (the depth map splatted into the view, nearest wins, widened by
        one pixel)."""
        h, w = self.view_shape
        x = self.x.ravel()
        tol = np.float32(OCCLUSION_PX / max(self.radius_px, 1e-12))
        out = []
        for mx, my in maps:
            ui = np.rint(mx).astype(np.int64).ravel()
            vi = np.rint(my).astype(np.int64).ravel()
            inside = (ui >= 0) & (ui < w) & (vi >= 0) & (vi < h)
            flat = vi * w + ui
            nearest = np.full(h * w, -np.inf, np.float32)
            np.maximum.at(nearest, flat[inside], x[inside])
            nearest = cv2.dilate(nearest.reshape(h, w), np.ones((3, 3), np.uint8)).ravel()
            occluded = np.zeros(h * w, bool)
            occluded[inside] = nearest[flat[inside]] > x[inside] + tol
            out.append(~occluded.reshape(h, w))
        return out

    def _all_in_focus(self, arr: np.ndarray, masks: np.ndarray):
        v, h, w, c = arr.shape
        warped = np.empty((v, h, w, c), np.float32)
        weight = np.empty((v, h, w), np.float32)
        maps = self._sampling_maps(v)
        for k, (mx, my) in enumerate(maps):
            src = arr[k] if np.all(masks[k] == 1.0) else arr[k] * masks[k][..., None]
            out = cv2.remap(src, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            warped[k] = out.reshape(h, w, c)
            weight[k] = cv2.remap(masks[k], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        present = weight > WEIGHT_FLOOR
        visible = np.stack(self._visible(maps)) & present
        # Where every view that sees the pixel is occluded by the depth map, trust the photometry alone.
        visible |= present & ~visible.any(axis=0)
        lum = luminance(warped)
        np.divide(lum, weight, out=lum, where=present)
        # The visible views' median (for up to four views: their mean without the extremes).
        n = visible.sum(axis=0)
        total = np.where(visible, lum, 0.0).sum(axis=0)
        trim = n >= 3
        top = np.where(trim, np.where(visible, lum, -np.inf).max(axis=0), 0.0)
        bottom = np.where(trim, np.where(visible, lum, np.inf).min(axis=0), 0.0)
        med = np.where(trim, (total - top - bottom) / np.maximum(n - 2, 1), total / np.maximum(n, 1)).astype(np.float32)
        dev = np.abs(lum - med)
        # The view nearest the median always counts (two groups of two: all of them).
        tol = np.maximum(np.float32(AGREE_TOL), np.where(visible, dev, np.inf).min(axis=0))
        phi = np.where(visible, np.clip(2.0 - dev / tol, 0.0, 1.0), 0.0).astype(np.float32)
        # Agreement for the in-focus blend: every view that sees the pixel, occluded or not.
        agree = np.where(present, np.clip(2.0 - dev / np.float32(AGREE_TOL), 0.0, 1.0), 1.0).min(axis=0)
        num = np.einsum("vhw,vhwc->hwc", phi, warped, optimize=True)
        den = (phi * weight).sum(axis=0)
        seen = den > WEIGHT_FLOOR
        colour = np.where(seen[..., None], num / np.where(seen, den, 1.0)[..., None], 0.0).astype(np.float32)
        return colour, np.where(n > 0, agree, 0.0).astype(np.float32), seen

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
        aperture = check_number(aperture, "aperture", minimum=0.0)
        disp = self.signed_radius_px(focus_m)
        colour = self.colour
        rho = disp * np.float32(aperture)
        if shift_and_add is not None:
            sa = np.asarray(shift_and_add, dtype=np.float32).reshape(colour.shape)
            s = np.clip((SHARP_PX + SHARP_RAMP_PX - np.abs(disp)) / SHARP_RAMP_PX, 0.0, 1.0) * self.agree
            colour = colour + s[..., None] * (sa - colour)
            # Shift-and-add is already spread over its V copies at radius |disp| (second moment
            # disp^2); a disc of radius r has r^2 / 2: blur its share only by the remainder.
            rho = np.sign(rho) * np.sqrt(np.maximum(rho * rho - 2.0 * s * disp * disp, 0.0))
        rmax = float(np.abs(rho).max())
        if rmax < 0.5:
            return np.where(self.seen[..., None], colour, 0.0).astype(np.float32)
        return self._composite(colour, rho, rmax)

    def _composite(self, colour: np.ndarray, rho: np.ndarray, rmax: float) -> np.ndarray:
        h, w, c = colour.shape
        ladder = _radius_ladder(rmax)
        # Fractional rung of every pixel; layer j takes the pixels nearest to it (|q - j| < 1/2).
        q = np.interp(rho.ravel(), ladder, np.arange(len(ladder), dtype=np.float64)).astype(np.float32).reshape(h, w)
        row_lo, row_hi = q.min(axis=1), q.max(axis=1)
        col_lo, col_hi = q.min(axis=0), q.max(axis=0)
        # Planar (C + 1, h, w) premultiplied colour and coverage: per-plane operations are the fastest.
        prem = np.empty((c + 1, h, w), np.float32)
        for i, plane in enumerate(cv2.split(colour)):
            prem[i] = plane
        prem[c] = self.seen
        if not np.all(self.seen):
            prem[:c, ~self.seen] = 0.0
        acc = np.zeros((c + 1, h, w), np.float32)
        threads = cv2.getNumThreads()
        for j, radius in enumerate(ladder):
            rows = np.flatnonzero((row_lo < j + 1) & (row_hi > j - 1))
            cols = np.flatnonzero((col_lo < j + 1) & (col_hi > j - 1))
            if rows.size == 0 or cols.size == 0:
                continue
            pad = int(math.ceil(abs(radius))) + 1
            y0, y1 = max(0, rows[0] - pad), min(h, rows[-1] + pad + 1)
            x0, x1 = max(0, cols[0] - pad), min(w, cols[-1] + pad + 1)
            qq = q[y0:y1, x0:x1]
            tent = ((qq >= j - 0.5) & (qq < j + 0.5)).astype(np.float32)  # the layer's own pixels
            if abs(radius) >= 1.0:  # a soft edge: what lies behind must reach under this layer and nearer ones
                _extend_under(acc[:, y0:y1, x0:x1], (qq >= j - 0.5).astype(np.float32), abs(float(radius)), threads)
            layer = [None] * (c + 1)

            def blur(i, y0=y0, y1=y1, x0=x0, x1=x1, tent=tent, radius=abs(float(radius))):
                layer[i] = _blur(cv2.multiply(prem[i, y0:y1, x0:x1], tent), radius)

            def over(i, y0=y0, y1=y1, x0=x0, x1=x1):
                # "over": a nearer layer (later) covers what is already there by its coverage.
                region = acc[i, y0:y1, x0:x1]
                cv2.multiply(region, cover, dst=region)
                cv2.add(region, layer[i], dst=region)

            run_threads([lambda i=i: blur(i) for i in range(c + 1)], threads)
            cover = np.float32(1.0) - layer[c]
            run_threads([lambda i=i: over(i) for i in range(c + 1)], threads)
        alpha = acc[c]
        inv = np.zeros((h, w), np.float32)
        np.divide(np.float32(1.0), alpha, out=inv, where=alpha > WEIGHT_FLOOR)
        planes = [acc[i] * inv for i in range(c)]
        return planes[0][..., None] if c == 1 else cv2.merge(planes)


def resolve_aperture(calibration, aperture=None, f_number=None, ring_device=None) -> float:
    """The depth-aware ``aperture`` (1: the disc through the views, 0: a pinhole) from either
    ``aperture`` or ``f_number`` (1.0 when neither is given).

    ``f_number`` needs the device: ``ring_device`` (a :class:`lfring.optics.RingDevice` with
    its positions), or else the built-in device the calibration was made from (calibrations
    from the optics name it), set to the positions the calibration records. See
    :func:`aperture_from_f_number` for the relation.
    """
    if aperture is not None and f_number is not None:
        raise InvalidInputError("give the depth of field as aperture or as f_number, not both")
    if f_number is None:
        return check_number(1.0 if aperture is None else aperture, "aperture", minimum=0,
                            hint=" (1: the views' aperture, 0: a pinhole)")
    if ring_device is None:
        if calibration.device is None:
            raise InvalidInputError(
                "f_number needs the device (its main lens's focal length and where the views sit in its aperture): "
                "pass ring_device=, or use aperture= (1 is the aperture the views span)"
            )
        from lfring.optics.device import load_device

        ring_device = load_device(calibration.device)
        prov = calibration.provenance
        if prov.get("ring_distance_m") is not None and prov.get("sensor_distance_m") is not None:
            ring_device = ring_device.with_positions(prov["ring_distance_m"], prov["sensor_distance_m"])
    return aperture_from_f_number(f_number, ring_device)


def _depth_map(arr, calibration, depth, zmin_m, zmax_m, reference) -> np.ndarray:
    """The depth map of the views in the reference frame: given, or estimated."""
    h, w = arr.shape[1:3]
    if depth is None:
        lo, hi = calibration.valid_depth_range_m
        zmin_m = lo if zmin_m is None else zmin_m
        zmax_m = hi if zmax_m is None else zmax_m
        if zmax_m is None:
            raise InvalidInputError("the calibration has no upper depth bound: give zmax_m (or a depth map as depth=)")
        depth = estimate_depth(arr, calibration, zmin_m=float(zmin_m), zmax_m=float(zmax_m), reference=reference)
    elif zmin_m is not None or zmax_m is not None:
        raise InvalidInputError("zmin_m/zmax_m set the range of the depth estimation: give them or a depth map, not both")
    if isinstance(depth, DepthResult):
        if depth.reference != reference:
            raise InvalidInputError(f"the depth map is in the frame of reference {depth.reference!r}, the refocusing in {reference!r}")
        depth = depth.depth_m
    dm = np.asarray(depth, dtype=np.float64)
    if dm.shape != (h, w):
        raise InvalidInputError(f"the depth map must be (h, w) = ({h}, {w}) metres like the views, got shape {dm.shape}")
    return dm


def depth_of_field(views, calibration, *, depth=None, zmin_m=None, zmax_m=None, reference="center") -> DepthOfField:
    """A :class:`DepthOfField` renderer of the views: from a depth map (``depth``, a
    :class:`lfring.DepthResult` or (h, w) metres in the reference frame), or one estimated over
    ``zmin_m``..``zmax_m`` (by default the calibration's valid range). Reuse it to render many
    focus depths and apertures from one depth map."""
    arr = check_views(views)
    ref = check_reference(reference, calibration.num_views)
    return DepthOfField(arr, calibration, _depth_map(arr, calibration, depth, zmin_m, zmax_m, ref), reference=ref)


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

