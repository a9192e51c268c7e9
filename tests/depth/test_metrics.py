"""Depth metrics (HCI conventions) against hand-computed numbers and the twin's geometry."""

import numpy as np
import pytest

from lfring.calibration.model import VariableHomography
from lfring.calibration.ring import RingCalibration
from lfring.depth.metrics import (
    badpix,
    depth_to_disparity_px,
    mae,
    median_relative_error,
    mse_x100,
    summary,
)
from lfring.errors import InvalidInputError
from lfring.optics.paraxial import sensor_to_pixel
from lfring.optics.views import optical_layout, view_cameras

# 2 x 3, asymmetric; one missing estimate, one pixel without ground truth.
EST = np.array([[1.0, 2.0, 3.0], [np.nan, 5.0, 6.5]])
TRUTH = np.array([[1.0, 2.05, 2.5], [4.0, 5.2, np.nan]])
# Evaluated: the 5 pixels with finite truth. Errors 0, 0.05, 0.5, missing, 0.2.


def test_badpix_counts_missing_estimates_as_bad_and_skips_unknown_truth():
    assert badpix(EST, TRUTH, 0.07) == pytest.approx(3 / 5)  # 0.5, missing, 0.2
    assert badpix(EST, TRUTH, 0.3) == pytest.approx(2 / 5)  # 0.5, missing
    assert badpix(EST, TRUTH, 1.0) == pytest.approx(1 / 5)  # missing only
    assert badpix(EST, TRUTH, 0.05 + 1e-12) == pytest.approx(3 / 5)


def test_error_means_leave_missing_estimates_out():
    assert mse_x100(EST, TRUTH) == pytest.approx(100 * (0 + 0.05**2 + 0.5**2 + 0.2**2) / 4)
    assert mae(EST, TRUTH) == pytest.approx((0 + 0.05 + 0.5 + 0.2) / 4)
    # relative errors 0, 0.05/2.05, 0.2, 0.2/5.2: median of four = mean of the middle two
    rel = sorted([0.0, 0.05 / 2.05, 0.5 / 2.5, 0.2 / 5.2])
    assert median_relative_error(EST, TRUTH) == pytest.approx((rel[1] + rel[2]) / 2)


def test_mask_selects_pixels():
    mask = np.array([[False, True, True], [True, False, True]])  # (1, 2) has no truth: not evaluated
    assert badpix(EST, TRUTH, 0.3, mask) == pytest.approx(2 / 3)  # 0.05 good; 0.5 and missing bad
    assert mae(EST, TRUTH, mask) == pytest.approx((0.05 + 0.5) / 2)
    assert mse_x100(EST, TRUTH, mask) == pytest.approx(100 * (0.05**2 + 0.5**2) / 2)


def test_float32_maps_are_evaluated_in_float64():
    t = np.full((4, 5), 100.0, np.float32)
    e = t + np.float32(0.25)
    assert mae(e, t) == pytest.approx(0.25)
    assert mse_x100(e, t) == pytest.approx(6.25)
    assert isinstance(badpix(e, t, 0.3), float)


def test_all_estimates_missing_gives_nan_means_and_all_bad():
    e = np.full((2, 3), np.nan)
    assert badpix(e, TRUTH, 1.0) == 1.0
    assert np.isnan(mae(e, TRUTH)) and np.isnan(mse_x100(e, TRUTH)) and np.isnan(median_relative_error(e, TRUTH))


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda: mae(EST, TRUTH[:, :2]), "same shape"),
        (lambda: mae(np.ones((2, 3), np.int64), TRUTH), "floating-point"),
        (lambda: mae(EST, TRUTH, np.zeros((2, 3), bool)), "selects no pixel"),
        (lambda: mae(EST, TRUTH, np.ones((2, 3), np.uint8)), "boolean"),
        (lambda: mae(EST, TRUTH, np.ones((3, 2), bool)), "shape of the maps"),
        (lambda: mae(EST, np.full((2, 3), np.nan)), "no finite value"),
        (lambda: badpix(EST, TRUTH, 0.0), "positive"),
        (lambda: badpix(EST, TRUTH, np.nan), "positive"),
        (lambda: median_relative_error(EST, -TRUTH), "positive depths"),
        (lambda: mae(np.array([]), np.array([])), "non-empty"),
    ],
)
def test_bad_inputs_raise_clear_errors(call, message):
    with pytest.raises(InvalidInputError, match=message):
        call()


# -- depth to disparity ------------------------------------------------------------------------
def _toy_model():
    """View 1 sits 10 - 2/(Z - 0.5) px right of view 0 in the reference; view 2 is 3/(Z - 0.5) px below."""
    a = np.stack([np.eye(3)] * 3)
    b = np.zeros((3, 3, 3))
    a[1, 0, 2], b[1, 0, 2] = 10.0, -2.0
    b[2, 1, 2] = 3.0
    return VariableHomography(a, b, 0.5, 0)


def test_disparity_by_hand():
    z = np.array([[1.5, 2.5, np.nan], [0.6, 1.0, np.inf]])
    d = depth_to_disparity_px(z, _toy_model(), 0, 1)
    np.testing.assert_allclose(d, [[8.0, 9.0, np.nan], [np.abs(10 - 20.0), 6.0, np.nan]])
    np.testing.assert_allclose(depth_to_disparity_px(z, _toy_model(), 0, 2)[0], [3.0, 1.5, np.nan])
    # |t_b - t_a| is symmetric in the pair; the signed disparity grows towards the viewer.
    np.testing.assert_allclose(depth_to_disparity_px(z, _toy_model(), 1, 0), d)
    s = depth_to_disparity_px(z, _toy_model(), 0, 1, signed=True)
    np.testing.assert_allclose(s, [[-8.0, -9.0, np.nan], [10.0, -6.0, np.nan]])
    # At Z = 0.7 the views coincide: |d| folds, the signed disparity does not.
    assert depth_to_disparity_px(np.array([0.7]), _toy_model(), 0, 1)[0] == pytest.approx(0.0)


def test_disparity_of_the_twin_matches_the_pinholes(prototype):
    dev = prototype.binned(4)
    layout = optical_layout(dev)
    cal = RingCalibration.from_optics(dev, layout=layout)
    cams = view_cameras(dev)
    corners = np.array([r[:2] for r in layout.rects], dtype=np.float64)
    z = np.array([[0.3, 0.5], [1.0, 4.0]], np.float32)
    for a, b in [(0, 1), (0, 2), (3, 1)]:
        got = depth_to_disparity_px(z, cal, a, b)
        # The same world point in the two views' own pixel frames: p_a - p_b is the disparity vector.
        pts = np.stack([np.full(z.shape, 0.01), np.full(z.shape, -0.02), z.astype(np.float64)], axis=-1)
        px = sensor_to_pixel(dev, cams.project_m(pts)) - corners[:, None, None, :]
        np.testing.assert_allclose(got, np.linalg.norm(px[a] - px[b], axis=-1), rtol=1e-9)
        # and exactly the translations of calibration.model(Z)
        h = cal.model(z.astype(np.float64).ravel())
        np.testing.assert_allclose(got.ravel(), np.linalg.norm(h[:, b, :2, 2] - h[:, a, :2, 2], axis=-1), rtol=1e-12)
    horiz = depth_to_disparity_px(z, cal, 0, 1, signed=True)
    assert np.all(np.diff(horiz.ravel()) < 0)  # farther, smaller


def test_disparity_rejects_bad_input():
    m = _toy_model()
    with pytest.raises(InvalidInputError, match="depth origin"):
        depth_to_disparity_px(np.array([0.4]), m)
    with pytest.raises(InvalidInputError, match="two different views"):
        depth_to_disparity_px(np.array([1.0]), m, 1, 1)
    with pytest.raises(InvalidInputError, match="view_b must be a view index 0..2"):
        depth_to_disparity_px(np.array([1.0]), m, 0, 3)
    with pytest.raises(InvalidInputError, match="RingCalibration"):
        depth_to_disparity_px(np.array([1.0]), "calib.json")
    with pytest.raises(InvalidInputError, match="floating-point"):
        depth_to_disparity_px(np.array([1, 2]), m)


# -- summary ------------------------------------------------------------------------------------
def test_summary_on_a_hand_made_model():
    m = _toy_model()
    truth = np.array([[1.5, 2.5], [4.5, np.nan]])  # signed disparity (0, 1): -8, -9, -9.5
    est = np.array([[1.5, 1.0], [np.nan, 3.0]])  # -8 (exact), -6 (3 px off), missing, no truth
    out = summary(est, truth, m, taus=(0.5, 4.0))
    assert out == pytest.approx(
        {
            "badpix_0.5px": 2 / 3,
            "badpix_4px": 1 / 3,
            "mse_x100": 100 * 9 / 2,
            "mae_m": 1.5 / 2,
            "mae_px": 3 / 2,
            "median_relative_error": 0.3,  # 0 and 0.6
            "n_pixels": 3,
            "n_missing": 1,
            "view_a": 0,
            "view_b": 1,
        }
    )
    out_v = summary(est, truth, m, view_b=2, taus=(1.0,))
    assert out_v["mae_px"] == pytest.approx(abs(3 / 0.5 - 3 / 2.0) / 2)
    assert out_v["mae_m"] == out["mae_m"]


def test_summary_of_the_twins_ground_truth(prototype):
    from lfring.synth import Plane, Scene, Texture, render

    r = render(prototype, Scene((Plane(0.5, (0.4, 0.4), Texture("speckle")),)), binning=4)
    cal = RingCalibration.from_optics(r.device, layout=r.layout)
    truth = r.depth_m[0]
    perfect = summary(truth, truth, cal)
    assert perfect["n_pixels"] == truth.size and perfect["n_missing"] == 0
    assert perfect["badpix_0.07px"] == 0 and perfect["mse_x100"] == 0 and perfect["median_relative_error"] == 0
    est = truth.copy()
    est[:10, :20] = 0.35  # 200 pixels 15 cm too near
    est[-1, :5] = np.nan
    d = abs(depth_to_disparity_px(np.array([0.35]), cal)[0] - depth_to_disparity_px(np.array([0.5]), cal)[0])
    out = summary(est, truth, cal)
    n = truth.size
    assert d > 1.0  # so every threshold sees the 200 wrong pixels
    for key in ("badpix_0.07px", "badpix_0.3px", "badpix_1px"):
        assert out[key] == pytest.approx(205 / n)
    assert out["mae_m"] == pytest.approx(200 * 0.15 / (n - 5), rel=1e-6)
    assert out["mae_px"] == pytest.approx(200 * d / (n - 5), rel=1e-6)
    assert out["mse_x100"] == pytest.approx(100 * 200 * d * d / (n - 5), rel=1e-6)
    assert out["median_relative_error"] == 0.0
    mask = np.zeros(truth.shape, bool)
    mask[:10, :10] = True
    assert summary(est, truth, cal, mask)["badpix_1px"] == 1.0


def test_summary_validates():
    m = _toy_model()
    t = np.ones((2, 2))
    with pytest.raises(InvalidInputError, match="at least one threshold"):
        summary(t, t, m, taus=())
    with pytest.raises(InvalidInputError, match="same shape"):
        summary(t, np.ones((2, 3)), m)
    with pytest.raises(InvalidInputError, match="selects no pixel"):
        summary(t, t, m, np.zeros((2, 2), bool))


def test_evaluation_mask_keeps_textured_pixels_away_from_depth_edges():
    from lfring.depth.metrics import evaluation_mask

    rng = np.random.default_rng(0)
    truth = np.full((60, 80), 0.5)
    truth[:, 40:] = 0.8  # a depth edge at column 40
    image = np.full((60, 80), 0.5, np.float32)
    image[:30] = rng.random((30, 80)).astype(np.float32)  # textured top half only
    m = evaluation_mask(truth, image, margin_px=11)
    assert not m[35:].any()  # untextured (the 9 px texture window reaches 4 px into it)
    assert not m[:, 35:45].any()  # within 5 px of the edge
    assert m[5:25, 5:30].all() and m[5:25, 50:75].all()
    with pytest.raises(InvalidInputError, match="shape"):
        evaluation_mask(truth, image[:, :10])
