"""Sub-aperture layout and splitting a raw frame into its views.

A :class:`Layout` says where each view lies on the raw frame: one rectangle per view, all of the
same size, in the frame *after* the optional 180-degree rotation (the frame the views are
numbered in: for the ring 0 top-left, 1 top-right, 2 bottom-left, 3 bottom-right), plus an
optional valid disc per view. Any number of views from ``MIN_VIEWS`` to ``MAX_VIEWS`` is
accepted: :func:`grid_layout` tiles the views of a stereo pair or a grid of cameras.

Split with a calibration (:func:`split_views`, :func:`correct_views`), each view is also
corrected as the calibration says: its lens distortion undone by one remap (tables made once per
calibration) and its vignetting divided out by a flat field.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from lfring.core.lens import FlatField, remap_views, undistortion_maps
from lfring.core.protocols import Calibration
from lfring.core.validate import check_bool, check_choice, check_int, is_integer
from lfring.core.viewstack import all_finite, calibration_cache, check_unit_range
from lfring.errors import EstimationError, FileFormatError, InvalidInputError
from lfring.io.readers import LAYOUT_KEY

__all__ = ["Layout", "split_views", "correct_views", "flat_field_from_frame", "read_views", "layout_from_circles",
           "grid_layout", "detect_layout", "DETECT_KINDS", "MIN_VIEWS", "MAX_VIEWS"]

LAYOUT_VERSION = 1
# Views a layout (and so a calibration, refocusing and depth) may hold: two for any parallax,
# at most a 10 x 10 grid (the cost of a sweep and its memory grow with the count).
MIN_VIEWS = 2
MAX_VIEWS = 100


@dataclass(frozen=True, eq=False)
class Layout:
    """Where the views lie on the raw frame.

    Parameters
    ----------
    raw_width_px, raw_height_px : int
        Size of the raw frame the layout belongs to.
    rects : tuple of (x, y, w, h)
        One rectangle per view in pixels of the (rotated) raw frame, ``MIN_VIEWS`` to
        ``MAX_VIEWS`` of them; every view has the same w and h. Pixel (x, y) is the view's
        pixel (0, 0).
    rotate180 : bool
        Rotate the raw frame by 180 degrees before cutting (the ring's image is erect on the
        sensor, which many cameras then read out upside down).
    circles : tuple of (cx, cy, r) or None
        Valid disc of each view in view pixel coordinates (the image of the main-lens iris);
        None when the whole rectangle is valid.
    """

    raw_width_px: int
    raw_height_px: int
    rects: tuple[tuple[int, int, int, int], ...]
    rotate180: bool = False
    circles: tuple[tuple[float, float, float], ...] | None = None

    def __post_init__(self) -> None:
        for key in ("raw_width_px", "raw_height_px"):
            check_int(getattr(self, key), f"layout {key}", minimum=1)
        rects = tuple(tuple(int(x) for x in r) for r in self.rects)
        if not rects or any(len(r) != 4 for r in rects):
            raise InvalidInputError(f"layout rects must be a non-empty list of (x, y, w, h), got {self.rects!r}")
        if not MIN_VIEWS <= len(rects) <= MAX_VIEWS:
            raise InvalidInputError(
                f"a layout holds {MIN_VIEWS} to {MAX_VIEWS} views, got {len(rects)}; "
                + ("depth and refocusing need at least two viewpoints" if len(rects) < MIN_VIEWS
                   else "use a subset of the views (e.g. every other one of a dense grid)")
            )
        object.__setattr__(self, "rects", rects)
        sizes = {(r[2], r[3]) for r in rects}
        if len(sizes) != 1:
            raise InvalidInputError(f"all views must have the same size, got sizes {sorted(sizes)}")
        for k, (x, y, w, h) in enumerate(rects):
            if w < 1 or h < 1 or x < 0 or y < 0 or x + w > self.raw_width_px or y + h > self.raw_height_px:
                raise InvalidInputError(
                    f"view {k} rectangle (x={x}, y={y}, w={w}, h={h}) does not fit the "
                    f"{self.raw_width_px} x {self.raw_height_px} px frame"
                )
        if self.circles is not None:
            circles = tuple(tuple(float(v) for v in c) for c in self.circles)
            if len(circles) != len(rects) or any(len(c) != 3 or not c[2] > 0 for c in circles):
                raise InvalidInputError("layout circles must be one (cx, cy, r>0) per view")
            object.__setattr__(self, "circles", circles)
        object.__setattr__(self, "rotate180", check_bool(self.rotate180, "layout rotate180"))  # bool("false") is True

    @property
    def num_views(self) -> int:
        """Number of views V."""
        return len(self.rects)

    @property
    def view_shape(self) -> tuple[int, int]:
        """(h, w) of every view."""
        return self.rects[0][3], self.rects[0][2]

    @property
    def raw_shape(self) -> tuple[int, int]:
        """(h, w) of the raw frame."""
        return self.raw_height_px, self.raw_width_px

    def masks(self) -> np.ndarray:
        """(V, h, w) bool: pixels inside each view's valid disc (all True without circles)."""
        h, w = self.view_shape
        if self.circles is None:
            return np.ones((self.num_views, h, w), dtype=bool)
        yy, xx = np.mgrid[0:h, 0:w]
        return np.stack([(xx - cx) ** 2 + (yy - cy) ** 2 <= r * r for cx, cy, r in self.circles])

    def to_dict(self) -> dict:
        """The JSON form of the layout (what :meth:`save` writes and :meth:`from_dict` reads).

        Returns
        -------
        dict
        """
        return {
            LAYOUT_KEY: LAYOUT_VERSION,
            "raw_width_px": int(self.raw_width_px),
            "raw_height_px": int(self.raw_height_px),
            "rotate180": self.rotate180,
            "rects_xywh_px": [list(r) for r in self.rects],
            "circles_view_px": None if self.circles is None else [list(c) for c in self.circles],
        }

    @classmethod
    def from_dict(cls, data: dict, *, source: str = "layout") -> Layout:
        """Build a layout from its JSON form.

        Parameters
        ----------
        data : dict
            As made by :meth:`to_dict`.
        source : str
            Names the data in error messages (a file name).

        Returns
        -------
        Layout

        Raises
        ------
        FileFormatError
            A key is missing or malformed, or the version is not supported.
        """
        try:
            version = data[LAYOUT_KEY]
            if version != LAYOUT_VERSION:
                raise InvalidInputError(f"{source}: layout version {version!r} is not supported (expected {LAYOUT_VERSION})")
            return cls(
                raw_width_px=data["raw_width_px"],
                raw_height_px=data["raw_height_px"],
                rects=tuple(tuple(r) for r in data["rects_xywh_px"]),
                rotate180=data.get("rotate180", False),
                circles=None if data.get("circles_view_px") is None else tuple(tuple(c) for c in data["circles_view_px"]),
            )
        except (KeyError, TypeError) as exc:
            raise FileFormatError(f"{source}: not a valid lfring layout (missing or malformed {exc})") from None
        except InvalidInputError as exc:
            raise FileFormatError(f"{source}: {exc}") from None

    def save(self, path: str | Path) -> Path:
        """Write the layout as JSON, atomically.

        Parameters
        ----------
        path : str or Path

        Returns
        -------
        Path
            The file written.
        """
        from lfring.io.atomic import atomic_write_text

        return atomic_write_text(path, json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> Layout:
        """Read a layout written by :meth:`save`.

        Parameters
        ----------
        path : str or Path

        Returns
        -------
        Layout

        Raises
        ------
        LfringFileNotFoundError, FileFormatError
        """
        from lfring.io.readers import read_json_object

        return cls.from_dict(read_json_object(path, "layout"), source=str(path))


def split_views(image: np.ndarray, layout, *, flat=None) -> np.ndarray:
    """Cut the views out of a raw-frame image (and, given a calibration, undo its lenses).

    Parameters
    ----------
    image : ndarray, (H, W) or (H, W, C), floating
        The whole frame as it came from the camera (before rotation), e.g. the output of
        :func:`lfring.demosaic`.
    layout : Layout or RingCalibration
        Where the views lie. Given a calibration, its layout, and then each view is corrected as
        the calibration says (:func:`correct_views`): its lens distortion undone (one cached
        remap per view) and its vignetting divided out when the calibration carries a flat
        field, so that refocusing and depth see the views the calibration's homographies
        relate. Given a layout alone, the views are only cut.
    flat : FlatField or ndarray (H, W[, C]), optional
        A flat (white) frame's field, or the frame itself: the views are divided by it (instead
        of the calibration's own), which makes every view equally bright at every pixel.

    Returns
    -------
    ndarray, float32, (V, h, w, C)
        Views in layout order (C = 1 for a 2D input).

    Examples
    --------
    The bundled scene of the twin (data/synthetic, paths relative to the repository root) cut
    with the built-in calibration for its frame size:

    >>> import lfring
    >>> cal = lfring.RingCalibration.load("twin_binned2")
    >>> views = lfring.split_views(lfring.demosaic(lfring.load_raw("data/synthetic/scene.png")), cal)
    >>> views.shape, views.dtype, bool(views.min() >= 0.0 and views.max() <= 1.0)
    ((4, 705, 705, 3), dtype('float32'), True)
    """
    cal = layout if isinstance(layout, Calibration) else None
    lay = cal.layout if cal is not None else layout
    if not isinstance(lay, Layout):
        raise InvalidInputError(f"split_views needs a Layout or a RingCalibration, got {type(layout).__name__}")
    out = _cut(image, lay)
    if isinstance(flat, np.ndarray):
        flat = flat_field_from_frame(flat, lay if cal is None else cal)
    if flat is not None and not isinstance(flat, FlatField):
        raise InvalidInputError(f"flat must be a FlatField or a flat frame (H, W[, C]) image, got {type(flat).__name__}")
    if cal is not None:
        return correct_views(out, cal, flat_field=flat)
    return out if flat is None else flat.apply(out)


def _cut(image, layout: Layout, what: str = "image") -> np.ndarray:
    from lfring.io.raw import RawFrame

    if isinstance(image, RawFrame):
        raise InvalidInputError(f"split_views takes the {what} demosaicked, lfring.demosaic(frame): a RawFrame holds "
                                "raw counts")
    arr = np.asarray(image)
    if arr.ndim == 2:
        arr = arr[..., None]
    if arr.ndim != 3:
        raise InvalidInputError(f"split_views expects the {what} as an (H, W) or (H, W, C) array, got shape "
                                f"{np.shape(image)}")
    if not np.issubdtype(arr.dtype, np.floating):
        raise InvalidInputError(
            f"split_views expects the {what} floating in [0, 1], got {arr.dtype}; normalise raw counts with "
            "lfring.demosaic (explicit black and white levels) first"
        )
    if arr.shape[:2] != layout.raw_shape:
        raise InvalidInputError(
            f"the {what} is {arr.shape[1]} x {arr.shape[0]} px but the layout is for "
            f"{layout.raw_width_px} x {layout.raw_height_px} px frames"
        )
    if layout.rotate180:
        arr = arr[::-1, ::-1]
    h, w = layout.view_shape
    out = np.empty((layout.num_views, h, w, arr.shape[2]), dtype=np.float32)
    for k, (x, y, _, _) in enumerate(layout.rects):
        out[k] = arr[y : y + h, x : x + w]
    # Judged on the views: most of a ring frame is the dark between the discs, which counts
    # (0..255 given as float) leave below the rule's level too.
    check_unit_range(out, f"the {what}")
    return out


def correct_views(views, calibration, *, flat_field=None) -> np.ndarray:
    """Views cut with ``calibration``'s layout, corrected as the calibration says: each view's
    lens distortion undone (``calibration.distortion``: a bilinear remap per view, its tables
    made once per calibration and view shape), then divided by a flat field (``flat_field``, or
    the calibration's own; none: left as they are).

    Parameters
    ----------
    views : (V, h, w, C) float32
    calibration : RingCalibration
    flat_field : FlatField, optional

    Returns
    -------
    (V, h, w, C) float32
        A new array when anything was corrected, else ``views`` itself.
    """
    dist = calibration.distortion
    out = views
    if dist is not None:
        shape = tuple(int(n) for n in out.shape[1:3])
        maps = calibration_cache(calibration, ("undistortion maps", shape), lambda: _fixed_point_maps(dist, shape))
        out = np.empty_like(views)
        for k in range(len(views)):
            # The fixed-point tables are what cv2.remap makes of float maps at every call.
            res = cv2.remap(views[k], maps[k][0], maps[k][1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            out[k] = res.reshape(views[k].shape)
    flat = flat_field if flat_field is not None else calibration.flat_field
    if flat is not None:
        out = flat.apply(out)
    return out


def _fixed_point_maps(distortions, shape) -> list:
    mx, my = undistortion_maps(distortions, shape)
    return [cv2.convertMaps(mx[k], my[k], cv2.CV_16SC2) for k in range(len(mx))]


def flat_field_from_frame(image, layout) -> FlatField:
    """The :class:`~lfring.core.lens.FlatField` of a flat (uniformly lit white) frame: cut with
    ``layout`` (a Layout, or a calibration whose distortion is then undone, as the frames it
    will correct are), its luminance relative to its brightest level."""
    if isinstance(layout, Calibration):
        views = _cut(image, layout.layout, "flat frame")
        if layout.distortion is not None:
            shape = views.shape[1:3]
            mx, my = undistortion_maps(layout.distortion, shape)
            views = remap_views(views, mx, my)
    else:
        views = _cut(image, layout, "flat frame")
    if not all(all_finite(v) for v in views):  # a NaN spreads into every view it corrects, or reads as black
        raise InvalidInputError("the flat frame holds NaN or infinite values where the views are")
    return FlatField.from_views(views)


def read_views(paths) -> np.ndarray:
    """Read separate view images (a stereo pair, the views of a camera array) into one stack.

    Parameters
    ----------
    paths : sequence of str or Path
        ``MIN_VIEWS`` to ``MAX_VIEWS`` image files of one size, in view order: RGB PNG/TIFF
        (8 or 16 bits), or anything :func:`lfring.load_raw` reads (a Bayer file with its
        sidecar), each demosaiced with its own black and white levels.

    Returns
    -------
    ndarray, float32, (V, h, w, 3)
    """
    from lfring.io.demosaic import demosaic
    from lfring.io.raw import load_raw

    paths = [paths] if isinstance(paths, (str, Path)) else list(paths)
    if not MIN_VIEWS <= len(paths) <= MAX_VIEWS:
        raise InvalidInputError(f"give {MIN_VIEWS} to {MAX_VIEWS} view images, got {len(paths)}")
    views = [demosaic(load_raw(p)) for p in paths]
    shapes = {v.shape for v in views}
    if len(shapes) != 1:
        sizes = ", ".join(f"{p}: {v.shape[1]} x {v.shape[0]}" for p, v in zip(paths, views))
        raise InvalidInputError(f"the view images must all have one size, got {sizes}")
    first: dict[bytes, int] = {}  # one view twice: every depth would fit it, and none be told
    for j, v in enumerate(views):
        i = first.setdefault(hashlib.blake2b(np.ascontiguousarray(v).tobytes(), digest_size=16).digest(), j)
        if i != j:
            raise InvalidInputError(f"view images {i} and {j} ({paths[i]}, {paths[j]}) are the same image: give each "
                                    "view's own image")
    return np.stack(views).astype(np.float32, copy=False)


def layout_from_circles(
    circles_px, raw_width_px: int, raw_height_px: int, *, grid: tuple[int, int] = (2, 2), rotate180: bool = False
) -> Layout:
    """The layout around one valid disc per view.

    Parameters
    ----------
    circles_px : (V, 3) array_like
        (cx, cy, r) of each view's disc in raw pixels of the (rotated) frame, in view order
        (row-major over ``grid``).
    raw_width_px, raw_height_px : int
    grid : (rows, cols)
        How the views tile the frame; each view must stay inside its cell of an even split.

    Returns
    -------
    Layout
        Squares of one common side, the largest that is at most the smallest disc's diameter
        and keeps every square, centred on its disc, inside its cell.
    """
    circ = np.asarray(circles_px, dtype=np.float64)
    rows, cols = grid
    if circ.ndim != 2 or circ.shape[1] != 3 or circ.shape[0] != rows * cols:
        raise InvalidInputError(f"expected {rows * cols} circles (cx, cy, r), got shape {circ.shape}")
    xs = [int(round(j * raw_width_px / cols)) for j in range(cols + 1)]
    ys = [int(round(i * raw_height_px / rows)) for i in range(rows + 1)]
    side = int(np.floor(2 * circ[:, 2].min()))
    for k, (cx, cy, _) in enumerate(circ):
        i, j = divmod(k, cols)
        half = min(cx - xs[j] + 0.5, xs[j + 1] - 0.5 - cx, cy - ys[i] + 0.5, ys[i + 1] - 0.5 - cy)
        side = min(side, int(np.floor(2 * half)))
    if side < 8:
        raise InvalidInputError(f"the views would be smaller than 8 px ({side} px): discs {circ.round(1).tolist()}")
    rects, circles = [], []
    for cx, cy, r in circ:
        x0 = int(np.round(cx - (side - 1) / 2.0))
        y0 = int(np.round(cy - (side - 1) / 2.0))
        rects.append((x0, y0, side, side))
        circles.append((cx - x0, cy - y0, r))
    return Layout(raw_width_px, raw_height_px, tuple(rects), rotate180, tuple(circles))


def grid_layout(view_shape: tuple[int, int], grid_positions) -> Layout:
    """The layout of separate views tiled into one mosaic frame.

    Parameters
    ----------
    view_shape : (h, w)
        Size of every view in pixels.
    grid_positions : (V, 2) array_like
        (x, y) of each view on its grid in grid units, x to the right, y down, in view order;
        ``MIN_VIEWS`` to ``MAX_VIEWS`` distinct positions.

    Returns
    -------
    Layout
        Without discs (views valid everywhere). With integer positions every view is the cell
        of a mosaic at its grid position (a 3 x 3 grid gives a 3 x 3 mosaic); otherwise the
        views lie in one row in view order (also when the grid would have more than
        ``MAX_VIEWS`` cells).

    Examples
    --------
    >>> grid_layout((4, 6), [(0, 0), (1, 0), (0, 1)]).rects
    ((0, 0, 6, 4), (6, 0, 6, 4), (0, 4, 6, 4))
    """
    shape = tuple(view_shape) if isinstance(view_shape, (tuple, list)) else ()
    if len(shape) != 2 or any(not is_integer(v) or v < 1 for v in shape):
        raise InvalidInputError(f"view_shape must be (h, w), two positive integers, got {view_shape!r}")
    h, w = (int(v) for v in shape)
    try:
        pos = np.asarray(grid_positions, dtype=np.float64)
    except (TypeError, ValueError):
        pos = np.empty((0, 0))
    if pos.ndim != 2 or pos.shape[1] != 2 or not np.all(np.isfinite(pos)):
        raise InvalidInputError(f"grid_positions must be (V, 2) finite (x, y) grid positions, got shape {np.shape(grid_positions)}")
    if not MIN_VIEWS <= len(pos) <= MAX_VIEWS:
        raise InvalidInputError(f"a grid holds {MIN_VIEWS} to {MAX_VIEWS} views, got {len(pos)} positions")
    if len(np.unique(pos, axis=0)) != len(pos):
        raise InvalidInputError(f"grid positions must be distinct, got {pos.tolist()}")
    cell = np.round(pos - pos.min(axis=0)).astype(np.int64)
    cols, rows = (int(v) + 1 for v in cell.max(axis=0))
    if np.all(pos == np.round(pos)) and cols * rows <= MAX_VIEWS:
        rects = tuple((int(cx) * w, int(cy) * h, w, h) for cx, cy in cell)
    else:
        rects = tuple((k * w, 0, w, h) for k in range(len(pos)))
        cols, rows = len(pos), 1
    return Layout(cols * w, rows * h, rects)


DETECT_KINDS = ("auto", "flat", "scene")
# A frame detected as a flat has discs without texture: the RMS of the inner half of each disc,
# high-passed at a sixteenth of its radius, over its mean, stays below this (above a flat's
# noise and the residue of its lenses' vignetting, far below any scene's or target's texture).
FLAT_DISC_TEXTURE = 0.05


def detect_layout(
    image: np.ndarray, *, kind: str = "auto", rotate180: bool = False, grid: tuple[int, int] = (2, 2),
    name: str | None = None,
) -> Layout:
    """Find the views on a raw frame: each mini-lens lights a disc (the image of the main-lens
    iris), dark around it.

    Parameters
    ----------
    image : ndarray, (H, W) or (H, W, C)
        A flat (white) frame, or an ordinary frame when no flat exists; raw counts or
        demosaiced values. A Bayer mosaic can be given as it is: the detector smooths well
        beyond the 2 x 2 pattern.
    kind : {'auto', 'flat', 'scene'}
        'flat' works on the smoothed brightness; 'scene' on its envelope (a morphological
        closing), so that the scene's own dark parts do not look like the disc's edge; 'auto'
        picks 'flat' when the discs are nearly uniform.
    rotate180 : bool
        The camera outputs the frame rotated; detection runs on the frame rotated back, and the
        layout records it.
    grid : (rows, cols)
        How the views tile the frame (2 x 2 for the ring).
    name : str, optional
        What the caller calls the image (a file, an option and its file): a refusal starts
        with it, since its own words speak only of "the frame".

    Returns
    -------
    Layout
        With the fitted disc of each view as its valid region.

    Notes
    -----
    Rough discs come from thresholding the smoothed frame. Each disc is then refined along 360
    rays from its rough centre: the brightness profile's interior (0.3 to 0.75 of the radius)
    is fitted by ``a + b r^2`` (the cos^4 fall-off), the edge is where the profile drops below
    half that fit extrapolated, and a circle is fitted to the edge points by least squares with
    outlier rejection. On a flat frame of the twin this finds the half-light disc within 0.2 px.
    An ordinary frame is smoothed first (its local mean) and the four discs are fitted jointly
    (one radius, symmetric centres); the scene's content near the edges still biases the
    result, by about 2 px on textured targets and up to about 20 px on scenes with large
    uniform areas at the edges. Use a flat frame, or the optics' layout, when it matters.

    Examples
    --------
    On the twin's flat frame (data/synthetic, paths relative to the repository root), against
    the layout it was rendered with (its ground truth):

    >>> import numpy as np
    >>> import lfring
    >>> layout = lfring.detect_layout(lfring.demosaic(lfring.load_raw("data/synthetic/flat.png")))
    >>> layout.num_views, layout.view_shape
    (4, (705, 705))
    >>> from lfring.views import Layout
    >>> truth = Layout.load("data/synthetic/flat_truth/layout.json")
    >>> def discs(lay):  # centre x, y in raw-frame pixels and radius of every view's disc
    ...     return np.array([(x + cx, y + cy, r) for (x, y, _, _), (cx, cy, r) in zip(lay.rects, lay.circles)])
    >>> float(np.abs(discs(layout) - discs(truth)).max()) < 0.2
    True
    """
    check_choice(kind, "kind", DETECT_KINDS)
    if not isinstance(grid, (tuple, list, np.ndarray)) or len(grid) != 2 or not all(is_integer(n) and n >= 1 for n in grid):
        raise InvalidInputError(f"grid must be (rows, cols) of views, two integers >= 1, got {grid!r}")
    grid = (int(grid[0]), int(grid[1]))
    try:
        return _detect_layout(image, kind, rotate180, grid)
    except (InvalidInputError, EstimationError) as exc:
        if name is None:
            raise
        raise type(exc)(f"{name}: {exc}") from None


def _detect_layout(image, kind: str, rotate180: bool, grid: tuple[int, int]) -> Layout:
    """:func:`detect_layout` without the name of the image in its refusals."""
    from lfring.io.raw import RawFrame

    if isinstance(image, RawFrame):
        raise InvalidInputError("detect_layout takes the frame's image: lfring.demosaic(frame), or its Bayer mosaic "
                                "frame.mosaic as it is")
    if isinstance(image, (str, Path)):
        raise InvalidInputError(f"detect_layout takes the frame's image, not a path: "
                                f"lfring.demosaic(lfring.load_raw({str(image)!r}))")
    arr = np.asarray(image)
    if arr.ndim == 3:
        arr = arr.mean(axis=2)
    if arr.ndim != 2:
        raise InvalidInputError(f"the frame must be an image, (H, W) or (H, W, C), got an array of shape {np.shape(image)}")
    if min(arr.shape) < 16:
        raise InvalidInputError(f"the frame is {arr.shape[1]} x {arr.shape[0]} px, too small to find views on (at least "
                                "16 px each way)")
    lum = arr.astype(np.float32)
    if not np.all(np.isfinite(lum)):
        raise InvalidInputError("the frame contains NaN or infinite values")
    if rotate180:
        lum = lum[::-1, ::-1]
    h, w = lum.shape
    lo, hi = np.percentile(lum, [1.0, 99.5])
    if not hi > lo:
        raise EstimationError("the frame is uniform (all black or constant); no views to find")
    lum = (lum - lo) / (hi - lo)
    fine = cv2.GaussianBlur(lum, (0, 0), 2.0)  # kills the Bayer pattern and pixel noise
    sigma = max(4.0, min(h, w) / 200.0)
    if kind != "flat":
        envelope = _envelope(fine)
    # Rough discs on a 4x decimated copy: only their approximate centre and size are needed.
    small = cv2.resize(fine if kind == "flat" else envelope, (w // 4, h // 4), interpolation=cv2.INTER_AREA)
    blobs = [(4 * x + 1.5, 4 * y + 1.5, 4 * r) for x, y, r in _rough_discs(cv2.GaussianBlur(small, (0, 0), sigma / 4), grid)]
    if kind == "auto":
        kind = "flat" if _uniform_inside(fine, blobs) else "scene"
    elif kind == "flat" and _disc_texture(fine, blobs) > FLAT_DISC_TEXTURE:
        raise InvalidInputError("the frame is not a flat field: the inner half of its discs of light "
                                "shows texture (a scene or a target?)")
    base = fine if kind == "flat" else envelope
    circles = [_refine_disc(base, cx, cy, r) for cx, cy, r in blobs]
    if kind == "scene" and grid == (2, 2):
        # Content near the edge biases single discs; the ring's four discs share one radius and
        # sit symmetrically, so fit them jointly (5 parameters instead of 12).
        points = [_edge_points(base, cx, cy, r) for cx, cy, r in circles]
        circles = _fit_ring(points, circles)
    _check_discs(circles, w, h, grid)
    return layout_from_circles(circles, w, h, grid=grid, rotate180=rotate180)


def _check_discs(circles, w: int, h: int, grid: tuple[int, int]) -> None:
    """Refuse detections that do not look like one disc per cell of similar size."""
    rows, cols = grid
    radii = np.array([c[2] for c in circles])
    problems = []
    for k, (cx, cy, r) in enumerate(circles):
        i, j = divmod(k, cols)
        if not (j * w / cols <= cx < (j + 1) * w / cols and i * h / rows <= cy < (i + 1) * h / rows):
            problems.append(f"view {k}'s centre ({cx:.0f}, {cy:.0f}) is outside its cell of the frame")
        if not r >= 8:
            problems.append(f"view {k}'s disc is only {r:.1f} px in radius")
    if radii.min() < 0.8 * radii.max():
        problems.append(f"the discs' radii differ too much ({radii.min():.0f} to {radii.max():.0f} px)")
    if problems:
        raise EstimationError("the bright regions do not look like the ring's views: " + "; ".join(problems))


_ENVELOPE_FRACTION = 80
# A bright region is taken for a view (for the count of views against the grid) when it is at
# least this share of the smallest view's area, its box within DISC_ALIKE_ASPECT of square, and
# it fills between DISC_ALIKE_FILL of its box (a disc fills pi / 4 of it).
DISC_ALIKE_AREA = 0.7
DISC_ALIKE_ASPECT = 1.25
DISC_ALIKE_FILL = (0.65, 0.9)


def _disc_like(stat) -> bool:
    """Whether a connected region (its row of ``cv2.connectedComponentsWithStats``) is round and
    filled as a view's disc is."""
    bw, bh, area = int(stat[cv2.CC_STAT_WIDTH]), int(stat[cv2.CC_STAT_HEIGHT]), int(stat[cv2.CC_STAT_AREA])
    fill = area / max(bw * bh, 1)
    return max(bw, bh) <= DISC_ALIKE_ASPECT * min(bw, bh) and DISC_ALIKE_FILL[0] <= fill <= DISC_ALIKE_FILL[1]


def _envelope(fine: np.ndarray) -> np.ndarray:
    """Local mean brightness of a scene frame (Gaussian, sigma = 1/_ENVELOPE_FRACTION of the
    frame's short side, on a 4x decimated copy for speed). The disc's soft edge is nearly
    antisymmetric about its half-light point, so smoothing keeps that point where it is, while
    the scene's texture averages out; a closing (local maximum) would instead follow the
    nearest bright details and pull the edge inwards."""
    h, w = fine.shape
    small = cv2.resize(fine, (w // 4, h // 4), interpolation=cv2.INTER_AREA)
    small = cv2.GaussianBlur(small, (0, 0), min(h, w) / (4.0 * _ENVELOPE_FRACTION))
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)


def _rough_discs(coarse: np.ndarray, grid: tuple[int, int]) -> list[tuple[float, float, float]]:
    n = grid[0] * grid[1]
    u8 = np.clip(coarse * 255, 0, 255).astype(np.uint8)
    thr, mask = cv2.threshold(u8, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    k = max(3, int(min(coarse.shape) / 100) | 1)
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
    count, labels, stats, cents = cv2.connectedComponentsWithStats(mask, connectivity=8)
    order = np.argsort(stats[1:, cv2.CC_STAT_AREA])[::-1] + 1
    min_area = coarse.size / (n * 40.0)
    found = [i for i in order[:n] if stats[i, cv2.CC_STAT_AREA] >= min_area]
    if len(found) < n:
        raise EstimationError(
            f"found {len(found)} bright region(s) where {n} views were expected; is this a "
            "frame of the ring camera (a flat frame shows one bright disc per view on a dark surround)?"
        )
    # The views' discs are alike: more round regions of a kept one's size than the grid holds are
    # views the grid leaves out (stray light along an edge is neither round nor filled as a disc).
    least = stats[found[-1], cv2.CC_STAT_AREA]
    alike = sum(1 for i in order if stats[i, cv2.CC_STAT_AREA] >= DISC_ALIKE_AREA * least and _disc_like(stats[i]))
    if alike > n:
        raise EstimationError(f"found {alike} bright regions of a view's size where the grid {grid[0]} x {grid[1]} "
                              f"holds {n} views: give the grid of the frame's views")
    blobs = []
    for i in found:
        comp = (labels == i).astype(np.uint8)
        # Fill holes (dark scene content inside a view) with the component's convex hull.
        contours, _ = cv2.findContours(comp, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        hull = cv2.convexHull(np.vstack(contours))
        area = cv2.contourArea(hull)
        m = cv2.moments(hull)
        blobs.append((m["m10"] / m["m00"], m["m01"] / m["m00"], float(np.sqrt(area / np.pi))))
    rows, cols = grid
    blobs.sort(key=lambda b: b[1])
    ordered = []
    for r in range(rows):
        ordered.extend(sorted(blobs[r * cols : (r + 1) * cols], key=lambda b: b[0]))
    return ordered


def _uniform_inside(fine: np.ndarray, blobs) -> bool:
    """True when the inner half of every disc is smooth, as in a flat frame."""
    for cx, cy, r in blobs:
        y0, y1 = int(cy - r / 2), int(cy + r / 2)
        x0, x1 = int(cx - r / 2), int(cx + r / 2)
        patch = fine[max(0, y0) : y1, max(0, x0) : x1]
        if patch.size == 0 or patch.std() > 0.08 * max(float(patch.mean()), 1e-6):
            return False
    return True


def _disc_texture(fine: np.ndarray, blobs) -> float:
    """The largest, over the discs, RMS of the inner half of a disc high-passed at a sixteenth
    of its radius, over its mean (see :data:`FLAT_DISC_TEXTURE`)."""
    worst = 0.0
    for cx, cy, r in blobs:
        patch = fine[max(0, int(cy - r / 2)):max(0, int(cy + r / 2)), max(0, int(cx - r / 2)):max(0, int(cx + r / 2))]
        if patch.size == 0:
            return float("inf")
        hp = patch - cv2.GaussianBlur(patch, (0, 0), max(2.0, r / 16))
        worst = max(worst, float(hp.std()) / max(float(patch.mean()), 1e-6))
    return worst


def _edge_points(fine: np.ndarray, cx: float, cy: float, r0: float) -> np.ndarray:
    """(N, 2) points where the brightness along 360 rays from (cx, cy) falls to half its
    interior level, fitted as a + b r^2 over 0.3..0.75 r0 (the cos^4 fall-off) and extrapolated."""
    angles = np.linspace(0, 2 * np.pi, 360, endpoint=False)
    if not 0 < r0 < max(fine.shape):
        raise EstimationError(f"could not find the edge of a view's disc (a bright region {r0:.0f} px "
                              "in radius, not a disc within the frame)")
    radii = np.arange(0.2 * r0, 1.5 * r0, 0.25, dtype=np.float64)
    mx = (cx + np.cos(angles)[:, None] * radii[None, :]).astype(np.float32)
    my = (cy + np.sin(angles)[:, None] * radii[None, :]).astype(np.float32)
    prof = cv2.remap(fine, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    inner = (radii >= 0.3 * r0) & (radii <= 0.75 * r0)
    x = radii[inner] ** 2
    # One design matrix for every ray: its pseudo-inverse solves all 360 fits at once.
    coef = np.linalg.pinv(np.stack([np.ones_like(x), x], axis=1)) @ prof[:, inner].T
    lev = coef[0][:, None] + coef[1][:, None] * radii[None, :] ** 2
    below = (prof < 0.5 * lev) & (radii[None, :] > 0.75 * r0)
    pts = []
    for a in range(len(angles)):
        idx = np.flatnonzero(below[a])
        if idx.size == 0 or idx[0] == 0:
            continue
        i = idx[0]
        p0 = prof[a, i - 1] - 0.5 * lev[a, i - 1]
        p1 = prof[a, i] - 0.5 * lev[a, i]
        t = p0 / (p0 - p1) if p0 != p1 else 0.0
        rr = radii[i - 1] + t * (radii[i] - radii[i - 1])
        pts.append((cx + np.cos(angles[a]) * rr, cy + np.sin(angles[a]) * rr))
    if len(pts) < 36:
        raise EstimationError("could not find the edge of a view's disc (too few edge points)")
    return np.asarray(pts)


def _refine_disc(fine: np.ndarray, cx: float, cy: float, r0: float) -> tuple[float, float, float]:
    for _ in range(2):  # a second pass from the refined centre
        cx, cy, r0 = _fit_circle(_edge_points(fine, cx, cy, r0))
    return float(cx), float(cy), float(r0)


def _fit_ring(points: list[np.ndarray], init) -> list[tuple[float, float, float]]:
    """Joint fit of four discs of one radius with centres (X0 +- DX, Y0 +- DY), by Gauss-Newton
    on the distances, rejecting points beyond 3 robust sigmas."""
    init = np.asarray(init, dtype=np.float64)
    sx = np.array([-1.0, 1.0, -1.0, 1.0])
    sy = np.array([-1.0, -1.0, 1.0, 1.0])
    p = np.array([init[:, 0].mean(), init[:, 1].mean(), np.mean(np.abs(init[:, 0] - init[:, 0].mean())),
                  np.mean(np.abs(init[:, 1] - init[:, 1].mean())), np.median(init[:, 2])])
    pts = np.vstack(points)
    k = np.concatenate([np.full(len(q), i) for i, q in enumerate(points)])
    keep = np.ones(len(pts), dtype=bool)
    for _ in range(30):
        cx = p[0] + sx[k] * p[2]
        cy = p[1] + sy[k] * p[3]
        dx, dy = pts[:, 0] - cx, pts[:, 1] - cy
        dist = np.hypot(dx, dy)
        res = dist - p[4]
        mad = np.median(np.abs(res[keep] - np.median(res[keep]))) * 1.4826 + 1e-3
        keep = np.abs(res - np.median(res[keep])) < 3 * mad
        ux, uy = -dx / dist, -dy / dist
        jac = np.stack([ux, uy, ux * sx[k], uy * sy[k], -np.ones_like(ux)], axis=1)
        step, *_ = np.linalg.lstsq(jac[keep], -res[keep], rcond=None)
        p += step
        if np.abs(step).max() < 1e-4:
            break
    return [(p[0] + sx[i] * p[2], p[1] + sy[i] * p[3], p[4]) for i in range(4)]


def _fit_circle(pts: np.ndarray) -> tuple[float, float, float]:
    """Least-squares (Kasa) circle with iterative rejection of points beyond 3 robust sigmas."""
    keep = np.ones(len(pts), dtype=bool)
    for _ in range(5):
        x, y = pts[keep, 0], pts[keep, 1]
        a = np.stack([x, y, np.ones_like(x)], axis=1)
        sol, *_ = np.linalg.lstsq(a, x * x + y * y, rcond=None)
        cx, cy = sol[0] / 2, sol[1] / 2
        r = np.sqrt(sol[2] + cx * cx + cy * cy)
        res = np.hypot(pts[:, 0] - cx, pts[:, 1] - cy) - r
        mad = np.median(np.abs(res[keep] - np.median(res[keep]))) * 1.4826 + 1e-3
        new = np.abs(res) < 3 * mad
        if new.sum() < 36 or np.array_equal(new, keep):
            break
        keep = new
    return cx, cy, r
