"""lfring.check_frame: ring frames of the twin pass, photographs do not; the numbers in
lfring.check.AGREEMENT_THRESHOLD's docstring."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from lfring import check_frame, demosaic, load_raw, split_views
from lfring.calibration.defaults import default_calibration
from lfring.check import AGREEMENT_THRESHOLD, draw_layout
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
