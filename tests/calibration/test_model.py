"""The variable-homography model against the optics' exact homographies."""

import numpy as np
import pytest

from lfring.calibration import fit_variable_homography
from lfring.core.geometry import homography_rms_px
from lfring.errors import InvalidInputError
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
    for p in planes:  # three planes and z0 fitted: any three depths fit, no plane checks the others
        assert p.residual_px.max() < 1e-6 and p.leave_one_out_px is None


def test_four_planes_leave_one_out_finds_a_mislabelled_plane(twin):
    """Where leave-one-out is measured with z0 fitted (four planes and more): exact labels
    predict every plane to 1e-5 px, a plane 1 cm off shows."""
    dev, lay = twin
    exact = _exact(twin, (0.3, 0.45, 0.6, 1.0))
    _, planes = fit_variable_homography(exact, shape_hw=lay.view_shape, depth_origin_m=None)
    assert all(p.leave_one_out_px.max() < 1e-5 for p in planes)
    wrong = {(0.46 if z == 0.45 else z): h for z, h in exact.items()}
    _, planes = fit_variable_homography(wrong, shape_hw=lay.view_shape, depth_origin_m=None)
    loo = [float(p.leave_one_out_px.max()) for p in planes]
    assert max(loo) > 0.1, loo


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


def test_a_calibration_s_model_cannot_be_edited_in_place():
    """A calibration is immutable, and what is derived from it is cached while it lives: an edit
    of model.B in place changed homographies() but not depth estimated with the same object
    (0.4 where a fresh calibration with the edited values gave 0.4365). The arrays are
    read-only copies, so an edit in place raises and a new calibration is the way."""
    import lfring

    cal = lfring.RingCalibration.load("twin_binned2")
    for arr in (cal.model.A, cal.model.B):
        assert not arr.flags.writeable
        with pytest.raises(ValueError, match="read-only"):
            arr[...] *= 1.1
    given = np.stack([np.eye(3)] * 2)
    from lfring.calibration.model import VariableHomography

    model = VariableHomography(given, np.zeros((2, 3, 3)), 0.0, 0)
    given[0, 0, 0] = 5.0  # the caller's array stays the caller's
    assert model.A[0, 0, 0] == 1.0
