"""Reading small JSON documents (calibrations, layouts) with errors that name the file."""

from __future__ import annotations

import json
from pathlib import Path

from lfring.errors import FileFormatError, LfringFileNotFoundError

__all__ = ["read_json_object"]


def read_json_object(path: str | Path, what: str) -> dict:
    """The JSON object in ``path``; ``what`` names the kind of file in error messages."""
    path = Path(path)
    if not path.is_file():
        raise LfringFileNotFoundError(f"{what} file not found: {path}")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise FileFormatError(f"{path}: not a JSON {what} file ({exc})") from None
    if not isinstance(data, dict):
        raise FileFormatError(f"{path}: not a JSON {what} object")
    return data
