"""Writers for images, float maps and JSON, all atomic (a killed run leaves no partial file)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import tifffile

from lfring.errors import FileFormatError, InvalidInputError
from lfring.io.atomic import atomic_path, atomic_write_text

__all__ = ["IMAGE_SUFFIXES", "check_writable", "encode_image", "write_float_tiff", "write_image", "write_json"]

IMAGE_SUFFIXES = (".png", ".tif", ".tiff")


def check_writable(paths, *, overwrite: bool) -> None:
    """Refuse, before anything is written, to replace existing files unless ``overwrite``."""
    existing = [str(p) for p in paths if Path(p).exists()]
    if existing and not overwrite:
        more = f" (and {len(existing) - 1} more)" if len(existing) > 1 else ""
        raise InvalidInputError(f"{existing[0]}{more} exists; pass --overwrite (overwrite=True) to replace")


def encode_image(image: np.ndarray, bit_depth: int = 8, encoding: str = "srgb") -> np.ndarray:
    """Linear-light float image in [0, 1] -> uint8/uint16 samples, sRGB-encoded or linear.

    (H, W, 1) images come back as (H, W).

    Examples
    --------
    >>> encode_image(np.array([[[0.0], [0.5], [1.0]]], np.float32)).tolist()
    [[0, 188, 255]]
    >>> encode_image(np.array([[[0.5]]], np.float32), 16, "linear").tolist()
    [[32768]]
    """
    if bit_depth not in (8, 16):
        raise InvalidInputError(f"bit depth must be 8 or 16, got {bit_depth!r}")
    if encoding not in ("srgb", "linear"):
        raise InvalidInputError(f"encoding must be 'srgb' or 'linear', got {encoding!r}")
    x = np.clip(image, 0.0, 1.0)
    if encoding == "srgb":
        x = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    top = 255 if bit_depth == 8 else 65535
    out = np.rint(x * top).astype(np.uint8 if bit_depth == 8 else np.uint16)
    return out[..., 0] if out.ndim == 3 and out.shape[-1] == 1 else out


def write_image(path: str | Path, image: np.ndarray, *, png_compression: int = 1) -> Path:
    """Write a uint8/uint16 image, (H, W) or (H, W, 3) RGB, as PNG or TIFF by suffix.

    ``png_compression`` is zlib's level 0-9: 1 (OpenCV's default) is fast; 3 makes noisy raw
    frames about 3.5 % smaller for about twice the time."""
    path = Path(path)
    arr = np.asarray(image)
    if arr.dtype not in (np.uint8, np.uint16):
        raise InvalidInputError(f"write_image takes uint8 or uint16 images, got {arr.dtype}")
    if not (arr.ndim == 2 or (arr.ndim == 3 and arr.shape[2] == 3)):
        raise InvalidInputError(f"write_image takes (H, W) or (H, W, 3) images, got shape {arr.shape}")
    suffix = path.suffix.lower()
    if suffix not in IMAGE_SUFFIXES:
        raise InvalidInputError(f"image files end in {', '.join(IMAGE_SUFFIXES)}, got {path.name!r}")
    with atomic_path(path) as tmp:
        if suffix == ".png":
            out = arr if arr.ndim == 2 else cv2.cvtColor(arr, cv2.COLOR_RGB2BGR)
            if not cv2.imwrite(str(tmp), out, [cv2.IMWRITE_PNG_COMPRESSION, int(png_compression)]):
                raise FileFormatError(f"could not write PNG {path}")
        else:
            tifffile.imwrite(tmp, arr, photometric="rgb" if arr.ndim == 3 else "minisblack")
    return path


def write_float_tiff(path: str | Path, data: np.ndarray) -> Path:
    """Write a float32 map (metres, confidence...) as a single-page TIFF."""
    with atomic_path(path) as tmp:
        tifffile.imwrite(tmp, np.asarray(data, dtype=np.float32), photometric="minisblack", compression="zlib")
    return Path(path)


def json_default(o):
    """``default=`` for :func:`json.dumps`: NumPy arrays and scalars, and paths."""
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"cannot write {type(o).__name__} to JSON")


def write_json(path: str | Path, obj) -> Path:
    """Write ``obj`` as indented JSON (NumPy arrays and scalars converted)."""
    return atomic_write_text(path, json.dumps(obj, indent=2, default=json_default, allow_nan=True) + "\n")
