"""Atomic file writes: a reader never sees a half-written output, a killed run leaves none."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

from lfring.core.signals import held_signals
from lfring.errors import InvalidInputError

__all__ = ["atomic_path", "atomic_write_bytes", "atomic_write_text", "refuse_folder"]


def refuse_folder(path: Path) -> None:
    """Refuse an output path that is a folder (a file name was meant)."""
    if path.is_dir():
        raise InvalidInputError(f"cannot write {path}: it is a folder; give a file name")


@contextlib.contextmanager
def atomic_path(path: str | Path, *, tmp_dir: str | Path | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (or in ``tmp_dir``, which must be on the same file
    system); on success it is renamed onto ``path``.

    The temporary file keeps the target's suffix so that writers choosing a format by extension
    (OpenCV, tifffile) work unchanged. On error the temporary file is removed.
    """
    path = Path(path)
    refuse_folder(path)
    where = path.parent if tmp_dir is None else Path(tmp_dir)
    tmp_path = None
    try:
        # A Ctrl-C or SIGTERM that comes while the temporary file is made waits until it is known
        # (and so removed below): between its creation and the block it would be left behind.
        with held_signals():
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
                where.mkdir(parents=True, exist_ok=True)
                fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".part{path.suffix}", dir=where)
            except OSError as exc:
                raise _naming(exc, path) from None
            tmp_path = Path(tmp)
            os.close(fd)
            # mkstemp creates 0600; outputs get the ordinary permissions the umask allows.
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp_path, 0o666 & ~umask)
        yield tmp_path
        os.replace(tmp_path, path)
    except BaseException as exc:
        if tmp_path is not None:
            with contextlib.suppress(FileNotFoundError):
                tmp_path.unlink()
            if isinstance(exc, OSError) and exc.filename in (str(tmp_path), tmp_path):
                raise _naming(exc, path) from None
        raise


def _naming(exc: OSError, path: Path) -> OSError:
    """The same error, naming the file the caller asked for (not a temporary file or a folder)."""
    if exc.errno is None:
        return exc
    return type(exc)(exc.errno, exc.strerror, str(path))


def atomic_write_bytes(path: str | Path, data: bytes, *, tmp_dir: str | Path | None = None) -> Path:
    """Write ``data`` to ``path`` atomically: readers see the old file or the whole new one.

    Parameters
    ----------
    path : str or Path
        The file to write; its folder must exist.
    data : bytes
    tmp_dir : str or Path, optional
        Where the temporary file is made (default: beside ``path``, on the same file system).

    Returns
    -------
    Path
        ``path``.
    """
    with atomic_path(path, tmp_dir=tmp_dir) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically, UTF-8 encoded (see :func:`atomic_write_bytes`).

    Parameters
    ----------
    path : str or Path
    text : str

    Returns
    -------
    Path
        ``path``.
    """
    return atomic_write_bytes(path, text.encode("utf-8"))
