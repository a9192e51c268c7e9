"""The synthetic twin against the optics it renders (issue: geometry exact, blur and noise
as modelled, every Bayer phase, ground truth consistent)."""

import cv2
import numpy as np
import pytest

from lfring.errors import DeviceError, InvalidInputError
from lfring.io.bayer import PATTERNS, mosaic
from lfring.optics import paraxial
from lfring.optics.views import view_cameras
from lfring.synth import Bump, HeightField, Plane, Scene, Texture, render
from lfring.synth.renderer import disc_kernel

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


def test_defocus_blur_width_matches_spec(prototype):
    """A step edge at 1.0 m, focus at 0.3 m: the edge's line-spread width gives the disc
    diameter (variance of a disc's LSF is D^2/16), compared with 2 Rml |c - c'| / c'."""
    z = 1.0
    tex = Texture("checker", square_m=0.2, colors=((0.1, 0.1, 0.1), (0.9, 0.9, 0.9)))
    scene = Scene((Plane(z, (0.4, 0.4), tex),))
    kw = dict(binning=2, pattern=None, vignetting=False)
    widths = {}
    for defocus in (False, True):
        r = render(prototype, scene, defocus=defocus, **kw)
        v = r.views[0, ..., 1]
        vh, vw = v.shape
        esf = v[vh // 8 : vh // 3].mean(axis=0).astype(np.float64)  # rows away from the horizontal edge
        lsf = np.abs(np.diff(esf))
        peak = int(np.argmax(lsf))
        win = lsf[peak - 20 : peak + 21]
        xs = np.arange(win.size)
        mu = (win * xs).sum() / win.sum()
        widths[defocus] = (win * (xs - mu) ** 2).sum() / win.sum()
    measured = 4.0 * np.sqrt(widths[True] - widths[False])
    expected = float(paraxial.blur_diameter_m(r.device, z)) / r.device.pixel_pitch_m
    assert expected == pytest.approx(7.86, abs=0.05)  # SPEC 2.3: ~16 px at full resolution
    assert measured == pytest.approx(expected, rel=0.10)


def test_disc_kernel():
    assert disc_kernel(0.5) is None
    k = disc_kernel(7.0)
    assert k.shape == (7, 7) and k.sum() == pytest.approx(1.0)
    yy, xx = np.indices(k.shape) - 3
    assert (k * (xx**2 + yy**2)).sum() == pytest.approx(7.0**2 / 8, rel=0.05)  # E[r^2] = R^2/2


@pytest.mark.parametrize("pattern", PATTERNS)
def test_bayer_phase_and_rotation(prototype, pattern):
    scene = Scene((Plane(0.5, (0.5, 0.5), Texture("image", name="astronaut")),))
    up = render(prototype, scene, binning=8, pattern=pattern, bit_depth=16)
    rot = render(prototype, scene, binning=8, pattern=pattern, bit_depth=16, rotate180=True)
    np.testing.assert_array_equal(rot.image, up.image[::-1, ::-1])
    for r in (up, rot):
        expect = np.rint(mosaic(r.image, pattern) * (r.white_level - r.black_level) + r.black_level)
        np.testing.assert_array_equal(r.raw, expect.astype(np.uint16))
    # Ground-truth views are the same with and without rotation (they are cut in the erect frame).
    np.testing.assert_array_equal(rot.views, up.views)
    np.testing.assert_array_equal(rot.depth_m, up.depth_m)


@pytest.mark.parametrize("bits, dtype", [(8, np.uint8), (12, np.uint16), (16, np.uint16)])
def test_bit_depths(prototype, bits, dtype):
    scene = Scene((Plane(0.5, (0.5, 0.5), Texture("constant", colors=((1, 1, 1),))),))
    r = render(prototype, scene, binning=8, bit_depth=bits, exposure=2.0)
    assert r.raw.dtype == dtype
    assert int(r.raw.max()) == 2**bits - 1  # over-exposed centre clips at the white level
    assert int(r.raw.min()) == r.black_level  # unlit corners sit at the black level


def test_noise_statistics(prototype):
    grey = Texture("constant", colors=((0.5, 0.5, 0.5),))
    scene = Scene((Plane(0.5, (0.5, 0.5), grey),))
    r = render(prototype, scene, binning=4, pattern="RGGB", bit_depth=16, noise="realistic", seed=1)
    clean = render(prototype, scene, binning=4, pattern="RGGB", bit_depth=16)
    diff = r.raw.astype(np.float64) - clean.raw.astype(np.float64)
    x, y, w, h = r.layout.rects[0]
    sl = np.s_[y + h // 3 : y + 2 * h // 3, x + w // 3 : x + 2 * w // 3]
    mean_signal = (clean.raw[sl].astype(np.float64) - r.black_level) / (r.white_level - r.black_level)
    full_well, read = 8000.0, 3.0
    span = r.white_level - r.black_level
    expected_var = ((mean_signal * full_well + read**2) * (span / full_well) ** 2).mean() + 1 / 12
    assert diff[sl].var() == pytest.approx(expected_var, rel=0.08)
    again = render(prototype, scene, binning=4, pattern="RGGB", bit_depth=16, noise="realistic", seed=1)
    np.testing.assert_array_equal(again.raw, r.raw)
    other = render(prototype, scene, binning=4, pattern="RGGB", bit_depth=16, noise="realistic", seed=2)
    assert np.any(other.raw != r.raw)


def test_ground_truth_depth_occlusion_and_slant(prototype):
    front = Plane(0.35, (0.03, 0.03), Texture("image", name="coffee"), center_m=(0.0, 0.0))
    slant = Plane(0.7, (0.4, 0.3), Texture("speckle", feature_m=0.004), center_m=(0.0, 0.0), tilt_deg=(35.0, 10.0))
    r = render(prototype, Scene((front, slant)), binning=BIN, pattern=None)
    dev, cams = r.device, view_cameras(r.device)
    depth = r.depth_m
    assert np.isclose(np.nanmin(depth), 0.35, atol=1e-6)
    p0, _, _, n = slant.axes()
    for k, (x, y, w, h) in enumerate(r.layout.rects):
        yy, xx = np.indices((h, w))
        far = np.isfinite(depth[k]) & (depth[k] > 0.36)
        sensor = paraxial.pixel_to_sensor(dev, np.stack([xx + x, yy + y], -1))
        o, d = cams.rays_m(k, sensor)
        pts = o + d * (depth[k][..., None] - cams.depth_origin_m)
        dist = (pts[far] - p0) @ n
        assert np.abs(dist).max() < 1e-6
        # The centre of every view sees the front plane, which occludes the slanted one.
        centre = paraxial.sensor_to_pixel(dev, cams.project_m(np.array([0.0, 0.0, 0.35]))[k]) - [x, y]
        assert depth[k][int(round(centre[1])), int(round(centre[0]))] == pytest.approx(0.35, abs=1e-6)


def test_height_field_depth(prototype):
    bumps = (
        Bump(center_m=(0.03, 0.03), size_m=(0.02, 0.02), height_m=0.005, shape="box"),
        Bump(center_m=(0.07, 0.05), size_m=(0.02, 0.02), height_m=-0.004, shape="box"),
    )
    part = HeightField(0.5, (0.1, 0.08), Texture("speckle", feature_m=0.002), center_m=(0.0, 0.0), bumps=bumps)
    r = render(prototype, Scene((part,)), binning=BIN, pattern=None)
    dev, cams = r.device, view_cameras(r.device)
    for (bx, by), hgt in (((0.03, 0.03), 0.005), ((0.07, 0.05), -0.004)):
        world = np.array([-0.05 + bx, -0.04 + by, 0.5 - hgt])
        for k, (x, y, w, h) in enumerate(r.layout.rects):
            c = paraxial.sensor_to_pixel(dev, cams.project_m(world)[k]) - [x, y]
            patch = r.depth_m[k][int(c[1]) - 2 : int(c[1]) + 3, int(c[0]) - 2 : int(c[0]) + 3]
            np.testing.assert_allclose(patch, 0.5 - hgt, atol=2e-5)
    base = r.depth_m[np.isfinite(r.depth_m)]
    assert np.isclose(np.median(base), 0.5, atol=1e-6)


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


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(binning=0), "binning"),
        (dict(pattern="RGBG"), "RGGB, BGGR, GRBG, GBRG"),
        (dict(bit_depth=10), "bit_depth"),
        (dict(noise="extreme"), "none, low, realistic, high"),
        (dict(exposure=-1), "exposure"),
    ],
)
def test_bad_settings(prototype, kwargs, match):
    with pytest.raises(InvalidInputError, match=match):
        render(prototype, _patch_scene((0, 0), 0.5), **kwargs)


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


def test_interleaved_surfaces_are_refused(prototype):
    # A floor rising from 0.45 m to 0.75 m behind a card at 0.5 m that it crosses in the image.
    floor = Plane(0.6, (0.3, 0.3), Texture("speckle"), center_m=(0.0, 0.0), tilt_deg=(60.0, 0.0), name="floor")
    card = Plane(0.5, (0.05, 0.2), Texture("checker"), center_m=(0.0, 0.0), name="card")
    with pytest.raises(InvalidInputError, match="'floor' and 'card' interleave"):
        render(prototype, Scene((floor, card)), binning=8)


@pytest.mark.parametrize("pattern", PATTERNS)
def test_each_bayer_phase_demosaics_back_to_the_rendered_colours(prototype, pattern):
    from lfring.io.demosaic import demosaic
    from lfring.io.raw import RawFrame

    scene = Scene((Plane(0.5, (0.4, 0.4), Texture("image", name="astronaut")),))
    r = render(prototype, scene, binning=4, pattern=pattern, bit_depth=16)
    frame = RawFrame(mosaic=r.raw, pattern=pattern, black_level=r.black_level, white_level=r.white_level, bit_depth=16)
    rgb = demosaic(frame, method="edge-aware")
    lit = np.zeros(rgb.shape[:2], bool)
    for x, y, w, h in r.layout.rects:
        lit[y + 8 : y + h - 8, x + 8 : x + w - 8] = True
    mse = np.mean((rgb[lit] - r.image[lit]) ** 2)
    psnr = 10 * np.log10(1.0 / mse)
    assert psnr > 38.0
    # A wrong phase must fail the same check: demosaicing with the pattern's mirror swaps red and blue.
    wrong = {"RGGB": "BGGR", "BGGR": "RGGB", "GRBG": "GBRG", "GBRG": "GRBG"}[pattern]
    bad = demosaic(RawFrame(mosaic=r.raw, pattern=wrong, black_level=r.black_level, white_level=r.white_level, bit_depth=16))
    assert 10 * np.log10(1.0 / np.mean((bad[lit] - r.image[lit]) ** 2)) < psnr - 10
