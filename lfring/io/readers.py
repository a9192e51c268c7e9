"""Reading small JSON documents (calibrations, layouts) with errors that name the file, and
telling an image file and a frame's size by its first bytes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from lfring.errors import FileFormatError, LfringFileNotFoundError

__all__ = ["DNG_VERSION_TAG", "IMAGE_SIGNATURES", "LAYOUT_KEY", "PNG_SIGNATURE", "RECORD_KEY", "frame_size", "image_format", "parse_json", "read_json", "read_json_object"]

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
"""The first eight bytes of every PNG file."""

DNG_VERSION_TAG = 50706
"""The TIFF tag that marks a DNG file."""

IMAGE_SIGNATURES = (
    (PNG_SIGNATURE, "PNG"), (b"II*\x00", "TIFF"), (b"MM\x00*", "TIFF"), (b"\xff\xd8\xff", "JPEG"), (b"GIF8", "GIF"),
)
"""(first bytes, format) of the image files a user may give where a JSON document belongs."""

LAYOUT_KEY = "lfring_layout_version"
"""The key that marks a layout file (:meth:`lfring.views.Layout.to_dict`); its value is the format's version."""

RECORD_KEY = "lfring_batch_record"
"""The key that marks the record of a command's or a batch's outputs
(:mod:`lfring.batch.record`); its value is the format's version."""


def image_format(head: bytes) -> str | None:
    """The format of the image file whose first bytes are ``head`` ('PNG', 'TIFF', ...), None
    where they are no image's of :data:`IMAGE_SIGNATURES`.

    >>> image_format(PNG_SIGNATURE + b"...."), image_format(b'{"a": 1}')
    ('PNG', None)
    """
    return next((name for signature, name in IMAGE_SIGNATURES if head.startswith(signature)), None)


def frame_size(path: str | Path) -> tuple[int, int] | None:
    """(width, height) of a PNG or TIFF frame read from its header (no pixels); (0, 0) where the
    file holds float samples (a map, not raw counts); None where the header does not tell it
    cheaply (camera RAW, a DNG under a TIFF name, unreadable files: the frame's own error says why
    when it is read). Only regular files are opened: a named pipe would wait for a writer."""
    p = Path(path)
    suffix = p.suffix.lower()
    if not p.is_file():
        return None
    try:
        if suffix == ".png":
            with open(p, "rb") as f:
                head = f.read(24)
            if len(head) == 24 and head.startswith(PNG_SIGNATURE) and head[12:16] == b"IHDR":
                return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
            return None
        if suffix in (".tif", ".tiff"):
            import tifffile

            with tifffile.TiffFile(p) as tf:
                page = tf.pages[0]
                if DNG_VERSION_TAG in page.tags:  # read through LibRaw, whose visible area may differ
                    return None
                if np.dtype(page.dtype).kind == "f":
                    return (0, 0)
                return int(page.imagewidth), int(page.imagelength)
    except Exception:  # noqa: BLE001 - any unreadable header: not decided here
        return None
    return None


def parse_json(raw: bytes) -> tuple[object, str]:
    """(value, '') of the JSON text in ``raw``, or (None, why) where it holds none, saying what
    it holds instead (an image, binary data, nothing, text that is not JSON) rather than in the
    decoder's words.

    >>> parse_json(b'{"a": 1}'), parse_json(PNG_SIGNATURE)
    (({'a': 1}, ''), (None, 'it is a PNG image'))
    """
    kind = image_format(raw)
    if kind:
        return None, f"it is a {kind} image"
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        return None, "it is a binary file, not JSON text"
    if not text.strip():
        return None, "it is empty"
    try:
        return json.loads(text), ""
    except ValueError as exc:  # JSONDecodeError, or a number too long to convert
        where = f" (line {exc.lineno}, column {exc.colno})" if isinstance(exc, json.JSONDecodeError) else ""
        return None, f"it is not valid JSON{where}"


def read_json(path: str | Path, what: str, *, refusal=None):
    """The JSON value in ``path``; ``what`` names the kind of file in error messages
    (:func:`parse_json` says what a file that holds none holds instead). ``refusal``, when
    given, words the refusal of such a file from that saying (a reader that tells the user what
    to give instead)."""
    path = Path(path)
    if path.is_dir():
        raise LfringFileNotFoundError(f"{what} file not found: {path} is a folder; give the file's path")
    if not path.is_file():
        raise LfringFileNotFoundError(f"{what} file not found: {path}")
    value, why = parse_json(path.read_bytes())
    if why:
        raise FileFormatError(refusal(why) if refusal is not None else f"{path}: not a JSON {what} file: {why}")
    return value


def read_json_object(path: str | Path, what: str) -> dict:
    """The JSON object in ``path`` (:func:`read_json`, refused where it holds another value)."""
    data = read_json(path, what)
    if not isinstance(data, dict):
        raise FileFormatError(f"{path}: not a JSON {what} object")
    return data
