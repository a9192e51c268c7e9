"""Refocusing quality against a full-aperture ground truth: shift-and-add vs depth-aware, with the
true depth map and with the estimated one.

    python benchmarks/bench_refocus_quality.py                   # every case + 1060^2 speed
    python benchmarks/bench_refocus_quality.py --no-speed        # quality only
    python benchmarks/bench_refocus_quality.py --no-quality      # speed only
    python benchmarks/bench_refocus_quality.py --cases lytro,slant --no-speed
    python benchmarks/bench_refocus_quality.py --cases slant-wide,ramp-wide --no-speed   # blurs on reduced grids
    python benchmarks/bench_refocus_quality.py --no-speed --estimate-as result   # as lfring refocus gives it
    (from a worktree elsewhere: --lytro /path/to/shared/data/lytro_gen1/IMG_0001)

Quality (:func:`compare`): PSNR and SSIM (scikit-image) of shift-and-add and of the depth-aware
renderer, given the true depth map and given the estimated one (``lfring.estimate_depth`` with
its defaults: what a user has), against a ground-truth image of what a lens with the whole
aperture records, at the aperture that matches it. The pixels are split by the TRUE depth's
circle of confusion at that aperture into those in focus (radius <= IN_FOCUS_PX) and those
visibly out of focus (> OUT_OF_FOCUS_PX), the same pixels for every method, leaving out the
frame's border and what less than one view's worth sees (MIN_VIEWS: the corners outside the
twin's valid view discs, which no method can render); several focus depths per case; time per
frame.

a) Lytro (../shared/data/lytro_gen1/IMG_0001, J. F. Jaramillo Hernandez and M. F. Hernandez
   Baena, CC BY 4.0): a real 10 x 10 light field. The four quadrant-centre views (rows/cols 3
   and 8) play the ring's four views; the mean of all 100 views shifted for the focus disparity
   is the ground truth. The 4-view calibration is built here (:func:`grid_calibration`):
   translations affine in x = 1/(Z - z0) with a made-up metric scale, disparity d = D_PER_X x +
   D0 px per grid step (z0 = 0). Aperture: the 100 views fill a 10 x 10-step square; its second
   moment about the centre is 2 (10^2 - 1) / 12 = 16.5 step^2 (grid positions -4.5..4.5), which
   a disc of radius sqrt(2 * 16.5) = 5.74 steps matches. The 4 views sit 2.5 sqrt(2) = 3.54
   steps from the centre (the depth-aware aperture 1), so ``aperture = 5.74 / 3.54 = 1.625``.
   There is no measured depth: the "true" depth is the one all 100 views agree on
   (:func:`dense_disparity`: a plane sweep over the 100 views, the least variance over a
   5 x 5 window, refined to a fraction of a step), far better constrained than what four views
   give.
b) The synthetic twin, every view rendered from the prototype's optics (Bayer frame with
   realistic noise, optical vignetting off since the truth has none, demosaiced and split);
   the truth is :func:`lfring.synth.render_conventional` through the aperture the four views
   span (aperture_scale 1 = the renderer's aperture 1), times the render's exposure; the true
   depth is the scene's depth seen from the central viewpoint (:func:`central_depth`).
   - 'three-depth' and 'hard' (4 x 4 binning): the paper's scene and the hard scene, mostly
     fronto-parallel planes with depth edges;
   - continuous depth that defocuses visibly (2 x 2 binning, blur radii up to about 6 px):
     'slant', a textured plane turned 70 degrees about the vertical, from about 0.38 to 1.05 m
     across the frame; 'sphere', a half sphere and a cylindrical ridge on a part at 0.5 m;
     'ramp', a floor tilted 72 degrees about the horizontal across the working range, about
     0.3 to 1.0 m from bottom to top; 'statue', a half sphere and a ridge on a part at 0.52 m,
     shaded and of faint texture, where shift-and-add's copies hardly show and a seam would.
   Their views are rendered without their own mini-lens defocus (--view-defocus on renders
   it): the truth is an ideal lens, and the views' own blur (their pupils focused at the
   design distance) would otherwise bound both methods alike.
   - 'slant-wide' and 'ramp-wide': the slant and the ramp through a lens three times as wide
     (aperture 3 and its truth at aperture_scale 3, blur radii to about 14 px): the renderer's
     wide blurs, made on reduced grids from 6 px, which no other case reaches.

Speed (``--speed``, default on): 4 x 1060 x 1060 RGB float32 views (bench_refocus.py's
prototype calibration, square views) with a given depth map: one-shot shift-and-add at a new
depth, one-shot depth-aware (depth map given: all-in-focus colour + render), a depth-aware
render at a new depth from a reused renderer, and 15-depth focal stacks of both methods; then
the render at a new depth (with its shift-and-add) and a one-shot shift-and-add timed in
alternation, the target's ratio as the median of the pairs' ratios.
"""

from __future__ import annotations

import argparse
import itertools
import os
import sys
import time
import warnings
from pathlib import Path

import cv2
import numpy as np
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from _timing import bench, paired
from lfring import estimate_depth
from lfring.calibration import RingCalibration
from lfring.focus.depth_aware import coc_radius_px
from lfring.errors import LfringWarning
from lfring.focus import Refocuser, depth_of_field, focal_stack, refocus
from lfring.views import Layout

LYTRO = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "lytro_gen1" / "IMG_0001"
GRID = 10
CENTRE = (GRID + 1) / 2.0  # 5.5: grid positions 1..10
QUADRANT = (3, 8)  # rows/cols of the four views
D_PER_X, D0 = 2.0, -2.0  # made-up metric scale: disparity per grid step d = 2 x - 2, x = 1/Z (z0 = 0)
LYTRO_APERTURE = float(np.sqrt(2 * 2 * (GRID**2 - 1) / 12.0) / (2.5 * np.sqrt(2)))  # 1.625, see above
FOCUS_DISPARITIES = (-0.2, 0.3, 0.62, 0.68, 1.0, 1.5)  # px per grid step; the scene spans about 0.6 .. 0.7
DENSE_DISPARITIES = np.arange(0.3, 1.0001, 0.02)  # the plane sweep of the dense depth, px per grid step
IN_FOCUS_PX, OUT_OF_FOCUS_PX = 0.5, 1.5
BORDER_PX = 12  # frame border left out of every metric (shifted views do not cover it)
MIN_VIEWS = 1.0  # and pixels that less than one view's worth sees (the corners outside the twin's view discs)
CASES = ("lytro", "three-depth", "hard", "slant", "sphere", "ramp", "statue", "slant-wide", "ramp-wide")
CONTINUOUS = ("slant", "sphere", "ramp", "statue")
# Continuous scenes through a lens three times as wide as the views span (blur radii to about
# 14 px): the renderer's wide blurs, on reduced grids from 6 px, which the other cases never reach.
WIDE = {"slant-wide": ("slant", 3.0), "ramp-wide": ("ramp", 3.0)}


def position(row, col):
    """(x, y) position of view (row, col) in grid steps from the centre. In this data set the
    file's row index moves the image along x and its column index along y (phase correlation:
    views (3, 5) -> (8, 5) differ by 3.3 px in x, (5, 3) -> (5, 8) by 3.3 px in y)."""
    return np.array([row - CENTRE, col - CENTRE], dtype=np.float64)


def depth_of_disparity(d):
    return 1.0 / ((np.asarray(d, dtype=np.float64) - D0) / D_PER_X)


def load_lytro(folder):
    """(10, 10, h, w, 3) float32 views by (row, col) 1..10."""
    files = sorted(Path(folder).glob("IMG_0001_*_*_*.png"))
    if len(files) != GRID * GRID:
        raise SystemExit(f"expected {GRID * GRID} views in {folder}, found {len(files)}")
    first = cv2.imread(str(files[0]))
    out = np.empty((GRID, GRID, *first.shape), np.float32)
    for f in files:
        row, col = f.stem.split("_")[-2:]
        img = cv2.imread(str(f), cv2.IMREAD_COLOR)[..., ::-1]
        out[int(row) - 1, int(col) - 1] = img.astype(np.float32) / 255.0
    return out


def shift_view(view, dx, dy, border=cv2.BORDER_CONSTANT):
    """The view sampled at x + (dx, dy) (bilinear, zero outside unless ``border`` says otherwise)."""
    h, w = view.shape[:2]
    m = np.array([[1, 0, -dx], [0, 1, -dy]], np.float64)  # warpAffine maps src -> dst: dst(x) = src(x + d)
    return cv2.warpAffine(view, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=border)


def full_aperture(grid_views, d):
    """Ground truth: the mean of all views aligned for disparity d (a point with disparity d
    appears in view (r, c) at x + d * position(r, c))."""
    acc = np.zeros(grid_views.shape[2:], np.float64)
    for r, c in itertools.product(range(GRID), range(GRID)):
        acc += shift_view(grid_views[r, c], *(d * position(r + 1, c + 1)))
    return (acc / GRID**2).astype(np.float32)


def dense_disparity(grid_views, disparities=DENSE_DISPARITIES, window_px: int = 5):
    """The disparity (px per grid step) all 100 views agree on at every pixel: the variance of
    their luminance aligned for each hypothesis, averaged over a ``window_px`` box, its least
    refined by a parabola through its neighbours (the views continued past the frame's edge by
    their last pixels, so that the border does not pull the sweep to a range end)."""
    lum = grid_views.mean(axis=-1)
    costs = []
    for d in disparities:
        s = np.zeros(lum.shape[2:], np.float64)
        s2 = np.zeros_like(s)
        for r, c in itertools.product(range(GRID), range(GRID)):
            v = shift_view(lum[r, c], *(d * position(r + 1, c + 1)), border=cv2.BORDER_REPLICATE)
            s += v
            s2 += v * v
        var = (s2 / GRID**2 - (s / GRID**2) ** 2).astype(np.float32)
        costs.append(cv2.boxFilter(var, -1, (window_px, window_px)))
    costs = np.stack(costs)
    i = np.clip(np.argmin(costs, axis=0), 1, len(disparities) - 2)
    c0, c1, c2 = (np.take_along_axis(costs, (i + k)[None], 0)[0] for k in (-1, 0, 1))
    den = c0 - 2 * c1 + c2
    frac = np.where(den > 1e-12, 0.5 * (c0 - c2) / np.maximum(den, 1e-12), 0.0)
    step = disparities[1] - disparities[0]
    return disparities[i] + np.clip(frac, -0.5, 0.5) * step


def grid_calibration(view_shape, positions):
    """A calibration of views on a regular grid at ``positions`` (grid steps (col, row) from the
    centre): ``H_center_from_k`` translates by ``-d(x) * position`` with d = D_PER_X x + D0.
    [Local helper: RingCalibration.from_grid is being added on another branch.]"""
    h, w = view_shape
    n = len(positions)
    cols = int(np.ceil(np.sqrt(n)))
    rects = tuple(((i % cols) * (w + 8), (i // cols) * (h + 8), w, h) for i in range(n))
    layout = Layout(cols * (w + 8), -(-n // cols) * (h + 8), rects)
    pos = np.asarray(positions, dtype=np.float64)

    def hs(z):
        d = D_PER_X / z + D0
        t = -d * pos  # view pixel u shows the reference point u - d * position
        out = np.repeat(np.eye(3)[None], n, axis=0)
        out[:, :2, 2] = t - t[0]
        return out

    zs = depth_of_disparity([1.5, -1.5])  # valid range: disparities -1.5..1.5 px per step
    return RingCalibration.from_plane_homographies({float(z): hs(float(z)) for z in zs}, layout=layout, depth_origin_m=0.0)


def region_scores(img, truth, mask):
    """PSNR (dB) and mean SSIM over ``mask``."""
    if not mask.any():
        return float("nan"), float("nan")
    psnr = peak_signal_noise_ratio(truth[mask], np.clip(img[mask], 0, 1), data_range=1.0)
    _, ssim_map = structural_similarity(truth, np.clip(img, 0, 1), channel_axis=2, data_range=1.0, full=True)
    return float(psnr), float(ssim_map.mean(axis=2)[mask].mean())


def compare(name, views, calibration, depths, truth, focus_m, aperture, *, border_px=BORDER_PX):
    """Shift-and-add and depth-aware (once per depth map of ``depths``, {'true': ..., 'estimated':
    ...}) against ``truth`` at ``focus_m``: one row per method with the PSNR/SSIM in and out of
    focus (regions from the TRUE depth map's circle of confusion at ``aperture``) and the time
    per frame (depth map given)."""
    r = coc_radius_px(calibration, depths["true"], focus_m, aperture=aperture)
    inner = np.zeros(truth.shape[:2], bool)
    inner[border_px:-border_px, border_px:-border_px] = True
    # Only what the views see: no method renders a pixel that less than one view's worth covers.
    inner &= Refocuser(calibration, focus_m, view_shape=truth.shape[:2]).weight >= MIN_VIEWS
    regions = {"in focus": inner & (r <= IN_FOCUS_PX), "out of focus": inner & (r > OUT_OF_FOCUS_PX), "all": inner}
    rows = []
    methods = [("shift-and-add", {})] + [(f"depth-aware, {k} depth", {"method": "depth-aware", "aperture": aperture, "depth": d})
                                         for k, d in depths.items()]
    for method, kw in methods:
        t = time.perf_counter()
        img = refocus(views, calibration, focus_m, **kw)
        dt = time.perf_counter() - t
        scores = {k: region_scores(img, truth, m) for k, m in regions.items()}
        rows.append({"case": name, "method": method, "focus_m": focus_m, "seconds": dt,
                     "fraction": {k: float(m.mean()) for k, m in regions.items()}, **scores})
    return rows


def lytro_cases(folder, *, as_result: bool = False):
    grid = load_lytro(folder)
    idx = [(r, c) for r in QUADRANT for c in QUADRANT]
    views = np.stack([grid[r - 1, c - 1] for r, c in idx])
    positions = [position(r, c) for r, c in idx]
    cal = grid_calibration(views.shape[1:3], positions)
    lo, hi = cal.valid_depth_range_m
    res = estimate_depth(views, cal, zmin_m=lo, zmax_m=hi)
    est = res.depth_m
    dense = dense_disparity(grid)
    disp = D_PER_X / est + D0
    print(f"Lytro IMG_0001: 4 views of {views.shape[2]} x {views.shape[1]} px; disparity per step "
          f"{np.nanpercentile(dense, 2):.2f} .. {np.nanpercentile(dense, 98):.2f} from all 100 views, "
          f"{np.nanpercentile(disp, 2):.2f} .. {np.nanpercentile(disp, 98):.2f} estimated from the four "
          f"(2nd..98th percentile; median difference {np.nanmedian(np.abs(disp - dense)):.3f}); aperture {LYTRO_APERTURE:.3f}")
    depths = {"true": depth_of_disparity(dense), "estimated": res if as_result else est}
    rows = []
    for d in FOCUS_DISPARITIES:
        rows += compare(f"lytro d={d:+.2f}", views, cal, depths, full_aperture(grid, d), float(depth_of_disparity(d)),
                        LYTRO_APERTURE)
    return rows


def continuous_scene(name: str):
    """The twin's continuous-depth scenes (see the module's description)."""
    from lfring.synth import Bump, HeightField, Plane, Scene, Texture

    if name == "slant":
        tex = Texture("speckle", feature_m=0.003, seed=21, colors=((0.1, 0.12, 0.18), (0.85, 0.75, 0.55)))
        return Scene((Plane(0.715, (0.8, 0.4), tex, center_m=(0.06, 0.0), tilt_deg=(0.0, -70.0), name="slanted plane"),),
                     name="slant")
    if name == "sphere":
        sphere = Bump(center_m=(0.18, 0.15), size_m=(0.12, 0.12), height_m=0.06, shape="sphere")
        ridge = Bump(center_m=(0.09, 0.15), size_m=(0.05, 0.3), height_m=0.025, shape="cylinder")
        part = HeightField(0.5, (0.3, 0.3), Texture("image", name="gravel"), bumps=(sphere, ridge),
                           name="sphere and cylinder")
        return Scene((part,), name="sphere")
    if name == "statue":
        # Smooth and shaded, like a statue: where shift-and-add's copies hardly show, a seam would.
        stone = Texture("speckle", feature_m=0.004, seed=23, colors=((0.55, 0.52, 0.48), (0.63, 0.6, 0.55)))
        head = Bump(center_m=(0.17, 0.14), size_m=(0.16, 0.16), height_m=0.08, shape="sphere")
        arm = Bump(center_m=(0.06, 0.15), size_m=(0.06, 0.3), height_m=0.03, shape="cylinder")
        return Scene((HeightField(0.52, (0.3, 0.3), stone, bumps=(head, arm), name="statue"),), name="statue")
    if name == "ramp":
        tex = Texture("image", name="gravel")
        return Scene((Plane(0.65, (0.4, 0.82), tex, center_m=(0.0, -0.062), tilt_deg=(-72.5, 0.0), name="ramp"),), name="ramp")
    raise ValueError(name)


TWIN_FOCUS_M = {"three-depth": (0.3, 0.5, 1.0), "hard": (0.3, 0.5, 1.0),  # the cup, the book and the chessboard
                "slant": (0.4, 0.55, 0.85), "sphere": (0.3, 0.44, 0.6), "ramp": (0.35, 0.5, 0.8),
                "statue": (0.3, 0.44, 0.7)}


def central_depth(scene, device, binning: int) -> np.ndarray:
    """(h, w) float32: the depth (metres) of the surface the central viewpoint sees at every
    pixel of the refocused frame ('center'), as :func:`lfring.synth.render_conventional` places
    that viewpoint and frame; NaN where no surface is seen."""
    from lfring.optics.views import ViewCameras, optical_layout, view_cameras
    from lfring.synth.layers import SurfaceRenderer
    from lfring.synth.settings import RenderSettings

    dev = device.binned(binning)
    cams = view_cameras(dev)
    layout = optical_layout(dev)
    vh, vw = layout.view_shape
    corner = np.mean([(x, y) for x, y, _, _ in layout.rects], axis=0)
    origin = np.floor(corner)
    rend = SurfaceRenderer(dev, scene, RenderSettings(binning=1, pattern=None, defocus=False, vignetting=False))
    rend.cams = ViewCameras(centres_m=cams.centres_m.mean(axis=0)[None], depth_origin_m=cams.depth_origin_m,
                            focal_m=cams.focal_m,
                            principal_points_m=(cams.principal_points_m.mean(axis=0) - (corner - origin) * dev.pixel_pitch_m)[None])
    x0, y0 = int(origin[0]), int(origin[1])
    depth = np.full((vh, vw), np.inf, np.float32)
    for lay in rend.layers(0, (x0, y0, vw, vh)):
        h, w = lay.depth.shape
        d = np.where(lay.rgba[..., 3] > 0.5, lay.depth, np.inf)
        sub = depth[lay.y0 - y0:lay.y0 - y0 + h, lay.x0 - x0:lay.x0 - x0 + w]
        np.minimum(sub, d, out=sub)
    return np.where(np.isfinite(depth), depth, np.nan).astype(np.float32)


def _cached(cache, name, make):
    """``make()``, kept in ``cache`` (a folder, or None) under ``name``.npy for the next run."""
    if cache is None:
        return make()
    path = Path(cache) / f"{name}.npy"
    if path.exists():
        return np.load(path)
    out = make()
    path.parent.mkdir(parents=True, exist_ok=True)
    np.save(path, out)
    return out


def twin_cases(scene_name: str, *, seed: int = 5, view_defocus: bool | None = None, cache=None, as_result: bool = False):
    """The twin: a Bayer frame with realistic noise (optical vignetting off, since the truth has
    none), demosaiced and split; the truth is the conventional image through the aperture the
    four views span (aperture_scale 1, lfring.synth.render_conventional), times the render's
    exposure (the views' photometric scale). The estimated depth map is estimate_depth's
    (defaults) over 0.27..1.1 m: the hole-filled map with NaN replaced by the median, as an
    array, or with ``as_result`` the DepthResult itself (the renderer then knows which depths
    were measured); the true one the central viewpoint's."""
    from lfring.io.demosaic import demosaic
    from lfring.io.raw import RawFrame
    from lfring.optics import load_device
    from lfring.synth import render, render_conventional
    from lfring.synth.presets import hard_scene, three_depth_scene
    from lfring.views import split_views

    label = scene_name
    scene_name, aperture = WIDE.get(label, (label, 1.0))
    binning = 2 if scene_name in CONTINUOUS else 4
    if view_defocus is None:
        view_defocus = scene_name not in CONTINUOUS
    scene = {"three-depth": three_depth_scene, "hard": hard_scene}.get(scene_name, lambda: continuous_scene(scene_name))()
    dev = load_device("prototype")
    r = render(dev, scene, binning=binning, noise="realistic", vignetting=False, defocus=view_defocus, seed=seed)
    frame = RawFrame(mosaic=r.raw, pattern="RGGB", black_level=r.black_level, white_level=r.white_level, bit_depth=12)
    views = split_views(demosaic(frame), r.layout)
    cal = RingCalibration.from_optics(r.device, layout=r.layout)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)
        res = estimate_depth(views, cal, zmin_m=0.27, zmax_m=1.1)
    est = res
    if not as_result:
        filled = res.depth_filled_m if res.depth_filled_m is not None else res.depth_m
        est = np.where(np.isfinite(filled), filled, np.nanmedian(filled)).astype(np.float32)
    true = central_depth(scene, dev, binning)
    true = np.where(np.isfinite(true), true, np.nanmax(true)).astype(np.float32)
    exposure = r.settings.exposure
    rad = coc_radius_px(cal, true, TWIN_FOCUS_M[scene_name][0], aperture=aperture)
    print(f"twin {label}: 4 views of {views.shape[2]} x {views.shape[1]} px (binning {binning}), true depth "
          f"{np.nanmin(true):.3f} .. {np.nanmax(true):.3f} m, blur radius up to {np.max(rad):.1f} px at "
          f"{TWIN_FOCUS_M[scene_name][0]} m; views {'with' if view_defocus else 'without'} their own defocus; "
          f"truth at aperture_scale {aperture:g} = aperture {aperture:g}; estimated depth given as "
          f"{'its DepthResult' if as_result else 'a filled array'}")
    rows = []
    for z in TWIN_FOCUS_M[scene_name]:
        wide = "" if aperture == 1.0 else f"_a{aperture:g}"
        truth = exposure * _cached(cache, f"truth_{scene_name}_{z:g}m{wide}",
                                   lambda z=z: render_conventional(scene, dev, z, aperture_scale=aperture, binning=binning))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LfringWarning)
            rows += compare(f"twin {label}", views, cal, {"true": true, "estimated": est}, truth, z, aperture)
    return rows


def _gains(rows, region, depth_kind):
    """Depth-aware minus shift-and-add PSNR (dB) in ``region`` for every case and focus."""
    sa = {(r["case"], r["focus_m"]): r[region][0] for r in rows if r["method"] == "shift-and-add"}
    out = [r[region][0] - sa[(r["case"], r["focus_m"])] for r in rows if r["method"] == f"depth-aware, {depth_kind} depth"]
    return [g for g in out if np.isfinite(g)]


def print_quality(rows, title):
    print(f"\n{title}")
    print("| case | focus (m) | method | in focus PSNR / SSIM (% px) | out of focus PSNR / SSIM (% px) | all PSNR / SSIM | s/frame |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        fi, fo = r["fraction"]["in focus"], r["fraction"]["out of focus"]
        print(f"| {r['case']} | {r['focus_m']:.3f} | {r['method']} | {r['in focus'][0]:.2f} / {r['in focus'][1]:.4f} ({100 * fi:.0f}) "
              f"| {r['out of focus'][0]:.2f} / {r['out of focus'][1]:.4f} ({100 * fo:.0f}) "
              f"| {r['all'][0]:.2f} / {r['all'][1]:.4f} | {r['seconds']:.3f} |")
    print()
    for kind in ("true", "estimated"):
        g_out, g_in = _gains(rows, "out of focus", kind), _gains(rows, "in focus", kind)
        if g_out:
            print(f"{title}, {kind} depth: depth-aware - shift-and-add out of focus: mean {np.mean(g_out):+.2f} dB, "
                  f"worst {min(g_out):+.2f} dB, each {' '.join(f'{g:+.2f}' for g in g_out)}")
        if g_in:
            print(f"{title}, {kind} depth: depth-aware - shift-and-add in focus: mean {np.mean(g_in):+.2f} dB, "
                  f"worst {min(g_in):+.2f} dB, largest difference {max(abs(g) for g in g_in):.2f} dB")


def speed(runs: int):
    from _common import numba_layer_line, refocus_speed_scene

    side = 1060
    views, cal, depth = refocus_speed_scene(side)  # a given depth map: a near block over a slanted far plane
    new_depth = (0.45 + 1e-5 * i for i in itertools.count())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)
        dof = depth_of_field(views, cal, depth=depth)
        stack_z = np.linspace(0.3, 1.0, 15)
        rows = [
            ("shift-and-add one-shot refocus, a new depth every call", runs, lambda: refocus(views, cal, next(new_depth))),
            ("depth-aware one-shot refocus, depth map given, a new depth every call", max(3, runs // 4),
             lambda: refocus(views, cal, next(new_depth), method="depth-aware", depth=depth)),
            # As many renders as shift-and-adds: the two rows' ratio is the target's.
            ("depth-aware render at a new depth, renderer reused (+ its shift-and-add)", runs,
             lambda: dof.render(next(new_depth), 1.0, refocus(views, cal, 0.45))),
            ("  of which the renderer's all-in-focus colour (once per depth map)", 3,
             lambda: depth_of_field(views, cal, depth=depth)),
            ("shift-and-add focal stack, 15 depths", 3, lambda: focal_stack(views, cal, stack_z)),
            ("depth-aware focal stack, 15 depths, depth map given", 3,
             lambda: focal_stack(views, cal, stack_z, method="depth-aware", depth=depth)),
        ]
        out = {}
        for name, n, fn in rows:
            out[name] = bench(fn, n)
        base = out[rows[0][0]][0]
        print(f"\n4 x {side} x {side} RGB views, {cv2.getNumThreads()} OpenCV threads; medians")
        print("| what | median ms | min | max | x shift-and-add one-shot |")
        print("|---|---|---|---|---|")
        for name, (med, lo, hi) in out.items():
            print(f"| {name} | {1e3 * med:.1f} | {1e3 * lo:.1f} | {1e3 * hi:.1f} | {med / base:.2f} |")
        # The target's ratio call by call: a render at a new depth with its shift-and-add, then a
        # one-shot shift-and-add, a moment apart (the host's speed drifts between the rows above).
        ratio, t_render, t_sa = paired(lambda: dof.render(next(new_depth), 1.0, refocus(views, cal, 0.45)),
                                       lambda: refocus(views, cal, next(new_depth)), runs)
        print(f"paired, {runs} pairs: render at a new depth (+ its shift-and-add) {1e3 * t_render:.1f} ms, "
              f"shift-and-add {1e3 * t_sa:.1f} ms; median ratio {ratio:.2f} (target 5)")
        print(numba_layer_line())
        t = time.perf_counter()
        estimate_depth(views, cal, zmin_m=0.3, zmax_m=1.0)
        print(f"estimate_depth 0.3..1.0 m (once, for comparison with the stacks): {1e3 * (time.perf_counter() - t):.0f} ms")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-speed", action="store_true")
    ap.add_argument("--no-quality", action="store_true")
    ap.add_argument("--runs", type=int, default=11)
    ap.add_argument("--cases", default=",".join(CASES), help=f"quality cases, of {','.join(CASES)}")
    ap.add_argument("--view-defocus", choices=("auto", "on", "off"), default="auto",
                    help="twin views rendered with their own mini-lens defocus: auto = on for three-depth and hard, "
                         "off for the continuous-depth scenes")
    ap.add_argument("--cache", type=Path, default=None, help="keep the twin's ground-truth images in this folder")
    ap.add_argument("--estimate-as", choices=("filled-array", "result"), default="filled-array",
                    help="the twin's estimated depth given to the renderer as its hole-filled map, NaN replaced by "
                         "the median, as a bare array (the default, as the figures so far), or as the DepthResult "
                         "itself, as lfring refocus and batches give it")
    ap.add_argument("--lytro", type=Path, default=LYTRO, help="the IMG_0001 folder (default: ../shared/data/... from the repo root)")
    args = ap.parse_args()
    twin = {"view_defocus": {"auto": None, "on": True, "off": False}[args.view_defocus], "cache": args.cache,
            "as_result": args.estimate_as == "result"}
    cases = [c for c in args.cases.split(",") if c]
    unknown = sorted(set(cases) - set(CASES))
    if unknown:
        raise SystemExit(f"unknown cases {unknown}: choose from {','.join(CASES)}")
    print(f"load: {os.getloadavg()[0]:.1f} {os.getloadavg()[1]:.1f} {os.getloadavg()[2]:.1f} on {os.cpu_count()} CPUs")
    if not args.no_quality:
        if "lytro" in cases:
            if not args.lytro.is_dir():
                print(f"no Lytro data at {args.lytro}: Lytro skipped", file=sys.stderr)
            else:
                print_quality(lytro_cases(args.lytro, as_result=twin["as_result"]), "Lytro")
        old = [c for c in cases if c in ("three-depth", "hard")]
        if old:
            print_quality([r for c in old for r in twin_cases(c, **twin)], "twin, planes with depth edges")
        new = [c for c in cases if c in CONTINUOUS]
        if new:
            print_quality([r for c in new for r in twin_cases(c, **twin)], "twin, continuous depth")
        wide = [c for c in cases if c in WIDE]
        if wide:
            print_quality([r for c in wide for r in twin_cases(c, **twin)], "twin, continuous depth, wide aperture")
    if not args.no_speed:
        speed(args.runs)


if __name__ == "__main__":
    main()
