"""demosaic: the Bayer code tables, every method on every pattern, levels, and kornia parity.

Ground truth by construction: a known RGB image is mosaicked with lfring.io.bayer.mosaic
(and written as a DNG for the 'rawpy' method), demosaicked, and compared with the original.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import numpy as np
import pytest
import tifffile
from skimage import data, filters

from lfring.errors import InvalidInputError, LfringFileNotFoundError
from lfring.io.bayer import (
    KORNIA_CFA,
    OPENCV_BAYER_TO_RGB,
    OPENCV_BAYER_TO_RGB_EA,
    OPENCV_BAYER_TO_RGB_VNG,
    PATTERNS,
    mosaic,
    pattern_channels,
)
from lfring.io.demosaic import METHODS, apply_levels, demosaic
from lfring.io.raw import RawFrame, load_raw, write_dng

BLACK, WHITE = 64, 4095  # 12-bit counts
PATCH_COLOURS = np.array([(0.8, 0.3, 0.1), (0.1, 0.8, 0.3), (0.3, 0.1, 0.8)], np.float32)


def _to_counts(linear):
    return np.rint(linear * (WHITE - BLACK) + BLACK).astype(np.uint16)


def _frame(linear_rgb, pattern, method, tmp_path, name="f"):
    """A 12-bit mosaic frame of ``linear_rgb``; through a DNG file for method 'rawpy'."""
    frame = RawFrame(mosaic=_to_counts(mosaic(linear_rgb, pattern)), pattern=pattern,
                     black_level=BLACK, white_level=WHITE, bit_depth=12)
    if method == "rawpy":
        frame = load_raw(write_dng(tmp_path / f"{name}_{pattern}.dng", frame))
    return frame


def _psnr(a, b, peak=1.0):
    return 10 * np.log10(peak**2 / np.mean((a.astype(np.float64) - b) ** 2))


@pytest.fixture(scope="module")
def smooth_rgb():
    """A natural image, blurred (sigma 2 px), 128 x 192, in [0.02, 0.98]."""
    rgb = data.astronaut().astype(np.float32) / 255
    rgb = filters.gaussian(rgb, sigma=2, channel_axis=-1)[100:228, 150:342]
    return (0.02 + 0.96 * rgb).astype(np.float32)


# -- the code tables --------------------------------------------------------------------------


def test_tables_cover_every_pattern_once():
    for table in (OPENCV_BAYER_TO_RGB, OPENCV_BAYER_TO_RGB_EA, OPENCV_BAYER_TO_RGB_VNG, KORNIA_CFA):
        assert tuple(table) == PATTERNS
        assert len(set(table.values())) == 4
    assert KORNIA_CFA == {"RGGB": "BG", "BGGR": "RG", "GRBG": "GB", "GBRG": "GR"}


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("pattern", PATTERNS)
def test_flat_colour_patches_come_back_for_every_pattern_and_method(tmp_path, pattern, method):
    # Three 16-px-wide patches with distinct levels in every channel: a wrong table entry swaps
    # or shifts channels and moves at least one patch far from its colour.
    rgb = np.repeat(np.repeat(PATCH_COLOURS[None], 32, axis=0), 16, axis=1)  # (32, 48, 3)
    out = demosaic(_frame(rgb, pattern, method, tmp_path, "patch"), method=method)
    assert out.shape == (32, 48, 3) and out.dtype == np.float32
    for k, colour in enumerate(PATCH_COLOURS):
        interior = out[4:-4, 16 * k + 4 : 16 * k + 12]
        np.testing.assert_allclose(interior, np.broadcast_to(colour, interior.shape), atol=1e-3)


# -- accuracy ---------------------------------------------------------------------------------

# PSNR (dB) of the 4-px interior of the smooth image, measured on this suite's image with
# OpenCV 5.0, kornia 0.9 and LibRaw (rawpy 0.28): bilinear 50.4, edge-aware 50.4, vng 52.2,
# rawpy (AHD) 56.3, kornia 50.4, identical to 0.1 dB across the four patterns.
PSNR_FLOOR_DB = {"bilinear": 49.5, "edge-aware": 49.5, "vng": 51.5, "rawpy": 55.5, "kornia": 49.5}


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("pattern", PATTERNS)
def test_psnr_of_a_smooth_image(tmp_path, smooth_rgb, pattern, method):
    out = demosaic(_frame(smooth_rgb, pattern, method, tmp_path, "smooth"), method=method)
    b = 4
    assert _psnr(out[b:-b, b:-b], smooth_rgb[b:-b, b:-b]) > PSNR_FLOOR_DB[method]
    assert _psnr(out, smooth_rgb) > 46.0  # borders included


def test_vng_keeps_raw_samples_and_dark_precision(smooth_rgb):
    # OpenCV's VNG is 8-bit only; a dark linear image (peak 5 % of white) must not fall to 8-bit
    # precision: a single 8-bit quantisation of the frame gives 31.8 dB here, lfring 51.8 dB.
    dark = 0.05 * smooth_rgb
    frame = RawFrame(mosaic=np.rint(mosaic(dark, "GRBG") * 65535).astype(np.uint16), pattern="GRBG")
    out = demosaic(frame, method="vng")
    assert _psnr(out[4:-4, 4:-4], dark[4:-4, 4:-4], peak=float(dark.max())) > 50.0
    linear = apply_levels(frame)
    channels = pattern_channels("GRBG")
    for dy in (0, 1):
        for dx in (0, 1):
            np.testing.assert_array_equal(out[dy::2, dx::2, channels[dy, dx]], linear[dy::2, dx::2])


@pytest.mark.parametrize("pattern", PATTERNS)
def test_kornia_matches_opencv_bilinear_in_the_interior(pattern):
    # Same algorithm; OpenCV works on 16-bit integers, kornia in float32, so they agree to one
    # 16-bit step (measured max 1.51e-5) everywhere but the outermost pixel ring, where the two
    # libraries extrapolate differently (up to 0.8 on random data).
    counts = np.random.default_rng(0).integers(0, 4096, (64, 96), dtype=np.uint16)
    frame = RawFrame(mosaic=counts, pattern=pattern, bit_depth=12)
    diff = np.abs(demosaic(frame, method="kornia") - demosaic(frame, method="bilinear"))
    assert diff[1:-1, 1:-1].max() < 2e-5


# -- levels -----------------------------------------------------------------------------------


@pytest.mark.parametrize("method", METHODS)
def test_per_channel_black_levels_are_removed_before_interpolation(tmp_path, method):
    black = (60, 70, 80, 90)  # per CFA position of 'GBRG': G1, B, R, G2
    level = np.float32(0.4)
    counts = np.empty((32, 48), np.uint16)
    for (dy, dx), b in zip(((0, 0), (0, 1), (1, 0), (1, 1)), black):
        counts[dy::2, dx::2] = round(b + float(level) * (WHITE - b))
    frame = RawFrame(mosaic=counts, pattern="GBRG", black_level=black, white_level=WHITE, bit_depth=12)
    expected = level
    if method == "rawpy":
        frame = load_raw(write_dng(tmp_path / "black.dng", frame))
        assert frame.black_level == tuple(float(b) for b in black)
        # LibRaw scales every channel by 1 / (white - smallest black), not by its own range:
        # R (black 80) and B (black 70) come back slightly low, G between its G1 and G2 values.
        expected = np.array([level * (WHITE - b) / (WHITE - 60) for b in (80, 75, 70)])  # R, G, B
    out = demosaic(frame, method=method)
    np.testing.assert_allclose(out[4:-4, 4:-4], np.broadcast_to(expected, out[4:-4, 4:-4].shape), atol=2e-3)


def test_levels_are_applied_and_clipped():
    counts = np.array([[0, 64, 2079, 4095], [5000 % 4096, 4095, 64, 0]], np.uint16)
    counts = np.tile(counts, (2, 1))
    frame = RawFrame(mosaic=counts, pattern="RGGB", black_level=64, white_level=4094, bit_depth=12)
    linear = apply_levels(frame)  # below black -> 0, above white -> 1
    assert linear.dtype == np.float32
    np.testing.assert_allclose(linear[0], [0.0, 0.0, 0.5, 1.0], atol=1e-6)
    frame = RawFrame(mosaic=counts, pattern="RGGB", black_level=64, white_level=2079, bit_depth=12)
    out = demosaic(frame, method="bilinear")
    assert out.min() >= 0.0 and out.max() <= 1.0
    assert out.flags.c_contiguous


@pytest.mark.parametrize("method", METHODS)
def test_rgb_frames_are_only_normalised(method):
    image = np.zeros((4, 6, 3), np.uint16)
    image[..., 0], image[..., 1], image[..., 2] = 1100, 100, 65535
    frame = RawFrame(image=image, black_level=100, white_level=2100)
    out = demosaic(frame, method=method)
    assert out.dtype == np.float32 and out.shape == (4, 6, 3)
    np.testing.assert_allclose(out[0, 0], [0.5, 0.0, 1.0])


def test_constant_frames_demosaic_to_constants():
    for value, expected in ((0, 0.0), (4095, 1.0)):
        frame = RawFrame(mosaic=np.full((6, 8), value, np.uint16), pattern="BGGR", bit_depth=12)
        for method in ("bilinear", "edge-aware", "vng", "kornia"):
            np.testing.assert_array_equal(demosaic(frame, method=method), expected)


def test_rawpy_output_keeps_sensor_orientation(tmp_path):
    # Camera files carry an Orientation tag that LibRaw would apply; the views are cut from the
    # unrotated mosaic, so 'rawpy' must not rotate (asymmetric, non-square content).
    rgb = np.zeros((32, 48, 3), np.float32)
    rgb[:8, :12] = (0.9, 0.1, 0.1)
    rgb[8:, :] = (0.1, 0.1, 0.5)
    counts = _to_counts(mosaic(rgb, "RGGB"))
    tags = [
        (33421, "H", 2, (2, 2), True), (33422, "B", 4, bytes([0, 1, 1, 2]), True),
        (50706, "B", 4, (1, 4, 0, 0), True), (50708, "s", 0, "lfring test", True),
        (50714, "H", 1, BLACK, True), (50717, "H", 1, WHITE, True), (274, "H", 1, 3, True),  # rotate 180
    ]  # fmt: skip
    path = tmp_path / "rotated.dng"
    tifffile.imwrite(path, counts, photometric=32803, subfiletype=0, extratags=tags, metadata=None)
    out = demosaic(load_raw(path), method="rawpy")
    np.testing.assert_allclose(out[2:6, 2:9], np.broadcast_to(rgb[0, 0], (4, 7, 3)), atol=2e-3)
    np.testing.assert_allclose(out[12:-2, 2:-2], np.broadcast_to(rgb[-1, -1], (18, 44, 3)), atol=2e-3)


# -- bad input --------------------------------------------------------------------------------


def test_unknown_method_lists_the_valid_ones():
    frame = RawFrame(mosaic=np.zeros((4, 4), np.uint8), pattern="RGGB")
    with pytest.raises(InvalidInputError, match="unknown demosaic method 'ahd'.*bilinear, edge-aware, vng, rawpy, kornia"):
        demosaic(frame, method="ahd")


def test_demosaic_needs_a_rawframe():
    with pytest.raises(InvalidInputError, match="RawFrame"):
        demosaic(np.zeros((4, 4), np.uint16))


def test_rawpy_method_needs_a_camera_raw_file(tmp_path):
    frame = RawFrame(mosaic=np.zeros((32, 32), np.uint16), pattern="RGGB")
    with pytest.raises(InvalidInputError, match="camera RAW file"):
        demosaic(frame, method="rawpy")
    path = write_dng(tmp_path / "p.dng", frame)
    with pytest.raises(InvalidInputError, match=r"file's own CFA \(RGGB\).*GRBG"):
        demosaic(load_raw(path, pattern="GRBG"), method="rawpy")


def test_importing_the_io_modules_does_not_import_torch():
    code = (
        "import sys, numpy as np\n"
        "import lfring, lfring.io.raw, lfring.io.demosaic\n"
        "from lfring.io.raw import RawFrame\n"
        "f = RawFrame(mosaic=np.zeros((4, 4), np.uint16), pattern='RGGB')\n"
        "lfring.io.demosaic.demosaic(f, method='edge-aware')\n"
        "assert 'torch' not in sys.modules and 'kornia' not in sys.modules\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_rawpy_method_demosaics_the_frames_own_counts(tmp_path):
    # The file gives LibRaw its context; the counts come from the frame, so an edited mosaic
    # (dark-frame subtraction, hot-pixel repair, ...) is what gets demosaicked.
    rgb = np.full((32, 48, 3), 0.2, np.float32)
    frame = load_raw(write_dng(tmp_path / "edit.dng", _frame(rgb, "BGGR", "bilinear", tmp_path)))
    edited = dataclasses.replace(frame, mosaic=_to_counts(mosaic(np.full_like(rgb, 0.6), "BGGR")))
    np.testing.assert_allclose(demosaic(edited, method="rawpy")[4:-4, 4:-4], 0.6, atol=1e-3)


def test_rawpy_method_when_the_file_is_gone(tmp_path):
    path = write_dng(tmp_path / "gone.dng", RawFrame(mosaic=np.zeros((32, 32), np.uint16), pattern="RGGB"))
    frame = load_raw(path)
    path.unlink()
    with pytest.raises(LfringFileNotFoundError, match="gone.dng"):
        demosaic(frame, method="rawpy")


@pytest.mark.parametrize("method", ["bilinear", "edge-aware", "vng"])
def test_a_mosaic_of_one_cfa_block_is_interpolated(method):
    """A 2 x 2 mosaic (one whole CFA block, accepted) came back all black: OpenCV leaves such
    a mosaic's border unset. Mirrored out first, a uniform block stays uniform, and each colour
    takes its own count."""
    from lfring.io.demosaic import demosaic
    from lfring.io.raw import RawFrame

    flat = demosaic(RawFrame(mosaic=np.full((2, 2), 2000, np.uint16), pattern="RGGB", bit_depth=12), method=method)
    np.testing.assert_allclose(flat, 2000 / 4095, atol=2e-4)
    block = np.array([[4000, 2000], [2000, 1000]], np.uint16)  # R, G / G, B
    rgb = demosaic(RawFrame(mosaic=block, pattern="RGGB", bit_depth=12), method=method)
    np.testing.assert_allclose(rgb.mean(axis=(0, 1)), np.array([4000, 2000, 1000]) / 4095, atol=0.02)
