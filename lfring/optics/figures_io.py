"""Writing matplotlib figures atomically, without clobbering files."""

from __future__ import annotations

from pathlib import Path

from lfring.errors import InvalidInputError
from lfring.io.atomic import atomic_path

__all__ = ["save_figure"]

_FORMATS = {".png", ".pdf", ".svg"}


def save_figure(fig, path: str | Path, *, overwrite: bool = False, dpi: int = 150) -> Path:
    """Save ``fig`` to ``path`` (.png, .pdf or .svg) atomically; refuse to replace a file unless
    ``overwrite``."""
    path = Path(path)
    if path.suffix.lower() not in _FORMATS:
        raise InvalidInputError(f"figure file must end in {', '.join(sorted(_FORMATS))}: got {path.name!r}")
    if path.exists() and not overwrite:
        raise InvalidInputError(f"{path} exists; pass --overwrite (overwrite=True) to replace it")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format=path.suffix.lower()[1:])
    return path
