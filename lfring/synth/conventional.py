"""The conventional image of a scene: ground truth for refocusing.

What a conventional camera focused at a given depth would record, in the pixel grid of the
ring's virtual central view: the average of pinhole views from points of an aperture disc in
the plane of the views' entrance pupil, each rendered as the raw frame's views are
(:mod:`lfring.synth.layers`).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from lfring.core.validate import check_int, check_number
from lfring.errors import InvalidInputError
from lfring.optics.device import RingDevice
from lfring.optics.paraxial import check_f_number
from lfring.optics.views import ViewCameras, optical_layout, view_cameras
from lfring.synth.layers import SurfaceRenderer, default_workers, over
from lfring.synth.scene import Scene
from lfring.synth.settings import RenderSettings

__all__ = [
    "render_conventional",
    "check_conventional",
    "conventional_aperture_radius_m",
    "conventional_blur_px",
    "conventional_sample_count",
    "viewpoint_radius_m",
    "aperture_samples",
    "CONVENTIONAL_SPACING_PX",
    "CONVENTIONAL_MIN_SAMPLES",
    "CONVENTIONAL_MAX_SAMPLES",
]

#: Aperture samples per pixel of blur: the default count puts the samples about
#: ``CONVENTIONAL_SPACING_PX`` apart on the most defocused surface (see :func:`render_conventional`).
CONVENTIONAL_SPACING_PX = 2.0
#: Fewest aperture samples the default count takes for an aperture that is not a pinhole (the
#: samples' union must look like a disc).
CONVENTIONAL_MIN_SAMPLES = 32
#: Most aperture samples the default count takes.
CONVENTIONAL_MAX_SAMPLES = 2048
_GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))


def viewpoint_radius_m(device: RingDevice) -> float:
    """Distance (metres) of the views' projection centres from their mean, in the plane of the
    views' entrance pupil: the radius of the aperture the four viewpoints span
    (``aperture_scale=1`` of :func:`render_conventional`)."""
    cams = view_cameras(device)
    c = cams.centres_m - cams.centres_m.mean(axis=0)
    return float(np.hypot(c[:, 0], c[:, 1]).max())


def conventional_aperture_radius_m(device: RingDevice, *, f_number=None, aperture_scale=None) -> float:
    """Radius (metres) of the aperture disc :func:`render_conventional` integrates over.

    ``f_number`` N gives the main lens's entrance pupil at N, ``FL / (2 N)`` (``inf`` gives a
    pinhole); ``aperture_scale`` a gives ``a * viewpoint_radius_m(device)``; neither gives the
    main lens's full aperture, ``device.effective_aperture_radius_m``. Not both. An f-number
    below ``MIN_F_NUMBER`` is refused: no lens has it.
    """
    if f_number is not None and aperture_scale is not None:
        raise InvalidInputError("give f_number or aperture_scale, not both")
    if f_number is not None:
        n = check_f_number(f_number, pinhole=True)
        return 0.0 if np.isinf(n) else device.main_focal_length_m / (2.0 * n)
    if aperture_scale is not None:
        a = check_number(aperture_scale, "aperture_scale", minimum=0)
        return a * viewpoint_radius_m(device)
    return float(device.effective_aperture_radius_m)


def check_conventional(device: RingDevice, focus_m, *, f_number=None, aperture_scale=None,
                       samples=None) -> tuple[float, float, int | None]:
    """Check the arguments of :func:`render_conventional` as it does, without rendering, so that
    a caller can refuse them before any work: ``focus_m`` beyond the views' entrance pupil, the
    aperture (:func:`conventional_aperture_radius_m`) and ``samples`` (an integer >= 1, or None).

    Parameters
    ----------
    device : RingDevice
        The binned device, with lens positions.
    focus_m, f_number, aperture_scale, samples
        As :func:`render_conventional`'s.

    Returns
    -------
    tuple
        The focus distance (metres), the aperture radius (metres) and the samples (None: the
        default count).
    """
    device.require_positions()
    zf = check_number(focus_m, "focus_m", above=view_cameras(device).depth_origin_m, what="a distance in metres",
                      hint=": beyond the views' entrance pupil")
    radius = conventional_aperture_radius_m(device, f_number=f_number, aperture_scale=aperture_scale)
    n = None if samples is None else check_int(samples, "samples", minimum=1)
    return zf, radius, n


def aperture_samples(n: int) -> np.ndarray:
    """(n, 2) points on the unit disc: a Vogel (sunflower) spiral, equal area per point; one
    point, the centre, for ``n = 1``."""
    if n == 1:
        return np.zeros((1, 2))
    i = np.arange(n)
    r = np.sqrt((i + 0.5) / n)
    t = i * _GOLDEN_ANGLE
    return np.column_stack([r * np.cos(t), r * np.sin(t)])


def conventional_blur_px(device: RingDevice, depth_m, focus_m: float, aperture_radius_m: float) -> np.ndarray:
    """Diameter (pixels of ``device``) of the blur disc of a point at ``depth_m`` in the
    conventional image focused at ``focus_m`` through an aperture of ``aperture_radius_m`` in
    the views' entrance-pupil plane: ``2 R f |1/(Zf - s) - 1/(Z - s)| / pitch``."""
    cams = view_cameras(device)
    s, f = cams.depth_origin_m, cams.focal_m
    z = np.asarray(depth_m, dtype=np.float64)
    return 2.0 * aperture_radius_m * f * np.abs(1.0 / (focus_m - s) - 1.0 / (z - s)) / device.pixel_pitch_m


class _SubApertureRenderer(SurfaceRenderer):
    """Renders the scene as seen from points of the aperture disc, each a small lens (one
    sample's share of the disc) focused at the focus depth, into the central view's grid."""

    def __init__(self, device: RingDevice, scene: Scene, focus_m: float, cell_radius_m: float, cams: ViewCameras):
        super().__init__(device, scene, RenderSettings(binning=1, pattern=None, defocus=cell_radius_m > 0,
                                                        vignetting=False))
        self.focus_m = focus_m
        self.cell_radius_m = cell_radius_m
        self.cams = cams

    def blur_px(self, z: np.ndarray) -> np.ndarray:
        z = np.asarray(z, dtype=np.float64)
        out = np.full(z.shape, np.nan)
        finite = np.isfinite(z)
        out[finite] = conventional_blur_px(self.dev, z[finite], self.focus_m, self.cell_radius_m)
        return out

    def sample(self, k: int, region) -> np.ndarray:
        """(h, w, 3) float32 radiance of aperture sample ``k`` over ``region``."""
        rx, ry, rw, rh = region
        layers = self.layers(k, region)
        acc = np.zeros((rh, rw, 4), np.float32)
        for lay in layers:
            rgba = self.defocus(lay) if self.settings.defocus else lay.rgba
            h, w = lay.depth.shape
            over(acc[lay.y0 - ry : lay.y0 - ry + h, lay.x0 - rx : lay.x0 - rx + w], rgba)
        bg = np.array(self.scene.background, np.float32)
        if np.any(bg != 0):
            acc[..., :3] += (1.0 - acc[..., 3:4]) * bg
        return acc[..., :3]


def render_conventional(scene: Scene, device: RingDevice, focus_m: float, *, f_number=None, aperture_scale=None,
                        samples: int | None = None, binning: int = 1, workers: int | None = None) -> np.ndarray:
    """The image a conventional camera focused at ``focus_m`` would record of ``scene``, in the
    views' reference frame ``'center'``: ground truth for refocusing.

    Every view of the ring is a pinhole camera (:func:`lfring.optics.views.view_cameras`) with
    its projection centre ``C_k`` in the plane ``Z = s`` of the views' entrance pupil. The
    conventional camera here has its aperture disc in that plane, centred on the central
    viewpoint (the mean of the ``C_k``), and its image is in the pixel grid of the virtual
    central view (the frame ``lfring.refocus`` renders into: view-sized, a point at the focus
    depth lands where the central view sees it). A point at depth Z is spread over a disc of
    ``2 R f |1/(Zf - s) - 1/(Z - s)|`` on the sensor (:func:`conventional_blur_px`), the
    synthetic-aperture form of the thin-lens circle of confusion.

    The image is the average of ``samples`` views from points of the disc (a Vogel spiral), each
    shifted so that the focus plane stays put, occlusions resolved per viewpoint; each sample
    is itself a small lens, its equal share of the disc (radius ``R / sqrt(samples)``), whose
    defocus is rendered per surface as the raw frame's is. More samples converge on the exact
    integral over the aperture (the small lenses shrink to pinholes).

    Parameters
    ----------
    scene : Scene
    device : RingDevice
        With lens positions (the unbinned device; ``binning`` bins it as ``render`` does).
    focus_m : float
        Focus distance Zf from the main lens, metres, beyond the entrance pupil s.
    f_number, aperture_scale : float, optional
        The aperture (:func:`conventional_aperture_radius_m`): the main lens's entrance pupil at
        f-number N, at least ``MIN_F_NUMBER`` (``inf``: a pinhole, the central view itself), or ``aperture_scale`` times the
        radius the four viewpoints span (1: the aperture the views span); default the main
        lens's full aperture.
    samples : int, optional
        Aperture samples; default about one per ``CONVENTIONAL_SPACING_PX`` of the largest blur
        diameter in the scene (from ``CONVENTIONAL_MIN_SAMPLES`` to ``CONVENTIONAL_MAX_SAMPLES``),
        one for a pinhole.
    binning : int
        Sensor binning, as :class:`RenderSettings` (the image has the views' shape at it).
    workers : int, optional
        Threads (default one per core, at most four); the image does not depend on them.

    Returns
    -------
    ndarray, (h, w, 3) float32
        Linear RGB radiance in [0, 1] (not scaled by ``RenderSettings.exposure``), without noise
        or vignetting; ``h, w`` the view shape of :func:`lfring.optics.views.optical_layout`.

    Notes
    -----
    How the views' viewpoints relate to the main lens's aperture. The main lens images the ring
    (at b behind it) to the plane ``s = b FL / (b - FL)`` in front of it, magnified by
    ``FL / (b - FL)``: mini-lens k (centre m_k, radius Rml) becomes the pupil of view k,
    centred at ``C_k = -m_k FL / (b - FL)`` with radius ``Rml FL / (b - FL)``, and the views
    are focused where their sensor is conjugate (``paraxial.blur_diameter_m`` is zero). The
    main lens's iris is not the views' pupil: it is their field stop (each view's valid disc
    is its image). For the prototype (FL 16 mm, b 37.37 mm, Rml 1 mm, m_k at 1.05 mm on both
    axes, iris radius 5 mm): s = 27.98 mm, |C_k| = 1.112 mm (``viewpoint_radius_m``, the
    radius of ``aperture_scale=1``, f/7.2 in main-lens terms), each view's own pupil radius
    0.749 mm (the conventional image with ``aperture_scale=0.673`` focused at 0.3 m has
    exactly the views' defocus blur), so the views' pupils together reach 1.86 mm from the
    axis, against the 5 mm (f/1.6) of the main lens's full aperture. An f-number puts the
    main lens's pupil diameter FL / N in the plane s, which keeps every viewpoint a view-like
    pinhole camera; the same pupil at the main lens itself (Z = 0) would take from a point at
    Z a cone ``(Z - s) / Z`` times as wide (0.91 at 0.3 m, 0.97 at 1 m), and a perspective
    from Z = 0 rather than from the views' plane.

    Examples
    --------
    >>> from lfring.optics import load_device
    >>> from lfring.synth import Plane, Scene, Texture
    >>> dev = load_device("prototype")
    >>> scene = Scene((Plane(0.5, (0.4, 0.3), Texture("checker", square_m=0.02)),))
    >>> img = render_conventional(scene, dev, 0.5, f_number=8, binning=8)
    >>> img.shape, img.dtype
    ((176, 176, 3), dtype('float32'))
    """
    if not isinstance(scene, Scene):
        raise InvalidInputError(f"scene must be a lfring.synth.Scene, got {type(scene).__name__}")
    check_int(binning, "binning", minimum=1)
    dev = device.binned(binning)
    zf, radius, samples = check_conventional(dev, focus_m, f_number=f_number, aperture_scale=aperture_scale,
                                             samples=samples)
    cams = view_cameras(dev)
    s, f, tp = cams.depth_origin_m, cams.focal_m, dev.pixel_pitch_m
    if radius == 0:
        n = 1
    elif samples is None:
        n = conventional_sample_count(scene, dev, zf, radius)
    else:
        n = samples
    layout = optical_layout(dev)
    vh, vw = layout.view_shape
    corner = np.mean([(x, y) for x, y, _, _ in layout.rects], axis=0)
    origin = np.floor(corner)
    # The central view: centre mean(C_k), principal point mean(p0_k); its pixel (0, 0) is the
    # raw pixel at the mean of the views' corners. Rendered on the integer grid at ``origin``,
    # the fractional part moves the principal point instead.
    c_mean = cams.centres_m.mean(axis=0)
    p_mean = cams.principal_points_m.mean(axis=0) - (corner - origin) * tp
    offsets = radius * aperture_samples(n)
    sample_cams = ViewCameras(
        centres_m=c_mean + offsets,
        depth_origin_m=s,
        focal_m=f,
        principal_points_m=p_mean + f * offsets / (zf - s),
    )
    cell = radius / np.sqrt(n) if n > 1 else 0.0
    rend = _SubApertureRenderer(dev, scene, zf, cell, sample_cams)
    # Render a margin around the view as wide as the samples' own blur, so that the blur at the
    # image's border sees the surfaces beyond it (a layer is zero outside its region).
    margin = int(np.ceil(float(np.max(conventional_blur_px(dev, np.array(scene.depth_range_m), zf, cell))) / 2)) + 2
    region = (int(origin[0]) - margin, int(origin[1]) - margin, vw + 2 * margin, vh + 2 * margin)
    inner = np.s_[margin : margin + vh, margin : margin + vw]
    workers = default_workers() if workers is None else check_int(workers, "workers", minimum=1)
    # Fixed chunks summed in order: the image does not depend on the number of threads.
    chunks = [range(i, n, 8) for i in range(min(8, n))]

    def chunk_sum(ks) -> np.ndarray:
        acc = np.zeros((vh, vw, 3), np.float64)
        for k in ks:
            acc += rend.sample(k, region)[inner]
        return acc

    with ThreadPoolExecutor(workers) as pool:
        list(pool.map(rend.prepare_texture, range(len(scene.surfaces))))
        sums = list(pool.map(chunk_sum, chunks))
    total = sums[0]
    for part in sums[1:]:
        total += part
    return np.clip(total / n, 0.0, 1.0).astype(np.float32)


def conventional_sample_count(scene: Scene, device: RingDevice, focus_m: float, aperture_radius_m: float) -> int:
    """The default aperture samples of :func:`render_conventional`: about one per
    ``CONVENTIONAL_SPACING_PX`` pixels (of the binned ``device``) across the largest blur disc
    of the scene's depth range, from ``CONVENTIONAL_MIN_SAMPLES`` to ``CONVENTIONAL_MAX_SAMPLES``
    (1 for a pinhole)."""
    if aperture_radius_m == 0:
        return 1
    d_max = float(np.max(conventional_blur_px(device, np.array(scene.depth_range_m), focus_m, aperture_radius_m)))
    return int(np.clip(np.ceil(np.pi / 4 * (d_max / CONVENTIONAL_SPACING_PX) ** 2), CONVENTIONAL_MIN_SAMPLES, CONVENTIONAL_MAX_SAMPLES))

