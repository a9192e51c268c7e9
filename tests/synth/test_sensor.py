"""The twin's sensor: every Bayer phase, bit depths and levels, shot and read noise as modelled."""

import numpy as np
import pytest

from lfring.io.bayer import PATTERNS, mosaic
from lfring.synth import Plane, Scene, Texture, render


@pytest.mark.parametrize("pattern", PATTERNS)
def test_bayer_phase_and_rotation(prototype, pattern):
    scene = Scene((Plane(0.5, (0.5, 0.5), Texture("image", name="astronaut")),))
    up = render(prototype, scene, binning=8, pattern=pattern, bit_depth=16)
    rot = render(prototype, scene, binning=8, pattern=pattern, bit_depth=16, rotate180=True)
    np.testing.assert_array_equal(rot.image, up.image[::-1, ::-1])
    for r in (up, rot):
        expect = np.rint(mosaic(r.image, pattern) * (r.white_level - r.black_level) + r.black_level)
        np.testing.assert_array_equal(r.raw, expect.astype(np.uint16))
    # Ground-truth views are the same with and without rotation (they are cut in the erect frame).
    np.testing.assert_array_equal(rot.views, up.views)
    np.testing.assert_array_equal(rot.depth_m, up.depth_m)


@pytest.mark.parametrize("bits, dtype", [(8, np.uint8), (12, np.uint16), (16, np.uint16)])
def test_bit_depths(prototype, bits, dtype):
    scene = Scene((Plane(0.5, (0.5, 0.5), Texture("constant", colors=((1, 1, 1),))),))
    r = render(prototype, scene, binning=8, bit_depth=bits, exposure=2.0)
    assert r.raw.dtype == dtype
    assert int(r.raw.max()) == 2**bits - 1  # over-exposed centre clips at the white level
    assert int(r.raw.min()) == r.black_level  # unlit corners sit at the black level


def test_noise_statistics(prototype):
    grey = Texture("constant", colors=((0.5, 0.5, 0.5),))
    scene = Scene((Plane(0.5, (0.5, 0.5), grey),))
    r = render(prototype, scene, binning=4, pattern="RGGB", bit_depth=16, noise="realistic", seed=1)
    clean = render(prototype, scene, binning=4, pattern="RGGB", bit_depth=16)
    diff = r.raw.astype(np.float64) - clean.raw.astype(np.float64)
    x, y, w, h = r.layout.rects[0]
    sl = np.s_[y + h // 3 : y + 2 * h // 3, x + w // 3 : x + 2 * w // 3]
    mean_signal = (clean.raw[sl].astype(np.float64) - r.black_level) / (r.white_level - r.black_level)
    full_well, read = 8000.0, 3.0
    span = r.white_level - r.black_level
    expected_var = ((mean_signal * full_well + read**2) * (span / full_well) ** 2).mean() + 1 / 12
    assert diff[sl].var() == pytest.approx(expected_var, rel=0.08)
    again = render(prototype, scene, binning=4, pattern="RGGB", bit_depth=16, noise="realistic", seed=1)
    np.testing.assert_array_equal(again.raw, r.raw)
    other = render(prototype, scene, binning=4, pattern="RGGB", bit_depth=16, noise="realistic", seed=2)
    assert np.any(other.raw != r.raw)


@pytest.mark.parametrize("pattern", PATTERNS)
def test_each_bayer_phase_demosaics_back_to_the_rendered_colours(prototype, pattern):
    from lfring.io.demosaic import demosaic
    from lfring.io.raw import RawFrame

    scene = Scene((Plane(0.5, (0.4, 0.4), Texture("image", name="astronaut")),))
    r = render(prototype, scene, binning=4, pattern=pattern, bit_depth=16)
    frame = RawFrame(mosaic=r.raw, pattern=pattern, black_level=r.black_level, white_level=r.white_level, bit_depth=16)
    rgb = demosaic(frame, method="edge-aware")
    lit = np.zeros(rgb.shape[:2], bool)
    for x, y, w, h in r.layout.rects:
        lit[y + 8 : y + h - 8, x + 8 : x + w - 8] = True
    mse = np.mean((rgb[lit] - r.image[lit]) ** 2)
    psnr = 10 * np.log10(1.0 / mse)
    assert psnr > 38.0
    # A wrong phase must fail the same check: demosaicing with the pattern's mirror swaps red and blue.
    wrong = {"RGGB": "BGGR", "BGGR": "RGGB", "GRBG": "GBRG", "GBRG": "GRBG"}[pattern]
    bad = demosaic(RawFrame(mosaic=r.raw, pattern=wrong, black_level=r.black_level, white_level=r.white_level, bit_depth=16))
    assert 10 * np.log10(1.0 / np.mean((bad[lit] - r.image[lit]) ** 2)) < psnr - 10
