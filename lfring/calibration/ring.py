"""RingCalibration: the refocusing calibration of one camera, in metric depth (SPEC 4 and 8)."""

from __future__ import annotations

import json
import math
import os
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from lfring._resources import calib_dir
from lfring.calibration.model import PlaneFit, VariableHomography, fit_variable_homography
from lfring.errors import FileFormatError, InvalidInputError, LfringFileNotFoundError, LfringWarning
from lfring.core.geometry import check_reference, to_reference
from lfring.optics.device import RingDevice
from lfring.optics.views import optical_homography_model, optical_layout, view_cameras
from lfring.views import Layout, grid_layout

__all__ = ["RingCalibration", "CALIBRATION_VERSION", "builtin_calibrations"]

CALIBRATION_VERSION = 1
SOURCES = ("planes", "optics", "grid")


@dataclass(frozen=True, eq=False)
class RingCalibration:
    """Where every view's pixels land in the reference frame, for a plane at any depth.

    Build one with :meth:`from_optics`, :meth:`from_plane_homographies`, :meth:`from_grid`
    (a rectified stereo pair or a regular grid of views, from its geometry) or
    :func:`lfring.calibrate`; read and write it with :meth:`load` / :meth:`save`.

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
        Name of the device description it came from, if any.
    black_level, white_level : float or None
        Levels in counts of the frames it was made from, when known: frames without their own
        (no sidecar, no option) are read with them.

    Examples
    --------
    The built-in calibration of the twin's 2 x 2 binned frames (:func:`builtin_calibrations`
    lists the others):

    >>> import numpy as np
    >>> cal = RingCalibration.load("twin_binned2")
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
    >>> views = lfring.split_views(lfring.demosaic(lfring.load_raw("data/synthetic/target_0.5m.png")), cal.layout)
    >>> def mismatch(depth_m):  # mean |view 0 - view 3 moved into view 0| (green) at the centre
    ...     moved = cv2.warpPerspective(views[3, :, :, 1], cal.homographies(depth_m, reference=0)[3], (705, 705))
    ...     return round(float(np.abs(moved - views[0, :, :, 1])[250:450, 250:450].mean()), 2)
    >>> [mismatch(0.3), mismatch(0.5), mismatch(1.0)]
    [0.19, 0.01, 0.16]
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

    def __post_init__(self) -> None:
        if self.source not in SOURCES:
            raise InvalidInputError(f"calibration source must be one of {SOURCES}, got {self.source!r}")
        if self.model.num_views != self.layout.num_views:
            raise InvalidInputError(f"the model has {self.model.num_views} views but the layout {self.layout.num_views}")
        rng = self.valid_depth_range_m
        if isinstance(rng, (str, bytes)) or not hasattr(rng, "__len__") or len(rng) != 2 \
                or not all(_is_finite_number(v) for v in (rng[0], *([] if rng[1] is None else [rng[1]]))):
            raise InvalidInputError(f"valid_depth_range_m must be (nearest, farthest or None) finite metres, got {rng!r} "
                                    "(None, not inf, for no farthest depth)")
        lo, hi = float(rng[0]), None if rng[1] is None else float(rng[1])
        object.__setattr__(self, "valid_depth_range_m", (lo, hi))
        if not (lo > self.model.depth_origin_m and (hi is None or hi >= lo)):
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

    def check_depth(self, depth_m, *, stacklevel: int = 3) -> np.ndarray:
        """Validate depths (finite, beyond z0) and warn for those outside the valid range."""
        z = np.asarray(depth_m, dtype=np.float64)
        if not np.all(np.isfinite(z)) or np.any(z <= 0):
            raise InvalidInputError(f"depth must be a positive, finite number of metres, got {depth_m!r}")
        if np.any(z <= self.depth_origin_m):
            raise InvalidInputError(f"depth {float(np.min(z))} m is not beyond the calibration's depth origin {self.depth_origin_m:.4g} m")
        lo, hi = self.valid_depth_range_m
        outside = (z < lo) | (z > hi if hi is not None else False)
        if np.any(outside):
            bad = np.atleast_1d(z)[np.atleast_1d(outside)]
            rng = f"{lo:g} to {hi:g} m" if hi is not None else f"beyond {lo:g} m"
            warnings.warn(
                f"depth {', '.join(f'{v:g}' for v in bad[:3])} m is outside the calibrated range ({rng}); "
                "the model is extrapolated", LfringWarning, stacklevel=stacklevel,
            )
        return z

    def homographies(self, depth_m, *, reference="center") -> np.ndarray:
        """``H_ref_from_view`` of every view at ``depth_m``: (V, 3, 3), or (N, V, 3, 3)."""
        z = self.check_depth(depth_m)
        ref = check_reference(reference, self.num_views)
        return to_reference(self.model(z), ref)

    def homography(self, view: int, depth_m: float, *, reference="center") -> np.ndarray:
        """(3, 3) ``H_ref_from_view`` of one view at ``depth_m`` (metres from the main lens)."""
        if isinstance(view, bool) or not isinstance(view, (int, np.integer)) or not 0 <= view < self.num_views:
            raise InvalidInputError(f"view must be an index 0..{self.num_views - 1}, got {view!r}")
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
                f"the calibration is for {self.num_views} views of {want_w} x {want_h} px but the {what} are "
                f"{v} of {w} x {h} px; give the views cut with this calibration's layout, in its view order"
            )

    def select_views(self, views) -> RingCalibration:
        """The calibration of a subset of the views (e.g. a horizontal pair of the ring's four),
        in the order given. The subset must hold the model's base view (``model.reference``).

        Examples
        --------
        >>> cal = RingCalibration.from_grid((8, 8), [(0, 0), (1, 0), (0, 1)], disparity_scale_px_m=1.0)
        >>> cal.select_views([2, 0]).homographies(1.0, reference=1)[:, :2, 2]
        array([[0., 1.],
               [0., 0.]])
        >>> cal.select_views([2, 0]).num_views
        2
        """
        idx = list(views) if not isinstance(views, (int, np.integer)) else [views]
        if any(isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k < self.num_views for k in idx) or (
            len(set(idx)) != len(idx)
        ):
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
        return replace(self, model=VariableHomography(a, b, m.depth_origin_m, base), layout=layout,
                       provenance={**self.provenance, "views_selected": idx})

    # -- constructors ----------------------------------------------------------------------
    @classmethod
    def from_optics(cls, device: RingDevice, *, layout: Layout | None = None, rotate180: bool = False) -> RingCalibration:
        """The calibration the paraxial model predicts (pure translations, z0 = s): the default
        when no measured calibration is given."""
        layout = layout or optical_layout(device, rotate180=rotate180)
        a, b, z0 = optical_homography_model(device, layout, reference=0)
        s = view_cameras(device).depth_origin_m
        return cls(
            model=VariableHomography(a, b, z0, 0),
            layout=layout,
            valid_depth_range_m=(round(2 * s, 6), None),
            source="optics",
            device=device.name,
            provenance={"ring_distance_m": device.ring_distance_m, "sensor_distance_m": device.sensor_distance_m,
                        "pixel_pitch_m": device.pixel_pitch_m},
        )

    @classmethod
    def from_plane_homographies(
        cls,
        homographies_by_depth: dict,
        *,
        reference: int = 0,
        depth_origin_m: float | None = 0.0,
        layout: Layout,
        pattern: str | None = None,
        rank1: bool = False,
        provenance: dict | None = None,
    ) -> RingCalibration:
        """Fit the model to homographies from elsewhere: ``{depth_m: H (V, 3, 3)}`` where each H
        maps a view's pixels into view ``reference``; ``depth_origin_m=None`` fits z0 (three
        or more planes)."""
        if not isinstance(layout, Layout):
            raise InvalidInputError("from_plane_homographies needs the layout the homographies were measured with")
        model, planes = fit_variable_homography(
            homographies_by_depth, shape_hw=layout.view_shape, reference=reference, depth_origin_m=depth_origin_m, rank1=rank1
        )
        depths = [p.depth_m for p in planes]
        return cls(
            model=model, layout=layout, valid_depth_range_m=(min(depths), max(depths)), pattern=pattern,
            planes=tuple(planes), source="planes", provenance=dict(provenance or {}),
        )

    @classmethod
    def from_grid(
        cls,
        view_shape: tuple[int, int],
        grid_positions,
        *,
        disparity_scale_px_m: float,
        disparity_offset_px: float = 0.0,
        depth_origin_m: float = 0.0,
        valid_depth_range_m: tuple[float, float | None] | None = None,
    ) -> RingCalibration:
        """The calibration of views on a regular grid, built from its geometry: a rectified
        stereo pair, a camera array, the sub-aperture views of a light-field camera.

        Parameters
        ----------
        view_shape : (h, w)
            Size of every view in pixels.
        grid_positions : (V, 2) array_like
            (x, y) of each view on the grid in grid units, x to the right, y down, in view
            order; 2 to ``MAX_VIEWS`` distinct positions. A rectified stereo pair is
            ``[(0, 0), (1, 0)]``, left view first.
        disparity_scale_px_m, disparity_offset_px : float
            The disparity per grid step of a point at depth Z, an affine function of
            1 / (Z - z0): ``d(Z) = disparity_offset_px + disparity_scale_px_m / (Z - z0)``
            pixels (for a stereo pair of focal length f px and baseline b m, ``f b`` and 0).
        depth_origin_m : float
            z0, the depth of the plane of the projection centres (0 for cameras whose depth
            is measured from their centres).
        valid_depth_range_m : (float, float or None), optional
            Depths the calibration is meant for (others warn). By default from the depth at
            which ``disparity_scale_px_m / (Z - z0)`` is one view's larger side (nearer than
            that, neighbouring views no longer overlap) to infinity.

        Returns
        -------
        RingCalibration
            ``source='grid'``; the layout tiles the views as cells of a mosaic (at their grid
            cell for integer positions, else in one row in view order) and the grid is kept
            in ``provenance``.

        Notes
        -----
        A point at depth Z lies at ``x_k = x_j - (p_k - p_j) d(Z)`` in view k for its position
        ``x_j`` in view j (both axes; p the grid positions), so
        ``H_ref_from_view_k(Z)`` is the translation by ``(p_k - p_ref) d(Z)``, with
        ``p_ref`` the mean of the positions for reference 'center'. For a Middlebury pair
        (left, right) at ``[(0, 0), (1, 0)]`` this is ``imL(x, y) = imR(x - d, y)``.

        Examples
        --------
        >>> cal = RingCalibration.from_grid((375, 450), [(0, 0), (1, 0)], disparity_scale_px_m=100.0)
        >>> cal.homographies(2.0)[:, 0, 2]  # 50 px of disparity, half of it each way from the centre
        array([-25.,  25.])
        """
        pos = np.asarray(grid_positions, dtype=np.float64) if _is_numeric(grid_positions) else None
        if pos is None or pos.ndim != 2 or pos.shape[1] != 2 or not np.all(np.isfinite(pos)):
            got = f"shape {pos.shape}" if pos is not None else repr(grid_positions)[:80]
            raise InvalidInputError(
                f"grid_positions must be (V, 2) finite (x, y) grid positions, got {got}; a stereo pair is [(0, 0), (1, 0)]"
            )
        layout = grid_layout(view_shape, pos)
        for name, value in (("disparity_scale_px_m", disparity_scale_px_m), ("disparity_offset_px", disparity_offset_px),
                            ("depth_origin_m", depth_origin_m)):
            if not _is_finite_number(value):
                raise InvalidInputError(f"{name} must be a finite number, got {value!r}")
        if disparity_scale_px_m == 0:
            raise InvalidInputError("disparity_scale_px_m must not be 0: the views would not move with depth")
        z0 = float(depth_origin_m)
        if valid_depth_range_m is None:
            valid_depth_range_m = (z0 + abs(float(disparity_scale_px_m)) / max(layout.view_shape), None)
        rel = pos - pos[0]
        a = np.repeat(np.eye(3)[None], len(pos), axis=0)
        b = np.zeros_like(a)
        a[:, :2, 2] = rel * float(disparity_offset_px)
        b[:, :2, 2] = rel * float(disparity_scale_px_m)
        return cls(
            model=VariableHomography(a, b, z0, 0),
            layout=layout,
            valid_depth_range_m=valid_depth_range_m,
            source="grid",
            provenance={"grid_positions": pos.tolist(), "disparity_scale_px_m": float(disparity_scale_px_m),
                        "disparity_offset_px": float(disparity_offset_px),
                        "disparity": "d(Z) = disparity_offset_px + disparity_scale_px_m / (Z - depth_origin_m) px per "
                                     "grid step; view k at grid position p_k: H_ref_from_view = translation by (p_k - p_ref) d(Z)"},
        )

    # -- files -----------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """The JSON form of the calibration (what :meth:`save` writes and :meth:`from_dict` reads).

        Returns
        -------
        dict
            JSON-ready: plain numbers, lists and strings, with the file version
            ``lfring_calibration_version``.
        """
        return {
            "lfring_calibration_version": CALIBRATION_VERSION,
            "source": self.source,
            "device": self.device,
            "raw_width_px": self.raw_size[0],
            "raw_height_px": self.raw_size[1],
            "bayer_pattern": self.pattern,
            "black_level": list(self.black_level) if isinstance(self.black_level, tuple) else self.black_level,
            "white_level": self.white_level,
            "layout": self.layout.to_dict(),
            "reference_view": self.model.reference,
            "depth_origin_m": self.depth_origin_m,
            "model": "H_ref_from_view(Z) = A + B / (Z - depth_origin_m), normalised so H[2,2] = 1",
            "A": self.model.A.tolist(),
            "B": self.model.B.tolist(),
            "valid_depth_range_m": list(self.valid_depth_range_m),
            "planes": [
                {"depth_m": p.depth_m, "residual_px": p.residual_px.tolist(),
                 "leave_one_out_px": None if p.leave_one_out_px is None else p.leave_one_out_px.tolist()}
                for p in self.planes
            ],
            "provenance": self.provenance,
        }

    def save(self, path: str | Path) -> Path:
        """Write the calibration as JSON (atomically: a reader never sees half a file).

        Parameters
        ----------
        path : str or Path
            The file to write; its folder must exist.

        Returns
        -------
        Path
            The file written.
        """
        from lfring.io.atomic import atomic_write_text

        return atomic_write_text(path, json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> RingCalibration:
        """Read a calibration file, or a calibration shipped with lfring by its name.

        Parameters
        ----------
        path : str or Path
            A JSON file written by :meth:`save` (or ``lfring calibrate``), or the name of a
            built-in calibration (:func:`builtin_calibrations`), e.g. ``'twin_binned2'``: a
            name without a path separator or ``.json`` suffix that is not an existing file is
            looked up among the built-ins.

        Returns
        -------
        RingCalibration

        Raises
        ------
        LfringFileNotFoundError
            No such file, nor a built-in calibration of that name (the message lists the
            built-in names).
        FileFormatError
            The file is not a valid calibration (the message names the key at fault).

        Examples
        --------
        >>> cal = RingCalibration.load("twin_binned2")
        >>> cal.raw_size, cal.num_views, cal.source
        ((2456, 1842), 4, 'planes')
        """
        from lfring.io.readers import read_json_object

        if _is_builtin_name(path):
            names = builtin_calibrations()
            if str(path) not in names:
                raise LfringFileNotFoundError(
                    f"calibration file not found: {path}, and no built-in calibration of that name "
                    f"(built-in: {', '.join(names) or 'none'}); give the path of a calibration file "
                    "(lfring calibrate makes one) or one of the built-in names"
                )
            data = json.loads((calib_dir() / f"{path}.json").read_text(encoding="utf-8"))
            return cls.from_dict(data, source_name=str(path))
        return cls.from_dict(read_json_object(path, "calibration"), source_name=str(path))

    @classmethod
    def from_dict(cls, data, *, source_name: str = "calibration") -> RingCalibration:
        """Build from the JSON form, validating every key (errors name the file and the key)."""
        v = _Validator(source_name)
        v.require(isinstance(data, dict), "the file must hold a JSON object")
        version = data.get("lfring_calibration_version")
        v.require(version == CALIBRATION_VERSION,
                  f"'lfring_calibration_version' is {version!r}; this lfring reads version {CALIBRATION_VERSION}")
        keys = {"lfring_calibration_version", "source", "device", "raw_width_px", "raw_height_px", "bayer_pattern",
                "layout", "reference_view", "depth_origin_m", "model", "A", "B", "valid_depth_range_m", "planes", "provenance",
                "black_level", "white_level"}
        v.require(not (set(data) - keys), f"unknown key(s) {sorted(set(data) - keys)}")
        for k in ("source", "layout", "reference_view", "depth_origin_m", "A", "B", "valid_depth_range_m", "raw_width_px", "raw_height_px"):
            v.require(k in data, f"missing key '{k}'")
        try:
            layout = Layout.from_dict(data["layout"], source=f"{source_name} 'layout'")
        except (FileFormatError, InvalidInputError, AttributeError) as exc:
            raise FileFormatError(str(exc)) from None
        v.require((data["raw_width_px"], data["raw_height_px"]) == (layout.raw_width_px, layout.raw_height_px),
                  "'raw_width_px'/'raw_height_px' disagree with the layout")
        a, b = v.matrices(data["A"], "A", layout.num_views), v.matrices(data["B"], "B", layout.num_views)
        z0 = v.number(data["depth_origin_m"], "depth_origin_m")
        ref = data["reference_view"]
        v.require(isinstance(ref, int) and not isinstance(ref, bool) and 0 <= ref < layout.num_views,
                  f"'reference_view' must be a view index, got {ref!r}")
        rng = data["valid_depth_range_m"]
        v.require(isinstance(rng, list) and len(rng) == 2, "'valid_depth_range_m' must be [min, max or null]")
        lo = v.number(rng[0], "valid_depth_range_m[0]")
        hi = None if rng[1] is None else v.number(rng[1], "valid_depth_range_m[1]")
        pattern = data.get("bayer_pattern")
        if pattern is not None:
            from lfring.io.bayer import PATTERNS

            v.require(pattern in PATTERNS, f"'bayer_pattern' must be one of {PATTERNS} or null, got {pattern!r}")
        levels = {"white_level": None if data.get("white_level") is None else v.number(data["white_level"], "white_level")}
        black = data.get("black_level")
        if isinstance(black, list):
            v.require(len(black) == 4, "'black_level' must be a number or four numbers (one per CFA position)")
            levels["black_level"] = tuple(v.number(b, f"black_level[{i}]") for i, b in enumerate(black))
        else:
            levels["black_level"] = None if black is None else v.number(black, "black_level")
        planes = []
        v.require(isinstance(data.get("planes", []), list), "'planes' must be a list")
        for i, p in enumerate(data.get("planes", [])):
            v.require(isinstance(p, dict) and "depth_m" in p and "residual_px" in p, f"'planes'[{i}] must have depth_m and residual_px")
            res = np.asarray(p["residual_px"], dtype=np.float64)
            loo = p.get("leave_one_out_px")
            planes.append(PlaneFit(v.number(p["depth_m"], f"planes[{i}].depth_m"), res,
                                   None if loo is None else np.asarray(loo, dtype=np.float64)))
        try:
            return cls(
                model=VariableHomography(a, b, z0, ref), layout=layout, valid_depth_range_m=(lo, hi), pattern=pattern,
                planes=tuple(planes), source=data["source"], device=data.get("device"),
                provenance=data.get("provenance") or {}, **levels,
            )
        except InvalidInputError as exc:
            raise FileFormatError(f"{source_name}: {exc}") from None


def builtin_calibrations() -> dict[str, tuple[int, int]]:
    """The calibrations shipped with lfring (the repository's calib/ folder, installed as the
    package ``lfring._calib``), by name.

    Returns
    -------
    dict of str to (int, int)
        Name (what :meth:`RingCalibration.load` accepts) -> raw size (width, height) in pixels
        of the frames the calibration is for, sorted by name.

    Examples
    --------
    >>> names = builtin_calibrations()
    >>> names["twin_binned2"], names["prototype_optics"]
    ((2456, 1842), (4912, 3684))
    """
    out = {}
    for entry in sorted(calib_dir().iterdir(), key=lambda e: e.name):
        if entry.name.endswith(".json"):
            data = json.loads(entry.read_text(encoding="utf-8"))
            if "lfring_calibration_version" in data:
                out[entry.name[: -len(".json")]] = (data["raw_width_px"], data["raw_height_px"])
    return out


def _is_builtin_name(path) -> bool:
    """Whether ``path`` is to be looked up among the built-in calibrations: a bare name (no path
    separator, no .json suffix) that is not an existing file."""
    text = str(path)
    separators = {"/", os.sep} | ({os.altsep} if os.altsep else set())
    return (bool(text) and not any(s in text for s in separators) and not text.lower().endswith(".json")
            and not Path(text).exists())


def _is_finite_number(value) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, float, np.integer, np.floating)) and math.isfinite(value)


def _is_numeric(value) -> bool:
    try:
        return np.asarray(value).dtype.kind in "iuf"
    except (TypeError, ValueError):
        return False


class _Validator:
    def __init__(self, source: str):
        self.source = source

    def require(self, ok: bool, message: str) -> None:
        if not ok:
            raise FileFormatError(f"{self.source}: {message}")

    def number(self, value, key: str) -> float:
        self.require(isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value),
                     f"'{key}' must be a finite number, got {value!r}")
        return float(value)

    def matrices(self, value, key: str, views: int) -> np.ndarray:
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            arr = None
        self.require(arr is not None and arr.shape == (views, 3, 3) and bool(np.all(np.isfinite(arr))),
                     f"'{key}' must be {views} finite 3 x 3 matrices")
        return arr
