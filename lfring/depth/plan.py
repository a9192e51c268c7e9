"""Planning a plane sweep: the hypotheses, the homographies into the reference frame, the
views' masks, the settings every stage of the sweep reads, and the progress reports.

:func:`plan_sweep` turns a depth range into a :class:`SweepPlan`; :class:`DepthSettings` holds the
checked options of :func:`lfring.estimate_depth`; the engines (:mod:`lfring.depth.engines`) read
both and never see the raw arguments.
"""

from __future__ import annotations

import math
import threading
import warnings
from dataclasses import dataclass

import numpy as np

from lfring.core.filters import luminance
from lfring.core.geometry import check_reference
from lfring.core.threads import run_threads
from lfring.core.viewstack import WEIGHT_FLOOR, cached_view_masks, calibration_cache
from lfring.core.warping import warp_image
from lfring.calibration.model import view_motion_px
from lfring.depth.hypotheses import check_depth_range, depth_hypotheses
from lfring.errors import DepthRangeError, InvalidInputError, LfringWarning

__all__ = ["DEPTH_TAPER", "GUIDE_WHITE_PERCENTILE", "JUDGED_MIN_PLANES", "MAX_PLANES_PER_PX", "MIN_RANGE_MOTION_PX", "NUMPY_INTERPOLATION_MATCHED",
           "DepthSettings", "Progress", "SweepPlan", "baseline_axis", "depths_key", "guide_image", "high_percentile",
           "in_reference_frame", "other_reference", "plan_sweep", "sweep_masks"]

# Fraction of a view's disc radius over which its weight rises from 0 to 1 in the sweep
# (lfring.core.viewstack.view_masks). The refocusing taper (lfring.core.viewstack.TAPER, 15 %) hides seams in an image;
# in the sweep it counted a view that sees a pixel as a fraction of a view over the outer 15 % of
# its disc, so pixels two views see came out unseen (min_views) and their costs were weighted
# down. This narrower taper measured fewer bad pixels on the twin's scenes, four views and pairs
# (benchmarks/RESULTS.md, "Depth on real data"). At 3 % and below the darkest, noisiest rim pixels
# of the inspection sample (data/synthetic/part_good.png) made a confident false dent at the bottom
# of the frame.
DEPTH_TAPER = 0.05
#: A depth range across which the views move by this much (px) or less holds no depth to tell
#: from another: every method refuses it.
MIN_RANGE_MOTION_PX = 1.0
#: Every method judges each answer against the hypotheses more than a pixel of view motion away
#: from it (its confidence): it needs at least this many, however far apart.
JUDGED_MIN_PLANES = 3
#: Hypotheses closer than 1/MAX_PLANES_PER_PX px of view motion tell nothing apart that the
#: sub-hypothesis refinement does not: a num_planes that asks for more is refused (a typo in
#: it otherwise ran for hours or ran out of memory).
MAX_PLANES_PER_PX = 8
#: The guide image's white: its values' percentile that maps to 1 (a few brighter highlights clip).
GUIDE_WHITE_PERCENTILE = 99.5
# high_percentile's sample of the values, from which it picks the threshold above which it looks,
# the sample's share above the threshold as a multiple of the share needed, and a few ranks more.
PERCENTILE_SAMPLE = 1 << 13
PERCENTILE_MARGIN = 2.0
PERCENTILE_MARGIN_RANKS = 16
# The arrays (at least this many values) and percentiles (from this one up) that high_percentile
# answers itself; NumPy answers the others.
PERCENTILE_MIN_VALUES = 4 * PERCENTILE_SAMPLE
PERCENTILE_MIN_Q = 90.0
# Whether this NumPy interpolates a percentile as high_percentile repeats it: a Python float
# weight from a float64 rank, in the values' type. NumPy 2.0 to 2.3 work float32 values' rank in
# float32; 1.26 and 2.4 were checked to match.
_NUMPY = np.lib.NumpyVersion(np.__version__)
NUMPY_INTERPOLATION_MATCHED = "1.26.0" <= _NUMPY < "2.0.0" or _NUMPY >= "2.4.0"


def sweep_masks(calibration, view_shape, taper: float = DEPTH_TAPER) -> np.ndarray:
    """(V, h, w) float32 weight of every view pixel in the sweep: :func:`lfring.core.viewstack.view_masks`
    with the rim ``taper`` (by default :data:`DEPTH_TAPER`), made once per calibration, view
    shape and taper (read-only)."""
    return cached_view_masks(calibration, view_shape, taper=taper)


@dataclass(frozen=True)
class DepthSettings:
    """The checked options of one depth estimation (see :func:`lfring.estimate_depth`)."""

    cost: object  # the lfring.depth.costs.DepthCost entry
    aggregation: str  # 'box' or 'guided'
    window_px: int  # odd window of the cost's normalisation or correlation
    aggregate_px: int  # odd window of the aggregation
    min_views: int
    threads: int
    backend: str  # 'numpy' or 'torch'
    device: object  # the torch device asked for, or None
    paths: int  # scan paths of the semi-global engine
    consistency: bool | None  # the left-right check (None: the engine's default)


@dataclass(frozen=True)
class SweepPlan:
    """What a sweep needs besides the views: hypotheses, homographies, masks and spacing."""

    depths: np.ndarray  # (N,) metres
    hs: np.ndarray  # (N, V, 3, 3) H_ref_from_view
    masks: np.ndarray  # (V, h, w)
    reference: object
    step_px: float  # largest view motion between neighbouring hypotheses
    exclude: int  # the second minimum is looked for more than this many hypotheses away
    taper: float  # rim taper of the masks (sweep_masks)
    calibration: object  # what the plan was made from: the key of what is cached for it


def depths_key(depths_m) -> tuple:
    """A hashable key of a list of depths for the caches kept with a calibration (rounded to
    1e-12 m, so that depths computed twice the same way share their entries)."""
    return tuple(np.round(np.asarray(depths_m, np.float64), 12))


def _planes_needed(motion_px: float) -> int:
    """The fewest hypotheses spread over ``motion_px`` (more than a pixel) of view motion among
    which every one has others more than a pixel away (as the plan spaces them and counts its
    ``exclude``)."""
    n = JUDGED_MIN_PLANES
    while n < max(JUDGED_MIN_PLANES, math.ceil((n - 1) / motion_px) + 2):
        n += 1
    return n


def _exclude(step_px: float) -> int:
    """Hypotheses within a pixel of view motion of the best, at ``step_px`` apart: the second
    minimum is looked for beyond them."""
    return max(1, int(np.ceil(1.0 / max(step_px, 1e-6))))


def plan_sweep(views, calibration, zmin_m, zmax_m, num_planes, reference, taper) -> SweepPlan:
    """The :class:`SweepPlan` of views (V, h, w, C) over ``zmin_m``..``zmax_m``.

    Every method judges an answer against the hypotheses more than a pixel of view motion from
    it: with ``num_planes`` None the plan takes as many as that needs (the default spacing, a
    pixel apart at most, leaves none over a range of a few pixels); a ``num_planes`` that leaves
    none, or a range that holds no pixel of motion, is refused
    (:class:`lfring.errors.DepthRangeError`)."""
    ref = check_reference(reference, calibration.num_views)
    shape = views.shape[1:3]
    if num_planes is not None:
        check_depth_range(zmin_m, zmax_m)
        span = view_motion_px(calibration, [zmin_m, zmax_m], shape) if zmin_m > calibration.depth_origin_m else 0.0
        most = max(JUDGED_MIN_PLANES, int(math.ceil(MAX_PLANES_PER_PX * span)) + 1)
        if span > MIN_RANGE_MOTION_PX and num_planes > most:
            raise InvalidInputError(
                f"num_planes {num_planes} puts the hypotheses closer than 1/{MAX_PLANES_PER_PX:g} px of view motion over "
                f"{zmin_m:g}..{zmax_m:g} m ({span:.3g} px), where no cost tells them apart (the refinement finds the "
                f"depths between them): give at most {most}")
    depths = depth_hypotheses(calibration, zmin_m, zmax_m, num=num_planes)

    def motion_step(depths):  # the same for every frame
        key = ("view motion", depths_key(depths), tuple(shape))
        return calibration_cache(calibration, key, lambda: view_motion_px(calibration, depths, shape))

    step = motion_step(depths)
    motion = step * (len(depths) - 1)  # the hypotheses are evenly spaced in view motion
    zmin, zmax = float(depths[0]), float(depths[-1])
    # Both refused before the out-of-range warning: the hint says more.
    if motion <= MIN_RANGE_MOTION_PX:
        raise DepthRangeError(
            f"zmin_m {zmin:g} .. zmax_m {zmax:g} m: the views move by {motion:.2g} px across it, too little to tell "
            "any depth in it from another; widen it", zmin_m=zmin, zmax_m=zmax, planes=len(depths), motion_px=motion,
            planes_needed=None, hint=calibration.millimetres_hint(zmin, zmax))
    if len(depths) < max(JUDGED_MIN_PLANES, _exclude(step) + 2):
        need = _planes_needed(motion)
        if num_planes is not None:
            raise DepthRangeError(
                f"each depth is judged against hypotheses more than one pixel of view motion away: {len(depths)} "
                f"hypotheses over {motion:.2g} px of motion ({zmin:g}..{zmax:g} m) have none; give num_planes >= {need} "
                "or widen the depth range", zmin_m=zmin, zmax_m=zmax, planes=len(depths), motion_px=motion,
                planes_needed=need, hint=calibration.millimetres_hint(zmin, zmax))
        depths = depth_hypotheses(calibration, zmin_m, zmax_m, num=need)
        step = motion_step(depths)
    calibration.check_depth(np.array([zmin_m, zmax_m]))  # warns once if outside the calibrated range
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)
        hs = calibration.homographies(depths, reference=ref)  # (N, V, 3, 3)
    return SweepPlan(depths, hs, sweep_masks(calibration, shape, taper), ref, step, _exclude(step), taper, calibration)


class Progress:
    """Serialises ``progress(fraction)`` calls from the sweep's threads; rows done map onto a
    span of the fraction."""

    def __init__(self, callback, height: int):
        self.callback, self.height = callback, height
        self.lock = threading.Lock()

    def at(self, fraction: float) -> None:
        """Report ``fraction`` of the work done (clamped to [0, 1])."""
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
        """Report the whole work done."""
        self.at(1.0)


def in_reference_frame(lum, plan, threads: int = 1) -> np.ndarray:
    """(h, w) float32 image of the reference frame from per-view images (V, h, w): the reference
    view's own, or for 'center' the views' weighted mean at the middle hypothesis (the views
    warped on ``threads`` threads, summed in their order)."""
    if plan.reference != "center":
        return lum[plan.reference]
    h, w = lum.shape[1:3]
    mid = len(plan.depths) // 2
    warped = np.empty(lum.shape, np.float32)

    def warp(k: int) -> None:  # float32 in, so that OpenCV writes into the given output
        warp_image(np.asarray(lum[k] * plan.masks[k], np.float32), plan.hs[mid, k], (w, h), dst=warped[k])

    run_threads([lambda k=k: warp(k) for k in range(len(lum))], threads)
    acc = np.zeros((h, w), np.float32)
    for k in range(len(lum)):
        acc += warped[k]
    return acc / _reference_weight(plan, mid)


def _reference_weight(plan, mid: int) -> np.ndarray:
    """(h, w) float32: the views' masks warped into the reference frame at hypothesis ``mid``,
    summed and floored at WEIGHT_FLOOR; made once per calibration, masks and homographies."""
    h, w = plan.masks.shape[1:3]

    def make():
        wsum = np.zeros((h, w), np.float32)
        for k in range(len(plan.masks)):
            wsum += warp_image(plan.masks[k], plan.hs[mid, k], (w, h))
        out = np.maximum(wsum, WEIGHT_FLOOR)
        out.setflags(write=False)
        return out

    key = ("sweep reference weight", plan.masks.shape, plan.taper, np.ascontiguousarray(plan.hs[mid]).tobytes())
    return calibration_cache(plan.calibration, key, make)


def guide_image(views, plan, threads: int = 1) -> np.ndarray:
    """(h, w) float32 luminance of the reference frame in [0, 1] (for 'center', the views' mean
    at the middle hypothesis), for the edge-aware optimisation and refinement; the views shared
    among ``threads`` threads."""
    if plan.reference == "center":
        g = in_reference_frame(luminance(views, threads), plan, threads)
    else:  # the reference view's own: the others' luminance is not needed
        g = luminance(views[plan.reference:plan.reference + 1])[0]
    top = float(high_percentile(g, GUIDE_WHITE_PERCENTILE))
    return np.clip(g / max(top, 1e-6), 0, 1).astype(np.float32)


def high_percentile(values, q: float):
    """``np.percentile(values, q)`` (linear interpolation) for a high ``q``, the same value and
    type (the sign of a zero aside, which NumPy leaves to its partition's order): only the values
    above a threshold read off a sorted sample of them are partitioned, not all of them.

    A percentile near 100 lies among the few largest values. The threshold is taken where the
    sample has :data:`PERCENTILE_MARGIN` times their share above it, and a few ranks more. NumPy's
    own percentile answers when fewer than needed lie above it (a sample that missed them), for
    small, NaN-holding or non-float arrays, a ``q`` under :data:`PERCENTILE_MIN_Q` or not a Python
    number, and on NumPy versions that interpolate otherwise (:data:`NUMPY_INTERPOLATION_MATCHED`).

    Examples
    --------
    >>> import numpy as np
    >>> x = np.random.default_rng(0).random(100_000, dtype=np.float32)
    >>> bool(high_percentile(x, 99.5) == np.percentile(x, 99.5))
    True
    """
    a = np.asarray(values)
    flat = a.reshape(-1)
    n = flat.size
    virtual = (n - 1) * (q / 100.0)  # the interpolated rank, as NumPy's 'linear' method
    if not NUMPY_INTERPOLATION_MATCHED or type(q) not in (int, float) or a.dtype not in (np.float32, np.float64) \
            or n < PERCENTILE_MIN_VALUES or not PERCENTILE_MIN_Q <= q < 100.0 or not virtual < n - 1:
        return np.percentile(a, q)
    lo = int(math.floor(virtual))
    need = n - lo  # the values from rank lo up
    sample = np.sort(flat[::n // PERCENTILE_SAMPLE])
    m = sample.size
    threshold = sample[max(0, m - 1 - math.ceil(PERCENTILE_MARGIN * need * m / n) - PERCENTILE_MARGIN_RANKS)]
    top = flat[flat >= threshold]  # the (n - top.size) values below it come before every one of these
    if top.size < need or np.isnan(flat).any():
        return np.percentile(a, q)
    k = lo - (n - top.size)
    top.partition((k, k + 1))
    below, above = top[k], top[k + 1]
    # NumPy's interpolation, in the values' type with a Python float weight.
    t = float(virtual - lo)
    diff = above - below
    return above - diff * (1 - t) if t >= 0.5 else below + diff * t


def other_reference(plan) -> int:
    """The view whose viewpoint lies farthest from the reference's (the largest baseline sees an
    occlusion from the other side): the second frame of the semi-global method's left-right
    check."""
    hs = plan.hs[len(plan.depths) // 2]
    centre = np.array([0.0, 0.0, 1.0])
    moved = [np.hypot(*(p[:2] / p[2])) for p in (np.linalg.inv(hk) @ centre for hk in hs)]
    return int(np.argmax(moved))


def baseline_axis(plan, view: int) -> int:
    """1 when ``view`` moves the reference's pixels mostly along rows as the depth changes (a
    horizontal baseline), 0 when mostly along columns."""
    h, w = plan.masks.shape[1:3]
    centre = np.array([w / 2.0, h / 2.0, 1.0])
    near, far = plan.hs[0, view] @ centre, plan.hs[-1, view] @ centre
    dx, dy = far[:2] / far[2] - near[:2] / near[2]
    return 1 if abs(dx) >= abs(dy) else 0
