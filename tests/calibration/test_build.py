"""Building calibrations: the functions of lfring.calibration.build and the RingCalibration
methods that delegate to them."""

import numpy as np
import pytest

from lfring.calibration import RingCalibration
from lfring.calibration.build import (
    calibration_from_grid,
    calibration_from_optics,
    calibration_from_plane_homographies,
)
from lfring.errors import InvalidInputError
from lfring.optics.views import optical_homographies, optical_layout
from lfring.views import grid_layout


@pytest.fixture(scope="module")
def twin(prototype):
    dev = prototype.binned(2)
    return dev, optical_layout(dev)


def test_from_optics_is_the_paraxial_model(twin):
    dev, lay = twin
    cal = calibration_from_optics(dev)
    assert isinstance(cal, RingCalibration) and cal.source == "optics" and cal.device == dev.name
    assert cal.valid_depth_range_m[1] is None and cal.depth_origin_m < cal.valid_depth_range_m[0]
    assert set(cal.provenance) == {"ring_distance_m", "sensor_distance_m", "pixel_pitch_m", "device_record"}
    assert cal.device_optics() == dev  # the device itself, every field
    np.testing.assert_allclose(cal.homographies(0.42, reference=0), optical_homographies(dev, lay, 0.42, reference=0), atol=1e-9)
    # A given layout is used as it is.
    assert calibration_from_optics(dev, layout=lay).layout is lay
    # The method builds the same calibration.
    method = RingCalibration.from_optics(dev)
    np.testing.assert_array_equal(method.homographies(0.42), cal.homographies(0.42))
    assert (method.valid_depth_range_m, method.provenance) == (cal.valid_depth_range_m, cal.provenance)
    # A device's name, as every other function taking a device takes it (it broke on an attribute).
    from lfring.optics import load_device

    named, given = RingCalibration.from_optics("prototype"), RingCalibration.from_optics(load_device("prototype"))
    assert named.device == "prototype" and named.raw_size == given.raw_size == (4912, 3684)
    np.testing.assert_array_equal(named.homographies(0.42), given.homographies(0.42))
    with pytest.raises(InvalidInputError, match="a device is a RingDevice, a built-in name"):
        RingCalibration.from_optics(None)


def test_from_plane_homographies_fits_and_keeps_the_planes(twin):
    dev, lay = twin
    meas = {z: optical_homographies(dev, lay, z, reference=0) for z in (0.3, 0.5, 1.0)}
    cal = calibration_from_plane_homographies(meas, layout=lay, depth_origin_m=None, rank1=True, provenance={"target": "x"})
    assert cal.source == "planes" and cal.valid_depth_range_m == (0.3, 1.0) and cal.provenance == {"target": "x"}
    assert [p.depth_m for p in cal.planes] == [0.3, 0.5, 1.0]
    np.testing.assert_allclose(cal.homographies(0.7, reference=0), optical_homographies(dev, lay, 0.7, reference=0), atol=1e-6)
    method = RingCalibration.from_plane_homographies(meas, layout=lay, depth_origin_m=None, rank1=True)
    np.testing.assert_array_equal(method.model.A, cal.model.A)
    with pytest.raises(InvalidInputError, match="needs the layout"):
        calibration_from_plane_homographies(meas, layout=None)


def test_from_grid_is_a_translation_per_grid_step():
    cal = calibration_from_grid((6, 10), [(0, 0), (2, 1)], disparity_scale_px_m=np.float32(4.0), disparity_offset_px=1)
    assert cal.source == "grid" and cal.layout.view_shape == (6, 10)
    np.testing.assert_allclose(cal.homographies(2.0, reference=0)[1, :2, 2], np.array([2.0, 1.0]) * (1 + 4.0 / 2.0))
    # Plain floats in provenance, whatever number type came in (it is written to JSON).
    assert type(cal.provenance["disparity_scale_px_m"]) is float and type(cal.provenance["disparity_offset_px"]) is float
    method = RingCalibration.from_grid((6, 10), [(0, 0), (2, 1)], disparity_scale_px_m=4.0, disparity_offset_px=1)
    np.testing.assert_array_equal(method.homographies(2.0), cal.homographies(2.0))
    assert method.layout.rects == cal.layout.rects == grid_layout((6, 10), [(0, 0), (2, 1)]).rects


@pytest.mark.parametrize("name", ["disparity_scale_px_m", "disparity_offset_px", "depth_origin_m"])
@pytest.mark.parametrize("bad", [True, "1.0", None, float("inf")])
def test_from_grid_refuses_what_is_not_a_finite_number(name, bad):
    kw = {"disparity_scale_px_m": 1.0, name: bad}
    with pytest.raises(InvalidInputError, match=f"{name} must be a number"):
        calibration_from_grid((8, 8), [(0, 0), (1, 0)], **kw)
