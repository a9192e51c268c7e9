"""Where a frame's pattern and levels come from: the calibration's stand in for the frame's own
only where they fit it."""

import cv2
import numpy as np
import pytest

from lfring.calibration import RingCalibration
from lfring.io.levels import load_frame


def test_an_8_bit_rgb_image_takes_neither_the_calibrations_pattern_nor_its_levels(tmp_path):
    # The built-in twin calibration records its 12-bit RGGB raw frames' pattern and levels
    # (64 .. 4095): an 8-bit RGB image of the same size is read with its own dtype's levels.
    cal = RingCalibration.load("twin_binned2")
    assert cal.pattern == "RGGB" and cal.white_level == 4095
    w, h = cal.raw_size
    rgb = np.zeros((h, w, 3), np.uint8)
    rgb[::2, ::2] = 200
    path = tmp_path / "frame.png"
    cv2.imwrite(str(path), rgb)
    frame, notes = load_frame(path, calibration=cal)
    assert frame.mosaic is None and frame.black_level == 0 and frame.white_level == 255
    assert not any("calibration's" in message for _, message in notes)
    # A 12-bit mosaic of that camera takes them (no sidecar of its own).
    raw = np.full((h, w), 64 + 1000, np.uint16)
    path = tmp_path / "raw.png"
    cv2.imwrite(str(path), raw)
    frame, notes = load_frame(path, calibration=cal)
    assert frame.pattern == "RGGB" and (frame.black_level, frame.white_level) == (64, 4095)
    assert any("using the calibration's" in message for _, message in notes)


def test_a_calibrations_level_that_does_not_fit_the_frame_is_named_as_the_calibrations(tmp_path):
    # It was reported "(from argument)", which the command line words "(from the command line)".
    from types import SimpleNamespace

    from lfring.errors import InvalidInputError
    from lfring.io.levels import load_frame

    path = tmp_path / "tiny.png"
    cv2.imwrite(str(path), np.full((8, 8), 100, np.uint8))
    cal = SimpleNamespace(pattern="RGGB", black_level=64.0, white_level=4095.0)
    with pytest.raises(InvalidInputError, match=r"white_level 4095(\.0)? \(from the calibration\) must be in \(0, 255\]"):
        load_frame(path, calibration=cal)
    with pytest.raises(InvalidInputError, match=r"white_level 4095(\.0)? \(from argument\)"):
        load_frame(path, pattern="RGGB", white_level=4095)


def test_a_calibration_picked_for_the_frame_gives_only_levels_that_fit_its_counts(tmp_path):
    # The built-in calibration picked by a frame's size records 12-bit counts (64 .. 4095): an
    # 8-bit mosaic was refused for them, and 12-bit counts stored in the top bits of 16 were read
    # as clipped. Levels that do not fit are left out (and said so); those that fit are taken.
    from types import SimpleNamespace

    cal = SimpleNamespace(pattern="RGGB", black_level=64.0, white_level=4095.0)
    rng = np.random.default_rng(0)
    eight, top = tmp_path / "eight.png", tmp_path / "top.png"
    cv2.imwrite(str(eight), rng.integers(0, 256, (8, 8), dtype=np.uint8))
    cv2.imwrite(str(top), (rng.integers(0, 4096, (8, 8)) << 4).astype(np.uint16))
    for path, white in ((eight, 255.0), (top, 65535.0)):
        frame, notes = load_frame(path, calibration=cal, only_fitting=True)
        assert (frame.pattern, frame.black_level, frame.white_level) == ("RGGB", 0.0, white)
        assert any("do not fit its counts: not used" in text for _, text in notes)
    fits = tmp_path / "fits.png"
    cv2.imwrite(str(fits), rng.integers(64, 4096, (8, 8)).astype(np.uint16))
    frame, notes = load_frame(fits, calibration=cal, only_fitting=True)
    assert (frame.black_level, frame.white_level) == (64.0, 4095.0)
    assert not any("do not fit" in text for _, text in notes)
    frame, _ = load_frame(top, calibration=cal)  # a calibration given, not picked: its levels stand
    assert frame.white_level == 4095.0


def test_a_black_level_above_most_counts_does_not_fit(tmp_path):
    """A calibration of frames with black level 1024 given for 12-bit frames whose black is 64:
    80 % of their counts lie below it, and the image came out crushed with only a hint about the
    white level. Given, its levels stand and a warning says they do not fit; picked for the
    frame's size, they are left out. A frame with the lens cap on (about half its counts below
    its own black level, by its noise) fits."""
    from types import SimpleNamespace

    rng = np.random.default_rng(1)
    cal = SimpleNamespace(pattern="RGGB", black_level=1024.0, white_level=65535.0)
    counts = np.where(rng.random((64, 64)) < 0.8, rng.integers(40, 900, (64, 64)), rng.integers(1100, 4095, (64, 64)))
    path = tmp_path / "other.png"
    cv2.imwrite(str(path), counts.astype(np.uint16))
    frame, notes = load_frame(path, calibration=cal)
    assert frame.black_level == 1024.0
    assert any(level == 30 and "of its counts lie below the calibration's black level 1024" in text and "--black-level" in text
               for level, text in notes)
    frame, notes = load_frame(path, calibration=cal, only_fitting=True)
    assert frame.black_level == 0.0 and any("do not fit its counts: not used" in text for _, text in notes)
    cap = tmp_path / "cap.png"
    cv2.imwrite(str(cap), np.clip(np.rint(rng.normal(1024, 3, (64, 64))), 0, 65535).astype(np.uint16))
    frame, notes = load_frame(cap, calibration=cal)
    assert frame.black_level == 1024.0 and not any("lie below" in text for _, text in notes)


def test_a_camera_raw_that_contradicts_the_calibration_is_warned_of(tmp_path):
    """A camera RAW is read with its own metadata (LibRaw's), the calibration's pattern and
    levels never standing in; where they differ from the calibration's (a TIFF of BGGR counts
    with black 1024 renamed .cr2: LibRaw guessed RGGB and black 0, and the image came out
    with its colours swapped) a warning names both. A RAW that agrees raises none."""
    from types import SimpleNamespace

    import tifffile

    rng = np.random.default_rng(0)
    path = tmp_path / "frame.cr2"
    tifffile.imwrite(path, rng.integers(1024, 4096, (64, 96)).astype(np.uint16))
    other = SimpleNamespace(pattern="BGGR", black_level=1024.0, white_level=65535.0)
    frame, notes = load_frame(path, calibration=other)
    assert (frame.pattern, frame.black_level) == ("RGGB", 0.0)  # the RAW's own
    said = [text for level, text in notes if "its camera metadata give" in text]
    assert said and "pattern RGGB (the calibration's: BGGR)" in said[0] and "black level 0.0 (the calibration's: 1024.0)" in said[0]
    # The same camera, its black level measured a count apart (LibRaw measures some per frame).
    same = SimpleNamespace(pattern=frame.pattern, black_level=frame.black_level + 1, white_level=frame.white_level)
    _, notes = load_frame(path, calibration=same)
    assert not any("its camera metadata give" in text for _, text in notes)
