"""Short reprs for records that hold arrays.

A dataclass's generated repr prints every array in full (NumPy elides the middle, but a
(705, 705) map still fills a screen). Records that hold arrays use :func:`record_repr`
instead: arrays show as their shape and dtype, every other field as its usual repr.
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["record_repr", "summarize"]


def summarize(value) -> str:
    """The repr of ``value`` with every NumPy array in it replaced by its shape and dtype.

    Parameters
    ----------
    value : object
        An array, a list, tuple or dict (searched for arrays, recursively), or anything else
        (its usual repr).

    Returns
    -------
    str

    Examples
    --------
    >>> import numpy as np
    >>> summarize(np.zeros((705, 705), np.float32))
    'array(shape=(705, 705), dtype=float32)'
    >>> summarize({"depth_m": np.ones(3), "n": 2})
    "{'depth_m': array(shape=(3,), dtype=float64), 'n': 2}"
    """
    if isinstance(value, np.ndarray):
        return f"array(shape={value.shape}, dtype={value.dtype})"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k!r}: {summarize(v)}" for k, v in value.items()) + "}"
    if isinstance(value, (list, tuple)) and not hasattr(value, "_fields"):
        inner = ", ".join(summarize(v) for v in value)
        if isinstance(value, list):
            return f"[{inner}]"
        return f"({inner},)" if len(value) == 1 else f"({inner})"
    return repr(value)


def record_repr(record) -> str:
    """Repr of a dataclass instance that shows its arrays as shapes and dtypes.

    Fields declared with ``repr=False`` are left out, as in the generated repr. Assign it in
    the class body (``__repr__ = record_repr``): the ``dataclass`` decorator keeps a
    ``__repr__`` the class defines itself.

    Parameters
    ----------
    record : dataclass instance

    Returns
    -------
    str
        ``ClassName(field=value, ...)``.

    Examples
    --------
    >>> import dataclasses
    >>> import numpy as np
    >>> @dataclasses.dataclass(frozen=True)
    ... class Map:
    ...     depth_m: np.ndarray
    ...     method: str
    ...     __repr__ = record_repr
    >>> Map(np.zeros((2, 3), np.float32), "local")
    Map(depth_m=array(shape=(2, 3), dtype=float32), method='local')
    """
    fields = ", ".join(
        f"{f.name}={summarize(getattr(record, f.name))}" for f in dataclasses.fields(record) if f.repr
    )
    return f"{type(record).__qualname__}({fields})"
