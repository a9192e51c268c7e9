"""Refocusing speed: 4 views of 1060 x 1060 RGB float32 at one depth, side by side with a
plain unwarped mean of the same views, in one run. Medians of 25 runs after a warm-up.

    python benchmarks/bench_refocus.py

The views' size is the paper's sub-aperture size; the calibration is the prototype's from its
optics with views of that size (translations of about 240 px between neighbours).
"""

from __future__ import annotations

import os
import platform
import time

import cv2
import numpy as np

from _timing import bench as _bench
from lfring.calibration import RingCalibration
from lfring.optics import load_device
from lfring.refocus import Refocuser, refocus
from lfring.views import layout_from_circles

RUNS = 25


def bench(fn):
    return _bench(fn, RUNS)


def main() -> None:
    dev = load_device("prototype")
    # 1060 px views around the iris discs of the full-resolution prototype.
    w, h = dev.sensor_width_px, dev.sensor_height_px
    cx, cy, side = 1228.0, 921.0, 1060
    circles = [(cx + dx, cy + dy, side / 2) for dy in (0, h / 2) for dx in (0, w / 2)]
    disc = layout_from_circles(circles, w, h)  # views valid inside their iris disc (the default)
    square = type(disc)(w, h, disc.rects, False, None)  # views valid everywhere
    cal = RingCalibration.from_optics(dev, layout=square)
    cal_disc = RingCalibration.from_optics(dev, layout=disc)
    rng = np.random.default_rng(0)
    views = cv2.GaussianBlur(rng.random((4 * side, side, 3), dtype=np.float32), (0, 0), 1.5).reshape(4, side, side, 3)
    fast = Refocuser(cal, 0.5)
    fast_disc = Refocuser(cal_disc, 0.5)
    rows = [
        ("peer: plain unwarped mean, views.mean(axis=0)", lambda: views.mean(axis=0)),
        ("refocus(views, cal, 0.5), views valid everywhere", lambda: refocus(views, cal, 0.5)),
        ("refocus, valid discs (tapered masks)", lambda: refocus(views, cal_disc, 0.5)),
        ("refocus, interpolation='cubic'", lambda: refocus(views, cal, 0.5, interpolation="cubic")),
        ("fast path: Refocuser(cal, 0.5) once, then per frame", lambda: fast(views)),
        ("fast path, valid discs", lambda: fast_disc(views)),
    ]
    try:
        import torch  # noqa: F401

        rows.append(("refocus backend='torch', device='cpu'", lambda: refocus(views, cal, 0.5, backend="torch", device="cpu")))
    except ImportError:
        pass
    res = [(name, *bench(fn)) for name, fn in rows]
    base = res[0][1]
    print(f"machine: {platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, numpy {np.__version__}, "
          f"OpenCV {cv2.__version__} ({cv2.getNumThreads()} threads), load {os.getloadavg()[0]:.2f}")
    print(f"4 views of {side} x {side} x 3 float32; median of {RUNS} runs")
    print("| what | median ms | min ms | max ms | x mean |")
    print("|---|---|---|---|---|")
    for name, med, lo, hi in res:
        print(f"| {name} | {med * 1e3:.1f} | {lo * 1e3:.1f} | {hi * 1e3:.1f} | {med / base:.2f} |")
    t0 = time.perf_counter()
    Refocuser(cal, 0.5)
    print(f"\nbuilding a Refocuser (geometry, masks, normalisation): {(time.perf_counter() - t0) * 1e3:.1f} ms")


if __name__ == "__main__":
    main()
