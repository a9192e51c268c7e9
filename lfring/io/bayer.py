"""Bayer colour-filter arrays: pattern names, per-pixel channels and mosaicking.

A pattern names the colours of the top-left 2 x 2 block of the raw frame, row by row:
'RGGB' means (0, 0) red, (0, 1) green, (1, 0) green, (1, 1) blue.

OpenCV and kornia name the same four layouts differently: they read two pixels starting at
(1, 1), so OpenCV's ``COLOR_BayerBG2RGB`` and kornia's ``CFA.BG`` are our 'RGGB'. The tables
below are the one place where that translation lives; ``tests/io/test_demosaic.py`` pins every
entry by mosaicking a known colour image and checking the colours that come back.
"""

from __future__ import annotations

import cv2
import numpy as np

from lfring.errors import InvalidInputError

__all__ = [
    "PATTERNS",
    "validate_pattern",
    "pattern_channels",
    "mosaic",
    "OPENCV_BAYER_TO_RGB",
    "OPENCV_BAYER_TO_RGB_EA",
    "OPENCV_BAYER_TO_RGB_VNG",
    "KORNIA_CFA",
]

PATTERNS = ("RGGB", "BGGR", "GRBG", "GBRG")
_CHANNEL = {"R": 0, "G": 1, "B": 2}


def validate_pattern(pattern: str) -> str:
    """Return the upper-case pattern name, or raise with the list of valid ones."""
    if isinstance(pattern, str) and pattern.upper() in PATTERNS:
        return pattern.upper()
    raise InvalidInputError(f"unknown Bayer pattern {pattern!r}; valid patterns: {', '.join(PATTERNS)}")


def pattern_channels(pattern: str) -> np.ndarray:
    """(2, 2) int array: the RGB channel index (0 R, 1 G, 2 B) of each pixel of the 2 x 2 block."""
    p = validate_pattern(pattern)
    return np.array([[_CHANNEL[p[0]], _CHANNEL[p[1]]], [_CHANNEL[p[2]], _CHANNEL[p[3]]]], dtype=np.intp)


def mosaic(rgb: np.ndarray, pattern: str) -> np.ndarray:
    """Sample an (H, W, 3) image through the colour-filter array: (H, W), same dtype.

    Examples
    --------
    >>> import numpy as np
    >>> from lfring.io.bayer import mosaic
    >>> rgb = np.zeros((2, 2, 3), np.float32); rgb[..., 0] = 1.0
    >>> mosaic(rgb, "RGGB")
    array([[1., 0.],
           [0., 0.]], dtype=float32)
    """
    arr = np.asarray(rgb)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise InvalidInputError(f"mosaic expects an (H, W, 3) image, got shape {arr.shape}")
    ch = pattern_channels(pattern)
    h, w = arr.shape[:2]
    out = np.empty((h, w), dtype=arr.dtype)
    for dy in (0, 1):
        for dx in (0, 1):
            out[dy::2, dx::2] = arr[dy::2, dx::2, ch[dy, dx]]
    return out


# Our pattern name -> OpenCV conversion code (output in RGB order). OpenCV's two letters are the
# colours of pixels (1, 1) and (1, 2), hence RGGB -> "BG". The two-letter names exist in OpenCV 4
# and 5 alike (OpenCV >= 4.5 also spells them COLOR_BayerRGGB2RGB etc., with the same values).
OPENCV_BAYER_TO_RGB: dict[str, int] = {
    "RGGB": cv2.COLOR_BayerBG2RGB,
    "BGGR": cv2.COLOR_BayerRG2RGB,
    "GRBG": cv2.COLOR_BayerGB2RGB,
    "GBRG": cv2.COLOR_BayerGR2RGB,
}
"""Bilinear demosaicing codes for :func:`cv2.demosaicing` (uint8 or uint16 input)."""

OPENCV_BAYER_TO_RGB_EA: dict[str, int] = {
    "RGGB": cv2.COLOR_BayerBG2RGB_EA,
    "BGGR": cv2.COLOR_BayerRG2RGB_EA,
    "GRBG": cv2.COLOR_BayerGB2RGB_EA,
    "GBRG": cv2.COLOR_BayerGR2RGB_EA,
}
"""Edge-aware demosaicing codes for :func:`cv2.demosaicing` (uint8 or uint16 input)."""

OPENCV_BAYER_TO_RGB_VNG: dict[str, int] = {
    "RGGB": cv2.COLOR_BayerBG2RGB_VNG,
    "BGGR": cv2.COLOR_BayerRG2RGB_VNG,
    "GRBG": cv2.COLOR_BayerGB2RGB_VNG,
    "GBRG": cv2.COLOR_BayerGR2RGB_VNG,
}
"""Variable-number-of-gradients codes for :func:`cv2.demosaicing` (uint8 input only)."""

# Our pattern name -> member name of ``kornia.color.CFA`` (kept as strings so that this module
# never imports torch). kornia follows OpenCV's naming.
KORNIA_CFA: dict[str, str] = {
    "RGGB": "BG",
    "BGGR": "RG",
    "GRBG": "GB",
    "GBRG": "GR",
}
