"""Two checkouts of lfring side by side: the refocus fast path, a one-shot refocus, the local
depth sweep and (where the checkout has it) the semi-global default, timed in each, alternately,
in fresh processes, so that a change of the machine's load falls on both alike; OpenCV's
StereoSGBM on the twin's views 0 and 1 in the same processes, the peer for the time ratio.

    git worktree add /tmp/lfring-old 188722c          # the commit before the warping core
    python benchmarks/bench_ab.py /tmp/lfring-old .   # old, new, old, new, ... (3 rounds)
    python benchmarks/bench_ab.py /tmp/lfring-old . --rounds 5

Times are medians within each process (21 frames, 3 sweeps at 1060 x 1060 x 64 planes, 7 at the
twin's 704 x 704 views and on the twin's three-depth scene); each round prints one line per
checkout, and the last lines the medians over the rounds, with a digest of the twin's default
depth map (equal digests: the same numbers to the bit).
"""

from __future__ import annotations

import json
import sys
import warnings


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
    if local:  # the semi-global default exists
        from _common import ZMAX, ZMIN, twin_scene
        from bench_depth import sgbm_depth

        out["depth_1060x64_default_s"] = _median(
            lambda: lfring.estimate_depth(views, cal, zmin_m=0.3, zmax_m=1.0, num_planes=64), 3)
        t = twin_scene()
        out["depth_twin_default_s"] = _median(
            lambda: lfring.estimate_depth(t.views, t.cal, zmin_m=ZMIN, zmax_m=ZMAX, reference=0), 7)
        out["sgbm_twin_s"] = _median(lambda: sgbm_depth(t.views, t.cal, ZMIN, ZMAX), 7)
        # The same numbers, not only the same time: a digest of the twin's default depth map.
        import hashlib

        res = lfring.estimate_depth(t.views, t.cal, zmin_m=ZMIN, zmax_m=ZMAX, reference=0)
        digest = hashlib.sha256(np.ascontiguousarray(res.depth_m).tobytes()).hexdigest()[:12]
        print(json.dumps({**{k: round(v, 4) for k, v in out.items()}, "depth_twin_default_sha256": digest}))
        return
    print(json.dumps({k: round(v, 4) for k, v in out.items()}))


if __name__ == "__main__":
    if sys.argv[1:] == ["--probe"]:
        probe()
    else:
        from _timing import alternate_checkouts

        alternate_checkouts(__file__, __doc__.splitlines()[0], default_rounds=3)
