"""Drawing an inspection: :func:`annotate` shows the refocused image with the working plane
tinted, the part's unchecked pixels hatched, the region of interest, the defect boxes and a banner
with the verdict and the share of the part checked.

Nothing here measures: every figure drawn comes from the
:class:`~lfring.inspect.records.InspectionResult` that :func:`lfring.inspect.inspect_frame` made.
"""

from __future__ import annotations

import cv2
import numpy as np

from lfring.core.validate import check_fraction, check_int
from lfring.inspect.records import BEYOND_SIGHT_TOLD, InspectionResult

__all__ = ["BUMP_RGB", "DENT_RGB", "annotate"]

# Defect boxes: bumps red, dents blue (the annotated image and the viewer's boxes alike).
BUMP_RGB = (255, 40, 40)
DENT_RGB = (40, 140, 255)
_PLANE_RGB = (40, 220, 60)
_ROI_RGB = (255, 220, 0)
_UNCHECKED_RGB = (255, 0, 255)
_JUDGE_RGB = (255, 170, 0)
#: Period and width of the diagonal hatching over the part's unchecked pixels, display pixels.
_HATCH_PERIOD_PX, _HATCH_WIDTH_PX = 8, 2


def _display(image: np.ndarray) -> np.ndarray:
    """Linear float image -> uint8 RGB for viewing: stretched to its 99.5th percentile, gamma 2.2."""
    img = np.asarray(image, dtype=np.float32)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[..., 0]
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    top = float(np.percentile(img, 99.5)) if img.size else 1.0
    img = np.clip(img / max(top, 1e-6), 0.0, 1.0) ** (1 / 2.2)
    return np.rint(img[..., :3] * 255).astype(np.uint8)


def annotate(result: InspectionResult, *, tint: float = 0.35, scale: int = 1) -> np.ndarray:
    """Draw an inspection: the refocused image, the working plane tinted green, the part's
    unchecked pixels hatched magenta, the region of interest in yellow, defect boxes (bumps
    red, dents blue) labelled with their number and deviation in mm, and a banner with the
    verdict (PASS, FAIL or CANNOT JUDGE and why) and "checked N % of the part".

    Parameters
    ----------
    result : InspectionResult
    tint : float in [0, 1]
        Opacity of the plane's tint.
    scale : int
        Integer upscaling before drawing, for legible labels on small frames.

    Returns
    -------
    (h * scale, w * scale, 3) uint8 RGB
    """
    tint = check_fraction(tint, "tint")
    scale = check_int(scale, "scale", minimum=1)
    img = _display(result.refocused).astype(np.float32)
    m = result.plane_mask
    img[m] = (1 - tint) * img[m] + tint * np.array(_PLANE_RGB, np.float32)
    out = np.rint(img).astype(np.uint8)
    unchecked = result.unchecked.astype(np.uint8)
    if scale > 1:
        out = cv2.resize(out, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
        unchecked = cv2.resize(unchecked, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    out = np.ascontiguousarray(out)
    h, w = out.shape[:2]
    yy, xx = np.mgrid[:h, :w]
    out[(unchecked > 0) & ((xx + yy) % _HATCH_PERIOD_PX < _HATCH_WIDTH_PX)] = _UNCHECKED_RGB
    thick = max(1, round(min(h, w) / 350))
    font = 0.4 * max(1.0, min(h, w) / 500)
    roi = result.settings.get("roi_px")
    if roi:
        x, y, rw, rh = (v * scale for v in roi)
        cv2.rectangle(out, (x, y), (x + rw - 1, y + rh - 1), _ROI_RGB, thick)
    s = result.settings
    if result.verdict == "pass":
        verdict, banner_rgb = "PASS", _PLANE_RGB
    elif result.verdict == "fail":
        verdict, banner_rgb = f"FAIL: {len(result.defects)} defect(s)", BUMP_RGB
    else:
        verdict, banner_rgb = f"CANNOT JUDGE: {(result.reason or '').split(':')[0]}", _JUDGE_RGB
    beyond = float(result.stats.get("beyond_sight_fraction") or 0.0)
    line = int(22 * font / 0.4)
    texts = [verdict, f"checked {result.coverage * 100:.0f} % of the part (unchecked: hatched)"]
    if beyond >= BEYOND_SIGHT_TOLD and result.verdict != "cannot_judge":
        texts.append(f"it may run on beyond two views' sight: +{100 * beyond:.0f} % (hatched)")
    texts.append(f"plane {s['plane_m']:.3f} m  tolerance {s['tolerance_m'] * 1e3:.1f} mm")
    banner = [(text, (8, (i + 1) * line + 4 * i)) for i, text in enumerate(texts)]
    banner_box = _union([_text_box(t, org, font * 1.2, thick) for t, org in banner])
    for i, d in enumerate(result.defects, 1):
        x, y, bw, bh = (v * scale for v in d.bbox_px)
        colour = BUMP_RGB if d.kind == "bump" else DENT_RGB
        cv2.rectangle(out, (x, y), (x + bw - 1, y + bh - 1), colour, thick)
        label = f"{i} {d.kind} {'>' if d.beyond_band else ''}{d.deviation_m * 1e3:+.1f} mm"
        _text(out, label, _label_origin(label, (x, y, bw, bh), font, thick, banner_box, (w, h)), font, colour, thick)
    for text, org in banner:
        _text(out, text, org, font * 1.2, banner_rgb, thick)
    return out


def _text_box(text, org, font, thick) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) that ``_text`` covers when drawn at ``org`` (its baseline's start)."""
    (tw, th), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, font, thick + 2)
    return org[0] - thick, org[1] - th - thick, org[0] + tw + thick, org[1] + base + thick


def _union(boxes):
    return min(b[0] for b in boxes), min(b[1] for b in boxes), max(b[2] for b in boxes), max(b[3] for b in boxes)


def _overlap(a, b) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def _label_origin(label, box, font, thick, banner_box, size_wh) -> tuple[int, int]:
    """Where a defect's label goes: above its box, else below it, else below the banner; never
    over the banner and inside the image where it fits."""
    x, y, bw, bh = box
    (tw, th), base = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, font, thick + 2)
    x = max(0, min(x, size_wh[0] - tw - 1))
    for ty in (y - 4, y + bh + th + 4):
        if th <= ty <= size_wh[1] - base - 1 and not _overlap(_text_box(label, (x, ty), font, thick), banner_box):
            return x, ty
    return x, banner_box[3] + th + 4


def _text(img, text, org, font, colour, thick) -> None:
    """Text with a dark outline, legible on any background."""
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, font, (0, 0, 0), thick + 2, cv2.LINE_AA)
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, font, colour, thick, cv2.LINE_AA)
