"""Variable-homography calibration of refocusing in metric depth (SPEC 4)."""

from lfring.calibration.fit import calibrate
from lfring.calibration.model import PlaneFit, VariableHomography, fit_variable_homography
from lfring.calibration.ring import CALIBRATION_VERSION, RingCalibration, builtin_calibrations

__all__ = [
    "CALIBRATION_VERSION",
    "PlaneFit",
    "RingCalibration",
    "VariableHomography",
    "builtin_calibrations",
    "calibrate",
    "fit_variable_homography",
]
