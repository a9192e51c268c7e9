"""Bayer colour-filter arrays: pattern names, per-pixel channels and mosaicking.

A pattern names the colours of the top-left 2 x 2 block of the raw frame, row by row:
'RGGB' means (0, 0) red, (0, 1) green, (1, 0) green, (1, 1) blue.
"""

from __future__ import annotations

import numpy as np

from lfring.errors import InvalidInputError

__all__ = ["PATTERNS", "validate_pattern", "pattern_channels", "mosaic"]

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
