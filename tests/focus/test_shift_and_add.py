"""The shift path of the Refocuser (translation homographies) against the general warp.

Non-square, asymmetric views; shifts with fractions on both axes, of both signs, one larger
than the view; with and without valid discs; and a homography just off a translation, which
must take the general warp.
"""

import cv2
import numpy as np
import pytest

from lfring.calibration import RingCalibration
from lfring.core import shift as warp
from lfring.focus import Refocuser, refocus
from lfring.core.warping import TRANSLATION_TOL_PX, translation_of, warp_views
from lfring.core.viewstack import view_masks
from lfring.views import Layout

H_PX, W_PX = 61, 97  # view size: non-square, odd
# Shifts (x, y) in reference pixels of each view at 0.5 m (view -> reference).
SHIFTS = [(0.0, 0.0), (17.3, -4.6), (-30.85, 22.2), (5.5, 40.01)]


def _translations(shifts):
    hs = np.repeat(np.eye(3)[None], len(shifts), axis=0)
    hs[:, 0, 2], hs[:, 1, 2] = np.array(shifts).T
    return hs


def _calibration(shifts, *, circles=None, warp=None):
    """Two planes, 0.5 m and 1.0 m, of translations (each shift halves at 1.0 m); ``warp``
    multiplies every homography of view 2 (a perturbation away from a translation)."""
    rects = tuple((k * (W_PX + 3), 0, W_PX, H_PX) for k in range(len(shifts)))
    layout = Layout(len(shifts) * (W_PX + 3), H_PX, rects, circles=circles)
    near, far = _translations(shifts), _translations(np.array(shifts) / 2)
    if warp is not None:
        near[2], far[2] = near[2] @ warp, far[2] @ warp
    return RingCalibration.from_plane_homographies({0.5: near, 1.0: far}, layout=layout, depth_origin_m=0.0)


def _general(views, cal, depth_m):
    """The reference: every view through cv2.warpAffine / warpPerspective (warp_views)."""
    masks = view_masks(cal, views.shape[1:3])
    warped, weights = warp_views(views, cal.homographies(depth_m, reference=0), masks=masks)
    wsum = weights.sum(axis=0)
    return np.where((wsum > 1e-3)[..., None], warped.sum(axis=0) / np.maximum(wsum, 1e-3)[..., None], 0.0), wsum


def _views(channels, seed=3):
    rng = np.random.default_rng(seed)
    v = rng.random((len(SHIFTS), H_PX, W_PX, channels), dtype=np.float32)
    return np.stack([cv2.GaussianBlur(x, (0, 0), 1.0).reshape(H_PX, W_PX, channels) for x in v])


DISCS = tuple((W_PX / 2 + dx, H_PX / 2 + dy, 28.0) for dx, dy in ((0, 0), (3, -2), (-4, 1), (1.5, 2.5)))


@pytest.fixture(params=["one-strip", "8-row-strips"])
def strips(request, monkeypatch):
    """The default strips (one for these small views) and the smallest (8 rows), so that
    view edges fall inside, at the start and at the end of strips."""
    if request.param == "8-row-strips":
        monkeypatch.setattr(warp, "STRIP_BYTES", 1)
    return request.param


@pytest.mark.parametrize("circles", [None, DISCS], ids=["valid-everywhere", "discs"])
@pytest.mark.parametrize("channels", [1, 3, 4])
@pytest.mark.parametrize("depth_m", [0.5, 0.71])
def test_shift_path_matches_the_general_warp(circles, channels, depth_m, strips):
    cal = _calibration(SHIFTS, circles=circles)
    views = _views(channels)
    r = Refocuser(cal, depth_m, reference=0)
    assert r.shift_path
    ref, wsum = _general(views, cal, depth_m)
    out = r(views)
    assert out.shape == views.shape[1:] and out.dtype == np.float32
    np.testing.assert_allclose(out, ref, atol=1e-5, rtol=0)
    np.testing.assert_allclose(r.weight, wsum, atol=1e-4, rtol=0)
    assert np.all(out[wsum <= 1e-3] == 0)
    # Later frames read full-size normalisation and masks, the first spreads single-channel ones.
    np.testing.assert_array_equal(r(views), out)
    # One-shot refocus takes the same path.
    np.testing.assert_array_equal(refocus(views, cal, depth_m, reference=0), out)


def test_threads_split_strips_without_changing_the_result(monkeypatch):
    monkeypatch.setattr(warp, "STRIP_BYTES", 1)  # 8 strips of 8 rows (the last 5)
    cal = _calibration(SHIFTS, circles=DISCS)
    views = _views(3)
    one = Refocuser(cal, 0.6, reference=0, threads=1)(views)
    for threads in (2, 3, 64):
        np.testing.assert_array_equal(Refocuser(cal, 0.6, reference=0, threads=threads)(views), one)


def test_shift_larger_than_the_view_and_integer_shifts(strips):
    """The shift engine itself (a Refocuser refuses such a depth: the views do not overlap)."""
    from lfring.errors import InvalidInputError
    from lfring.core.shift import ShiftEngine

    shifts = [(0.0, 0.0), (W_PX + 5.5, 0.25), (-3.0, 2.0), (0.5, -H_PX - 1.0)]
    cal = _calibration(shifts)
    views = _views(3)
    with pytest.raises(InvalidInputError, match="cannot be rendered"):
        Refocuser(cal, 0.5, reference=0)
    hs = cal.homographies(0.5, reference=0)
    engine = ShiftEngine(np.array([translation_of(h, (H_PX, W_PX)) for h in hs]), (H_PX, W_PX))
    out = np.empty(views.shape[1:], np.float32)
    engine.run(np.ascontiguousarray(views), out, inv_rows=[np.repeat(row[:, None], 3, axis=1) for *_, row in engine.inv_bands()])
    ref, _ = _general(views, cal, 0.5)
    np.testing.assert_allclose(out, ref, atol=1e-5, rtol=0)


@pytest.mark.parametrize("circles", [None, DISCS], ids=["valid-everywhere", "discs"])
def test_slightly_projective_homography_falls_back_to_the_general_warp(circles):
    # 1e-5 of perspective moves the far corner by about 0.1 px: not a translation.
    warp = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1e-5, 0.0, 1.0]])
    cal = _calibration(SHIFTS, circles=circles, warp=warp)
    views = _views(3)
    r = Refocuser(cal, 0.5, reference=0)
    assert not r.shift_path
    ref, _ = _general(views, cal, 0.5)
    np.testing.assert_allclose(r(views), ref, atol=1e-5, rtol=0)
    # Cubic interpolation always takes the general warp.
    assert not Refocuser(_calibration(SHIFTS), 0.5, interpolation="cubic").shift_path


def test_translation_bound_is_rigorous():
    """Whenever a homography is accepted as a translation, no reference pixel samples the view
    further than the tolerance from where the shift puts it (checked on every pixel)."""
    rng = np.random.default_rng(5)
    yy, xx = np.mgrid[0:H_PX, 0:W_PX].astype(np.float64)
    pts = np.stack([xx.ravel(), yy.ravel(), np.ones(xx.size)])
    accepted = rejected = 0
    for scale in np.geomspace(1e-9, 1e-4, 40):
        h = np.eye(3) + rng.normal(size=(3, 3)) * scale * np.array([[1, 1, 1e4], [1, 1, 1e4], [1e-2, 1e-2, 0]])
        h[:2, 2] += rng.normal(size=2) * 20
        s = translation_of(h, (H_PX, W_PX))
        g = np.linalg.inv(h) @ pts
        dev = np.abs(g[:2] / g[2] - pts[:2] - (np.zeros((2, 1)) if s is None else np.asarray(s)[:, None])).max()
        if s is None:
            rejected += 1
        else:
            accepted += 1
            assert dev <= TRANSLATION_TOL_PX, (scale, dev)
    assert accepted > 5 and rejected > 5
    assert translation_of(_translations([(3.25, -1.5)])[0], (H_PX, W_PX)) == pytest.approx([-3.25, 1.5], abs=1e-12)
    assert translation_of(np.array([[1.0, 0, 0], [0, 1, 0], [0, -1.0, 1]]), (H_PX, W_PX)) is None  # horizon inside


def test_bad_threads():
    from lfring.errors import InvalidInputError

    with pytest.raises(InvalidInputError, match="threads"):
        Refocuser(_calibration(SHIFTS), 0.5, threads=0)


@pytest.mark.skipif(not hasattr(__import__("os"), "fork"), reason="needs os.fork")
def test_threads_work_in_a_forked_child():
    """A child forked after the worker threads started has none of them: it makes its own."""
    import multiprocessing

    cal = _calibration(SHIFTS)
    views = _views(3)
    warp.STRIP_BYTES, saved = 1, warp.STRIP_BYTES
    try:
        expected = Refocuser(cal, 0.6, reference=0, threads=2)(views)  # starts the threads here
        ctx = multiprocessing.get_context("fork")
        with ctx.Pool(1) as pool:
            got = pool.apply_async(_refocus_in_child, (cal, views)).get(timeout=60)
    finally:
        warp.STRIP_BYTES = saved
    np.testing.assert_array_equal(got, expected)


def _refocus_in_child(cal, views):
    return Refocuser(cal, 0.6, reference=0, threads=2)(views)


@pytest.mark.parametrize("circles", [None, DISCS], ids=["valid-everywhere", "discs"])
@pytest.mark.parametrize("projective", [False, True], ids=["shift-path", "general-warp"])
def test_views_with_nan_or_infinity_are_refused(circles, projective):
    """As depth estimation refuses them: a NaN or an infinity would spread over the output."""
    from lfring.errors import InvalidInputError

    warp = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1e-5, 0.0, 1.0]]) if projective else None
    cal = _calibration(SHIFTS, circles=circles, warp=warp)
    r = Refocuser(cal, 0.5, reference=0)
    assert r.shift_path != projective
    for bad in (np.nan, np.inf, -np.inf):
        views = _views(3)
        views[1, H_PX // 2, W_PX // 2, 0] = bad
        with pytest.raises(InvalidInputError, match="NaN or infinite"):
            r(views)
        with pytest.raises(InvalidInputError, match="NaN or infinite"):
            refocus(views, cal, 0.5, reference=0)
    assert np.isfinite(r(_views(3))).all()
