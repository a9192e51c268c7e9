"""RingCalibration's queries: homographies at any depth and reference, the checks of depths,
views and frames, and its short repr."""

import numpy as np
import pytest

from lfring.calibration import RingCalibration, calibration_from_grid
from lfring.errors import InvalidInputError, LfringWarning
from lfring.optics.views import optical_homographies, optical_layout


@pytest.fixture(scope="module")
def twin(prototype):
    dev = prototype.binned(2)
    return dev, optical_layout(dev)


def _exact(twin, depths, reference=0):
    dev, lay = twin
    return {z: optical_homographies(dev, lay, z, reference=reference) for z in depths}


def test_ring_calibration_from_optics_and_references(twin):
    dev, lay = twin
    cal = RingCalibration.from_optics(dev)
    for ref in ("center", 0, 3):
        np.testing.assert_allclose(cal.homographies(0.42, reference=ref), optical_homographies(dev, lay, 0.42, reference=ref), atol=1e-9)
    np.testing.assert_allclose(cal.homography(2, 0.42, reference="center"), optical_homographies(dev, lay, 0.42)[2], atol=1e-9)
    assert cal.raw_size == (2456, 1842)
    with pytest.raises(InvalidInputError, match="view must be"):
        cal.homography(4, 0.5)
    with pytest.raises(InvalidInputError, match="reference"):
        cal.homographies(0.5, reference="middle")
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(InvalidInputError, match="depth"):
            cal.homographies(bad)
    with pytest.raises(InvalidInputError, match="1228 x 920 px but the calibration is for 2456 x 1842"):
        cal.check_frame((920, 1228))


def test_outside_the_calibrated_range_warns(twin):
    dev, lay = twin
    cal = RingCalibration.from_plane_homographies(_exact(twin, (0.3, 1.0)), layout=lay, depth_origin_m=dev.entrance_pupil_m)
    assert cal.valid_depth_range_m == (0.3, 1.0)
    cal.homographies(0.5)  # inside: no warning (warnings are errors in the test suite)
    with pytest.warns(LfringWarning, match="outside the calibrated range"):
        cal.homographies(2.0)


def test_repr_is_one_short_line(twin):
    """The repr names what the calibration is for, never its arrays (the generated one printed
    every matrix of the model and every residual)."""
    dev, lay = twin
    fitted = RingCalibration.from_plane_homographies(_exact(twin, (0.3, 0.5, 1.0)), layout=lay, depth_origin_m=None)
    for cal in (RingCalibration.from_optics(dev), fitted, RingCalibration.load("twin_binned2")):
        text = repr(cal)
        assert "\n" not in text and "array" not in text and len(text) < 200
        assert text.startswith(f"RingCalibration(source={cal.source!r}, num_views=4, view_shape={cal.layout.view_shape}, ")
    grid = calibration_from_grid((8, 12), [(x, y) for y in range(10) for x in range(10)], disparity_scale_px_m=2.0)
    assert repr(grid) == ("RingCalibration(source='grid', num_views=100, view_shape=(8, 12), depth_origin_m=0, "
                          "valid_depth_range_m=(0.16666666666666666, None), device=None)")
    optics = RingCalibration.from_optics(dev)
    assert repr(optics).endswith(f"valid_depth_range_m=({optics.valid_depth_range_m[0]!r}, None), device='prototype')")


@pytest.mark.parametrize("views", [True, [0, 0], [0, 3], [0.0, 1], [False, 1], "01"])
def test_select_views_refuses_what_is_not_a_set_of_view_indices(views):
    cal = calibration_from_grid((8, 8), [(0, 0), (1, 0), (0, 1)], disparity_scale_px_m=1.0)
    with pytest.raises(InvalidInputError, match=r"views must be distinct view indices 0\.\.2"):
        cal.select_views(views)
    assert cal.select_views(np.array([2, 0])).num_views == 2


def test_homography_takes_numpy_view_indices_but_not_bools():
    cal = calibration_from_grid((8, 8), [(0, 0), (1, 0)], disparity_scale_px_m=1.0)
    np.testing.assert_array_equal(cal.homography(np.int64(1), 2.0), cal.homographies(2.0)[1])
    for bad in (True, 1.0, -1, 2):
        with pytest.raises(InvalidInputError, match=r"view must be a view index 0\.\.1"):
            cal.homography(bad, 2.0)


def test_a_frame_given_to_a_grid_calibration_is_told_to_give_the_views():
    """A grid calibration takes separate view images: a frame of another size is refused with
    the views it wants, not as a frame of the wrong size."""
    pair = RingCalibration.from_grid((64, 96), [(0, 0), (1, 0)], disparity_scale_px_m=120.0)
    with pytest.raises(InvalidInputError, match=r"is one image of 300 x 200 px, but the calibration is a grid of 2 "
                                                r"separate view images of 96 x 64 px: give its 2 view images"):
        pair.check_frame((200, 300), what="frame f.png")
