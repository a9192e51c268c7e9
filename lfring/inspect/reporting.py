"""Reporting an inspection: :func:`report` turns it into a JSON-ready dict (verdict, coverage,
settings, defects, statistics and the conventions they follow) and :func:`write_report` writes that
report and the drawing of :func:`lfring.inspect.draw.annotate`, atomically.
"""

from __future__ import annotations

from pathlib import Path

from lfring.inspect.draw import annotate
from lfring.inspect.records import InspectionResult

__all__ = ["report", "write_report"]


def report(result: InspectionResult, **metadata) -> dict:
    """The JSON-ready report of an inspection: verdict, coverage, settings, defects, statistics.

    Keyword arguments (input file, calibration name...) are added under ``"input"``. Lengths
    are in the units their keys name; a defect's ``max_deviation_mm`` is positive towards the
    camera (bump) and negative away from it (dent); boxes are in reference-frame pixels.
    ``"verdict"`` is 'pass', 'fail' or 'cannot_judge' (then ``"reason"`` says why; it is null
    otherwise), ``"coverage"`` the fraction of the part checked with confident depth.
    """
    return {
        "passed": bool(result.passed),
        "verdict": result.verdict,
        "coverage": round(float(result.coverage), 4),
        "reason": result.reason,
        "num_defects": len(result.defects),
        "defects": [dict(id=i, **d.to_dict()) for i, d in enumerate(result.defects, 1)],
        "settings": result.settings,
        "stats": result.stats,
        "input": metadata,
        "conventions": {
            "deviation": "target depth minus measured depth: positive towards the camera (bump), negative away (dent)",
            "bbox_px": "x, y, w, h in pixels of the reference frame (x right, y down)",
            "coverage": "fraction of the part (pixels whose surface lies near the plane) checked with confident depth",
        },
    }


def write_report(result: InspectionResult, json_path, *, image_path=None, overwrite: bool = False, **metadata) -> list[Path]:
    """Write the JSON report (and the annotated image when ``image_path`` is given), atomically.

    Existing files are refused unless ``overwrite`` (checked before anything is written).
    Returns the paths written.
    """
    from lfring.io.writers import check_writable, write_image, write_json

    paths = [Path(json_path)] + ([Path(image_path)] if image_path is not None else [])
    check_writable(paths, overwrite=overwrite)
    for p in paths:
        p.parent.mkdir(parents=True, exist_ok=True)
    if image_path is not None:
        write_image(image_path, annotate(result))
    write_json(json_path, report(result, **metadata))
    return paths
