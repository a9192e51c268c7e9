"""Calibrations are recognised by the protocol the stages need."""

import pytest

from lfring.calibration.defaults import default_calibration
from lfring.core.protocols import Calibration, check_calibration
from lfring.errors import InvalidInputError


def test_a_ring_calibration_meets_the_protocol_and_others_do_not():
    cal, _ = default_calibration((2456, 1842))
    assert isinstance(cal, Calibration) and check_calibration(cal) is cal
    for other in (None, "twin_binned2", object(), {"homographies": None}):
        with pytest.raises(InvalidInputError, match="calibration must be a RingCalibration"):
            check_calibration(other)
