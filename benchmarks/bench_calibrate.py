"""Calibration of the 2 x 2 binned twin: time per pair of targets and accuracy at held-out
planes, and what assuming z0 = 0 costs (in pixels and in millimetres of depth).

Targets at 0.3 and 1.0 m (and 0.5 m for the three-plane fit), held-out planes at 0.5 and
2.0 m; errors are the RMS over the view of the distance between points mapped by the fitted
and the exact homographies (worst view). Peer in the same run: the same pair calibrated with
SIFT + RANSAC instead of ECC.

Real mini-lenses (``--lenses`` runs only this part): the twin through the four distorting
lenses of calib/prototype_lenses.toml (up to 3 % of the disc radius at the rim, each lens its
own), calibrated from the same two planes with and without the distortion model, against the
twin of ideal lenses in the same run: the held-out planes' view-to-reference maps against the
truth's, the depth of a held-out flat target (lfring.estimate_depth, its default method), and a
refocused flat field's uniformity with and without the calibration's flat field.

    python benchmarks/bench_calibrate.py
    python benchmarks/bench_calibrate.py --lenses
"""

from __future__ import annotations

import platform
import statistics
import sys
import time
import warnings
from pathlib import Path

import cv2
import numpy as np
from scipy.optimize import minimize_scalar

from lfring.calibration import calibrate
from lfring.core.geometry import homography_rms_px
from lfring.io.raw import RawFrame
from lfring.optics import load_device
from lfring.optics.views import optical_homographies
from lfring.synth import render
from lfring.synth.presets import flat_scene, target_scene

RUNS = 5
ROOT = Path(__file__).resolve().parents[1]


def frame(r):
    return RawFrame(mosaic=r.raw, pattern=r.settings.pattern, black_level=r.black_level, white_level=r.white_level, bit_depth=12)


def main() -> None:
    proto = load_device("prototype")
    print(f"machine: {platform.machine()}, {cv2.getNumberOfCPUs()} CPUs, Python {platform.python_version()}, "
          f"numpy {np.__version__}, OpenCV {cv2.__version__}")
    flat_r = render(proto, flat_scene(proto), binning=2, noise="low")
    dev, layout, flat = flat_r.device, flat_r.layout, frame(flat_r)
    s = dev.entrance_pupil_m
    rows = []
    for noise in ("none", "realistic"):
        t = {z: frame(render(proto, target_scene(proto, z, seed=int(10 * z)), binning=2, noise=noise, seed=3)) for z in (0.3, 0.5, 1.0)}
        pair = {0.3: t[0.3], 1.0: t[1.0]}
        for label, kw in (("ECC, z0 = s (device)", dict(device=dev)), ("ECC, z0 = 0", dict(depth_origin_m=0.0)),
                          ("SIFT, z0 = s (device)", dict(device=dev, method="sift"))):
            times = []
            for _ in range(RUNS if noise == "realistic" else 1):
                t0 = time.perf_counter()
                cal = calibrate(pair, flat=flat, **kw)  # layout detected on the flat, as a user would
                times.append(time.perf_counter() - t0)
            # Compare against the truth in the detected layout's own view coordinates.
            errs = [float(homography_rms_px(cal.model(z), optical_homographies(dev, cal.layout, z, reference=0), cal.layout.view_shape).max())
                    for z in (0.5, 2.0)]
            rows.append((noise, label, statistics.median(times), *errs))
        three = calibrate(t, flat=flat)
        rows.append((noise, "ECC, 3 planes, z0 fitted", float("nan"), *[
            float(homography_rms_px(three.model(z), optical_homographies(dev, three.layout, z, reference=0), three.layout.view_shape).max())
            for z in (0.5, 2.0)]))
        print(f"noise={noise}: 3-plane z0 = {three.depth_origin_m * 1e3:.3f} mm, optics s = {s * 1e3:.3f} mm, "
              f"error {abs(three.depth_origin_m - s) * 1e3:.3f} mm")
    print(f"\nmedian of {RUNS} runs (realistic noise), layout detected on the flat each time")
    print("| noise | method | time per pair s | held-out 0.5 m px | held-out 2.0 m px |")
    print("|---|---|---|---|---|")
    for noise, label, tm, e05, e2 in rows:
        print(f"| {noise} | {label} | {'' if np.isnan(tm) else f'{tm:.2f}'} | {e05:.4f} | {e2:.4f} |")

    # What z0 = 0 costs in depth: the depth whose true homographies best match the naive model.
    lay = layout
    meas = {z: optical_homographies(dev, lay, z, reference=0) for z in (0.3, 1.0)}
    from lfring.calibration import fit_variable_homography

    naive, _ = fit_variable_homography(meas, shape_hw=lay.view_shape, depth_origin_m=0.0)
    print("\nexact homographies at 0.3 and 1.0 m, model with z0 = 0 instead of s:")
    print("| depth m | error px | equivalent depth error mm |")
    print("|---|---|---|")
    for z in (0.4, 0.5, 0.7, 2.0):
        hz = naive(z)
        err = float(homography_rms_px(hz, optical_homographies(dev, lay, z, reference=0), lay.view_shape).max())
        best = minimize_scalar(lambda zz: float(np.mean(homography_rms_px(hz, optical_homographies(dev, lay, zz, reference=0), lay.view_shape, step=16) ** 2)),
                               bounds=(z * 0.8, z * 1.25), method="bounded", options={"xatol": 1e-7})
        print(f"| {z} | {err:.3f} | {(best.x - z) * 1e3:+.1f} |")


def _mapping_error_px(cal, truth, depth_m, view, *, reference=0, whole_disc=False):
    """RMS over ``view``'s disc (the part that lands in the reference's disc, or all of it) of
    the distance between where the calibration and the truth send its recorded pixels."""
    from lfring.core.geometry import apply_homography

    lay, tl = cal.layout, truth.layout
    off_k = np.subtract(lay.rects[view][:2], tl.rects[view][:2])
    off_r = np.subtract(lay.rects[reference][:2], tl.rects[reference][:2])
    masks = tl.masks()
    ys, xs = np.nonzero(masks[view][::2, ::2])
    pts = np.stack([xs * 2.0, ys * 2.0], axis=-1)
    want = truth.to_reference(depth_m, view, pts, reference=reference)
    dist = cal.distortion
    u = pts - off_k if dist is None else dist[view].undistort(pts - off_k)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        got = apply_homography(cal.homographies(depth_m, reference=reference)[view], u)
    got = (got if dist is None else dist[reference].distort(got)) + off_r
    ix, iy = np.round(want).astype(int).T
    seen = (ix >= 0) & (iy >= 0) & (ix < masks.shape[2]) & (iy < masks.shape[1])
    seen[seen] = masks[reference][iy[seen], ix[seen]]
    if whole_disc:
        seen[:] = True
    err = np.hypot(*(got - want)[seen].T)
    return float(np.sqrt(np.mean(err**2)))


def _depth_errors(cal, frames, depth_m):
    """Relative depth error (%) of flat targets at ``depth_m``, over the pixels
    lfring.estimate_depth (its default method) gives a depth: median, 95th percentile and the
    share of pixels more than 2 % off, each the mean over the frames."""
    import lfring
    from lfring.io.demosaic import demosaic
    from lfring.views import split_views

    out = []
    for r in frames:
        views = split_views(demosaic(frame(r)), cal)
        d = lfring.estimate_depth(views, cal, zmin_m=0.3, zmax_m=1.0).depth_m
        e = np.abs(d[np.isfinite(d)] - depth_m) / depth_m * 100
        out.append((np.median(e), np.percentile(e, 95), np.mean(e > 2) * 100))
    return tuple(float(v) for v in np.mean(out, axis=0))


def _flat_uniformity(cal, r, *, box_px: int = 1):
    """Largest |value / median - 1| (%) of a refocused white plane (each pixel, or the mean of
    ``box_px`` x ``box_px`` boxes), where every view contributes (its weight in the reference
    frame is above 0)."""
    import lfring
    from lfring.core.viewstack import view_masks
    from lfring.io.demosaic import demosaic
    from lfring.views import split_views

    views = split_views(demosaic(frame(r)), cal)
    out = lfring.refocus(views, cal, 0.5).mean(axis=2)
    h, w = cal.layout.view_shape
    masks = view_masks(cal, (h, w))
    hs = cal.homographies(0.5, reference="center")
    weight = np.stack([cv2.warpPerspective(masks[k], hs[k], (w, h), flags=cv2.INTER_LINEAR) for k in range(len(hs))])
    sel = (weight > 0).all(axis=0)
    if box_px > 1:
        # Box means over pixels all inside the region (noise averaged, the brightness kept).
        k = (box_px, box_px)
        inside = cv2.blur(sel.astype(np.float32), k) > 0.999
        out, sel = cv2.blur(np.where(sel, out, 0).astype(np.float32), k), inside
    v = out[sel]
    return float(np.max(np.abs(v / np.median(v) - 1)) * 100)


def lenses() -> None:
    """The twin through real mini-lenses against the twin of ideal lenses, side by side."""
    from lfring.synth import Plane, Scene, Texture

    proto = load_device("prototype")
    real = load_device(ROOT / "calib" / "prototype_lenses.toml")
    print(f"\nreal mini-lenses: {real.name} (calib/prototype_lenses.toml), 2 x 2 binned")
    white = Scene((Plane(0.5, (1.0, 1.0), Texture("constant", colors=((1.0, 1.0, 1.0),)), name="white"),))
    rows, depth_rows, flat_rows = [], [], []
    for label, dev in (("ideal lenses", proto), ("real lenses", real)):
        flat = frame(render(dev, flat_scene(dev), binning=2, noise="none"))
        held_out = [render(dev, target_scene(dev, 0.5, seed=s), binning=2, noise="low", seed=s) for s in (21, 22, 23)]
        for noise in ("low", "realistic"):
            t = {z: render(dev, target_scene(dev, z, seed=int(10 * z)), binning=2, noise=noise, seed=3) for z in (0.3, 0.5, 1.0)}
            pair = {0.3: frame(t[0.3]), 1.0: frame(t[1.0])}
            for model in (True, False):
                t0 = time.perf_counter()
                cal = calibrate(pair, flat=flat, device=dev, distortion=model)
                dt = time.perf_counter() - t0
                errs = [max(_mapping_error_px(cal, t[0.5], z, k, whole_disc=whole) for k in (1, 2, 3))
                        for z in (0.5, 2.0) for whole in (False, True)]
                info = cal.provenance["distortion"]
                kept = "modelled" if cal.distortion is not None else ("negligible" if model else "not estimated")
                rows.append((label, noise, "on" if model else "off", kept, dt, *errs))
                print(f"  {label}, {noise} noise, distortion model {'on' if model else 'off'}: {dt:.1f} s, tiles "
                      f"{info.get('tiles_rms_before_px', float('nan')):.3f} -> {info.get('tiles_rms_after_px', float('nan')):.3f} px",
                      flush=True)
                if noise != "low":
                    continue
                depth_rows.append((label, "on" if model else "off", "none", *_depth_errors(cal, held_out, 0.5)))
                if model:
                    fielded = calibrate(pair, flat=flat, device=dev, carry_flat=True)
                    depth_rows.append((label, "on", "carried", *_depth_errors(fielded, held_out, 0.5)))
                    w = render(dev, white, binning=2, noise="realistic", seed=11, exposure=0.6)
                    w0 = render(dev, white, binning=2, noise="none", exposure=0.6)
                    for flat_label, c in (("carried", fielded), ("none", cal)):
                        flat_rows.append((label, flat_label, _flat_uniformity(c, w0), _flat_uniformity(c, w, box_px=9),
                                          _flat_uniformity(c, w)))
    print("\nheld-out planes: the view-to-reference (view 0) map against the truth's, RMS px, worst view; 'overlap': the "
          "part of the view that lands in the reference's disc, 'disc': all of it")
    print("| lenses | target noise | distortion model | result | time s | 0.5 m overlap | 0.5 m disc | 2.0 m overlap | 2.0 m disc |")
    print("|---|---|---|---|---|---|---|---|---|")
    for label, noise, model, kept, dt, e05, e05d, e2, e2d in rows:
        print(f"| {label} | {noise} | {model} | {kept} | {dt:.1f} | {e05:.4f} | {e05d:.4f} | {e2:.4f} | {e2d:.4f} |")
    print("\ndepth of held-out flat targets at 0.5 m (lfring.estimate_depth, default method; 'low' noise; the mean over "
          "3 targets of each figure)")
    print("| lenses | distortion model | flat field | median error % | p95 error % | pixels > 2 % off |")
    print("|---|---|---|---|---|---|")
    for label, model, fl, med, p95, off in depth_rows:
        print(f"| {label} | {model} | {fl} | {med:.2f} | {p95:.2f} | {off:.1f} |")
    print("\na white plane at 0.5 m refocused at 0.5 m (shift-and-add), where every view contributes: largest "
          "|value / median - 1| in %")
    print("| lenses | flat field | no noise | realistic noise, 9 x 9 px means | realistic noise, each pixel |")
    print("|---|---|---|---|---|")
    for label, fl, a, b, c in flat_rows:
        print(f"| {label} | {fl} | {a:.2f} | {b:.2f} | {c:.2f} |")


if __name__ == "__main__":
    if "--lenses" not in sys.argv[1:]:
        main()
    lenses()
