"""lfring.check_frame: ring frames of the twin pass, photographs do not; the numbers in
lfring.check.AGREEMENT_THRESHOLD's docstring."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from lfring import check_frame, demosaic, load_raw, split_views
from lfring.calibration.defaults import default_calibration
from lfring.check import AGREEMENT_THRESHOLD, CHECK_MIN_SIDE_PX, draw_layout
from lfring.errors import InvalidInputError

DATA = Path(__file__).resolve().parents[1] / "data" / "synthetic"


@pytest.fixture(scope="module")
def cal():
    return default_calibration((2456, 1842))[0]


@pytest.mark.parametrize("name, lowest", [("scene.png", 0.73), ("target_0.3m.png", 0.7), ("target_1m.png", 0.88),
                                          ("part_good.png", 0.77)])
def test_ring_frames_agree(cal, name, lowest):
    res = check_frame(load_raw(DATA / name), cal)
    assert res.ok and res.agreement > lowest > 2 * AGREEMENT_THRESHOLD
    assert res.size_px == (2456, 1842) and res.raw["pattern"] == "RGGB" and res.raw["white_level"] == 4095
    assert res.disc_contrast > 0.8  # dark between the discs
    assert cal.valid_depth_range_m[0] / 2 <= res.best_depth_m <= 2 * cal.valid_depth_range_m[1]


@pytest.mark.parametrize("name", ["astronaut", "coffee", "chelsea"])
def test_photographs_do_not(cal, name):
    from skimage import data

    img = getattr(data, name)().astype(np.float32) / 255
    img = np.clip(cv2.resize(img, (2456, 1842), interpolation=cv2.INTER_CUBIC), 0, 1) ** 2.2
    res = check_frame(img.astype(np.float32), cal)
    assert not res.ok and res.agreement < AGREEMENT_THRESHOLD / 10
    assert abs(res.disc_contrast) < 0.2  # light everywhere
    assert "do not agree" in res.message and "--no-check" in res.message


@pytest.fixture(scope="module")
def scene_views(cal):
    return split_views(demosaic(load_raw(DATA / "scene.png")), cal.layout)


def test_views_input(cal, scene_views):
    assert check_frame(scene_views, cal).ok


@pytest.mark.parametrize("order", [[1, 0, 3, 2], [2, 3, 0, 1], [3, 2, 1, 0], [0, 2, 1, 3]])
def test_views_in_the_wrong_places(cal, scene_views, order):
    res = check_frame(np.ascontiguousarray(scene_views[order]), cal)
    assert not res.ok and res.agreement < AGREEMENT_THRESHOLD / 5


def test_views_turned(cal, scene_views):
    res = check_frame(np.ascontiguousarray(scene_views[:, ::-1, ::-1]), cal)
    assert not res.ok and res.agreement < AGREEMENT_THRESHOLD / 5


def test_exposure_fractions(cal):
    image = np.full((1842, 2456, 3), 0.5, np.float32)
    image[:, :1228] = 1.0  # left half clipped: views 0 and 2
    res = check_frame(image, cal)
    assert res.clipped_fraction == pytest.approx(0.5, abs=1e-6) and res.dark_fraction == 0.0
    assert not res.ok  # no texture: nothing agrees


def test_wrong_size_refused(cal):
    with pytest.raises(InvalidInputError, match="2456 x 1842"):
        check_frame(np.zeros((100, 120, 3), np.float32), cal)


def test_draw_layout(cal):
    out = draw_layout(np.zeros((1842, 2456, 3), np.float32), cal.layout)
    assert out.dtype == np.uint8 and out.shape == (1842, 2456, 3)
    x, y, w, h = cal.layout.rects[0]
    assert tuple(out[y, x + 5]) == (255, 220, 0)  # the rectangle, yellow
    assert tuple(out[y + h // 2, x + 1]) == (0, 255, 0)  # the disc touches its left edge, green


def _gradient(kind: str) -> np.ndarray:
    """A smooth RGB gradient filling a 2456 x 1842 frame, as 8-bit counts."""
    h, w = 1842, 2456
    x = np.linspace(0, 1, w)[None, :].repeat(h, 0)
    ramp = x if kind == "horizontal" else (x + np.linspace(0, 1, h)[:, None]) / 2
    return (np.stack([ramp, 0.8 * ramp, 0.6 * ramp], -1) * 255).astype(np.uint8)


@pytest.mark.parametrize("kind", ["horizontal", "diagonal"])
def test_a_gradient_has_no_discs_and_is_refused(cal, kind):
    """Its views may agree (a horizontal ramp's quadrants do), but there are no discs of light."""
    res = check_frame(_gradient(kind).astype(np.float32) / 255, cal)
    assert abs(res.disc_contrast) < 0.05
    assert not res.ok and res.reason == "no_discs" and "no discs" in res.message and "--no-check" in res.message


def test_a_photograph_with_a_clipped_sky_has_no_discs_rather_than_too_much_light(cal):
    """A textured photograph whose top fifth is clipped (a sky): it was refused as 'an
    over-exposed flat (white) frame ... reduce the exposure', which sends the user to the
    exposure of a frame that is not a ring frame at all. No discs comes first, and no exposure
    warning rides along."""
    from lfring.io.raw import RawFrame

    rng = np.random.default_rng(3)
    x = cv2.GaussianBlur(rng.random((1842, 2456)).astype(np.float32), (0, 0), 1)
    x = (x - x.min()) / (x.max() - x.min()) * 0.8 + 0.05
    x[:400] = 1.0
    frame = RawFrame(mosaic=(x * 4095).astype(np.uint16), pattern="RGGB", black_level=0.0, white_level=4095.0, bit_depth=12)
    res = check_frame(frame, cal)
    assert res.clipped_fraction >= 0.05 and abs(res.disc_contrast) < 0.05
    assert not res.ok and res.reason == "no_discs" and res.message.startswith("no discs of light")
    assert res.warning == "" and "exposure" not in res.message


@pytest.mark.parametrize("kind", ["horizontal"])
def test_cli_check_and_refocus_refuse_a_gradient(tmp_path, kind):
    """What the user did: a gradient PNG of the sensor's size through `lfring check` (exit 1) and
    `lfring refocus` (exit 2, nothing written)."""
    import subprocess
    import sys

    frame = tmp_path / "gradient.png"
    cv2.imwrite(str(frame), _gradient(kind)[..., ::-1])
    check = subprocess.run([sys.executable, "-m", "lfring", "check", str(frame)], capture_output=True, text=True,
                           cwd=tmp_path, timeout=300)
    assert check.returncode == 1, check.stdout + check.stderr
    assert "disc contrast" in check.stdout and "NOT a ring frame" in check.stdout and "no discs" in check.stdout
    # The check itself does not send the user to the check; its agreement is the best of a few
    # depths, not a depth it measured.
    assert "lfring check'" not in check.stdout and "pass --no-check to the processing commands" in check.stdout
    assert "the best of 7 depths tried from 0.15 to 2 m" in check.stdout
    refocus = subprocess.run([sys.executable, "-m", "lfring", "refocus", str(frame), "--depth", "0.5",
                              "--method", "shift-and-add"], capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert refocus.returncode == 2 and "no discs" in refocus.stderr and "Traceback" not in refocus.stderr
    assert "check it with 'lfring check', or pass --no-check" in refocus.stderr
    assert not list(tmp_path.glob("gradient_refocus*"))


def test_the_flat_frame_is_recognised_as_a_flat_field(cal):
    res = check_frame(load_raw(DATA / "flat.png"), cal)
    assert res.disc_contrast > 0.8 and res.texture < 0.05
    assert not res.ok and res.flat_field and res.reason == "flat_field" and "flat field" in res.message


@pytest.mark.parametrize("name", ["scene.png", "target_0.3m.png", "part_good.png", "hard.png"])
def test_scenes_have_texture(cal, name):
    from lfring.check import FLAT_TEXTURE

    res = check_frame(load_raw(DATA / name), cal)
    assert res.ok and res.reason == "" and not res.flat_field and res.texture > 2 * FLAT_TEXTURE


# -- exposure ----------------------------------------------------------------------------------


def _exposed(name: str, gain: float, *, about_black: bool = True):
    """A bundled frame as a RawFrame with its light multiplied by ``gain`` (clipped at the white
    level): about the black level, as a longer exposure does; or, with ``about_black`` False, its
    counts multiplied as they are (the black level too: light between the discs as well)."""
    from lfring.io.raw import RawFrame

    frame = load_raw(DATA / name)
    counts = frame.mosaic.astype(np.float64)
    black = frame.black_level if about_black else 0.0
    counts = np.clip((counts - black) * gain + black, 0, frame.white_level).astype(np.uint16)
    return RawFrame(mosaic=counts, pattern=frame.pattern, black_level=frame.black_level, white_level=frame.white_level,
                    bit_depth=frame.bit_depth)


@pytest.mark.parametrize("name", sorted(p.name for p in DATA.glob("*.png")))
def test_bundled_frames_are_not_over_exposed(cal, name):
    """No warning (pytest turns warnings into errors) and no over-exposure verdict: the
    thresholds leave every well-exposed bundled frame, the flat one included, alone."""
    from lfring.check import CLIPPED_WARN

    res = check_frame(load_raw(DATA / name), cal)
    assert res.clipped_fraction < CLIPPED_WARN / 10
    assert res.reason != "over_exposed" and res.warning == "" and "over-exposed" not in res.message


def test_a_somewhat_over_exposed_frame_is_processed_with_a_warning(cal):
    from lfring.check import CLIPPED_REFUSE, CLIPPED_WARN, OverExposureWarning

    with pytest.warns(OverExposureWarning, match=r"over-exposed: .* clipped at the white level.*; reduce the exposure"):
        res = check_frame(_exposed("scene.png", 2), cal)  # a stop over: its bright areas clip
    assert CLIPPED_WARN <= res.clipped_fraction < CLIPPED_REFUSE
    assert res.ok and res.reason == "" and "over-exposed" in res.warning and res.message.endswith(res.warning)


@pytest.mark.parametrize("gain, about_black", [(8, True), (20, False)])
def test_a_mostly_clipped_frame_is_refused_as_over_exposed(cal, gain, about_black):
    """Over-exposure is named, not the causes its clipping imitates: discs without texture (a
    flat field) or, with the black level lifted too, no discs at all (an image that fills the
    sensor)."""
    from lfring.check import CLIPPED_REFUSE, MIN_DISC_CONTRAST

    res = check_frame(_exposed("scene.png", gain, about_black=about_black), cal)
    assert res.clipped_fraction >= CLIPPED_REFUSE
    if not about_black:
        assert res.disc_contrast < MIN_DISC_CONTRAST  # what the verdict blamed before
    assert not res.ok and res.reason == "over_exposed" and not res.flat_field
    assert res.message.startswith("over-exposed: ") and "--no-check" in res.message
    assert "fills the sensor" not in res.message and "flat field" not in res.message


def test_an_over_exposed_flat_frame_is_not_a_flat_field(cal):
    """A flat frame clipped in part is of no use as a flat: refused as over-exposed, from the
    share that only warns about a scene."""
    from lfring.check import CLIPPED_REFUSE, CLIPPED_WARN

    res = check_frame(_exposed("flat.png", 1.25), cal)
    assert CLIPPED_WARN <= res.clipped_fraction < CLIPPED_REFUSE
    assert not res.ok and not res.flat_field and res.reason == "over_exposed" and "over-exposed flat" in res.message


def _write_frame(path: Path, frame) -> Path:
    cv2.imwrite(str(path), frame.mosaic)
    sidecar = {"pattern": frame.pattern, "black_level": frame.black_level, "white_level": frame.white_level,
               "bit_depth": frame.bit_depth}
    Path(f"{path}.json").write_text(__import__("json").dumps(sidecar))
    return path


@pytest.mark.filterwarnings("always::lfring.errors.LfringWarning")
def test_cli_check_and_refocus_name_over_exposure(tmp_path, capsys, monkeypatch):
    """What the user did: an over-exposed copy of the scene through `lfring check` (exit 1,
    over-exposed) and `lfring refocus` (exit 2, nothing written); a less exposed one is
    processed with a warning."""
    from lfring.cli.main import main

    monkeypatch.chdir(tmp_path)
    over = _write_frame(tmp_path / "over.png", _exposed("scene.png", 8))
    assert main(["check", str(over)]) == 1
    out = capsys.readouterr().out
    assert "verdict      NOT a frame to process: over-exposed: " in out and "refused from 40%" in out
    assert "pass --no-check to the processing commands" in out
    assert main(["refocus", str(over), "--depth", "0.5", "--method", "shift-and-add"]) == 2
    err = capsys.readouterr().err
    assert "over.png: over-exposed: " in err and "--no-check" in err and "Traceback" not in err
    assert not list(tmp_path.glob("over_refocus*"))

    bright = _write_frame(tmp_path / "bright.png", _exposed("scene.png", 2))
    assert main(["check", str(bright)]) == 0
    captured = capsys.readouterr()
    assert "verdict      ring frame, over-exposed: " in captured.out and "over-exposed from 5%" in captured.out
    assert "WARNING" not in captured.err  # said once, on the verdict line
    assert main(["refocus", str(bright), "--depth", "0.5", "--method", "shift-and-add"]) == 0
    assert f"WARNING: {bright}: over-exposed: " in capsys.readouterr().err  # named by its frame


def test_cli_check_names_the_sidecar_for_counts_above_its_bit_depth(tmp_path, capsys, monkeypatch):
    """12-bit counts shifted left by 4 bits with the 12-bit sidecar: the error names the sidecar,
    its bit_depth and the options that exist; the scaled --white-level and --black-level it
    suggests read the frame."""
    from lfring.cli.main import main

    monkeypatch.chdir(tmp_path)
    frame = load_raw(DATA / "scene.png")
    path = tmp_path / "scene16.png"
    cv2.imwrite(str(path), (frame.mosaic.astype(np.uint16) << 4))
    (tmp_path / "scene16.png.json").write_text((DATA / "scene.png.json").read_text())
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert 'the 12 bits come from the sidecar scene16.png.json ("bit_depth": 12)' in err
    assert 'set "bit_depth": 16 in scene16.png.json' in err and '"white_level": 65520, "black_level": 1024' in err
    assert "pass --black-level and --white-level scaled by 16 (1024 and 65520 counts)" in err
    assert "bit_depth=" not in err and "white_level/" not in err
    assert main(["check", str(path), "--white-level", "65520", "--black-level", "1024"]) == 0
    out = capsys.readouterr().out
    assert "Bayer RGGB, 16 bits" in out and "black 1024 white 65520" in out and "verdict      ring frame:" in out


def test_a_threshold_no_zncc_reaches_is_refused(cal):
    """threshold=2 was taken, and every frame then failed with 'a ring frame scores above 2'."""
    views = np.full((4, *cal.layout.view_shape, 3), 0.5, np.float32)
    for bad in (2.0, -1.5, float("nan")):
        with pytest.raises(InvalidInputError, match="threshold must be a ZNCC >= -1 and <= 1"):
            check_frame(views, cal, threshold=bad)


def test_draw_layout_of_a_turned_layout_draws_on_the_turned_frame(cal):
    """A layout that turns the frame by 180 degrees has its rectangles in the turned frame: the
    overlay is drawn there (it drew them on the frame as read, off the discs of light), so each
    rectangle holds the pixels its view is cut from."""
    import dataclasses

    from lfring.views import split_views

    turned = dataclasses.replace(cal.layout, rotate180=True)
    frame = np.zeros((1842, 2456, 3), np.float32)
    x, y, w, h = turned.rects[0]
    frame[-1 - (y + h // 2), -1 - (x + w // 2)] = 1.0  # the centre of view 0 as the frame is read
    assert split_views(frame, turned)[0][h // 2, w // 2].max() == 1.0
    out = draw_layout(frame, turned)
    assert tuple(out[y + h // 2, x + w // 2]) == (255, 255, 255)
    assert tuple(out[y, x + 5]) == (255, 220, 0)


@pytest.mark.parametrize("exposure, dim", [(1.0, False), (0.05, True)])
def test_a_dim_frame_passes_with_an_under_exposure_warning(prototype, exposure, dim):
    """A target at 0.7 m exposed at 5 %: its depth read 0.725 m with confidence 0.82 and not a
    word. The check passes it and says it is under-exposed (its discs' 99th percentile under
    DIM_LEVEL), as a warning that the CLI gives with the frame's name."""
    import warnings

    from lfring.check import DIM_LEVEL, UnderExposureWarning
    from lfring.io.raw import RawFrame
    from lfring.synth import render
    from lfring.synth.presets import target_scene

    r = render(prototype, target_scene(prototype, 0.7, seed=2), binning=2, noise="realistic", seed=2, exposure=exposure)
    frame = RawFrame(mosaic=r.raw, pattern="RGGB", black_level=r.black_level, white_level=r.white_level, bit_depth=12)
    cal = default_calibration((2456, 1842))[0]
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        res = check_frame(demosaic(frame), cal)
    said = [w for w in seen if issubclass(w.category, UnderExposureWarning)]
    assert res.ok and bool(said) == dim and (res.warning.startswith("under-exposed") if dim else res.warning == "")
    if dim:
        assert f"(under-exposed below {DIM_LEVEL:.0%})" in str(said[0].message) and "reads too far" in res.message


def test_bad_frames_and_options_are_refused_by_name(cal, scene_views):
    """A NaN in the frame was judged "no discs, an image" (in the views: a pass, with NumPy's
    warnings), three views broke a broadcast, a downsampling past the views' size broke OpenCV's
    resize, a path was named by its dtype: each is now refused, saying what to give."""
    frame = demosaic(load_raw(DATA / "scene.png"))
    frame[100, 100, 0] = np.nan
    with pytest.raises(InvalidInputError, match="NaN or infinite"):
        check_frame(frame, cal)
    views = scene_views.copy()
    views[2, 300, 300, 1] = np.inf
    with pytest.raises(InvalidInputError, match="NaN or infinite"):
        check_frame(views, cal)
    with pytest.raises(InvalidInputError, match=r"the calibration is for 4 views .* the views are 3 of 705 x 705 px"):
        check_frame(scene_views[:3], cal)
    most = 705 // CHECK_MIN_SIDE_PX
    with pytest.raises(InvalidInputError, match=rf"downsample must be an integer >= 1 and <= {most}, got 1000"):
        check_frame(scene_views, cal, downsample=1000)
    assert check_frame(scene_views, cal, downsample=most).size_px == cal.raw_size
    with pytest.raises(InvalidInputError, match=r"not a path: lfring.load_raw\("):
        check_frame(str(DATA / "scene.png"), cal)


def test_small_views_are_checked_at_a_smaller_default_downsampling():
    """The cap on downsample (views kept at CHECK_MIN_SIDE_PX a side) refused views under 64 px
    at the default factor, which the user never gave: the default is the cap there."""
    from lfring.calibration import RingCalibration
    from lfring.check import CHECK_DOWNSAMPLE

    cal = RingCalibration.from_grid((40, 40), [(0, 0), (1, 0), (0, 1), (1, 1)], disparity_scale_px_m=20.0)
    views = np.random.default_rng(0).random((4, 40, 40, 3), dtype=np.float32)
    assert 40 // CHECK_MIN_SIDE_PX < CHECK_DOWNSAMPLE
    res = check_frame(views, cal)  # no refusal: checked at the factor that keeps 16 px
    assert np.isfinite(res.agreement)
    with pytest.raises(InvalidInputError, match="downsample must be an integer >= 1 and <= 2, got 4"):
        check_frame(views, cal, downsample=4)
