"""Textures for synthetic scenes: scikit-image's bundled photographs and procedural patterns.

Nothing is downloaded. A texture is rasterised for a given physical size and texel size, so a
procedural pattern is as sharp as the view needs and a photograph is resampled to the same
grid. Values are linear radiance in [0, 1] (photographs are converted from sRGB).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from lfring.core.validate import check_choice, check_number
from lfring.errors import InvalidInputError

__all__ = ["Texture", "IMAGES", "KINDS", "rasterize", "raster_shape"]

# scikit-image images shipped inside its wheel (no download).
IMAGES = (
    "astronaut", "coffee", "chelsea", "camera", "text", "page", "brick", "grass", "gravel",
    "rocket", "colorwheel", "immunohistochemistry", "retina", "hubble_deep_field",
)
KINDS = ("image", "checker", "speckle", "constant")


@dataclass(frozen=True)
class Texture:
    """What a surface looks like.

    kind : 'image' (``name`` from :data:`IMAGES`, stretched over the surface), 'checker'
        (squares of ``square_m``), 'speckle' (random blobs of about ``feature_m``, like a
        printed calibration target; ``seed``), or 'constant'.
    colors : two RGB triples in [0, 1] (dark, light) for checker and speckle, one for constant.
    """

    kind: str = "speckle"
    name: str = "astronaut"
    square_m: float = 0.01
    feature_m: float = 0.001
    seed: int = 0
    colors: tuple = ((0.05, 0.05, 0.05), (0.9, 0.9, 0.9))

    def __post_init__(self) -> None:
        check_choice(self.kind, "texture kind", KINDS)
        if self.kind == "image":
            check_choice(self.name, "texture image", IMAGES)
        check_number(self.square_m, "texture square_m", above=0, what="a length in metres")
        check_number(self.feature_m, "texture feature_m", above=0, what="a length in metres")
        cols = np.asarray(self.colors, dtype=np.float64)
        if cols.ndim != 2 or cols.shape[1] != 3 or np.any(cols < 0) or np.any(cols > 1):
            raise InvalidInputError(f"texture colors must be RGB triples in [0, 1], got {self.colors!r}")
        object.__setattr__(self, "colors", tuple(tuple(float(v) for v in c) for c in cols))


def _srgb_to_linear(x: np.ndarray) -> np.ndarray:
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(np.float32)


def _image(name: str) -> np.ndarray:
    import skimage.data

    img = getattr(skimage.data, name)()
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    img = img[..., :3].astype(np.float32) / 255.0
    return _srgb_to_linear(img)


def raster_shape(size_m: tuple[float, float], texel_m: float) -> tuple[int, int]:
    """(rows, cols) of the raster :func:`rasterize` makes: texels no larger than ``texel_m``
    that tile the surface exactly (texel width = width / cols, height = height / rows)."""
    w_m, h_m = size_m
    check_number(w_m, "texture width", above=0, what="a length in metres")
    check_number(h_m, "texture height", above=0, what="a length in metres")
    check_number(texel_m, "texel size", above=0, what="a length in metres")
    return max(2, int(np.ceil(h_m / texel_m))), max(2, int(np.ceil(w_m / texel_m)))


def rasterize(texture: Texture, size_m: tuple[float, float], texel_m: float, *, alpha: bool = False) -> np.ndarray:
    """(rows, cols, 3) float32 raster of ``texture`` over a surface of ``size_m`` = (width,
    height) metres, shape from :func:`raster_shape`; texel (0, 0) is the top-left corner.
    With ``alpha``, an opaque alpha channel is appended ((rows, cols, 4): the renderer's layers
    are RGBA, and appending it here saves a copy of a large raster)."""
    w_m, h_m = size_m
    rows, cols = raster_shape(size_m, texel_m)
    tx, ty = w_m / cols, h_m / rows
    if rows * cols > 64e6:
        raise InvalidInputError(f"texture raster of {cols} x {rows} texels is too large; use a larger texel size")
    lo, hi = (np.array(c, dtype=np.float32) for c in (texture.colors + texture.colors)[:2])
    nch = 4 if alpha else 3
    # colour = lo + (hi - lo) t per channel; with alpha, a fourth channel 1 + 0 t = 1.
    base = np.append(lo, np.float32(1))[:nch]
    scale = np.append(hi - lo, np.float32(0))[:nch]
    if texture.kind == "constant":
        return np.broadcast_to(base, (rows, cols, nch)).copy()
    if texture.kind == "image":
        img = _image(texture.name)
        interp = cv2.INTER_AREA if img.shape[0] > rows else cv2.INTER_CUBIC
        rgb = np.clip(cv2.resize(img, (cols, rows), interpolation=interp), 0.0, 1.0)
        return cv2.cvtColor(rgb, cv2.COLOR_RGB2RGBA) if alpha else rgb
    if texture.kind == "checker":
        # Area-weighted squares: each texel gets the fraction of its area that is light.
        def frac(n, step, pitch):
            edges = np.arange(n + 1) * step / pitch
            # Integral of the square wave sq(t) = floor(t) mod 2 == 0 over [a, b].
            def prim(t):
                k = np.floor(t)
                return np.ceil(k / 2.0) + np.where(k % 2 == 0, t - k, 0.0)

            return (prim(edges[1:]) - prim(edges[:-1])) / (edges[1:] - edges[:-1])

        fx, fy = frac(cols, tx, texture.square_m), frac(rows, ty, texture.square_m)
        # A row depends only on its fraction fy, and rows take few distinct fractions (0, 1 and
        # the squares' edges): compute each distinct row once and repeat it.
        fy_distinct, row_kind = np.unique(fy, return_inverse=True)
        light = fy_distinct[:, None] * fx[None, :] + (1 - fy_distinct[:, None]) * (1 - fx[None, :])
        distinct = base + scale * light[..., None].astype(np.float32)
        return distinct[row_kind.ravel()]
    # speckle: band-limited noise pushed towards two levels, like a printed random-dot target.
    rng = np.random.default_rng(texture.seed)
    coarse = max(1.0, texture.feature_m / min(tx, ty) / 2.0)
    gh, gw = int(np.ceil(rows / coarse)) + 3, int(np.ceil(cols / coarse)) + 3
    noise = rng.standard_normal((gh, gw)).astype(np.float32)
    noise = cv2.GaussianBlur(noise, (0, 0), 0.8)
    field = cv2.resize(noise, (int(gw * coarse), int(gh * coarse)), interpolation=cv2.INTER_CUBIC)[:rows, :cols]
    field /= field.std() + 1e-12
    t = np.multiply(field, np.float32(1.5))
    np.tanh(t, out=t)
    t *= np.float32(0.5)
    t += np.float32(0.5)  # t = 0.5 + 0.5 tanh(1.5 field), in place
    # Channel by channel, then interleaved (broadcasting into a length-3/4 last axis is slow).
    return cv2.merge([t * scale[c] + base[c] for c in range(nch)])
