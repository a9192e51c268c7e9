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


def test_twin_default_is_measured_and_predicts_the_held_out_target(prototype):
    from pathlib import Path

    from lfring.calibration.planes import estimate_plane_homographies
    from lfring.core.geometry import homography_rms_px
    from lfring.io.demosaic import demosaic
    from lfring.io.raw import load_raw
    from lfring.optics.views import optical_homographies
    from lfring.views import split_views

    cal, name = default_calibration((2456, 1842))
    assert name == "twin_binned2" and cal.source == "planes"
    assert cal.depth_origin_m == pytest.approx(prototype.binned(2).entrance_pupil_m)
    data = Path(__file__).resolve().parents[2] / "data" / "synthetic"
    lay = cal.layout
    views = split_views(demosaic(load_raw(data / "target_0.5m.png")), lay)
    flat = split_views(demosaic(load_raw(data / "flat.png")), lay)
    measured = estimate_plane_homographies(views, masks=lay.masks(), flat_views=flat).H_ref_from_view
    predicted = cal.homographies(0.5, reference=0)
    assert homography_rms_px(predicted, measured, lay.view_shape).max() < 0.05
    # And against the optics' exact homographies in the same (detected) layout, in and out of range.
    truth = optical_homographies(prototype.binned(2), lay, 0.5, reference=0)
    assert homography_rms_px(predicted, truth, lay.view_shape).max() < 0.05
    assert homography_rms_px(cal.model(2.0), optical_homographies(prototype.binned(2), lay, 2.0, reference=0), lay.view_shape).max() < 0.05
