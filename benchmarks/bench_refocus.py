"""Refocusing speed: 4 views of 1060 x 1060 RGB float32 at one depth, side by side with a
plain unwarped mean of the same views, in one run.

    python benchmarks/bench_refocus.py

The views' size is the paper's sub-aperture size; the calibration is the prototype's from its
optics with views of that size (translations of about 240 px between neighbours), so the
Refocuser takes its shift path; the general warp (``cv2.warpAffine`` per view, what every
calibration took before the shift path) is timed beside it for reference.

Every row is timed once per round, rows interleaved, after one warm-up round: a change in the
machine's load during the run then falls on all rows alike. Medians over ``RUNS`` rounds. The
peer, the fast path and the one-shot row are then timed again back to back (all runs of one
row, then the next), where the mean finds more of the views still in the cache. The
one-shot ``refocus`` rows use a new depth every call, so nothing that depends on the depth is
reused from an earlier call (what does not depend on it, the view masks, is cached per
calibration).
"""

from __future__ import annotations

import itertools
import os
import platform
import statistics
import time

import cv2
import numpy as np

from _timing import bench
from lfring.calibration import RingCalibration
from lfring.optics import load_device
from lfring.refocus import Refocuser, refocus
from lfring.views import layout_from_circles

RUNS = 31


def interleaved(rows, runs: int):
    """{name: (median, min, max) seconds} of every row timed once per round, rows interleaved."""
    times = {name: [] for name, _ in rows}
    for r in range(runs + 1):
        for name, fn in rows:
            t = time.perf_counter()
            fn()
            if r:  # round 0 warms up
                times[name].append(time.perf_counter() - t)
    return {name: (statistics.median(ts), min(ts), max(ts)) for name, ts in times.items()}


def general(calibration, depth_m, **kw) -> Refocuser:
    """A Refocuser that warps every view (``cv2.warpAffine``) even where the shift path applies."""
    r = Refocuser(calibration, depth_m, **kw)
    r._shift = None
    return r


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
    fast, fast_disc, fast_1 = Refocuser(cal, 0.5), Refocuser(cal_disc, 0.5), Refocuser(cal, 0.5, threads=1)
    assert fast.shift_path and fast_disc.shift_path
    warp, warp_disc = general(cal, 0.5), general(cal_disc, 0.5)
    new_depth = (0.45 + 1e-5 * i for i in itertools.count())  # a different depth every call
    threads = cv2.getNumThreads()
    rows = [
        ("peer: plain unwarped mean, views.mean(axis=0)", lambda: views.mean(axis=0)),
        (f"fast path: Refocuser(cal, 0.5) once, then per frame ({threads} threads)", lambda: fast(views)),
        ("fast path, threads=1", lambda: fast_1(views)),
        ("fast path, valid discs (tapered masks)", lambda: fast_disc(views)),
        ("one-shot refocus(views, cal, z), a new z every call", lambda: refocus(views, cal, next(new_depth))),
        ("one-shot refocus, valid discs, a new z every call", lambda: refocus(views, cal_disc, next(new_depth))),
        ("reference: general warp (cv2.warpAffine per view), Refocuser once", lambda: warp(views)),
        ("reference: general warp, valid discs", lambda: warp_disc(views)),
        ("reference: one-shot refocus, interpolation='cubic' (general warp), a new z every call",
         lambda: refocus(views, cal, next(new_depth), interpolation="cubic")),
    ]
    err = float(np.abs(fast(views) - warp(views)).max())
    err_disc = float(np.abs(fast_disc(views) - warp_disc(views)).max())
    res = interleaved(rows, RUNS)
    base = res[rows[0][0]][0]
    print(f"machine: {platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, numpy {np.__version__}, "
          f"OpenCV {cv2.__version__} ({threads} threads), load {os.getloadavg()[0]:.2f}")
    print(f"4 views of {side} x {side} x 3 float32; median of {RUNS} interleaved rounds after a warm-up round")
    print("| what | median ms | min ms | max ms | x mean |")
    print("|---|---|---|---|---|")
    for name, (med, lo, hi) in res.items():
        print(f"| {name} | {med * 1e3:.1f} | {lo * 1e3:.1f} | {hi * 1e3:.1f} | {med / base:.2f} |")
    # The same three rows back to back (each row's runs in a row, as this benchmark did before):
    # the mean then finds more of the views in the cache than when interleaved.
    print("\nback to back (each row's runs in a row, then the next row):")
    print("| what | median ms | min ms | max ms | x mean |")
    print("|---|---|---|---|---|")
    solo = [(name, *bench(fn, RUNS)) for name, fn in (rows[0], rows[1], rows[4])]
    for name, med, lo, hi in solo:
        print(f"| {name} | {med * 1e3:.1f} | {lo * 1e3:.1f} | {hi * 1e3:.1f} | {med / solo[0][1]:.2f} |")
    print(f"\nshift path against the general warp, largest difference: {err:.1e} (valid everywhere), {err_disc:.1e} (discs)")
    for name, c in (("valid everywhere", cal), ("valid discs", cal_disc)):
        med = bench(lambda: Refocuser(c, next(new_depth)), RUNS)[0]  # noqa: B023
        print(f"building a Refocuser at a new depth ({name}; its normalisation is made on its first frame): {med * 1e3:.1f} ms")
    try:  # timed apart: torch's CPU threads would disturb the interleaved rows
        import torch  # noqa: F401

        t = interleaved([("torch", lambda: refocus(views, cal, 0.5, backend="torch", device="cpu"))], 5)["torch"][0]
        print(f"refocus backend='torch', device='cpu', timed after the others (median of 5): {t * 1e3:.1f} ms, {t / base:.1f}x the mean")
    except ImportError:
        pass


if __name__ == "__main__":
    main()
