"""Scenes for the synthetic twin: textured planes (fronto-parallel or slanted, turned in their
own plane, rectangles or discs) and height-field parts with bumps and dents of known height,
among them curved surfaces (spherical caps, cylindrical ridges) whose depth is exact.

World coordinates: X right, Y down, Z forward, metres from the main lens.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lfring.core.validate import check_choice, check_number, is_number
from lfring.errors import InvalidInputError
from lfring.synth.textures import Texture

__all__ = ["Plane", "Bump", "HeightField", "Scene", "SHAPES", "BUMP_SHAPES", "CURVED_SHAPES"]

SHAPES = ("rect", "disk")
BUMP_SHAPES = ("dome", "box", "gaussian", "sphere", "cylinder")
#: bump shapes whose surface is analytic: the renderer's depth lies on it exactly.
CURVED_SHAPES = ("sphere", "cylinder")


def _pair(value, name: str, *, positive: bool) -> tuple[float, float]:
    """``value`` as two finite floats (both > 0 when ``positive``)."""
    try:
        a, b = value
    except (TypeError, ValueError):
        raise InvalidInputError(f"{name} must be a pair of numbers, got {value!r}") from None
    if not (is_number(a) and is_number(b)):
        raise InvalidInputError(f"{name} must be a pair of numbers, got {value!r}")
    a, b = float(a), float(b)
    if not (np.isfinite(a) and np.isfinite(b)) or (positive and not (a > 0 and b > 0)):
        raise InvalidInputError(f"{name} must be {'positive ' if positive else ''}finite numbers, got {value!r}")
    return a, b


@dataclass(frozen=True)
class Plane:
    """A textured planar patch.

    depth_m : Z of the patch centre. size_m : (width, height) along the patch's own axes.
    center_m : (X, Y) of the centre. tilt_deg : (about X, about Y); a positive tilt about X
    pushes the top edge (smaller Y) farther away, like a table seen from above its edge.
    shape : 'rect' or 'disk' (an ellipse inscribed in the rectangle).
    roll_deg : turn of the patch about its own normal, applied before the tilts; positive turns
        its right axis towards its down axis (clockwise as seen by the camera). 45 degrees makes
        a square a diamond, a thin bar a diagonal wire.
    """

    depth_m: float
    size_m: tuple[float, float]
    texture: Texture = field(default_factory=Texture)
    center_m: tuple[float, float] = (0.0, 0.0)
    tilt_deg: tuple[float, float] = (0.0, 0.0)
    shape: str = "rect"
    name: str = ""
    roll_deg: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "depth_m", check_number(self.depth_m, "plane depth_m", above=0, what="a distance in metres"))
        object.__setattr__(self, "roll_deg", check_number(self.roll_deg, "plane roll_deg", what="a number of degrees"))
        object.__setattr__(self, "size_m", _pair(self.size_m, "plane size_m", positive=True))
        object.__setattr__(self, "center_m", _pair(self.center_m, "plane center_m", positive=False))
        tilt = _pair(self.tilt_deg, "plane tilt_deg", positive=False)
        if max(abs(tilt[0]), abs(tilt[1])) >= 80:
            raise InvalidInputError(f"plane tilt must stay within +-80 degrees, got {tilt}")
        object.__setattr__(self, "tilt_deg", tilt)
        check_choice(self.shape, "plane shape", SHAPES)
        if not isinstance(self.texture, Texture):
            raise InvalidInputError("plane texture must be a lfring.synth.Texture")

    def axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Centre P0 (3,), unit axes u (right), v (down) and normal n (towards +Z)."""
        ax, ay = np.radians(self.tilt_deg)
        rx = np.array([[1, 0, 0], [0, np.cos(ax), -np.sin(ax)], [0, np.sin(ax), np.cos(ax)]])
        ry = np.array([[np.cos(ay), 0, np.sin(ay)], [0, 1, 0], [-np.sin(ay), 0, np.cos(ay)]])
        r = ry @ rx
        if self.roll_deg != 0.0:  # (without a roll the axes stay bit for bit what they were)
            az = np.radians(self.roll_deg)
            r = r @ np.array([[np.cos(az), -np.sin(az), 0], [np.sin(az), np.cos(az), 0], [0, 0, 1]])
        p0 = np.array([self.center_m[0], self.center_m[1], self.depth_m])
        return p0, r[:, 0], r[:, 1], r[:, 2]

    def corners_m(self) -> np.ndarray:
        """The plane's four corners in camera coordinates.

        Returns
        -------
        (4, 3) ndarray
            Metres; in the order (-u, -v), (-u, +v), (+u, -v), (+u, +v) of :meth:`axes`.
        """
        p0, u, v, _ = self.axes()
        w, h = self.size_m
        return np.array([p0 + su * w / 2 * u + sv * h / 2 * v for su in (-1, 1) for sv in (-1, 1)])

    @property
    def depth_range_m(self) -> tuple[float, float]:
        """Nearest and farthest Z (metres) of the plane: those of its corners."""
        zs = self.corners_m()[:, 2]
        return float(zs.min()), float(zs.max())


@dataclass(frozen=True)
class Bump:
    """A bump (height > 0, towards the camera) or dent (height < 0) on a part.

    center_m : (x, y) from the part's top-left corner. size_m : (width, height) of its footprint.
    shape : 'dome' (smooth cap), 'box' (flat top, short ramps), 'gaussian' (sigma = size / 4),
        'sphere' (a spherical cap whose rim is the footprint's circle: width and height equal;
        radius of the sphere ``(a**2 + H**2) / (2 H)`` for rim radius a and height H) or
        'cylinder' (a circular-arc ridge across the width, its axis along y, over the whole
        footprint height).
    """

    center_m: tuple[float, float]
    size_m: tuple[float, float]
    height_m: float
    shape: str = "dome"

    def __post_init__(self) -> None:
        object.__setattr__(self, "center_m", _pair(self.center_m, "bump center_m", positive=False))
        object.__setattr__(self, "size_m", _pair(self.size_m, "bump size_m", positive=True))
        h = check_number(self.height_m, "bump height_m", what="a non-zero number of metres")
        if h == 0:
            raise InvalidInputError(f"bump height_m must be a non-zero number of metres, got {self.height_m!r}")
        object.__setattr__(self, "height_m", h)
        check_choice(self.shape, "bump shape", BUMP_SHAPES)
        if self.shape == "sphere" and self.size_m[0] != self.size_m[1]:
            raise InvalidInputError(f"a 'sphere' bump has a circular footprint: give equal width and height, got {self.size_m}")
        if self.shape in CURVED_SHAPES and abs(h) > self.size_m[0] / 2:
            raise InvalidInputError(f"a '{self.shape}' bump is at most a half sphere/cylinder: |height_m| <= width / 2, "
                                    f"got {h} m on {self.size_m[0]} m")

    @property
    def radius_m(self) -> float:
        """Radius of the sphere or cylinder of a curved bump: (a**2 + H**2) / (2 |H|), a = width / 2."""
        a, hh = self.size_m[0] / 2, abs(self.height_m)
        return (a * a + hh * hh) / (2 * hh)


@dataclass(frozen=True)
class HeightField:
    """A part: a fronto-parallel base at ``depth_m`` with bumps and dents.

    The surface is at Z = depth_m - height(x, y): positive heights come towards the camera.
    """

    depth_m: float
    size_m: tuple[float, float]
    texture: Texture = field(default_factory=Texture)
    center_m: tuple[float, float] = (0.0, 0.0)
    bumps: tuple[Bump, ...] = ()
    shading: bool = True
    name: str = ""

    @property
    def depth_range_m(self) -> tuple[float, float]:
        """Nearest and farthest Z (metres) of the part: its base moved by the highest bump and
        the deepest dent (no nearer than the base, nor farther)."""
        highest = max([b.height_m for b in self.bumps if b.height_m > 0], default=0.0)
        deepest = min([b.height_m for b in self.bumps if b.height_m < 0], default=0.0)
        return self.depth_m - highest, self.depth_m - deepest

    @property
    def curved(self) -> bool:
        """True when a bump is a sphere or cylinder: the renderer then puts the depth on the
        analytic surface (:meth:`height_at`) rather than on the sampled height map."""
        return any(b.shape in CURVED_SHAPES for b in self.bumps)

    def __post_init__(self) -> None:
        object.__setattr__(self, "depth_m", check_number(self.depth_m, "part depth_m", above=0, what="a distance in metres"))
        object.__setattr__(self, "size_m", _pair(self.size_m, "part size_m", positive=True))
        object.__setattr__(self, "center_m", _pair(self.center_m, "part center_m", positive=False))
        object.__setattr__(self, "bumps", tuple(self.bumps))
        for b in self.bumps:
            if not isinstance(b, Bump):
                raise InvalidInputError("part bumps must be lfring.synth.Bump records")
            if abs(b.height_m) >= 0.5 * self.depth_m:
                raise InvalidInputError(f"bump height {b.height_m} m is not small against the part distance")

    def height_map(self, texel_m: tuple[float, float], shape: tuple[int, int]) -> np.ndarray:
        """(rows, cols) float32 heights in metres at the centres of texels of (width, height)
        ``texel_m``."""
        rows, cols = shape
        x = (np.arange(cols) + 0.5) * texel_m[0]
        y = (np.arange(rows) + 0.5) * texel_m[1]
        return self.height_at(x[None, :], y[:, None]).astype(np.float32)

    def height_at(self, x_m, y_m) -> np.ndarray:
        """The analytic height (metres, float64) at points ``(x_m, y_m)`` from the part's
        top-left corner (arrays that broadcast together)."""
        x = np.asarray(x_m, dtype=np.float64)
        y = np.asarray(y_m, dtype=np.float64)
        out = np.zeros(np.broadcast(x, y).shape, dtype=np.float64)
        for b in self.bumps:
            dx = (x - b.center_m[0]) / (b.size_m[0] / 2)
            dy = (y - b.center_m[1]) / (b.size_m[1] / 2)
            if b.shape in CURVED_SHAPES:
                a, big = b.size_m[0] / 2, b.radius_m
                r2 = (dx * dx + (dy * dy if b.shape == "sphere" else 0.0)) * a * a
                inside = (r2 < a * a) & (np.abs(dy) < 1)
                cap = np.sqrt(np.maximum(big * big - r2, 0.0)) - (big - abs(b.height_m))
                out += np.where(inside, np.copysign(np.maximum(cap, 0.0), b.height_m), 0.0)
                continue
            if b.shape == "dome":
                r2 = dx * dx + dy * dy
                prof = np.where(r2 < 1, np.cos(np.sqrt(np.minimum(r2, 1)) * np.pi / 2) ** 2, 0.0)
            elif b.shape == "gaussian":
                prof = np.exp(-0.5 * (dx * dx + dy * dy) * 4)
            else:
                ramp = 0.1
                fx = np.clip((1 - np.abs(dx)) / ramp, 0, 1)
                fy = np.clip((1 - np.abs(dy)) / ramp, 0, 1)
                prof = fx * fy
            out += b.height_m * prof
        return out

    def shading_map(self, heights: np.ndarray, texel_m: tuple[float, float]) -> np.ndarray:
        """Lambertian shading in (0, 1] of the height field lit from the upper left."""
        gy, gx = np.gradient(heights.astype(np.float64), texel_m[1], texel_m[0])
        # Surface z grows away from the camera as heights fall: normal ~ (gx, gy, -1) towards camera.
        n = np.stack([gx, gy, -np.ones_like(gx)], axis=-1)
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        light = np.array([-0.4, -0.5, -0.77])
        light /= np.linalg.norm(light)
        lam = np.clip(n @ light, 0, 1)
        flat = float(light[2] * -1)
        return (0.6 + 0.4 * lam / flat).astype(np.float32)


@dataclass(frozen=True)
class Scene:
    """Surfaces in front of the camera; ``background`` is the RGB radiance where none is hit."""

    surfaces: tuple
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    name: str = ""

    def __post_init__(self) -> None:
        surfaces = tuple(self.surfaces)
        if not surfaces:
            raise InvalidInputError("a scene needs at least one surface")
        for s in surfaces:
            if not isinstance(s, (Plane, HeightField)):
                raise InvalidInputError(f"scene surfaces must be Plane or HeightField records, got {type(s).__name__}")
        object.__setattr__(self, "surfaces", surfaces)
        try:
            bg = np.asarray(self.background, dtype=np.float64)
        except (TypeError, ValueError):  # words, or a mix of numbers and words
            bg = np.full(0, np.nan)
        if bg.shape != (3,) or not np.all((bg >= 0) & (bg <= 1)):
            raise InvalidInputError(f"scene background must be an RGB triple in [0, 1], got {self.background!r}")
        object.__setattr__(self, "background", tuple(float(v) for v in bg))

    @property
    def depth_range_m(self) -> tuple[float, float]:
        """Nearest and farthest Z (metres) of the scene's surfaces."""
        ranges = [surf.depth_range_m for surf in self.surfaces]
        return float(min(lo for lo, _ in ranges)), float(max(hi for _, hi in ranges))

