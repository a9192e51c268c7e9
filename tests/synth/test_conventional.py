"""Ground truth for refocusing: the conventional image of the twin (pinhole limit, sharp focus
plane, defocus blur of the thin-lens size, the views' own blur as a special case)."""

import cv2
import numpy as np
import pytest

from lfring.errors import InvalidInputError
from lfring.optics import paraxial
from lfring.optics.views import view_cameras
from lfring.synth import (
    Plane,
    Scene,
    Texture,
    aperture_samples,
    conventional_aperture_radius_m,
    conventional_blur_px,
    render,
    render_conventional,
    viewpoint_radius_m,
)

BIN = 4


def _central_from_views(r, depth_m):
    """The central pinhole view of a fronto-parallel plane, from each rendered sharp view moved by
    its exact H_center_from_view (the views of a plane are translates of one another)."""
    h = r.homographies(depth_m)
    vh, vw = r.views_sharp.shape[1:3]
    return [cv2.warpAffine(r.views_sharp[k], h[k, :2], (vw, vh), flags=cv2.INTER_LINEAR) for k in range(4)]


def test_pinhole_limit_is_the_central_view(prototype):
    z = 0.5
    scene = Scene((Plane(z, (0.4, 0.4), Texture("image", name="astronaut")),))
    r = render(prototype, scene, binning=BIN, pattern=None, exposure=1.0, vignetting=False, defocus=False)
    inner = np.s_[40:-40, 40:-40]  # where every translated view has content
    for kw in (dict(f_number=np.inf), dict(aperture_scale=0.0), dict(f_number=1e12, samples=4)):
        conv = render_conventional(scene, prototype, 0.8, binning=BIN, **kw)
        assert conv.shape == r.views_sharp.shape[1:] and conv.dtype == np.float32
        for moved in _central_from_views(r, z):
            # Bilinear resampling of a sub-pixel shift is all that separates them.
            assert np.abs(moved[inner] - conv[inner]).mean() < 0.006
            assert np.percentile(np.abs(moved[inner] - conv[inner]), 99) < 0.05
    # The pinhole image does not depend on the focus distance.
    np.testing.assert_array_equal(render_conventional(scene, prototype, 0.31, f_number=np.inf, binning=BIN),
                                  render_conventional(scene, prototype, 3.0, f_number=np.inf, binning=BIN))


def _edge_scene(depth_m):
    """A white plane whose left edge, at X = 0, is the only edge in the image (on grey)."""
    white = Texture("constant", colors=((0.9, 0.9, 0.9),))
    return Scene((Plane(depth_m, (0.6, 1.0), white, center_m=(0.3, 0.0)),), background=(0.1, 0.1, 0.1))


def _edge_spread_width_px(img):
    """Variance (px^2) of the line-spread function of the vertical edge, from the image's middle
    rows (the variance of a disc's LSF is D^2 / 16)."""
    h = img.shape[0]
    esf = img[h // 3 : 2 * h // 3, :, 1].mean(axis=0).astype(np.float64)
    lsf = np.abs(np.diff(esf))
    peak = int(np.argmax(lsf))
    assert 40 <= peak < lsf.size - 40
    win = lsf[peak - 40 : peak + 41]
    xs = np.arange(win.size)
    mu = (win * xs).sum() / win.sum()
    return (win * (xs - mu) ** 2).sum() / win.sum()


@pytest.mark.parametrize("f_number, far", [(4.0, 1.0), (2.0, 0.7)])
def test_focus_plane_sharp_far_plane_blurred_by_the_thin_lens_disc(prototype, f_number, far):
    # One step edge on a plane at the focus depth, one on a plane far from it.
    focus = 0.35
    kw = dict(binning=BIN, f_number=f_number)
    dev = prototype.binned(BIN)
    widths = {}
    for z in (focus, far):
        scene = _edge_scene(z)
        pin = render_conventional(scene, prototype, focus, binning=BIN, f_number=np.inf)
        conv = render_conventional(scene, prototype, focus, **kw)
        widths[z] = (_edge_spread_width_px(pin), _edge_spread_width_px(conv), pin, conv)
    # In focus: the image is the pinhole image.
    _, _, pin, conv = widths[focus]
    assert np.abs(conv - pin).max() < 1e-3
    # Out of focus: the edge is spread by the disc of the circle of confusion.
    v_pin, v_conv, _, _ = widths[far]
    measured = 4.0 * np.sqrt(v_conv - v_pin)
    radius = prototype.main_focal_length_m / (2 * f_number)
    expected = float(conventional_blur_px(dev, far, focus, radius))
    cams = view_cameras(dev)
    # The thin-lens circle of confusion, written out: 2 R f |1/(Zf - s) - 1/(Z - s)| / pitch.
    s, f = cams.depth_origin_m, cams.focal_m
    assert expected == pytest.approx(2 * radius * f * (1 / (focus - s) - 1 / (far - s)) / dev.pixel_pitch_m, rel=1e-12)
    assert expected > 4.0
    assert measured == pytest.approx(expected, rel=0.10)


def test_views_own_pupil_gives_the_views_blur(prototype):
    """The views are the conventional camera with the mini-lens's image as aperture, focused
    where the views are: its blur diameter is blur_diameter_m's exactly, and a rendered view of
    a defocused edge matches the conventional image with that aperture."""
    dev = prototype.binned(2)
    b, _ = dev.require_positions()
    fl = dev.main_focal_length_m
    r_pupil = dev.mini_lens_radius_m * fl / (b - fl)
    for z in (0.4, 0.7, 1.0, 2.0):
        want = paraxial.blur_diameter_m(dev, z) / dev.pixel_pitch_m
        assert conventional_blur_px(dev, z, 0.3, r_pupil) == pytest.approx(want, rel=1e-9)
    scene = _edge_scene(1.0)
    scale = r_pupil / viewpoint_radius_m(prototype)
    conv = render_conventional(scene, prototype, 0.3, aperture_scale=scale, samples=64, binning=2)
    pin = render_conventional(scene, prototype, 0.3, f_number=np.inf, binning=2)
    measured = 4.0 * np.sqrt(_edge_spread_width_px(conv) - _edge_spread_width_px(pin))
    assert measured == pytest.approx(paraxial.blur_diameter_m(dev, 1.0) / dev.pixel_pitch_m, rel=0.10)


def test_occlusion_and_convergence(prototype):
    """A card in front of a far plane: more aperture samples change the image less and less."""
    scene = Scene((
        Plane(0.4, (0.03, 0.03), Texture("constant", colors=((0.9, 0.2, 0.1),))),
        Plane(0.9, (0.6, 0.6), Texture("speckle", feature_m=0.004, seed=2)),
    ))
    imgs = {n: render_conventional(scene, prototype, 0.6, f_number=2.8, samples=n, binning=8) for n in (16, 64, 256)}
    d1 = np.sqrt(np.mean((imgs[16] - imgs[256]) ** 2))
    d2 = np.sqrt(np.mean((imgs[64] - imgs[256]) ** 2))
    assert d2 < 0.6 * d1 and d2 < 0.01
    assert all(0.0 <= im.min() and im.max() <= 1.0 for im in imgs.values())


def test_aperture_definitions(prototype):
    assert conventional_aperture_radius_m(prototype) == prototype.effective_aperture_radius_m
    assert conventional_aperture_radius_m(prototype, f_number=4) == pytest.approx(0.016 / 8)
    assert conventional_aperture_radius_m(prototype, f_number=np.inf) == 0.0
    # aperture 1 = the circle through the four viewpoints, |C_k| = m FL / (b - FL).
    b, _ = prototype.require_positions()
    m = np.abs(prototype.lens_centres_m[0])
    want = np.hypot(*m) * prototype.main_focal_length_m / (b - prototype.main_focal_length_m)
    assert conventional_aperture_radius_m(prototype, aperture_scale=1) == pytest.approx(want, rel=1e-12)
    assert viewpoint_radius_m(prototype) == pytest.approx(1.1118e-3, abs=1e-7)
    pts = aperture_samples(500)
    assert np.all(np.hypot(*pts.T) < 1) and np.abs(pts.mean(axis=0)).max() < 0.01
    assert np.mean(np.sum(pts**2, axis=1)) == pytest.approx(0.5, abs=1e-3)  # uniform over the disc
    scene = Scene((Plane(0.5, (0.1, 0.1)),))
    for kw, match in ((dict(f_number=4, aperture_scale=1), "not both"), (dict(f_number=0), "f_number"),
                      (dict(aperture_scale=-1), "aperture_scale"), (dict(samples=0), "samples")):
        with pytest.raises(InvalidInputError, match=match):
            render_conventional(scene, prototype, 0.5, binning=8, **kw)
    with pytest.raises(InvalidInputError, match="focus_m"):
        render_conventional(scene, prototype, 0.01, binning=8)


def test_f_numbers_no_lens_has_are_refused(prototype):
    from lfring.optics.paraxial import MIN_F_NUMBER
    from lfring.synth.conventional import check_conventional

    dev = prototype.binned(8)
    assert conventional_aperture_radius_m(dev, f_number=MIN_F_NUMBER) == pytest.approx(
        dev.main_focal_length_m / (2 * MIN_F_NUMBER))
    for n in (0.1, MIN_F_NUMBER * 0.999, 0, -2, np.nan):
        with pytest.raises(InvalidInputError, match="f_number must be an f-number >= 0.5"):
            conventional_aperture_radius_m(dev, f_number=n)
    # The checks of render_conventional, without rendering: the samples are checked for a pinhole too.
    assert check_conventional(dev, 0.5, f_number=4, samples=16) == (0.5, pytest.approx(0.002), 16)
    for kw, match in (({"focus_m": 0.01}, "focus_m"), ({"samples": 0, "f_number": np.inf}, "samples"),
                      ({"f_number": 0.2}, "f_number")):
        with pytest.raises(InvalidInputError, match=match):
            check_conventional(dev, **{"focus_m": 0.5, **kw})
