"""Ready-made scenes for the twin: a flat field, calibration targets, the paper's three-depth
scene and inspection parts, plus scenes described in TOML files."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from lfring.errors import FileFormatError, InvalidInputError, LfringFileNotFoundError
from lfring.optics import paraxial
from lfring.optics.device import RingDevice
from lfring.optics.views import view_cameras
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
    "load_scene",
]

PRESETS = ("flat", "target", "scene", "part")


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
    if not (np.isfinite(depth_m) and depth_m > 0):
        raise InvalidInputError(f"target depth must be a positive number of metres, got {depth_m!r}")
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


def part_scene(
    *,
    defect_heights_m=(0.015, -0.015),
    defect_size_m: float = 0.012,
    depth_m: float = 0.3,
    seed: int = 0,
) -> Scene:
    """An inspection part: a textured plate at ``depth_m`` on a backdrop, with bumps (positive
    heights, towards the camera) and dents (negative) of ``defect_size_m`` at seeded random,
    non-overlapping places. ``defect_heights_m=()`` gives a good part.

    The ring's baseline is small: at 0.3 m one pixel of disparity between neighbouring views of
    the 2 x 2 binned prototype is about 24 mm of depth, so defects worth finding are
    centimetre-high features, not scratches.
    """
    heights = tuple(float(h) for h in defect_heights_m)
    if not (np.isfinite(defect_size_m) and defect_size_m > 0):
        raise InvalidInputError(f"defect size must be a positive number of metres, got {defect_size_m!r}")
    size = (0.08, 0.08)
    rng = np.random.default_rng(seed)
    placed: list[tuple[float, float]] = []
    bumps = []
    margin = defect_size_m * 0.75
    for h in heights:
        for _ in range(1000):
            c = (rng.uniform(margin, size[0] - margin), rng.uniform(margin, size[1] - margin))
            if all(np.hypot(c[0] - p[0], c[1] - p[1]) > 1.6 * defect_size_m for p in placed):
                break
        else:
            raise InvalidInputError(f"cannot place {len(heights)} defects of {defect_size_m} m on a {size[0]} m part")
        placed.append(c)
        bumps.append(Bump(center_m=c, size_m=(defect_size_m, defect_size_m), height_m=h, shape="dome"))
    part = HeightField(depth_m, size, Texture("image", name="gravel"), bumps=tuple(bumps), name="part")
    backdrop = Plane(depth_m + 0.1, (0.5, 0.5), Texture("speckle", feature_m=0.003, seed=seed + 1,
                                                        colors=((0.02, 0.02, 0.03), (0.25, 0.25, 0.3))), name="belt")
    return Scene((part, backdrop), name="part")


# -- TOML scenes ---------------------------------------------------------------------------------
_TEXTURE_KEYS = {"kind", "name", "square_m", "feature_m", "seed", "colors"}
_PLANE_KEYS = {"depth_m", "size_m", "texture", "center_m", "tilt_deg", "shape", "name"}
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
        return Scene(tuple(surfaces), background=tuple(data.get("background", (0.0, 0.0, 0.0))), name=data.get("name", p.stem))
    except TypeError as exc:
        raise FileFormatError(f"{src}: {exc}") from None
    except InvalidInputError as exc:
        raise FileFormatError(f"{src}: {exc}") from None
