"""Selecting each pixel's depth from a sweep's costs: the streamed running minimum, the
sub-hypothesis parabola, the confidence, and the finisher that turns hypothesis indices into
a :class:`DepthResult`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from lfring.core.records import record_repr
from lfring.errors import warn_caller

__all__ = ["COST_FLOOR", "DepthResult", "Finisher", "RunningMinimum", "RunningMinimumTorch", "parabola", "refine"]

COST_FLOOR = 1e-9
"""Costs this small are float rounding, not texture (a real frame's least costs are thousands of
times larger, its noise alone: on the bundled scene 4e-4 for 'lcn' and 5e-6 for 'ssd' at the 1st
percentile): added to both costs of the confidence ratio, so that two rounding errors (on
featureless views, 1e-16 against 1e-15) make no confident pixel."""


@dataclass(frozen=True, eq=False)
class DepthResult:
    """A depth map in the reference frame.

    Attributes
    ----------
    depth_m : (h, w) float32
        Distance from the main lens in metres; NaN where fewer than ``min_views`` views see the
        pixel, and for the 'sgm' method with the left-right check (``consistency``) also where
        the check fails or the confidence is below ``lfring.depth.refine.MIN_CONFIDENCE``.
    confidence : (h, w) float32 in [0, 1]
        How distinct the best hypothesis is: 1 - best cost / best cost away from it.
    hypothesis_index : (h, w) float32
        The disparity-space result: the refined (fractional) index into ``depths_m``, which are
        evenly spaced in 1/(Z - z0), i.e. in disparity.
    depths_m : (N,) float64
        The hypotheses.
    step_px : float
        Largest motion of any view pixel between neighbouring hypotheses.
    reference : 'center' or int
    cost, aggregation, method : str
        The settings that made it (see :func:`lfring.estimate_depth`).
    depth_filled_m : (h, w) float32 or None
        The 'sgm' method's depth with the unconfident pixels filled from confident neighbours of
        the same image region (an estimate, not a measurement); known wherever ``depth_m`` is;
        NaN where fewer than ``min_views`` views see the pixel, and where ``depth_m`` is NaN and
        strong image edges cut the pixel off from every confident one. None for the 'local'
        method.
    paths : int or None
        The 'sgm' method's scan paths; None for 'local'.
    consistency : bool or None
        Whether the 'sgm' method ran the left-right check (its default decided for the number
        of views); None for 'local'.
    """

    depth_m: np.ndarray
    confidence: np.ndarray
    hypothesis_index: np.ndarray
    depths_m: np.ndarray
    step_px: float
    reference: object
    cost: str
    aggregation: str
    method: str = "local"
    depth_filled_m: np.ndarray | None = None
    paths: int | None = None
    consistency: bool | None = None

    __repr__ = record_repr

    def to_points(self, calibration, *, colors=None, min_confidence: float = 0.0, device=None):
        """Metric 3D points of the map's known pixels, as ``lfring depth`` writes them to PLY (which
        keeps the pixels at its ``--min-confidence``, 0.5 by default; here ``min_confidence``).

        Parameters
        ----------
        calibration : RingCalibration
            The calibration the map was estimated with.
        colors : (h, w, 3) ndarray, optional
            uint8, or float in [0, 1] (linear; sRGB-encoded as the PLY's colours): e.g. the
            views' mean for the 'center' reference.
        min_confidence : float
            Keep only pixels at least this confident.
        device : RingDevice or str, optional
            The camera's optics; by default the device the calibration was made with (its
            record, else the built-in device it names; else the prototype, with a warning),
            binned to its frames (:func:`lfring.depth.io.device_for`).

        Returns
        -------
        points : (N, 3) float64
            (X, Y, Z) in metres: X right, Y down, Z forward from the main lens.
        colors : (N, 3) uint8 or None

        Examples
        --------
        >>> import numpy as np
        >>> import lfring
        >>> cal = lfring.RingCalibration.load("twin_binned2")
        >>> views = lfring.split_views(lfring.demosaic(lfring.load_raw("data/synthetic/scene.png")), cal)
        >>> depth = lfring.estimate_depth(views, cal, zmin_m=0.3, zmax_m=1.0, method="local")
        >>> points, colors = depth.to_points(cal, colors=views.mean(axis=0), min_confidence=0.5)
        >>> points.shape[1], colors.dtype.name, bool(0.25 < np.median(points[:, 2]) < 1.05)
        (3, 'uint8', True)
        """
        from lfring.core.protocols import check_calibration
        from lfring.depth.io import depth_to_points, device_for

        check_calibration(calibration)
        optics = device_for(calibration, device)
        if device is None and calibration.device_optics() is None:
            warn_caller("the calibration names no device: the points take the ring prototype's optics, which may not "
                        "be the camera's (pass device=, or calibrate with the camera's device)")
        return depth_to_points(self.depth_m, optics, calibration.layout, self.reference, colors=colors,
                               confidence=self.confidence, min_confidence=min_confidence)


class RunningMinimum:
    """Streamed argmin over hypotheses with what refinement and confidence need, per pixel:
    the best cost and its (first) index, its neighbours' costs, and the best cost more than
    ``exclude`` hypotheses away from the final best. That last one is exact: the minimum over
    the slices before the best (a prefix minimum lagging ``exclude + 1`` slices, copied when
    the best moves) and over the slices after it (restarted when the best moves); the tracker
    keeps the last ``exclude + 2`` slices for it. OpenCV masked copies throughout: NumPy's
    masked assignments are many times slower on these arrays."""

    def __init__(self, shape, exclude: int = 1):
        self.exclude = e = max(1, int(exclude))
        inf = lambda: np.full(shape, np.inf, np.float32)
        self.best, self.c_prev, self.c_next, self.far_lo, self.far_hi, self.prefix = (inf() for _ in range(6))
        self.best_i = np.zeros(shape, np.int32)
        self.ring = [np.empty(shape, np.float32) for _ in range(e + 2)]  # slices i - e - 1 .. i
        self._inf = inf()
        self._idx = np.empty(shape, np.int32)
        self._tmp = np.empty(shape, np.float32)
        self._mask = np.empty(shape, np.uint8)
        self._new = np.empty(shape, np.uint8)
        self.i = 0

    def slot(self) -> np.ndarray:
        """The buffer to write the next slice into (then call :meth:`push`)."""
        return self.ring[self.i % len(self.ring)]

    def push(self) -> None:
        """Take in the slice written into :meth:`slot`: update the best cost and its index, its
        neighbours' costs and the minimum away from the best.
        """
        i, e, ring = self.i, self.exclude, self.ring
        cur = ring[i % len(ring)]
        if i >= e + 1:
            cv2.min(self.prefix, ring[(i - e - 1) % len(ring)], dst=self.prefix)  # min over slices <= i - e - 1
        if i >= 1:
            cv2.compare(self.best_i, i - 1, cv2.CMP_EQ, dst=self._mask)
            cv2.copyTo(cur, self._mask, dst=self.c_next)
            cv2.compare(self.best_i, i - e, cv2.CMP_LT, dst=self._mask)  # slice i is far after the best
            cv2.min(self.far_hi, cur, dst=self._tmp)
            cv2.copyTo(self._tmp, self._mask, dst=self.far_hi)
        new = cv2.compare(cur, self.best, cv2.CMP_LT, dst=self._new)
        cv2.copyTo(cur, new, dst=self.best)
        self._idx.fill(i)
        cv2.copyTo(self._idx, new, dst=self.best_i)
        if i >= 1:
            cv2.copyTo(ring[(i - 1) % len(ring)], new, dst=self.c_prev)
            cv2.copyTo(self._inf, new, dst=self.c_next)
            cv2.copyTo(self._inf, new, dst=self.far_hi)
        if i >= e + 1:
            cv2.copyTo(self.prefix, new, dst=self.far_lo)
        self.i += 1

    def second(self) -> np.ndarray:
        """The best cost more than ``exclude`` hypotheses away from the best, per pixel.

        Returns
        -------
        (h, w) float32
        """
        return np.minimum(self.far_lo, self.far_hi)


class RunningMinimumTorch:
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
        """Fold a chunk of slices (C, h, w), one after the other."""
        for a in aggs:
            self.push(a)

    def push(self, cur) -> None:
        """Fold the next slice (h, w)."""
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
        """The lowest cost more than ``exclude`` hypotheses from the best, (h, w)."""
        return self.torch.minimum(self.far_lo, self.far_hi)


def parabola(a, b, c):
    """Offset of the minimum of the parabola through (-1, a), (0, b), (1, c), within +-0.5;
    0 where a neighbour is missing (inf) or the curve is not convex. float32."""
    a, b, c = (np.asarray(x, np.float32) for x in (a, b, c))
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        denom = a + c
        denom -= 2 * b  # inf or nan where a cost is missing
        delta = a - c
        delta *= 0.5
        delta /= denom
        ok = (denom > 1e-12) & np.isfinite(denom) & np.isfinite(delta)
    delta = np.where(ok, delta, np.float32(0.0))
    return np.clip(delta, -0.5, 0.5, out=delta)


def refine(best_i, c_best, c_prev, c_next, c_second, n):
    """Fractional hypothesis index (parabola, none at the range's ends) and confidence
    ``1 - (c_best + f) / (c_second + f)``, f = :data:`COST_FLOOR` (0 where c_second is missing or
    not positive), float32."""
    edge = (best_i <= 0) | (best_i >= n - 1)
    c_prev = np.where(edge, np.float32(np.inf), c_prev)
    idx = parabola(c_prev, c_best, c_next)
    idx += best_i
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        floor = np.float32(COST_FLOOR)
        conf = (c_best + floor) / (c_second + floor)
        np.subtract(np.float32(1.0), conf, out=conf)
    ok = np.isfinite(c_second) & (c_second > 0) & np.isfinite(conf)
    conf = np.where(ok, conf, np.float32(0.0))
    return idx, np.clip(conf, 0.0, 1.0, out=conf)


class Finisher:
    """Depth, confidence and index rows from a sweep's strips (called from its threads)."""

    def __init__(self, depths, z0, shape, min_views):
        self.n = len(depths)
        self.inv = 1.0 / (np.asarray(depths, np.float64) - z0)
        self.z0 = z0
        # Hypotheses evenly spaced in 1/(Z - z0) (depth_hypotheses): interpolation is a line.
        step = (self.inv[-1] - self.inv[0]) / max(self.n - 1, 1)
        self.linear = bool(np.allclose(self.inv, self.inv[0] + step * np.arange(self.n), rtol=1e-9, atol=0))
        self.step = step
        self.min_views = min_views
        self.depth, self.conf, self.index = (np.empty(shape, np.float32) for _ in range(3))

    def __call__(self, r0, r1, best_i, c_best, c_prev, c_next, c_second, nviews):
        idx, conf = refine(best_i, c_best, c_prev, c_next, c_second, self.n)
        self.rows(r0, r1, idx, conf, c_best, nviews)

    @property
    def seen_views(self) -> float:
        """The views' summed weight from which a pixel counts as seen: ``min_views`` less half a
        view (the views' weights taper at their rims)."""
        return self.min_views - 0.5

    def rows(self, r0, r1, idx, conf, c_best, nviews):
        """Rows r0 to r1 from fractional hypothesis indices and confidences."""
        depth = self._depth(idx)
        seen = (nviews >= self.seen_views) & np.isfinite(c_best)
        self.depth[r0:r1] = np.where(seen, depth, np.float32(np.nan))
        self.conf[r0:r1] = np.where(seen, conf, np.float32(0.0))
        self.index[r0:r1] = np.where(seen, idx, np.float32(np.nan))

    def refined_maps(self, refined, index, filled, confidence, nviews, *, fallback_index: bool) -> np.ndarray:
        """The whole frame's rows from a refined index map (``refined``; where it is unknown the
        unrefined ``index`` with ``fallback_index``, else unknown) and its confidence; returns the
        depth of the ``filled`` index map (that index where it is unknown). Hypotheses evenly
        spaced in 1 / (Z - z0), as :func:`lfring.depth.hypotheses.depth_hypotheses` makes them,
        take one compiled pass (:func:`lfring.depth.refine_kernels.depth_maps`, the same floats);
        others these NumPy steps."""
        h, w = self.depth.shape
        if self.linear:
            from lfring.depth import refine_kernels

            depth_filled = np.empty((h, w), np.float32)
            maps = (np.ascontiguousarray(a, np.float32) for a in (refined, index, filled, confidence, nviews))
            refine_kernels.depth_maps(*maps, fallback_index, np.float32(self.step), np.float32(self.inv[0]),
                                      np.float32(self.z0), np.float32(self.seen_views), self.depth, self.conf,
                                      self.index, depth_filled)
            return depth_filled
        idx = np.where(np.isfinite(refined), refined, index if fallback_index else np.nan).astype(np.float32)
        fills = np.where(np.isfinite(filled), filled, idx).astype(np.float32)  # never unknown where idx is known
        missing = np.where(np.isfinite(idx), np.float32(0.0), np.float32(np.inf))
        self.rows(0, h, np.nan_to_num(idx), confidence, missing, nviews)
        return self.depth_of(fills, nviews)

    def depth_of(self, idx, nviews) -> np.ndarray:
        """Depth in metres (float32) of a map (or a strip of rows) of fractional indices; NaN
        where the index is NaN or fewer than ``min_views`` views see the pixel."""
        seen = nviews >= self.seen_views
        return np.where(seen, self._depth(np.asarray(idx, np.float32)), np.float32(np.nan)).astype(np.float32)

    def _depth(self, idx):
        if self.linear:
            inv_at = idx * np.float32(self.step)
            inv_at += np.float32(self.inv[0])
        else:
            inv_at = np.interp(idx, np.arange(self.n), self.inv).astype(np.float32)
        depth = np.divide(np.float32(1.0), inv_at, out=inv_at)
        depth += np.float32(self.z0)
        return depth

    def result(self, **record) -> DepthResult:
        """The finished :class:`DepthResult`: this finisher's depth, confidence and index.

        Parameters
        ----------
        **record
            The other fields of :class:`DepthResult` (``depths_m``, ``step_px``, ``reference``,
            ``cost``, ``aggregation``, ...).

        Returns
        -------
        DepthResult
        """
        return DepthResult(depth_m=self.depth, confidence=self.conf, hypothesis_index=self.index, **record)
