"""Luminance, the luminance normalised by its local mean, and the box filter with its torch twin."""

import cv2
import numpy as np
import pytest

from lfring.core.filters import (
    box_filter,
    local_mean_sigma_px,
    luminance,
    normalised_luminance,
)


@pytest.mark.parametrize("shape, k", [((37, 53), 9), ((53, 37), 5), ((20, 30), 1), ((4, 9), 3)])
def test_box_filter_is_opencvs(shape, k):
    x = np.random.default_rng(3).random(shape).astype(np.float32)
    np.testing.assert_allclose(box_filter(x, k), cv2.boxFilter(x, -1, (k, k)), atol=1e-6)


def test_luminance_is_the_mean_of_the_channels():
    v = np.random.default_rng(1).random((2, 4, 5, 3)).astype(np.float32)
    np.testing.assert_allclose(luminance(v), v.mean(axis=3), atol=1e-6)
    assert luminance(v[..., :1]).shape == (2, 4, 5)
    # Other types and strided channels: float32 means all the same.
    for other in (v.astype(np.float64), (v * 60000).astype(np.uint16), np.concatenate([v, v], axis=3)[..., 1:4]):
        got = luminance(other)
        assert got.dtype == np.float32
        np.testing.assert_allclose(got, other.astype(np.float64).mean(axis=3), rtol=1e-6, atol=1e-6)
    # The views shared among threads: the same numbers.
    many = np.random.default_rng(2).random((5, 31, 47, 3)).astype(np.float32)
    np.testing.assert_array_equal(luminance(many, threads=3), luminance(many))


def test_normalised_luminance_removes_each_views_vignetting_and_exposure():
    """Two views of one texture, one under a smooth vignette and at half exposure: divided by
    their local means they agree to within a few percent away from the border."""
    rng = np.random.default_rng(2)
    h, w = 160, 200
    texture = 0.5 + 0.3 * cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 1.5)
    yy, xx = np.mgrid[0:h, 0:w]
    vignette = (1.0 - 0.5 * ((xx - w / 2) ** 2 + (yy - h / 2) ** 2) / (w * w / 4)).astype(np.float32)
    views = np.stack([texture, 0.5 * texture * vignette])[..., None]
    masks = np.ones((2, h, w), np.float32)
    n = normalised_luminance(views, masks)
    inner = (slice(20, -20), slice(20, -20))
    assert np.median(np.abs(n[0][inner] - n[1][inner])) < 0.02
    assert abs(np.median(views[1][..., 0][inner] / views[0][..., 0][inner]) - 0.5) > 0.05  # they differed before
    assert local_mean_sigma_px((160, 200)) == 8.0 and local_mean_sigma_px((800, 1000)) == 20.0


def test_box_filter_torch_twin(device):
    torch = pytest.importorskip("torch")
    from lfring.core.filters import BoxTorch

    x = np.random.default_rng(4).random((21, 34)).astype(np.float32)
    got = BoxTorch(torch, x.shape, 7, 1, device)(torch.from_numpy(x)[None, None].to(device))[0, 0].cpu().numpy()
    np.testing.assert_allclose(got, cv2.boxFilter(x, -1, (7, 7)), atol=1e-6)
