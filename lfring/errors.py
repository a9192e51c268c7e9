"""Exceptions raised by lfring.

Every error lfring raises on purpose is an :class:`LfringError`. Each subclass also inherits the
builtin exception a caller would naturally catch (``ValueError`` for bad values, ``OSError`` for
files), so ``except ValueError`` keeps working in code that does not know about lfring.
"""

from __future__ import annotations

import os
import sys
import warnings

__all__ = [
    "LfringError",
    "InvalidInputError",
    "DepthRangeError",
    "DeviceError",
    "DesignError",
    "FileFormatError",
    "LfringFileNotFoundError",
    "EstimationError",
    "LfringWarning",
    "warn_caller",
]


class LfringError(Exception):
    """Base class of every error lfring raises on purpose."""


class InvalidInputError(LfringError, ValueError):
    """An argument has the wrong value, shape, dtype or unit."""


class DepthRangeError(InvalidInputError):
    """The depth range holds too few hypotheses for the depth method to judge an answer.

    Attributes
    ----------
    zmin_m, zmax_m : float
        The range's ends.
    planes : int
        Its hypotheses.
    motion_px : float
        The views' motion across it, in pixels.
    planes_needed : int or None
        The fewest hypotheses over the same range that the method works with; None where no
        number does (the range itself is too narrow).
    hint : str
        What else may be wrong (millimetres given as metres), '' where nothing is seen.
    """

    def __init__(self, message: str, *, zmin_m: float, zmax_m: float, planes: int, motion_px: float,
                 planes_needed: int | None, hint: str = ""):
        super().__init__(message + hint)
        self.zmin_m, self.zmax_m, self.planes, self.motion_px = zmin_m, zmax_m, planes, motion_px
        self.planes_needed, self.hint = planes_needed, hint

    def narrow(self, remedy: str) -> str:
        """Why the range is too narrow, then ``remedy``: the sentence every entry point words
        its refusal with (the ends named ``zmin_m`` and ``zmax_m``, which the CLI turns into
        its options)."""
        return (f"zmin_m {self.zmin_m:g} .. zmax_m {self.zmax_m:g} m is too narrow to estimate depth over: the views "
                f"move by {self.motion_px:.2g} px across it, and the estimation judges each depth against others more "
                f"than a pixel of motion away; {remedy}{self.hint}")


class DeviceError(InvalidInputError):
    """A device description is incomplete, malformed or physically impossible."""


class DesignError(LfringError, ValueError):
    """The requested design cannot be built (for example the object cannot fit the sensor)."""


class FileFormatError(LfringError, OSError):
    """A file exists but cannot be read as what it claims to be (truncated, corrupt, wrong kind)."""


class LfringFileNotFoundError(LfringError, FileNotFoundError):
    """A file that lfring was asked to read does not exist."""


class EstimationError(LfringError, RuntimeError):
    """An estimator could not produce a trustworthy result from valid input."""


class LfringWarning(UserWarning):
    """Something works but deserves attention (a depth outside the calibrated range, say)."""


_PACKAGE_DIR = os.path.dirname(os.path.abspath(__file__)) + os.sep


def warn_caller(message: str, category: type[Warning] = LfringWarning) -> None:
    """``warnings.warn`` attributed to the first frame outside the lfring package: the user's own
    call, however deep inside lfring the warning arises (a fixed ``stacklevel`` points into
    lfring from every path but one)."""
    level = 2  # the caller of this function
    frame = sys._getframe(1)
    while frame is not None and os.path.abspath(frame.f_code.co_filename).startswith(_PACKAGE_DIR):
        frame = frame.f_back
        level += 1
    warnings.warn(message, category, stacklevel=level)
