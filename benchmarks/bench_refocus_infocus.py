"""Where depth-aware refocusing loses to shift-and-add in focus: the in-focus pixels of one case
of bench_refocus_quality.py (the same scene, views, truth and masks), the estimate handed to the
renderer as lfring refocus hands it (the DepthResult), and the excess squared error of
depth-aware over shift-and-add split by what the renderer knew at each pixel: whether the
estimate has a depth there, how many views' worth see it at the focus, and the blur radius the
estimated depth gives. Prints only.

    python benchmarks/bench_refocus_infocus.py                      # slant-wide at 0.4 m
    python benchmarks/bench_refocus_infocus.py --case ramp-wide --focus 0.35
    python benchmarks/bench_refocus_infocus.py --depth      # also the depth's errors, and two continuations

With ``--depth``: the renderer's depth against the truth in px of view motion (aperture 1), by
bands of columns from the frame's left edge (where the slant is nearest and fewer views see it),
the estimate's measured pixels apart from the ones the renderer continues; and the continued
pixels' error for the renderer's continuation (the nearest measured depth, feathered), the
nearest measured depth alone, and a first-order continuation (the nearest measured pixel's
local plane, fitted over its measured neighbours by a Gaussian window of ``--plane-px``,
extended to the continued pixel), by distance from the nearest measured pixel.
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np

from bench_refocus_quality import BORDER_PX, CONTINUOUS, IN_FOCUS_PX, MIN_VIEWS, WIDE, central_depth, continuous_scene
from lfring import estimate_depth
from lfring.calibration import RingCalibration
from lfring.errors import LfringWarning
from lfring.focus import Refocuser, refocus
from lfring.focus.depth_aware import coc_radius_px


def _psnr(mse: float) -> float:
    return float(-10.0 * np.log10(mse))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--case", default="slant-wide", choices=sorted((*CONTINUOUS, *WIDE)))
    ap.add_argument("--focus", type=float, default=0.4, help="focus depth (m)")
    ap.add_argument("--depth", action="store_true", help="also the depth's errors and two continuations")
    ap.add_argument("--rim-taper", type=float, default=None, help="estimate_depth's rim_taper (default: its own)")
    ap.add_argument("--plane-px", type=float, default=12.0, help="the first-order continuation's window (Gaussian sigma, px)")
    args = ap.parse_args()
    from lfring.io.demosaic import demosaic
    from lfring.io.raw import RawFrame
    from lfring.optics import load_device
    from lfring.synth import render, render_conventional
    from lfring.views import split_views

    name, aperture = WIDE.get(args.case, (args.case, 1.0))
    scene = continuous_scene(name)
    dev = load_device("prototype")
    r = render(dev, scene, binning=2, noise="realistic", vignetting=False, defocus=False, seed=5)
    frame = RawFrame(mosaic=r.raw, pattern="RGGB", black_level=r.black_level, white_level=r.white_level, bit_depth=12)
    views = split_views(demosaic(frame), r.layout)
    cal = RingCalibration.from_optics(r.device, layout=r.layout)
    warnings.simplefilter("ignore", LfringWarning)
    taper = {} if args.rim_taper is None else {"rim_taper": args.rim_taper}
    res = estimate_depth(views, cal, zmin_m=0.27, zmax_m=1.1, **taper)
    true = central_depth(scene, dev, 2)
    true = np.where(np.isfinite(true), true, np.nanmax(true)).astype(np.float32)
    truth = r.settings.exposure * render_conventional(scene, dev, args.focus, aperture_scale=aperture, binning=2)

    z = args.focus
    rad = coc_radius_px(cal, true, z, aperture=aperture)
    worth = Refocuser(cal, z, view_shape=truth.shape[:2]).weight
    inner = np.zeros(truth.shape[:2], bool)
    inner[BORDER_PX:-BORDER_PX, BORDER_PX:-BORDER_PX] = True
    focus = inner & (worth >= MIN_VIEWS) & (rad <= IN_FOCUS_PX)
    sa = refocus(views, cal, z)
    da = refocus(views, cal, z, method="depth-aware", aperture=aperture, depth=res)
    err_sa = ((np.clip(sa, 0, 1) - truth) ** 2).mean(axis=2)
    err_da = ((np.clip(da, 0, 1) - truth) ** 2).mean(axis=2)
    excess = err_da - err_sa
    total = float(excess[focus].sum())
    n = int(focus.sum())
    print(f"{args.case} at {z:g} m, aperture {aperture:g}: {n} in-focus pixels ({focus.mean():.1%}); PSNR "
          f"shift-and-add {_psnr(err_sa[focus].mean()):.2f} dB, depth-aware {_psnr(err_da[focus].mean()):.2f} dB")
    known = np.isfinite(res.depth_m)
    est_rad = coc_radius_px(cal, np.where(known, res.depth_m, np.nanmedian(res.depth_m)), z, aperture=aperture)

    def rows(title, parts):
        print(f"\n| {title} | pixels | share of the excess | depth-aware - shift-and-add if only these differed (dB) |")
        print("|---|---|---|---|")
        for label, m in parts:
            m = focus & m
            if not m.any():
                continue
            part = float(excess[m].sum())
            alone = _psnr(err_sa[focus].mean() + part / n) - _psnr(err_sa[focus].mean())
            print(f"| {label} | {int(m.sum())} | {part / total:.0%} | {alone:+.2f} |")

    rows("the estimate at the pixel", [("no depth (fewer than two views saw it)", ~known), ("a depth", known)])
    rows("views' worth at the focus", [(f"{lo:g} .. {hi:g}", (worth >= lo) & (worth < hi))
                                       for lo, hi in ((0, 1.01), (1.01, 1.5), (1.5, 2.5), (2.5, 3.5), (3.5, 9))])
    rows("blur radius of the estimated depth (px), pixels with a depth",
         [(f"{lo:g} .. {hi:g}", known & (est_rad >= lo) & (est_rad < hi))
          for lo, hi in ((0, 0.5), (0.5, 1), (1, 1.5), (1.5, 3), (3, np.inf))])
    if args.depth:
        depth_errors(views, cal, res, true, inner, args.plane_px)


def _plane_continuation(x: np.ndarray, measured: np.ndarray, sigma_px: float) -> np.ndarray:
    """Every pixel's inverse depth from its nearest measured pixel's local plane: a weighted
    least-squares plane over the measured pixels around it (Gaussian window), extended."""
    import cv2

    h, w = x.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    wt = measured.astype(np.float64)
    xv = np.where(measured, x, 0.0)

    def g(a):
        return cv2.GaussianBlur(a, (0, 0), sigma_px)

    s = g(wt) + 1e-12
    mu = [g(wt * a) / s for a in (xx, yy, xv)]
    cuu = g(wt * xx * xx) / s - mu[0] ** 2
    cuv = g(wt * xx * yy) / s - mu[0] * mu[1]
    cvv = g(wt * yy * yy) / s - mu[1] ** 2
    czu = g(wt * xv * xx) / s - mu[2] * mu[0]
    czv = g(wt * xv * yy) / s - mu[2] * mu[1]
    det = cuu * cvv - cuv ** 2
    ok = det > 1e-3
    det = np.where(ok, det, 1.0)
    gu = np.where(ok, (czu * cvv - czv * cuv) / det, 0.0)
    gv = np.where(ok, (czv * cuu - czu * cuv) / det, 0.0)
    fit = mu[2] + gu * (xx - mu[0]) + gv * (yy - mu[1])
    _, labels = cv2.distanceTransformWithLabels((~measured).view(np.uint8), cv2.DIST_L2, 5,
                                                labelType=cv2.DIST_LABEL_PIXEL)
    iy, ix = np.nonzero(measured)
    ny, nx = iy[labels - 1], ix[labels - 1]
    return np.where(measured, x, fit[ny, nx] + gu[ny, nx] * (xx - nx) + gv[ny, nx] * (yy - ny))


def depth_errors(views, cal, res, true, inner, plane_px: float) -> None:
    """The renderer's depth and two other continuations against the truth (px of view motion)."""
    import cv2

    from lfring.focus.depth_aware import aperture_radius_px, depth_of_field

    z0 = cal.depth_origin_m
    radius = aperture_radius_px(cal)
    dof = depth_of_field(views, cal, depth=res)
    x_true = 1.0 / (true.astype(np.float64) - z0)
    known = np.isfinite(res.depth_m)
    x_est = np.where(known, 1.0 / (np.where(known, res.depth_m, 1.0) - z0), 0.0)
    # The pixels whose estimated depth the renderer kept (elsewhere it continued the nearest kept).
    kept = known & (np.abs(dof.x - x_est) <= 1e-6 * np.abs(x_est))
    h, w = x_true.shape
    print("\nthe estimate's measured depth against the truth by columns (px of view motion; "
          "the renderer keeps these pixels' depths)")
    print("| columns | measured pixels | views' worth there | mean error | rms error |")
    print("|---|---|---|---|---|")
    for c0 in range(0, 200, 20):
        m = inner & kept
        m[:, :c0] = False
        m[:, c0 + 20:] = False
        e = radius * (x_est[m] - x_true[m])
        worth = Refocuser(cal, float(np.median(true[m])), view_shape=(h, w)).weight[m].mean()
        print(f"| {c0}..{c0 + 19} | {int(m.sum())} | {worth:.2f} | {e.mean():+.3f} | {np.sqrt((e ** 2).mean()):.3f} |")
    nearest_only = x_est[kept][cv2.distanceTransformWithLabels((~kept).view(np.uint8), cv2.DIST_L2, 5,
                                                               labelType=cv2.DIST_LABEL_PIXEL)[1] - 1]
    ways = (("the renderer's (nearest, feathered)", dof.x), ("the nearest measured depth", nearest_only),
            (f"first order (plane over sigma {plane_px:g} px)", _plane_continuation(x_est, kept, plane_px)))
    dist = cv2.distanceTransform((~kept).view(np.uint8), cv2.DIST_L2, 5)
    bands = ((0, 10), (10, 30), (30, 60), (60, np.inf))
    print("\nthe continued pixels' depth error, rms px of view motion, by distance from the nearest measured pixel")
    print("| continuation | " + " | ".join(f"{lo:g}..{hi:g} px" for lo, hi in bands) + " |")
    print("|---" * (len(bands) + 1) + "|")
    for label, x in ways:
        cells = []
        for lo, hi in bands:
            m = inner & ~kept & (dist >= lo) & (dist < hi)
            cells.append(f"{np.sqrt(((radius * (x[m] - x_true[m])) ** 2).mean()):.3f} ({int(m.sum())})" if m.any() else "-")
        print(f"| {label} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
