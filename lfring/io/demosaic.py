"""Demosaicing: a :class:`~lfring.io.raw.RawFrame` -> linear float32 RGB in [0, 1].

Every method first applies the levels explicitly, ``(counts - black) / (white - black)``
clipped to [0, 1] (per CFA position when the black level is per channel), then interpolates
the missing colours. The output is camera RGB: no white balance, no colour matrix, no gamma.

Methods
-------
'bilinear'
    OpenCV ``cv2.demosaicing`` with ``COLOR_Bayer*2RGB``.
'edge-aware' (default)
    OpenCV's edge-aware interpolation, ``COLOR_Bayer*2RGB_EA``.
'vng'
    OpenCV's variable number of gradients, ``COLOR_Bayer*2RGB_VNG``, which accepts 8-bit input
    only. Rather than quantise the whole frame to 8 bits (which ruins dark, linear data), the
    levelled mosaic is cut into 64 x 64 tiles (with an 8-pixel overlap, even offsets so the
    pattern is unchanged), each tile is scaled so that its own maximum is 255 before
    quantisation (VNG is homogeneous: scaling the input scales the output) and scaled back
    after. The quantisation residual (below half a code of the tile) is interpolated
    bilinearly and added back, so the raw samples come back exactly and smooth regions keep
    their full precision. What remains 8-bit is the gradient-dependent part of VNG's estimate:
    at most about one code of the tile's own range. OpenCV handles the last few columns of an
    image in its own way, so next to the right edge of a tile or frame the result can differ
    from one whole-frame 8-bit call by a few codes.
'rawpy'
    LibRaw's own pipeline (AHD), for frames read from a camera RAW file: the file at
    ``frame.path`` is decoded again and the frame's mosaic written into LibRaw's buffer, then
    ``postprocess`` runs with linear output (``gamma=(1, 1)``, ``no_auto_bright=True``,
    ``output_bps=16``, ``adjust_maximum_thr=0``), camera colour space (``output_color=raw``),
    no white balance (``user_wb=[1, 1, 1, 1]``, not the camera's as-shot balance, so that all
    methods return the same quantity), no rotation (``user_flip=0``) and the frame's levels
    (``user_black``, ``user_cblack``, ``user_sat``). With per-channel black levels LibRaw scales
    every channel by ``1 / (white - common black)``, not ``1 / (white - channel black)``.
'kornia'
    ``kornia.color.raw_to_rgb`` on CPU in float32 (bilinear, exact float arithmetic; torch and
    kornia are imported on first use).

The OpenCV paths take the levelled mosaic as uint16 on the full 0..65535 scale (OpenCV's
Bayer code has no float path), so any input depth keeps its precision up to 1/65535.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from lfring.core.registry import Registry
from lfring.errors import InvalidInputError
from lfring.io.bayer import (
    KORNIA_CFA,
    OPENCV_BAYER_TO_RGB,
    OPENCV_BAYER_TO_RGB_EA,
    OPENCV_BAYER_TO_RGB_VNG,
    pattern_channels,
)
from lfring.io.raw import RawFrame

__all__ = ["METHODS", "demosaic", "apply_levels"]

_U16 = 65535.0
# Mosaics narrower than this are mirrored out to interpolate them (see demosaic).
SMALLEST_INTERPOLATED_PX = 4


def apply_levels(frame: RawFrame) -> np.ndarray:
    """Raw counts -> linear float32 in [0, 1]: ``(counts - black) / (white - black)``, clipped.

    Returns (H, W) for a mosaic (black level per CFA position) or (H, W, 3) for an RGB image.
    """
    if not isinstance(frame, RawFrame):
        raise InvalidInputError(f"apply_levels expects a RawFrame, got {type(frame).__name__}")
    white = float(frame.white_level)
    if frame.image is not None:
        black = float(frame.black_level)
        scale = np.float32(1.0 / (white - black))
        out = (frame.image.astype(np.float32) - np.float32(black)) * scale
        return np.clip(out, 0.0, 1.0, out=out)
    h, w = frame.shape
    black = frame.black_level_2x2.astype(np.float32)
    scale = np.float32(1.0) / (np.float32(white) - black)
    # View the mosaic as (H/2, 2, W/2, 2) so that the per-position levels broadcast in one pass.
    blocks = frame.mosaic.reshape(h // 2, 2, w // 2, 2).astype(np.float32)
    blocks -= black[None, :, None, :]
    blocks *= scale[None, :, None, :]
    out = blocks.reshape(h, w)
    return np.clip(out, 0.0, 1.0, out=out)


def demosaic(frame: RawFrame, *, method: str = "edge-aware") -> np.ndarray:
    """Interpolate a raw frame to linear RGB.

    Parameters
    ----------
    frame : RawFrame
        From :func:`lfring.io.raw.load_raw`, or built from arrays.
    method : {'bilinear', 'edge-aware', 'vng', 'rawpy', 'kornia'}
        Interpolation; see the module documentation. Ignored for frames that are already RGB,
        which are only normalised.

    Returns
    -------
    ndarray of float32, shape (H, W, 3)
        Camera RGB, linear, in [0, 1]: 0 at the black level, 1 at the white level.

    Notes
    -----
    Linear value ``v = clip((counts - black) / (white - black), 0, 1)``, computed before the
    interpolation, so per-channel black levels are removed where they apply.

    Examples
    --------
    >>> import numpy as np, lfring
    >>> counts = np.full((4, 4), 4095, np.uint16)
    >>> rgb = lfring.demosaic(lfring.RawFrame(mosaic=counts, pattern="RGGB", bit_depth=12), method="bilinear")
    >>> rgb.shape, rgb.dtype, float(rgb.min())
    ((4, 4, 3), dtype('float32'), 1.0)

    The twin's flat (white) frame in data/synthetic: linear light, about 0.8 at the centre of
    the first view's disc (the render's exposure), 0 outside the discs:

    >>> rgb = lfring.demosaic(lfring.load_raw("data/synthetic/flat.png"))
    >>> rgb.shape, rgb.dtype, [round(float(c), 2) for c in rgb[426, 733]], rgb[10, 10].tolist()
    ((1842, 2456, 3), dtype('float32'), [0.8, 0.8, 0.8], [0.0, 0.0, 0.0])
    """
    if not isinstance(frame, RawFrame):
        raise InvalidInputError(
            f"demosaic expects a RawFrame (from load_raw, or RawFrame(mosaic=..., pattern=...)), "
            f"got {type(frame).__name__}"
        )
    if not isinstance(method, str) or method not in METHODS:
        raise InvalidInputError(
            f"unknown demosaic method {method!r}; valid methods: {', '.join(METHODS)}"
        )
    if frame.image is not None:
        return np.ascontiguousarray(apply_levels(frame))
    h, w = frame.mosaic.shape
    if min(h, w) < SMALLEST_INTERPOLATED_PX:
        # OpenCV's interpolation leaves such a mosaic black: it is mirrored about its edge pixels
        # first (a mirror keeps every pixel's colour in the pattern) and cut back after.
        p = SMALLEST_INTERPOLATED_PX
        out = METHODS[method](dataclasses.replace(frame, mosaic=np.pad(frame.mosaic, p, mode="reflect")))[p:p + h, p:p + w]
    else:
        out = METHODS[method](frame)
    return np.ascontiguousarray(np.clip(out, 0.0, 1.0, out=out), dtype=np.float32)


def _demosaic_bilinear(frame: RawFrame) -> np.ndarray:
    return _opencv_u16(apply_levels(frame), OPENCV_BAYER_TO_RGB[frame.pattern])


def _demosaic_edge_aware(frame: RawFrame) -> np.ndarray:
    return _opencv_u16(apply_levels(frame), OPENCV_BAYER_TO_RGB_EA[frame.pattern])


def _opencv_u16(linear: np.ndarray, code: int) -> np.ndarray:
    import cv2

    # Values are in [0, 1], so adding one half and truncating rounds to nearest.
    counts = (linear * np.float32(_U16) + np.float32(0.5)).astype(np.uint16)
    return cv2.demosaicing(counts, code).astype(np.float32) * np.float32(1.0 / _U16)


_VNG_TILE = 64
_VNG_HALO = 8


def _tile_spans(n: int, tile: int, halo: int):
    """(core start, core end, region start, region end) along one axis; all even offsets."""
    size = min(n, tile + 2 * halo)
    for c0 in range(0, n, tile):
        start = min(max(0, c0 - halo), n - size)
        yield c0, min(n, c0 + tile), start, start + size


def _demosaic_vng(frame: RawFrame) -> np.ndarray:
    import cv2

    linear, pattern = apply_levels(frame), frame.pattern
    code = OPENCV_BAYER_TO_RGB_VNG[pattern]
    h, w = linear.shape
    out = np.empty((h, w, 3), dtype=np.float32)
    residual = np.empty((h, w), dtype=np.float32)
    for y0, y1, ya, yb in _tile_spans(h, _VNG_TILE, _VNG_HALO):
        for x0, x1, xa, xb in _tile_spans(w, _VNG_TILE, _VNG_HALO):
            region = linear[ya:yb, xa:xb]
            peak = float(region.max())
            gain = np.float32(255.0 / peak if peak > 0 else 255.0)
            codes = np.clip(np.rint(region * gain), 0, 255)
            vng = cv2.demosaicing(codes.astype(np.uint8), code)
            cy, cx = slice(y0 - ya, y1 - ya), slice(x0 - xa, x1 - xa)
            out[y0:y1, x0:x1] = vng[cy, cx].astype(np.float32) / gain
            residual[y0:y1, x0:x1] = region[cy, cx] - codes[cy, cx].astype(np.float32) / gain
    out += _bilinear_float(residual, pattern)
    return out


def _bilinear_float(values: np.ndarray, pattern: str) -> np.ndarray:
    """Float32 bilinear demosaicing by normalised convolution (mirror borders keep CFA parity)."""
    import cv2

    channels = pattern_channels(pattern)
    h, w = values.shape
    out = np.empty((h, w, 3), dtype=np.float32)
    # Mirroring about the edge pixel (BORDER_REFLECT_101) maps a CFA position onto one of the same
    # colour, so the same kernels hold at the borders.
    kernel_g = np.array([[0, 1, 0], [1, 4, 1], [0, 1, 0]], np.float32) / 4.0
    kernel_rb = np.array([[1, 2, 1], [2, 4, 2], [1, 2, 1]], np.float32) / 4.0
    for c in range(3):
        mask = np.zeros((h, w), dtype=np.float32)
        for dy in (0, 1):
            for dx in (0, 1):
                if channels[dy, dx] == c:
                    mask[dy::2, dx::2] = 1.0
        kernel = kernel_g if c == 1 else kernel_rb
        out[..., c] = cv2.filter2D(values * mask, cv2.CV_32F, kernel, borderType=cv2.BORDER_REFLECT_101)
    return out


def _demosaic_kornia(frame: RawFrame) -> np.ndarray:
    import torch
    from kornia.color import CFA, raw_to_rgb

    tensor = torch.from_numpy(np.ascontiguousarray(apply_levels(frame)))[None, None]
    with torch.no_grad():
        rgb = raw_to_rgb(tensor, getattr(CFA, KORNIA_CFA[frame.pattern]))
    return rgb[0].permute(1, 2, 0).contiguous().numpy()


def _demosaic_rawpy(frame: RawFrame) -> np.ndarray:
    if frame.file_format != "camera_raw" or frame.path is None:
        raise InvalidInputError(
            "demosaic method 'rawpy' needs a frame read from a camera RAW file by load_raw "
            f"(file_format 'camera_raw'), got file_format {frame.file_format!r}; use 'edge-aware', "
            "'vng', 'bilinear' or 'kornia'"
        )
    import rawpy

    from lfring.errors import FileFormatError, LfringError, LfringFileNotFoundError
    from lfring.io.raw import cfa_letters, visible_cfa_indices

    p = frame.path
    if not p.is_file():
        raise LfringFileNotFoundError(f"{p}: no such file; method 'rawpy' re-reads the camera RAW file")
    h, w = frame.shape
    try:
        with rawpy.imread(str(p)) as raw:
            indices = visible_cfa_indices(raw, p)
            letters = cfa_letters(raw, indices, p)
            if letters != frame.pattern:
                raise InvalidInputError(
                    f"{p}: method 'rawpy' demosaics with the file's own CFA ({letters}), but the frame "
                    f"says {frame.pattern}; use another method for an overridden pattern"
                )
            visible = raw.raw_image_visible
            if visible.shape[0] < h or visible.shape[1] < w:
                raise InvalidInputError(
                    f"{p}: the frame ({w} x {h}) is larger than the file's visible area "
                    f"({visible.shape[1]} x {visible.shape[0]}); method 'rawpy' cannot use it"
                )
            visible[:h, :w] = frame.mosaic
            black = frame.black_level_2x2
            base = float(black.min())
            cblack = [0, 0, 0, 0]
            for (dy, dx), index in np.ndenumerate(indices):
                cblack[int(index)] = int(round(black[dy, dx] - base))
            rgb = raw.postprocess(
                demosaic_algorithm=rawpy.DemosaicAlgorithm.AHD,
                use_camera_wb=False,
                use_auto_wb=False,
                user_wb=[1.0, 1.0, 1.0, 1.0],
                output_color=rawpy.ColorSpace.raw,
                output_bps=16,
                gamma=(1.0, 1.0),
                no_auto_bright=True,
                adjust_maximum_thr=0.0,
                user_flip=0,
                user_black=int(round(base)),
                user_cblack=cblack,
                # LibRaw applies user_sat after subtracting the black level.
                user_sat=int(round(frame.white_level - base)),
            )
    except LfringError:
        raise
    except (rawpy.LibRawError, OSError) as exc:
        raise FileFormatError(
            f"{p}: LibRaw could not re-read the file for method 'rawpy' ({exc})"
        ) from exc
    out = rgb[:h, :w, :3].astype(np.float32) * np.float32(1.0 / _U16)
    return np.ascontiguousarray(np.clip(out, 0.0, 1.0, out=out))


#: The demosaicing methods by name, each ``RawFrame -> (H, W, 3) float32`` linear camera RGB
#: (clipped to [0, 1] by :func:`demosaic`), in the order the documentation lists them.
METHODS = Registry("method")
METHODS.register("bilinear", _demosaic_bilinear)
METHODS.register("edge-aware", _demosaic_edge_aware)
METHODS.register("vng", _demosaic_vng)
METHODS.register("rawpy", _demosaic_rawpy)
METHODS.register("kornia", _demosaic_kornia)
