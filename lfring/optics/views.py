"""What the optics says about the views: one pinhole camera per mini-lens, the layout of the
views on the sensor, their vignetting, and the exact plane-induced homographies.

Each view is exactly a pinhole camera under the thin-lens model. The chief rays through
mini-lens k all pass through the image of that mini-lens formed by the main lens, the view's
entrance pupil, at distance ``s = b FL / (b - FL)`` in front of the main lens and lateral
position ``C_k = -m_k FL / (b - FL)``. A world point (X, Y, Z) lands on the sensor at

    p_k = p0_k + f (X - C_k) / (Z - s),   f = c FL / (b - FL),   p0_k = m_k (1 + c / (b - FL)),

which is the paraxial chief-ray formula rewritten (``x2_k = m_k + (m_k - x1) c / b2``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lfring.core.geometry import to_reference
from lfring.core.lens import LensDistortion
from lfring.errors import InvalidInputError
from lfring.optics.device import RingDevice
from lfring.optics.paraxial import pixel_to_sensor, sensor_to_pixel
from lfring.views import Layout, layout_from_circles

__all__ = [
    "ViewCameras",
    "ideal_discs_px",
    "lens_distortions",
    "lit_region",
    "optical_homographies",
    "optical_homography_model",
    "optical_layout",
    "quadrant_rects",
    "view_cameras",
    "vignetting",
    "vignetting_region",
]


@dataclass(frozen=True, eq=False)
class ViewCameras:
    """Pinhole cameras of the views, in sensor metres (x right, y down, origin on the axis).

    Attributes
    ----------
    centres_m : (V, 2)
        Lateral position (X, Y) of each view's projection centre.
    depth_origin_m : float
        s, the depth (from the main lens) of every projection centre.
    focal_m : float
        f, the common focal length.
    principal_points_m : (V, 2)
        Sensor position of the image of the point straight ahead of each centre.
    """

    centres_m: np.ndarray
    depth_origin_m: float
    focal_m: float
    principal_points_m: np.ndarray

    def project_m(self, points_m) -> np.ndarray:
        """World points (..., 3) -> sensor positions (V, ..., 2) in metres."""
        p = np.asarray(points_m, dtype=np.float64)
        zs = p[..., 2] - self.depth_origin_m
        if np.any(zs <= 0):
            raise InvalidInputError("points must lie in front of the views' projection centres (Z > s)")
        shape = (len(self.centres_m),) + (1,) * (p.ndim - 1) + (2,)
        c = self.centres_m.reshape(shape)
        p0 = self.principal_points_m.reshape(shape)
        return p0 + self.focal_m * (p[None, ..., :2] - c) / zs[None, ..., None]

    def rays_m(self, view: int, sensor_xy_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ray origin (3,) and directions (..., 3) with unit Z component for sensor points of a view."""
        xy = np.asarray(sensor_xy_m, dtype=np.float64)
        d = (xy - self.principal_points_m[view]) / self.focal_m
        origin = np.array([*self.centres_m[view], self.depth_origin_m])
        return origin, np.concatenate([d, np.ones(d.shape[:-1] + (1,))], axis=-1)


def view_cameras(device: RingDevice) -> ViewCameras:
    """The pinhole model of each view of a device with lens positions set."""
    b, c = device.require_positions()
    fl = device.main_focal_length_m
    m = device.lens_centres_m
    return ViewCameras(
        centres_m=-m * fl / (b - fl),
        depth_origin_m=b * fl / (b - fl),
        focal_m=c * fl / (b - fl),
        principal_points_m=m * (1.0 + c / (b - fl)),
    )


def lens_distortions(device: RingDevice, layout: Layout | None = None) -> tuple[LensDistortion, ...] | None:
    """Each view's distortion by its mini-lens (``device.lenses``), or None when no lens distorts.

    Parameters
    ----------
    device : RingDevice
        With lens positions set.
    layout : Layout, optional
        Express each distortion in the pixels of the views this layout cuts (the erect frame's
        rectangles); by default in raw pixels of the erect frame.

    Returns
    -------
    tuple of LensDistortion (view order), or None
        Centred where each lens's centre projects onto the sensor, ``scale_px`` the sensor
        distance c in pixels (so the coefficients are the device's, on OpenCV's normalised
        coordinates), tilted as the lens is.

    Examples
    --------
    >>> import dataclasses
    >>> from lfring.optics.device import MiniLens, load_device
    >>> dev = load_device("prototype").binned(2)
    >>> lens_distortions(dev) is None
    True
    >>> dev = dev.with_lenses([MiniLens(k1=-1.5)] + [MiniLens()] * 3)
    >>> d = lens_distortions(dev)[0]
    >>> [round(v, 1) for v in d.centre_px], round(d.scale_px, 1), d.k1
    ([807.5, 500.5], 2646.5, -1.5)
    """
    if not device.distorts:
        return None
    _, c = device.require_positions()
    centres = sensor_to_pixel(device, device.lens_centres_m)
    scale = c / device.pixel_pitch_m
    out = []
    for k in range(len(centres)):
        lens = device.lens(k)
        d = LensDistortion((float(centres[k, 0]), float(centres[k, 1])), scale, lens.k1, lens.k2, lens.p1, lens.p2,
                           tilt_rad=(float(np.radians(lens.tilt_deg[0])), float(np.radians(lens.tilt_deg[1]))))
        if layout is not None:
            x, y = layout.rects[k][:2]
            d = d.shifted(-x, -y)
        out.append(d)
    return tuple(out)


def ideal_discs_px(device: RingDevice) -> list[tuple[float, float, float]]:
    """Each view's valid disc (cx, cy, r) in raw pixels of the erect frame as ideal mini-lenses
    would record it: the image of the main-lens iris, where half the light cone gets through."""
    centres, radius = _iris_disc_px(device)
    return [(float(cx), float(cy), float(radius)) for cx, cy in centres]


def _recorded_discs(device: RingDevice) -> list[tuple[float, float, float]]:
    """Each view's valid disc (cx, cy, r) in raw pixels as the sensor records it: the iris's
    image through the ideal lens (:func:`_iris_disc_px`), moved by the lens's distortion (the
    circle through the distorted rim that fits it best)."""
    centres, radius = _iris_disc_px(device)
    dist = lens_distortions(device)
    if dist is None:
        return [(float(cx), float(cy), float(radius)) for cx, cy in centres]
    t = np.linspace(0.0, 2 * np.pi, 720, endpoint=False)
    out = []
    for k, (cx, cy) in enumerate(centres):
        rim = dist[k].distort(np.stack([cx + radius * np.cos(t), cy + radius * np.sin(t)], axis=-1))
        centre = rim.mean(axis=0)
        out.append((float(centre[0]), float(centre[1]), float(np.mean(np.hypot(*(rim - centre).T)))))
    return out


def quadrant_rects(device: RingDevice) -> list[tuple[int, int, int, int]]:
    """(x, y, w, h) of the sensor quadrant each mini-lens lights, in view order."""
    w, h = device.sensor_width_px, device.sensor_height_px
    hw, hh = w // 2, h // 2
    return [(0, 0, hw, hh), (hw, 0, w - hw, hh), (0, hh, hw, h - hh), (hw, hh, w - hw, h - hh)]


def _iris_disc_px(device: RingDevice) -> tuple[np.ndarray, float]:
    """Centres (V, 2) in raw pixels and radius in pixels of each view's valid disc: the image
    of the main-lens iris through the mini-lens, centred at m_k (1 + c/b), out to where exactly
    half of the pixel's light cone gets through the iris (see :func:`vignetting`)."""
    b, c = device.require_positions()
    centres = sensor_to_pixel(device, device.lens_centres_m * (1.0 + c / b))
    r_iris, r_foot = device.effective_aperture_radius_m, _footprint_radius_m(device)
    # Transmission falls monotonically with the chief ray's distance d from the axis at the
    # main lens; bisect for the half-light point (just inside d = r_iris by curvature).
    lo, hi = max(0.0, r_iris - r_foot), r_iris + r_foot
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        frac = _disc_overlap(np.array([mid]), r_foot, r_iris)[0] / (np.pi * r_foot**2)
        lo, hi = (mid, hi) if frac > 0.5 else (lo, mid)
    radius = 0.5 * (lo + hi) * c / b / device.pixel_pitch_m
    return centres, radius


def _footprint_radius_m(device: RingDevice) -> float:
    """Radius on the main-lens plane of the light cone one pixel receives through its mini-lens
    (cone through the mini-lens aperture, converging on the conjugate point b2_f = c Fml/(c - Fml))."""
    b, c = device.require_positions()
    fml = device.mini_focal_length_m
    b2f = c * fml / (c - fml)
    return device.mini_lens_radius_m * (b - b2f) / b2f


def optical_layout(device: RingDevice, *, rotate180: bool = False) -> Layout:
    """The layout the optics predicts: each view's valid disc is the image of the main-lens iris
    through its mini-lens (where half the light cone gets through; moved by the lens's
    distortion when it has one), and the views are the squares around those discs
    (:func:`lfring.views.layout_from_circles`)."""
    if device.distorts:
        circles = _recorded_discs(device)
    else:
        centres, radius = _iris_disc_px(device)
        circles = [(cx, cy, radius) for cx, cy in centres]
    try:
        return layout_from_circles(circles, device.sensor_width_px, device.sensor_height_px, rotate180=rotate180)
    except InvalidInputError as exc:
        raise InvalidInputError(f"device '{device.name}': {exc}") from None


def optical_homographies(device: RingDevice, layout: Layout, depth_m, *, reference="center") -> np.ndarray:
    """Exact ``H_ref_from_view`` for a fronto-parallel plane at ``depth_m``.

    Parameters
    ----------
    device : RingDevice
        With lens positions.
    layout : Layout
        Where the views are cut (view pixel (0, 0) is rect corner (x, y)).
    depth_m : float or array of N floats
        Plane distance Z from the main lens, metres, > s.
    reference : 'center' or int

    Returns
    -------
    ndarray, (V, 3, 3) or (N, V, 3, 3)
        Pure translations: view pixels -> reference pixels.
    """
    cams = view_cameras(device)
    z = np.asarray(depth_m, dtype=np.float64)
    if not np.all(np.isfinite(z)) or np.any(z <= cams.depth_origin_m):
        raise InvalidInputError(
            f"depth must be a finite distance beyond the views' entrance pupil ({cams.depth_origin_m:.4g} m), got {depth_m!r}"
        )
    if layout.num_views != len(cams.centres_m):
        raise InvalidInputError(f"layout has {layout.num_views} views but the device has {len(cams.centres_m)}")
    corners = np.array([[x, y] for x, y, _, _ in layout.rects], dtype=np.float64)
    # Sensor position of the world point seen at view pixel 0 of view 0, rebased per view:
    # p_k = p0_k + f (X - C_k)/(Z - s), so view-k pixel u_k relates to view 0 by a translation.
    zs = (z - cams.depth_origin_m)[..., None, None]
    shift_m = cams.principal_points_m - cams.focal_m * cams.centres_m / zs  # (..., V, 2)
    shift_px = shift_m / device.pixel_pitch_m - corners  # view-local pixel of the same point, up to a common term
    t = shift_px[..., 0:1, :] - shift_px  # H_0_from_k translation
    h = np.zeros(t.shape[:-1] + (3, 3))
    h[..., 0, 0] = h[..., 1, 1] = h[..., 2, 2] = 1.0
    h[..., :2, 2] = t
    return to_reference(h, reference)


def optical_homography_model(device: RingDevice, layout: Layout, *, reference="center"):
    """The variable-homography model (as :func:`lfring.calibrate` fits it) that the optics
    predicts, exactly:
    ``H_ref_from_view(Z) = A + B / (Z - z0)`` with z0 = s, the views' entrance pupil.

    Returns
    -------
    A, B : ndarray, (V, 3, 3)
        For the ring both are translations (B has a zero [2, 2] entry).
    z0 : float
        The depth origin s in metres.
    """
    s = view_cameras(device).depth_origin_m
    z1, z2 = s + 0.25, s + 2.0
    h1 = optical_homographies(device, layout, z1, reference=reference)
    h2 = optical_homographies(device, layout, z2, reference=reference)
    inv1, inv2 = 1.0 / (z1 - s), 1.0 / (z2 - s)
    b = (h1 - h2) / (inv1 - inv2)
    a = h1 - b * inv1
    return a, b, s


def vignetting(device: RingDevice, layout: Layout | None = None) -> np.ndarray:
    """Relative illumination of every sensor pixel through its own mini-lens, in [0, 1].

    Returns (H, W) for the whole sensor (in the erect, rotation-undone frame), or (V, h, w)
    cut with ``layout`` when given.

    Notes
    -----
    A pixel p of quadrant k receives the cone through mini-lens k (radius Rml) that converges on
    its conjugate point at b2_f = c Fml / (c - Fml) in front of the ring and reaches the main
    lens plane as a disc of radius Rml b1_f / b2_f around the chief ray's crossing
    ``y_L = m_k + (m_k - p) b / c``. The fraction of that disc inside the iris (radius R) is the
    vignetting; cos^4 of the chief ray's angle behind the mini-lens is the natural fall-off.
    Light of lens k outside quadrant k is blocked (the ring's baffles).
    """
    out = np.zeros((device.sensor_height_px, device.sensor_width_px), dtype=np.float32)
    for k, rect in enumerate(quadrant_rects(device)):
        x, y, w, h = rect
        out[y : y + h, x : x + w] = vignetting_region(device, k, rect)
    if layout is None:
        return out
    vh, vw = layout.view_shape
    return np.stack([out[y : y + vh, x : x + vw] for x, y, _, _ in layout.rects])


def lit_region(device: RingDevice, view: int) -> tuple[int, int, int, int]:
    """(x, y, w, h) bounding box, inside the view's quadrant, of the pixels its mini-lens lights
    at all (vignetting > 0): the iris image widened by the light cone's footprint."""
    b, c = device.require_positions()
    r_foot = _footprint_radius_m(device)
    centres, _ = _iris_disc_px(device)
    radius = (device.effective_aperture_radius_m + r_foot) * c / b / device.pixel_pitch_m + 1.0
    dist = lens_distortions(device)
    if dist is not None:  # the lens moves the lit disc's rim by at most this much
        radius += dist[view].displacement_px(float(np.hypot(*(centres[view] - dist[view].centre_px))) + radius) + 1.0
    qx, qy, qw, qh = quadrant_rects(device)[view]
    cx, cy = centres[view]
    x0 = max(qx, int(np.floor(cx - radius)))
    y0 = max(qy, int(np.floor(cy - radius)))
    x1 = min(qx + qw, int(np.ceil(cx + radius)) + 1)
    y1 = min(qy + qh, int(np.ceil(cy + radius)) + 1)
    return x0, y0, max(0, x1 - x0), max(0, y1 - y0)


def vignetting_region(device: RingDevice, view: int, rect: tuple[int, int, int, int], *, ideal_px=None) -> np.ndarray:
    """(h, w) float32 vignetting of mini-lens ``view`` over the raw-pixel rectangle ``rect``
    (see :func:`vignetting`).

    A pixel's light comes along its chief ray, which a distorting lens bends: the cone is the
    one of the pixel's ideal position (``LensDistortion.undistort``; ``ideal_px``, (h, w, 2) raw
    pixels, when the caller has them). The lens's ``transmission`` and ``falloff`` multiply it.
    """
    b, c = device.require_positions()
    r_foot = _footprint_radius_m(device)
    r_iris = device.effective_aperture_radius_m
    x, y, w, h = rect
    tp = device.pixel_pitch_m
    lens = device.lens(view)
    if ideal_px is None and lens.distorts:
        ideal_px = lens_distortions(device)[view].undistort_box(x, y, w, h)
    if ideal_px is None:
        px = ((np.arange(x, x + w) + 0.5 - device.sensor_width_px / 2.0) * tp)[None, :]
        py = ((np.arange(y, y + h) + 0.5 - device.sensor_height_px / 2.0) * tp)[:, None]
    else:
        sensor = pixel_to_sensor(device, ideal_px)
        px, py = sensor[..., 0], sensor[..., 1]
    m = device.lens_centres_m[view]
    yl = np.hypot(m[0] + (m[0] - px) * b / c, m[1] + (m[1] - py) * b / c)
    frac = _disc_overlap(yl, r_foot, r_iris) / (np.pi * r_foot**2)
    cos4 = (c * c / (c * c + (px - m[0]) ** 2 + (py - m[1]) ** 2)) ** 2
    out = frac * cos4
    if lens.transmission != 1.0:
        out = out * lens.transmission
    if lens.falloff[0] > 0:
        strength, ox, oy = lens.falloff
        centres, radius = _iris_disc_px(device)
        cx, cy = centres[view]
        if ideal_px is None:
            ux = np.arange(x, x + w, dtype=np.float64)[None, :]
            uy = np.arange(y, y + h, dtype=np.float64)[:, None]
        else:
            ux, uy = ideal_px[..., 0], ideal_px[..., 1]
        rho2 = ((ux - (cx + ox * radius)) / radius) ** 2 + ((uy - (cy + oy * radius)) / radius) ** 2
        out = out / (1.0 + strength * rho2) ** 2
    return np.broadcast_to(out, (h, w)).astype(np.float32)


def _disc_overlap(d: np.ndarray, r1: float, r2: float) -> np.ndarray:
    """Area of the intersection of two discs of radii r1, r2 whose centres are d apart."""
    d = np.asarray(d, dtype=np.float64)
    out = np.zeros_like(d)
    inside = d <= abs(r1 - r2)
    out[inside] = np.pi * min(r1, r2) ** 2
    part = (~inside) & (d < r1 + r2)
    dd = d[part]
    a1 = r1 * r1 * np.arccos(np.clip((dd * dd + r1 * r1 - r2 * r2) / (2 * dd * r1), -1, 1))
    a2 = r2 * r2 * np.arccos(np.clip((dd * dd + r2 * r2 - r1 * r1) / (2 * dd * r2), -1, 1))
    a3 = 0.5 * np.sqrt(np.clip((-dd + r1 + r2) * (dd + r1 - r2) * (dd - r1 + r2) * (dd + r1 + r2), 0, None))
    out[part] = a1 + a2 - a3
    return out
