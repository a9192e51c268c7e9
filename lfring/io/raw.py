"""Raw frames: camera RAW files (through rawpy/LibRaw), Bayer PNG/TIFF and RGB PNG/TIFF.

:func:`load_raw` returns a :class:`RawFrame`: the raw counts copied out of the decoder, the Bayer
pattern, and the black and white levels that turn counts into linear light. Nothing is
normalised here; :func:`lfring.io.demosaic.demosaic` applies the levels explicitly.

Where the metadata comes from
-----------------------------
Camera RAW (``.dng``, ``.cr2``, ``.nef``, ``.arw``, ``.raf``, ``.orf``, ``.rw2``, ... see
:data:`RAW_SUFFIXES`)
    rawpy/LibRaw decodes the file. The pattern comes from ``raw_pattern`` and ``color_desc``,
    shifted to the origin of the visible area; the black level from
    ``black_level_per_channel``; the white level from ``white_level``. Keyword arguments given
    to :func:`load_raw` override the metadata (no sidecar is read). Only 2 x 2 Bayer CFAs are
    accepted: stacked raws (Foveon, LinearRaw DNG: several colours per pixel), X-Trans (6 x 6)
    and CMYG sensors are refused with :class:`~lfring.errors.FileFormatError`.
Single-channel PNG/TIFF (uint8 or uint16)
    A Bayer mosaic. Pattern and levels come from the keyword arguments, else from a JSON
    sidecar named after the *whole* file name plus ``.json`` (``frame.png`` ->
    ``frame.png.json``, so ``frame.png`` and ``frame.tif`` never share one), else from
    defaults: black 0, bit depth of the container (8 or 16, or a TIFF's smaller
    ``BitsPerSample``), white ``2**bit_depth - 1``. There is **no default pattern**: a grey
    image is never silently taken as monochrome (on a Bayer sensor that gives a checkerboard),
    so a single-channel file without a pattern is an error that says how to give one.
    Sidecar keys: ``pattern`` (str), ``black_level`` (number, or a list of four in pattern
    order), ``white_level`` (number), ``bit_depth`` (int); other keys are ignored so that the
    sidecar may carry more (exposure, device, ground truth).
RGB PNG/TIFF (uint8 or uint16)
    ``image`` is set and ``pattern`` is None. An alpha channel (RGBA, or grey + alpha) is
    dropped and the colour values are kept as stored (no un-premultiplication). Levels as
    above (default black 0, white full scale); a pattern for an RGB file is an error.
"""

from __future__ import annotations

import json
import math
import struct
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from lfring.core.validate import check_int, check_number, is_number
from lfring.errors import FileFormatError, InvalidInputError, LfringError, LfringFileNotFoundError
from lfring.io.bayer import PATTERNS, validate_pattern
from lfring.io.readers import DNG_VERSION_TAG, PNG_SIGNATURE
from lfring.core.records import record_repr

__all__ = ["RawFrame", "load_raw", "write_dng", "RAW_SUFFIXES", "FILE_FORMATS", "sidecar_path"]

RAW_SUFFIXES = frozenset(
    {
        ".dng", ".cr2", ".cr3", ".crw", ".nef", ".nrw", ".arw", ".srf", ".sr2", ".raf", ".orf",
        ".rw2", ".rwl", ".pef", ".ptx", ".srw", ".x3f", ".3fr", ".fff", ".iiq", ".mos", ".mef",
        ".mrw", ".erf", ".kdc", ".dcr", ".k25", ".raw", ".cap", ".ari",
    }
)
"""File suffixes (lower case) decoded through rawpy/LibRaw."""

_PNG_SUFFIXES = frozenset({".png"})
_TIFF_SUFFIXES = frozenset({".tif", ".tiff"})

FILE_FORMATS = ("camera_raw", "png", "tiff")
"""Values of :attr:`RawFrame.file_format` for frames read from a file (None for arrays)."""

_SIDECAR_KEYS = ("pattern", "black_level", "white_level", "bit_depth")
_CFA_CODES = {"R": 0, "G": 1, "B": 2}


def _where(path: Path | None) -> str:
    return f"{path}: " if path is not None else ""


@dataclass(frozen=True, eq=False)
class RawFrame:
    """One raw frame: a Bayer mosaic of raw counts, or an image that is already RGB.

    Parameters
    ----------
    mosaic : ndarray of uint8 or uint16, shape (H, W), optional
        Raw counts as the sensor delivered them, one colour per pixel. H and W are even.
    image : ndarray of uint8 or uint16, shape (H, W, 3), optional
        An image that is already RGB (R, G, B order). Exactly one of ``mosaic`` and ``image``
        is given.
    pattern : {'RGGB', 'BGGR', 'GRBG', 'GBRG'} or None
        Colours of the top-left 2 x 2 block of ``mosaic``, row by row. Required with
        ``mosaic``, None with ``image``.
    black_level : float or tuple of 4 floats
        Counts of a pixel that received no light. A tuple gives one level per position of the
        2 x 2 CFA block in raster order ((0, 0), (0, 1), (1, 0), (1, 1)), i.e. in the order of
        the letters of ``pattern`` ('RGGB' -> R, G1, G2, B). Four equal values are stored as one
        float. Default 0.
    white_level : float, optional
        Counts at saturation. Default ``2**bit_depth - 1``.
    bit_depth : int, optional
        Significant bits of the counts; default the container (8 for uint8, 16 for uint16).
        For camera RAW files it is the number of bits that holds ``white_level``.
    path : Path or None
        The file the frame was read from.
    file_format : {'camera_raw', 'png', 'tiff'} or None
        How it was read (None for frames built from arrays). ``demosaic(method='rawpy')``
        needs 'camera_raw'.

    Notes
    -----
    Levels are kept in counts; linear light is ``(counts - black) / (white - black)``, clipped
    to [0, 1] (see :func:`lfring.io.demosaic.apply_levels`). The arrays are stored as read-only
    views. Frames compare by identity (``eq=False``): arrays have no single truth value.

    Examples
    --------
    >>> import numpy as np, lfring
    >>> frame = lfring.RawFrame(mosaic=np.zeros((4, 6), np.uint16), pattern="RGGB", bit_depth=12)
    >>> frame.white_level, frame.shape
    (4095.0, (4, 6))
    """

    mosaic: np.ndarray | None = None
    image: np.ndarray | None = None
    pattern: str | None = None
    black_level: float | tuple[float, float, float, float] = 0.0
    white_level: float | None = None
    bit_depth: int | None = None
    path: Path | None = None
    file_format: str | None = None

    __repr__ = record_repr

    def __post_init__(self) -> None:
        path = None if self.path is None else Path(self.path)
        object.__setattr__(self, "path", path)
        where = _where(path)
        if (self.mosaic is None) == (self.image is None):
            raise InvalidInputError(f"{where}RawFrame needs exactly one of 'mosaic' and 'image'")
        if self.file_format is not None and self.file_format not in FILE_FORMATS:
            raise InvalidInputError(
                f"{where}unknown file_format {self.file_format!r}; valid: "
                f"{', '.join(FILE_FORMATS)} or None"
            )
        is_mosaic = self.mosaic is not None
        data = np.asarray(self.mosaic if is_mosaic else self.image)
        name = "mosaic" if is_mosaic else "image"
        if data.dtype.kind == "u" and not data.dtype.isnative:  # big-endian counts (a FITS or TIFF reader's)
            data = data.astype(data.dtype.newbyteorder("="))
            object.__setattr__(self, name, data)
        if data.dtype not in (np.uint8, np.uint16):
            hint = " (float images are not raw counts)" if data.dtype.kind == "f" else ""
            raise InvalidInputError(
                f"{where}{name} must be uint8 or uint16 raw counts, got {data.dtype}{hint}"
            )
        if is_mosaic:
            if data.ndim != 2:
                raise InvalidInputError(f"{where}mosaic must be 2-D (H, W), got shape {data.shape}")
            h, w = data.shape
            if h < 2 or w < 2:
                raise InvalidInputError(
                    f"{where}a Bayer mosaic needs at least one whole 2 x 2 CFA block, got {w} x {h} (W x H)"
                )
            if h % 2 or w % 2:
                raise InvalidInputError(
                    f"{where}a Bayer mosaic needs an even width and height (whole 2 x 2 CFA "
                    f"blocks), got {w} x {h} (W x H); crop it to {w - w % 2} x {h - h % 2}"
                )
            if self.pattern is None:
                raise InvalidInputError(
                    f"{where}a mosaic needs a Bayer pattern, one of {', '.join(PATTERNS)}"
                )
            try:
                object.__setattr__(self, "pattern", validate_pattern(self.pattern))
            except InvalidInputError as exc:
                raise InvalidInputError(f"{where}{exc}") from None
        else:
            if data.ndim != 3 or data.shape[2] != 3:
                raise InvalidInputError(f"{where}image must be (H, W, 3) RGB, got shape {data.shape}")
            if self.pattern is not None:
                raise InvalidInputError(
                    f"{where}pattern {self.pattern!r} given for an RGB image: a Bayer pattern "
                    "applies to single-channel mosaics only"
                )
        view = data.view()
        view.flags.writeable = False
        object.__setattr__(self, name, view)

        container_bits = data.dtype.itemsize * 8
        bit_depth = container_bits if self.bit_depth is None else self.bit_depth
        bit_depth = check_int(bit_depth, f"{where}bit_depth", minimum=1, maximum=container_bits,
                              hint=f" for {data.dtype} data")
        object.__setattr__(self, "bit_depth", bit_depth)
        full_scale = 2 ** int(bit_depth) - 1
        white = float(full_scale)
        if self.white_level is not None:
            white = _as_level(self.white_level, "white_level", where)
        if not 0 < white <= full_scale:
            raise InvalidInputError(
                f"{where}white_level must be in (0, {full_scale}] for bit_depth {bit_depth}, "
                f"got {white!r}"
            )
        object.__setattr__(self, "white_level", white)

        black = _normalise_black(self.black_level, where, allow_per_channel=is_mosaic)
        for value in black if isinstance(black, tuple) else (black,):
            if not 0 <= value < white:
                raise InvalidInputError(
                    f"{where}black_level must be >= 0 and below white_level ({white:g}), got "
                    f"{self.black_level!r}; pass black_level=... and white_level=... to override"
                )
        object.__setattr__(self, "black_level", black)

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) in pixels."""
        data = self.mosaic if self.mosaic is not None else self.image
        return int(data.shape[0]), int(data.shape[1])

    @property
    def black_level_2x2(self) -> np.ndarray:
        """(2, 2) float64 black level of each position of the CFA block (uniform for one value)."""
        if isinstance(self.black_level, tuple):
            return np.asarray(self.black_level, dtype=np.float64).reshape(2, 2)
        return np.full((2, 2), float(self.black_level))


def _as_level(value: Any, name: str, where: str) -> float:
    return check_number(value, f"{where}{name}")


def _normalise_black(value: Any, where: str, *, allow_per_channel: bool) -> float | tuple[float, ...]:
    if isinstance(value, np.ndarray) and value.ndim == 0:
        value = value.item()
    if isinstance(value, (str, bytes)) or not isinstance(value, (Sequence, np.ndarray)):
        return _as_level(value, "black_level", where)
    values = [_as_level(v, "black_level", where) for v in np.asarray(value, dtype=object).ravel()]
    if not allow_per_channel:
        raise InvalidInputError(
            f"{where}black_level for an RGB image must be one number, got {value!r}"
        )
    if len(values) != 4:
        raise InvalidInputError(
            f"{where}black_level must be one number or four (one per 2 x 2 CFA position, in "
            f"pattern order), got {len(values)} values"
        )
    if len(set(values)) == 1:
        return values[0]
    return tuple(values)


def sidecar_path(path: str | PathLike[str]) -> Path:
    """The JSON sidecar of a PNG/TIFF raw frame: the full file name plus '.json'."""
    path = Path(path)
    return path.with_name(path.name + ".json")


def load_raw(
    path: str | PathLike[str],
    *,
    pattern: str | None = None,
    black_level: float | Sequence[float] | None = None,
    white_level: float | None = None,
    bit_depth: int | None = None,
) -> RawFrame:
    """Read a raw frame from a camera RAW file, a Bayer PNG/TIFF or an RGB PNG/TIFF.

    Parameters
    ----------
    path : str or path-like
        The file. Its suffix picks the reader: camera RAW suffixes (:data:`RAW_SUFFIXES`) go
        through rawpy, ``.png`` through OpenCV, ``.tif``/``.tiff`` through tifffile (a TIFF
        carrying a DNGVersion tag is a DNG and goes through rawpy).
    pattern : {'RGGB', 'BGGR', 'GRBG', 'GBRG'}, optional
        Bayer pattern of the top-left 2 x 2 block; overrides the file's metadata or sidecar.
    black_level : float or sequence of 4 floats, optional
        Black level in counts, one value or one per CFA position in pattern order; overrides.
    white_level : float, optional
        Saturation level in counts; overrides.
    bit_depth : int, optional
        Significant bits of the counts; overrides (PNG/TIFF: the container depth by default).

    Returns
    -------
    RawFrame
        ``mosaic`` (H, W) raw counts copied out of the decoder, or ``image`` (H, W, 3) for an
        RGB file, with the pattern, levels, bit depth, path and file format.

    Raises
    ------
    LfringFileNotFoundError
        The file does not exist.
    FileFormatError
        The file cannot be read as what its suffix says (corrupt, truncated, unreadable), or it
        is a kind lfring does not handle (stacked or non-Bayer raw, float or CMYK TIFF, ...).
    InvalidInputError
        A parameter or sidecar value is invalid, no pattern is known for a mosaic, the mosaic
        has an odd size, or the levels contradict each other or the data.

    Notes
    -----
    Camera RAW: the visible area (``raw_image_visible``) is returned; if it has an odd width or
    height, its last column or row is dropped so that the mosaic holds whole CFA blocks (the
    pattern origin is unchanged). ``black_level`` is a tuple when LibRaw reports different
    levels per channel, ordered by CFA position. ``bit_depth`` is the number of bits that holds
    ``white_level`` (12 for 4095, 14 for 16383).

    A constant or all-black frame is valid data, not an error.

    Examples
    --------
    A 12-bit GRBG mosaic stored in a 16-bit PNG, its levels given in a sidecar:

    >>> import json, os, tempfile
    >>> import cv2, numpy as np, lfring
    >>> path = os.path.join(tempfile.mkdtemp(), "frame.png")
    >>> _ = cv2.imwrite(path, np.full((4, 6), 2079, np.uint16))
    >>> with open(path + ".json", "w") as f:
    ...     json.dump({"pattern": "GRBG", "black_level": 64, "white_level": 4095, "bit_depth": 12}, f)
    >>> frame = lfring.load_raw(path)
    >>> frame.mosaic.shape, frame.pattern, frame.black_level, frame.white_level
    ((4, 6), 'GRBG', 64.0, 4095.0)
    >>> round(float(lfring.demosaic(frame, method="bilinear")[2, 3, 1]), 4)  # (2079 - 64) / (4095 - 64)
    0.4999

    A frame of the synthetic twin bundled in data/synthetic (paths relative to the repository
    root), its levels read from its sidecar ``scene.png.json``:

    >>> frame = lfring.load_raw("data/synthetic/scene.png")
    >>> frame.shape, frame.pattern, frame.black_level, frame.white_level, frame.bit_depth
    ((1842, 2456), 'RGGB', 64.0, 4095.0, 12)
    """
    if isinstance(path, bytes) or not isinstance(path, (str, PathLike)):
        raise InvalidInputError(
            f"load_raw expects a file path (str or path-like), got {type(path).__name__}"
        )
    p = Path(path)
    if not p.exists():
        raise LfringFileNotFoundError(f"{p}: no such file")
    if not p.is_file():
        raise FileFormatError(f"{p}: not a regular file (a folder, a named pipe or a device); expected a raw frame file")
    if p.stat().st_size == 0:
        raise FileFormatError(f"{p}: the file is empty (0 bytes); expected a raw frame file")
    overrides = {
        "pattern": pattern,
        "black_level": black_level,
        "white_level": white_level,
        "bit_depth": bit_depth,
    }
    suffix = p.suffix.lower()
    if suffix in RAW_SUFFIXES:
        return _load_camera_raw(p, overrides)
    if suffix in _PNG_SUFFIXES:
        data, info = _read_png(p)
        return _frame_from_pixels(p, data, info, overrides, "png")
    if suffix in _TIFF_SUFFIXES:
        read = _read_tiff(p)
        if read is None:  # a DNG under a TIFF name
            return _load_camera_raw(p, overrides)
        data, info = read
        return _frame_from_pixels(p, data, info, overrides, "tiff")
    raise FileFormatError(
        f"{p}: unsupported file type {p.suffix!r}; lfring reads camera RAW files "
        f"({', '.join(sorted(RAW_SUFFIXES)[:8])}, ...), PNG (.png) and TIFF (.tif, .tiff)"
    )


def write_dng(path: str | PathLike[str], frame: RawFrame) -> Path:
    """Write a mosaic frame as a minimal uncompressed CFA DNG (1.4) that LibRaw reads back.

    The counts are stored as uint16 with the pattern (CFAPattern), the black level (BlackLevel,
    one per CFA position with BlackLevelRepeatDim 2 x 2) and the white level (WhiteLevel).
    ``load_raw(write_dng(path, frame))`` returns the same counts, pattern and levels (LibRaw
    keeps whole counts of a fractional black level). The file is written atomically.

    Parameters
    ----------
    path : str or path-like
        Destination, normally ending in ``.dng``.
    frame : RawFrame
        A frame with a ``mosaic``, at least 22 x 22 pixels (LibRaw ignores smaller images).

    Returns
    -------
    Path
        ``path``.
    """
    import tifffile

    from lfring.io.atomic import atomic_path

    if not isinstance(frame, RawFrame) or frame.mosaic is None:
        raise InvalidInputError("write_dng expects a RawFrame with a mosaic (not an RGB image)")
    h, w = frame.shape
    if h < 22 or w < 22:
        raise InvalidInputError(
            f"write_dng: LibRaw does not read images smaller than 22 x 22 pixels, got {w} x {h}"
        )
    black = frame.black_level_2x2.ravel()
    if np.all(black == np.round(black)):
        black_tag = (50714, "I", 4, tuple(int(b) for b in black), True)
    else:
        rationals = []
        for b in black:
            rationals += [int(round(b * 1000)), 1000]
        black_tag = (50714, "2I", 4, tuple(rationals), True)
    identity = (1, 1, 0, 1, 0, 1, 0, 1, 1, 1, 0, 1, 0, 1, 0, 1, 1, 1)
    tags = [
        (33421, "H", 2, (2, 2), True),  # CFARepeatPatternDim
        (33422, "B", 4, bytes(_CFA_CODES[c] for c in frame.pattern), True),  # CFAPattern
        (DNG_VERSION_TAG, "B", 4, (1, 4, 0, 0), True),  # DNGVersion
        (50707, "B", 4, (1, 1, 0, 0), True),  # DNGBackwardVersion
        (50708, "s", 0, "lfring synthetic", True),  # UniqueCameraModel
        (50710, "B", 3, (0, 1, 2), True),  # CFAPlaneColor
        (50711, "H", 1, 1, True),  # CFALayout: rectangular
        (50713, "H", 2, (2, 2), True),  # BlackLevelRepeatDim
        black_tag,  # BlackLevel
        (50717, "I", 1, int(round(frame.white_level)), True),  # WhiteLevel
        (50721, "2i", 9, identity, True),  # ColorMatrix1 (identity: camera RGB is the output)
        (50778, "H", 1, 21, True),  # CalibrationIlluminant1: D65
    ]
    path = Path(path)
    with atomic_path(path) as tmp:
        tifffile.imwrite(
            tmp,
            np.ascontiguousarray(frame.mosaic, dtype=np.uint16),
            photometric=32803,
            subfiletype=0,
            extratags=tags,
            metadata=None,
        )
    return path


# -- camera RAW --------------------------------------------------------------------------------


def _load_camera_raw(p: Path, overrides: dict[str, Any]) -> RawFrame:
    import rawpy

    try:
        with rawpy.imread(str(p)) as raw:
            indices = visible_cfa_indices(raw, p)
            letters = cfa_letters(raw, indices, p)
            mosaic = np.array(raw.raw_image_visible, dtype=np.uint16, copy=True)
            per_channel = [float(v) for v in raw.black_level_per_channel]
            meta_black = tuple(per_channel[i] for i in indices.ravel())
            meta_white = float(raw.white_level)
    except LfringError:
        raise
    except rawpy.LibRawFileUnsupportedError as exc:
        raise FileFormatError(
            f"{p}: not a camera RAW file LibRaw can decode ({_libraw_message(exc)}); the file is "
            "corrupt, of another kind, or from an unsupported camera"
        ) from exc
    except rawpy.LibRawIOError as exc:
        raise FileFormatError(
            f"{p}: could not be read ({_libraw_message(exc)}); the file is truncated or unreadable"
        ) from exc
    except (rawpy.LibRawError, NotImplementedError, RuntimeError) as exc:
        raise FileFormatError(
            f"{p}: LibRaw failed to decode the raw data ({_libraw_message(exc)})"
        ) from exc

    h, w = mosaic.shape
    mosaic = mosaic[: h - h % 2, : w - w % 2]
    white = meta_white if overrides["white_level"] is None else overrides["white_level"]
    bit_depth = overrides["bit_depth"]
    if bit_depth is None:
        bit_depth = max(1, math.ceil(_as_level(white, "white_level", f"{p}: ")).bit_length())
        bit_depth = min(bit_depth, 16)
    return RawFrame(
        mosaic=mosaic,
        pattern=letters if overrides["pattern"] is None else overrides["pattern"],
        black_level=meta_black if overrides["black_level"] is None else overrides["black_level"],
        white_level=white,
        bit_depth=bit_depth,
        path=p,
        file_format="camera_raw",
    )


def _libraw_message(exc: BaseException) -> str:
    arg = exc.args[0] if exc.args else exc
    if isinstance(arg, bytes):
        return arg.decode("utf-8", "replace")
    return str(arg)


def visible_cfa_indices(raw: Any, p: Path) -> np.ndarray:
    """(2, 2) LibRaw colour indices of the top-left block of the visible area; refuse non-Bayer."""
    import rawpy

    if raw.raw_type != rawpy.RawType.Flat:
        shape = tuple(raw.raw_image.shape)
        raise FileFormatError(
            f"{p}: a stacked raw image (shape {shape}: several colour samples per pixel, e.g. a "
            "Foveon or LinearRaw DNG), not a 2 x 2 Bayer mosaic; lfring needs an undemosaiced "
            "Bayer raw"
        )
    pattern = raw.raw_pattern
    if pattern is None or pattern.shape != (2, 2):
        size = "?" if pattern is None else f"{pattern.shape[0]} x {pattern.shape[1]}"
        kind = " (monochrome)" if pattern is not None and pattern.shape == (1, 1) else (
            " (X-Trans or another non-Bayer layout)" if pattern is not None else ""
        )
        raise FileFormatError(
            f"{p}: the colour-filter array repeats every {size} pixels{kind}, not a 2 x 2 Bayer "
            "pattern; lfring handles 2 x 2 Bayer CFAs only"
        )
    # raw_pattern is anchored at the corner of the full raw image; the mosaic we return starts
    # at the visible area, so shift by the margins.
    top, left = int(raw.sizes.top_margin), int(raw.sizes.left_margin)
    rows = [[pattern[(y + top) % 2, (x + left) % 2] for x in (0, 1)] for y in (0, 1)]
    return np.array(rows, dtype=np.intp)


def cfa_letters(raw: Any, indices: np.ndarray, p: Path) -> str:
    """The Bayer pattern of a camera RAW file as letters, e.g. 'RGGB'.

    Parameters
    ----------
    raw : rawpy.RawPy
        The open file.
    indices : (2, 2) ndarray of int
        Colour indices of the top-left 2 x 2 block of the visible mosaic (into LibRaw's colour
        description).
    p : Path
        The file, for error messages.

    Returns
    -------
    str
        One of :data:`lfring.io.bayer.PATTERNS`.

    Raises
    ------
    FileFormatError
        The colours are not an R/G/B Bayer pattern.
    """
    desc = raw.color_desc.decode("ascii", "replace")
    try:
        letters = "".join(desc[i] for i in indices.ravel())
    except IndexError:
        letters = "?"
    if letters not in PATTERNS:
        raise FileFormatError(
            f"{p}: CFA colours {letters!r} (LibRaw colour description {desc!r}) are not a 2 x 2 "
            f"R/G/B Bayer pattern ({', '.join(PATTERNS)}); lfring handles RGB Bayer sensors only"
        )
    return letters


# -- PNG ---------------------------------------------------------------------------------------

_PNG_COLOUR_TYPES = {0: "grey", 2: "RGB", 3: "palette", 4: "grey + alpha", 6: "RGBA"}


def _read_png(p: Path) -> tuple[np.ndarray, dict[str, Any]]:
    """Check the chunk structure (truncation, CRC) and decode with OpenCV, keeping 16 bits."""
    import cv2

    data = _read_bytes(p)
    if not data.startswith(PNG_SIGNATURE):
        raise FileFormatError(
            f"{p}: not a PNG file (the PNG signature is missing); the file is corrupt or of "
            "another kind"
        )
    pos, header, seen_idat, seen_iend = len(PNG_SIGNATURE), None, False, False
    while pos < len(data):
        if pos + 8 > len(data):
            raise FileFormatError(f"{p}: truncated PNG (a chunk header is cut off at byte {pos})")
        length, ctype = struct.unpack(">I4s", data[pos : pos + 8])
        end = pos + 12 + length
        if end > len(data):
            raise FileFormatError(
                f"{p}: truncated PNG (chunk {ctype.decode('latin-1')!r} at byte {pos} needs "
                f"{length} bytes, the file ends {end - len(data)} bytes short)"
            )
        body = data[pos + 8 : pos + 8 + length]
        (crc,) = struct.unpack(">I", data[pos + 8 + length : end])
        if zlib.crc32(ctype + body) & 0xFFFFFFFF != crc:
            raise FileFormatError(
                f"{p}: corrupt PNG (chunk {ctype.decode('latin-1')!r} at byte {pos} fails its CRC)"
            )
        if header is None:
            if ctype != b"IHDR" or length != 13:
                raise FileFormatError(f"{p}: corrupt PNG (the first chunk is not a valid IHDR)")
            header = struct.unpack(">IIBBBBB", body)
        seen_idat |= ctype == b"IDAT"
        pos = end
        if ctype == b"IEND":
            seen_iend = True
            break
    if header is None or not seen_iend:
        raise FileFormatError(f"{p}: truncated PNG (the file ends before the IEND chunk)")
    if not seen_idat:
        raise FileFormatError(f"{p}: corrupt PNG (no image data chunk)")
    width, height, depth, colour_type = header[:4]
    if colour_type not in _PNG_COLOUR_TYPES:
        raise FileFormatError(f"{p}: corrupt PNG (invalid colour type {colour_type})")
    if depth not in (8, 16):
        raise FileFormatError(
            f"{p}: PNG with {depth}-bit samples; lfring reads 8- and 16-bit PNGs (raw counts need "
            "whole bytes), convert it"
        )
    arr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if arr is None or arr.shape[:2] != (height, width):
        raise FileFormatError(f"{p}: the PNG image data could not be decoded (corrupt compressed data)")
    kind = _PNG_COLOUR_TYPES[colour_type]
    if colour_type in (0, 4):
        # OpenCV hands grey + alpha back as BGRA with the grey value repeated: keep one copy.
        arr = arr[..., 0] if arr.ndim == 3 else arr
    else:
        arr = arr[..., 2::-1] if arr.ndim == 3 and arr.shape[2] >= 3 else arr
    return np.ascontiguousarray(arr), {"kind": f"PNG {kind}", "bits_per_sample": depth}


def _read_bytes(p: Path) -> bytes:
    try:
        return p.read_bytes()
    except OSError as exc:
        raise FileFormatError(f"{p}: cannot be read ({exc.strerror or exc})") from exc


# -- TIFF --------------------------------------------------------------------------------------


def _read_tiff(p: Path) -> tuple[np.ndarray, dict[str, Any]] | None:
    """Decode the single image of a TIFF; None when the TIFF is a DNG (read it with rawpy)."""
    import tifffile

    try:
        size = p.stat().st_size
        with tifffile.TiffFile(p) as tif:
            page = tif.pages.first
            if DNG_VERSION_TAG in page.tags:
                return None
            full = [pg for pg in tif.pages if not getattr(pg, "is_reduced", False)]
            if len(full) > 1:
                raise FileFormatError(
                    f"{p}: the TIFF holds {len(full)} images; lfring reads single-image TIFFs "
                    "(one raw frame per file)"
                )
            for offset, count in zip(page.dataoffsets, page.databytecounts):
                if offset + count > size:
                    raise FileFormatError(
                        f"{p}: truncated TIFF (image data runs to byte {offset + count}, the "
                        f"file has {size})"
                    )
            dtype = np.dtype(page.dtype) if page.dtype is not None else None
            if dtype is None or dtype.kind == "f":
                raise FileFormatError(
                    f"{p}: {'floating-point' if dtype is not None else 'unsupported'} TIFF samples "
                    f"({dtype}); lfring reads uint8/uint16 raw counts, not processed float images"
                )
            if dtype not in (np.uint8, np.uint16):
                raise FileFormatError(
                    f"{p}: TIFF samples are {dtype}; lfring reads uint8 or uint16 raw counts"
                )
            photometric = int(page.photometric)
            samples = int(page.samplesperpixel)
            extras = tuple(int(e) for e in (page.extrasamples or ()))
            bits = int(page.bitspersample)
            axes = page.axes
            arr = page.asarray()
    except LfringError:
        raise
    except NotImplementedError as exc:  # e.g. a compression or bit depth that needs imagecodecs
        raise FileFormatError(f"{p}: tifffile cannot decode this TIFF ({exc})") from exc
    except Exception as exc:  # tifffile raises many types (TiffFileError, struct.error, ...)
        with open(p, "rb") as f:
            head = f.read(4)
        what = ("it does not begin as a TIFF does (another kind of file under a .tif name?)"
                if head[:2] not in (b"II", b"MM") else "it is corrupt or truncated")
        raise FileFormatError(f"{p}: not a readable TIFF file: {what}") from exc

    if axes.startswith("S") and arr.ndim == 3:  # planar configuration 'separate'
        arr = np.moveaxis(arr, 0, -1)
    alpha = len(extras) == 1 and extras[0] in (1, 2)
    # photometric: 0 min-is-white, 1 min-is-black, 2 RGB, 32803 CFA
    if photometric in (1, 32803) and (samples == 1 or (samples == 2 and alpha)):
        arr = arr[..., 0] if arr.ndim == 3 else arr
        kind = "TIFF grey" + (" + alpha" if samples == 2 else "")
    elif photometric == 2 and (samples == 3 or (samples == 4 and alpha)):
        arr = arr[..., :3]
        kind = "TIFF RGB" + ("A" if samples == 4 else "")
    elif photometric == 0:
        raise FileFormatError(f"{p}: a min-is-white (inverted) TIFF; raw counts are stored min-is-black")
    else:
        raise FileFormatError(
            f"{p}: TIFF with photometric interpretation {photometric} and {samples} samples per "
            f"pixel (extra samples {extras}); lfring reads grey (a Bayer mosaic), RGB or RGBA"
        )
    return np.ascontiguousarray(arr), {"kind": kind, "bits_per_sample": bits}


# -- PNG/TIFF pixels -> RawFrame ----------------------------------------------------------------


def _read_sidecar(p: Path) -> dict[str, Any]:
    side = sidecar_path(p)
    if not side.is_file():
        return {}
    try:
        content = json.loads(side.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise FileFormatError(f"{side}: sidecar of {p.name} is not valid JSON ({exc})") from exc
    if not isinstance(content, dict):
        raise FileFormatError(
            f"{side}: sidecar of {p.name} must hold a JSON object, got {type(content).__name__}"
        )
    return {k: content[k] for k in _SIDECAR_KEYS if k in content and content[k] is not None}


def _levels(value: Any) -> list[float] | None:
    """A sidecar's level (one number, or a list of them) as floats; None when it is not numbers."""
    values = value if isinstance(value, (list, tuple)) else [value]
    if not values or not all(is_number(v) for v in values):
        return None
    return [float(v) for v in values]


def _above_bit_depth(p: Path, peak: int, bit_depth: int, container: int, sidecar: dict[str, Any],
                     given: dict[str, Any] | None) -> str:
    """The error for counts above the largest ``bit_depth``-bit value: where the bit depth comes
    from (the caller, the sidecar by name, or the file's header) and what to change there, with
    the levels the data would have if MSB-aligned: the levels of that bit depth (the caller's
    with its bit depth, else the sidecar's, else the defaults), scaled."""
    side = sidecar_path(p).name
    full_scale, scale = 2**bit_depth - 1, 2 ** (container - bit_depth)
    # A sidecar's levels are of its own bit depth: they go with a bit depth given here only if it is that one.
    own = sidecar if given is None or sidecar.get("bit_depth", container) == bit_depth else {}
    levels = {**own, **{k: v for k, v in (given or {}).items() if v is not None}}
    whites, blacks = _levels(levels.get("white_level", full_scale)), _levels(levels.get("black_level", 0))
    as_json = as_text = ""  # the scaled levels, when they are numbers (a bad one is said when it is read)
    white_scaled = None if whites is None or len(whites) != 1 else whites[0] * (scale if whites[0] <= full_scale else 1)
    # Levels of another bit depth (a sidecar's, given another one here) scale to nonsense: none offered.
    if white_scaled is not None and blacks is not None and max(blacks) * scale < white_scaled <= 2**container - 1:
        white = f"{white_scaled:g}"  # one above full scale is of the container's scale already
        black = ",".join(f"{b * scale:g}" for b in blacks)
        as_json = f' ("white_level": {white}, "black_level": {f"[{black}]" if len(blacks) > 1 else black})'
        as_text = f" ({black} and {white} counts)"
    if given is not None:
        origin = "the bit_depth argument"
        fix = f"pass bit_depth={container} with black_level and white_level scaled by {scale}{as_text}"
        otherwise = "fix bit_depth"
    else:
        if "bit_depth" in sidecar:
            origin = f'the sidecar {side} ("bit_depth": {bit_depth})'
            fix = f'set "bit_depth": {container} in {side}'
            otherwise = f'correct "bit_depth" in {side}'
        else:
            origin = f"the file's header ({bit_depth} bits per sample)"
            fix = f'write "bit_depth": {container} in a sidecar {side}'
            otherwise = f'write the right "bit_depth" in a sidecar {side}'
        fix += (f" with the levels scaled by {scale}{as_json}, or pass black_level=... and white_level=... scaled by "
                f"{scale}{as_text}")
    return (f"{p}: counts reach {peak}, above {full_scale}, the largest {bit_depth}-bit value; the {bit_depth} bits "
            f"come from {origin}. If the data are MSB-aligned ({bit_depth}-bit counts shifted left by "
            f"{container - bit_depth} bits), {fix}; otherwise {otherwise}")


def _frame_from_pixels(
    p: Path, data: np.ndarray, info: dict[str, Any], overrides: dict[str, Any], file_format: str
) -> RawFrame:
    if data.dtype.kind == "f":
        raise FileFormatError(
            f"{p}: floating-point samples ({data.dtype}); lfring reads uint8/uint16 raw counts"
        )
    if data.dtype not in (np.uint8, np.uint16):
        raise FileFormatError(f"{p}: samples are {data.dtype}; lfring reads uint8 or uint16 raw counts")
    sidecar = _read_sidecar(p)
    side_name = f"sidecar {sidecar_path(p).name}"
    source = {k: "argument" if overrides[k] is not None else side_name for k in _SIDECAR_KEYS}
    values = {k: overrides[k] if overrides[k] is not None else sidecar.get(k) for k in _SIDECAR_KEYS}
    is_mosaic = data.ndim == 2
    where = f"{p}: "

    if is_mosaic and values["pattern"] is None:
        raise InvalidInputError(
            f"{p}: single-channel {info['kind']} image with no Bayer pattern. Pass "
            f"load_raw(..., pattern=...) with one of {', '.join(PATTERNS)}, or write a sidecar "
            f'{sidecar_path(p).name} with {{"pattern": "RGGB"}}. (Grey images are not taken as '
            "monochrome: on a Bayer sensor that would keep the CFA checkerboard.)"
        )
    if not is_mosaic and values["pattern"] is not None:
        raise InvalidInputError(
            f"{p}: {info['kind']} image is already RGB, but a Bayer pattern "
            f"{values['pattern']!r} was given (by {source['pattern']}); drop it"
        )
    if values["pattern"] is not None and (
        not isinstance(values["pattern"], str) or values["pattern"].upper() not in PATTERNS
    ):
        raise InvalidInputError(
            f"{p}: unknown Bayer pattern {values['pattern']!r} (from {source['pattern']}); "
            f"valid patterns: {', '.join(PATTERNS)}"
        )

    container = data.dtype.itemsize * 8
    bit_depth = values["bit_depth"]
    if bit_depth is None:
        bits = info.get("bits_per_sample", container)
        bit_depth = bits if 1 <= bits <= container else container
    else:
        bit_depth = check_int(bit_depth, f"{p}: bit_depth (from {source['bit_depth']})", minimum=1, maximum=container,
                              hint=f" for a {container}-bit file")
    full_scale = 2 ** int(bit_depth) - 1
    peak = int(data.max()) if data.size else 0
    given_white = overrides["white_level"]
    side_blacks = _levels(sidecar.get("black_level", 0))
    stale_black = overrides["black_level"] is None and (side_blacks is None or any(side_blacks))
    if (peak > full_scale and overrides["bit_depth"] is None and is_number(given_white)
            and full_scale < given_white <= 2 ** container - 1 and not stale_black):
        # The counts and the white level given for this read both pass the bit depth of the
        # sidecar (or of the file's header): that bit depth is stale, and the given level, which
        # overrides the sidecar's, says how many bits the data have. A sidecar's black level
        # other than 0 is on the stale scale too, so it must be given as well.
        bit_depth = math.ceil(given_white).bit_length()
        full_scale = 2 ** bit_depth - 1
    if peak > full_scale:
        given = overrides if overrides["bit_depth"] is not None else None
        raise InvalidInputError(_above_bit_depth(p, peak, int(bit_depth), container, sidecar, given))
    black = values["black_level"] if values["black_level"] is not None else 0.0
    white = values["white_level"] if values["white_level"] is not None else float(full_scale)
    black_source = source["black_level"] if values["black_level"] is not None else "default 0"
    white_source = source["white_level"]
    if values["white_level"] is None:
        white_source = f"default 2**{bit_depth} - 1"
    white = _as_level(white, f"white_level (from {white_source})", where)
    if not 0 < white <= full_scale:
        raise InvalidInputError(
            f"{p}: white_level {white:g} (from {white_source}) must be in (0, {full_scale}] for "
            f"{bit_depth}-bit data"
        )
    black = _normalise_black(black, f"{where}(from {black_source}) ", allow_per_channel=is_mosaic)
    blacks = black if isinstance(black, tuple) else (black,)
    if max(blacks) >= white or min(blacks) < 0:
        raise InvalidInputError(
            f"{p}: black_level {black!r} (from {black_source}) must be >= 0 and below white_level "
            f"{white:g} (from {white_source}); pass black_level=... / white_level=... to fix"
        )
    return RawFrame(
        mosaic=data if is_mosaic else None,
        image=None if is_mosaic else data,
        pattern=values["pattern"],
        black_level=black,
        white_level=white,
        bit_depth=int(bit_depth),
        path=p,
        file_format=file_format,
    )
