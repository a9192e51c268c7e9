import numpy as np
import pytest

from lfring.calibration import RingCalibration
from lfring.calibration.defaults import builtin_calibrations, default_calibration
from lfring.errors import LfringFileNotFoundError


def test_prototype_default_is_its_optics(prototype):
    assert builtin_calibrations()["prototype_optics"] == (4912, 3684)
    cal, name = default_calibration((4912, 3684))
    assert name == "prototype_optics" and cal.source == "optics"
    ref = RingCalibration.from_optics(prototype)
    np.testing.assert_allclose(cal.homographies(0.5), ref.homographies(0.5), atol=1e-9)


def test_no_default_for_other_sizes():
    with pytest.raises(LfringFileNotFoundError, match="no built-in calibration for 640 x 480 px.*prototype_optics"):
        default_calibration((640, 480))
