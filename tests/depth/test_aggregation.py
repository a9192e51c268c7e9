"""Spatial aggregation of cost slices: shiftable windows and the seen-pixel box mean."""


import cv2
import numpy as np
import pytest

from lfring.errors import InvalidInputError


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
