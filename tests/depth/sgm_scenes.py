"""Cost volumes with known disparity, built by construction, for the SGM and refinement tests.

Also a brute-force NumPy reference of the SGM recursion, pixel by pixel along every path.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lfring.depth.sgm import PATHS, edge_penalty

STEP_COLUMN = 32  # the step edge between the two fronto-parallel planes
FAR_INDEX, NEAR_INDEX = 8.0, 20.0


@dataclass
class Scene:
    cost: np.ndarray  # (N, h, w) float32
    truth: np.ndarray  # (h, w) true hypothesis index (fractional on the slanted plane)
    guide: np.ndarray  # (h, w) float32 luminance in [0, 1], its edge on the step edge
    flat: np.ndarray  # (h, w) bool: textureless band (cost flat up to noise)
    slant: np.ndarray  # (h, w) bool: slanted plane


def scene(seed: int = 0, *, n: int = 32, h: int = 48, w: int = 64, noise: float = 0.05, flat_noise: float | None = None,
          flat_band: bool = True,
          edge_band: bool = False, slanted: bool = True) -> Scene:
    """Two planes with a step edge (top), a slanted plane (bottom), optional textureless bands.

    The matching cost of a textured pixel is min((d - truth)^2, 4) plus Gaussian noise, so a
    parabola through three hypotheses around the minimum recovers the fractional truth; in a
    textureless pixel it is 1 plus noise (``flat_noise``, default ``noise``). ``flat_band``: rows 12..19 textureless; ``edge_band``:
    every row textureless over columns 18..39, off-centre around the step edge at column 32, which
    the guide still shows (only paths from the left and right bring depth there); ``slanted``:
    the bottom third is a slanted plane instead of the two planes.
    """
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    truth = np.where(x < STEP_COLUMN, FAR_INDEX, NEAR_INDEX)
    slant = (y >= 32) & slanted
    truth[slant] = 4.0 + 0.3 * x[slant] + 0.05 * y[slant]
    guide = np.where(x < STEP_COLUMN, 0.3, 0.7) + 0.02 * rng.standard_normal((h, w))
    guide[slant] = 0.5 + 0.02 * rng.standard_normal(int(slant.sum()))
    d = np.arange(n, dtype=np.float64)[:, None, None]
    cost = np.minimum((d - truth) ** 2, 4.0) + noise * rng.standard_normal((n, h, w))
    flat = np.zeros((h, w), bool)
    if flat_band:
        flat[12:20, 4:60] = True
    if edge_band:
        flat[:, 18:40] = True
    flat_noise = noise if flat_noise is None else flat_noise
    cost[:, flat] = 1.0 + flat_noise * rng.standard_normal((n, int(flat.sum())))
    return Scene(np.maximum(cost, 0).astype(np.float32), truth, guide.astype(np.float32), flat, slant)


def reference_sgm(cost, *, guide=None, p1, p2, paths=4, edge_scale=None) -> np.ndarray:
    """SGM by the textbook recursion, one pixel at a time (slow: tiny volumes only)."""
    c = np.array(cost, np.float32)
    n, h, w = c.shape
    finite = np.isfinite(c)
    counts = finite.sum(axis=0)
    mean = np.where(counts > 0, np.where(finite, c, 0).astype(np.float64).sum(axis=0) / np.maximum(counts, 1), 0)
    c = np.where(finite, c, mean.astype(np.float32)[None])
    p1 = np.float32(p1)
    p2 = np.float32(max(p2, p1))
    out = np.zeros_like(c)
    for dy, dx in PATHS[paths]:
        L = np.zeros_like(c)
        ys = range(h) if dy >= 0 else range(h - 1, -1, -1)
        xs = range(w) if dx >= 0 else range(w - 1, -1, -1)
        for y in ys:
            for x in xs:
                yp, xp = y - dy, x - dx
                if not (0 <= yp < h and 0 <= xp < w):
                    L[:, y, x] = c[:, y, x]
                    continue
                prev = L[:, yp, xp]
                m = prev.min()
                p2e = p2
                if guide is not None and edge_scale is not None:
                    p2e = edge_penalty(guide[y, x], guide[yp, xp], p1=p1, p2=p2, edge_scale=edge_scale)
                best = np.minimum(prev, m + p2e)
                best[1:] = np.minimum(best[1:], prev[:-1] + p1)
                best[:-1] = np.minimum(best[:-1], prev[1:] + p1)
                L[:, y, x] = c[:, y, x] + (best - m)
        out += L
    return out


def disparity(cal, z):
    """Disparity in px between views 0 and 1 (horizontal neighbours) at depth ``z``."""
    h = cal.model(np.asarray(z, dtype=np.float64))
    return h[..., 1, 0, 2] - h[..., 0, 0, 2]
