"""Semi-global optimisation of a disparity-space cost volume, selection and confidence.

A plane sweep gives, for every pixel, a cost curve over N hypotheses evenly spaced in disparity.
Winner-take-all on that curve fails where the image has no texture (the curve is flat) and near
depth edges (the aggregation window straddles two surfaces). Semi-global matching (SGM,
Hirschmuller 2008) adds, along several 1-D scan paths through the image, a penalty ``p1`` for a
change of one hypothesis between neighbouring pixels and a larger penalty ``p2`` for any larger
jump; the per-path minima are summed into one aggregated volume, on which winner-take-all is run.

Functional interface::

    aggregated = sgm_aggregate(cost, guide=luminance)      # (N, h, w) float32
    index, confidence = select(aggregated, raw=cost)       # (h, w) float32 each
    confidence = combine_confidence(confidence, index, other_index)
    curve = sparsification_auc(error, confidence)          # how well confidence ranks errors

:mod:`lfring.depth.refine` turns ``index`` and ``confidence`` into an edge-aware refined map and
a hole-filled one.

The kernels (:mod:`lfring.depth.sgm_kernels`) are compiled with numba on first use (importing
lfring imports neither numba nor compiles anything): the very first call pays the compile time
(many seconds), and numba's on-disk cache serves every later process in a fraction of that.
:func:`sgm_aggregate_torch` is the torch twin of :func:`sgm_aggregate` (one line of a path per step).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from lfring.errors import InvalidInputError
from lfring.core.backend import require_torch, resolve_device
from lfring.core.threads import numba_threads
from lfring.core.validate import check_int, check_number, check_threads, is_integer

__all__ = [
    "PATHS",
    "P1_SCALE",
    "P2_SCALE",
    "EDGE_SCALE",
    "Sparsification",
    "check_guide",
    "check_paths",
    "check_penalty",
    "cost_scale",
    "edge_penalty",
    "sgm_aggregate",
    "sgm_aggregate_torch",
    "select",
    "combine_confidence",
    "sparsification_auc",
]

# Scan directions (dy, dx) of a path: a pixel's predecessor on the path is (y - dy, x - dx).
PATHS = {
    4: ((0, 1), (0, -1), (1, 0), (-1, 0)),
    8: ((0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (1, -1), (-1, 1), (-1, -1)),
}
# Default penalties, in units of the cost volume's own scale (see cost_scale): the penalties then
# follow the cost function (LCN variance, absolute differences, census) without retuning. Tuned
# on real stereo pairs with one pixel of motion per hypothesis (lfring's spacing): census and
# locally normalised absolute differences both did best near these values.
P1_SCALE = 1.0
P2_SCALE = 8.0
# Guide-luminance step (guide in [0, 1]) that halves p2: P2_eff = p2 / (1 + |dI| / s). On real
# stereo pairs steps from 0.04 to 0.1 measured better than no edge awareness.
EDGE_SCALE = 0.04
# Lines (columns or diagonals) per parallel task of the vertical and diagonal paths: the lines
# split into LINE_TASKS_PER_THREAD blocks per thread, of at least MIN_LINE_BLOCK lines. Longer
# blocks make longer vector loops: the vertical paths ran markedly faster in longer blocks, with
# the same numbers.
MIN_LINE_BLOCK = 64
LINE_TASKS_PER_THREAD = 2


def _line_block(lines: int) -> int:
    """Lines per parallel task for a path of ``lines`` lines on numba's current thread count."""
    import numba

    return max(MIN_LINE_BLOCK, -(-lines // (LINE_TASKS_PER_THREAD * numba.get_num_threads())))


_KERNEL_NAMES = {"fill": "fill_values", "horizontal": "horizontal", "lines": "lines", "select": "select_index",
                 "select_both": "select_index_both"}


def _kernel(name: str):
    """The compiled kernel ``name`` (:mod:`lfring.depth.sgm_kernels`): compiled on the first call
    of the first process, loaded from numba's on-disk cache after that."""
    try:
        from lfring.depth import sgm_kernels
    except ImportError as exc:  # pragma: no cover - numba is a core dependency
        raise InvalidInputError(f"semi-global matching needs numba ({exc}): pip install numba") from None
    return getattr(sgm_kernels, _KERNEL_NAMES[name])


# --------------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------------


def _check_cost(cost, name="cost") -> np.ndarray:
    a = np.asarray(cost)
    if a.ndim != 3:
        raise InvalidInputError(f"{name} must be a (N, h, w) cost volume, got shape {a.shape}: "
                                "stack one (h, w) cost slice per hypothesis along axis 0")
    if a.shape[0] < 1 or a.shape[1] < 1 or a.shape[2] < 1:
        raise InvalidInputError(f"{name} must not be empty, got shape {a.shape}")
    if not np.issubdtype(a.dtype, np.floating):
        raise InvalidInputError(f"{name} must be floating point (float32), got {a.dtype}: cast it with .astype(np.float32)")
    return np.ascontiguousarray(a, dtype=np.float32)


def check_guide(guide, shape) -> np.ndarray:
    """The guide of the edge-aware penalty as a contiguous (h, w) float32 luminance: an (h, w)
    image, or (h, w, 1 or 3) averaged over its channels; finite and numeric (not bool)."""
    try:
        g = np.asarray(guide)
    except (TypeError, ValueError):
        g = np.asarray(None)
    got = g.shape
    if g.ndim == 3 and g.shape[2] in (1, 3):
        g = g[..., 0] if g.dtype == bool else g.mean(axis=2)
    if g.shape != tuple(shape):
        raise InvalidInputError(f"guide must be an (h, w), (h, w, 1) or (h, w, 3) image of the cost's (h, w) = "
                                f"{tuple(shape)}, got shape {got}")
    if g.dtype == bool or not np.issubdtype(g.dtype, np.number) or not np.all(np.isfinite(g)):
        raise InvalidInputError("guide must be a finite numeric image (luminance in [0, 1])")
    return np.ascontiguousarray(g, dtype=np.float32)


def check_penalty(value, name, *, allow_zero=True) -> float:
    """A penalty or scale as a float: finite, >= 0 (> 0 unless ``allow_zero``), a real number."""
    v = check_number(value, name)
    if v < 0 or (v == 0 and not allow_zero):
        raise InvalidInputError(f"{name} must be {'>= 0' if allow_zero else '> 0'} and finite, got {value!r}")
    return v


# --------------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------------


def check_paths(paths) -> int:
    """``paths`` as one of :data:`PATHS`' keys (an integer, 4 or 8)."""
    if not is_integer(paths) or int(paths) not in PATHS:
        raise InvalidInputError(f"paths must be one of {sorted(PATHS)}, got {paths!r}")
    return int(paths)


def cost_scale(cost, *, max_pixels: int = 1 << 14) -> float:
    """Typical height of a pixel's cost curve above its minimum: the unit of the default penalties.

    Parameters
    ----------
    cost : (N, h, w) float array
        Cost volume; non-finite entries are ignored.
    max_pixels : int
        Pixels sampled on a regular grid (the scale is a median, so a sample is enough).

    Returns
    -------
    float
        ``median_p (mean_d C(p, d) - min_d C(p, d))`` over sampled pixels with at least two finite
        costs; 1.0 when there is none or the median is zero.
    """
    c = _check_cost(cost)
    n, h, w = c.shape
    stride = max(1, int(math.ceil(math.sqrt(h * w / max_pixels))))
    s = c[:, ::stride, ::stride].reshape(n, -1)
    finite = np.isfinite(s)
    ok = finite.sum(axis=0) >= 2
    if not ok.any():
        return 1.0
    s = s[:, ok]
    fin = finite[:, ok]
    mean = np.where(fin, s, 0).sum(axis=0) / fin.sum(axis=0)
    low = np.where(fin, s, np.inf).min(axis=0)
    scale = float(np.median(mean - low))
    return scale if scale > 0 and math.isfinite(scale) else 1.0


def edge_penalty(guide_a, guide_b, *, p1: float, p2: float, edge_scale: float):
    """The large-jump penalty between neighbouring pixels with guide values ``a`` and ``b``.

    ``P2_eff = max(p1, p2 / (1 + |a - b| / edge_scale))``, in float32 like the kernels.
    """
    a = np.asarray(guide_a, np.float32)
    b = np.asarray(guide_b, np.float32)
    p1 = np.float32(p1)
    p2 = np.float32(p2)
    return np.maximum(p1, (p2 / (np.float32(1.0) + np.abs(a - b) / np.float32(edge_scale))).astype(np.float32))


def sgm_aggregate(cost, *, guide=None, p1: float | None = None, p2: float | None = None, paths: int = 4,
                  edge_scale: float | None = EDGE_SCALE, threads: int | None = None) -> np.ndarray:
    """Semi-global aggregation of a cost volume along 4 or 8 scan paths.

    Parameters
    ----------
    cost : (N, h, w) float array
        Matching cost of N hypotheses evenly spaced in disparity (lower is better, >= 0 for the
        confidence of :func:`select` to mean anything). NaN or inf marks an invalid entry; it is
        replaced by the mean of the pixel's finite costs (0 where none is finite), a neutral value
        that neither attracts nor repels the path minimum.
    guide : (h, w) or (h, w, C) float array, optional
        Reference image (luminance in [0, 1]). When given, the large-jump penalty is lowered
        across its edges (see Notes), so depth edges may follow image edges.
    p1, p2 : float, optional
        Penalties for a change of one hypothesis and of more than one between neighbouring pixels
        on a path, in cost units. Default: ``P1_SCALE`` and ``P2_SCALE`` times
        :func:`cost_scale` of ``cost``. ``p2`` is raised to ``p1`` if smaller.
    paths : {4, 8}
        4: left-right, right-left, top-bottom, bottom-top; 8 adds the four diagonals.
    edge_scale : float or None
        Guide step that halves ``p2`` (ignored without a guide; None: no edge awareness).
    threads : int, optional
        numba threads for this call (default: numba's current setting).

    Returns
    -------
    aggregated : (N, h, w) float32
        ``S(p, d) = sum_r L_r(p, d)``, finite everywhere while ``paths * (max C + p2)`` is
        (costs below about 1e37).

    Notes
    -----
    Along a path r through pixel p with predecessor p - r:

    .. math::

        L_r(p, d) = C(p, d) + \\min\\big(L_r(p-r, d),\\ L_r(p-r, d\\pm 1) + P_1,\\
                    \\min_k L_r(p-r, k) + P_2^{eff}(p)\\big) - \\min_k L_r(p-r, k)

    with :math:`L_r = C` at the first pixel of a path, and the edge-aware large-jump penalty

    .. math::

        P_2^{eff}(p) = \\max\\big(P_1,\\ P_2 / (1 + |I(p) - I(p-r)| / s_{edge})\\big).

    The subtraction keeps :math:`L_r - C` within [0, P_2], so float32 is exact enough for any
    volume: values stay below ``paths * (max C + p2)``.

    Memory: the result (N, h, w) float32 is the only volume allocated (the input is read, not
    copied, when it is C-contiguous float32); the horizontal paths keep two (w, N) float32
    rows per task (one image row), the others two (N, B) buffers per task of B lines (the lines
    split into ``LINE_TASKS_PER_THREAD`` blocks per thread, at least ``MIN_LINE_BLOCK`` lines).
    The result takes 4 N h w bytes (plus the caller's cost volume of the same size); a uint16
    accumulator would halve it but needs integer costs and saturating sums, not worth the loss
    of the float cost's resolution. Time grows as paths * N * h * w.

    Examples
    --------
    >>> import numpy as np
    >>> from lfring.depth.sgm import sgm_aggregate, select
    >>> cost = np.ones((5, 3, 4), np.float32)
    >>> cost[2] = 0.0
    >>> cost[:, 1, 1] = 1.0                     # a pixel with no information
    >>> index, confidence = select(sgm_aggregate(cost, p1=0.1, p2=0.5))
    >>> index[1, 1]                             # filled in by its neighbours
    np.float32(2.0)
    """
    c = _check_cost(cost)
    paths = check_paths(paths)
    threads = check_threads(threads)
    n, h, w = c.shape
    if p1 is None or p2 is None:
        scale = cost_scale(c)
        p1 = P1_SCALE * scale if p1 is None else p1
        p2 = P2_SCALE * scale if p2 is None else p2
    p1 = check_penalty(p1, "p1")
    p2 = max(check_penalty(p2, "p2"), p1)
    use_guide = guide is not None and edge_scale is not None
    if use_guide:
        edge_scale = check_penalty(edge_scale, "edge_scale", allow_zero=False)
        g = check_guide(guide, (h, w))
    else:
        g = np.zeros((1, 1), np.float32)
        edge_scale = 1.0
    f32 = np.float32
    out = np.zeros((n, h, w), np.float32)
    with numba_threads(threads):
        fill = np.empty((h, w), np.float32)
        _kernel("fill")(c, fill)
        directions = PATHS[paths]
        _kernel("horizontal")(c, fill, g, use_guide, f32(p1), f32(p2), f32(edge_scale), out,
                              (0, 1) in directions, (0, -1) in directions)
        for dy, dx in directions:
            if dy != 0:
                lines = w if dx == 0 else w + h - 1
                _kernel("lines")(c, fill, g, use_guide, f32(p1), f32(p2), f32(edge_scale), out, dy, dx, _line_block(lines))
    return out


def select(aggregated, raw=None, *, exclude: int = 1, threads: int | None = None,
           raw_distinctness: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Winner-take-all with a sub-hypothesis parabola and the distinctness confidence.

    Parameters
    ----------
    aggregated : (N, h, w) float array
        The cost to minimise (usually :func:`sgm_aggregate`'s result).
    raw : (N, h, w) float array, optional
        When given, the parabola is fitted to ``raw`` (the cost before SGM) at the aggregated
        winner's index and its two neighbours; otherwise to ``aggregated`` (see Notes).
    exclude : int
        Hypotheses within ``exclude`` of the winner are not candidates for the second best.
    threads : int, optional
        numba threads for this call.
    raw_distinctness : bool
        With ``raw``: the confidence times ``raw``'s own distinctness (the confidence
        ``select(raw)`` gives), in the same pass.

    Returns
    -------
    index : (h, w) float32
        Fractional hypothesis index ``k* + delta``, delta in [-0.5, 0.5]; NaN where the whole
        curve is non-finite.
    confidence : (h, w) float32 in [0, 1]
        ``1 - S(k*) / min_{|k - k*| > exclude} S(k)``; 0 where undefined.

    Notes
    -----
    With c_-, c_0, c_+ the costs at k* - 1, k*, k* + 1, ``delta = (c_- - c_+) / (2 (c_- - 2 c_0
    + c_+))`` when the curvature is positive, else 0. At the first or last hypothesis the parabola
    goes through it and the next two inwards, and delta is its vertex clamped to [0, 0.5] inwards
    (0 unless it curves up): a surface just inside the range's end would otherwise come out at the
    end, as it did on the synthetic twin's textured surfaces.
    The aggregated curve is piecewise smooth in P1 steps around its minimum and biases delta
    towards 0 ("pixel locking"); the raw curve keeps the sub-hypothesis information but is noisy.
    On a slanted plane both fits are about equally accurate; on real stereo pairs the aggregated
    fit measured slightly better before a left-right check and as good after it; hence the
    default fits the aggregated curve.
    """
    agg = _check_cost(aggregated, "aggregated")
    threads = check_threads(threads)
    n, h, w = agg.shape
    if raw is not None:
        r = _check_cost(raw, "raw")
        if r.shape != agg.shape:
            raise InvalidInputError(f"raw must have the aggregated volume's shape {agg.shape}, got {r.shape}")
    else:
        r = np.zeros((1, 1, 1), np.float32)
    check_int(exclude, "exclude", minimum=0)
    index = np.empty((h, w), np.float32)
    conf = np.empty((h, w), np.float32)
    if raw_distinctness and raw is None:
        raise InvalidInputError("raw_distinctness needs the raw volume")
    with numba_threads(threads):
        if raw_distinctness:
            _kernel("select_both")(agg, r, int(exclude), index, conf)
            return index, conf
        fill = np.empty((h, w), np.float32)
        if raw is not None:
            _kernel("fill")(r, fill)
        _kernel("select")(agg, r, fill, raw is not None, int(exclude), index, conf)
    return index, conf


def combine_confidence(confidence, index, other_index, *, tolerance: float = 1.0) -> np.ndarray:
    """Distinctness times agreement with a second, independent estimate of the same map.

    Parameters
    ----------
    confidence : (h, w) float array in [0, 1]
        Distinctness from :func:`select`.
    index, other_index : (h, w) float arrays
        Two estimates in the same units (for example the SGM result and the winner-take-all of
        the raw cost, or the result seen from another reference view mapped back).
    tolerance : float
        Disagreement (in the units of ``index``) at which the agreement factor is exp(-1/2).

    Returns
    -------
    (h, w) float32 in [0, 1]
        ``confidence * exp(-(index - other_index)^2 / (2 tolerance^2))``; 0 where either estimate
        is NaN.
    """
    c = np.asarray(confidence, np.float32)
    a = np.asarray(index, np.float32)
    b = np.asarray(other_index, np.float32)
    if not (c.shape == a.shape == b.shape) or c.ndim != 2:
        raise InvalidInputError(f"confidence, index and other_index must be (h, w) arrays of one shape, "
                                f"got {c.shape}, {a.shape}, {b.shape}")
    tol = check_penalty(tolerance, "tolerance", allow_zero=False)
    diff = a - b
    agree = np.exp(-0.5 * (diff / np.float32(tol)) ** 2)
    out = np.where(np.isfinite(diff), np.clip(c, 0, 1) * agree, 0.0)
    return out.astype(np.float32)


class Sparsification(NamedTuple):
    """Sparsification curves of an error map ranked by a confidence map.

    Attributes
    ----------
    auc, oracle_auc, random_auc : float
        Mean of the curve over the kept fractions, for the confidence ranking, for the ranking by
        the error itself (the best possible), and for no ranking (the overall mean error).
    fractions : (K,) float64
        Fractions of the most confident pixels kept, ``1/K, 2/K, ..., 1``.
    curve, oracle_curve : (K,) float64
        Mean absolute error of the kept pixels.
    """

    auc: float
    oracle_auc: float
    random_auc: float
    fractions: np.ndarray
    curve: np.ndarray
    oracle_curve: np.ndarray


def sparsification_auc(error, confidence, *, mask=None, steps: int = 20) -> Sparsification:
    """How well a confidence ranks errors: the area under the sparsification curve.

    Parameters
    ----------
    error : (h, w) float array
        Per-pixel error (its absolute value is used); NaN pixels are left out.
    confidence : (h, w) float array
        Higher means more trustworthy; NaN counts as the least confident.
    mask : (h, w) bool array, optional
        Pixels to evaluate.
    steps : int
        Number of kept fractions K.

    Returns
    -------
    Sparsification
        ``auc`` between ``oracle_auc`` (perfect ranking) and ``random_auc`` (no ranking) when the
        confidence helps; smaller is better.

    Notes
    -----
    For the kept fraction f, the curve is the mean |error| over the ceil(f M) most confident of
    the M evaluated pixels (ties broken by a stable sort); the AUC is the mean over f = k/K.

    Examples
    --------
    >>> import numpy as np
    >>> err = np.array([[0.0, 1.0], [2.0, 3.0]])
    >>> s = sparsification_auc(err, -err, steps=4)
    >>> float(s.auc) == float(s.oracle_auc)
    True
    """
    e = np.abs(np.asarray(error, np.float64))
    c = np.asarray(confidence, np.float64)
    if e.shape != c.shape:
        raise InvalidInputError(f"error and confidence must have one shape, got {e.shape} and {c.shape}")
    check_int(steps, "steps", minimum=1)
    keep = np.isfinite(e)
    if mask is not None:
        m = np.asarray(mask, bool)
        if m.shape != e.shape:
            raise InvalidInputError(f"mask must have the error's shape {e.shape}, got {m.shape}")
        keep &= m
    e = e[keep]
    c = np.nan_to_num(c[keep], nan=-np.inf)
    if e.size == 0:
        raise InvalidInputError("no pixel to evaluate: the mask is empty or every error is NaN")
    fractions = np.arange(1, steps + 1) / steps
    counts = np.maximum(1, np.ceil(fractions * e.size).astype(np.int64))

    def curve_of(order):
        cum = np.cumsum(e[order])
        return cum[counts - 1] / counts

    curve = curve_of(np.argsort(-c, kind="stable"))
    oracle = curve_of(np.argsort(e, kind="stable"))
    return Sparsification(float(curve.mean()), float(oracle.mean()), float(e.mean()), fractions, curve, oracle)


# --------------------------------------------------------------------------------------------
# The torch twin of sgm_aggregate
# --------------------------------------------------------------------------------------------


def _neutral(c, torch):
    finite = torch.isfinite(c)
    count = finite.sum(dim=0)
    total = torch.where(finite, c, torch.zeros((), dtype=c.dtype, device=c.device)).double().sum(dim=0)
    mean = torch.where(count > 0, total / count.clamp(min=1), torch.zeros_like(total)).float()
    return torch.where(finite, c, mean.unsqueeze(0))


def _step(prev, pmin, c, p1, p2e, torch):
    """One step of the recursion for a whole line: prev, c (N, M); pmin, p2e (M,)."""
    inf = torch.full_like(prev[:1], float("inf"))
    down = torch.cat([inf, prev[:-1]], dim=0) + p1  # prev[d - 1] + p1
    up = torch.cat([prev[1:], inf], dim=0) + p1  # prev[d + 1] + p1
    best = torch.minimum(torch.minimum(torch.minimum(prev, down), up), (pmin + p2e).unsqueeze(0))
    return c + (best - pmin.unsqueeze(0))


def _p2_line(g_cur, g_prev, p1, p2, edge_scale, torch):
    one = torch.ones((), dtype=torch.float32, device=g_cur.device)
    return torch.maximum(p1, p2 / (one + torch.abs(g_cur - g_prev) / edge_scale))


def sgm_aggregate_torch(cost, *, guide=None, p1: float | None = None, p2: float | None = None, paths: int = 4,
                        edge_scale: float | None = EDGE_SCALE, device=None):
    """Semi-global aggregation in torch; same arguments and result as :func:`~lfring.depth.sgm.sgm_aggregate`.

    Parameters
    ----------
    cost : (N, h, w) float array or tensor
        Cost volume; NaN or inf are invalid (see :func:`lfring.depth.sgm.sgm_aggregate`).
    guide : (h, w) array or tensor, optional
        Reference luminance in [0, 1] for the edge-aware large-jump penalty.
    p1, p2, paths, edge_scale
        As in :func:`lfring.depth.sgm.sgm_aggregate`.
    device : str or torch.device, optional
        Where to compute (default: the tensor's device, or CUDA when available for arrays).

    Returns
    -------
    (N, h, w) float32
        A NumPy array when ``cost`` is a NumPy array, otherwise a tensor on ``device``.
    """
    torch = require_torch()
    is_tensor = isinstance(cost, torch.Tensor)
    if is_tensor:
        dev = cost.device if device is None else resolve_device(device)
        c = cost.detach().to(dev)
    else:
        a = np.asarray(cost)
        dev = resolve_device(device)
        c = torch.from_numpy(np.ascontiguousarray(a)).to(dev) if a.dtype.kind == "f" else None
        if c is None:
            raise InvalidInputError(f"cost must be floating point (float32), got {a.dtype}")
    if c.ndim != 3 or min(c.shape) < 1:
        raise InvalidInputError(f"cost must be a non-empty (N, h, w) cost volume, got shape {tuple(c.shape)}")
    if not c.is_floating_point():
        raise InvalidInputError(f"cost must be floating point (float32), got {c.dtype}")
    paths = check_paths(paths)
    c = c.float()
    n, h, w = c.shape
    if p1 is None or p2 is None:
        scale = cost_scale(c.cpu().numpy())
        p1 = P1_SCALE * scale if p1 is None else p1
        p2 = P2_SCALE * scale if p2 is None else p2
    p1 = check_penalty(p1, "p1")
    p2 = max(check_penalty(p2, "p2"), p1)
    f32 = torch.float32
    tp1 = torch.tensor(np.float32(p1), dtype=f32, device=dev)
    tp2 = torch.tensor(np.float32(p2), dtype=f32, device=dev)
    use_guide = guide is not None and edge_scale is not None
    if use_guide:
        edge_scale = check_penalty(edge_scale, "edge_scale", allow_zero=False)
        # The numba version's checks and luminance (an (h, w) image of guide values is small).
        g = torch.from_numpy(check_guide(guide.detach().cpu().numpy() if isinstance(guide, torch.Tensor) else guide,
                                         (h, w))).to(dev)
        tes = torch.tensor(np.float32(edge_scale), dtype=f32, device=dev)
    c = _neutral(c, torch)
    out = torch.zeros_like(c)
    with torch.no_grad():
        for dy, dx in PATHS[paths]:
            if dy == 0:  # horizontal: the line is a column of all rows, stepping along x
                xs = range(w) if dx > 0 else range(w - 1, -1, -1)
                prev = pmin = None
                for x in xs:
                    cx = c[:, :, x]
                    if prev is None:
                        cur = cx.clone()
                    else:
                        p2e = _p2_line(g[:, x], g[:, x - dx], tp1, tp2, tes, torch) if use_guide else tp2.expand(h)
                        cur = _step(prev, pmin, cx, tp1, p2e, torch)
                    out[:, :, x] += cur
                    prev, pmin = cur, cur.min(dim=0).values
                continue
            ys = range(h) if dy > 0 else range(h - 1, -1, -1)
            has_pred = torch.ones(w, dtype=torch.bool, device=dev)
            if dx == 1:
                has_pred[0] = False
            elif dx == -1:
                has_pred[-1] = False
            prev = pmin = None
            for y in ys:
                cy = c[:, y, :]
                if prev is None:
                    cur = cy.clone()
                else:
                    # The predecessor of (y, x) is (y - dy, x - dx): shift the previous line by dx.
                    sp = torch.roll(prev, shifts=dx, dims=1) if dx else prev
                    spm = torch.roll(pmin, shifts=dx, dims=0) if dx else pmin
                    if use_guide:
                        gp = torch.roll(g[y - dy], shifts=dx, dims=0) if dx else g[y - dy]
                        p2e = _p2_line(g[y], gp, tp1, tp2, tes, torch)
                    else:
                        p2e = tp2.expand(w)
                    cur = torch.where(has_pred.unsqueeze(0), _step(sp, spm, cy, tp1, p2e, torch), cy)
                out[:, y, :] += cur
                prev, pmin = cur, cur.min(dim=0).values
    if is_tensor:
        return out
    return out.cpu().numpy()
