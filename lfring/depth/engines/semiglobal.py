"""The semi-global engine: the whole cost volume optimised along scan lines.

Along ``paths`` scan lines a penalty for every change of depth, lowered across image edges
(:mod:`lfring.depth.sgm`), fills weak texture and keeps gross outliers away. The engine optimises
the least cost of the aggregation boxes that contain each pixel (shiftable windows,
:func:`lfring.depth.aggregation.least_over_windows`), so a surface's texture does not spread its
depth over the pixels beside it; fits the sub-hypothesis parabola to a wider box of the raw cost;
refines the result by an edge-aware weighted median and fills the unconfident pixels for
``depth_filled_m`` (:mod:`lfring.depth.refine`). With the left-right check (``consistency``) it
estimates the map again from the view farthest from the reference and makes unknown the pixels
whose two answers disagree.
"""

from __future__ import annotations

import dataclasses
import functools
import warnings

import numpy as np

from lfring.core.threads import numba_threads
from lfring.depth.aggregation import box_mean_of_finite, least_over_windows
from lfring.depth.costs.lcn_halves import take_halves, view_halves
from lfring.depth.engines.base import DepthEngine
from lfring.depth.engines.fused import fused_index, fused_shifts
from lfring.depth.engines.gpu import run_semiglobal_gpu
from lfring.depth.plan import JUDGED_MIN_PLANES, baseline_axis, guide_image, other_reference
from lfring.depth.refine import fill_from_farther_side, refine_index
from lfring.depth.sgm import P1_SCALE, P2_SCALE, cost_scale, select, sgm_aggregate, sgm_aggregate_torch
from lfring.depth.sweep import run_sweep
from lfring.errors import LfringWarning

__all__ = ["CONSISTENCY_STEPS", "SEMIGLOBAL", "SEMIGLOBAL_REFERENCE", "SGM_AGGREGATE_PX", "SGM_MIN_PLANES", "SUBPIXEL_BOX_PX", "SWEEP_SHARE",
           "run_semiglobal", "semiglobal_index"]

# The box over which the 'lcn' cost is aggregated before the semi-global optimisation (which does
# the rest of the smoothing); 'local' aggregates over LCN_AGGREGATE_PX.
SGM_AGGREGATE_PX = 5
# The box of the cost the sub-hypothesis parabola is fitted to after the optimisation.
SUBPIXEL_BOX_PX = 15
# The semi-global method judges each answer against the hypotheses more than one step of view
# motion away (its confidence), as every method does (the sweep plan's rule).
SGM_MIN_PLANES = JUDGED_MIN_PLANES
# Two reference frames agree when their hypotheses differ by at most this many times the
# smallest distinguishable step (one pixel of view motion).
CONSISTENCY_STEPS = 1
# The share of the semi-global method's time that the sweep into the volume takes (for progress).
SWEEP_SHARE = 0.3


def run_semiglobal(views, calibration, plan, settings, finisher, progress, *, fused: bool = True) -> dict:
    """Optimise, select and refine (see the module's docstring); the finisher gets the depth and
    confidence, the returned fields the hole-filled map, the paths and whether the check ran.
    With ``fused`` the cost volume and its optimisation take the 16-bit passes of
    :mod:`lfring.depth.engines.fused` wherever they apply; without, the float32 reference."""
    check = views.shape[0] == 2 if settings.consistency is None else bool(settings.consistency)
    if settings.backend == "torch" and fused:  # the GPU engine; None where its kernels cannot run on the device
        out = run_semiglobal_gpu(views, calibration, plan, settings, finisher, progress, consistency=check,
                                 subpixel_box_px=SUBPIXEL_BOX_PX, consistency_steps=CONSISTENCY_STEPS)
        if out is not None:
            return out
    with numba_threads(settings.threads):  # every compiled kernel of the method, not only the optimisation's
        filled = _optimise(views, calibration, plan, settings, finisher, consistency=check, report=progress, fused=fused)
    progress.done()
    return dict(depth_filled_m=filled, paths=settings.paths, consistency=check)


def _consistent(calibration, plan, index, other_plan, other_index, tolerance: float) -> np.ndarray:
    """(h, w) bool: pixels whose depth, seen from the other reference frame at that depth, is
    the depth found there (to ``tolerance`` hypotheses): the left-right check of stereo."""
    h, w = index.shape
    n = len(plan.depths)
    # H_other_from_ref(Z_i) through view 0: H_other_from_0 @ H_0_from_ref.
    maps = other_plan.hs[:, 0] @ np.linalg.inv(plan.hs[:, 0])  # (N, 3, 3)
    ok = np.isfinite(index)
    i = np.clip(np.rint(np.where(ok, index, 0)), 0, n - 1).astype(np.intp)
    m = maps[i]  # (h, w, 3, 3)
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    den = m[..., 2, 0] * xs + m[..., 2, 1] * ys + m[..., 2, 2]
    x2 = (m[..., 0, 0] * xs + m[..., 0, 1] * ys + m[..., 0, 2]) / den
    y2 = (m[..., 1, 0] * xs + m[..., 1, 1] * ys + m[..., 1, 2]) / den
    xi, yi = np.rint(x2).astype(np.intp), np.rint(y2).astype(np.intp)
    inside = ok & (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
    there = other_index[np.clip(yi, 0, h - 1), np.clip(xi, 0, w - 1)]
    with np.errstate(invalid="ignore"):
        return inside & (np.abs(there - index) <= tolerance)


def _index(views, calibration, plan, settings, report, start, end, fused):
    """:func:`semiglobal_index`, by the fused 16-bit passes where they apply and ``fused``."""
    if fused:
        out = fused_index(views, calibration, plan, settings, SUBPIXEL_BOX_PX,
                          on_stage=lambda fraction: report.at(start + (end - start) * fraction))
        if out is not None:
            return out
    return semiglobal_index(views, calibration, plan, settings, report, start, end)


def _optimise(views, calibration, plan, settings, fin, consistency=True, report=None, fused=True):
    """The 'sgm' method: fill the cost volume, optimise it, select and refine; with
    ``consistency``, the same from a second reference frame, and pixels whose two answers
    disagree become unknown. The finisher gets the depth and confidence; the hole-filled depth
    is returned."""
    share = 0.5 if consistency else 1.0  # of the work, per reference frame
    index, confidence, nviews, guide = _index(views, calibration, plan, settings, report, 0.0, share, fused)
    if consistency:
        other = dataclasses.replace(plan, reference=other_reference(plan))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LfringWarning)
            other = dataclasses.replace(other, hs=calibration.homographies(plan.depths, reference=other.reference))
        other_index = _index(views, calibration, other, settings, report, share, 1.0, fused)[0]
        keep = _consistent(calibration, plan, index, other, other_index, CONSISTENCY_STEPS * plan.exclude)
        confidence = np.where(keep, confidence, np.float32(0.0))
    refined, filled = refine_index(index, confidence, guide)
    if consistency:
        # The pixels the check rejects are mostly occlusions (background the other view cannot
        # see): the filled map takes the farther side along the baseline there, the smoother's
        # interpolation elsewhere, which spread the nearer surface over the occluded background:
        # fewer bad pixels in depth_filled_m on real stereo pairs, and no more on the twin's pairs.
        behind = fill_from_farther_side(refined, ~keep, axis=baseline_axis(plan, other.reference))
        filled = np.where(~keep & np.isfinite(behind), behind, filled).astype(np.float32)
    return fin.refined_maps(refined, index, filled, confidence, nviews, fallback_index=not consistency)


def semiglobal_index(views, calibration, plan, settings, report=None, start=0.0, end=1.0):
    """Fractional hypothesis index, confidence, views seen and guide of one reference frame: the
    float32 reference of the method (``report`` advanced from ``start`` to ``end``: the sweep
    about a third, the optimisation the rest)."""
    h, w = views.shape[1:3]
    volume = np.empty((len(plan.depths), h, w), np.float32)
    swept = start + (end - start) * SWEEP_SHARE
    on_rows = None if report is None else report.rows(start, swept)
    # 'lcn-halves': the halves' volume beside it (only while the sweep runs; none for a pair).
    halves = np.empty_like(volume) if settings.cost.halves and view_halves(plan.hs, (h, w)) else None
    nviews = run_sweep(views, calibration, plan, settings, volume=volume, halves=halves, on_rows=on_rows)
    # The penalties follow the cost of all views: the halves' lower minima at the pixels they
    # take would otherwise raise the scale and smooth every surface more.
    scale = cost_scale(volume)
    penalties = dict(p1=P1_SCALE * scale, p2=P2_SCALE * scale)
    if halves is not None:
        take_halves(volume, halves)
    # The optimisation sees the least cost of the boxes that contain each pixel (shiftable
    # windows), in the halves' buffer when there is one; the sub-hypothesis parabola and the
    # raw distinctness keep the centred box's cost, whose curve is not flattened by the minimum.
    # Shiftable windows measured as few or fewer bad pixels than centred ones on real stereo pairs
    # and on every twin scene, four views and pairs; the parabola and distinctness on the shiftable
    # cost as well made the textured pixels' depth less precise.
    shifted = least_over_windows(volume, settings.aggregate_px, out=halves, threads=settings.threads)
    del halves
    guide = guide_image(views, plan, settings.threads)
    if settings.backend == "torch":
        optimised = sgm_aggregate_torch(shifted, guide=guide, paths=settings.paths, device=settings.device, **penalties)
    else:
        optimised = sgm_aggregate(shifted, guide=guide, paths=settings.paths, threads=settings.threads, **penalties)
    del shifted
    if report is not None:
        report.at(start + (end - start) * (SWEEP_SHARE + 1.0) / 2.0)
    # The sub-hypothesis parabola is fitted to the cost aggregated over the local method's wider
    # box (over the seen pixels, as every aggregation): the optimised curve is flat-bottomed in P1
    # steps and the small box's is noisy.
    scratch = np.empty((h, w), np.float32)
    for slice_ in volume:
        box_mean_of_finite(slice_, SUBPIXEL_BOX_PX, scratch)
    # The optimised curve is distinct wherever the neighbours decided, textured or not; its
    # distinctness times the local curve's ranks errors better than either (sparsification, on the
    # twin and on a real stereo pair).
    index, confidence = select(optimised, raw=volume, exclude=plan.exclude, threads=settings.threads, raw_distinctness=True)
    if report is not None:
        report.at(end)
    return index, confidence, nviews, guide


# Host memory per pixel and hypothesis: the fused passes' volume and paths' sums, uint16 each (more
# kept between their passes where they fit KEEP_VOLUMES_BYTES); the float32 passes' three volumes
# (the cost, its eroded copy, the optimised one), which 'sgm' runs where the fused passes do not
# serve the call.
FUSED_CELL_BYTES = 4
FLOAT32_CELL_BYTES = 12


def _sgm_cell_bytes(calibration, plan, settings, view_shape) -> int:
    served = fused_shifts(calibration, plan, settings, view_shape) is not None
    return FUSED_CELL_BYTES if served else FLOAT32_CELL_BYTES


SEMIGLOBAL = DepthEngine(
    name="sgm",
    summary="the whole cost volume optimised semi-globally along scan lines, in 16-bit fused passes (default)",
    run=run_semiglobal,
    default_cost="lcn-halves",
    lcn_aggregate_px=SGM_AGGREGATE_PX,
    whole_volume=True,
    options=frozenset({"paths", "consistency"}),
    cell_bytes=FUSED_CELL_BYTES,
    call_cell_bytes=_sgm_cell_bytes,
    device_frames=True,
)

SEMIGLOBAL_REFERENCE = DepthEngine(
    name="sgm-reference",
    summary="the semi-global method computed plainly in float32 over whole volumes: the reference of 'sgm'",
    run=functools.partial(run_semiglobal, fused=False),
    default_cost="lcn-halves",
    lcn_aggregate_px=SGM_AGGREGATE_PX,
    whole_volume=True,
    options=frozenset({"paths", "consistency"}),
    cell_bytes=FLOAT32_CELL_BYTES,
)
