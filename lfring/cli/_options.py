"""Option parsers shared by the commands."""

from __future__ import annotations

import logging

import click

from lfring.optics.device import RingDevice, load_device


def parse_range(text: str, *, with_count: bool) -> tuple[float, ...]:
    """'a:b' or 'a:b:n' -> floats (n an int >= 2); raises click.BadParameter on bad text."""
    parts = text.split(":")
    want = 3 if with_count else 2
    if len(parts) != want:
        form = "START:STOP:COUNT" if with_count else "START:STOP"
        raise click.BadParameter(f"expected {form}, got {text!r}")
    try:
        start, stop = float(parts[0]), float(parts[1])
    except ValueError:
        raise click.BadParameter(f"START and STOP must be numbers in metres, got {text!r}") from None
    if with_count:
        try:
            count = int(parts[2])
        except ValueError:
            raise click.BadParameter(f"COUNT must be an integer, got {parts[2]!r}") from None
        if count < 2:
            raise click.BadParameter(f"COUNT must be >= 2, got {count}")
        return start, stop, count
    return start, stop


def parse_depths(text: str, *, param_hint: str) -> tuple[float, ...]:
    """'0.3,0.5 1.0' -> (0.3, 0.5, 1.0) metres; raises click.BadParameter on bad text."""
    import re

    try:
        return tuple(float(t) for t in re.split(r"[,\s]+", text.strip()) if t)
    except ValueError:
        raise click.BadParameter(f"expected comma-separated metres, got {text!r}", param_hint=param_hint) from None


device_option = click.option(
    "--device",
    "device_name",
    default="prototype",
    show_default=True,
    metavar="NAME|FILE",
    help="Built-in device name or a .toml/.json device file (lengths in metres).",
)


def get_device(name: str) -> RingDevice:
    return load_device(name)


def load_views(raw, calib: str | None):
    """Load, demosaic and split a raw frame; the calibration from --calib or the built-in
    default for the frame's size (logged). Several paths are separate view images instead
    (see :func:`load_view_files`)."""
    from lfring.calibration import RingCalibration
    from lfring.calibration.defaults import default_calibration
    from lfring.io.demosaic import demosaic
    from lfring.io.raw import load_raw
    from lfring.views import split_views

    if not isinstance(raw, str):
        if len(raw) > 1:
            return load_view_files(raw, calib)
        raw = raw[0]
    frame = load_raw(raw)
    image = demosaic(frame)
    if calib:
        cal, name = RingCalibration.load(calib), calib
    else:
        cal, name = default_calibration((image.shape[1], image.shape[0]))
        logging.getLogger("lfring.cli").info("no --calib given: using the built-in calibration '%s' (%s, %d x %d px frames)",
                 name, "measured" if cal.source == "planes" else "from the optics", *cal.raw_size)
    cal.check_frame(image.shape, what=f"frame {raw}")
    return split_views(image, cal.layout), cal, name


def load_view_files(paths, calib: str | None):
    """Separate view images (a stereo pair, a camera array) in the view order of --calib, a
    calibration of as many views (``lfring grid-calib`` writes one)."""
    from lfring.calibration import RingCalibration
    from lfring.views import read_views

    if not calib:
        raise click.UsageError(f"{len(paths)} images given: separate views need --calib FILE, a calibration of "
                               f"{len(paths)} views in their order (lfring grid-calib writes one for a stereo pair or a grid)")
    cal = RingCalibration.load(calib)
    if cal.num_views != len(paths):
        raise click.UsageError(f"{len(paths)} view images given but the calibration {calib} has {cal.num_views} views")
    views = read_views(paths)
    cal.check_fits(views.shape, what="view images")
    return views, cal, calib
