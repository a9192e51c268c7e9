"""Refocusing on the twin's three-depth scene (cup 0.3 m, book 0.5 m, chessboard 1.0 m)."""

import warnings

import cv2
import numpy as np
import pytest

from lfring.calibration import RingCalibration
from lfring.errors import InvalidInputError, LfringWarning
from lfring.io.demosaic import demosaic
from lfring.io.raw import RawFrame
from lfring.depth.hypotheses import depth_hypotheses
from lfring.focus import Refocuser, all_in_focus, focal_stack, refocus
from lfring.optics import load_device
from lfring.synth import render
from lfring.synth.presets import three_depth_scene
from lfring.views import Layout, split_views

OBJECTS = {"cup": 0.3, "book": 0.5, "chessboard": 1.0}


@pytest.fixture(scope="module", params=["none", "realistic"])
def scene(request, prototype):
    r = render(prototype, three_depth_scene(), binning=2, noise=request.param, seed=11)
    cal = RingCalibration.from_optics(r.device, layout=r.layout)
    if request.param == "none":
        views = r.views
    else:
        frame = RawFrame(mosaic=r.raw, pattern="RGGB", black_level=r.black_level, white_level=r.white_level, bit_depth=12)
        views = split_views(demosaic(frame), r.layout)
    weight = Refocuser(cal, 0.5, reference=0).weight
    regions = {}
    for name, z in OBJECTS.items():
        m = (np.abs(r.depth_m[0] - z) < 1e-6).astype(np.uint8)
        # Away from occlusion edges (defocus spills over them) and seen by all four views.
        regions[name] = cv2.erode(m, np.ones((31, 31), np.uint8)).astype(bool) & (weight > 3.9)
    return request.param, r, cal, views, regions


def _band_energy(img, mask):
    """Focus measure: energy of a band-pass (difference of Gaussians, sigma 1 and 3 px), the
    band where misregistration blurs and interpolation is still accurate."""
    g = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    d = cv2.GaussianBlur(g, (0, 0), 1.0) - cv2.GaussianBlur(g, (0, 0), 3.0)
    return float((d[mask] ** 2).mean())


def _one_pixel_away(cal, z):
    """The nearer and farther depths at which the views move by one pixel (reference 0)."""
    z0 = cal.depth_origin_m
    hz = cal.model(z)[:, :2, 2]
    f = 0.0
    while True:
        f += 0.0005
        if np.abs(cal.model(z0 + (z - z0) / (1 - f))[:, :2, 2] - hz).max() >= 1.0:
            return z0 + (z - z0) / (1 + f), z0 + (z - z0) / (1 - f)


def test_cup_is_sharpest_at_its_depth_within_2_cm(scene):
    _, r, cal, views, regions = scene
    m = regions["cup"]
    at = _band_energy(refocus(views, cal, 0.3, reference=0), m)
    for dz in (-0.02, 0.02):
        assert at > 1.02 * _band_energy(refocus(views, cal, 0.3 + dz, reference=0), m)


def test_every_object_is_sharpest_at_its_depth(scene):
    """Each object against the depths that move the views by one pixel. (At 0.5 m, 2 cm moves
    the views by 0.38 px and at 1.0 m by 0.09 px: less than what the sub-pixel phase of the
    interpolation changes in any focus measure, so 2 cm is asserted for the cup only.)"""
    _, r, cal, views, regions = scene
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)  # 1.44 m is beyond the calibrated range
        for name, z in OBJECTS.items():
            m = regions[name]
            assert m.sum() > 1500, name
            at = _band_energy(refocus(views, cal, z, reference=0), m)
            for other in _one_pixel_away(cal, z):
                assert at > 1.005 * _band_energy(refocus(views, cal, other, reference=0), m), name


def test_refocused_objects_match_the_ground_truth(scene):
    noise, r, cal, views, regions = scene
    for name, z in OBJECTS.items():
        out = refocus(views, cal, z, reference=0)
        m = regions[name]
        psnr = 10 * np.log10(1.0 / np.mean((out[m] - r.views[0][m]) ** 2))
        assert psnr > (40.0 if noise == "none" else 34.0), (name, psnr)
    # The cup is in focus at the design distance: it matches the defocus-free texture as well.
    out = refocus(views, cal, 0.3, reference=0)
    m = regions["cup"]
    assert 10 * np.log10(1.0 / np.mean((out[m] - r.views_sharp[0][m]) ** 2)) > (40.0 if noise == "none" else 34.0)


def test_borders_are_not_darkened_and_fast_path_is_identical(scene):
    _, r, cal, views, _ = scene
    flat = np.full_like(views, 0.6)
    fast = Refocuser(cal, 0.45)
    out = fast(flat)
    seen = fast.weight > 1e-3
    np.testing.assert_allclose(out[seen], 0.6, rtol=1e-5)
    assert np.all(out[~seen] == 0)
    np.testing.assert_array_equal(fast(views), refocus(views, cal, 0.45))
    assert fast(views).dtype == np.float32


def test_focal_stack_and_all_in_focus(scene):
    noise, r, cal, views, regions = scene
    stack = focal_stack(views, cal, [0.3, 0.5, 1.0], reference=0)
    assert stack.shape == (3, *views.shape[1:]) and stack.dtype == np.float32
    np.testing.assert_array_equal(stack[1], refocus(views, cal, 0.5, reference=0))
    depths = depth_hypotheses(cal, 0.28, 1.1)
    image, chosen = all_in_focus(views, cal, depths, reference=0)
    for name, z in OBJECTS.items():
        med = float(np.nanmedian(chosen[regions[name]]))
        # Within one hypothesis step (one pixel of view motion) of the true depth.
        motion = np.abs(cal.model(med)[:, :2, 2] - cal.model(z)[:, :2, 2]).max()
        assert motion <= 1.0, (name, med, motion)
        psnr = 10 * np.log10(1.0 / np.mean((image[regions[name]] - r.views[0][regions[name]]) ** 2))
        assert psnr > 30, (name, psnr)
    # Given a depth map, every pixel comes from the nearest depth of the list.
    dm = np.full(views.shape[1:3], 0.52)
    img2, chosen2 = all_in_focus(views, cal, [0.3, 0.5, 1.0], depth_map_m=dm, reference=0)
    covered = Refocuser(cal, 0.5, reference=0).weight > 1e-3  # elsewhere no view sees 0.5 m
    assert np.all(chosen2[covered] == np.float32(0.5))


def test_depth_hypotheses_spacing(scene):
    _, r, cal, _, _ = scene
    z = depth_hypotheses(cal, 0.3, 1.0)
    inv = 1 / (z - cal.depth_origin_m)
    np.testing.assert_allclose(np.diff(inv), np.diff(inv)[0])
    steps = [np.abs(cal.model(a)[:, :2, 2] - cal.model(b)[:, :2, 2]).max() for a, b in zip(z[:-1], z[1:])]
    assert max(steps) <= 1.0 + 1e-9
    assert z[0] == pytest.approx(0.3) and z[-1] == pytest.approx(1.0)


def test_two_view_pair():
    """Nothing needs four views: a horizontal pair calibrated from two planes refocuses."""
    lay = Layout(220, 100, ((0, 0, 100, 100), (120, 0, 100, 100)))
    # View 1 sees a plane at 0.5 m shifted 8 px to the left: its pixel x is view 0's x + 8.
    hs = {0.5: np.array([np.eye(3), [[1, 0, 8.0], [0, 1, 0], [0, 0, 1]]]),
          1.0: np.array([np.eye(3), [[1, 0, 5.0], [0, 1, 0], [0, 0, 1]]])}
    cal = RingCalibration.from_plane_homographies(hs, layout=lay, depth_origin_m=0.0)
    rng = np.random.default_rng(0)
    base = cv2.GaussianBlur(rng.random((100, 140, 3)).astype(np.float32), (0, 0), 2)
    views = np.stack([base[:, :100], base[:, 8:108]])  # view 1 sees the scene 8 px to the right
    out = refocus(views, cal, 0.5, reference=0)
    np.testing.assert_allclose(out, base[:, :100], atol=1e-5)
    # At another depth the two copies no longer agree.
    assert np.abs(refocus(views, cal, 1.0, reference=0)[:, 10:90] - base[:, 10:90]).mean() > 0.01


@pytest.mark.parametrize("bad", [0.0, -0.5, float("nan"), float("inf")])
def test_bad_depths(scene, bad):
    _, r, cal, views, _ = scene
    with pytest.raises(InvalidInputError, match="depth"):
        refocus(views, cal, bad)


def test_bad_inputs_and_warnings(scene):
    _, r, cal, views, _ = scene
    with pytest.warns(LfringWarning, match="outside the calibrated range"):
        RingCalibration.from_plane_homographies({0.3: cal.model(0.3), 1.0: cal.model(1.0)}, layout=cal.layout,
                                                depth_origin_m=cal.depth_origin_m).homographies(2.0)
    with pytest.raises(InvalidInputError, match="float32"):
        refocus(views.astype(np.float64), cal, 0.5)
    with pytest.raises(InvalidInputError, match="calibration's layout"):
        refocus(views[:, :100, :100], cal, 0.5)
    with pytest.raises(InvalidInputError, match="interpolation"):
        refocus(views, cal, 0.5, interpolation="nearest")
    with pytest.raises(InvalidInputError, match="reference"):
        refocus(views, cal, 0.5, reference=7)
    # Bare Python errors before: an OverflowError, a ValueError of int(), an all-black image.
    with pytest.raises(InvalidInputError, match="depth_m must be a number of metres, got 1000"):
        refocus(views, cal, 10**400)
    with pytest.raises(InvalidInputError, match=r"view_shape must be \(h, w\) in pixels, two integers >= 1, got '705x705'"):
        Refocuser(cal, 0.5, view_shape="705x705")
    with pytest.raises(InvalidInputError, match=r"depths_m must be a non-empty list of depths \(or None"):
        all_in_focus(views, cal, [])
    # Three views were refused as "one homography per view, got (4, 3, 3) for 3 views".
    with pytest.raises(InvalidInputError, match=r"the calibration is for 4 views .* but the views are 3 of"):
        all_in_focus(views[:3], cal, [0.3, 0.5])
    # Sizes that ran for minutes or asked for terabytes.
    with pytest.raises(InvalidInputError, match=r"window_px must be an odd positive integer at most"):
        all_in_focus(views, cal, [0.5, 1.0], window_px=999999)
    near = np.full(views.shape[1:3], 0.5)
    near[:50] = 0.3
    with pytest.raises(InvalidInputError, match=r"aperture 1e\+06 blurs this depth map by up to \d+ px at the focus 0.5 m, "
                                                r"more than 4 times the frame's diagonal"):
        refocus(views, cal, 0.5, method="depth-aware", aperture=1e6, depth=near)
    # A blur wider than the frame but not without end is rendered (it was refused at the diagonal).
    assert np.isfinite(refocus(views, cal, 0.5, method="depth-aware", aperture=40.0, depth=near)).all()
    # The device for --f-number by name, as inspect_frame and calibrate take it (an AttributeError).
    flat = np.full(views.shape[1:3], 0.5)
    np.testing.assert_array_equal(
        refocus(views, cal, 0.5, method="depth-aware", ring_device="prototype", f_number=2.8, depth=flat),
        refocus(views, cal, 0.5, method="depth-aware", ring_device=load_device("prototype"), f_number=2.8, depth=flat))


def test_depths_where_the_views_no_longer_overlap_are_refused():
    """Just beyond z0 the views slide off the reference frame: the library refuses, naming the
    nearest depth that works, rather than returning a black image."""
    from lfring.calibration.defaults import default_calibration

    cal, _ = default_calibration((2456, 1842))
    views = np.zeros((4, *cal.layout.view_shape, 3), np.float32)
    nearest = cal.overlap_depth_range()[0]
    assert cal.depth_origin_m < nearest < 0.05
    for fn in (lambda: refocus(views, cal, 0.0285), lambda: Refocuser(cal, 0.03),
               lambda: focal_stack(views, cal, [0.5, 0.03])):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LfringWarning)  # outside the calibrated range, too
            with pytest.raises(InvalidInputError, match=f"nearest depth that works with this calibration is {nearest:.4f}"[:-1]):
                fn()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)
        assert refocus(views, cal, nearest * 1.01).shape == views.shape[1:]


def test_depths_that_are_not_numbers_of_metres_are_refused_by_name_and_entry():
    cal = RingCalibration.load("twin_binned2")
    views = np.full((4, *cal.layout.view_shape, 3), 0.5, np.float32)
    for depth, match in (("0.5", r"depth_m must be a number of metres, got '0.5'"),
                         (True, r"depth_m must be a number of metres, got True")):
        with pytest.raises(InvalidInputError, match=match):
            refocus(views, cal, depth)
    for depths, match in (([0.5, float("nan")], r"depths_m\[1\] must be a positive, finite number of metres, got nan"),
                          (["0.5"], r"depths_m must be numbers of metres, got \['0.5'\]"),
                          ([0.5, 0.01], r"depths_m\[1\] \(0.01 m\) is not beyond the calibration's depth origin"),
                          ([], "depths_m must be a non-empty list of depths")):
        with pytest.raises(InvalidInputError, match=match):
            focal_stack(views, cal, depths)
    # Counts given as float32 are refused where the frame is cut, as where views are used.
    with pytest.raises(InvalidInputError, match=r"the image must be float in \[0, 1\].*raw counts\?"):
        split_views(np.full((*cal.layout.raw_shape, 3), 200.0, np.float32), cal.layout)


def test_a_focal_stack_larger_than_the_free_memory_is_refused(scene, monkeypatch):
    """100 000 depths asked for terabytes and failed after 25 s with OpenCV's error; the stack's
    size is known before any work."""
    from lfring.core import memory

    _, r, cal, views, _ = scene
    monkeypatch.setattr(memory, "available_memory_bytes", lambda: 10 * views[0].nbytes)
    with pytest.raises(InvalidInputError, match=r"a focal stack of 6 depths \(68 MiB while it is made: its images twice\) "
                                                r"needs more memory than the 57 MiB free: give "
                                                r"fewer depths_m"):
        focal_stack(views, cal, np.linspace(0.4, 0.9, 6))
    assert focal_stack(views, cal, [0.4, 0.6]).shape == (2, *views.shape[1:])
