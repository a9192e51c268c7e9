"""Design numbers of SPEC 2.1 for the paper prototype, and properties of the paraxial model."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lfring.errors import DesignError, InvalidInputError
from lfring.optics import design, design_working_range, evaluate, sweep
from lfring.optics import paraxial


def sig3(x):
    return float(f"{x:.3g}")


def test_fit_sensor_prototype_numbers(prototype):
    d = design(prototype, object_size_m=0.1, distance_m=0.3, method="fit-sensor")
    # SPEC 2.1 item 2-4: b = 37.37 mm, c = 6.616 mm, G = 0.0182, Ia = 0.79 hs/2, d = 383.1 px,
    # o = 0.737, B = 37.61 mm, s = 28.0 mm.
    assert d.ring_distance_m == pytest.approx(37.37e-3, abs=0.005e-3)
    assert d.sensor_distance_m == pytest.approx(6.616e-3, abs=0.0005e-3)
    assert sig3(d.magnification) == 0.0182
    assert d.image_height_m / (prototype.sensor_height_m / 2) == pytest.approx(0.79, abs=0.005)
    assert d.disparity_px == pytest.approx(383.1, abs=0.05)
    assert d.overlap == pytest.approx(0.737, abs=0.0005)
    assert d.mount_distance_m == pytest.approx(37.61e-3, abs=0.005e-3)
    assert d.entrance_pupil_m == pytest.approx(28.0e-3, abs=0.05e-3)
    assert d.upper_image_top_m == pytest.approx(prototype.sensor_height_m / 2, abs=1e-12)
    assert d.valid


def test_max_magnification_prototype_numbers(prototype):
    d = design(prototype, object_size_m=0.1, distance_m=0.3, method="max-magnification")
    assert d.ring_distance_m == pytest.approx(34.15e-3, abs=0.005e-3)
    assert d.sensor_distance_m == pytest.approx(7.04e-3, abs=0.005e-3)
    assert d.magnification == pytest.approx(prototype.sensor_height_m / (4 * 0.05))
    # The paper's reason for Sec. 4.2: the image is as tall as half the sensor but runs past its edge.
    assert not d.valid
    assert any("past the sensor edge" in p for p in d.problems)


def test_disparity_over_distance_fixed_positions(prototype):
    sw = sweep(prototype, object_size_m=0.1, distances_m=[0.1, 0.3, 0.5, 1.0, 6.0], fixed=True)
    np.testing.assert_allclose(sw.disparity_px, [446.7, 383.1, 373.4, 366.6, 361.2], atol=0.05)
    # Invalid points are kept and explained, never dropped.
    assert sw.valid.tolist() == [False, True, True, True, False]
    assert "taller than half the sensor" in sw.problems[0][0]
    assert "no overlap" in sw.problems[4][0]


def test_evaluate_matches_design_at_design_point(prototype):
    a = design(prototype, object_size_m=0.1, distance_m=0.3)
    b = evaluate(prototype, object_size_m=0.1, distance_m=0.3)
    assert b.disparity_px == pytest.approx(a.disparity_px, rel=1e-12)
    assert b.blur_px == pytest.approx(0.0, abs=1e-9)
    # SPEC 2.3: a plane at 1.0 m is blurred by about 16 px on the prototype.
    assert evaluate(prototype, object_size_m=0.1, distance_m=1.0).blur_px == pytest.approx(15.7, abs=0.1)


def test_sweep_redesign_matches_pointwise(prototype):
    zs = np.linspace(0.2, 1.5, 7)
    sw = sweep(prototype, object_size_m=0.1, distances_m=zs, method="fit-sensor")
    for i, z in enumerate(zs):
        d = design(prototype, object_size_m=0.1, distance_m=z)
        assert sw.ring_distance_m[i] == pytest.approx(d.ring_distance_m, rel=1e-12)
        assert sw.overlap[i] == pytest.approx(d.overlap, rel=1e-12)
        assert sw.valid[i] == d.valid


def test_working_range(prototype):
    wr = design_working_range(prototype, object_size_m=0.1, near_m=0.3, far_m=1.0, num=30)
    sw = wr.sweep
    # Fitted at the near end: the image top is at the sensor edge there.
    near = evaluate(prototype.with_positions(wr.ring_distance_m, wr.sensor_distance_m), object_size_m=0.1, distance_m=0.3)
    assert near.upper_image_top_m == pytest.approx(prototype.sensor_height_m / 2, rel=1e-9)
    # Blur balanced at both ends, and smaller inside.
    assert sw.blur_px[0] == pytest.approx(sw.blur_px[-1], rel=1e-6)
    assert np.all(sw.blur_px[1:-1] < sw.blur_px[0])
    assert 0.3 < wr.focus_distance_m < 1.0
    assert sw.valid.all() and not wr.problems
    # Depth resolution grows with distance (roughly as Z^2).
    assert np.all(np.diff(sw.depth_resolution_m_per_px) > 0)
    with pytest.raises(InvalidInputError, match="far distance"):
        design_working_range(prototype, object_size_m=0.1, near_m=1.0, far_m=0.3)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(object_size_m=-0.1, distance_m=0.3), "object size"),
        (dict(object_size_m=0.1, distance_m=0.01), "inside the main lens focal length"),
        (dict(object_size_m=0.1, distance_m=float("nan")), "distance"),
        (dict(object_size_m=0.1, distance_m=0.3, method="best"), "fit-sensor, max-magnification"),
    ],
)
def test_bad_inputs(prototype, kwargs, match):
    with pytest.raises(InvalidInputError, match=match):
        design(prototype, **kwargs)


def test_object_too_large_is_reported(prototype):
    # A 2 m object at 0.3 m: the fit-sensor design exists but the mini-lens cannot form the image.
    d = design(prototype, object_size_m=2.0, distance_m=0.3)
    assert not d.valid


def test_fit_sensor_impossible(prototype):
    from dataclasses import replace

    dev = replace(prototype, mini_lens_offset_m=2.4e-3, mini_lens_radius_m=1e-3)
    with pytest.raises(DesignError, match="half the sensor height"):
        design(dev, object_size_m=0.1, distance_m=0.3)


# --- properties -----------------------------------------------------------------------------
sizes = st.floats(0.01, 0.5)
dists = st.floats(0.05, 5.0)


@settings(max_examples=60, deadline=None)
@given(size=sizes, z=dists, method=st.sampled_from(["fit-sensor", "max-magnification"]))
def test_thin_lens_identities(prototype, size, z, method):
    d = design(prototype, object_size_m=size, distance_m=z, method=method)
    fl, fml = prototype.main_focal_length_m, prototype.mini_focal_length_m
    # 1/Z + 1/b1 = 1/FL and 1/b2 + 1/c = 1/Fml (the designed plane is sharp).
    assert 1 / z + 1 / d.intermediate_distance_m == pytest.approx(1 / fl, rel=1e-9)
    assert 1 / d.mini_object_distance_m + 1 / d.sensor_distance_m == pytest.approx(1 / fml, rel=1e-9)
    assert d.ring_distance_m == pytest.approx(d.intermediate_distance_m + d.mini_object_distance_m, rel=1e-12)
    assert d.magnification * size == pytest.approx(d.image_height_m, rel=1e-12)
    if method == "fit-sensor":
        assert d.upper_image_top_m == pytest.approx(prototype.sensor_height_m / 2, rel=1e-9)
    else:
        assert d.image_height_m == pytest.approx(prototype.sensor_height_m / 2, rel=1e-9)


@settings(max_examples=40, deadline=None)
@given(size=sizes, z=st.floats(0.1, 2.0))
def test_disparity_affine_in_inverse_depth(prototype, size, z):
    d = design(prototype, object_size_m=size, distance_m=z)
    dev = prototype.with_positions(d.ring_distance_m, d.sensor_distance_m)
    s = dev.entrance_pupil_m
    zs = np.array([0.07, 0.2, 0.6, 3.0, 40.0])
    disp = paraxial.disparity_px(dev, zs)
    x = 1.0 / (zs - s)
    coef = np.polyfit(x, disp, 1)
    np.testing.assert_allclose(np.polyval(coef, x), disp, rtol=0, atol=1e-7 * np.abs(disp).max())
