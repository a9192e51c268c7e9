"""Inspection at a working plane: which pixels lie on it, which regions leave it, and a report.

An inspection line images parts at a known distance: :func:`inspect_frame` checks that the
surface the views see lies on the working plane (or a golden part's depth) within a tolerance
and gives the verdict 'pass', 'fail' or 'cannot_judge', with the share of the part it checked;
nothing passes that was not checked. A deviation is the target depth minus the measured depth:
positive towards the camera (a bump), negative away (a dent).

Modules
-------
measure
    The check itself: :func:`inspect_frame` (depth band, plane sweep, photo-consistency, the
    part and its coverage, the defects, the verdict), :func:`default_depth_band`,
    :func:`photo_consistency` and the constants of the verdict (:data:`MIN_COVERAGE`,
    :data:`DARK_LEVEL`, ...).
records
    The immutable results: :class:`Defect` and :class:`InspectionResult`.
draw
    :func:`annotate`: the drawing (the plane tinted, the unchecked part hatched, the defect
    boxes, the verdict's banner).
reporting
    :func:`report` (the JSON-ready dict) and :func:`write_report` (the report and the drawing
    written to files, atomically).
"""

from lfring.inspect.measure import (
    DARK_LEVEL,
    MARGIN_PX,
    MIN_CONFIDENCE_TWO_VIEWS,
    MIN_COVERAGE,
    MIN_PART_FRACTION,
    MIN_TEXTURED_FRACTION,
    PART_OPENING_PX,
    PHOTO_MIN_CONTRAST,
    STEP_PX,
    VERDICTS,
    default_depth_band,
    inspect_frame,
    photo_consistency,
)
from lfring.inspect.records import Defect, InspectionResult
from lfring.inspect.draw import annotate
from lfring.inspect.reporting import report, write_report

__all__ = [
    "DARK_LEVEL", "MARGIN_PX", "MIN_CONFIDENCE_TWO_VIEWS", "MIN_COVERAGE", "MIN_PART_FRACTION", "MIN_TEXTURED_FRACTION",
    "PART_OPENING_PX", "PHOTO_MIN_CONTRAST", "STEP_PX", "VERDICTS", "Defect", "InspectionResult", "annotate",
    "default_depth_band", "inspect_frame", "photo_consistency", "report", "write_report",
]
