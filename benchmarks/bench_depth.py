"""Plane-sweep depth against OpenCV's StereoSGBM, side by side on the same frame.

The twin's three-depth scene (2 x 2 binned, realistic noise), depth in view 0's frame, where
the ground truth lives. SGBM runs on views 0 and 1 (horizontal neighbours: rectified by
construction) over the same depth range, and its disparity is turned into depth with the same
calibration model. Errors on textured pixels that all four views see, away from depth edges (and,
as a separate region, the textured pixels all views see within 15 px of a depth edge); pixels
without an estimate count as failures; disparities between views 0 and 1. Times are medians of 9
runs, every method timed first, one after the other; the last column divides by SGBM's median.
The defaults and SGBM are also timed alternately, call by call: the median of those pairs'
ratios is the figure to judge the speed by on a shared machine, whose speed can change between
one method's runs and the next's.

A second table times 4 views of 1060 x 1060 (the paper's sub-aperture size; random texture, the
prototype's optics calibration with views valid everywhere) at exactly 64 planes, medians of 3 runs,
beside StereoSGBM on a 1060 x 1060 pair with 64 disparities in the same run, with the default at
1, 2, 4, 8, 16 threads (those the machine has) for its thread scaling; the default beside SGBM,
and one thread beside all cores, are also timed alternately (medians of the pairs' ratios). It
gives the peak memory of one call at 128 planes (in a fresh process). The four random views do
not correspond, so almost no pixel takes the halves of the 'lcn-halves' cost there: a real scene
costs more (the twin's row).

    python benchmarks/bench_depth.py
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
from _common import ZMAX, ZMIN, machine_line, numba_layer_line, random_views, twin_scene
from _timing import bench, paired

from lfring.depth import estimate_depth
from lfring.depth.metrics import evaluation_mask
from lfring.focus import Refocuser

RUNS = 9


def sgbm_depth(views, cal, zmin, zmax, block=5):
    """StereoSGBM on views 0 (left) and 1 (right), disparity d = x0 - x1 turned into depth by
    inverting the calibration's x translation t(Z) = a + b / (Z - z0) of view 1 into view 0."""
    g = [cv2.cvtColor(np.clip(views[k], 0, 1), cv2.COLOR_RGB2GRAY) for k in (0, 1)]
    g8 = [np.rint(x / max(float(x.max()), 1e-6) * 255).astype(np.uint8) for x in g]
    t = lambda z: cal.model(z)[1, 0, 2] - cal.model(z)[0, 0, 2]
    lo, hi = sorted([t(zmin), t(zmax)])
    min_d = int(np.floor(lo)) - 1
    num = int(np.ceil((hi - min_d + 1) / 16.0)) * 16
    sgbm = cv2.StereoSGBM_create(minDisparity=min_d, numDisparities=num, blockSize=block, P1=8 * block * block,
                                 P2=32 * block * block, uniquenessRatio=5, mode=cv2.STEREO_SGBM_MODE_SGBM)
    d = sgbm.compute(g8[0], g8[1]).astype(np.float32) / 16.0
    d[d < min_d] = np.nan
    z0 = cal.depth_origin_m
    a = cal.model(1e6)[1, 0, 2] - cal.model(1e6)[0, 0, 2]
    b = (t(0.5) - a) * (0.5 - z0)
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = z0 + b / (d - a)
    depth[(depth < zmin * 0.8) | (depth > zmax * 1.5)] = np.nan
    return depth.astype(np.float32), (min_d, num)


def main() -> None:
    t = twin_scene()
    r, cal, views, gt = t.render, t.cal, t.views, t.gt
    # Non-occluded textured pixels: seen by all four views (at mid-range), away from depth edges.
    seen = Refocuser(cal, 0.5, reference=0).weight > 3.9
    usable = evaluation_mask(gt, r.views_sharp[0]) & seen
    near_edges = evaluation_mask(gt, r.views_sharp[0], margin_px=3) & seen & ~usable
    est = lambda **kw: (lambda: estimate_depth(views, cal, zmin_m=ZMIN, zmax_m=ZMAX, reference=0, **kw).depth_m)
    runs = {
        "lfring, defaults (sgm over lcn-halves, 1 px spacing)": est(),
        "lfring, defaults, threads=1": est(threads=1),
        "lfring, method='sgm-reference' (the float32 reference of the default)": est(method="sgm-reference"),
        "lfring, cost='lcn' (all views only: the former default)": est(cost="lcn"),
        "lfring, method='local' (lcn, box 15 px: the former defaults)": est(method="local"),
        "lfring, method='local', aggregation='guided'": est(method="local", aggregation="guided"),
        "lfring, method='local', 0.25 px spacing": est(method="local", num_planes=41),
        "OpenCV StereoSGBM, views 0 and 1": lambda: sgbm_depth(views, cal, ZMIN, ZMAX)[0],
    }
    disp = lambda z: cal.model(np.asarray(z, np.float64))[..., 1, 0, 2] - cal.model(np.asarray(z, np.float64))[..., 0, 0, 2]
    print(machine_line())
    print(f"frame: twin three-depth scene, 2 x 2 binned, realistic noise; views {views.shape[2]} x {views.shape[1]} px; "
          f"depth range {ZMIN}-{ZMAX} m; SGBM disparities {sgbm_depth(views, cal, ZMIN, ZMAX)[1]}")
    print("| method | region | pixels | BadPix 0.3 px | MAE px | MAE mm | median rel. error | time s | time / SGBM |")
    print("|---|---|---|---|---|---|---|---|---|")
    times = {name: bench(fn, RUNS)[0] for name, fn in runs.items()}  # all timed first, in one stretch
    sgbm_s = times["OpenCV StereoSGBM, views 0 and 1"]
    # The target's ratio, with SGBM timed beside each call rather than minutes apart.
    pair = paired(runs["lfring, defaults (sgm over lcn-halves, 1 px spacing)"], runs["OpenCV StereoSGBM, views 0 and 1"], RUNS)
    for name, fn in runs.items():
        med = times[name]
        depth = fn()
        for region, z in (("all usable", None), ("cup 0.3 m", 0.3), ("book 0.5 m", 0.5), ("chessboard 1.0 m", 1.0),
                          ("within 15 px of a depth edge", "edges")):
            if z == "edges":
                m = near_edges & np.isfinite(gt)
            else:
                m = usable & np.isfinite(gt) & (np.ones_like(usable) if z is None else (np.abs(gt - z) < 1e-6))
            est = depth[m]
            ok = np.isfinite(est)
            err = np.where(ok, np.abs(disp(np.where(ok, est, 1.0)) - disp(gt[m])), np.inf)
            mae_px = float(np.mean(err[ok])) if ok.any() else float("nan")
            mae_mm = float(np.mean(np.abs(est[ok] - gt[m][ok]))) * 1e3 if ok.any() else float("nan")
            rel = float(np.median(np.abs(est[ok] - gt[m][ok]) / gt[m][ok])) if ok.any() else float("nan")
            print(f"| {name} | {region} | {m.sum()} | {np.mean(err > 0.3) * 100:.1f} % | {mae_px:.3f} | {mae_mm:.1f} | "
                  f"{rel * 100:.2f} % | {med:.3f} | {med / sgbm_s:.2f} |")
    print(f"\nthe defaults and SGBM timed alternately, {RUNS} pairs: median ratio {pair[0]:.2f} "
          f"(defaults {pair[1]:.3f} s, SGBM {pair[2]:.3f} s)")
    big_views()


def big_views(side: int = 1060, planes: int = 64, runs: int = 3) -> None:
    """4 views of side x side px at exactly ``planes`` hypotheses (reference 'center'), and the
    peak memory at 128 planes."""
    views, cal = random_views(side)
    print(f"\n4 views of {side} x {side} x 3 float32, {planes} planes, depth range {ZMIN}-{ZMAX} m; median of {runs} runs")
    print("| what | median s | min s | max s | / SGBM |")
    print("|---|---|---|---|---|")
    a8 = [np.rint(cv2.cvtColor(views[k], cv2.COLOR_RGB2GRAY) * 255).astype(np.uint8) for k in (0, 1)]
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=planes, blockSize=5, P1=200, P2=800, uniquenessRatio=5,
                                 mode=cv2.STEREO_SGBM_MODE_SGBM)
    sgbm_s = bench(lambda: sgbm.compute(a8[0], a8[1]), runs)[0]
    print(f"| OpenCV StereoSGBM, a {side} x {side} pair, {planes} disparities, block 5 | {sgbm_s:.2f} | | | 1.00 |")
    cores = os.cpu_count() or 1
    rows = [("estimate_depth, defaults (sgm)", {}), ("estimate_depth, method='sgm-reference'", {"method": "sgm-reference"})]
    rows += [(f"estimate_depth, defaults, threads={t}", {"threads": t}) for t in sorted({1, 2, 4, 8, 16, cores}) if t <= cores]
    rows += [("estimate_depth, cost='lcn'", {"cost": "lcn"}), ("estimate_depth, method='local'", {"method": "local"}),
             ("estimate_depth, method='local', cost='zncc', aggregation='guided'",
              {"method": "local", "cost": "zncc", "aggregation": "guided"})]
    times = {}
    for name, kw in rows:
        med, lo, hi = bench(lambda kw=kw: estimate_depth(views, cal, zmin_m=ZMIN, zmax_m=ZMAX, num_planes=planes, **kw), runs)
        times[name] = med
        print(f"| {name} | {med:.2f} | {lo:.2f} | {hi:.2f} | {med / sgbm_s:.2f} |")
    default = lambda threads=None: estimate_depth(views, cal, zmin_m=ZMIN, zmax_m=ZMAX, num_planes=planes, threads=threads)
    pairs = 2 * runs + 1
    pair = paired(default, lambda: sgbm.compute(a8[0], a8[1]), pairs)
    print(f"\nthe default and SGBM timed alternately, {pairs} pairs: median ratio {pair[0]:.2f} "
          f"(default {pair[1]:.2f} s, SGBM {pair[2]:.2f} s)")
    if cores > 1:
        pair = paired(lambda: default(1), lambda: default(cores), pairs)
        print(f"1 thread and {cores} timed alternately, {pairs} pairs: time(1) / time({cores}) median {pair[0]:.2f} "
              f"({pair[1]:.2f} s, {pair[2]:.2f} s)")
    one = times.get("estimate_depth, defaults, threads=1")
    if one:
        print("\nthread scaling of the default, time(1 thread) / time(t threads): " + ", ".join(
            f"{t}: {one / times[f'estimate_depth, defaults, threads={t}']:.2f}"
            for t in sorted({1, 2, 4, 8, 16, cores}) if t <= cores))
    print(numba_layer_line())
    print("\npeak memory of one call at 128 planes (rise of VmHWM over the resident set before it, fresh process):")
    for method in ("sgm", "sgm-reference", "local"):
        out = subprocess.run([sys.executable, __file__, "--memory", str(side), "128", method], capture_output=True, text=True,
                             check=True, env={**os.environ, "MALLOC_MMAP_THRESHOLD_": "65536"})
        print(f"- method={method!r}: {out.stdout.strip()} MiB")


def _status_kib(field: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    raise RuntimeError(field)


def memory(side: int, planes: int, method: str) -> None:
    """Print the rise of the peak resident set of one estimate_depth call (after a warm-up on a
    small frame, so that numba's compiled kernels are loaded)."""
    views, cal = random_views(side)
    small, small_cal = random_views(64)
    estimate_depth(small, small_cal, zmin_m=ZMIN, zmax_m=ZMAX, num_planes=8, method=method)
    before = _status_kib("VmRSS")
    Path("/proc/self/clear_refs").write_text("5")  # resets VmHWM to the current resident set
    estimate_depth(views, cal, zmin_m=ZMIN, zmax_m=ZMAX, num_planes=planes, method=method)
    print(f"{(_status_kib('VmHWM') - before) / 1024.0:.0f}")


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--memory":
        memory(int(sys.argv[2]), int(sys.argv[3]), sys.argv[4])
    else:
        main()
