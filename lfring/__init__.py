"""lfring: light-field processing for a camera fitted with a ring of four mini-lenses.

The pipeline: ``load_raw`` -> ``demosaic`` -> ``detect_layout`` / ``split_views`` -> views
(V, h, w, C). The optics (device design, ray tracing, the views' exact geometry) live in
:mod:`lfring.optics`, the synthetic twin in :mod:`lfring.synth`.

Importing lfring never imports torch; the torch/kornia paths load on first use.
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
from lfring.io.demosaic import demosaic
from lfring.io.raw import RawFrame, load_raw
from lfring.views import Layout, detect_layout, split_views

__version__ = "0.1.0"

__all__ = [
    "DesignError",
    "DeviceError",
    "EstimationError",
    "FileFormatError",
    "InvalidInputError",
    "Layout",
    "LfringError",
    "LfringFileNotFoundError",
    "RawFrame",
    "__version__",
    "demosaic",
    "detect_layout",
    "load_raw",
    "split_views",
]
