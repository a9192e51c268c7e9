"""Where the views overlap, and the sign of the ring's disparity."""

import json

import numpy as np
import pytest

from lfring.calibration import RingCalibration, VariableHomography
from lfring.calibration.fit import check_disparity_sign
from lfring.calibration.overlap import MIN_OVERLAP_FRACTION, disparity_spread_px, nearest_overlap_depth_m, overlap_fraction
from lfring.errors import InvalidInputError
from lfring.views import Layout


def _translation_cal(shift_m_px: float, z0: float = 0.03, size: int = 400) -> RingCalibration:
    """Four views whose translations are +-shift/(Z - z0) px in x and y (the ring's geometry)."""
    signs = [(-1, -1), (1, -1), (-1, 1), (1, 1)]
    a = np.repeat(np.eye(3)[None], 4, axis=0)
    b = np.zeros((4, 3, 3))
    for k, (sx, sy) in enumerate(signs):
        b[k, 0, 2], b[k, 1, 2] = sx * shift_m_px, sy * shift_m_px
    rects = ((0, 0, size, size), (size, 0, size, size), (0, size, size, size), (size, size, size, size))
    layout = Layout(raw_width_px=2 * size, raw_height_px=2 * size, rects=rects)
    return RingCalibration(model=VariableHomography(a, b, z0, 0), layout=layout, valid_depth_range_m=(0.3, 1.0))


def test_nearest_overlap_matches_construction():
    cal = _translation_cal(2.0)
    # 'center': view k moves by +-t in x and y, so all four share (size - 2t)^2 of the frame.
    t_star = 400 * (1 - np.sqrt(MIN_OVERLAP_FRACTION)) / 2
    z_star = 0.03 + 2.0 / t_star
    assert nearest_overlap_depth_m(cal) == pytest.approx(z_star, rel=0.05)
    assert overlap_fraction(cal, 0.031) == 0.0
    assert overlap_fraction(cal, float("inf")) == 1.0
    assert overlap_fraction(cal, 0.5) == pytest.approx((1 - 2 * 2.0 / 0.47 / 400) ** 2, abs=0.05)
    assert cal.overlap_depth_range() == (nearest_overlap_depth_m(cal), float("inf"))


def test_overlap_refuses_depths_before_origin():
    with pytest.raises(InvalidInputError, match="depth origin"):
        overlap_fraction(_translation_cal(2.0), 0.02)


def test_disparity_sign_names_the_swap():
    cal = _translation_cal(2.0)
    near, far = cal.model(0.3), cal.model(1.0)
    assert disparity_spread_px(near, (400, 400)) > disparity_spread_px(far, (400, 400))
    check_disparity_sign({0.3: near, 1.0: far}, {0.3: "near.png", 1.0: "far.png"}, (400, 400))
    with pytest.raises(InvalidInputError, match=r"given as 0.3 m \(far.png\).*look swapped"):
        check_disparity_sign({0.3: far, 1.0: near}, {0.3: "far.png", 1.0: "near.png"}, (400, 400))


def test_calibration_json_keeps_device_and_levels(tmp_path):
    import dataclasses

    cal = dataclasses.replace(_translation_cal(2.0), device="prototype", pattern="GRBG", black_level=(64.0, 60.0, 60.0, 64.0),
                              white_level=1023.0)
    path = cal.save(tmp_path / "c.json")
    back = RingCalibration.load(path)
    assert (back.device, back.pattern, back.black_level, back.white_level) == ("prototype", "GRBG", (64.0, 60.0, 60.0, 64.0), 1023.0)
    # Files written before these keys load as before.
    data = json.loads(path.read_text())
    del data["black_level"], data["white_level"]
    old = RingCalibration.from_dict(data)
    assert old.black_level is None and old.white_level is None
