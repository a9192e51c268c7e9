"""The semi-global method with 16-bit costs in fused passes (:mod:`lfring.depth.engines.fused_volume`,
:mod:`lfring.depth.engines.fused_paths`).

The same method as the float32 reference (:func:`lfring.depth.engines.semiglobal.semiglobal_index`):
the 'lcn' cost of all views and of the halves aggregated over a box, the halves taken where no
depth suits all views, the shiftable windows, four scan paths with edge-aware penalties, the
winner, its parabola on the wider box of the cost and the two distinctness measures. What differs
is how it is computed: the views are shifted in row strips (every homography a translation, after
at most a fixed near-identity resampling of each view), the volume is held once, in 16-bit
integers, and the erosion, the paths, the wider box and the selection run in passes that read it
row by row or column block by column block, so memory traffic is a few passes over a 16-bit
volume and every thread has independent work. Beside it are the paths' sums and, up to a size
(:data:`ERODED_VOLUME_BYTES`), the eroded volume, which the horizontal paths make and the vertical
ones read.

:func:`fused_index` answers None where it does not apply (another backend, cost or aggregation,
eight paths, or homographies that are not translations up to a fixed resampling); the engine then
runs the reference.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from lfring.core.filters import luminance
from lfring.core.memory import fresh_zeros
from lfring.core.threads import run_threads
from lfring.core.viewstack import WEIGHT_FLOOR, cached_view_masks, calibration_cache
from lfring.core.warping import TRANSLATION_TOL_PX
from lfring.depth.costs.lcn_halves import (HALVES_GAIN, HALVES_MEDIAN_SAMPLE, HALVES_MIN_SUPPORT, halves_poor,
                                           view_halves)
from lfring.depth.costs.lcn_occlusion import OCCLUSION_PENALTY
from lfring.depth.plan import depths_key, guide_image
from lfring.depth.sgm import EDGE_SCALE, P1_SCALE, P2_SCALE

__all__ = ["ERODED_VOLUME_BYTES", "KEEP_VOLUMES_BYTES", "RESAMPLE_TOL_PX", "UNITS_PER_SCALE", "fused_index", "fused_shifts",
           "shift_plan"]

# Integer steps per unit of the cost's scale (the small penalty P1 is one scale unit): fine
# enough that rounding moves no decision of the paths, coarse enough that four paths of the
# clipped cost plus the large penalty fit in 16 bits.
UNITS_PER_SCALE = 64
# A view is resampled once by a fixed near-identity map, so that every hypothesis is a pure shift,
# when what is left over after that is within this many pixels everywhere in the frame.
RESAMPLE_TOL_PX = 0.01
# Rows of a strip of the sweep (per parallel task), and the fewest columns of a block of the
# vertical paths (one block per thread, a tile of the paths' sums: fused_paths).
STRIP_ROWS = 16
MIN_COLUMN_BLOCK = 32
# Rows sampled for a first estimate of the cost's scale (which sets the integer unit).
SCALE_SAMPLE_ROWS = 16
# The call's two 16-bit volumes (the costs and the horizontal paths' sums) are kept with the
# calibration for its next call, when together they take at most this many bytes: fresh memory
# costs a page fault per page on its first write (the kernel zeroes it; on a virtual machine the
# host may have to back it too), which on large frames was a large and erratic part of a call.
KEEP_VOLUMES_BYTES = 512 << 20
# The horizontal paths keep the eroded volume for the vertical ones (which would otherwise erode
# every row again in each of their two directions) when it takes at most this many bytes: a third
# 16-bit volume, left out on the largest volumes so that a call's peak memory stays near two, and
# small enough that the three are kept for the next call (judged on the tiles' size, which is at
# least the cost volume's: the three then fit in KEEP_VOLUMES_BYTES).
ERODED_VOLUME_BYTES = KEEP_VOLUMES_BYTES // 3
# The eroded volume's stand-in where it is not kept.
_NOT_KEPT = np.empty((0, 0, 0, 0), np.uint16)


def _all_valid(masks) -> bool:
    return bool(np.all(masks == 1.0))


def _apply(H, pts):
    q = pts @ H[:2, :2].T + H[:2, 2]
    return q / (pts @ H[2, :2] + H[2, 2])[:, None]


def shift_plan(hs, view_shape):
    """Per view, a fixed resampling and per hypothesis a shift such that sampling the resampled
    view at ``x + shift`` is sampling the view where ``H_ref_from_view(Z)^-1`` puts ``x``, to
    within :data:`RESAMPLE_TOL_PX` over the frame; None where no such factoring exists.

    Returns
    -------
    shifts : (N, V, 2) float64
        (sx, sy) per hypothesis and view.
    remaps : list of V (map_x, map_y) float32 pairs or None
        The resampling of each view (None where it is the identity).
    """
    hs = np.asarray(hs, np.float64)
    n, v = hs.shape[:2]
    h, w = view_shape
    ys, xs = np.mgrid[0:h:max(1, (h - 1) // 8), 0:w:max(1, (w - 1) // 8)]
    grid = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float64)
    grid = np.vstack([grid, [[w - 1, 0], [0, h - 1], [w - 1, h - 1]]])
    centre = np.array([[(w - 1) / 2.0, (h - 1) / 2.0]])
    inv = np.linalg.inv(hs)  # reference -> view
    mid = n // 2
    shifts = np.empty((n, v, 2))
    remaps = []
    for k in range(v):
        s_mid = _apply(inv[mid, k], centre)[0] - centre[0]
        # The resampling P(u) = S_mid(u - s_mid): the identity wherever S_mid is a translation.
        t = np.array([[1.0, 0.0, -s_mid[0]], [0.0, 1.0, -s_mid[1]], [0.0, 0.0, 1.0]])
        p = inv[mid, k] @ t
        p_inv = np.linalg.inv(p)
        moved = np.abs(_apply(p, grid) - grid).max()
        for i in range(n):
            # The shift that puts the frame's centre where the hypothesis samples it.
            shifts[i, k] = _apply(p_inv, _apply(inv[i, k], centre))[0] - centre[0]
            err = np.abs(_apply(p, grid + shifts[i, k]) - _apply(inv[i, k], grid)).max()
            if err > RESAMPLE_TOL_PX:
                return None
        if moved <= TRANSLATION_TOL_PX:
            remaps.append(None)
            continue
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
        pts = np.stack([xx.ravel(), yy.ravel()], axis=1)
        q = _apply(p, pts).astype(np.float32)
        remaps.append((q[:, 0].reshape(h, w), q[:, 1].reshape(h, w)))
    return shifts, remaps


def _edges(shifts: np.ndarray, n: int) -> np.ndarray:
    """(..., n) float32 weight of a zero-padded line of ones sampled at ``x + shift`` (bilinear),
    for every shift of ``shifts``."""
    shifts = np.asarray(shifts, np.float64)[..., None]
    i = np.floor(shifts)
    f = shifts - i
    pos = np.arange(n) + i
    return (np.where((pos >= 0) & (pos < n), 1.0 - f, 0.0) +
            np.where((pos + 1 >= 0) & (pos + 1 < n), f, 0.0)).astype(np.float32)


def _padded(images, remaps, pad, scale=None, threads: int = 1):
    """(V, h + 2 pad + 1, w + 2 pad + 1) float32: each image (times its ``scale`` image, where
    given) resampled (where it has a map) and zero-padded; one view per task on ``threads``."""
    v, h, w = images.shape
    out = np.zeros((v, h + 2 * pad + 1, w + 2 * pad + 1), np.float32)

    def one(k: int) -> None:
        inside = out[k, pad:pad + h, pad:pad + w]
        if remaps[k] is None and scale is not None and images.dtype == scale.dtype == np.float32:
            # The product written in place, no temporary (OpenCV writes into a given output of
            # its inputs' type only, and would otherwise return a new array).
            cv2.multiply(images[k], scale[k], dst=inside)
            return
        img = images[k] if scale is None else images[k] * scale[k]
        if remaps[k] is not None:
            img = cv2.remap(img, remaps[k][0], remaps[k][1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        inside[...] = img

    run_threads([lambda k=k: one(k) for k in range(v)], threads)
    return out


def _runs_of_ones(masks):
    """Per view and row of the padded masks (V, H, W), the run [lo, hi) of columns where the mask
    is exactly 1 (a disc's inside, one run per row), lo = hi where there is none: there the
    weights need no interpolation."""
    v, hh, ww = masks.shape
    lo = np.zeros((v, hh), np.int64)
    hi = np.zeros((v, hh), np.int64)
    rows = np.arange(hh)
    for k in range(v):
        one = masks[k] == 1.0
        has = one.any(axis=1)
        first = np.where(has, np.argmax(one, axis=1), 0)
        last = np.where(has, ww - np.argmax(one[:, ::-1], axis=1), 0)
        # Only where the ones form one run: every column between the first and the last is one.
        count = np.cumsum(one, axis=1)
        before = np.where(first > 0, count[rows, np.maximum(first - 1, 0)], 0)
        run = has & (count[rows, np.maximum(last - 1, 0)] - before == last - first)
        lo[k] = np.where(run, first, 0)
        hi[k] = np.where(run, last, 0)
    return lo, hi


def fused_shifts(calibration, plan, settings, view_shape):
    """The shift plan (:func:`shift_plan`, made once per calibration, hypotheses and view size)
    of a call that the fused passes serve, or None where they do not: the NumPy backend, an
    'lcn' cost of all views, box aggregation, 4 paths, and views that every hypothesis moves by
    a shift (after a fixed resampling)."""
    cost = settings.cost
    if (settings.backend != "numpy" or not cost.lcn or cost.leave_one_out or settings.aggregation != "box"
            or settings.paths != 4):
        return None
    h, w = view_shape
    return calibration_cache(calibration, _plan_key(plan, (h, w)), lambda: shift_plan(plan.hs, (h, w)))


def _plan_key(plan, view_shape) -> tuple:
    """The calibration cache's key of a shift plan, and the prefix of what is made from it."""
    return ("fused_shift_plan", plan.reference, depths_key(plan.depths), tuple(view_shape))


def fused_index(views, calibration, plan, settings, subpixel_box_px: int, on_stage=None):
    """Fractional hypothesis index, confidence, views seen and guide of one reference frame, as
    :func:`lfring.depth.engines.semiglobal.semiglobal_index` defines them (the parabola fitted to
    the cost's mean over ``subpixel_box_px`` boxes), or None where the fused passes do not apply.
    ``on_stage(fraction)``, when given, is called as the passes finish (for progress reports)."""
    stage = on_stage if on_stage is not None else (lambda fraction: None)
    cost = settings.cost
    h, w = views.shape[1:3]
    planned = fused_shifts(calibration, plan, settings, (h, w))
    if planned is None:
        return None
    from lfring.depth.engines import fused_paths, fused_volume
    from lfring.depth.engines.fused_common import PENALTY_MAX

    plan_key = _plan_key(plan, (h, w))
    shifts, remaps = planned
    n, v = shifts.shape[:2]
    masks = plan.masks
    # The 'lcn' sources and the guide both start from the views' luminance: made once, it is
    # their views (of one channel, which luminance passes through unchanged).
    gray = luminance(views, settings.threads)[..., None]
    src = cost.sources(gray, calibration, plan, settings.window_px, settings.threads)
    pad = int(math.ceil(np.abs(shifts).max(initial=0.0))) + 2
    weighted = _padded(src, remaps, pad, scale=masks, threads=settings.threads)
    all_valid = cached_view_masks(calibration, (h, w), "all_valid", _all_valid, taper=plan.taper) and \
        all(r is None for r in remaps)
    def padded_masks():
        m = _padded(np.asarray(masks, np.float32), remaps, pad)
        return m, *_runs_of_ones(m)

    if all_valid:  # runs of ones: those of the edge weights, below
        mpad = weighted
    else:  # the masks resampled and padded, and their runs of ones: the same for every frame
        mpad, ones_lo, ones_hi = calibration_cache(calibration, (plan_key, "masks", plan.taper, pad), padded_masks)
    iy = np.floor(shifts[..., 1]).astype(np.int64)
    ix = np.floor(shifts[..., 0]).astype(np.int64)
    fy = (shifts[..., 1] - iy).astype(np.float32)
    fx = (shifts[..., 0] - ix).astype(np.float32)
    if all_valid:  # the same for every frame; the runs of ones per hypothesis and view (N, V)
        edge_y, edge_x = calibration_cache(calibration, (plan_key, "edges"),
                                           lambda: (_edges(shifts[..., 1], h), _edges(shifts[..., 0], w)))
        ones_lo, ones_hi = calibration_cache(calibration, (plan_key, "edge runs"), lambda: _runs_of_ones(edge_x))
    else:
        edge_y = np.zeros((1, 1, 1), np.float32)
        edge_x = np.zeros((1, 1, 1), np.float32)
    views_idx = np.arange(v, dtype=np.int64)
    halves = view_halves(plan.hs, (h, w)) if cost.halves else []
    flat = np.array([k for half in halves for k in half], np.int64)
    ptr = np.cumsum([0] + [len(half) for half in halves]).astype(np.int64)
    rad = settings.aggregate_px // 2
    floor = np.float32(WEIGHT_FLOOR)
    geometry = (weighted, mpad, all_valid, edge_y, edge_x, iy, ix, fy, fx, pad, ones_lo, ones_hi, views_idx)

    # A first estimate of the cost's scale, on a few rows: the unit of the integer costs.
    rows = np.unique(np.linspace(0, h - 1, min(h, SCALE_SAMPLE_ROWS)).astype(np.int64))
    stride = max(1, w // 256)
    ncol = (w + stride - 1) // stride
    sample_best = np.empty((len(rows), ncol), np.float32)
    sample_spread = np.empty((len(rows), ncol), np.float32)
    fused_volume.sample_costs(*geometry, rows, stride, rad, floor, sample_best, sample_spread)
    spread = sample_spread[np.isfinite(sample_spread)]
    first = float(np.median(spread)) if spread.size else 1.0
    unit = (first if first > 0 and math.isfinite(first) else 1.0) / UNITS_PER_SCALE

    # As few blocks as threads: every block pays a fixed cost per row and hypothesis.
    block = max(MIN_COLUMN_BLOCK, -(-w // max(1, settings.threads)))
    tiles = fused_paths.tile_shape(h, n, w, block)
    vol, paths, *kept = _volumes(calibration, (h, n, w), tiles, eroded=2 * math.prod(tiles) <= ERODED_VOLUME_BYTES)
    eroded = kept[0] if kept else _NOT_KEPT
    best = np.empty((h, w), np.float32)
    total = np.empty((h, w), np.float32)
    count = np.empty((h, w), np.float32)
    nviews = np.empty((h, w), np.float32)
    fused_volume.sweep_volume(*geometry, rad, STRIP_ROWS, floor, np.float32(unit), vol, best, total, count, nviews)
    stage(0.35)
    # The penalties follow the cost of all views, before the halves are taken, as in the reference.
    scale = _scale(best, total, count)
    if halves:
        stride = max(1, int(np.ceil(np.sqrt(h * w / HALVES_MEDIAN_SAMPLE))))
        sample = best[::stride, ::stride]
        sample = sample[np.isfinite(sample)]
        if sample.size:
            poor = halves_poor(best, float(np.median(sample)))
            fused_volume.sweep_halves(*geometry, flat, ptr, rad, STRIP_ROWS, floor, np.float32(OCCLUSION_PENALTY),
                            np.float32(HALVES_MIN_SUPPORT), np.float32(HALVES_GAIN), np.float32(unit), poor, best, vol)
    p1 = int(round(min(P1_SCALE * scale / unit, PENALTY_MAX)))
    p2 = int(round(min(max(P2_SCALE * scale / unit, p1), PENALTY_MAX)))
    guide = guide_image(gray, plan, settings.threads)
    erode = settings.aggregate_px // 2
    stage(0.5)
    fused_paths.horizontal_paths(vol, guide, True, p1, p2, np.float32(EDGE_SCALE), erode, paths, eroded)
    stage(0.7)
    index = np.empty((h, w), np.float32)
    confidence = np.empty((h, w), np.float32)
    fused_paths.vertical_paths(vol, eroded, paths, guide, True, p1, p2, np.float32(EDGE_SCALE), erode,
                               subpixel_box_px // 2, int(plan.exclude), WEIGHT_FLOOR, index, confidence)
    _keep_volumes(calibration, (vol, paths, *kept))
    stage(1.0)
    return index, confidence, nviews, guide


def _volumes(calibration, shape, tiles, eroded: bool) -> tuple:
    """The uint16 volumes for one call: the costs' of ``shape``, the paths' sums in ``tiles``
    (:func:`lfring.depth.engines.fused_paths.tile_shape`) and with ``eroded`` the eroded
    volume's in the same tiles: those the calibration's last call left
    (:data:`KEEP_VOLUMES_BYTES`) when they match, else new ones. A call takes them out of the
    cache, so calls running at once never share them."""
    kept = calibration_cache(calibration, "fused volumes", list)
    try:
        vols = kept.pop()
    except IndexError:
        vols = None
    shapes = (tuple(shape), tuple(tiles), tuple(tiles))[:3 if eroded else 2]
    if vols is not None and tuple(v.shape for v in vols) == shapes:
        return vols
    return tuple(fresh_zeros(s, np.uint16) for s in shapes)  # written before they are read


def _keep_volumes(calibration, vols) -> None:
    if sum(v.nbytes for v in vols) <= KEEP_VOLUMES_BYTES:
        kept = calibration_cache(calibration, "fused volumes", list)
        kept.clear()
        kept.append(vols)


def _scale(best, total, count) -> float:
    """:func:`lfring.depth.sgm.cost_scale` from each pixel's least cost and the sum and number of
    its finite costs: the median over a grid of pixels with two or more finite costs of their mean
    minus their least."""
    h, w = best.shape
    stride = max(1, int(math.ceil(math.sqrt(h * w / (1 << 14)))))
    b, t, c = (a[::stride, ::stride] for a in (best, total, count))
    ok = c >= 2
    if not ok.any():
        return 1.0
    scale = float(np.median(t[ok].astype(np.float64) / c[ok] - b[ok]))
    return scale if scale > 0 and math.isfinite(scale) else 1.0
