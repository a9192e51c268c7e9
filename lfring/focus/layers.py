"""The layered blur of depth-aware refocusing (:class:`lfring.focus.depth_aware.DepthOfField`,
step 5): the ladder of blur radii, each rung's layer of premultiplied colour and coverage on its
grid, blurred by the rung's disc, and the layers composited far to near. The per-pixel passes
are compiled (:mod:`lfring.focus.depth_aware_kernels`, imported on first use); the renderer
gives the rules of its in-focus share (``sharp_rule``) and keeps the scratch memory.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from lfring.core.memory import fresh_zeros

__all__ = ["COARSE_DISC_PX", "COMPOSITE", "GEOMETRIC_STEP", "LINEAR_UNTIL_PX", "NO_IMAGE", "NO_MAP", "SCRATCH_GROWTH",
           "Grid", "Layer", "blur_moment", "composite", "disc_kernel", "grid_factor", "ladder", "sum_layers"]

# The ladder of blur radii of the layers: 0 and 1 px, then 0.5 px apart up to 3 px, 1 px apart up
# to LINEAR_UNTIL_PX, then each GEOMETRIC_STEP times the last. Every pixel is shared between the
# two rungs around its own radius, so the spacing sets how closely a mixture of two discs stands
# for the disc between them, not where the blur changes.
LINEAR_UNTIL_PX = 6.0
GEOMETRIC_STEP = 1.2
# A rung's layer is blurred on a grid reduced by a power of two f (area averaging down, bicubic
# up), as far as its disc there stays at least COARSE_DISC_PX: a blurred layer holds no detail
# finer than its disc. The area averaging itself spreads a pixel by f^2 / 12 per axis, a disc of
# radius r by r^2 / 4: the disc there is shrunk to radius sqrt(r^2 - f^2 / 3) / f. Bicubic's
# negative lobes overshoot where a layer's coverage falls steeply, and where little covers a pixel
# (the frame's corners) the colour divided by it left the views' range: the resized cells are
# clamped to what premultiplied colour and coverage can be (see _resize).
COARSE_DISC_PX = 3.0


_DISCS: dict = {}


def disc_kernel(radius_px: float) -> np.ndarray:
    """(2n+1, 2n+1) float32 disc of ``radius_px``, each tap the fraction of its pixel inside the
    disc (8 x 8 samples), normalised to sum 1."""
    key = round(float(radius_px), 3)
    kern = _DISCS.get(key)
    if kern is None:
        n = int(math.ceil(key - 0.5)) if key > 0.5 else 0
        sub = (np.arange(8) + 0.5) / 8 - 0.5
        grid = np.arange(-n, n + 1)
        xs = (grid[:, None] + sub[None, :]).ravel()
        inside = (xs[:, None] ** 2 + xs[None, :] ** 2) <= key * key
        cover = inside.reshape(2 * n + 1, 8, 2 * n + 1, 8).mean(axis=(1, 3))
        if cover.sum() == 0:
            cover[n, n] = 1.0
        kern = _DISCS.setdefault(key, (cover / cover.sum()).astype(np.float32))
    return kern


def blur_moment(radius_px: float, factor: int = 1) -> float:
    """Mean squared distance (px^2) over which a rung of ``radius_px`` spreads a pixel: its disc
    kernel's at full resolution; on a grid reduced ``factor`` times, a disc's r^2 / 2 and a
    pixel's 1 / 6 (the reduction and the disc there are sized to it)."""
    if radius_px < 0.5:
        return 0.0
    if factor == 1:
        kern = disc_kernel(radius_px)
        n = kern.shape[0] // 2
        yy, xx = np.mgrid[-n:n + 1, -n:n + 1]
        return float((kern * (xx * xx + yy * yy)).sum())
    return radius_px * radius_px / 2.0 + 1.0 / 6.0


def ladder(max_px: float) -> np.ndarray:
    """Unsigned layer radii from 0 to at least ``max_px``: 0, 1, 1.5, 2, 2.5, 3, 4, 5, ...,
    LINEAR_UNTIL_PX, then geometric."""
    r = [0.0, 1.0]
    while r[-1] < max_px:
        last = r[-1]
        r.append(last * GEOMETRIC_STEP if last >= LINEAR_UNTIL_PX else last + (0.5 if last < 3.0 else 1.0))
    return np.array(r)


# Scratch that has to grow is made this many times the size asked for: the layers' sizes change
# with the focus, a little from one render to the next, and fresh memory costs a page fault per
# page on its first write (more than the render's own work on it).
SCRATCH_GROWTH = 1.25

# The scratch buffer of the composite (:func:`composite`), which a render's last pass may leave
# all zeros for the next (:meth:`Grid.left_zeros`).
COMPOSITE = "composite"

# What the compiled passes take for "no image" and "no map".
NO_IMAGE = np.zeros((0, 0, 0), np.float32)
NO_MAP = np.zeros((0, 0), np.float32)


def grid_factor(radius_px: float) -> int:
    """How many times a rung's grid is reduced (a power of two): as long as its disc stays at
    least :data:`COARSE_DISC_PX` there."""
    f = 1
    while radius_px / (2 * f) >= COARSE_DISC_PX:
        f *= 2
    return f


def _resize(cells: np.ndarray, size, vmax: float) -> np.ndarray:
    """``cells`` (rows, cols[, n]) resized bicubically to ``size`` (width, height), any ``n``,
    and clamped to what they can hold: a map (a transmission, a coverage) to [0, 1]; cells of
    premultiplied colour and coverage (the last value) to a coverage of at least 0 and colours
    in [0, coverage * ``vmax``], ``vmax`` the largest colour of what was blurred (clipping the
    coverage at 1 as well moved the image further from the same layers blurred at full
    resolution)."""
    if cells.ndim == 2 or cells.shape[2] <= 4:
        out = cv2.resize(cells, size, interpolation=cv2.INTER_CUBIC)
        out = out if out.ndim == cells.ndim else out[..., None]
    else:
        out = np.stack([cv2.resize(np.ascontiguousarray(cells[..., i]), size, interpolation=cv2.INTER_CUBIC)
                        for i in range(cells.shape[2])], axis=2)
    from lfring.focus.depth_aware_kernels import clamp_cells

    out = np.ascontiguousarray(out)
    clamp_cells(out[..., None] if out.ndim == 2 else out, -1.0 if out.ndim == 2 else float(vmax))
    return out


class Layer:
    """One rung's premultiplied colour and coverage (rows, cols, C + 1) on its grid (reduced
    ``f`` times; full-resolution origin ``y0``, ``x0``), blurred by the rung's disc; ``vmax``
    the largest colour blurred."""

    __slots__ = ("_full", "cells", "f", "k", "vmax", "x0", "y0")

    def __init__(self, k, f, y0, x0, cells, vmax):
        self.k, self.f, self.y0, self.x0, self.cells, self.vmax = k, f, y0, x0, cells, vmax
        self._full = None

    @property
    def extent(self):
        """(y0, y1, x0, x1) in full-resolution pixels (may reach past the frame)."""
        return self.y0, self.y0 + self.cells.shape[0] * self.f, self.x0, self.x0 + self.cells.shape[1] * self.f

    def full(self) -> np.ndarray:
        """The cells at full resolution over :attr:`extent`."""
        if self._full is None:
            _, y1, _, x1 = self.extent
            self._full = self.cells if self.f == 1 else _resize(self.cells, (x1 - self.x0, y1 - self.y0), self.vmax)
        return self._full


class Grid:
    """The ladder of one render: each rung's radius, grid factor and blur, and the passes that
    share every pixel between two rungs (:mod:`lfring.focus.depth_aware_kernels`).

    ``params`` is (x_f, R, aperture): the focus's inverse depth, the view motion per unit of it
    and the aperture; ``sharp_rule`` (in-focus px, ramp px, the shift-and-add image's own second
    moment, px^2) the renderer's share of the shift-and-add image; ``scratch`` the renderer's
    kept memory (a dict); ``vmax`` the largest colour of the views (layers resized up are
    clamped by it)."""

    def __init__(self, radii, shape, channels, params, scratch, sharp_rule, vmax: float = 1.0):
        self.radii = radii
        self.vmax = float(vmax)
        self.scratch = scratch
        self.n = len(radii) - 1
        self.factors = np.array([grid_factor(r) for r in radii], np.int64)
        self.moments = np.array([blur_moment(r, f) for r, f in zip(radii, self.factors)])
        top = int(self.factors.max())
        self.stripe = top * max(1, 16 // top)
        self.shape, self.channels, self.params = shape, channels, params
        self.sharp_rule = sharp_rule

    def buffer(self, name: str, shape, fill=None) -> np.ndarray:
        """A float32 array of ``shape`` from the renderer's scratch memory (kept between renders:
        fresh memory costs a page fault per page on first write), filled with ``fill`` unless
        None. Scratch that has to grow is made :data:`SCRATCH_GROWTH` times the size asked
        for. Fresh scratch is :func:`lfring.core.memory.fresh_zeros` (fast to touch, and zeros
        already; the pages never written cost no memory), and scratch handed back with
        :meth:`left_zeros` holds zeros: a fill with 0 is then left out."""
        size = math.prod(shape)
        mem = self.scratch.get(name)
        zeros = self.scratch.pop((name, "zeros"), 0)  # handed out, it holds zeros no longer
        if mem is None or mem.size < size:
            mem = self.scratch[name] = fresh_zeros(max(int(size * SCRATCH_GROWTH), 1))
            zeros = size
        out = mem[:size].reshape(shape)
        if fill is not None and not (fill == 0.0 and zeros >= size):
            out.fill(fill)
        return out

    def left_zeros(self, name: str, size: int) -> None:
        """Records that the caller left the first ``size`` values of the scratch buffer ``name``
        all zeros (the next :meth:`buffer` of it with a fill of 0 is then not filled)."""
        self.scratch[(name, "zeros")] = int(size)

    def layers(self, kern, x, agree, cover, colour, sharp, window=None, name="front") -> list:
        """The blurred layers (far to near) of the pixels of ``colour`` where ``cover`` > 0
        (all within ``window``, (row0, row1, col0, col1), when given)."""
        h, w = self.shape
        c1 = self.channels + 1
        n = self.n
        xf, motion, aperture = self.params
        q = self.buffer(name + " rungs", (h, w))
        s = self.buffer(name + " shares", (h, w))
        stripes = (h + self.stripe - 1) // self.stripe
        boxes = np.empty((stripes, 2 * n + 1, 4), np.int64)
        boxes[..., 0::2] = np.iinfo(np.int64).max
        boxes[..., 1::2] = -1
        window = np.array((0, h, 0, w) if window is None else window, np.int64)
        kern.rungs(x, agree, cover, sharp, window, xf, motion, aperture, *self.sharp_rule,
                   self.moments, self.stripe, q, s, boxes)
        lo = boxes[..., 0::2].min(axis=0)
        hi = boxes[..., 1::2].max(axis=0)
        shift = np.zeros(2 * n + 1, np.int64)
        y0 = np.zeros(2 * n + 1, np.int64)
        x0 = np.zeros(2 * n + 1, np.int64)
        rows = np.zeros(2 * n + 1, np.int64)
        cols = np.zeros(2 * n + 1, np.int64)
        offset = np.zeros(2 * n + 1, np.int64)
        used = []
        total = 0
        for k in range(2 * n + 1):
            if hi[k, 0] < 0:
                continue
            radius = float(self.radii[abs(k - n)])
            f = int(self.factors[abs(k - n)])
            pad = int(math.ceil(radius)) + 1
            if f == 1:
                ya, yb = max(0, lo[k, 0] - pad), min(h, hi[k, 0] + pad + 1)
                xa, xb = max(0, lo[k, 1] - pad), min(w, hi[k, 1] + pad + 1)
            else:  # cells of f x f pixels, from a multiple of f
                ya, yb = max(0, (lo[k, 0] - pad) // f * f), -(-(hi[k, 0] + pad + 1) // f) * f
                xa, xb = max(0, (lo[k, 1] - pad) // f * f), -(-(hi[k, 1] + pad + 1) // f) * f
            shift[k], y0[k], x0[k] = f.bit_length() - 1, ya, xa
            rows[k], cols[k] = (yb - ya) // f, (xb - xa) // f
            offset[k] = total
            total += c1 * rows[k] * cols[k]
            used.append(k)
        buf = self.buffer(name + " layers", (total,))
        for k in used:  # the scatter writes the full-resolution boxes whole
            if shift[k] > 0:
                buf[offset[k]:offset[k] + c1 * rows[k] * cols[k]] = 0.0
        kern.scatter(colour, sharp, s, cover, q, window, n, shift, y0, x0, rows, cols, offset, self.stripe, buf)
        blurred = self.buffer(name + " blurred", (total,))
        out = []
        for k in used:
            cut = slice(offset[k], offset[k] + c1 * rows[k] * cols[k])
            radius = float(self.radii[abs(k - n)])
            f = 1 << int(shift[k])
            disc = radius if f == 1 else math.sqrt(max(radius * radius - f * f / 3.0, 0.0)) / f
            cells = buf[cut].reshape(rows[k], cols[k], c1)
            if disc >= 0.5:
                kernel = disc_kernel(disc)
                reach = kernel.shape[0] // 2
                cells, src = blurred[cut].reshape(cells.shape), cells
                kern.disc_blur(src, np.ascontiguousarray(kernel[reach:, reach:]), cells)
            out.append(Layer(k, f, int(y0[k]), int(x0[k]), cells, self.vmax))
        return out


def composite(layers: list, grid: Grid, kern) -> np.ndarray:
    """(h, w, C + 1): ``layers`` composited far to near. A layer covers ("over") what lies
    behind it, except the layer of the rung just behind: the two rungs around a pixel's radius
    are one surface, which does not hide itself. Consecutive layers on one reduced grid are
    composited there first, as one group (the composite of a group is a premultiplied layer
    too, with the group's transmission). A reduced grid's group of one layer is that layer: it
    is composited at full resolution as the others are (its full-resolution cells are kept for
    the next layer, which has it behind)."""
    h, w = grid.shape
    c = grid.channels
    acc = grid.buffer(COMPOSITE, (h, w, c + 1), 0.0)
    prev = None
    i = 0
    while i < len(layers):
        j = i
        while j < len(layers) and layers[j].f == layers[i].f:
            j += 1
        group = layers[i:j]
        f = group[0].f
        if f == 1 or len(group) == 1:
            for lay in group:
                behind, py, px = NO_IMAGE, 0, 0
                if prev is not None and lay.k == prev.k + 1:
                    behind, py, px = prev.full(), prev.y0, prev.x0
                kern.over(acc, lay.y0, lay.x0, lay.full(), behind, py, px, NO_MAP, NO_MAP, False)
                prev = lay
        else:
            uy0 = min(lay.y0 for lay in group)
            uy1 = max(lay.extent[1] for lay in group)
            ux0 = min(lay.x0 for lay in group)
            ux1 = max(lay.extent[3] for lay in group)
            rows, cols = (uy1 - uy0) // f, (ux1 - ux0) // f
            g = np.zeros((rows, cols, c + 1), np.float32)
            trans = np.ones((rows, cols), np.float32)
            adjacent = prev is not None and group[0].k == prev.k + 1
            skip = np.zeros((rows, cols), np.float32) if adjacent else NO_MAP
            last = None
            for n_in, lay in enumerate(group):
                behind, py, px = NO_IMAGE, 0, 0
                if last is not None and lay.k == last.k + 1:
                    behind, py, px = last.cells, (last.y0 - uy0) // f, (last.x0 - ux0) // f
                kern.over(g, (lay.y0 - uy0) // f, (lay.x0 - ux0) // f, lay.cells, behind, py, px, trans, skip, n_in == 0)
                last = lay
            # Onto the full-resolution composite: acc = group + transmission * acc (+ the skip term).
            size = (ux1 - ux0, uy1 - uy0)
            behind, py, px = (prev.full(), prev.y0, prev.x0) if adjacent else (NO_IMAGE, 0, 0)
            kern.merge(acc, uy0, ux0, _resize(g, size, grid.vmax), _resize(trans, size, 1.0),
                       _resize(skip, size, 1.0) if adjacent else NO_MAP, behind, py, px)
            prev = group[-1]
        i = j
    return acc


def sum_layers(layers: list, shape, c: int) -> tuple:
    """(y0, x0, cells): the layers summed over the frame's part they reach (the background: it
    only fills what the surfaces leave uncovered, so it needs no order)."""
    h, w = shape
    y0 = min(lay.y0 for lay in layers)
    x0 = min(lay.x0 for lay in layers)
    y1 = min(h, max(lay.extent[1] for lay in layers))
    x1 = min(w, max(lay.extent[3] for lay in layers))
    out = np.zeros((y1 - y0, x1 - x0, c + 1), np.float32)
    for lay in layers:
        cells = lay.full()
        ey0, ey1, ex0, ex1 = lay.extent
        ey1, ex1 = min(ey1, y1), min(ex1, x1)
        out[ey0 - y0:ey1 - y0, ex0 - x0:ex1 - x0] += cells[:ey1 - ey0, :ex1 - ex0]
    return y0, x0, out
