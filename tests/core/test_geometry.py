"""Homography helpers: normalising, changing the reference frame, applying, comparing."""

import numpy as np
import pytest

from lfring.core.geometry import (
    apply_homography,
    check_reference,
    homography_rms_px,
    normalize_homographies,
    to_reference,
)
from lfring.errors import InvalidInputError


def _shift(tx, ty):
    return np.array([[1.0, 0, tx], [0, 1, ty], [0, 0, 1]])


def test_the_centre_frame_of_translations_is_each_translation_minus_their_mean():
    hs = np.stack([_shift(10, 0), _shift(-2, 4), _shift(0, -8), _shift(4, 0)])
    got = to_reference(hs, "center")
    mean = np.array([3.0, -1.0])
    for k in range(4):
        np.testing.assert_allclose(got[k][:2, 2], hs[k][:2, 2] - mean, atol=1e-12)
    np.testing.assert_allclose(to_reference(hs, 1)[1], np.eye(3), atol=1e-12)
    np.testing.assert_allclose(to_reference(hs, 1)[0][:2, 2], [12.0, -4.0], atol=1e-12)


def test_normalise_apply_and_compare():
    h = normalize_homographies(2.0 * _shift(3, -1))
    assert h[2, 2] == 1.0
    np.testing.assert_allclose(apply_homography(h, np.array([[1.0, 2.0]])), [[4.0, 1.0]])
    assert homography_rms_px(_shift(0.3, 0.4), np.eye(3), (5, 7)) == pytest.approx(0.5)
    with pytest.raises(InvalidInputError, match="mask selects no pixel"):
        homography_rms_px(np.eye(3), np.eye(3), (2, 2), mask=np.zeros((2, 2), bool))


def test_reference_names():
    assert check_reference("center", 4) == "center" and check_reference("2", 4) == 2
    for bad in ("centre", 4, -1, True, 1.0):
        with pytest.raises(InvalidInputError, match="reference must be 'center' or a view index 0..3"):
            check_reference(bad, 4)
