"""Lens distortion and flat fields: the maps, their inverses, their file forms."""

import numpy as np
import pytest

from lfring.core.lens import (
    FLAT_FLOOR,
    POLYNOMIAL_TERMS,
    FlatField,
    LensDistortion,
    PolynomialDistortion,
    distortion_from_dict,
    polynomial_basis,
    remap_views,
    undistortion_maps,
)
from lfring.errors import InvalidInputError

LENSES = [
    LensDistortion((350.0, 340.0), 2600.0, k1=-0.5, k2=-2.0, p1=0.01, p2=-0.005),
    LensDistortion((420.0, 300.0), 2600.0, k1=-0.45, k2=3.6, p1=0.005, p2=0.03, tilt_rad=(0.03, -0.02)),
]


def _grid(step=17):
    yy, xx = np.mgrid[0:700:step, 0:700:step].astype(float)
    return np.stack([xx, yy], axis=-1)


@pytest.mark.parametrize("lens", LENSES)
def test_undistort_inverts_distort(lens):
    pts = _grid()
    np.testing.assert_allclose(lens.undistort(lens.distort(pts)), pts, atol=1e-6)
    np.testing.assert_allclose(lens.distort(lens.undistort(pts)), pts, atol=1e-6)
    # The distortion is a few pixels at the rim, barrel (points move towards the centre).
    assert 3 < lens.displacement_px(350.0) < 30


def test_undistort_box_matches_the_exact_inverse():
    lens = LENSES[1]
    box = lens.undistort_box(300, 10, 160, 90, step=8)
    yy, xx = np.mgrid[10:100, 300:460].astype(float)
    np.testing.assert_allclose(box, lens.undistort(np.stack([xx, yy], axis=-1)), atol=1e-4)
    # Its grid is interpolated by scipy's bicubic spline, written without scipy.interpolate.
    from scipy.interpolate import RectBivariateSpline

    step = 8
    gx = np.arange(300 - 2 * step, 300 + 160 + 3 * step, step, dtype=float)
    gy = np.arange(10 - 2 * step, 10 + 90 + 3 * step, step, dtype=float)
    nodes = np.stack(np.meshgrid(gx, gy), axis=-1)
    shift = lens.undistort(nodes) - nodes
    want_x = RectBivariateSpline(gy, gx, shift[..., 0])(np.arange(10, 100.0), np.arange(300, 460.0)) + xx[0]
    np.testing.assert_allclose(box[..., 0], want_x, atol=1e-9)


def test_a_tilt_alone_moves_nothing():
    lens = LensDistortion((350.0, 350.0), 2600.0, tilt_rad=(0.03, 0.02))
    assert lens.is_identity
    np.testing.assert_array_equal(lens.distort(_grid()), _grid())


def test_radial_terms_are_polynomial_terms():
    # k1 is the term r^2 z, k2 the term r^4 z: the same map about the same centre and scale.
    r = 300.0
    lens = LensDistortion((350.0, 350.0), r, k1=-0.02, k2=0.004)
    coef = [0j] * len(POLYNOMIAL_TERMS)
    coef[POLYNOMIAL_TERMS.index((2, 1))] = -0.02
    coef[POLYNOMIAL_TERMS.index((3, 2))] = 0.004
    poly = PolynomialDistortion((350.0, 350.0), r, tuple(coef))
    np.testing.assert_allclose(poly.distort(_grid()), lens.distort(_grid()), atol=1e-9)


def test_polynomial_basis_and_inverse():
    coef = np.zeros(len(POLYNOMIAL_TERMS), complex)
    coef[POLYNOMIAL_TERMS.index((2, 1))] = -0.02
    coef[POLYNOMIAL_TERMS.index((1, 1))] = 0.003 + 0.002j
    d = PolynomialDistortion((300.0, 310.0), 320.0, tuple(coef))
    z = np.array([0.5 + 0.1j, -0.3 + 0.7j])
    assert polynomial_basis(z).shape == (2, len(POLYNOMIAL_TERMS))
    np.testing.assert_allclose(d.displacement(z), polynomial_basis(z) @ coef)
    np.testing.assert_allclose(d.undistort(d.distort(_grid())), _grid(), atol=1e-6)


@pytest.mark.parametrize("d", [LENSES[1], PolynomialDistortion((350.0, 350.0), 330.0, tuple(
    complex(0.001 * j, -0.0005 * j) for j in range(len(POLYNOMIAL_TERMS))))])
def test_distortion_file_form_round_trips(d):
    back = distortion_from_dict(d.to_dict())
    assert type(back) is type(d)
    np.testing.assert_allclose(back.distort(_grid()), d.distort(_grid()), atol=1e-9)


@pytest.mark.parametrize("bad, match", [
    ({"model": "fisheye", "centre_view_px": [0, 0], "scale_px": 1}, "'model'"),
    ({"model": "polynomial", "centre_view_px": [0, 0], "scale_px": 1, "terms": [[9, 9, 1, 0]]}, "term"),
    ({"model": "brown-conrady", "centre_view_px": [0, 0], "scale_px": 1, "k9": 1}, "unknown"),
    ({"model": "brown-conrady", "scale_px": 1}, "centre_view_px"),
])
def test_bad_distortion_files_are_refused(bad, match):
    with pytest.raises(InvalidInputError, match=match):
        distortion_from_dict(bad)


def test_undistortion_maps_sample_the_recorded_position():
    lens = LENSES[0]
    mx, my = undistortion_maps([None, lens], (40, 50))
    yy, xx = np.mgrid[0:40, 0:50]
    np.testing.assert_array_equal(mx[0], xx)
    np.testing.assert_allclose(np.stack([mx[1], my[1]], -1), lens.distort(np.stack([xx, yy], -1).astype(float)),
                               atol=1e-4)
    # Undoing a distortion: an image recorded through the lens, remapped, is the ideal image.
    rng = np.random.default_rng(0)
    ideal = rng.random((40, 50)).astype(np.float32)
    ideal = np.ascontiguousarray(np.repeat(np.repeat(ideal, 1, 0), 1, 1))
    views = np.stack([ideal, ideal])[..., None]
    out = remap_views(views, mx, my, skip=(0, 1))
    np.testing.assert_array_equal(out, views)


def test_flat_field_divides_each_view_to_the_same_brightness():
    yy, xx = np.mgrid[0:60, 0:80]
    vig = np.clip(1 - ((xx - 40) ** 2 + (yy - 30) ** 2) / 40.0**2, 0, 1).astype(np.float32)
    flat = np.stack([0.8 * vig, 0.6 * vig])[..., None].repeat(3, axis=3)
    ff = FlatField.from_views(flat, smoothing_px=0)
    assert ff.response.max() == pytest.approx(1.0, abs=1e-3)
    scene = 0.3 * flat  # a grey surface seen through the same vignetting
    out = ff.apply(scene)
    bright = ff.response >= FLAT_FLOOR
    # Both views come out alike, at the grey's brightness through the least vignetted pixel.
    np.testing.assert_allclose(out[..., 0][bright], 0.3 * 0.8, rtol=5e-3)
    with pytest.raises(InvalidInputError, match="flat field is for 2 views"):
        ff.apply(scene[:1])


def test_flat_field_grid_round_trip():
    yy, xx = np.mgrid[0:101, 0:90]
    # A smooth fall-off to the rim, as vignetting is.
    r = np.exp(-((xx - 45) ** 2 + (yy - 50) ** 2) / (2 * 40.0**2)).astype(np.float32)
    ff = FlatField(np.stack([r, 0.9 * r]))
    grid = ff.to_grid(16)
    assert grid.shape == (2, 8, 7)
    back = FlatField.from_grid(grid, 16, (101, 90))
    inside = r > 0.3
    assert float(np.abs(back.response[0] - r)[inside].max()) < 0.005
    with pytest.raises(InvalidInputError, match="grid"):
        FlatField.from_grid(grid[:, :3], 16, (101, 90))


@pytest.mark.parametrize("shape, step", [((101, 90), 16), ((705, 705), 15), ((40, 100), 16), ((50, 50), 16)])
def test_flat_field_grid_is_restored_by_scipys_bicubic_spline(shape, step):
    # The restore is written without scipy.interpolate (its import costs a command's start half a
    # second); it must be the same spline: FITPACK's interpolating bicubic with not-a-knot ends,
    # also with a last interval of one pixel (50 px, step 16: nodes 0, 16, 32, 48, 49).
    from scipy.interpolate import RectBivariateSpline

    rng = np.random.default_rng(5)
    h, w = shape
    ys = np.unique(np.r_[np.arange(0, h, step), h - 1])
    xs = np.unique(np.r_[np.arange(0, w, step), w - 1])
    grid = rng.random((2, len(ys), len(xs)))
    back = FlatField.from_grid(grid, step, shape)
    k = min(3, len(ys) - 1, len(xs) - 1)
    want = np.stack([RectBivariateSpline(ys, xs, g, kx=k, ky=k)(np.arange(h), np.arange(w)) for g in grid])
    # The response is kept in [0, 1], as float32.
    np.testing.assert_allclose(back.response, np.clip(want, 0.0, 1.0), rtol=0, atol=1e-6)


@pytest.mark.parametrize("value", [0.0, -0.5])
def test_a_flat_field_that_no_light_reached_is_refused(value):
    """A calibration's flat field of zeros (or negative values, clipped to zeros) was taken: every
    view divided by it saturated (31 % of the refocused image clipped), while a NaN was refused."""
    r = np.full((2, 20, 30), 0.8, np.float32)
    r[1] = value
    with pytest.raises(InvalidInputError, match="view 1's is nowhere above 0"):
        FlatField(r)
    r[1, 5, 5] = 0.2  # light somewhere: a real, if odd, flat field
    assert FlatField(r).response[1, 5, 5] == pytest.approx(0.2)
