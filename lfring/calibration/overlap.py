"""Where the views overlap: the depths at which refocusing has something to average, and the
sign of the ring's disparity (views of nearer planes lie farther apart: d(Z) falls as Z grows).

Close to the depth origin z0 the homographies' translations B / (Z - z0) grow without bound:
the warped views slide off the reference frame and a refocused image is black. These functions
find that limit from the calibration alone (no pixels), so that a command can refuse a depth
before it renders garbage.
"""

from __future__ import annotations

import numpy as np

from lfring.errors import InvalidInputError

__all__ = [
    "INFINITE_DEPTH_M",
    "MIN_OVERLAP_FRACTION",
    "disparity_spread_px",
    "nearest_overlap_depth_m",
    "nearest_renderable_depth_m",
    "check_renderable",
    "overlap_fraction",
]

MIN_OVERLAP_FRACTION = 0.1
"""Smallest fraction of the reference frame that every view must cover at a renderable depth.

On the binned twin all views cover most of the frame at working distances; the common area
shrinks as the depth nears z0 and vanishes just beyond it, and this limit falls within a
centimetre of z0 (:func:`nearest_overlap_depth_m`), so only depths where next to nothing could
be averaged are refused."""

INFINITE_DEPTH_M = 1e9
"""A depth standing for infinity: 1 / (Z - z0) is below 1e-9 /m there, so H(Z) equals A to
far below a pixel on any sensor."""

_GRID = 32  # samples per side of the reference frame


def _common_coverage(h_ref_from_view: np.ndarray, view_shape_hw) -> float:
    """Fraction of a grid over the reference frame (of the views' size) that every view sees."""
    h, w = view_shape_hw
    xs = (np.arange(_GRID) + 0.5) * (w / _GRID) - 0.5  # cell centres: each sample stands for 1/_GRID of a side
    ys = (np.arange(_GRID) + 0.5) * (h / _GRID) - 0.5
    gx, gy = np.meshgrid(xs, ys)
    pts = np.stack([gx.ravel(), gy.ravel(), np.ones(gx.size)])  # (3, N) reference pixels
    inside = np.ones(gx.size, dtype=bool)
    for hk in h_ref_from_view:
        q = np.linalg.solve(hk, pts)  # view pixels of each reference pixel
        with np.errstate(divide="ignore", invalid="ignore"):
            u, v = q[0] / q[2], q[1] / q[2]
        inside &= (q[2] > 0) & (u >= -0.5) & (u <= w - 0.5) & (v >= -0.5) & (v <= h - 0.5)
    return float(inside.mean())


def _homographies_at_x(calibration, x: float, reference) -> np.ndarray:
    """H_ref_from_view at inverse distance x = 1 / (Z - z0) (x = 0: infinity), without the
    valid-range warnings of :meth:`RingCalibration.homographies`."""
    from lfring.core.geometry import normalize_homographies, to_reference

    model = calibration.model
    return to_reference(normalize_homographies(model.A + model.B * x), reference)


def overlap_fraction(calibration, depth_m: float, *, reference="center") -> float:
    """Fraction of the reference frame that all views cover at ``depth_m``.

    Parameters
    ----------
    calibration : RingCalibration
    depth_m : float
        Metres from the main lens, beyond the depth origin; ``inf`` is the limit H = A.
    reference : 'center' or int

    Returns
    -------
    float in [0, 1]
    """
    z = float(depth_m)
    z0 = calibration.depth_origin_m
    if not (z > z0):
        raise InvalidInputError(f"depth {depth_m!r} m is not beyond the calibration's depth origin {z0:.4g} m")
    x = 0.0 if np.isinf(z) else 1.0 / (z - z0)
    return _common_coverage(_homographies_at_x(calibration, x, reference), calibration.layout.view_shape)


def nearest_overlap_depth_m(calibration, *, reference="center", min_fraction: float = MIN_OVERLAP_FRACTION) -> float:
    """The nearest depth (metres) at which all views still cover ``min_fraction`` of the
    reference frame; every farther depth does too (the translations shrink with depth).

    Returns ``inf`` when even the limit at infinity falls short (a calibration whose views
    never overlap).

    Examples
    --------
    >>> from lfring.calibration.defaults import default_calibration
    >>> cal, _ = default_calibration((2456, 1842))
    >>> round(nearest_overlap_depth_m(cal), 3)
    0.037
    """
    view_shape = calibration.layout.view_shape

    def ok(x: float) -> bool:
        return _common_coverage(_homographies_at_x(calibration, x, reference), view_shape) >= min_fraction

    if not ok(0.0):
        return float("inf")
    lo, hi = 0.0, 1.0  # x = 1 / (Z - z0): ok at lo; grow hi until it fails
    while ok(hi):
        lo, hi = hi, hi * 4
        if hi > 1e9:
            return float(calibration.depth_origin_m)  # overlap all the way to z0 (not a ring)
    for _ in range(24):  # 1 / (Z - z0) to 1e-7 of its value
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return float(calibration.depth_origin_m + 1.0 / lo)


def disparity_spread_px(h_ref_from_view: np.ndarray, view_shape_hw) -> float:
    """RMS distance (px) of the views' centres, mapped into the reference frame, from their
    mean: how far apart the views of one plane lie. For the ring it falls as the plane recedes.

    Parameters
    ----------
    h_ref_from_view : (V, 3, 3)
    view_shape_hw : (h, w)
    """
    h, w = view_shape_hw
    c = np.array([(w - 1) / 2, (h - 1) / 2, 1.0])
    q = np.einsum("vij,j->vi", np.asarray(h_ref_from_view, dtype=np.float64), c)
    xy = q[:, :2] / q[:, 2:3]
    return float(np.sqrt(np.mean(np.sum((xy - xy.mean(axis=0)) ** 2, axis=1))))


def nearest_renderable_depth_m(calibration, *, reference="center") -> float:
    """:func:`nearest_overlap_depth_m`, computed once per calibration object and reference."""
    from lfring.core.viewstack import calibration_cache

    return calibration_cache(calibration, ("nearest_overlap_depth_m", reference),
                             lambda: nearest_overlap_depth_m(calibration, reference=reference))


def check_renderable(calibration, depths_m, *, reference="center", name: str = "depth") -> None:
    """Refuse depths nearer than where the views still overlap in the reference frame (a
    refocused image there is black or ghosted), naming the nearest depth that works; ``name``
    starts the refusal (the parameter that gave the depth, such as ``zmin_m``)."""
    zs = np.atleast_1d(np.asarray(depths_m, dtype=np.float64))
    if not np.all(zs > 0):  # NaN included
        raise InvalidInputError(f"{name} must be a positive distance in metres from the main lens, got "
                                f"{float(zs[~(zs > 0)][0]):g}")
    nearest = nearest_renderable_depth_m(calibration, reference=reference)
    bad = [float(z) for z in zs if z < nearest]
    if bad:
        raise InvalidInputError(
            f"{name} {bad[0]:g} m cannot be rendered: the views no longer overlap in the reference frame there "
            f"(less than {MIN_OVERLAP_FRACTION:.0%} of it is seen by every view, so the image would be black or "
            f"ghosted); the nearest depth that works with this calibration is {np.ceil(nearest * 1e4) / 1e4:g} m")
