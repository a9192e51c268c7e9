"""The twin through real mini-lenses: each view rendered through its own lens, the truth records it."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from lfring.calibration.planes import local_shifts
from lfring.optics import MiniLens, load_device
from lfring.synth import render
from lfring.synth.presets import real_lenses, rim_displacement_px, target_scene
from lfring.optics.views import optical_layout

CALIB = Path(__file__).resolve().parents[2] / "calib"


@pytest.fixture(scope="module")
def lens_render():
    dev = load_device(CALIB / "prototype_lenses.toml")
    return render(dev, target_scene(dev, 0.5, seed=4), binning=4, noise="none", defocus=False, vignetting=False)


def test_the_preset_draws_four_different_lenses_scaled_to_the_rim(prototype):
    dev = real_lenses(prototype.binned(2), rim_fraction=0.025, seed=3)
    rims = rim_displacement_px(dev)
    radius = min(r for _, _, r in optical_layout(prototype.binned(2)).circles)
    assert max(rims) / radius == pytest.approx(0.025, rel=1e-3)
    assert min(rims) >= 0.5 * max(rims) and len({round(r, 6) for r in rims}) == 4
    assert real_lenses(prototype.binned(2), rim_fraction=0.0).distorts is False


def test_ideal_lenses_render_exactly_as_before(prototype):
    scene = target_scene(prototype, 0.6, seed=1)
    a = render(prototype, scene, binning=8, noise="none")
    b = render(prototype.with_lenses([MiniLens()] * 4), scene, binning=8, noise="none")
    assert a.distortion is None and b.distortion is None
    np.testing.assert_array_equal(a.raw, b.raw)
    assert "distortion" not in a.metadata()


def test_the_truth_maps_recorded_pixels_between_views(lens_render):
    """Each view of a plane, moved by the truth's view-to-reference map, lands on the reference:
    tile by tile to a few hundredths of a pixel, where the ideal homography alone is pixels off."""
    r = lens_render
    h, w = r.layout.view_shape
    masks = r.layout.masks()
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    pts = np.stack([xx, yy], axis=-1)
    lum = r.views_sharp.mean(axis=3)
    worst_truth, worst_ideal = 0.0, 0.0
    for k in (1, 3):
        src = r.to_reference(0.5, 0, pts, reference=k)  # where each pixel of view 0 lies in view k
        moved = cv2.remap(lum[k], src[..., 0].astype(np.float32), src[..., 1].astype(np.float32), cv2.INTER_CUBIC)
        inside = cv2.remap(masks[k].astype(np.float32), src[..., 0].astype(np.float32), src[..., 1].astype(np.float32),
                           cv2.INTER_NEAREST) > 0
        _, d = local_shifts(lum[0], moved, inside & masks[0], tile_px=16)
        worst_truth = max(worst_truth, float(np.median(np.hypot(*d.T))))
        hk = r.homographies(0.5, reference=k)[0]
        ideal = cv2.warpPerspective(lum[k], hk, (w, h), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP)
        _, d = local_shifts(lum[0], ideal, masks[0] & masks[k], tile_px=16)
        worst_ideal = max(worst_ideal, float(np.percentile(np.hypot(*d.T), 90)))
    assert worst_truth < 0.05
    assert worst_ideal > 0.3


def test_the_truth_records_each_views_distortion(lens_render, tmp_path):
    from lfring.cli.synth import write_render

    r = lens_render
    assert len(r.distortion) == 4 and not any(d.is_identity for d in r.distortion)
    write_render(r, tmp_path / "t.png", preset="target")
    truth = json.loads((tmp_path / "t_truth" / "truth.json").read_text())
    assert len(truth["distortion"]["views"]) == 4 and truth["device"]["lenses"][0]["k1"] == r.device.lenses[0].k1
    # The views' discs are the distorted images of the iris: the layout fits them.
    assert r.layout.circles[0][2] < optical_layout(load_device(CALIB / "prototype.toml").binned(4)).circles[0][2]
