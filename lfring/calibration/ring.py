"""RingCalibration: the refocusing calibration of one camera, in metric depth (SPEC 4 and 8)."""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lfring.calibration.model import PlaneFit, VariableHomography, fit_variable_homography
from lfring.errors import FileFormatError, InvalidInputError, LfringWarning
from lfring.geometry import check_reference, to_reference
from lfring.optics.device import RingDevice
from lfring.optics.views import optical_homography_model, optical_layout, view_cameras
from lfring.views import Layout

__all__ = ["RingCalibration", "CALIBRATION_VERSION"]

CALIBRATION_VERSION = 1
SOURCES = ("planes", "optics")


@dataclass(frozen=True, eq=False)
class RingCalibration:
    """Where every view's pixels land in the reference frame, for a plane at any depth.

    Build one with :meth:`from_optics`, :meth:`from_plane_homographies` or
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
    source : 'planes' or 'optics'
    device : str or None
        Name of the device description it came from, if any.
    black_level, white_level : float or None
        Levels in counts of the frames it was made from, when known: frames without their own
        (no sidecar, no option) are read with them.
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
        lo, hi = self.valid_depth_range_m
        if not (np.isfinite(lo) and lo > self.model.depth_origin_m and (hi is None or hi >= lo)):
            raise InvalidInputError(f"valid depth range {self.valid_depth_range_m} must lie beyond z0 = {self.model.depth_origin_m}")
        object.__setattr__(self, "planes", tuple(self.planes))

    # -- queries ---------------------------------------------------------------------------
    @property
    def depth_origin_m(self) -> float:
        return self.model.depth_origin_m

    @property
    def num_views(self) -> int:
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

    # -- files -----------------------------------------------------------------------------
    def to_dict(self) -> dict:
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
        from lfring.io.atomic import atomic_write_text

        return atomic_write_text(path, json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> RingCalibration:
        from lfring.io.readers import read_json_object

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
