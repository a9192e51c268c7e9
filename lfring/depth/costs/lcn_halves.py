"""The 'lcn-halves' cost (the default of the semi-global engine): the 'lcn' cost, and where no
depth suits all views, the cost of the views on one side of the reference.

It keeps a second volume beside the first: per hypothesis the least cost of a half of the views,
those on one side of a line through the reference (:func:`view_halves`, :func:`half_aggregate`).
Next to a depth edge the views on one side see the occluder over the background and those on the
other side do not. Once the sweep is done, :func:`take_halves` uses the halves' volume only at the
pixels where no depth suits all views and a half agrees much better.
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

from lfring.core.viewstack import WEIGHT_FLOOR
from lfring.depth.costs.base import compiled_kernels
from lfring.depth.costs.lcn import LCN, lcn_cost_torch, weighted_square, weighted_square_torch
from lfring.depth.costs.lcn_occlusion import OCCLUSION_PENALTY
from lfring.errors import InvalidInputError

__all__ = ["HALVES_GAIN", "HALVES_LINE_TOL", "HALVES_MEDIAN_SAMPLE", "HALVES_MIN_SUPPORT", "HALVES_POOR", "LCN_HALVES",
           "checked_halves", "half_aggregate", "halves_least_torch", "halves_poor", "take_halves", "view_halves"]

# 'lcn-halves' (for the whole cost volume of the semi-global method): a half of the views is the
# views on one side of a line through the reference (along the image's rows or columns; with the
# reference's own view on the line), as many as move at most this fraction of the largest view
# motion towards that side. It takes the halves' cost at a pixel whose best cost over all views is
# over HALVES_POOR times the image's median best cost (no depth suits every view; halves_poor)
# while some half's best is under HALVES_GAIN times it (a half agrees). The factors were tuned on
# the twin's hard and three-depth scenes, where the rule lowers the bad pixels, and checked on a
# layout they were not tuned on (the hard scene's objects mirrored and moved), where it does too.
# Taking the halves' cost wherever it is lower made the three-depth scene worse: two views agree
# by chance in weak texture (benchmarks/RESULTS.md, "Depth on real data").
HALVES_LINE_TOL = 0.25
HALVES_POOR = 3.0
HALVES_GAIN = 0.5
# A half's cost counts over a window where two of its views see at least this share of the window's
# pixels (a mean over a few rim pixels makes a distinct and wrong cost curve).
HALVES_MIN_SUPPORT = 0.75
HALVES_MEDIAN_SAMPLE = 1 << 16


def view_halves(hs: np.ndarray, view_shape) -> list[tuple[int, ...]]:
    """The halves of the views that 'lcn-halves' compares: for each of the directions +x, -x, +y,
    -y of the reference frame, the views whose motion over the hypotheses ``hs`` (N, V, 3, 3) at
    the frame's centre does not go that way (a component at most :data:`HALVES_LINE_TOL` times the
    largest motion). Only halves of two views or more and fewer than all are kept, without repeats.

    Next to a depth edge the views on one side of the reference see the occluding surface over
    the background; those on the other side do not. For the ring with reference 0 (top left) the
    halves are its column (0, 2) and its row (0, 1); for 'center', the four sides of the square. A
    pair has none.

    Examples
    --------
    >>> import numpy as np
    >>> hs = np.tile(np.eye(3), (2, 4, 1, 1))
    >>> hs[1, 1, 0, 2] = hs[1, 3, 0, 2] = 5.0     # views 1 and 3 move along x with depth,
    >>> hs[1, 2, 1, 2] = hs[1, 3, 1, 2] = 5.0     # views 2 and 3 along y; view 0 is the reference
    >>> view_halves(hs, (10, 10))
    [(0, 2), (0, 1)]
    """
    hs = np.asarray(hs, np.float64)
    h, w = view_shape
    c = np.array([(w - 1) / 2.0, (h - 1) / 2.0, 1.0])
    ends = [hs[i] @ c for i in (0, -1)]  # (V, 3) the centre's place at the nearest and farthest hypothesis
    motion = ends[1][:, :2] / ends[1][:, 2:] - ends[0][:, :2] / ends[0][:, 2:]  # (V, 2)
    tol = HALVES_LINE_TOL * float(np.abs(motion).max(initial=0.0))
    halves = []
    for u in ((1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)):
        half = tuple(int(k) for k in np.flatnonzero(motion @ np.array(u) <= tol))
        if 2 <= len(half) < len(hs[0]) and half not in halves:
            halves.append(half)
    return halves


def checked_halves(halves, volume, hs: np.ndarray, view_shape, cost=None) -> list[tuple[int, ...]]:
    """The halves (:func:`view_halves`) a sweep fills the ``halves`` volume for, after checking
    it: none without it; with it, a whole ``volume``, an 'lcn' cost (``cost``, a
    :class:`lfring.depth.costs.base.DepthCost`; None for the strip sweep, whose cost is 'lcn') and
    a float32 (N, h, w) array are needed. Where there are no halves (a pair) it is filled with inf
    at once."""
    if halves is None:
        return []
    n = np.shape(hs)[0]
    want = (n, *tuple(view_shape))
    lcn = cost is None or (cost.lcn and not cost.leave_one_out)
    if volume is None or not lcn or np.shape(halves) != want or getattr(halves, "dtype", None) != np.float32:
        name = "lcn" if cost is None else cost.name
        raise InvalidInputError(f"halves needs a volume, an 'lcn' cost and a float32 {want} array, got {name!r} "
                                f"{getattr(halves, 'dtype', None)} {np.shape(halves)}")
    found = view_halves(hs, view_shape)
    if not found:
        halves.fill(np.inf)
    return found


def half_aggregate(parts, seen: np.ndarray, box, out: np.ndarray, scratch=None) -> np.ndarray:
    """One half's candidate for 'lcn-halves', folded into ``out`` (the least so far, (h, w) float32,
    in place).

    The candidate is :data:`OCCLUSION_PENALTY` times the 'lcn' cost of the half's views
    (:func:`lcn_cost`) averaged by ``box`` over the pixels of the window that all views see
    (``seen``) and two of the half's views see; it counts at those pixels where they fill at
    least :data:`HALVES_MIN_SUPPORT` of the window.

    Parameters
    ----------
    parts : sequence of ((h, w), (h, w)) float32
        Per view of the half, its warped value premultiplied by its warped mask, and the mask.
    seen : (h, w) bool
    box : callable
        The aggregation, (h, w) float32 -> (h, w) float32.
    out : (h, w) float32
    scratch : sequence of five (h, w) float32 buffers, optional
    """
    h, w = out.shape
    s1, s2, count, cost, own = scratch if scratch is not None else [np.empty((h, w), np.float32) for _ in range(5)]
    kernels = compiled_kernels()
    if len(parts) == 2:  # the ring's halves
        (a0, w0), (a1, w1) = parts
        n_own = kernels.pair_terms(a0, w0, a1, w1, seen, WEIGHT_FLOOR, cost, own)
    else:
        np.copyto(s1, parts[0][0])
        np.copyto(s2, weighted_square(*parts[0]))
        np.copyto(count, parts[0][1])
        for a_k, w_k in parts[1:]:
            cv2.add(s1, a_k, dst=s1)
            cv2.add(s2, weighted_square(a_k, w_k), dst=s2)
            cv2.add(count, w_k, dst=count)
        n_own = kernels.half_terms(s1, s2, count, seen, WEIGHT_FLOOR, cost, own)
    full = n_own == h * w  # then every window's mean is its box
    kernels.fold_half(box(cost), cost if full else box(own), own, full, OCCLUSION_PENALTY, HALVES_MIN_SUPPORT, out)
    return out


def halves_poor(best, median):
    """The pixels where the halves' cost may be taken: ``best`` (the least cost over all views,
    inf where no view pair sees the pixel at any hypothesis) over :data:`HALVES_POOR` times the
    image's ``median`` best, and finite. A pixel that no two views see at any hypothesis has no
    half that sees it either (a half's cost counts only where all views' does), so leaving it out
    changes no cost and spares the halves' pass those pixels (the views' rims, the frame's
    border). For NumPy arrays and torch tensors alike.

    Examples
    --------
    >>> import numpy as np
    >>> halves_poor(np.array([0.1, 0.5, np.inf], np.float32), 0.1).tolist()
    [False, True, False]
    """
    return (best > HALVES_POOR * median) & (best < math.inf)


def take_halves(volume: np.ndarray, halves: np.ndarray) -> np.ndarray:
    """'lcn-halves': in the cost volume (N, h, w) of all views, in place, the least of it and the
    halves' volume (:func:`half_aggregate` of every half, inf where none counts) at the pixels
    where no hypothesis suits all views and a half agrees much better (see :data:`HALVES_POOR`,
    :data:`HALVES_GAIN`); elsewhere the volume is unchanged. Returns the share of pixels taken.

    Examples
    --------
    >>> import numpy as np
    >>> volume = np.array([[[0.1, 0.2, 0.1, 4.0]], [[0.3, 0.4, 0.2, 5.0]]], np.float32)  # (2 hypotheses, 1, 4)
    >>> halves = np.array([[[0.1, 0.1, 0.1, 3.9]], [[0.1, 0.1, 0.1, 0.25]]], np.float32)
    >>> take_halves(volume, halves)   # pixel 3: its best over all views (4.0) is poor, a half's agrees
    0.25
    >>> volume[:, 0, 3].tolist(), volume[:, 0, 0].tolist()
    ([3.9000000953674316, 0.25], [0.10000000149011612, 0.30000001192092896])
    """
    for name, a in (("volume", volume), ("halves", halves)):
        if not isinstance(a, np.ndarray) or a.dtype != np.float32 or a.ndim != 3 or not a.flags.c_contiguous:
            raise InvalidInputError(f"{name} must be a C-contiguous float32 (N, h, w) array, got {np.shape(a)}")
    if halves.shape != volume.shape:
        raise InvalidInputError(f"halves must have the volume's shape {volume.shape}, got {halves.shape}")
    n, h, w = volume.shape
    best, half_best = np.empty((h, w), np.float32), np.empty((h, w), np.float32)
    compiled_kernels().volume_minima(volume, halves, best, half_best)
    # The median best cost is a scale: the pixels of a regular grid, about HALVES_MEDIAN_SAMPLE of
    # them, give it (closely: no benchmark figure moved) in a fraction of the whole image's time.
    stride = max(1, int(np.ceil(np.sqrt(h * w / HALVES_MEDIAN_SAMPLE))))
    sample = best[::stride, ::stride]
    sample = sample[np.isfinite(sample)]
    if not sample.size:
        return 0.0
    take = halves_poor(best, float(np.median(sample))) & (half_best < HALVES_GAIN * best)
    if take.any():
        compiled_kernels().take_where(volume, halves, take)
    return float(take.mean())


def halves_least_torch(torch, lum_w, wts, nview, halves_of, window):
    """The torch twin of :func:`half_aggregate` folded over every half: (C, h, w) the least
    candidate of the halves ``halves_of`` (inf where none counts), from chunks ``lum_w``, ``wts``
    (C, V, h, w) and ``nview``; ``window`` the plain aggregation."""
    least = torch.full_like(nview, float("inf"))
    seen = nview >= 1.5
    for half in halves_of:
        a_h, w_h = lum_w[:, list(half)], wts[:, list(half)]
        count = w_h.sum(dim=1)
        own = seen & (count >= 1.5)
        support = window(own.to(nview.dtype))
        ok = own & (support >= HALVES_MIN_SUPPORT)
        cand = window(torch.where(own, lcn_cost_torch(a_h.sum(dim=1), weighted_square_torch(a_h, w_h).sum(dim=1), count),
                                  0.0))
        cand = OCCLUSION_PENALTY * cand / torch.where(ok, support, 1.0)
        least = torch.where(ok & (cand < least), cand, least)
    return least


LCN_HALVES = dataclasses.replace(
    LCN, name="lcn-halves", halves=True,
    summary="'lcn', and where no depth suits all views, the cost of the views on one side (needs the whole volume)")
