"""Option parsers shared by the commands."""

from __future__ import annotations

import contextlib
import functools
import logging
import os
import shlex
from pathlib import Path

import click

from lfring.errors import InvalidInputError
from lfring.optics.device import RingDevice, load_device


SWEEP_METAVAR = "START:STOP:N"
"""A --sweep (refocus, design) as its help names it, and so the messages about it."""


def parse_range(text: str, *, with_count: bool, param_hint: str | None = None, metavar: str | None = None) -> tuple[float, ...]:
    """'a:b' or 'a:b:n' -> floats (n an int >= 2); raises click.BadParameter on bad text, naming
    the option ``param_hint`` and the parts as its help's ``metavar`` does (``START:STOP:N``)."""
    start_w, stop_w, *count_w = (metavar or ("START:STOP:COUNT" if with_count else "START:STOP")).split(":")
    count_w = count_w[0] if count_w else "COUNT"
    parts = text.split(":")
    want = 3 if with_count else 2
    if len(parts) != want:
        form = f"{start_w}:{stop_w}:{count_w}" if with_count else f"{start_w}:{stop_w}"
        raise click.BadParameter(f"expected {form}, got {text!r}", param_hint=param_hint)
    try:
        start, stop = float(parts[0]), float(parts[1])
    except ValueError:
        raise click.BadParameter(f"{start_w} and {stop_w} must be numbers in metres, got {text!r}",
                                 param_hint=param_hint) from None
    if with_count:
        try:
            count = int(parts[2])
        except ValueError:
            raise click.BadParameter(f"{count_w} must be an integer, got {parts[2]!r}", param_hint=param_hint) from None
        if count < 2:
            raise click.BadParameter(f"{count_w} must be >= 2, got {count}", param_hint=param_hint)
        return start, stop, count
    return start, stop


def check_figure_output(path, param_hint: str) -> None:
    """Refuse a figure file whose suffix :func:`lfring.optics.figures.save_figure` cannot write,
    naming the option that gave it, before any work is done.

    Parameters
    ----------
    path : str or Path
        The figure file.
    param_hint : str
        The option that names it (``-o`` of ``lfring raytrace``, ``--plot`` of ``lfring design``).

    Raises
    ------
    click.BadParameter
        Naming the option and the suffixes that can be written.
    """
    from lfring.optics.figures import FIGURE_SUFFIXES  # the one list: save_figure writes these

    if Path(path).suffix.lower() not in FIGURE_SUFFIXES:
        raise click.BadParameter(f"the figure file must end in {', '.join(FIGURE_SUFFIXES)}, got {Path(path).name!r}",
                                 param_hint=param_hint)


def parse_depths(text: str, *, param_hint: str) -> tuple[float, ...]:
    """'0.3,0.5 1.0' -> (0.3, 0.5, 1.0) metres; raises click.BadParameter on bad text."""
    import re

    try:
        out = tuple(float(t) for t in re.split(r"[,\s]+", text.strip()) if t)
    except ValueError:
        raise click.BadParameter(f"expected comma-separated metres, got {text!r}", param_hint=param_hint) from None
    if not out:
        raise click.BadParameter(f"expected comma-separated metres, got no number in {text!r}", param_hint=param_hint)
    if any(not entry.strip() for entry in text.strip().split(",")):
        raise click.BadParameter(f"{text.strip()} has an empty entry: give a depth in metres between every two commas",
                                 param_hint=param_hint)
    return out


@contextlib.contextmanager
def depth_range_words(remedy):
    """Turn a :class:`lfring.errors.DepthRangeError` raised inside the block into a usage error
    that names the range and ``remedy`` (text, or a function of the hypotheses needed, None
    where no number of them would do), in the words of the command at hand (the library's
    message names options of ``lfring depth`` that other commands lack)."""
    from lfring.cli.words import cli_words
    from lfring.errors import DepthRangeError

    try:
        yield
    except DepthRangeError as exc:
        raise click.UsageError(cli_words(exc.narrow(remedy(exc.planes_needed) if callable(remedy) else remedy))) from None


def check_calibration_output(output) -> None:
    """Refuse a calibration output whose name does not end in ``.json``.

    The file holds JSON, and only a ``.json`` name tells a file from the name of a built-in
    calibration when a later command reads it (:func:`lfring.calibration.load_calibration`).

    Parameters
    ----------
    output : str or Path
        The -o of ``lfring calibrate`` or ``lfring grid-calib``.

    Raises
    ------
    click.BadParameter
        Naming -o and the suffix expected.
    """
    from lfring.calibration.jsonio import CALIBRATION_SUFFIX

    if Path(output).suffix.lower() != CALIBRATION_SUFFIX:
        raise click.BadParameter(f"the calibration file must end in {CALIBRATION_SUFFIX}, got {Path(output).name!r}",
                                 param_hint="-o")


OTHER_FILE_SUFFIXES = (".ply", ".pcd", ".xyz", ".obj", ".stl", ".jpg", ".jpeg", ".pfm", ".exr", ".npy", ".npz", ".csv",
                       ".txt", ".h5")
"""Suffixes of files besides lfring's images, raw frames and calibrations (point clouds, other
images, arrays): an output folder that does not exist yet and is named like any of them is
refused (a file name given where a folder goes)."""


def output_folder(ctx, param, value):
    """Click callback of an -o that names a folder: refuse a new one named like a file."""
    if value is None:
        return value
    from lfring.calibration.jsonio import CALIBRATION_SUFFIX
    from lfring.io.raw import RAW_SUFFIXES
    from lfring.io.writers import IMAGE_SUFFIXES

    path = Path(value)
    said_folder = str(value).endswith(("/", os.sep))  # out.ply/ says it is a folder
    files = {*IMAGE_SUFFIXES, *RAW_SUFFIXES, CALIBRATION_SUFFIX, *OTHER_FILE_SUFFIXES}
    if not path.exists() and not said_folder and path.suffix.lower() in files:
        raise click.BadParameter(f"-o names the folder the outputs go to, got the file name {path.name!r}; e.g. -o "
                                 f"{path.with_suffix('')}", param_hint="-o")
    return value


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


class RawLevels:
    """--pattern, --black-level, --white-level as given on the command line (None: not given)."""

    def __init__(self, pattern=None, black_level=None, white_level=None):
        self.pattern = pattern.upper() if pattern else None
        self.black_level = black_level
        self.white_level = white_level

    def as_kwargs(self) -> dict:
        return {"pattern": self.pattern, "black_level": self.black_level, "white_level": self.white_level}


def _parse_black(ctx, param, text):
    if text is None:
        return None
    import re

    try:
        values = [float(t) for t in re.split(r"[,\s]+", text.strip()) if t]
    except ValueError:
        raise click.BadParameter(f"expected a number of counts or four (one per CFA position), got {text!r}") from None
    if len(values) not in (1, 4):
        raise click.BadParameter(f"expected one number of counts or four (one per CFA position), got {len(values)}")
    return values[0] if len(values) == 1 else tuple(values)


def raw_options(fn=None, *, calibration: bool = True):
    """Adds --pattern, --black-level and --white-level to a command that reads raw frames; the
    command receives them as one ``levels`` argument (a :class:`RawLevels`). ``calibration``:
    the command reads a calibration, whose recorded levels they override too (its help says
    so); ``@raw_options(calibration=False)`` for one that reads none."""
    from lfring.io.bayer import PATTERNS

    if fn is None:
        return functools.partial(raw_options, calibration=calibration)

    @functools.wraps(fn)
    def wrapper(*args, pattern=None, black_level=None, white_level=None, **kwargs):
        return fn(*args, levels=RawLevels(pattern, black_level, white_level), **kwargs)

    over = "overrides a sidecar or the calibration's" if calibration else "overrides a sidecar"
    opts = [
        click.option("--pattern", type=click.Choice(PATTERNS, case_sensitive=False), default=None,
                     help=f"Bayer pattern of the frames ({over})."),
        click.option("--black-level", callback=_parse_black, default=None, metavar="COUNTS",
                     help=f"Black level in counts, one number or four in CFA order ({over})."),
        click.option("--white-level", type=float, default=None, metavar="COUNTS",
                     help=f"White (saturation) level in counts ({over})."),
    ]
    for opt in reversed(opts):
        wrapper = opt(wrapper)
    return wrapper


def check_option(fn):
    """Adds --no-check: skip the check that a frame is a ring frame for the calibration."""
    return click.option("--no-check", "no_check", is_flag=True,
                        help="Process frames that do not look like ring frames for the calibration (see lfring check).")(fn)


# The commands whose work lfring batch does over many frames, and the batch option that does it:
# a folder or a pattern given to one of them is pointed there.
BATCH_COMMANDS = {"refocus": "--refocus Z", "depth": "--depth", "view": "--viewer"}


class FramePath(click.Path):
    """A frame (or view image) given on the command line: a file. A folder, or a quoted pattern
    that matched nothing because no shell expanded it, is refused saying so, and for the
    commands that ``lfring batch`` runs over many frames, pointing there."""

    def __init__(self):
        super().__init__(dir_okay=True)

    def convert(self, value, param, ctx):
        text = os.fspath(value)
        path = Path(text)
        command = ctx.command.name if ctx is not None else None
        quoted = shlex.quote(text) if os.name == "posix" else f'"{text}"'
        many = (f"; lfring batch takes folders and patterns (lfring batch {quoted} -o OUTDIR "
                f"{BATCH_COMMANDS[command]})" if command in BATCH_COMMANDS else "")
        if path.is_dir():
            self.fail(f"{text} is a folder: give one frame{many}", param, ctx)
        if not path.exists() and any(ch in text for ch in "*?["):
            self.fail(f"{text}: no such file (a quoted pattern is not expanded here){many}", param, ctx)
        return super().convert(value, param, ctx)


FRAME = FramePath()


def read_frame(raw: str, levels: RawLevels | None = None, calibration=None, *, picked: bool = False):
    """Load a raw frame: options first, then its sidecar or metadata, then the calibration's
    pattern and levels (said at info level; a calibration ``picked`` for the frame's size, not
    given, only where its levels fit the frame's counts), then defaults (said at warning level);
    see :func:`lfring.io.levels.load_frame`."""
    from lfring.io.levels import load_frame

    frame, notes = load_frame(raw, **(levels or RawLevels()).as_kwargs(), calibration=calibration, only_fitting=picked)
    log = logging.getLogger("lfring.cli")
    for level, message in notes:
        log.log(level, "%s", message)
    return frame


def aperture_options(fn):
    """--aperture A and --f-number N: the depth of field of depth-aware refocusing."""
    fn = click.option("--f-number", "f_number", type=float, default=None, metavar="N",
                      help="depth-aware: the main lens's f-number instead of --aperture (needs a calibration made "
                           "from a described device, as the built-in ones are).")(fn)
    return click.option("--aperture", type=float, default=None, metavar="A",
                        help="depth-aware: aperture radius, 1 = the aperture the four views span (default), 0 = all "
                             "in focus.")(fn)


def flat_option(fn):
    """Adds --flat FILE: the views are divided by a flat (white) frame's, which takes each view's
    vignetting out (the command receives the path as ``flat``)."""
    return click.option("--flat", "flat", type=click.Path(dir_okay=False), default=None, metavar="FILE",
                        help="Flat (white) frame of the camera: the views are divided by it (each view's vignetting). "
                             "Default: the calibration's flat field, when it carries one.")(fn)


def read_calibrated_frame(raw: str, calib: str | None, levels: RawLevels | None = None):
    """(frame, calibration, name): the raw frame ``raw`` (:func:`read_frame`) and --calib's
    calibration, else the built-in one for the frame's size (logged). The size comes from the
    file's header where it tells it, so that the built-in calibration's pattern and levels stand
    in for those the frame lacks (where they fit its counts); else (camera RAW) from the frame."""
    from lfring.calibration import RingCalibration
    from lfring.calibration.defaults import calibration_for_frame, default_calibration

    if calib:
        cal = RingCalibration.load(calib)
        return read_frame(raw, levels, cal), cal, calib
    found = calibration_for_frame(raw)
    frame = read_frame(raw, levels, found[0] if found else None, picked=True)
    cal, name = found or default_calibration(frame.shape[::-1])
    logging.getLogger("lfring.cli").info("no --calib given: using the built-in calibration '%s' (%s, %d x %d px frames)",
                                         name, "measured" if cal.source == "planes" else "from the optics", *cal.raw_size)
    return frame, cal, name


def load_views(raw, calib: str | None, levels: RawLevels | None = None, *, check: bool = True, flat: str | None = None):
    """Load, demosaic and split a raw frame; the calibration from --calib or the built-in
    default for the frame's size (logged). The split undoes the calibration's lens distortion
    and divides by the flat field (``flat``, a flat frame's path, else the calibration's own).
    Unless ``check`` is False, refuse a frame that does not look like a ring frame for the
    calibration, and a flat frame that does not look like one (:func:`lfring.check.check_frame`).
    Several paths are separate view images instead (see :func:`load_view_files`)."""
    from lfring.io.demosaic import demosaic
    from lfring.views import flat_field_from_frame, split_views

    if not isinstance(raw, str):
        if len(raw) > 1:
            given = [o for o, v in (("--pattern", levels and levels.pattern), ("--black-level", levels and levels.black_level),
                                    ("--white-level", levels and levels.white_level), ("--flat", flat)) if v is not None]
            if given:
                raise click.UsageError(f"{', '.join(given)} apply to one raw frame: separate view images are read as RGB "
                                       "images, or as raw mosaics with the pattern and levels of their sidecars (IMAGE.json)")
            return load_view_files(raw, calib, check=check)
        raw = raw[0]
    frame, cal, name = read_calibrated_frame(raw, calib, levels)
    image = demosaic(frame)
    cal.check_frame(image.shape, what=f"frame {raw}")
    if check:
        require_ring_frame(image, cal, raw)
    flat_field = None
    if flat:
        flat_image = demosaic(read_frame(flat, levels, cal, picked=not calib))
        cal.check_frame(flat_image.shape, what=f"flat frame {flat}")
        if check:  # --no-check takes the flat as it is too, as its refusal offers
            require_flat_frame(flat_image, cal, flat)
        flat_field = flat_field_from_frame(flat_image, cal)
    return split_views(image, cal, flat=flat_field), cal, name


def load_view_files(paths, calib: str | None, *, check: bool = True):
    """Separate view images (a stereo pair, a camera array) in the view order of --calib, a
    calibration of as many views (``lfring grid-calib`` writes one). Unless ``check`` is False,
    the views of a ring calibration must agree as a ring frame's do (:func:`lfring.check.check_frame`):
    views in another order, or from different frames, do not. The views are taken as cut from
    the frame (as ``lfring split`` writes them) and corrected as a frame's split views are: the
    calibration's lens distortion undone and its flat field divided out, where it carries them."""
    from lfring.calibration import RingCalibration
    from lfring.check import AGREEMENT_THRESHOLD, check_frame
    from lfring.views import correct_views, read_views

    if not calib:
        from lfring.calibration import builtin_calibrations
        from lfring.io.readers import frame_size

        frames = {tuple(size) for size in builtin_calibrations().values()}
        if all(frame_size(p) in frames for p in paths):  # whole ring frames, as an unquoted pattern gives them
            command = click.get_current_context().info_name
            how = BATCH_COMMANDS.get(command)
            raise click.UsageError(f"{len(paths)} ring frames given (whole frames of a built-in calibration's size): lfring "
                                   f"{command} takes one frame" + (f"; for many, lfring batch FILES... {how}" if how else ""))
        raise click.UsageError(f"{len(paths)} images given: separate views need --calib FILE, a calibration of "
                               f"{len(paths)} views in their order (lfring grid-calib writes one for a stereo pair or a grid)")
    cal = RingCalibration.load(calib)
    if cal.num_views != len(paths):
        raise click.UsageError(f"{len(paths)} view images given but the calibration {calib} has {cal.num_views} views")
    views = read_views(paths)
    cal.check_fits(views.shape, what="view images")
    if check and cal.source != "grid":  # a grid's views have no discs to judge agreement on
        res = check_frame(views, cal)
        if res.reason == "views_disagree":
            raise InvalidInputError(
                f"the view images {' '.join(map(str, paths))} do not agree as the views of one frame in this order (ZNCC "
                f"{res.agreement:.2f} at best, a ring frame's views score above {AGREEMENT_THRESHOLD:g}): give the views "
                "of one frame in the calibration's view order, or pass --no-check to process them anyway")
    corrected = correct_views(views, cal)
    if corrected is not views:
        done = [w for w, on in (("lens distortion undone", cal.distortion is not None),
                                ("flat field divided out", cal.flat_field is not None)) if on]
        logging.getLogger("lfring.cli").info("view images taken as cut from the frame: the calibration's %s",
                                             " and ".join(done))
    return corrected, cal, calib


def require_ring_frame(image, cal, raw) -> None:
    """Raise (an InvalidInputError naming ``raw``) unless the frame's views agree as a ring
    frame's do for ``cal``."""
    import warnings

    from lfring.check import ExposureWarning, check_frame

    with warnings.catch_warnings():  # said below with the frame's name
        warnings.simplefilter("ignore", ExposureWarning)
        res = check_frame(image, cal)
    logging.getLogger("lfring.cli").debug("%s: %s", raw, res.message)
    if not res.ok:
        raise InvalidInputError(f"{raw}: {res.message}")
    if res.warning:
        logging.getLogger("lfring.cli").warning("%s: %s", raw, res.warning)


def require_flat_frame(image, cal, path) -> None:
    """Raise (an InvalidInputError naming ``path``) unless the frame is a flat (white) frame of
    the camera ``cal`` describes: discs of light without texture (:func:`lfring.check.check_frame`).
    Dividing by anything else would print its texture into every view."""
    from lfring.check import check_frame

    res = check_frame(image, cal)
    if not res.flat_field:
        raise InvalidInputError(f"--flat {path} is not a flat (white) frame of this camera: {res.message}")


class _SilentBar:
    """What :func:`progress_bar` gives where no bar is shown: it counts and draws nothing, and,
    unlike a disabled tqdm, has no finaliser, in which a Ctrl-C or SIGTERM that lands there
    would be printed as an ignored exception's traceback instead of stopping the command."""

    def __init__(self):
        self.n = 0

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def update(self, n=1):
        self.n += n


def progress_bar(total: int, desc: str, unit: str):
    """A tqdm bar on stderr, shown only when stderr is a terminal and lfring is not quiet."""
    import sys

    quiet = not logging.getLogger("lfring").isEnabledFor(logging.INFO)
    if quiet or not sys.stderr.isatty():
        return _SilentBar()
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, leave=False, dynamic_ncols=True)


# The modules whose numba kernels the commands' default path compiles (numba caches them on
# disk): the depth engine's, and the depth-aware renderer's besides for refocusing and the viewer.
DEPTH_KERNELS = ("lfring.depth.costs.kernels", "lfring.depth.engines.fused_volume", "lfring.depth.engines.fused_paths",
                 "lfring.depth.refine_kernels")
REFOCUS_KERNELS = (*DEPTH_KERNELS, "lfring.focus.depth_aware_kernels")


def note_first_compile(modules=DEPTH_KERNELS) -> None:
    """Say, once per machine, that the kernels of ``modules`` (dotted names) are being
    compiled: numba compiles them on their first use and keeps them on disk, so only the very
    first run is slow, and silent without this note. Looks for numba's cache index of every
    module."""
    import importlib.util
    import os
    import sys

    tag = f"py{sys.version_info.major}{sys.version_info.minor}"
    where = [Path(d) for d in (os.environ.get("NUMBA_CACHE_DIR"), Path.home() / ".cache" / "numba") if d]

    def cached(module: Path) -> bool:
        for d in (module.parent / "__pycache__", *where):
            if d.is_dir() and next(d.rglob(f"{module.stem}.*.{tag}.nbi"), None) is not None:
                return True
        return False

    if not all(cached(Path(importlib.util.find_spec(name).origin)) for name in modules):
        logging.getLogger("lfring.cli").info("compiling the numerical kernels once (numba keeps them on disk): this "
                                             "first run takes longer")
