"""The plane sweep: every hypothesis's cost, aggregated over a window, folded into a running
minimum or kept as a whole volume.

- :mod:`lfring.depth.sweep.strips`: the 'lcn' costs with box aggregation, strip by strip in the
  cache, on several threads (the fast path);
- :mod:`lfring.depth.sweep.slices`: any cost and aggregation a whole slice at a time, and its
  torch twin.

:func:`run_sweep` chooses between them for the engines (:mod:`lfring.depth.engines`).
"""

from __future__ import annotations

import numpy as np

from lfring.core.filters import normalised_luminance
from lfring.depth.aggregation import guided_filter
from lfring.depth.costs.base import wide_sources
from lfring.depth.plan import in_reference_frame
from lfring.depth.sweep.slices import sweep_slices, sweep_slices_torch
from lfring.depth.sweep.strips import sweep_strips

__all__ = ["run_sweep"]


def run_sweep(views, calibration, plan, settings, *, volume=None, halves=None, on_strip=None, on_rows=None):
    """Sweep the views over the plan's hypotheses with the settings' cost, aggregation and backend.

    Parameters
    ----------
    views : (V, h, w, C) float32
    calibration : RingCalibration
    plan : lfring.depth.plan.SweepPlan
    settings : lfring.depth.plan.DepthSettings
    volume, halves : (N, h, w) float32, optional
        Filled with every hypothesis's aggregated cost (and, for a cost with
        :attr:`~lfring.depth.costs.base.DepthCost.halves`, the halves' least cost) instead of a
        running minimum; then the number of views that see each pixel is returned.
    on_strip : callable, optional
        Without ``volume``: called as ``on_strip(r0, r1, best_i, c_best, c_prev, c_next,
        c_second, nviews)`` with the running minimum's results for rows r0 to r1 (the whole frame
        at once for the whole-slice sweeps); then nothing is returned.
    on_rows : callable, optional
        Progress: ``on_rows(r0, r1)`` as the strip sweep finishes rows.

    Returns
    -------
    nviews (h, w) with ``volume``; None with ``on_strip``; else the running minimum's arrays
    (best_i, c_best, c_prev, c_next, c_second, nviews).
    """
    cost = settings.cost
    if cost.lcn and settings.aggregation == "box" and settings.backend == "numpy":
        sources = cost.sources(views, calibration, plan, settings.window_px, settings.threads)
        return sweep_strips(sources, plan.masks, plan.hs, aggregate_px=settings.aggregate_px, exclude=plan.exclude,
                            threads=settings.threads, on_strip=on_strip, volume=volume, occlusion=cost.leave_one_out,
                            on_rows=on_rows, halves=halves)
    wide = guide = None
    if settings.aggregation == "guided":
        # The guided filter's guide: the reference frame's luminance, normalised like the costs'.
        wide = normalised_luminance(views, plan.masks)
        g = in_reference_frame(wide, plan)
        guide = np.clip(g / max(float(g.max()), 1e-6), 0, 1).astype(np.float32)
    if wide is not None and cost.sources is wide_sources:
        sources = wide
    else:
        sources = cost.sources(views, calibration, plan, settings.window_px, settings.threads)
    if settings.backend == "torch":
        out = sweep_slices_torch(sources, plan.masks, plan.hs, cost=cost, aggregation=settings.aggregation,
                                 window_px=settings.window_px, aggregate_px=settings.aggregate_px, guide=guide,
                                 exclude=plan.exclude, device=settings.device, volume=volume, halves=halves)
    else:
        window = None if guide is None else guided_filter(guide, settings.aggregate_px)
        out = sweep_slices(sources, plan.masks, plan.hs, cost, settings.window_px, window, plan.exclude,
                           settings.aggregate_px, volume=volume, halves=halves)
    if volume is None and on_strip is not None:
        on_strip(0, views.shape[1], *out)
        return None
    return out
