"""RingCalibration: the refocusing calibration of one camera, in metric depth.

This module holds the record and its queries. Building one lives in
:mod:`lfring.calibration.build` and its JSON form in :mod:`lfring.calibration.jsonio`; both
make RingCalibration objects, so they import this module, and the package
(:mod:`lfring.calibration`) attaches the thin methods that reach them (``from_optics``,
``from_plane_homographies``, ``from_grid``, ``to_dict``, ``from_dict``, ``save``, ``load``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from lfring.calibration.model import PlaneFit, VariableHomography
from lfring.core.geometry import check_reference, to_reference
from lfring.core.lens import Distortion, FlatField
from lfring.core.validate import check_choice, check_view_index, is_integer, is_number
from lfring.errors import InvalidInputError, warn_caller
from lfring.views import Layout

__all__ = ["DEVICE_RECORD", "SOURCES", "RingCalibration"]

DEVICE_RECORD = "device_record"
"""The key of ``provenance`` that holds the device a calibration was made with, every field
(:meth:`lfring.optics.RingDevice.to_dict`)."""

SOURCES = ("planes", "optics", "grid")
"""Where a calibration comes from: fitted to measured planes, predicted by the optics, or built
from a grid of views."""


@dataclass(frozen=True, eq=False)
class RingCalibration:
    """Where every view's pixels land in the reference frame, for a plane at any depth.

    Build one with :meth:`from_optics`, :meth:`from_plane_homographies`, :meth:`from_grid`
    (a rectified stereo pair or a regular grid of views, from its geometry) or
    :func:`lfring.calibrate`; read and write it with :meth:`load` / :meth:`save`. These
    methods delegate to the functions of :mod:`lfring.calibration.build` and
    :mod:`lfring.calibration.jsonio`.

    Attributes
    ----------
    model : VariableHomography
        ``H_r_from_k(Z) = A_k + B_k / (Z - z0)`` into the base reference view r.
    layout : Layout
        Where the views lie on the raw frame (raw size and rotation included).
    pattern : str or None
        Bayer pattern of the frames it was made for, when known.
    valid_depth_range_m : (float, float or None)
        Depths the calibration was measured or is meant for; requests outside warn.
    planes : tuple of PlaneFit
        The planes it was fitted to, with their residuals in pixels.
    source : 'planes', 'optics' or 'grid'
    device : str or None
        Name of the device description it came from, if any (its optics:
        :meth:`device_optics`).
    provenance : dict
        How it was made (the device's distances, the grid, the views selected...), kept in
        its file.
    black_level, white_level : float or None
        Levels in counts of the frames it was made from, when known: frames without their own
        (no sidecar, no option) are read with them.
    distortion : tuple of Distortion, or None
        Each view's lens distortion (ideal pixel -> recorded pixel, in the pixels of the views
        the layout cuts), when the calibration models it: :func:`lfring.split_views` given the
        calibration undoes it, and the model's homographies relate the undistorted views. The
        layout's circles are then the valid discs of the undistorted views. None: the views are
        used as they are cut.
    flat_field : FlatField or None
        Each view's vignetting (its response to a flat, white field, in the undistorted views),
        when the calibration carries it: :func:`lfring.split_views` given the calibration
        divides the views by it.

    Examples
    --------
    The built-in calibration of the twin's 2 x 2 binned frames
    (:func:`lfring.calibration.builtin_calibrations` lists the others):

    >>> import numpy as np
    >>> from lfring import RingCalibration
    >>> cal = RingCalibration.load("twin_binned2")
    >>> cal  # doctest: +ELLIPSIS
    RingCalibration(source='planes', num_views=4, view_shape=(705, 705), depth_origin_m=0.02798, ...)
    >>> cal.raw_size, cal.layout.view_shape, cal.valid_depth_range_m
    ((2456, 1842), (705, 705), (0.3, 1.0))
    >>> H = cal.homographies([0.3, 0.5, 1.0])  # H_ref_from_view into the centre frame
    >>> H.shape
    (3, 4, 3, 3)
    >>> np.round(H[:, 0, 0, 2], 1).tolist()  # view 0's shift in x, px: the nearer, the larger
    [61.3, 58.8, 57.1]

    On the bundled target at 0.5 m (data/synthetic, paths relative to the repository root; a
    depth the calibration was not fitted at), view 3 moved into view 0 by the homography of a
    plane at 0.5 m lands on it; at other depths it does not:

    >>> import cv2, lfring
    >>> views = lfring.split_views(lfring.demosaic(lfring.load_raw("data/synthetic/target_0.5m.png")), cal)
    >>> def mismatch(depth_m):  # mean |view 0 - view 3 moved into view 0| (green) at the centre
    ...     moved = cv2.warpPerspective(views[3, :, :, 1], cal.homographies(depth_m, reference=0)[3], (705, 705))
    ...     return round(float(np.abs(moved - views[0, :, :, 1])[250:450, 250:450].mean()), 2)
    >>> [mismatch(0.3), mismatch(0.5), mismatch(1.0)]
    [0.2, 0.01, 0.16]
    """

    model: VariableHomography
    layout: Layout
    valid_depth_range_m: tuple[float, float | None]
    pattern: str | None = None
    planes: tuple[PlaneFit, ...] = ()
    source: str = "planes"
    device: str | None = None
    provenance: dict = field(default_factory=dict)
    black_level: float | tuple[float, float, float, float] | None = None
    white_level: float | None = None
    distortion: tuple | None = None
    flat_field: FlatField | None = None

    def __post_init__(self) -> None:
        check_choice(self.source, "calibration source", SOURCES)
        if self.model.num_views != self.layout.num_views:
            raise InvalidInputError(f"the model has {self.model.num_views} views but the layout {self.layout.num_views}")
        if self.distortion is not None:
            dist = tuple(self.distortion) if not isinstance(self.distortion, (str, dict)) else ()
            if len(dist) != self.layout.num_views or not all(isinstance(d, Distortion) for d in dist):
                raise InvalidInputError(f"distortion must be one lfring.core.lens.Distortion per view "
                                        f"({self.layout.num_views}), got {self.distortion!r}")
            object.__setattr__(self, "distortion", None if all(d.is_identity for d in dist) else dist)
        if self.flat_field is not None:
            if not isinstance(self.flat_field, FlatField):
                raise InvalidInputError(f"flat_field must be a lfring.core.lens.FlatField, got {type(self.flat_field).__name__}")
            if self.flat_field.response.shape != (self.layout.num_views, *self.layout.view_shape):
                raise InvalidInputError(
                    f"the flat field is for {self.flat_field.num_views} views of {self.flat_field.view_shape[1]} x "
                    f"{self.flat_field.view_shape[0]} px, the layout cuts {self.layout.num_views} of "
                    f"{self.layout.view_shape[1]} x {self.layout.view_shape[0]} px")
        rng = self.valid_depth_range_m
        if isinstance(rng, (str, bytes)) or not hasattr(rng, "__len__") or len(rng) != 2 \
                or not all(_is_finite_number(v) for v in (rng[0], *([] if rng[1] is None else [rng[1]]))):
            raise InvalidInputError(f"valid_depth_range_m must be (nearest, farthest or None) finite metres, got {rng!r} "
                                    "(None, not inf, for no farthest depth)")
        lo, hi = float(rng[0]), None if rng[1] is None else float(rng[1])
        object.__setattr__(self, "valid_depth_range_m", (lo, hi))
        if hi is not None and hi < lo:
            raise InvalidInputError(f"valid depth range {self.valid_depth_range_m} must be (nearest, farthest): its "
                                    "farthest depth is the nearer")
        if not lo > self.model.depth_origin_m:
            raise InvalidInputError(f"valid depth range {self.valid_depth_range_m} must lie beyond z0 = {self.model.depth_origin_m}")
        object.__setattr__(self, "planes", tuple(self.planes))

    # -- queries ---------------------------------------------------------------------------
    @property
    def depth_origin_m(self) -> float:
        """The depth origin z0 of ``H(Z) = A + B / (Z - z0)``, metres from the main lens."""
        return self.model.depth_origin_m

    @property
    def num_views(self) -> int:
        """Number of views V the calibration maps (the layout's)."""
        return self.layout.num_views

    @property
    def raw_size(self) -> tuple[int, int]:
        """(width, height) of the raw frames this calibration belongs to."""
        return self.layout.raw_width_px, self.layout.raw_height_px

    def check_depth(self, depth_m, *, name: str = "depth_m") -> np.ndarray:
        """Validate depths (numbers, finite, beyond z0) and warn for those outside the valid
        range (asking whether they were millimetres where they would be in range as such,
        :meth:`millimetres_hint`); ``name`` is how the messages name them (an entry of a list by
        its index)."""
        raw = np.asarray(depth_m)
        if raw.dtype.kind not in "iuf":
            raise InvalidInputError(f"{name} must be {'a number' if raw.ndim == 0 else 'numbers'} of metres, got {depth_m!r}")
        z = raw.astype(np.float64)
        flat = np.atleast_1d(z).ravel()
        bad = np.flatnonzero(~np.isfinite(flat) | (flat <= 0))
        where = lambda i: name if z.ndim == 0 else f"{name}[{i}]"  # noqa: E731
        if bad.size:
            raise InvalidInputError(f"{where(bad[0])} must be a positive, finite number of metres, got {flat[bad[0]]:g}")
        near = np.flatnonzero(flat <= self.depth_origin_m)
        if near.size:
            raise InvalidInputError(f"{where(near[0])} ({flat[near[0]]:g} m) is not beyond the calibration's depth origin "
                                    f"{self.depth_origin_m:.4g} m")
        lo, hi = self.valid_depth_range_m
        outside = (z < lo) | (z > hi if hi is not None else False)
        if np.any(outside):
            bad = np.atleast_1d(z)[np.atleast_1d(outside)]
            rng = f"{lo:g} to {hi:g} m" if hi is not None else f"beyond {lo:g} m"
            warn_caller(
                f"depth {', '.join(f'{v:g}' for v in bad[:3])} m is outside the calibrated range ({rng}); "
                f"the model is extrapolated{self.millimetres_hint(*bad)}"
            )
        return z

    def millimetres_hint(self, *depths_m: float) -> str:
        """``"; depths are in metres: was ... given in mm?"`` when every depth given lies beyond
        the valid range and, read as millimetres, within it (the usual unit mistake), else ''.

        >>> from lfring.calibration import RingCalibration
        >>> pair = RingCalibration.from_grid((64, 96), [(0, 0), (1, 0)], disparity_scale_px_m=120.0)
        >>> pair.valid_depth_range_m[0], pair.millimetres_hint(3000.0), pair.millimetres_hint(3.0)
        (1.25, '; depths are in metres: was 3000 given in mm?', '')
        """
        lo, hi = self.valid_depth_range_m
        z = [float(v) for v in depths_m]
        if not z or not all(math.isfinite(v) for v in z):
            return ""
        beyond = all(v > hi if hi is not None else v / 1000.0 >= lo for v in z)
        within_mm = all(lo <= v / 1000.0 and (hi is None or v / 1000.0 <= hi) for v in z)
        if not (beyond and within_mm):
            return ""
        words = " and ".join(f"{v:g}" for v in dict.fromkeys(z))
        return f"; depths are in metres: {'was' if len(set(z)) == 1 else 'were'} {words} given in mm?"

    def device_optics(self):
        """The :class:`lfring.optics.RingDevice` the calibration was made with, as it was: the
        record it keeps of that device (calibrations made with a device keep one,
        :data:`DEVICE_RECORD`), else the built-in device it names; None when it names none.

        A device file's optics travel with the calibration, so a later command neither needs the
        file again nor takes a built-in device of the same name for it.

        Raises
        ------
        LfringError
            The record is not a device's, or the name is not a built-in device's (a calibration
            written before the record was kept: give the device file).
        """
        from lfring.optics.device import RingDevice, load_device

        record = self.provenance.get(DEVICE_RECORD)
        if record is not None:
            return RingDevice.from_dict(record, source=f"the calibration's record of device '{self.device}'")
        return None if self.device is None else load_device(self.device)

    def homographies(self, depth_m, *, reference="center") -> np.ndarray:
        """``H_ref_from_view`` of every view at ``depth_m``: (V, 3, 3), or (N, V, 3, 3)."""
        z = self.check_depth(depth_m)
        ref = check_reference(reference, self.num_views)
        return to_reference(self.model(z), ref)

    def homography(self, view: int, depth_m: float, *, reference="center") -> np.ndarray:
        """(3, 3) ``H_ref_from_view`` of one view at ``depth_m`` (metres from the main lens)."""
        view = check_view_index(view, "view", self.num_views)
        if np.ndim(depth_m) != 0:
            raise InvalidInputError("homography() takes one depth; use homographies() for several")
        return self.homographies(depth_m, reference=reference)[view]

    def overlap_depth_range(self, *, reference="center") -> tuple[float, float]:
        """(nearest, inf): the depths in metres at which every view still covers
        :data:`lfring.calibration.overlap.MIN_OVERLAP_FRACTION` of the reference frame; nearer
        than that a refocused image is mostly black."""
        from lfring.calibration.overlap import nearest_overlap_depth_m

        return nearest_overlap_depth_m(self, reference=reference), float("inf")

    def check_frame(self, shape_hw, *, what: str = "frame") -> None:
        """Raise if a raw frame of ``shape_hw`` does not belong to this calibration."""
        h, w = shape_hw[:2]
        if (w, h) != self.raw_size and self.source == "grid":
            vh, vw = self.layout.view_shape
            raise InvalidInputError(
                f"the {what} is one image of {w} x {h} px, but the calibration is a grid of {self.num_views} separate view "
                f"images of {vw} x {vh} px: give its {self.num_views} view images in its view order (e.g. lfring depth "
                f"{' '.join(f'view{k}.png' for k in range(min(self.num_views, 3)))}{' ...' if self.num_views > 3 else ''} "
                "--calib FILE)"
            )
        if (w, h) != self.raw_size:
            raise InvalidInputError(
                f"the {what} is {w} x {h} px but the calibration is for {self.raw_size[0]} x {self.raw_size[1]} px "
                "frames; use the calibration of this camera and binning"
            )

    def check_fits(self, views_shape, *, what: str = "views") -> None:
        """Raise unless a (V, h, w[, C]) stack of views holds this calibration's views: as many,
        of its layout's size."""
        v, h, w = (tuple(views_shape) + (0, 0, 0))[:3]
        want_h, want_w = self.layout.view_shape
        if (v, h, w) != (self.num_views, want_h, want_w):
            raise InvalidInputError(
                f"the calibration is for {self.num_views} views of {want_w} x {want_h} px, (V, h, w, C) = "
                f"({self.num_views}, {want_h}, {want_w}, C), but the {what} are {v} of {w} x {h} px (shape "
                f"{tuple(views_shape)}); give the views cut with this calibration's layout, in its view order"
            )

    def select_views(self, views) -> RingCalibration:
        """The calibration of a subset of the views (e.g. a horizontal pair of the ring's four),
        in the order given. The subset must hold the model's base view (``model.reference``).

        Examples
        --------
        >>> from lfring import RingCalibration
        >>> cal = RingCalibration.from_grid((8, 8), [(0, 0), (1, 0), (0, 1)], disparity_scale_px_m=1.0)
        >>> cal.select_views([2, 0]).homographies(1.0, reference=1)[:, :2, 2]
        array([[0., 1.],
               [0., 0.]])
        >>> cal.select_views([2, 0]).num_views
        2
        """
        idx = list(views) if hasattr(views, "__iter__") else [views]
        if any(not is_integer(k) or not 0 <= k < self.num_views for k in idx) or len(set(idx)) != len(idx):
            raise InvalidInputError(f"views must be distinct view indices 0..{self.num_views - 1}, got {views!r}")
        lay = self.layout
        layout = Layout(lay.raw_width_px, lay.raw_height_px, tuple(lay.rects[k] for k in idx), lay.rotate180,
                        None if lay.circles is None else tuple(lay.circles[k] for k in idx))
        m = self.model
        if m.reference not in idx:
            raise InvalidInputError(
                f"select_views keeps the model's base view {m.reference} (its homographies map into it), got {views!r}"
            )
        a, b, base = m.A[idx], m.B[idx], idx.index(m.reference)
        dist = None if self.distortion is None else tuple(self.distortion[k] for k in idx)
        flat = None if self.flat_field is None else FlatField(self.flat_field.response[idx])
        return replace(self, model=VariableHomography(a, b, m.depth_origin_m, base), layout=layout,
                       provenance={**self.provenance, "views_selected": idx}, distortion=dist, flat_field=flat)

    def __repr__(self) -> str:
        """One line: where it comes from, its views and depths (the arrays stay out)."""
        extra = "".join(f", {name}=True" for name in ("distortion", "flat_field") if getattr(self, name) is not None)
        return (f"{type(self).__qualname__}(source={self.source!r}, num_views={self.num_views}, "
                f"view_shape={self.layout.view_shape}, depth_origin_m={self.depth_origin_m:.6g}, "
                f"valid_depth_range_m={self.valid_depth_range_m!r}, device={self.device!r}{extra})")


def _is_finite_number(value) -> bool:
    return is_number(value) and math.isfinite(value)
