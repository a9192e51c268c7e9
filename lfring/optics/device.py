"""The ring-camera device record and its files.

A device is everything the source paper's paraxial model needs: the main lens, the four
mini-lenses, the sensor, the mount, and optionally the positions ``b`` (main lens -> ring) and
``c`` (ring -> sensor) the device is set to. All lengths are in metres.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import sys
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from lfring._resources import calib_dir
from lfring.core.validate import check_int, check_number, is_number
from lfring.errors import DeviceError, InvalidInputError, LfringFileNotFoundError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised only on Python 3.10
    import tomli as tomllib

__all__ = ["MiniLens", "RingDevice", "load_device", "save_device", "builtin_devices"]

_LENGTH_FIELDS = (
    "main_focal_length_m",
    "main_lens_radius_m",
    "mini_focal_length_m",
    "mini_lens_radius_m",
    "mini_lens_offset_m",
    "pixel_pitch_m",
)
_OPTIONAL_LENGTHS = ("sensor_width_m", "sensor_height_m", "aperture_radius_m", "ring_distance_m", "sensor_distance_m")
#: Relative disagreement allowed between a declared sensor size and pixels times pitch.
SENSOR_SIZE_TOLERANCE = 0.01
#: Largest tilt of a mini-lens in its seat, degrees: "a little", where the thin-lens picture holds.
MAX_TILT_DEG = 10.0
#: Longest length of a device record (focal lengths, radii, distances, the sensor), metres: a
#: camera the ring fits into is smaller; a longer one is millimetres given as metres.
MAX_LENGTH_M = 1.0
#: The pixel pitches a sensor (binned or not) can have, metres: outside, micrometres or
#: millimetres were given as metres.
PITCH_RANGE_M = (1e-7, 1e-3)


@dataclass(frozen=True)
class MiniLens:
    """How one real mini-lens departs from the ideal thin lens of the paraxial model.

    Parameters
    ----------
    k1, k2 : float
        Radial distortion, OpenCV's convention, on normalised coordinates: the sensor offset
        from the lens's axis divided by the sensor distance c (the tangent of the ray's angle
        behind the lens). Negative is barrel.
    p1, p2 : float
        Decentring (tangential) distortion, on the same coordinates.
    decentre_m : (float, float)
        (dx, dy) of the lens's centre from its nominal place (+-hml, +-hml), metres: the view's
        projection centre, principal point and disc move with it.
    tilt_deg : (float, float)
        Rotation of the lens in its seat about the x and then the y axis, degrees (at most
        ``MAX_TILT_DEG``). The chief ray through a thin lens's centre keeps its line, so a tilt
        moves where the distortion is centred and nothing else (its slight defocus and
        vignetting changes are not modelled).
    transmission : float
        Share of the light it lets through relative to an ideal lens, in (0, 1].
    falloff : (float, float, float)
        (strength, dx, dy): an extra radial fall-off of its view, ``1 / (1 + strength rho^2)^2``,
        rho the distance from the view's disc centre moved by (dx, dy) disc radii, in disc radii
        (as :attr:`lfring.synth.RenderSettings.view_falloff`).

    Notes
    -----
    The distortion of view k, in view pixels, is :func:`lfring.optics.views.lens_distortions`:
    a :class:`lfring.core.lens.LensDistortion` centred where the lens's centre projects onto
    the sensor, with ``scale_px`` = c over the pixel pitch.
    """

    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    decentre_m: tuple[float, float] = (0.0, 0.0)
    tilt_deg: tuple[float, float] = (0.0, 0.0)
    transmission: float = 1.0
    falloff: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        for key in ("k1", "k2", "p1", "p2"):
            object.__setattr__(self, key, check_number(getattr(self, key), f"mini-lens '{key}'", error=DeviceError))
        object.__setattr__(self, "decentre_m", _numbers(self.decentre_m, "decentre_m", 2))
        tilt = _numbers(self.tilt_deg, "tilt_deg", 2)
        if max(abs(t) for t in tilt) > MAX_TILT_DEG:
            raise DeviceError(f"mini-lens 'tilt_deg' must be at most {MAX_TILT_DEG:g} degrees about each axis, got {tilt}")
        object.__setattr__(self, "tilt_deg", tilt)
        object.__setattr__(self, "transmission", check_number(self.transmission, "mini-lens 'transmission'", above=0.0,
                                                              maximum=1.0, error=DeviceError))
        fall = _numbers(self.falloff, "falloff", 3)
        if fall[0] < 0 or max(abs(fall[1]), abs(fall[2])) > 1:
            raise DeviceError(f"mini-lens 'falloff' must be (strength >= 0, dx, dy) with |dx|, |dy| <= 1, got {fall}")
        object.__setattr__(self, "falloff", fall)

    @property
    def distorts(self) -> bool:
        """True when the lens moves image points (a distortion coefficient is not 0)."""
        return any((self.k1, self.k2, self.p1, self.p2))

    @property
    def is_ideal(self) -> bool:
        """True when the lens is the paraxial model's (every field at its default)."""
        return self == MiniLens()

    def to_dict(self) -> dict[str, Any]:
        """The fields that differ from an ideal lens (tuples as lists)."""
        ideal = MiniLens()
        return {f.name: (list(v) if isinstance(v, tuple) else v)
                for f in fields(self) if (v := getattr(self, f.name)) != getattr(ideal, f.name)}

    @classmethod
    def from_dict(cls, data: dict[str, Any], *, source: str = "mini-lens") -> MiniLens:
        """Build from a table of the fields, with errors that name the bad key."""
        if not isinstance(data, dict):
            raise DeviceError(f"{source}: expected a table of mini-lens keys, got {type(data).__name__}")
        known = [f.name for f in fields(cls)]
        unknown = sorted(set(data) - set(known))
        if unknown:
            raise DeviceError(f"{source}: unknown key(s) {', '.join(repr(k) for k in unknown)}; valid keys are "
                              f"{', '.join(known)}")
        try:
            return cls(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in data.items()})
        except DeviceError as exc:
            raise DeviceError(f"{source}: {exc}") from None


def _numbers(value, key: str, count: int) -> tuple[float, ...]:
    try:
        items = tuple(value)
    except TypeError:
        items = ()
    if len(items) != count:
        raise DeviceError(f"mini-lens '{key}' must be {count} numbers, got {value!r}")
    return tuple(check_number(v, f"mini-lens '{key}'", error=DeviceError) for v in items)


@dataclass(frozen=True)
class RingDevice:
    """Paraxial description of a camera fitted with a four mini-lens ring.

    Parameters
    ----------
    name : str
        Short identifier, e.g. ``"prototype"``.
    main_focal_length_m, main_lens_radius_m : float
        Focal length FL and mechanical radius RL of the main lens.
    mini_focal_length_m, mini_lens_radius_m : float
        Focal length Fml and aperture radius Rml of each mini-lens.
    mini_lens_offset_m : float
        hml: each mini-lens centre sits at (+-hml, +-hml) from the optical axis.
    sensor_width_px, sensor_height_px : int
        Sensor size in pixels.
    pixel_pitch_m : float
        tpix, the pixel pitch.
    sensor_width_m, sensor_height_m : float or None
        ws, hs: the active area as the datasheet gives it, used by the lens-position design
        equations. ``None`` means pixels times pitch; a given value must agree with that
        within ``SENSOR_SIZE_TOLERANCE`` (a relative tolerance: datasheets round).
    flange_focal_distance_m, screw_thread_m : float
        FFD and ST of the lens mount, used for the mount distance B of the lens-position design.
    aperture_radius_m : float or None
        Radius of the main lens iris. Its image through each mini-lens is the disc of sensor that
        the mini-lens lights (the field stop of the view). ``None`` means the full lens radius.
    ring_distance_m, sensor_distance_m : float or None
        The positions b and c the device is set to; ``None`` when not set (design them with
        :func:`lfring.optics.design`, then :meth:`with_positions`).
    description : str
        Free text.
    lenses : tuple of four MiniLens, or None
        How each real mini-lens (view order) departs from the ideal one: distortion,
        decentring, tilt, transmission and fall-off. None: four ideal lenses. In a file, four
        ``[[lenses]]`` tables.

    Notes
    -----
    Mini-lens k has its centre at ``lens_centres_m[k]`` in sensor coordinates (x to the right,
    y down, origin on the optical axis), in view order 0 top-left, 1 top-right, 2 bottom-left,
    3 bottom-right.
    """

    name: str
    main_focal_length_m: float
    main_lens_radius_m: float
    mini_focal_length_m: float
    mini_lens_radius_m: float
    mini_lens_offset_m: float
    sensor_width_px: int
    sensor_height_px: int
    pixel_pitch_m: float
    sensor_width_m: float | None = None
    sensor_height_m: float | None = None
    flange_focal_distance_m: float = 0.0
    screw_thread_m: float = 0.0
    aperture_radius_m: float | None = None
    ring_distance_m: float | None = None
    sensor_distance_m: float | None = None
    description: str = ""
    lenses: tuple[MiniLens, ...] | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise DeviceError(f"device 'name' must be a non-empty string, got {self.name!r}")
        if self.lenses is not None:
            lenses = tuple(self.lenses) if not isinstance(self.lenses, (str, dict)) else ()
            if len(lenses) != 4 or not all(isinstance(lens, MiniLens) for lens in lenses):
                raise DeviceError(f"device 'lenses' must be four MiniLens records (one per view), got {self.lenses!r}")
            object.__setattr__(self, "lenses", None if all(lens.is_ideal for lens in lenses) else lenses)
        millimetres = " (lengths are in metres: no part of a camera the ring fits is longer; were millimetres given?)"
        for key in _LENGTH_FIELDS:
            if key != "pixel_pitch_m":
                _metres(key, getattr(self, key), above=0.0, maximum=MAX_LENGTH_M, hint=millimetres)
        for key in _OPTIONAL_LENGTHS:
            _metres(key, getattr(self, key), above=0.0, maximum=MAX_LENGTH_M, allow_none=True, hint=millimetres)
        for key in ("flange_focal_distance_m", "screw_thread_m"):
            _metres(key, getattr(self, key), minimum=0.0, maximum=MAX_LENGTH_M, hint=millimetres)
        _metres("pixel_pitch_m", self.pixel_pitch_m, minimum=PITCH_RANGE_M[0], maximum=PITCH_RANGE_M[1],
                hint=" (a sensor's pixel pitch: 1.85 um is 1.85e-06 m)")
        for key in ("sensor_width_px", "sensor_height_px"):
            check_int(getattr(self, key), f"device '{key}'", minimum=2, error=DeviceError)
        for key, px in (("sensor_width_m", "sensor_width_px"), ("sensor_height_m", "sensor_height_px")):
            from_pixels = getattr(self, px) * self.pixel_pitch_m
            declared = getattr(self, key)
            if declared is None:
                object.__setattr__(self, key, float(from_pixels))
            elif abs(declared - from_pixels) > SENSOR_SIZE_TOLERANCE * from_pixels:
                raise DeviceError(
                    f"device '{key}' ({declared!r} m) disagrees with '{px}' x 'pixel_pitch_m' "
                    f"({from_pixels!r} m) by more than {SENSOR_SIZE_TOLERANCE:.0%}"
                )
        if self.mini_lens_offset_m < self.mini_lens_radius_m:
            raise DeviceError(
                "device mini-lenses overlap: 'mini_lens_offset_m' "
                f"({self.mini_lens_offset_m!r}) must be >= 'mini_lens_radius_m' "
                f"({self.mini_lens_radius_m!r})"
            )
        if self.aperture_radius_m is not None and self.aperture_radius_m > self.main_lens_radius_m:
            raise DeviceError(
                f"device 'aperture_radius_m' ({self.aperture_radius_m!r}) cannot exceed "
                f"'main_lens_radius_m' ({self.main_lens_radius_m!r})"
            )
        if (self.ring_distance_m is None) != (self.sensor_distance_m is None):
            raise DeviceError(
                "device 'ring_distance_m' and 'sensor_distance_m' must be given together"
            )
        if self.sensor_distance_m is not None and self.sensor_distance_m <= self.mini_focal_length_m:
            raise DeviceError(
                f"device 'sensor_distance_m' ({self.sensor_distance_m!r} m) must exceed the mini-lenses' focal length "
                f"'mini_focal_length_m' ({self.mini_focal_length_m!r} m): nearer, they image nothing on the sensor"
            )
        if self.ring_distance_m is not None and self.ring_distance_m <= self.main_focal_length_m:
            raise DeviceError(
                f"device 'ring_distance_m' ({self.ring_distance_m!r} m) must exceed the main "
                f"focal length ({self.main_focal_length_m!r} m): the ring sits behind the "
                "intermediate image"
            )

    # -- derived quantities -------------------------------------------------------------------
    @property
    def effective_aperture_radius_m(self) -> float:
        """The main-lens iris radius, the full lens radius when no iris is given."""
        return self.main_lens_radius_m if self.aperture_radius_m is None else self.aperture_radius_m

    @property
    def lens_centres_m(self) -> np.ndarray:
        """(4, 2) mini-lens centres (x, y) in metres, view order 0 TL, 1 TR, 2 BL, 3 BR (each
        lens's ``decentre_m`` included)."""
        h = self.mini_lens_offset_m
        centres = np.array([[-h, -h], [h, -h], [-h, h], [h, h]], dtype=np.float64)
        if self.lenses is not None:
            centres += np.array([lens.decentre_m for lens in self.lenses], dtype=np.float64)
        return centres

    def lens(self, view: int) -> MiniLens:
        """The mini-lens of view ``view`` (an ideal one when the device describes none)."""
        return MiniLens() if self.lenses is None else self.lenses[view]

    @property
    def distorts(self) -> bool:
        """True when some mini-lens distorts its view."""
        return self.lenses is not None and any(lens.distorts for lens in self.lenses)

    def with_lenses(self, lenses) -> RingDevice:
        """A copy of the device with these four mini-lenses (view order; None: ideal ones)."""
        return dataclasses.replace(self, lenses=None if lenses is None else tuple(lenses))

    @property
    def has_positions(self) -> bool:
        """True when the lens positions (``ring_distance_m`` b, ``sensor_distance_m`` c) are set."""
        return self.ring_distance_m is not None

    def require_positions(self) -> tuple[float, float]:
        """Return (b, c) or raise :class:`DeviceError` if the device has none."""
        if self.ring_distance_m is None or self.sensor_distance_m is None:
            raise DeviceError(
                f"device '{self.name}' has no lens positions: set 'ring_distance_m' and "
                "'sensor_distance_m', or design them with lfring.optics.design() and "
                "RingDevice.with_positions()"
            )
        return self.ring_distance_m, self.sensor_distance_m

    @property
    def entrance_pupil_m(self) -> float:
        """s = b FL / (b - FL): where the views' projection centres sit in front of the main lens."""
        b, _ = self.require_positions()
        fl = self.main_focal_length_m
        return b * fl / (b - fl)

    def with_positions(self, ring_distance_m: float, sensor_distance_m: float) -> RingDevice:
        """A copy of the device set to ring distance b and sensor distance c (metres)."""
        return dataclasses.replace(
            self, ring_distance_m=float(ring_distance_m), sensor_distance_m=float(sensor_distance_m)
        )

    def binned(self, factor: int) -> RingDevice:
        """The same optics on a sensor binned ``factor`` x ``factor`` (pitch times ``factor``).

        Pixel counts are rounded down to even numbers: a binned colour sensor still delivers
        whole 2 x 2 CFA blocks."""
        check_int(factor, "binning factor", minimum=1, error=DeviceError)
        if factor == 1:
            return self

        def fits(f: int) -> bool:  # whole 2 x 2 blocks cover the sensor to within its size tolerance
            return all(n - (n // f) // 2 * 2 * f <= SENSOR_SIZE_TOLERANCE * n and n // f >= 2
                       for n in (self.sensor_width_px, self.sensor_height_px))

        if not fits(factor):
            top = max(f for f in range(1, factor) if fits(f))
            raise DeviceError(f"binning factor {factor} is too coarse for the {self.sensor_width_px} x "
                              f"{self.sensor_height_px} px sensor of device '{self.name}': its binned pixels, in whole "
                              f"2 x 2 blocks, would leave more than {SENSOR_SIZE_TOLERANCE:.0%} of it uncovered (the "
                              f"largest factor below it that fits: {top})")
        return dataclasses.replace(
            self,
            sensor_width_px=(self.sensor_width_px // factor) // 2 * 2,
            sensor_height_px=(self.sensor_height_px // factor) // 2 * 2,
            pixel_pitch_m=self.pixel_pitch_m * factor,
        )

    def for_frames(self, size, *, whose: str = "") -> RingDevice:
        """This device binned to frames of ``size`` (width, height) px: itself when its sensor is
        that size, else the binning that makes it so. Raises DeviceError when none does (the
        frames are another camera's); ``whose`` names the frames there ("the calibration's ")."""
        scale = self.sensor_width_px // size[0] if size[0] else 0
        dev = self
        if scale > 1:
            with contextlib.suppress(DeviceError):  # too coarse a binning for the sensor: no match either
                dev = self.binned(scale)
        if (dev.sensor_width_px, dev.sensor_height_px) != tuple(size):
            raise DeviceError(f"the device {self.name!r} has a {self.sensor_width_px} x {self.sensor_height_px} px sensor, "
                              f"which no binning turns into {whose}{size[0]} x {size[1]} px frames")
        return dev

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of every field (``None`` fields left out), suitable for JSON or TOML."""
        out: dict[str, Any] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if value is None:
                continue
            if f.name == "lenses":
                out[f.name] = [lens.to_dict() for lens in value]
                continue
            out[f.name] = int(value) if f.name.endswith("_px") else value
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any], *, source: str = "device") -> RingDevice:
        """Build a device from a dict, with errors that name the bad key and the source."""
        if not isinstance(data, dict):
            raise DeviceError(f"{source}: expected a table of device keys, got {type(data).__name__}")
        known = {f.name: f for f in fields(cls)}
        unknown = sorted(set(data) - set(known))
        if unknown:
            raise DeviceError(
                f"{source}: unknown key(s) {', '.join(repr(k) for k in unknown)}; "
                f"valid keys are {', '.join(known)}"
            )
        required = [
            f.name
            for f in fields(cls)
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        ]
        missing = [k for k in required if k not in data]
        if missing:
            raise DeviceError(f"{source}: missing key(s) {', '.join(repr(k) for k in missing)}")
        data = dict(data)
        if "lenses" in data:
            lenses = data["lenses"]
            if not isinstance(lenses, list) or len(lenses) != 4:
                raise DeviceError(f"{source}: key 'lenses' must be four tables (one per view, [[lenses]] in TOML), "
                                  f"got {lenses!r}")
            data["lenses"] = tuple(MiniLens.from_dict(t, source=f"{source}: lenses[{i}]") for i, t in enumerate(lenses))
        for key, value in data.items():
            if key == "lenses":
                continue
            if key in ("name", "description"):
                if not isinstance(value, str):
                    raise DeviceError(f"{source}: key '{key}' must be a string, got {value!r}")
            elif key.endswith("_px"):
                check_int(value, f"{source}: key '{key}'", error=DeviceError)
            elif not is_number(value):
                raise DeviceError(
                    f"{source}: key '{key}' must be a number in metres, got {value!r}"
                )
        try:
            return cls(**{k: (float(v) if k.endswith("_m") else v) for k, v in data.items()})
        except DeviceError as exc:
            raise DeviceError(f"{source}: {exc}") from None


def _metres(key: str, value: Any, **bounds) -> float | None:
    """A finite length of the device record within ``bounds`` (those of :func:`check_number`)."""
    return check_number(value, f"device '{key}'", what="a number in metres", error=DeviceError, **bounds)


def builtin_devices() -> list[str]:
    """Names of the device files shipped with lfring (usable with :func:`load_device`)."""
    root = calib_dir()
    return sorted(p.name[: -len(".toml")] for p in root.iterdir() if p.name.endswith(".toml"))


def load_device(name_or_path: str | Path | RingDevice) -> RingDevice:
    """Load a device by built-in name (``"prototype"``) or from a TOML or JSON file.

    Parameters
    ----------
    name_or_path : str, path-like or RingDevice
        A name from :func:`builtin_devices`, or the path of a ``.toml`` / ``.json`` file whose
        keys are the fields of :class:`RingDevice` (an optional top-level ``[device]`` table is
        accepted); a RingDevice is returned as it is (so that functions taking a device take
        any of the three).

    Returns
    -------
    RingDevice

    Examples
    --------
    >>> import lfring.optics
    >>> dev = lfring.optics.load_device("prototype")
    >>> round(dev.main_focal_length_m * 1e3, 3)
    16.0
    """
    if isinstance(name_or_path, RingDevice):
        return name_or_path
    if not isinstance(name_or_path, (str, os.PathLike)):
        raise InvalidInputError(f"a device is a RingDevice, a built-in name ({', '.join(builtin_devices())}) or the path "
                                f"of a .toml/.json device file, got {type(name_or_path).__name__}")
    text_name = str(name_or_path)
    path = Path(text_name)
    if path.suffix.lower() not in (".toml", ".json") and path.parent == Path("."):
        resource = calib_dir() / f"{text_name}.toml"
        if not resource.is_file():
            raise LfringFileNotFoundError(
                f"no built-in device named {text_name!r}; built-in devices: "
                f"{', '.join(builtin_devices())}; or give the path of a .toml/.json device file"
            )
        return _parse_device(resource.read_bytes(), ".toml", f"device '{text_name}'")
    if not path.is_file():
        raise LfringFileNotFoundError(f"device file not found: {path}")
    return _parse_device(path.read_bytes(), path.suffix.lower(), str(path))


def _parse_device(raw: bytes, suffix: str, source: str) -> RingDevice:
    try:
        text = raw.decode("utf-8")
        data = json.loads(text) if suffix == ".json" else tomllib.loads(text)
    except (UnicodeDecodeError, json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
        raise DeviceError(f"{source}: not a valid {suffix[1:].upper()} file ({exc})") from None
    if isinstance(data, dict) and set(data) == {"device"}:
        data = data["device"]
    return RingDevice.from_dict(data, source=source)


def save_device(device: RingDevice, path: str | Path) -> Path:
    """Write ``device`` to a ``.toml`` or ``.json`` file that :func:`load_device` reads back."""
    path = Path(path)
    data = device.to_dict()
    if path.suffix.lower() == ".json":
        text = json.dumps(data, indent=2) + "\n"
    elif path.suffix.lower() == ".toml":
        lines = []
        lenses = data.pop("lenses", None)
        for key, value in data.items():
            lines.append(f"{key} = {json.dumps(value) if isinstance(value, str) else repr(value)}")
        for lens in lenses or ():
            lines += ["", "[[lenses]]"] + [f"{key} = {value!r}" for key, value in lens.items()]
        text = "\n".join(lines) + "\n"
    else:
        raise DeviceError(f"device files are .toml or .json, got {path.name!r}")
    from lfring.io.atomic import atomic_write_text

    atomic_write_text(path, text)
    return path
