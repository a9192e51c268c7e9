"""Plane-sweep depth on the twin's three-depth scene (binned, realistic noise), reference view 0
where the ground truth lives. Disparities are between views 0 and 1 (horizontal neighbours)."""

import cv2
import numpy as np
import pytest

from lfring.calibration import RingCalibration
from lfring.depth import estimate_depth
from lfring.depth.metrics import evaluation_mask
from lfring.errors import InvalidInputError, LfringWarning
from lfring.io.demosaic import demosaic
from lfring.io.raw import RawFrame
from lfring.synth import render
from lfring.synth.presets import three_depth_scene
from lfring.views import split_views


@pytest.fixture(scope="module")
def twin(prototype):
    r = render(prototype, three_depth_scene(), binning=2, noise="realistic", seed=3)
    cal = RingCalibration.from_optics(r.device, layout=r.layout)
    frame = RawFrame(mosaic=r.raw, pattern="RGGB", black_level=r.black_level, white_level=r.white_level, bit_depth=12)
    views = split_views(demosaic(frame), r.layout)
    gt = r.depth_m[0]
    res = estimate_depth(views, cal, zmin_m=0.27, zmax_m=1.1, num_planes=41, reference=0)
    return r, cal, views, gt, evaluation_mask(gt, r.views_sharp[0]), res


def _disparity(cal, z):
    h = cal.model(np.asarray(z, dtype=np.float64))
    return h[..., 1, 0, 2] - h[..., 0, 0, 2]


@pytest.mark.parametrize(
    "name, depth, max_bad, max_rel",
    [
        # Issue targets: at most 5 % of pixels off by more than 0.3 px, median relative error 0.5 %.
        ("cup", 0.3, 0.05, 0.005),
        # The book is defocused by 4.6 px; 0.5 % of depth there is 0.035 px of disparity.
        ("book", 0.5, 0.05, 0.008),
        # The chessboard is defocused by 7.9 px and 0.5 % of 1.0 m is 0.013 px: out of reach.
        ("chessboard", 1.0, 0.10, 0.04),
    ],
)
def test_accuracy_per_object(twin, name, depth, max_bad, max_rel):
    r, cal, views, gt, usable, res = twin
    m = usable & (np.abs(gt - depth) < 1e-6) & np.isfinite(res.depth_m)
    assert m.sum() > 5000
    err = np.abs(_disparity(cal, res.depth_m[m]) - _disparity(cal, gt[m]))
    rel = np.abs(res.depth_m[m] - gt[m]) / gt[m]
    assert np.mean(err > 0.3) <= max_bad
    assert np.median(rel) <= max_rel


def test_result_record_and_confidence(twin):
    r, cal, views, gt, usable, res = twin
    assert res.depth_m.dtype == np.float32 and res.depth_m.shape == views.shape[1:3]
    assert res.confidence.dtype == np.float32 and 0 <= res.confidence.min() and res.confidence.max() <= 1
    assert len(res.depths_m) == 41 and res.step_px == pytest.approx(0.25, abs=0.05)
    inv = 1 / (res.depths_m - cal.depth_origin_m)
    np.testing.assert_allclose(np.diff(inv), np.diff(inv)[0])  # evenly spaced in disparity
    # Confidence separates textured pixels from the book's blank margins and uniform squares.
    g = cv2.cvtColor(r.views_sharp[0], cv2.COLOR_RGB2GRAY)
    flat = (cv2.boxFilter(g * g, -1, (9, 9)) - cv2.boxFilter(g, -1, (9, 9)) ** 2 < 1e-5) & np.isfinite(res.depth_m)
    assert np.median(res.confidence[usable]) > 0.7 > 3 * np.median(res.confidence[flat])
    # Depth where confident is better than depth overall.
    conf = usable & (res.confidence > 0.8)
    rel = np.abs(res.depth_m - gt) / gt
    assert np.nanmedian(rel[conf]) <= np.nanmedian(rel[usable])


def test_default_spacing_and_costs(twin):
    r, cal, views, gt, usable, res = twin
    small = views[:, ::2, ::2].copy()
    with pytest.raises(InvalidInputError, match="layout"):
        estimate_depth(small, cal, zmin_m=0.3, zmax_m=1.0)
    for cost in ("lcn", "sad", "ssd", "zncc", "sad-occlusion"):
        out = estimate_depth(views, cal, zmin_m=0.28, zmax_m=0.8, cost=cost, aggregation="box", reference=0)
        assert out.step_px <= 1.0 + 1e-9
        m = usable & (np.abs(gt - 0.3) < 1e-6)
        assert np.nanmedian(np.abs(out.depth_m[m] - 0.3)) < 0.01, cost


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(zmin_m=1.0, zmax_m=0.5), "smaller than zmax"),
        (dict(zmin_m=0.01, zmax_m=0.5), "beyond the depth origin"),
        (dict(zmin_m=0.3, zmax_m=0.5, num_planes=0), "num_planes"),
        (dict(zmin_m=0.3, zmax_m=0.5, cost="census9"), "cost must be one of"),
        (dict(zmin_m=0.3, zmax_m=0.5, cost="lcn-halves", method="local"), "needs method='sgm'"),
        (dict(zmin_m=0.3, zmax_m=0.5, aggregation="sgm"), "aggregation must be one of"),
        (dict(zmin_m=0.3, zmax_m=0.5, window_px=4), "odd"),
        (dict(zmin_m=0.3, zmax_m=0.5, aggregate_px=0), "aggregate_px must be an odd"),
        (dict(zmin_m=0.3, zmax_m=0.5, threads=0), "threads"),
        (dict(zmin_m=0.3, zmax_m=0.5, backend="cuda"), "backend"),
        (dict(zmin_m=float("nan"), zmax_m=0.5), "zmin_m"),
    ],
)
def test_bad_inputs(twin, kwargs, match):
    r, cal, views, *_ = twin
    with pytest.raises(InvalidInputError, match=match):
        estimate_depth(views, cal, **kwargs)


def test_nan_views_and_out_of_range(twin):
    r, cal, views, *_ = twin
    bad = views.copy()
    bad[1, 10, 10, 0] = np.nan
    with pytest.raises(InvalidInputError, match="NaN"):
        estimate_depth(bad, cal, zmin_m=0.3, zmax_m=0.5)
    cal2 = RingCalibration.from_plane_homographies({0.3: cal.model(0.3), 1.0: cal.model(1.0)}, layout=cal.layout,
                                                   depth_origin_m=cal.depth_origin_m)
    with pytest.warns(LfringWarning, match="outside the calibrated range"):
        estimate_depth(views, cal2, zmin_m=0.3, zmax_m=1.5, num_planes=3)


def test_issue_targets_on_pixels_all_views_see(twin):
    """The issue's targets on non-occluded textured pixels (seen by all four views, away from
    depth edges): at most 5 % off by more than 0.3 px, median relative depth error <= 0.5 %."""
    from lfring.focus import Refocuser

    r, cal, views, gt, usable, res = twin
    seen = Refocuser(cal, 0.5, reference=0).weight > 3.9
    m = usable & seen & np.isfinite(gt)
    assert m.sum() > 100_000
    est = res.depth_m[m]
    ok = np.isfinite(est)
    err = np.where(ok, np.abs(_disparity(cal, np.where(ok, est, 1.0)) - _disparity(cal, gt[m])), np.inf)
    assert np.mean(err > 0.3) <= 0.05
    assert np.median(np.abs(est[ok] - gt[m][ok]) / gt[m][ok]) <= 0.005


def _issue_errors(cal, res, gt, m):
    est = res.depth_m[m]
    ok = np.isfinite(est)
    err = np.where(ok, np.abs(_disparity(cal, np.where(ok, est, 1.0)) - _disparity(cal, gt[m])), np.inf)
    return np.mean(err > 0.3), np.median(np.abs(est[ok] - gt[m][ok]) / gt[m][ok])


def test_default_settings_meet_the_issue_targets(twin):
    """At the default settings ('sgm' over 'lcn-halves', box aggregation, 1 px spacing, strips on threads)
    and with the slower, edge-aware options, on pixels all four views see: at most 5 % off by
    more than 0.3 px and a median relative error of at most 0.5 %; threads change nothing."""
    from lfring.focus import Refocuser

    _, cal, views, gt, usable, _ = twin
    m = usable & (Refocuser(cal, 0.5, reference=0).weight > 3.9) & np.isfinite(gt)
    res = estimate_depth(views, cal, zmin_m=0.27, zmax_m=1.1, reference=0)
    assert (res.method, res.cost, res.aggregation) == ("sgm", "lcn-halves", "box") and len(res.depths_m) == 11
    bad, rel = _issue_errors(cal, res, gt, m)
    assert bad <= 0.05 and rel <= 0.005, (bad, rel)
    assert np.median(res.confidence[m]) > 0.5
    one = estimate_depth(views, cal, zmin_m=0.27, zmax_m=1.1, reference=0, threads=1)
    np.testing.assert_array_equal(one.depth_m, res.depth_m)
    np.testing.assert_array_equal(one.confidence, res.confidence)
    for kw in ({"aggregation": "guided"}, {"cost": "zncc", "aggregation": "guided"}):
        bad_k, rel_k = _issue_errors(cal, estimate_depth(views, cal, zmin_m=0.27, zmax_m=1.1, reference=0, **kw), gt, m)
        assert bad_k <= 0.05 and rel_k <= 0.005, (kw, bad_k, rel_k)


@pytest.mark.parametrize("cost", ["lcn", "lcn-occlusion", "lcn-halves"])
@pytest.mark.parametrize("reference", [0, "center"])
@pytest.mark.parametrize("warp", ["translation", "perspective"])
def test_strips_equal_whole_slices(prototype, reference, warp, cost):
    """The default sweep, strip by strip on threads (two weighted adds per shift, or
    warpPerspective per strip), gives what the whole-slice sweep gives for the same cost."""
    import warnings

    from lfring.depth.costs.lcn import lcn_sources
    from lfring.depth.hypotheses import depth_hypotheses
    from lfring.depth.sweep.slices import sweep_slices
    from lfring.depth.sweep.strips import sweep_strips
    from lfring.core.viewstack import cached_view_masks

    r = render(prototype, three_depth_scene(), binning=4)
    cal = RingCalibration.from_optics(r.device, layout=r.layout)
    h, w = r.views.shape[1:3]
    masks = cached_view_masks(cal, (h, w))
    src = lcn_sources(r.views, cal, 9, threads=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)
        hs = cal.homographies(depth_hypotheses(cal, 0.28, 1.1), reference=reference)
    if warp == "perspective":  # a slight tilt: no longer translations
        tilt = np.array([[1.0, 0.002, 0.3], [-0.001, 1.0, -0.2], [2e-6, -1e-6, 1.0]])
        hs = np.where(np.all(hs == np.eye(3), axis=(-2, -1))[..., None, None], hs, tilt @ hs)
    if cost == "lcn-halves":  # a volume beside the volume: both sweeps fill the same numbers
        n = len(hs)
        want_v, want_h, got_v, got_h = (np.empty((n, h, w), np.float32) for _ in range(4))
        sweep_slices(src, masks, hs, cost, 9, None, 2, 15, volume=want_v, halves=want_h)
        sweep_strips(src, masks, hs, aggregate_px=15, exclude=2, threads=3, volume=got_v, halves=got_h)
        for got, want in ((got_v, want_v), (got_h, want_h)):
            np.testing.assert_array_equal(np.isfinite(got), np.isfinite(want))
            fin = np.isfinite(want)
            np.testing.assert_allclose(got[fin], want[fin], rtol=1e-3, atol=1e-4)
        assert 0.3 < np.isfinite(want_h).mean() < np.isfinite(want_v).mean()  # the halves see less
        return
    want = sweep_slices(src, masks, hs, cost, 9, None, 2, 15)
    occlusion = cost == "lcn-occlusion"
    for threads in (1, 3):
        got = sweep_strips(src, masks, hs, aggregate_px=15, exclude=2, threads=threads, occlusion=occlusion)
        ok = np.isfinite(want[1])
        np.testing.assert_array_equal(np.isfinite(got[1]), ok)
        assert np.mean(got[0][ok] == want[0][ok]) > 0.999
        same = ok & (got[0] == want[0])
        for g, x in zip(got[1:5], want[1:5]):
            fin = same & np.isfinite(x)
            np.testing.assert_allclose(g[fin], x[fin], rtol=1e-3, atol=1e-4)
        np.testing.assert_allclose(got[5], want[5], atol=1e-4)
    # The whole volume instead of the running minimum: the same best hypothesis and costs.
    volume = np.empty((len(hs), h, w), np.float32)
    nviews = sweep_strips(src, masks, hs, aggregate_px=15, exclude=2, threads=3, volume=volume, occlusion=occlusion)
    np.testing.assert_allclose(nviews, want[5], atol=1e-4)
    ok = np.isfinite(want[1])
    np.testing.assert_array_equal(np.isfinite(volume).any(axis=0), ok)
    best = np.argmin(np.where(np.isfinite(volume), volume, np.inf), axis=0)
    assert np.mean(best[ok] == want[0][ok]) > 0.999
    np.testing.assert_allclose(np.take_along_axis(volume, best[None], 0)[0][ok], want[1][ok], rtol=1e-3, atol=1e-4)


def test_sgm_default_beats_the_local_sweep_on_every_seen_pixel(twin):
    """On every pixel with ground truth that two views see (weak texture, depth edges and the
    far chessboard included), the default semi-global method leaves far fewer pixels off by
    more than 1 px than the local winner-take-all, and keeps the textured pixels' accuracy."""
    from lfring.focus import Refocuser

    r, cal, views, gt, usable, res = twin
    assert res.method == "sgm" and res.depth_filled_m is not None
    local = estimate_depth(views, cal, zmin_m=0.27, zmax_m=1.1, num_planes=41, reference=0, method="local")
    seen = (Refocuser(cal, 0.5, reference=0).weight > 1.9) & np.isfinite(gt)
    assert seen.sum() > 200_000

    def bad(depth, m, px):
        ok = np.isfinite(depth[m])
        err = np.abs(_disparity(cal, np.where(ok, depth[m], 1.0)) - _disparity(cal, gt[m]))
        return np.mean(~ok | (err > px))

    bad_sgm, bad_local = bad(res.depth_filled_m, seen, 1.0), bad(local.depth_m, seen, 1.0)
    assert bad_sgm < 0.7 * bad_local, (bad_sgm, bad_local)
    textured = usable & (Refocuser(cal, 0.5, reference=0).weight > 3.9) & np.isfinite(gt)
    assert bad(res.depth_m, textured, 0.3) <= 0.05
    # The filled depth covers every pixel the raw one knows.
    known = np.isfinite(res.depth_m)
    assert np.all(np.isfinite(res.depth_filled_m[known]))
    assert np.isfinite(res.depth_filled_m).sum() >= known.sum()


def _occluding_pair(d_back=4.0, d_front=12.0, shape=(96, 160), square=(60, 30, 110, 70), seed=0):
    """A stereo pair by construction: a textured background at disparity ``d_back`` and a
    textured square (x0, y0, x1, y1) in front of it at ``d_front``; imL(x) = imR(x - d)."""
    rng = np.random.default_rng(seed)
    h, w = shape
    tex = lambda: cv2.GaussianBlur(rng.random((h, w + 64), dtype=np.float32), (0, 0), 1.2)
    back, front = tex(), tex()
    x0, y0, x1, y1 = square
    xs = np.arange(w)
    left = back[:, xs + 32].copy()
    left[y0:y1, x0:x1] = front[y0:y1, x0 + 32:x1 + 32]
    right = back[:, (xs + 32 + int(d_back))].copy()
    xr0, xr1 = x0 - int(d_front), x1 - int(d_front)  # the square seen from the right
    right[y0:y1, xr0:xr1] = front[y0:y1, x0 + 32:x1 + 32]
    occluded = np.zeros(shape, bool)  # background seen from the left, hidden in the right
    occluded[y0:y1, x0 - int(d_front - d_back):x0] = True
    truth = np.full(shape, d_back, np.float32)
    truth[y0:y1, x0:x1] = d_front
    views = np.stack([left, right])[..., None].astype(np.float32)
    return views, truth, occluded


def test_pair_consistency_makes_occluded_pixels_unknown():
    """Two views: the background next to a foreground square that the other view cannot see
    becomes unknown (NaN) by the left-right check, and the filled depth covers it; elsewhere the
    disparity is right."""
    views, truth, occluded = _occluding_pair()
    cal = RingCalibration.from_grid(views.shape[1:3], [(0, 0), (1, 0)], disparity_scale_px_m=100.0)
    kw = dict(zmin_m=100.0 / 16, zmax_m=100.0 / 2, reference=0)
    res = estimate_depth(views, cal, **kw)
    unchecked = estimate_depth(views, cal, consistency=False, **kw)
    disparity = lambda z: 100.0 / z
    assert np.mean(np.isnan(res.depth_m[occluded])) >= 0.8
    assert np.mean(np.isnan(unchecked.depth_m[occluded])) <= 0.2
    assert np.all(np.isfinite(res.depth_filled_m[occluded]))
    inner = np.zeros_like(occluded)
    inner[5:-5, 25:-5] = True
    inner &= ~cv2.dilate(occluded.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    inner[np.abs(cv2.Laplacian(truth, cv2.CV_32F)) > 0] = False
    err = np.abs(disparity(res.depth_m[inner]) - truth[inner])
    assert np.mean(err < 0.5) >= 0.95


@pytest.mark.parametrize("vertical", [False, True])
def test_pair_fills_the_occlusion_from_the_background(vertical):
    """The filled map gives the background's disparity to the strip beside a nearer square that
    only the reference sees (the left-right check's holes take the farther side along the
    baseline: rows for a horizontal pair, columns for a vertical one). Measured: 88 % of the
    strip within 0.5 px, against 13-15 % when the edge-aware smoother filled it."""
    views, truth, occluded = _occluding_pair()
    positions = [(0, 0), (1, 0)]
    if vertical:
        views, truth, occluded = np.ascontiguousarray(views.transpose(0, 2, 1, 3)), truth.T, occluded.T
        positions = [(0, 0), (0, 1)]
    cal = RingCalibration.from_grid(views.shape[1:3], positions, disparity_scale_px_m=100.0)
    res = estimate_depth(views, cal, zmin_m=100.0 / 16, zmax_m=100.0 / 2, reference=0)
    assert np.mean(np.isnan(res.depth_m[occluded])) >= 0.8  # the raw map keeps them unknown
    assert np.mean(np.abs(100.0 / res.depth_filled_m[occluded] - truth[occluded]) < 0.5) >= 0.8


def test_background_beside_a_nearer_square_keeps_its_depth():
    """Shiftable windows: the background pixels within 4 px of a nearer textured square (those
    both views see) keep the background's disparity; with the centred boxes alone 7-8 % of them
    took the square's (measured on seeds 0-3: 7.1-8.3 %, now 3.4-5.3 %)."""
    bad = []
    for seed in (0, 1):
        views, truth, occluded = _occluding_pair(seed=seed)
        cal = RingCalibration.from_grid(views.shape[1:3], [(0, 0), (1, 0)], disparity_scale_px_m=100.0)
        res = estimate_depth(views, cal, zmin_m=100.0 / 16, zmax_m=100.0 / 2, reference=0)
        front = (truth > 8).astype(np.uint8)
        ring = cv2.dilate(front, np.ones((9, 9), np.uint8)).astype(bool) & ~front.astype(bool) & ~occluded
        bad.append(np.mean(np.abs(100.0 / res.depth_filled_m[ring] - truth[ring]) > 1.0))
    assert np.mean(bad) <= 0.055, bad


@pytest.mark.parametrize("shape, box", [((9, 11, 13), 5), ((2, 4, 3), 7), ((1, 1, 6), 3)])
def test_least_over_windows_is_the_least_of_the_boxes_containing_each_pixel(shape, box):
    """Of a box-aggregated cost, the erosion is the least box mean over every box that contains
    the pixel (boxes cut at the border), by brute force; inf stays inf only where the whole
    neighbourhood is."""
    from lfring.depth.aggregation import least_over_windows

    rng = np.random.default_rng(box)
    v = rng.random(shape, dtype=np.float32)
    v[rng.random(shape) < 0.3] = np.inf
    v[..., :2] = np.inf  # an all-inf border strip
    got = least_over_windows(v, box, threads=2)
    n, h, w = shape
    r = box // 2
    want = np.full(shape, np.inf, np.float32)
    for y in range(h):
        for x in range(w):
            for cy in range(y - r, y + r + 1):  # the centres of the boxes containing (y, x)
                for cx in range(x - r, x + r + 1):
                    if 0 <= cy < h and 0 <= cx < w:
                        want[:, y, x] = np.minimum(want[:, y, x], v[:, cy, cx])
    np.testing.assert_array_equal(got, want)
    out = np.empty_like(v)
    assert least_over_windows(v, box, out=out) is out


@pytest.mark.parametrize("v, box, kw, match", [
    (np.zeros((2, 3, 3), np.float64), 3, {}, "float32"), (np.zeros((3, 3), np.float32), 3, {}, r"\(N, h, w\)"),
    (np.zeros((2, 3, 3), np.float32), 4, {}, "odd"), (np.zeros((2, 3, 3), np.float32), True, {}, "odd"),
    (np.zeros((2, 3, 3), np.float32), 3, {"out": np.zeros((2, 3, 4), np.float32)}, "out must"),
    (np.zeros((2, 3, 3), np.float32), 3, {"out": "self"}, "apart from volume"),
    (np.zeros((2, 0, 0), np.float32), 3, {}, "non-empty"),
    (np.zeros((2, 3, 4), np.float32).transpose(0, 2, 1), 3, {}, "C-contiguous"),
    (np.zeros((2, 3, 3), np.float32), 3, {"out": np.zeros((2, 3, 3), np.float32).transpose(0, 2, 1)}, "out must"),
    (np.zeros((2, 3, 3), np.float32), 3, {"out": [1]}, "out must"),
    (np.where(np.arange(18).reshape(2, 3, 3) == 13, np.nan, 1.0).astype(np.float32), 3, {}, "NaN in slice 1"),
    (np.zeros((2, 3, 3), np.float32), 3, {"threads": 0}, "threads"),
    (np.zeros((2, 3, 3), np.float32), 3, {"threads": None}, "threads")])
def test_least_over_windows_refuses_bad_inputs(v, box, kw, match):
    from lfring.depth.aggregation import least_over_windows

    if isinstance(kw.get("out"), str):
        kw = {"out": v}
    with pytest.raises(InvalidInputError, match=match):
        least_over_windows(v, box, **kw)


def test_least_over_windows_wider_than_the_slice_is_its_minimum():
    from lfring.depth.aggregation import least_over_windows

    v = np.random.default_rng(0).random((2, 5, 7)).astype(np.float32)
    got = least_over_windows(v, 10**9 + 1)  # used to allocate the whole square
    np.testing.assert_array_equal(got, np.broadcast_to(v.min(axis=(1, 2))[:, None, None], v.shape))


@pytest.mark.parametrize("bad, match", [(dict(method="global"), "method"), (dict(paths=6), "paths"),
                                        (dict(paths=4.0), "paths"), (dict(paths=[4]), "paths"),
                                        (dict(consistency="no"), "consistency must be"),
                                        (dict(method="local", paths=8), "belong to method='sgm'"),
                                        (dict(method="local", consistency=True), "belong to method='sgm'"),
                                        (dict(min_views=0), "min_views"), (dict(min_views=5), "min_views"),
                                        (dict(min_views=True), "min_views"), (dict(min_views="a"), "min_views"),
                                        (dict(progress=1), "progress must be"), (dict(threads=True), "threads"),
                                        (dict(zmin_m=True), "zmin_m"),
                                        (dict(zmin_m=0.5, zmax_m=0.5001), "widen the depth range"),
                                        (dict(rim_taper=-0.1), "rim_taper"), (dict(rim_taper=1.5), "rim_taper"),
                                        (dict(rim_taper=float("nan")), "rim_taper"), (dict(rim_taper="5 %"), "rim_taper"),
                                        (dict(rim_taper=True), "rim_taper")])
def test_bad_method_options_are_refused(twin, bad, match):
    r, cal, views, gt, usable, res = twin
    with pytest.raises(InvalidInputError, match=match):
        estimate_depth(views, cal, **{"zmin_m": 0.27, "zmax_m": 1.1, **bad})


def test_occlusion_aware_cost_leaves_out_the_view_that_disagrees():
    """Three views agree and one (occluded) does not: over the window, 'lcn-occlusion' takes the
    three's variance (0) where 'lcn' is high; where only two views see the window, or the view
    left out would leave fewer than two, nothing is left out."""
    from lfring.depth.costs.lcn import lcn_cost
    from lfring.depth.costs.lcn_occlusion import OCCLUSION_PENALTY, lcn_leave_one_out, occlusion_aggregate
    from lfring.core.filters import box_filter

    rng = np.random.default_rng(1)
    x = np.broadcast_to(rng.random((1, 12, 16), dtype=np.float32), (4, 12, 16)).copy()
    x[3] += 1.0  # view 3 sees something else
    wts = np.ones_like(x)
    box = lambda c: box_filter(np.ascontiguousarray(c, np.float32), 5)

    def cost(wts):
        a = x * wts
        s1, s2, cnt = a.sum(0), (a * a).sum(0), wts.sum(0)
        full = box(lcn_cost(s1, s2, cnt))
        outs = [(lcn_leave_one_out(s1, s2, cnt, a[k], wts[k]), wts[k]) for k in (1, 2, 3)]  # view 0: the reference
        return full.copy(), occlusion_aggregate(full, cnt, outs, box, box)

    full, occ = cost(wts)
    assert np.all(full > 0.15)
    np.testing.assert_allclose(occ, 0.0, atol=1e-5)
    wts[2:] = 0.0  # only views 0 and 1 see it: nothing to leave out
    full, occ = cost(wts)
    np.testing.assert_array_equal(occ, full)
    wts[2:] = 1.0
    wts[1:3, :, :8] = 0.0  # left half: views 0 and 3 only; right half: all four
    full, occ = cost(wts)
    np.testing.assert_array_equal(occ[:, :4], full[:, :4])  # whole window in the left half
    np.testing.assert_allclose(occ[:, 11:], 0.0, atol=1e-5)  # whole window in the right half
    assert np.all(occ <= full) and OCCLUSION_PENALTY >= 1.0


@pytest.mark.parametrize("method", ["sgm", "local"])
def test_progress_reports_rise_to_one(twin, method):
    r, cal, views, *_ = twin
    seen = []
    estimate_depth(views, cal, zmin_m=0.3, zmax_m=1.0, num_planes=6, method=method, progress=seen.append)
    assert len(seen) >= 3 and seen[-1] == 1.0
    assert all(0.0 <= a <= b <= 1.0 for a, b in zip(seen, seen[1:]))


@pytest.fixture(scope="module")
def hard_twin(prototype):
    """The twin's hard scene (slants, wires, a blank card, vignetting from 30 % to 96 % per view),
    4 x 4 binned with realistic noise, and its calibration."""
    from lfring.synth.presets import HARD_VIEW_FALLOFF, hard_scene

    r = render(prototype, hard_scene(), binning=4, pattern=None, view_falloff=HARD_VIEW_FALLOFF, noise="realistic", seed=3)
    return r, RingCalibration.from_optics(r.device, layout=r.layout)


def test_occlusion_aware_costs_beat_all_views_on_the_hard_scene(hard_twin):
    """The hard scene (4 x 4 binned) against its exact ground truth on every pixel of view 0's
    disc: the two occlusion-aware costs have fewer pixels off by more than 0.5 px of disparity
    than 'lcn' (measured: 'lcn' 19.8 %, 'lcn-occlusion' 17.9 %, the default 'lcn-halves' 18.4 %).
    Off by more than 1 px: 10.5, 9.8 and 11.6 %. Since the optimisation takes the shiftable
    windows' cost, the halves no longer win at 1 px on this coarse frame (the centred boxes
    alone: 13.1, 12.2 and 11.7 %); on the 2 x 2 binned frame of benchmarks/bench_depth_real.py
    they still do (every pixel two views see: 8.8 % against 10.0 %)."""
    r, cal = hard_twin
    gt = r.depth_m[0]
    m = np.isfinite(gt) & (r.layout.masks()[0] > 0)
    bad, bad1 = {}, {}
    for cost in ("lcn", "lcn-occlusion", None):
        res = estimate_depth(r.views, cal, zmin_m=0.27, zmax_m=1.1, reference=0, cost=cost)
        d = res.depth_filled_m[m]
        err = np.abs(_disparity(cal, np.where(np.isfinite(d), d, 1.0)) - _disparity(cal, gt[m]))
        bad[res.cost], bad1[res.cost] = np.mean(~(err <= 0.5)), np.mean(~(err <= 1.0))
    assert bad["lcn-occlusion"] <= 0.19 and bad["lcn-occlusion"] <= 0.93 * bad["lcn"], bad
    assert bad["lcn-halves"] <= 0.19 and bad["lcn-halves"] <= 0.95 * bad["lcn"], bad
    assert bad1["lcn-occlusion"] <= 0.95 * bad1["lcn"] and max(bad1.values()) <= 0.12, bad1


def test_threads_bound_every_compiled_kernel_of_the_semi_global_method(twin, monkeypatch):
    """threads=1: the refinement's and the halves' kernels (which take numba's thread count) run
    on one thread too, and the count is restored afterwards."""
    import numba

    import lfring.depth.engines.semiglobal as sweep

    r, cal, views, *_ = twin
    seen = {}
    for name in ("refine_index", "take_halves", "box_mean_of_finite"):
        real = getattr(sweep, name)

        def spy(*a, _real=real, _name=name, **k):
            seen[_name] = numba.get_num_threads()
            return _real(*a, **k)

        monkeypatch.setattr(sweep, name, spy)
    before = numba.get_num_threads()
    estimate_depth(views, cal, zmin_m=0.3, zmax_m=1.0, num_planes=6, reference=0, threads=1)
    assert seen == {"refine_index": 1, "take_halves": 1, "box_mean_of_finite": 1}
    assert numba.get_num_threads() == before


def test_the_halves_volume_needs_the_whole_volume_and_an_lcn_cost(twin):
    import warnings

    from lfring.depth.sweep.slices import sweep_slices
    from lfring.depth.sweep.strips import sweep_strips

    r, cal, views, *_ = twin
    h, w = views.shape[1:3]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)
        hs = cal.homographies(np.array([0.3, 0.5, 1.0]), reference=0)
    lum = np.zeros((4, h, w), np.float32)
    masks = np.ones((4, h, w), np.float32)
    vol = np.empty((3, h, w), np.float32)
    with pytest.raises(ValueError, match="halves needs a volume"):
        sweep_strips(lum, masks, hs, aggregate_px=5, halves=vol)
    with pytest.raises(ValueError, match="halves needs a volume"):
        sweep_strips(lum, masks, hs, aggregate_px=5, volume=vol, halves=np.empty((2, h, w), np.float32))
    with pytest.raises(ValueError, match="an 'lcn' cost"):
        sweep_slices(lum, masks, hs, "zncc", 9, None, volume=vol, halves=np.empty_like(vol))
    from lfring.depth.costs.lcn_halves import take_halves

    with pytest.raises(InvalidInputError, match="halves must have the volume's shape"):
        take_halves(vol, np.empty((2, h, w), np.float32))
    with pytest.raises(InvalidInputError, match="volume must be a C-contiguous float32"):
        take_halves(vol.astype(np.float64), vol)


@pytest.mark.parametrize("shape, box", [((40, 57), 15), ((1, 6), 3), ((5, 3), 7), ((9, 1), 5), ((30, 30), 1)])
def test_box_mean_of_finite_is_the_seen_mean_over_a_box(shape, box):
    """The compiled seen-pixel mean equals seen_mean with OpenCV's box (reflected borders, boxes
    larger than the image included) in float64, to float32 rounding; inf stays where c is."""
    from lfring.depth.aggregation import box_mean_of_finite, seen_mean

    rng = np.random.default_rng(box)
    c = rng.uniform(0.0, 2.0, shape).astype(np.float32)
    c[rng.random(shape) < 0.3] = np.inf
    c[0, 0] = np.nan
    finite = np.isfinite(c)
    window = lambda x: cv2.boxFilter(x.astype(np.float64), -1, (box, box), borderType=cv2.BORDER_REFLECT_101)
    expected = seen_mean(c, finite, window)
    got = box_mean_of_finite(c.copy(), box)
    assert np.array_equal(np.isfinite(got), finite) and np.all(got[~finite] == np.inf)
    np.testing.assert_allclose(got[finite], expected[finite], rtol=2e-6, atol=1e-7)
    full = np.where(finite, c, np.float32(1.5))  # every pixel finite: the plain box mean
    np.testing.assert_allclose(box_mean_of_finite(full.copy(), box), window(full), rtol=2e-6, atol=1e-7)


@pytest.mark.parametrize("c, box, match", [
    (np.zeros((4, 4), np.float64), 3, "float32"), (np.zeros((2, 4, 4), np.float32), 3, r"\(h, w\)"),
    (np.zeros((4, 4), np.float32), 4, "odd positive"), (np.zeros((4, 4), np.float32), 0, "odd positive"),
    (np.zeros((4, 4), np.float32), True, "odd positive")])
def test_box_mean_of_finite_refuses_bad_inputs(c, box, match):
    from lfring.depth.aggregation import box_mean_of_finite

    with pytest.raises(InvalidInputError, match=match):
        box_mean_of_finite(c, box)
    with pytest.raises(InvalidInputError, match="scratch must be float32"):
        box_mean_of_finite(np.zeros((4, 4), np.float32), 3, np.zeros((4, 5), np.float32))


def test_view_halves_follow_the_rows_and_columns_of_the_ring(twin):
    """Reference 0 (top left): its column and its row; 'center': the four sides of the square;
    the pair and a single line of views: none; the cost is 'lcn' there."""
    import warnings

    from lfring.depth.costs.lcn_halves import view_halves

    r, cal, views, *_ = twin
    shape = views.shape[1:3]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LfringWarning)
        hs = lambda c, ref: c.homographies(np.array([0.3, 1.0]), reference=ref)
        assert view_halves(hs(cal, 0), shape) == [(0, 2), (0, 1)]
        assert view_halves(hs(cal, 3), shape) == [(1, 3), (2, 3)]
        assert sorted(view_halves(hs(cal, "center"), shape)) == [(0, 1), (0, 2), (1, 3), (2, 3)]
        pair = cal.select_views([0, 1])
        assert view_halves(hs(pair, 0), shape) == [] and view_halves(hs(pair, "center"), shape) == []
        a = estimate_depth(views[:2], pair, zmin_m=0.3, zmax_m=1.0, reference=0)
        b = estimate_depth(views[:2], pair, zmin_m=0.3, zmax_m=1.0, reference=0, cost="lcn")
    assert a.cost == "lcn-halves"
    np.testing.assert_array_equal(a.depth_m, b.depth_m)


def test_a_pair_measures_every_pixel_both_views_see_up_to_their_rims(hard_twin):
    """Views 0 and 1 of the hard scene: every pixel of view 0 that view 1 also sees at its true
    depth (inside both discs, not hidden: from the per-view ground truth) gets a depth, also in
    the outer 15 % of the discs where the refocusing taper weighs a view down (the sweep's masks
    used to count such a pixel as fewer than two views and leave it unknown), and the depth is
    no worse there (measured: 4.3 % unknown and 10.7 % of the known off by more than 1 px of
    disparity; with the refocusing taper 15.5 % and 11.5 %)."""
    from lfring.core.viewstack import TAPER

    r, cal = hard_twin
    pair = cal.select_views([0, 1])
    gt = r.depth_m[0]
    h, w = gt.shape
    discs = r.layout.masks()
    ok = np.isfinite(gt) & (discs[0] > 0)
    t = pair.model(np.where(ok, gt, 1.0))[..., 1, :2, 2]  # H_0_from_1 at the true depth: a translation
    ys, xs = np.mgrid[0:h, 0:w]
    x1, y1 = np.rint(xs - t[..., 0]).astype(int), np.rint(ys - t[..., 1]).astype(int)
    inside = (x1 >= 0) & (x1 < w) & (y1 >= 0) & (y1 < h)
    x1, y1 = np.clip(x1, 0, w - 1), np.clip(y1, 0, h - 1)
    seen = ok & inside & (discs[1][y1, x1] > 0) & (np.abs(r.depth_m[1][y1, x1] - gt) < 0.01 * np.where(ok, gt, 1.0))
    res = estimate_depth(r.views[:2], pair, zmin_m=0.27, zmax_m=1.1, reference=0, consistency=False)
    d = res.depth_m[seen]
    known = np.isfinite(d)
    err = np.abs(_disparity(pair, np.where(known, d, 1.0)) - _disparity(pair, gt[seen]))
    assert seen.sum() > 0.3 * h * w
    assert np.mean(~known) <= 0.06, np.mean(~known)
    assert np.mean(~(err[known] <= 1.0)) <= 0.115, np.mean(~(err[known] <= 1.0))
    # Inspection's choice, the refocusing taper, counts the periphery's views as less than two.
    cautious = estimate_depth(r.views[:2], pair, zmin_m=0.27, zmax_m=1.1, reference=0, consistency=False, rim_taper=TAPER)
    assert np.mean(np.isnan(cautious.depth_m[seen])) >= 0.12


def test_a_calibration_that_is_none_is_refused(twin):
    r, cal, views, *_ = twin
    with pytest.raises(InvalidInputError, match="calibration must be a RingCalibration"):
        estimate_depth(views, None, zmin_m=0.3, zmax_m=1.0)


def test_filled_map_is_known_wherever_the_depth_is():
    """Flat views: no pixel is confident, so the refinement knows nothing; without the left-right
    check the depth keeps the optimisation's answers, and the filled map must not be emptier."""
    cal = RingCalibration.from_grid((40, 56), [(0, 0), (1, 0)], disparity_scale_px_m=20.0)
    views = np.full((2, 40, 56, 3), 0.5, np.float32)
    res = estimate_depth(views, cal, zmin_m=2.0, zmax_m=10.0, reference=0, consistency=False)
    known = np.isfinite(res.depth_m)
    assert known.mean() > 0.9
    assert np.isfinite(res.depth_filled_m[known]).all()
