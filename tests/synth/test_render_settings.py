"""Render settings: what the renderer refuses."""

import pytest

from lfring.errors import InvalidInputError
from lfring.synth import Plane, Scene, Texture, render


def _patch_scene(xy, z, size=0.002):
    bright = Texture("constant", colors=((1.0, 1.0, 1.0),))
    return Scene((Plane(z, (size, size), bright, center_m=xy),))


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(binning=0), "binning"),
        (dict(pattern="RGBG"), "RGGB, BGGR, GRBG, GBRG"),
        (dict(bit_depth=10), "bit_depth"),
        (dict(noise="extreme"), "none, low, realistic, high"),
        (dict(exposure=-1), "exposure"),
    ],
)
def test_bad_settings(prototype, kwargs, match):
    with pytest.raises(InvalidInputError, match=match):
        render(prototype, _patch_scene((0, 0), 0.5), **kwargs)
