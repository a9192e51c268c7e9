"""Writers for images, float maps and JSON, all atomic (a killed run leaves no partial file)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import numpy as np
import tifffile

from lfring.core.validate import check_choice
from lfring.errors import FileFormatError, InvalidInputError
from lfring.io.atomic import atomic_path, atomic_write_bytes, atomic_write_text, refuse_folder

__all__ = [
    "IMAGE_SUFFIXES", "check_output_folder", "check_writable", "encode_file", "encode_float_tiff", "encode_image", "write_float_tiff", "write_gif",
    "write_image", "write_json", "write_tiff_stack",
]

IMAGE_SUFFIXES = (".png", ".tif", ".tiff")


def check_output_folder(folder: str | Path) -> Path:
    """``folder`` as a Path, if it is a folder or can be made one (its first existing ancestor is
    a writable folder), else a clear error naming what is in the way."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise InvalidInputError(f"cannot write into {folder}: it is a file, not a folder")
    why = _unwritable_below(folder)
    if why:
        raise InvalidInputError(f"cannot {'write into' if folder.exists() else 'make the folder'} {folder}: {why}")
    return folder


def _unwritable_below(path: Path) -> str:
    """Why nothing can be written at ``path`` (its nearest existing ancestor, ``path`` itself if
    it exists, is a file or a folder that is not writable), or ''."""
    parent = path
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        return f"{parent} is a file, not a folder"
    if not os.access(parent, os.W_OK | os.X_OK):
        return f"the folder {parent} is not writable"
    return ""


def check_writable(paths, *, overwrite: bool) -> None:
    """Refuse, before anything is written, outputs that cannot be written: a file that exists
    (unless ``overwrite``), a path whose parent is a file, a folder that is not writable.

    Raises
    ------
    InvalidInputError
        Naming the first path that fails and why.
    """
    paths = [Path(p) for p in paths]
    for p in paths:
        refuse_folder(p)
        why = _unwritable_below(p.parent)
        if why:
            raise InvalidInputError(f"cannot write {p}: {why}")
    existing = [str(p) for p in paths if p.exists()]
    if existing and not overwrite:
        more = f" (and {len(existing) - 1} more)" if len(existing) > 1 else ""
        raise InvalidInputError(f"{existing[0]}{more} exists; pass overwrite=True to replace it")


def encode_image(image: np.ndarray, bit_depth: int = 8, encoding: str = "srgb") -> np.ndarray:
    """Linear-light float image in [0, 1] -> uint8/uint16 samples, sRGB-encoded or linear.

    (H, W, 1) images come back as (H, W).

    Examples
    --------
    >>> import numpy as np
    >>> from lfring.io.writers import encode_image
    >>> encode_image(np.array([[[0.0], [0.5], [1.0]]], np.float32)).tolist()
    [[0, 188, 255]]
    >>> encode_image(np.array([[[0.5]]], np.float32), 16, "linear").tolist()
    [[32768]]
    """
    check_choice(bit_depth, "bit depth", (8, 16))
    check_choice(encoding, "encoding", ("srgb", "linear"))
    x = np.clip(image, 0.0, 1.0)
    if encoding == "srgb":
        x = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    top = 255 if bit_depth == 8 else 65535
    out = np.rint(x * top).astype(np.uint8 if bit_depth == 8 else np.uint16)
    return out[..., 0] if out.ndim == 3 and out.shape[-1] == 1 else out


def write_image(path: str | Path, image: np.ndarray, *, png_compression: int = 1) -> Path:
    """Write a uint8/uint16 image, (H, W) or (H, W, 3) RGB, as PNG or TIFF by suffix.

    ``png_compression`` is zlib's level 0-9: 1 (OpenCV's default) is fast; 3 makes noisy raw
    frames slightly smaller and takes markedly longer."""
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


def write_float_tiff(path: str | Path, data: np.ndarray, *, metadata: dict | None = None) -> Path:
    """Write a float32 map (metres, confidence...) as a single-page TIFF; ``metadata`` (what the
    values are, their unit) goes into its ImageDescription as JSON, beside the shape, so that
    the file says what it holds without its sidecar."""
    with atomic_path(path) as tmp:
        tifffile.imwrite(tmp, np.asarray(data, dtype=np.float32), photometric="minisblack", compression="zlib",
                         metadata=metadata or {})
    return Path(path)


def json_default(o):
    """``default=`` for :func:`json.dumps`: NumPy arrays and scalars, and paths."""
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):  # a NumPy scalar: its Python twin
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"cannot write {type(o).__name__} to JSON")


def write_json(path: str | Path, obj) -> Path:
    """Write ``obj`` as indented JSON (NumPy arrays and scalars converted)."""
    return atomic_write_text(path, json.dumps(obj, indent=2, default=json_default, allow_nan=True) + "\n")


def write_tiff_stack(path: str | Path, frames: np.ndarray, *, metadata: dict | None = None) -> Path:
    """Write (N, H, W) or (N, H, W, 3) uint8/uint16 frames as one multi-page TIFF, atomically.

    ``metadata`` (JSON-ready values, e.g. ``{"depths_m": [...]}``) goes into the TIFF's
    ImageDescription, as tifffile writes it.
    """
    arr = np.asarray(frames)
    if arr.dtype not in (np.uint8, np.uint16):
        raise InvalidInputError(f"write_tiff_stack takes uint8 or uint16 frames, got {arr.dtype}")
    if not (arr.ndim == 3 or (arr.ndim == 4 and arr.shape[3] == 3)) or arr.shape[0] < 1:
        raise InvalidInputError(f"write_tiff_stack takes (N, H, W) or (N, H, W, 3) frames, got shape {arr.shape}")
    with atomic_path(path) as tmp:
        tifffile.imwrite(tmp, arr, photometric="rgb" if arr.ndim == 4 else "minisblack", metadata=metadata or {})
    return Path(path)


def write_gif(path: str | Path, frames: np.ndarray, *, frame_ms: int = 250, loop: int = 0) -> Path:
    """Write (N, H, W) or (N, H, W, 3) uint8 frames as an animated GIF (``loop=0``: forever),
    atomically.

    The GIF is encoded in memory first and written in one step, so an interrupt during the
    encoding leaves no file and no writer behind that would try to finish it later.
    """
    import io

    from PIL import Image

    arr = np.asarray(frames)
    if arr.dtype != np.uint8:
        raise InvalidInputError(f"write_gif takes uint8 frames (GIF has 8 bits per sample), got {arr.dtype}")
    if not (arr.ndim == 3 or (arr.ndim == 4 and arr.shape[3] == 3)) or arr.shape[0] < 1:
        raise InvalidInputError(f"write_gif takes (N, H, W) or (N, H, W, 3) frames, got shape {arr.shape}")
    images = [Image.fromarray(frame) for frame in arr]
    bio = io.BytesIO()
    images[0].save(bio, format="GIF", save_all=True, append_images=images[1:], duration=int(frame_ms), loop=int(loop))
    return atomic_write_bytes(path, bio.getvalue())


def encode_file(image: np.ndarray, suffix: str, *, png_compression: int = 1) -> bytes:
    """A uint8/uint16 image, (H, W) or (H, W, 3) RGB, encoded in memory as PNG or TIFF (by
    ``suffix``): the bytes :func:`write_image` would write."""
    import io

    arr = np.asarray(image)
    if arr.dtype not in (np.uint8, np.uint16):
        raise InvalidInputError(f"encode_file takes uint8 or uint16 images, got {arr.dtype}")
    if not (arr.ndim == 2 or (arr.ndim == 3 and arr.shape[2] == 3)):
        raise InvalidInputError(f"encode_file takes (H, W) or (H, W, 3) images, got shape {arr.shape}")
    suffix = suffix.lower()
    if suffix == ".png":
        out = arr if arr.ndim == 2 else cv2.cvtColor(arr, cv2.COLOR_RGB2BGR)
        ok, buf = cv2.imencode(".png", out, [cv2.IMWRITE_PNG_COMPRESSION, int(png_compression)])
        if not ok:
            raise FileFormatError("could not encode a PNG")
        return buf.tobytes()
    if suffix in (".tif", ".tiff"):
        bio = io.BytesIO()
        tifffile.imwrite(bio, arr, photometric="rgb" if arr.ndim == 3 else "minisblack")
        return bio.getvalue()
    raise InvalidInputError(f"images are encoded as {', '.join(IMAGE_SUFFIXES)}, got {suffix!r}")


def encode_float_tiff(data: np.ndarray) -> bytes:
    """A float32 map encoded in memory as :func:`write_float_tiff` writes it."""
    import io

    bio = io.BytesIO()
    tifffile.imwrite(bio, np.asarray(data, dtype=np.float32), photometric="minisblack", compression="zlib")
    return bio.getvalue()
