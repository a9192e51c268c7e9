"""Shared by the depth benchmarks: the twin's scene as bench_depth.py renders it, OpenCV's
StereoSGBM with the Middlebury SDK's hole filling, the machine line, and the GPU benchmarks'
check for a CUDA device."""

from __future__ import annotations

import os
import platform
from types import SimpleNamespace

import cv2
import numpy as np

ZMIN, ZMAX = 0.27, 1.1  # depth range of the twin's three-depth scene [m]


def cuda_torch():
    """torch where a CUDA device is present; else None, having printed that the GPU path cannot
    be judged here."""
    try:
        import torch
    except ImportError:
        print("cannot judge: no CUDA device (torch is not installed)")
        return None
    if not torch.cuda.is_available():
        print("cannot judge: no CUDA device")
        return None
    return torch


def random_views(side: int):
    """4 random-texture views of side x side px (float32 RGB) and a calibration from the
    prototype's optics whose views are valid everywhere: the large case of the depth and GPU
    benchmarks."""
    from lfring.calibration import RingCalibration
    from lfring.optics import load_device
    from lfring.views import layout_from_circles

    dev = load_device("prototype")
    w, h = dev.sensor_width_px, dev.sensor_height_px
    circles = [(1228.0 + dx, 921.0 + dy, side / 2) for dy in (0, h / 2) for dx in (0, w / 2)]
    disc = layout_from_circles(circles, w, h)
    square = type(disc)(w, h, disc.rects, False, None)  # views valid everywhere
    cal = RingCalibration.from_optics(dev, layout=square)
    rng = np.random.default_rng(0)
    views = cv2.GaussianBlur(rng.random((4 * side, side, 3), dtype=np.float32), (0, 0), 1.5).reshape(4, side, side, 3)
    return views, cal


def refocus_speed_scene(side: int = 1060):
    """The refocusing speed scene: :func:`random_views` and a given depth map, a near block
    (0.3 m) over a slanted far plane (0.5 .. 1.0 m)."""
    views, cal = random_views(side)
    yy, xx = np.mgrid[0:side, 0:side]
    depth = 0.5 + 0.5 * xx / side
    depth[side // 4:side // 2, side // 4:side // 2] = 0.3
    return views, cal, depth


def machine_line() -> str:
    return (f"machine: {platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, "
            f"OpenCV {cv2.__version__}, load {os.getloadavg()[0]:.2f}")


def numba_layer_line() -> str:
    """numba's threading layer (it picks one on its first parallel call: print this after)."""
    import numba

    try:
        return f"numba threading layer: {numba.threading_layer()}"
    except ValueError:
        return "numba threading layer: none started"


def mirrored_hard_scene():
    """The hard scene laid out anew, for rules tuned on the hard scene: every surface's centre
    mirrored through the optical axis and moved (x -> 4 mm - 0.9 x, y -> -3 mm - 0.9 y), the
    wires 3 cm farther and the diagonal one turned to -25 degrees. Same surfaces and textures."""
    import dataclasses

    from lfring.synth.presets import hard_scene
    from lfring.synth.scene import Plane

    surfaces = []
    for o in hard_scene().surfaces:
        cx, cy = o.center_m
        kw = dict(center_m=(0.004 - 0.9 * cx, -0.003 - 0.9 * cy))
        if isinstance(o, Plane) and "wire" in o.name:
            kw.update(depth_m=o.depth_m + 0.03, roll_deg=-o.roll_deg + (15.0 if o.roll_deg else 0.0))
        elif isinstance(o, Plane):
            kw.update(roll_deg=-o.roll_deg)
        surfaces.append(dataclasses.replace(o, **kw))
    return dataclasses.replace(hard_scene(), surfaces=tuple(surfaces))


def twin_scene(seed: int = 3, *, scene: str = "three_depth") -> SimpleNamespace:
    """The twin's three-depth scene; with ``scene='hard'`` the hard one (slants, curves, thin
    wires, a blank card, per-view vignetting of 15 to 90 %: HARD_VIEW_FALLOFF), with
    ``'hard_mirrored'`` its surfaces laid out anew (:func:`mirrored_hard_scene`, the same
    vignetting); 2 x 2 binned with realistic noise: ``render`` (the RenderResult), ``cal`` (the
    optics calibration), ``views`` (demosaiced, split), ``gt`` (view 0's depth [m])."""
    from lfring.calibration import RingCalibration
    from lfring.io.demosaic import demosaic
    from lfring.io.raw import RawFrame
    from lfring.optics import load_device
    from lfring.synth import render
    from lfring.synth.presets import HARD_VIEW_FALLOFF, hard_scene, three_depth_scene
    from lfring.views import split_views

    scenes = {"three_depth": three_depth_scene, "hard": hard_scene, "hard_mirrored": mirrored_hard_scene}
    # The hard scenes with their per-view vignetting, as `lfring synth hard` renders it.
    falloff = HARD_VIEW_FALLOFF if scene.startswith("hard") else None
    r = render(load_device("prototype"), scenes[scene](), binning=2, noise="realistic", seed=seed, view_falloff=falloff)
    cal = RingCalibration.from_optics(r.device, layout=r.layout)
    frame = RawFrame(mosaic=r.raw, pattern="RGGB", black_level=r.black_level, white_level=r.white_level, bit_depth=12)
    return SimpleNamespace(render=r, cal=cal, views=split_views(demosaic(frame), r.layout), gt=r.depth_m[0])


def fill_invalid(disparity: np.ndarray, *, far_is_lower: bool = True) -> np.ndarray:
    """Invalid (NaN) disparities replaced by the farther of the nearest valid values to their
    left and right on the same row (the Middlebury SDK's filling: an occlusion's hole belongs to
    the background); rows with no valid pixel stay NaN. The rule is lfring's own
    (:func:`lfring.depth.refine.fill_from_farther_side`, on a value that grows with depth).

    The SDK takes the lower disparity, which is the farther one for a left view's disparity
    x_left - x_right > 0. Where the disparity grows with depth instead (the twin's x0 - x1 is
    negative and rises towards the far plane), ``far_is_lower=False`` takes the higher one.
    """
    from lfring.depth.refine import fill_from_farther_side

    d = np.asarray(disparity, np.float32)
    sign = np.float32(-1.0 if far_is_lower else 1.0)  # sign * d grows with depth
    return sign * fill_from_farther_side(sign * d, ~np.isfinite(d))


def sgbm_disparity(left: np.ndarray, right: np.ndarray, min_disparity_px: float, max_disparity_px: float, *,
                   block: int = 5) -> tuple[np.ndarray, dict]:
    """OpenCV StereoSGBM on a rectified pair, colour, with P1 = 8 * 3 * block^2 and
    P2 = 32 * 3 * block^2 (OpenCV's suggested penalties for 3 channels) and numDisparities
    covering [min, max] rounded up to 16. ``left``, ``right``: (h, w, 3) uint8 (or floats in
    [0, 1], scaled by their common maximum). Returns the left view's disparity (px; NaN where
    SGBM finds none) and the settings."""
    if left.dtype != np.uint8:
        top = max(float(left.max()), float(right.max()), 1e-6)
        left, right = (np.rint(np.clip(x / top, 0, 1) * 255).astype(np.uint8) for x in (left, right))
    min_d = int(np.floor(min_disparity_px))
    num = int(np.ceil((max_disparity_px - min_d + 1) / 16.0)) * 16
    p1, p2 = 8 * 3 * block * block, 32 * 3 * block * block
    sgbm = cv2.StereoSGBM_create(minDisparity=min_d, numDisparities=num, blockSize=block, P1=p1, P2=p2,
                                 mode=cv2.STEREO_SGBM_MODE_SGBM)
    d = sgbm.compute(left, right).astype(np.float32) / 16.0
    d[d < min_d] = np.nan
    return d, {"minDisparity": min_d, "numDisparities": num, "blockSize": block, "P1": p1, "P2": p2}
