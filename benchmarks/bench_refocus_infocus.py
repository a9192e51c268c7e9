"""Where depth-aware refocusing loses to shift-and-add in focus: the in-focus pixels of one case
of bench_refocus_quality.py (the same scene, views, truth and masks), the estimate handed to the
renderer as lfring refocus hands it (the DepthResult), and the excess squared error of
depth-aware over shift-and-add split by what the renderer knew at each pixel: whether the
estimate has a depth there, how many views' worth see it at the focus, and the blur radius the
estimated depth gives. Prints only.

    python benchmarks/bench_refocus_infocus.py                      # slant-wide at 0.4 m
    python benchmarks/bench_refocus_infocus.py --case ramp-wide --focus 0.35
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
    res = estimate_depth(views, cal, zmin_m=0.27, zmax_m=1.1)
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


if __name__ == "__main__":
    main()
