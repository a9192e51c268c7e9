"""What the stages need of a calibration, declared once.

Refocusing, depth, inspection and the checks take any object that behaves like a
:class:`lfring.RingCalibration`: the homographies of every view into a reference frame at any
depth, the sub-aperture layout and the depth origin. :class:`Calibration` names that contract,
so a stage asks ``isinstance(obj, Calibration)`` (:func:`check_calibration`) instead of probing
attribute names one by one.
"""

from __future__ import annotations

import os
from typing import Protocol, runtime_checkable

from lfring.errors import InvalidInputError

__all__ = ["Calibration", "check_calibration"]


@runtime_checkable
class Calibration(Protocol):
    """The calibration contract of the processing stages (see :class:`lfring.RingCalibration`):
    ``distortion`` and ``flat_field`` (None, or one per view) are what the split undoes."""

    layout: object
    valid_depth_range_m: tuple
    distortion: object
    flat_field: object

    @property
    def depth_origin_m(self) -> float:
        """z0, the depth origin of the views' projection centres (metres from the main lens)."""

    @property
    def num_views(self) -> int:
        """The number of views V."""

    def homographies(self, depth_m, *, reference="center"):
        """(..., V, 3, 3) ``H_ref_from_view`` at each depth in metres."""

    def check_depth(self, depth_m):
        """The depths as an array, refused when not beyond z0, with a warning outside the valid range."""

    def check_fits(self, views_shape, *, what: str = "views") -> None:
        """Refuse a view stack whose number of views or view size the calibration does not cut."""


def check_calibration(calibration, name: str = "calibration"):
    """``calibration`` if it meets :class:`Calibration`, else a clear error.

    Examples
    --------
    >>> check_calibration(None)
    Traceback (most recent call last):
    ...
    lfring.errors.InvalidInputError: calibration must be a RingCalibration, got NoneType
    """
    if not isinstance(calibration, Calibration):
        hint = " (a name or a file: load it with RingCalibration.load)" if isinstance(calibration, (str, os.PathLike)) else ""
        raise InvalidInputError(f"{name} must be a RingCalibration, got {type(calibration).__name__}{hint}")
    return calibration
