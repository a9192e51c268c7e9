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
