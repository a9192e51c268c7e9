"""Refocusing quality against a full-aperture ground truth: shift-and-add vs depth-aware.

    python benchmarks/bench_refocus_quality.py            # Lytro quality + 1060^2 speed
    python benchmarks/bench_refocus_quality.py --no-speed # quality only
    (from a worktree elsewhere: --lytro /path/to/shared/data/lytro_gen1/IMG_0001)

Quality (:func:`compare`): PSNR and SSIM (scikit-image) of both methods against a ground-truth
image of what a lens with the whole aperture records, separately over the pixels in focus
(circle-of-confusion radius <= IN_FOCUS_PX) and those visibly out of focus (> OUT_OF_FOCUS_PX),
at several focus depths; time per frame. ``compare`` takes any views, calibration, depth map
and ground truth, so the synthetic twin's conventional render (``lfring synth ...
--conventional-focus Z``, on another branch) can be added as one more case.

a) Lytro (../shared/data/lytro_gen1/IMG_0001, J. F. Jaramillo Hernandez and M. F. Hernandez
   Baena, CC BY 4.0): a real 10 x 10 light field. The four quadrant-centre views (rows/cols 3
   and 8) play the ring's four views; the mean of all 100 views shifted for the focus disparity
   is the ground truth. The 4-view calibration is built here (:func:`grid_calibration`):
   translations affine in x = 1/(Z - z0) with a made-up metric scale, disparity d = D_PER_X x +
   D0 px per grid step (z0 = 0). [Lead: switch to ``RingCalibration.from_grid`` once merged.]
   Aperture: the 100 views fill a 10 x 10-step square; its second moment about the centre is
   2 (10^2 - 1) / 12 = 16.5 step^2 (grid positions -4.5..4.5), which a disc of radius
   sqrt(2 * 16.5) = 5.74 steps matches. The 4 views sit 2.5 sqrt(2) = 3.54 steps from the
   centre (the depth-aware aperture 1), so ``aperture = 5.74 / 3.54 = 1.625``.
   The depth map is estimated from the four views (``lfring.estimate_depth`` over the
   calibration's valid range): what a user would have.
b) The synthetic twin's full-aperture render is not yet on main; lfring.synth.renderer places
   its pinholes only at the views (no viewpoint anywhere in the aperture), so no honest
   twin ground truth can be made here without changing the renderer: skipped.

Speed (``--speed``, default on): 4 x 1060 x 1060 RGB float32 views (bench_refocus.py's
prototype calibration, square views) with a given depth map: one-shot shift-and-add at a new
depth, one-shot depth-aware (depth map given: all-in-focus colour + render), a depth-aware
render at a new depth from a reused renderer, and 15-depth focal stacks of both methods.
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

from _timing import bench
from lfring import estimate_depth
from lfring.calibration import RingCalibration
from lfring.focus.depth_aware import coc_radius_px
from lfring.errors import LfringWarning
from lfring.focus import depth_of_field, focal_stack, refocus
from lfring.views import Layout

LYTRO = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "lytro_gen1" / "IMG_0001"
GRID = 10
CENTRE = (GRID + 1) / 2.0  # 5.5: grid positions 1..10
QUADRANT = (3, 8)  # rows/cols of the four views
D_PER_X, D0 = 2.0, -2.0  # made-up metric scale: disparity per grid step d = 2 x - 2, x = 1/Z (z0 = 0)
LYTRO_APERTURE = float(np.sqrt(2 * 2 * (GRID**2 - 1) / 12.0) / (2.5 * np.sqrt(2)))  # 1.625, see above
FOCUS_DISPARITIES = (-0.2, 0.3, 0.62, 0.68, 1.0, 1.5)  # px per grid step; the scene spans about 0.6 .. 0.7
IN_FOCUS_PX, OUT_OF_FOCUS_PX = 0.5, 1.5
BORDER_PX = 12  # frame border left out of every metric (shifted views do not cover it)


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


def shift_view(view, dx, dy):
    """The view sampled at x + (dx, dy) (bilinear, zero outside)."""
    h, w = view.shape[:2]
    m = np.array([[1, 0, -dx], [0, 1, -dy]], np.float64)  # warpAffine maps src -> dst: dst(x) = src(x + d)
    return cv2.warpAffine(view, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)


def full_aperture(grid_views, d):
    """Ground truth: the mean of all views aligned for disparity d (a point with disparity d
    appears in view (r, c) at x + d * position(r, c))."""
    acc = np.zeros(grid_views.shape[2:], np.float64)
    for r, c in itertools.product(range(GRID), range(GRID)):
        acc += shift_view(grid_views[r, c], *(d * position(r + 1, c + 1)))
    return (acc / GRID**2).astype(np.float32)


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


def compare(name, views, calibration, depth_m, truth, focus_m, aperture, *, border_px=BORDER_PX):
    """Both methods against ``truth`` at ``focus_m``: one row per method with the PSNR/SSIM in
    and out of focus (regions from the depth map's circle of confusion at ``aperture``) and the
    time per frame (depth map given)."""
    r = coc_radius_px(calibration, depth_m, focus_m, aperture=aperture)
    inner = np.zeros(truth.shape[:2], bool)
    inner[border_px:-border_px, border_px:-border_px] = True
    regions = {"in focus": inner & (r <= IN_FOCUS_PX), "out of focus": inner & (r > OUT_OF_FOCUS_PX), "all": inner}
    rows = []
    for method, kw in (("shift-and-add", {}), ("depth-aware", {"aperture": aperture, "depth": depth_m})):
        t = time.perf_counter()
        img = refocus(views, calibration, focus_m, method=method, **kw)
        dt = time.perf_counter() - t
        scores = {k: region_scores(img, truth, m) for k, m in regions.items()}
        rows.append({"case": name, "method": method, "focus_m": focus_m, "seconds": dt,
                     "fraction": {k: float(m.mean()) for k, m in regions.items()}, **scores})
    return rows


def lytro_cases(folder):
    grid = load_lytro(folder)
    idx = [(r, c) for r in QUADRANT for c in QUADRANT]
    views = np.stack([grid[r - 1, c - 1] for r, c in idx])
    positions = [position(r, c) for r, c in idx]
    cal = grid_calibration(views.shape[1:3], positions)
    lo, hi = cal.valid_depth_range_m
    depth = estimate_depth(views, cal, zmin_m=lo, zmax_m=hi)
    disp = D_PER_X / depth.depth_m + D0
    print(f"Lytro IMG_0001: 4 views of {views.shape[2]} x {views.shape[1]} px; estimated disparity per step "
          f"{np.nanpercentile(disp, 2):.2f} .. {np.nanpercentile(disp, 98):.2f} (2nd..98th percentile); "
          f"aperture {LYTRO_APERTURE:.3f}")
    rows = []
    for d in FOCUS_DISPARITIES:
        rows += compare(f"lytro d={d:+.2f}", views, cal, depth.depth_m, full_aperture(grid, d),
                        float(depth_of_disparity(d)), LYTRO_APERTURE)
    return rows


TWIN_FOCUS_M = (0.3, 0.5, 1.0)  # the three-depth scene's cup, book and chessboard


def twin_cases(scene_name: str, *, binning: int = 4, seed: int = 5):
    """The twin: a Bayer frame with realistic noise (optical vignetting off, since the truth has
    none), demosaiced and split; the truth is the conventional image through the aperture the
    four views span (aperture_scale 1, lfring.synth.render_conventional), times the render's
    exposure (the views' photometric scale). The depth map is estimate_depth's (defaults) over
    0.27..1.1 m, the hole-filled one."""
    from lfring.io.demosaic import demosaic
    from lfring.io.raw import RawFrame
    from lfring.optics import load_device
    from lfring.synth import render, render_conventional
    from lfring.synth.presets import hard_scene, three_depth_scene
    from lfring.views import split_views

    scene = {"three-depth": three_depth_scene, "hard": hard_scene}[scene_name]()
    dev = load_device("prototype")
    r = render(dev, scene, binning=binning, noise="realistic", vignetting=False, seed=seed)
    frame = RawFrame(mosaic=r.raw, pattern="RGGB", black_level=r.black_level, white_level=r.white_level, bit_depth=12)
    views = split_views(demosaic(frame), r.layout)
    cal = RingCalibration.from_optics(r.device, layout=r.layout)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)
        res = estimate_depth(views, cal, zmin_m=0.27, zmax_m=1.1)
    depth = res.depth_filled_m if res.depth_filled_m is not None else res.depth_m
    depth = np.where(np.isfinite(depth), depth, np.nanmedian(depth)).astype(np.float32)
    exposure = r.settings.exposure
    print(f"twin {scene_name}: 4 views of {views.shape[2]} x {views.shape[1]} px (binning {binning}), "
          f"truth at aperture_scale 1 = aperture 1")
    rows = []
    for z in TWIN_FOCUS_M:
        truth = exposure * render_conventional(scene, dev, z, aperture_scale=1.0, binning=binning)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LfringWarning)
            rows += compare(f"twin {scene_name}", views, cal, depth, truth, z, 1.0)
    return rows


def print_quality(rows):
    print("| case | focus (m) | method | in focus PSNR / SSIM (% px) | out of focus PSNR / SSIM (% px) | all PSNR / SSIM | s/frame |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        fi, fo = r["fraction"]["in focus"], r["fraction"]["out of focus"]
        print(f"| {r['case']} | {r['focus_m']:.3f} | {r['method']} | {r['in focus'][0]:.2f} / {r['in focus'][1]:.4f} ({100 * fi:.0f}) "
              f"| {r['out of focus'][0]:.2f} / {r['out of focus'][1]:.4f} ({100 * fo:.0f}) "
              f"| {r['all'][0]:.2f} / {r['all'][1]:.4f} | {r['seconds']:.3f} |")
    gains_out, gains_in = [], []
    for sa, da in zip(rows[::2], rows[1::2]):
        gains_out.append(da["out of focus"][0] - sa["out of focus"][0])
        gains_in.append(da["in focus"][0] - sa["in focus"][0])
    g_out = [g for g in gains_out if np.isfinite(g)]
    g_in = [g for g in gains_in if np.isfinite(g)]
    print(f"\ndepth-aware - shift-and-add, out of focus: mean {np.mean(g_out):+.2f} dB, worst {min(g_out):+.2f} dB "
          f"(target: mean >= +3 dB, none below 0)")
    print(f"depth-aware - shift-and-add, in focus: mean {np.mean(g_in):+.2f} dB, worst {min(g_in):+.2f} dB (target: within 0.3 dB)")


def speed(runs: int):
    from lfring.optics import load_device
    from lfring.views import layout_from_circles

    dev = load_device("prototype")
    w, h = dev.sensor_width_px, dev.sensor_height_px
    cx, cy, side = 1228.0, 921.0, 1060
    circles = [(cx + dx, cy + dy, side / 2) for dy in (0, h / 2) for dx in (0, w / 2)]
    disc = layout_from_circles(circles, w, h)
    cal = RingCalibration.from_optics(dev, layout=type(disc)(w, h, disc.rects, False, None))
    rng = np.random.default_rng(0)
    views = cv2.GaussianBlur(rng.random((4 * side, side, 3), dtype=np.float32), (0, 0), 1.5).reshape(4, side, side, 3)
    # A given depth map: a near block over a slanted far plane, 0.3 .. 1.0 m.
    yy, xx = np.mgrid[0:side, 0:side]
    depth = 0.5 + 0.5 * xx / side
    depth[side // 4:side // 2, side // 4:side // 2] = 0.3
    new_depth = (0.45 + 1e-5 * i for i in itertools.count())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)
        dof = depth_of_field(views, cal, depth=depth)
        stack_z = np.linspace(0.3, 1.0, 15)
        rows = [
            ("shift-and-add one-shot refocus, a new depth every call", runs, lambda: refocus(views, cal, next(new_depth))),
            ("depth-aware one-shot refocus, depth map given, a new depth every call", max(3, runs // 4),
             lambda: refocus(views, cal, next(new_depth), method="depth-aware", depth=depth)),
            ("depth-aware render at a new depth, renderer reused (+ its shift-and-add)", max(3, runs // 4),
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
        t = time.perf_counter()
        estimate_depth(views, cal, zmin_m=0.3, zmax_m=1.0)
        print(f"estimate_depth 0.3..1.0 m (once, for comparison with the stacks): {1e3 * (time.perf_counter() - t):.0f} ms")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-speed", action="store_true")
    ap.add_argument("--no-quality", action="store_true")
    ap.add_argument("--runs", type=int, default=11)
    ap.add_argument("--lytro", type=Path, default=LYTRO, help="the IMG_0001 folder (default: ../shared/data/... from the repo root)")
    args = ap.parse_args()
    print(f"load: {os.getloadavg()[0]:.1f} {os.getloadavg()[1]:.1f} {os.getloadavg()[2]:.1f} on {os.cpu_count()} CPUs")
    if not args.no_quality:
        if not args.lytro.is_dir():
            print(f"no Lytro data at {args.lytro}: quality skipped", file=sys.stderr)
        else:
            print_quality(lytro_cases(args.lytro))
        print_quality(twin_cases("three-depth") + twin_cases("hard"))
    if not args.no_speed:
        speed(args.runs)


if __name__ == "__main__":
    main()
