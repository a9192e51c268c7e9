"""Surfaces as layers: the depth ground truth of planes (occlusion, slant) and height fields, and
the refusal of surfaces that interleave in depth."""

import numpy as np
import pytest

from lfring.errors import InvalidInputError
from lfring.optics import paraxial
from lfring.optics.views import view_cameras
from lfring.synth import Bump, HeightField, Plane, Scene, Texture, render

BIN = 4  # 1228 x 921 px, 5 um: fast, and every geometric relation is independent of binning


def test_ground_truth_depth_occlusion_and_slant(prototype):
    front = Plane(0.35, (0.03, 0.03), Texture("image", name="coffee"), center_m=(0.0, 0.0))
    slant = Plane(0.7, (0.4, 0.3), Texture("speckle", feature_m=0.004), center_m=(0.0, 0.0), tilt_deg=(35.0, 10.0))
    r = render(prototype, Scene((front, slant)), binning=BIN, pattern=None)
    dev, cams = r.device, view_cameras(r.device)
    depth = r.depth_m
    assert np.isclose(np.nanmin(depth), 0.35, atol=1e-6)
    p0, _, _, n = slant.axes()
    for k, (x, y, w, h) in enumerate(r.layout.rects):
        yy, xx = np.indices((h, w))
        far = np.isfinite(depth[k]) & (depth[k] > 0.36)
        sensor = paraxial.pixel_to_sensor(dev, np.stack([xx + x, yy + y], -1))
        o, d = cams.rays_m(k, sensor)
        pts = o + d * (depth[k][..., None] - cams.depth_origin_m)
        dist = (pts[far] - p0) @ n
        assert np.abs(dist).max() < 1e-6
        # The centre of every view sees the front plane, which occludes the slanted one.
        centre = paraxial.sensor_to_pixel(dev, cams.project_m(np.array([0.0, 0.0, 0.35]))[k]) - [x, y]
        assert depth[k][int(round(centre[1])), int(round(centre[0]))] == pytest.approx(0.35, abs=1e-6)


def test_height_field_depth(prototype):
    bumps = (
        Bump(center_m=(0.03, 0.03), size_m=(0.02, 0.02), height_m=0.005, shape="box"),
        Bump(center_m=(0.07, 0.05), size_m=(0.02, 0.02), height_m=-0.004, shape="box"),
    )
    part = HeightField(0.5, (0.1, 0.08), Texture("speckle", feature_m=0.002), center_m=(0.0, 0.0), bumps=bumps)
    r = render(prototype, Scene((part,)), binning=BIN, pattern=None)
    dev, cams = r.device, view_cameras(r.device)
    for (bx, by), hgt in (((0.03, 0.03), 0.005), ((0.07, 0.05), -0.004)):
        world = np.array([-0.05 + bx, -0.04 + by, 0.5 - hgt])
        for k, (x, y, w, h) in enumerate(r.layout.rects):
            c = paraxial.sensor_to_pixel(dev, cams.project_m(world)[k]) - [x, y]
            patch = r.depth_m[k][int(c[1]) - 2 : int(c[1]) + 3, int(c[0]) - 2 : int(c[0]) + 3]
            np.testing.assert_allclose(patch, 0.5 - hgt, atol=2e-5)
    base = r.depth_m[np.isfinite(r.depth_m)]
    assert np.isclose(np.median(base), 0.5, atol=1e-6)


def test_interleaved_surfaces_are_refused(prototype):
    # A floor rising from 0.45 m to 0.75 m behind a card at 0.5 m that it crosses in the image.
    floor = Plane(0.6, (0.3, 0.3), Texture("speckle"), center_m=(0.0, 0.0), tilt_deg=(60.0, 0.0), name="floor")
    card = Plane(0.5, (0.05, 0.2), Texture("checker"), center_m=(0.0, 0.0), name="card")
    with pytest.raises(InvalidInputError, match="'floor' and 'card' interleave"):
        render(prototype, Scene((floor, card)), binning=8)
