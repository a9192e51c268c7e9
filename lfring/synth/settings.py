"""How the twin's sensor records a scene: the render settings and the sensor's fixed choices
(noise presets, bit depths, default black levels)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lfring.core.validate import check_choice, check_int, check_number
from lfring.errors import InvalidInputError
from lfring.io.bayer import validate_pattern

__all__ = ["RenderSettings", "NOISE_PRESETS", "BIT_DEPTHS", "DEFAULT_BLACK_LEVELS"]

#: full well (electrons at full scale) and read noise (electrons rms) per output pixel.
NOISE_PRESETS = {"none": None, "low": (30000.0, 1.5), "realistic": (8000.0, 3.0), "high": (2000.0, 6.0)}
BIT_DEPTHS = (8, 12, 16)
#: black level (counts) per bit depth when the settings give none.
DEFAULT_BLACK_LEVELS = {8: 4, 12: 64, 16: 1024}


@dataclass(frozen=True)
class RenderSettings:
    """How the twin's sensor records the scene.

    binning : sensor binning factor (2 gives the 2456 x 1842 px, 2.5 um twin of the prototype).
    pattern : Bayer pattern of the raw frame, or None for an RGB frame.
    bit_depth : 8, 12 or 16 bits per sample. black_level : counts of a dark pixel (default
        4, 64, 1024 for 8, 12, 16 bits); the white level is 2**bit_depth - 1.
    noise : 'none', 'low', 'realistic' or 'high' (see NOISE_PRESETS); gain divides the
        electrons that reach full scale (more gain, more relative noise).
    exposure : fraction of full scale that a white (radiance 1), unvignetted surface reaches.
    rotate180 : output the frame rotated by 180 degrees, as cameras reading the erect image do.
    defocus, vignetting : physical effects, on by default (turn off only to isolate geometry).
    view_falloff : None, or per view (strength, dx, dy): an extra radial fall-off
        ``1 / (1 + strength rho**2)**2`` multiplying that view's optical vignetting, rho being
        the distance from the view's valid-disc centre moved by (dx, dy) disc radii, in disc
        radii. Different per view, it stands for lenses that are not quite alike (scenes that
        should not favour methods assuming equal views); off with ``vignetting=False``.
    """

    binning: int = 1
    pattern: str | None = "RGGB"
    bit_depth: int = 12
    noise: str = "none"
    gain: float = 1.0
    exposure: float = 0.8
    black_level: int | None = None
    rotate180: bool = False
    seed: int = 0
    defocus: bool = True
    vignetting: bool = True
    view_falloff: tuple | None = None

    def __post_init__(self) -> None:
        if self.view_falloff is not None:
            try:
                fall = tuple(tuple(float(v) for v in t) for t in self.view_falloff)
            except (TypeError, ValueError):
                fall = ()
            if len(fall) != 4 or any(len(t) != 3 or not all(np.isfinite(t)) or t[0] < 0 or max(abs(t[1]), abs(t[2])) > 1
                                     for t in fall):
                raise InvalidInputError(
                    "view_falloff must be four (strength >= 0, dx, dy) triples, one per view, with |dx|, |dy| <= 1, "
                    f"got {self.view_falloff!r}")
            object.__setattr__(self, "view_falloff", fall)
        check_int(self.binning, "binning", minimum=1)
        if self.pattern is not None:
            object.__setattr__(self, "pattern", validate_pattern(self.pattern))
        check_choice(self.bit_depth, "bit_depth", BIT_DEPTHS)
        check_choice(self.noise, "noise", NOISE_PRESETS)
        check_number(self.gain, "gain", above=0)
        check_number(self.exposure, "exposure", above=0, maximum=4)
        check_int(self.black_level, "black_level", minimum=0, maximum=self.white_level // 2 - 1, allow_none=True)

    @property
    def white_level(self) -> int:
        """Counts at saturation: ``2**bit_depth - 1``."""
        return 2**self.bit_depth - 1

    @property
    def effective_black_level(self) -> int:
        """The black level in counts: ``black_level``, or the default for ``bit_depth`` when None."""
        return DEFAULT_BLACK_LEVELS[self.bit_depth] if self.black_level is None else int(self.black_level)
