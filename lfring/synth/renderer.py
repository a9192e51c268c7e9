"""The synthetic twin: raw frames rendered from the paraxial model, with ground truth (SPEC 3).

Every view is the pinhole camera of :mod:`lfring.optics.views`, so a plane maps to a view by a
homography and a height field by a short fixed-point iteration along each chief ray. Each
surface is rendered as a layer (premultiplied colour, coverage, depth), blurred by its own
defocus disc (SPEC 2.3, the blur varying with depth across slanted and curved surfaces), and the
layers are composited front to back. Then come per-view vignetting and the iris field stop, the
optional 180-degree rotation, the Bayer mosaic, shot and read noise, and quantisation.

The views render on parallel threads (the heavy loops are OpenCV's and NumPy's, which release
the GIL) while the noise is drawn on another; every thread writes its own part of the outputs,
so the frame is the same whatever the number of threads (``benchmarks/bench_render.py``).
"""

from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass

import cv2
import numpy as np

from lfring.errors import InvalidInputError
from lfring.io.bayer import mosaic, validate_pattern
from lfring.optics.device import RingDevice
from lfring.optics.paraxial import blur_diameter_m
from lfring.optics.views import (
    ViewCameras,
    lit_region,
    optical_homographies,
    optical_layout,
    view_cameras,
    vignetting_region,
)
from lfring.core.records import record_repr
from lfring.synth.scene import HeightField, Plane, Scene
from lfring.synth.textures import raster_shape, rasterize
from lfring.views import Layout, split_views

__all__ = [
    "RenderSettings",
    "RenderResult",
    "render",
    "render_conventional",
    "conventional_aperture_radius_m",
    "conventional_blur_px",
    "conventional_sample_count",
    "viewpoint_radius_m",
    "aperture_samples",
    "NOISE_PRESETS",
    "BIT_DEPTHS",
    "disc_kernel",
    "view_falloff_map",
]

#: full well (electrons at full scale) and read noise (electrons rms) per output pixel.
NOISE_PRESETS = {"none": None, "low": (30000.0, 1.5), "realistic": (8000.0, 3.0), "high": (2000.0, 6.0)}
BIT_DEPTHS = (8, 12, 16)
_DEFAULT_BLACK = {8: 4, 12: 64, 16: 1024}


@dataclass(frozen=True)
class RenderSettings:
    """How the twin's sensor records the scene.

    binning : sensor binning factor (2 gives the 2456 x 1842 px, 2.5 um twin of the prototype).
    pattern : Bayer pattern of the raw frame, or None for an RGB frame.
    bit_depth : 8, 12 or 16 bits per sample. black_level : counts of a dark pixel (default
        4, 64, 1024 for 8, 12, 16 bits); the white level is 2**bit_depth - 1.
    noise : 'none', 'low', 'realistic' or 'high' (see NOISE_PRESETS); gain divides the
        electrons that reach full scale (more gain, more relative noise).
    exposure : fraction of full scale that a white (radiance 1), unvignetted surface reaches.
    rotate180 : output the frame rotated by 180 degrees, as cameras reading the erect image do.
    defocus, vignetting : physical effects, on by default (turn off only to isolate geometry).
    view_falloff : None, or per view (strength, dx, dy): an extra radial fall-off
        ``1 / (1 + strength rho**2)**2`` multiplying that view's optical vignetting, rho being
        the distance from the view's valid-disc centre moved by (dx, dy) disc radii, in disc
        radii. Different per view, it stands for lenses that are not quite alike (scenes that
        should not favour methods assuming equal views); off with ``vignetting=False``.
    """

    binning: int = 1
    pattern: str | None = "RGGB"
    bit_depth: int = 12
    noise: str = "none"
    gain: float = 1.0
    exposure: float = 0.8
    black_level: int | None = None
    rotate180: bool = False
    seed: int = 0
    defocus: bool = True
    vignetting: bool = True
    view_falloff: tuple | None = None

    def __post_init__(self) -> None:
        if self.view_falloff is not None:
            try:
                fall = tuple(tuple(float(v) for v in t) for t in self.view_falloff)
            except (TypeError, ValueError):
                fall = ()
            if len(fall) != 4 or any(len(t) != 3 or not all(np.isfinite(t)) or t[0] < 0 or max(abs(t[1]), abs(t[2])) > 1
                                     for t in fall):
                raise InvalidInputError(
                    "view_falloff must be four (strength >= 0, dx, dy) triples, one per view, with |dx|, |dy| <= 1, "
                    f"got {self.view_falloff!r}")
            object.__setattr__(self, "view_falloff", fall)
        if isinstance(self.binning, bool) or not isinstance(self.binning, (int, np.integer)) or self.binning < 1:
            raise InvalidInputError(f"binning must be an integer >= 1, got {self.binning!r}")
        if self.pattern is not None:
            object.__setattr__(self, "pattern", validate_pattern(self.pattern))
        if self.bit_depth not in BIT_DEPTHS:
            raise InvalidInputError(f"bit_depth must be one of {BIT_DEPTHS}, got {self.bit_depth!r}")
        if self.noise not in NOISE_PRESETS:
            raise InvalidInputError(f"noise must be one of {', '.join(NOISE_PRESETS)}, got {self.noise!r}")
        if not (np.isfinite(self.gain) and self.gain > 0):
            raise InvalidInputError(f"gain must be > 0, got {self.gain!r}")
        if not (np.isfinite(self.exposure) and 0 < self.exposure <= 4):
            raise InvalidInputError(f"exposure must be in (0, 4], got {self.exposure!r}")
        if self.black_level is not None and not 0 <= self.black_level < self.white_level // 2:
            raise InvalidInputError(f"black_level must be in [0, {self.white_level // 2}), got {self.black_level!r}")

    @property
    def white_level(self) -> int:
        """Counts at saturation: ``2**bit_depth - 1``."""
        return 2**self.bit_depth - 1

    @property
    def effective_black_level(self) -> int:
        """The black level in counts: ``black_level``, or the default for ``bit_depth`` when None."""
        return _DEFAULT_BLACK[self.bit_depth] if self.black_level is None else int(self.black_level)


@dataclass(frozen=True, eq=False)
class RenderResult:
    """A rendered raw frame and its ground truth.

    raw : (H, W) uint8/uint16 Bayer mosaic (or (H, W, 3) without a pattern), as the camera
        outputs it (rotated when ``settings.rotate180``).
    image : (H, W, 3) float32, the noise-free linear image in [0, 1] in the raw frame's
        orientation: what ``(raw - black) / (white - black)`` estimates at every pixel.
    views : (V, h, w, 3) float32, ``image`` cut by the layout (vignetting and defocus included).
    views_sharp : (V, h, w, 3) float32, the same views without defocus or vignetting.
    depth_m : (V, h, w) float32, distance Z of the visible surface from the main lens, NaN where
        no surface is seen.
    layout, device (binned when asked), settings, scene.
    """

    raw: np.ndarray
    image: np.ndarray
    views: np.ndarray
    views_sharp: np.ndarray
    depth_m: np.ndarray
    layout: Layout
    device: RingDevice
    settings: RenderSettings
    scene: Scene

    __repr__ = record_repr

    def homographies(self, depth_m, *, reference="center") -> np.ndarray:
        """Exact ``H_ref_from_view`` of a fronto-parallel plane at ``depth_m`` (SPEC 4)."""
        return optical_homographies(self.device, self.layout, depth_m, reference=reference)

    @property
    def black_level(self) -> int:
        """Black level of ``raw`` in counts."""
        return self.settings.effective_black_level

    @property
    def white_level(self) -> int:
        """White level (saturation) of ``raw`` in counts."""
        return self.settings.white_level

    def metadata(self) -> dict:
        """JSON-ready description of the render (device, settings, layout, levels)."""
        return {
            "device": self.device.to_dict(),
            "ring_distance_m": self.device.ring_distance_m,
            "sensor_distance_m": self.device.sensor_distance_m,
            "entrance_pupil_m": self.device.entrance_pupil_m,
            "settings": _settings_dict(self.settings),
            "black_level": self.black_level,
            "white_level": self.white_level,
            "pattern": self.settings.pattern,
            "layout": self.layout.to_dict(),
        }


def _settings_dict(settings: RenderSettings) -> dict:
    """The settings as a dict; ``view_falloff`` only when set (so frames without it are
    described as before it existed)."""
    d = asdict(settings)
    if d["view_falloff"] is None:
        del d["view_falloff"]
    return d


def view_falloff_map(layout: Layout, view: int, rect: tuple[int, int, int, int], falloff) -> np.ndarray:
    """(h, w) float32 extra fall-off of ``RenderSettings.view_falloff`` for view ``view`` over the
    raw-pixel rectangle ``rect`` (x, y, w, h) of the erect frame, around the view's valid disc
    ``layout.circles[view]`` (an unrotated layout; circles are in view pixels)."""
    strength, ox, oy = falloff[view]
    lx, ly, r = layout.circles[view]
    cx, cy = layout.rects[view][0] + lx, layout.rects[view][1] + ly
    x, y, w, h = rect
    xs = (np.arange(x, x + w) - (cx + ox * r)) / r
    ys = (np.arange(y, y + h) - (cy + oy * r)) / r
    rho2 = xs[None, :] ** 2 + ys[:, None] ** 2
    return (1.0 / (1.0 + strength * rho2) ** 2).astype(np.float32)


# ------------------------------------------------------------------------------------------------
def disc_kernel(diameter_px: float) -> np.ndarray | None:
    """Normalised pillbox of the given diameter, anti-aliased by 8 x 8 supersampling; None
    below 1 px (a blur smaller than a pixel is left to the pixel itself)."""
    if not diameter_px >= 1.0:
        return None
    r = diameter_px / 2.0
    half = int(np.ceil(r - 0.5))
    n = 2 * half + 1
    sub = (np.arange(n * 8) + 0.5) / 8.0 - n / 2.0
    inside = (sub[None, :] ** 2 + sub[:, None] ** 2) <= r * r
    k = inside.reshape(n, 8, n, 8).mean(axis=(1, 3)).astype(np.float32)
    return k / k.sum()


def _blur(layer: np.ndarray, diameter_px: float) -> np.ndarray:
    return _convolve(layer, disc_kernel(diameter_px))


def _convolve(layer: np.ndarray, k: np.ndarray | None) -> np.ndarray:
    if k is None:
        return layer
    # filter2D correlates; the disc is symmetric, so this is the convolution. Zero outside.
    return cv2.filter2D(layer, -1, k, borderType=cv2.BORDER_CONSTANT)


#: fixed-point steps along each chief ray on an analytic (curved) height field: each step
#: shrinks the error by the surface slope times the ray's angle to the axis (the prototype's
#: views reach about 0.2 rad), so 60 steps converge to double precision on slopes up to 3.
_CURVED_ITERATIONS = 60

#: rows per block of the memory-bound per-pixel passes: the temporaries stay in cache and are
#: reused instead of being fresh (page-faulted) arrays the size of a layer.
_BLOCK_ROWS = 64


def _workers() -> int:
    """Threads for the views, texture rasters and sensor stripes: the heavy work is in OpenCV
    and NumPy loops that release the GIL; four views bound the useful count."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(4, cores))


@dataclass
class _Layer:
    x0: int
    y0: int
    rgba: np.ndarray  # (h, w, 4) premultiplied colour and coverage
    depth: np.ndarray  # (h, w) Z in metres, inf where not covered
    zmin: float
    name: str


def _sorted_layers(renderer, key, region) -> list:
    """Every surface's layer over ``region`` seen from ``key`` (a view, or an aperture sample),
    near to far, checked for a consistent occlusion order."""
    layers = []
    for idx, surf in enumerate(renderer.scene.surfaces):
        fn = renderer.plane_layer if isinstance(surf, Plane) else renderer.heightfield_layer
        lay = fn(idx, surf, key, region)
        if lay is not None:
            layers.append(lay)
    layers.sort(key=lambda la: la.zmin)
    _check_order(layers)
    return layers


def _check_order(layers: list[_Layer]) -> None:
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


class _Renderer:
    def __init__(self, device: RingDevice, scene: Scene, settings: RenderSettings):
        self.dev = device
        self.scene = scene
        self.settings = settings
        self.cams: ViewCameras = view_cameras(device)
        self.tp = device.pixel_pitch_m
        self._textures: dict[int, tuple] = {}
        self.regions = [lit_region(device, k) for k in range(4)]
        self.erect_layout = optical_layout(device) if settings.view_falloff is not None else None
        self._vignetting: dict[int, np.ndarray] = {}
        self.vignetting_source = (
            _mirror_sources(device, self.regions) if settings.vignetting else [(k, 1, 1) for k in range(4)]
        )
        s = self.cams.depth_origin_m
        for idx, surf in enumerate(scene.surfaces):
            if isinstance(surf, Plane):
                znear = float(surf.corners_m()[:, 2].min())
            else:
                znear = surf.depth_m - max([bp.height_m for bp in surf.bumps if bp.height_m > 0], default=0.0)
            if znear <= s * 1.05:
                raise InvalidInputError(
                    f"surface {surf.name or idx} reaches Z = {znear:.4g} m, not beyond the views' "
                    f"entrance pupil at {s:.4g} m: move it farther away"
                )

    # -- geometry helpers --------------------------------------------------------------------
    def blur_px(self, z: np.ndarray) -> np.ndarray:
        """Defocus disc diameter in pixels for surfaces at Z (SPEC 2.3); NaN where Z is."""
        z = np.asarray(z, dtype=np.float64)
        out = np.full(z.shape, np.nan)
        finite = np.isfinite(z)
        out[finite] = blur_diameter_m(self.dev, z[finite]) / self.tp
        return out

    def _pixel_rays(self, view: int, x0: int, y0: int, w: int, h: int):
        dev = self.dev
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

    def _texel(self, zmin: float) -> float:
        """Texel size matched to the view pixel footprint at the nearest depth of a surface."""
        return self.tp * (zmin - self.cams.depth_origin_m) / self.cams.focal_m

    # -- surfaces ----------------------------------------------------------------------------
    def _plane_texture(self, idx: int, plane: Plane):
        if idx not in self._textures:
            zs = plane.corners_m()[:, 2]
            texel = self._texel(zs.min())
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
            ratio = (zs.max() - self.cams.depth_origin_m) / (zs.min() - self.cams.depth_origin_m)
            while ratio > 1.5 and min(levels[-1].shape[:2]) > 8:
                levels.append(cv2.pyrDown(levels[-1]))
                ratio /= 2
            # Texels tile the plane exactly at every level: (width / cols, height / rows).
            steps = [(plane.size_m[0] / lv.shape[1], plane.size_m[1] / lv.shape[0]) for lv in levels]
            self._textures[idx] = (texel, levels, steps)
        return self._textures[idx]

    def plane_layer(self, idx: int, plane: Plane, view: int, region) -> _Layer | None:
        texel, levels, steps = self._plane_texture(idx, plane)
        corners = plane.corners_m()
        zs = corners[:, 2]
        margin = 2 + (np.ceil(self.blur_px(zs).max() / 2) if self.settings.defocus else 0)
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
        warped = []
        for tex, (tx, ty) in zip(levels, steps):
            a = np.column_stack([tx * u, ty * v, tl + 0.5 * (tx * u + ty * v) - cam])
            hmat = pix_from_sensor @ k @ a
            warped.append(cv2.warpPerspective(tex, hmat, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT))
        if len(warped) == 1:
            acc = warped[0]
        else:
            # Trilinear mip blend by the local minification (pixel footprint / base texel).
            lod = np.log2(np.maximum(self._texel(depth) / texel, 1.0))
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
        return _Layer(x0, y0, acc, depth, float(zs.min()), plane.name or f"surface {idx}")

    def _heightfield_texture(self, idx: int, part: HeightField):
        wm, hm = part.size_m
        if idx not in self._textures:
            hmax = max([b.height_m for b in part.bumps if b.height_m > 0], default=0.0)
            texel = self._texel(part.depth_m - hmax)
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

    def prepare_vignetting(self, view: int) -> None:
        """Compute the vignetting of a view that is not a mirror image of another."""
        self._vignetting[view] = vignetting_region(self.dev, view, self.regions[view])

    def prepare_tasks(self) -> list:
        """Per-render work the views share (texture rasters, vignetting maps), largest first."""
        tasks = []
        for idx, surf in enumerate(self.scene.surfaces):
            if isinstance(surf, Plane):
                texel = self._texel(float(surf.corners_m()[:, 2].min()))
            else:
                texel = self._texel(surf.depth_m - max([b.height_m for b in surf.bumps if b.height_m > 0], default=0.0))
            rows, cols = raster_shape(surf.size_m, texel)
            tasks.append((rows * cols, lambda i=idx: self.prepare_texture(i)))
        if self.settings.vignetting:
            for k, (src, _, _) in enumerate(self.vignetting_source):
                if src == k:
                    tasks.append((self.regions[k][2] * self.regions[k][3], lambda k=k: self.prepare_vignetting(k)))
        return [fn for _, fn in sorted(tasks, key=lambda t: -t[0])]

    def vignetting(self, view: int) -> np.ndarray:
        """(h, w) vignetting over the view's lit region: computed, or the flipped map of the
        view it mirrors (:func:`_mirror_sources`)."""
        src, sx, sy = self.vignetting_source[view]
        if src not in self._vignetting:
            self.prepare_vignetting(src)
        return self._vignetting[src][::sy, ::sx]

    def heightfield_layer(self, idx: int, part: HeightField, view: int, region) -> _Layer | None:
        wm, hm = part.size_m
        (tx, ty), rgba, heights = self._heightfield_texture(idx, part)
        zlo = part.depth_m - max(float(heights.max()), 0.0)
        zhi = part.depth_m - min(float(heights.min()), 0.0)
        cx, cy = part.center_m
        corners = np.array([[cx + sx * wm / 2, cy + sy * hm / 2, z] for sx in (-1, 1) for sy in (-1, 1) for z in (zlo, zhi)])
        margin = 2 + (np.ceil(self.blur_px(np.array([zlo, zhi])).max() / 2) if self.settings.defocus else 0)
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
        return _Layer(x0, y0, acc, depth, zlo, part.name or f"surface {idx}")

    # -- one view ----------------------------------------------------------------------------
    def view(self, view: int, image: np.ndarray, views_sharp: np.ndarray, depth_views: np.ndarray,
             rects, times: dict | None = None) -> None:
        """Render view ``view`` into its lit region of ``image`` (exposed and clipped to [0, 1])
        and into its share of the ground truth: the parts of ``views_sharp`` and
        ``depth_views`` whose view rectangle ``rects[j]`` (erect frame) lies in that region.

        Views write disjoint parts of the outputs (the lit regions are clipped to the
        quadrants), so they can run in parallel threads.
        """
        clock = time.perf_counter
        t0 = clock()
        region = self.regions[view]
        rx, ry, rw, rh = region
        layers = _sorted_layers(self, view, region)
        t1 = clock()
        # Sharp colour and depth are only output inside the view rectangles: composite them
        # over the box that the rectangles' parts in this region span, not the whole region.
        vh, vw = views_sharp.shape[1:3]
        cuts = []
        for j, (x, y) in enumerate((r[0], r[1]) for r in rects):
            ix0, iy0, ix1, iy1 = max(x, rx), max(y, ry), min(x + vw, rx + rw), min(y + vh, ry + rh)
            if ix1 > ix0 and iy1 > iy0:
                cuts.append((j, x, y, ix0, iy0, ix1, iy1))
        if cuts:
            gx0, gy0 = min(c[3] for c in cuts), min(c[4] for c in cuts)
            gx1, gy1 = max(c[5] for c in cuts), max(c[6] for c in cuts)
        else:
            gx0 = gy0 = gx1 = gy1 = 0
        sharp = np.zeros((gy1 - gy0, gx1 - gx0, 4), np.float32)
        depth = np.full((gy1 - gy0, gx1 - gx0), np.inf, np.float32)
        blurred = np.zeros((rh, rw, 4), np.float32)
        t_blur = 0.0
        for lay in layers:
            h, w = lay.depth.shape
            lx0, ly0 = max(lay.x0, gx0), max(lay.y0, gy0)
            lx1, ly1 = min(lay.x0 + w, gx1), min(lay.y0 + h, gy1)
            if lx1 > lx0 and ly1 > ly0:
                src = np.s_[ly0 - lay.y0 : ly1 - lay.y0, lx0 - lay.x0 : lx1 - lay.x0]
                dst = np.s_[ly0 - gy0 : ly1 - gy0, lx0 - gx0 : lx1 - gx0]
                _over(sharp[dst], lay.rgba[src])
                front = (lay.rgba[src][..., 3] > 0.5) & (lay.depth[src] < depth[dst])
                np.copyto(depth[dst], lay.depth[src], where=front)
            tb = clock()
            rgba = self._defocus(lay) if self.settings.defocus else lay.rgba
            t_blur += clock() - tb
            _over(blurred[lay.y0 - ry : lay.y0 - ry + h, lay.x0 - rx : lay.x0 - rx + w], rgba)
        bg = np.array(self.scene.background, np.float32)
        if np.any(bg != 0):  # adding (1 - alpha) * 0 would change nothing
            for acc in (blurred, sharp):
                acc[..., :3] += (1.0 - acc[..., 3:4]) * bg
        t2 = clock()
        exposure = np.float32(self.settings.exposure)
        vig = self.vignetting(view) if self.settings.vignetting else None
        if vig is not None and self.settings.view_falloff is not None:
            vig = vig * view_falloff_map(self.erect_layout, view, region, self.settings.view_falloff)
        for r in range(0, rh, _BLOCK_ROWS):
            out = image[ry + r : ry + min(rh, r + _BLOCK_ROWS), rx : rx + rw]
            rgb = cv2.cvtColor(blurred[r : r + _BLOCK_ROWS], cv2.COLOR_RGBA2RGB)
            if vig is not None:
                v = vig[r : r + _BLOCK_ROWS]
                # Contiguous three-channel operands: NumPy broadcasting over a short axis is slow.
                np.multiply(rgb, cv2.merge([v, v, v]), out=out)
            else:
                out[...] = rgb
            out *= exposure
            np.clip(out, 0.0, 1.0, out=out)
        depth[~np.isfinite(depth)] = np.nan
        for j, x, y, ix0, iy0, ix1, iy1 in cuts:
            g = np.s_[iy0 - gy0 : iy1 - gy0, ix0 - gx0 : ix1 - gx0]
            v = np.s_[iy0 - y : iy1 - y, ix0 - x : ix1 - x]
            np.multiply(cv2.cvtColor(sharp[g], cv2.COLOR_RGBA2RGB), exposure, out=views_sharp[j][v])
            depth_views[j][v] = depth[g]
        if times is not None:
            t3 = clock()
            for key, dt in (("layers (warp, depth)", t1 - t0), ("defocus", t_blur), ("composite", t2 - t1 - t_blur),
                            ("out (vignetting, exposure, clip, ground truth)", t3 - t2)):
                times[key] = times.get(key, 0.0) + dt

    def _defocus(self, lay: _Layer) -> np.ndarray:
        finite = np.isfinite(lay.depth)
        if not finite.any():
            return lay.rgba
        zs = lay.depth[finite]
        zlo, zhi = zs.min(), zs.max()
        if zlo == zhi:  # one depth (a fronto-parallel plane): one disc, no per-pixel blur map
            return _blur(lay.rgba, float(self.blur_px(np.float64(zlo))))
        d = self.blur_px(np.where(finite, lay.depth, np.nan).astype(np.float64))
        lo, hi = float(np.nanmin(d)), float(np.nanmax(d))
        if hi - lo < 0.5:
            return _blur(lay.rgba, 0.5 * (lo + hi))
        # Depth-varying blur: split the surface into bins of 0.5 px of blur diameter, blur each
        # with its own disc and add them (the bins tile the surface, so the sum is exact where
        # the blur is constant and smooth where it changes).
        edges = np.arange(lo, hi + 0.5, 0.5)
        idx = np.clip(np.digitize(np.nan_to_num(d, nan=lo), edges) - 1, 0, len(edges) - 1)
        # Pixels at the coverage fringe (no depth) follow their nearest bin: the lowest.
        rgba = np.ascontiguousarray(lay.rgba)
        bits = rgba.view(np.uint64)  # two channels per word: nonzero where any bit is set
        nonzero = (bits[..., 0] | bits[..., 1]) != 0
        # Range of bins met on each row and column (pixels that are zero contribute nothing).
        n = len(edges)
        low, high = np.where(nonzero, idx, n), np.where(nonzero, idx, -1)
        row_lo, row_hi = low.min(axis=1), high.max(axis=1)
        col_lo, col_hi = low.min(axis=0), high.max(axis=0)
        out = np.zeros_like(rgba)
        h, w = idx.shape
        for i in range(n):
            rows = np.flatnonzero((row_lo <= i) & (i <= row_hi))
            cols = np.flatnonzero((col_lo <= i) & (i <= col_hi))
            if rows.size == 0 or cols.size == 0:
                continue
            k = disc_kernel(edges[i] + 0.25)
            half = 0 if k is None else k.shape[0] // 2
            # The bin's blur is zero farther than the disc radius from its pixels: convolve
            # only a box around them grown by that radius (same result, far fewer pixels).
            r0, r1 = max(0, rows[0] - half), min(h, rows[-1] + 1 + half)
            c0, c1 = max(0, cols[0] - half), min(w, cols[-1] + 1 + half)
            mask = (idx[r0:r1, c0:c1] == i).view(np.uint8)
            part = cv2.copyTo(rgba[r0:r1, c0:c1], mask)  # the bin's pixels, zero elsewhere
            out[r0:r1, c0:c1] += _convolve(part, k)
        return out


def _mirror_sources(device: RingDevice, regions) -> list[tuple[int, int, int]]:
    """For each view, (source view, x step, y step): its vignetting is the source's map read
    with those steps (-1 mirrors; a view that is its own source is computed directly)."""
    out: list[tuple[int, int, int]] = []
    for k in range(len(regions)):
        out.append(_mirror_of(device, regions, out, k) or (k, 1, 1))
    return out


def _mirror_of(device: RingDevice, regions, sources, k: int) -> tuple[int, int, int] | None:
    """An earlier, directly computed view whose vignetting map mirrors view ``k``'s exactly.

    The ring is symmetric: the mini-lens at (-mx, my) lights the mirror image of what the lens
    at (mx, my) lights, and the mirrored pixel grid is the negated one. Negation is exact in
    floating point, so the mirrored map equals a direct computation bit for bit; a row and a
    column through the middle are checked against one all the same.
    """
    W, H = device.sensor_width_px, device.sensor_height_px
    m = device.lens_centres_m
    x, y, w, h = regions[k]
    if w == 0 or h == 0:
        return None
    for j in range(k):
        if sources[j][0] != j:
            continue
        jx, jy, jw, jh = regions[j]
        for sx, sy in ((-1, 1), (1, -1), (-1, -1)):
            mirrored = (jx if sx == 1 else W - jx - jw, jy if sy == 1 else H - jy - jh, jw, jh)
            if mirrored != (x, y, w, h) or m[k, 0] != sx * m[j, 0] or m[k, 1] != sy * m[j, 1]:
                continue
            jrow = jy + (h // 2 if sy == 1 else h - 1 - h // 2)
            jcol = jx + (w // 2 if sx == 1 else w - 1 - w // 2)
            row_ok = np.array_equal(vignetting_region(device, k, (x, y + h // 2, w, 1)),
                                    vignetting_region(device, j, (jx, jrow, w, 1))[:, ::sx])
            col_ok = np.array_equal(vignetting_region(device, k, (x + w // 2, y, 1, h)),
                                    vignetting_region(device, j, (jcol, jy, 1, h))[::sy, :])
            if row_ok and col_ok:
                return j, sx, sy
    return None


def _over(acc: np.ndarray, rgba: np.ndarray) -> None:
    """Front-to-back 'over' compositing of a premultiplied layer behind ``acc`` (in place):
    ``acc += (1 - acc_alpha) rgba``."""
    for r in range(0, acc.shape[0], _BLOCK_ROWS):
        a, c = acc[r : r + _BLOCK_ROWS], rgba[r : r + _BLOCK_ROWS]
        t = 1.0 - a[..., 3]
        t = cv2.merge([t, t, t, t])  # transmittance per channel (NumPy broadcasting over 4 is slow)
        t *= c
        a += t


# ------------------------------------------------------------------------------------------------
def render(device: RingDevice, scene: Scene, settings: RenderSettings | None = None, **options) -> RenderResult:
    """Render the raw frame the ring camera would record, with ground truth.

    Parameters
    ----------
    device : RingDevice
        With lens positions (``ring_distance_m``, ``sensor_distance_m``) set.
    scene : Scene
    settings : RenderSettings, optional
        Or give its fields as keyword options, e.g. ``binning=2, noise='realistic'``.

    Returns
    -------
    RenderResult

    Examples
    --------
    >>> from lfring.optics import load_device
    >>> from lfring.synth import Plane, Scene, Texture, render
    >>> dev = load_device("prototype")
    >>> scene = Scene((Plane(0.5, (0.4, 0.3), Texture("checker", square_m=0.02)),))
    >>> r = render(dev, scene, binning=8, pattern="GRBG", bit_depth=8)
    >>> r.raw.shape, r.raw.dtype, r.views.shape
    ((460, 614), dtype('uint8'), (4, 176, 176, 3))
    """
    if settings is None:
        settings = RenderSettings(**options)
    elif options:
        raise InvalidInputError("give either settings or keyword options, not both")
    if not isinstance(scene, Scene):
        raise InvalidInputError(f"scene must be a lfring.synth.Scene, got {type(scene).__name__}")
    return _render(device, scene, settings)


def _render(device: RingDevice, scene: Scene, settings: RenderSettings, *, timings: dict | None = None,
            workers: int | None = None) -> RenderResult:
    """:func:`render` after validation, on ``workers`` threads (default: one per core, at most
    four). ``timings``, when given, receives seconds per stage: wall clock for the stages, and
    for the ``view:`` entries the time summed over the views (which run ``workers`` at a time,
    so with several workers they include the threads' waits for a core)."""
    workers = _workers() if workers is None else max(1, int(workers))
    clock = time.perf_counter
    t0 = clock()
    dev = device.binned(settings.binning)
    dev.require_positions()
    layout = optical_layout(dev, rotate180=settings.rotate180)
    rend = _Renderer(dev, scene, settings)
    H, W = dev.sensor_height_px, dev.sensor_width_px
    shape = (H, W) if settings.pattern else (H, W, 3)
    view_times: list[dict | None] = [({} if timings is not None else None) for _ in range(4)]
    stages = {}
    with ThreadPoolExecutor(1) as side, ThreadPoolExecutor(workers) as pool:
        # The noise depends only on the seed and the frame's shape: draw it on a side thread
        # while the views render (the generator releases the GIL), the same numbers as drawing
        # it afterwards.
        noise = side.submit(_draw_noise, shape, settings) if NOISE_PRESETS[settings.noise] else None
        t1 = clock()
        list(pool.map(lambda fn: fn(), rend.prepare_tasks()))
        t2 = clock()
        image = np.zeros((H, W, 3), np.float32)
        vh, vw = layout.view_shape
        views_sharp = np.zeros((layout.num_views, vh, vw, 3), np.float32)
        depth_views = np.full((layout.num_views, vh, vw), np.nan, np.float32)
        # Ground truth cut in the erect frame (the frame the views are numbered in).
        list(pool.map(lambda k: rend.view(k, image, views_sharp, depth_views, layout.rects, view_times[k]), range(4)))
        t3 = clock()
        if settings.rotate180:
            image = np.ascontiguousarray(image[::-1, ::-1])
        views = split_views(image, layout)
        t4 = clock()
        raw = _sensor(image, settings, noise=None if noise is None else noise.result()[0], pool=pool, stripes=workers)
        t5 = clock()
    if timings is not None:
        stages["setup"] = t1 - t0
        stages["textures, vignetting"] = t2 - t1
        stages["views (parallel)"] = t3 - t2
        for vt in view_times:
            for key, dt in vt.items():
                stages[f"view: {key}"] = stages.get(f"view: {key}", 0.0) + dt
        stages["rotate, split views"] = t4 - t3
        stages["sensor (mosaic, noise, quantise)"] = t5 - t4
        if noise is not None:
            stages["noise draw (overlapped)"] = noise.result()[1]
        stages["total"] = t5 - t0
        timings.update(stages)
    return RenderResult(
        raw=raw, image=image, views=views, views_sharp=views_sharp, depth_m=depth_views,
        layout=layout, device=dev, settings=settings, scene=scene,
    )


def _draw_noise(shape: tuple[int, ...], settings: RenderSettings) -> tuple[np.ndarray, float]:
    """Standard normal float32 noise of the frame from the settings' seed, and the seconds it took."""
    t = time.perf_counter()
    noise = np.random.default_rng(settings.seed).standard_normal(shape, dtype=np.float32)
    return noise, time.perf_counter() - t


def _sensor(image: np.ndarray, settings: RenderSettings, *, noise: np.ndarray | None = None, pool=None,
            stripes: int = 1) -> np.ndarray:
    """Colour filter, shot and read noise, and quantisation of a [0, 1] linear image.

    ``noise`` is the frame's standard normal draw (see :func:`_draw_noise`), drawn here when
    not given; it is used up (scaled in place). ``stripes`` bands of rows run on ``pool``'s
    threads.
    """
    pattern = settings.pattern
    shape = image.shape[:2] if pattern else image.shape
    black, white = settings.effective_black_level, settings.white_level
    span = white - black
    preset = NOISE_PRESETS[settings.noise]
    if preset is not None and noise is None:
        noise = _draw_noise(shape, settings)[0]
    out = np.empty(shape, np.uint8 if settings.bit_depth == 8 else np.uint16)

    def stripe(rows: slice) -> None:
        signal = mosaic(image[rows], pattern) if pattern else image[rows].copy()
        if preset is not None:
            full_well, read = preset
            e_full = full_well / settings.gain  # electrons at full scale
            e = signal
            e *= np.float32(e_full)
            sd = e + np.float32(read * read)
            np.sqrt(sd, out=sd)
            n = noise[rows]
            n *= sd
            e += n
            e *= np.float32(1.0 / e_full)
        counts = signal
        counts *= np.float32(span)
        counts += np.float32(black)
        np.rint(counts, out=counts)
        np.clip(counts, 0, white, out=counts)
        np.copyto(out[rows], counts, casting="unsafe")

    # Stripes start on even rows, so every stripe sees the Bayer pattern in its own phase.
    n = 1 if pool is None else max(1, stripes)
    cuts = sorted({0, shape[0]} | {2 * ((shape[0] * i // n) // 2) for i in range(1, n)})
    rows = [slice(a, b) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]
    if pool is None:
        for r in rows:
            stripe(r)
    else:
        list(pool.map(stripe, rows))
    return out


# -- the conventional image: ground truth for refocusing -----------------------------------------
#: Aperture samples per pixel of blur: the default count puts the samples about
#: ``CONVENTIONAL_SPACING_PX`` apart on the most defocused surface (see :func:`render_conventional`).
CONVENTIONAL_SPACING_PX = 2.0
#: Fewest aperture samples the default count takes for an aperture that is not a pinhole (the
#: samples' union must look like a disc).
CONVENTIONAL_MIN_SAMPLES = 32
#: Most aperture samples the default count takes.
CONVENTIONAL_MAX_SAMPLES = 2048
_GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))


def viewpoint_radius_m(device: RingDevice) -> float:
    """Distance (metres) of the views' projection centres from their mean, in the plane of the
    views' entrance pupil: the radius of the aperture the four viewpoints span
    (``aperture_scale=1`` of :func:`render_conventional`)."""
    cams = view_cameras(device)
    c = cams.centres_m - cams.centres_m.mean(axis=0)
    return float(np.hypot(c[:, 0], c[:, 1]).max())


def conventional_aperture_radius_m(device: RingDevice, *, f_number=None, aperture_scale=None) -> float:
    """Radius (metres) of the aperture disc :func:`render_conventional` integrates over.

    ``f_number`` N gives the main lens's entrance pupil at N, ``FL / (2 N)`` (``inf`` gives a
    pinhole); ``aperture_scale`` a gives ``a * viewpoint_radius_m(device)``; neither gives the
    main lens's full aperture, ``device.effective_aperture_radius_m``. Not both.
    """
    if f_number is not None and aperture_scale is not None:
        raise InvalidInputError("give f_number or aperture_scale, not both")
    if f_number is not None:
        try:
            n = float(f_number)
        except (TypeError, ValueError):
            n = float("nan")
        if not n > 0:
            raise InvalidInputError(f"f_number must be a positive number (inf for a pinhole), got {f_number!r}")
        return 0.0 if np.isinf(n) else device.main_focal_length_m / (2.0 * n)
    if aperture_scale is not None:
        try:
            a = float(aperture_scale)
        except (TypeError, ValueError):
            a = float("nan")
        if not (np.isfinite(a) and a >= 0):
            raise InvalidInputError(f"aperture_scale must be a finite number >= 0, got {aperture_scale!r}")
        return a * viewpoint_radius_m(device)
    return float(device.effective_aperture_radius_m)


def aperture_samples(n: int) -> np.ndarray:
    """(n, 2) points on the unit disc: a Vogel (sunflower) spiral, equal area per point; one
    point, the centre, for ``n = 1``."""
    if n == 1:
        return np.zeros((1, 2))
    i = np.arange(n)
    r = np.sqrt((i + 0.5) / n)
    t = i * _GOLDEN_ANGLE
    return np.column_stack([r * np.cos(t), r * np.sin(t)])


def conventional_blur_px(device: RingDevice, depth_m, focus_m: float, aperture_radius_m: float) -> np.ndarray:
    """Diameter (pixels of ``device``) of the blur disc of a point at ``depth_m`` in the
    conventional image focused at ``focus_m`` through an aperture of ``aperture_radius_m`` in
    the views' entrance-pupil plane: ``2 R f |1/(Zf - s) - 1/(Z - s)| / pitch``."""
    cams = view_cameras(device)
    s, f = cams.depth_origin_m, cams.focal_m
    z = np.asarray(depth_m, dtype=np.float64)
    return 2.0 * aperture_radius_m * f * np.abs(1.0 / (focus_m - s) - 1.0 / (z - s)) / device.pixel_pitch_m


class _SubApertureRenderer(_Renderer):
    """Renders the scene as seen from points of the aperture disc, each a small lens (one
    sample's share of the disc) focused at the focus depth, into the central view's grid."""

    def __init__(self, device: RingDevice, scene: Scene, focus_m: float, cell_radius_m: float, cams: ViewCameras):
        super().__init__(device, scene, RenderSettings(binning=1, pattern=None, defocus=cell_radius_m > 0,
                                                        vignetting=False))
        self.focus_m = focus_m
        self.cell_radius_m = cell_radius_m
        self.cams = cams

    def blur_px(self, z: np.ndarray) -> np.ndarray:
        z = np.asarray(z, dtype=np.float64)
        out = np.full(z.shape, np.nan)
        finite = np.isfinite(z)
        out[finite] = conventional_blur_px(self.dev, z[finite], self.focus_m, self.cell_radius_m)
        return out

    def sample(self, k: int, region) -> np.ndarray:
        """(h, w, 3) float32 radiance of aperture sample ``k`` over ``region``."""
        rx, ry, rw, rh = region
        layers = _sorted_layers(self, k, region)
        acc = np.zeros((rh, rw, 4), np.float32)
        for lay in layers:
            rgba = self._defocus(lay) if self.settings.defocus else lay.rgba
            h, w = lay.depth.shape
            _over(acc[lay.y0 - ry : lay.y0 - ry + h, lay.x0 - rx : lay.x0 - rx + w], rgba)
        bg = np.array(self.scene.background, np.float32)
        if np.any(bg != 0):
            acc[..., :3] += (1.0 - acc[..., 3:4]) * bg
        return acc[..., :3]


def render_conventional(scene: Scene, device: RingDevice, focus_m: float, *, f_number=None, aperture_scale=None,
                        samples: int | None = None, binning: int = 1, workers: int | None = None) -> np.ndarray:
    """The image a conventional camera focused at ``focus_m`` would record of ``scene``, in the
    views' reference frame ``'center'``: ground truth for refocusing.

    Every view of the ring is a pinhole camera (:func:`lfring.optics.views.view_cameras`) with
    its projection centre ``C_k`` in the plane ``Z = s`` of the views' entrance pupil. The
    conventional camera here has its aperture disc in that plane, centred on the central
    viewpoint (the mean of the ``C_k``), and its image is in the pixel grid of the virtual
    central view (the frame ``lfring.refocus`` renders into: view-sized, a point at the focus
    depth lands where the central view sees it). A point at depth Z is spread over a disc of
    ``2 R f |1/(Zf - s) - 1/(Z - s)|`` on the sensor (:func:`conventional_blur_px`), the
    synthetic-aperture form of the thin-lens circle of confusion.

    The image is the average of ``samples`` views from points of the disc (a Vogel spiral), each
    shifted so that the focus plane stays put, occlusions resolved per viewpoint; each sample
    is itself a small lens, its equal share of the disc (radius ``R / sqrt(samples)``), whose
    defocus is rendered per surface as the raw frame's is. More samples converge on the exact
    integral over the aperture (the small lenses shrink to pinholes).

    Parameters
    ----------
    scene : Scene
    device : RingDevice
        With lens positions (the unbinned device; ``binning`` bins it as ``render`` does).
    focus_m : float
        Focus distance Zf from the main lens, metres, beyond the entrance pupil s.
    f_number, aperture_scale : float, optional
        The aperture (:func:`conventional_aperture_radius_m`): the main lens's entrance pupil at
        f-number N (``inf``: a pinhole, the central view itself), or ``aperture_scale`` times the
        radius the four viewpoints span (1: the aperture the views span); default the main
        lens's full aperture.
    samples : int, optional
        Aperture samples; default about one per ``CONVENTIONAL_SPACING_PX`` of the largest blur
        diameter in the scene (from ``CONVENTIONAL_MIN_SAMPLES`` to ``CONVENTIONAL_MAX_SAMPLES``),
        one for a pinhole.
    binning : int
        Sensor binning, as :class:`RenderSettings` (the image has the views' shape at it).

    Returns
    -------
    ndarray, (h, w, 3) float32
        Linear RGB radiance in [0, 1] (not scaled by ``RenderSettings.exposure``), without noise
        or vignetting; ``h, w`` the view shape of :func:`lfring.optics.views.optical_layout`.

    Notes
    -----
    How the views' viewpoints relate to the main lens's aperture. The main lens images the ring
    (at b behind it) to the plane ``s = b FL / (b - FL)`` in front of it, magnified by
    ``FL / (b - FL)``: mini-lens k (centre m_k, radius Rml) becomes the pupil of view k,
    centred at ``C_k = -m_k FL / (b - FL)`` with radius ``Rml FL / (b - FL)``, and the views
    are focused where their sensor is conjugate (``paraxial.blur_diameter_m`` is zero). The
    main lens's iris is not the views' pupil: it is their field stop (each view's valid disc
    is its image). For the prototype (FL 16 mm, b 37.37 mm, Rml 1 mm, m_k at 1.05 mm on both
    axes, iris radius 5 mm): s = 27.98 mm, |C_k| = 1.112 mm (``viewpoint_radius_m``, the
    radius of ``aperture_scale=1``, f/7.2 in main-lens terms), each view's own pupil radius
    0.749 mm (the conventional image with ``aperture_scale=0.673`` focused at 0.3 m has
    exactly the views' defocus blur), so the views' pupils together reach 1.86 mm from the
    axis, against the 5 mm (f/1.6) of the main lens's full aperture. An f-number puts the
    main lens's pupil diameter FL / N in the plane s, which keeps every viewpoint a view-like
    pinhole camera; the same pupil at the main lens itself (Z = 0) would take from a point at
    Z a cone ``(Z - s) / Z`` times as wide (0.91 at 0.3 m, 0.97 at 1 m), and a perspective
    from Z = 0 rather than from the views' plane.

    Examples
    --------
    >>> from lfring.optics import load_device
    >>> from lfring.synth import Plane, Scene, Texture
    >>> dev = load_device("prototype")
    >>> scene = Scene((Plane(0.5, (0.4, 0.3), Texture("checker", square_m=0.02)),))
    >>> img = render_conventional(scene, dev, 0.5, f_number=8, binning=8)
    >>> img.shape, img.dtype
    ((176, 176, 3), dtype('float32'))
    """
    if not isinstance(scene, Scene):
        raise InvalidInputError(f"scene must be a lfring.synth.Scene, got {type(scene).__name__}")
    RenderSettings(binning=binning)  # validates the binning
    dev = device.binned(binning)
    dev.require_positions()
    cams = view_cameras(dev)
    s, f, tp = cams.depth_origin_m, cams.focal_m, dev.pixel_pitch_m
    try:
        zf = float(focus_m)
    except (TypeError, ValueError):
        zf = float("nan")
    if not (np.isfinite(zf) and zf > s):
        raise InvalidInputError(f"focus_m must be a distance in metres beyond the views' entrance pupil ({s:.4g} m), "
                                f"got {focus_m!r}")
    radius = conventional_aperture_radius_m(dev, f_number=f_number, aperture_scale=aperture_scale)
    if radius == 0:
        n = 1
    elif samples is None:
        n = conventional_sample_count(scene, dev, zf, radius)
    else:
        if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 1:
            raise InvalidInputError(f"samples must be an integer >= 1, got {samples!r}")
        n = int(samples)
    layout = optical_layout(dev)
    vh, vw = layout.view_shape
    corner = np.mean([(x, y) for x, y, _, _ in layout.rects], axis=0)
    origin = np.floor(corner)
    # The central view: centre mean(C_k), principal point mean(p0_k); its pixel (0, 0) is the
    # raw pixel at the mean of the views' corners. Rendered on the integer grid at ``origin``,
    # the fractional part moves the principal point instead.
    c_mean = cams.centres_m.mean(axis=0)
    p_mean = cams.principal_points_m.mean(axis=0) - (corner - origin) * tp
    offsets = radius * aperture_samples(n)
    sample_cams = ViewCameras(
        centres_m=c_mean + offsets,
        depth_origin_m=s,
        focal_m=f,
        principal_points_m=p_mean + f * offsets / (zf - s),
    )
    cell = radius / np.sqrt(n) if n > 1 else 0.0
    rend = _SubApertureRenderer(dev, scene, zf, cell, sample_cams)
    # Render a margin around the view as wide as the samples' own blur, so that the blur at the
    # image's border sees the surfaces beyond it (a layer is zero outside its region).
    margin = int(np.ceil(float(np.max(conventional_blur_px(dev, np.array(_scene_depth_range(scene)), zf, cell))) / 2)) + 2
    region = (int(origin[0]) - margin, int(origin[1]) - margin, vw + 2 * margin, vh + 2 * margin)
    inner = np.s_[margin : margin + vh, margin : margin + vw]
    workers = _workers() if workers is None else max(1, int(workers))
    # Fixed chunks summed in order: the image does not depend on the number of threads.
    chunks = [range(i, n, 8) for i in range(min(8, n))]

    def chunk_sum(ks) -> np.ndarray:
        acc = np.zeros((vh, vw, 3), np.float64)
        for k in ks:
            acc += rend.sample(k, region)[inner]
        return acc

    with ThreadPoolExecutor(workers) as pool:
        list(pool.map(rend.prepare_texture, range(len(scene.surfaces))))
        sums = list(pool.map(chunk_sum, chunks))
    total = sums[0]
    for part in sums[1:]:
        total += part
    return np.clip(total / n, 0.0, 1.0).astype(np.float32)


def conventional_sample_count(scene: Scene, device: RingDevice, focus_m: float, aperture_radius_m: float) -> int:
    """The default aperture samples of :func:`render_conventional`: about one per
    ``CONVENTIONAL_SPACING_PX`` pixels (of the binned ``device``) across the largest blur disc
    of the scene's depth range, from ``CONVENTIONAL_MIN_SAMPLES`` to ``CONVENTIONAL_MAX_SAMPLES``
    (1 for a pinhole)."""
    if aperture_radius_m == 0:
        return 1
    d_max = float(np.max(conventional_blur_px(device, np.array(_scene_depth_range(scene)), focus_m, aperture_radius_m)))
    return int(np.clip(np.ceil(np.pi / 4 * (d_max / CONVENTIONAL_SPACING_PX) ** 2), CONVENTIONAL_MIN_SAMPLES, CONVENTIONAL_MAX_SAMPLES))


def _scene_depth_range(scene: Scene) -> tuple[float, float]:
    """Nearest and farthest Z (metres) of the scene's surfaces."""
    lo, hi = np.inf, -np.inf
    for surf in scene.surfaces:
        if isinstance(surf, Plane):
            zs = surf.corners_m()[:, 2]
            lo, hi = min(lo, zs.min()), max(hi, zs.max())
        else:
            lo = min(lo, surf.depth_m - max([b.height_m for b in surf.bumps if b.height_m > 0], default=0.0))
            hi = max(hi, surf.depth_m - min([b.height_m for b in surf.bumps if b.height_m < 0], default=0.0))
    return float(lo), float(hi)
