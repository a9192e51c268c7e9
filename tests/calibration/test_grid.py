"""Calibrations of a stereo pair and of regular grids of views, built from their geometry, against
views rendered by construction: random textures on fronto-parallel planes, shifted by whole
pixels of known disparity."""

import json

import cv2
import numpy as np
import pytest

from lfring.calibration import RingCalibration
from lfring.cli.main import main
from lfring.depth import estimate_depth
from lfring.errors import FileFormatError, InvalidInputError
from lfring.focus import refocus
from lfring.views import MAX_VIEWS, Layout, grid_layout

SCALE_PX_M = 120.0  # disparity per grid step d = SCALE_PX_M / Z (z0 = 0)
PAD = 40


def _texture(rng, h, w):
    t = rng.random((h + 2 * PAD, w + 2 * PAD, 3), dtype=np.float32)
    return np.clip(cv2.GaussianBlur(t, (0, 0), 1.0) * 2.5 - 0.75, 0, 1)


def _render(positions, ref_pos, shape, layers):
    """(V, h, w, 3) views: ``layers`` back to front, each (disparity_px per grid step (an
    integer), rectangle (x, y, w, h) in the reference frame or None for the whole frame,
    texture). View k at grid position p_k shows at pixel x the layer's point that lies at
    x + (p_k - p_ref) d in the reference frame."""
    h, w = shape
    views = np.zeros((len(positions), h, w, 3), np.float32)
    for k, p in enumerate(positions):
        for d, rect, tex in layers:
            sx, sy = (int(v) for v in np.rint((np.asarray(p, float) - ref_pos) * d))
            patch = tex[PAD + sy : PAD + sy + h, PAD + sx : PAD + sx + w]
            if rect is None:
                views[k] = patch
            else:
                x, y, rw, rh = rect
                x0, x1, y0, y1 = max(x - sx, 0), min(x + rw - sx, w), max(y - sy, 0), min(y + rh - sy, h)
                views[k, y0:y1, x0:x1] = patch[y0:y1, x0:x1]
    return views


def _scene(positions, ref_pos, shape, seed):
    """Background plane at 4 px per step, a rectangle at 10 px per step in front of it."""
    rng = np.random.default_rng(seed)
    h, w = shape
    rect = (w // 3, h // 4, w // 3, h // 2)
    layers = [(4, None, _texture(rng, h, w)), (10, rect, _texture(rng, h, w))]
    gt = np.full(shape, 4.0)
    x, y, rw, rh = rect
    gt[y : y + rh, x : x + rw] = 10.0
    return _render(positions, ref_pos, shape, layers), gt, rect, layers


def _plane_masks(gt, rect, margin):
    """Pixels of each plane at least ``margin`` px from its edges, the frame's border and the
    background hidden behind the rectangle in some view."""
    h, w = gt.shape
    x, y, rw, rh = rect
    inner = np.zeros_like(gt, bool)
    inner[y + margin : y + rh - margin, x + margin : x + rw - margin] = True
    far = np.ones_like(gt, bool)
    far[max(y - margin, 0) : y + rh + margin, max(x - margin, 0) : x + rw + margin] = False
    far[:margin], far[-margin:], far[:, :margin], far[:, -margin:] = False, False, False, False
    return {10.0: inner, 4.0: far}


def test_stereo_pair_sign_convention_is_middleburys():
    # imL(x, y) = imR(x - d, y): the right view (one grid step right) sees the point d px further left.
    cal = RingCalibration.from_grid((30, 40), [(0, 0), (1, 0)], disparity_scale_px_m=SCALE_PX_M)
    d = 8.0
    h_l_from_r = cal.homography(1, SCALE_PX_M / d, reference=0)
    np.testing.assert_allclose(h_l_from_r, [[1, 0, d], [0, 1, 0], [0, 0, 1]], atol=1e-12)
    # With reference 'center' each view moves half of it, in opposite directions.
    np.testing.assert_allclose(cal.homographies(SCALE_PX_M / d)[:, :2, 2], [[-d / 2, 0], [d / 2, 0]], atol=1e-12)
    # A pair built by that rule refocuses into the left view exactly where both views see it.
    rng = np.random.default_rng(0)
    im_r = rng.random((30, 48, 3), dtype=np.float32)
    im_l = np.zeros_like(im_r)
    im_l[:, 8:] = im_r[:, :-8]  # imL(x) = imR(x - 8)
    views = np.stack([im_l[:, :40], im_r[:, :40]])
    out = refocus(views, cal, SCALE_PX_M / d, reference=0, interpolation="linear")
    np.testing.assert_allclose(out[:, 8:], im_l[:, 8:40], atol=1e-5)


def test_vertical_steps_move_views_up():
    # y down: the view one step below sees the point d px higher.
    cal = RingCalibration.from_grid((30, 40), [(0, 0), (0, 1)], disparity_scale_px_m=SCALE_PX_M, disparity_offset_px=1.0)
    np.testing.assert_allclose(cal.homography(1, SCALE_PX_M / 5.0, reference=0)[:2, 2], [0, 6.0], atol=1e-12)
    assert cal.layout.rects == ((0, 0, 40, 30), (0, 30, 40, 30))


def test_stereo_pair_depth_recovers_the_planes():
    shape = (96, 128)
    pos = [(0, 0), (1, 0)]
    views, gt, rect, _ = _scene(pos, np.array([0.0, 0.0]), shape, seed=1)
    cal = RingCalibration.from_grid(shape, pos, disparity_scale_px_m=SCALE_PX_M)
    res = estimate_depth(views, cal, zmin_m=SCALE_PX_M / 14, zmax_m=SCALE_PX_M / 2, reference=0)
    disparity = SCALE_PX_M / res.depth_m
    for d, m in _plane_masks(gt, rect, margin=12).items():
        err = np.abs(disparity[m] - d)
        assert m.sum() > 400
        assert np.mean(err < 0.5) > 0.97, (d, np.mean(err < 0.5))
        assert np.nanmedian(err) < 0.1
        np.testing.assert_allclose(np.nanmedian(res.depth_m[m]), SCALE_PX_M / d, rtol=0.01)


def test_three_by_three_grid_depth_and_refocus():
    shape = (72, 96)
    pos = [(x, y) for y in range(3) for x in range(3)]
    views, gt, rect, layers = _scene(pos, np.array([1.0, 1.0]), shape, seed=2)
    cal = RingCalibration.from_grid(shape, pos, disparity_scale_px_m=SCALE_PX_M)
    assert cal.layout.raw_shape == (3 * 72, 3 * 96) and cal.layout.rects[4] == (96, 72, 96, 72)
    res = estimate_depth(views, cal, zmin_m=SCALE_PX_M / 14, zmax_m=SCALE_PX_M / 2)  # reference 'center' = view 4
    disparity = SCALE_PX_M / res.depth_m
    for d, m in _plane_masks(gt, rect, margin=12).items():
        err = np.abs(disparity[m] - d)
        assert np.mean(err < 0.5) > 0.97, (d, np.mean(err < 0.5))
        assert np.nanmedian(err) < 0.1
    # Refocused at a plane's depth, the plane lines up: the result is its texture where every
    # view sees it (bilinear at whole-pixel shifts is exact).
    h, w = shape
    for (d, _, tex), m in zip(layers, (_plane_masks(gt, rect, margin=12)[4.0], _plane_masks(gt, rect, margin=12)[10.0])):
        out = refocus(views, cal, SCALE_PX_M / d, interpolation="linear")
        truth = tex[PAD : PAD + h, PAD : PAD + w]
        np.testing.assert_allclose(out[m], truth[m], atol=1e-5)
        # ... and the other plane is not aligned there.
        assert np.mean(np.abs(out[~m] - truth[~m])) > 0.02


def test_calibration_json_round_trip(tmp_path):
    for pos in ([(0, 0), (1, 0)], [(x, y) for y in range(10) for x in range(10)], [(0.0, 0.0), (0.5, 0.25), (2.0, 1.0)]):
        cal = RingCalibration.from_grid((20, 30), pos, disparity_scale_px_m=-3.5, disparity_offset_px=0.7, depth_origin_m=0.02)
        path = cal.save(tmp_path / f"grid{len(pos)}.json")
        back = RingCalibration.load(path)
        assert back.source == "grid" and back.num_views == len(pos)
        assert back.layout.rects == cal.layout.rects and back.raw_size == cal.raw_size
        assert back.depth_origin_m == 0.02 and back.valid_depth_range_m == cal.valid_depth_range_m
        assert back.provenance["grid_positions"] == np.asarray(pos, float).tolist()
        for z in (0.5, 3.0):
            np.testing.assert_allclose(back.homographies(z), cal.homographies(z), atol=1e-12)
            # The disparity per step is the affine function of 1 / (Z - z0) asked for.
            t = back.homographies(z, reference=0)[:, :2, 2]
            np.testing.assert_allclose(t, (np.asarray(pos) - pos[0]) * (0.7 - 3.5 / (z - 0.02)), atol=1e-12)
    # Non-integer positions lie in one row of the mosaic.
    assert back.layout.rects == ((0, 0, 30, 20), (30, 0, 30, 20), (60, 0, 30, 20))
    # A file with a model for another number of views than its layout is refused.
    data = json.loads(path.read_text())
    data["A"] = data["A"][:2]
    path.write_text(json.dumps(data))
    with pytest.raises(FileFormatError, match="3 finite 3 x 3"):
        RingCalibration.load(path)


@pytest.mark.parametrize("count", [1, MAX_VIEWS + 1])
def test_view_counts_outside_2_to_100_are_refused(count):
    pos = [(k % 11, k // 11) for k in range(count)]
    with pytest.raises(InvalidInputError, match=f"2 to 100 views, got {count}"):
        RingCalibration.from_grid((8, 8), pos, disparity_scale_px_m=1.0)
    with pytest.raises(InvalidInputError, match=f"2 to 100 views, got {count}"):
        Layout(8 * count, 8, tuple((8 * k, 0, 8, 8) for k in range(count)))


def test_views_that_do_not_match_the_calibration_are_refused():
    cal = RingCalibration.from_grid((16, 20), [(0, 0), (1, 0), (2, 0)], disparity_scale_px_m=10.0)
    views = np.zeros((4, 16, 20, 3), np.float32)
    with pytest.raises(InvalidInputError, match=r"3 views of 20 x 16 px, \(V, h, w, C\) = \(3, 16, 20, C\), but the views are 4 of 20 x 16 px \(shape \(4, 16, 20"):
        estimate_depth(views, cal, zmin_m=1.0, zmax_m=5.0)
    with pytest.raises(InvalidInputError, match="expected 3 views"):
        refocus(views, cal, 2.0)


@pytest.mark.parametrize("bad, match", [
    ({"grid_positions": [(0, 0), (0, 0)]}, "distinct"),
    ({"grid_positions": [0, 1]}, r"\(V, 2\)"),
    ({"disparity_scale_px_m": 0.0}, "must not be 0"),
    ({"disparity_scale_px_m": float("nan")}, "finite"),
    ({"view_shape": (0, 5)}, "view_shape"),
    ({"grid_positions": [(0, 0), (1,)]}, r"\(V, 2\)"),
    ({"valid_depth_range_m": (1.0, float("inf"))}, "None, not inf"),  # save() would write what load() refuses
    ({"valid_depth_range_m": (1.0,)}, "valid_depth_range_m must be"),
    ({"valid_depth_range_m": 5}, "valid_depth_range_m must be"),
    ({"valid_depth_range_m": ("a", "b")}, "valid_depth_range_m must be"),
    ({"valid_depth_range_m": (5.0, 1.0)}, r"must be \(nearest, farthest\): its farthest depth is the nearer"),
    ({"valid_depth_range_m": (-1.0, 1.0)}, "must lie beyond z0"),
])
def test_bad_grids_are_refused(bad, match):
    kw = {"view_shape": (8, 8), "grid_positions": [(0, 0), (1, 0)], "disparity_scale_px_m": 1.0, **bad}
    with pytest.raises(InvalidInputError, match=match):
        RingCalibration.from_grid(kw.pop("view_shape"), kw.pop("grid_positions"), **kw)


def test_grid_layout_places_integer_positions_on_their_cells():
    lay = grid_layout((4, 6), [(1, 1), (0, 0), (2, 0)])
    assert lay.rects == ((6, 4, 6, 4), (0, 0, 6, 4), (12, 0, 6, 4)) and lay.raw_shape == (8, 18)


def test_cli_grid_calib_then_depth_and_refocus_of_separate_views(tmp_path):
    shape = (64, 96)
    pos = [(0, 0), (1, 0)]
    views, gt, rect, _ = _scene(pos, np.array([0.0, 0.0]), shape, seed=3)
    paths = []
    for k, v in enumerate(views):
        paths.append(str(tmp_path / f"v{k}.png"))
        cv2.imwrite(paths[-1], np.rint(v[..., ::-1] * 65535).astype(np.uint16))
    cal_path = tmp_path / "pair.json"
    assert main(["grid-calib", "--size", "96x64", "--disparity-scale", str(SCALE_PX_M), "-o", str(cal_path)]) == 0
    cal = RingCalibration.load(cal_path)
    assert cal.num_views == 2 and cal.layout.view_shape == shape
    assert main(["depth", *paths, "--calib", str(cal_path), "--zmin", str(SCALE_PX_M / 14), "--zmax", str(SCALE_PX_M / 2),
                 "--reference", "0", "-o", str(tmp_path / "out")]) == 0
    import tifffile

    depth = tifffile.imread(tmp_path / "out" / "v0_depth.tiff")
    m = _plane_masks(gt, rect, margin=12)[10.0]
    assert np.mean(np.abs(SCALE_PX_M / depth[m] - 10.0) < 0.5) > 0.95
    record = json.loads((tmp_path / "out" / "v0_depth.json").read_text())
    assert record["input"] == paths
    assert (record["paths"], record["consistency"]) == (4, True)  # a pair's default: the left-right check
    # A grid's calibration reaches infinity: the depth-aware default needs the depth range.
    assert main(["refocus", *paths, "--calib", str(cal_path), "--depth", "12", "-o", str(tmp_path / "r.png")]) == 2
    assert not (tmp_path / "r.png").exists()
    assert main(["refocus", *paths, "--calib", str(cal_path), "--depth", "12", "--method", "shift-and-add",
                 "-o", str(tmp_path / "r.png")]) == 0
    assert cv2.imread(str(tmp_path / "r.png")).shape == (64, 96, 3)
    # Separate views need a calibration of as many views.
    assert main(["depth", *paths, "--zmin", "1", "--zmax", "5", "-o", str(tmp_path / "o2")]) == 2
    assert main(["depth", *paths, paths[0], "--calib", str(cal_path), "--zmin", "9", "--zmax", "50", "-o", str(tmp_path / "o3")]) == 2
    assert main(["grid-calib", "--size", "96x64", "--grid", "11x10", "--disparity-scale", "1", "-o", str(tmp_path / "g.json")]) == 2
    # Refused before any view is built (a huge grid used to be listed first), and no traceback.
    for size, grid in (("96x64", "100000x100000"), ("nanx64", "2x1"), ("infx64", "2x1")):
        assert main(["grid-calib", "--size", size, "--grid", grid, "--disparity-scale", "1", "-o", str(tmp_path / "g.json")]) == 2
    assert not (tmp_path / "g.json").exists()


def test_select_views_of_the_ring_keeps_their_homographies(prototype):
    cal = RingCalibration.from_optics(prototype.binned(2))
    pair = cal.select_views([0, 1])
    assert pair.num_views == 2 and pair.layout.rects == cal.layout.rects[:2]
    assert pair.layout.circles == cal.layout.circles[:2]
    for z in (0.3, 1.0):
        np.testing.assert_allclose(pair.homographies(z, reference=0), cal.homographies(z, reference=0)[:2], atol=1e-12)
        # 'center' of the pair is the middle of views 0 and 1, not of all four.
        t = pair.homographies(z)[:, :2, 2]
        np.testing.assert_allclose(t[0], -t[1], atol=1e-12)
    with pytest.raises(InvalidInputError, match="base view 0"):
        cal.select_views([1, 2])
    with pytest.raises(InvalidInputError, match="distinct view indices 0..3"):
        cal.select_views([0, 0])


def test_cli_grid_calib_positions(tmp_path):
    out = tmp_path / "g.json"
    assert main(["grid-calib", "--size", "30x20", "--positions", "0,0 2,0 1,1", "--disparity-scale", "2",
                 "--disparity-offset", "-0.5", "-o", str(out)]) == 0
    cal = RingCalibration.load(out)
    assert cal.layout.rects == ((0, 0, 30, 20), (60, 0, 30, 20), (30, 20, 30, 20))
    np.testing.assert_allclose(cal.homographies(1.0, reference=0)[:, :2, 2], [[0, 0], [3.0, 0], [1.5, 1.5]], atol=1e-12)
    assert main(["grid-calib", "--size", "30x20", "--positions", "0,0 1,0", "--grid", "2x1", "--disparity-scale", "2",
                 "-o", str(tmp_path / "h.json")]) == 2


def test_ten_by_ten_grid_refocus_and_depth_of_a_plane():
    shape = (40, 48)
    pos = [(x, y) for y in range(10) for x in range(10)]
    rng = np.random.default_rng(4)
    tex = _texture(rng, *shape)
    views = _render(pos, np.array([4.5, 4.5]), shape, [(2, None, tex)])  # odd whole-pixel shifts from the centre
    cal = RingCalibration.from_grid(shape, pos, disparity_scale_px_m=SCALE_PX_M)
    assert cal.num_views == 100 and cal.layout.raw_shape == (400, 480)
    out = refocus(views, cal, SCALE_PX_M / 2, interpolation="linear")
    np.testing.assert_allclose(out[10:-10, 10:-10], tex[PAD + 10 : PAD + shape[0] - 10, PAD + 10 : PAD + shape[1] - 10], atol=1e-5)
    res = estimate_depth(views, cal, zmin_m=SCALE_PX_M / 3, zmax_m=SCALE_PX_M / 1)
    np.testing.assert_allclose(SCALE_PX_M / res.depth_m[12:-12, 12:-12], 2.0, atol=0.1)


def test_a_grid_pair_without_a_depth_range_is_refused_alike_by_the_api_refocus_and_batch(tmp_path, capsys):
    """The grid's open range starts where its views stop overlapping: no far end follows from
    it (lfring.focus.depth_aware.estimation_range), and every entry point of depth-aware
    refocusing says so, writing nothing; given the scene's range they all take it."""
    from lfring.batch import BatchSettings
    from lfring.focus.depth_aware import estimation_range

    shape = (64, 96)
    views, _, _, _ = _scene([(0, 0), (1, 0)], np.array([0.5, 0.0]), shape, seed=5)
    cal = RingCalibration.from_grid(shape, [(0, 0), (1, 0)], disparity_scale_px_m=SCALE_PX_M)
    cal_path = tmp_path / "pair.json"
    cal.save(cal_path)
    refusal = r"no upper depth bound, and none follows from it.*farthest depth as zmax_m.*shift-and-add"
    with pytest.raises(InvalidInputError, match=refusal):
        estimation_range(cal)
    with pytest.raises(InvalidInputError, match=refusal):
        refocus(views, cal, 12.0, method="depth-aware")
    with pytest.raises(InvalidInputError, match=refusal):
        BatchSettings(refocus_m=(12.0,), calibration=cal)
    # The all-in-focus image's depths follow the same rule.
    from lfring.focus import all_in_focus

    with pytest.raises(InvalidInputError, match="give depths_m: the calibration has no upper depth bound, and none follows"):
        all_in_focus(views, cal)
    cal_path_aif = tmp_path / "pair_aif.json"
    cal.save(cal_path_aif)
    for k, v in enumerate(views):
        cv2.imwrite(str(tmp_path / f"a{k}.png"), np.rint(v[..., ::-1] * 65535).astype(np.uint16))
    capsys.readouterr()
    assert main(["refocus", str(tmp_path / "a0.png"), str(tmp_path / "a1.png"), "--calib", str(cal_path_aif), "--depth", "12",
                 "--method", "shift-and-add", "--all-in-focus", "-o", str(tmp_path / "aif.png")]) == 2
    err = capsys.readouterr().err
    assert "--depth Z1,Z2" in err and "depths_m" not in err and "Traceback" not in err
    assert not list(tmp_path.glob("aif*"))
    assert main(["depth", str(tmp_path / "a0.png"), str(tmp_path / "a1.png"), "--calib", str(cal_path_aif), "--reference", "0",
                 "-o", str(tmp_path / "dep")]) == 2
    assert "no upper depth bound, and none follows from it: give --zmax" in capsys.readouterr().err
    # The CLIs: exit 2, one line naming their options, no traceback, no output.
    paths = []
    for k, v in enumerate(views):
        paths.append(str(tmp_path / f"v{k}.png"))
        cv2.imwrite(paths[-1], np.rint(v[..., ::-1] * 65535).astype(np.uint16))
    assert main(["refocus", *paths, "--calib", str(cal_path), "--depth", "12", "-o", str(tmp_path / "r.png")]) == 2
    err = capsys.readouterr().err
    assert "--zmax" in err and "--method shift-and-add" in err and "Traceback" not in err
    assert not (tmp_path / "r.png").exists() and not (tmp_path / "r.png.json").exists()
    frame = tmp_path / "pair.png"  # the views side by side: the grid's raw frame
    cv2.imwrite(str(frame), np.rint(np.concatenate(list(views), axis=1)[..., ::-1] * 65535).astype(np.uint16))
    out = tmp_path / "batch"
    assert main(["batch", str(frame), "-o", str(out), "--refocus", "12", "--calib", str(cal_path), "--workers", "1",
                 "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "no upper depth bound" in err and "--zmax" in err and "Traceback" not in err
    assert not out.exists()
    # Shift-and-add needs no depth map: the batch takes the pair.
    assert main(["batch", str(frame), "-o", str(out), "--refocus", "12", "--method", "shift-and-add", "--calib",
                 str(cal_path), "--workers", "1", "--no-progress", "--no-check"]) == 0
    assert (out / "pair_refocus_12m.png").is_file()
    # Given the scene's near end (6 m, 20 px of disparity), the far end follows from it (1 px at
    # 120 m), for the API and the CLI alike; the sidecar records the range.
    lo, hi = estimation_range(cal, zmin_m=6.0)
    assert (lo, hi) == pytest.approx((6.0, 120.0))
    assert main(["refocus", *paths, "--calib", str(cal_path), "--depth", "12", "--zmin", "6",
                 "-o", str(tmp_path / "r.png")]) == 0
    side = json.loads((tmp_path / "r.png.json").read_text())
    assert (side["zmin_m"], side["zmax_m"]) == (lo, hi)
    api = refocus(views, cal, 12.0, method="depth-aware", zmin_m=6.0)
    assert api.shape == (64, 96, 3) and np.all(np.isfinite(api))
