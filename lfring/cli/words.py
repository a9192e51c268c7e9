"""The library's words in the command line's: its messages name API parameters (``zmin_m``,
``overwrite=True``), which the CLI turns into its options (``--zmin``, ``--overwrite``) before
a user reads them, in errors, log lines and warnings alike.

:data:`API_TO_CLI` is the one table; :func:`cli_words` applies it.
"""

from __future__ import annotations

import logging
import re

__all__ = ["API_TO_CLI", "CliFormatter", "cli_words"]

API_TO_CLI: tuple[tuple[str, str], ...] = (
    # Whole phrases first: a hint that names a call, or a parameter the CLI has no option for.
    (r"load_raw\(\.\.\., pattern=\.\.\.\)", "--pattern"),
    (r"pass ring_device=, or use aperture=", "use a calibration made with lfring calibrate --device, or --aperture"),
    (r" \(or a depth map as depth=\)", ""),
    (r"\bpass black_level=\.\.\. and white_level=\.\.\.", "pass --black-level and --white-level"),
    (r"\bpass black_level=\.\.\. / white_level=\.\.\.", "pass --black-level / --white-level"),
    (r"\((by|from) argument\)", r"(\1 the command line)"),
    (r"\bdepth_method='([\w-]+)'", r"--depth-method \1"),
    (r"\bgive planes\b", "give --planes"),
    (r"\bflat frame (\S+): ", r"--flat \1: "),
    (r"\bmethod='([\w-]+)'", r"--method \1"),
    (r"\bgive depths_m\b", "give the depths to choose from (--depth Z1,Z2,...)"),
    (r"\boverwrite=True\b", "--overwrite"),
    (r" \(None: the default spacing\)", " (leave --planes out for the default spacing)"),
    (r" or None\b", ""),  # an option left out is the API's None
    (r"\b(aperture|reference|workers|threads|planes) must be\b", r"--\1 must be"),
    (r"\bas aperture or as\b", "as --aperture or as"),
    # Parameters and their options.
    (r"\bzmin_m\b", "--zmin"),
    (r"\bzmax_m\b", "--zmax"),
    (r"\bnum_planes\b", "--planes"),
    (r"\bbinning factor\b", "--binning"),
    (r"\btolerance_m\b", "--tolerance"),
    (r"\bplane_m\b", "--plane"),
    (r"\bmin_confidence\b", "--min-confidence"),
    (r"\bmin_coverage\b", "--min-coverage"),
    (r"\bmin_area_px\b", "--min-area"),
    (r"\breference_depth_m\b", "--reference-depth"),
    (r"\brim_taper\b", "--rim-taper"),
    (r"\baperture_scale\b", "--aperture-scale"),
    (r"\bf_number\b", "--f-number"),
    (r"\baperture=", "--aperture"),
    (r"\bdevice=", "--device-file"),
)
"""(regular expression, replacement) pairs, applied in order."""

_RULES = tuple((re.compile(p), r) for p, r in API_TO_CLI)


def cli_words(message: str) -> str:
    """``message`` with the library's parameter names replaced by the CLI's options.

    >>> cli_words("zmin_m (1.0) must be smaller than zmax_m (0.5)")
    '--zmin (1.0) must be smaller than --zmax (0.5)'
    >>> cli_words("give num_planes >= 3, widen the depth range, or use method='local'")
    'give --planes >= 3, widen the depth range, or use --method local'
    >>> cli_words("give zmax_m, or refocus by method='shift-and-add'")
    'give --zmax, or refocus by --method shift-and-add'
    >>> cli_words("give planes >= 5, or use depth_method='local'")
    'give --planes >= 5, or use --depth-method local'
    >>> cli_words("num_planes must be an integer >= 3 or None, got 2")
    '--planes must be an integer >= 3, got 2'
    >>> cli_words("planes must be an integer >= 3 (a depth is judged against the others), got 2")
    '--planes must be an integer >= 3 (a depth is judged against the others), got 2'
    >>> cli_words("give the depth of field as aperture or as f_number, not both")
    'give the depth of field as --aperture or as --f-number, not both'
    """
    for pattern, replacement in _RULES:
        message = pattern.sub(replacement, message)
    return message


class CliFormatter(logging.Formatter):
    """A log formatter whose lines speak the CLI's words (:func:`cli_words`)."""

    def formatMessage(self, record: logging.LogRecord) -> str:  # noqa: N802 - logging's name
        """The record's line as :class:`logging.Formatter` makes it, in the CLI's words."""
        return cli_words(super().formatMessage(record))
