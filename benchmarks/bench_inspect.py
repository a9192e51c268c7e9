"""Defect detection at a working plane on rendered parts (``lfring.inspect.inspect_frame``).

The twin's ``part`` preset (2 x 2 binned, realistic noise, the shipped calibration calib/twin_binned2.json) at
0.3 m: good parts, and parts with two or three planted domes (bumps towards the camera, dents
away) of seeded random heights and sizes, every one at least 0.5 px of disparity between
neighbouring views high and at least 40 x 40 px wide. Ground truth: the rendered per-view depth
warped into the reference (central) frame; a planted defect is its connected region deviating
from the plane by more than half the tolerance, its deviation the extreme there. A detection
matches a planted defect when their boxes overlap and the signs agree.

Coverage of the good parts: the share of the part that ``inspect_frame`` found (its ``coverage``:
pixels near the plane, see its Notes) and of the true plate (ground truth within 5 cm of the
plane) that was checked with confident depth, and the share of the true plate that only one view
sees (no depth can be measured there: the limit of the second figure).

    python benchmarks/bench_inspect.py            # 24 parts (12 good, 12 with defects)
    python benchmarks/bench_inspect.py --parts 6  # quicker
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import cv2
import numpy as np

from lfring.calibration.defaults import default_calibration
from lfring.depth.metrics import depth_to_disparity_px
from lfring.inspect import inspect_frame
from lfring.io.demosaic import demosaic
from lfring.io.raw import RawFrame
from lfring.optics import load_device
from lfring.core.viewstack import view_masks
from lfring.core.warping import warp_views
from lfring.synth import render
from lfring.synth.presets import part_scene
from lfring.views import split_views

PLANE, TOL = 0.3, 0.008


def truth_deviation(r, cal, plane_m, reference="center"):
    """Plane minus true depth (m, + towards the camera) in the reference frame, NaN off-surface:
    every view's ground truth carried by its plane homography, averaged where seen."""
    h, w = cal.layout.view_shape
    acc, cnt = np.zeros((h, w)), np.zeros((h, w))
    hs = cal.homographies(plane_m, reference=reference)
    for k in range(cal.num_views):
        t = np.eye(3)
        t[0, 2] = r.layout.rects[k][0] - cal.layout.rects[k][0]
        t[1, 2] = r.layout.rects[k][1] - cal.layout.rects[k][1]
        z = r.depth_m[k].astype(np.float32)
        dev = np.where(np.isfinite(z), plane_m - z, 0).astype(np.float32)
        ok = np.isfinite(z).astype(np.float32)
        wd = cv2.warpPerspective(dev, hs[k] @ t, (w, h), flags=cv2.INTER_NEAREST)
        wo = cv2.warpPerspective(ok, hs[k] @ t, (w, h), flags=cv2.INTER_NEAREST)
        acc += wd * wo
        cnt += wo
    with np.errstate(invalid="ignore"):
        return np.where(cnt > 0, acc / np.maximum(cnt, 1), np.nan)


def views_seeing(cal, plane_m, reference="center"):
    """Number of views whose usable area (the calibration's view masks) sees each reference
    pixel at the plane."""
    h, w = cal.layout.view_shape
    masks = view_masks(cal, (h, w))
    _, weights = warp_views(np.ones((cal.num_views, h, w, 1), np.float32), cal.homographies(plane_m, reference=reference),
                            masks=masks)
    return (weights > 0.5).sum(axis=0)


def truth_defects(dev_m, tol_m, max_m=0.05):
    """Planted defects: regions with tol/2 < |deviation| < max_m (the belt behind is farther)."""
    out = []
    for sign in (1, -1):
        m = (np.nan_to_num(sign * dev_m) > tol_m / 2) & (np.abs(np.nan_to_num(dev_m)) < max_m)
        n, lab, st, _ = cv2.connectedComponentsWithStats(m.astype(np.uint8))
        for j in range(1, n):
            if st[j, 4] >= 50:
                out.append({"bbox": tuple(int(v) for v in st[j, :4]), "deviation_m": float(sign * np.max(sign * dev_m[lab == j]))})
    return out


def overlap(a, b) -> bool:
    return a[0] < b[0] + b[2] and b[0] < a[0] + a[2] and a[1] < b[1] + b[3] and b[1] < a[1] + a[3]


def make_part(dev, seed, defects: bool):
    rng = np.random.default_rng(1000 + seed)
    heights = ()
    size = 0.012
    if defects:
        n = int(rng.integers(2, 4))
        heights = tuple(float(s * rng.uniform(0.0125, 0.018)) for s in rng.choice([-1, 1], n))
        size = float(rng.uniform(0.0115, 0.015))
    r = render(dev, part_scene(defect_heights_m=heights, defect_size_m=size, depth_m=PLANE, seed=seed), binning=2,
               noise="realistic", seed=seed)
    frame = RawFrame(mosaic=r.raw, pattern="RGGB", black_level=r.black_level, white_level=r.white_level, bit_depth=12)
    cal = default_calibration((r.raw.shape[1], r.raw.shape[0]))[0]  # measured, as shipped: what the CLI uses
    return r, cal, split_views(demosaic(frame), cal.layout)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--parts", type=int, default=24)
    args = ap.parse_args()
    dev = load_device("prototype")
    print(f"machine: {platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, OpenCV {cv2.__version__}")
    rows, times, errs, cover = [], [], [], []
    det = miss = false = planted = 0
    min_disp, min_side = np.inf, np.inf
    for i in range(args.parts):
        defects = i % 2 == 1
        r, cal, views = make_part(dev, 100 + i, defects)
        t = time.perf_counter()
        res = inspect_frame(views, cal, plane_m=PLANE, tolerance_m=TOL, device=r.device)
        times.append(time.perf_counter() - t)
        tdev, nviews = truth_deviation(r, cal, PLANE), views_seeing(cal, PLANE)
        truth = truth_defects(tdev, TOL)
        plate = np.isfinite(tdev) & (np.abs(tdev) < 0.05)
        plate_checked = float((res.reliable & plate).sum() / plate.sum())
        if not defects:
            cover.append((res.coverage, plate_checked, float((plate & (nviews < 2)).sum() / plate.sum())))
        for b in r.scene.surfaces[0].bumps:
            d = float(np.ptp(depth_to_disparity_px(np.array([PLANE, PLANE - b.height_m]), cal, signed=True)))
            min_disp = min(min_disp, d)
        for tr in truth:
            min_side = min(min_side, min(tr["bbox"][2:]))
        used = set()
        for tr in truth:
            planted += 1
            hit = [j for j, d in enumerate(res.defects) if overlap(d.bbox_px, tr["bbox"]) and np.sign(d.deviation_m) == np.sign(tr["deviation_m"])]
            if hit:
                det += 1
                used.update(hit)
                errs.append(res.defects[hit[0]].deviation_m - tr["deviation_m"])
            else:
                miss += 1
        false += len(res.defects) - len(used)
        planted_mm = ", ".join(f"{tr['deviation_m'] * 1e3:+.1f}" for tr in truth) or "-"
        found_mm = ", ".join(f"{d.deviation_m * 1e3:+.1f}" for d in res.defects) or "-"
        rows.append(f"| {i} | {'defects' if defects else 'good'} | {planted_mm} | {found_mm} | {res.verdict} | "
                    f"{res.coverage:.1%} | {plate_checked:.1%} | {times[-1]:.2f} |")
    print(f"{args.parts} parts at {PLANE} m, tolerance {TOL * 1e3:g} mm; planted defects down to {min_disp:.2f} px of "
          f"disparity (views 0-1) and footprints (> tol/2) at least {min_side} px wide")
    print("| part | kind | planted max deviation mm | found mm | verdict | coverage (part found) | true plate checked | time s |")
    print("|---|---|---|---|---|---|---|---|")
    print("\n".join(rows))
    e = np.abs(np.array(errs)) * 1e3
    print(f"\nplanted {planted}: detected {det}, missed {miss}; false defects {false}; "
          f"deviation error |found - truth| median {np.median(e):.2f} mm, max {e.max():.2f} mm; "
          f"inspect_frame median {np.median(times):.2f} s per frame (min {min(times):.2f}, max {max(times):.2f})")
    if cover:
        c = np.array(cover)
        print(f"good parts ({len(c)}): coverage of the part found min {c[:, 0].min():.1%}, median {np.median(c[:, 0]):.1%}; "
              f"true plate checked min {c[:, 1].min():.1%}, median {np.median(c[:, 1]):.1%}; "
              f"true plate seen by one view only (unmeasurable) median {np.median(c[:, 2]):.1%}; "
              f"verdicts: {sum(1 for row in rows if '| good |' in row and '| pass |' in row)} pass")


if __name__ == "__main__":
    main()
