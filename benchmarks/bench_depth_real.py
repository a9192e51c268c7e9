"""Depth on real stereo pairs (Middlebury 2003 Teddy and Cones) and on the twin's scene: lfring
beside OpenCV StereoSGBM, accuracy, time and peak memory.

Middlebury (../shared/data/middlebury2003, 450 x 375 px, ground truth: the left view's disparity):
lfring gets the pair through ``RingCalibration.from_grid`` (views at grid positions (0, 0) and
(1, 0), d = 100 / Z, so depth is any affine function of 1 / d), searches disparities 1 to 60 px
and returns depth in the left view's frame; SGBM gets the same pair and range. Bad 1 px and bad
2 px over every pixel with ground truth at least 10 px from the border.

Twin (the three-depth scene of bench_depth.py; the hard scene with its per-view vignetting; the
hard scene's surfaces laid out anew, ``_common.mirrored_hard_scene``, for rules tuned on the hard
one; depth in view 0's frame): lfring on all four views and on views 0 and 1; SGBM on views 0 and 1 (a horizontal pair, rectified: the twin's views
differ by translations), its disparity turned into depth by the calibration. BadPix 0.3 px
(disparity between views 0 and 1) and the median relative depth error, on every pixel with
ground truth that at least two views see (inside their disc, not occluded: from the per-view
ground truth), on every pixel that views 0 and 1 both see (the pair's fair share), and on
bench_depth.py's mask (textured pixels all four views see, away from depth
edges).

Every method's invalid pixels (NaN) are filled as the Middlebury SDK does (the farther of the
nearest valid disparities to the left and right on the row: the lower on Middlebury, the higher
on the twin, whose disparity x0 - x1 is negative and rises with depth) before scoring; "invalid"
is the fraction filled. The rows "its own filled map" score lfring's ``depth_filled_m`` instead
(nothing left to fill), what a user who wants no holes gets. Times: median of RUNS calls after a warm-up, every method timed one after the
other; "/ SGBM" divides by SGBM's median on the same data. Peak memory: the rise of the
process's peak resident set (VmHWM, reset through /proc/self/clear_refs after a warm-up call)
over its resident set before the call, on a calibration object of its own (what the warm-up's
calibration keeps between calls is not reused), in a fresh process per method and dataset with glibc's
mmap threshold fixed at 64 KiB (so freed blocks go back to the system), so OpenCV's and every
thread's allocations count.

To add a method, append a ``Method`` to ``METHODS``: a name, the views it gets ('all' or
'pair': views 0 and 1) and a function (views, calibration, data) -> disparity of view 0 in px
(NaN where unknown); ``lfring_method(**options)`` wraps ``estimate_depth`` with options.

    python benchmarks/bench_depth_real.py            # Teddy, Cones and the twin, 5 runs, memory
    python benchmarks/bench_depth_real.py --quick    # Teddy and the twin, 1 run, no memory
    python benchmarks/bench_depth_real.py --data /work/shared/data/middlebury2003   # from a worktree
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Callable

import cv2
import numpy as np
from _common import ZMAX, ZMIN, fill_invalid, machine_line, sgbm_disparity, twin_scene
from _timing import bench

from lfring.calibration import RingCalibration
from lfring.depth import estimate_depth

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "middlebury2003"
SCENES = ("Teddy", "Cones")
DISPARITY_SCALE_PX_M = 100.0  # Middlebury: d = 100 / Z
DISPARITY_RANGE_PX = (1.0, 60.0)  # Middlebury search range (both methods)
BORDER_PX = 10
RUNS = 5


@dataclass(frozen=True)
class Method:
    name: str
    views: str  # 'all' or 'pair' (views 0 and 1)
    run: Callable  # (views, calibration, data) -> (h, w) disparity of view 0 [px], NaN where unknown


def lfring_method(filled: bool = False, **options) -> Callable:
    """estimate_depth (its defaults, plus ``options``) in view 0's frame, as disparity: its raw
    map (NaN where unknown), or with ``filled`` its own hole-filled map (``depth_filled_m``)."""

    def run(views, cal, data):
        res = estimate_depth(views, cal, zmin_m=data.zmin_m, zmax_m=data.zmax_m, reference=0, **options)
        return data.disparity(res.depth_filled_m if filled else res.depth_m)

    return run


def sgbm_method(views, cal, data):
    d, _ = sgbm_disparity(views[0], views[1], *data.disparity_range_px)
    return d


METHODS = [
    Method("lfring estimate_depth, defaults", "all", lfring_method()),
    Method("lfring estimate_depth, defaults", "pair", lfring_method()),
    Method("lfring estimate_depth, method='sgm-reference' (the float32 reference of the default)", "all",
           lfring_method(method="sgm-reference")),
    Method("lfring estimate_depth, method='sgm-reference' (the float32 reference of the default)", "pair",
           lfring_method(method="sgm-reference")),
    Method("lfring estimate_depth, defaults, its own filled map", "all", lfring_method(filled=True)),
    Method("lfring estimate_depth, defaults, its own filled map", "pair", lfring_method(filled=True)),
    Method("lfring estimate_depth, cost='lcn' (all views only)", "all", lfring_method(cost="lcn")),
    Method("lfring estimate_depth, cost='lcn-occlusion'", "all", lfring_method(cost="lcn-occlusion")),
    Method("lfring estimate_depth, method='local'", "all", lfring_method(method="local")),
    Method("lfring estimate_depth, method='local'", "pair", lfring_method(method="local")),
    Method("OpenCV StereoSGBM (block 5)", "pair", sgbm_method),
]
SGBM = METHODS[-1].name


# -- data ------------------------------------------------------------------------------------
def pair_model(cal):
    """(a, b, z0): the x translation of view 1 into view 0, d(Z) = a + b / (Z - z0), which is
    the disparity x0 - x1 of a point at depth Z."""
    m = cal.model
    if m.reference != 0 or not (np.allclose(m.A[:, 2, :2], 0) and np.allclose(m.B[:, 2], 0) and np.allclose(m.B[:, :2, :2], 0)):
        raise ValueError("the benchmark needs a translation-only model into view 0")
    return m.A[1, 0, 2] - m.A[0, 0, 2], m.B[1, 0, 2] - m.B[0, 0, 2], m.depth_origin_m


def make_data(name, views, cal, *, zmin_m=None, zmax_m=None, disparity_range_px=None):
    a, b, z0 = pair_model(cal)
    disparity = lambda z: (a + b / (np.asarray(z, np.float64) - z0)).astype(np.float32)
    if disparity_range_px is None:
        disparity_range_px = tuple(sorted(float(disparity(z)) for z in (zmin_m, zmax_m)))
    else:
        zs = sorted(z0 + b / (d - a) for d in disparity_range_px)
        zmin_m, zmax_m = zs
    # The far side of a hole is the lower disparity where it falls with depth (b > 0: Middlebury's
    # x_left - x_right), the higher where it rises (the twin's x0 - x1).
    return SimpleNamespace(name=name, views=views, cal=cal, zmin_m=float(zmin_m), zmax_m=float(zmax_m),
                           disparity_range_px=disparity_range_px, disparity=disparity, far_is_lower=bool(b > 0),
                           regions={})


def middlebury(scene: str, root: Path = DATA):
    d = root / scene
    if not (d / "imL.png").is_file():
        raise SystemExit(f"{d}: no Middlebury 2003 {scene} here; give --data DIR (the folder with Teddy/ and Cones/)")
    left, right = (cv2.imread(str(d / f), cv2.IMREAD_COLOR)[..., ::-1].astype(np.float32) / 255.0 for f in ("imL.png", "imR.png"))
    views = np.ascontiguousarray(np.stack([left, right]))
    cal = RingCalibration.from_grid(left.shape[:2], [(0, 0), (1, 0)], disparity_scale_px_m=DISPARITY_SCALE_PX_M)
    data = make_data(f"Middlebury 2003 {scene}", views, cal, disparity_range_px=DISPARITY_RANGE_PX)
    gt = cv2.imread(str(d / "disp2.png"), cv2.IMREAD_GRAYSCALE).astype(np.float32) / 4.0
    known = gt > 0
    known[:BORDER_PX], known[-BORDER_PX:], known[:, :BORDER_PX], known[:, -BORDER_PX:] = False, False, False, False
    data.gt_disparity = np.where(gt > 0, gt, np.nan)
    data.gt_depth = None
    data.regions = {f"ground truth, {BORDER_PX} px from the border": known}
    return data


def seen_by(cal, gt, depth_views, masks) -> np.ndarray:
    """(V, h, w) bool: whether each view sees each pixel of view 0 at its true depth (inside its
    disc and not hidden: its own ground-truth depth there within 1 %); translation-only models."""
    m = cal.model
    h, w = gt.shape
    ys, xs = np.mgrid[0:h, 0:w]
    ok = np.isfinite(gt)
    inv = np.where(ok, 1.0 / (np.where(ok, gt, 1.0) - m.depth_origin_m), 0.0)
    seen = np.zeros((m.num_views, h, w), bool)
    for k in range(m.num_views):
        xk = np.rint(xs - (m.A[k, 0, 2] + m.B[k, 0, 2] * inv)).astype(np.int64)  # H_0_from_k: x0 = xk + t
        yk = np.rint(ys - (m.A[k, 1, 2] + m.B[k, 1, 2] * inv)).astype(np.int64)
        inside = ok & (xk >= 0) & (xk < w) & (yk >= 0) & (yk < h)
        xc, yc = np.clip(xk, 0, w - 1), np.clip(yk, 0, h - 1)
        dk = depth_views[k][yc, xc]
        seen[k] = inside & masks[k][yc, xc] & (np.abs(dk - gt) < 0.01 * np.where(ok, gt, 1.0))
    return seen


def twin(scene: str = "three_depth"):
    from lfring.depth.metrics import evaluation_mask
    from lfring.focus import Refocuser

    t = twin_scene(scene=scene)
    data = make_data(f"twin {scene.replace('_', '-')} scene", t.views, t.cal, zmin_m=ZMIN, zmax_m=ZMAX)
    r = t.render
    data.gt_depth = t.gt
    data.gt_disparity = np.where(np.isfinite(t.gt), data.disparity(np.where(np.isfinite(t.gt), t.gt, 1.0)), np.nan)
    seen = seen_by(t.cal, t.gt, r.depth_m, r.layout.masks())
    textured = evaluation_mask(t.gt, r.views_sharp[0]) & (Refocuser(t.cal, 0.5, reference=0).weight > 3.9)
    data.regions = {"every pixel seen by >= 2 views": np.isfinite(t.gt) & (seen.sum(axis=0) >= 2),
                    "every pixel seen by views 0 and 1": np.isfinite(t.gt) & seen[0] & seen[1],
                    "textured, all 4 views, off edges (bench_depth)": textured & np.isfinite(t.gt)}
    return data


def method_inputs(method, data):
    if method.views == "pair" or data.views.shape[0] == 2:
        return data.views[:2], data.cal.select_views([0, 1]) if data.cal.num_views > 2 else data.cal
    return data.views, data.cal


def applicable(method, data) -> bool:
    """On a stereo pair a 'pair' row would repeat the 'all' row of the same name."""
    return not (method.views == "pair" and data.views.shape[0] == 2
                and any(m.views == "all" and m.name == method.name for m in METHODS))


# -- scoring ---------------------------------------------------------------------------------
def score(est, data, region):
    m = data.regions[region]
    invalid = ~np.isfinite(est[m])
    filled = fill_invalid(est, far_is_lower=data.far_is_lower)[m]
    err = np.abs(filled - data.gt_disparity[m])
    err = np.where(np.isfinite(err), err, np.inf)
    row = {"pixels": int(m.sum()), "invalid": float(invalid.mean()), "bad0.3": float(np.mean(err > 0.3)),
           "bad1": float(np.mean(err > 1.0)), "bad2": float(np.mean(err > 2.0)), "rel": float("nan")}
    if data.gt_depth is not None:
        a, b, z0 = pair_model(data.cal)
        with np.errstate(divide="ignore", invalid="ignore"):
            z = z0 + b / (filled - a)
        gt = data.gt_depth[m]
        rel = np.abs(z - gt) / gt
        row["rel"] = float(np.median(np.where(np.isfinite(rel), rel, np.inf)))
    return row


# -- peak memory in a fresh process ------------------------------------------------------------
# glibc otherwise keeps freed blocks (and raises its mmap threshold after frees), so a call after
# the warm-up would reuse the warm-up's memory without the resident set rising: blocks of 64 KiB
# and more are mapped for each allocation and unmapped when freed.
MALLOC_ENV = {"MALLOC_MMAP_THRESHOLD_": "65536", "MALLOC_TRIM_THRESHOLD_": "131072"}

def _status_kib(key: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    raise KeyError(key)


def child(folder: str, method_index: int) -> None:
    meta = json.loads((Path(folder) / "meta.json").read_text())
    views = np.load(Path(folder) / "views.npy")
    method = METHODS[method_index]

    def inputs():
        cal = RingCalibration.load(Path(folder) / "calibration.json")
        data = make_data(meta["name"], views, cal, zmin_m=meta["zmin_m"], zmax_m=meta["zmax_m"])
        data.disparity_range_px = tuple(meta["disparity_range_px"])
        return (*method_inputs(method, data), data)

    method.run(*inputs())  # warm-up: thread pools, lazy imports, compiled kernels
    # A fresh calibration object for the measured call: what the warm-up's calibration keeps
    # between calls (masks, the fused engine's volumes) is resident but not reused, so the
    # rise is what one call on a new calibration needs.
    v, c, data = inputs()
    Path("/proc/self/clear_refs").write_text("5")  # resets VmHWM to the current resident set
    before = _status_kib("VmRSS")
    method.run(v, c, data)
    print(json.dumps({"peak_rise_mib": (_status_kib("VmHWM") - before) / 1024.0}))


def peak_memory_mib(data, index: int, folder: Path) -> float:
    (folder / "meta.json").write_text(json.dumps({"name": data.name, "zmin_m": data.zmin_m, "zmax_m": data.zmax_m,
                                                  "disparity_range_px": list(data.disparity_range_px)}))
    out = subprocess.run([sys.executable, __file__, "--child", str(folder), str(index)], capture_output=True, text=True,
                         check=True, env={**os.environ, **MALLOC_ENV})
    return json.loads(out.stdout.strip().splitlines()[-1])["peak_rise_mib"]


# -- main --------------------------------------------------------------------------------------
def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="Teddy and the twin, one timed run, no memory")
    parser.add_argument("--data", type=Path, default=DATA, help=f"Middlebury 2003 folder (default {DATA})")
    parser.add_argument("--child", nargs=2, metavar=("FOLDER", "METHOD"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child[0], int(args.child[1]))
        return
    runs = 1 if args.quick else RUNS
    print(machine_line())
    print(f"times: median of {runs} run(s) after a warm-up; memory: rise of the peak resident set (VmHWM) over the "
          "resident set before one call, in a fresh process after a warm-up call")
    datasets = [middlebury(s, args.data) for s in (SCENES[:1] if args.quick else SCENES)] + [twin(), twin("hard"),
                                                                                              twin("hard_mirrored")]
    print("| data | method | views | region | pixels | invalid | bad 0.3 px | bad 1 px | bad 2 px | median rel. depth error "
          "| time s | / SGBM | peak memory MiB |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for data in datasets:
        methods = [(i, m) for i, m in enumerate(METHODS) if applicable(m, data)]
        times, results = {}, {}
        for i, m in methods:
            v, c = method_inputs(m, data)
            times[i] = bench(lambda m=m, v=v, c=c: m.run(v, c, data), runs)[0]
            results[i] = m.run(v, c, data)
        mem = {}
        if not args.quick:
            with tempfile.TemporaryDirectory() as tmp:
                folder = Path(tmp)
                np.save(folder / "views.npy", data.views)
                data.cal.save(folder / "calibration.json")
                mem = {i: peak_memory_mib(data, i, folder) for i, _ in methods}
        sgbm_s = next(times[i] for i, m in methods if m.name == SGBM)
        for i, m in methods:
            nviews = method_inputs(m, data)[0].shape[0]
            for region in data.regions:
                s = score(results[i], data, region)
                rel = "-" if np.isnan(s["rel"]) else f"{s['rel'] * 100:.2f} %"
                mib = f"{mem[i]:.0f}" if i in mem else "-"
                print(f"| {data.name} | {m.name} | {nviews} | {region} | {s['pixels']} | {s['invalid'] * 100:.1f} % | "
                      f"{s['bad0.3'] * 100:.1f} % | {s['bad1'] * 100:.1f} % | {s['bad2'] * 100:.1f} % | {rel} | "
                      f"{times[i]:.3f} | {times[i] / sgbm_s:.2f} | {mib} |", flush=True)


if __name__ == "__main__":
    main()
