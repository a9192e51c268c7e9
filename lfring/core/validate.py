"""Argument checks at the public boundary: the one place where lfring decides what counts as an
integer, a number, a fraction or a choice, and how a refusal reads.

Every public function checks its scalar arguments with these helpers, so that the same mistake
(a bool passed as a count, a NaN as a distance, a misspelt option) gets the same clear error
everywhere: what was expected, what came. ``bool`` is never an integer or a number here, although
Python makes it a subclass of ``int``: ``threads=True`` is a mistake, not one thread.

Each check returns the value converted to the plain Python type (``int``, ``float``) so that
callers do not convert again, or raises ``error`` (:class:`lfring.InvalidInputError` unless the
caller names another :class:`lfring.LfringError` subclass, such as a device file's
:class:`lfring.DeviceError`).
"""

from __future__ import annotations

import math
import numbers

import numpy as np

from lfring.errors import InvalidInputError

__all__ = [
    "ANY_WINDOW_PX", "check_bool", "check_callable", "check_choice", "check_fraction", "check_int", "check_number", "check_odd_px",
    "check_shape_hw", "check_threads", "check_view_index", "is_integer", "is_number",
]


def is_integer(value) -> bool:
    """True for Python and NumPy integers, False for bools and everything else."""
    return isinstance(value, (numbers.Integral, np.integer)) and not isinstance(value, (bool, np.bool_))


def is_number(value) -> bool:
    """True for real Python and NumPy numbers (integers included), False for bools and the rest."""
    return isinstance(value, (numbers.Real, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def _bounds(minimum, maximum, above, below) -> str:
    parts = []
    if minimum is not None:
        parts.append(f">= {minimum:g}" if isinstance(minimum, float) else f">= {minimum}")
    if above is not None:
        parts.append(f"> {above:g}" if isinstance(above, float) else f"> {above}")
    if maximum is not None:
        parts.append(f"<= {maximum:g}" if isinstance(maximum, float) else f"<= {maximum}")
    if below is not None:
        parts.append(f"< {below:g}" if isinstance(below, float) else f"< {below}")
    return " and ".join(parts)


def check_int(value, name: str, *, minimum=None, maximum=None, allow_none: bool = False, what: str = "an integer",
              hint: str = "", error=InvalidInputError):
    """``value`` as an ``int`` within [minimum, maximum] (either bound optional); None passes
    when ``allow_none``.

    Examples
    --------
    >>> check_int(3, "num_planes", minimum=2)
    3
    >>> check_int(True, "threads", minimum=1)
    Traceback (most recent call last):
    ...
    lfring.errors.InvalidInputError: threads must be an integer >= 1, got True
    """
    if value is None and allow_none:
        return None
    if not is_integer(value) or (minimum is not None and value < minimum) or (maximum is not None and value > maximum):
        bounds = _bounds(minimum, maximum, None, None)
        raise error(f"{name} must be {what}{' ' + bounds if bounds else ''}{' or None' if allow_none else ''}{hint}, "
                    f"got {value!r}")
    return int(value)


def check_shape_hw(value, name: str, *, error=InvalidInputError) -> tuple[int, int]:
    """``value`` as an image size ``(h, w)``: two integers >= 1.

    Examples
    --------
    >>> check_shape_hw((705, 705), "view_shape")
    (705, 705)
    >>> check_shape_hw("705x705", "view_shape")
    Traceback (most recent call last):
    ...
    lfring.errors.InvalidInputError: view_shape must be (h, w) in pixels, two integers >= 1, got '705x705'
    """
    if isinstance(value, (str, bytes)) or np.ndim(value) != 1 or np.size(value) != 2 or not all(
            is_integer(n) and n >= 1 for n in value):
        raise error(f"{name} must be (h, w) in pixels, two integers >= 1, got {value!r}")
    return int(value[0]), int(value[1])


def check_number(value, name: str, *, minimum=None, maximum=None, above=None, below=None, finite: bool = True,
                 allow_none: bool = False, what: str = "a number", hint: str = "", error=InvalidInputError):
    """``value`` as a ``float`` within the bounds (``minimum``/``maximum`` inclusive,
    ``above``/``below`` exclusive; each optional), finite unless ``finite`` is False (NaN is
    always refused); None passes when ``allow_none``.

    Examples
    --------
    >>> check_number(0.5, "depth_m", above=0.0, what="a distance in metres")
    0.5
    >>> check_number(float("nan"), "depth_m", above=0.0, what="a distance in metres")
    Traceback (most recent call last):
    ...
    lfring.errors.InvalidInputError: depth_m must be a distance in metres > 0 (finite), got nan
    """
    if value is None and allow_none:
        return None
    try:
        v = float(value) if is_number(value) else math.nan
    except OverflowError:  # an integer beyond float's range
        v = math.nan
    ok = not math.isnan(v) and (not finite or math.isfinite(v))
    if ok:
        ok = not ((minimum is not None and v < minimum) or (maximum is not None and v > maximum)
                  or (above is not None and v <= above) or (below is not None and v >= below))
    if not ok:
        bounds = _bounds(minimum, maximum, above, below)
        extra = " (finite)" if finite else ""
        raise error(f"{name} must be {what}{' ' + bounds if bounds else ''}{extra}{' or None' if allow_none else ''}"
                    f"{hint}, got {value!r}")
    return float(value)


def check_fraction(value, name: str, *, allow_none: bool = False, hint: str = "", error=InvalidInputError):
    """``value`` as a ``float`` in [0, 1].

    Examples
    --------
    >>> check_fraction(0.05, "rim_taper")
    0.05
    """
    if value is None and allow_none:
        return None
    if not is_number(value) or not 0.0 <= float(value) <= 1.0:
        raise error(f"{name} must be a number in [0, 1]{' or None' if allow_none else ''}{hint}, got {value!r}")
    return float(value)


def check_choice(value, name: str, choices, *, allow_none: bool = False, error=InvalidInputError):
    """``value`` if it is one of ``choices`` (any iterable of hashable values, a registry
    included), else an error that lists them.

    Examples
    --------
    >>> check_choice("sgm", "method", ("sgm", "local"))
    'sgm'
    >>> check_choice("sgn", "method", ("sgm", "local"))
    Traceback (most recent call last):
    ...
    lfring.errors.InvalidInputError: method must be one of sgm, local, got 'sgn'
    """
    if value is None and allow_none:
        return None
    options = list(choices)
    try:
        known = value in options and not isinstance(value, (bool, np.bool_))
    except TypeError:  # unhashable or not comparable
        known = False
    if not known:
        listed = ", ".join(str(c) for c in options)
        raise error(f"{name} must be one of {listed}{' or None' if allow_none else ''}, got {value!r}")
    return value


def check_bool(value, name: str, *, allow_none: bool = False, hint: str = "", error=InvalidInputError):
    """``value`` as a ``bool`` (Python or NumPy bools only: 'no' is not False)."""
    if value is None and allow_none:
        return None
    if not isinstance(value, (bool, np.bool_)):
        raise error(f"{name} must be True or False{' or None' if allow_none else ''}{hint}, got {value!r}")
    return bool(value)


def check_odd_px(value, name: str, *, within=None, error=InvalidInputError) -> int:
    """A window side: an odd positive integer (a centred window); with ``within``, an image's
    (h, w), at most :data:`ANY_WINDOW_PX` or twice its larger side and one, whichever is more (a
    wider window holds nothing more, and costs its area)."""
    if not is_integer(value) or value < 1 or value % 2 == 0:
        raise error(f"{name} must be an odd positive integer, got {value!r}")
    most = None if within is None else max(ANY_WINDOW_PX, 2 * max(within) + 1)
    if most is not None and value > most:
        raise error(f"{name} must be an odd positive integer at most {most} (twice the image's larger side, "
                    f"{max(within)} px, and one), got {value!r}")
    return int(value)


ANY_WINDOW_PX = 31
"""Windows up to this side are taken on any image, however small (the defaults among them)."""


def check_threads(threads, *, allow_none: bool = True):
    """``threads`` as an int >= 1 (None passes when ``allow_none``: the caller's default)."""
    return check_int(threads, "threads", minimum=1, allow_none=allow_none)


def check_view_index(value, name: str, num_views: int, *, allow_center: bool = False, hint: str = "",
                     error=InvalidInputError):
    """A view index in [0, num_views) (or 'center' when ``allow_center``) as an ``int`` (or
    'center')."""
    if allow_center and value == "center" and isinstance(value, str):
        return value
    if not is_integer(value) or not 0 <= value < num_views:
        head = "'center' or a view index" if allow_center else "a view index"
        raise error(f"{name} must be {head} 0..{num_views - 1}{hint}, got {value!r}")
    return int(value)


def check_callable(value, name: str, *, allow_none: bool = True, what: str = "a callable"):
    """``value`` if it can be called (None passes when ``allow_none``)."""
    if value is None and allow_none:
        return None
    if not callable(value):
        raise InvalidInputError(f"{name} must be {what}{' or None' if allow_none else ''}, got {value!r}")
    return value
