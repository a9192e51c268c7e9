"""The Triton kernel of the torch refocus (:func:`lfring.focus.shift_and_add.refocus_torch`):
compiled for the GPU, or interpreted on CPU tensors where the process sees no CUDA device
(:mod:`lfring.core.triton_kernels`). Imported on first use only.
"""

from __future__ import annotations

from lfring.core.triton_kernels import jit, project, taps, tl

__all__ = ["refocus_kernel"]


@jit
def refocus_kernel(frames_ptr, msk_ptr, hinv_ptr, out_ptr, n_views, h, w, channels, offset, scale, floor,
                   CH: tl.constexpr, BLOCK: tl.constexpr, CLIP: tl.constexpr):
    """Shift-and-add of frame ``program_id(1)`` of a batch (B, V, h, w, C) (any dtype; each value
    becomes ``(value - offset) * scale``, clipped to [0, 1] with ``CLIP``, as raw counts are): per reference pixel the views' values premultiplied by
    their masks and the masks, each warped (bilinear, zero outside) by ``hinv`` (V, 9, reference
    to view), summed, and their ratio where the weight exceeds ``floor`` (else 0), into ``out``
    (B, h, w, C) float32. ``CH``: the channels rounded up to a power of two."""
    pid = tl.program_id(0)
    b = tl.program_id(1)
    hw = h * w
    p = pid * BLOCK + tl.arange(0, BLOCK)
    inside = p < hw
    ch = tl.arange(0, CH)[None, :]
    ch_ok = ch < channels
    yf = (p // w).to(tl.float32)
    xf = (p % w).to(tl.float32)
    acc = tl.zeros([BLOCK, CH], tl.float32)
    weight = tl.zeros([BLOCK], tl.float32)
    for k in range(0, n_views):
        u, v = project(hinv_ptr + k * 9, xf, yf)
        o00, m00, m01, m10, m11, fx, fy = taps(u, v, h, w)
        mk = msk_ptr + tl.cast(k, tl.int64) * hw
        frame = frames_ptr + (b.to(tl.int64) * n_views + k) * hw * channels
        # Each tap's mask and its values premultiplied by it, combined as the mask's own sample.
        t00 = tl.load(mk + o00, mask=m00, other=0.0)
        t01 = tl.load(mk + o00 + 1, mask=m01, other=0.0)
        t10 = tl.load(mk + o00 + w, mask=m10, other=0.0)
        t11 = tl.load(mk + o00 + w + 1, mask=m11, other=0.0)
        c00 = (tl.load(frame + o00[:, None] * channels + ch, mask=m00[:, None] & ch_ok, other=0).to(tl.float32)
               - offset) * scale
        c01 = (tl.load(frame + (o00 + 1)[:, None] * channels + ch, mask=m01[:, None] & ch_ok, other=0).to(tl.float32)
               - offset) * scale
        c10 = (tl.load(frame + (o00 + w)[:, None] * channels + ch, mask=m10[:, None] & ch_ok, other=0).to(tl.float32)
               - offset) * scale
        c11 = (tl.load(frame + (o00 + w + 1)[:, None] * channels + ch, mask=m11[:, None] & ch_ok,
                       other=0).to(tl.float32) - offset) * scale
        if CLIP:
            c00 = tl.minimum(tl.maximum(c00, 0.0), 1.0)
            c01 = tl.minimum(tl.maximum(c01, 0.0), 1.0)
            c10 = tl.minimum(tl.maximum(c10, 0.0), 1.0)
            c11 = tl.minimum(tl.maximum(c11, 0.0), 1.0)
        c00 = c00 * t00[:, None]
        c01 = c01 * t01[:, None]
        c10 = c10 * t10[:, None]
        c11 = c11 * t11[:, None]
        weight += (t00 * (1.0 - fx) + t01 * fx) * (1.0 - fy) + (t10 * (1.0 - fx) + t11 * fx) * fy
        gx = fx[:, None]
        gy = fy[:, None]
        acc += (c00 * (1.0 - gx) + c01 * gx) * (1.0 - gy) + (c10 * (1.0 - gx) + c11 * gx) * gy
    ok = weight > floor
    out = tl.where(ok[:, None], acc / tl.maximum(weight, floor)[:, None], 0.0)
    tl.store(out_ptr + (b.to(tl.int64) * hw + p[:, None]) * channels + ch, out, mask=inside[:, None] & ch_ok)
