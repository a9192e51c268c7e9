"""Depth outputs: PFM/TIFF round trips, the colour preview, 3D points and PLY files."""

import numpy as np
import pytest
import tifffile
from PIL import Image

from lfring.depth.io import (
    colorize_depth,
    depth_to_points,
    read_pfm,
    read_ply,
    write_depth_preview,
    write_depth_tiff,
    write_pfm,
    write_ply,
)
from lfring.errors import FileFormatError, InvalidInputError, LfringFileNotFoundError
from lfring.optics import paraxial
from lfring.optics.views import view_cameras

# Non-square, asymmetric, with the special values a depth map holds.
MAP = np.arange(15, dtype=np.float32).reshape(3, 5) / 4 + 0.5
MAP[0, 1] = np.nan
MAP[2, 4] = np.inf


def _no_leftovers(folder):
    assert not [p.name for p in folder.iterdir() if ".part" in p.name]


# -- PFM ----------------------------------------------------------------------------------------
def test_pfm_round_trip_and_layout(tmp_path):
    path = write_pfm(tmp_path / "d.pfm", MAP)
    raw = path.read_bytes()
    header = b"Pf\n5 3\n-1.0\n"
    assert raw.startswith(header) and len(raw) == len(header) + 15 * 4
    # rows bottom-to-top, little-endian
    np.testing.assert_array_equal(np.frombuffer(raw[len(header):len(header) + 20], "<f4"), MAP[2])
    back = read_pfm(path)
    assert back.dtype == np.float32 and back.shape == (3, 5)
    np.testing.assert_array_equal(back, MAP)  # NaN and inf kept
    _no_leftovers(tmp_path)


def test_pfm_reads_big_endian_and_colour(tmp_path):
    big = tmp_path / "big.pfm"
    big.write_bytes(b"Pf\n5 3\n1.0\n" + np.ascontiguousarray(MAP[::-1], ">f4").tobytes())
    back = read_pfm(big)
    np.testing.assert_array_equal(back, MAP)
    assert back.dtype == np.float32 and back.dtype.isnative
    rgb = np.random.default_rng(0).random((4, 2, 3))  # float64 in: stored as float32
    np.testing.assert_array_equal(read_pfm(write_pfm(tmp_path / "c.pfm", rgb)), rgb.astype(np.float32))
    assert (tmp_path / "c.pfm").read_bytes().startswith(b"PF\n2 4\n-1.0\n")


@pytest.mark.parametrize(
    "content, message",
    [
        (b"P6\n5 3\n255\n" + bytes(45), "not a PFM file"),
        (b"Pf\n5 3\n-1.0\n" + bytes(59), "truncated"),
        (b"Pf\n5 3\n-1.0\n" + bytes(61), "trailing bytes"),
        (b"Pf\n5 3\n0.0\n" + bytes(60), "non-zero"),
        (b"Pf\n0 3\n-1.0\n", "positive"),
        (b"", "not a PFM file"),
    ],
)
def test_corrupt_pfm_raises(tmp_path, content, message):
    path = tmp_path / "bad.pfm"
    path.write_bytes(content)
    with pytest.raises(FileFormatError, match=message):
        read_pfm(path)


def test_pfm_bad_input(tmp_path):
    with pytest.raises(LfringFileNotFoundError, match="not found"):
        read_pfm(tmp_path / "missing.pfm")
    with pytest.raises(InvalidInputError, match="floating-point"):
        write_pfm(tmp_path / "i.pfm", np.ones((3, 5), np.uint16))
    with pytest.raises(InvalidInputError, match=r"\(h, w\) or \(h, w, 3\)"):
        write_pfm(tmp_path / "v.pfm", np.ones(5, np.float32))
    assert not list(tmp_path.iterdir())


# -- TIFF ---------------------------------------------------------------------------------------
def test_depth_tiff_round_trip(tmp_path):
    path = write_depth_tiff(tmp_path / "d.tif", MAP.astype(np.float64))
    with tifffile.TiffFile(path) as tif:
        page = tif.pages[0]
        assert page.compression == tifffile.COMPRESSION.ADOBE_DEFLATE
        back = page.asarray()
    assert back.dtype == np.float32
    np.testing.assert_array_equal(back, MAP)
    with pytest.raises(InvalidInputError, match="floating-point"):
        write_depth_tiff(tmp_path / "i.tif", np.ones((3, 5), np.int32))
    _no_leftovers(tmp_path)


# -- colour -------------------------------------------------------------------------------------
def test_colorize_near_warm_far_cold_unknown_black():
    z = np.array([[0.4, 0.7, 1.0, np.nan], [0.4, 0.7, 1.0, 2.0]], np.float32)
    conf = np.array([[1.0, 1.0, 1.0, 1.0], [0.1, np.nan, 0.9, 0.9]], np.float32)
    rgb = colorize_depth(z, zmin_m=0.4, zmax_m=1.0, confidence=conf, min_confidence=0.5)
    assert rgb.dtype == np.uint8 and rgb.shape == (2, 4, 3)
    near, mid, far = rgb[0, 0].astype(int), rgb[0, 1].astype(int), rgb[0, 2].astype(int)
    assert near[0] > 150 and near[0] > near[2] + 100  # red
    assert far[2] > 150 and far[2] > far[0] + 100  # blue
    assert mid[1] > max(mid[0], mid[2]) - 60  # green-yellow in between
    assert rgb[0, 3].tolist() == [0, 0, 0]  # NaN depth
    assert rgb[1, 0].tolist() == [0, 0, 0] and rgb[1, 1].tolist() == [0, 0, 0]  # low / NaN confidence
    np.testing.assert_array_equal(rgb[1, 3], rgb[1, 2])  # beyond zmax: the far end's colour
    assert all(rgb[0, k].sum() > 60 for k in range(3))  # no shown pixel is near-black


def test_colorize_default_range_and_flat_maps():
    z = np.linspace(0.3, 1.2, 101, dtype=np.float32).reshape(1, -1)
    rgb = colorize_depth(z)
    assert rgb[0, 0, 0] > rgb[0, 0, 2] and rgb[0, -1, 2] > rgb[0, -1, 0]
    flat = colorize_depth(np.full((3, 2), 0.5, np.float32))
    assert len({tuple(p) for p in flat.reshape(-1, 3)}) == 1 and flat.sum() > 0
    assert colorize_depth(np.full((2, 2), np.nan)).sum() == 0


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"zmin_m": 1.0, "zmax_m": 0.5}, "less than"),
        ({"cmap": "no-such-map"}, "colour map"),
        ({"confidence": np.ones((2, 2), np.float32)}, "shape"),
        ({"min_confidence": np.nan}, "finite"),
        ({"zmin_m": "near"}, "finite number"),
    ],
)
def test_colorize_bad_options(kwargs, message):
    with pytest.raises(InvalidInputError, match=message):
        colorize_depth(MAP, **kwargs)


def test_colorize_needs_a_float_map():
    with pytest.raises(InvalidInputError, match="floating-point"):
        colorize_depth(np.ones((3, 5), np.uint16))
    with pytest.raises(InvalidInputError, match=r"\(h, w\)"):
        colorize_depth(np.ones((2, 3, 5), np.float32))


def test_depth_preview_png(tmp_path):
    z = np.full((60, 90), 0.8, np.float32)
    z[10:30, 20:50] = 0.45
    z[:5, :5] = np.nan
    path = write_depth_preview(tmp_path / "depth.png", z, title="two planes", confidence=np.ones_like(z))
    with Image.open(path) as im:
        img = np.asarray(im)
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[1] > img.shape[0]
    # the map is enlarged to at least 320 px wide, and its colours appear in the figure
    assert img.shape[1] >= 320 + 100
    near = colorize_depth(z, zmin_m=0.45, zmax_m=0.8)[15, 30]
    assert np.any(np.all(img[..., :3] == near, axis=-1))
    with pytest.raises(InvalidInputError, match=".png"):
        write_depth_preview(tmp_path / "depth.jpg", z)
    _no_leftovers(tmp_path)


# -- points -------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def plane_render():
    from lfring.optics import load_device
    from lfring.synth import Plane, Scene, Texture, render

    return render(load_device("prototype"), Scene((Plane(0.5, (0.4, 0.4), Texture("speckle")),)), binning=4)


@pytest.mark.parametrize("view", [0, 3])
def test_points_of_a_fronto_parallel_plane(plane_render, view):
    r = plane_render
    dev, layout = r.device, r.layout
    depth = r.depth_m[view]
    assert np.all(depth == np.float32(0.5))
    points, colors = depth_to_points(depth, dev, layout, view)
    h, w = layout.view_shape
    assert points.shape == (h * w, 3) and points.dtype == np.float64 and colors is None
    np.testing.assert_allclose(points[:, 2], 0.5)
    # The field: w pixels of pitch tp, seen through the pinhole (focal f, centre at depth s),
    # span (w - 1) tp (Z - s) / f metres at Z; the plane (0.4 m square) covers it.
    cams = view_cameras(dev)
    span = (np.array([w, h]) - 1) * dev.pixel_pitch_m * (0.5 - cams.depth_origin_m) / cams.focal_m
    np.testing.assert_allclose(np.ptp(points[:, :2], axis=0), span, rtol=1e-12)
    assert np.all(np.abs(points[:, :2]) < 0.2)
    # Row-major order: the first point is view pixel (0, 0), the next (1, 0), then row 1 starts at w.
    x0, y0 = layout.rects[view][:2]
    for i, (u, v) in {0: (0, 0), 1: (1, 0), w: (0, 1), h * w - 1: (w - 1, h - 1), 12345: (12345 % w, 12345 // w)}.items():
        want = np.array([u + x0, v + y0], dtype=np.float64)
        # back through the pinholes and, independently, through the chief-ray formula
        np.testing.assert_allclose(paraxial.sensor_to_pixel(dev, cams.project_m(points[i])[view]), want, atol=1e-9)
        np.testing.assert_allclose(paraxial.sensor_to_pixel(dev, paraxial.project_points_m(dev, points[i])[view]), want, atol=1e-9)


@pytest.mark.parametrize("z", [0.5, 1.7])
def test_points_in_the_center_frame(plane_render, z):
    # The centre frame of lfring.core.geometry.to_reference: view pixels moved by H_center_from_k(Z).
    from lfring.optics.views import optical_homographies

    r = plane_render
    dev, layout = r.device, r.layout
    depth = np.full(layout.view_shape, z, np.float32)
    points, _ = depth_to_points(depth, dev, layout, "center")
    assert points.shape == (depth.size, 3)
    h_center = optical_homographies(dev, layout, z, reference="center")  # (V, 3, 3)
    corners = np.array([rc[:2] for rc in layout.rects], dtype=np.float64)
    w = layout.view_shape[1]
    for i in (0, 777, depth.size - 1):
        want = np.array([i % w, i // w], dtype=np.float64)
        view_px = paraxial.sensor_to_pixel(dev, paraxial.project_points_m(dev, points[i])) - corners  # (V, 2)
        for k in range(4):
            np.testing.assert_allclose(h_center[k, :2, :2] @ view_px[k] + h_center[k, :2, 2], want, atol=1e-6)


def test_points_colours_and_confidence(plane_render):
    r = plane_render
    depth = r.depth_m[1].copy()
    depth[0, 0] = np.nan
    conf = np.ones_like(depth)
    conf[1, :] = 0.2
    points, colors = depth_to_points(depth, r.device, r.layout, 1, colors=r.views_sharp[1], confidence=conf, min_confidence=0.5)
    h, w = depth.shape
    assert len(points) == h * w - 1 - w == len(colors)
    assert colors.dtype == np.uint8
    # Linear light as lfring's images hold it, sRGB-encoded as lfring's PNGs and point-cloud viewers take it.
    srgb = lambda v: np.rint(255 * np.where(v <= 0.0031308, 12.92 * v, 1.055 * np.clip(v, 0, 1) ** (1 / 2.4) - 0.055))  # noqa: E731
    np.testing.assert_array_equal(colors[0], srgb(np.clip(r.views_sharp[1][0, 1], 0, 1)).astype(np.uint8))
    np.testing.assert_array_equal(colors[w - 1], srgb(np.clip(r.views_sharp[1][2, 0], 0, 1)).astype(np.uint8))
    assert colors.mean() > 1.2 * np.clip(r.views_sharp[1], 0, 1).mean() * 255  # brighter than linear bytes


def test_points_bad_input(plane_render):
    r = plane_render
    z = r.depth_m[0]
    for bad in (4, "centre", True, 1.0):
        with pytest.raises(InvalidInputError, match="view must be 'center' or a view index 0..3"):
            depth_to_points(z, r.device, r.layout, bad)
    with pytest.raises(InvalidInputError, match="binned"):
        depth_to_points(z, r.device.binned(2), r.layout, 0)
    with pytest.raises(InvalidInputError, match="view shape"):
        depth_to_points(z[:, :-1], r.device, r.layout, 0)
    with pytest.raises(InvalidInputError, match="beyond the views' projection centres"):
        depth_to_points(np.full_like(z, 0.01), r.device, r.layout, 0)
    with pytest.raises(InvalidInputError, match="colors"):
        depth_to_points(z, r.device, r.layout, 0, colors=np.zeros(z.shape + (3,), np.int32))
    with pytest.raises(InvalidInputError, match=r"colors must be float in \[0, 1\].*raw counts"):
        depth_to_points(z, r.device, r.layout, 0, colors=np.full(z.shape + (3,), 128.0, np.float32))
    for bad in (2.0, -0.1):  # confidence lies in [0, 1]: such a threshold keeps every point or none
        with pytest.raises(InvalidInputError, match=r"min_confidence must be a number >= 0 and <= 1"):
            depth_to_points(z, r.device, r.layout, 0, confidence=np.ones_like(z), min_confidence=bad)


# -- PLY ----------------------------------------------------------------------------------------
def _header(raw: bytes) -> list[str]:
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    return raw[:end].decode("ascii").splitlines(), end


def test_ply_with_colours(tmp_path):
    pts = np.array([[0.1, -0.2, 0.5], [0.0, 0.0, 1.25], [1e-3, 2e-3, 3.0]])
    col = np.array([[255, 0, 0], [0, 128, 0], [1, 2, 3]], np.uint8)
    path = write_ply(tmp_path / "cloud.ply", pts, col)
    raw = path.read_bytes()
    lines, end = _header(raw)
    assert lines[:2] == ["ply", "format binary_little_endian 1.0"]
    assert "element vertex 3" in lines
    props = [ln for ln in lines if ln.startswith("property")]
    assert props == ["property float x", "property float y", "property float z",
                     "property uchar red", "property uchar green", "property uchar blue"]
    assert len(raw) - end == 3 * (3 * 4 + 3)
    first = np.frombuffer(raw[end:end + 12], "<f4")
    np.testing.assert_array_equal(first, pts[0].astype(np.float32))
    assert raw[end + 12:end + 15] == bytes([255, 0, 0])
    p2, c2 = read_ply(path)
    np.testing.assert_array_equal(p2, pts.astype(np.float32))
    np.testing.assert_array_equal(c2, col)
    _no_leftovers(tmp_path)


def test_ply_without_colours_and_empty(tmp_path):
    pts = np.random.default_rng(1).random((7, 3)).astype(np.float32)
    raw = write_ply(tmp_path / "a.ply", pts).read_bytes()
    lines, end = _header(raw)
    assert not any("uchar" in ln for ln in lines) and len(raw) - end == 7 * 12
    p2, c2 = read_ply(tmp_path / "a.ply")
    assert c2 is None
    np.testing.assert_array_equal(p2, pts)
    p0, _ = read_ply(write_ply(tmp_path / "e.ply", np.zeros((0, 3))))
    assert p0.shape == (0, 3)


def test_ply_bad_input(tmp_path):
    with pytest.raises(InvalidInputError, match="finite"):
        write_ply(tmp_path / "n.ply", np.array([[0.0, np.nan, 1.0]]))
    with pytest.raises(InvalidInputError, match=r"\(N, 3\)"):
        write_ply(tmp_path / "s.ply", np.zeros((4, 2)))
    with pytest.raises(InvalidInputError, match="uint8"):
        write_ply(tmp_path / "c.ply", np.zeros((4, 3)), np.zeros((4, 3)))
    assert not list(tmp_path.iterdir())
    bad = tmp_path / "bad.ply"
    bad.write_bytes(write_ply(tmp_path / "ok.ply", np.zeros((2, 3))).read_bytes()[:-1])
    with pytest.raises(FileFormatError, match="need"):
        read_ply(bad)
    bad.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 0\nend_header\n")
    with pytest.raises(FileFormatError, match="binary little-endian"):
        read_ply(bad)
    with pytest.raises(LfringFileNotFoundError):
        read_ply(tmp_path / "missing.ply")


def test_a_calibration_no_binning_of_the_device_fits_names_the_sensor_as_it_is():
    """A stereo pair's calibration (800 x 600 px frames) asked for the prototype's optics: the
    refusal gave the sensor as '818 x 614 px', the size the binning it tried made of it."""
    from lfring.calibration import RingCalibration
    from lfring.depth.io import device_for
    from lfring.errors import InvalidInputError

    for width in (800, 400, 60):  # the last one too coarse a binning even to try
        cal = RingCalibration.from_grid((600, width), [(0, 0), (1, 0)], disparity_scale_px_m=100.0)
        with pytest.raises(InvalidInputError, match=r"the device 'prototype' has a 4912 x 3684 px sensor, which no "
                                                    rf"binning turns into the calibration's {2 * width} x 600 px frames"):
            device_for(cal)
