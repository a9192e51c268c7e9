"""Large working arrays that a call writes before it reads, in memory that is fast to touch.

NumPy asks the system for huge pages for every large array. Where the system is set to compact
its memory to find them on the first write (transparent huge pages with ``defrag`` set to
``madvise``, a common default), the first write to a fresh array of tens of MB can wait on that
compaction for longer than the work on the array takes, most of all in a process that has just
freed other large arrays. A one-shot refocus (the command line's main job) made its depth
volumes and render layers fresh each time and paid it. Memory mapped anonymously is not given
huge pages unless asked for, and comes zeroed, page by page as it is first written.
"""

from __future__ import annotations

import mmap

import numpy as np

__all__ = ["available_memory_bytes", "check_free_memory", "fresh_zeros", "memory_words"]

# Private to the process: a forked child gets its own copy on write, as with any NumPy array
# (a shared map would let a child's writes reach the parent's arrays). Windows has no flags.
_MAP_FLAGS = {"flags": mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS} if hasattr(mmap, "MAP_PRIVATE") else {}


def fresh_zeros(shape, dtype=np.float32) -> np.ndarray:
    """A new C-ordered array of zeros, in an anonymous memory map of its own.

    The zeros cost nothing until written (each page is zeroed by the system on its first
    write), so a caller that fills the array itself pays only that write.

    Parameters
    ----------
    shape : int or tuple of int
    dtype : numpy dtype, optional

    Returns
    -------
    numpy.ndarray
        Writable; it (and every view of it) keeps its map alive.

    Raises
    ------
    MemoryError
        The system has no room for the array (named with its shape, type and size).

    Examples
    --------
    >>> a = fresh_zeros((2, 3), np.uint16)
    >>> a.shape, a.dtype, int(a.sum())
    ((2, 3), dtype('uint16'), 0)
    """
    shape = (int(shape),) if np.ndim(shape) == 0 else tuple(int(s) for s in shape)
    dtype = np.dtype(dtype)
    size = int(np.prod(shape, dtype=np.int64))
    nbytes = size * dtype.itemsize
    try:
        mem = mmap.mmap(-1, max(nbytes, 1), **_MAP_FLAGS)
    except (OSError, OverflowError) as exc:
        raise MemoryError(f"Unable to allocate {nbytes / 2**20:.1f} MiB for an array with shape {shape} and data type "
                          f"{dtype} ({exc})") from None
    return np.frombuffer(mem, dtype, count=size).reshape(shape)


def available_memory_bytes() -> int | None:
    """The memory the system can give a new allocation without swapping, in bytes: Linux's
    ``MemAvailable`` (free memory and the caches it can drop); None where the system does not
    say it (a check that needs it cannot judge: the free pages alone leave out the caches, and
    would refuse what fits)."""
    try:
        with open("/proc/meminfo", "rb") as f:
            for line in f:
                if line.startswith(b"MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def memory_words(n_bytes: float) -> str:
    """A size in words: GiB to one decimal from 1 GiB, whole MiB below.

    >>> memory_words(2.04e9), memory_words(120e6)
    ('1.9 GiB', '114 MiB')
    """
    if n_bytes >= 2**30:
        return f"{n_bytes / 2 ** 30:.1f} GiB"
    return f"{n_bytes / 2 ** 20:.0f} MiB"


def check_free_memory(need_bytes: int, what: str, remedy: str) -> None:
    """Refuse work that needs ``need_bytes`` when the system has less free
    (:func:`available_memory_bytes`; where it cannot say, the work goes ahead), before it starts:
    an :class:`~lfring.errors.InvalidInputError` "``what`` needs more memory than the ... free:
    ``remedy``"."""
    from lfring.errors import InvalidInputError

    free = available_memory_bytes() if need_bytes else None
    if free is not None and need_bytes > free:
        raise InvalidInputError(f"{what} needs more memory than the {memory_words(free)} free: {remedy}")
