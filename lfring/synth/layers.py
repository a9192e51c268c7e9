"""Surfaces rendered as layers: each surface of a scene, seen from one pinhole camera, becomes a
layer of premultiplied colour, coverage and depth, blurred by its own defocus disc; the layers
are composited front to back.

Every view of the ring is the pinhole camera of :mod:`lfring.optics.views`, so a plane maps to
a view by a homography and a height field by a short fixed-point iteration along each chief ray.
The raw-frame renderer (:mod:`lfring.synth.renderer`) and the conventional image
(:mod:`lfring.synth.conventional`) both render their cameras through :class:`SurfaceRenderer`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import cv2
import numpy as np

from lfring.core.validate import is_integer
from lfring.errors import InvalidInputError
from lfring.optics.device import RingDevice
from lfring.optics.paraxial import blur_diameter_m
from lfring.optics.views import ViewCameras, view_cameras
from lfring.synth.defocus import defocus_layer
from lfring.synth.scene import HeightField, Plane, Scene
from lfring.synth.settings import RenderSettings
from lfring.synth.textures import rasterize

__all__ = ["BLOCK_ROWS", "Layer", "SurfaceRenderer", "default_workers", "over"]

#: fixed-point steps along each chief ray on an analytic (curved) height field: each step
#: shrinks the error by the surface slope times the ray's angle to the axis (the prototype's
#: views reach about 0.2 rad), so 60 steps converge to double precision on slopes up to 3.
_CURVED_ITERATIONS = 60

#: rows per block of the memory-bound per-pixel passes: the temporaries stay in cache and are
#: reused instead of being fresh (page-faulted) arrays the size of a layer.
BLOCK_ROWS = 64


def default_workers() -> int:
    """Threads for the views, texture rasters and sensor stripes: the heavy work is in OpenCV
    and NumPy loops that release the GIL; four views bound the useful count."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(4, cores))


@dataclass
class Layer:
    """One surface's rendering over a box of pixels whose top-left pixel is (x0, y0)."""

    x0: int
    y0: int
    rgba: np.ndarray  # (h, w, 4) premultiplied colour and coverage
    depth: np.ndarray  # (h, w) Z in metres, inf where not covered
    zmin: float
    name: str


class SurfaceRenderer:
    """Renders the surfaces of ``scene`` as layers seen from the pinhole cameras ``cams``
    (default: the views of ``device``), in the raw pixel grid of ``device``.

    Layers are asked for by camera (``key``: a view, or another camera of ``cams``) and by a
    raw-pixel ``region`` (x, y, w, h); each surface's texture is rasterised once, at the texel
    that matches a pixel's footprint at its nearest depth, and kept for every camera.
    """

    def __init__(self, device: RingDevice, scene: Scene, settings: RenderSettings):
        self.dev = device
        self.scene = scene
        self.settings = settings
        self.cams: ViewCameras = view_cameras(device)
        self.tp = device.pixel_pitch_m
        self._textures: dict[int, tuple] = {}
        # Each camera's lens distortion in raw pixels (None: pinhole cameras), the region over
        # which its pixels' ideal positions are kept, and those positions.
        self.distortions = None
        self.regions: list | None = None
        self._ideal: dict = {}
        s = self.cams.depth_origin_m
        for idx, surf in enumerate(scene.surfaces):
            znear = surf.depth_range_m[0]
            if znear <= s * 1.05:
                raise InvalidInputError(
                    f"surface {surf.name or idx} reaches Z = {znear:.4g} m, not beyond the views' "
                    f"entrance pupil at {s:.4g} m: move it farther away"
                )

    # -- geometry helpers --------------------------------------------------------------------
    def blur_px(self, z: np.ndarray) -> np.ndarray:
        """Defocus disc diameter in pixels for surfaces at Z (:func:`lfring.optics.paraxial.blur_diameter_m`);
        NaN where Z is."""
        z = np.asarray(z, dtype=np.float64)
        out = np.full(z.shape, np.nan)
        finite = np.isfinite(z)
        out[finite] = blur_diameter_m(self.dev, z[finite]) / self.tp
        return out

    # -- real mini-lenses ----------------------------------------------------------------------
    def ideal_px(self, view, x0: int, y0: int, w: int, h: int) -> np.ndarray | None:
        """(h, w, 2) float64 ideal (pinhole) raw-pixel position of every pixel of the box: where
        the chief ray that reaches the pixel through its distorting mini-lens would land through
        an ideal one. None for an ideal lens. Computed once per view over its region."""
        if self.distortions is None or not is_integer(view) or view >= len(self.distortions):
            return None
        if view not in self._ideal:
            rx, ry, rw, rh = self.regions[view]
            ideal = self.distortions[view].undistort_box(rx, ry, rw, rh)
            yy, xx = np.mgrid[ry : ry + rh, rx : rx + rw]
            self._ideal[view] = ideal, float(np.max(np.hypot(ideal[..., 0] - xx, ideal[..., 1] - yy), initial=0.0))
        rx, ry = self.regions[view][:2]
        return self._ideal[view][0][y0 - ry : y0 - ry + h, x0 - rx : x0 - rx + w]

    def distortion_margin_px(self, view) -> float:
        """How far the lens of ``view`` moves any point of its region (0 for an ideal lens)."""
        if self.ideal_px(view, 0, 0, 0, 0) is None:
            return 0.0
        return self._ideal[view][1]

    def _pixel_rays(self, view: int, x0: int, y0: int, w: int, h: int):
        dev = self.dev
        ideal = self.ideal_px(view, x0, y0, w, h)
        if ideal is not None:  # each pixel's chief ray, bent by its lens: (h, w) directions
            xs = (ideal[..., 0] + 0.5 - dev.sensor_width_px / 2.0) * self.tp
            ys = (ideal[..., 1] + 0.5 - dev.sensor_height_px / 2.0) * self.tp
            return ((xs - self.cams.principal_points_m[view, 0]) / self.cams.focal_m,
                    (ys - self.cams.principal_points_m[view, 1]) / self.cams.focal_m)
        xs = (np.arange(x0, x0 + w) + 0.5 - dev.sensor_width_px / 2.0) * self.tp
        ys = (np.arange(y0, y0 + h) + 0.5 - dev.sensor_height_px / 2.0) * self.tp
        dx = (xs - self.cams.principal_points_m[view, 0]) / self.cams.focal_m
        dy = (ys - self.cams.principal_points_m[view, 1]) / self.cams.focal_m
        return dx[None, :], dy[:, None]

    def _project_px(self, view: int, pts: np.ndarray) -> np.ndarray:
        """World points (N, 3) -> raw pixel (col, row) of view ``view``."""
        s = self.cams.project_m(pts)[view]
        return s / self.tp + np.array([self.dev.sensor_width_px, self.dev.sensor_height_px]) / 2.0 - 0.5

    def _bbox(self, view, pts, region, margin):
        px = self._project_px(view, pts)
        rx, ry, rw, rh = region
        x0 = max(rx, int(np.floor(px[:, 0].min() - margin)))
        y0 = max(ry, int(np.floor(px[:, 1].min() - margin)))
        x1 = min(rx + rw, int(np.ceil(px[:, 0].max() + margin)) + 1)
        y1 = min(ry + rh, int(np.ceil(px[:, 1].max() + margin)) + 1)
        if x1 <= x0 or y1 <= y0:
            return None
        return x0, y0, x1 - x0, y1 - y0

    def texel_m(self, depth_m):
        """Texel size (metres) matched to a view pixel's footprint at ``depth_m``: textures are
        rasterised at that of a surface's nearest depth."""
        return self.tp * (depth_m - self.cams.depth_origin_m) / self.cams.focal_m

    # -- surfaces ----------------------------------------------------------------------------
    def _plane_texture(self, idx: int, plane: Plane):
        if idx not in self._textures:
            zmin, zmax = plane.depth_range_m
            # Kept a NumPy float64: the mip blend (plane_layer) divides float32 footprints by
            # it, which NumPy then does in double precision.
            texel = self.texel_m(np.float64(zmin))
            rgba = rasterize(plane.texture, plane.size_m, texel, alpha=True)  # opaque RGBA
            rows, cols = rgba.shape[:2]
            if plane.shape == "disk":
                yy = (np.arange(rows) + 0.5) / rows * 2 - 1
                xx = (np.arange(cols) + 0.5) / cols * 2 - 1
                r = np.sqrt(xx[None, :] ** 2 + yy[:, None] ** 2)
                # anti-aliased edge about one texel wide
                alpha = np.clip((1 - r) * min(rows, cols) / 2 + 0.5, 0, 1).astype(np.float32)
                rgba *= alpha[..., None]  # premultiplied colour, and alpha itself (1 * alpha)
            levels = [rgba]
            # Mip levels for the far side of slanted planes (minification > ~1.5 texels/pixel).
            ratio = (zmax - self.cams.depth_origin_m) / (zmin - self.cams.depth_origin_m)
            while ratio > 1.5 and min(levels[-1].shape[:2]) > 8:
                levels.append(cv2.pyrDown(levels[-1]))
                ratio /= 2
            # Texels tile the plane exactly at every level: (width / cols, height / rows).
            steps = [(plane.size_m[0] / lv.shape[1], plane.size_m[1] / lv.shape[0]) for lv in levels]
            self._textures[idx] = (texel, levels, steps)
        return self._textures[idx]

    def plane_layer(self, idx: int, plane: Plane, view: int, region) -> Layer | None:
        """Plane ``idx`` seen from camera ``view`` over ``region``: its texture warped by the
        plane's homography, its depth by ray-plane intersection; None where it is not seen."""
        texel, levels, steps = self._plane_texture(idx, plane)
        corners = plane.corners_m()
        zs = corners[:, 2]
        margin = 2 + (np.ceil(self.blur_px(zs).max() / 2) if self.settings.defocus else 0)
        margin += np.ceil(self.distortion_margin_px(view)) if self.distortions is not None else 0
        box = self._bbox(view, corners, region, margin)
        if box is None:
            return None
        x0, y0, w, h = box
        p0, u, v, n = plane.axes()
        wm, hm = plane.size_m
        tl = p0 - wm / 2 * u - hm / 2 * v
        cam = np.array([*self.cams.centres_m[view], self.cams.depth_origin_m])
        f = self.cams.focal_m
        pp = self.cams.principal_points_m[view]
        W, H = self.dev.sensor_width_px, self.dev.sensor_height_px
        pix_from_sensor = np.array([[1 / self.tp, 0, W / 2 - 0.5 - x0], [0, 1 / self.tp, H / 2 - 0.5 - y0], [0, 0, 1]])
        k = np.array([[f, 0, pp[0]], [0, f, pp[1]], [0, 0, 1]])
        dx, dy = self._pixel_rays(view, x0, y0, w, h)
        # Ray-plane intersection: Z = s + n.(P0 - C) / n.(dx, dy, 1).
        if n[0] == 0 and n[1] == 0:  # fronto-parallel: n.(dx, dy, 1) is n_z at every pixel
            depth = np.full((h, w), self.cams.depth_origin_m + float(n @ (p0 - cam)) / n[2], np.float32)
        else:
            denom = n[0] * dx + n[1] * dy + n[2]
            depth = (self.cams.depth_origin_m + float(n @ (p0 - cam)) / denom).astype(np.float32)
        ideal = self.ideal_px(view, x0, y0, w, h)
        warped = []
        for tex, (tx, ty) in zip(levels, steps):
            a = np.column_stack([tx * u, ty * v, tl + 0.5 * (tx * u + ty * v) - cam])
            hmat = pix_from_sensor @ k @ a
            if ideal is None:
                warped.append(cv2.warpPerspective(tex, hmat, (w, h), flags=cv2.INTER_LINEAR,
                                                  borderMode=cv2.BORDER_CONSTANT))
                continue
            # A distorting lens: each pixel samples the texel its bent chief ray meets.
            inv = np.linalg.inv(hmat)
            bx, by = ideal[..., 0] - x0, ideal[..., 1] - y0
            den = inv[2, 0] * bx + inv[2, 1] * by + inv[2, 2]
            mx = ((inv[0, 0] * bx + inv[0, 1] * by + inv[0, 2]) / den).astype(np.float32)
            my = ((inv[1, 0] * bx + inv[1, 1] * by + inv[1, 2]) / den).astype(np.float32)
            warped.append(cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT))
        if len(warped) == 1:
            acc = warped[0]
        else:
            # Trilinear mip blend by the local minification (pixel footprint / base texel).
            lod = np.log2(np.maximum(self.texel_m(depth) / texel, 1.0))
            lod = np.clip(lod, 0, len(warped) - 1)
            lo = np.floor(lod)
            fr = (lod - lo).astype(np.float32)  # exact: a number minus its floor
            # Gather level lo and lo + 1 per pixel by masks (no stacked copy of the levels).
            acc = warped[-1].copy()
            upper = warped[-1].copy()
            for i in range(len(warped) - 1):
                at = (lo == i).view(np.uint8)
                cv2.copyTo(warped[i], at, acc)
                cv2.copyTo(warped[i + 1], at, upper)
            w_lo, w_hi = 1 - fr, fr
            acc *= cv2.merge([w_lo] * 4)  # per-channel weights (broadcasting over 4 is slow)
            upper *= cv2.merge([w_hi] * 4)
            acc += upper
        depth[acc[..., 3] <= 1e-4] = np.inf
        return Layer(x0, y0, acc, depth, float(zs.min()), plane.name or f"surface {idx}")

    def _heightfield_texture(self, idx: int, part: HeightField):
        wm, hm = part.size_m
        if idx not in self._textures:
            texel = self.texel_m(part.depth_range_m[0])
            rgb = rasterize(part.texture, part.size_m, texel)
            heights = part.height_map((wm / rgb.shape[1], hm / rgb.shape[0]), rgb.shape[:2])
            if part.shading:
                rgb = rgb * part.shading_map(heights, (wm / rgb.shape[1], hm / rgb.shape[0]))[..., None]
            rgba = np.dstack([rgb, np.ones(rgb.shape[:2], np.float32)]).astype(np.float32)
            steps = (wm / rgba.shape[1], hm / rgba.shape[0])
            self._textures[idx] = (steps, rgba, heights)
        return self._textures[idx]

    def prepare_texture(self, idx: int) -> None:
        """Rasterise surface ``idx`` once, before the views that share it are rendered."""
        surf = self.scene.surfaces[idx]
        if isinstance(surf, Plane):
            self._plane_texture(idx, surf)
        else:
            self._heightfield_texture(idx, surf)

    def heightfield_layer(self, idx: int, part: HeightField, view: int, region) -> Layer | None:
        """Part ``idx`` seen from camera ``view`` over ``region``: each chief ray followed to the
        height field; None where the part is not seen."""
        wm, hm = part.size_m
        (tx, ty), rgba, heights = self._heightfield_texture(idx, part)
        zlo = part.depth_m - max(float(heights.max()), 0.0)
        zhi = part.depth_m - min(float(heights.min()), 0.0)
        cx, cy = part.center_m
        corners = np.array([[cx + sx * wm / 2, cy + sy * hm / 2, z] for sx in (-1, 1) for sy in (-1, 1) for z in (zlo, zhi)])
        margin = 2 + (np.ceil(self.blur_px(np.array([zlo, zhi])).max() / 2) if self.settings.defocus else 0)
        margin += np.ceil(self.distortion_margin_px(view)) if self.distortions is not None else 0
        box = self._bbox(view, corners, region, margin)
        if box is None:
            return None
        x0, y0, w, h = box
        dx, dy = self._pixel_rays(view, x0, y0, w, h)
        s = self.cams.depth_origin_m
        ox, oy = self.cams.centres_m[view]
        left, top = cx - wm / 2, cy - hm / 2
        if part.curved:
            # Spheres and cylinders: walk the chief ray on the analytic surface, from the
            # highest point down, so the depth is exact and the nearest crossing is the one
            # found (a ray that meets a raised surface beyond the footprint's edge included).
            z = np.full((h, w), zlo, np.float64)
            for _ in range(_CURVED_ITERATIONS):
                z = part.depth_m - part.height_at(ox + (z - s) * dx - left, oy + (z - s) * dy - top)
            mx = ((ox + (z - s) * dx - left) / tx - 0.5).astype(np.float32)
            my = ((oy + (z - s) * dy - top) / ty - 0.5).astype(np.float32)
        else:
            z = np.full((h, w), part.depth_m, np.float64)
            for _ in range(12):
                mx = ((ox + (z - s) * dx - left) / tx - 0.5).astype(np.float32)
                my = ((oy + (z - s) * dy - top) / ty - 0.5).astype(np.float32)
                hz = cv2.remap(heights, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
                z = part.depth_m - hz.astype(np.float64)
        acc = cv2.remap(rgba, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        depth = np.where(acc[..., 3] > 1e-4, z, np.inf).astype(np.float32)
        return Layer(x0, y0, acc, depth, zlo, part.name or f"surface {idx}")

    def layers(self, key, region) -> list[Layer]:
        """Every surface's layer over ``region`` seen from camera ``key``, near to far, checked
        for a consistent occlusion order."""
        layers = []
        for idx, surf in enumerate(self.scene.surfaces):
            fn = self.plane_layer if isinstance(surf, Plane) else self.heightfield_layer
            lay = fn(idx, surf, key, region)
            if lay is not None:
                layers.append(lay)
        layers.sort(key=lambda la: la.zmin)
        _check_order(layers)
        return layers

    def defocus(self, lay: Layer) -> np.ndarray:
        """The layer's premultiplied colour blurred by the defocus disc of its depth (:meth:`blur_px`)."""
        return defocus_layer(lay.rgba, lay.depth, self.blur_px)


def _check_order(layers: list[Layer]) -> None:
    """Layers are composited in order of their nearest point. Refuse scenes where that order
    is wrong somewhere (a later layer in front of an earlier one on the same pixel), since the
    colours there would be wrong; the depth ground truth alone would still be right."""
    for i, a in enumerate(layers):
        for b in layers[i + 1 :]:
            x0, y0 = max(a.x0, b.x0), max(a.y0, b.y0)
            x1 = min(a.x0 + a.depth.shape[1], b.x0 + b.depth.shape[1])
            y1 = min(a.y0 + a.depth.shape[0], b.y0 + b.depth.shape[0])
            if x1 <= x0 or y1 <= y0:
                continue
            da = a.depth[y0 - a.y0 : y1 - a.y0, x0 - a.x0 : x1 - a.x0]
            db = b.depth[y0 - b.y0 : y1 - b.y0, x0 - b.x0 : x1 - b.x0]
            both = np.isfinite(da) & np.isfinite(db)
            if np.any(db[both] < da[both] - 1e-9):
                raise InvalidInputError(
                    f"surfaces '{a.name}' and '{b.name}' interleave in depth where they overlap in the "
                    "image; the renderer composites surfaces in order of their nearest point, so move "
                    "one so that it is entirely in front of the other where they overlap"
                )



def over(acc: np.ndarray, rgba: np.ndarray) -> None:
    """Front-to-back 'over' compositing of a premultiplied layer behind ``acc`` (in place):
    ``acc += (1 - acc_alpha) rgba``."""
    for r in range(0, acc.shape[0], BLOCK_ROWS):
        a, c = acc[r : r + BLOCK_ROWS], rgba[r : r + BLOCK_ROWS]
        t = 1.0 - a[..., 3]
        t = cv2.merge([t, t, t, t])  # transmittance per channel (NumPy broadcasting over 4 is slow)
        t *= c
        a += t
