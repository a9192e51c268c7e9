"""View stacks and results between the host and a torch device: what the torch backends of
refocusing and depth share.

NumPy input travels through pinned (page-locked) host memory to a CUDA device, and results come
back the same way, in one copy per call. Integer view stacks (uint8, uint16: raw counts) travel as
integers, a half or a quarter of the bytes of float32, and become float32 on the device through
an explicit normalisation with black and white levels (:func:`count_levels`): by default 0 and
the dtype's largest value. torch is imported by the functions that need it, never by importing
this module.
"""

from __future__ import annotations

import sys

import numpy as np

from lfring.core.backend import require_torch
from lfring.core.validate import check_number
from lfring.core.viewstack import cached_view_masks, calibration_cache
from lfring.errors import InvalidInputError

__all__ = ["COUNT_DTYPES", "check_frames", "count_levels", "device_masks", "download", "download_maps", "frames_dtype", "inverse_maps",
           "is_tensor", "normalised", "to_device"]

# The integer view stacks the torch backends take (raw counts), by their dtype's name.
COUNT_DTYPES = ("uint8", "uint16")


def is_tensor(x) -> bool:
    """Whether ``x`` is a torch tensor (without importing torch where nothing has)."""
    torch = sys.modules.get("torch")
    return torch is not None and isinstance(x, torch.Tensor)


def frames_dtype(frames) -> str:
    """The dtype's name of a NumPy or torch view stack ('float32', 'uint8', ...)."""
    return str(frames.dtype).replace("torch.", "")


def check_frames(frames) -> tuple[tuple[int, ...], bool]:
    """The shape of a NumPy or torch view stack for the torch backends, as (B, V, h, w, C), and
    whether it was one frame: (V, h, w, C) or (V, h, w) (one channel) is a frame, (B, V, h, w, C)
    a batch; 1 to 4 channels, views of 2 x 2 px or more."""
    shape = tuple(int(n) for n in frames.shape)
    single = len(shape) in (3, 4)
    if len(shape) == 3:
        shape = shape + (1,)
    if single:
        shape = (1,) + shape
    if len(shape) != 5 or shape[1] < 1 or min(shape[2:4]) < 2 or not 1 <= shape[4] <= 4:
        raise InvalidInputError(f"views must be (V, h, w, C) or a batch (B, V, h, w, C) of 1 to 4 channels, got shape "
                                f"{tuple(frames.shape)}")
    return shape, single


def count_levels(dtype: str, levels=None) -> tuple[float, float]:
    """``(offset, scale)`` that make views of ``dtype`` float32: ``(value - offset) * scale``.

    Parameters
    ----------
    dtype : str
        'float32' (taken as it is) or one of :data:`COUNT_DTYPES` (raw counts).
    levels : (black, white), optional
        For integer views: the count of black and of white (``white > black``); by default 0 and
        the dtype's largest value. Float views take none.

    Examples
    --------
    >>> count_levels("uint8")
    (0.0, 0.00392156862745098)
    >>> count_levels("uint16", (64, 1023))[0]
    64.0
    """
    if dtype == "float32":
        if levels is not None:
            raise InvalidInputError("levels are the black and white counts of integer (uint8, uint16) views; "
                                    "float32 views are already in [0, 1]")
        return 0.0, 1.0
    if dtype not in COUNT_DTYPES:
        raise InvalidInputError(f"views must be float32 in [0, 1], or raw counts ({', '.join(COUNT_DTYPES)}) on the "
                                f"torch backend, got {dtype}")
    if levels is None:
        return 0.0, 1.0 / float(np.iinfo(dtype).max)
    try:
        black, white = levels
    except (TypeError, ValueError):
        raise InvalidInputError(f"levels must be (black, white) counts, got {levels!r}") from None
    top = float(np.iinfo(dtype).max)
    black = check_number(black, "the black level", minimum=0.0, below=top, hint=f" ({dtype} counts)")
    white = check_number(white, "the white level", above=black, maximum=top,
                         hint=f" (above the black level, at most {dtype}'s largest count)")
    return black, 1.0 / (white - black)


def to_device(array, device):
    """A NumPy array as a tensor on ``device``: to a CUDA device through pinned memory (the copy
    runs asynchronously on the current stream); on the CPU the array's own memory (read-only
    use)."""
    torch = require_torch()
    a = np.ascontiguousarray(array)
    t = torch.from_numpy(a if a.flags.writeable else a.copy())  # torch warns on read-only memory
    if torch.device(device).type != "cuda":
        return t.to(device)
    return t.pin_memory().to(device, non_blocking=True)


def inverse_maps(hs, device):
    """(..., 9) float32 tensor on ``device`` of the inverses of the homographies ``hs`` (..., 3, 3):
    the maps from reference pixels to view pixels, which the kernels sample through."""
    torch = require_torch()
    inv = np.linalg.inv(np.asarray(hs, np.float64))
    return torch.from_numpy(np.ascontiguousarray(inv.reshape(*inv.shape[:-2], 9), np.float32)).to(device)


def normalised(frames, offset: float, scale: float):
    """Views of any dtype as float32 ``(value - offset) * scale`` on their device, raw counts
    (integer views) clipped to [0, 1] as :func:`lfring.demosaic` clips them (counts below black,
    above white); float32 views with offset 0 and scale 1 are returned as they are."""
    torch = require_torch()
    if frames.dtype == torch.float32 and offset == 0.0 and scale == 1.0:
        return frames
    out = (frames.to(torch.float32) - np.float32(offset)) * np.float32(scale)
    return out if frames.is_floating_point() else out.clamp_(0.0, 1.0)


def download(tensor) -> np.ndarray:
    """A tensor as a NumPy array on the host: from a CUDA device through pinned memory."""
    torch = require_torch()
    if tensor.device.type != "cuda":
        return tensor.detach().numpy()
    host = torch.empty(tensor.shape, dtype=tensor.dtype, pin_memory=True)
    host.copy_(tensor, non_blocking=True)
    torch.cuda.current_stream(tensor.device).synchronize()
    return host.numpy()


def download_maps(maps) -> list[np.ndarray]:
    """Several maps of one shape and dtype copied to the host in one copy (stacked on the device)."""
    torch = require_torch()
    return list(download(torch.stack(list(maps))))


def device_masks(calibration, view_shape, device, *, taper: float | None = None):
    """:func:`lfring.core.viewstack.cached_view_masks` (the default taper unless given) as a
    float32 tensor on ``device``, uploaded once per calibration, view shape, taper and device."""
    torch = require_torch()
    shape = tuple(int(n) for n in view_shape)
    kw = {} if taper is None else {"taper": float(taper)}

    def make():
        return torch.from_numpy(np.array(cached_view_masks(calibration, shape, **kw), np.float32)).to(device)

    return calibration_cache(calibration, ("device_masks", shape, kw.get("taper"), str(torch.device(device))), make)
