"""Thin-lens (paraxial) model of the ring camera: intermediate image, magnification, chief-ray
images on the sensor, defocus and disparity.

Sensor coordinates are metres from the optical axis, x to the right and y down, in the frame
the views are numbered in (after the optional 180-degree rotation of the raw frame). The image
through the main lens and then a mini-lens is erect, so world X (right) and Y (down) map to
sensor x and y with a positive scale.
"""

from __future__ import annotations

import numpy as np

from lfring.core.validate import check_number
from lfring.errors import InvalidInputError
from lfring.optics.device import RingDevice

__all__ = [
    "MIN_F_NUMBER",
    "check_f_number",
    "intermediate_distance_m",
    "mini_object_distance_m",
    "magnification",
    "project_points_m",
    "sensor_to_pixel",
    "pixel_to_sensor",
    "focus_sensor_distance_m",
    "blur_diameter_m",
    "disparity_px",
]

#: Smallest f-number a lens can have: in air the image-side numerical aperture NA (the sine of
#: the marginal ray's angle) is at most 1, and N = 1 / (2 NA), so N >= 0.5. A smaller one names
#: an aperture no lens has.
MIN_F_NUMBER = 0.5


def check_f_number(f_number, *, allow_none: bool = False, pinhole: bool = False) -> float | None:
    """``f_number`` as a float of at least :data:`MIN_F_NUMBER` (``inf``, a pinhole, where
    ``pinhole``; None where ``allow_none``), else an error that says why.

    >>> check_f_number(2.8), check_f_number(float("inf"), pinhole=True)
    (2.8, inf)
    """
    hint = " (no lens in air has a smaller one; inf for a pinhole)" if pinhole else ": no lens in air has a smaller one"
    return check_number(f_number, "f_number", minimum=MIN_F_NUMBER, finite=not pinhole, allow_none=allow_none,
                        what="an f-number", hint=hint)


def _depth(distance_m, device: RingDevice) -> np.ndarray:
    z = np.asarray(distance_m, dtype=np.float64)
    if not np.all(np.isfinite(z)):
        raise InvalidInputError("distances must be finite numbers of metres")
    if np.any(z <= device.main_focal_length_m):
        raise InvalidInputError(
            f"distance must exceed the main lens focal length ({device.main_focal_length_m} m): "
            f"got {np.min(z)!r} m, which forms no real intermediate image"
        )
    return z


def intermediate_distance_m(device: RingDevice, distance_m) -> np.ndarray:
    """b1 = Z FL / (Z - FL): distance behind the main lens of the intermediate image."""
    z = _depth(distance_m, device)
    fl = device.main_focal_length_m
    return z * fl / (z - fl)


def mini_object_distance_m(device: RingDevice, distance_m) -> np.ndarray:
    """b2 = b - b1: distance of the intermediate image in front of the ring."""
    b, _ = device.require_positions()
    return b - intermediate_distance_m(device, distance_m)


def magnification(device: RingDevice, distance_m) -> np.ndarray:
    """Chief-ray lateral magnification G = FL/(Z - FL) * c/b2 of a plane at ``distance_m``."""
    z = _depth(distance_m, device)
    _, c = device.require_positions()
    return device.main_focal_length_m / (z - device.main_focal_length_m) * c / mini_object_distance_m(device, z)


def project_points_m(device: RingDevice, points_m) -> np.ndarray:
    """Chief-ray images of world points on the sensor, one per mini-lens.

    Parameters
    ----------
    device : RingDevice
        With lens positions set.
    points_m : array_like, (..., 3)
        World points (X right, Y down, Z forward from the main lens), metres.

    Returns
    -------
    ndarray, (4, ..., 2)
        Sensor positions (x, y) in metres, per view.

    Notes
    -----
    ``x1 = -X b1 / Z`` (the inverted intermediate image) and ``x2_k = m_k + (m_k - x1) c / b2``.
    """
    p = np.asarray(points_m, dtype=np.float64)
    if p.shape[-1] != 3:
        raise InvalidInputError(f"points_m must have a last axis of 3 (X, Y, Z), got shape {p.shape}")
    _, c = device.require_positions()
    z = p[..., 2]
    b1 = intermediate_distance_m(device, z)
    b2 = mini_object_distance_m(device, z)
    x1 = -p[..., :2] * (b1 / z)[..., None]
    m = device.lens_centres_m.reshape((4,) + (1,) * (p.ndim - 1) + (2,))
    return m + (m - x1[None]) * (c / b2)[None, ..., None]


def sensor_to_pixel(device: RingDevice, xy_m) -> np.ndarray:
    """Sensor metres -> raw pixel (col, row); pixel centres are at integer coordinates."""
    xy = np.asarray(xy_m, dtype=np.float64)
    size = np.array([device.sensor_width_px, device.sensor_height_px], dtype=np.float64)
    return xy / device.pixel_pitch_m + size / 2.0 - 0.5


def pixel_to_sensor(device: RingDevice, colrow) -> np.ndarray:
    """Raw pixel (col, row) -> sensor metres; the inverse of :func:`sensor_to_pixel`."""
    cr = np.asarray(colrow, dtype=np.float64)
    size = np.array([device.sensor_width_px, device.sensor_height_px], dtype=np.float64)
    return (cr + 0.5 - size / 2.0) * device.pixel_pitch_m


def focus_sensor_distance_m(device: RingDevice, distance_m) -> np.ndarray:
    """c'(Z) = b2 Fml / (b2 - Fml): where the mini-lens images a plane at Z sharply."""
    b2 = mini_object_distance_m(device, distance_m)
    f = device.mini_focal_length_m
    with np.errstate(divide="ignore"):
        return np.where(b2 > f, b2 * f / (b2 - f), np.inf)


def blur_diameter_m(device: RingDevice, distance_m) -> np.ndarray:
    """Defocus blur-circle diameter on the sensor, 2 Rml |c - c'| / c' (the sensor at c, the
    plane imaged sharply at c')."""
    _, c = device.require_positions()
    cp = focus_sensor_distance_m(device, distance_m)
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(cp), 2.0 * device.mini_lens_radius_m * np.abs(c - cp) / cp, np.inf)


def disparity_px(device: RingDevice, distance_m, *, axis: str = "vertical") -> np.ndarray:
    """Disparity between adjacent views cut at half the sensor pitch (the paper's Eq. 16).

    ``d = ((4 hml - hs)/2 + 2 hml c/b2) / tpix`` for vertically adjacent views (``hs`` replaced by
    ``ws`` for ``axis='horizontal'``). It is affine in 1/(Z - s).
    """
    if axis not in ("vertical", "horizontal"):
        raise InvalidInputError(f"axis must be 'vertical' or 'horizontal', got {axis!r}")
    _, c = device.require_positions()
    span = device.sensor_height_m if axis == "vertical" else device.sensor_width_m
    h = device.mini_lens_offset_m
    b2 = mini_object_distance_m(device, distance_m)
    return ((4.0 * h - span) / 2.0 + 2.0 * h * c / b2) / device.pixel_pitch_m
