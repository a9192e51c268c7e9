"""Depth hypotheses: depths evenly spaced in disparity, and how far views move between them.

A ring's views of a fronto-parallel plane at depth Z differ by maps that are affine in
1/(Z - z0) (the variable-homography model), so hypotheses evenly spaced in 1/(Z - z0) are evenly spaced in disparity:
a sweep over them samples every pixel's cost curve at a constant step.
"""

from __future__ import annotations

import numpy as np

from lfring.core.validate import check_int, check_number
from lfring.errors import InvalidInputError
from lfring.core.geometry import apply_homography

__all__ = ["check_depth_range", "depth_hypotheses", "view_motion_px"]


def view_motion_px(calibration, depths_m, view_shape) -> float:
    """Largest distance any view pixel moves in the reference frame between consecutive depths
    of ``depths_m`` (its corners bound it: the maps are affine, or nearly so)."""
    h, w = view_shape
    corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]], dtype=np.float64)
    hs = calibration.model(np.asarray(depths_m, dtype=np.float64))
    steps = [np.abs(apply_homography(hs[i, k], corners) - apply_homography(hs[i + 1, k], corners)).max()
             for i in range(len(hs) - 1) for k in range(hs.shape[1])]
    return float(max(steps)) if steps else 0.0


def check_depth_range(zmin_m, zmax_m) -> tuple[float, float]:
    """(zmin_m, zmax_m) as floats: positive distances in metres, the first the smaller."""
    for name, v in (("zmin_m", zmin_m), ("zmax_m", zmax_m)):
        check_number(v, name, above=0.0, what="a distance in metres")
    if not zmin_m < zmax_m:
        raise InvalidInputError(f"zmin_m ({zmin_m}) must be smaller than zmax_m ({zmax_m})")
    return float(zmin_m), float(zmax_m)


def depth_hypotheses(calibration, zmin_m: float, zmax_m: float, *, num=None, max_step_px: float = 1.0) -> np.ndarray:
    """Depths between ``zmin_m`` and ``zmax_m`` evenly spaced in 1/(Z - z0) (evenly in disparity),
    by default close enough that no view moves more than ``max_step_px`` between neighbours."""
    z0 = calibration.depth_origin_m
    check_depth_range(zmin_m, zmax_m)
    if zmin_m <= z0:
        raise InvalidInputError(f"zmin_m ({zmin_m}) must lie beyond the depth origin z0 = {z0:.4g} m")
    if num is None:
        move = view_motion_px(calibration, [zmin_m, zmax_m], calibration.layout.view_shape)
        num = max(2, int(np.ceil(move / max_step_px)) + 1)
    check_int(num, "the number of depths", minimum=2)
    inv = np.linspace(1.0 / (zmin_m - z0), 1.0 / (zmax_m - z0), int(num))
    return z0 + 1.0 / inv
