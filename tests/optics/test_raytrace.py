"""The 2D ray tracer agrees with the paraxial model of SPEC 2 (2.2, 2.3)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lfring.errors import DeviceError, InvalidInputError
from lfring.optics import design, load_device
from lfring.optics.paraxial import blur_diameter_m
from lfring.optics.raytrace import (
    LOWER,
    MISSED_RING,
    STOPPED_MAIN,
    UPPER,
    bundle_stats,
    convergence_spread_m,
    mean_hit_height_m,
    paraxial_hit_height_m,
    trace,
)

UM = 1e-6


def _h2(device, h0, z):
    """H2,a and H2,b of SPEC 2.1 item 2 for the object point at +h0, written out by hand."""
    fl, hml = device.main_focal_length_m, device.mini_lens_offset_m
    b, c = device.require_positions()
    b1 = z * fl / (z - fl)
    b2 = b - b1
    h1 = b1 * h0 / z
    return hml + c * (hml + h1) / b2, -hml + c * (-hml + h1) / b2


def _designed(device, size, z, method="fit-sensor"):
    d = design(device, object_size_m=size, distance_m=z, method=method)
    return device.with_positions(d.ring_distance_m, d.sensor_distance_m)


def test_prototype_bundles_converge_at_design_c(prototype):
    rt = trace(prototype, object_size_m=0.1, distance_m=0.3)
    st = bundle_stats(rt)
    np.testing.assert_allclose(rt.source_heights_m, [-0.05, -0.025, 0.0, 0.025, 0.05])
    # Every source point is imaged through both mini-lenses, each bundle by several rays.
    assert np.all(st.count >= 7)
    assert np.all(st.spread_m < 1 * UM)
    h2a, h2b = _h2(prototype, 0.05, 0.3)
    assert abs(st.mean_height_m[-1, UPPER] - h2a) < 1 * UM
    assert abs(st.mean_height_m[-1, LOWER] - h2b) < 1 * UM
    # The fit-sensor design puts the top of the upper image on the sensor edge, hs/2 = 2.3 mm.
    assert abs(st.mean_height_m[-1, UPPER] - prototype.sensor_height_m / 2) < 1 * UM
    assert st.mean_height_m[-1, LOWER] == pytest.approx(-0.4788e-3, abs=0.1 * UM)
    # Each ray, not only the bundle mean, lands on the paraxial image of its source.
    hit = rt.lens >= 0
    expected = st.paraxial_height_m[rt.source_index[hit], rt.lens[hit]]
    assert np.max(np.abs(rt.sensor_y_m[hit] - expected)) < 1 * UM
    # The two views of the symmetric object are mirror images.
    np.testing.assert_allclose(st.mean_height_m[::-1, LOWER], -st.mean_height_m[:, UPPER], atol=1e-12)


@pytest.mark.parametrize(
    ("size", "z", "method"),
    [(0.05, 0.5, "fit-sensor"), (0.2, 1.0, "fit-sensor"), (0.1, 0.3, "max-magnification")],
)
def test_other_designs_converge_to_h2(prototype, size, z, method):
    dev = _designed(prototype, size, z, method)
    rt = trace(dev, object_size_m=size, distance_m=z, num_points=7)
    st = bundle_stats(rt)
    assert np.all(st.count > 0)
    assert np.nanmax(st.spread_m) < 1 * UM
    h2a, h2b = _h2(dev, size / 2, z)
    assert abs(st.mean_height_m[-1, UPPER] - h2a) < 1 * UM
    assert abs(st.mean_height_m[-1, LOWER] - h2b) < 1 * UM
    # The tracer's paraxial helper is the same formula.
    assert paraxial_hit_height_m(rt)[-1] == pytest.approx([h2a, h2b], abs=1e-12)
    np.testing.assert_allclose(convergence_spread_m(rt), st.spread_m)
    np.testing.assert_allclose(mean_hit_height_m(rt), st.mean_height_m)


def test_max_magnification_overfills_the_sensor(prototype):
    # Paper Sec. 4.1 / Fig. 5: with b = 34.15 mm, c = 7.04 mm the images run past the sensor edge.
    dev = _designed(prototype, 0.1, 0.3, "max-magnification")
    st = bundle_stats(trace(dev, object_size_m=0.1, distance_m=0.3))
    assert st.mean_height_m[-1, UPPER] > prototype.sensor_height_m / 2 + 100 * UM


def test_defocus_spread_is_the_blur_circle(prototype):
    b, c = prototype.require_positions()
    defocused = prototype.with_positions(b, 1.05 * c)
    rt = trace(defocused, object_size_m=0.1, distance_m=0.3, num_points=1, rays_per_point=0, rays_per_lens=41)
    st = bundle_stats(rt)
    # SPEC 2.3 with c' = c (the design is in focus at 0.3 m): 2 Rml * 0.05 = 100 um.
    blur = 2 * prototype.mini_lens_radius_m * 0.05
    assert float(blur_diameter_m(defocused, 0.3)) == pytest.approx(blur, rel=1e-9)
    # The on-axis bundle fills each mini-lens (its cone at the ring is ~+-6 mm wide even through
    # the 5 mm iris), so rim rays pass and the spread is the full blur diameter.
    for k, m in ((UPPER, prototype.mini_lens_offset_m), (LOWER, -prototype.mini_lens_offset_m)):
        ring = rt.y_m[rt.lens == k, 2]
        assert ring.min() == pytest.approx(m - prototype.mini_lens_radius_m, abs=1e-12)
        assert ring.max() == pytest.approx(m + prototype.mini_lens_radius_m, abs=1e-12)
    np.testing.assert_allclose(st.spread_m, blur, rtol=1e-6)
    assert np.all(st.spread_m > 50 * UM)
    # The blur is centred on the chief ray: the paraxial image height at the new c.
    np.testing.assert_allclose(st.mean_height_m, st.paraxial_height_m, atol=1e-12)


def test_defocus_even_fan_undersamples_the_blur(prototype):
    # With only the even fan over the main lens, the rays through a mini-lens do not reach its
    # rims, so the measured spread is a little below the blur diameter, never above.
    b, c = prototype.require_positions()
    defocused = prototype.with_positions(b, 1.05 * c)
    rt = trace(defocused, object_size_m=0.1, distance_m=0.3, num_points=1, rays_per_point=2001, rays_per_lens=0)
    spread = convergence_spread_m(rt)
    blur = 2 * prototype.mini_lens_radius_m * 0.05
    assert np.all(spread < blur)
    assert np.all(spread > 0.95 * blur)


def test_iris_vignettes_off_axis_points(prototype):
    # Through the 5 mm iris the top object point cannot reach the upper mini-lens at all
    # (vignetting), and neither can the bottom one reach the lower mini-lens.
    rt = trace(prototype, object_size_m=0.1, distance_m=0.3, aperture="iris")
    st = bundle_stats(rt)
    assert rt.stop_radius_m == prototype.effective_aperture_radius_m == 0.005
    assert st.count[-1, UPPER] == 0 and st.count[0, LOWER] == 0
    assert np.isnan(st.spread_m[-1, UPPER]) and np.isnan(st.mean_height_m[-1, UPPER])
    assert np.all(st.count[1:-1] > 0)
    # The 7 rays of the top point aimed at lens a (after its 21 fan rays) are stopped at the iris.
    aimed_a = np.flatnonzero(rt.source_index == 4)[21:28]
    assert np.all(rt.aimed[aimed_a]) and np.all(rt.lens[aimed_a] == STOPPED_MAIN)
    assert np.all(np.abs(rt.y_m[aimed_a, 1]) > 0.005)


def test_ray_classification_by_hand(prototype):
    b, _ = prototype.require_positions()
    rl = prototype.main_lens_radius_m
    # On-axis source, rays at main-lens heights -2RL, -RL, 0, RL, 2RL.
    rt = trace(prototype, object_size_m=0.1, distance_m=0.3, num_points=1, rays_per_point=5,
               rays_per_lens=0, fan_radius_m=2 * rl)
    np.testing.assert_allclose(rt.y_m[:, 1], [-2 * rl, -rl, 0.0, rl, 2 * rl])
    # The outer two are stopped at the rim: drawn up to the lens, NaN beyond, no sensor hit.
    assert rt.lens.tolist() == [STOPPED_MAIN, MISSED_RING, MISSED_RING, MISSED_RING, STOPPED_MAIN]
    assert np.all(np.isnan(rt.y_m[[0, 4], 2:])) and np.all(np.isnan(rt.z_m[[0, 4], 2:]))
    assert np.all(np.isfinite(rt.y_m[[0, 4], :2]))
    # The axial ray meets the ring at 0, in the holder between the two mini-lenses
    # (hml = 1.05 mm > Rml = 1 mm); the rim rays land far outside: yR = RL (1 + b/Z - b/FL).
    gain = 1 + b / 0.3 - b / prototype.main_focal_length_m
    np.testing.assert_allclose(rt.y_m[1:4, 2], [-rl * gain, 0.0, rl * gain], atol=1e-15)
    assert np.all(np.isnan(rt.sensor_y_m)) and not rt.reached_sensor.any()


def test_ray_classification_matches_ring_apertures(prototype):
    rt = trace(prototype, object_size_m=0.1, distance_m=0.3, rays_per_point=401, rays_per_lens=0)
    fl, hml, rml = prototype.main_focal_length_m, prototype.mini_lens_offset_m, prototype.mini_lens_radius_m
    b, c = prototype.require_positions()
    ys, yl = rt.y_m[:, 0], rt.y_m[:, 1]
    ring = yl + b * ((yl - ys) / 0.3 - yl / fl)
    expected = np.where(np.abs(ring - hml) <= rml, UPPER, np.where(np.abs(ring + hml) <= rml, LOWER, MISSED_RING))
    np.testing.assert_array_equal(rt.lens, expected)
    counts = {k: int((rt.lens == k).sum()) for k in (UPPER, LOWER, MISSED_RING, STOPPED_MAIN)}
    # Most of the fan misses the 2 mm mini-lenses; none is stopped when the fan spans the lens.
    assert counts[STOPPED_MAIN] == 0
    assert counts[MISSED_RING] > 10 * (counts[UPPER] + counts[LOWER]) > 0
    # Missed rays end on the ring plane; the others go on to the sensor plane at b + c.
    missed = rt.lens == MISSED_RING
    assert np.all(np.isnan(rt.y_m[missed, 3])) and np.all(rt.z_m[missed, 2] == b)
    assert np.all(rt.z_m[~missed, 3] == pytest.approx(b + c))
    # Through a mini-lens the ray bends by -(yR - m)/Fml.
    k = rt.lens == UPPER
    slope_out = (rt.y_m[k, 3] - rt.y_m[k, 2]) / c
    slope_in = (rt.y_m[k, 2] - rt.y_m[k, 1]) / b
    np.testing.assert_allclose(slope_out, slope_in - (rt.y_m[k, 2] - hml) / prototype.mini_focal_length_m)


def test_single_point_and_single_ray(prototype):
    rt = trace(prototype, object_size_m=0.1, distance_m=0.3, num_points=1, rays_per_point=0, rays_per_lens=1)
    # One on-axis source; one chief ray per mini-lens, through its centre.
    assert rt.source_heights_m.tolist() == [0.0]
    np.testing.assert_allclose(rt.y_m[:, 2], [prototype.mini_lens_offset_m, -prototype.mini_lens_offset_m])
    assert rt.lens.tolist() == [UPPER, LOWER]


def test_result_is_read_only(prototype):
    rt = trace(prototype, object_size_m=0.1, distance_m=0.3)
    with pytest.raises(ValueError):
        rt.y_m[0, 0] = 1.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        rt.distance_m = 1.0


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"object_size_m": 0.0}, "object size must be a positive"),
        ({"object_size_m": -0.1}, "object size must be a positive"),
        ({"object_size_m": float("nan")}, "object size must be a positive"),
        ({"distance_m": 0.016}, "does not exceed the main lens focal length"),
        ({"distance_m": 0.01}, "does not exceed the main lens focal length"),
        ({"distance_m": -1.0}, "object distance must be a positive"),
        ({"num_points": 0}, "num_points must be an integer >= 1"),
        ({"num_points": 2.5}, "num_points must be an integer >= 1"),
        ({"rays_per_point": -1}, "rays_per_point must be an integer >= 0"),
        ({"rays_per_point": 0, "rays_per_lens": 0}, "no ray to trace"),
        ({"aperture": "pupil"}, "aperture must be one of lens, iris"),
        ({"fan_radius_m": 0.0}, "fan radius must be a positive"),
    ],
)
def test_bad_input(prototype, kwargs, match):
    args = {"object_size_m": 0.1, "distance_m": 0.3, **kwargs}
    with pytest.raises(InvalidInputError, match=match):
        trace(prototype, **args)


def test_device_without_positions(prototype):
    bare = dataclasses.replace(prototype, ring_distance_m=None, sensor_distance_m=None)
    with pytest.raises(DeviceError, match="has no lens positions"):
        trace(bare, object_size_m=0.1, distance_m=0.3)


def test_ring_on_the_intermediate_image_cannot_aim(prototype):
    z = 0.3
    b1 = z * prototype.main_focal_length_m / (z - prototype.main_focal_length_m)
    dev = prototype.with_positions(b1, 0.006)
    with pytest.raises(InvalidInputError, match="intermediate image"):
        trace(dev, object_size_m=0.1, distance_m=z)
    # Without aimed rays it still traces: the whole bundle meets the ring at one height.
    rt = trace(dev, object_size_m=0.1, distance_m=z, num_points=1, rays_per_lens=0)
    assert np.ptp(rt.y_m[:, 2]) < 1e-15


def test_bundle_stats_rejects_other_objects():
    with pytest.raises(InvalidInputError, match="expected a RayTrace"):
        bundle_stats({"y_m": []})


def test_load_device_is_the_same_prototype(prototype):
    # The fixture is the shipped device, whose b and c are the fit-sensor design for 0.1 m at 0.3 m.
    d = design(load_device("prototype"), object_size_m=0.1, distance_m=0.3)
    assert prototype.require_positions() == pytest.approx((d.ring_distance_m, d.sensor_distance_m), abs=1e-12)


def test_figure_and_save(prototype, tmp_path):
    from matplotlib.figure import Figure

    from lfring.optics.figures import raytrace_figure, save_figure

    rt = trace(prototype, object_size_m=0.1, distance_m=0.3, num_points=3, rays_per_point=9, rays_per_lens=3)
    fig = raytrace_figure(rt)
    assert isinstance(fig, Figure)
    assert len(fig.axes) == 4
    assert "b = 37.369 mm, c = 6.616 mm" in fig.get_suptitle()
    out = save_figure(fig, tmp_path / "rays.png", dpi=60)
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000
    with pytest.raises(InvalidInputError, match="exists"):
        save_figure(fig, out)
    with pytest.raises(InvalidInputError, match="must end in"):
        save_figure(fig, tmp_path / "rays.jpg")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rays.png"]  # no temporary left behind
