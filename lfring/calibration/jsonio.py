"""The JSON form of a RingCalibration: writing and reading calibration files, checking every
key of a file it reads, and the calibrations shipped with lfring.

The methods ``RingCalibration.to_dict``, ``from_dict``, ``save`` and ``load`` delegate here.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from pathlib import Path

import numpy as np

from lfring._resources import calib_dir
from lfring.calibration.model import PlaneFit, VariableHomography
from lfring.calibration.ring import RingCalibration
from lfring.core.lens import FlatField, distortion_from_dict
from lfring.core.validate import is_integer, is_number
from lfring.errors import FileFormatError, InvalidInputError, LfringFileNotFoundError
from lfring.io.atomic import atomic_write_text
from lfring.io.bayer import PATTERNS
from lfring.io.readers import LAYOUT_KEY, RECORD_KEY, read_json
from lfring.optics.device import RingDevice
from lfring.views import Layout

__all__ = [
    "CALIBRATION_SUFFIX",
    "CALIBRATION_VERSION",
    "FLAT_FIELD_GRID_DIVISIONS",
    "READABLE_VERSIONS",
    "builtin_calibrations",
    "calibration_from_dict",
    "calibration_to_dict",
    "load_calibration",
    "save_calibration",
]

CALIBRATION_SUFFIX = ".json"
"""How a calibration file's name ends: the files lfring writes, and what tells a file from the
name of a built-in calibration (:func:`load_calibration`)."""

CALIBRATION_VERSION = 2
"""Version of the calibration file format, written as ``lfring_calibration_version``. Version 2
added each view's lens distortion (``distortion``) and vignetting (``flat_field``); files of
version 1 (neither) are read as they were; other versions are refused."""

READABLE_VERSIONS = (1, 2)
"""The file versions :func:`calibration_from_dict` reads."""

FLAT_FIELD_GRID_DIVISIONS = 48
"""A calibration's flat field is stored as samples every ``side / FLAT_FIELD_GRID_DIVISIONS``
pixels of the views (14 px on the binned twin's 705 px views): the vignetting is smooth, and a
bicubic spline through them restores it to a fraction of a per cent, rims included."""

KEYS = frozenset({
    "lfring_calibration_version", "source", "device", "raw_width_px", "raw_height_px", "bayer_pattern", "layout",
    "reference_view", "depth_origin_m", "model", "A", "B", "valid_depth_range_m", "planes", "provenance",
    "black_level", "white_level", "distortion", "flat_field",
})
"""Every key a calibration file may hold."""

MODEL_KEYS = ("A", "B")
"""The keys of the homography model: a JSON object that holds them is taken for a calibration
(one that lacks its file version is refused as such), any other for no calibration at all."""

REQUIRED_KEYS = ("source", "layout", "reference_view", "depth_origin_m", "A", "B", "valid_depth_range_m",
                 "raw_width_px", "raw_height_px")
"""The keys a calibration file must hold (the others have defaults)."""

_GIVE_A_CALIBRATION = ("give a calibration file (lfring calibrate or lfring grid-calib writes one) or a built-in "
                       "calibration's name")
"""How a refusal of what is no calibration (a file that is not one, a name that is neither a file
nor a built-in) ends: what to give instead."""

_JSON_VALUES = {list: "a JSON list", str: "a JSON string", int: "a JSON number", float: "a JSON number",
                bool: "JSON true or false", type(None): "JSON null"}
"""What a JSON file holds instead of an object, by the Python type json.loads gives it."""

_DEVICE_KEYS = frozenset(f.name for f in dataclasses.fields(RingDevice)
                         if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING)
"""The keys every device description holds (the fields of RingDevice without a default)."""


def calibration_to_dict(calibration: RingCalibration) -> dict:
    """The JSON form of ``calibration`` (what :func:`save_calibration` writes and
    :func:`calibration_from_dict` reads).

    Parameters
    ----------
    calibration : RingCalibration

    Returns
    -------
    dict
        JSON-ready: plain numbers, lists and strings, with the file version
        ``lfring_calibration_version``.

    Examples
    --------
    >>> from lfring.calibration.build import calibration_from_grid
    >>> data = calibration_to_dict(calibration_from_grid((8, 8), [(0, 0), (1, 0)], disparity_scale_px_m=1.0))
    >>> data["lfring_calibration_version"], data["source"], data["valid_depth_range_m"]
    (2, 'grid', [0.125, None])
    """
    cal = calibration
    out = {
        "lfring_calibration_version": CALIBRATION_VERSION,
        "source": cal.source,
        "device": cal.device,
        "raw_width_px": cal.raw_size[0],
        "raw_height_px": cal.raw_size[1],
        "bayer_pattern": cal.pattern,
        "black_level": list(cal.black_level) if isinstance(cal.black_level, tuple) else cal.black_level,
        "white_level": cal.white_level,
        "layout": cal.layout.to_dict(),
        "reference_view": cal.model.reference,
        "depth_origin_m": cal.depth_origin_m,
        "model": "H_ref_from_view(Z) = A + B / (Z - depth_origin_m), normalised so H[2,2] = 1",
        "A": cal.model.A.tolist(),
        "B": cal.model.B.tolist(),
        "valid_depth_range_m": list(cal.valid_depth_range_m),
        "planes": [
            {"depth_m": p.depth_m, "residual_px": p.residual_px.tolist(),
             "leave_one_out_px": None if p.leave_one_out_px is None else p.leave_one_out_px.tolist()}
            for p in cal.planes
        ],
        "provenance": cal.provenance,
    }
    if cal.distortion is not None:
        out["distortion"] = {
            "model": "recorded = ideal + scale_px D((ideal - centre) / scale_px), D a polynomial of z = x + i y and "
                     "its conjugate (terms [a, b, real, imag]: z^a conj(z)^b), or Brown-Conrady; view pixels as the "
                     "layout cuts them",
            "views": [d.to_dict() for d in cal.distortion],
        }
    if cal.flat_field is not None:
        step = max(2, round(min(cal.layout.view_shape) / FLAT_FIELD_GRID_DIVISIONS))
        grid = cal.flat_field.to_grid(step)
        out["flat_field"] = {
            "step_px": step,
            "meaning": "each view's response to a flat white field (1 at the brightest pixel of any view), sampled "
                       "every step_px pixels of the undistorted views from pixel (0, 0), and on their last row "
                       "and column",
            "response": np.round(grid.astype(np.float64), 4).tolist(),
        }
    return out


def calibration_from_dict(data, *, source_name: str = "calibration") -> RingCalibration:
    """Build a calibration from its JSON form, checking every key.

    Parameters
    ----------
    data : dict
        What :func:`calibration_to_dict` returns, or a calibration file's JSON object.
    source_name : str
        Where the data came from (a path or a built-in name), to start error messages with.

    Returns
    -------
    RingCalibration

    Raises
    ------
    FileFormatError
        The data is not a valid calibration; the message names ``source_name`` and the key at
        fault, or, for data that is no calibration at all, what it looks like instead.

    Examples
    --------
    >>> from lfring.calibration.build import calibration_from_grid
    >>> cal = calibration_from_grid((8, 8), [(0, 0), (1, 0)], disparity_scale_px_m=1.0)
    >>> calibration_from_dict(calibration_to_dict(cal)).homographies(1.0)[:, 0, 2]
    array([-0.5,  0.5])
    >>> calibration_from_dict({"lfring_calibration_version": 99}, source_name="new.json")
    Traceback (most recent call last):
    ...
    lfring.errors.FileFormatError: new.json: a calibration of file version 99, written by a newer lfring; this lfring reads versions 1 and 2

    Data that is no calibration at all is named as what it is instead, so that a wrong file
    does not read as a version problem:

    >>> calibration_from_dict([1, 2], source_name="list.json")
    Traceback (most recent call last):
    ...
    lfring.errors.FileFormatError: list.json: not an lfring calibration file: it holds a JSON list; give a calibration file (lfring calibrate or lfring grid-calib writes one) or a built-in calibration's name
    """
    v = _Validator(source_name)
    if not (isinstance(data, dict) and ("lfring_calibration_version" in data or set(MODEL_KEYS) <= set(data))):
        raise FileFormatError(_not_a_calibration(source_name, _what_it_holds(data, source_name)))
    v.require("lfring_calibration_version" in data,
              f"missing key 'lfring_calibration_version' (the file version, {CALIBRATION_VERSION} in the files this "
              "lfring writes)")
    version = data["lfring_calibration_version"]
    readable = f"this lfring reads versions {', '.join(map(str, READABLE_VERSIONS[:-1]))} and {READABLE_VERSIONS[-1]}"
    v.require(is_integer(version), f"its calibration file version is {json.dumps(version)}, not a version number; "
                                   f"{readable}")
    v.require(version in READABLE_VERSIONS,
              f"a calibration of file version {version}" + (", written by a newer lfring" if version > CALIBRATION_VERSION
                                                            else "") + f"; {readable}")
    if version == 1:
        v.require("distortion" not in data and "flat_field" not in data,
                  "'distortion' and 'flat_field' came with version 2; this file says version 1")
    v.require(not (set(data) - KEYS), f"unknown key(s) {sorted(set(data) - KEYS)}")
    for k in REQUIRED_KEYS:
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
    v.require(is_integer(ref) and 0 <= ref < layout.num_views, f"'reference_view' must be a view index, got {ref!r}")
    rng = data["valid_depth_range_m"]
    v.require(isinstance(rng, list) and len(rng) == 2, "'valid_depth_range_m' must be [min, max or null]")
    lo = v.number(rng[0], "valid_depth_range_m[0]")
    hi = None if rng[1] is None else v.number(rng[1], "valid_depth_range_m[1]")
    pattern = data.get("bayer_pattern")
    v.require(pattern is None or pattern in PATTERNS, f"'bayer_pattern' must be one of {PATTERNS} or null, got {pattern!r}")
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
        v.require(isinstance(p, dict) and "depth_m" in p and "residual_px" in p,
                  f"'planes'[{i}] must have depth_m and residual_px")
        res = np.asarray(p["residual_px"], dtype=np.float64)
        loo = p.get("leave_one_out_px")
        planes.append(PlaneFit(v.number(p["depth_m"], f"planes[{i}].depth_m"), res,
                               None if loo is None else np.asarray(loo, dtype=np.float64)))
    extra = {}
    if data.get("distortion") is not None:
        dist = data["distortion"]
        v.require(isinstance(dist, dict) and isinstance(dist.get("views"), list) and len(dist["views"]) == layout.num_views,
                  f"'distortion' must hold 'views': one distortion per view ({layout.num_views})")
        try:
            extra["distortion"] = tuple(distortion_from_dict(d) for d in dist["views"])
        except InvalidInputError as exc:
            raise FileFormatError(f"{source_name}: 'distortion': {exc}") from None
    if data.get("flat_field") is not None:
        flat = data["flat_field"]
        v.require(isinstance(flat, dict) and "step_px" in flat and "response" in flat,
                  "'flat_field' must hold 'step_px' and 'response'")
        try:
            extra["flat_field"] = FlatField.from_grid(np.asarray(flat["response"], dtype=np.float64), flat["step_px"],
                                                      layout.view_shape)
        except (InvalidInputError, TypeError, ValueError) as exc:
            raise FileFormatError(f"{source_name}: 'flat_field': {exc}") from None
    try:
        return RingCalibration(
            model=VariableHomography(a, b, z0, ref), layout=layout, valid_depth_range_m=(lo, hi), pattern=pattern,
            planes=tuple(planes), source=data["source"], device=data.get("device"),
            provenance=data.get("provenance") or {}, **levels, **extra,
        )
    except InvalidInputError as exc:
        raise FileFormatError(f"{source_name}: {exc}") from None


def save_calibration(calibration: RingCalibration, path: str | Path) -> Path:
    """Write ``calibration`` as JSON (atomically: a reader never sees half a file).

    Parameters
    ----------
    calibration : RingCalibration
    path : str or Path
        The file to write; missing folders on its path are made.

    Returns
    -------
    Path
        The file written.
    """
    return atomic_write_text(path, json.dumps(calibration_to_dict(calibration), indent=2) + "\n")


def load_calibration(path: str | Path) -> RingCalibration:
    """Read a calibration file, or a calibration shipped with lfring by its name.

    Parameters
    ----------
    path : str or Path
        A JSON file written by :func:`save_calibration` (or ``lfring calibrate``), or the name
        of a built-in calibration (:func:`builtin_calibrations`), e.g. ``'twin_binned2'``: a
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
        The file is not a valid calibration (the message names the key at fault), or no
        calibration at all: not JSON (an image, say) or another kind of JSON file (the message
        says which, where its keys or name tell).

    Examples
    --------
    >>> cal = load_calibration("twin_binned2")
    >>> cal.raw_size, cal.num_views, cal.source
    ((2456, 1842), 4, 'planes')
    """
    if _is_builtin_name(path):
        names = builtin_calibrations()
        if str(path) not in names:
            raise LfringFileNotFoundError(
                f"calibration file not found: {path}, and no built-in calibration of that name "
                f"(built-in: {', '.join(names) or 'none'}); {_GIVE_A_CALIBRATION}"
            )
        data = json.loads((calib_dir() / f"{path}{CALIBRATION_SUFFIX}").read_text(encoding="utf-8"))
        return calibration_from_dict(data, source_name=str(path))
    data = read_json(path, "calibration", refusal=lambda why: _not_a_calibration(str(path), why))
    return calibration_from_dict(data, source_name=str(path))


def builtin_calibrations() -> dict[str, tuple[int, int]]:
    """The calibrations shipped with lfring (the repository's calib/ folder, installed as the
    package ``lfring._calib``), by name.

    Returns
    -------
    dict of str to (int, int)
        Name (what :func:`load_calibration` and ``RingCalibration.load`` accept) -> raw size
        (width, height) in pixels of the frames the calibration is for, sorted by name.

    Examples
    --------
    >>> names = builtin_calibrations()
    >>> names["twin_binned2"], names["prototype_optics"]
    ((2456, 1842), (4912, 3684))
    """
    out = {}
    for entry in sorted(calib_dir().iterdir(), key=lambda e: e.name):
        if entry.name.endswith(CALIBRATION_SUFFIX):
            data = json.loads(entry.read_text(encoding="utf-8"))
            if "lfring_calibration_version" in data:
                out[entry.name[: -len(CALIBRATION_SUFFIX)]] = (data["raw_width_px"], data["raw_height_px"])
    return out


def _is_builtin_name(path) -> bool:
    """Whether ``path`` is to be looked up among the built-in calibrations: a bare name (no path
    separator, no .json suffix) that is not an existing file."""
    text = str(path)
    separators = {"/", os.sep} | ({os.altsep} if os.altsep else set())
    return (bool(text) and not any(s in text for s in separators) and not text.lower().endswith(CALIBRATION_SUFFIX)
            and not Path(text).exists())


def _not_a_calibration(source: str, what: str) -> str:
    """The refusal of a file (or data) that is no calibration at all: its name, ``what`` it is
    instead, and what to give."""
    return f"{source}: not an lfring calibration file: {what}; {_GIVE_A_CALIBRATION}"


def _what_it_holds(data, source: str) -> str:
    """What JSON ``data`` that is no calibration is: the kind of lfring file whose marks it
    carries (a layout, a record of outputs, a device description, an image's sidecar, told by
    its keys or, for a sidecar, by its name beside the image), else the kind of JSON value."""
    if not isinstance(data, dict):
        return f"it holds {_JSON_VALUES.get(type(data), 'no JSON object')}"
    if LAYOUT_KEY in data:
        return "it looks like a layout file (lfring split writes one; --layout reads it)"
    if RECORD_KEY in data:
        return "it looks like the record lfring keeps of a command's or a batch's outputs"
    device = data["device"] if set(data) == {"device"} else data  # a device file may hold one [device] table
    if isinstance(device, dict) and _DEVICE_KEYS <= set(device):
        return "it looks like a device description (lfring calibrate --device reads one)"
    image = Path(source).with_suffix("")
    if Path(source).suffix.lower() == CALIBRATION_SUFFIX and image.suffix and image.is_file():
        return f"it looks like the sidecar of the image {image.name}"
    return "it holds a JSON object without a calibration's keys"


class _Validator:
    """Checks of a calibration file's values; each refusal is a FileFormatError that starts
    with the file's name and names the key at fault."""

    def __init__(self, source: str):
        self.source = source

    def require(self, ok: bool, message: str) -> None:
        if not ok:
            raise FileFormatError(f"{self.source}: {message}")

    def number(self, value, key: str) -> float:
        try:
            finite = is_number(value) and math.isfinite(value)
        except OverflowError:  # a JSON integer too large for a float
            finite = False
        self.require(finite, f"'{key}' must be a finite number, got {value!r}")
        return float(value)

    def matrices(self, value, key: str, views: int) -> np.ndarray:
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            arr = None
        self.require(arr is not None and arr.shape == (views, 3, 3) and bool(np.all(np.isfinite(arr))),
                     f"'{key}' must be {views} finite 3 x 3 matrices")
        return arr
