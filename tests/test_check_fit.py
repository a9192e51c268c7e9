"""check_frame measures how well a frame fits the calibration at the depth that fits it best."""

import numpy as np

import lfring
from lfring.calibration.defaults import default_calibration
from lfring.check import check_frame


def test_a_target_of_the_calibrated_camera_fits_to_hundredths_of_a_pixel():
    image = lfring.demosaic(lfring.load_raw("data/synthetic/target_0.5m.png"))
    cal, _ = default_calibration((image.shape[1], image.shape[0]))
    res = check_frame(image, cal, measure_fit=True)
    assert res.ok and res.fit_px < 0.03 and abs(res.fit_depth_m - 0.5) < 0.005
    assert np.isnan(check_frame(image, cal).fit_px)  # measured only when asked
