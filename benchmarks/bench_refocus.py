"""Refocusing speed: 4 views of 1060 x 1060 RGB float32 at one depth, side by side with a
plain unwarped mean of the same views, in one run.

    python benchmarks/bench_refocus.py

The views' size is the paper's sub-aperture size; the calibration is the prototype's from its
optics with views of that size (translations of about 240 px between neighbours), so the
Refocuser takes its shift path; the general warp (``cv2.warpAffine`` per view, what every
calibration took before the shift path) is timed beside it for reference.

The issue's rows (the peer, the fast path and the one-shot refocus, each with and without
valid discs) are timed back to back, all runs of one row after a warm-up run and then the next
row, and judged against the targets there. Then every row, the references included, is timed
once per round, rows interleaved, after a warm-up round, so that a change in the machine's
load falls on all rows alike; there the peer is slower than alone (its output allocation gets
fresh pages after the other rows' temporaries). Medians of ``RUNS`` runs. The one-shot rows
use a new depth every call, so nothing that depends on the depth is reused from an earlier
call (what does not, the view masks, is cached per calibration).
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
from lfring.focus import Refocuser, refocus
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
    # The rows back to back (each row's runs in a row, as this benchmark did before):
    # the targets are judged here. Interleaved, the peer's output allocation gets fresh pages
    # (about 700 page faults a call, measured) after the other rows' temporaries, which makes
    # it slower than it is alone; back to back it reuses its own.
    solo = [(name, *bench(fn, RUNS)) for name, fn in rows[:6]]
    res = interleaved(rows, RUNS)
    print(f"machine: {platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, numpy {np.__version__}, "
          f"OpenCV {cv2.__version__} ({threads} threads), load {os.getloadavg()[0]:.2f}")
    print(f"4 views of {side} x {side} x 3 float32\n")
    print(f"the issue's rows back to back (all {RUNS} runs of a row after a warm-up run, then the next row); medians:")
    print("| what | median ms | min ms | max ms | x mean |")
    print("|---|---|---|---|---|")
    for name, med, lo, hi in solo:
        print(f"| {name} | {med * 1e3:.1f} | {lo * 1e3:.1f} | {hi * 1e3:.1f} | {med / solo[0][1]:.2f} |")
    base = res[rows[0][0]][0]
    print(f"\nall rows interleaved ({RUNS} rounds of one run of every row, after a warm-up round; the peer pays page faults "
          "for its output here); medians:")
    print("| what | median ms | min ms | max ms | x mean |")
    print("|---|---|---|---|---|")
    for name, (med, lo, hi) in res.items():
        print(f"| {name} | {med * 1e3:.1f} | {lo * 1e3:.1f} | {hi * 1e3:.1f} | {med / base:.2f} |")
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
