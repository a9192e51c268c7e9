"""View stacks, their valid discs and the per-calibration cache."""

import gc
import weakref

import numpy as np
import pytest

from lfring.calibration.defaults import default_calibration
from lfring.core.viewstack import (
    COUNTS_MEDIAN,
    TAPER,
    WEIGHT_FLOOR,
    cached_view_masks,
    calibration_cache,
    check_views,
    inverse_weight,
    view_masks,
)
from lfring.errors import InvalidInputError


def test_check_views_shapes_and_refusals():
    assert check_views(np.zeros((2, 3, 4), np.float32)).shape == (2, 3, 4, 1)
    arr = np.zeros((4, 5, 6, 3), np.float32)
    assert check_views(arr) is arr  # no copy
    for bad, match in ((np.zeros((4, 5, 6), np.float64), "float32"), (np.zeros((5, 6), np.float32), "shape"),
                       (np.zeros((1, 5, 6), np.float32), "at least 2"), (np.zeros((2, 5, 6, 5), np.float32), "1 to 4 channels")):
        with pytest.raises(InvalidInputError, match=match):
            check_views(bad, min_views=2)


def test_counts_passed_as_float32_are_refused_and_bright_images_are_not():
    rng = np.random.default_rng(0)
    image = rng.random((4, 300, 200, 3), dtype=np.float32)
    assert check_views(image) is image
    # A flat-field-corrected frame: brighter than 1 towards the rims, most of it below.
    bright = image.copy()
    bright[:, :, :90] *= 1.6
    assert check_views(bright) is bright
    for counts in (image * 255, image * 65535, np.full((4, 30, 20), 128.0, np.float32)):
        with pytest.raises(InvalidInputError, match=r"\[0, 1\].*raw counts\? Divide by the white level"):
            check_views(counts)
    # A map that is not an image passes when said so (a high-pass, a weight).
    assert check_views(image * 255, images=False).shape == image.shape
    # Refusals reach the processing functions: refocusing and depth.
    import lfring

    cal = lfring.RingCalibration.load("twin_binned2")
    views = np.full((4, *cal.layout.view_shape, 3), 2 * COUNTS_MEDIAN, np.float32)
    with pytest.raises(InvalidInputError, match="raw counts"):
        lfring.refocus(views, cal, 0.5)
    with pytest.raises(InvalidInputError, match="raw counts"):
        lfring.estimate_depth(views, cal, zmin_m=0.3, zmax_m=1.0)
    # A ring frame read as 0..255 floats (cv2.imread(...).astype(np.float32)) is mostly the dark
    # between the discs: judged on the views it cuts, it is refused where it is cut (it was cut,
    # clipped to 1 at 90 % of the views' pixels by the correction, and the depth went wrong).
    from pathlib import Path

    frame = lfring.demosaic(lfring.load_raw(Path(__file__).resolve().parents[2] / "data" / "synthetic" / "scene.png"))
    assert np.count_nonzero(frame * 255 > COUNTS_MEDIAN) < 0.5 * frame.size  # the frame alone passed
    with pytest.raises(InvalidInputError, match=r"the image must be float in \[0, 1\].*raw counts"):
        lfring.split_views(frame * 255, cal)


def test_masks_are_one_inside_the_disc_zero_outside_and_taper_over_the_rim():
    cal, _ = default_calibration((2456, 1842))
    h, w = cal.layout.view_shape
    m = view_masks(cal, (h, w))
    cx, cy, r = cal.layout.circles[0]
    assert m.shape == (4, h, w) and m.dtype == np.float32
    assert m[0, int(cy), int(cx)] == 1.0 and m[0, 0, 0] == 0.0
    # The weight is 1 out to (1 - TAPER) r, 0 beyond the disc, in between over the rim, and falls
    # monotonically along the diagonal from the centre to the corner.
    yy, xx = np.mgrid[0:h, 0:w]
    d = np.hypot(xx - cx, yy - cy)
    assert np.all(m[0][d <= (1 - TAPER) * r - 1] == 1.0) and np.all(m[0][d >= r + 1] == 0.0)
    band = m[0][(d > (1 - TAPER) * r + 1) & (d < r - 1)]
    assert band.size and np.all((band > 0.0) & (band < 1.0))
    diag = m[0][np.arange(int(cy), -1, -1), np.arange(int(cx), int(cx) - int(cy) - 1, -1)]
    assert np.all(np.diff(diag) <= 1e-6)
    with pytest.raises(InvalidInputError, match="layout cuts"):
        view_masks(cal, (h + 1, w))


def test_the_cache_is_per_calibration_and_goes_with_it():
    cal, _ = default_calibration((2456, 1842))
    shape = cal.layout.view_shape
    masks = cached_view_masks(cal, shape)
    assert cached_view_masks(cal, shape) is masks and not masks.flags.writeable
    calls = []
    assert cached_view_masks(cal, shape, "sum", lambda m: calls.append(1) or float(m.sum())) == float(masks.sum())
    cached_view_masks(cal, shape, "sum", lambda m: calls.append(1))
    assert calls == [1]
    assert calibration_cache(cal, "k", lambda: 5) == 5 and calibration_cache(cal, "k", lambda: 6) == 5
    other, _ = default_calibration((2456, 1842))
    assert calibration_cache(other, "k", lambda: 6) == 6  # another calibration object, its own entries
    from lfring.core import viewstack

    gc.collect()  # first the calibrations that earlier tests left unreachable, whose entries go too
    before = len(viewstack._CALIBRATION_CACHE)
    gone = weakref.ref(other)
    del other
    gc.collect()
    assert gone() is None and len(viewstack._CALIBRATION_CACHE) == before - 1
    assert calibration_cache(cal, "k", lambda: 6) == 5  # the first calibration keeps its own


def test_inverse_weight_floors_unseen_pixels_to_zero():
    got = inverse_weight(np.array([0.0, WEIGHT_FLOOR / 2, 0.5, 4.0], np.float32))
    np.testing.assert_array_equal(got, np.array([0.0, 0.0, 2.0, 0.25], np.float32))


def test_big_endian_views_are_taken_as_their_values():
    """Big-endian float32 views were refused as "must be float32 ..., got >f4"."""
    rng = np.random.default_rng(0)
    views = rng.random((4, 6, 5, 3), dtype=np.float32)
    got = check_views(views.astype(">f4"))
    assert got.dtype == np.float32 and got.dtype.isnative
    np.testing.assert_array_equal(got, views)
    with pytest.raises(InvalidInputError, match="got float64"):  # other widths are still refused, by their width
        check_views(views.astype(">f8"))
