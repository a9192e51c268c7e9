"""Two checkouts of lfring side by side: the refocus fast path, a one-shot refocus and the local
depth sweep (the default before the semi-global one) timed in each, alternately, in fresh
processes, so that a change of the machine's load falls on both alike.

    git worktree add /tmp/lfring-old 188722c          # the commit before the warping core
    python benchmarks/bench_ab.py /tmp/lfring-old .   # old, new, old, new, ... (3 rounds)

Times are medians within each process (21 frames, 3 sweeps at 1060 x 1060 x 64 planes, 7 at the
twin's 704 x 704 views); each round prints one line per checkout.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import warnings
from pathlib import Path


def _median(fn, n):
    from _timing import bench

    return bench(fn, n)[0]


def probe() -> None:
    import cv2
    import numpy as np

    import lfring
    from lfring.calibration import RingCalibration
    from lfring.optics import load_device
    from lfring.views import layout_from_circles

    warnings.simplefilter("ignore")
    local = {"method": "local"} if "method" in lfring.estimate_depth.__code__.co_varnames else {}
    dev = load_device("prototype")
    w, h = dev.sensor_width_px, dev.sensor_height_px
    side = 1060
    circles = [(1228.0 + dx, 921.0 + dy, side / 2) for dy in (0, h / 2) for dx in (0, w / 2)]
    disc = layout_from_circles(circles, w, h)
    square = type(disc)(w, h, disc.rects, False, None)
    cal = RingCalibration.from_optics(dev, layout=square)
    views = cv2.GaussianBlur(np.random.default_rng(0).random((4 * side, side, 3), dtype=np.float32), (0, 0), 1.5)
    views = views.reshape(4, side, side, 3)
    r = lfring.Refocuser(cal, 0.5)
    out = {"refocus_fast_ms": 1e3 * _median(lambda: r(views), 21)}
    zs = iter(np.linspace(0.4, 0.6, 1000))
    out["refocus_one_shot_ms"] = 1e3 * _median(lambda: lfring.refocus(views, cal, float(next(zs))), 21)
    out["depth_1060x64_local_s"] = _median(
        lambda: lfring.estimate_depth(views, cal, zmin_m=0.3, zmax_m=1.0, num_planes=64, **local), 3)
    small = np.ascontiguousarray(views[:, :704, :704])
    lay = type(disc)(w, h, [(x, y, 704, 704) for x, y, *_ in disc.rects], False, None)
    cal2 = RingCalibration.from_optics(dev, layout=lay)
    out["depth_704_local_s"] = _median(
        lambda: lfring.estimate_depth(small, cal2, zmin_m=0.27, zmax_m=1.1, reference=0, **local), 7)
    print(json.dumps({k: round(v, 4) for k, v in out.items()}))


def main() -> None:
    trees = [str(Path(p).resolve()) for p in sys.argv[1:3]]
    print(f"load {os.getloadavg()[0]:.2f}")
    for _ in range(3):
        for tree in trees:
            env = {**os.environ, "PYTHONPATH": tree}
            res = subprocess.run([sys.executable, __file__, "--probe"], env=env, capture_output=True, text=True, check=True)
            print(Path(tree).name, res.stdout.strip(), flush=True)
    print(f"load {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    probe() if sys.argv[1:] == ["--probe"] else main()
