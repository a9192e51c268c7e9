"""Ready-made scenes for the twin: a flat field, calibration targets, the paper's three-depth
scene and inspection parts, plus scenes described in TOML files."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np

from lfring.core.validate import check_number
from lfring.errors import FileFormatError, InvalidInputError, LfringFileNotFoundError
from lfring.optics import paraxial
from lfring.optics.device import MiniLens, RingDevice
from lfring.optics.views import lens_distortions, optical_layout, view_cameras
from lfring.synth.scene import Bump, HeightField, Plane, Scene
from lfring.synth.textures import Texture

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = [
    "PRESETS",
    "field_radius_m",
    "flat_scene",
    "target_scene",
    "three_depth_scene",
    "part_scene",
    "PART_SIZE_M",
    "DEFECT_CLEARANCE",
    "MAX_DEFECT_SIZE_M",
    "hard_scene",
    "HARD_VIEW_FALLOFF",
    "load_scene",
    "real_lenses",
    "rim_displacement_px",
]

PRESETS = ("flat", "target", "scene", "part", "hard")

#: The hard scene's extra per-view vignetting (``RenderSettings.view_falloff``): per view
#: (strength, dx, dy), from a mild centred fall-off to one that leaves about 30 % at the disc's
#: rim around a centre a quarter radius off, so the four views differ in brightness by place.
HARD_VIEW_FALLOFF = ((0.15, 0.0, 0.0), (0.6, 0.3, -0.2), (0.35, -0.25, 0.3), (0.9, 0.1, 0.25))

#: Side (metres) of the square plate of :func:`part_scene`.
PART_SIZE_M = 0.08
#: How far a defect's centre keeps from the plate's edge, in defect diameters (a defect lies
#: wholly on the plate, with some plate around it).
DEFECT_CLEARANCE = 0.75
#: Largest defect diameter (metres) of :func:`part_scene`: one defect with its clearance on
#: both sides spans the plate.
MAX_DEFECT_SIZE_M = PART_SIZE_M / (2 * DEFECT_CLEARANCE)


def real_lenses(device: RingDevice, *, rim_fraction: float = 0.03, seed: int = 0) -> RingDevice:
    """``device`` fitted with four real mini-lenses, each its own: barrel distortion with some
    decentring, a lens a little off its place and tilted, and its own transmission and fall-off.

    Parameters
    ----------
    device : RingDevice
        With lens positions set (the distortion is scaled on its views' discs).
    rim_fraction : float
        The most any view's distortion moves a point of its disc's rim, as a fraction of the
        disc's radius; the other views move theirs by 55 to 95 % of that.
    seed : int
        Draws the lenses.

    Returns
    -------
    RingDevice
        With ``lenses`` set (:class:`lfring.optics.MiniLens`).

    Examples
    --------
    >>> from lfring.optics import load_device
    >>> dev = real_lenses(load_device("prototype").binned(2))
    >>> round(max(rim_displacement_px(dev)) / min(r for _, _, r in optical_layout(dev).circles), 3)
    0.03
    """
    check_number(rim_fraction, "rim_fraction", minimum=0.0, maximum=0.2, what="a fraction of the disc's radius")
    device.require_positions()
    rng = np.random.default_rng(seed)
    shares = np.concatenate([[1.0], rng.uniform(0.55, 0.95, 3)])[rng.permutation(4)]
    lenses = []
    for _ in range(4):
        k1 = -rng.uniform(0.6, 1.0)
        lenses.append(MiniLens(
            k1=k1, k2=k1 * rng.uniform(-0.4, 0.4) * 50.0, p1=k1 * rng.uniform(-0.08, 0.08), p2=k1 * rng.uniform(-0.08, 0.08),
            decentre_m=tuple(rng.uniform(-8e-6, 8e-6, 2)), tilt_deg=tuple(rng.uniform(-2.0, 2.0, 2)),
            transmission=float(rng.uniform(0.88, 1.0)),
            falloff=(float(rng.uniform(0.1, 0.5)), float(rng.uniform(-0.15, 0.15)), float(rng.uniform(-0.15, 0.15)))))
    dev = device.with_lenses(lenses)
    radius = min(r for _, _, r in optical_layout(device).circles)
    # The rim displacement is linear in the coefficients (up to the tilt): two scalings land it.
    for _ in range(3):
        rims = rim_displacement_px(dev)
        scaled = []
        for lens, rim, share in zip(dev.lenses, rims, shares):
            f = rim_fraction * radius * share / rim if rim > 0 else 0.0
            scaled.append(dataclasses.replace(lens, k1=lens.k1 * f, k2=lens.k2 * f, p1=lens.p1 * f, p2=lens.p2 * f))
        dev = device.with_lenses(scaled)
    return dev


def rim_displacement_px(device: RingDevice) -> list[float]:
    """How far each view's lens moves the points of its valid disc's rim, at most, in pixels
    (0 for ideal lenses)."""
    dist = lens_distortions(device)
    if dist is None:
        return [0.0] * 4
    from lfring.optics.views import ideal_discs_px

    out = []
    for d, (cx, cy, r) in zip(dist, ideal_discs_px(device)):
        t = np.linspace(0.0, 2 * np.pi, 720, endpoint=False)
        pts = np.stack([cx + r * np.cos(t), cy + r * np.sin(t)], axis=-1)
        out.append(float(np.max(np.hypot(*(d.distort(pts) - pts).T))))
    return out


def field_radius_m(device: RingDevice, depth_m: float) -> float:
    """Radius of the region around the optical axis at ``depth_m`` that every view can see
    (the views' discs projected to the plane, plus their lateral offsets)."""
    b, c = device.require_positions()
    cams = view_cameras(device)
    disc_m = device.effective_aperture_radius_m * c / b
    scale = (depth_m - cams.depth_origin_m) / cams.focal_m
    offset = float(np.abs(cams.centres_m).max() + np.abs(device.lens_centres_m * (1 + c / b) - cams.principal_points_m).max() * scale)
    return disc_m * scale + offset


def flat_scene(device: RingDevice) -> Scene:
    """A uniformly white field (the flat frame used to find the layout and the vignetting)."""
    r = field_radius_m(device, 1.0)
    white = Texture("constant", colors=((1.0, 1.0, 1.0),))
    return Scene((Plane(1.0, (3 * r, 3 * r), white, name="white field"),), name="flat")


def target_scene(device: RingDevice, depth_m: float, *, seed: int = 0) -> Scene:
    """A random-speckle calibration target filling the field at ``depth_m``.

    The speckle grain is chosen for the distance, as one would print a target for it: about
    four pixels of the 2 x 2 binned sensor, and larger than the defocus blur there, so the
    target keeps its contrast when out of focus.
    """
    check_number(depth_m, "target depth", above=0, what="a distance in metres")
    cams = view_cameras(device)
    if depth_m <= cams.depth_origin_m * 1.1:
        raise InvalidInputError(f"target depth {depth_m} m is too close to the camera (entrance pupil at {cams.depth_origin_m:.3f} m)")
    pitch2 = 2 * device.pixel_pitch_m
    footprint = pitch2 * (depth_m - cams.depth_origin_m) / cams.focal_m
    blur = float(paraxial.blur_diameter_m(device, depth_m)) / pitch2
    feature = footprint * max(4.0, 1.2 * blur)
    r = field_radius_m(device, depth_m)
    tex = Texture("speckle", feature_m=feature, seed=seed, colors=((0.08, 0.08, 0.08), (0.85, 0.85, 0.85)))
    return Scene((Plane(depth_m, (3 * r, 3 * r), tex, name=f"target {depth_m:g} m"),), name=f"target_{depth_m:g}m")


def three_depth_scene() -> Scene:
    """The paper's scene: a cup at 0.3 m, a book at 0.5 m, a chessboard at 1.0 m, and a slanted
    floor from about 0.55 to 0.85 m (between book and chessboard, so no surfaces interleave)."""
    return Scene(
        (
            Plane(0.3, (0.05, 0.05), Texture("image", name="coffee"), center_m=(-0.018, -0.012), shape="disk", name="cup"),
            Plane(0.5, (0.07, 0.09), Texture("image", name="page"), center_m=(0.035, 0.0), name="book"),
            Plane(0.7, (0.35, 0.32), Texture("speckle", feature_m=0.004, seed=1), center_m=(0.0, 0.08),
                  tilt_deg=(70.0, 0.0), name="floor"),
            Plane(1.0, (0.6, 0.6), Texture("checker", square_m=0.03), name="chessboard"),
        ),
        name="scene",
    )


def hard_scene() -> Scene:
    """A scene that does not favour one method: every surface kind the twin has, seen at once.

    - three thin wires at 0.33 m (vertical, horizontal, diagonal; 3 to 5 px wide in the views
      of the 2 x 2 binned prototype) in front of everything;
    - a speckled disc at 0.4 m and a diamond (a square turned by 30 degrees) at 0.75 m: depth
      edges at every orientation;
    - a part at 0.45 m with a spherical cap (12 mm high) and a cylindrical ridge (4 mm):
      curved surfaces, their depth exact;
    - a photograph on a plane at 0.55 m tilted about both axes, and a floor tilted by 55
      degrees from about 0.55 to 0.69 m: depth varying across surfaces;
    - a flat grey-blue card at 0.5 m: a textureless patch, where depth is not observable;
    - a low-contrast, fine speckle background turned by 20 degrees about the vertical, from
      about 0.81 to 1.09 m.

    Render it with ``RenderSettings(view_falloff=HARD_VIEW_FALLOFF)`` (``lfring synth hard``
    does) for vignetting that differs per view.
    """
    wire = Texture("constant", colors=((0.85, 0.8, 0.7),))
    dark_wire = Texture("constant", colors=((0.06, 0.06, 0.07),))
    cap = Bump(center_m=(0.045, 0.03), size_m=(0.04, 0.04), height_m=0.012, shape="sphere")
    ridge = Bump(center_m=(0.012, 0.03), size_m=(0.016, 0.06), height_m=0.004, shape="cylinder")
    part = HeightField(0.45, (0.07, 0.06), Texture("speckle", feature_m=0.0015, seed=11,
                                                   colors=((0.15, 0.12, 0.1), (0.75, 0.65, 0.5))),
                       center_m=(0.045, -0.035), bumps=(cap, ridge), name="curved part")
    return Scene(
        (
            Plane(0.33, (0.0006, 0.14), wire, center_m=(-0.02, 0.0), name="vertical wire"),
            Plane(0.33, (0.14, 0.0007), dark_wire, center_m=(0.0, 0.036), name="horizontal wire"),
            Plane(0.33, (0.12, 0.0005), wire, center_m=(0.012, -0.01), roll_deg=40.0, name="diagonal wire"),
            Plane(0.4, (0.035, 0.035), Texture("speckle", feature_m=0.0012, seed=12), center_m=(0.0, 0.0),
                  shape="disk", name="disc"),
            part,
            Plane(0.5, (0.04, 0.035), Texture("constant", colors=((0.35, 0.45, 0.6),)), center_m=(-0.05, 0.03),
                  name="textureless card"),
            Plane(0.55, (0.08, 0.08), Texture("image", name="astronaut"), center_m=(-0.06, -0.05),
                  tilt_deg=(30.0, -35.0), name="slanted photo"),
            Plane(0.62, (0.25, 0.16), Texture("image", name="gravel"), center_m=(0.0, 0.085), tilt_deg=(55.0, 0.0),
                  name="floor"),
            Plane(0.75, (0.06, 0.06), Texture("checker", square_m=0.01, colors=((0.1, 0.1, 0.35), (0.9, 0.85, 0.3))),
                  center_m=(0.07, 0.04), roll_deg=30.0, name="diamond"),
            Plane(0.95, (0.8, 0.8), Texture("speckle", feature_m=0.005, seed=13,
                                            colors=((0.2, 0.22, 0.2), (0.5, 0.52, 0.48))),
                  tilt_deg=(0.0, 20.0), name="background"),
        ),
        name="hard",
    )


def part_scene(
    *,
    defect_heights_m=(0.015, -0.015),
    defect_size_m: float = 0.012,
    depth_m: float = 0.3,
    seed: int = 0,
) -> Scene:
    """An inspection part: a textured plate at ``depth_m`` on a backdrop, with bumps (positive
    heights, towards the camera) and dents (negative) of ``defect_size_m`` at seeded random,
    non-overlapping places. ``defect_heights_m=()`` gives a good part. The plate is
    ``PART_SIZE_M`` square; a defect's centre keeps ``DEFECT_CLEARANCE`` diameters from its edge,
    so a defect is at most ``MAX_DEFECT_SIZE_M`` across.

    The ring's baseline is small: at 0.3 m one pixel of disparity between neighbouring views of
    the 2 x 2 binned prototype is about 24 mm of depth, so defects worth finding are
    centimetre-high features, not scratches.
    """
    heights = tuple(float(h) for h in defect_heights_m)
    check_number(defect_size_m, "defect size", above=0, maximum=MAX_DEFECT_SIZE_M, what="a length in metres",
                 hint=f": a defect and its clearance must fit on the {PART_SIZE_M:g} m part")
    size = (PART_SIZE_M, PART_SIZE_M)
    rng = np.random.default_rng(seed)
    placed: list[tuple[float, float]] = []
    bumps = []
    margin = defect_size_m * DEFECT_CLEARANCE
    for h in heights:
        for _ in range(1000):
            c = (rng.uniform(margin, size[0] - margin), rng.uniform(margin, size[1] - margin))
            if all(np.hypot(c[0] - p[0], c[1] - p[1]) > 1.6 * defect_size_m for p in placed):
                break
        else:
            raise InvalidInputError(f"cannot place {len(heights)} defects of {defect_size_m} m on a {size[0]} m part: "
                                    "give fewer or smaller defects")
        placed.append(c)
        bumps.append(Bump(center_m=c, size_m=(defect_size_m, defect_size_m), height_m=h, shape="dome"))
    part = HeightField(depth_m, size, Texture("image", name="gravel"), bumps=tuple(bumps), name="part")
    backdrop = Plane(depth_m + 0.1, (0.5, 0.5), Texture("speckle", feature_m=0.003, seed=seed + 1,
                                                        colors=((0.02, 0.02, 0.03), (0.25, 0.25, 0.3))), name="belt")
    return Scene((part, backdrop), name="part")


# -- TOML scenes ---------------------------------------------------------------------------------
_TEXTURE_KEYS = {"kind", "name", "square_m", "feature_m", "seed", "colors"}
_PLANE_KEYS = {"depth_m", "size_m", "texture", "center_m", "tilt_deg", "roll_deg", "shape", "name"}
_PART_KEYS = {"depth_m", "size_m", "texture", "center_m", "bump", "shading", "name"}
_BUMP_KEYS = {"center_m", "size_m", "height_m", "shape"}


def _keys(table, allowed: set, where: str, source: str) -> dict:
    if not isinstance(table, dict):
        raise FileFormatError(f"{source}: {where} must be a table")
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise FileFormatError(f"{source}: unknown key(s) {', '.join(map(repr, unknown))} in {where}; valid: {', '.join(sorted(allowed))}")
    return table


def load_scene(path: str | Path) -> Scene:
    """Read a scene from TOML: ``[[plane]]`` and ``[[part]]`` tables (with ``[[part.bump]]``),
    each with a ``texture`` table, and an optional top-level ``background = [r, g, b]`` and
    ``name``. Keys are the fields of :class:`Plane`, :class:`HeightField`, :class:`Bump` and
    :class:`Texture`; lengths in metres.

    Examples
    --------
    A file holding::

        name = "two planes"
        [[plane]]
        depth_m = 0.4
        size_m = [0.2, 0.2]
        texture = { kind = "image", name = "astronaut" }
    """
    p = Path(path)
    if not p.is_file():
        raise LfringFileNotFoundError(f"scene file not found: {p}")
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise FileFormatError(f"{p}: not a valid TOML scene ({exc})") from None
    src = str(p)
    _keys(data, {"name", "background", "plane", "part"}, "the file", src)
    for key in ("plane", "part"):
        if not isinstance(data.get(key, []), list) or not all(isinstance(t, dict) for t in data.get(key, [])):
            raise FileFormatError(f"{src}: {key} must be an array of tables, each [[{key}]] with its keys, got "
                                  f"{data[key]!r}")
    background = data.get("background", (0.0, 0.0, 0.0))
    surfaces = []
    try:
        for i, t in enumerate(data.get("plane", [])):
            t = dict(_keys(t, _PLANE_KEYS, f"plane {i}", src))
            t["texture"] = Texture(**_keys(t.get("texture", {}), _TEXTURE_KEYS, f"plane {i} texture", src))
            surfaces.append(Plane(**t))
        for i, t in enumerate(data.get("part", [])):
            t = dict(_keys(t, _PART_KEYS, f"part {i}", src))
            t["texture"] = Texture(**_keys(t.get("texture", {}), _TEXTURE_KEYS, f"part {i} texture", src))
            t["bumps"] = tuple(Bump(**_keys(b, _BUMP_KEYS, f"part {i} bump {j}", src)) for j, b in enumerate(t.pop("bump", [])))
            surfaces.append(HeightField(**t))
        return Scene(tuple(surfaces), background=tuple(background) if isinstance(background, list) else background,
                     name=data.get("name", p.stem))
    except TypeError as exc:
        raise FileFormatError(f"{src}: {exc}") from None
    except InvalidInputError as exc:
        raise FileFormatError(f"{src}: {exc}") from None
