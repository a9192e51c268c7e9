"""The hard scene of the twin: its per-view depth is the analytic surfaces' (slanted and turned
planes, discs, a spherical cap and a cylindrical ridge, thin wires), and its per-view vignetting
differs by view as set."""

import numpy as np
import pytest

from lfring.errors import InvalidInputError
from lfring.optics import paraxial
from lfring.optics.views import optical_layout, view_cameras, vignetting_region
from lfring.synth import Bump, HeightField, Plane, Scene, Texture, render, view_falloff_map
from lfring.synth.presets import HARD_VIEW_FALLOFF, hard_scene, load_scene

BIN = 4


def _plane_hit(plane: Plane, o, d):
    """Depth (NaN where missed) of rays o + t d (d with unit Z) on a finite plane."""
    p0, u, v, n = plane.axes()
    t = ((p0 - o) @ n) / (d @ n)
    pts = o + t[..., None] * d
    a, b = (pts - p0) @ u / (plane.size_m[0] / 2), (pts - p0) @ v / (plane.size_m[1] / 2)
    inside = (np.abs(a) < 1) & (np.abs(b) < 1) if plane.shape == "rect" else (a * a + b * b < 1)
    return np.where(inside & (t > 0), o[2] + t, np.nan)


def _quadratic_near(a, b, c):
    disc = b * b - 4 * a * c
    with np.errstate(invalid="ignore"):
        return np.where(disc >= 0, (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a), np.nan)


def _part_hit(part: HeightField, o, d):
    """Depth of rays on a part of fronto-parallel base with sphere and cylinder bumps, solved in
    closed form (ray-sphere, ray-cylinder), independently of the renderer's iteration."""
    left, top = part.center_m[0] - part.size_m[0] / 2, part.center_m[1] - part.size_m[1] / 2
    z_base = part.depth_m
    t = z_base - o[2]
    x, y = o[0] + t * d[..., 0] - left, o[1] + t * d[..., 1] - top
    on_part = (x > 0) & (x < part.size_m[0]) & (y > 0) & (y < part.size_m[1])
    best = np.where(on_part, z_base, np.nan)
    for b in part.bumps:
        assert b.shape in ("sphere", "cylinder") and b.height_m > 0
        r = b.radius_m
        cx, cy, cz = left + b.center_m[0], top + b.center_m[1], z_base - b.height_m + r
        oc = o - np.array([cx, cy, cz])
        if b.shape == "sphere":
            tt = _quadratic_near((d * d).sum(-1), 2 * (d @ oc), oc @ oc - r * r)
        else:
            dx, dz = d[..., 0], d[..., 2]
            tt = _quadratic_near(dx * dx + dz * dz, 2 * (dx * oc[0] + dz * oc[2]), oc[0] ** 2 + oc[2] ** 2 - r * r)
        z = o[2] + tt
        yy = o[1] + tt * d[..., 1] - top
        ok = np.isfinite(z) & (z < z_base)
        if b.shape == "cylinder":
            ok &= np.abs(yy - b.center_m[1]) < b.size_m[1] / 2
        best = np.where(ok & ~(best < z), z, best)
    return best


def _analytic_depth(scene: Scene, o, d):
    """(h, w) nearest analytic depth and (h, w) index of the surface it is on (-1: none)."""
    depth = np.full(d.shape[:-1], np.inf)
    label = np.full(d.shape[:-1], -1)
    for i, s in enumerate(scene.surfaces):
        z = _plane_hit(s, o, d) if isinstance(s, Plane) else _part_hit(s, o, d)
        nearer = np.isfinite(z) & (z < depth)
        depth[nearer], label[nearer] = z[nearer], i
    return depth, label


@pytest.fixture(scope="module")
def hard(prototype):
    return render(prototype, hard_scene(), binning=BIN, pattern=None, view_falloff=HARD_VIEW_FALLOFF)


def test_hard_scene_depth_is_the_analytic_surfaces(hard):
    r, scene = hard, hard_scene()
    dev, cams = r.device, view_cameras(r.device)
    seen = set()
    for k, (x, y, w, h) in enumerate(r.layout.rects):
        yy, xx = np.indices((h, w))
        o, d = cams.rays_m(k, paraxial.pixel_to_sensor(dev, np.stack([xx + x, yy + y], -1)))
        want, label = _analytic_depth(scene, o, d)
        # Away from silhouettes (where coverage, not the surface, decides): pixels whose 3 x 3
        # neighbourhood is on one surface.
        pad = np.pad(label, 1, mode="edge")
        same = np.ones_like(label, bool)
        for dy in range(3):
            for dx in range(3):
                same &= pad[dy : dy + h, dx : dx + w] == label
        inner = same & (label >= 0) & r.layout.masks()[k]
        got = r.depth_m[k]
        assert np.isfinite(got[inner]).all()
        err = np.abs(got[inner] - want[inner])
        assert err.max() < 1e-7, (k, err.max())  # float32 rounding of metres near 1 m
        seen |= set(np.unique(label[inner]).tolist())
        # And pixels that see nothing analytically see nothing in the render, and back.
        assert not np.isfinite(got[(label < 0) & same]).any()
        assert np.isfinite(got[(label >= 0) & same]).all()
    wires = {i for i, s in enumerate(scene.surfaces) if "wire" in s.name}
    assert seen >= set(range(len(scene.surfaces))) - wires  # every surface is checked, and
    # the wires, 2 px wide here, on their centre lines too, where every view sees them.
    for i in wires:
        p0, u, v, _ = scene.surfaces[i].axes()
        along = u if scene.surfaces[i].size_m[0] > scene.surfaces[i].size_m[1] else v
        pts = p0 + np.linspace(-0.03, 0.03, 25)[:, None] * along
        for k, (x, y, w, h) in enumerate(r.layout.rects):
            px = paraxial.sensor_to_pixel(dev, cams.project_m(pts)[k]) - [x, y]
            col, row = np.rint(px).astype(int).T
            np.testing.assert_allclose(r.depth_m[k][row, col], 0.33, atol=1e-6)


def test_hard_scene_has_what_it_promises(hard):
    r, scene = hard, hard_scene()
    names = [s.name for s in scene.surfaces]
    dev = r.device
    # Thin wires: 3 to 5 px wide in the views at 2 x 2 binning (here BIN: half that).
    px_m = 2 * dev.pixel_pitch_m / BIN  # one 2 x 2 binned pixel in metres on the sensor
    cams = view_cameras(dev)
    for s in scene.surfaces:
        if "wire" in s.name:
            width_px = min(s.size_m) * cams.focal_m / (s.depth_m - cams.depth_origin_m) / px_m
            assert 2.5 < width_px < 5.0, (s.name, width_px)
    # Slanted and curved surfaces: depth varies over them; the textureless card is one colour.
    slanted = [s for s in scene.surfaces if isinstance(s, Plane) and s.tilt_deg != (0.0, 0.0)]
    assert len(slanted) >= 3 and any(s.tilt_deg[0] and s.tilt_deg[1] for s in slanted)
    assert any(isinstance(s, HeightField) and s.curved for s in scene.surfaces)
    card = scene.surfaces[names.index("textureless card")]
    assert card.texture.kind == "constant"
    assert any(s.shape == "disk" for s in scene.surfaces if isinstance(s, Plane))
    assert any(s.roll_deg % 90 for s in scene.surfaces if isinstance(s, Plane))
    # Depth edges: nearest and farthest surfaces both seen in every view.
    for k in range(4):
        z = r.depth_m[k]
        assert np.nanmin(z) == pytest.approx(0.33, abs=1e-6) and np.nanmax(z) > 1.0


def test_per_view_falloff_multiplies_the_optical_vignetting(prototype):
    white = Texture("constant", colors=((1.0, 1.0, 1.0),))
    scene = Scene((Plane(0.6, (0.6, 0.6), white),))
    kw = dict(binning=8, pattern=None, exposure=0.5)
    plain = render(prototype, scene, **kw)
    fall = render(prototype, scene, view_falloff=HARD_VIEW_FALLOFF, **kw)
    dev = plain.device
    lay = optical_layout(dev)
    for k, (x, y, w, h) in enumerate(lay.rects):
        vig = vignetting_region(dev, k, (x, y, w, h))
        extra = view_falloff_map(lay, k, (x, y, w, h), HARD_VIEW_FALLOFF)
        np.testing.assert_allclose(plain.views[k, ..., 1], 0.5 * vig, atol=1e-6)
        np.testing.assert_allclose(fall.views[k, ..., 1], 0.5 * vig * extra, atol=1e-6)
        # The extra fall-off is 1 at its centre (the disc centre moved by dx, dy radii) and
        # 1 / (1 + s)**2 one radius from it.
        s, ox, oy = HARD_VIEW_FALLOFF[k]
        cx, cy, rad = lay.circles[k]
        c = (int(round(cy + oy * rad)), int(round(cx + ox * rad)))
        assert extra[c] == pytest.approx(1.0, abs=1e-3)
        assert extra.min() < 1 / (1 + s) ** 2 + 1e-6
    # The views are lit differently: the mean brightness ratios to the plain render differ.
    ratios = [fall.views[k][lay.masks()[k]].mean() / plain.views[k][lay.masks()[k]].mean() for k in range(4)]
    assert max(ratios) - min(ratios) > 0.3
    # Ground truth is the same: depth and sharp views do not see the vignetting.
    np.testing.assert_array_equal(fall.depth_m, plain.depth_m)
    np.testing.assert_array_equal(fall.views_sharp, plain.views_sharp)
    # The fall-off belongs to the views, not to the frame: a rotated frame has the same views.
    rot = render(prototype, scene, view_falloff=HARD_VIEW_FALLOFF, rotate180=True, **kw)
    np.testing.assert_array_equal(rot.views, fall.views)
    with pytest.raises(InvalidInputError, match="view_falloff"):
        render(prototype, scene, view_falloff=((0.1, 0, 0),) * 3, **kw)


def test_roll_turns_a_plane_in_its_own_plane():
    sq = Plane(0.5, (0.02, 0.02), roll_deg=45.0)
    c = sq.corners_m()
    assert np.allclose(c[:, 2], 0.5)
    # A square turned by 45 degrees is a diamond: corners on the axes at half the diagonal.
    assert np.allclose(np.sort(np.abs(c[:, :2]).max(axis=1)), 0.01 * np.sqrt(2))
    assert Plane(0.5, (0.02, 0.02), roll_deg=90.0).corners_m()[:, :2] == pytest.approx(
        Plane(0.5, (0.02, 0.02)).corners_m()[[2, 0, 3, 1], :2], abs=1e-12)
    with pytest.raises(InvalidInputError, match="roll_deg"):
        Plane(0.5, (0.02, 0.02), roll_deg=float("nan"))


def test_curved_bumps_validate_and_load_from_toml(tmp_path):
    with pytest.raises(InvalidInputError, match="circular footprint"):
        Bump(center_m=(0, 0), size_m=(0.02, 0.03), height_m=0.005, shape="sphere")
    with pytest.raises(InvalidInputError, match="half sphere"):
        Bump(center_m=(0, 0), size_m=(0.02, 0.02), height_m=0.011, shape="sphere")
    cap = Bump(center_m=(0.02, 0.02), size_m=(0.02, 0.02), height_m=0.004, shape="sphere")
    assert cap.radius_m == pytest.approx((0.01**2 + 0.004**2) / 0.008)
    part = HeightField(0.4, (0.04, 0.04), bumps=(cap,))
    # The cap's top and rim, and a point on the sphere in between.
    assert part.height_at(0.02, 0.02) == pytest.approx(0.004)
    assert part.height_at(0.03, 0.02) == pytest.approx(0.0, abs=1e-15)
    r = cap.radius_m
    assert part.height_at(0.025, 0.02) == pytest.approx(np.sqrt(r * r - 0.005**2) - (r - 0.004))
    f = tmp_path / "s.toml"
    f.write_text("[[plane]]\ndepth_m = 0.5\nsize_m = [0.1, 0.1]\nroll_deg = 30.0\n"
                 "[[part]]\ndepth_m = 0.4\nsize_m = [0.04, 0.04]\n"
                 "[[part.bump]]\ncenter_m = [0.02, 0.02]\nsize_m = [0.01, 0.04]\nheight_m = 0.003\nshape = 'cylinder'\n")
    scene = load_scene(f)
    assert scene.surfaces[0].roll_deg == 30.0 and scene.surfaces[1].curved


@pytest.mark.parametrize("text, message", [
    ('background = "grey"\n[[plane]]\ndepth_m = 0.4\nsize_m = [0.2, 0.2]\n',
     "scene background must be an RGB triple in [0, 1], got 'grey'"),
    ('background = [2.0, -1, "x"]\n[[plane]]\ndepth_m = 0.4\nsize_m = [0.2, 0.2]\n',
     "scene background must be an RGB triple in [0, 1], got (2.0, -1, 'x')"),
    ("plane = 3\n", "plane must be an array of tables, each [[plane]] with its keys, got 3"),
    ("part = [1, 2]\n", "part must be an array of tables, each [[part]] with its keys, got [1, 2]"),
])
def test_a_scene_file_s_bad_values_are_named(tmp_path, text, message):
    """A word for the background crashed with ValueError ('could not convert string to float');
    a plane that is not a table with TypeError ('int' object is not iterable)."""
    from lfring.errors import FileFormatError

    f = tmp_path / "s.toml"
    f.write_text(text)
    with pytest.raises(FileFormatError) as info:
        load_scene(f)
    assert str(info.value) == f"{f}: {message}"
