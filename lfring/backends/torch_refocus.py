"""Refocusing with torch/kornia: batches of frames on a GPU, the same numbers on the CPU.

The NumPy/OpenCV :mod:`lfring.focus` is the reference; tests hold the two together.
"""

from __future__ import annotations

import numpy as np

from lfring.core.backend import require_torch, resolve_device
from lfring.errors import InvalidInputError
from lfring.core.viewstack import WEIGHT_FLOOR, cached_view_masks

__all__ = ["refocus_torch"]


def refocus_torch(frames, calibration, depth_m: float, *, reference="center", device=None, interpolation: str = "linear"):
    """Refocus one frame's views (V, h, w, C) or a batch of frames (B, V, h, w, C).

    NumPy input gives NumPy output (float32); a torch tensor gives a tensor on ``device``.
    ``interpolation`` is 'linear' (or 'nearest'); see :func:`lfring.refocus`.
    """
    torch = require_torch()
    from kornia.geometry.transform import warp_perspective

    if interpolation not in ("linear", "nearest"):
        raise InvalidInputError(f"the torch backend interpolates 'linear' or 'nearest', got {interpolation!r}")
    is_tensor = isinstance(frames, torch.Tensor)
    dev = resolve_device(device if device is not None else (frames.device if is_tensor else None))
    x = frames if is_tensor else torch.from_numpy(np.ascontiguousarray(frames))
    if x.dtype != torch.float32:
        raise InvalidInputError(f"views must be float32, got {x.dtype}")
    single = x.ndim == 4
    if single:
        x = x[None]
    if x.ndim != 5:
        raise InvalidInputError(f"expected (V, h, w, C) or (B, V, h, w, C) views, got shape {tuple(x.shape)}")
    b, v, h, w, c = x.shape
    masks = torch.from_numpy(np.array(cached_view_masks(calibration, (h, w)))).to(dev)  # writable copy of the read-only cache  # (V, h, w)
    hs = torch.from_numpy(calibration.homographies(depth_m, reference=reference)).to(dev, torch.float32)
    if hs.shape[0] != v:
        raise InvalidInputError(f"the calibration has {hs.shape[0]} views, the frames {v}")
    x = x.to(dev)
    # (B, V, h, w, C) -> (B*V, C+1, h, w): the masked views and their masks warp together.
    src = torch.cat([x * masks[None, :, :, :, None], masks[None, :, :, :, None].expand(b, v, h, w, 1)], dim=-1)
    src = src.permute(0, 1, 4, 2, 3).reshape(b * v, c + 1, h, w)
    mode = "bilinear" if interpolation == "linear" else "nearest"
    warped = warp_perspective(src, hs.repeat(b, 1, 1), (h, w), mode=mode, padding_mode="zeros", align_corners=True)
    warped = warped.reshape(b, v, c + 1, h, w).sum(dim=1)
    weight = warped[:, c:]
    out = torch.where(weight > WEIGHT_FLOOR, warped[:, :c] / weight.clamp_min(WEIGHT_FLOOR), torch.zeros_like(warped[:, :c]))
    out = out.permute(0, 2, 3, 1)
    if single:
        out = out[0]
    return out if is_tensor else out.cpu().numpy()
