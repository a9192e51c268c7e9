"""Layout detection against the twin's ground truth, layout files, and splitting."""

import json

import numpy as np
import pytest

from lfring.errors import EstimationError, FileFormatError, InvalidInputError, LfringFileNotFoundError
from lfring.io.bayer import PATTERNS
from lfring.synth import render
from lfring.synth.presets import flat_scene, target_scene
from lfring.views import Layout, detect_layout, split_views


def _raw_circles(lay):
    return np.array([[c[0] + r[0], c[1] + r[1], c[2]] for c, r in zip(lay.circles, lay.rects)])


@pytest.fixture(scope="module")
def flats(prototype):
    scene = flat_scene(prototype)
    return {
        (p, n): render(prototype, scene, binning=2, pattern=p, noise=n, seed=7)
        for p in PATTERNS
        for n in ("none", "realistic")
    }


@pytest.mark.parametrize("pattern", PATTERNS)
@pytest.mark.parametrize("noise", ["none", "realistic"])
def test_flat_frame_layout_matches_ground_truth(flats, pattern, noise):
    r = flats[(pattern, noise)]
    lay = detect_layout(r.raw)  # the Bayer mosaic as it is
    assert lay.view_shape == r.layout.view_shape or abs(lay.view_shape[0] - r.layout.view_shape[0]) <= 2
    assert np.abs(np.array(lay.rects) - np.array(r.layout.rects)).max() <= 2
    err = _raw_circles(lay) - _raw_circles(r.layout)
    assert np.abs(err[:, :2]).max() < 0.5 and np.abs(err[:, 2]).max() < 0.5
    # Views cut with the detected layout match the ground-truth views.
    from lfring.io.demosaic import demosaic
    from lfring.io.raw import RawFrame

    frame = RawFrame(mosaic=r.raw, pattern=pattern, black_level=r.black_level, white_level=r.white_level, bit_depth=12)
    if lay.rects == r.layout.rects:
        views = split_views(demosaic(frame, method="bilinear"), lay)
        gt = r.views
        inner = np.s_[:, 20:-20, 20:-20]
        mse = np.mean((views[inner] - gt[inner]) ** 2)
        psnr = 10 * np.log10(1.0 / mse)
        assert psnr > (60 if noise == "none" else 33)


def test_rotated_flat(prototype):
    r = render(prototype, flat_scene(prototype), binning=2, pattern="GBRG", rotate180=True, noise="realistic")
    lay = detect_layout(r.raw, rotate180=True)
    assert lay.rotate180
    assert np.abs(np.array(lay.rects) - np.array(r.layout.rects)).max() <= 2


def test_ordinary_frame_layout(prototype):
    """Without a flat frame: a textured target gives the discs within a few pixels (the
    content at the edges biases the half-light point; see detect_layout's notes)."""
    r = render(prototype, target_scene(prototype, 0.5), binning=2, noise="realistic")
    lay = detect_layout(r.raw)
    err = _raw_circles(lay) - _raw_circles(r.layout)
    assert np.abs(err[:, :2]).max() < 3.0
    assert np.abs(err[:, 2]).max() < 2.5
    assert np.abs(np.array(lay.rects) - np.array(r.layout.rects)).max() <= 5


def test_detect_errors():
    with pytest.raises(EstimationError, match="uniform"):
        detect_layout(np.zeros((200, 300), np.uint16))
    one = np.zeros((200, 300), np.float32)
    yy, xx = np.indices(one.shape)
    one[(yy - 100) ** 2 + (xx - 150) ** 2 < 60**2] = 1.0
    with pytest.raises(EstimationError, match="found 1 bright region"):
        detect_layout(one)
    noise = np.random.default_rng(0).random((200, 300)).astype(np.float32)
    with pytest.raises(EstimationError):
        detect_layout(noise)
    with pytest.raises(InvalidInputError, match="NaN"):
        detect_layout(np.full((100, 100), np.nan))
    with pytest.raises(InvalidInputError, match="kind"):
        detect_layout(one, kind="white")


def _discs(texture: float) -> np.ndarray:
    """A 200 x 300 frame of four bright discs on black, ``texture`` the amplitude of the
    random blotches inside them."""
    frame = np.zeros((200, 300), np.float32)
    yy, xx = np.indices(frame.shape)
    noise = np.kron(np.random.default_rng(1).random((25, 38)), np.ones((8, 8)))[:200, :300]  # 8 px blotches
    for cx, cy in ((75, 50), (225, 50), (75, 150), (225, 150)):
        inside = (yy - cy) ** 2 + (xx - cx) ** 2 < 40**2
        frame[inside] = 1.0 - texture * noise[inside]
    return frame


@pytest.mark.parametrize("frame, kind, error, says", [
    (np.zeros((8, 40), np.float32), "auto", InvalidInputError,
     "the frame is 40 x 8 px, too small to find views on (at least 16 px each way)"),
    (np.zeros((4, 5, 6, 7)), "auto", InvalidInputError, "the frame must be an image, (H, W) or (H, W, C)"),
    (np.full((100, 100), np.nan), "auto", InvalidInputError, "the frame contains NaN or infinite values"),
    (np.zeros((200, 300), np.float32), "auto", EstimationError, "the frame is uniform"),
    (_discs(0.6), "flat", InvalidInputError, "the frame is not a flat field: the inner half of its discs of light shows texture"),
    (_discs(0.0)[:, :150], "auto", EstimationError, "found 2 bright region(s) where 4 views were expected"),
])
def test_detect_errors_speak_of_the_frame_not_the_function(frame, kind, error, says):
    """The refusals read as about the frame given (a caller names its file or option before
    them, as lfring split does with --flat FILE), never about a function the user did not call."""
    with pytest.raises(error) as err:
        detect_layout(frame, kind=kind)
    assert str(err.value).startswith(says) and "detect_layout" not in str(err.value)


def test_the_same_discs_without_texture_are_a_flat_field():
    """The textured frame above is refused for its texture alone."""
    assert detect_layout(_discs(0.0), kind="flat").num_views == 4


def test_detect_as_flat_refuses_a_frame_with_texture_in_its_discs(prototype):
    """kind='flat' on a target: refused as not a flat field (and the same frame's own kind,
    'auto', finds it a scene and detects its discs)."""
    r = render(prototype, target_scene(prototype, 0.5), binning=4, noise="low")
    with pytest.raises(InvalidInputError, match="not a flat field"):
        detect_layout(r.raw, kind="flat")
    lay = detect_layout(r.raw)
    assert np.abs(_raw_circles(lay)[:, :2] - _raw_circles(r.layout)[:, :2]).max() < 4.0


def test_layout_round_trip_and_bad_files(tmp_path, prototype):
    r = render(prototype, flat_scene(prototype), binning=8)
    p = r.layout.save(tmp_path / "layout.json")
    back = Layout.load(p)
    assert back.rects == r.layout.rects and back.circles == r.layout.circles and back.rotate180 == r.layout.rotate180
    np.testing.assert_array_equal(back.masks(), r.layout.masks())
    bad = json.loads(p.read_text())
    side = bad["rects_xywh_px"][0][2]
    bad["rects_xywh_px"][0] = [614 - side // 2, 0, side, side]
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    with pytest.raises(FileFormatError, match="does not fit"):
        Layout.load(tmp_path / "bad.json")
    (tmp_path / "trunc.json").write_text(p.read_text()[:50])
    with pytest.raises(FileFormatError, match="not a JSON layout"):
        Layout.load(tmp_path / "trunc.json")
    with pytest.raises(LfringFileNotFoundError):
        Layout.load(tmp_path / "none.json")
    with pytest.raises(InvalidInputError, match="same size"):
        Layout(100, 100, ((0, 0, 10, 10), (20, 0, 11, 10)))


def test_layouts_hold_2_to_100_views():
    from lfring.views import MAX_VIEWS, MIN_VIEWS

    assert (MIN_VIEWS, MAX_VIEWS) == (2, 100)
    lay = Layout(1000, 100, tuple((10 * k, 0, 10, 10) for k in range(100)))
    assert lay.num_views == 100 and Layout.from_dict(json.loads(json.dumps(lay.to_dict()))).rects == lay.rects
    for n in (1, 101):
        with pytest.raises(InvalidInputError, match=f"2 to 100 views, got {n}"):
            Layout(1010, 100, tuple((10 * k, 0, 10, 10) for k in range(n)))


def test_read_views_stacks_separate_images(tmp_path):
    import cv2

    from lfring.views import read_views

    rng = np.random.default_rng(0)
    imgs = [rng.integers(0, 256, (12, 16, 3), dtype=np.uint8) for _ in range(3)]
    paths = []
    for k, im in enumerate(imgs):
        paths.append(tmp_path / f"v{k}.png")
        cv2.imwrite(str(paths[-1]), im[..., ::-1])
    views = read_views(paths)
    assert views.shape == (3, 12, 16, 3) and views.dtype == np.float32
    np.testing.assert_allclose(views, np.stack(imgs) / 255.0, atol=1e-6)
    cv2.imwrite(str(tmp_path / "small.png"), imgs[0][:10])
    with pytest.raises(InvalidInputError, match="one size"):
        read_views([paths[0], tmp_path / "small.png"])
    with pytest.raises(InvalidInputError, match="2 to 100 view images, got 1"):
        read_views(paths[:1])
    # One view twice (or a copy of it): refused, naming both.
    (tmp_path / "copy.png").write_bytes(paths[1].read_bytes())
    for twice in ([paths[0], paths[1], paths[1]], [paths[1], paths[0], tmp_path / "copy.png"]):
        with pytest.raises(InvalidInputError, match=r"view images (1 and 2|0 and 2) \(.*\) are the same image"):
            read_views(twice)


def test_splitting_with_a_calibration_corrects_the_views(prototype):
    """A calibration without distortion or flat field cuts exactly what its layout cuts; a flat
    frame given to the split divides every view to the same brightness."""
    from lfring.calibration import RingCalibration

    dev = prototype.binned(4)
    cal = RingCalibration.from_optics(dev)
    r = render(dev, target_scene(dev, 0.5, seed=1), binning=1, pattern=None, noise="none")
    np.testing.assert_array_equal(split_views(r.image, cal), split_views(r.image, cal.layout))
    flat = render(dev, flat_scene(dev), binning=1, pattern=None, noise="none").image
    fielded = split_views(flat, cal, flat=flat)
    inside = cal.layout.masks()
    inside &= split_views(flat, cal.layout)[..., 1] > 0.5 * flat.max()
    inside[:, :3] = inside[:, -3:] = inside[:, :, :3] = inside[:, :, -3:] = False  # the smoothing's border
    lum = fielded[..., 1][inside]
    assert float(lum.max() - lum.min()) < 0.02
    assert np.array_equal(split_views(flat, cal.layout, flat=flat), fielded)
    with pytest.raises(InvalidInputError, match="Layout or a RingCalibration"):
        split_views(flat, "twin_binned2")
    # Each message names what is wrong: a RawFrame not demosaicked, the flat frame (not the image).
    from lfring.io.raw import RawFrame

    raw = RawFrame(mosaic=np.zeros(r.image.shape[:2], np.uint16), pattern="RGGB", black_level=0, white_level=4095,
                   bit_depth=12)
    with pytest.raises(InvalidInputError, match=r"lfring.demosaic\(frame\): a RawFrame holds raw counts"):
        split_views(raw, cal)
    with pytest.raises(InvalidInputError, match="the flat frame is .* px but the layout is for"):
        split_views(r.image, cal, flat=flat[:-2])


def test_a_flat_frame_with_nan_inside_the_views_is_refused_as_such():
    """A NaN in the flat was reported as "the flat frame is black where the views are"."""
    from pathlib import Path

    import lfring

    data = Path(__file__).resolve().parents[1] / "data" / "synthetic"
    cal = lfring.RingCalibration.load("twin_binned2")
    frame = lfring.demosaic(lfring.load_raw(data / "scene.png"))
    flat = lfring.demosaic(lfring.load_raw(data / "flat.png"))
    x, y, _, _ = cal.layout.rects[0]
    flat[y + 300:y + 310, x + 300:x + 310] = np.nan
    with pytest.raises(InvalidInputError, match="the flat frame holds NaN or infinite values where the views are"):
        split_views(frame, cal, flat=flat)


def test_a_grid_that_leaves_views_out_is_refused(flats):
    """grid=(1, 2) on a frame of four discs kept the two largest without a word; a grid that is no
    (rows, cols) pair of counts broke on a division or an index; a RawFrame or a path was called
    an image of the wrong shape. Each is refused, saying what to give; the right grid finds the
    four views."""
    from lfring.io.raw import RawFrame

    r = flats[("RGGB", "realistic")]
    with pytest.raises(EstimationError, match=r"found 4 bright regions of a view's size where the grid 1 x 2 holds 2"):
        detect_layout(r.raw, grid=(1, 2))
    for grid in [(0, 0), 4, (2, 2, 1), (2.5, 2), "2x2"]:
        with pytest.raises(InvalidInputError, match="grid must be \\(rows, cols\\) of views"):
            detect_layout(r.raw, grid=grid)
    assert detect_layout(r.raw, grid=(2, 2)).num_views == 4
    frame = RawFrame(mosaic=r.raw, pattern="RGGB", black_level=r.black_level, white_level=r.white_level, bit_depth=12)
    with pytest.raises(InvalidInputError, match=r"lfring.demosaic\(frame\), or its Bayer mosaic"):
        detect_layout(frame)
    with pytest.raises(InvalidInputError, match=r"not a path"):
        detect_layout("flat.png")


def test_stray_light_along_an_edge_is_not_taken_for_a_view_the_grid_leaves_out():
    """The count of views against the grid refused a flat frame with a bright band along its
    edge (half a disc's area: "found 5 bright regions of a view's size"): only round regions
    filled as discs count; the band changes none of the discs found."""
    from pathlib import Path

    import lfring

    flat = lfring.demosaic(lfring.load_raw(Path(__file__).resolve().parents[1] / "data" / "synthetic" / "flat.png"))
    clean = detect_layout(flat)
    banded = flat.copy()
    banded[:, :110] = 0.9
    lay = detect_layout(banded)
    np.testing.assert_allclose(_raw_circles(lay), _raw_circles(clean), atol=0.01)
