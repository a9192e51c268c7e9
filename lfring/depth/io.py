"""Outputs of a depth map: PFM and TIFF files, a colour preview, 3D points and PLY point clouds.

Every writer is atomic (a killed run leaves no partial file) and raises the errors of
:mod:`lfring.errors`. Depth maps are (h, w) float metres from the main lens, NaN where unknown.
"""

from __future__ import annotations

import io
import re
from pathlib import Path

import numpy as np

from lfring.core.validate import check_number, check_view_index
from lfring.core.viewstack import check_unit_range
from lfring.errors import DeviceError, FileFormatError, InvalidInputError, LfringFileNotFoundError
from lfring.io.atomic import atomic_write_bytes
from lfring.io.writers import encode_image, write_float_tiff
from lfring.optics.device import RingDevice
from lfring.optics.paraxial import pixel_to_sensor
from lfring.optics.views import view_cameras
from lfring.views import Layout

__all__ = [
    "colorize_depth",
    "depth_to_points",
    "points_camera",
    "device_for",
    "read_pfm",
    "read_ply",
    "depth_preview_png", "write_depth_preview",
    "DEPTH_TIFF_WORDS", "write_depth_tiff",
    "write_pfm",
    "write_ply",
]


def _float_map(a, name: str, *, channels_ok: bool = False) -> np.ndarray:
    arr = np.asarray(a)
    if not np.issubdtype(arr.dtype, np.floating):
        raise InvalidInputError(
            f"{name} must be a floating-point map (float32, NaN where unknown), got dtype {arr.dtype}; "
            "convert it explicitly, e.g. with .astype(np.float32)"
        )
    shapes = "(h, w) or (h, w, 3)" if channels_ok else "(h, w)"
    ok = arr.ndim == 2 or (channels_ok and arr.ndim == 3 and arr.shape[2] == 3)
    if not ok or arr.size == 0:
        raise InvalidInputError(f"{name} must be a non-empty {shapes} array, got shape {arr.shape}")
    return arr


# -- PFM -----------------------------------------------------------------------------------------
# Magic, width, height, scale, then exactly one whitespace byte before the samples.
_PFM_HEADER = re.compile(rb"\A(P[Ff])\s+(\d+)\s+(\d+)\s+([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s")


def write_pfm(path: str | Path, data) -> Path:
    """Write a float map as PFM: ``Pf`` for (h, w), ``PF`` for (h, w, 3), little-endian.

    Parameters
    ----------
    path : str or Path
    data : ndarray, floating, (h, w) or (h, w, 3)
        Stored as float32, the only sample type of PFM (NaN and inf kept).

    Notes
    -----
    PFM stores the rows bottom-to-top; the header's scale is -1.0 for little-endian samples
    (+1.0 would mean big-endian). The array is written top row first in memory order and
    comes back the same way from :func:`read_pfm`.
    """
    arr = _float_map(data, "data", channels_ok=True)
    h, w = arr.shape[:2]
    magic = "PF" if arr.ndim == 3 else "Pf"
    header = f"{magic}\n{w} {h}\n-1.0\n".encode("ascii")
    return atomic_write_bytes(path, header + np.ascontiguousarray(arr[::-1], dtype="<f4").tobytes())


def read_pfm(path: str | Path) -> np.ndarray:
    """Read a PFM file (``Pf`` grey or ``PF`` colour, either endianness).

    Returns
    -------
    ndarray, float32, (h, w) or (h, w, 3)
        Top row first, native byte order.

    Raises
    ------
    LfringFileNotFoundError
        No such file.
    FileFormatError
        Not a PFM file, a bad header, or a sample count that disagrees with the header.
    """
    path = Path(path)
    if not path.is_file():
        raise LfringFileNotFoundError(f"PFM file not found: {path}")
    raw = path.read_bytes()
    m = _PFM_HEADER.match(raw)
    if m is None:
        raise FileFormatError(
            f"{path}: not a PFM file (expected a header 'Pf' or 'PF', width, height and scale, got {raw[:24]!r})"
        )
    magic, w, h, scale = m.group(1), int(m.group(2)), int(m.group(3)), float(m.group(4))
    if w < 1 or h < 1:
        raise FileFormatError(f"{path}: PFM size must be positive, got {w} x {h}")
    if scale == 0 or not np.isfinite(scale):
        raise FileFormatError(f"{path}: PFM scale must be a non-zero number (its sign gives the byte order), got {scale!r}")
    channels = 3 if magic == b"PF" else 1
    want = w * h * channels * 4
    got = len(raw) - m.end()
    if got != want:
        what = "truncated" if got < want else "has trailing bytes"
        raise FileFormatError(f"{path}: PFM data {what}: {w} x {h} x {channels} float32 need {want} bytes, found {got}")
    dtype = "<f4" if scale < 0 else ">f4"
    shape = (h, w, 3) if channels == 3 else (h, w)
    return np.frombuffer(raw, dtype=dtype, offset=m.end()).reshape(shape)[::-1].astype(np.float32)


# -- TIFF ----------------------------------------------------------------------------------------
def write_depth_tiff(path: str | Path, depth_m) -> Path:
    """Write a depth map (metres, NaN where unknown) as a float32, zlib-compressed TIFF that says
    so in its description."""
    return write_float_tiff(path, _float_map(depth_m, "depth_m"), metadata=DEPTH_TIFF_WORDS)


DEPTH_TIFF_WORDS = {"quantity": "depth", "unit": "m", "from": "the main lens", "unknown": "NaN"}
"""What a depth TIFF's description says of its values."""


# -- colour preview ------------------------------------------------------------------------------
_CMAP_ENDS = (0.08, 0.92)


def _colour_table(cmap: str) -> np.ndarray:
    import matplotlib

    if not isinstance(cmap, str) or cmap not in matplotlib.colormaps:
        raise InvalidInputError(
            f"cmap must be the name of a matplotlib colour map, e.g. 'turbo', 'viridis', 'plasma' or 'cividis'; got {cmap!r}"
        )
    # The outer 8 % of each end are left out: turbo (and viridis, magma...) end in near-black,
    # which must stay the colour of "no depth" alone.
    rgba = matplotlib.colormaps[cmap](np.linspace(_CMAP_ENDS[0], _CMAP_ENDS[1], 256))
    return np.rint(rgba[:, :3] * 255.0).astype(np.uint8)


def _shown(z: np.ndarray, confidence, min_confidence) -> np.ndarray:
    """Pixels with a finite depth and, when given, confidence >= min_confidence."""
    check_number(min_confidence, "min_confidence", minimum=0.0, maximum=1.0, hint=" (confidence lies in [0, 1])")
    shown = np.isfinite(z)
    if confidence is not None:
        c = _float_map(confidence, "confidence")
        if c.shape != z.shape:
            raise InvalidInputError(f"confidence must have the depth map's shape {z.shape}, got {c.shape}")
        with np.errstate(invalid="ignore"):
            shown &= c >= min_confidence  # NaN confidence compares False: not shown
    return shown


def _depth_range(z_shown: np.ndarray, zmin_m, zmax_m) -> tuple[float, float]:
    for name, v in (("zmin_m", zmin_m), ("zmax_m", zmax_m)):
        check_number(v, name, allow_none=True, what="a finite number of metres")
    if zmin_m is not None and zmax_m is not None and not zmin_m < zmax_m:
        raise InvalidInputError(f"zmin_m must be less than zmax_m, got {zmin_m} and {zmax_m}")
    lo, hi = np.percentile(z_shown, [1.0, 99.0]) if z_shown.size else (0.0, 1.0)
    lo = float(lo if zmin_m is None else zmin_m)
    hi = float(hi if zmax_m is None else zmax_m)
    if not hi > lo:  # a flat map, or one given bound beyond every depth: the other bound follows
        if zmin_m is None and zmax_m is None:
            lo, hi = lo - 5e-4, hi + 5e-4
        elif zmin_m is None:
            lo = hi - 1e-3
        else:
            hi = lo + 1e-3
    return lo, hi


def _colorize(depth_m, zmin_m, zmax_m, confidence, min_confidence, cmap):
    z = _float_map(depth_m, "depth_m")
    shown = _shown(z, confidence, min_confidence)
    table = _colour_table(cmap)
    lo, hi = _depth_range(z[shown].astype(np.float64), zmin_m, zmax_m)
    t = (hi - z[shown].astype(np.float64)) / (hi - lo)  # near -> 1, the warm end of turbo
    out = np.zeros(z.shape + (3,), np.uint8)
    out[shown] = table[np.clip(np.rint(t * 255.0), 0, 255).astype(np.intp)]
    return out, shown, (lo, hi), table


def colorize_depth(depth_m, *, zmin_m=None, zmax_m=None, confidence=None, min_confidence=0.0, cmap="turbo") -> np.ndarray:
    """A depth map as an RGB image: near in warm colours, far in cold ones, unknown in black.

    Parameters
    ----------
    depth_m : (h, w) ndarray, floating
        Metres, NaN where unknown.
    zmin_m, zmax_m : float, optional
        Depths of the two ends of the colour map; depths beyond them take the end colours.
        Default: the 1st and 99th percentiles of the shown depths (robust to a few outliers).
    confidence : (h, w) ndarray, floating, optional
        Pixels with ``confidence < min_confidence`` (or NaN confidence) are black.
    min_confidence : float
    cmap : str
        A matplotlib colour map, sampled from 8 % to 92 % of its length (the ends of 'turbo'
        are near-black); zmin_m takes the high end (red for 'turbo'), zmax_m the low end.

    Returns
    -------
    (h, w, 3) uint8 RGB

    Examples
    --------
    >>> import numpy as np
    >>> import lfring.depth.io
    >>> rgb = lfring.depth.io.colorize_depth(np.array([[0.5, 1.0, np.nan]], np.float32), zmin_m=0.5, zmax_m=1.0)
    >>> rgb[0].tolist()  # near: red; far: blue; unknown: black
    [[183, 29, 2], [66, 75, 181], [0, 0, 0]]
    """
    return _colorize(depth_m, zmin_m, zmax_m, confidence, min_confidence, cmap)[0]


def write_depth_preview(path: str | Path, depth_m, **options) -> Path:
    """Write :func:`depth_preview_png` (``options`` are its keywords) to ``path``, which ends in
    .png, atomically."""
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise InvalidInputError(f"a depth preview is a PNG file ending in .png, got {path.name!r}")
    atomic_write_bytes(path, depth_preview_png(depth_m, **options))
    return path


def depth_preview_png(
    depth_m,
    *,
    confidence=None,
    zmin_m=None,
    zmax_m=None,
    title: str | None = None,
    min_confidence: float = 0.0,
    cmap: str = "turbo",
    dpi: int = 100,
) -> bytes:
    """PNG bytes of :func:`colorize_depth` beside a colour bar labelled in metres.

    Parameters
    ----------
    depth_m, confidence, zmin_m, zmax_m, min_confidence, cmap
        As for :func:`colorize_depth`.
    title : str, optional
    dpi : int

    Notes
    -----
    The map is shown 320 to 1000 px wide (at its own size in between), near at the warm end of
    the bar; arrows on the bar mean depths beyond its ends (which take the end colours), and a
    line under the map says what black means and what fraction of the map is shown.
    """
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import ListedColormap, Normalize
    from matplotlib.figure import Figure

    rgb, shown, (lo, hi), table = _colorize(depth_m, zmin_m, zmax_m, confidence, min_confidence, cmap)
    h, w = shown.shape
    shown_w = min(max(w, 320), 1000)  # display width in pixels: small maps enlarged, large ones reduced
    img_w, img_h = shown_w / dpi, max(h * shown_w / w / dpi, 1.2)
    fig = Figure(figsize=(img_w + 1.6, img_h + (0.9 if title else 0.6)), dpi=dpi, layout="constrained")
    ax = fig.add_subplot()
    ax.imshow(rgb, interpolation="nearest" if shown_w >= w else "antialiased")
    ax.tick_params(labelsize=7)
    black = "no depth" if confidence is None else f"no depth or confidence < {min_confidence:g}"
    ax.set_xlabel(f"x (px)\nblack: {black}; {shown.mean():.1%} of pixels shown", fontsize=8)
    ax.set_ylabel("y (px)", fontsize=8)
    if title:
        ax.set_title(title, fontsize=10)
    z_shown = np.asarray(depth_m)[shown]
    extend = {(False, False): "neither", (True, False): "min", (False, True): "max", (True, True): "both"}[
        (bool(np.any(z_shown < lo)), bool(np.any(z_shown > hi)))
    ]
    # The bar uses the very table the image was coloured with (reversed: near = high end).
    bar = ScalarMappable(Normalize(lo, hi), ListedColormap(table[::-1] / 255.0))
    cb = fig.colorbar(bar, ax=ax, extend=extend, fraction=0.08, pad=0.02)
    cb.set_label("depth from the main lens (m)", fontsize=9)
    cb.ax.tick_params(labelsize=8)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


# -- 3D points -----------------------------------------------------------------------------------
def _colour_bytes(colors, shape_hw) -> np.ndarray:
    c = np.asarray(colors)
    if c.shape != tuple(shape_hw) + (3,):
        raise InvalidInputError(f"colors must be an (h, w, 3) RGB image of the depth map's size {tuple(shape_hw)}, got {c.shape}")
    if c.dtype == np.uint8:
        return c
    if np.issubdtype(c.dtype, np.floating):
        # Processing images are linear float in [0, 1]; PLY stores 8-bit display values, as
        # lfring's PNGs do. Out-of-range values clip, but counts given as floats would all be white.
        check_unit_range(c, "colors")
        return encode_image(np.nan_to_num(c, nan=0.0), 8, "srgb")
    raise InvalidInputError(f"colors must be uint8 or float in [0, 1], got dtype {c.dtype}")


def device_for(calibration, device=None) -> RingDevice:
    """The optics of the frames ``calibration`` describes: ``device`` (a RingDevice, a built-in
    name or a device file), else the device the calibration was made with
    (:meth:`lfring.RingCalibration.device_optics`), else the prototype; binned to the
    calibration's frame size when it is a binned sensor's.

    Raises
    ------
    InvalidInputError
        No such device matches the calibration's frame size, or it has no lens positions: pass
        ``device=`` the optics of the camera.

    Examples
    --------
    >>> import lfring
    >>> dev = lfring.depth.io.device_for(lfring.RingCalibration.load("twin_binned2"))
    >>> (dev.sensor_width_px, dev.sensor_height_px)
    (2456, 1842)
    """
    from lfring.optics.device import load_device

    dev = load_device(device) if device else (calibration.device_optics() or load_device("prototype"))
    if not dev.has_positions:  # where the views' pinholes are follows from b and c
        raise InvalidInputError(f"device '{dev.name}' has no lens positions (ring_distance_m, sensor_distance_m), which "
                                "metric points need; pass device= the optics of the camera with them")
    try:
        return dev.for_frames(tuple(calibration.raw_size), whose="the calibration's ")
    except DeviceError as exc:
        raise InvalidInputError(f"{exc}; pass device= the optics of the camera") from None


def depth_to_points(
    depth_m,
    device: RingDevice,
    layout: Layout,
    view: int,
    *,
    colors=None,
    confidence=None,
    min_confidence: float = 0.0,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Metric 3D points of every valid pixel of a depth map seen from one view.

    Parameters
    ----------
    depth_m : (h, w) ndarray, floating
        Depth Z from the main lens, metres, NaN where unknown, in the frame of view ``view``.
    device : RingDevice
        With lens positions, and binned like the frames (its sensor is the layout's raw frame).
    layout : Layout
        Where the views were cut; ``(h, w)`` must be its view shape.
    view : int or 'center'
        The reference frame of the map: a view index, or the virtual central view.
    colors : (h, w, 3) ndarray, optional
        uint8 (taken as display values), or a float image in [0, 1] (linear light, as lfring's
        images are: clipped and sRGB-encoded to 8 bits, the display values point-cloud viewers
        show).
    confidence : (h, w) ndarray, floating, optional
        Keep only pixels with ``confidence >= min_confidence``.
    min_confidence : float

    Returns
    -------
    points : (N, 3) float64
        (X, Y, Z) in metres: X right, Y down, Z forward from the main lens; valid pixels in
        row-major order.
    colors : (N, 3) uint8 or None

    Notes
    -----
    View pixel (u, v) is raw pixel (u + x_k, v + y_k) of the layout's rectangle (x_k, y_k, w, h)
    in the (rotation-undone) raw frame, at sensor position p (:func:`pixel_to_sensor`). The view's
    pinhole (:func:`lfring.optics.views.view_cameras`: centre C_k at depth s, focal length f,
    principal point p0_k) gives the point at depth Z on that pixel's ray:

        (X, Y) = C_k + (p - p0_k) (Z - s) / f.

    The 'center' frame (:func:`lfring.core.geometry.to_reference`: ``H_center_from_k`` is view k's
    translation minus the mean translation) puts a point at the mean of its four view-pixel
    positions. For the ring that is again a pinhole: centre mean(C_k), principal point
    mean(p0_k), and pixel (u, v) at raw pixel (u, v) + mean(x_k, y_k) (exact in the optics
    model; a measured calibration's centre frame agrees to its residuals).
    """
    if not isinstance(device, RingDevice):
        raise InvalidInputError(f"device must be a RingDevice, got {type(device).__name__}")
    if not isinstance(layout, Layout):
        raise InvalidInputError(f"layout must be a lfring.views.Layout, got {type(layout).__name__}")
    check_view_index(view, "view", layout.num_views, allow_center=True)
    if (device.sensor_width_px, device.sensor_height_px) != (layout.raw_width_px, layout.raw_height_px):
        raise InvalidInputError(
            f"device '{device.name}' has a {device.sensor_width_px} x {device.sensor_height_px} px sensor but the layout "
            f"is for {layout.raw_width_px} x {layout.raw_height_px} px frames; use device.binned(n) for binned frames"
        )
    z = _float_map(depth_m, "depth_m")
    if z.shape != layout.view_shape:
        raise InvalidInputError(f"depth_m must have the layout's view shape (h, w) = {layout.view_shape}, got {z.shape}")
    cam = points_camera(device, layout, view)
    s = cam["depth_origin_m"]
    keep = _shown(z, confidence, min_confidence)
    if np.any(z[keep] <= s):
        raise InvalidInputError(
            f"depth_m must lie beyond the views' projection centres (s = {s:.4g} m) where it is valid, "
            f"got a minimum of {float(np.min(z[keep])):.4g} m"
        )
    rgb = None if colors is None else _colour_bytes(colors, z.shape)
    rows, cols = np.nonzero(keep)
    zz = z[rows, cols].astype(np.float64)
    offset = np.stack([cols, rows], axis=-1) - np.asarray(cam["principal_point_px"])
    xy = np.asarray(cam["centre_m"][:2]) + offset * ((zz - s) / cam["focal_px"])[:, None]
    points = np.concatenate([xy, zz[:, None]], axis=1)
    return points, (None if rgb is None else np.ascontiguousarray(rgb[rows, cols]))


def points_camera(device: RingDevice, layout: Layout, view) -> dict:
    """The pinhole through which :func:`depth_to_points` sees a depth map of ``view`` (an index
    or 'center') cut with ``layout`` from frames of ``device`` (binned like them), in the map's
    own pixels: JSON-ready, with the formula in words.

    ``focal_px`` f / pitch; ``principal_point_px`` (column, row) in the map, pixel centres at
    whole numbers; ``centre_m`` the projection centre (X, Y, Z), Z = ``depth_origin_m`` = s in
    front of the main lens, from which the map's depths are not measured (they are from the main
    lens): a pinhole back-projection that takes the map's Z as distance from the centre is off
    laterally by s / (Z - s).

    Examples
    --------
    >>> import lfring
    >>> from lfring.depth.io import device_for, points_camera
    >>> cal = lfring.RingCalibration.load("twin_binned2")
    >>> cam = points_camera(device_for(cal), cal.layout, "center")
    >>> round(cam["focal_px"], 1), [round(c, 1) for c in cam["principal_point_px"]], round(cam["depth_origin_m"], 4)
    (1981.6, [352.0, 352.0], 0.028)
    """
    cams = view_cameras(device)
    corners = np.array([r[:2] for r in layout.rects], dtype=np.float64)
    if view == "center":
        centre, p0, corner = cams.centres_m.mean(axis=0), cams.principal_points_m.mean(axis=0), corners.mean(axis=0)
    else:
        centre, p0, corner = cams.centres_m[view], cams.principal_points_m[view], corners[view]
    # Raw pixel q lies at sensor position pixel_to_sensor(q); the principal point is where that is p0.
    origin = pixel_to_sensor(device, np.zeros(2))
    principal = (np.asarray(p0, dtype=np.float64) - origin) / device.pixel_pitch_m - corner
    s = float(cams.depth_origin_m)
    return {
        "focal_px": float(cams.focal_m / device.pixel_pitch_m),
        "principal_point_px": [float(principal[0]), float(principal[1])],
        "centre_m": [float(centre[0]), float(centre[1]), s],
        "depth_origin_m": s,
        "model": "X = centre_x + (col - principal_col) (Z - s) / focal_px, Y = centre_y + (row - principal_row) "
                 "(Z - s) / focal_px, Z the map's depth from the main lens, s = depth_origin_m; X right, Y down, "
                 "metres; col, row the map's pixel (centres at whole numbers)",
        "device": device.name,
    }


# -- PLY -----------------------------------------------------------------------------------------
_XYZ = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
_RGB = [("red", "u1"), ("green", "u1"), ("blue", "u1")]


def write_ply(path: str | Path, points, colors=None) -> Path:
    """Write a point cloud as binary little-endian PLY.

    Parameters
    ----------
    points : (N, 3) ndarray, floating
        Finite (X, Y, Z) in metres; stored as float32 (``property float x``, ``y``, ``z``).
    colors : (N, 3) uint8, optional
        Stored as ``property uchar red``, ``green``, ``blue``.
    """
    pts = np.asarray(points)
    if not np.issubdtype(pts.dtype, np.floating) or pts.ndim != 2 or pts.shape[1] != 3:
        raise InvalidInputError(f"points must be an (N, 3) floating array, got {pts.dtype} of shape {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise InvalidInputError("points must be finite; drop the pixels without depth first (depth_to_points does)")
    fields = list(_XYZ)
    if colors is not None:
        col = np.asarray(colors)
        if col.dtype != np.uint8 or col.shape != pts.shape:
            raise InvalidInputError(f"colors must be (N, 3) uint8 matching points {pts.shape}, got {col.dtype} of shape {col.shape}")
        fields += _RGB
    vertex = np.empty(len(pts), dtype=fields)
    for i, name in enumerate("xyz"):
        vertex[name] = pts[:, i]
    if colors is not None:
        for i, (name, _) in enumerate(_RGB):
            vertex[name] = col[:, i]
    props = "".join(f"property {'float' if t == '<f4' else 'uchar'} {n}\n" for n, t in fields)
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        "comment lfring: metres, X right, Y down, Z forward from the main lens\n"
        f"element vertex {len(pts)}\n{props}end_header\n"
    )
    return atomic_write_bytes(path, header.encode("ascii") + vertex.tobytes())


def read_ply(path: str | Path) -> tuple[np.ndarray, np.ndarray | None]:
    """Read a point cloud written by :func:`write_ply`: (N, 3) float32 points, (N, 3) uint8 colours or None.

    Only that form is read (binary little-endian, one vertex element with float x, y, z and
    optionally uchar red, green, blue).
    """
    path = Path(path)
    if not path.is_file():
        raise LfringFileNotFoundError(f"PLY file not found: {path}")
    raw = path.read_bytes()
    end = raw.find(b"end_header\n")
    if not raw.startswith(b"ply\n") or end < 0:
        raise FileFormatError(f"{path}: not a PLY file (no 'ply' ... 'end_header' header)")
    lines = [ln.strip() for ln in raw[:end].decode("ascii", "replace").splitlines()[1:]]
    lines = [ln for ln in lines if ln and not ln.startswith(("comment", "obj_info"))]
    unsupported = FileFormatError(f"{path}: read_ply reads binary little-endian vertex clouds as write_ply writes them")
    if not lines or lines[0] != "format binary_little_endian 1.0" or len(lines) < 2:
        raise unsupported
    m = re.fullmatch(r"element vertex (\d+)", lines[1])
    props = lines[2:]
    xyz = [f"property float {n}" for n, _ in _XYZ]
    rgb = [f"property uchar {n}" for n, _ in _RGB]
    if m is None or props not in (xyz, xyz + rgb):
        raise unsupported
    fields = _XYZ + (_RGB if props == xyz + rgb else [])
    n = int(m.group(1))
    data = raw[end + len(b"end_header\n"):]
    want = n * np.dtype(fields).itemsize
    if len(data) != want:
        raise FileFormatError(f"{path}: PLY body has {len(data)} bytes, {n} vertices need {want}")
    vertex = np.frombuffer(data, dtype=fields, count=n)
    points = np.stack([vertex[k] for k, _ in _XYZ], axis=1).astype(np.float32)
    colors = np.stack([vertex[k] for k, _ in _RGB], axis=1) if len(fields) > 3 else None
    return points, colors
