"""The synthetic twin's raw frames: rendered from the paraxial model, with ground truth.

Each view renders its surfaces as layers (:mod:`lfring.synth.layers`): premultiplied colour,
coverage and depth, blurred by their own defocus disc (:mod:`lfring.synth.defocus`, the blur
varying with depth across slanted and curved surfaces), composited front to back. Through real
mini-lenses (``RingDevice.lenses``) each pixel's chief ray is bent by its lens's distortion
before it meets the scene. Then come per-view vignetting (each lens's own, with its
transmission and fall-off) and the iris field stop, the optional 180-degree rotation, and the
sensor (:mod:`lfring.synth.sensor`: the Bayer mosaic, shot and read noise, quantisation).

The views render on parallel threads (the heavy loops are OpenCV's and NumPy's, which release
the GIL) while the noise is drawn on another; every thread writes its own part of the outputs,
so the frame is the same whatever the number of threads (``benchmarks/bench_render.py``).
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np

from lfring.core.validate import check_int
from lfring.errors import InvalidInputError
from lfring.optics.device import RingDevice
from lfring.optics.views import lens_distortions, lit_region, optical_layout, vignetting_region
from lfring.synth.layers import BLOCK_ROWS, SurfaceRenderer, default_workers, over
from lfring.synth.result import RenderResult
from lfring.synth.scene import Scene
from lfring.synth.sensor import draw_noise, raw_counts
from lfring.synth.settings import NOISE_PRESETS, RenderSettings
from lfring.synth.textures import raster_shape
from lfring.views import Layout, split_views

__all__ = ["render", "view_falloff_map"]


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


class _FrameRenderer(SurfaceRenderer):
    """Renders the views of the raw frame: each view's surfaces over its lit region, then its
    vignetting and exposure, and its share of the ground truth."""

    def __init__(self, device: RingDevice, scene: Scene, settings: RenderSettings):
        super().__init__(device, scene, settings)
        self.regions = [lit_region(device, k) for k in range(4)]
        self.distortions = lens_distortions(device)
        self.erect_layout = optical_layout(device) if settings.view_falloff is not None else None
        self._vignetting: dict[int, np.ndarray] = {}
        if not settings.vignetting:
            self.vignetting_source = [(k, 1, 1) for k in range(4)]
        elif device.lenses is not None:  # lenses of their own: no view mirrors another
            self.vignetting_source = [(k, 1, 1) for k in range(4)]
        else:
            self.vignetting_source = _mirror_sources(device, self.regions)

    def prepare_vignetting(self, view: int) -> None:
        """Compute the vignetting of a view that is not a mirror image of another."""
        self._vignetting[view] = vignetting_region(self.dev, view, self.regions[view],
                                                   ideal_px=self.ideal_px(view, *self.regions[view]))

    def prepare_tasks(self) -> list:
        """Per-render work the views share (texture rasters, vignetting maps), largest first."""
        tasks = []
        for idx, surf in enumerate(self.scene.surfaces):
            texel = self.texel_m(surf.depth_range_m[0])
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
        layers = self.layers(view, region)
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
                over(sharp[dst], lay.rgba[src])
                front = (lay.rgba[src][..., 3] > 0.5) & (lay.depth[src] < depth[dst])
                np.copyto(depth[dst], lay.depth[src], where=front)
            tb = clock()
            rgba = self.defocus(lay) if self.settings.defocus else lay.rgba
            t_blur += clock() - tb
            over(blurred[lay.y0 - ry : lay.y0 - ry + h, lay.x0 - rx : lay.x0 - rx + w], rgba)
        bg = np.array(self.scene.background, np.float32)
        if np.any(bg != 0):  # adding (1 - alpha) * 0 would change nothing
            for acc in (blurred, sharp):
                acc[..., :3] += (1.0 - acc[..., 3:4]) * bg
        t2 = clock()
        exposure = np.float32(self.settings.exposure)
        vig = self.vignetting(view) if self.settings.vignetting else None
        if vig is not None and self.settings.view_falloff is not None:
            vig = vig * view_falloff_map(self.erect_layout, view, region, self.settings.view_falloff)
        for r in range(0, rh, BLOCK_ROWS):
            out = image[ry + r : ry + min(rh, r + BLOCK_ROWS), rx : rx + rw]
            rgb = cv2.cvtColor(blurred[r : r + BLOCK_ROWS], cv2.COLOR_RGBA2RGB)
            if vig is not None:
                v = vig[r : r + BLOCK_ROWS]
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
    workers = default_workers() if workers is None else check_int(workers, "workers", minimum=1)
    clock = time.perf_counter
    t0 = clock()
    dev = device.binned(settings.binning)
    dev.require_positions()
    layout = optical_layout(dev, rotate180=settings.rotate180)
    rend = _FrameRenderer(dev, scene, settings)
    H, W = dev.sensor_height_px, dev.sensor_width_px
    shape = (H, W) if settings.pattern else (H, W, 3)
    view_times: list[dict | None] = [({} if timings is not None else None) for _ in range(4)]
    stages = {}
    with ThreadPoolExecutor(1) as side, ThreadPoolExecutor(workers) as pool:
        # The noise depends only on the seed and the frame's shape: draw it on a side thread
        # while the views render (the generator releases the GIL), the same numbers as drawing
        # it afterwards.
        noise = side.submit(draw_noise, shape, settings) if NOISE_PRESETS[settings.noise] else None
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
        raw = raw_counts(image, settings, noise=None if noise is None else noise.result()[0], pool=pool, stripes=workers)
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
        layout=layout, device=dev, settings=settings, scene=scene, distortion=lens_distortions(dev, layout),
    )
