"""The ring-camera device record and its files.

A device is everything the source paper's paraxial model needs: the main lens, the four
mini-lenses, the sensor, the mount, and optionally the positions ``b`` (main lens -> ring) and
``c`` (ring -> sensor) the device is set to. All lengths are in metres.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from lfring._resources import calib_dir
from lfring.core.validate import check_int, check_number, is_number
from lfring.errors import DeviceError, LfringFileNotFoundError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised only on Python 3.10
    import tomli as tomllib

__all__ = ["RingDevice", "load_device", "save_device", "builtin_devices"]

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

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise DeviceError(f"device 'name' must be a non-empty string, got {self.name!r}")
        for key in _LENGTH_FIELDS:
            _metres(key, getattr(self, key), above=0.0)
        for key in _OPTIONAL_LENGTHS:
            _metres(key, getattr(self, key), above=0.0, allow_none=True)
        for key in ("flange_focal_distance_m", "screw_thread_m"):
            _metres(key, getattr(self, key), minimum=0.0)
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
        """(4, 2) mini-lens centres (x, y) in metres, view order 0 TL, 1 TR, 2 BL, 3 BR."""
        h = self.mini_lens_offset_m
        return np.array([[-h, -h], [h, -h], [-h, h], [h, h]], dtype=np.float64)

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
        return dataclasses.replace(
            self,
            sensor_width_px=(self.sensor_width_px // factor) // 2 * 2,
            sensor_height_px=(self.sensor_height_px // factor) // 2 * 2,
            pixel_pitch_m=self.pixel_pitch_m * factor,
        )

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of every field (``None`` fields left out), suitable for JSON or TOML."""
        out: dict[str, Any] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if value is None:
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
        for key, value in data.items():
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


def load_device(name_or_path: str | Path) -> RingDevice:
    """Load a device by built-in name (``"prototype"``) or from a TOML or JSON file.

    Parameters
    ----------
    name_or_path : str or path-like
        A name from :func:`builtin_devices`, or the path of a ``.toml`` / ``.json`` file whose
        keys are the fields of :class:`RingDevice` (an optional top-level ``[device]`` table is
        accepted).

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
        for key, value in data.items():
            lines.append(f"{key} = {json.dumps(value) if isinstance(value, str) else repr(value)}")
        text = "\n".join(lines) + "\n"
    else:
        raise DeviceError(f"device files are .toml or .json, got {path.name!r}")
    from lfring.io.atomic import atomic_write_text

    atomic_write_text(path, text)
    return path
