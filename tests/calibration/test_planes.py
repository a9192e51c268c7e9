"""Per-plane homographies measured on the synthetic twin against the optics' exact ones."""

import cv2
import numpy as np
import pytest

import lfring
from lfring.calibration.planes import (
    PlaneHomographies,
    estimate_plane_homographies,
    phase_correlation_translations,
)
from lfring.errors import EstimationError, InvalidInputError
from lfring.core.geometry import homography_rms_px
from lfring.io.raw import RawFrame
from lfring.synth import render
from lfring.synth.presets import flat_scene, target_scene

DEPTHS = (0.4, 1.5)


def _camera_views(result):
    """The views as a user gets them: raw counts (with the sensor's noise) -> demosaic -> split.
    (``result.views`` is the noise-free image before the sensor.)"""
    frame = RawFrame(mosaic=result.raw, pattern=result.settings.pattern, black_level=result.black_level,
                     white_level=result.white_level, bit_depth=result.settings.bit_depth)
    return lfring.split_views(lfring.demosaic(frame), result.layout)


@pytest.fixture(scope="module")
def twin(prototype):
    """Targets at two depths, noise-free and with realistic noise, and a flat, binned 2 x 2."""
    planes = {}
    for z in DEPTHS:
        clean = render(prototype, target_scene(prototype, z, seed=3), binning=2)
        noisy = render(prototype, target_scene(prototype, z, seed=3), binning=2, noise="realistic", seed=5)
        planes[(z, "none")] = clean.views
        planes[(z, "realistic")] = _camera_views(noisy)
        planes[(z, "truth")] = clean.homographies(z, reference=0)
    flat = render(prototype, flat_scene(prototype), binning=2, noise="low")
    return {"planes": planes, "flat": _camera_views(flat), "masks": clean.layout.masks(), "layout": clean.layout,
            "result": clean}


def _errors(twin, est, z):
    return homography_rms_px(est.H_ref_from_view, twin["planes"][(z, "truth")], twin["layout"].view_shape,
                             mask=twin["masks"])


@pytest.mark.parametrize("noise", ["none", "realistic"])
@pytest.mark.parametrize("z", DEPTHS)
@pytest.mark.parametrize("use_flat", [False, True])
def test_ecc_matches_the_exact_homographies(twin, z, noise, use_flat):
    views = twin["planes"][(z, noise)]
    est = estimate_plane_homographies(views, masks=twin["masks"], flat_views=twin["flat"] if use_flat else None)
    assert isinstance(est, PlaneHomographies)
    assert est.H_ref_from_view.shape == (4, 3, 3) and est.method == "ecc" and est.reference == 0
    np.testing.assert_array_equal(est.H_ref_from_view[0], np.eye(3))
    np.testing.assert_allclose(est.H_ref_from_view[:, 2, 2], 1.0)
    err = _errors(twin, est, z)
    # Measured 0.002 to 0.012 px (the twin's own bilinear texture resampling accounts for up to
    # 0.01 px near best focus); the downstream budget is 0.02 px per plane.
    assert err.max() < 0.02, err
    assert np.all(est.residual_px[1:] < 0.03) and est.residual_px[0] == 0
    assert np.all(est.correlation > 0.99)


def test_phase_correlation_alone_lands_within_a_pixel(twin):
    for z in DEPTHS:
        truth = twin["planes"][(z, "truth")][:, :2, 2]
        shift, response = phase_correlation_translations(twin["planes"][(z, "realistic")], masks=twin["masks"])
        assert np.hypot(*truth[1:].T).min() > 100  # the disparities ECC alone could never bridge
        assert np.abs(shift - truth).max() < 1.0  # measured <= 0.3 px
        assert np.all(response[1:] > 0.3)  # measured 0.5 to 0.8; noise alone gives < 0.03


def test_sift_cross_check_agrees_with_ecc(twin):
    z = DEPTHS[1]
    views = twin["planes"][(z, "realistic")]
    ecc = estimate_plane_homographies(views, masks=twin["masks"], flat_views=twin["flat"])
    sift = estimate_plane_homographies(views, masks=twin["masks"], flat_views=twin["flat"], method="sift")
    assert sift.method == "sift"
    # SIFT alone is 0.01 to 0.05 px from the truth (ECC 0.002 to 0.01): agreement within 0.08 px.
    assert _errors(twin, sift, z).max() < 0.08
    disagreement = homography_rms_px(sift.H_ref_from_view, ecc.H_ref_from_view, views.shape[1:3], mask=twin["masks"])
    assert disagreement.max() < 0.08, disagreement
    assert np.all(sift.residual_px[1:] < 0.4)  # inlier reprojection scatter, measured 0.1 to 0.2 px
    assert np.all(sift.correlation[1:] > 0.9)  # inlier fraction


def test_a_general_homography_is_recovered_not_only_translations(twin):
    """The twin's views differ by translations; tilt one view by a known homography and the
    estimate must follow it."""
    z = DEPTHS[1]
    views = twin["planes"][(z, "none")].copy()
    masks = twin["masks"].copy()
    h, w = masks.shape[1:]
    c, s = np.cos(np.radians(0.6)), np.sin(np.radians(0.6))
    G = np.array([[1.004 * c, -s, 3.0], [s, 1.004 * c, -2.0], [2e-6, -3e-6, 1.0]])  # view 2 -> tilted view 2
    views[2] = cv2.warpPerspective(views[2], G, (w, h), flags=cv2.INTER_CUBIC)
    masks[2] = cv2.warpPerspective(masks[2].astype(np.uint8), G, (w, h), flags=cv2.INTER_NEAREST) > 0
    est = estimate_plane_homographies(views, masks=masks)
    truth = twin["planes"][(z, "truth")].copy()
    truth[2] = truth[2] @ np.linalg.inv(G)
    truth[2] /= truth[2][2, 2]
    err = homography_rms_px(est.H_ref_from_view, truth, (h, w), mask=masks)
    assert err.max() < 0.03, err
    # ... which a translation cannot represent.
    tr = estimate_plane_homographies(views, masks=masks, model="translation")
    assert homography_rms_px(tr.H_ref_from_view[2], truth[2], (h, w), mask=masks[2]) > 1.0


@pytest.mark.parametrize("model", ["translation", "affine"])
def test_restricted_models(twin, model):
    z = DEPTHS[0]
    est = estimate_plane_homographies(twin["planes"][(z, "realistic")], masks=twin["masks"], model=model)
    assert est.model == model
    np.testing.assert_allclose(est.H_ref_from_view[:, 2, :2], 0.0)
    if model == "translation":
        np.testing.assert_allclose(est.H_ref_from_view[:, :2, :2], np.broadcast_to(np.eye(2), (4, 2, 2)))
    assert _errors(twin, est, z).max() < 0.02


def test_any_reference_and_any_number_of_views(twin):
    z = DEPTHS[0]
    views = twin["planes"][(z, "none")]
    est = estimate_plane_homographies(views, reference=3, masks=twin["masks"])
    truth = twin["result"].homographies(z, reference=3)
    np.testing.assert_array_equal(est.H_ref_from_view[3], np.eye(3))
    assert homography_rms_px(est.H_ref_from_view, truth, views.shape[1:3], mask=twin["masks"]).max() < 0.02
    # A two-view pair (the diagonal one) and single-channel views work the same way.
    pair = estimate_plane_homographies(views[[1, 2], ..., 1], reference=1, masks=twin["masks"][[1, 2]])
    truth_pair = twin["result"].homographies(z, reference=2)[1]
    assert homography_rms_px(pair.H_ref_from_view[0], truth_pair, views.shape[1:3], mask=twin["masks"][1]) < 0.02


def test_homography_rms_px():
    t = np.eye(3)
    t[:2, 2] = (3.0, 4.0)
    assert homography_rms_px(np.eye(3), t, (5, 7)) == pytest.approx(5.0)
    # A scaling about the origin: the distance grows with the pixel's radius; the mask picks pixels.
    s = np.diag([2.0, 2.0, 1.0])
    mask = np.zeros((5, 7), bool)
    mask[4, 6] = True
    assert homography_rms_px(s, np.eye(3), (5, 7), mask=mask) == pytest.approx(np.hypot(6, 4))
    ys, xs = np.mgrid[0:5, 0:7]
    assert homography_rms_px(s, np.eye(3), (5, 7)) == pytest.approx(np.sqrt(np.mean(xs**2 + ys**2)))
    # Stacks broadcast, with one mask per homography; scale does not matter.
    out = homography_rms_px(np.stack([np.eye(3), 2 * t]), t, (5, 7), mask=np.ones((2, 5, 7), bool))
    np.testing.assert_allclose(out, [5.0, 0.0], atol=1e-12)
    with pytest.raises(InvalidInputError):
        homography_rms_px(np.eye(2), t, (5, 7))
    with pytest.raises(InvalidInputError):
        homography_rms_px(t, t, (5, 7), mask=np.zeros((4, 7), bool))


# ------------------------------------------------------------------------------------------------
# Inputs that must be refused
def test_a_blank_plane_is_refused(prototype, twin):
    flat = render(prototype, flat_scene(prototype), binning=2, noise="realistic", seed=9)
    for views in (flat.views, _camera_views(flat)):  # noise-free, and with the sensor's noise
        with pytest.raises(EstimationError, match="no texture"):
            estimate_plane_homographies(views, masks=twin["masks"])
    # Noise strong enough to pass as texture still has no common shift between the views.
    rng = np.random.default_rng(0)
    noise_only = np.clip(0.3 + 0.05 * rng.standard_normal((4, 704, 704, 1)), 0, 1).astype(np.float32)
    with pytest.raises(EstimationError, match="no clear peak"):
        estimate_plane_homographies(noise_only, masks=twin["masks"])


def test_badly_exposed_views_are_refused(twin):
    views = twin["planes"][(DEPTHS[0], "none")]
    with pytest.raises(EstimationError, match="view 0 is overexposed"):
        estimate_plane_homographies(np.clip(views * 20, 0, 1), masks=twin["masks"])
    with pytest.raises(EstimationError, match="underexposed"):
        estimate_plane_homographies(views * 0.01, masks=twin["masks"])
    # A quarter of the pixels clipped is still fine: the highlights clip at nearly the same
    # target points in every view.
    bright = np.clip(views * 2.0, 0, 1)
    assert 0.15 < (bright.max(axis=3)[twin["masks"]] >= 0.995).mean() < 0.4
    est = estimate_plane_homographies(bright, masks=twin["masks"])
    assert _errors(twin, est, DEPTHS[0]).max() < 0.02


def test_an_opencv_failure_names_the_view(twin, monkeypatch):
    calls = []

    def failing(*args, **kwargs):
        calls.append(1)
        raise cv2.error("The algorithm stopped before its convergence")

    monkeypatch.setattr(cv2, "findTransformECCWithMask", failing)
    with pytest.raises(EstimationError, match=r"view 1: ECC alignment onto view 0 did not converge"):
        estimate_plane_homographies(twin["planes"][(DEPTHS[0], "none")], masks=twin["masks"])
    assert calls


def test_invalid_inputs_are_refused(twin):
    views = twin["planes"][(DEPTHS[0], "none")]
    masks = twin["masks"]
    cases = [
        (dict(views=[views[0], views[1][:-1]]), "same size"),
        (dict(views=views[0, ..., 0]), r"\(V, h, w, C\)"),
        (dict(views=(views * 255).astype(np.uint8)), "floating"),
        (dict(views=np.where(np.arange(704)[None, None, :, None] == 5, np.nan, views)), "NaN"),
        (dict(views=views[:1]), "two or more views"),
        (dict(views=views, masks=masks[:, :-1]), "masks must have shape"),
        (dict(views=views, masks=masks.astype(np.uint8)), "boolean"),
        (dict(views=views, flat_views=twin["flat"][:, :-1]), "flat_views"),
        (dict(views=views, flat_views=np.ones_like(twin["flat"])), "flat frame is clipped"),
        (dict(views=views, reference=4), "reference"),
        (dict(views=views, reference="center"), "reference"),
        (dict(views=views, method="orb"), "ecc, sift"),
        (dict(views=views, model="projective"), "homography, affine, translation"),
        (dict(views=views, pyramid_levels=0), "pyramid_levels"),
        (dict(views=views, margin_px=-1.0), "margin_px"),
    ]
    for kwargs, message in cases:
        kwargs.setdefault("masks", masks)
        args = kwargs.pop("views")
        with pytest.raises(InvalidInputError, match=message):
            estimate_plane_homographies(args, **kwargs)
