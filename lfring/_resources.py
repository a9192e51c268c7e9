"""Where the files shipped in the repository's calib/ folder are found.

An installed lfring carries them as the package ``lfring._calib`` (pyproject maps calib/ there);
a source checkout imported without installing has them beside the package.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # importlib.abc.Traversable is deprecated from Python 3.12 and gone in 3.14
    from importlib.resources.abc import Traversable


def calib_dir() -> Traversable:
    """The folder of built-in device and calibration files."""
    try:
        return resources.files("lfring._calib")
    except ModuleNotFoundError:
        return Path(__file__).resolve().parent.parent / "calib"
