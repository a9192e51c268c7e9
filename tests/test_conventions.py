"""Each item of the README's conventions section, pinned with non-square, asymmetric data."""

import numpy as np
import pytest

from lfring.core.geometry import to_reference
from lfring.optics import paraxial
from lfring.optics.views import optical_homographies, optical_layout
from lfring.views import Layout, split_views


def test_pixel_centres_and_sensor_axes(prototype):
    dev = prototype.binned(4)  # 1228 x 921 px: non-square, odd height
    w, h = dev.sensor_width_px, dev.sensor_height_px
    # The optical axis is at the centre of the frame: between pixels for even counts.
    np.testing.assert_allclose(paraxial.sensor_to_pixel(dev, [0.0, 0.0]), [(w - 1) / 2, (h - 1) / 2])
    # x right -> column grows, y down -> row grows; pixel (0, 0) centre is half a pitch in.
    np.testing.assert_allclose(
        paraxial.pixel_to_sensor(dev, [0, 0]), [-(w / 2 - 0.5) * dev.pixel_pitch_m, -(h / 2 - 0.5) * dev.pixel_pitch_m]
    )


def test_view_order_and_erect_image(prototype):
    dev = prototype.binned(4)
    # A point up and to the left of the axis: every view sees it up-left of the axis point.
    p_ul = paraxial.project_points_m(dev, np.array([-0.01, -0.01, 0.5]))
    p_0 = paraxial.project_points_m(dev, np.array([0.0, 0.0, 0.5]))
    assert np.all(p_ul < p_0)
    # View 0 is top-left, 1 top-right, 2 bottom-left, 3 bottom-right.
    x, y = p_0[:, 0], p_0[:, 1]
    assert x[0] < x[1] and x[2] < x[3] and y[0] < y[2] and y[1] < y[3]


def test_split_views_axes_and_rotation():
    # 6 x 10 frame (h, w), two views of 3 x 4 (h, w): values (in [0, 1], as images are) encode (row, col).
    frame = np.arange(60, dtype=np.float32).reshape(6, 10) / np.float32(64)
    lay = Layout(raw_width_px=10, raw_height_px=6, rects=((0, 0, 4, 3), (5, 2, 4, 3)))
    v = split_views(frame, lay)
    assert v.shape == (2, 3, 4, 1) and v.dtype == np.float32
    assert v[1, 0, 0, 0] == frame[2, 5]
    rot = Layout(raw_width_px=10, raw_height_px=6, rects=lay.rects, rotate180=True)
    np.testing.assert_array_equal(split_views(frame[::-1, ::-1], rot), v)
    with pytest.raises(ValueError, match="floating"):
        split_views(frame.astype(np.uint16), lay)
    with pytest.raises(ValueError, match="10 x 6 px"):
        split_views(frame[:, :8], lay)


def test_homography_direction_and_center(prototype):
    dev = prototype.binned(4)
    lay = optical_layout(dev)
    z = 0.45
    h0 = optical_homographies(dev, lay, z, reference=0)
    # H_0_from_k maps the pixel of a world point in view k onto its pixel in view 0.
    world = np.array([0.004, -0.006, z])
    pix = paraxial.sensor_to_pixel(dev, paraxial.project_points_m(dev, world)) - np.array([r[:2] for r in lay.rects])
    for k in range(4):
        mapped = h0[k] @ np.array([*pix[k], 1.0])
        np.testing.assert_allclose(mapped[:2] / mapped[2], pix[0], atol=1e-9)
    # Composition: H_2_from_k = H_2_from_0 @ H_0_from_k, and the center is the mean viewpoint.
    h2 = optical_homographies(dev, lay, z, reference=2)
    np.testing.assert_allclose(h2, to_reference(h0, 2), atol=1e-9)
    hc = optical_homographies(dev, lay, z, reference="center")
    np.testing.assert_allclose(hc[:, :2, 2].mean(axis=0), 0.0, atol=1e-9)
    np.testing.assert_allclose(hc[:, 2, 2], 1.0)
