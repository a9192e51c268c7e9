"""Time `lfring split` on a 2 x 2 binned frame of the twin (2456 x 1842 px, 12-bit RGGB).

Side by side in one run: decoding the PNG with OpenCV alone (the floor any loader pays), each
stage of the split, and the whole command in-process. Medians of 7 runs after a warm-up.

    python benchmarks/bench_split.py
"""

from __future__ import annotations

import platform
import tempfile
from pathlib import Path

import cv2
import numpy as np

from _timing import bench as _bench

import lfring
from lfring.cli.main import main
from lfring.cli.synth import write_render
from lfring.optics import load_device
from lfring.synth import render
from lfring.synth.presets import flat_scene, three_depth_scene

RUNS = 7


def bench(fn):
    return _bench(fn, RUNS)


def main_bench() -> None:
    dev = load_device("prototype")
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        write_render(render(dev, three_depth_scene(), binning=2, noise="realistic"), d / "scene.png")
        write_render(render(dev, flat_scene(dev), binning=2, noise="low"), d / "flat.png")
        frame = lfring.load_raw(d / "scene.png")
        image = lfring.demosaic(frame)
        flat = lfring.demosaic(lfring.load_raw(d / "flat.png"), method="bilinear")
        layout = lfring.Layout.load(d / "scene_truth" / "layout.json")
        n = [0]

        def cli_with_layout():
            n[0] += 1
            assert main(["-q", "split", str(d / "scene.png"), "--layout", str(d / "scene_truth" / "layout.json"),
                         "-o", str(d / f"out{n[0]}")]) == 0

        def cli_with_flat():
            n[0] += 1
            assert main(["-q", "split", str(d / "scene.png"), "--flat", str(d / "flat.png"), "-o", str(d / f"out{n[0]}")]) == 0

        rows = [
            ("peer: cv2.imread of the PNG", lambda: cv2.imread(str(d / "scene.png"), cv2.IMREAD_UNCHANGED)),
            ("load_raw", lambda: lfring.load_raw(d / "scene.png")),
            ("demosaic edge-aware", lambda: lfring.demosaic(frame)),
            ("demosaic bilinear", lambda: lfring.demosaic(frame, method="bilinear")),
            ("detect_layout on the flat", lambda: lfring.detect_layout(flat, kind="flat")),
            ("split_views", lambda: lfring.split_views(image, layout)),
            ("lfring split --layout (in-process)", cli_with_layout),
            ("lfring split --flat (in-process)", cli_with_flat),
        ]
        results = [(name, *bench(fn)) for name, fn in rows]
    floor = results[0][1]
    print(f"machine: {platform.processor() or platform.machine()}, {cv2.getNumberOfCPUs()} CPUs, "
          f"Python {platform.python_version()}, numpy {np.__version__}, OpenCV {cv2.__version__}")
    print(f"frame: 2456 x 1842 px 12-bit RGGB PNG; median of {RUNS} runs after a warm-up")
    print("| step | median ms | min ms | max ms | x imread |")
    print("|---|---|---|---|---|")
    for name, med, lo, hi in results:
        print(f"| {name} | {med * 1e3:.0f} | {lo * 1e3:.0f} | {hi * 1e3:.0f} | {med / floor:.1f} |")


if __name__ == "__main__":
    main_bench()
