"""lfring: light-field processing for a camera fitted with a ring of four mini-lenses.

Importing lfring never imports torch; the torch/kornia backend loads on first use.
"""

from lfring.errors import (
    DesignError,
    DeviceError,
    EstimationError,
    FileFormatError,
    InvalidInputError,
    LfringError,
    LfringFileNotFoundError,
)

__version__ = "0.1.0"

__all__ = [
    "DesignError",
    "DeviceError",
    "EstimationError",
    "FileFormatError",
    "InvalidInputError",
    "LfringError",
    "LfringFileNotFoundError",
    "__version__",
]
