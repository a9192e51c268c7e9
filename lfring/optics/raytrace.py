"""2D meridional ray tracer of the ring camera through thin lenses with finite apertures.

The tracer works in the meridional plane (y, z) that holds the optical axis and the centres of two
of the four mini-lenses. **y points up** (as in the source paper's ray diagram), z runs from the
object to the sensor, the main lens L sits at z = 0, the ring at z = b and the sensor at
z = b + c. The two mini-lenses of the plane are lens ``a`` (index 0, ``UPPER``) centred at
y = +hml and lens ``b`` (index 1, ``LOWER``) at y = -hml, both of radius Rml. The object is the
segment -h0 <= y <= +h0 at z = -Z.

This differs from the sensor frame of :mod:`lfring.optics.paraxial`, where y points *down*: a
height here is minus the sensor y of that module for the column of views through lenses a and b.

Every lens is thin and paraxial: a ray (height y, slope u = dy/dz) crossing a lens of focal length
f centred at m leaves with slope ``u - (y - m) / f``. A ray is stopped at the main lens when
``|y| > R`` (R the stop radius, see ``aperture`` in :func:`trace`) and at the ring when it misses
both mini-lens apertures ``|y - m_k| <= Rml``. Nothing here prints or touches the disk.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lfring.core.validate import check_choice, check_int, check_number
from lfring.errors import InvalidInputError
from lfring.optics.device import RingDevice
from lfring.core.records import record_repr

__all__ = [
    "APERTURES",
    "UPPER",
    "LOWER",
    "MISSED_RING",
    "STOPPED_MAIN",
    "LENS_NAMES",
    "RayTrace",
    "BundleStats",
    "trace",
    "bundle_stats",
    "convergence_spread_m",
    "mean_hit_height_m",
    "paraxial_hit_height_m",
]

#: Stops of the main lens: its full radius RL (the paper's figure) or the device iris.
APERTURES = ("lens", "iris")

#: Codes of :attr:`RayTrace.lens`.
UPPER = 0
LOWER = 1
MISSED_RING = -1
STOPPED_MAIN = -2
LENS_NAMES = ("a (upper)", "b (lower)")

# A ray that grazes a rim passes: aimed rays land on the rim up to rounding (~1e-18 m).
_RIM_TOL = 1e-9


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.flags.writeable = False
    return a


@dataclass(frozen=True, eq=False)
class RayTrace:
    """Rays traced through the ring camera in the meridional plane (y up, metres).

    Attributes
    ----------
    device : RingDevice
        The device traced (with the lens positions used).
    object_size_m, distance_m : float
        Object size 2 h0 and distance Z in front of the main lens.
    ring_distance_m, sensor_distance_m : float
        b (main lens -> ring) and c (ring -> sensor).
    aperture : {'lens', 'iris'}
        Which main-lens stop was applied; ``stop_radius_m`` is its radius.
    stop_radius_m : float
        Radius of the main-lens stop.
    lens_centres_m : ndarray, (2,)
        Heights of the mini-lens centres in the plane, ``(+hml, -hml)`` (lens a, lens b).
    source_heights_m : ndarray, (P,)
        Heights y of the source points on the object, bottom to top.
    source_index : ndarray of int, (N,)
        Source point of each ray.
    aimed : ndarray of bool, (N,)
        True for rays aimed at a mini-lens aperture, False for the even fan over the main lens.
    lens : ndarray of int, (N,)
        0 (``UPPER``, through lens a), 1 (``LOWER``, through lens b), -1 (``MISSED_RING``:
        passed the main lens, hit the ring outside both mini-lenses), -2 (``STOPPED_MAIN``:
        outside the main-lens stop).
    z_m, y_m : ndarray, (N, 4)
        Polyline vertices of each ray at the object, main lens, ring and sensor planes; NaN
        after the plane where the ray is stopped (so a stopped ray ends on its stop).
    sensor_y_m : ndarray, (N,)
        Height where the ray meets the sensor plane, NaN for stopped rays.

    Notes
    -----
    All arrays are read-only. A ray reaching the sensor plane may still land outside the
    sensor (``|y| > hs/2``); see :attr:`on_sensor`.
    """

    __repr__ = record_repr

    device: RingDevice
    object_size_m: float
    distance_m: float
    ring_distance_m: float
    sensor_distance_m: float
    aperture: str
    stop_radius_m: float
    lens_centres_m: np.ndarray
    source_heights_m: np.ndarray
    source_index: np.ndarray
    aimed: np.ndarray
    lens: np.ndarray
    z_m: np.ndarray
    y_m: np.ndarray
    sensor_y_m: np.ndarray

    @property
    def num_rays(self) -> int:
        """Number of rays N traced."""
        return int(self.lens.size)

    @property
    def num_points(self) -> int:
        """Number of object points P the rays start from."""
        return int(self.source_heights_m.size)

    @property
    def reached_sensor(self) -> np.ndarray:
        """(N,) True for rays that went through a mini-lens to the sensor plane."""
        return self.lens >= 0

    @property
    def on_sensor(self) -> np.ndarray:
        """(N,) True for rays that land on the active sensor area, ``|y| <= hs/2``."""
        half = self.device.sensor_height_m / 2.0
        return np.abs(np.nan_to_num(self.sensor_y_m, nan=np.inf)) <= half


@dataclass(frozen=True, eq=False)
class BundleStats:
    """Per source point and mini-lens, the bundle of rays that reach the sensor.

    All arrays have shape (P, 2): source point (as in ``RayTrace.source_heights_m``) by lens
    (0 = a, upper; 1 = b, lower). Bundles with no ray hold ``count == 0`` and NaN.

    Attributes
    ----------
    source_heights_m : ndarray, (P,)
        Heights of the source points, as in the trace.
    count : ndarray of int
        Rays of the bundle that reach the sensor plane.
    spread_m : ndarray
        Convergence spread, max - min of the sensor hit heights, metres. Zero (to rounding) when
        the sensor is at the sharp-image distance; the defocus blur diameter
        ``2 Rml |c - c'| / c'`` when the bundle fills the mini-lens (the source paper's blur circle).
    mean_height_m : ndarray
        Mean sensor hit height, metres (y up).
    paraxial_height_m : ndarray
        The chief-ray image height of the source paper, ``m_k + (m_k - y1) c / b2`` with ``y1 = -y0 b1 / Z``
        (H2,a and H2,b for the source at +h0).
    """

    __repr__ = record_repr

    source_heights_m: np.ndarray
    count: np.ndarray
    spread_m: np.ndarray
    mean_height_m: np.ndarray
    paraxial_height_m: np.ndarray

    def rows(self) -> list[dict]:
        """One dict per (source, lens), lens ``'a'`` or ``'b'``, NaN as None: for logs and JSON."""
        ys = self.source_heights_m
        out = []
        for i in range(self.count.shape[0]):
            for k in range(2):
                out.append(
                    {
                        "source_height_m": float(ys[i]),
                        "lens": "ab"[k],
                        "count": int(self.count[i, k]),
                        "spread_m": _json_float(self.spread_m[i, k]),
                        "mean_height_m": _json_float(self.mean_height_m[i, k]),
                        "paraxial_height_m": float(self.paraxial_height_m[i, k]),
                    }
                )
        return out


def _json_float(x) -> float | None:
    x = float(x)
    return x if np.isfinite(x) else None


def _positive_length(name: str, value) -> float:
    return check_number(value, name, above=0.0, what="a positive length in metres")


def _even(n: int) -> np.ndarray:
    """n values evenly spread over [-1, 1]; a single value is the centre."""
    return np.linspace(-1.0, 1.0, n) if n > 1 else np.zeros(n)


def trace(
    device: RingDevice,
    *,
    object_size_m: float,
    distance_m: float,
    num_points: int = 5,
    rays_per_point: int = 21,
    rays_per_lens: int = 7,
    aperture: str = "lens",
    fan_radius_m: float | None = None,
) -> RayTrace:
    """Trace rays from points of an object through the main lens and the ring to the sensor.

    Parameters
    ----------
    device : RingDevice
        Optics with lens positions b and c set (see :meth:`RingDevice.with_positions` and
        :func:`lfring.optics.design`).
    object_size_m : float
        Object size 2 h0, metres.
    distance_m : float
        Object distance Z in front of the main lens, metres; must exceed the main focal length.
    num_points : int, default 5
        Source points evenly spread over the object from -h0 to +h0; a single point sits on the
        optical axis.
    rays_per_point : int, default 21
        Rays per source point whose heights at the main lens are evenly spread over
        ``[-fan_radius_m, +fan_radius_m]``: the fan of the source paper's ray diagram, most of which misses
        the ring. May be 0.
    rays_per_lens : int, default 7
        Further rays per source point and mini-lens, aimed so that their heights at the ring are
        evenly spread over that mini-lens aperture, rims included (one ray: its centre, the chief
        ray). They sample each bundle that reaches the sensor densely enough to measure its
        convergence; those that fall outside the main-lens stop are stopped like any other.
        May be 0 (but not together with ``rays_per_point``).
    aperture : {'lens', 'iris'}, default 'lens'
        Main-lens stop: ``'lens'`` is the lens radius RL, as the paper's figure uses; ``'iris'``
        is ``device.effective_aperture_radius_m``, which cuts the bundles of off-axis points
        (vignetting: the iris is the field stop of each view).
    fan_radius_m : float, optional
        Half-height of the even fan at the main lens; default the stop radius. A larger value
        shows rays stopped by the lens rim.

    Returns
    -------
    RayTrace

    Raises
    ------
    InvalidInputError
        Bad sizes, distances, counts or aperture name; a ring placed exactly on the intermediate
        image when rays are aimed at the mini-lenses.
    DeviceError
        The device has no lens positions.

    Notes
    -----
    With source height y0 and main-lens height yL the ray has slope ``u0 = (yL - y0)/Z``, then
    ``u1 = u0 - yL/FL`` behind the main lens, height ``yR = yL + b u1`` at the ring, slope
    ``u2 = u1 - (yR - m_k)/Fml`` behind mini-lens k and height ``yS = yR + c u2`` on the sensor.
    Aimed rays invert the affine map ``yR = yL (1 + b/Z - b/FL) - b y0/Z``.

    Examples
    --------
    >>> from lfring.optics import load_device
    >>> from lfring.optics.raytrace import UPPER, bundle_stats, trace
    >>> rt = trace(load_device("prototype"), object_size_m=0.1, distance_m=0.3)
    >>> st = bundle_stats(rt)
    >>> round(float(st.mean_height_m[-1, UPPER]) * 1e3, 3)  # H2,a = hs/2 for this design
    2.3
    >>> bool(st.spread_m.max() < 1e-9)
    True
    """
    if not isinstance(device, RingDevice):
        raise InvalidInputError(f"device must be a RingDevice, got {type(device).__name__}")
    b, c = device.require_positions()
    size = _positive_length("object size", object_size_m)
    z = _positive_length("object distance", distance_m)
    fl = device.main_focal_length_m
    if z <= fl:
        raise InvalidInputError(
            f"object distance {z!r} m does not exceed the main lens focal length ({fl} m): the main "
            "lens forms no real intermediate image; use a larger distance"
        )
    num_points = check_int(num_points, "num_points", minimum=1)
    rays_per_point = check_int(rays_per_point, "rays_per_point", minimum=0)
    rays_per_lens = check_int(rays_per_lens, "rays_per_lens", minimum=0)
    if rays_per_point + rays_per_lens == 0:
        raise InvalidInputError("rays_per_point and rays_per_lens are both 0: there is no ray to trace")
    check_choice(aperture, "aperture", APERTURES)
    stop = device.main_lens_radius_m if aperture == "lens" else device.effective_aperture_radius_m
    fan = stop if fan_radius_m is None else _positive_length("fan radius", fan_radius_m)

    fml, rml = device.mini_focal_length_m, device.mini_lens_radius_m
    centres = np.array([device.mini_lens_offset_m, -device.mini_lens_offset_m])
    h0 = size / 2.0
    y0 = h0 * _even(num_points)  # (P,)

    # Main-lens heights of every ray, (P, R + 2A): the even fan, then the rays aimed at lens a, b.
    gain = 1.0 + b / z - b / fl  # d yR / d yL
    parts = [np.broadcast_to(fan * _even(rays_per_point), (num_points, rays_per_point))]
    if rays_per_lens:
        if abs(gain) < 1e-9:
            raise InvalidInputError(
                "the ring sits on the intermediate image of this distance (b = b1): every ray meets "
                "the ring at one height, so rays cannot be aimed at the mini-lenses; use "
                "rays_per_lens=0 or another distance"
            )
        ring_targets = (centres[:, None] + rml * _even(rays_per_lens)[None, :]).ravel()  # (2A,)
        parts.append((ring_targets[None, :] + b * y0[:, None] / z) / gain)
    y_lens = np.concatenate(parts, axis=1)
    per_point = y_lens.shape[1]
    src = np.repeat(np.arange(num_points), per_point)
    aimed = np.tile(np.arange(per_point) >= rays_per_point, num_points)
    y_lens = y_lens.ravel()
    ys = y0[src]

    u1 = (y_lens - ys) / z - y_lens / fl
    y_ring = y_lens + b * u1
    passes_main = np.abs(y_lens) <= stop * (1.0 + _RIM_TOL)
    in_lens = np.abs(y_ring[:, None] - centres[None, :]) <= rml * (1.0 + _RIM_TOL)  # (N, 2)
    hit = passes_main & in_lens.any(axis=1)
    k = np.argmax(in_lens, axis=1)  # first lens hit; they touch at most at one point
    lens = np.where(passes_main, np.where(hit, k, MISSED_RING), STOPPED_MAIN)

    u2 = u1 - (y_ring - centres[k]) / fml
    y_sensor = np.where(hit, y_ring + c * u2, np.nan)
    y_ring = np.where(passes_main, y_ring, np.nan)
    y = np.stack([ys, y_lens, y_ring, y_sensor], axis=1)
    zz = np.where(np.isnan(y), np.nan, np.array([-z, 0.0, b, b + c])[None, :])

    return RayTrace(
        device=device,
        object_size_m=size,
        distance_m=z,
        ring_distance_m=float(b),
        sensor_distance_m=float(c),
        aperture=aperture,
        stop_radius_m=float(stop),
        lens_centres_m=_readonly(centres),
        source_heights_m=_readonly(y0),
        source_index=_readonly(src),
        aimed=_readonly(aimed),
        lens=_readonly(lens.astype(np.int64)),
        z_m=_readonly(zz),
        y_m=_readonly(y),
        sensor_y_m=_readonly(y_sensor),
    )


def _check_trace(rt) -> None:
    if not isinstance(rt, RayTrace):
        raise InvalidInputError(f"expected a RayTrace from lfring.optics.raytrace.trace(), got {type(rt).__name__}")


def paraxial_hit_height_m(rt: RayTrace) -> np.ndarray:
    """(P, 2) chief-ray image heights of the source points through lens a and b (the source paper's equations).

    ``m_k + (m_k - y1) c / b2`` with ``y1 = -y0 b1 / Z``, ``b1 = Z FL / (Z - FL)``, ``b2 = b - b1``.
    For the source at +h0 these are H2,a = hml + c (hml + h1)/b2 and H2,b = -hml + c (h1 - hml)/b2.
    """
    _check_trace(rt)
    fl = rt.device.main_focal_length_m
    z = rt.distance_m
    b1 = z * fl / (z - fl)
    b2 = rt.ring_distance_m - b1
    y1 = -rt.source_heights_m * b1 / z
    m = rt.lens_centres_m
    with np.errstate(divide="ignore", invalid="ignore"):
        return m[None, :] + (m[None, :] - y1[:, None]) * rt.sensor_distance_m / b2


def bundle_stats(rt: RayTrace) -> BundleStats:
    """Count, convergence spread and mean sensor height of each (source point, mini-lens) bundle.

    Every ray that reaches the sensor plane counts, whether or not it lands on the active area.
    """
    _check_trace(rt)
    hit = rt.lens >= 0
    group = rt.source_index[hit] * 2 + rt.lens[hit]  # bundle of each ray reaching the sensor
    y = rt.sensor_y_m[hit]
    n = rt.num_points * 2
    count = np.bincount(group, minlength=n)
    total = np.bincount(group, weights=y, minlength=n)
    top = np.full(n, -np.inf)
    bottom = np.full(n, np.inf)
    np.maximum.at(top, group, y)
    np.minimum.at(bottom, group, y)
    some = count > 0
    spread = np.where(some, top - bottom, np.nan).reshape(-1, 2)
    mean = np.where(some, total / np.maximum(count, 1), np.nan).reshape(-1, 2)
    count = count.reshape(-1, 2)
    return BundleStats(
        source_heights_m=rt.source_heights_m,
        count=_readonly(count),
        spread_m=_readonly(spread),
        mean_height_m=_readonly(mean),
        paraxial_height_m=_readonly(paraxial_hit_height_m(rt)),
    )


def convergence_spread_m(rt: RayTrace) -> np.ndarray:
    """(P, 2) max - min of the sensor hit heights per source point and mini-lens (NaN: no ray)."""
    return bundle_stats(rt).spread_m


def mean_hit_height_m(rt: RayTrace) -> np.ndarray:
    """(P, 2) mean sensor hit height per source point and mini-lens, metres, y up (NaN: no ray)."""
    return bundle_stats(rt).mean_height_m
