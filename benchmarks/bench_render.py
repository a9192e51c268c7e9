"""Time the synthetic twin rendering the paper's three-depth scene (SPEC 3) with realistic noise.

Side by side in one run: two floors that any renderer of a full frame pays (drawing the
frame's read-noise numbers, and one `cv2.warpPerspective` of a full 4912 x 3684 RGB float32
frame), then `render` at full resolution and at binning 2, the same render with the views one
at a time (the speed-up of the threads), and a per-stage breakdown of the full-resolution
render. Medians of 5 runs after a warm-up; prints only, writes nothing.

    python benchmarks/bench_render.py
"""

from __future__ import annotations

import os
import platform
import statistics

import cv2
import numpy as np

from _timing import bench as _bench
from lfring.optics import load_device
from lfring.synth import RenderSettings, render
from lfring.synth.presets import three_depth_scene

from lfring.synth import renderer as _render_module
from lfring.synth.layers import default_workers

RUNS = 5
SETTINGS = dict(noise="realistic", pattern="RGGB", bit_depth=12)


def bench(fn):
    return _bench(fn, RUNS)


def cpu_name() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def stage_breakdown(dev, scene):
    """Median seconds per stage of the full-resolution render (the renderer's own clocks)."""
    runs = []
    for _ in range(RUNS):
        t = {}
        _render_module._render(dev, scene, RenderSettings(binning=1, **SETTINGS), timings=t)
        runs.append(t)
    return {key: statistics.median(r[key] for r in runs) for key in runs[0]}


def main_bench() -> None:
    dev = load_device("prototype")
    scene = three_depth_scene()
    H, W = dev.sensor_height_px, dev.sensor_width_px
    frame = np.random.default_rng(0).random((H, W, 3), dtype=np.float32)
    # A view-to-reference warp of the kind the pipeline applies: small rotation, scale, shift.
    h_ref_from_view = np.array([[1.001, 0.002, 3.5], [-0.002, 1.001, -2.25], [1e-7, -1e-7, 1.0]])
    dev1_settings = RenderSettings(binning=1, **SETTINGS)
    load_before = os.getloadavg()[0]

    rows = [
        ("peer: standard_normal of a full frame (3684 x 4912 float32)",
         lambda: np.random.default_rng().standard_normal((H, W), dtype=np.float32)),
        ("peer: cv2.warpPerspective of a full frame (4912 x 3684 x 3 float32)",
         lambda: cv2.warpPerspective(frame, h_ref_from_view, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)),
        ("render, full resolution (4912 x 3684)", lambda: render(dev, scene, binning=1, **SETTINGS)),
        ("render, binning 2 (2456 x 1842)", lambda: render(dev, scene, binning=2, **SETTINGS)),
    ]
    # The renderer before its threads (git history) has neither; the script still times it.
    threaded = hasattr(_render_module, "_render")
    if threaded:
        rows.append(("render, full resolution, views one at a time (workers=1)",
                     lambda: _render_module._render(dev, scene, dev1_settings, workers=1)))
    results = [(name, *bench(fn)) for name, fn in rows]
    stages = stage_breakdown(dev, scene) if threaded else {}
    load_after = os.getloadavg()[0]

    noise_floor, warp_floor = results[0][1], results[1][1]
    print(f"machine: {cpu_name()}, {os.cpu_count()} CPUs (OpenCV threads {cv2.getNumThreads()}), "
          f"Python {platform.python_version()}, numpy {np.__version__}, OpenCV {cv2.__version__}")
    print(f"load average (1 min) before / after: {load_before:.2f} / {load_after:.2f}")
    print(f"scene: lfring.synth.presets.three_depth_scene(); render(..., {', '.join(f'{k}={v!r}' for k, v in SETTINGS.items())}); "
          f"median of {RUNS} runs after a warm-up")
    print()
    print("| what | median s | min s | max s | x noise draw | x warpPerspective |")
    print("|---|---|---|---|---|---|")
    for name, med, lo, hi in results:
        print(f"| {name} | {med:.3f} | {lo:.3f} | {hi:.3f} | {med / noise_floor:.1f} | {med / warp_floor:.1f} |")
    print()
    if not stages:
        return
    n = default_workers()
    print(f"Full-resolution stages (median of {RUNS}; `view:` rows are summed over the four views, which")
    print(f"run {n} at a time, so with more than one they add up to more than the views' wall time):")
    print()
    print("| stage | median s |")
    print("|---|---|")
    for key, value in stages.items():
        print(f"| {key} | {value:.3f} |")


if __name__ == "__main__":
    main_bench()
