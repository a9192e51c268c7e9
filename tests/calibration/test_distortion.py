"""Each view's lens distortion, calibrated from the target planes and undone by the split."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from lfring.calibration import RingCalibration, calibrate
from lfring.calibration.distortion import KEEP_RATIO, NEGLIGIBLE_DISTORTION_PX
from lfring.check import check_frame
from lfring.core.geometry import apply_homography
from lfring.io.demosaic import demosaic
from lfring.io.raw import RawFrame
from lfring.optics import load_device
from lfring.synth import render
from lfring.synth.presets import flat_scene, target_scene
from lfring.views import split_views

CALIB = Path(__file__).resolve().parents[2] / "calib"
BINNING = 4


def _frame(r):
    return RawFrame(mosaic=r.raw, pattern=r.settings.pattern, black_level=r.black_level, white_level=r.white_level,
                    bit_depth=r.settings.bit_depth)


def _twin(device):
    targets = {z: render(device, target_scene(device, z, seed=int(10 * z)), binning=BINNING, noise="low", seed=5)
               for z in (0.3, 0.5, 1.0)}
    flat = render(device, flat_scene(device), binning=BINNING, noise="none")
    return targets, flat


@pytest.fixture(scope="module")
def lenses():
    device = load_device(CALIB / "prototype_lenses.toml")
    targets, flat = _twin(device)
    cal = calibrate({0.3: _frame(targets[0.3]), 1.0: _frame(targets[1.0])}, flat=_frame(flat), device=device,
                    carry_flat=True)
    return device, targets, flat, cal


def _mapping_error_px(cal, truth, depth_m, view, *, reference=0, with_distortion=True):
    """RMS over the part of ``view``'s disc that lands in the reference's disc of the distance
    between where the calibration and the truth send its recorded pixels."""
    lay, tl = cal.layout, truth.layout
    off_k = np.subtract(lay.rects[view][:2], tl.rects[view][:2])
    off_r = np.subtract(lay.rects[reference][:2], tl.rects[reference][:2])
    masks = tl.masks()
    ys, xs = np.nonzero(masks[view][::3, ::3])
    pts = np.stack([xs * 3.0, ys * 3.0], axis=-1)
    want = truth.to_reference(depth_m, view, pts, reference=reference)
    dist = cal.distortion if with_distortion else None
    u = pts - off_k if dist is None else dist[view].undistort(pts - off_k)
    got = apply_homography(cal.homographies(depth_m, reference=reference)[view], u)
    got = (got if dist is None else dist[reference].distort(got)) + off_r
    ix, iy = np.round(want).astype(int).T
    seen = (ix >= 0) & (iy >= 0) & (ix < masks.shape[2]) & (iy < masks.shape[1])
    seen[seen] = masks[reference][iy[seen], ix[seen]]
    err = np.hypot(*(got - want)[seen].T)
    return float(np.sqrt(np.mean(err**2)))


def test_distortion_is_calibrated_from_two_planes(lenses):
    _, targets, _, cal = lenses
    assert cal.distortion is not None and len(cal.distortion) == 4
    info = cal.provenance["distortion"]
    assert info["modelled"] and info["effect_px"] > NEGLIGIBLE_DISTORTION_PX
    assert info["tiles_rms_after_px"] < 0.2 * info["tiles_rms_before_px"]
    # The homographies were measured again on the undistorted views.
    for plane in cal.provenance["planes"]:
        assert max(plane["alignment_residual_px"]) < 0.2 * max(plane["alignment_residual_before_px"])


@pytest.mark.parametrize("depth_m", [0.5, 0.75])
def test_held_out_planes_map_as_the_truth(lenses, depth_m):
    _, targets, _, cal = lenses
    truth = targets[0.5]  # its truth maps any depth
    errors = [_mapping_error_px(cal, truth, depth_m, k) for k in (1, 2, 3)]
    assert max(errors) < 0.05, errors
    # Homographies alone (what the calibration did before it modelled the lenses) miss by far more.
    plain = calibrate({0.3: _frame(targets[0.3]), 1.0: _frame(targets[1.0])}, flat=_frame(lenses[2]),
                      device=lenses[0], distortion=False)
    assert plain.distortion is None
    assert max(_mapping_error_px(plain, truth, depth_m, k) for k in (1, 2, 3)) > 5 * max(errors)


def test_the_split_undoes_the_distortion_and_check_sees_the_fit(lenses):
    _, targets, _, cal = lenses
    image = demosaic(_frame(targets[0.5]))
    views = split_views(image, cal)
    assert views.shape == (4, *cal.layout.view_shape, 3)
    assert not np.array_equal(views, split_views(image, cal.layout))
    fitted = check_frame(image, cal, measure_fit=True)
    plain = check_frame(image, dataclasses.replace(cal, distortion=None, flat_field=None), measure_fit=True)
    assert fitted.ok and fitted.fit_px < 0.08 and abs(fitted.fit_depth_m - 0.5) < 0.01
    assert plain.fit_px > 3 * fitted.fit_px


def test_frames_of_ideal_lenses_calibrate_exactly_as_before(prototype):
    targets, flat = _twin(prototype)
    frames = {0.3: _frame(targets[0.3]), 1.0: _frame(targets[1.0])}
    cal = calibrate(frames, flat=_frame(flat), device=prototype)
    before = calibrate(frames, flat=_frame(flat), device=prototype, distortion=False)
    info = cal.provenance["distortion"]
    assert cal.distortion is None and info["estimated"] and not info["modelled"]
    assert info["effect_px"] < NEGLIGIBLE_DISTORTION_PX or info["tiles_rms_after_px"] >= KEEP_RATIO * info["tiles_rms_before_px"]
    np.testing.assert_array_equal(cal.model.A, before.model.A)
    np.testing.assert_array_equal(cal.model.B, before.model.B)
    assert cal.layout.to_dict() == before.layout.to_dict()


def test_calibration_files_carry_the_distortion_and_the_flat_field(lenses, tmp_path):
    _, targets, _, cal = lenses
    assert cal.flat_field is not None and cal.flat_field.response.shape == (4, *cal.layout.view_shape)
    back = RingCalibration.load(cal.save(tmp_path / "lenses.json"))
    data = json.loads((tmp_path / "lenses.json").read_text())
    assert data["lfring_calibration_version"] == 2 and len(data["distortion"]["views"]) == 4
    pts = np.array([[100.0, 120.0], [200.0, 50.0]])
    for a, b in zip(cal.distortion, back.distortion):
        np.testing.assert_allclose(b.distort(pts), a.distort(pts), atol=1e-9)
    inside = cal.layout.masks() & (cal.flat_field.response > 0.3)
    ratio = back.flat_field.response[inside] / cal.flat_field.response[inside]
    assert float(np.abs(ratio - 1).max()) < 0.02  # the file's grid restores the response
    image = demosaic(_frame(targets[0.5]))
    a, b = split_views(image, back), split_views(image, cal)
    assert float(np.abs(a - b)[inside].max()) < 0.02
    # Version 1 files (no distortion, no flat field) still read; a version 1 file that holds
    # either is refused.
    old = RingCalibration.load("prototype_optics").to_dict()
    old["lfring_calibration_version"] = 1
    assert RingCalibration.from_dict(old).distortion is None
    data["lfring_calibration_version"] = 1
    with pytest.raises(Exception, match="version 2"):
        RingCalibration.from_dict(data)


def test_views_selected_keep_their_distortion(lenses):
    cal = lenses[3]
    pair = cal.select_views([0, 2])
    assert pair.distortion == (cal.distortion[0], cal.distortion[2])
    assert pair.flat_field.num_views == 2


def test_the_optics_calibration_of_real_lenses_knows_their_distortion():
    device = load_device(CALIB / "prototype_lenses.toml").binned(BINNING)
    cal = RingCalibration.from_optics(device)
    assert cal.distortion is not None
    r = render(device, target_scene(device, 0.5, seed=2), binning=1, noise="none")
    assert r.layout.rects == cal.layout.rects
    for k in (1, 2, 3):
        assert _mapping_error_px(cal, r, 0.5, k) < 1e-3
