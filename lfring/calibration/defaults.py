"""Calibrations shipped with lfring (the repository's calib/ folder, inside the package)."""

from __future__ import annotations

import json

from lfring._resources import calib_dir
from lfring.calibration.jsonio import CALIBRATION_SUFFIX, builtin_calibrations, calibration_from_dict
from lfring.calibration.ring import RingCalibration
from lfring.errors import LfringFileNotFoundError

__all__ = ["builtin_calibrations", "calibration_for_frame", "default_calibration"]


def default_calibration(raw_size: tuple[int, int]) -> tuple[RingCalibration, str]:
    """The shipped calibration for frames of ``raw_size`` = (width, height), and its name.

    Measured calibrations are preferred to ones derived from the optics.
    """
    matches = [name for name, size in builtin_calibrations().items() if tuple(size) == tuple(raw_size)]
    if not matches:
        known = ", ".join(f"{n} ({w} x {h} px)" for n, (w, h) in builtin_calibrations().items())
        raise LfringFileNotFoundError(
            f"no built-in calibration for {raw_size[0]} x {raw_size[1]} px frames (built-in: {known}); "
            "make one with lfring calibrate and pass it with --calib"
        )
    # Read from the package even when the working folder holds a file of the same name.
    cals = [(calibration_from_dict(json.loads((calib_dir() / f"{n}{CALIBRATION_SUFFIX}").read_text()), source_name=n), n)
            for n in matches]
    cals.sort(key=lambda c: c[0].source != "planes")
    return cals[0]


def calibration_for_frame(path) -> tuple[RingCalibration, str] | None:
    """The shipped calibration for the frame file ``path`` and its name, told from the file's
    header before its pixels are read (so that the calibration's Bayer pattern and levels can
    stand in for those the frame lacks); None where the header does not tell the size (camera
    RAW, float samples, unreadable files). Raises as :func:`default_calibration` where no
    shipped calibration has that size."""
    from lfring.io.readers import frame_size

    size = frame_size(path)
    if not size or size == (0, 0):
        return None
    return default_calibration(size)
