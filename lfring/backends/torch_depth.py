"""The plane sweep with torch/kornia: chunks of depth hypotheses at once, on a GPU or the CPU.

The NumPy/OpenCV :func:`lfring.depth.stream.sweep_slices` is the reference and defines every
number here; tests hold the two together. Hypotheses are processed in chunks sized so that the
chunk's tensors stay under about ``_CHUNK_BYTES``: memory does not grow with their number.
"""

from __future__ import annotations

import numpy as np

from lfring.core.backend import require_torch, resolve_device
from lfring.depth.costs import (AGGREGATIONS, COSTS, GUIDED_EPS, HALVES_MIN_SUPPORT, MIN_VIEWS_TO_LEAVE_ONE_OUT,
                                OCCLUSION_PENALTY, checked_halves, leavable_views)
from lfring.errors import InvalidInputError
from lfring.core.viewstack import WEIGHT_FLOOR

__all__ = ["sweep_torch"]

_CHUNK_BYTES = 1 << 30
# Float32 images of the (V, h, w) size alive at once per hypothesis in the worst case (zncc):
# the repeated sources and their warps (2 channels each), the cost's per-view terms and the
# three padded window statistics per view.
_IMAGES_PER_HYPOTHESIS = 24


def _border_index(n: int, pad: int, delta: int) -> np.ndarray:
    """Source index of every padded position, as cv2.borderInterpolate: ``delta`` 1 for
    BORDER_REFLECT_101 (cv2.boxFilter's default), 0 for BORDER_REFLECT (the ximgproc guided filter)."""
    idx = np.arange(-pad, n + pad)
    if n == 1:
        return np.zeros_like(idx)
    out = idx.copy()
    for _ in range(4 * (pad // max(n, 1) + 1)):
        lo, hi = out < 0, out >= n
        if not (lo.any() or hi.any()):
            break
        out = np.where(lo, -out - 1 + delta, np.where(hi, 2 * n - 1 - out - delta, out))
    return out


class _Box:
    """Normalised k x k box filter of (B, C, h, w) tensors with OpenCV's border handling."""

    def __init__(self, torch, shape_hw, k: int, delta: int, device):
        self.torch = torch
        self.k = k
        self.pad = k // 2
        self.delta = delta
        # Windows wider than the image reflect more than once: gather by cv2.borderInterpolate's indices.
        self.general = self.pad >= min(shape_hw)
        if self.general:
            self.rows = torch.from_numpy(_border_index(shape_hw[0], self.pad, delta)).to(device)
            self.cols = torch.from_numpy(_border_index(shape_hw[1], self.pad, delta)).to(device)

    def _padded(self, x):
        p = self.pad
        if self.general:
            return x.index_select(-2, self.rows).index_select(-1, self.cols)
        if self.delta == 1:
            return self.torch.nn.functional.pad(x, (p, p, p, p), mode="reflect")
        cat = self.torch.cat
        x = cat([x[..., :p, :].flip(-2), x, x[..., -p:, :].flip(-2)], dim=-2)
        return cat([x[..., :p].flip(-1), x, x[..., -p:].flip(-1)], dim=-1)

    def __call__(self, x):
        if self.k == 1:
            return x
        x = self._padded(x)
        # The vertical pass as k shifted adds: avg_pool2d over columns is several times slower on the CPU.
        h = x.shape[-2] - self.k + 1
        y = x[..., :h, :].clone()
        for i in range(1, self.k):
            y += x[..., i:i + h, :]
        return self.torch.nn.functional.avg_pool2d(y, (1, self.k), stride=1).mul_(1.0 / self.k)


def _lcn(s1, s2, count):
    """:func:`lfring.depth.costs.lcn_cost` of torch sums."""
    return (s2 - s1 * s1 / count.clamp_min(WEIGHT_FLOOR)) / (count - 1.0).clamp_min(0.5)


def _leave_one_out(torch, lum_w, wts, nview, k: int):
    """:func:`lfring.depth.costs.lcn_leave_one_out` of view k for a chunk (C, V, h, w) -> (C, h, w)."""
    a_k = lum_w[:, k]
    return _lcn(lum_w.sum(dim=1) - a_k, (lum_w * lum_w).sum(dim=1) - a_k * a_k, nview - wts[:, k])


def _slice_cost(torch, lum_w, wts, cost: str, box):
    """:func:`lfring.depth.costs.slice_cost` for a chunk: lum_w, wts (C, V, h, w) -> (C, h, w) twice."""
    nview = wts.sum(dim=1)
    safe = nview.clamp_min(WEIGHT_FLOOR)
    vals = lum_w / wts.clamp_min(WEIGHT_FLOOR)
    valid = (wts > 0.5).to(lum_w.dtype)
    nvalid = valid.sum(dim=1)  # small integers, exact in float32
    mean = lum_w.sum(dim=1) / safe
    if cost in ("sad", "sad-occlusion"):
        dev = (vals - mean[:, None]).abs() * valid
        if cost == "sad-occlusion":
            more = nvalid > 2
            c = (dev.sum(dim=1) - torch.where(more, dev.amax(dim=1), 0.0)) / (nvalid - more.to(nvalid.dtype)).clamp_min(1)
        else:
            c = dev.sum(dim=1) / nvalid.clamp_min(1)
    elif cost in ("lcn", "lcn-halves", "lcn-occlusion"):  # lum_w: the warped locally normalised luminances times their masks
        c = _lcn(lum_w.sum(dim=1), (lum_w * lum_w).sum(dim=1), nview)
    elif cost == "ssd":
        c = ((vals - mean[:, None]) ** 2 * valid).sum(dim=1) / nvalid.clamp_min(1)
    else:  # zncc of every view with the mean, over the window
        cc, v, h, w = vals.shape
        stats_m = box(torch.stack([mean, mean * mean], dim=1))  # (C, 2, h, w)
        mu_m = stats_m[:, 0]
        var_m = (stats_m[:, 1] - mu_m**2).clamp_min(1e-8)
        vj = vals * valid
        stats = box(torch.stack([vj, vj * vj, vj * mean[:, None]], dim=2).reshape(cc, v * 3, h, w)).reshape(cc, v, 3, h, w)
        mu_j = stats[:, :, 0]
        var_j = (stats[:, :, 1] - mu_j**2).clamp_min(1e-8)
        cov = stats[:, :, 2] - mu_j * mu_m[:, None]
        acc = (cov / torch.sqrt(var_j * var_m[:, None]) * valid).sum(dim=1)
        c = 1.0 - acc / nvalid.clamp_min(1)
    return c, nview


class _Guided:
    """OpenCV's ximgproc guided filter (radius k // 2, BORDER_REFLECT windows) with a fixed
    grey guide, applied to chunks of (C, h, w) cost slices; the guide's statistics are kept."""

    def __init__(self, torch, guide, k: int, eps: float, device):
        self.box = _Box(torch, guide.shape, k, 0, device)
        self.guide = torch.from_numpy(np.ascontiguousarray(guide, dtype=np.float32)).to(device)[None, None]
        stats = self.box(torch.cat([self.guide, self.guide * self.guide], dim=1))
        self.mean_i = stats[:, :1]
        self.var_eps = stats[:, 1:] - self.mean_i**2 + eps

    def __call__(self, torch, p):
        p = p[:, None]
        stats = self.box(torch.cat([p, self.guide * p], dim=1))
        mean_p = stats[:, :1]
        a = (stats[:, 1:] - self.mean_i * mean_p) / self.var_eps
        b = mean_p - a * self.mean_i
        ab = self.box(torch.cat([a, b], dim=1))
        return (ab[:, :1] * self.guide + ab[:, 1:])[:, 0]


class _RunningMinimum:
    """:class:`lfring.depth.selection.RunningMinimum` with torch tensors, folding chunks of slices
    one slice at a time with the same rules (strict '<', so the earliest minimum wins; the
    second minimum exact, from a lagging prefix minimum and a minimum after the best)."""

    def __init__(self, torch, shape, exclude: int, device):
        self.torch = torch
        self.exclude = e = max(1, int(exclude))
        full = lambda: torch.full(shape, float("inf"), dtype=torch.float32, device=device)
        self.best, self.c_prev, self.c_next, self.far_lo, self.far_hi, self.prefix = (full() for _ in range(6))
        self.best_i = torch.zeros(shape, dtype=torch.int64, device=device)
        self.ring = [full() for _ in range(e + 2)]  # slices i - e - 1 .. i
        self.inf = torch.tensor(float("inf"), dtype=torch.float32, device=device)
        self.i = 0

    def push_chunk(self, aggs) -> None:
        for a in aggs:
            self.push(a)

    def push(self, cur) -> None:
        torch, i, e, ring = self.torch, self.i, self.exclude, self.ring
        ring[i % len(ring)].copy_(cur)  # a copy: a view would keep the whole chunk alive
        cur = ring[i % len(ring)]
        if i >= e + 1:
            torch.minimum(self.prefix, ring[(i - e - 1) % len(ring)], out=self.prefix)
        if i >= 1:
            self.c_next.copy_(torch.where(self.best_i == i - 1, cur, self.c_next))
            self.far_hi.copy_(torch.where(self.best_i < i - e, torch.minimum(self.far_hi, cur), self.far_hi))
        new = cur < self.best
        self.best.copy_(torch.where(new, cur, self.best))
        self.best_i.masked_fill_(new, i)
        if i >= 1:
            self.c_prev.copy_(torch.where(new, ring[(i - 1) % len(ring)], self.c_prev))
            self.c_next.masked_fill_(new, float("inf"))
            self.far_hi.masked_fill_(new, float("inf"))
        if i >= e + 1:
            self.far_lo.copy_(torch.where(new, self.prefix, self.far_lo))
        self.i += 1

    def second(self):
        return self.torch.minimum(self.far_lo, self.far_hi)


def _checked_inputs(lum, masks, cost: str, aggregation: str, guide):
    """The argument checks both torch sweeps share: cost and aggregation names, float32 (V, h, w)
    luminances and masks, and a guide of the views' size for the guided aggregation."""
    if cost not in COSTS:
        raise InvalidInputError(f"cost must be one of {', '.join(COSTS)}, got {cost!r}")
    if aggregation not in AGGREGATIONS:
        raise InvalidInputError(f"aggregation must be one of {', '.join(AGGREGATIONS)}, got {aggregation!r}")
    lum = np.asarray(lum)
    masks = np.asarray(masks)
    if lum.dtype != np.float32 or masks.dtype != np.float32 or lum.ndim != 3 or masks.shape != lum.shape:
        raise InvalidInputError(
            f"need float32 (V, h, w) luminances and masks, got {lum.dtype} {lum.shape} and {masks.dtype} {masks.shape}"
        )
    h, w = lum.shape[1:]
    if aggregation == "guided" and (guide is None or np.shape(guide) != (h, w)):
        got = None if guide is None else np.shape(guide)
        raise InvalidInputError(f"the guided aggregation needs a ({h}, {w}) guide image, got {got}")
    return lum, masks


def _chunk_size(n: int, v: int, h: int, w: int) -> int:
    per = _IMAGES_PER_HYPOTHESIS * v * h * w * 4
    return int(max(1, min(n, _CHUNK_BYTES // max(per, 1))))


def sweep_torch(lum, masks, hs, *, cost, aggregation, window_px, guide, exclude=1, device=None, aggregate_px=None,
                volume=None, halves=None):
    """Same contract as :func:`lfring.depth.stream.sweep_slices`, with kornia.

    Parameters
    ----------
    lum : (V, h, w) float32
        Normalised luminances.
    masks : (V, h, w) float32
        Valid weight of every view pixel.
    hs : (N, V, 3, 3) float64
        H_ref_from_view for every hypothesis and view.
    cost : {'lcn', 'lcn-halves', 'lcn-occlusion', 'zncc', 'sad', 'ssd', 'sad-occlusion'}
        For 'lcn', ``lum`` holds the locally normalised luminances (:func:`lfring.depth.costs.lcn_sources`).
    aggregation : {'box', 'guided'}
    window_px : int
        Odd window of the cost ('zncc').
    aggregate_px : int, optional
        Odd window of the aggregation (guided: radius ``aggregate_px // 2``); ``window_px`` by default.
    guide : (h, w) float32 in [0, 1] or None
        The guided filter's guide image (required for 'guided').
    exclude : int
        The second minimum is looked for more than ``exclude`` hypotheses from the best.
    device : str or torch.device, optional
    volume : (N, h, w) float32 ndarray, optional
        Filled with every aggregated slice instead of keeping a running minimum; then only
        ``nviews`` is returned (as :func:`lfring.depth.stream.sweep_slices`).
    halves : (N, h, w) float32 ndarray, optional
        With ``volume``: every hypothesis's least cost of a half of the views, as
        :func:`lfring.depth.stream.sweep_slices` fills it.

    Returns
    -------
    best_i : (h, w) int32
    c_best, c_prev, c_next, c_second, nviews : (h, w) float32
        As the NumPy sweep defines them.
    """
    torch = require_torch()
    from kornia.geometry.transform import warp_perspective

    lum, masks = _checked_inputs(lum, masks, cost, aggregation, guide)
    v, h, w = lum.shape
    hs = np.asarray(hs, dtype=np.float64)
    if hs.ndim != 4 or hs.shape[1:] != (v, 3, 3):
        raise InvalidInputError(f"need (N, {v}, 3, 3) homographies, got {hs.shape}")
    dev = resolve_device(device)
    n = hs.shape[0]

    aggregate_px = window_px if aggregate_px is None else aggregate_px
    box_cost = _Box(torch, (h, w), window_px, 1, dev)  # cv2.boxFilter: BORDER_REFLECT_101
    box_agg = box_cost if aggregate_px == window_px else _Box(torch, (h, w), aggregate_px, 1, dev)
    guided = _Guided(torch, guide, aggregate_px, GUIDED_EPS, dev) if aggregation == "guided" else None
    lum_t = torch.from_numpy(np.ascontiguousarray(lum)).to(dev)
    masks_t = torch.from_numpy(np.array(masks, dtype=np.float32)).to(dev)  # a writable copy: the cached masks are read-only
    src = torch.stack([lum_t * masks_t, masks_t], dim=1)  # (V, 2, h, w): each view warps with its mask
    hs_t = torch.from_numpy(hs).to(dev, torch.float32)

    def full(value):
        return torch.full((h, w), value, dtype=torch.float32, device=dev)

    run = _RunningMinimum(torch, (h, w), exclude, dev)
    nviews = full(0.0)
    leavable = leavable_views(hs) if cost == "lcn-occlusion" else []
    halves_of = checked_halves(halves, volume, hs, (h, w), cost)
    chunk = _chunk_size(n, v, h, w)
    with torch.no_grad():
        for i0 in range(0, n, chunk):
            i1 = min(n, i0 + chunk)
            c = i1 - i0
            warped = warp_perspective(src.repeat(c, 1, 1, 1), hs_t[i0:i1].reshape(c * v, 3, 3), (h, w),
                                      mode="bilinear", padding_mode="zeros", align_corners=True)
            warped = warped.reshape(c, v, 2, h, w)
            cst, nv = _slice_cost(torch, warped[:, :, 0], warped[:, :, 1], cost, box_cost)
            finite = (nv >= 1.5) & torch.isfinite(cst)
            plain = lambda x: guided(torch, x) if guided is not None else box_agg(x[:, None])[:, 0]
            support = plain(finite.to(cst.dtype)).clamp_min(WEIGHT_FLOOR)  # as lfring.depth.costs.aggregate
            aggregate = lambda x: plain(torch.where(finite, x, 0.0)) / support
            agg = aggregate(cst)
            agg_count = plain(nv) if leavable else None
            for k in leavable:  # as lfring.depth.costs.occlusion_aggregate
                allowed = agg_count - plain(warped[:, k, 1]) > MIN_VIEWS_TO_LEAVE_ONE_OUT - 1.5
                one = aggregate(_leave_one_out(torch, warped[:, :, 0], warped[:, :, 1], nv, k))
                agg = torch.where(allowed, torch.minimum(agg, OCCLUSION_PENALTY * one), agg)
            if halves_of:  # as lfring.depth.costs.half_aggregate
                least = torch.full_like(agg, float("inf"))
                for half in halves_of:
                    a_h, w_h = warped[:, list(half), 0], warped[:, list(half), 1]
                    count = w_h.sum(dim=1)
                    own = (nv >= 1.5) & (count >= 1.5)
                    support = plain(own.to(cst.dtype))
                    ok = own & (support >= HALVES_MIN_SUPPORT)
                    cand = plain(torch.where(own, _lcn(a_h.sum(dim=1), (a_h * a_h).sum(dim=1), count), 0.0))
                    cand = OCCLUSION_PENALTY * cand / torch.where(ok, support, 1.0)
                    least = torch.where(ok & (cand < least), cand, least)
                halves[i0:i1] = least.cpu().numpy()
            del warped
            agg = torch.where(finite, agg, float("inf"))
            if volume is None:
                run.push_chunk(agg)
            else:
                volume[i0:i1] = agg.cpu().numpy()
            torch.maximum(nviews, nv.amax(dim=0), out=nviews)
    if volume is not None:
        return nviews.cpu().numpy()
    out = (run.best, run.c_prev, run.c_next, run.second(), nviews)
    return (run.best_i.to(torch.int32).cpu().numpy(), *(x.cpu().numpy() for x in out))
