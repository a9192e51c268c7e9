"""Calibration of the 2 x 2 binned twin: time per pair of targets and accuracy at held-out
planes, and what assuming z0 = 0 costs (in pixels and in millimetres of depth).

Targets at 0.3 and 1.0 m (and 0.5 m for the three-plane fit), held-out planes at 0.5 and
2.0 m; errors are the RMS over the view of the distance between points mapped by the fitted
and the exact homographies (worst view). Peer in the same run: the same pair calibrated with
SIFT + RANSAC instead of ECC.

    python benchmarks/bench_calibrate.py
"""

from __future__ import annotations

import platform
import statistics
import time

import cv2
import numpy as np
from scipy.optimize import minimize_scalar

from lfring.calibration import calibrate
from lfring.core.geometry import homography_rms_px
from lfring.io.raw import RawFrame
from lfring.optics import load_device
from lfring.optics.views import optical_homographies
from lfring.synth import render
from lfring.synth.presets import flat_scene, target_scene

RUNS = 5


def frame(r):
    return RawFrame(mosaic=r.raw, pattern=r.settings.pattern, black_level=r.black_level, white_level=r.white_level, bit_depth=12)


def main() -> None:
    proto = load_device("prototype")
    print(f"machine: {platform.machine()}, {cv2.getNumberOfCPUs()} CPUs, Python {platform.python_version()}, "
          f"numpy {np.__version__}, OpenCV {cv2.__version__}")
    flat_r = render(proto, flat_scene(proto), binning=2, noise="low")
    dev, layout, flat = flat_r.device, flat_r.layout, frame(flat_r)
    s = dev.entrance_pupil_m
    rows = []
    for noise in ("none", "realistic"):
        t = {z: frame(render(proto, target_scene(proto, z, seed=int(10 * z)), binning=2, noise=noise, seed=3)) for z in (0.3, 0.5, 1.0)}
        pair = {0.3: t[0.3], 1.0: t[1.0]}
        for label, kw in (("ECC, z0 = s (device)", dict(device=dev)), ("ECC, z0 = 0", dict(depth_origin_m=0.0)),
                          ("SIFT, z0 = s (device)", dict(device=dev, method="sift"))):
            times = []
            for _ in range(RUNS if noise == "realistic" else 1):
                t0 = time.perf_counter()
                cal = calibrate(pair, flat=flat, **kw)  # layout detected on the flat, as a user would
                times.append(time.perf_counter() - t0)
            # Compare against the truth in the detected layout's own view coordinates.
            errs = [float(homography_rms_px(cal.model(z), optical_homographies(dev, cal.layout, z, reference=0), cal.layout.view_shape).max())
                    for z in (0.5, 2.0)]
            rows.append((noise, label, statistics.median(times), *errs))
        three = calibrate(t, flat=flat)
        rows.append((noise, "ECC, 3 planes, z0 fitted", float("nan"), *[
            float(homography_rms_px(three.model(z), optical_homographies(dev, three.layout, z, reference=0), three.layout.view_shape).max())
            for z in (0.5, 2.0)]))
        print(f"noise={noise}: 3-plane z0 = {three.depth_origin_m * 1e3:.3f} mm, optics s = {s * 1e3:.3f} mm, "
              f"error {abs(three.depth_origin_m - s) * 1e3:.3f} mm")
    print(f"\nmedian of {RUNS} runs (realistic noise), layout detected on the flat each time")
    print("| noise | method | time per pair s | held-out 0.5 m px | held-out 2.0 m px |")
    print("|---|---|---|---|---|")
    for noise, label, tm, e05, e2 in rows:
        print(f"| {noise} | {label} | {'' if np.isnan(tm) else f'{tm:.2f}'} | {e05:.4f} | {e2:.4f} |")

    # What z0 = 0 costs in depth: the depth whose true homographies best match the naive model.
    lay = layout
    meas = {z: optical_homographies(dev, lay, z, reference=0) for z in (0.3, 1.0)}
    from lfring.calibration import fit_variable_homography

    naive, _ = fit_variable_homography(meas, shape_hw=lay.view_shape, depth_origin_m=0.0)
    print("\nexact homographies at 0.3 and 1.0 m, model with z0 = 0 instead of s:")
    print("| depth m | error px | equivalent depth error mm |")
    print("|---|---|---|")
    for z in (0.4, 0.5, 0.7, 2.0):
        hz = naive(z)
        err = float(homography_rms_px(hz, optical_homographies(dev, lay, z, reference=0), lay.view_shape).max())
        best = minimize_scalar(lambda zz: float(np.mean(homography_rms_px(hz, optical_homographies(dev, lay, zz, reference=0), lay.view_shape, step=16) ** 2)),
                               bounds=(z * 0.8, z * 1.25), method="bounded", options={"xatol": 1e-7})
        print(f"| {z} | {err:.3f} | {(best.x - z) * 1e3:+.1f} |")


if __name__ == "__main__":
    main()
