"""The records of an inspection: :class:`Defect` (one region off the target) and
:class:`InspectionResult` (the verdict, the coverage, the defects and the maps behind them).

Immutable (frozen dataclasses): :func:`lfring.inspect.inspect_frame` builds them, and
:mod:`lfring.inspect.report` draws them and turns them into JSON. A deviation is the **target
depth minus the measured depth**, positive towards the camera (a bump) and negative away from it
(a dent).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lfring.core.records import record_repr

__all__ = ["BEYOND_SIGHT_TOLD", "Defect", "InspectionResult"]

#: Where the part may run on beyond two views' sight over at least this share of its area
#: (:attr:`InspectionResult.beyond_sight`), the verdict line and the drawn report say so.
BEYOND_SIGHT_TOLD = 0.005


@dataclass(frozen=True)
class Defect:
    """A region whose depth leaves the target by more than the tolerance.

    Attributes
    ----------
    bbox_px : (x, y, w, h)
        Bounding box in pixels of the reference frame (x right, y down, pixel centres at
        integers).
    centroid_px : (x, y)
    area_px : int
        Pixels in the region (after morphological clean-up).
    area_mm2 : float or None
        The same at the plane's distance, when the optics are known.
    deviation_m : float
        Robust maximum deviation (see ``percentile`` of
        :func:`~lfring.inspect.inspect_frame`), signed: positive towards the camera (bump),
        negative away (dent).
    kind : {'bump', 'dent'}
    mean_confidence : float
        Mean sweep confidence of the region's pixels, in [0, 1].
    beyond_band : bool
        The region holds depths beyond the band searched, on its side: its deviation there was
        not measured, so ``deviation_m`` is a lower bound (a wider band measures it).
    """

    bbox_px: tuple[int, int, int, int]
    centroid_px: tuple[float, float]
    area_px: int
    area_mm2: float | None
    deviation_m: float
    kind: str
    mean_confidence: float
    beyond_band: bool = False

    def to_dict(self) -> dict:
        """The defect as written in the inspection's JSON report.

        Returns
        -------
        dict
            ``kind``, ``bbox_px`` (x, y, w, h), ``centroid_px``, ``area_px``, ``area_mm2`` (None
            without a pixel footprint), ``max_deviation_mm`` (+ towards the camera; at least
            that much where ``beyond_band``), ``beyond_band`` and ``mean_confidence``, rounded
            for reading.
        """
        x, y, w, h = self.bbox_px
        return {
            "kind": self.kind,
            "bbox_px": {"x": x, "y": y, "w": w, "h": h},
            "centroid_px": [round(self.centroid_px[0], 2), round(self.centroid_px[1], 2)],
            "area_px": self.area_px,
            "area_mm2": None if self.area_mm2 is None else round(self.area_mm2, 3),
            "max_deviation_mm": round(self.deviation_m * 1e3, 3),
            "beyond_band": self.beyond_band,
            "mean_confidence": round(self.mean_confidence, 4),
        }


@dataclass(frozen=True, eq=False)
class InspectionResult:
    """The outcome of :func:`~lfring.inspect.inspect_frame`, all maps in the reference frame (h, w).

    Attributes
    ----------
    verdict : {'pass', 'fail', 'cannot_judge'}
        'pass': the part was found, at least ``min_coverage`` of it checked, no defect;
        'fail': defects were found; 'cannot_judge': the frame is too dark or too flat, no
        surface lies near the plane, or too little of the part was checked (see ``reason``).
    coverage : float in [0, 1]
        Fraction of the part (``part``) checked with confident depth; 0 when no part was found
        (the frame too dark or too flat, or nothing near the plane).
    reason : str or None
        Why the frame cannot be judged (None otherwise); it starts with one of 'frame too
        dark', 'frame too flat', 'no surface found at the working plane' or 'too few confident
        pixels'.
    defects : tuple of Defect
        Largest deviation first; empty unless the verdict is 'fail'.
    plane_mask : (h, w) bool
        Pixels photo-consistent at the plane's depth (textured, seen by two views or more).
    consistency : (h, w) float32
        Spread of the views warped to the plane over the local contrast (0: perfectly
        consistent; NaN where fewer than two views see the pixel).
    deviation_m : (h, w) float32
        Target depth minus measured depth, metres (positive towards the camera); NaN where the
        sweep has no depth or the depth left the searched band.
    reliable : (h, w) bool
        Pixels that can raise an alarm (the checked ones): seen by two views or more, confident
        (more so with two views), inside the band and the region of interest.
    deviating : (h, w) bool
        Reliable pixels beyond the tolerance after clean-up (the defects are its components
        of at least ``min_area_px``).
    part : (h, w) bool
        The inspected region: the part, found as :func:`~lfring.inspect.inspect_frame`'s Notes
        say; the coverage is the fraction of it that is ``reliable``.
    beyond_sight : (h, w) bool or None
        Where the part may run on beyond what two views see (near that rim, or seen by one view
        alone): not part of ``part``, and unchecked.
    depth : DepthResult
        The plane sweep over the band.
    refocused : (h, w, C) float32
        The views refocused at the plane.
    settings : dict
        The inspection's parameters (JSON-ready), the band included.
    stats : dict
        Fractions of reliable, on-plane and out-of-band pixels inside the region of interest,
        the median absolute deviation of the reliable ones in metres, the coverage, the part's
        fraction of the region, the textured fraction, the views' 99th percentile of
        luminance and ``beyond_sight``'s area over the part's.
    """

    verdict: str
    coverage: float
    reason: str | None
    defects: tuple
    plane_mask: np.ndarray
    consistency: np.ndarray
    deviation_m: np.ndarray
    reliable: np.ndarray
    deviating: np.ndarray
    part: np.ndarray
    depth: object
    refocused: np.ndarray
    settings: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)
    beyond_sight: np.ndarray | None = None

    __repr__ = record_repr

    @property
    def unchecked(self) -> np.ndarray:
        """(h, w) bool: what was not checked of the part (``part`` less ``reliable``) and where it
        may run on beyond two views' sight (``beyond_sight``): what the drawings hatch."""
        out = np.asarray(self.part, dtype=bool) & ~np.asarray(self.reliable, dtype=bool)
        return out if self.beyond_sight is None else out | np.asarray(self.beyond_sight, dtype=bool)

    @property
    def passed(self) -> bool:
        """True only for the verdict 'pass' (a frame that cannot be judged has not passed)."""
        return self.verdict == "pass"

