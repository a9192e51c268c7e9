"""Plane-sweep depth over the views (SPEC 6): the entry point, which checks the arguments, plans
the sweep and runs it.

For every hypothesis Z (evenly spaced in 1/(Z - z0), at most one pixel of view motion apart by
default; :mod:`lfring.depth.hypotheses`) every view is warped into the reference frame with
H_ref_from_view(Z), the warped views are compared with their consensus
(:mod:`lfring.depth.costs`), the cost is aggregated spatially, and each pixel keeps its best
hypothesis and the costs of its neighbours (:mod:`lfring.depth.selection`). A parabola through
those three costs gives the sub-hypothesis depth; the cost curve's distinctness gives the
confidence. The default cost ('lcn' with box aggregation) runs strip by strip on several threads
(:func:`lfring.depth.stream.sweep_strips`); the others a whole slice at a time
(:func:`lfring.depth.stream.sweep_slices`) or with the torch backend.
"""

from __future__ import annotations

import dataclasses
import threading
import warnings
from dataclasses import dataclass

import cv2
import numpy as np

from lfring.depth.costs import (AGGREGATIONS, COSTS, DEPTH_TAPER, GUIDED_EPS, LCN_AGGREGATE_PX, box_mean_of_finite,
                                check_odd_px, lcn_sources, least_over_windows, sweep_masks, take_halves, view_halves)
from lfring.depth.refine import fill_from_farther_side, refine_index
from lfring.depth.sgm import P1_SCALE, P2_SCALE, check_paths, cost_scale, select, sgm_aggregate
from lfring.core.threads import numba_threads
from lfring.depth.hypotheses import depth_hypotheses, view_motion_px
from lfring.depth.selection import DepthResult, Finisher
from lfring.depth.stream import sweep_slices, sweep_strips
from lfring.errors import InvalidInputError, LfringWarning
from lfring.core.geometry import check_reference
from lfring.core.viewstack import WEIGHT_FLOOR, check_views
from lfring.core.validate import check_threads
from lfring.core.filters import luminance, normalised_luminance
from lfring.core.warping import warp_image

__all__ = ["AGGREGATIONS", "COSTS", "METHODS", "SGM_MIN_PLANES", "DepthResult", "estimate_depth"]

METHODS = ("sgm", "local")
# The costs that compare the views' locally normalised luminances (lcn_sources), in strips.
LCN_COSTS = ("lcn", "lcn-halves", "lcn-occlusion")
# The default cost of each method: 'lcn-halves' needs the whole cost volume ('sgm').
DEFAULT_COSTS = {"sgm": "lcn-halves", "local": "lcn"}
# The box over which the 'lcn' cost is aggregated before the semi-global optimisation (which does
# the rest of the smoothing); 'local' aggregates over LCN_AGGREGATE_PX.
SGM_AGGREGATE_PX = 5
# The box of the cost the sub-hypothesis parabola is fitted to after the optimisation.
SUBPIXEL_BOX_PX = 15
# The semi-global method judges each answer against the hypotheses more than one step of view
# motion away (its confidence): it needs at least this many, however far apart.
SGM_MIN_PLANES = 3
# Two reference frames agree when their hypotheses differ by at most this many times the
# smallest distinguishable step (one pixel of view motion).
CONSISTENCY_STEPS = 1


def _optional_count(name: str, value, least: int, meaning: str) -> None:
    if value is not None and (isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < least):
        raise InvalidInputError(f"{name} must be an integer >= {least}{meaning}, got {value!r}")


def estimate_depth(
    views,
    calibration,
    *,
    zmin_m: float,
    zmax_m: float,
    num_planes: int | None = None,
    reference="center",
    backend: str = "numpy",
    device=None,
    cost: str | None = None,
    aggregation: str = "box",
    window_px: int = 9,
    aggregate_px: int | None = None,
    min_views: int = 2,
    rim_taper: float = DEPTH_TAPER,
    threads: int | None = None,
    method: str = "sgm",
    paths: int = 4,
    consistency: bool | None = None,
    progress=None,
) -> DepthResult:
    """Metric depth and confidence by plane sweep over the views.

    Parameters
    ----------
    views : (V, h, w, C) float32 in [0, 1]
        Cut with the calibration's layout (:func:`lfring.split_views`).
    calibration : RingCalibration
    zmin_m, zmax_m : float
        Depth range in metres from the main lens; zmin_m must lie beyond z0.
    num_planes : int, optional
        Number of hypotheses, evenly spaced in 1/(Z - z0). By default just enough that no view
        pixel moves more than one pixel between neighbours (``step_px`` reports it).
    reference : 'center' or int
        Frame of the depth map.
    backend : {'numpy', 'torch'}, device : str, optional
        The torch backend runs the same algorithm with kornia (GPU-ready).
    cost : {'lcn', 'lcn-halves', 'lcn-occlusion', 'zncc', 'sad', 'ssd', 'sad-occlusion'}, optional
        Photo-consistency; by default 'lcn-halves' for 'sgm' and 'lcn' for 'local'. 'lcn': the
        variance across views of their luminances normalised by the local mean and contrast over
        ``window_px`` (normalised once per view, before the sweep: the fastest, and blind to each
        view's vignetting; see :mod:`lfring.depth.costs`). 'lcn-halves' ('sgm' only): the same,
        and where no depth suits all views but the views on one side of the reference agree much
        better (a depth edge hides the background from the views on the other side), that side's
        cost (:func:`lfring.depth.costs.take_halves`; from three views on, otherwise 'lcn'): on
        the twin's hard scene 8.8 % of the pixels two views see are off by more than 1 px
        against 10.0 % for 'lcn', for -5 to +30 % time on the twin's scenes (the benchmarks' runs
        differ that much) and 70 % more at 1060 x 1060 x 64 planes with the 'center' reference's
        four halves (``benchmarks/RESULTS.md``).
        'lcn-occlusion': over each aggregation window, the least of the 'lcn' cost and the costs
        without one view (from three views on; :func:`lfring.depth.costs.occlusion_aggregate`).
        The others compare the warped luminances divided by their wide local mean: absolute or
        squared deviation from their mean, one minus their mean zero-normalised
        cross-correlation with the mean over ``window_px``, or the absolute deviation without
        the view deviating most per pixel.
    aggregation : {'box', 'guided'}
        Spatial aggregation of each cost slice over ``aggregate_px``: a box, or an edge-aware
        guided filter (guide: the reference view, or for 'center' the views' mean refocused at
        the middle hypothesis).
    window_px : int
        Odd window of the normalisation ('lcn') or of the correlation ('zncc').
    aggregate_px : int, optional
        Odd window of the aggregation: by default, for the 'lcn' costs, SGM_AGGREGATE_PX (5) with
        'sgm' (the optimisation does the rest of the smoothing) and LCN_AGGREGATE_PX (15) with
        'local'; ``window_px`` for the other costs.
    min_views : int
        From 1 to the number of views: pixels seen by fewer views get NaN.
    rim_taper : float
        Fraction of each view's disc radius, in [0, 1], over which its weight rises from 0 to 1
        (:func:`lfring.core.viewstack.view_masks`); a view counts as the sum of its weights towards
        ``min_views``. The default (5 %, ``lfring.depth.costs.DEPTH_TAPER``) measures every pixel
        that two views see; the refocusing taper (``lfring.core.viewstack.TAPER``, 15 %) trusts the dark
        periphery of the discs less, as inspection does.
    threads : int, optional
        Threads of the sweep and of the optimisation; by default OpenCV's thread count.
    method : {'sgm', 'local'}
        'sgm' (default): the whole cost volume is optimised semi-globally (:mod:`lfring.depth.sgm`:
        along ``paths`` scan lines a penalty for every change of depth, lowered across image
        edges), which fills weak texture and keeps gross outliers away; it optimises the least
        cost of the aggregation boxes that contain each pixel (shiftable windows,
        :func:`lfring.depth.costs.least_over_windows`; with the guided aggregation, the least
        over the same neighbourhood), so a surface's texture does not spread its depth over the
        pixels beside it. It holds three (N, h, w) float32 volumes at once (the cost, its
        eroded copy and the optimised one: 1646 MiB at 1060 x 1060 x 128 hypotheses, a peak of
        1754 MiB measured). It needs hypotheses more than one pixel of view motion apart
        (``InvalidInputError`` otherwise). The result is refined by an
        edge-aware weighted median; ``DepthResult.depth_filled_m`` also fills the unconfident
        pixels (:mod:`lfring.depth.refine`). 'local': winner-take-all on the aggregated cost of
        each pixel alone, streamed (memory does not grow with the number of hypotheses): the
        fastest, and exact where the texture is good.
    paths : {4, 8}
        Scan paths of 'sgm' (the 'local' method refuses 8).
    consistency : bool, optional
        'sgm' only: estimate the map again from the view farthest from the reference and make
        unknown (NaN) the pixels whose two answers disagree by more than one pixel of motion:
        the left-right check of stereo, which finds the pixels the other view cannot see. With
        the check, the pixels whose confidence is below ``lfring.depth.refine.MIN_CONFIDENCE``
        are unknown too (without it they keep the optimisation's answer, which their scan lines
        gave them). It doubles the time. ``depth_filled_m`` fills the rejected pixels from the
        farther side along the baseline (they are mostly background hidden from the other view
        by a nearer surface). By default on for two views (a pixel occluded in the other view
        has no information at all) and off for more (a pixel hidden from one view is still
        measured by the others, and a single second frame would reject it).
    progress : callable, optional
        Called as ``progress(fraction)`` (0 to 1) as the work advances, possibly from worker
        threads (the calls are serialised): for a progress bar.

    Returns
    -------
    DepthResult

    Notes
    -----
    With c(i) the aggregated cost, i* = argmin c and a parabola through c(i*-1), c(i*), c(i*+1),
    the refined index is ``i* + (c(i*-1) - c(i*+1)) / (2 (c(i*-1) - 2 c(i*) + c(i*+1)))``; the
    depth follows from linear interpolation in 1/(Z - z0). The confidence is
    ``1 - c(i*) / c2`` with c2 the lowest cost more than one pixel of view motion from i*.

    Examples
    --------
    The bundled scene of the twin (data/synthetic, paths relative to the repository root): a
    cup at 0.3 m, a book at 0.5 m, a chessboard at 1 m. The fast 'local' method; the rows
    300:400, columns 450:550 of the centre frame lie on the book:

    >>> import numpy as np
    >>> import lfring
    >>> cal = lfring.RingCalibration.load("twin_binned2")
    >>> views = lfring.split_views(lfring.demosaic(lfring.load_raw("data/synthetic/scene.png")), cal.layout)
    >>> result = estimate_depth(views, cal, zmin_m=0.3, zmax_m=1.0, method="local")
    >>> result.depth_m.shape, result.depth_m.dtype
    ((705, 705), dtype('float32'))
    >>> round(float(np.nanmedian(result.depth_m[300:400, 450:550])), 2)  # the book, metres
    0.5
    """
    from lfring.core.backend import BACKENDS

    if backend not in BACKENDS:
        raise InvalidInputError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    if method not in METHODS:
        raise InvalidInputError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    if cost is None:
        cost = DEFAULT_COSTS[method]
    if cost not in COSTS:
        raise InvalidInputError(f"cost must be one of {', '.join(COSTS)}, got {cost!r}")
    if cost == "lcn-halves" and method != "sgm":
        raise InvalidInputError("cost 'lcn-halves' chooses per pixel over the whole cost volume: it needs method='sgm'")
    if aggregation not in AGGREGATIONS:
        raise InvalidInputError(f"aggregation must be one of {', '.join(AGGREGATIONS)}, got {aggregation!r}")
    paths = check_paths(paths)
    if consistency is not None and not isinstance(consistency, (bool, np.bool_)):
        raise InvalidInputError(f"consistency must be True, False or None (on for two views), got {consistency!r}")
    if method != "sgm" and (paths != 4 or consistency):
        raise InvalidInputError("paths and consistency belong to method='sgm'")
    check_odd_px("window_px", window_px)
    if aggregate_px is not None:
        check_odd_px("aggregate_px", aggregate_px)
    threads = check_threads(threads)
    _optional_count("num_planes", num_planes, 2, " (or None for the default spacing)")
    if progress is not None and not callable(progress):
        raise InvalidInputError(f"progress must be a callable progress(fraction) or None, got {progress!r}")
    if not hasattr(calibration, "homographies") or not hasattr(calibration, "check_fits"):
        raise InvalidInputError(f"calibration must be a RingCalibration, got {type(calibration).__name__}")
    if isinstance(rim_taper, bool) or not isinstance(rim_taper, (int, float, np.integer, np.floating)) \
            or not 0.0 <= float(rim_taper) <= 1.0:
        raise InvalidInputError(f"rim_taper must be a fraction of the disc radius in [0, 1], got {rim_taper!r}")
    arr = check_views(views)
    calibration.check_fits(arr.shape)
    if isinstance(min_views, bool) or not isinstance(min_views, (int, np.integer)) or not 1 <= min_views <= arr.shape[0]:
        raise InvalidInputError(f"min_views must be an integer from 1 to the {arr.shape[0]} views, got {min_views!r}")
    if not np.all(np.isfinite(arr)):
        raise InvalidInputError("views contain NaN or infinite values")
    plan = _plan(arr, calibration, zmin_m, zmax_m, num_planes, reference, float(rim_taper))
    if aggregate_px is None:
        aggregate_px = (SGM_AGGREGATE_PX if method == "sgm" else LCN_AGGREGATE_PX) if cost in LCN_COSTS else window_px
    threads = max(1, cv2.getNumThreads()) if threads is None else threads
    if method == "sgm" and len(plan.depths) < max(SGM_MIN_PLANES, plan.exclude + 2):
        raise InvalidInputError(
            f"method='sgm' judges each answer against hypotheses more than one pixel of view motion away: "
            f"{len(plan.depths)} hypotheses over {plan.step_px * (len(plan.depths) - 1):.2g} px of motion "
            f"({zmin_m}..{zmax_m} m) have none; give num_planes >= {SGM_MIN_PLANES}, widen the depth range, "
            "or use method='local'")
    fin = Finisher(plan.depths, calibration.depth_origin_m, arr.shape[1:3], min_views)
    report = _Progress(progress, arr.shape[1])
    record = dict(depths_m=plan.depths, step_px=plan.step_px, reference=plan.reference, cost=cost, aggregation=aggregation,
                  method=method)
    if method == "sgm":
        check = arr.shape[0] == 2 if consistency is None else bool(consistency)
        with numba_threads(threads):  # every compiled kernel of the method, not only the optimisation's
            filled = _optimise(arr, calibration, plan, fin, backend, device, cost, aggregation, window_px, aggregate_px,
                               threads, paths, consistency=check, report=report)
        report.done()
        return fin.result(depth_filled_m=filled, paths=paths, consistency=check, **record)
    if cost in LCN_COSTS and aggregation == "box" and backend == "numpy":
        sweep_strips(lcn_sources(arr, calibration, window_px, threads=threads, taper=plan.taper), plan.masks, plan.hs,
                     aggregate_px=aggregate_px, exclude=plan.exclude, threads=threads, on_strip=fin,
                     occlusion=cost == "lcn-occlusion", on_rows=report.rows(0.0, 1.0))
    else:
        out = _sweep_whole(arr, calibration, plan, backend, device, cost, aggregation, window_px, aggregate_px, threads)
        fin(0, arr.shape[1], *out)
    report.done()
    return fin.result(**record)


@dataclass(frozen=True)
class _Plan:
    """What a sweep needs besides the views: hypotheses, homographies, masks and spacing."""

    depths: np.ndarray  # (N,) metres
    hs: np.ndarray  # (N, V, 3, 3) H_ref_from_view
    masks: np.ndarray  # (V, h, w)
    reference: object
    step_px: float  # largest view motion between neighbouring hypotheses
    exclude: int  # the second minimum is looked for more than this many hypotheses away
    taper: float  # rim taper of the masks (sweep_masks)


def _plan(views, calibration, zmin_m, zmax_m, num_planes, reference, taper) -> _Plan:
    ref = check_reference(reference, calibration.num_views)
    depths = depth_hypotheses(calibration, zmin_m, zmax_m, num=num_planes)
    calibration.check_depth(np.array([zmin_m, zmax_m]))  # warns once if outside the calibrated range
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)
        hs = calibration.homographies(depths, reference=ref)  # (N, V, 3, 3)
    shape = views.shape[1:3]
    step = view_motion_px(calibration, depths, shape)
    # The second minimum is looked for more than one pixel of motion away from the best.
    exclude = max(1, int(np.ceil(1.0 / max(step, 1e-6))))
    return _Plan(depths, hs, sweep_masks(calibration, shape, taper), ref, step, exclude, taper)


# The share of the semi-global method's time that the sweep into the volume takes (for progress).
SWEEP_SHARE = 0.3


class _Progress:
    """Serialises ``progress(fraction)`` calls from the sweep's threads; rows done map onto a
    span of the fraction."""

    def __init__(self, callback, height: int):
        self.callback, self.height = callback, height
        self.lock = threading.Lock()
        self.rows_done = 0

    def at(self, fraction: float) -> None:
        if self.callback is not None:
            with self.lock:
                self.callback(min(1.0, max(0.0, float(fraction))))

    def rows(self, start: float, end: float):
        """An ``on_rows`` callback for one sweep advancing the fraction from start to end."""
        if self.callback is None:
            return None
        counted = [0]

        def on_rows(r0, r1):
            with self.lock:
                counted[0] += r1 - r0
                self.callback(start + (end - start) * counted[0] / self.height)

        return on_rows

    def done(self) -> None:
        self.at(1.0)


def _in_reference_frame(lum, plan) -> np.ndarray:
    """(h, w) float32 image of the reference frame from per-view images (V, h, w): the reference
    view's own, or for 'center' the views' weighted mean at the middle hypothesis."""
    if plan.reference != "center":
        return lum[plan.reference]
    h, w = lum.shape[1:3]
    mid = len(plan.depths) // 2
    acc = np.zeros((h, w), np.float32)
    wsum = np.zeros((h, w), np.float32)
    for k in range(len(lum)):
        acc += warp_image(lum[k] * plan.masks[k], plan.hs[mid, k], (w, h))
        wsum += warp_image(plan.masks[k], plan.hs[mid, k], (w, h))
    return acc / np.maximum(wsum, WEIGHT_FLOOR)


def _guide(views, plan) -> np.ndarray:
    """(h, w) float32 luminance of the reference frame in [0, 1] (for 'center', the views' mean
    at the middle hypothesis), for the edge-aware optimisation and refinement."""
    if plan.reference == "center":
        g = _in_reference_frame(luminance(views), plan)
    else:  # the reference view's own: the others' luminance is not needed
        g = luminance(views[plan.reference:plan.reference + 1])[0]
    top = float(np.percentile(g, 99.5))
    return np.clip(g / max(top, 1e-6), 0, 1).astype(np.float32)


def _other_reference(plan) -> int:
    """The view whose viewpoint lies farthest from the reference's (the largest baseline sees an
    occlusion from the other side): the consistency check's second frame."""
    hs = plan.hs[len(plan.depths) // 2]
    centre = np.array([0.0, 0.0, 1.0])
    moved = [np.hypot(*(p[:2] / p[2])) for p in (np.linalg.inv(hk) @ centre for hk in hs)]
    return int(np.argmax(moved))


def _baseline_axis(plan, view: int) -> int:
    """1 when ``view`` moves the reference's pixels mostly along rows as the depth changes (a
    horizontal baseline), 0 when mostly along columns."""
    h, w = plan.masks.shape[1:3]
    centre = np.array([w / 2.0, h / 2.0, 1.0])
    near, far = plan.hs[0, view] @ centre, plan.hs[-1, view] @ centre
    dx, dy = far[:2] / far[2] - near[:2] / near[2]
    return 1 if abs(dx) >= abs(dy) else 0


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


def _optimise(views, calibration, plan, fin, backend, device, cost, aggregation, window_px, aggregate_px, threads, paths,
              consistency=True, report=None):
    """The 'sgm' method: fill the cost volume, optimise it, select and refine; with
    ``consistency``, the same from a second reference frame, and pixels whose two answers
    disagree become unknown. The finisher gets the depth and confidence; the hole-filled depth
    is returned."""
    h, w = views.shape[1:3]
    share = 0.5 if consistency else 1.0  # of the work, per reference frame
    index, confidence, nviews, guide = _sgm_index(views, calibration, plan, backend, device, cost, aggregation, window_px,
                                                  aggregate_px, threads, paths, report, 0.0, share)
    if consistency:
        other = dataclasses.replace(plan, reference=_other_reference(plan))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LfringWarning)
            other = dataclasses.replace(other, hs=calibration.homographies(plan.depths, reference=other.reference))
        other_index = _sgm_index(views, calibration, other, backend, device, cost, aggregation, window_px, aggregate_px,
                                 threads, paths, report, share, 1.0)[0]
        keep = _consistent(calibration, plan, index, other, other_index, CONSISTENCY_STEPS * plan.exclude)
        confidence = np.where(keep, confidence, np.float32(0.0))
    refined, filled = refine_index(index, confidence, guide)
    if consistency:
        # The pixels the check rejects are mostly occlusions (background the other view cannot
        # see): the filled map takes the farther side along the baseline there, the smoother's
        # interpolation elsewhere. Bad 1 px of depth_filled_m on Teddy / Cones 17.2 / 14.4 % ->
        # 14.0 / 12.2 %; the twin's pairs 4.6 / 10.5 / 10.6 % -> 4.2 / 10.5 / 10.5 %.
        behind = fill_from_farther_side(refined, ~keep, axis=_baseline_axis(plan, other.reference))
        filled = np.where(~keep & np.isfinite(behind), behind, filled).astype(np.float32)
    index = np.where(np.isfinite(refined), refined, np.nan if consistency else index).astype(np.float32)
    filled = np.where(np.isfinite(filled), filled, index).astype(np.float32)  # never unknown where index is known
    missing = np.where(np.isfinite(index), np.float32(0.0), np.float32(np.inf))
    fin.rows(0, h, np.nan_to_num(index), confidence, missing, nviews)
    return fin.depth_of(filled, nviews)


def _sgm_index(views, calibration, plan, backend, device, cost, aggregation, window_px, aggregate_px, threads, paths,
               report=None, start=0.0, end=1.0):
    """Fractional hypothesis index, confidence, views seen and guide of one reference frame
    (``report`` advanced from ``start`` to ``end``: the sweep about a third, the optimisation
    the rest)."""
    h, w = views.shape[1:3]
    volume = np.empty((len(plan.depths), h, w), np.float32)
    swept = start + (end - start) * SWEEP_SHARE
    on_rows = None if report is None else report.rows(start, swept)
    # 'lcn-halves': the halves' volume beside it (only while the sweep runs; none for a pair).
    halves = np.empty_like(volume) if cost == "lcn-halves" and view_halves(plan.hs, (h, w)) else None
    if cost in LCN_COSTS and aggregation == "box" and backend == "numpy":
        nviews = sweep_strips(lcn_sources(views, calibration, window_px, threads=threads, taper=plan.taper), plan.masks, plan.hs,
                              aggregate_px=aggregate_px, threads=threads, volume=volume, occlusion=cost == "lcn-occlusion",
                              on_rows=on_rows, halves=halves)
    else:
        nviews = _sweep_whole(views, calibration, plan, backend, device, cost, aggregation, window_px, aggregate_px,
                              threads, volume=volume, halves=halves)
    # The penalties follow the cost of all views: the halves' lower minima at the pixels they
    # take would otherwise raise the scale and smooth every surface more.
    scale = cost_scale(volume)
    penalties = dict(p1=P1_SCALE * scale, p2=P2_SCALE * scale)
    if halves is not None:
        take_halves(volume, halves)
    # The optimisation sees the least cost of the boxes that contain each pixel (shiftable
    # windows), in the halves' buffer when there is one; the sub-hypothesis parabola and the
    # raw distinctness keep the centred box's cost, whose curve is not flattened by the minimum.
    # Bad 1 px, centred -> shiftable: Teddy 14.1 -> 12.9 %, Cones 12.7 -> 11.6 %; twin, every
    # pixel two views see, 4 views and the pair 0-1: three-depth 5.8 -> 5.4 % and 5.0 -> 4.1 %,
    # hard 8.9 -> 8.8 % and 11.0 -> 11.0 %, hard-mirrored 10.9 -> 10.0 % and 11.0 -> 10.3 %.
    # Parabola and distinctness on the shiftable cost instead: three-depth textured median
    # relative error 0.38 -> 0.44 %.
    shifted = least_over_windows(volume, aggregate_px, out=halves, threads=threads)
    del halves
    guide = _guide(views, plan)
    if backend == "torch":
        from lfring.backends.torch_sgm import sgm_aggregate_torch

        optimised = sgm_aggregate_torch(shifted, guide=guide, paths=paths, device=device, **penalties)
    else:
        optimised = sgm_aggregate(shifted, guide=guide, paths=paths, threads=threads, **penalties)
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
    # distinctness times the local curve's ranks errors better than either (sparsification AUC
    # on the twin 0.156 against 0.157 and 0.225, on Teddy 0.588 against 0.644 and 0.713).
    index, confidence = select(optimised, raw=volume, exclude=plan.exclude, threads=threads, raw_distinctness=True)
    if report is not None:
        report.at(end)
    return index, confidence, nviews, guide


def _sweep_whole(views, calibration, plan, backend, device, cost, aggregation, window_px, aggregate_px, threads, volume=None,
                 halves=None):
    """The sweep for the other costs, the guided aggregation and the torch backend (a running
    minimum, or the whole ``volume``)."""
    h, w = views.shape[1:3]
    masks, hs = plan.masks, plan.hs
    lum = None
    if cost not in LCN_COSTS or aggregation == "guided":
        lum = normalised_luminance(views, masks, sigma=max(8.0, min(h, w) / 40.0))
    guide_image = None
    if aggregation == "guided":
        g = _in_reference_frame(lum, plan)
        guide_image = np.clip(g / max(float(g.max()), 1e-6), 0, 1).astype(np.float32)
    if cost in LCN_COSTS:  # the sweep compares the locally normalised luminances instead
        lum = lcn_sources(views, calibration, window_px, threads=threads, taper=plan.taper)
    if backend == "torch":
        from lfring.backends.torch_depth import sweep_torch

        return sweep_torch(lum, masks, hs, cost=cost, aggregation=aggregation, window_px=window_px,
                           aggregate_px=aggregate_px, guide=guide_image, exclude=plan.exclude, device=device, volume=volume,
                           halves=halves)
    guide = None if guide_image is None else cv2.ximgproc.createGuidedFilter(guide_image, aggregate_px // 2, GUIDED_EPS)
    return sweep_slices(lum, masks, hs, cost, window_px, guide, plan.exclude, aggregate_px, volume=volume, halves=halves)
