"""Torch twin of :func:`lfring.depth.sgm.sgm_aggregate` (CPU or CUDA).

Each path is a loop over its scan direction; every step updates a whole image line at once, a
(N, line length) minimum over the previous line's state shifted by one hypothesis. The equations,
the neutral value of invalid costs and the default penalties are those of
:mod:`lfring.depth.sgm`; ``tests/depth/test_sgm_torch.py`` holds the two together.
"""

from __future__ import annotations

import numpy as np

from lfring.core.backend import require_torch, resolve_device
from lfring.depth.sgm import EDGE_SCALE, P1_SCALE, P2_SCALE, PATHS, check_guide, check_paths, check_penalty, cost_scale
from lfring.errors import InvalidInputError

__all__ = ["sgm_aggregate_torch"]


def _neutral(c, torch):
    finite = torch.isfinite(c)
    count = finite.sum(dim=0)
    total = torch.where(finite, c, torch.zeros((), dtype=c.dtype, device=c.device)).double().sum(dim=0)
    mean = torch.where(count > 0, total / count.clamp(min=1), torch.zeros_like(total)).float()
    return torch.where(finite, c, mean.unsqueeze(0))


def _step(prev, pmin, c, p1, p2e, torch):
    """One step of the recursion for a whole line: prev, c (N, M); pmin, p2e (M,)."""
    inf = torch.full_like(prev[:1], float("inf"))
    down = torch.cat([inf, prev[:-1]], dim=0) + p1  # prev[d - 1] + p1
    up = torch.cat([prev[1:], inf], dim=0) + p1  # prev[d + 1] + p1
    best = torch.minimum(torch.minimum(torch.minimum(prev, down), up), (pmin + p2e).unsqueeze(0))
    return c + (best - pmin.unsqueeze(0))


def _p2_line(g_cur, g_prev, p1, p2, edge_scale, torch):
    one = torch.ones((), dtype=torch.float32, device=g_cur.device)
    return torch.maximum(p1, p2 / (one + torch.abs(g_cur - g_prev) / edge_scale))


def sgm_aggregate_torch(cost, *, guide=None, p1: float | None = None, p2: float | None = None, paths: int = 4,
                        edge_scale: float | None = EDGE_SCALE, device=None):
    """Semi-global aggregation in torch; same arguments and result as :func:`~lfring.depth.sgm.sgm_aggregate`.

    Parameters
    ----------
    cost : (N, h, w) float array or tensor
        Cost volume; NaN or inf are invalid (see :func:`lfring.depth.sgm.sgm_aggregate`).
    guide : (h, w) array or tensor, optional
        Reference luminance in [0, 1] for the edge-aware large-jump penalty.
    p1, p2, paths, edge_scale
        As in :func:`lfring.depth.sgm.sgm_aggregate`.
    device : str or torch.device, optional
        Where to compute (default: the tensor's device, or CUDA when available for arrays).

    Returns
    -------
    (N, h, w) float32
        A NumPy array when ``cost`` is a NumPy array, otherwise a tensor on ``device``.
    """
    torch = require_torch()
    is_tensor = isinstance(cost, torch.Tensor)
    if is_tensor:
        dev = cost.device if device is None else resolve_device(device)
        c = cost.detach().to(dev)
    else:
        a = np.asarray(cost)
        dev = resolve_device(device)
        c = torch.from_numpy(np.ascontiguousarray(a)).to(dev) if a.dtype.kind == "f" else None
        if c is None:
            raise InvalidInputError(f"cost must be floating point (float32), got {a.dtype}")
    if c.ndim != 3 or min(c.shape) < 1:
        raise InvalidInputError(f"cost must be a non-empty (N, h, w) cost volume, got shape {tuple(c.shape)}")
    if not c.is_floating_point():
        raise InvalidInputError(f"cost must be floating point (float32), got {c.dtype}")
    paths = check_paths(paths)
    c = c.float()
    n, h, w = c.shape
    if p1 is None or p2 is None:
        scale = cost_scale(c.cpu().numpy())
        p1 = P1_SCALE * scale if p1 is None else p1
        p2 = P2_SCALE * scale if p2 is None else p2
    p1 = check_penalty(p1, "p1")
    p2 = max(check_penalty(p2, "p2"), p1)
    f32 = torch.float32
    tp1 = torch.tensor(np.float32(p1), dtype=f32, device=dev)
    tp2 = torch.tensor(np.float32(p2), dtype=f32, device=dev)
    use_guide = guide is not None and edge_scale is not None
    if use_guide:
        edge_scale = check_penalty(edge_scale, "edge_scale", allow_zero=False)
        # The numba version's checks and luminance (an (h, w) image of guide values is small).
        g = torch.from_numpy(check_guide(guide.detach().cpu().numpy() if isinstance(guide, torch.Tensor) else guide,
                                         (h, w))).to(dev)
        tes = torch.tensor(np.float32(edge_scale), dtype=f32, device=dev)
    c = _neutral(c, torch)
    out = torch.zeros_like(c)
    with torch.no_grad():
        for dy, dx in PATHS[paths]:
            if dy == 0:  # horizontal: the line is a column of all rows, stepping along x
                xs = range(w) if dx > 0 else range(w - 1, -1, -1)
                prev = pmin = None
                for x in xs:
                    cx = c[:, :, x]
                    if prev is None:
                        cur = cx.clone()
                    else:
                        p2e = _p2_line(g[:, x], g[:, x - dx], tp1, tp2, tes, torch) if use_guide else tp2.expand(h)
                        cur = _step(prev, pmin, cx, tp1, p2e, torch)
                    out[:, :, x] += cur
                    prev, pmin = cur, cur.min(dim=0).values
                continue
            ys = range(h) if dy > 0 else range(h - 1, -1, -1)
            has_pred = torch.ones(w, dtype=torch.bool, device=dev)
            if dx == 1:
                has_pred[0] = False
            elif dx == -1:
                has_pred[-1] = False
            prev = pmin = None
            for y in ys:
                cy = c[:, y, :]
                if prev is None:
                    cur = cy.clone()
                else:
                    # The predecessor of (y, x) is (y - dy, x - dx): shift the previous line by dx.
                    sp = torch.roll(prev, shifts=dx, dims=1) if dx else prev
                    spm = torch.roll(pmin, shifts=dx, dims=0) if dx else pmin
                    if use_guide:
                        gp = torch.roll(g[y - dy], shifts=dx, dims=0) if dx else g[y - dy]
                        p2e = _p2_line(g[y], gp, tp1, tp2, tes, torch)
                    else:
                        p2e = tp2.expand(w)
                    cur = torch.where(has_pred.unsqueeze(0), _step(sp, spm, cy, tp1, p2e, torch), cy)
                out[:, y, :] += cur
                prev, pmin = cur, cur.min(dim=0).values
    if is_tensor:
        return out
    return out.cpu().numpy()
