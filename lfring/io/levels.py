"""Reading a raw frame with its levels from the best source, and saying which source that was.

For each of the Bayer pattern, the black level and the white level the first of these wins:
the caller's value (a command-line option), the frame's own metadata or sidecar, the
calibration the frame is processed with (which records the frames it was made from), and last
the defaults (black 0, white 2**bits - 1), which are only assumptions: the frame then gets a
warning that names them. A frame whose brightest count is far below its white level (10-bit
counts in a 16-bit PNG) gets a warning that names the white level to pass.
"""

from __future__ import annotations

import json
import logging
import re
from pathlib import Path

import numpy as np

from lfring.errors import InvalidInputError

__all__ = ["BELOW_BLACK_FRACTION", "LEVEL_KEYS", "LOW_PEAK_FRACTION", "RAW_LEVEL_TOL", "load_frame"]

LEVEL_KEYS = ("pattern", "black_level", "white_level")
_LEVELS = LEVEL_KEYS[1:]  # the black and white levels

LOW_PEAK_FRACTION = 1 / 16
"""A frame whose brightest count is below this fraction of its white level gets a warning: its
data likely have fewer bits than its container (10-bit counts in a 16-bit PNG reach 1/64 of
full scale)."""

RAW_LEVEL_TOL = 0.01
"""A camera RAW's black or white level that differs from the calibration's by more than this share
of the calibration's range (white - black) is another camera's (LibRaw may measure a black level
from each frame's masked pixels, a count or two apart from frame to frame)."""

BELOW_BLACK_FRACTION = 0.75
"""A calibration's black level under which more than this share of a frame's counts lie does not
fit the frame (another camera, or another bit depth): a frame's noise spreads its darkest counts
around its own black level, so even a frame with the lens cap on has about half of them below."""

_OPTION = {"pattern": "--pattern", "black_level": "--black-level", "white_level": "--white-level"}


def _sidecar_keys(p: Path) -> set:
    from lfring.io.raw import sidecar_path

    side = sidecar_path(p)
    if not side.is_file():
        return set()
    try:
        content = json.loads(side.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return set()  # load_raw reports a broken sidecar by name
    return {k for k in LEVEL_KEYS if isinstance(content, dict) and content.get(k) is not None}


def _load(p: Path, given: dict, from_cal: dict):
    """:func:`lfring.io.raw.load_raw` with the given values and the calibration's; an error over
    a value of the calibration names it as the calibration's, not as given."""
    from lfring.io.raw import load_raw

    try:
        return load_raw(p, **{**given, **from_cal})
    except InvalidInputError as exc:
        message = str(exc)
        for key in from_cal:
            message = re.sub(rf"\b({key}\b[^()]*)\((from|by) argument\)", r"\1(\2 the calibration)", message)
        if message == str(exc):
            raise
        raise InvalidInputError(message) from None


def load_frame(path, *, pattern=None, black_level=None, white_level=None, calibration=None, only_fitting=False):
    """Read a raw frame, its pattern and levels from the best source (see the module).

    Parameters
    ----------
    path : str or Path
    pattern, black_level, white_level : optional
        Given values (they win); as for :func:`lfring.io.raw.load_raw`.
    calibration : RingCalibration, optional
        Its ``pattern``, ``black_level`` and ``white_level``, when recorded, stand in for
        values that neither the caller nor the frame's sidecar gives.
    only_fitting : bool
        The calibration's levels stand in only where they fit the frame's counts (the data's
        type holds its white level, no count lies above it): for a calibration picked for the
        frame (the built-in one for its size) rather than given, whose frames may have been
        stored otherwise. Otherwise levels that do not fit are an error.

    Returns
    -------
    frame : RawFrame
    notes : list of (int, str)
        Logging level and message: INFO for values taken from the calibration, WARNING for
        assumed levels and for data far below the white level.
    """
    from lfring.io.raw import RAW_SUFFIXES, load_raw, sidecar_path

    p = Path(path)
    given = {"pattern": pattern.upper() if isinstance(pattern, str) else pattern, "black_level": black_level,
             "white_level": white_level}
    camera_raw = p.suffix.lower() in RAW_SUFFIXES
    from_file = set() if camera_raw else _sidecar_keys(p)
    from_cal = {}
    if calibration is not None and not camera_raw:
        for k in LEVEL_KEYS:
            v = getattr(calibration, k, None)
            if given[k] is None and k not in from_file and v is not None:
                from_cal[k] = v
    unfit = {}
    try:
        frame = _load(p, given, from_cal)
    except InvalidInputError as exc:
        levels = [k for k in _LEVELS if k in from_cal]
        if only_fitting and levels and "already RGB" not in str(exc):
            unfit = {k: from_cal.pop(k) for k in levels}  # the levels did not fit: the frame's own or the dtype's
            frame = _load(p, given, from_cal)
        elif "pattern" not in from_cal or "already RGB" not in str(exc):
            raise
        else:
            del from_cal["pattern"]  # an RGB frame: the calibration's Bayer pattern does not apply
            try:
                frame = _load(p, given, from_cal)
            except InvalidInputError:
                if not from_cal:
                    raise
                # Nor its levels, where they do not fit the frame's counts (an 8-bit RGB image, a
                # calibration of 12-bit raw frames): the frame's own or the dtype's are taken.
                from_cal = {}
                frame = load_raw(p, **given)
    data = frame.mosaic if frame.mosaic is not None else frame.image
    peak = int(data.max()) if data.size else 0
    levels = [k for k in _LEVELS if k in from_cal]
    below = 0.0
    if "black_level" in from_cal and data.size:
        black = min(np.atleast_1d(np.asarray(frame.black_level, dtype=np.float64)))
        sample = data[::4, ::4]
        below = float(np.count_nonzero(sample < black)) / sample.size
    if only_fitting and levels and (peak > frame.white_level or below > BELOW_BLACK_FRACTION):  # not this frame's
        unfit = {k: from_cal.pop(k) for k in levels}
        frame = _load(p, given, from_cal)  # the same counts, its own levels
    notes = []
    if not only_fitting and below > BELOW_BLACK_FRACTION:
        notes.append((logging.WARNING, f"{path}: {below:.0%} of its counts lie below the calibration's black level "
                                       f"{frame.black_level}: its levels do not fit this frame (another camera or bit "
                                       "depth?); pass --black-level and --white-level for it (or write them in "
                                       f"{sidecar_path(p).name})"))
    if camera_raw and calibration is not None:
        # The RAW's own metadata wins; a calibration made from frames read otherwise is another
        # camera's (or the file is not what its name says).
        differ = [(k, getattr(frame, k), getattr(calibration, k, None)) for k in LEVEL_KEYS if given[k] is None]
        span = float(np.max(getattr(calibration, "white_level", None) or 0.0)) - float(
            np.min(getattr(calibration, "black_level", None) or 0.0))
        tol = {"pattern": 0.0, "black_level": RAW_LEVEL_TOL * span, "white_level": RAW_LEVEL_TOL * span}

        def apart(k, mine, theirs) -> bool:
            if k == "pattern":
                return mine != theirs
            return bool(np.any(np.abs(np.asarray(mine, np.float64) - np.asarray(theirs, np.float64)) > tol[k]))

        differ = [(k, mine, theirs) for k, mine, theirs in differ
                  if theirs is not None and mine is not None and apart(k, mine, theirs)]
        if differ:
            said = ", ".join(f"{k.replace('_', ' ')} {mine} (the calibration's: {theirs})" for k, mine, theirs in differ)
            notes.append((logging.WARNING, f"{path}: its camera metadata give {said}: the calibration was made from "
                                           "frames read otherwise, another camera's or another format's; check the "
                                           "calibration, or pass the frame's pattern and levels"))
    if unfit:
        values = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in unfit.items())
        notes.append((logging.WARNING, f"{path}: the levels of the calibration picked for its size ({values}) do not fit "
                                       "its counts: not used"))
    if from_cal:
        names = " or ".join(k.replace("_", " ") for k in from_cal)
        values = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in from_cal.items())
        notes.append((logging.INFO, f"{path}: no {names} of its own; using the calibration's ({values})"))
    if not camera_raw:
        assumed = [k for k in _LEVELS if given[k] is None and k not in from_file and k not in from_cal]
        if assumed and (frame.mosaic is not None or frame.bit_depth > 8):
            what = {"black_level": f"black {frame.black_level:g}", "white_level": f"white {frame.white_level:g}"}
            notes.append((logging.WARNING,
                          f"{path}: levels assumed ({', '.join(what[k] for k in assumed)}): no sidecar, option or "
                          f"calibration gives them; pass {' and '.join(_OPTION[k] for k in assumed)} (or write them in "
                          f"{sidecar_path(p).name}) if the result looks too dark or too bright"))
    if peak == 0 and data.size:
        notes.append((logging.WARNING, f"{path}: every count is 0: the frame holds no light"))
    elif given["white_level"] is None and peak < LOW_PEAK_FRACTION * frame.white_level:
        bits = max(1, peak.bit_length())
        notes.append((logging.WARNING,
                      f"{path}: the brightest count is {peak}, far below the white level {frame.white_level:g}: if the data "
                      f"have fewer bits than the file (e.g. {bits}-bit counts in a {data.dtype.itemsize * 8}-bit file), "
                      f"pass --white-level {2 ** bits - 1}"))
    return frame, notes
