"""Photo-consistency costs of one depth hypothesis and their spatial aggregation.

The 'lcn' cost of a hypothesis at a pixel is the variance across the views of their
locally normalised luminances, ``n = (L - mu) / sqrt(var + LCN_EPS mu^2 + LCN_FLOOR)`` with
``mu`` and ``var`` the masked local mean and variance of the luminance ``L`` over ``window_px``.
The normalisation is done once per view, before the sweep (:func:`lcn_sources`), so a hypothesis
only has to shift the views and sum: with S1, S2 the sums over views of the (mask-weighted)
normalised values and their squares and C the sum of the views' weights,
``c = (S2 - S1^2 / C) / max(C - 1, 0.5)`` (:func:`lcn_cost`). Dividing by the local mean makes
it blind to the views' different vignetting and exposure.

'lcn-occlusion' is the same cost with one view left out where that is cheaper over the
aggregation window (:func:`occlusion_aggregate`): next to a depth edge
a view that sees the occluding surface no longer spoils the true depth's cost.

'lcn-halves' (the default of the semi-global method) keeps a second volume beside the first: per
hypothesis the least cost of a half of the views, those on one side of a line through the
reference (:func:`view_halves`, :func:`half_aggregate`). Next to a depth edge the views on one
side see the occluder over the background and those on the other side do not. Once the sweep is
done, :func:`take_halves` uses the halves' volume only at the pixels where no depth suits all views
and a half agrees much better.

Every cost is aggregated over the pixels that at least 1.5 views see (:func:`aggregate`,
:func:`seen_mean`: a normalised convolution); pixels seen by fewer are inf. The semi-global
method optimises the least of the aggregated costs of the boxes that contain a pixel
(:func:`least_over_windows`, shiftable windows).

The other costs (:func:`slice_cost`) compare warped luminances divided by their wide local mean
(:func:`lfring.core.filters.normalised_luminance`).
"""

from __future__ import annotations

import cv2
import numpy as np

from lfring.errors import InvalidInputError
from lfring.core.viewstack import WEIGHT_FLOOR, cached_view_masks
from lfring.core.filters import box_filter, luminance
from lfring.core.validate import check_threads
from lfring.core.threads import run_threads

__all__ = ["AGGREGATIONS", "COSTS", "DEPTH_TAPER", "GUIDED_EPS", "HALVES_GAIN", "HALVES_LINE_TOL",
           "HALVES_MEDIAN_SAMPLE", "HALVES_MIN_SUPPORT", "HALVES_POOR", "LCN_AGGREGATE_PX", "LCN_EPS", "LCN_FLOOR",
           "MIN_VIEWS_TO_LEAVE_ONE_OUT", "OCCLUSION_PENALTY", "STRIP_PIXELS", "aggregate", "aggregation_window",
           "box_mean_of_finite", "check_odd_px", "checked_halves", "half_aggregate", "lcn_cost", "lcn_leave_one_out",
           "lcn_sources", "least_over_windows", "leavable_views", "occlusion_aggregate", "seen_mean", "slice_cost",
           "sweep_masks", "take_halves", "view_halves", "window_weights"]

# Fraction of a view's disc radius over which its weight rises from 0 to 1 in the sweep
# (lfring.core.viewstack.view_masks). The refocusing taper (lfring.core.viewstack.TAPER, 15 %) hides seams in an image;
# in the sweep it counted a view that sees a pixel as a fraction of a view over the outer 15 % of
# its disc, so pixels two views see came out unseen (min_views) and their costs were weighted
# down. Twin, every pixel two views see, bad 1 px, taper 15 / 5 / 2 %: hard scene 13.1 / 10.9 /
# 11.0 % (4 views) and 15.0 / 11.5 / 10.7 % (views 0 and 1); three-depth 8.0 / 6.3 / 5.7 % and
# 7.3 / 5.2 / 4.7 %. At 3 % and below the darkest, noisiest rim pixels of the inspection sample
# (data/synthetic/part_good.png) made a confident false dent at the bottom of the frame.
DEPTH_TAPER = 0.05
COSTS = ("lcn", "lcn-halves", "lcn-occlusion", "zncc", "sad", "ssd", "sad-occlusion")
# A view may be left out of a window where on average at least this many views see its pixels
# (with two, neither can be told to be the occluded one). Judged over the window, not per pixel: a
# per-pixel rule switches the candidates on and off as the views' edges move with the hypothesis,
# and measured worse than no leaving out at all (twin three-depth scene, bad 1 px 11.8 % against
# 8.9 %).
MIN_VIEWS_TO_LEAVE_ONE_OUT = 3
# 'lcn-occlusion': the aggregated cost of the views without one competes with all views' cost
# after this factor. Fewer samples give a noisier variance, and the least of several noisy
# candidates is biased low; on the twin's hard scene 1.0 and 1.15 measured the same (bad 1 px
# 12.6 %), on the three-depth scene 1.15 was better (8.5 % against 8.7 %).
OCCLUSION_PENALTY = 1.15
# 'lcn-halves' (for the whole cost volume of the semi-global method): a half of the views is the
# views on one side of a line through the reference (along the image's rows or columns; with the
# reference's own view on the line), as many as move at most this fraction of the largest view
# motion towards that side. It takes the halves' cost at a pixel whose best cost over all views is
# over HALVES_POOR times the image's median best cost (no depth suits every view) while some half's
# best is under HALVES_GAIN times it (a half agrees). On the twin (every pixel two views see, bad
# 1 px, four views, reference 0): the hard scene 11.4 -> 8.9 %, three-depth 6.3 -> 6.0 %, and a
# layout the rule was not tuned on (the hard scene's objects mirrored and moved) 12.6 -> 11.0 %.
# Taking the halves' cost wherever it is lower made the three-depth scene worse (9.1 %): two views
# agree by chance in weak texture.
HALVES_LINE_TOL = 0.25
HALVES_POOR = 3.0
HALVES_GAIN = 0.5
# A half's cost counts over a window where two of its views see at least this share of the window's
# pixels (a mean over a few rim pixels makes a distinct and wrong cost curve).
HALVES_MIN_SUPPORT = 0.75
HALVES_MEDIAN_SAMPLE = 1 << 16
AGGREGATIONS = ("box", "guided")
# Regularisation of the guided aggregation (cv2.ximgproc.createGuidedFilter's eps; the torch twin the same).
GUIDED_EPS = 1e-3
# The default aggregation window of the 'lcn' cost (the other costs aggregate over window_px).
LCN_AGGREGATE_PX = 15
# Relative contrast floor of the normalisation (its variance term is LCN_EPS mu^2): texture
# fainter than 10 % of the local mean is compared unnormalised; LCN_FLOOR keeps black regions finite.
LCN_EPS = 1e-2
LCN_FLOOR = 1e-6
# Pixels per strip (rows times width, with the halo): about 0.4 MiB a buffer, so a thread's dozen
# buffers stay in its L2 and L3 share; larger strips measured no faster, smaller ones slower.
STRIP_PIXELS = 1 << 17


def check_odd_px(name: str, value) -> None:
    """Refuse a window side ``value`` that is not an odd positive integer (a centred window)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1 or value % 2 == 0:
        raise InvalidInputError(f"{name} must be an odd positive integer, got {value!r}")


def sweep_masks(calibration, view_shape, taper: float = DEPTH_TAPER) -> np.ndarray:
    """(V, h, w) float32 weight of every view pixel in the sweep: :func:`lfring.core.viewstack.view_masks`
    with the rim ``taper`` (by default :data:`DEPTH_TAPER`), made once per calibration, view
    shape and taper (read-only)."""
    return cached_view_masks(calibration, view_shape, taper=taper)


def lcn_sources(views: np.ndarray, calibration, window_px: int, *, threads: int = 1, taper: float = DEPTH_TAPER) -> np.ndarray:
    """(V, h, w) float32 locally normalised luminance of every view (masked by
    :func:`sweep_masks` with ``taper``), to be multiplied by the mask before warping; views are
    shared among ``threads`` threads."""
    masks = sweep_masks(calibration, views.shape[1:3], taper)
    lum = luminance(views)
    out = np.empty(lum.shape, np.float32)

    weights = window_weights(calibration, views.shape[1:3], window_px, taper)
    v, h, w = lum.shape
    pad = window_px // 2
    rows = max(8, STRIP_PIXELS // (2 * max(w, 1)))  # row strips of every view, in the cache

    def one(k: int, r0: int, r1: int) -> None:
        q0, q1 = max(0, r0 - pad), min(h, r1 + pad)
        inner = slice(r0 - q0, r1 - q0)
        m, x = masks[k][q0:q1], lum[k][q0:q1]
        a = cv2.multiply(x, m)
        mu = box_filter(a, window_px)[inner]
        cv2.multiply(a, x, dst=a)
        s2 = box_filter(a, window_px)[inner]
        wk = weights[k][r0:r1]
        cv2.multiply(mu, wk, dst=mu)
        cv2.multiply(s2, wk, dst=s2)
        # sqrt(max(E[x^2] - mu^2, 0) + eps mu^2 + floor)
        sq = cv2.multiply(mu, mu)
        var = cv2.subtract(s2, sq)
        cv2.max(var, 0.0, dst=var)
        cv2.scaleAdd(sq, LCN_EPS, var, dst=var)
        cv2.add(var, LCN_FLOOR, dst=var)
        cv2.sqrt(var, dst=var)
        dst = out[k][r0:r1]
        cv2.subtract(x[inner], mu, dst=dst)
        cv2.divide(dst, var, dst=dst)

    run_threads([lambda k=k, r=r: one(k, r, min(h, r + rows)) for k in range(v) for r in range(0, h, rows)], threads)
    return out


def window_weights(calibration, view_shape, window_px: int, taper: float = DEPTH_TAPER) -> np.ndarray:
    """(V, h, w) float32 ``1 / max(box(mask), WEIGHT_FLOOR)`` of every view's
    :func:`sweep_masks` over ``window_px``: made once per calibration, view shape, window and taper."""
    return cached_view_masks(
        calibration, view_shape, ("window_weights", int(window_px)),
        taper=taper, make=lambda masks: np.stack([1.0 / np.maximum(box_filter(m, window_px), WEIGHT_FLOOR) for m in masks]).astype(np.float32),
    )


def lcn_cost(s1: np.ndarray, s2: np.ndarray, count: np.ndarray) -> np.ndarray:
    """The 'lcn' cost from the sums over views (S1, S2, C; see the module's docstring)."""
    c = s2 - s1 * s1 / np.maximum(count, WEIGHT_FLOOR)
    c /= np.maximum(count - 1.0, 0.5)
    return c.astype(np.float32, copy=False)


def _kernels():
    """:mod:`lfring.depth.cost_kernels`, imported (and numba with it) on first use."""
    from lfring.depth import cost_kernels

    return cost_kernels


def lcn_leave_one_out(s1: np.ndarray, s2: np.ndarray, count: np.ndarray, a_k: np.ndarray, w_k: np.ndarray,
                      out: np.ndarray | None = None) -> np.ndarray:
    """The 'lcn' cost of the views without view k (:func:`lcn_cost`), from all views' sums (S1,
    S2, C) and view k's warped value ``a_k`` (premultiplied by its warped mask) and mask ``w_k``,
    all (h, w) float32; written into ``out`` when given. The views that remain are ``count - w_k``.

    Examples
    --------
    >>> import numpy as np
    >>> x = np.array([0.3, 0.3, 0.3, 2.0], np.float32)[:, None, None] * np.ones((4, 1, 2), np.float32)
    >>> ones = np.ones_like(x)
    >>> cost = lcn_leave_one_out(x.sum(0), (x * x).sum(0), ones.sum(0), x[3], ones[3])
    >>> np.allclose(cost, 0.0, atol=1e-6)        # the three that agree
    True
    """
    out = np.empty(np.shape(s1), np.float32) if out is None else out
    _kernels().leave_one_out(s1, s2, count, a_k, w_k, WEIGHT_FLOOR, out)
    return out


def leavable_views(hs: np.ndarray) -> list[int]:
    """The views 'lcn-occlusion' may leave out: all but the reference view (whose homography is
    the identity at every hypothesis; it sees its own pixel by definition), for the 'center'
    reference every view; none with fewer than :data:`MIN_VIEWS_TO_LEAVE_ONE_OUT` views."""
    hs = np.asarray(hs)
    if hs.shape[1] < MIN_VIEWS_TO_LEAVE_ONE_OUT:
        return []
    return [k for k in range(hs.shape[1]) if not np.all(hs[:, k] == np.eye(3))]


def occlusion_aggregate(agg_all: np.ndarray, count: np.ndarray, leave_outs, aggregate_cost, aggregate_count) -> np.ndarray:
    """The 'lcn-occlusion' cost of one hypothesis, in place in ``agg_all``.

    Next to a depth edge, some views see the occluding surface instead of the reference's pixel,
    and at the rim of a view's disc its few, dark, tapered pixels are noisy: at the true depth
    such a view disagrees with the others and the variance over all views is high. Over a window,
    the cost is therefore the least of all views' aggregated cost and, for every view k that may
    be left out, :data:`OCCLUSION_PENALTY` times the aggregated cost of the views without k
    (:func:`lcn_leave_one_out`), where the window's aggregated count of the views that remain
    reaches :data:`MIN_VIEWS_TO_LEAVE_ONE_OUT` - 1. The choice is made per window, after the
    aggregation, so one noisy pixel does not drop a view.

    Parameters
    ----------
    agg_all : (h, w) float32
        The aggregated 'lcn' cost of all views.
    count : (h, w) float32
        The views that see each pixel (the sum of their warped masks).
    leave_outs : iterable of ((h, w), (h, w)) float32
        Per view that may be left out, its per-pixel :func:`lcn_leave_one_out` cost and warped
        mask ``w_k`` (the cost may share a buffer: each is aggregated before the next is made).
    aggregate_cost, aggregate_count : callable
        ``agg_all``'s spatial aggregation, (h, w) -> (h, w), for the costs (over the same pixels
        as ``agg_all``'s, :func:`aggregate`) and, plain, for the counts.
    """
    agg_count = aggregate_count(count)
    least_rest = MIN_VIEWS_TO_LEAVE_ONE_OUT - 1.5
    # An aggregated mask lies in [0, 1]: only where the count is within 1 of the bound does the
    # left-out view's own share decide (the rims of the views' discs); elsewhere the count alone.
    rim = bool(np.any((agg_count > least_rest) & (agg_count <= least_rest + 1.0)))
    whole = None if rim else np.ones_like(agg_count)  # the most a view's aggregated mask can be
    for c, w_k in leave_outs:
        agg_w = aggregate_count(w_k) if rim else whole
        _kernels().take_least(agg_all, aggregate_cost(c), OCCLUSION_PENALTY, agg_count, agg_w, least_rest)
    return agg_all


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


def checked_halves(halves, volume, hs: np.ndarray, view_shape, cost: str = "lcn") -> list[tuple[int, ...]]:
    """The halves (:func:`view_halves`) a sweep fills the ``halves`` volume for, after checking
    it: none without it; with it, a whole ``volume``, an 'lcn' cost and a float32 (N, h, w)
    array are needed. Where there are no halves (a pair) it is filled with inf at once."""
    if halves is None:
        return []
    n = np.shape(hs)[0]
    want = (n, *tuple(view_shape))
    if volume is None or cost not in ("lcn", "lcn-halves") or np.shape(halves) != want \
            or getattr(halves, "dtype", None) != np.float32:
        raise InvalidInputError(f"halves needs a volume, an 'lcn' cost and a float32 {want} array, got {cost!r} "
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
    kernels = _kernels()
    if len(parts) == 2:  # the ring's halves
        (a0, w0), (a1, w1) = parts
        n_own = kernels.pair_terms(a0, w0, a1, w1, seen, WEIGHT_FLOOR, cost, own)
    else:
        np.copyto(s1, parts[0][0])
        cv2.multiply(parts[0][0], parts[0][0], dst=s2)
        np.copyto(count, parts[0][1])
        for a_k, w_k in parts[1:]:
            cv2.add(s1, a_k, dst=s1)
            cv2.accumulateSquare(a_k, s2)
            cv2.add(count, w_k, dst=count)
        n_own = kernels.half_terms(s1, s2, count, seen, WEIGHT_FLOOR, cost, own)
    full = n_own == h * w  # then every window's mean is its box
    kernels.fold_half(box(cost), cost if full else box(own), own, full, OCCLUSION_PENALTY, HALVES_MIN_SUPPORT, out)
    return out


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
    _kernels().volume_minima(volume, halves, best, half_best)
    # The median best cost is a scale: the pixels of a regular grid, about HALVES_MEDIAN_SAMPLE of
    # them, give it (to about 1 %) in a fraction of the whole image's time.
    stride = max(1, int(np.ceil(np.sqrt(h * w / HALVES_MEDIAN_SAMPLE))))
    sample = best[::stride, ::stride]
    sample = sample[np.isfinite(sample)]
    if not sample.size:
        return 0.0
    take = (best > HALVES_POOR * float(np.median(sample))) & (half_best < HALVES_GAIN * best)
    if take.any():
        _kernels().take_where(volume, halves, take)
    return float(take.mean())


def slice_cost(lum_w: np.ndarray, wts: np.ndarray, cost: str, window_px: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel cost of one hypothesis from warped luminances (V, h, w) premultiplied by their
    warped masks ``wts`` (V, h, w); returns (cost before aggregation, number of views)."""
    nview = wts.sum(axis=0)
    if cost == "zncc":
        return zncc_cost(lum_w, wts, nview, window_px), nview
    if cost in ("lcn", "lcn-halves", "lcn-occlusion"):
        # lum_w: the warped locally normalised luminances (lcn_sources) times their masks
        # (for 'lcn-occlusion' the cost of all views; occlusion_aggregate adds the leave-one-outs)
        return lcn_cost(lum_w.sum(axis=0), np.square(lum_w).sum(axis=0), nview), nview
    safe = np.maximum(nview, WEIGHT_FLOOR)
    vals = lum_w / np.maximum(wts, WEIGHT_FLOOR)
    valid = wts > 0.5
    mean = (lum_w.sum(axis=0)) / safe
    if cost in ("sad", "sad-occlusion"):
        dev = np.abs(vals - mean) * valid
        if cost == "sad-occlusion":
            worst = dev.max(axis=0)
            n = valid.sum(axis=0)
            c = (dev.sum(axis=0) - np.where(n > 2, worst, 0.0)) / np.maximum(n - (n > 2), 1)
        else:
            c = dev.sum(axis=0) / np.maximum(valid.sum(axis=0), 1)
    else:  # ssd
        c = ((vals - mean) ** 2 * valid).sum(axis=0) / np.maximum(valid.sum(axis=0), 1)
    return c.astype(np.float32), nview


def zncc_cost(lum_w: np.ndarray, wts: np.ndarray, nview: np.ndarray, window_px: int) -> np.ndarray:
    """One minus the mean, over the views valid at a pixel, of the zero-normalised
    cross-correlation over the window of each view with the views' weighted mean.

    The same numbers as the textbook expression (box means, variances clamped at 1e-8), computed
    with in-place float32 operations: a slice costs a few dozen passes over the image."""
    k = window_px
    mean = lum_w.sum(axis=0)
    np.divide(mean, np.maximum(nview, WEIGHT_FLOOR), out=mean)
    mu_m = box_filter(mean, k)
    t = np.multiply(mean, mean)
    var_m = box_filter(t, k)
    var_m -= mu_m * mu_m
    np.maximum(var_m, 1e-8, out=var_m)
    np.sqrt(var_m, out=var_m)  # now the standard deviation of the mean
    acc = np.zeros_like(mean)
    nvalid = np.zeros_like(mean)
    vj = np.empty_like(mean)
    valid = np.empty_like(mean)
    mu_j = np.empty_like(mean)
    s2 = np.empty_like(mean)
    cov = np.empty_like(mean)
    for j in range(len(lum_w)):
        np.greater(wts[j], 0.5, out=valid, casting="unsafe")
        nvalid += valid
        np.maximum(wts[j], WEIGHT_FLOOR, out=vj)
        np.divide(lum_w[j], vj, out=vj)
        vj *= valid
        box_filter(vj, k, dst=mu_j)
        np.multiply(vj, vj, out=t)
        box_filter(t, k, dst=s2)
        np.multiply(vj, mean, out=t)
        box_filter(t, k, dst=cov)
        # cov / sqrt(var_j var_m), var_j = max(E[v^2] - E[v]^2, 1e-8)
        np.multiply(mu_j, mu_m, out=t)
        cov -= t
        np.multiply(mu_j, mu_j, out=t)
        s2 -= t
        np.maximum(s2, 1e-8, out=s2)
        np.sqrt(s2, out=s2)
        s2 *= var_m
        cov /= s2
        cov *= valid
        acc += cov
    np.maximum(nvalid, 1.0, out=nvalid)
    acc /= nvalid
    np.subtract(1.0, acc, out=acc)
    return acc


def seen_mean(c: np.ndarray, seen: np.ndarray, window) -> np.ndarray:
    """The mean of ``c`` over the ``seen`` pixels of each window: ``window(c s) / window(s)`` with
    s = 1 where ``seen`` and 0 elsewhere (a normalised convolution, so a window at the edge of
    what the views see is not pulled towards an arbitrary value); inf where not ``seen``.

    Parameters
    ----------
    c : (h, w) float array
    seen : (h, w) bool array
    window : callable
        A linear window filter (h, w) float32 -> (h, w) float32: a box, a guided filter.

    Examples
    --------
    >>> import numpy as np
    >>> from lfring.core.filters import box_filter
    >>> c = np.array([[1.0, 1.0, 9.0]], np.float32)
    >>> seen_mean(c, np.array([[True, True, False]]), lambda x: box_filter(x, 3)).tolist()
    [[1.0, 1.0, inf]]
    """
    out = window(np.where(seen, c, np.float32(0.0)).astype(np.float32))
    if not seen.all():
        out /= np.maximum(window(seen.astype(np.float32)), np.float32(WEIGHT_FLOOR))
        out[~seen] = np.inf
    return out


def box_mean_of_finite(c: np.ndarray, box_px: int, scratch: np.ndarray | None = None) -> np.ndarray:
    """:func:`seen_mean` of a float32 (h, w) ``c`` over its finite pixels with a ``box_px`` box
    (odd; borders reflected as ``cv2.BORDER_REFLECT_101``), in place; inf where ``c`` is not
    finite. Compiled: float64 running sums, rows in parallel on numba's threads. ``scratch``: an
    (h, w) float32 buffer, optional.

    Examples
    --------
    >>> import numpy as np
    >>> c = np.array([[2.0, 2.0, np.inf, 4.0]], np.float32)
    >>> box_mean_of_finite(c, 3).tolist()  # pixel 3's box holds 4 and inf (twice, reflected)
    [[2.0, 2.0, inf, 4.0]]
    """
    import numba

    if not isinstance(c, np.ndarray) or c.dtype != np.float32 or c.ndim != 2:
        raise InvalidInputError(f"c must be a float32 (h, w) array, got {getattr(c, 'dtype', type(c))} {np.shape(c)}")
    check_odd_px("box_px", box_px)
    out = np.empty_like(c) if scratch is None else scratch
    if out.shape != c.shape or out.dtype != np.float32:
        raise InvalidInputError(f"scratch must be float32 {c.shape}, got {out.dtype} {out.shape}")
    _kernels().finite_box_mean(c, int(box_px) // 2, WEIGHT_FLOOR, 4 * numba.get_num_threads(), out)
    np.copyto(c, out)
    return c


def least_over_windows(volume: np.ndarray, box_px: int, *, out: np.ndarray | None = None, threads: int = 1) -> np.ndarray:
    """Shiftable windows: each slice of a cost volume eroded by a ``box_px`` square, the least cost
    of the ``box_px`` neighbourhood (borders ignored; inf only where the whole neighbourhood is).

    Of a cost aggregated over ``box_px`` boxes it is the least cost of every box that contains the
    pixel, not only of the box centred on it. Next to a depth edge one of those boxes lies on the
    pixel's own surface, so the texture of the surface beside it no longer pulls the pixel to its
    depth (the "foreground fattening" of window costs; Scharstein and Szeliski 2002, section 3.2).

    Parameters
    ----------
    volume : (N, h, w) float32, C-contiguous
        Costs; inf marks an unknown entry (NaN is refused: it is no cost).
    box_px : int
        Odd side of the neighbourhood.
    out : (N, h, w) float32, C-contiguous, optional
        The result's buffer (not ``volume``); allocated when not given.
    threads : int
        Slices are shared among this many threads.

    Examples
    --------
    >>> import numpy as np
    >>> v = np.array([[[3.0, 1.0, 4.0, 5.0, np.inf, np.inf, np.inf]]], np.float32)
    >>> least_over_windows(v, 3).tolist()
    [[[1.0, 1.0, 1.0, 4.0, 5.0, inf, inf]]]
    """
    def usable(a) -> bool:
        return isinstance(a, np.ndarray) and a.dtype == np.float32 and a.ndim == 3 and a.flags.c_contiguous

    if not usable(volume) or min(volume.shape) < 1:
        raise InvalidInputError(f"volume must be a non-empty C-contiguous float32 (N, h, w) array, got "
                                f"{getattr(volume, 'dtype', type(volume).__name__)} {np.shape(volume)}")
    check_odd_px("box_px", box_px)
    threads = check_threads(threads, allow_none=False)
    if out is None:
        out = np.empty_like(volume)
    elif not usable(out) or out.shape != volume.shape or np.shares_memory(out, volume):
        raise InvalidInputError(f"out must be a C-contiguous float32 {volume.shape} array apart from volume, got "
                                f"{getattr(out, 'dtype', type(out).__name__)} {np.shape(out)}")
    # A box wider than twice the slice covers all of it from every pixel: the same minimum.
    side = min(int(box_px), 2 * max(volume.shape[1:]) + 1)
    square = np.ones((side, side), np.uint8)
    has_nan = []

    def one(k: int) -> None:
        # OpenCV's minimum would move a NaN. The check: 9 ms of the erosion's 50 at 1060^2 x 64 on
        # two threads, under 0.5 % of estimate_depth's call.
        if np.isnan(volume[k]).any():
            has_nan.append(k)
            return
        # Replicated borders, which the minimum ignores (OpenCV's default border value would
        # turn an all-inf neighbourhood at the border into FLT_MAX).
        cv2.erode(volume[k], square, dst=out[k], borderType=cv2.BORDER_REPLICATE)

    run_threads([lambda k=k: one(k) for k in range(len(volume))], threads)
    if has_nan:
        raise InvalidInputError(f"volume has NaN in slice {min(has_nan)}: mark unknown costs with inf")
    return out


def aggregation_window(guide, window_px: int):
    """The aggregation's linear window, (h, w) float32 -> (h, w) float32: ``guide`` (a guided
    filter) when given, else a box of ``window_px``."""
    return (lambda x: guide.filter(x)) if guide is not None else (lambda x: box_filter(x, window_px))


def aggregate(c, nv, guide, window_px):
    """Aggregate one cost slice over ``window_px`` (box) or with ``guide`` (a guided filter),
    over the pixels that at least 1.5 views see and whose cost is finite (:func:`seen_mean`);
    inf at the others."""
    return seen_mean(c, (nv >= 1.5) & np.isfinite(c), aggregation_window(guide, window_px))
