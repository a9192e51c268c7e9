"""The semi-global method on the GPU: the same method as the float32 reference
(:func:`lfring.depth.engines.semiglobal.semiglobal_index`), device-resident from the views to the
depth map, its passes fused into Triton kernels (:mod:`lfring.depth.engines.gpu_kernels`).

The views are uploaded once; the 'lcn' sources, the sweep (each view warped by its homography
inside the cost kernel), the cost's scale and penalties, the halves of 'lcn-halves', the shiftable
windows (an erosion), the scan paths (one program per block of lines, walking them with their
state on chip), the winner with its parabola and confidences (one pass), the left-right check,
the weighted median, the hole filling by the fast global smoother (a tridiagonal solve per row and
column) and the finisher's depth all run on the device, and the maps are copied to the host once.
Nothing needs OpenCV's contrib modules. The costs other than the 'lcn' family prepare their
sources on the host (as their records define them) and sweep on the device.

The kernels run compiled on CUDA devices, and through Triton's interpreter on the CPU in a process
without CUDA (for the tests; slow). Where they cannot run (no Triton, or a CPU device in a process
with CUDA) :func:`run_semiglobal_gpu` answers None and the engine runs the float32 reference with
its torch twins.

Memory: the cost volume, its eroded copy and the sum of the paths, (N, h, w) float32 each, at the
peak (during the sweep the volume and the halves' one), and chunks of hypotheses of at most
:data:`CHUNK_BYTES` of temporaries beside them.
"""

from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np

from lfring.core.backend import kernels_run_on, require_torch, resolve_device
from lfring.core.filters import BoxTorch, normalised_luminance
from lfring.core.transfer import device_masks, download_maps, inverse_maps, is_tensor, to_device
from lfring.core.viewstack import WEIGHT_FLOOR, calibration_cache
from lfring.depth.aggregation import GUIDED_EPS, GuidedTorch
from lfring.depth.costs.lcn import LCN_EPS, LCN_FLOOR, LCN_STATS_TAPER, window_weights
from lfring.depth.costs.lcn_halves import (HALVES_GAIN, HALVES_MEDIAN_SAMPLE, HALVES_MIN_SUPPORT, halves_poor,
                                           halves_least_torch, view_halves)
from lfring.depth.costs.lcn_occlusion import OCCLUSION_PENALTY, leavable_views, occlusion_aggregate_torch
from lfring.depth.plan import GUIDE_WHITE_PERCENTILE, baseline_axis, in_reference_frame, other_reference
from lfring.depth.refine import (FGS_ATTENUATION, FGS_ITERATIONS, FGS_LAMBDA, FGS_SIGMA, FILL_WEIGHT_FLOOR,
                                 MEDIAN_COARSE_BINS, MEDIAN_FINE_BINS, MEDIAN_RADIUS_PX, MEDIAN_SIGMA, MIN_CONFIDENCE)
from lfring.depth.selection import Finisher
from lfring.depth.sgm import EDGE_SCALE, P1_SCALE, P2_SCALE, PATHS
from lfring.errors import LfringWarning

__all__ = ["CHUNK_BYTES", "MAX_PLANES", "PATH_PROGRAMS", "SCALE_SAMPLE", "DeviceFinisher", "aggregate_device", "consistent_device", "cost_scale_device",
           "engine_runs_on", "fgs_device", "fill_from_farther_side_device", "finish_device", "guide_device", "index_device",
           "lcn_sources_device", "luminance_device", "refine_index_device", "run_semiglobal_gpu",
           "select_device", "semiglobal_device", "weighted_median_device"]

# Temporaries of the chunked passes (hypotheses at a time) stay under about this many bytes.
CHUNK_BYTES = 256 << 20
# The most hypotheses the kernels hold (their blocks keep a pixel's whole curve on chip).
MAX_PLANES = 1024
# Programs the path kernel aims at per scan direction (about the multiprocessors of a large GPU).
PATH_PROGRAMS = 128
# Pixels sampled for the cost's scale (lfring.depth.sgm.cost_scale's default).
SCALE_SAMPLE = 1 << 14
# The share of one reference frame's work that the sweep takes (for progress reports).
_SWEEP_SHARE = 0.3


def _kernels():
    from lfring.depth.engines import gpu_kernels

    return gpu_kernels


def _triton():
    from lfring.core import triton_kernels

    return triton_kernels


# -- sizes of the kernels' blocks ----------------------------------------------------------------
def _interpreted() -> bool:
    return _triton().INTERPRETED


def _pow2(n: int) -> int:
    return _triton().next_power_of_2(n)


def _pixel_block(hw: int) -> int:
    """Pixels per program of the per-pixel kernels: all of them interpreted (the interpreter's cost
    is per operation, not per element), a few warps' worth compiled."""
    return min(_pow2(hw), 1 << 20) if _interpreted() else 256


def _curve_block(n_pad: int, hw: int) -> int:
    """Pixels per program of the kernels that hold (n_pad, P) tiles of whole cost curves."""
    if _interpreted():
        return max(1, min(_pow2(hw), (1 << 22) // n_pad))
    return max(1, 4096 // n_pad)


def _cdiv(a: int, b: int) -> int:
    return -(-int(a) // int(b))


def _path_lines(n_lines: int, n_pad: int) -> int:
    """Lines per program of the path kernel: all of them interpreted; compiled, enough programs
    to spread over a large GPU's multiprocessors (the paths are latency-bound: a program's time is
    its steps, whatever its lines), at most 2048 state values per program (8 per thread)."""
    if _interpreted():
        return max(1, min(_pow2(n_lines), (1 << 22) // n_pad))
    most = max(1, min(32, 2048 // n_pad))
    return max(1, min(most, _pow2(max(1, n_lines // PATH_PROGRAMS + 1)) // 2))


def _warps(elements: int) -> int:
    return 1 if _interpreted() else max(1, min(8, elements // 256))


def _launch(kernel, grid, *args, num_warps=4, **constants):
    _triton().launch(kernel, grid, *args, num_warps=num_warps, **constants)


# -- device caches -------------------------------------------------------------------------------
def _cached(calibration, key, device, make):
    """A tensor on ``device`` made once per calibration, key and device from the array ``make()``."""
    return calibration_cache(calibration, ("gpu", key, str(device)), lambda: to_device(make(), device))


# -- small statistics without a host round trip ----------------------------------------------------
def _median(values, valid):
    """NumPy's median of ``values[valid]`` (1-D tensors) as a 0-d tensor on their device (NaN
    where none is valid): the mean of the two middle values of an even count."""
    torch = require_torch()
    count = valid.sum()
    ordered = torch.sort(torch.where(valid, values, torch.full_like(values, float("inf")))).values
    lo = ((count - 1).clamp_min(0) // 2)
    hi = (count // 2).clamp_max(values.numel() - 1)
    mid = (ordered[lo] + ordered[hi]) / 2
    return torch.where(count > 0, mid, torch.full_like(mid, float("nan")))


def _quantile(values, q: float):
    """NumPy's linear percentile ``q`` (in [0, 1]) of a 1-D tensor, as a 0-d tensor."""
    torch = require_torch()
    ordered = torch.sort(values).values
    pos = q * (values.numel() - 1)
    lo = int(math.floor(pos))
    hi = min(lo + 1, values.numel() - 1)
    frac = pos - lo
    return ordered[lo] + (ordered[hi] - ordered[lo]) * frac


def cost_scale_device(volume, max_pixels: int = SCALE_SAMPLE):
    """:func:`lfring.depth.sgm.cost_scale` of an (N, h, w) tensor, as a 0-d float64 tensor on its
    device (1.0 where there is no sample or the median is not positive)."""
    torch = require_torch()
    n, h, w = volume.shape
    stride = max(1, int(math.ceil(math.sqrt(h * w / max_pixels))))
    s = volume[:, ::stride, ::stride].reshape(n, -1)
    finite = torch.isfinite(s)
    count = finite.sum(dim=0)
    ok = count >= 2
    mean = torch.where(finite, s, 0.0).sum(dim=0).double() / count.clamp_min(1)
    low = torch.where(finite, s, float("inf")).amin(dim=0).double()
    med = _median(torch.where(ok, mean - low, 0.0), ok)
    return torch.where((med > 0) & torch.isfinite(med), med, torch.ones_like(med))


# -- the views -----------------------------------------------------------------------------------
def luminance_device(frames):
    """(..., V, h, w) float32 mean of the channels of (..., V, h, w, C) views, as
    :func:`lfring.core.filters.luminance`."""
    c = frames.shape[-1]
    if c == 1:
        return frames[..., 0]
    return (frames * np.float32(1.0 / c)).sum(dim=-1)


def lcn_sources_device(lum, masks, weights, window_px: int):
    """:func:`lfring.depth.costs.lcn.lcn_sources` of the luminances ``lum`` (V, h, w), with the
    views' masks for the statistics (:data:`~lfring.depth.costs.lcn.LCN_STATS_TAPER`) and their
    :func:`~lfring.depth.costs.lcn.window_weights`, on their device."""
    torch = require_torch()
    v, h, w = lum.shape
    box = BoxTorch(torch, (h, w), window_px, 1, lum.device)
    a = lum * masks
    mu = box(a[:, None])[:, 0] * weights
    s2 = box((a * lum)[:, None])[:, 0] * weights
    sq = mu * mu
    var = (s2 - sq).clamp_min(0.0)
    var = sq * LCN_EPS + var
    var = torch.sqrt(var + LCN_FLOOR)
    return (lum - mu) / var


def guide_device(lum, masks, hinv_mid, reference):
    """:func:`lfring.depth.plan.guide_image` from the views' luminances (V, h, w) on their device:
    the reference view's, or for 'center' the views' weighted mean warped by ``hinv_mid`` (V, 9,
    the middle hypothesis), divided by its percentile :data:`lfring.depth.plan.GUIDE_WHITE_PERCENTILE`
    and clipped to [0, 1]."""
    torch = require_torch()
    if reference == "center":
        v, h, w = lum.shape
        a = torch.empty((1, v, h, w), dtype=torch.float32, device=lum.device)
        wts = torch.empty_like(a)
        block = _pixel_block(h * w)
        _launch(_kernels().warp_kernel, (_cdiv(h * w, block), 1), (lum * masks).contiguous(), masks,
                hinv_mid.contiguous(), a, wts, v, h, w, 0, BLOCK=block, num_warps=_warps(block))
        acc, wsum = a[0, 0].clone(), wts[0, 0].clone()
        for k in range(1, v):
            acc += a[0, k]
            wsum += wts[0, k]
        g = acc / wsum.clamp_min(WEIGHT_FLOOR)
    else:
        g = lum[reference]
    top = _quantile(g.reshape(-1), GUIDE_WHITE_PERCENTILE / 100.0)
    return (g / top.clamp_min(1e-6)).clamp(0.0, 1.0).contiguous()




# -- the sweep -----------------------------------------------------------------------------------
def _box_ratio(num, den, k: int, out, mode: int, cols, *, scale: float = 1.0, min_support: float = 0.0) -> None:
    """The k x k box means of the (C, h, w) chunks ``num`` and ``den`` and what ``mode`` makes of
    them into ``out`` (:func:`lfring.depth.engines.gpu_kernels.box_ratio_kernel`), through the
    (2, >= C, h, w) scratch ``cols``."""
    c, h, w = num.shape
    kernels = _kernels()
    block = _pixel_block(h * w)
    grid = (_cdiv(h * w, block), c)
    col_num, col_den = cols[0, :c], cols[1, :c]
    _launch(kernels.box_columns_kernel, grid, num, den, col_num, col_den, h, w, FINITE=mode == kernels.BOX_FINITE, K=k,
            BLOCK=block, num_warps=_warps(block))
    _launch(kernels.box_ratio_kernel, grid, num, den, col_num, col_den, out, h, w, WEIGHT_FLOOR, float(scale),
            float(min_support), MODE=mode, K=k, BLOCK=block, num_warps=_warps(block))


def _chunk(per_hypothesis_bytes: int, n: int) -> int:
    return int(max(1, min(n, CHUNK_BYTES // max(per_hypothesis_bytes, 1))))


def _sweep_lcn(src, masks, hinv, halves, aggregate_px: int):
    """From the views' sources ``src`` and masks (V, h, w): the 'lcn' volume of all views aggregated over ``aggregate_px`` boxes of the seen pixels
    (inf where unseen), the halves' least candidate volume of 'lcn-halves' (None without halves;
    :func:`lfring.depth.costs.lcn_halves.halves_least_torch`) and the views that see each pixel."""
    torch = require_torch()
    v, h, w = src.shape
    n = hinv.shape[0]
    dev = src.device
    hw = h * w
    src = (src * masks).contiguous()  # each view warps premultiplied by its mask, and its mask beside it
    volume = torch.empty((n, h, w), dtype=torch.float32, device=dev)
    half_volume = torch.empty_like(volume) if halves else None
    nviews = torch.zeros((h, w), dtype=torch.float32, device=dev)
    chunk = _chunk(12 * hw * 4, n)
    cost = torch.empty((chunk, h, w), dtype=torch.float32, device=dev)
    seen = torch.empty_like(cost)
    cols = torch.empty((2, chunk, h, w), dtype=torch.float32, device=dev)
    block = _pixel_block(hw)
    grid = (_cdiv(hw, block),)
    kernel = _kernels().lcn_kernel
    everyone = (1 << v) - 1
    for d0 in range(0, n, chunk):
        c = min(chunk, n - d0)
        _launch(kernel, grid, src, masks, hinv, cost, seen, nviews, v, everyone, h, w, d0, c, WEIGHT_FLOOR,
                WRITE_NV=True, BLOCK=block, num_warps=_warps(block))
        _box_ratio(cost[:c], seen[:c], aggregate_px, volume[d0:d0 + c], _kernels().BOX_MEAN, cols)
        if not halves:
            continue
        least = half_volume[d0:d0 + c]
        least.fill_(float("inf"))
        for half in halves:
            members = sum(1 << k for k in half)
            _launch(kernel, grid, src, masks, hinv, cost, seen, nviews, v, members, h, w, d0, c, WEIGHT_FLOOR,
                    WRITE_NV=False, BLOCK=block, num_warps=_warps(block))
            _box_ratio(cost[:c], seen[:c], aggregate_px, least, _kernels().BOX_HALF, cols, scale=OCCLUSION_PENALTY,
                       min_support=HALVES_MIN_SUPPORT)
    return volume, half_volume, nviews


def _sweep_general(src, masks, hinv, plan, settings, guide, halves):
    """Any cost and aggregation (as :func:`lfring.depth.sweep.slices.sweep_slices_torch` computes
    them), every view warped by the warp kernel, chunks of hypotheses at a time; ``guide``: the
    guided aggregation's (h, w) float32 NumPy guide or None. Returns as :func:`_sweep_lcn`."""
    torch = require_torch()
    cost = settings.cost
    v, h, w = src.shape
    n = hinv.shape[0]
    dev = src.device
    hw = h * w
    box_cost = BoxTorch(torch, (h, w), settings.window_px, 1, dev)
    box_agg = box_cost if settings.aggregate_px == settings.window_px else BoxTorch(torch, (h, w), settings.aggregate_px,
                                                                                    1, dev)
    guided = GuidedTorch(torch, guide, settings.aggregate_px, GUIDED_EPS, dev) if settings.aggregation == "guided" else None
    leavable = leavable_views(plan.hs) if cost.leave_one_out else []
    volume = torch.empty((n, h, w), dtype=torch.float32, device=dev)
    half_volume = torch.empty_like(volume) if halves else None
    nviews = torch.zeros((h, w), dtype=torch.float32, device=dev)
    chunk = _chunk(24 * v * hw * 4, n)  # as the torch sweep: its worst cost's images per hypothesis
    block = _pixel_block(hw)
    src_m = (src * masks).contiguous()

    def plain(x):
        return guided(torch, x) if guided is not None else box_agg(x[:, None])[:, 0]

    for d0 in range(0, n, chunk):
        c = min(chunk, n - d0)
        lum_w = torch.empty((c, v, h, w), dtype=torch.float32, device=dev)
        wts = torch.empty_like(lum_w)
        _launch(_kernels().warp_kernel, (_cdiv(hw, block), c), src_m, masks, hinv, lum_w, wts, v, h, w, d0,
                BLOCK=block, num_warps=_warps(block))
        nv = wts.sum(dim=1)
        cst = cost.slice_cost_torch(torch, lum_w, wts, nv, box_cost)
        finite = (nv >= 1.5) & torch.isfinite(cst)
        support = plain(finite.to(cst.dtype)).clamp_min(WEIGHT_FLOOR)

        def aggregate(x, finite=finite, support=support):
            return plain(torch.where(finite, x, 0.0)) / support

        agg = occlusion_aggregate_torch(torch, aggregate(cst), lum_w, wts, nv, leavable, plain, aggregate)
        if halves:
            half_volume[d0:d0 + c] = halves_least_torch(torch, lum_w, wts, nv, halves, plain)
        volume[d0:d0 + c] = torch.where(finite, agg, float("inf"))
        torch.maximum(nviews, nv.amax(dim=0), out=nviews)
    return volume, half_volume, nviews


def _take_halves(volume, half_volume) -> None:
    """:func:`lfring.depth.costs.lcn_halves.take_halves` in place on device tensors."""
    torch = require_torch()
    n, h, w = volume.shape
    best = volume.amin(dim=0)
    half_best = half_volume.amin(dim=0)
    stride = max(1, int(np.ceil(np.sqrt(h * w / HALVES_MEDIAN_SAMPLE))))
    sample = best[::stride, ::stride].reshape(-1)
    median = _median(sample, torch.isfinite(sample)).to(torch.float32)
    take = halves_poor(best, median) & (half_best < HALVES_GAIN * best)
    half_volume.masked_fill_(~take, float("inf"))
    torch.minimum(volume, half_volume, out=volume)


def _erode(volume, box_px: int):
    """:func:`lfring.depth.aggregation.least_over_windows` of a device volume (a new tensor)."""
    torch = require_torch()
    n, h, w = volume.shape
    side = min(int(box_px), 2 * max(h, w) + 1)
    out = torch.empty_like(volume)
    if side == 1:
        out.copy_(volume)
        return out
    chunk = _chunk(3 * h * w * 4, n)
    for d0 in range(0, n, chunk):
        part = volume[d0:d0 + chunk]
        out[d0:d0 + chunk] = -torch.nn.functional.max_pool2d(-part[:, None], side, stride=1, padding=side // 2)[:, 0]
    return out


def _box_mean_of_finite(volume, box_px: int) -> None:
    """:func:`lfring.depth.aggregation.box_mean_of_finite` of every slice of a device volume, in
    place."""
    torch = require_torch()
    n, h, w = volume.shape
    chunk = _chunk(8 * h * w * 4, n)
    cols = torch.empty((2, min(chunk, n), h, w), dtype=torch.float32, device=volume.device)
    for d0 in range(0, n, chunk):
        part = volume[d0:d0 + chunk]
        _box_ratio(part, part, box_px, part, _kernels().BOX_FINITE, cols)


def _fill_unknown(volume) -> None:
    """Each pixel's unknown costs replaced by the mean of its known ones, in place."""
    n, h, w = volume.shape
    n_pad = _pow2(n)
    p = _curve_block(n_pad, h * w)
    _launch(_kernels().fill_kernel, (_cdiv(h * w, p),), volume, n, h * w, N_PAD=n_pad, P=p,
            num_warps=_warps(n_pad * p))


# -- the semi-global optimisation ----------------------------------------------------------------
def _penalty_maps(guide, p1, p2, directions, edge_scale):
    """Per scan direction (dy, dx), each pixel's large-jump penalty towards its predecessor
    (y - dy, x - dx): ``max(p1, p2 / (1 + |I - I_prev| / edge_scale))`` in float32, as the numba
    kernels compute it; p2 where there is no predecessor or no guide."""
    torch = require_torch()
    out = []
    for dy, dx in directions:
        h, w = guide.shape
        pen = p2.expand(h, w).clone()
        if edge_scale is not None:
            ys = slice(max(dy, 0), h + min(dy, 0))
            xs = slice(max(dx, 0), w + min(dx, 0))
            yp = slice(max(-dy, 0), h + min(-dy, 0))
            xp = slice(max(-dx, 0), w + min(-dx, 0))
            step = torch.abs(guide[ys, xs] - guide[yp, xp]) / np.float32(edge_scale)
            pen[ys, xs] = torch.maximum(p1, p2 / (1.0 + step))
        out.append(pen.contiguous())
    return out


def aggregate_device(cost, guide, p1, p2, *, paths: int = 4, edge_scale: float | None = EDGE_SCALE):
    """:func:`lfring.depth.sgm.sgm_aggregate` of an (N, h, w) float32 device tensor (non-finite
    costs are replaced in place by their pixel's mean known cost), by the path kernel: one launch
    per scan direction, each program walking a block of lines. ``p1``, ``p2``: penalties (floats
    or 0-d tensors); ``guide``: (h, w) float32 on the device, or None."""
    torch = require_torch()
    n, h, w = cost.shape
    dev = cost.device
    p1 = torch.as_tensor(p1, dtype=torch.float32, device=dev).reshape(())
    p2 = torch.maximum(torch.as_tensor(p2, dtype=torch.float32, device=dev).reshape(()), p1)
    _fill_unknown(cost)
    directions = PATHS[paths]
    use_guide = guide is not None and edge_scale is not None
    g = guide if use_guide else torch.zeros((h, w), dtype=torch.float32, device=dev)
    pens = _penalty_maps(g, p1, p2, directions, edge_scale if use_guide else None)
    total = torch.empty_like(cost)
    n_pad = _pow2(n)
    p1_t = p1.reshape(1).contiguous()
    kernel = _kernels().path_kernel
    for i, ((dy, dx), pen) in enumerate(zip(directions, pens)):
        horizontal = dy == 0
        slope = dx * dy
        if horizontal:
            line0, n_lines, n_steps = 0, h, w
        elif slope == 0:
            line0, n_lines, n_steps = 0, w, h
        elif slope == 1:  # x = k + y
            line0, n_lines, n_steps = -(h - 1), w + h - 1, h
        else:  # x = k - y
            line0, n_lines, n_steps = 0, w + h - 1, h
        lines = _path_lines(n_lines, n_pad)
        programs = _cdiv(n_lines, lines)
        scratch = torch.empty(programs * n_pad * lines, dtype=torch.float32, device=dev)
        _launch(kernel, (programs,), cost, total, pen, p1_t, scratch, n, h, w, line0, n_lines, n_steps,
                HORIZONTAL=horizontal, REVERSE=(dx < 0) if horizontal else (dy < 0), SLOPE=0 if horizontal else slope,
                FIRST=i == 0, N_PAD=n_pad, LINES=lines, num_warps=_warps(n_pad * lines))
    return total


def select_device(total, raw, exclude: int):
    """:func:`lfring.depth.sgm.select` of ``total`` with ``raw`` and ``raw_distinctness``: the
    fractional index and the confidence, (h, w) float32 tensors, by the selection kernel."""
    torch = require_torch()
    n, h, w = total.shape
    index = torch.empty((h, w), dtype=torch.float32, device=total.device)
    conf = torch.empty_like(index)
    n_pad = _pow2(n)
    p = _curve_block(n_pad, h * w)
    _launch(_kernels().select_kernel, (_cdiv(h * w, p),), total, raw, index, conf, n, h * w, int(exclude),
            N_PAD=n_pad, P=p, num_warps=_warps(n_pad * p))
    return index, conf


def index_device(frame, lum, calibration, plan, settings, subpixel_box_px: int, report=None, start=0.0, end=1.0):
    """Fractional hypothesis index, confidence, views seen and guide ((h, w) device tensors) of
    one reference frame from its views ``frame`` (V, h, w, C) and luminances ``lum`` (V, h, w):
    :func:`lfring.depth.engines.semiglobal.semiglobal_index` on the device."""
    torch = require_torch()
    dev = frame.device
    v, h, w = lum.shape
    masks = device_masks(calibration, (h, w), dev, taper=plan.taper)
    hinv = inverse_maps(plan.hs, dev)
    cost = settings.cost
    if cost.lcn:
        weights = _cached(calibration, ("window_weights", (h, w), settings.window_px), dev,
                          lambda: window_weights(calibration, (h, w), settings.window_px))
        stats_masks = device_masks(calibration, (h, w), dev, taper=LCN_STATS_TAPER)
        src = lcn_sources_device(lum, stats_masks, weights, settings.window_px).contiguous()
    else:  # the sources as the cost's record makes them, on the host
        views = frame.cpu().numpy()
        src = to_device(cost.sources(views, calibration, plan, settings.window_px, settings.threads), dev)
    halves = view_halves(plan.hs, (h, w)) if cost.halves else []
    if cost.lcn and not cost.leave_one_out and settings.aggregation == "box":
        volume, half_volume, nviews = _sweep_lcn(src, masks, hinv, halves, settings.aggregate_px)
    else:
        guided = None
        if settings.aggregation == "guided":
            g = in_reference_frame(normalised_luminance(frame.cpu().numpy(), plan.masks), plan)
            guided = np.clip(g / max(float(g.max()), 1e-6), 0, 1).astype(np.float32)
        volume, half_volume, nviews = _sweep_general(src, masks, hinv, plan, settings, guided, halves)
    if report is not None:
        report.at(start + (end - start) * _SWEEP_SHARE)
    # The penalties follow the cost of all views, before the halves are taken (as the reference).
    scale = cost_scale_device(volume)
    p1 = (P1_SCALE * scale).to(torch.float32)
    p2 = (P2_SCALE * scale).to(torch.float32)
    if half_volume is not None:
        _take_halves(volume, half_volume)
    del half_volume
    eroded = _erode(volume, settings.aggregate_px)
    guide = guide_device(lum, masks, hinv[len(plan.depths) // 2], plan.reference)
    total = aggregate_device(eroded, guide, p1, p2, paths=settings.paths)
    del eroded
    if report is not None:
        report.at(start + (end - start) * (_SWEEP_SHARE + 1.0) / 2.0)
    _box_mean_of_finite(volume, subpixel_box_px)
    index, confidence = select_device(total, volume, plan.exclude)
    if report is not None:
        report.at(end)
    return index, confidence, nviews, guide


# -- the left-right check ------------------------------------------------------------------------
def consistent_device(plan, index, other_plan, other_index, tolerance: float):
    """(h, w) bool tensor: the pixels whose depth, seen from the other reference frame at that
    depth, is the depth found there (to ``tolerance`` hypotheses), as the reference engine's
    left-right check."""
    torch = require_torch()
    dev = index.device
    h, w = index.shape
    n = len(plan.depths)
    maps = other_plan.hs[:, 0] @ np.linalg.inv(plan.hs[:, 0])  # H_other_from_ref(Z_i), (N, 3, 3)
    m = torch.from_numpy(np.ascontiguousarray(maps.reshape(n, 9), np.float64)).to(dev)
    ok = torch.isfinite(index)
    i = torch.round(torch.where(ok, index, 0.0)).clamp(0, n - 1).long()
    ys = torch.arange(h, dtype=torch.float64, device=dev)[:, None].expand(h, w)
    xs = torch.arange(w, dtype=torch.float64, device=dev)[None, :].expand(h, w)

    def at(k):
        return m[:, k][i]

    den = at(6) * xs + at(7) * ys + at(8)
    x2 = (at(0) * xs + at(1) * ys + at(2)) / den
    y2 = (at(3) * xs + at(4) * ys + at(5)) / den
    xi = torch.round(x2).nan_to_num(-1.0).clamp(-1, w).long()
    yi = torch.round(y2).nan_to_num(-1.0).clamp(-1, h).long()
    inside = ok & (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
    there = other_index[yi.clamp(0, h - 1), xi.clamp(0, w - 1)]
    return inside & (torch.abs(there - index) <= tolerance)


# -- the refinement ------------------------------------------------------------------------------
def _guide8(guide):
    """The 8-bit guide of :mod:`lfring.depth.refine` from a float guide in [0, 1]."""
    torch = require_torch()
    return torch.clamp(torch.round(guide * 255.0), 0, 255).to(torch.uint8)


def weighted_median_device(values, known, guide8, radius_px: int = MEDIAN_RADIUS_PX, sigma: float = MEDIAN_SIGMA):
    """:func:`lfring.depth.refine.weighted_median` on device tensors ((h, w) float32 values, bool
    known, uint8 guide): the same bins (their range cut into units of one value, at most
    :data:`~lfring.depth.refine.MEDIAN_COARSE_BINS`, each in
    :data:`~lfring.depth.refine.MEDIAN_FINE_BINS`), weights and answer, by the median kernel."""
    torch = require_torch()
    h, w = values.shape
    dev = values.device
    v = values.contiguous()
    inf = torch.tensor(float("inf"), dtype=torch.float32, device=dev)
    lo = torch.where(known, v, inf).amin()
    hi = torch.where(known, v, -inf).amax()
    span = hi.double() - lo.double()
    coarse = torch.clamp(torch.ceil(span) + 1, max=MEDIAN_COARSE_BINS)
    fine_width = (torch.clamp(span / torch.clamp(coarse - 1, min=1), min=1e-6) / MEDIAN_FINE_BINS).to(torch.float32)
    fine = coarse * MEDIAN_FINE_BINS
    scaled = torch.floor((torch.where(known, v, lo) - lo) / fine_width)
    bins = torch.minimum(torch.clamp(torch.nan_to_num(scaled, nan=0.0), min=0).double(), fine - 1)
    bins = torch.where(known, bins.to(torch.int32), -1).contiguous()
    lut = np.exp(-np.arange(256, dtype=np.float64) ** 2 / (2.0 * max(float(sigma), 1e-6) ** 2))
    lut = torch.from_numpy(lut.astype(np.float32)).to(dev)
    side = 2 * int(radius_px) + 1
    out = torch.empty_like(v)
    p = min(_pow2(h * w), 8192) if _interpreted() else 32
    _launch(_kernels().median_kernel, (_cdiv(h * w, p),), v, bins, guide8.contiguous(), lut, out, h, w,
            RADIUS=int(radius_px), WIN=_pow2(side * side), P=p, num_warps=_warps(p * _pow2(side * side)))
    return out


def fgs_device(guide8, images, fill_lambda: float = FGS_LAMBDA, fill_sigma: float = FGS_SIGMA):
    """``cv2.ximgproc.createFastGlobalSmootherFilter(guide8, fill_lambda, fill_sigma).filter`` of
    each of the (I, h, w) float32 ``images`` (one or two), in place: per iteration a tridiagonal
    solve along every row, then every column (the fgs kernel), with the weights
    ``exp(-|I_p - I_q| / fill_sigma)`` between neighbours of the 8-bit guide."""
    torch = require_torch()
    count, h, w = images.shape
    dev = images.device
    g = guide8.to(torch.float32)
    sigma = np.float32(fill_sigma)

    def weight(a, b):  # OpenCV's table: -exp(-sqrt(d^2) / sigma) in float32
        d = a - b
        return -torch.exp(-torch.sqrt(d * d) / sigma)

    # Every buffer with a row of slack before and after it (the kernel loads a step ahead).
    across = torch.zeros((h + 2, w), dtype=torch.float32, device=dev)
    down = torch.zeros_like(across)
    across[1:-1, :-1] = weight(g[:, :-1], g[:, 1:])
    down[1:-2, :] = weight(g[:-1, :], g[1:, :])
    coef = torch.zeros_like(across)
    inter = torch.zeros_like(across)
    lanes = _pow2(count)
    x = torch.zeros((lanes, h + 2, w), dtype=torch.float32, device=dev)
    x[:count, 1:-1] = images
    kernel = _kernels().fgs_kernel
    lam = np.float32(fill_lambda)
    for _ in range(FGS_ITERATIONS):
        for weights, n_lines, n_steps, stride_line, stride_step, columns in ((across, h, w, w, 1, False),
                                                                               (down, w, h, 1, w, True)):
            torch.mul(weights, lam, out=coef)
            lines = _pow2(n_lines) if _interpreted() else 32
            _launch(kernel, (_cdiv(n_lines, lines),), coef[1:], x[:, 1:], inter[1:], n_lines, n_steps, stride_line,
                    stride_step, (h + 2) * w, IMAGES=lanes, COLUMNS=columns, LINES=lines, num_warps=_warps(lanes * lines))
        lam = np.float32(lam * np.float32(FGS_ATTENUATION))
    images.copy_(x[:count, 1:-1])
    return images


def refine_index_device(index, confidence, guide, *, min_confidence: float = MIN_CONFIDENCE):
    """:func:`lfring.depth.refine.refine_index` on device tensors ((h, w) float32 index and
    confidence, float guide in [0, 1]): the refined and the filled maps."""
    torch = require_torch()
    g8 = _guide8(guide)
    known = torch.isfinite(index) & torch.isfinite(confidence) & (confidence >= min_confidence)
    refined = weighted_median_device(index, known, g8)
    weight = torch.where(known, confidence.clamp_min(FILL_WEIGHT_FLOOR), 0.0)
    images = torch.stack([torch.where(known, refined, 0.0) * weight, weight]).contiguous()
    fgs_device(g8, images)
    num, den = images[0], images[1]
    interp = torch.where(den > FILL_WEIGHT_FLOOR, num / den, float("nan"))
    return refined, torch.where(known, refined, interp)


def fill_from_farther_side_device(index, holes, axis: int = 1):
    """:func:`lfring.depth.refine.fill_from_farther_side` on device tensors."""
    torch = require_torch()
    v, holes = (index, holes) if axis == 1 else (index.T, holes.T)
    h, w = v.shape
    known = torch.isfinite(v) & ~holes
    cols = torch.arange(w, device=v.device).expand(h, w)
    before = torch.cummax(torch.where(known, cols, -1), dim=1).values
    after = torch.cummin(torch.where(known, cols, w).flip(1), dim=1).values.flip(1)
    vb = torch.where(before >= 0, torch.gather(v, 1, before.clamp(0, w - 1)), float("-inf"))
    va = torch.where(after < w, torch.gather(v, 1, after.clamp(0, w - 1)), float("-inf"))
    far = torch.maximum(vb, va)
    out = torch.where(holes, torch.where(torch.isfinite(far), far, float("nan")), v)
    return out if axis == 1 else out.T.contiguous()


# -- the whole method ----------------------------------------------------------------------------
def _depth_of(finisher, idx):
    """The finisher's depth (metres, float32) of fractional indices, on their device."""
    torch = require_torch()
    if finisher.linear:
        inv_at = idx * np.float32(finisher.step) + np.float32(finisher.inv[0])
    else:  # np.interp over the hypotheses' inverse distances
        inv = torch.from_numpy(np.asarray(finisher.inv, np.float64)).to(idx.device)
        x = idx.double().clamp(0, finisher.n - 1)
        i0 = torch.floor(x).nan_to_num(0.0).long().clamp(0, max(finisher.n - 2, 0))
        i1 = (i0 + 1).clamp(max=finisher.n - 1)
        inv_at = (inv[i0] + (inv[i1] - inv[i0]) * (x - i0)).to(torch.float32)
        inv_at = torch.where(torch.isnan(idx), float("nan"), inv_at)
    return 1.0 / inv_at + np.float32(finisher.z0)


def finish_device(finisher, index, confidence, missing, nviews, filled):
    """What :meth:`lfring.depth.selection.Finisher.rows` and ``depth_of`` make of the method's
    maps, on their device: depth, confidence, index and filled depth ((h, w) float32)."""
    torch = require_torch()
    seen = nviews >= finisher.seen_views
    rows = seen & torch.isfinite(missing)
    nan = float("nan")
    depth = torch.where(rows, _depth_of(finisher, index), nan)
    conf = torch.where(rows, confidence, 0.0)
    idx = torch.where(rows, index, nan)
    filled_m = torch.where(seen, _depth_of(finisher, filled), nan)
    return depth, conf, idx, filled_m


def semiglobal_device(frame, calibration, plan, settings, finisher, progress, *, consistency: bool,
                      subpixel_box_px: int, consistency_steps: float):
    """The 'sgm' method on one frame's views (V, h, w, C) float32 on the device: its depth,
    confidence, index and filled depth ((h, w) tensors on the device; see :func:`finish_device`)."""
    torch = require_torch()
    with torch.no_grad():
        lum = luminance_device(frame).contiguous()
        share = 0.5 if consistency else 1.0
        index, confidence, nviews, guide = index_device(frame, lum, calibration, plan, settings, subpixel_box_px,
                                                        progress, 0.0, share)
        keep = None
        if consistency:
            other = dataclasses.replace(plan, reference=other_reference(plan))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", LfringWarning)
                other = dataclasses.replace(other, hs=calibration.homographies(plan.depths, reference=other.reference))
            other_index = index_device(frame, lum, calibration, other, settings, subpixel_box_px, progress, share,
                                       1.0)[0]
            keep = consistent_device(plan, index, other, other_index, consistency_steps * plan.exclude)
            confidence = torch.where(keep, confidence, 0.0)
        refined, filled = refine_index_device(index, confidence, guide)
        if consistency:
            behind = fill_from_farther_side_device(refined, ~keep, axis=baseline_axis(plan, other.reference))
            filled = torch.where(~keep & torch.isfinite(behind), behind, filled)
        index = torch.where(torch.isfinite(refined), refined, float("nan") if consistency else index)
        filled = torch.where(torch.isfinite(filled), filled, index)
        missing = torch.where(torch.isfinite(index), 0.0, float("inf"))
        return finish_device(finisher, torch.nan_to_num(index, nan=0.0), confidence, missing, nviews, filled)


class DeviceFinisher(Finisher):
    """A :class:`lfring.depth.selection.Finisher` whose depth, confidence and index are torch
    tensors on the device (set by the GPU engine): what a batch of frames collects there."""


def engine_runs_on(device, plan) -> bool:
    """Whether the GPU engine takes a sweep of ``plan`` on ``device``: its kernels run there and
    they hold the plan's hypotheses (:data:`MAX_PLANES`)."""
    return kernels_run_on(device) and len(plan.depths) <= MAX_PLANES


def run_semiglobal_gpu(views, calibration, plan, settings, finisher, progress, *, consistency: bool,
                       subpixel_box_px: int, consistency_steps: float) -> dict | None:
    """The 'sgm' engine's contract (:func:`lfring.depth.engines.semiglobal.run_semiglobal`) on the
    torch backend's device: NumPy views (V, h, w, C) float32 are uploaded once and the maps come
    back in one copy into the finisher; a float32 tensor on the device with a
    :class:`DeviceFinisher` keeps them there. The returned fields as the reference's. None where
    the engine does not run on the device (:func:`engine_runs_on`): the caller runs the reference."""
    dev = views.device if is_tensor(views) else resolve_device(settings.device)
    if not engine_runs_on(dev, plan):
        return None
    frame = views if is_tensor(views) else to_device(views, dev)
    maps = semiglobal_device(frame, calibration, plan, settings, finisher, progress, consistency=consistency,
                             subpixel_box_px=subpixel_box_px, consistency_steps=consistency_steps)
    if isinstance(finisher, DeviceFinisher):
        finisher.depth, finisher.conf, finisher.index, filled = maps
    else:
        depth, conf, index, filled = download_maps(maps)
        np.copyto(finisher.depth, depth)
        np.copyto(finisher.conf, conf)
        np.copyto(finisher.index, index)
    progress.done()
    return dict(depth_filled_m=filled, paths=settings.paths, consistency=consistency)
