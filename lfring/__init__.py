"""lfring: light-field processing for a camera fitted with a ring of four mini-lenses.

The pipeline: ``load_raw`` -> ``demosaic`` -> ``detect_layout`` / ``split_views`` -> views
(V, h, w, C) -> ``calibrate`` / ``RingCalibration`` -> ``check_frame`` -> ``refocus`` / ``estimate_depth`` -> ``inspect_frame`` /
:mod:`lfring.batch`. The optics (device design, ray tracing, the views' exact geometry) live in
:mod:`lfring.optics`, the synthetic twin in :mod:`lfring.synth`.

Importing lfring never imports torch; the torch/kornia paths load on first use.
"""

from lfring.errors import (
    DepthRangeError,
    DesignError,
    DeviceError,
    EstimationError,
    FileFormatError,
    InvalidInputError,
    LfringError,
    LfringFileNotFoundError,
    LfringWarning,
)
from lfring.calibration import RingCalibration, calibrate
from lfring.check import ExposureWarning, FrameCheck, OverExposureWarning, UnderExposureWarning, check_frame
from lfring.depth import DepthResult, estimate_depth
from lfring.io.demosaic import demosaic
from lfring.inspect import Defect, InspectionResult, inspect_frame
from lfring.io.raw import RawFrame, load_raw
from lfring.focus import Refocuser, all_in_focus, focal_stack, refocus
from lfring.views import Layout, detect_layout, split_views

__version__ = "0.1.0"

__all__ = [
    "Defect",
    "DepthRangeError",
    "DepthResult",
    "DesignError",
    "DeviceError",
    "EstimationError",
    "ExposureWarning",
    "FileFormatError",
    "FrameCheck",
    "InspectionResult",
    "InvalidInputError",
    "Layout",
    "LfringError",
    "LfringFileNotFoundError",
    "LfringWarning",
    "OverExposureWarning",
    "UnderExposureWarning",
    "RawFrame",
    "Refocuser",
    "RingCalibration",
    "__version__",
    "all_in_focus",
    "calibrate",
    "check_frame",
    "demosaic",
    "detect_layout",
    "estimate_depth",
    "focal_stack",
    "inspect_frame",
    "load_raw",
    "refocus",
    "split_views",
]
