"""Throughput of `lfring batch`: frames per second at 1 and 2 local workers and through Dask.

The frames are the bundled samples of the twin (2 x 2 binned, 2456 x 1842 px, 12-bit RGGB PNG),
copied N times into a folder; every frame is loaded, demosaiced, split, refocused at one depth
with the built-in calibration and written as an 8-bit PNG. Peer in the same run: the same work as
a plain sequential loop over the library calls in this process (no pool, no records, no
manifest), which is what the batch machinery has to beat or at least not lose to.

    python benchmarks/bench_batch.py            # 24 frames, refocus at 0.3 m
    python benchmarks/bench_batch.py --frames 48 --depth-map

Each configuration runs into a fresh output folder; the figure is the median of 3 runs of the
whole batch (pool or cluster start-up included, since a user pays it).
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
from _timing import bench

import lfring
from lfring.batch import BatchSettings, run_batch

DATA = Path(__file__).resolve().parents[1] / "data" / "synthetic"
SOURCES = ("scene.png", "part_good.png", "part_defects.png")


def make_folder(root: Path, n: int) -> None:
    root.mkdir(parents=True)
    for i in range(n):
        src = DATA / SOURCES[i % len(SOURCES)]
        shutil.copyfile(src, root / f"f{i:03d}.png")
        shutil.copyfile(str(src) + ".json", root / f"f{i:03d}.png.json")


def plain_loop(root: Path, out: Path, depth_m: float, depth_map: bool) -> None:
    from lfring.calibration.defaults import default_calibration
    from lfring.io.writers import encode_image, write_image

    out.mkdir()
    refocuser = None
    for p in sorted(root.glob("*.png")):
        image = lfring.demosaic(lfring.load_raw(p))
        cal, _ = default_calibration((image.shape[1], image.shape[0]))
        views = lfring.split_views(image, cal.layout)
        if refocuser is None:
            refocuser = lfring.Refocuser(cal, depth_m, interpolation="cubic")
        write_image(out / f"{p.stem}_refocus.png", encode_image(refocuser(views), 8, "srgb"))
        if depth_map:  # the same three files as the batch writes
            from lfring.depth.io import write_depth_preview, write_depth_tiff
            from lfring.io.writers import write_float_tiff

            res = lfring.estimate_depth(views, cal, zmin_m=0.3, zmax_m=0.45)
            write_depth_tiff(out / f"{p.stem}_depth.tiff", res.depth_m)
            write_float_tiff(out / f"{p.stem}_confidence.tiff", res.confidence)
            write_depth_preview(out / f"{p.stem}_depth_preview.png", res.depth_m, confidence=res.confidence, zmin_m=0.3,
                                zmax_m=0.45, min_confidence=0.5)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--depth-map", action="store_true", help="also a depth map of every frame (0.3-0.45 m)")
    args = ap.parse_args()
    settings = BatchSettings(refocus_m=(0.3,), depth=args.depth_map, zmin_m=0.3 if args.depth_map else None,
                             zmax_m=0.45 if args.depth_map else None)
    print(f"machine: {platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, "
          f"numpy {np.__version__}, OpenCV {cv2.__version__}, load {os.getloadavg()[0]:.2f}")
    work = "refocus at 0.3 m" + (" + depth map 0.3-0.45 m (TIFFs and preview)" if args.depth_map else "")
    print(f"{args.frames} frames of 2456 x 1842 px (12-bit RGGB PNG), {work}, 8-bit PNG out; median of {args.runs} runs")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "in"
        make_folder(root, args.frames)
        counter = iter(range(10**6))

        def fresh() -> Path:
            return Path(tmp) / f"out{next(counter)}"

        def batch(**kw):
            rep = run_batch([str(root)], fresh(), settings, **kw)
            assert rep.exit_code == 0 and len(rep.done) == args.frames, rep.summary()

        configs = [
            ("peer: plain loop over the library calls, in-process", lambda: plain_loop(root, fresh(), 0.3, args.depth_map)),
            ("lfring batch, 1 worker (in-process)", lambda: batch(workers=1)),
            ("lfring batch, 2 local worker processes", lambda: batch(workers=2)),
            ("lfring batch, Dask LocalCluster, 2 worker processes", lambda: batch(workers=2, executor="dask")),
        ]
        configs[0][1]()  # warm-up: imports and the built-in calibration's first load
        for name, fn in configs:
            med, lo, hi = bench(fn, args.runs, warmup=False)
            rows.append((name, med, lo, hi))
        # Resume: a rerun over a finished folder only reads records.
        out = fresh()
        run_batch([str(root)], out, settings, workers=2)
        t = time.perf_counter()
        rep = run_batch([str(root)], out, settings, workers=2)
        resume = time.perf_counter() - t
        assert len(rep.skipped) == args.frames
    peer = rows[0][1]
    print("| what | median s | min s | max s | frames/s | x peer time |")
    print("|---|---|---|---|---|---|")
    for name, med, lo, hi in rows:
        print(f"| {name} | {med:.2f} | {lo:.2f} | {hi:.2f} | {args.frames / med:.2f} | {med / peer:.2f} |")
    print(f"rerun over the finished folder (all {args.frames} skipped): {resume:.3f} s")


if __name__ == "__main__":
    main()
