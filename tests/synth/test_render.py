"""The raw frames of the twin against the optics they render: geometry exact, views where the
layout puts them, and what the renderer refuses."""

import cv2
import numpy as np
import pytest

from lfring.errors import DeviceError, InvalidInputError
from lfring.optics import paraxial
from lfring.synth import Plane, Scene, Texture, render

BIN = 4  # 1228 x 921 px, 5 um: fast, and every geometric relation is independent of binning


def _patch_scene(xy, z, size=0.002):
    bright = Texture("constant", colors=((1.0, 1.0, 1.0),))
    return Scene((Plane(z, (size, size), bright, center_m=xy),))


@pytest.mark.parametrize("z, xy", [(0.3, (0.004, -0.003)), (0.55, (-0.01, 0.006)), (1.2, (0.02, 0.01))])
def test_point_lands_where_the_optics_projects_it(prototype, z, xy):
    # A patch about 7 px wide at every depth: its centroid is the image of its centre (the
    # map is affine), and it is large enough that pixel sampling does not bias the centroid.
    r = render(prototype, _patch_scene(xy, z, size=0.007 * z / 0.3), binning=BIN, pattern=None, vignetting=False)
    dev = r.device
    want = paraxial.sensor_to_pixel(dev, paraxial.project_points_m(dev, np.array([xy[0], xy[1], z])))
    img = r.image[..., 1].astype(np.float64)
    yy, xx = np.indices(img.shape)
    for k, (x, y, w, h) in enumerate(r.layout.rects):
        # The patch is seen by every view; weigh only the pixels of view k's quadrant.
        qx, qy = (0 if k % 2 == 0 else dev.sensor_width_px // 2), (0 if k < 2 else dev.sensor_height_px // 2)
        q = np.s_[qy : qy + dev.sensor_height_px // 2, qx : qx + dev.sensor_width_px // 2]
        wsum = img[q].sum()
        assert wsum > 1.0
        got = np.array([(img[q] * xx[q]).sum() / wsum, (img[q] * yy[q]).sum() / wsum])
        np.testing.assert_allclose(got, want[k], atol=0.05)


@pytest.mark.parametrize("z", [0.3, 0.5, 1.0])
def test_view_offset_matches_spec_disparity(prototype, z):
    """Vertical neighbours (views 0 and 2) are displaced by hs/2 + d(Z) on the raw frame."""
    dev = prototype.binned(2)
    pts = np.array([[0.003, -0.002, z]])
    p = paraxial.sensor_to_pixel(dev, paraxial.project_points_m(dev, pts))[:, 0]
    raw_offset_px = p[2, 1] - p[0, 1]
    d = raw_offset_px - dev.sensor_height_m / 2 / dev.pixel_pitch_m
    from lfring.optics import evaluate

    spec = evaluate(dev, object_size_m=0.1, distance_m=z).disparity_px
    assert d == pytest.approx(spec, abs=1e-9)
    assert d == pytest.approx({0.3: 383.07 / 2, 0.5: 373.36 / 2, 1.0: 366.57 / 2}[z], abs=0.01)


@pytest.mark.parametrize("z", [0.35, 0.8])
def test_rendered_views_follow_the_exact_homographies(prototype, z):
    tex = Texture("speckle", feature_m=0.004 * z, seed=3)
    scene = Scene((Plane(z, (1.0, 1.0), tex),))
    r = render(prototype, scene, binning=BIN, pattern=None, vignetting=False)
    h = r.homographies(z, reference=0)
    ref = cv2.cvtColor(r.views[0], cv2.COLOR_RGB2GRAY)
    vh, vw = ref.shape
    c = np.s_[vh // 4 : 3 * vh // 4, vw // 4 : 3 * vw // 4]
    for k in (1, 2, 3):
        view = cv2.cvtColor(r.views[k], cv2.COLOR_RGB2GRAY)
        # ECC's warp maps template (ref crop) pixels into view k: crop pixel x is ref pixel
        # x + o and view-k pixel x + t_w, so H_0_from_k's translation is o - t_w.
        o = np.array([vw // 4, vh // 4], dtype=np.float32)
        warp = np.eye(2, 3, dtype=np.float32)
        warp[:, 2] = o - h[k, :2, 2] + 0.4  # start 0.4 px off: ECC must find the offset itself
        criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 200, 1e-8)
        _, warp = cv2.findTransformECC(ref[c], view, warp, cv2.MOTION_TRANSLATION, criteria, None, 5)
        np.testing.assert_allclose(o - warp[:, 2], h[k, :2, 2], atol=0.05)


def test_layout_and_views_consistent(prototype):
    r = render(prototype, _patch_scene((0.0, 0.0), 0.5, size=0.5), binning=2, pattern=None, rotate180=True)
    lay = r.layout
    assert lay.rotate180 and lay.num_views == 4
    # Square views as wide as the half-light disc of the iris image (radius about 352 px here).
    side = int(np.floor(2 * lay.circles[0][2]))
    assert lay.view_shape == (side, side) and 700 <= side <= 710
    from lfring.views import split_views

    np.testing.assert_array_equal(split_views(r.image, lay), r.views)
    masks = lay.masks()
    # Inside the valid disc the white plane is lit at better than 40 % of the centre (vignetting).
    for k in range(4):
        v = r.views[k, ..., 1]
        assert v[masks[k]].min() > 0.4 * v.max()
        assert v[~masks[k]].mean() < v[masks[k]].mean()


def test_bad_scenes(prototype):
    from dataclasses import replace

    with pytest.raises(DeviceError, match="no lens positions"):
        render(replace(prototype, ring_distance_m=None, sensor_distance_m=None), _patch_scene((0, 0), 0.5))
    with pytest.raises(InvalidInputError, match="entrance pupil"):
        render(prototype, _patch_scene((0, 0), 0.02), binning=8)
    with pytest.raises(InvalidInputError, match="at least one surface"):
        Scene(())
    with pytest.raises(InvalidInputError, match="texture image"):
        Texture("image", name="lena")
    with pytest.raises(InvalidInputError, match="size_m"):
        Plane(0.5, (0.0, 0.1))
