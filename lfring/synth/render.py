"""The synthetic twin: raw frames rendered from the paraxial model, with ground truth (SPEC 3).

Every view is the pinhole camera of :mod:`lfring.optics.views`, so a plane maps to a view by a
homography and a height field by a short fixed-point iteration along each chief ray. Each
surface is rendered as a layer (premultiplied colour, coverage, depth), blurred by its own
defocus disc (SPEC 2.3, the blur varying with depth across slanted and curved surfaces), and the
layers are composited front to back. Then come per-view vignetting and the iris field stop, the
optional 180-degree rotation, the Bayer mosaic, shot and read noise, and quantisation.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import cv2
import numpy as np

from lfring.errors import InvalidInputError
from lfring.io.bayer import mosaic, validate_pattern
from lfring.optics.device import RingDevice
from lfring.optics.views import (
    ViewCameras,
    lit_region,
    optical_homographies,
    optical_layout,
    view_cameras,
    vignetting_region,
)
from lfring.synth.scene import HeightField, Plane, Scene
from lfring.synth.textures import rasterize
from lfring.views import Layout, split_views

__all__ = ["RenderSettings", "RenderResult", "render", "NOISE_PRESETS", "BIT_DEPTHS", "disc_kernel"]

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

    def __post_init__(self) -> None:
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
        return 2**self.bit_depth - 1

    @property
    def effective_black_level(self) -> int:
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

    def homographies(self, depth_m, *, reference="center") -> np.ndarray:
        """Exact ``H_ref_from_view`` of a fronto-parallel plane at ``depth_m`` (SPEC 4)."""
        return optical_homographies(self.device, self.layout, depth_m, reference=reference)

    @property
    def black_level(self) -> int:
        return self.settings.effective_black_level

    @property
    def white_level(self) -> int:
        return self.settings.white_level

    def metadata(self) -> dict:
        """JSON-ready description of the render (device, settings, layout, levels)."""
        return {
            "device": self.device.to_dict(),
            "ring_distance_m": self.device.ring_distance_m,
            "sensor_distance_m": self.device.sensor_distance_m,
            "entrance_pupil_m": self.device.entrance_pupil_m,
            "settings": asdict(self.settings),
            "black_level": self.black_level,
            "white_level": self.white_level,
            "pattern": self.settings.pattern,
            "layout": self.layout.to_dict(),
        }


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
    k = disc_kernel(diameter_px)
    if k is None:
        return layer
    return cv2.filter2D(layer, -1, k, borderType=cv2.BORDER_CONSTANT)


@dataclass
class _Layer:
    x0: int
    y0: int
    rgba: np.ndarray  # (h, w, 4) premultiplied colour and coverage
    depth: np.ndarray  # (h, w) Z in metres, inf where not covered
    zmin: float
    name: str


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
        b, c = device.require_positions()
        self.c = c
        self.b = b
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
        """Defocus disc diameter in pixels for surfaces at Z (SPEC 2.3)."""
        dev = self.dev
        fl, fml = dev.main_focal_length_m, dev.mini_focal_length_m
        b2 = self.b - z * fl / (z - fl)
        cp = b2 * fml / (b2 - fml)
        return 2.0 * dev.mini_lens_radius_m * np.abs(self.c - cp) / cp / self.tp

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
            rgb = rasterize(plane.texture, plane.size_m, texel)
            rows, cols = rgb.shape[:2]
            alpha = np.ones((rows, cols), np.float32)
            if plane.shape == "disk":
                yy = (np.arange(rows) + 0.5) / rows * 2 - 1
                xx = (np.arange(cols) + 0.5) / cols * 2 - 1
                r = np.sqrt(xx[None, :] ** 2 + yy[:, None] ** 2)
                # anti-aliased edge about one texel wide
                alpha = np.clip((1 - r) * min(rows, cols) / 2 + 0.5, 0, 1).astype(np.float32)
            rgba = np.dstack([rgb * alpha[..., None], alpha]).astype(np.float32)
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
        acc = np.zeros((h, w, 4), np.float32)
        dx, dy = self._pixel_rays(view, x0, y0, w, h)
        # Ray-plane intersection: Z = s + n.(P0 - C) / n.(dx, dy, 1).
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
            lo = np.floor(lod).astype(int)
            fr = (lod - lo)[..., None].astype(np.float32)
            stack = np.stack(warped)
            hi = np.minimum(lo + 1, len(warped) - 1)
            yy, xx = np.indices(lod.shape)
            acc = stack[lo, yy, xx] * (1 - fr) + stack[hi, yy, xx] * fr
        depth = np.where(acc[..., 3] > 1e-4, depth, np.inf).astype(np.float32)
        return _Layer(x0, y0, acc, depth, float(zs.min()), plane.name or f"surface {idx}")

    def heightfield_layer(self, idx: int, part: HeightField, view: int, region) -> _Layer | None:
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
        (tx, ty), rgba, heights = self._textures[idx]
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
    def view(self, view: int):
        region = lit_region(self.dev, view)
        rx, ry, rw, rh = region
        layers = []
        for idx, surf in enumerate(self.scene.surfaces):
            fn = self.plane_layer if isinstance(surf, Plane) else self.heightfield_layer
            lay = fn(idx, surf, view, region)
            if lay is not None:
                layers.append(lay)
        layers.sort(key=lambda la: la.zmin)
        _check_order(layers)
        bg = np.array(self.scene.background, np.float32)
        blurred = np.zeros((rh, rw, 4), np.float32)
        sharp = np.zeros((rh, rw, 4), np.float32)
        depth = np.full((rh, rw), np.inf, np.float32)
        for lay in layers:
            h, w = lay.depth.shape
            sl = np.s_[lay.y0 - ry : lay.y0 - ry + h, lay.x0 - rx : lay.x0 - rx + w]
            _over(sharp[sl], lay.rgba)
            front = (lay.rgba[..., 3] > 0.5) & (lay.depth < depth[sl])
            depth[sl] = np.where(front, lay.depth, depth[sl])
            _over(blurred[sl], self._defocus(lay) if self.settings.defocus else lay.rgba)
        for acc in (blurred, sharp):
            acc[..., :3] += (1.0 - acc[..., 3:4]) * bg
        vig = vignetting_region(self.dev, view, region) if self.settings.vignetting else np.ones((rh, rw), np.float32)
        radiance = blurred[..., :3] * vig[..., None]
        depth[~np.isfinite(depth)] = np.nan
        return region, radiance, sharp[..., :3], depth

    def _defocus(self, lay: _Layer) -> np.ndarray:
        d = self.blur_px(np.where(np.isfinite(lay.depth), lay.depth, np.nan).astype(np.float64))
        covered = np.isfinite(d)
        if not covered.any():
            return lay.rgba
        lo, hi = float(np.nanmin(d)), float(np.nanmax(d))
        if hi - lo < 0.5:
            return _blur(lay.rgba, 0.5 * (lo + hi))
        # Depth-varying blur: split the surface into bins of 0.5 px of blur diameter, blur each
        # with its own disc and add them (the bins tile the surface, so the sum is exact where
        # the blur is constant and smooth where it changes).
        edges = np.arange(lo, hi + 0.5, 0.5)
        idx = np.clip(np.digitize(np.nan_to_num(d, nan=lo), edges) - 1, 0, len(edges) - 1)
        # Pixels at the coverage fringe (no depth) follow their nearest bin: the lowest.
        out = np.zeros_like(lay.rgba)
        for i in range(len(edges)):
            m = idx == i
            if not m.any():
                continue
            part = lay.rgba * m[..., None]
            out += _blur(part, edges[i] + 0.25)
        return out


def _over(acc: np.ndarray, rgba: np.ndarray) -> None:
    """Front-to-back 'over' compositing of a premultiplied layer behind ``acc`` (in place)."""
    acc += (1.0 - acc[..., 3:4]) * rgba


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
    ((460, 614), dtype('uint8'), (4, 88, 88, 3))
    """
    if settings is None:
        settings = RenderSettings(**options)
    elif options:
        raise InvalidInputError("give either settings or keyword options, not both")
    if not isinstance(scene, Scene):
        raise InvalidInputError(f"scene must be a lfring.synth.Scene, got {type(scene).__name__}")
    dev = device.binned(settings.binning)
    dev.require_positions()
    layout = optical_layout(dev, rotate180=settings.rotate180)
    rend = _Renderer(dev, scene, settings)
    H, W = dev.sensor_height_px, dev.sensor_width_px
    image = np.zeros((H, W, 3), np.float32)
    sharp = np.zeros((H, W, 3), np.float32)
    depth = np.full((H, W), np.nan, np.float32)
    for k in range(4):
        (rx, ry, rw, rh), rad, shp, dep = rend.view(k)
        image[ry : ry + rh, rx : rx + rw] = rad
        sharp[ry : ry + rh, rx : rx + rw] = shp
        depth[ry : ry + rh, rx : rx + rw] = dep
    image *= np.float32(settings.exposure)
    sharp *= np.float32(settings.exposure)
    # Ground truth cut in the erect frame (the frame the views are numbered in).
    erect = Layout(W, H, layout.rects, False, layout.circles)
    views_sharp = split_views(sharp, erect)
    depth_views = split_views(depth, erect)[..., 0]
    if settings.rotate180:
        image = np.ascontiguousarray(image[::-1, ::-1])
    np.clip(image, 0.0, 1.0, out=image)
    views = split_views(image, layout)
    raw = _sensor(image, settings)
    return RenderResult(
        raw=raw, image=image, views=views, views_sharp=views_sharp, depth_m=depth_views,
        layout=layout, device=dev, settings=settings, scene=scene,
    )


def _sensor(image: np.ndarray, settings: RenderSettings) -> np.ndarray:
    """Colour filter, shot and read noise, and quantisation of a [0, 1] linear image."""
    signal = mosaic(image, settings.pattern) if settings.pattern else image
    black, white = settings.effective_black_level, settings.white_level
    span = white - black
    preset = NOISE_PRESETS[settings.noise]
    if preset is not None:
        full_well, read = preset
        e_full = full_well / settings.gain  # electrons at full scale
        rng = np.random.default_rng(settings.seed)
        e = signal * np.float32(e_full)
        noise = rng.standard_normal(signal.shape, dtype=np.float32)
        noise *= np.sqrt(e + np.float32(read * read))
        e += noise
        signal = e * np.float32(1.0 / e_full)
    counts = signal * np.float32(span) + np.float32(black)
    np.rint(counts, out=counts)
    np.clip(counts, 0, white, out=counts)
    return counts.astype(np.uint8 if settings.bit_depth == 8 else np.uint16)

