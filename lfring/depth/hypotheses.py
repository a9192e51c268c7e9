"""Depth hypotheses: depths evenly spaced in disparity, and how far views move between them.

A ring's views of a fronto-parallel plane at depth Z differ by maps that are affine in
1/(Z - z0) (the variable-homography model), so hypotheses evenly spaced in 1/(Z - z0) are evenly spaced in disparity:
a sweep over them samples every pixel's cost curve at a constant step.
"""

from __future__ import annotations

import numpy as np

from lfring.core.validate import check_int, check_number
from lfring.errors import InvalidInputError
from lfring.calibration.model import view_motion_px

__all__ = ["check_depth_range", "depth_hypotheses"]


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
