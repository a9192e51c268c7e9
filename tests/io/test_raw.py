"""load_raw and RawFrame: camera RAW (DNG through rawpy), Bayer and RGB PNG/TIFF, and bad input.

All files are generated in tmp_path: DNGs with tifffile (uncompressed CFA, DNG 1.4 tags),
PNGs with OpenCV, TIFFs with tifffile.
"""

from __future__ import annotations

import dataclasses
import json

import cv2
import numpy as np
import pytest
import tifffile

from lfring.errors import FileFormatError, InvalidInputError, LfringError, LfringFileNotFoundError
from lfring.io.bayer import PATTERNS, mosaic
from lfring.io.raw import RawFrame, load_raw, sidecar_path, write_dng

CFA_CODE = {"R": 0, "G": 1, "B": 2}
FLAT_RGB_COUNTS = {"R": 3000, "G": 1500, "B": 700}  # distinct counts per colour


def _counts(shape=(32, 48), seed=0, low=64, high=4096):
    return np.random.default_rng(seed).integers(low, high, shape, dtype=np.uint16)


def _write_tiff_dng(path, data, tags, photometric=32803):
    """A DNG with hand-picked tags (for the layouts write_dng does not produce)."""
    base = [
        (50706, "B", 4, (1, 4, 0, 0), True),  # DNGVersion
        (50708, "s", 0, "lfring test", True),  # UniqueCameraModel
        (50714, "H", 1, 64, True),  # BlackLevel
        (50717, "H", 1, 4095, True),  # WhiteLevel
    ]
    # Samples per pixel said explicitly: newer tifffile releases no longer take the last axis
    # of a LinearRaw image as its samples, and write a stack of grey pages instead.
    contig = {"planarconfig": "contig"} if data.ndim == 3 else {}
    tifffile.imwrite(path, data, photometric=photometric, subfiletype=0, extratags=base + tags, metadata=None, **contig)
    return path


def _cfa_tags(pattern_codes, dim=(2, 2)):
    return [(33421, "H", 2, dim, True), (33422, "B", len(pattern_codes), bytes(pattern_codes), True)]


def _flat_colour_mosaic(pattern, shape=(32, 48)):
    colours = np.array([[FLAT_RGB_COUNTS[c] for c in "RGB"]], dtype=np.uint16)
    return mosaic(np.broadcast_to(colours, (*shape, 3)), pattern)


def _assert_names_file(exc_info, path):
    assert str(path) in str(exc_info.value)


# -- camera RAW (DNG) -------------------------------------------------------------------------


@pytest.mark.parametrize("pattern", PATTERNS)
def test_dng_round_trip_reads_pattern_and_levels_from_metadata(tmp_path, pattern):
    counts = _counts()
    source = RawFrame(mosaic=counts, pattern=pattern, black_level=64, white_level=4095, bit_depth=12)
    path = write_dng(tmp_path / f"frame_{pattern}.dng", source)

    frame = load_raw(path)

    assert frame.pattern == pattern
    assert frame.black_level == 64.0
    assert frame.white_level == 4095.0
    assert frame.bit_depth == 12
    assert frame.file_format == "camera_raw"
    assert frame.path == path
    assert frame.image is None
    assert frame.mosaic.dtype == np.uint16
    np.testing.assert_array_equal(frame.mosaic, counts)


def test_dng_mosaic_is_a_read_only_copy_that_outlives_the_decoder(tmp_path):
    counts = _counts(seed=3)
    frame = load_raw(write_dng(tmp_path / "f.dng", RawFrame(mosaic=counts, pattern="RGGB", bit_depth=12)))
    assert frame.mosaic.base is None or frame.mosaic.base.flags.owndata
    with pytest.raises(ValueError):
        frame.mosaic[0, 0] = 1
    np.testing.assert_array_equal(frame.mosaic, counts)


def test_dng_per_channel_black_levels_come_back_in_pattern_order(tmp_path):
    black = (60.0, 61.0, 62.0, 63.0)  # R, G1, G2, B for GRBG positions (0,0),(0,1),(1,0),(1,1)
    source = RawFrame(mosaic=_counts(), pattern="GRBG", black_level=black, white_level=4000, bit_depth=12)
    frame = load_raw(write_dng(tmp_path / "bl.dng", source))
    assert frame.black_level == black
    np.testing.assert_array_equal(frame.black_level_2x2, [[60, 61], [62, 63]])
    assert frame.white_level == 4000.0


def test_dng_arguments_override_metadata(tmp_path):
    path = write_dng(tmp_path / "o.dng", RawFrame(mosaic=_counts(), pattern="RGGB", black_level=64, bit_depth=12))
    frame = load_raw(path, pattern="bggr", black_level=(10, 11, 12, 13), white_level=4000)
    assert frame.pattern == "BGGR"
    assert frame.black_level == (10.0, 11.0, 12.0, 13.0)
    assert frame.white_level == 4000.0
    assert frame.bit_depth == 12


def test_dng_pattern_is_anchored_at_the_visible_area(tmp_path):
    # DNG's CFAPattern is relative to the ActiveArea origin, here (1, 1): the visible mosaic must
    # still carry the right colour at each position, whatever margins LibRaw chooses.
    full = np.zeros((34, 50), np.uint16)
    full[1:33, 1:49] = _flat_colour_mosaic("RGGB")
    tags = _cfa_tags([0, 1, 1, 2]) + [(50829, "I", 4, (1, 1, 33, 49), True)]  # ActiveArea
    frame = load_raw(_write_tiff_dng(tmp_path / "aa.dng", full, tags))

    assert frame.mosaic.shape[0] % 2 == 0 and frame.mosaic.shape[1] % 2 == 0
    for dy in (0, 1):
        for dx in (0, 1):
            colour = frame.pattern[2 * dy + dx]
            assert np.all(frame.mosaic[dy::2, dx::2] == FLAT_RGB_COUNTS[colour])


def test_dng_odd_visible_area_is_cropped_to_whole_cfa_blocks(tmp_path):
    # ActiveArea (0, 0, 31, 47) leaves a 47 x 31 visible area: the last row and column go.
    counts = _counts(shape=(32, 48), seed=5)
    tags = _cfa_tags([1, 0, 2, 1]) + [(50829, "I", 4, (0, 0, 31, 47), True)]
    frame = load_raw(_write_tiff_dng(tmp_path / "odd.dng", counts, tags))
    assert frame.shape == (30, 46)
    assert frame.pattern == "GRBG"
    np.testing.assert_array_equal(frame.mosaic, counts[:30, :46])


def test_dng_stored_with_a_tiff_suffix_is_read_as_camera_raw(tmp_path):
    counts = _counts(seed=7)
    path = write_dng(tmp_path / "frame.tif", RawFrame(mosaic=counts, pattern="GBRG", black_level=64, bit_depth=12))
    frame = load_raw(path)
    assert frame.file_format == "camera_raw"
    assert frame.pattern == "GBRG"
    np.testing.assert_array_equal(frame.mosaic, counts)


def test_stacked_linear_raw_dng_is_refused_clearly(tmp_path):
    data = np.random.default_rng(0).integers(64, 4096, (32, 48, 3), dtype=np.uint16)
    path = _write_tiff_dng(tmp_path / "linear.dng", data, [], photometric=34892)  # LinearRaw
    with pytest.raises(FileFormatError, match=r"stacked raw image.*not a 2 x 2 Bayer mosaic") as info:
        load_raw(path)
    _assert_names_file(info, path)


def test_xtrans_dng_is_refused_clearly(tmp_path):
    xtrans = [1, 1, 0, 1, 1, 2, 1, 1, 2, 1, 1, 0, 2, 0, 1, 0, 2, 1,
              1, 1, 2, 1, 1, 0, 1, 1, 0, 1, 1, 2, 0, 2, 1, 2, 0, 1]  # fmt: skip
    path = _write_tiff_dng(tmp_path / "xtrans.dng", _counts(), _cfa_tags(xtrans, dim=(6, 6)))
    with pytest.raises(FileFormatError, match=r"6 x 6 pixels \(X-Trans.*2 x 2 Bayer") as info:
        load_raw(path)
    _assert_names_file(info, path)


def test_cmyg_dng_is_refused_clearly(tmp_path):
    tags = _cfa_tags([3, 4, 5, 1]) + [(50710, "B", 4, (3, 4, 5, 1), True)]  # CFAPlaneColor CMYG
    path = _write_tiff_dng(tmp_path / "cmyg.dng", _counts(), tags)
    with pytest.raises(FileFormatError, match="not a 2 x 2 R/G/B Bayer pattern") as info:
        load_raw(path)
    _assert_names_file(info, path)


@pytest.mark.parametrize("suffix", [".dng", ".nef"])
def test_random_bytes_with_a_raw_suffix(tmp_path, suffix):
    path = tmp_path / f"noise{suffix}"
    path.write_bytes(np.random.default_rng(1).bytes(5000))
    with pytest.raises(FileFormatError, match="not a camera RAW file LibRaw can decode") as info:
        load_raw(path)
    _assert_names_file(info, path)


def test_truncated_dng(tmp_path):
    whole = write_dng(tmp_path / "whole.dng", RawFrame(mosaic=_counts(), pattern="RGGB", bit_depth=12)).read_bytes()
    path = tmp_path / "cut.dng"
    path.write_bytes(whole[: len(whole) // 2])
    with pytest.raises(FileFormatError, match="truncated") as info:
        load_raw(path)
    _assert_names_file(info, path)


def test_black_level_at_or_above_white_level_is_refused(tmp_path):
    path = write_dng(tmp_path / "lv.dng", RawFrame(mosaic=_counts(), pattern="RGGB", bit_depth=12))
    with pytest.raises(InvalidInputError, match="black_level") as info:
        load_raw(path, black_level=4095, white_level=4095)
    _assert_names_file(info, path)


def test_write_dng_refuses_what_libraw_would_ignore(tmp_path):
    with pytest.raises(InvalidInputError, match="22 x 22"):
        write_dng(tmp_path / "tiny.dng", RawFrame(mosaic=np.zeros((8, 8), np.uint16), pattern="RGGB"))
    with pytest.raises(InvalidInputError, match="mosaic"):
        write_dng(tmp_path / "rgb.dng", RawFrame(image=np.zeros((32, 32, 3), np.uint8)))


# -- files that are not there or not images ---------------------------------------------------


def test_missing_file(tmp_path):
    path = tmp_path / "nope.dng"
    with pytest.raises(LfringFileNotFoundError, match="no such file") as info:
        load_raw(path)
    assert isinstance(info.value, FileNotFoundError)
    _assert_names_file(info, path)


def test_directory_is_not_a_frame(tmp_path):
    path = tmp_path / "dir.png"
    path.mkdir()
    with pytest.raises(FileFormatError, match="not a regular file") as info:
        load_raw(path)
    _assert_names_file(info, path)


def test_unsupported_suffix(tmp_path):
    path = tmp_path / "frame.jpg"
    path.write_bytes(b"\xff\xd8\xff\xe0")
    with pytest.raises(FileFormatError, match=r"unsupported file type '\.jpg'") as info:
        load_raw(path)
    _assert_names_file(info, path)


def test_path_of_the_wrong_type():
    with pytest.raises(InvalidInputError, match="file path"):
        load_raw(42)


# -- Bayer PNG / TIFF -------------------------------------------------------------------------


@pytest.mark.parametrize(("dtype", "bits"), [(np.uint8, 8), (np.uint16, 16)])
def test_bayer_png_with_pattern_argument_and_default_levels(tmp_path, dtype, bits):
    counts = np.random.default_rng(2).integers(0, 2**bits, (24, 36), dtype=dtype)
    path = tmp_path / "bayer.png"
    assert cv2.imwrite(str(path), counts)
    frame = load_raw(path, pattern="GBRG")
    assert (frame.pattern, frame.bit_depth, frame.black_level, frame.white_level) == ("GBRG", bits, 0.0, 2.0**bits - 1)
    assert frame.file_format == "png"
    assert frame.mosaic.dtype == dtype
    np.testing.assert_array_equal(frame.mosaic, counts)


def test_bayer_png_levels_from_sidecar_and_arguments_win(tmp_path):
    counts = np.random.default_rng(3).integers(0, 4096, (24, 36), dtype=np.uint16)
    path = tmp_path / "frame.png"
    cv2.imwrite(str(path), counts)
    side = sidecar_path(path)
    assert side.name == "frame.png.json"
    side.write_text(json.dumps({"pattern": "BGGR", "black_level": [64, 65, 66, 67], "white_level": 4000,
                                "bit_depth": 12, "exposure_s": 0.01}))

    frame = load_raw(path)
    assert frame.pattern == "BGGR"
    assert frame.black_level == (64.0, 65.0, 66.0, 67.0)
    assert (frame.white_level, frame.bit_depth) == (4000.0, 12)

    frame = load_raw(path, pattern="RGGB", black_level=10, white_level=4095)
    assert (frame.pattern, frame.black_level, frame.white_level) == ("RGGB", 10.0, 4095.0)


def test_a_stem_json_is_not_the_sidecar(tmp_path):
    path = tmp_path / "frame.png"
    cv2.imwrite(str(path), np.zeros((4, 4), np.uint8))
    (tmp_path / "frame.json").write_text(json.dumps({"pattern": "RGGB"}))
    with pytest.raises(InvalidInputError, match="no Bayer pattern"):
        load_raw(path)


def test_grey_png_without_any_pattern_says_how_to_give_one(tmp_path):
    path = tmp_path / "grey.png"
    cv2.imwrite(str(path), np.zeros((8, 8), np.uint8))
    with pytest.raises(InvalidInputError, match=r"no Bayer pattern.*pattern=.*grey\.png\.json") as info:
        load_raw(path)
    _assert_names_file(info, path)


def test_unknown_pattern_name_from_argument_and_from_sidecar(tmp_path):
    path = tmp_path / "p.png"
    cv2.imwrite(str(path), np.zeros((8, 8), np.uint8))
    with pytest.raises(InvalidInputError, match=r"unknown Bayer pattern 'RGBG'.*RGGB, BGGR, GRBG, GBRG") as info:
        load_raw(path, pattern="RGBG")
    _assert_names_file(info, path)
    sidecar_path(path).write_text(json.dumps({"pattern": "XYZW"}))
    with pytest.raises(InvalidInputError, match=r"'XYZW' \(from sidecar p\.png\.json\)"):
        load_raw(path)


@pytest.mark.parametrize("shape", [(7, 8), (8, 9), (3, 2)])
def test_odd_mosaic_size_is_refused(tmp_path, shape):
    path = tmp_path / "odd.png"
    cv2.imwrite(str(path), np.zeros(shape, np.uint8))
    with pytest.raises(InvalidInputError, match="even width and height") as info:
        load_raw(path, pattern="RGGB")
    _assert_names_file(info, path)


@pytest.mark.parametrize("shape", [(1, 1), (1, 2), (4, 1)])
def test_a_mosaic_without_a_whole_cfa_block_is_refused_without_a_crop_to_nothing(tmp_path, shape):
    path = tmp_path / "tiny.png"
    cv2.imwrite(str(path), np.zeros(shape, np.uint8))
    with pytest.raises(InvalidInputError, match="at least one whole 2 x 2 CFA block") as info:
        load_raw(path, pattern="RGGB")
    assert "crop" not in str(info.value)
    _assert_names_file(info, path)


@pytest.mark.parametrize("name", ["empty.png", "empty.tif", "empty.dng"])
def test_an_empty_file_is_said_to_be_empty(tmp_path, name):
    path = tmp_path / name
    path.write_bytes(b"")
    with pytest.raises(FileFormatError, match=r"the file is empty \(0 bytes\)") as info:
        load_raw(path)
    _assert_names_file(info, path)


@pytest.mark.parametrize(("kwargs", "sidecar"), [({"black_level": 255}, None), ({}, {"black_level": 200, "white_level": 100})])
def test_black_not_below_white_is_refused_and_names_the_source(tmp_path, kwargs, sidecar):
    path = tmp_path / "lv.png"
    cv2.imwrite(str(path), np.zeros((8, 8), np.uint8))
    if sidecar is not None:
        sidecar_path(path).write_text(json.dumps(sidecar))
    with pytest.raises(InvalidInputError, match="black_level") as info:
        load_raw(path, pattern="RGGB", **kwargs)
    _assert_names_file(info, path)
    assert ("sidecar" in str(info.value)) == (sidecar is not None)


def test_white_level_above_the_bit_depth_is_refused(tmp_path):
    path = tmp_path / "w.png"
    cv2.imwrite(str(path), np.zeros((8, 8), np.uint8))
    with pytest.raises(InvalidInputError, match=r"white_level 300 .* \(0, 255\]"):
        load_raw(path, pattern="RGGB", white_level=300)


def test_counts_above_the_declared_bit_depth_suggest_msb_alignment(tmp_path):
    path = tmp_path / "msb.png"
    counts = (np.random.default_rng(4).integers(0, 4096, (8, 8)) << 4).astype(np.uint16)
    counts[0, 0] = 4095 << 4
    cv2.imwrite(str(path), counts)
    with pytest.raises(InvalidInputError, match=r"MSB-aligned .* shifted left by 4 bits") as info:
        load_raw(path, pattern="RGGB", bit_depth=12)
    _assert_names_file(info, path)


def _msb_aligned(tmp_path, sidecar):
    """8 x 8 12-bit counts shifted left by 4 bits in a 16-bit PNG, with ``sidecar`` (12-bit)."""
    path = tmp_path / "msb.png"
    counts = (np.random.default_rng(5).integers(64, 4096, (8, 8)) << 4).astype(np.uint16)
    counts[0, 0] = 4095 << 4
    cv2.imwrite(str(path), counts)
    sidecar_path(path).write_text(json.dumps(sidecar))
    return path


def test_counts_above_the_sidecars_bit_depth_name_the_sidecar_and_what_to_change(tmp_path):
    path = _msb_aligned(tmp_path, {"pattern": "RGGB", "black_level": 64, "white_level": 4095, "bit_depth": 12})
    with pytest.raises(InvalidInputError) as info:
        load_raw(path)
    message = str(info.value)
    _assert_names_file(info, path)
    assert "counts reach 65520, above 4095, the largest 12-bit value" in message
    assert 'the 12 bits come from the sidecar msb.png.json ("bit_depth": 12)' in message
    assert 'set "bit_depth": 16 in msb.png.json with the levels scaled by 16 ("white_level": 65520, "black_level": 1024)' in message
    assert "pass black_level=... and white_level=... scaled by 16 (1024 and 65520 counts)" in message
    assert 'otherwise correct "bit_depth" in msb.png.json' in message and "bit_depth=" not in message


def test_counts_above_the_sidecars_bit_depth_scale_per_channel_black_levels(tmp_path):
    path = _msb_aligned(tmp_path, {"pattern": "RGGB", "black_level": [64, 60, 60, 66], "bit_depth": 12})
    with pytest.raises(InvalidInputError) as info:
        load_raw(path)
    assert '"white_level": 65520, "black_level": [1024,960,960,1056]' in str(info.value)
    assert "(1024,960,960,1056 and 65520 counts)" in str(info.value)


def test_given_levels_above_a_stale_sidecar_bit_depth_read_the_frame(tmp_path):
    """Counts and a given white level both above the sidecar's bit depth: the given levels win
    over the sidecar, and the bit depth follows the white level."""
    path = _msb_aligned(tmp_path, {"pattern": "RGGB", "black_level": 64, "white_level": 4095, "bit_depth": 12})
    frame = load_raw(path, white_level=65520, black_level=1024)
    assert (frame.bit_depth, frame.white_level, frame.black_level) == (16, 65520.0, 1024.0)
    # The sidecar's black level is on its 12-bit scale too: the white level alone is not enough.
    with pytest.raises(InvalidInputError, match=r"pass black_level=\.\.\. and white_level=\.\.\. scaled by 16"):
        load_raw(path, white_level=65520)
    # ... unless that black level is 0 (the same on every scale).
    path = _msb_aligned(tmp_path, {"pattern": "RGGB", "black_level": 0, "bit_depth": 12})
    assert load_raw(path, white_level=65520).bit_depth == 16


def test_a_given_white_level_alone_does_not_outvote_the_sidecars_bit_depth(tmp_path):
    """Counts within the sidecar's 12 bits: its bit depth stands, and a white level above it is
    refused (the data do not reach it)."""
    path = tmp_path / "twelve.png"
    cv2.imwrite(str(path), np.full((8, 8), 4000, np.uint16))
    sidecar_path(path).write_text(json.dumps({"pattern": "RGGB", "bit_depth": 12}))
    with pytest.raises(InvalidInputError, match=r"white_level 65520 .* \(0, 4095\]"):
        load_raw(path, white_level=65520, black_level=0)


def test_counts_above_a_given_bit_depth_name_the_argument(tmp_path):
    """The levels suggested are those given with the bit depth (they override the sidecar's)."""
    path = _msb_aligned(tmp_path, {"pattern": "RGGB", "black_level": 1000, "white_level": 60000, "bit_depth": 16})
    with pytest.raises(InvalidInputError) as info:
        load_raw(path, bit_depth=12, white_level=4095, black_level=64)
    message = str(info.value)
    assert "the 12 bits come from the bit_depth argument" in message and "sidecar" not in message
    assert "pass bit_depth=16 with black_level and white_level scaled by 16 (1024 and 65520 counts)" in message
    # A sidecar's levels are of its own bit depth (16 here), not of the one given: scaled they were
    # offered as 16000 and 60000 (its 1000 and 60000 were 16-bit counts already). Without levels
    # given, a 12-bit frame's own: 0 and 4095, scaled.
    with pytest.raises(InvalidInputError) as info:
        load_raw(path, bit_depth=12)
    assert "scaled by 16 (0 and 65520 counts); otherwise fix bit_depth" in str(info.value)
    # A sidecar that names no bit depth holds levels of the file's own (16 bits): not scaled either.
    path = _msb_aligned(tmp_path, {"pattern": "RGGB", "black_level": 1000, "white_level": 60000})
    with pytest.raises(InvalidInputError) as info:
        load_raw(path, bit_depth=12)
    assert "scaled by 16 (0 and 65520 counts); otherwise fix bit_depth" in str(info.value)


@pytest.mark.parametrize("value", [0, 1234])
def test_constant_frames_are_data_not_errors(tmp_path, value):
    path = tmp_path / "flat.png"
    cv2.imwrite(str(path), np.full((8, 10), value, np.uint16))
    frame = load_raw(path, pattern="RGGB")
    assert np.all(frame.mosaic == value)


def test_bayer_tiff_and_grey_alpha_png(tmp_path):
    counts = np.random.default_rng(5).integers(0, 65536, (12, 16), dtype=np.uint16)
    tifffile.imwrite(tmp_path / "b.tiff", counts)
    frame = load_raw(tmp_path / "b.tiff", pattern="GRBG")
    assert (frame.file_format, frame.bit_depth) == ("tiff", 16)
    np.testing.assert_array_equal(frame.mosaic, counts)

    grey_alpha = np.stack([counts[..., None].astype(np.uint8)[..., 0], np.full((12, 16), 255, np.uint8)], -1)
    png_la = tmp_path / "la.png"
    _write_png(png_la, grey_alpha, colour_type=4)
    frame = load_raw(png_la, pattern="GRBG")
    np.testing.assert_array_equal(frame.mosaic, grey_alpha[..., 0])


def _write_png(path, pixels, colour_type):
    """A minimal 8-bit PNG of any colour type (OpenCV writes no grey + alpha)."""
    import struct
    import zlib

    h, w = pixels.shape[:2]
    raw = b"".join(b"\x00" + pixels[y].tobytes() for y in range(h))

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", w, h, 8, colour_type, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))
    return path


def test_packed_12_bit_tiff_sets_bit_depth_or_names_the_missing_codec(tmp_path):
    counts = np.random.default_rng(6).integers(0, 4096, (8, 12), dtype=np.uint16)
    pairs = counts.reshape(-1, 2).astype(np.uint32)
    packed = np.stack(
        [pairs[:, 0] >> 4, ((pairs[:, 0] & 15) << 4) | (pairs[:, 1] >> 8), pairs[:, 1] & 255], -1
    ).astype(np.uint8)
    path = tmp_path / "b12.tif"
    with tifffile.TiffWriter(path) as tif:
        tif.write(iter([packed.tobytes()]), shape=(8, 12), dtype="uint16", bitspersample=12,
                  photometric="minisblack", rowsperstrip=8)
    try:
        import imagecodecs  # noqa: F401  (tifffile needs it to unpack 12-bit samples)
    except ImportError:
        with pytest.raises(FileFormatError, match="imagecodecs") as info:
            load_raw(path, pattern="RGGB")
        _assert_names_file(info, path)
        return
    frame = load_raw(path, pattern="RGGB")
    assert (frame.bit_depth, frame.white_level) == (12, 4095.0)
    np.testing.assert_array_equal(frame.mosaic, counts)


# -- RGB PNG / TIFF ---------------------------------------------------------------------------


def _asymmetric_rgb(dtype, shape=(6, 10)):
    high = np.iinfo(dtype).max
    rgb = np.zeros((*shape, 3), dtype)
    rgb[..., 0] = high  # red everywhere
    rgb[..., 1] = high // 3
    rgb[0, :, 2] = high // 7  # blue only on the top row
    return rgb


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_rgb_png_comes_back_in_rgb_order(tmp_path, dtype):
    rgb = _asymmetric_rgb(dtype)
    path = tmp_path / "rgb.png"
    cv2.imwrite(str(path), rgb[..., ::-1])  # OpenCV writes BGR
    frame = load_raw(path)
    assert frame.mosaic is None and frame.pattern is None
    assert (frame.bit_depth, frame.white_level) == (np.iinfo(dtype).bits, float(np.iinfo(dtype).max))
    np.testing.assert_array_equal(frame.image, rgb)


def test_rgba_png_and_tiff_drop_alpha(tmp_path):
    rgb = _asymmetric_rgb(np.uint16)
    alpha = np.full(rgb.shape[:2] + (1,), 1000, np.uint16)
    cv2.imwrite(str(tmp_path / "rgba.png"), np.concatenate([rgb[..., ::-1], alpha], -1))
    np.testing.assert_array_equal(load_raw(tmp_path / "rgba.png").image, rgb)
    tifffile.imwrite(tmp_path / "rgba.tif", np.concatenate([rgb, alpha], -1), photometric="rgb", extrasamples=["unassalpha"])
    np.testing.assert_array_equal(load_raw(tmp_path / "rgba.tif").image, rgb)
    tifffile.imwrite(tmp_path / "rgb.tif", rgb, photometric="rgb")
    assert load_raw(tmp_path / "rgb.tif").file_format == "tiff"


def test_rgb_image_with_a_pattern_is_refused(tmp_path):
    path = tmp_path / "rgb.png"
    cv2.imwrite(str(path), _asymmetric_rgb(np.uint8))
    with pytest.raises(InvalidInputError, match="already RGB") as info:
        load_raw(path, pattern="RGGB")
    _assert_names_file(info, path)


@pytest.mark.parametrize("shape", [(8, 8), (8, 8, 3)])
def test_float_tiff_is_refused(tmp_path, shape):
    path = tmp_path / "float.tif"
    tifffile.imwrite(path, np.zeros(shape, np.float32), photometric="rgb" if len(shape) == 3 else "minisblack")
    with pytest.raises(FileFormatError, match="floating-point") as info:
        load_raw(path, pattern="RGGB" if len(shape) == 2 else None)
    _assert_names_file(info, path)


@pytest.mark.parametrize(
    ("samples", "kwargs"),
    [
        (4, {"photometric": "separated"}),  # CMYK
        (4, {"photometric": "rgb", "extrasamples": ["unspecified"]}),  # RGB + not-alpha
        (5, {"photometric": "rgb", "extrasamples": ["unassalpha", "unspecified"]}),
    ],
)
def test_tiff_with_four_or_more_channels_other_than_rgba_is_refused(tmp_path, samples, kwargs):
    path = tmp_path / "many.tif"
    tifffile.imwrite(path, np.zeros((8, 8, samples), np.uint8), **kwargs)
    with pytest.raises(FileFormatError, match=f"{samples} samples per pixel") as info:
        load_raw(path)
    _assert_names_file(info, path)


def test_multi_image_tiff_is_refused(tmp_path):
    path = tmp_path / "stack.tif"
    tifffile.imwrite(path, np.zeros((3, 8, 8), np.uint16), photometric="minisblack")
    with pytest.raises(FileFormatError, match="holds 3 images") as info:
        load_raw(path, pattern="RGGB")
    _assert_names_file(info, path)


# -- corrupt and truncated PNG / TIFF ---------------------------------------------------------


def _png_bytes(tmp_path):
    counts = np.random.default_rng(8).integers(0, 65536, (32, 40), dtype=np.uint16)
    path = tmp_path / "src.png"
    cv2.imwrite(str(path), counts)
    return path.read_bytes()


@pytest.mark.parametrize("cut", ["half", "no_iend", "header"])
def test_truncated_png(tmp_path, cut):
    data = _png_bytes(tmp_path)
    keep = {"half": len(data) // 2, "no_iend": len(data) - 12, "header": 20}[cut]
    path = tmp_path / "cut.png"
    path.write_bytes(data[:keep])
    with pytest.raises(FileFormatError, match="truncated|IHDR") as info:
        load_raw(path, pattern="RGGB")
    _assert_names_file(info, path)


def test_png_with_a_flipped_byte_fails_its_crc(tmp_path):
    data = bytearray(_png_bytes(tmp_path))
    data[len(data) // 2] ^= 0xFF
    path = tmp_path / "bad.png"
    path.write_bytes(bytes(data))
    with pytest.raises(FileFormatError, match="CRC") as info:
        load_raw(path, pattern="RGGB")
    _assert_names_file(info, path)


def test_random_bytes_with_a_png_suffix(tmp_path):
    path = tmp_path / "noise.png"
    path.write_bytes(np.random.default_rng(9).bytes(3000))
    with pytest.raises(FileFormatError, match="not a PNG file") as info:
        load_raw(path, pattern="RGGB")
    _assert_names_file(info, path)


@pytest.mark.parametrize("keep", [7, 100, "half"])
def test_truncated_or_random_tiff(tmp_path, keep):
    counts = np.random.default_rng(10).integers(0, 65536, (32, 40), dtype=np.uint16)
    tifffile.imwrite(tmp_path / "src.tif", counts)
    data = (tmp_path / "src.tif").read_bytes()
    path = tmp_path / "cut.tif"
    path.write_bytes(data[: len(data) // 2 if keep == "half" else keep])
    with pytest.raises(FileFormatError) as info:
        load_raw(path, pattern="RGGB")
    _assert_names_file(info, path)
    if keep == "half":
        assert "truncated" in str(info.value)
    assert "Error" not in str(info.value)  # says what is wrong, not which exception the reader raised


def test_another_kind_of_file_under_a_tiff_name_is_said_to_be_one(tmp_path):
    path = tmp_path / "t.tif"
    path.write_text("hello, not an image")
    with pytest.raises(FileFormatError, match=r"t\.tif: not a readable TIFF file: it does not begin as a TIFF does") as info:
        load_raw(path, pattern="RGGB")
    assert "Error" not in str(info.value)


def test_sidecar_that_is_not_json(tmp_path):
    path = tmp_path / "f.png"
    cv2.imwrite(str(path), np.zeros((8, 8), np.uint8))
    sidecar_path(path).write_text("{pattern: RGGB")
    with pytest.raises(FileFormatError, match=r"f\.png\.json.*not valid JSON"):
        load_raw(path)


# -- RawFrame ---------------------------------------------------------------------------------


def test_rawframe_defaults_and_immutability():
    counts = np.arange(24, dtype=np.uint16).reshape(4, 6)
    frame = RawFrame(mosaic=counts, pattern="gbrg", bit_depth=10)
    assert (frame.pattern, frame.white_level, frame.black_level, frame.shape) == ("GBRG", 1023.0, 0.0, (4, 6))
    with pytest.raises(dataclasses.FrozenInstanceError):
        frame.pattern = "RGGB"
    with pytest.raises(ValueError):
        frame.mosaic[0, 0] = 5
    counts[0, 0] = 7  # the caller's array stays writable
    assert RawFrame(mosaic=counts, pattern="RGGB", black_level=[3, 3, 3, 3]).black_level == 3.0


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({}, "exactly one of"),
        ({"mosaic": np.zeros((4, 4), np.uint8), "image": np.zeros((4, 4, 3), np.uint8)}, "exactly one of"),
        ({"mosaic": np.zeros((4, 4), np.float32), "pattern": "RGGB"}, "float images are not raw counts"),
        ({"mosaic": np.zeros((4, 4), np.int32), "pattern": "RGGB"}, "uint8 or uint16"),
        ({"mosaic": np.zeros((4, 4), np.uint8)}, "needs a Bayer pattern"),
        ({"mosaic": np.zeros((4, 4), np.uint8), "pattern": "RGBG"}, "unknown Bayer pattern"),
        ({"mosaic": np.zeros((4, 4, 1), np.uint8), "pattern": "RGGB"}, "2-D"),
        ({"image": np.zeros((4, 4, 4), np.uint8)}, r"\(H, W, 3\)"),
        ({"image": np.zeros((4, 4, 3), np.uint8), "black_level": (1, 2, 3, 4)}, "one number"),
        ({"mosaic": np.zeros((4, 4), np.uint8), "pattern": "RGGB", "black_level": (1, 2, 3)}, "four"),
        ({"mosaic": np.zeros((4, 4), np.uint8), "pattern": "RGGB", "black_level": float("nan")}, "finite"),
        ({"mosaic": np.zeros((4, 4), np.uint8), "pattern": "RGGB", "black_level": -1}, "black_level"),
        ({"mosaic": np.zeros((4, 4), np.uint8), "pattern": "RGGB", "bit_depth": 12}, "bit_depth"),
        ({"mosaic": np.zeros((4, 4), np.uint8), "pattern": "RGGB", "white_level": 0}, "white_level"),
        ({"mosaic": np.zeros((4, 4), np.uint8), "pattern": "RGGB", "file_format": "jpeg"}, "file_format"),
    ],
)
def test_rawframe_validation(kwargs, match):
    with pytest.raises(InvalidInputError, match=match) as info:
        RawFrame(**kwargs)
    assert isinstance(info.value, (ValueError, LfringError))


def test_big_endian_counts_are_taken_as_their_values():
    """A big-endian uint16 mosaic was refused as "must be uint8 or uint16 raw counts, got >u2"."""
    counts = np.random.default_rng(1).integers(0, 4096, (8, 10)).astype(np.uint16)
    frame = RawFrame(mosaic=counts.astype(">u2"), pattern="RGGB", bit_depth=12)
    assert frame.mosaic.dtype == np.uint16 and frame.mosaic.dtype.isnative
    np.testing.assert_array_equal(frame.mosaic, counts)
