"""Shift-and-add refocusing: every view warped into the reference frame at the focus depth and
averaged, each pixel weighted by how many views are valid there, so the borders are not darkened.

Objects at the focus depth line up and are sharp; others appear as displaced copies.
:class:`Refocuser` is the NumPy/OpenCV reference (and the fast path for many frames at one depth);
:func:`refocus_torch` its torch twin, which also takes batches of frames; tests hold the two
together.
"""

from __future__ import annotations

import cv2
import numpy as np

from lfring.calibration.overlap import check_renderable
from lfring.core.backend import kernels_run_on, require_torch, resolve_device
from lfring.core.transfer import (check_frames, count_levels, device_masks, download, frames_dtype, inverse_maps, is_tensor,
                                  normalised, to_device)
from lfring.core.shift import ShiftEngine
from lfring.core.validate import check_shape_hw, check_threads, is_number
from lfring.core.viewstack import (WEIGHT_FLOOR, all_finite, cached_view_masks, check_unit_range, check_views,
                                   inverse_weight, unit_range_sample)
from lfring.core.warping import DEFAULT_INTERPOLATION, interpolation_flag, translation_of, warp_image
from lfring.errors import InvalidInputError
from lfring.focus.base import RefocusMethod
from lfring.core.protocols import check_calibration

__all__ = ["SHIFT_AND_ADD", "Refocuser", "refocus_torch"]


def _all_valid(masks) -> bool:
    return bool(np.all(masks == 1.0))


def _channel_masks(channels: int):
    """The masks shaped like a view of ``channels`` channels (made once per calibration)."""
    return lambda masks: [m if channels == 1 else np.repeat(m[..., None], channels, axis=2) for m in masks]


class Refocuser:
    """Refocus many frames at one depth: warps, masks and normalisation are computed once.

    An inspection line refocuses thousands of frames at one depth; this does the geometry
    once and leaves each frame with the resampling and one normalisation.

    Parameters
    ----------
    calibration : RingCalibration
    depth_m : float
        Distance from the main lens, metres.
    reference : 'center' or int
    view_shape : (h, w), optional
        Size of the views: the calibration's layout's (the default); any other is refused,
        since the calibration's valid discs are made for its layout.
    interpolation : {'linear', 'cubic'}
        Bilinear is fastest; bicubic keeps more detail and its smoothing depends less on the
        sub-pixel phase of each view's shift.
    threads : int, optional
        Threads for the shift path (default: OpenCV's, ``cv2.getNumThreads()``).

    Notes
    -----
    When every view's ``H_ref_from_view`` is a translation to within ``TRANSLATION_TOL_PX``
    (1e-3 px) over the whole reference frame, as for a ring whose views are parallel pinhole
    cameras of one focal length, bilinear resampling has the same four weights at every pixel:
    the views are then shifted and accumulated strip by strip in the cache (``shift_path`` is
    True). Otherwise every view goes through ``cv2.warpAffine`` / ``cv2.warpPerspective``.
    Both give the same image to float32 rounding.

    Examples
    --------
    >>> import lfring
    >>> cal = lfring.RingCalibration.load("twin_binned2")
    >>> r = lfring.Refocuser(cal, 0.5)
    >>> import numpy as np
    >>> views = np.full((4, *cal.layout.view_shape, 3), 0.5, np.float32)
    >>> out = r(views)
    >>> out.shape, float(round(out[352, 352, 0], 6))
    ((705, 705, 3), 0.5)
    """

    def __init__(self, calibration, depth_m: float, *, reference="center", view_shape=None, interpolation: str = DEFAULT_INTERPOLATION,
                 threads: int | None = None):
        check_calibration(calibration)
        if np.ndim(depth_m) != 0:
            raise InvalidInputError("Refocuser takes one depth; use focal_stack for several")
        check_threads(threads)
        try:
            depth = float(depth_m) if is_number(depth_m) else None
        except OverflowError:  # an integer beyond a float's range
            depth = None
        if depth is None:
            raise InvalidInputError(f"depth_m must be a number of metres, got {depth_m!r}")
        self.depth_m = depth
        self.reference = reference
        self._flag = interpolation_flag(interpolation)
        check_renderable(calibration, self.depth_m, reference=reference)
        self.view_shape = calibration.layout.view_shape if view_shape is None else check_shape_hw(view_shape, "view_shape")
        self.threads = threads
        self.H = calibration.homographies(self.depth_m, reference=reference)
        self._calibration = calibration
        self.masks = cached_view_masks(calibration, self.view_shape)
        self._all_valid = cached_view_masks(calibration, self.view_shape, "all_valid", _all_valid)
        self._shift = None
        if self._flag == cv2.INTER_LINEAR:
            shifts = [translation_of(hk, self.view_shape) for hk in self.H]
            if all(s is not None for s in shifts):
                self._shift = ShiftEngine(np.array(shifts), self.view_shape, None if self._all_valid else self.masks)
        self._weight = None
        self._inv = None
        self._cache: dict[int, tuple] = {}

    @property
    def shift_path(self) -> bool:
        """Whether frames take the shift path (every homography a translation)."""
        return self._shift is not None

    @property
    def weight(self) -> np.ndarray:
        """(h, w) number of views that see each reference pixel (fractional at edges)."""
        if self._weight is None:
            h, w = self.view_shape
            weight = np.zeros((h, w), np.float32)
            if self._shift is not None and self._all_valid:
                for y0, y1, row, _ in self._shift.inv_bands():
                    weight[y0:y1] = row
            elif self._shift is not None:  # the masks shifted like the views (not masked again)
                ShiftEngine(self._shift.shifts, self.view_shape).run(self.masks, weight)
            else:
                for k in range(len(self.H)):
                    weight += warp_image(self.masks[k], self.H[k], (w, h))
            self._weight = weight
        return self._weight

    def _inverse(self) -> np.ndarray:
        if self._inv is None:
            self._inv = inverse_weight(self.weight)
        return self._inv

    def _buffers(self, c: int):
        """Per channel count: the normalisation (a map like the result, or per band of rows one
        row) and the masks shaped like a view, made once and reused for every frame.

        With masks on the shift path, a Refocuser's first frame (all that a one-shot
        :func:`refocus` makes) takes the single-channel masks and inverse weight, spread over
        the channels strip by strip in the cache, rather than first writing a full-size
        per-depth map; later frames read the maps shaped like a view, which is faster per
        frame. Both give the same bits."""
        first = c not in self._cache
        if first or self._cache[c] is None:
            masks = None if self._all_valid else cached_view_masks(self._calibration, self.view_shape, ("channels", c), _channel_masks(c))
            if self._shift is not None and self._all_valid:
                inv = [row if c == 1 else np.repeat(row[:, None], c, axis=1) for _, _, _, row in self._shift.inv_bands()]
            elif self._shift is not None and first:
                self._cache[c] = None
                return self._inverse(), self.masks
            else:
                inv = self._inverse() if c == 1 else cv2.merge([self._inverse()] * c)
            self._cache[c] = (inv, masks)
        return self._cache[c]

    def __call__(self, views) -> np.ndarray:
        """The refocused image, (h, w, C) float32, of one frame's views (V, h, w, C)."""
        arr = check_views(views)
        if arr.shape[1:3] != self.view_shape or arr.shape[0] != len(self.H):
            raise InvalidInputError(f"expected {len(self.H)} views of {self.view_shape[1]} x {self.view_shape[0]} px, got shape {arr.shape}")
        c = arr.shape[3]
        inv, masks = self._buffers(c)
        h, w = self.view_shape
        src = np.ascontiguousarray(arr[..., 0] if c == 1 else arr)
        if self._shift is not None:
            out = np.empty((h, w) if c == 1 else (h, w, c), np.float32)
            threads = cv2.getNumThreads() if self.threads is None else self.threads
            if self._all_valid:
                self._shift.run(src, out, inv_rows=inv, threads=threads)
            else:
                self._shift.run(src, out, masks=masks, inv=inv, threads=threads)
            return out[..., None] if c == 1 else out
        shape = (h, w) if c == 1 else (h, w, c)
        tmp, masked = np.empty(shape, np.float32), np.empty(shape, np.float32)
        acc = None
        for k in range(len(self.H)):
            if masks is None:
                s_k = src[k]
            else:
                s_k = cv2.multiply(src[k], masks[k], dst=masked)
            if acc is None:  # the first view is warped straight into the result
                acc = warp_image(s_k, self.H[k], (w, h), interpolation=self._flag)
            else:
                warp_image(s_k, self.H[k], (w, h), dst=tmp, interpolation=self._flag)
                cv2.add(acc, tmp, dst=acc)
        cv2.multiply(acc, inv, dst=acc)
        if not all_finite(acc):
            raise InvalidInputError("views contain NaN or infinite values")
        if self._flag != cv2.INTER_LINEAR:
            np.clip(acc, 0.0, None, out=acc)  # bicubic overshoots below zero at dark edges
        return acc[..., None] if c == 1 else acc


def refocus_torch(frames, calibration, depth_m: float, *, reference="center", device=None, interpolation: str = "linear",
                  levels=None):
    """Refocus one frame's views (V, h, w, C) or a batch of frames (B, V, h, w, C) with torch.

    NumPy input gives NumPy output (float32); a torch tensor gives a tensor on ``device`` (by
    default its own). Views are float32 in [0, 1] or raw counts (uint8, uint16): counts travel to
    the device as integers and become ``(count - black) / (white - black)`` there, ``levels`` =
    (black, white), by default (0, the dtype's largest count); float views holding NaN or
    infinite values are refused. NumPy input travels through pinned memory, and the result comes
    back in one copy.

    On a CUDA device, bilinear refocusing is one Triton kernel
    (:mod:`lfring.focus.shift_and_add_kernels`): every output pixel reads its views' taps, in
    their dtype, once. Elsewhere (a CPU device, 'nearest', no Triton) kornia warps the views.
    ``interpolation`` is 'linear' (or 'nearest'); see :func:`lfring.refocus`.
    """
    torch = require_torch()
    if interpolation not in ("linear", "nearest"):
        raise InvalidInputError(f"the torch backend interpolates 'linear' or 'nearest', got {interpolation!r}")
    tensor_in = is_tensor(frames)
    if not tensor_in:
        frames = np.asarray(frames)
    offset, scale = count_levels(frames_dtype(frames), levels)
    shape, single = check_frames(frames)
    b, v, h, w, c = shape
    dev = resolve_device(device if device is not None or not tensor_in else frames.device)
    hs = calibration.homographies(depth_m, reference=reference)
    if hs.shape[0] != v:
        raise InvalidInputError(f"the calibration has {hs.shape[0]} views, the frames {v}")
    sample = unit_range_sample(frames.reshape(shape))  # counts given as floats, judged as NumPy's are
    check_unit_range(sample.detach().cpu().numpy() if tensor_in else sample, "views")
    raw = (frames if tensor_in else to_device(frames, dev)).to(dev).reshape(shape)
    masks = device_masks(calibration, (h, w), dev)
    with torch.no_grad():
        if interpolation == "linear" and kernels_run_on(dev):
            out = _refocus_kernel(raw.contiguous(), masks, hs, offset, scale)
        else:
            out = _refocus_kornia(torch, normalised(raw, offset, scale), masks, hs, interpolation)
        # As the NumPy path: a NaN or an infinity in float views would spread over the output
        # (counts cannot hold one). The check waits for the device, once a call.
        if raw.is_floating_point() and not bool(torch.isfinite(out).all()):
            raise InvalidInputError("views contain NaN or infinite values")
    if single:
        out = out[0]
    return out if tensor_in else download(out)


def _refocus_kernel(raw, masks, hs, offset: float, scale: float):
    """The refocus kernel over a batch (B, V, h, w, C) of any dtype on its device (raw counts
    clipped to [0, 1] once levelled, as :func:`lfring.core.transfer.normalised` does)."""
    torch = require_torch()
    from lfring.core import triton_kernels as tk
    from lfring.focus.shift_and_add_kernels import refocus_kernel

    b, v, h, w, c = raw.shape
    out = torch.empty((b, h, w, c), dtype=torch.float32, device=raw.device)
    hinv = inverse_maps(hs, raw.device)
    block = min(tk.next_power_of_2(h * w), 1 << 20) if tk.INTERPRETED else 256
    tk.launch(refocus_kernel, (-(-h * w // block), b), raw, masks, hinv, out, v, h, w, c, float(offset), float(scale),
              WEIGHT_FLOOR, CH=tk.next_power_of_2(c), BLOCK=block, CLIP=not raw.is_floating_point(),
              num_warps=1 if tk.INTERPRETED else 4)
    return out


def _refocus_kornia(torch, x, masks, hs, interpolation: str):
    """Shift-and-add of a float32 batch (B, V, h, w, C) by kornia's warps."""
    from kornia.geometry.transform import warp_perspective

    b, v, h, w, c = x.shape
    hs = torch.from_numpy(np.asarray(hs)).to(x.device, torch.float32)
    # (B, V, h, w, C) -> (B*V, C+1, h, w): the masked views and their masks warp together.
    src = torch.cat([x * masks[None, :, :, :, None], masks[None, :, :, :, None].expand(b, v, h, w, 1)], dim=-1)
    src = src.permute(0, 1, 4, 2, 3).reshape(b * v, c + 1, h, w)
    mode = "bilinear" if interpolation == "linear" else "nearest"
    warped = warp_perspective(src, hs.repeat(b, 1, 1), (h, w), mode=mode, padding_mode="zeros", align_corners=True)
    warped = warped.reshape(b, v, c + 1, h, w).sum(dim=1)
    weight = warped[:, c:]
    out = torch.where(weight > WEIGHT_FLOOR, warped[:, :c] / weight.clamp_min(WEIGHT_FLOOR), torch.zeros_like(warped[:, :c]))
    return out.permute(0, 2, 3, 1)


SHIFT_AND_ADD = RefocusMethod(
    name="shift-and-add",
    summary="the views' average aligned at the focus depth: out-of-focus objects as displaced copies (fastest)",
    prepare=None,
    backends=("numpy", "torch"),
)
