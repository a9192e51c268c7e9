"""The record of one photo-consistency cost: what the sweep needs to know of it.

A cost compares the views warped to one hypothesis. Its record holds the NumPy reference and the
torch twin side by side, and says what the sweep must do for it: prepare the views' sources
(:attr:`DepthCost.sources`), leave one view out over each window (:attr:`DepthCost.leave_one_out`),
or keep the cost of half of the views beside the whole volume (:attr:`DepthCost.halves`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from lfring.core.filters import normalised_luminance
from lfring.core.viewstack import WEIGHT_FLOOR

__all__ = ["DepthCost", "compiled_kernels", "wide_sources", "wide_terms", "wide_terms_torch"]


@dataclass(frozen=True)
class DepthCost:
    """One photo-consistency cost of the plane sweep.

    Attributes
    ----------
    name : str
        The name ``estimate_depth(cost=...)`` takes.
    summary : str
        One line for help texts.
    sources : callable
        ``sources(views, calibration, plan, window_px, threads)`` -> (V, h, w) float32: what each
        view becomes before the sweep (multiplied by its mask and warped at every hypothesis).
    slice_cost : callable
        ``slice_cost(lum_w, wts, nview, window_px)`` -> (h, w) float32: the per-pixel cost of one
        hypothesis from the warped sources premultiplied by their warped masks ``lum_w`` (V, h, w),
        the warped masks ``wts`` and their sum ``nview``.
    slice_cost_torch : callable
        The torch twin, ``slice_cost_torch(torch, lum_w, wts, nview, box)`` on chunks of
        hypotheses (C, V, h, w) -> (C, h, w), ``box`` the cost window's
        :class:`lfring.core.filters.BoxTorch`.
    lcn : bool
        The sources are the locally normalised luminances and the cost their variance across
        views: the strip sweep (:func:`lfring.depth.sweep.strips.sweep_strips`) computes it.
    leave_one_out : bool
        Over each window, the least of the cost and the costs without one view
        (:mod:`lfring.depth.costs.lcn_occlusion`).
    halves : bool
        Keeps every hypothesis's cost of half of the views beside the volume and takes it where no
        depth suits all views (:mod:`lfring.depth.costs.lcn_halves`): needs an engine that holds
        the whole cost volume.
    """

    name: str
    summary: str
    sources: Callable
    slice_cost: Callable
    slice_cost_torch: Callable
    lcn: bool = False
    leave_one_out: bool = False
    halves: bool = False


def wide_sources(views, calibration, plan, window_px: int, threads: int) -> np.ndarray:
    """(V, h, w) float32 luminance of every view divided by its wide local mean
    (:func:`lfring.core.filters.normalised_luminance`): the sources of the costs that compare
    luminances directly."""
    return normalised_luminance(views, plan.masks)


def wide_terms(lum_w: np.ndarray, wts: np.ndarray, nview: np.ndarray):
    """The terms the direct comparisons share: every view's value (``lum_w / wts``), where it is
    valid (``wts > 0.5``) and the views' weighted mean."""
    vals = lum_w / np.maximum(wts, WEIGHT_FLOOR)
    valid = wts > 0.5
    mean = lum_w.sum(axis=0) / np.maximum(nview, WEIGHT_FLOOR)
    return vals, valid, mean


def wide_terms_torch(lum_w, wts, nview):
    """The torch twin of :func:`wide_terms` for chunks (C, V, h, w); also the number of valid
    views (small integers, exact in float32)."""
    vals = lum_w / wts.clamp_min(WEIGHT_FLOOR)
    valid = (wts > 0.5).to(lum_w.dtype)
    mean = lum_w.sum(dim=1) / nview.clamp_min(WEIGHT_FLOOR)
    return vals, valid, valid.sum(dim=1), mean


def compiled_kernels():
    """:mod:`lfring.depth.costs.kernels`, imported (and numba with it) on first use."""
    from lfring.depth.costs import kernels

    return kernels
