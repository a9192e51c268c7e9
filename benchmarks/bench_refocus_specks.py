"""Specks and seams of depth-aware refocusing on the README's main job: the bundled frame
(`data/synthetic/scene.png`), its built-in calibration, the depth map `lfring refocus` makes.

A speck is a pixel of the image, where some view sees it, that is darker (or brighter) than the
median of its 5 x 5 neighbourhood by more than 0.15 (linear [0, 1]). Thin dark lines along the
views' disc rims and dark dots inside flat regions are what users saw; an edge of the scene
itself (a corner of a chessboard square) can also count, so compare counts between trees, not
against zero. Counted for the renderer's all-in-focus colour and for renders at three foci and
apertures; without the flat field (as the main job runs) and with the bundled flat frame.

    python benchmarks/bench_refocus_specks.py

The depth map is estimated once per run (in the tree on the path) and shared by every row. To
compare two trees, run it with each first on PYTHONPATH.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from lfring import demosaic, refocus, split_views
from lfring.calibration.defaults import default_calibration
from lfring.check import check_frame
from lfring.focus.depth_aware import depth_of_field, estimation_range
from lfring.io.levels import load_frame
from lfring.views import flat_field_from_frame

DATA = Path(__file__).resolve().parents[1] / "data" / "synthetic"
# A speck: this much (linear [0, 1]) off the median of its 5 x 5 neighbourhood.
SPECK = 0.15
RENDERS = ((0.5, 1.0), (0.3, 2.0), (1.0, 1.0))


def specks(image: np.ndarray, seen: np.ndarray) -> tuple[int, int]:
    """(dark, bright) speck counts of ``image`` (h, w, C) over the ``seen`` pixels."""
    g = image.mean(axis=2)
    med = cv2.medianBlur(np.clip(g * 255.0, 0, 255).astype(np.uint8), 5).astype(np.float32) / 255.0
    return int((seen & (med - g > SPECK)).sum()), int((seen & (g - med > SPECK)).sum())


def views_of(name: str, cal, flat=None) -> np.ndarray:
    frame, _ = load_frame(DATA / name, calibration=cal)
    return split_views(demosaic(frame), cal, flat=flat)


def main() -> None:
    probe, _ = load_frame(DATA / "scene.png")
    image = demosaic(probe)
    cal, cal_name = default_calibration((image.shape[1], image.shape[0]))
    assert check_frame(image, cal).ok
    flat_frame = demosaic(load_frame(DATA / "flat.png", calibration=cal)[0])
    zmin, zmax = estimation_range(cal)
    print(f"scene.png, built-in calibration {cal_name}, depth range {zmin:.3g} .. {zmax:.3g} m; speck: "
          f"{SPECK} off the 5 x 5 median")
    print("| flat field | image | dark specks | bright specks | pixels seen |")
    print("|---|---|---|---|---|")
    for label, flat in (("none (the main job)", None), ("flat.png", flat_field_from_frame(flat_frame, cal))):
        views = views_of("scene.png", cal, flat)
        dof = depth_of_field(views, cal, zmin_m=zmin, zmax_m=zmax)
        rows = [("all-in-focus colour", dof.colour)]
        rows += [(f"render at {f:g} m, aperture {a:g}", dof.render(f, a, refocus(views, cal, f))) for f, a in RENDERS]
        for what, img in rows:
            dark, bright = specks(img, dof.seen)
            print(f"| {label} | {what} | {dark} | {bright} | {int(dof.seen.sum())} |")


if __name__ == "__main__":
    main()
