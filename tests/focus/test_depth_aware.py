"""Depth-aware refocusing (lfring.focus.depth_aware) against exact constructions: two fronto-parallel textured
planes, a near one partly covering a far one, rendered as four views by shifting them with
occlusion; the exact depth map is given."""

import math
import warnings
from pathlib import Path

import cv2
import numba
import numpy as np
import pytest

from lfring.calibration import RingCalibration
from lfring.core.threads import numba_threads
from lfring.focus.depth_aware import (MIN_DEPTH_VIEWS, MIN_ESTIMATED_VIEWS, DepthOfField, aperture_from_f_number,
                                      aperture_radius_px, coc_radius_px)
from lfring.depth import DepthResult
from lfring.errors import InvalidInputError, LfringWarning
from lfring.focus import Refocuser, all_in_focus, depth_of_field, focal_stack, refocus, resolve_aperture
from lfring.optics import load_device
from lfring.views import Layout

SCENE = Path(__file__).resolve().parents[2] / "data" / "synthetic" / "scene.png"
N = 96  # view side
FAR_M, NEAR_M = 2.0, 0.5  # x = 1/Z: 0.5 and 2 (z0 = 0)
GAIN = 4.0  # view motion per unit x along each axis: shifts of 2 px (far) and 8 px (near)
DIRS = np.array([[-1, -1], [1, -1], [-1, 1], [1, 1]])  # where each view sits in the aperture
NEAR_BOX = (slice(30, 70), slice(20, 60))  # rows, cols of the near plane in the reference frame
# Views valid only in discs, each a little off the frame's centre.
DISCS = tuple((N / 2 + dx, N / 2 + dy, N / 2 - 10) for dx, dy in ((-6, -4), (5, -6), (-4, 6), (6, 5)))


def _calibration(circles=None):
    lay = Layout(2 * N + 10, 2 * N + 10, ((0, 0, N, N), (N + 10, 0, N, N), (0, N + 10, N, N), (N + 10, N + 10, N, N)),
                 False, circles)

    def hs(z):
        t = -GAIN / z * DIRS  # H_center_from_k: view pixel u lands on reference u + t_k
        out = np.repeat(np.eye(3)[None], 4, axis=0)
        out[:, :2, 2] = t - t[0]  # into view 0
        return out

    return RingCalibration.from_plane_homographies({0.4: hs(0.4), 3.0: hs(3.0)}, layout=lay, depth_origin_m=0.0)


def _scene(far_tex, near_tex, *, with_near=True, box=NEAR_BOX):
    """Views and the exact depth map: view k shows reference point X of a plane at depth Z at
    view pixel X + (GAIN / Z) d_k; the near plane (over ``box`` of the reference frame) hides
    the far one."""
    yy, xx = np.mgrid[0:N, 0:N]
    near_mask = np.zeros((N, N), bool)
    near_mask[box] = with_near
    views = []
    for d in DIRS:
        gf, gn = (GAIN / FAR_M * d).astype(int), (GAIN / NEAR_M * d).astype(int)
        # Reference point seen at view pixel u: X = u - g d (textures are padded by 16 px).
        far = far_tex[yy - gf[1] + 16, xx - gf[0] + 16]
        ny, nx = yy - gn[1], xx - gn[0]
        inside = (ny >= 0) & (ny < N) & (nx >= 0) & (nx < N)
        hit = np.zeros((N, N), bool)
        hit[inside] = near_mask[ny[inside], nx[inside]]
        v = far.copy()
        v[hit] = near_tex[ny[hit] + 16, nx[hit] + 16]
        views.append(v)
    depth = np.where(near_mask, NEAR_M, FAR_M)
    return np.stack(views).astype(np.float32), depth, near_mask


def _textures():
    """Random textures, padded by 16 px: a dark far one and a bright near one (every occlusion
    is visible)."""
    rng = np.random.default_rng(3)
    far = (0.05 + 0.3 * rng.random((N + 32, N + 32, 3))).astype(np.float32)
    near = (0.65 + 0.3 * rng.random((N + 32, N + 32, 3))).astype(np.float32)
    return far, near


@pytest.fixture(scope="module")
def textured():
    far, near = _textures()
    views, depth, mask = _scene(far, near)
    return _calibration(), views, depth, mask, far[16:-16, 16:-16], near[16:-16, 16:-16]


def test_the_blur_scale_is_the_views_radius_in_the_aperture():
    cal = _calibration()
    assert aperture_radius_px(cal) == pytest.approx(GAIN * math.sqrt(2), rel=1e-9)
    assert aperture_radius_px(cal, reference=2) == pytest.approx(GAIN * math.sqrt(2), rel=1e-9)
    assert coc_radius_px(cal, NEAR_M, FAR_M, aperture=0.5) == pytest.approx(0.5 * GAIN * math.sqrt(2) * 1.5)


def test_focused_on_the_far_plane_its_interior_is_shift_and_add(textured):
    cal, views, depth, mask, far, near = textured
    sa = refocus(views, cal, FAR_M)
    out = refocus(views, cal, FAR_M, method="depth-aware", depth=depth)
    # Away from the near plane's blur (radius 8.5 px) and the frame's edge.
    far_inside = np.ones((N, N), bool)
    far_inside[30 - 12:70 + 12, 20 - 12:60 + 12] = False
    far_inside[:4] = far_inside[-4:] = False
    far_inside[:, :4] = far_inside[:, -4:] = False
    np.testing.assert_allclose(out[far_inside], sa[far_inside], atol=1e-5)
    np.testing.assert_allclose(out[far_inside], far[far_inside], atol=1e-5)


def test_near_edge_blurs_over_the_far_plane_and_far_never_bleeds_over_a_sharp_near(textured):
    cal, views, depth, mask, far, near = textured
    # Focused far: just outside the near plane's left edge, its light spreads over the far plane.
    out = refocus(views, cal, FAR_M, method="depth-aware", depth=depth)
    rows = slice(40, 60)
    just_outside = out[rows, 17:20].mean()  # 1-3 px left of the edge at column 20
    assert just_outside > far[rows, 17:20].mean() + 0.15  # the bright near plane's blur
    excess = (out - far)[rows, 8:20].mean(axis=(0, 2))  # the near plane's light over the far plane
    assert np.all(np.diff(excess[2:]) > 0) and excess[0] < 0.01  # a smooth ramp from 9 px out, no step
    # Shift-and-add leaves a hard step (a ghost copy 6 px out) instead.
    sa_excess = (refocus(views, cal, FAR_M) - far)[rows, 8:20].mean(axis=(0, 2))
    assert np.abs(np.diff(sa_excess)).max() > 4 * np.abs(np.diff(excess)).max()
    # Focused near: every near pixel is the near texture (the blurred far plane stays outside).
    out_near = refocus(views, cal, NEAR_M, method="depth-aware", depth=depth)
    np.testing.assert_allclose(out_near[mask], near[mask], atol=1e-5)
    # ... and the far plane is blurred, not doubled: next to the near plane, still dark.
    assert out_near[rows, 12:19].max() < 0.45


def test_a_blurred_near_edge_is_a_ramp_on_both_sides():
    """Focused far, a uniform near plane's edge over a uniform far plane spreads over the disc's
    width on both sides of the edge (the far plane continues under the near one's soft edge),
    with no step anywhere; shift-and-add has steps."""
    cal = _calibration()
    views, depth, _ = _scene(np.full((N + 32, N + 32, 1), 0.2, np.float32), np.full((N + 32, N + 32, 1), 0.8, np.float32))
    r = coc_radius_px(cal, NEAR_M, FAR_M)  # 8.5 px
    profile = refocus(views, cal, FAR_M, method="depth-aware", depth=depth)[40:60, 4:36, 0].mean(axis=0)  # edge at column 20
    # No step: at most 1.5 x the steepest slope of a disc's edge, contrast * 2 / (pi r) per px.
    assert np.abs(np.diff(profile)).max() < 1.5 * 0.6 * 2 / (np.pi * r)
    assert profile[20 - 4 - 4] > 0.3 and profile[20 + 4 - 4] < 0.7  # light spreads 4 px out and 4 px in
    assert profile[0] == pytest.approx(0.2, abs=1e-3) and profile[-1] == pytest.approx(0.8, abs=1e-3)
    sa = refocus(views, cal, FAR_M)[40:60, 4:36, 0].mean(axis=0)
    assert np.abs(np.diff(sa)).max() > 0.1


def test_aperture_zero_is_all_in_focus(textured):
    cal, views, depth, mask, far, near = textured
    truth = np.where(mask[..., None], near, far)
    inner = (slice(8, N - 8), slice(8, N - 8))  # every view sees these points
    for focus in (FAR_M, NEAR_M, 1.0):
        out = refocus(views, cal, focus, method="depth-aware", depth=depth, aperture=0.0)
        np.testing.assert_allclose(out[inner], truth[inner], atol=1e-5)
    # all_in_focus with the depth map is the same renderer (values the nearest of depths_m).
    img, chosen = all_in_focus(views, cal, [FAR_M, NEAR_M], depth_map_m=depth)
    np.testing.assert_allclose(img[inner], truth[inner], atol=1e-5)
    assert np.all(chosen[mask] == np.float32(NEAR_M))


def _edge_width(profile):
    """Distance between the 10 % and 90 % crossings of a rising step profile (px, linear)."""
    p = (profile - profile[0]) / (profile[-1] - profile[0])
    return float(np.interp(0.9, p, np.arange(len(p))) - np.interp(0.1, p, np.arange(len(p))))


def _disc_edge_width(r):
    """10-90 % width of the edge of a disc of radius r: the disc's area beyond a chord."""
    d = np.linspace(-r, r, 20001)
    frac = 1 - (r * r * np.arccos(d / r) - d * np.sqrt(r * r - d * d)) / (np.pi * r * r)
    return float(np.interp(0.9, frac, d) - np.interp(0.1, frac, d))


@pytest.mark.parametrize("aperture", [0.5, 1.0])
def test_blur_radius_matches_the_circle_of_confusion(aperture):
    """A step on the far plane (no near plane) focused at the near depth: its edge spreads as a
    disc of radius r(Z) = aperture * R * |1/Z - 1/Z_f|."""
    cal = _calibration()
    step = np.full((N + 32, N + 32, 1), 0.2, np.float32)
    step[:, (N + 32) // 2:] = 0.8
    flat = np.full_like(step, 0.9)
    views, _, _ = _scene(step, flat, with_near=False)
    depth = np.full((N, N), FAR_M)
    out = refocus(views, cal, NEAR_M, method="depth-aware", depth=depth, aperture=aperture)[..., 0]
    r = coc_radius_px(cal, FAR_M, NEAR_M, aperture=aperture)
    profile = out[20:76, N // 2 - 20:N // 2 + 20].mean(axis=0)
    width = _edge_width(profile)
    assert width == pytest.approx(_disc_edge_width(r), abs=0.6), (r, width)
    assert abs(width - _disc_edge_width(1.25 * r)) > 0.6 and abs(width - _disc_edge_width(0.8 * r)) > 0.6


def test_f_number_and_aperture_agree():
    dev = load_device("prototype")
    cal = RingCalibration.from_optics(dev)
    a = resolve_aperture(cal, f_number=4.0)
    assert a == pytest.approx(aperture_from_f_number(4.0, dev))
    assert resolve_aperture(cal, f_number=2.0) == pytest.approx(2 * a)  # aperture ~ 1 / N
    # The relation: the lens's pupil radius FL / (2 N) over the views' radius in it.
    from lfring.optics.views import view_cameras

    c = view_cameras(dev).centres_m
    assert a * np.linalg.norm(c - c.mean(axis=0), axis=1).mean() == pytest.approx(dev.main_focal_length_m / 8.0)
    # Rendering with one or the other gives the same image.
    small = _calibration()
    rng = np.random.default_rng(0)
    views = rng.random((4, N, N, 1)).astype(np.float32)
    depth = np.full((N, N), FAR_M)
    a2 = resolve_aperture(small, f_number=4.0, ring_device=dev)
    np.testing.assert_array_equal(refocus(views, small, NEAR_M, method="depth-aware", depth=depth, aperture=a2),
                                  refocus(views, small, NEAR_M, method="depth-aware", depth=depth, f_number=4.0, ring_device=dev))


def test_no_seams_where_the_number_of_valid_views_changes(textured):
    """Views valid only inside discs (tapered weights): a uniform scene stays uniform wherever
    any view sees it, in focus and out, although one to four views see each pixel."""
    _, _, depth, _, _, _ = textured
    cal = _calibration(tuple((N / 2, N / 2, N / 2 - 6) for _ in range(4)))
    views = np.full((4, N, N, 3), 0.6, np.float32)
    seen = refocus(views, cal, FAR_M) > 0.3  # where shift-and-add sees anything
    for focus, aperture in ((FAR_M, 1.0), (NEAR_M, 1.0), (NEAR_M, 2.5), (1.0, 0.0)):
        out = refocus(views, cal, focus, method="depth-aware", depth=depth, aperture=aperture)
        np.testing.assert_allclose(out[seen], 0.6, atol=1e-5)
    assert seen.mean() > 0.6 and not seen.all()  # the discs do leave part of the frame unseen


def test_focal_stack_reuses_one_depth_map(textured):
    cal, views, depth, mask, far, near = textured
    stack = focal_stack(views, cal, [FAR_M, NEAR_M], method="depth-aware", depth=depth)
    np.testing.assert_array_equal(stack[1], refocus(views, cal, NEAR_M, method="depth-aware", depth=depth))
    dof = depth_of_field(views, cal, depth=depth)
    np.testing.assert_array_equal(stack[0], dof.render(FAR_M, 1.0, refocus(views, cal, FAR_M)))


def test_bad_inputs(textured):
    cal, views, depth, mask, far, near = textured
    with pytest.raises(InvalidInputError, match="aperture must be"):
        refocus(views, cal, FAR_M, method="depth-aware", depth=depth, aperture=-1.0)
    with pytest.raises(InvalidInputError, match="depth map must be"):
        refocus(views, cal, FAR_M, method="depth-aware", depth=depth[:-1])
    with pytest.raises(InvalidInputError, match="method must be one of"):
        refocus(views, cal, FAR_M, method="bokeh")
    with pytest.raises(InvalidInputError, match="not both"):
        refocus(views, cal, FAR_M, method="depth-aware", depth=depth, aperture=1.0, f_number=2.8)
    with pytest.raises(InvalidInputError, match="f_number needs the device"):
        refocus(views, cal, FAR_M, method="depth-aware", depth=depth, f_number=2.8)
    with pytest.raises(InvalidInputError, match="for method='depth-aware'"):
        refocus(views, cal, FAR_M, aperture=0.5)
    with pytest.raises(InvalidInputError, match="not both"):
        refocus(views, cal, FAR_M, method="depth-aware", depth=depth, zmin_m=0.5, zmax_m=2.5)
    with pytest.raises(InvalidInputError, match="depth"):
        refocus(views, cal, -1.0, method="depth-aware", depth=depth)
    for bad in (-0.5, 4.5, float("nan")):
        with pytest.raises(InvalidInputError, match="measured_views"):
            DepthOfField(views, cal, depth, measured_views=bad)
    for bad in (0, -3, 4, 7.0, "7"):  # cv2.error from the box filter, or an even box taken
        with pytest.raises(InvalidInputError, match="window_px must be an odd positive integer"):
            all_in_focus(views, cal, window_px=bad)


def test_cli_depth_aware_stack_is_labelled(tmp_path, capsys):
    import json
    from pathlib import Path

    import tifffile
    from gif_frames import read_gif

    from lfring.cli.main import main

    scene = Path(__file__).resolve().parents[2] / "data" / "synthetic" / "scene.png"
    out = tmp_path / "s.png"
    assert main(["refocus", str(scene), "--depths", "0.3,0.6", "--method", "depth-aware", "--aperture", "0.5",
                 "--zmin", "0.3", "--zmax", "0.9", "-o", str(out)]) == 0
    side = json.loads((tmp_path / "s_000_0.3m.png.json").read_text())
    assert side["method"] == "depth-aware" and side["aperture"] == 0.5 and side["zmax_m"] == 0.9
    with tifffile.TiffFile(tmp_path / "s_stack.tif") as tif:
        assert "0.6" in tif.pages[0].description  # the depths in the TIFF's metadata
    gif = read_gif(tmp_path / "s_stack.gif")
    corner = gif[:, :40, :120].astype(int)
    assert gif.shape[0] == 2 and corner.max() >= 200  # the caption's white text
    # Depth-of-field options need the depth-aware method.
    assert main(["refocus", str(scene), "--depth", "0.5", "--method", "shift-and-add", "--aperture", "0.5",
                 "-o", str(tmp_path / "o.png")]) == 2
    assert "--method depth-aware" in capsys.readouterr().err


def test_homographies_that_are_not_translations():
    """A calibration whose views also scale with depth takes the general sampling path
    (interpolated between depths): at one depth everywhere, aperture 0 is shift-and-add there."""
    lay = _calibration().layout

    def hs(z):
        out = np.repeat(np.eye(3)[None], 4, axis=0)
        for k, d in enumerate(DIRS):
            s = 1.0 + 0.02 * k / z
            out[k, :2, :2] *= s
            out[k, :2, 2] = -GAIN / z * d - (s - 1) * N / 2
        return out

    cal = RingCalibration.from_plane_homographies({0.4: hs(0.4), 3.0: hs(3.0)}, layout=lay, depth_origin_m=0.0)
    rng = np.random.default_rng(1)
    texture = cv2.GaussianBlur(rng.random((N, N, 3), dtype=np.float32), (0, 0), 2.0)
    z = 0.8
    # Views of a plane at z: view k's pixel u shows the reference point H_k(z) u.
    views = np.stack([cv2.warpPerspective(texture, np.linalg.inv(hk), (N, N), flags=cv2.INTER_LINEAR)
                      for hk in cal.homographies(z)])
    depth = np.full((N, N), z)
    depth[0, 0] = 2.0  # a second depth, so the sampling positions are interpolated between knots
    dof = depth_of_field(views, cal, depth=depth)
    inner = (slice(12, N - 12), slice(12, N - 12))
    # The all-in-focus colour samples the views where shift-and-add does (the general warp).
    np.testing.assert_allclose(dof.colour[inner], refocus(views, cal, z)[inner], atol=2e-3)
    np.testing.assert_allclose(dof.colour[inner], texture[inner], atol=2e-2)


# -- continuous depth: a slanted textured plane --------------------------------------------------
SLANT_X = (0.5, 2.5)  # x = 1/Z from the left column to the right one: radii up to 5.7 px focused at x = 1.5


def _smooth_texture(seed, channels=3):
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.random((N + 128, N + 128, channels)).astype(np.float32), (0, 0), 1.2)
    tex = (tex - tex.mean()) / tex.std() * 0.12 + 0.45
    return np.clip(tex, 0.0, 1.0).reshape(N + 128, N + 128, channels).astype(np.float32)


def _slanted_image(tex, offset, x_focus):
    """The plane x = a + b X (X the reference column) seen from aperture position ``offset`` (in
    the units of DIRS) in the frame refocused at ``x_focus``: reference point X appears at
    u = X + GAIN (x(X) - x_focus) offset, solved for X (linear in X)."""
    a, b = SLANT_X[0], (SLANT_X[1] - SLANT_X[0]) / (N - 1)
    yy, xx = np.mgrid[0:N, 0:N].astype(np.float64)
    cols = (xx - GAIN * (a - x_focus) * offset[0]) / (1.0 + GAIN * b * offset[0])
    rows = yy - GAIN * (a + b * cols - x_focus) * offset[1]
    out = cv2.remap(tex, (cols + 64).astype(np.float32), (rows + 64).astype(np.float32), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REFLECT)
    return out.reshape(N, N, tex.shape[2])


def _slanted_plane(seed=7, x_focus=1.5, samples=700):
    """Four views of the plane with its exact depth map, and the ground truth focused at
    ``x_focus``: the average over an aperture disc through the views of what a pinhole there
    sees (a Vogel spiral of ``samples`` points), as lfring.synth.render_conventional builds it."""
    tex = _smooth_texture(seed)
    views = np.stack([_slanted_image(tex, d, 0.0) for d in DIRS])
    i = np.arange(samples)
    points = np.sqrt(2.0) * np.sqrt((i + 0.5) / samples)[:, None] * np.column_stack(
        [np.cos(i * np.pi * (3 - np.sqrt(5))), np.sin(i * np.pi * (3 - np.sqrt(5)))])
    truth = np.mean([_slanted_image(tex, e, x_focus) for e in points], axis=0).astype(np.float32)
    depth = np.broadcast_to(1.0 / np.linspace(*SLANT_X, N), (N, N)).copy()
    return views, depth, truth


@pytest.mark.parametrize("x_focus", [1.5, 0.8, 2.2])
def test_a_slanted_plane_blurs_without_seams(x_focus):
    """A plane whose blur radius grows steadily across the frame, refocused with its exact depth
    against the image through the whole aperture: close to it everywhere (shift-and-add, with its
    copies, is 10 dB further), and no iso-depth column's mean error stands out. The layers'
    own seams are pinned closer by two tests below: a pixel that jumps from one layer to the
    next as the focus moves (layers that each take the pixels nearest their radius) fails
    test_the_blur_changes_continuously_with_the_focus_and_the_depth, and a gap in the coverage
    where the radius crosses from one pair of rungs to the next (which the division by the
    coverage hides on a lone surface, but which shows whatever lies behind) fails
    test_a_continuous_surface_s_layers_cover_it_wholly."""
    cal = _calibration()
    views, depth, truth = _slanted_plane(x_focus=x_focus)
    out = refocus(views, cal, 1.0 / x_focus, method="depth-aware", depth=depth)
    sa = refocus(views, cal, 1.0 / x_focus)
    inner = (slice(8, N - 8), slice(8, N - 8))
    psnr = 10 * np.log10(1.0 / np.mean((out[inner] - truth[inner]) ** 2))
    psnr_sa = 10 * np.log10(1.0 / np.mean((sa[inner] - truth[inner]) ** 2))
    assert psnr > 40.0 and psnr > psnr_sa + 10.0, (psnr, psnr_sa)
    # A seam runs along an iso-depth line, here a column: the error averaged down each column.
    column_error = (out - truth)[inner].mean(axis=(0, 2))
    assert np.abs(column_error).max() < 0.006, np.abs(column_error).max()


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="one thread: nothing to compare")
def test_renders_on_one_thread_and_on_two_are_the_same():
    """Every pass shares its rows among the threads without changing what a row sums: the image
    is the same to the bit on one thread and on two, far and near rungs, full and reduced grids."""
    cal = _calibration()
    views, depth, _ = _slanted_plane(samples=8)
    depth[:, 30:] = FAR_M  # most of the frame on one pair of rungs
    depth[20:50, 50:70] = NEAR_M  # and rungs on the focus's other side
    dof = depth_of_field(views, cal, depth=depth)
    for focus_m, aperture in ((1.0, 1.0), (1.0, 2.5), (0.7, 1.0)):
        with numba_threads(1):
            one = dof.render(focus_m, aperture)
        with numba_threads(2):
            two = dof.render(focus_m, aperture)
        assert np.array_equal(one, two)
        assert np.isfinite(one).all() and one.std() > 0.01


def test_a_renderer_reused_renders_what_a_fresh_one_does():
    """The renderer keeps its layers' memory between renders (fresh memory comes zeroed, reused
    memory is cleared): foci whose layers need more memory, then less, then more again, give
    the same images to the bit as a renderer made for each."""
    cal = _calibration()
    views, depth, _ = _slanted_plane(samples=8)
    depth[20:50, 50:70] = NEAR_M
    reused = depth_of_field(views, cal, depth=depth)
    for focus_m, aperture in ((1.0 / 1.5, 0.5), (1.0, 2.5), (1.0 / 1.5, 0.3), (FAR_M, 3.0), (NEAR_M, 1.0)):
        fresh = depth_of_field(views, cal, depth=depth)
        assert np.array_equal(reused.render(focus_m, aperture), fresh.render(focus_m, aperture)), (focus_m, aperture)


def test_a_renderer_moved_through_nearby_foci_keeps_its_memory(monkeypatch):
    """The layers' sizes change a little with the focus; the renderer's scratch grows with room
    to spare (fresh memory costs a page fault per page on first write), so a slider's worth of
    nearby foci makes almost none anew, and renders what a fresh renderer does."""
    from lfring.focus import layers

    cal = _calibration()
    views, depth, _ = _slanted_plane(samples=8)
    depth[20:50, 50:70] = NEAR_M
    dof = depth_of_field(views, cal, depth=depth)
    dof.render(NEAR_M, 1.0)
    made = []
    real = layers.fresh_zeros
    monkeypatch.setattr(layers, "fresh_zeros", lambda size: made.append(size) or real(size))
    foci = NEAR_M + (FAR_M - NEAR_M) * np.linspace(0.0, 0.3, 40)
    for focus_m in foci:
        img = dof.render(focus_m, 1.0)
    assert len(made) <= 2, made
    assert np.array_equal(img, depth_of_field(views, cal, depth=depth).render(foci[-1], 1.0))


def test_a_render_stopped_midway_leaves_the_next_one_right(monkeypatch):
    """A render leaves its composite's memory zeros for the next, which then does not clear it;
    one stopped after compositing began (an error, an interrupt) must not: the next render
    clears it, and gives the same image to the bit as a fresh renderer."""
    from lfring.focus import depth_aware_kernels as kern

    cal = _calibration()
    views, depth, _ = _slanted_plane(samples=8)
    depth[20:50, 50:70] = NEAR_M
    dof = depth_of_field(views, cal, depth=depth)
    first = dof.render(FAR_M, 1.0)  # leaves the composite zeros
    real_over = kern.over

    def over_then_stop(acc, *args):
        real_over(acc, *args)
        if acc.shape[:2] == depth.shape:  # the full-resolution composite, not a reduced group's
            assert acc.any()  # it holds layers when the render stops
            raise KeyboardInterrupt

    monkeypatch.setattr(kern, "over", over_then_stop)
    with pytest.raises(KeyboardInterrupt):
        dof.render(1.0 / 1.5, 2.5)
    monkeypatch.setattr(kern, "over", real_over)
    fresh = depth_of_field(views, cal, depth=depth)
    assert np.array_equal(dof.render(NEAR_M, 1.0), fresh.render(NEAR_M, 1.0))
    assert np.array_equal(dof.render(FAR_M, 1.0), first)


def test_one_renderer_used_from_several_threads_renders_what_it_renders_alone():
    """Renders share the renderer's kept memory: from a thread pool they came out mixed (parts
    of one focus's layers in another's image). They render one at a time now, each image as
    a serial render gives it; a pickled renderer renders the same images too."""
    import pickle
    from concurrent.futures import ThreadPoolExecutor

    cal = _calibration()
    views, depth, _ = _slanted_plane(samples=8)
    depth[20:50, 50:70] = NEAR_M
    dof = depth_of_field(views, cal, depth=depth)
    foci = [(1.0 / 1.5, 0.5), (1.0, 2.5), (FAR_M, 3.0), (NEAR_M, 1.0)] * 3
    alone = {f: dof.render(*f) for f in set(foci)}
    with ThreadPoolExecutor(4) as pool:
        together = list(pool.map(lambda f: dof.render(*f), foci))
    for f, image in zip(foci, together):
        assert np.array_equal(image, alone[f]), f
    copy = pickle.loads(pickle.dumps(dof))
    assert np.array_equal(copy.render(1.0, 2.5), alone[(1.0, 2.5)])
    for bad in (float("nan"), -0.5, cal.depth_origin_m, "1.0", None):
        with pytest.raises(InvalidInputError, match="focus_m must be a depth in metres"):
            dof.render(bad, 1.0)
    assert np.isfinite(dof.render(float("inf"), 1.0)).all()


def test_a_continuous_surface_s_layers_cover_it_wholly():
    """A slanted surface's pixels are each shared between the two rungs around their blur
    radius, and the two are one surface, which does not hide itself: composited far to near, its
    layers cover it wholly away from the frame's edge. Where the rung behind is not seen through
    the one in front (the rule for adjacent rungs broken) every boundary between two pairs of
    rungs lost up to a quarter of its coverage (0.75 at worst here), a seam through which
    anything behind the surface would show."""
    import lfring.focus.depth_aware_kernels as kern
    from lfring.focus.layers import NO_IMAGE, Grid, composite, ladder

    rng = np.random.default_rng(5)
    x = np.broadcast_to(np.linspace(*SLANT_X, N, dtype=np.float32), (N, N)).copy()
    ones = np.ones((N, N), np.float32)
    x_focus, motion = 1.5, GAIN * math.sqrt(2.0)
    rmax = motion * max(abs(v - x_focus) for v in SLANT_X)  # 5.7 px: full-resolution rungs and one reduced
    grid = Grid(ladder(rmax), (N, N), 3, (x_focus, motion, 1.0), {}, (0.5, 1.0, 0.0), 1.0)
    acc = composite(grid.layers(kern, x, ones, ones, rng.random((N, N, 3)).astype(np.float32), NO_IMAGE), grid, kern)
    m = math.ceil(rmax) + 2  # beyond the blurs' reach of the frame's edge
    coverage = acc[m:N - m, m:N - m, 3]
    assert grid.factors.max() == 2 and np.abs(coverage - 1.0).max() < 0.04, (coverage.min(), coverage.max())


def test_the_blur_changes_continuously_with_the_focus_and_the_depth():
    """A small change of the focus depth, or of the depth map, changes the image a little: no
    pixel jumps from one layer to another."""
    cal = _calibration()
    views, depth, _ = _slanted_plane(samples=1)
    z = 1.0 / 1.5
    a = refocus(views, cal, z, method="depth-aware", depth=depth)
    b = refocus(views, cal, z * 1.002, method="depth-aware", depth=depth)
    c = refocus(views, cal, z, method="depth-aware", depth=depth * 1.002)
    # 0.2 % of the focus distance moves every radius by under 0.01 px.
    assert np.abs(a - b).max() < 0.01 and np.abs(a - c).max() < 0.01, (np.abs(a - b).max(), np.abs(a - c).max())


def test_a_uniform_scene_stays_uniform_whatever_the_depth_map():
    """Every weight is normalised: a uniform scene renders uniform for any depth map (steps,
    slopes, noise, views valid only in discs), at any focus and aperture; a dark speck, a halo or
    a seam would show as a departure."""
    rng = np.random.default_rng(11)
    yy, xx = np.mgrid[0:N, 0:N]
    depth = 1.0 / (0.6 + 1.8 * xx / N + 0.3 * rng.standard_normal((N, N)).clip(-1.5, 1.5))
    depth[20:50, 30:70] = 0.4
    depth[60:80, 10:40] = 3.0
    cal = _calibration(tuple((N / 2, N / 2, N / 2 - 6) for _ in range(4)))
    views = np.full((4, N, N, 3), 0.6, np.float32)
    seen = refocus(views, cal, FAR_M)[..., 0] > 0.3
    for focus, aperture in ((FAR_M, 1.0), (NEAR_M, 1.0), (1.0, 2.5), (0.7, 0.3)):
        out = refocus(views, cal, focus, method="depth-aware", depth=depth, aperture=aperture)
        # 0.6 wherever anything is rendered; nothing only where no view sees the pixel at its
        # own depth (a few pixels at the discs' edge, where the depth map is noise).
        rendered = out[..., 0] > 0
        np.testing.assert_allclose(out[rendered], 0.6, atol=1e-5)
        assert (seen & ~rendered).mean() < 0.002, (seen & ~rendered).mean()


def test_no_seam_follows_the_views_disc_rims():
    """Views that differ in brightness by more than the agreement tolerance (each its own
    vignetting) and fade out at their discs' rims: the all-in-focus image of a plane changes
    across every rim no faster than shift-and-add's average of the same views, although a
    different number of views sees each pixel and they disagree."""
    cal = _calibration(DISCS)
    gains = np.array((0.84, 1.0, 1.12, 0.93), np.float32)
    ramp = np.broadcast_to(np.linspace(0.3, 0.6, N + 32, dtype=np.float32)[None, :, None], (N + 32, N + 32, 3))
    views, _, _ = _scene(np.ascontiguousarray(ramp), np.ascontiguousarray(ramp), with_near=False)
    views = (views * gains[:, None, None, None]).astype(np.float32)
    depth = np.full((N, N), FAR_M)
    sa = refocus(views, cal, FAR_M)[..., 0]
    out = refocus(views, cal, FAR_M, method="depth-aware", depth=depth, aperture=0.0)[..., 0]
    inner = cv2.erode((sa > 0.1).astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)

    def steepest(img):
        step = np.zeros_like(img)
        step[:, 1:] = np.abs(np.diff(img, axis=1))
        step[1:, :] = np.maximum(step[1:, :], np.abs(np.diff(img, axis=0)))
        return float(step[inner].max())

    assert steepest(out) < 1.25 * steepest(sa), (steepest(out), steepest(sa))


@pytest.mark.parametrize("box", [(slice(4, 40), slice(30, 70)), (slice(30, 70), slice(4, 40)), (slice(56, 92), slice(30, 70))])
def test_a_depth_continued_into_a_rim_cuts_no_seam(box):
    """Where fewer than two views' worth see a surface at its depth (the discs' rims), the
    renderer continues the depth of the nearest pixel that enough views see. A near plane that
    reaches the rim of a far one: continued with a step where the two planes' nearest pixels
    meet, the far plane's rim beside the near one's corners was sampled at the near depth (wedges
    of misplaced texture cut by straight seams, as in the corners of the main job's image). With
    the exact depth map, the all-in-focus image of the far plane is its texture there. Both
    planes carry smooth ramps, so a sample taken at a wrong depth shows as an error."""
    cal = _calibration(DISCS)
    yy, xx = np.mgrid[0:N + 32, 0:N + 32]

    def ramp(lo, span):
        return np.repeat((lo + span * (xx + yy) / (2 * (N + 32)))[..., None], 3, axis=2).astype(np.float32)

    far = ramp(0.2, 0.5)
    views, depth, near_mask = _scene(far, ramp(0.6, 0.3), box=box)
    weight = Refocuser(cal, FAR_M).weight
    out = refocus(views, cal, FAR_M, method="depth-aware", depth=depth, aperture=0.0)[..., 0]
    # The far plane's pixels that some view sees, not at the near plane's edge; the rims among them.
    far_px = (out > 0.05) & (weight > 0.5) & ~cv2.dilate(near_mask.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    assert (far_px & (weight < 2.0)).sum() > 500  # the rims are there
    error = np.abs(out - far[16:-16, 16:-16, 0])[far_px]
    assert np.percentile(error, 99) < 0.03, np.percentile(error, 99)


def _estimated(depth_m: np.ndarray, filled_m=None, confidence=None) -> DepthResult:
    """``depth_m`` recorded as depth estimation's result (NaN where it was not measured), with
    ``filled_m`` as its hole-filled map and its ``confidence`` (1 everywhere by default)."""
    h, w = depth_m.shape
    conf = np.ones((h, w), np.float32) if confidence is None else confidence.astype(np.float32)
    return DepthResult(depth_m.astype(np.float32), conf, np.zeros((h, w), np.float32), np.linspace(0.4, 3.0, 40), 1.0,
                       "center", "lcn-halves", "box", "sgm",
                       depth_filled_m=None if filled_m is None else filled_m.astype(np.float32))


def test_an_estimate_takes_its_fill_on_a_smooth_surface_and_its_winner_at_an_edge():
    """Where depth estimation was not confident, its depth is the unrefined winner and its
    hole-filled map the smoother's fill. On a smooth surface (a patch of the far plane, its
    winner wrong) the fill is rendered; across a depth edge (a band over the near plane's right
    edge, its fill between the two planes) the winner."""
    cal = _calibration()
    far, near = _textures()
    views, depth, near_mask = _scene(far, near)
    truth = np.where(near_mask[..., None], near[16:-16, 16:-16], far[16:-16, 16:-16])
    winner, filled = depth.astype(np.float64), depth.astype(np.float64)
    confidence = np.ones(depth.shape)
    patch = (slice(78, 90), slice(72, 88))  # inside the far plane, over 10 px from the near one
    winner[patch] = NEAR_M
    band = (slice(36, 64), slice(57, 64))  # over the near plane's right edge (column 60), as narrow as such bands are
    filled[band] = 2.0 / (1.0 / NEAR_M + 1.0 / FAR_M)
    confidence[patch] = confidence[band] = 0.0
    estimate = _estimated(winner, filled, confidence)
    out = refocus(views, cal, FAR_M, method="depth-aware", depth=estimate, aperture=0.0)
    aif = all_in_focus(views, cal, depth_map_m=estimate)[0]  # the same rule
    for img in (out, aif):
        np.testing.assert_allclose(img[patch], truth[patch], atol=0.02)
        np.testing.assert_allclose(img[band], truth[band], atol=0.02)


@pytest.mark.parametrize("box", [(slice(0, 96), slice(20, 60)), (slice(4, 40), slice(30, 70))])
def test_an_estimated_depth_counts_where_fewer_views_see_it(box):
    """Depth estimation says itself where it measured a depth (NaN elsewhere), counting views by
    its own taper: the renderer keeps such a depth wherever MIN_ESTIMATED_VIEWS views' worth see
    the pixel, fewer than a bare map needs (MIN_DEPTH_VIEWS: its origin is unknown, and a depth
    that few views see may be a stand-in). A strip of the far plane between a near plane and the
    discs' rims, whose nearest pixels that two views see are the near plane's, is then sampled at
    the far plane's depth and shows its texture."""
    cal = _calibration(DISCS)
    far, near = _textures()
    views, depth, near_mask = _scene(far, near, box=box)
    out = refocus(views, cal, FAR_M, method="depth-aware", depth=_estimated(depth), aperture=0.0)
    weight = Refocuser(cal, FAR_M).weight
    # The far plane's pixels that some view sees, beyond the reach of the near plane's occlusion
    # (its copies lie 6 px from the far plane's: a rim's one view may see the near plane there).
    far_px = (weight >= MIN_ESTIMATED_VIEWS) & ~cv2.dilate(near_mask.astype(np.uint8), np.ones((15, 15), np.uint8)).astype(bool)
    assert (far_px & (weight < MIN_DEPTH_VIEWS)).sum() > 100  # where a bare map's depth would not count
    # The all-in-focus image from the estimate follows the same rule, with or without depths to snap to.
    for img in (out, all_in_focus(views, cal, depth_map_m=_estimated(depth))[0],
                all_in_focus(views, cal, [NEAR_M, FAR_M], depth_map_m=_estimated(depth))[0]):
        error = np.abs(img - far[16:-16, 16:-16]).max(axis=2)[far_px]
        assert error.max() < 0.02, error.max()


def test_a_slant_without_depth_at_the_frame_edge_is_continued_along_its_slope():
    """Where a slanted surface has no depth (the frame's edge, which fewer views see, or a map's
    unknown band), the renderer continues the plane that the measured depths around lie on, not
    the depth of the nearest measured pixel (here up to 0.4 of x = 1/Z off, the views 1.6 px apart):
    the all-in-focus image there is what the exact depth gives. (Beside a depth edge no plane
    fits and the nearest depth is continued: the next test's hole.)"""
    cal = _calibration()
    views, depth, _ = _slanted_plane()
    exact, _ = all_in_focus(views, cal, depth_map_m=depth)
    # Bands at the left and right (their nearest measured pixels inside the frame) and at the top
    # (theirs along the row below, out to the frame's corners: the plane there is the outermost
    # fitted one, extended, not its value held).
    for band in ((slice(None), slice(0, 20)), (slice(None), slice(N - 20, N)), (slice(0, 20), slice(None))):
        unknown = depth.copy()
        unknown[band] = np.nan
        img, chosen = all_in_focus(views, cal, depth_map_m=unknown)
        assert np.isnan(chosen[band]).all()
        inner = tuple(slice(max(b.start or 0, 3), min(b.stop or N, N - 3)) for b in band)
        error = np.abs(img - exact)[inner]
        assert error.max() < 0.01 and error.mean() < 0.002, (band, error.max(), error.mean())


def test_unknown_depths_are_continued_from_the_nearest_known_ones():
    """An unknown depth (NaN) is not a measurement: it takes the nearest known pixel's depth,
    not a stand-in that happens to be seen by enough views (the known depths' median, here the
    near plane's, which covers most of the frame)."""
    cal = _calibration()
    far, near = _textures()
    big = (slice(0, 96), slice(0, 60))  # the near plane over most of the frame
    views, depth, _ = _scene(far, near, box=big)
    hole = (slice(40, 56), slice(72, 88))  # inside the far plane, every view sees it
    unknown = depth.astype(np.float64)
    unknown[hole] = np.nan
    for given in (unknown, _estimated(unknown)):
        out = refocus(views, cal, FAR_M, method="depth-aware", depth=given, aperture=0.0)
        np.testing.assert_allclose(out[hole], far[16:-16, 16:-16][hole], atol=0.02)
        # The all-in-focus image from the same map, its first depth the near plane's: the hole
        # continues the far plane too, and says it had no depth of its own.
        for depths in ([NEAR_M, FAR_M], None):
            img, chosen = all_in_focus(views, cal, depths, depth_map_m=given)
            np.testing.assert_allclose(img[hole], far[16:-16, 16:-16][hole], atol=0.02)
            assert np.isnan(chosen[hole]).all() and np.isnan(chosen).sum() == chosen[hole].size
    with pytest.raises(InvalidInputError, match="frame of reference 'center', the refocusing in 0"):
        all_in_focus(views, cal, [NEAR_M, FAR_M], depth_map_m=_estimated(unknown), reference=0)
    with pytest.raises(InvalidInputError, match="the depth map holds no finite depth beyond the depth origin"):
        all_in_focus(views, cal, [NEAR_M, FAR_M], depth_map_m=np.full(depth.shape, np.nan))
    with pytest.raises(InvalidInputError, match=r"must be \(h, w\) = \(96, 96\) metres like the views, got shape \(4, 4\)"):
        all_in_focus(views, cal, [NEAR_M, FAR_M], depth_map_m=np.ones((4, 4)))
    # Zeros (many depth sensors' "no reading"), negatives, depths nearer than z0 and infinities
    # are no depths either: rendered as NaN is, and said.
    nan_out = refocus(views, cal, FAR_M, method="depth-aware", depth=unknown, aperture=0.0)
    for bad in (0.0, -0.5, np.inf, -np.inf):
        odd = depth.astype(np.float64)
        odd[hole] = bad
        with pytest.warns(LfringWarning, match=r"256 pixels of the depth map \(2.8%\) are not depths beyond the depth "
                                               r"origin z0 = 0 m .*taken as unknown, as NaN is"):
            out = refocus(views, cal, FAR_M, method="depth-aware", depth=odd, aperture=0.0)
        np.testing.assert_array_equal(out, nan_out)
    with pytest.raises(InvalidInputError, match=r"the depth map must be \(h, w\) metres"):
        refocus(views, cal, FAR_M, method="depth-aware", depth="far")


def test_a_renderer_given_as_the_depth_map_is_used_as_it_is(renderers_made):
    """A renderer made from the views (depth_of_field) and given where a depth map is taken gives
    refocus, focal_stack and all_in_focus what the map itself gives, to the bit, without being
    prepared again; one that does not fit the views, the calibration or the reference is refused."""
    cal = _calibration()
    far, near = _textures()
    views, depth, _ = _scene(far, near)
    unknown = depth.astype(np.float64)
    unknown[40:56, 72:88] = np.nan
    for given in (unknown, _estimated(unknown)):
        renderer = depth_of_field(views, cal, depth=given)
        expected = (refocus(views, cal, NEAR_M, method="depth-aware", depth=given, aperture=0.7),
                    focal_stack(views, cal, [NEAR_M, FAR_M], method="depth-aware", depth=given),
                    *all_in_focus(views, cal, depth_map_m=given),
                    *all_in_focus(views, cal, [NEAR_M, FAR_M], depth_map_m=given))
        renderers_made.clear()
        got = (refocus(views, cal, NEAR_M, method="depth-aware", depth=renderer, aperture=0.7),
               focal_stack(views, cal, [NEAR_M, FAR_M], method="depth-aware", depth=renderer),
               *all_in_focus(views, cal, depth_map_m=renderer))
        assert renderers_made == []  # none prepared again
        got += all_in_focus(views, cal, [NEAR_M, FAR_M], depth_map_m=renderer)  # snapped: a new one from its map
        assert len(renderers_made) == 1
        for a, b in zip(got, expected, strict=True):
            np.testing.assert_array_equal(a, b)
    with pytest.raises(InvalidInputError, match=r"made from 4 views of \(96, 96, 3\) \(h, w, C\), these are 4 of \(96, 96, 1\)"):
        all_in_focus(views[..., :1], cal, depth_map_m=renderer)
    with pytest.raises(InvalidInputError, match=r"made from 4 views .* these are 3 of \(96, 96, 3\)"):
        all_in_focus(views[:3], cal, depth_map_m=renderer)
    with pytest.raises(InvalidInputError, match="made from other views"):
        focal_stack(views[:, ::-1].copy(), cal, [NEAR_M], method="depth-aware", depth=renderer)
    with pytest.raises(InvalidInputError, match="made with another calibration"):
        refocus(views, _calibration(), NEAR_M, method="depth-aware", depth=renderer)
    with pytest.raises(InvalidInputError, match="in the frame of reference 'center', the refocusing in 0"):
        focal_stack(views, cal, [NEAR_M], method="depth-aware", depth=renderer, reference=0)
    with pytest.raises(InvalidInputError, match="give them or a depth map, not both"):
        depth_of_field(views, cal, depth=renderer, zmin_m=0.5)


def test_an_f_number_wider_than_the_lens_is_warned_of():
    """f/0.5 on the prototype (its main lens opens to f/1.6) was taken without a word: the image
    is of a lens the camera does not have. Warned of; its own f-number and narrower are not."""
    import warnings

    dev = load_device("prototype")
    with pytest.warns(LfringWarning, match=r"f/0.5 is wider than the main lens of device 'prototype' opens \(f/1.6\)"):
        wide = aperture_from_f_number(0.5, dev)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert aperture_from_f_number(1.6, dev) < wide and aperture_from_f_number(2.8, dev) > 0


def test_f_number_works_with_the_built_in_calibration():
    """The shipped calibration of the twin records the device it was made from, so an f-number
    can be turned into an aperture without naming the device."""
    from pathlib import Path

    cal = RingCalibration.load(Path(__file__).resolve().parents[2] / "calib" / "twin_binned2.json")
    assert cal.device == "prototype"
    assert resolve_aperture(cal, f_number=2.8) == pytest.approx(aperture_from_f_number(2.8, load_device("prototype")), rel=1e-6)


def test_the_depth_range_of_a_calibration_without_an_upper_bound():
    """estimation_range: the optics' open range gets a far end where the views stop moving,
    over which they move by a small part of their size; a grid's (open from where its views
    stop overlapping) would hold every disparity they can show, and is refused saying what to
    give, unless its near end is given."""
    from lfring.calibration.model import view_motion_px
    from lfring.depth.hypotheses import depth_hypotheses
    from lfring.focus.depth_aware import DERIVED_RANGE_MAX_MOTION, FAR_MOTION_PX, estimation_range

    optics = RingCalibration.from_optics(load_device("prototype").binned(2))
    lo, hi = estimation_range(optics)
    assert lo == optics.valid_depth_range_m[0]
    assert hi == pytest.approx(optics.depth_origin_m + aperture_radius_px(optics) / FAR_MOTION_PX)
    side = min(optics.layout.view_shape)
    assert view_motion_px(optics, [lo, hi], optics.layout.view_shape) < 0.25 * side < DERIVED_RANGE_MAX_MOTION * side
    assert estimation_range(optics, zmax_m=2.0) == (lo, 2.0)
    # A bounded calibration: its range as it is, or as given.
    cal = _calibration()
    assert estimation_range(cal) == (0.4, 3.0) and estimation_range(cal, 0.5, 2.5) == (0.5, 2.5)
    # Grids: a pair, and a 10 x 10 grid whose outer views would move by nine times their width.
    pair = RingCalibration.from_grid((64, 96), [(0, 0), (1, 0)], disparity_scale_px_m=120.0)
    grid = RingCalibration.from_grid((40, 48), [(x, y) for y in range(10) for x in range(10)], disparity_scale_px_m=120.0)
    for g in (pair, grid):
        with pytest.raises(InvalidInputError, match=r"no upper depth bound, and none follows from it.*as zmax_m.*"
                                                    r"method='shift-and-add'"):
            estimation_range(g)
    assert estimation_range(pair, zmax_m=20.0) == (1.25, 20.0)
    # From a near end the scene has (20 px of disparity), the far end follows: 1 px at 120 m.
    lo, hi = estimation_range(pair, zmin_m=6.0)
    assert (lo, hi) == pytest.approx((6.0, 120.0)) and len(depth_hypotheses(pair, lo, hi)) == 20
    for bad in ({"zmin_m": -1.0}, {"zmax_m": float("nan")}, {"zmax_m": "far"}):
        with pytest.raises(InvalidInputError, match="must be a distance in metres"):
            estimation_range(pair, **bad)


def test_never_brighter_or_darker_than_the_views_however_wide_the_blur():
    """A blur is a weighted average: at any aperture (wide ones blur on reduced grids, whose
    reconstruction must not overshoot where little covers a pixel, at the frame's corners) the
    image stays within the views' values."""
    import lfring

    cal = lfring.RingCalibration.load("twin_binned2")
    views = lfring.split_views(lfring.demosaic(lfring.load_raw(SCENE)), cal)
    lo, hi = float(views.min()), float(views.max())
    far = np.full(cal.layout.view_shape, 1.0, np.float32)
    dof = depth_of_field(views, cal, depth=far)
    sharp = refocus(views, cal, 0.5)
    for aperture in (1.0, 3.0, 6.0, 8.0):
        out = dof.render(0.5, aperture, sharp)
        assert lo - 1e-6 <= float(out.min()) and float(out.max()) <= hi + 1e-6, (aperture, out.min(), out.max(), hi)


def test_a_depth_map_in_millimetres_is_warned_of():
    """A depth map in millimetres rendered as a scene hundreds of metres away without a word
    (all_in_focus reported depths of 500-2000 m): warned, as for a focus depth in mm."""
    cal = _calibration()
    far, near = _textures()
    views, depth, _ = _scene(far, near)
    with pytest.warns(LfringWarning, match=r"the depth map's depths lie beyond the calibration's range \(median 2000 m\); "
                                           r"depths are in metres: was 2000 given in mm\?"):
        refocus(views, cal, FAR_M, method="depth-aware", depth=depth * 1000.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        refocus(views, cal, FAR_M, method="depth-aware", depth=depth)


def test_a_far_scene_with_an_open_calibration_is_not_taken_for_millimetres():
    """A calibration open to infinity says nothing of a far scene's unit: a landscape at 2000 m was
    asked whether it was given in mm."""
    cal = RingCalibration.from_grid((N, N), [(0, 0), (1, 0), (0, 1), (1, 1)], disparity_scale_px_m=8.0)
    assert cal.valid_depth_range_m[1] is None
    views = np.full((4, N, N, 3), 0.5, np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        refocus(views, cal, 50.0, method="depth-aware", depth=np.full((N, N), 2000.0), aperture=0.5)
