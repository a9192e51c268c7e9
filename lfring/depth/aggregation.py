"""Spatial aggregation of the sweep's cost slices, over the pixels the views see.

Every cost is aggregated over the pixels that at least 1.5 views see (:func:`aggregate`,
:func:`seen_mean`: a normalised convolution); pixels seen by fewer are inf. The window is a box
or an edge-aware guided filter (:func:`aggregation_window`; :class:`GuidedTorch` is the guided
filter's torch twin). The semi-global engine optimises the least of the aggregated costs of the
boxes that contain a pixel (:func:`least_over_windows`, shiftable windows) and fits its
sub-hypothesis parabola to a wider seen-pixel mean (:func:`box_mean_of_finite`).
"""

from __future__ import annotations

import cv2
import numpy as np

from lfring.core.filters import BoxTorch, box_filter
from lfring.core.threads import run_threads
from lfring.core.validate import check_odd_px, check_threads
from lfring.core.viewstack import WEIGHT_FLOOR
from lfring.errors import InvalidInputError

__all__ = ["AGGREGATIONS", "GUIDED_EPS", "GuidedTorch", "aggregate", "aggregation_window", "box_mean_of_finite",
           "guided_filter", "least_over_windows", "seen_mean"]

AGGREGATIONS = ("box", "guided")
# Regularisation of the guided aggregation (cv2.ximgproc.createGuidedFilter's eps; the torch twin the same).
GUIDED_EPS = 1e-3


def guided_filter(guide_image: np.ndarray, aggregate_px: int):
    """The guided aggregation's window: OpenCV's ximgproc guided filter of radius
    ``aggregate_px // 2`` on ``guide_image`` ((h, w) float32 in [0, 1])."""
    return cv2.ximgproc.createGuidedFilter(guide_image, aggregate_px // 2, GUIDED_EPS)


def aggregation_window(guide, window_px: int):
    """The aggregation's linear window, (h, w) float32 -> (h, w) float32: ``guide`` (a guided
    filter) when given, else a box of ``window_px``."""
    return (lambda x: guide.filter(x)) if guide is not None else (lambda x: box_filter(x, window_px))


def aggregate(c, nv, guide, window_px):
    """Aggregate one cost slice over ``window_px`` (box) or with ``guide`` (a guided filter),
    over the pixels that at least 1.5 views see and whose cost is finite (:func:`seen_mean`);
    inf at the others."""
    return seen_mean(c, (nv >= 1.5) & np.isfinite(c), aggregation_window(guide, window_px))


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

    from lfring.depth import aggregation_kernels

    if not isinstance(c, np.ndarray) or c.dtype != np.float32 or c.ndim != 2:
        raise InvalidInputError(f"c must be a float32 (h, w) array, got {getattr(c, 'dtype', type(c))} {np.shape(c)}")
    check_odd_px(box_px, "box_px")
    out = np.empty_like(c) if scratch is None else scratch
    if out.shape != c.shape or out.dtype != np.float32:
        raise InvalidInputError(f"scratch must be float32 {c.shape}, got {out.dtype} {out.shape}")
    aggregation_kernels.finite_box_mean(c, int(box_px) // 2, WEIGHT_FLOOR, 4 * numba.get_num_threads(), out)
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
    check_odd_px(box_px, "box_px")
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
        # OpenCV's minimum would move a NaN. The check costs a small part of the erosion and a
        # negligible part of estimate_depth's call.
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


class GuidedTorch:
    """OpenCV's ximgproc guided filter (radius k // 2, BORDER_REFLECT windows) with a fixed
    grey guide, applied to chunks of (C, h, w) cost slices; the guide's statistics are kept."""

    def __init__(self, torch, guide, k: int, eps: float, device):
        self.box = BoxTorch(torch, guide.shape, k, 0, device)
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
