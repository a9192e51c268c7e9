"""The record of a rendered raw frame: the frame, its noise-free image and its ground truth."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from lfring.core.geometry import apply_homography, check_reference
from lfring.core.records import record_repr
from lfring.errors import InvalidInputError
from lfring.optics.device import RingDevice
from lfring.optics.views import optical_homographies
from lfring.synth.scene import Scene
from lfring.synth.settings import RenderSettings
from lfring.views import Layout

__all__ = ["RenderResult"]


@dataclass(frozen=True, eq=False)
class RenderResult:
    """A rendered raw frame and its ground truth.

    raw : (H, W) uint8/uint16 Bayer mosaic (or (H, W, 3) without a pattern), as the camera
        outputs it (rotated when ``settings.rotate180``).
    image : (H, W, 3) float32, the noise-free linear image in [0, 1] in the raw frame's
        orientation: what ``(raw - black) / (white - black)`` estimates at every pixel.
    views : (V, h, w, 3) float32, ``image`` cut by the layout (vignetting and defocus included).
    views_sharp : (V, h, w, 3) float32, the same views without defocus or vignetting.
    depth_m : (V, h, w) float32, distance Z of the visible surface from the main lens, NaN where
        no surface is seen.
    layout, device (binned when asked), settings, scene.
    distortion : tuple of LensDistortion (view order), or None
        Each view's distortion by its mini-lens in the pixels of the views ``layout`` cuts (ideal
        pinhole pixel -> recorded pixel); None when the device's lenses are ideal. The
        homographies (:meth:`homographies`) relate the ideal views; :meth:`to_reference` maps
        recorded pixels as the frame shows them.
    """

    raw: np.ndarray
    image: np.ndarray
    views: np.ndarray
    views_sharp: np.ndarray
    depth_m: np.ndarray
    layout: Layout
    device: RingDevice
    settings: RenderSettings
    scene: Scene
    distortion: tuple | None = None

    __repr__ = record_repr

    def homographies(self, depth_m, *, reference="center") -> np.ndarray:
        """Exact ``H_ref_from_view`` of a fronto-parallel plane at ``depth_m``."""
        return optical_homographies(self.device, self.layout, depth_m, reference=reference)

    def to_reference(self, depth_m: float, view: int, points_px, *, reference=0) -> np.ndarray:
        """Where recorded pixels (..., 2) of view ``view`` showing a fronto-parallel plane at
        ``depth_m`` lie in the recorded reference view (a view index, or 'center' for the ideal
        central view): the lens of ``view`` undone, the plane's homography, the reference's lens
        applied. The exact view-to-reference mapping a calibration should reproduce."""
        ref = check_reference(reference, self.layout.num_views)
        if not 0 <= int(view) < self.layout.num_views:
            raise InvalidInputError(f"view must be 0..{self.layout.num_views - 1}, got {view!r}")
        pts = np.asarray(points_px, dtype=np.float64)
        if self.distortion is not None:
            pts = self.distortion[view].undistort(pts)
        out = apply_homography(self.homographies(depth_m, reference=ref)[view], pts)
        if self.distortion is not None and ref != "center":
            out = self.distortion[ref].distort(out)
        return out

    @property
    def black_level(self) -> int:
        """Black level of ``raw`` in counts."""
        return self.settings.effective_black_level

    @property
    def white_level(self) -> int:
        """White level (saturation) of ``raw`` in counts."""
        return self.settings.white_level

    def metadata(self) -> dict:
        """JSON-ready description of the render (device, settings, layout, levels)."""
        out = {
            "device": self.device.to_dict(),
            "ring_distance_m": self.device.ring_distance_m,
            "sensor_distance_m": self.device.sensor_distance_m,
            "entrance_pupil_m": self.device.entrance_pupil_m,
            "settings": _settings_dict(self.settings),
            "black_level": self.black_level,
            "white_level": self.white_level,
            "pattern": self.settings.pattern,
            "layout": self.layout.to_dict(),
        }
        if self.distortion is not None:
            out["distortion"] = {
                "model": "recorded = centre + scale_px D(R, (ideal - centre) / scale_px): Brown-Conrady (k1, k2, p1, p2) "
                         "in the lens's frame (tilt R), ideal and recorded pixels of each view as the layout cuts it",
                "views": [d.to_dict() for d in self.distortion],
            }
        return out


def _settings_dict(settings: RenderSettings) -> dict:
    """The settings as a dict; ``view_falloff`` only when set (so frames without it are
    described as before it existed)."""
    d = asdict(settings)
    if d["view_falloff"] is None:
        del d["view_falloff"]
    return d
