"""Lens-position design of the ring camera (the source paper's design equations) and the working-range design.

Every function here is pure: device and numbers in, frozen records out.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from lfring.core.registry import Registry
from lfring.core.validate import check_int
from lfring.errors import DesignError, InvalidInputError
from lfring.optics.device import RingDevice
from lfring.core.records import record_repr

__all__ = [
    "METHODS",
    "Design",
    "Sweep",
    "WorkingRange",
    "design",
    "evaluate",
    "sweep",
    "design_working_range",
]

_TOL_M = 1e-12


@dataclass(frozen=True)
class Design:
    """Lens positions and the imaging numbers of one design point (all lengths in metres).

    ``disparity_px`` is the source paper's vertical disparity between adjacent views cut at half
    the sensor pitch; ``depth_resolution_m_per_px`` is |dZ/dd| at ``distance_m``.
    ``problems`` lists, in words, every validity limit the design breaks; ``valid`` is True when
    there is none.
    """

    method: str
    object_size_m: float
    distance_m: float
    ring_distance_m: float
    sensor_distance_m: float
    intermediate_distance_m: float
    mini_object_distance_m: float
    magnification: float
    image_height_m: float
    upper_image_top_m: float
    lower_image_top_m: float
    disparity_px: float
    disparity_horizontal_px: float
    overlap: float
    mount_distance_m: float
    entrance_pupil_m: float
    depth_resolution_m_per_px: float
    blur_px: float
    problems: tuple[str, ...] = field(default=())

    @property
    def valid(self) -> bool:
        """True when the design has no problems (``problems`` is empty)."""
        return not self.problems

    def to_dict(self) -> dict:
        """The design as a JSON-ready dict, with ``problems`` as a list and ``valid``.

        Returns
        -------
        dict
        """
        out = asdict(self)
        out["problems"] = list(self.problems)
        out["valid"] = self.valid
        return out


@dataclass(frozen=True)
class Sweep:
    """Design numbers over a grid of distances (and/or object sizes), arrays of equal shape.

    ``fixed`` says whether b and c were held at the device's positions (True) or redesigned at
    every point (False). ``problems[i]`` lists what is wrong at point i; ``valid`` is the mask of
    points with no problem.
    """

    __repr__ = record_repr

    method: str
    fixed: bool
    object_size_m: np.ndarray
    distance_m: np.ndarray
    ring_distance_m: np.ndarray
    sensor_distance_m: np.ndarray
    magnification: np.ndarray
    image_height_m: np.ndarray
    disparity_px: np.ndarray
    overlap: np.ndarray
    depth_resolution_m_per_px: np.ndarray
    blur_px: np.ndarray
    problems: tuple[tuple[str, ...], ...]

    @property
    def valid(self) -> np.ndarray:
        """(N,) bool: True at the sweep's points that have no problem."""
        return np.array([not p for p in self.problems], dtype=bool)

    def points(self) -> list[dict]:
        """One dict per point, for tables and JSON."""
        keys = (
            "object_size_m", "distance_m", "ring_distance_m", "sensor_distance_m",
            "magnification", "image_height_m", "disparity_px", "overlap",
            "depth_resolution_m_per_px", "blur_px",
        )
        rows = []
        for i in range(self.distance_m.size):
            row = {k: float(getattr(self, k).ravel()[i]) for k in keys}
            row["valid"] = not self.problems[i]
            row["problems"] = list(self.problems[i])
            rows.append(row)
        return rows


@dataclass(frozen=True)
class WorkingRange:
    """A design for a range of distances: b and c, and the numbers over the range."""

    object_size_m: float
    near_m: float
    far_m: float
    focus_distance_m: float
    ring_distance_m: float
    sensor_distance_m: float
    mount_distance_m: float
    entrance_pupil_m: float
    sweep: Sweep

    @property
    def problems(self) -> tuple[str, ...]:
        """The kinds of problem met anywhere over the range, each once (the sweep's problems
        without their 'at Z=...' position).
        """
        seen: dict[str, None] = {}
        for p in self.sweep.problems:
            for item in p:
                seen[item.split(" at Z=")[0]] = None
        return tuple(seen)


# ------------------------------------------------------------------------------------------------
def _check_inputs(device: RingDevice, object_size_m, distance_m) -> tuple[np.ndarray, np.ndarray]:
    size = np.asarray(object_size_m, dtype=np.float64)
    z = np.asarray(distance_m, dtype=np.float64)
    if not np.all(np.isfinite(size)) or np.any(size <= 0):
        raise InvalidInputError(f"object size must be a positive number of metres, got {object_size_m!r}")
    if not np.all(np.isfinite(z)) or np.any(z <= 0):
        raise InvalidInputError(f"distance must be a positive number of metres, got {distance_m!r}")
    fl = device.main_focal_length_m
    if np.any(z <= fl):
        raise InvalidInputError(
            f"distance {float(np.min(z))!r} m is inside the main lens focal length ({fl} m): "
            "the main lens forms no real image; use a distance greater than the focal length"
        )
    return np.broadcast_arrays(size, z)


def _fit_sensor_b2(device: RingDevice, h0: np.ndarray, z: np.ndarray, b1: np.ndarray) -> np.ndarray:
    """b2 that puts the top of the upper image at the sensor edge (the paper's fit-sensor design)."""
    fml, hml, hs = device.mini_focal_length_m, device.mini_lens_offset_m, device.sensor_height_m
    if hs / 2.0 <= hml:
        raise DesignError(
            f"the mini-lens offset ({hml} m) is not inside half the sensor height "
            f"({hs / 2} m): no image can be placed at the sensor edge"
        )
    h1 = b1 * h0 / z
    # H2,a = hml + c (hml + h1) / b2 = hs/2 with c/b2 = Fml/(b2 - Fml), solved for b2.
    return fml + fml * (hml + h1) / (hs / 2.0 - hml)


def _max_magnification_b2(device: RingDevice, h0: np.ndarray, z: np.ndarray, b1: np.ndarray) -> np.ndarray:
    """b2 of the largest magnification G = hs / (4 h0) (the paper's max-magnification design)."""
    fl, fml = device.main_focal_length_m, device.mini_focal_length_m
    g = device.sensor_height_m / (4.0 * h0)
    return fl * (fml / g + z) / (z - fl) + fml - b1


#: The lens-position designs by name, each ``(device, h0, Z, b1) -> b2``, vectorised.
METHODS = Registry("method")
METHODS.register("fit-sensor", _fit_sensor_b2)
METHODS.register("max-magnification", _max_magnification_b2)


def _solve_positions(device: RingDevice, h0: np.ndarray, z: np.ndarray, method: str):
    """b and c of the design ``method`` (the paper's first two design steps), vectorised."""
    solve_b2 = METHODS.lookup(method)
    fl, fml = device.main_focal_length_m, device.mini_focal_length_m
    b1 = z * fl / (z - fl)
    b2 = solve_b2(device, h0, z, b1)
    c = b2 * fml / (b2 - fml)
    return b1 + b2, c


def _numbers(device: RingDevice, b, c, h0, z) -> dict[str, np.ndarray]:
    """Everything the design equations derive from b, c, the object half-size h0 and the distance Z."""
    fl, fml, hml = device.main_focal_length_m, device.mini_focal_length_m, device.mini_lens_offset_m
    hs, ws, tpix = device.sensor_height_m, device.sensor_width_m, device.pixel_pitch_m
    b1 = z * fl / (z - fl)
    b2 = b - b1
    with np.errstate(divide="ignore", invalid="ignore"):
        h1 = b1 * h0 / z
        g = fl / (z - fl) * c / b2
        ia = g * 2.0 * h0
        h2a = hml + c * (hml + h1) / b2
        h2b = -hml + c * (-hml + h1) / b2
        d = ((4.0 * hml - hs) / 2.0 + 2.0 * hml * c / b2) / tpix
        dh = ((4.0 * hml - ws) / 2.0 + 2.0 * hml * c / b2) / tpix
        o = 1.0 - d * tpix / ia
        # c' of the mini-lens for the plane at Z, and the blur circle at c (the paper's defocus blur).
        cp = np.where(b2 > fml, b2 * fml / (b2 - fml), np.inf)
        blur = np.where(np.isfinite(cp), 2.0 * device.mini_lens_radius_m * np.abs(c - cp) / cp, np.inf) / tpix
        # |dZ/dd|: d depends on Z through b2 only, d(b2)/dZ = FL^2 / (Z - FL)^2.
        res = tpix * b2**2 * (z - fl) ** 2 / (2.0 * hml * c * fl**2)
        mount = c * fml / (c - fml) + device.flange_focal_distance_m - device.screw_thread_m
        pupil = b * fl / (b - fl)
    return dict(
        b1=b1, b2=b2, g=g, ia=ia, h2a=h2a, h2b=h2b, d=d, dh=dh, o=o, blur=blur, res=res,
        mount=mount, pupil=pupil,
    )


def _problems(device: RingDevice, b, c, z, n: dict[str, np.ndarray]) -> list[tuple[str, ...]]:
    hs = device.sensor_height_m
    fml = device.mini_focal_length_m
    out = []
    flat = {k: np.broadcast_to(v, np.shape(z)).ravel() for k, v in n.items()}
    bb = np.broadcast_to(b, np.shape(z)).ravel()
    cc = np.broadcast_to(c, np.shape(z)).ravel()
    for i, zi in enumerate(np.ravel(z)):
        where = f" at Z={zi:.4g} m"
        p = []
        b2 = flat["b2"][i]
        if not (cc[i] > 0 and np.isfinite(cc[i])):
            p.append(f"sensor distance c is not a positive length{where}")
        if b2 <= 0:
            p.append(f"the intermediate image lies behind the ring (b2 = {b2 * 1e3:.3g} mm){where}")
        elif b2 <= fml + _TOL_M:
            p.append(
                f"the intermediate image is inside the mini-lens focal length "
                f"(b2 = {b2 * 1e3:.4g} mm <= Fml): no real image{where}"
            )
        else:
            ia, top = flat["ia"][i], flat["h2a"][i]
            if ia > hs / 2.0 + _TOL_M:
                p.append(
                    f"image taller than half the sensor ({ia * 1e3:.4g} mm > {hs / 2 * 1e3:.4g} mm)"
                    f"{where}"
                )
            elif top > hs / 2.0 + 1e-9:
                p.append(
                    f"the upper image runs past the sensor edge by {(top - hs / 2) * 1e3:.4g} mm{where}"
                )
            elif top - ia < -1e-9:
                p.append(f"the upper image crosses the sensor centre line{where}")
            if flat["o"][i] <= 0:
                p.append(f"no overlap between adjacent views (o = {flat['o'][i]:.3g}){where}")
        if not bb[i] > device.main_focal_length_m:
            p.append(f"ring distance b is not beyond the main lens focal length{where}")
        out.append(tuple(p))
    return out


def _design_from(device, method, size, z, b, c) -> Design:
    h0 = size / 2.0
    n = _numbers(device, b, c, h0, z)
    problems = _problems(device, b, c, z, n)[0]
    return Design(
        method=method,
        object_size_m=float(size),
        distance_m=float(z),
        ring_distance_m=float(b),
        sensor_distance_m=float(c),
        intermediate_distance_m=float(n["b1"]),
        mini_object_distance_m=float(n["b2"]),
        magnification=float(n["g"]),
        image_height_m=float(n["ia"]),
        upper_image_top_m=float(n["h2a"]),
        lower_image_top_m=float(n["h2b"]),
        disparity_px=float(n["d"]),
        disparity_horizontal_px=float(n["dh"]),
        overlap=float(n["o"]),
        mount_distance_m=float(n["mount"]),
        entrance_pupil_m=float(n["pupil"]),
        depth_resolution_m_per_px=float(n["res"]),
        blur_px=float(n["blur"]),
        problems=tuple(p.replace(f" at Z={float(z):.4g} m", "") for p in problems),
    )


def design(device: RingDevice, *, object_size_m: float, distance_m: float, method: str = "fit-sensor") -> Design:
    """Lens positions b, c for an object of size ``object_size_m`` at ``distance_m``.

    Parameters
    ----------
    device : RingDevice
        Optics and sensor; its own lens positions, if any, are ignored.
    object_size_m : float
        Object size 2 h0, metres.
    distance_m : float
        Object distance Z in front of the main lens, metres; must exceed the focal length.
    method : {'fit-sensor', 'max-magnification'}
        ``'max-magnification'`` (the source paper's first design): G = hs / (4 h0) and
        b = FL (Fml/G + Z)/(Z - FL) + Fml. ``'fit-sensor'`` (its second): the top of the upper
        image at the sensor edge, hml + c (hml + h1)/b2 = hs/2 with c = b2 Fml/(b2 - Fml).

    Returns
    -------
    Design
        b, c, G, Ia, d, o, B, s and the list of broken validity limits.

    Examples
    --------
    >>> import lfring.optics
    >>> d = lfring.optics.design(lfring.optics.load_device("prototype"), object_size_m=0.1, distance_m=0.3)
    >>> round(d.ring_distance_m * 1e3, 2), round(d.sensor_distance_m * 1e3, 3)
    (37.37, 6.616)
    >>> round(d.disparity_px, 1), round(d.overlap, 3)
    (383.1, 0.737)
    """
    size, z = _check_inputs(device, object_size_m, distance_m)
    if size.ndim or z.ndim:
        raise InvalidInputError("design() takes one object size and one distance; use sweep() for grids")
    b, c = _solve_positions(device, size / 2.0, z, method)
    return _design_from(device, method, size, z, b, c)


def evaluate(device: RingDevice, *, object_size_m: float, distance_m: float) -> Design:
    """The numbers of a device whose lens positions are already set, for one object and distance."""
    b, c = device.require_positions()
    size, z = _check_inputs(device, object_size_m, distance_m)
    return _design_from(device, "fixed", size, z, np.float64(b), np.float64(c))


def sweep(
    device: RingDevice,
    *,
    object_size_m,
    distances_m,
    method: str = "fit-sensor",
    fixed: bool = False,
) -> Sweep:
    """Design numbers over distances and/or object sizes (the source paper's design curves).

    With ``fixed=False`` the positions are redesigned at every point with ``method``; with
    ``fixed=True`` the device's own b and c are kept and only the imaging numbers change.
    Points that break a validity limit are kept and listed in ``problems``, never dropped.
    """
    METHODS.lookup(method)
    size, z = _check_inputs(device, object_size_m, distances_m)
    size, z = np.atleast_1d(size).astype(np.float64), np.atleast_1d(z).astype(np.float64)
    if fixed:
        b0, c0 = device.require_positions()
        b, c = np.full(z.shape, b0), np.full(z.shape, c0)
    else:
        b, c = _solve_positions(device, size / 2.0, z, method)
    n = _numbers(device, b, c, size / 2.0, z)
    return Sweep(
        method="fixed" if fixed else method,
        fixed=fixed,
        object_size_m=size,
        distance_m=z,
        ring_distance_m=np.asarray(b, dtype=np.float64),
        sensor_distance_m=np.asarray(c, dtype=np.float64),
        magnification=n["g"],
        image_height_m=n["ia"],
        disparity_px=n["d"],
        overlap=n["o"],
        depth_resolution_m_per_px=n["res"],
        blur_px=n["blur"],
        problems=tuple(_problems(device, b, c, z, n)),
    )


def design_working_range(
    device: RingDevice, *, object_size_m: float, near_m: float, far_m: float, num: int = 50
) -> WorkingRange:
    """Choose b and c for objects anywhere between ``near_m`` and ``far_m``.

    The image is largest at the near end, so the object is fitted to the sensor there (the top
    of the upper image at the sensor edge); c is the harmonic mean of the sharp-image distances
    c'(near) and c'(far), which makes the relative defocus |c - c'|/c', and so the blur circle,
    equal at both ends of the range. The two conditions fix b and c.

    Returns
    -------
    WorkingRange
        b, c, the distance in sharpest focus, and a :class:`Sweep` over the range with disparity,
        overlap, depth resolution (metres per pixel of disparity) and blur in pixels.
    """
    size, near = _check_inputs(device, object_size_m, near_m)
    _, far = _check_inputs(device, object_size_m, far_m)
    if not far > near:
        raise InvalidInputError(f"the far distance ({float(far)} m) must exceed the near one ({float(near)} m)")
    check_int(num, "num", minimum=2)
    fl, fml, hml = device.main_focal_length_m, device.mini_focal_length_m, device.mini_lens_offset_m
    hs = device.sensor_height_m
    if hs / 2.0 <= hml:
        raise DesignError("the mini-lens offset is not inside half the sensor height")
    h0 = float(size) / 2.0
    b1n = float(near) * fl / (float(near) - fl)
    b1f = float(far) * fl / (float(far) - fl)
    h1n = b1n * h0 / float(near)

    def c_of_b(b: float) -> float:
        cpn = (b - b1n) * fml / (b - b1n - fml)
        cpf = (b - b1f) * fml / (b - b1f - fml)
        return 2.0 / (1.0 / cpn + 1.0 / cpf)

    def top_minus_edge(b: float) -> float:
        return hml + c_of_b(b) * (hml + h1n) / (b - b1n) - hs / 2.0

    lo = b1n + fml * (1.0 + 1e-9)
    hi = lo + 1.0
    if top_minus_edge(lo) <= 0 or top_minus_edge(hi) >= 0:
        raise DesignError("no ring position fits the object to the sensor over this range")
    from scipy.optimize import brentq  # here, not at import: see lfring.calibration.model

    b = brentq(top_minus_edge, lo, hi, xtol=1e-15, rtol=1e-14)
    c = c_of_b(b)
    # The plane in sharpest focus: b2 = c Fml / (c - Fml), Z from b1 = b - b2.
    b1_focus = b - c * fml / (c - fml)
    focus = b1_focus * fl / (b1_focus - fl)
    dev = device.with_positions(b, c)
    sw = sweep(dev, object_size_m=size, distances_m=np.geomspace(float(near), float(far), num), fixed=True)
    return WorkingRange(
        object_size_m=float(size),
        near_m=float(near),
        far_m=float(far),
        focus_distance_m=float(focus),
        ring_distance_m=float(b),
        sensor_distance_m=float(c),
        mount_distance_m=float(c * fml / (c - fml) + device.flange_focal_distance_m - device.screw_thread_m),
        entrance_pupil_m=float(b * fl / (b - fl)),
        sweep=sw,
    )

