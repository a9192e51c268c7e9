"""Sub-aperture layout and splitting a raw frame into its views.

A :class:`Layout` says where each view lies on the raw frame: one rectangle per view, all of the
same size, in the frame *after* the optional 180-degree rotation (the frame the views are
numbered in: 0 top-left, 1 top-right, 2 bottom-left, 3 bottom-right), plus an optional valid
disc per view.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lfring.errors import FileFormatError, InvalidInputError, LfringFileNotFoundError

__all__ = ["Layout", "split_views"]

LAYOUT_VERSION = 1


@dataclass(frozen=True, eq=False)
class Layout:
    """Where the views lie on the raw frame.

    Parameters
    ----------
    raw_width_px, raw_height_px : int
        Size of the raw frame the layout belongs to.
    rects : tuple of (x, y, w, h)
        One rectangle per view in pixels of the (rotated) raw frame; every view has the same
        w and h. Pixel (x, y) is the view's pixel (0, 0).
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
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise InvalidInputError(f"layout {key} must be a positive integer, got {v!r}")
        rects = tuple(tuple(int(x) for x in r) for r in self.rects)
        if not rects or any(len(r) != 4 for r in rects):
            raise InvalidInputError(f"layout rects must be a non-empty list of (x, y, w, h), got {self.rects!r}")
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
        object.__setattr__(self, "rotate180", bool(self.rotate180))

    @property
    def num_views(self) -> int:
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
        return {
            "lfring_layout_version": LAYOUT_VERSION,
            "raw_width_px": int(self.raw_width_px),
            "raw_height_px": int(self.raw_height_px),
            "rotate180": self.rotate180,
            "rects_xywh_px": [list(r) for r in self.rects],
            "circles_view_px": None if self.circles is None else [list(c) for c in self.circles],
        }

    @classmethod
    def from_dict(cls, data: dict, *, source: str = "layout") -> Layout:
        try:
            version = data["lfring_layout_version"]
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
        from lfring.io.atomic import atomic_write_text

        return atomic_write_text(path, json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | Path) -> Layout:
        path = Path(path)
        if not path.is_file():
            raise LfringFileNotFoundError(f"layout file not found: {path}")
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise FileFormatError(f"{path}: not a JSON layout file ({exc})") from None
        if not isinstance(data, dict):
            raise FileFormatError(f"{path}: not a JSON layout object")
        return cls.from_dict(data, source=str(path))


def split_views(image: np.ndarray, layout: Layout) -> np.ndarray:
    """Cut the views out of a raw-frame image.

    Parameters
    ----------
    image : ndarray, (H, W) or (H, W, C), floating
        The whole frame as it came from the camera (before rotation), e.g. the output of
        :func:`lfring.demosaic`.
    layout : Layout

    Returns
    -------
    ndarray, float32, (V, h, w, C)
        Views in layout order (C = 1 for a 2D input).
    """
    arr = np.asarray(image)
    if arr.ndim == 2:
        arr = arr[..., None]
    if arr.ndim != 3:
        raise InvalidInputError(f"split_views expects an (H, W) or (H, W, C) image, got shape {np.shape(image)}")
    if not np.issubdtype(arr.dtype, np.floating):
        raise InvalidInputError(
            f"split_views expects a floating image in [0, 1], got {arr.dtype}; normalise raw counts with "
            "lfring.demosaic (explicit black and white levels) first"
        )
    if arr.shape[:2] != layout.raw_shape:
        raise InvalidInputError(
            f"image is {arr.shape[1]} x {arr.shape[0]} px but the layout is for "
            f"{layout.raw_width_px} x {layout.raw_height_px} px frames"
        )
    if layout.rotate180:
        arr = arr[::-1, ::-1]
    h, w = layout.view_shape
    out = np.empty((layout.num_views, h, w, arr.shape[2]), dtype=np.float32)
    for k, (x, y, _, _) in enumerate(layout.rects):
        out[k] = arr[y : y + h, x : x + w]
    return out
