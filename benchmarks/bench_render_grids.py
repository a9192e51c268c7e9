"""Depth-aware refocusing's wide blurs: the layers blurred on reduced grids against the same
layers blurred at full resolution, and whether the image stays within the views' values.

The renderer blurs a rung's layer on a grid reduced by a power of two wherever its disc stays at
least ``lfring.focus.layers.COARSE_DISC_PX`` px there (from 6 px of blur), and brings it back by
a bicubic resize whose cells are clamped to what premultiplied colour and coverage can hold.
Here, on the bundled frame (its built-in calibration, the depth map estimated at the defaults),
at three foci and three apertures: PSNR (over every pixel / over the frame less 24 px) of the
shipped image, of the same without the clamp, and of a bilinear resize (which cannot overshoot)
against the image whose layers are all blurred at full resolution (``COARSE_DISC_PX`` infinite),
and how many pixels leave the views' range. Prints only.

    python benchmarks/bench_render_grids.py
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import cv2
import numpy as np

import lfring
import lfring.focus.layers as layers
from lfring.errors import LfringWarning
from lfring.focus.depth_aware import depth_of_field

SCENE = Path(__file__).resolve().parents[1] / "data" / "synthetic" / "scene.png"
BORDER_PX = 24


def _resize(interpolation, clamp: bool):
    """A stand-in for the layers' resize: ``interpolation``, clamped as shipped or not."""
    shipped = layers._resize

    def resize(cells, size, vmax):
        if clamp and interpolation == cv2.INTER_CUBIC:
            return shipped(cells, size, vmax)
        chans = [cells] if cells.ndim == 2 or cells.shape[2] <= 4 else [np.ascontiguousarray(cells[..., i]) for i in range(cells.shape[2])]
        out = [cv2.resize(c, size, interpolation=interpolation) for c in chans]
        out = out[0] if len(out) == 1 else np.stack(out, axis=2)
        return out if out.ndim == cells.ndim else out[..., None]
    return resize


def main() -> None:
    warnings.simplefilter("ignore", LfringWarning)
    cal = lfring.RingCalibration.load("twin_binned2")
    views = lfring.split_views(lfring.demosaic(lfring.load_raw(SCENE)), cal)
    dof = depth_of_field(views, cal)
    shipped, coarse = layers._resize, layers.COARSE_DISC_PX
    variants = {"shipped (bicubic, clamped)": (_resize(cv2.INTER_CUBIC, True), coarse),
                "bicubic, not clamped": (_resize(cv2.INTER_CUBIC, False), coarse),
                "bilinear": (_resize(cv2.INTER_LINEAR, False), coarse)}
    h, w = views.shape[1:3]
    inner = np.zeros((h, w, 3), bool)
    inner[BORDER_PX:-BORDER_PX, BORDER_PX:-BORDER_PX] = True
    psnr = lambda a, b, m: 10 * math.log10(1.0 / float(((a - b) ** 2)[m].mean()))  # noqa: E731
    lo, hi = float(views.min()), float(views.max())
    print("| focus m | aperture | largest blur px | " + " | ".join(f"{k}: PSNR all / inner" for k in variants)
          + " | pixels outside the views' values, per variant |")
    print("|---" * (4 + len(variants)) + "|")
    try:
        for focus in (0.3, 0.5, 1.0):
            sharp = lfring.refocus(views, cal, focus)
            for aperture in (2.0, 3.0, 5.0):
                layers._resize, layers.COARSE_DISC_PX = shipped, math.inf
                full = dof.render(focus, aperture, sharp)
                cells, outside = [], []
                for resize, c in variants.values():
                    layers._resize, layers.COARSE_DISC_PX = resize, c
                    img = dof.render(focus, aperture, sharp)
                    cells.append(f"{psnr(img, full, np.ones_like(inner)):.2f} / {psnr(img, full, inner):.2f}")
                    outside.append(str(int(((img < lo - 1e-6) | (img > hi + 1e-6)).sum())))
                blur = float(np.nanmax(np.abs(dof.signed_radius_px(focus)))) * aperture
                print(f"| {focus} | {aperture} | {blur:.1f} | " + " | ".join(cells) + f" | {' / '.join(outside)} |")
    finally:
        layers._resize, layers.COARSE_DISC_PX = shipped, coarse


if __name__ == "__main__":
    main()
