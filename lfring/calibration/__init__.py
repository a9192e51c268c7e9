"""Variable-homography calibration of refocusing in metric depth.

:class:`RingCalibration` (:mod:`~lfring.calibration.ring`) is the record and its queries; it is
built by :mod:`~lfring.calibration.build` (and :func:`calibrate`, from photographs) and read and
written by :mod:`~lfring.calibration.jsonio`. Those modules make RingCalibration objects, so they
import ring.py; the methods that reach them (``RingCalibration.load`` and the rest) are attached
here, above all three, so that ring.py never imports them back.
"""

from pathlib import Path

from lfring.calibration.build import (
    calibration_from_grid,
    calibration_from_optics,
    calibration_from_plane_homographies,
)
from lfring.calibration.fit import calibrate
from lfring.calibration.jsonio import (
    CALIBRATION_VERSION,
    builtin_calibrations,
    calibration_from_dict,
    calibration_to_dict,
    load_calibration,
    save_calibration,
)
from lfring.calibration.model import PlaneFit, VariableHomography, fit_variable_homography
from lfring.calibration.ring import RingCalibration
from lfring.optics.device import RingDevice
from lfring.views import Layout

__all__ = [
    "CALIBRATION_VERSION",
    "PlaneFit",
    "RingCalibration",
    "VariableHomography",
    "builtin_calibrations",
    "calibrate",
    "calibration_from_dict",
    "calibration_from_grid",
    "calibration_from_optics",
    "calibration_from_plane_homographies",
    "calibration_to_dict",
    "fit_variable_homography",
    "load_calibration",
    "save_calibration",
]


# -- RingCalibration's constructors and file methods: each delegates to one function ----------
def _from_optics(cls, device: RingDevice | str, *, layout: Layout | None = None, rotate180: bool = False) -> RingCalibration:
    """The calibration the paraxial model predicts (pure translations, z0 = s): the default
    when no measured calibration is given. See :func:`calibration_from_optics`."""
    return calibration_from_optics(device, layout=layout, rotate180=rotate180)


def _from_plane_homographies(cls, homographies_by_depth: dict, *, reference: int = 0, depth_origin_m: float | None = 0.0,
                             layout: Layout, pattern: str | None = None, rank1: bool = False,
                             provenance: dict | None = None) -> RingCalibration:
    """Fit the model to homographies from elsewhere: ``{depth_m: H (V, 3, 3)}`` where each H
    maps a view's pixels into view ``reference``; ``depth_origin_m=None`` fits z0 (three
    or more planes). See :func:`calibration_from_plane_homographies`."""
    return calibration_from_plane_homographies(homographies_by_depth, reference=reference, depth_origin_m=depth_origin_m,
                                               layout=layout, pattern=pattern, rank1=rank1, provenance=provenance)


def _from_grid(cls, view_shape: tuple[int, int], grid_positions, *, disparity_scale_px_m: float,
               disparity_offset_px: float = 0.0, depth_origin_m: float = 0.0,
               valid_depth_range_m: tuple[float, float | None] | None = None) -> RingCalibration:
    """The calibration of views on a regular grid, built from its geometry: a rectified
    stereo pair, a camera array, the sub-aperture views of a light-field camera. See
    :func:`calibration_from_grid` for the parameters and the disparity convention."""
    return calibration_from_grid(view_shape, grid_positions, disparity_scale_px_m=disparity_scale_px_m,
                                 disparity_offset_px=disparity_offset_px, depth_origin_m=depth_origin_m,
                                 valid_depth_range_m=valid_depth_range_m)


def _to_dict(self) -> dict:
    """The JSON form of the calibration (what :meth:`save` writes and :meth:`from_dict` reads):
    plain numbers, lists and strings, with the file version ``lfring_calibration_version``. See
    :func:`calibration_to_dict`."""
    return calibration_to_dict(self)


def _from_dict(cls, data, *, source_name: str = "calibration") -> RingCalibration:
    """Build from the JSON form, validating every key (errors name the file and the key). See
    :func:`calibration_from_dict`."""
    return calibration_from_dict(data, source_name=source_name)


def _save(self, path: str | Path) -> Path:
    """Write the calibration as JSON (atomically: a reader never sees half a file) to ``path``,
    making its folder if missing; returns the file written. See :func:`save_calibration`."""
    return save_calibration(self, path)


def _load(cls, path: str | Path) -> RingCalibration:
    """Read a calibration file, or a calibration shipped with lfring by its name (a name
    without a path separator or ``.json`` suffix that is not an existing file, e.g.
    ``'twin_binned2'``; :func:`builtin_calibrations` lists them). See :func:`load_calibration`
    for the errors."""
    return load_calibration(path)


def _attach(name: str, func, *, on_class: bool) -> None:
    """Make ``func`` the method ``RingCalibration.<name>`` (a classmethod when ``on_class``)."""
    func.__name__, func.__qualname__ = name, f"RingCalibration.{name}"
    setattr(RingCalibration, name, classmethod(func) if on_class else func)


for _name, _func, _on_class in (
    ("from_optics", _from_optics, True),
    ("from_plane_homographies", _from_plane_homographies, True),
    ("from_grid", _from_grid, True),
    ("to_dict", _to_dict, False),
    ("from_dict", _from_dict, True),
    ("save", _save, False),
    ("load", _load, True),
):
    _attach(_name, _func, on_class=_on_class)
del _name, _func, _on_class
