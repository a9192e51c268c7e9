"""The variable-homography model against the optics' exact homographies."""

import json

import numpy as np
import pytest

from lfring.calibration import RingCalibration, fit_variable_homography
from lfring.errors import FileFormatError, InvalidInputError, LfringFileNotFoundError, LfringWarning
from lfring.core.geometry import homography_rms_px
from lfring.optics.views import optical_homographies, optical_layout


@pytest.fixture(scope="module")
def twin(prototype):
    dev = prototype.binned(2)
    return dev, optical_layout(dev)


def _exact(twin, depths, reference=0):
    dev, lay = twin
    return {z: optical_homographies(dev, lay, z, reference=reference) for z in depths}


def _worst(model_h, truth_h, shape):
    return max(homography_rms_px(model_h[k], truth_h[k], shape) for k in range(len(truth_h)))


def test_two_planes_with_the_right_z0_are_exact_and_z0_zero_is_not(twin):
    dev, lay = twin
    s = dev.entrance_pupil_m
    meas = _exact(twin, (0.3, 1.0))
    good, _ = fit_variable_homography(meas, shape_hw=lay.view_shape, depth_origin_m=s)
    naive, _ = fit_variable_homography(meas, shape_hw=lay.view_shape, depth_origin_m=0.0)
    for z in (0.5, 2.0):
        truth = optical_homographies(dev, lay, z, reference=0)
        assert _worst(good(z), truth, lay.view_shape) < 1e-9
        # Assuming z0 = 0 costs about 0.2 px on the binned twin at the held-out planes.
        err = _worst(naive(z), truth, lay.view_shape)
        assert 0.1 < err < 0.3


def test_three_planes_recover_z0(twin):
    dev, lay = twin
    model, planes = fit_variable_homography(_exact(twin, (0.3, 0.6, 1.0)), shape_hw=lay.view_shape, depth_origin_m=None)
    assert model.depth_origin_m == pytest.approx(dev.entrance_pupil_m, abs=1e-6)
    for p in planes:
        assert p.residual_px.max() < 1e-6 and p.leave_one_out_px.max() < 1e-5


def test_fit_with_measurement_noise(twin):
    dev, lay = twin
    rng = np.random.default_rng(0)
    meas = {z: h + np.pad(rng.normal(0, 0.02, (4, 2, 1)), ((0, 0), (0, 1), (2, 0))) for z, h in _exact(twin, (0.3, 0.45, 0.7, 1.0)).items()}
    model, planes = fit_variable_homography(meas, shape_hw=lay.view_shape, depth_origin_m=None, rank1=True)
    assert abs(model.depth_origin_m - dev.entrance_pupil_m) < 0.01
    for k in range(4):
        assert np.linalg.matrix_rank(model.B[k], tol=1e-9) <= 1
    truth = optical_homographies(dev, lay, 0.5, reference=0)
    assert _worst(model(0.5), truth, lay.view_shape) < 0.05


@pytest.mark.parametrize(
    "planes, kwargs, match",
    [
        ({0.3: np.eye(3)[None].repeat(4, 0)}, {}, "two or more depths"),
        ({0.3: np.eye(3)[None].repeat(4, 0), 0.3 + 1e-9: np.eye(3)[None].repeat(4, 0)}, {}, "distinct"),
        ({-0.3: np.eye(3)[None].repeat(4, 0), 1.0: np.eye(3)[None].repeat(4, 0)}, {}, "positive"),
        ({0.3: np.full((4, 3, 3), np.nan), 1.0: np.eye(3)[None].repeat(4, 0)}, {}, "finite"),
        ({0.3: np.eye(3)[None].repeat(4, 0), 1.0: np.eye(3)[None].repeat(4, 0)}, {"depth_origin_m": 0.5}, "in front of"),
        ({0.3: np.eye(3)[None].repeat(4, 0), 1.0: np.eye(3)[None].repeat(4, 0)}, {"depth_origin_m": None}, "three or more"),
    ],
)
def test_fit_errors(planes, kwargs, match):
    with pytest.raises(InvalidInputError, match=match):
        fit_variable_homography(planes, shape_hw=(100, 100), **kwargs)


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


def test_save_load_round_trip(tmp_path, twin):
    dev, lay = twin
    cal = RingCalibration.from_plane_homographies(_exact(twin, (0.3, 0.5, 1.0)), layout=lay, depth_origin_m=None, pattern="GRBG")
    back = RingCalibration.load(cal.save(tmp_path / "c.json"))
    np.testing.assert_array_equal(back.model.A, cal.model.A)
    np.testing.assert_array_equal(back.model.B, cal.model.B)
    assert back.depth_origin_m == cal.depth_origin_m and back.pattern == "GRBG"
    assert [p.depth_m for p in back.planes] == [0.3, 0.5, 1.0]
    np.testing.assert_array_equal(back.planes[1].leave_one_out_px, cal.planes[1].leave_one_out_px)


def _edit(tmp_path, cal, fn):
    data = cal.to_dict()
    fn(data)
    p = tmp_path / "edited.json"
    p.write_text(json.dumps(data))
    return p


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda d: d.update(lfring_calibration_version=99), "version"),
        (lambda d: d.pop("A"), "missing key 'A'"),
        (lambda d: d.update(B=[[1, 2], [3, 4]]), "'B' must be 4 finite 3 x 3"),
        (lambda d: d.update(depth_origin_m="zero"), "'depth_origin_m' must be a finite number"),
        (lambda d: d.update(colour="red"), "unknown key"),
        (lambda d: d.update(reference_view=7), "reference_view"),
        (lambda d: d.update(raw_width_px=100), "disagree with the layout"),
        (lambda d: d["layout"].update(rects_xywh_px=[[0, 0, 10, 10]] * 3), "4 views but the layout 3|layout"),
        (lambda d: d.update(bayer_pattern="RGBG"), "bayer_pattern"),
        (lambda d: d.update(valid_depth_range_m=[0.01, 1.0]), "valid depth range"),
    ],
)
def test_hand_edited_calibration_files(tmp_path, twin, edit, match):
    cal = RingCalibration.from_optics(twin[0])
    with pytest.raises(FileFormatError, match=match):
        RingCalibration.load(_edit(tmp_path, cal, edit))


def test_corrupt_and_missing_files(tmp_path, twin):
    cal = RingCalibration.from_optics(twin[0])
    p = cal.save(tmp_path / "c.json")
    p.write_text(p.read_text()[:200])
    with pytest.raises(FileFormatError, match="not a JSON calibration"):
        RingCalibration.load(p)
    with pytest.raises(LfringFileNotFoundError):
        RingCalibration.load(tmp_path / "none.json")
