"""What the Triton kernels of lfring share: whether they run compiled or interpreted, how they are
launched, and the bilinear sampling of an image through a homography.

Importing this module imports torch and Triton (where installed: Triton's wheels are for Linux
x86-64; :data:`AVAILABLE` says whether it is); the stages import it on first use only, never
``import lfring``. The kernels are compiled for the GPU. A process that sees no CUDA device runs
them through Triton's interpreter on CPU tensors instead (the same kernels, slowly: for the
tests, within :func:`interpreted_on_cpu`). The choice is made once, at the first import, because
Triton reads ``TRITON_INTERPRET`` when it is itself first imported: :data:`INTERPRETED` holds it
and :func:`runs_on` says whether the kernels run on a given device. The choice is the process's
own (Triton's knob): the environment is left as it was, so subprocesses choose for themselves,
and a ``TRITON_INTERPRET`` set by the caller is obeyed. Outside :func:`interpreted_on_cpu` no
stage runs a kernel on a CPU tensor, so the choice changes nothing else.
"""

from __future__ import annotations

import contextlib
import contextvars
import os
import sys

import numpy as np

try:
    import torch

    _choose = not torch.cuda.is_available() and "triton" not in sys.modules and "TRITON_INTERPRET" not in os.environ
    if _choose:
        # No device for compiled kernels: Triton's interpreter runs them on CPU tensors. It must
        # be chosen before Triton is first imported (its library functions are made then).
        os.environ["TRITON_INTERPRET"] = "1"
    try:
        import triton
        import triton.language as tl
    finally:
        if _choose:
            # The choice stays with this process (Triton's knob), not with the environment that
            # subprocesses inherit.
            del os.environ["TRITON_INTERPRET"]
    if _choose:
        triton.knobs.runtime.interpret = True
        os.environ.pop("TRITON_INTERPRET", None)  # the knob's setter writes it back
except ImportError:  # pragma: no cover - the torch extra without Triton (not Linux x86-64)
    triton = tl = None

__all__ = ["AVAILABLE", "INTERPRETED", "bilinear", "device_function", "interpreted_on_cpu", "jit", "launch", "next_power_of_2", "project",
           "reduce_min", "reduce_sum", "runs_on", "sample", "taps", "tl"]

# Whether Triton is installed (the kernels exist).
AVAILABLE = triton is not None
# Whether this process runs the kernels through Triton's interpreter (on CPU tensors).
INTERPRETED = bool(AVAILABLE and triton.knobs.runtime.interpret)


def jit(fn):
    """``triton.jit`` for a kernel, or the plain function where Triton is missing (then nothing
    launches it)."""
    return triton.jit(fn) if AVAILABLE else fn


def device_function(fn):
    """``triton.jit`` for a function the kernels call; interpreted, the plain function (the
    interpreter runs a kernel's body as Python, and a jitted callee costs a re-patching of
    Triton's language on every call)."""
    return triton.jit(fn) if AVAILABLE and not INTERPRETED else fn


# Whether the stages hand CPU tensors to the interpreted kernels (see interpreted_on_cpu).
_ON_CPU = contextvars.ContextVar("lfring_kernels_on_cpu", default=False)


def runs_on(device) -> bool:
    """Whether the stages run their kernels on tensors of ``device``: compiled on CUDA; on the CPU
    only within :func:`interpreted_on_cpu` in a process that interprets them; never without
    Triton. Elsewhere the stages take their torch paths."""
    if not AVAILABLE:
        return False
    kind = torch.device(device).type
    return kind == "cpu" and _ON_CPU.get() if INTERPRETED else kind == "cuda"


@contextlib.contextmanager
def interpreted_on_cpu():
    """Within it the stages run their kernels on CPU tensors through Triton's interpreter (where
    the process interprets them: :data:`INTERPRETED`): how the tests run the GPU paths without a
    GPU. The interpreter runs a kernel's operations one by one in Python, far slower than the
    torch and NumPy paths a CPU device takes otherwise. Yields whether it applies."""
    token = _ON_CPU.set(True)
    try:
        yield INTERPRETED
    finally:
        _ON_CPU.reset(token)


def launch(kernel, grid, *args, num_warps: int = 4, **constants) -> None:
    """``kernel[grid](*args, **constants)``, compiled without fused multiply-adds (the rounding of
    the NumPy references); interpreted, numpy's warnings on infinite intermediate values are
    silenced (the kernels select around them, as the compiled code does silently)."""
    with np.errstate(all="ignore"):
        kernel[grid](*args, num_warps=num_warps, enable_fp_fusion=False, **constants)


def next_power_of_2(n: int) -> int:
    """The least power of two >= n (>= 1): the sizes of Triton's blocks."""
    return 1 << max(0, int(n) - 1).bit_length()


@device_function
def project(hinv_ptr, xf, yf):
    """Where the 3 x 3 map at ``hinv_ptr`` (row-major float32) takes the pixels (xf, yf); NaN
    (a degenerate map) is sent outside the frame."""
    h00 = tl.load(hinv_ptr + 0)
    h01 = tl.load(hinv_ptr + 1)
    h02 = tl.load(hinv_ptr + 2)
    h10 = tl.load(hinv_ptr + 3)
    h11 = tl.load(hinv_ptr + 4)
    h12 = tl.load(hinv_ptr + 5)
    h20 = tl.load(hinv_ptr + 6)
    h21 = tl.load(hinv_ptr + 7)
    h22 = tl.load(hinv_ptr + 8)
    den = h20 * xf + h21 * yf + h22
    u = (h00 * xf + h01 * yf + h02) / den
    v = (h10 * xf + h11 * yf + h12) / den
    u = tl.where(u == u, u, -4.0)
    v = tl.where(v == v, v, -4.0)
    return u, v


@device_function
def taps(u, v, h, w):
    """The four taps of bilinear sampling at (u, v) in an (h, w) image: their offsets, whether each
    lies inside, and the fractions along x and y (outside the image every tap is zero)."""
    u = tl.minimum(tl.maximum(u, -4.0), w + 4.0)
    v = tl.minimum(tl.maximum(v, -4.0), h + 4.0)
    x0f = tl.floor(u)
    y0f = tl.floor(v)
    x0 = x0f.to(tl.int64)  # 64-bit index arithmetic: no overflow, and no overflow checks interpreted
    y0 = y0f.to(tl.int64)
    ix0 = (x0 >= 0) & (x0 < w)
    ix1 = (x0 >= -1) & (x0 < w - 1)
    iy0 = (y0 >= 0) & (y0 < h)
    iy1 = (y0 >= -1) & (y0 < h - 1)
    o00 = y0 * w + x0
    return o00, iy0 & ix0, iy0 & ix1, iy1 & ix0, iy1 & ix1, u - x0f, v - y0f


@device_function
def sample(img_ptr, o00, m00, m01, m10, m11, fx, fy, w):
    """The bilinear sample of the image at ``img_ptr`` from :func:`taps` (zero outside it, as
    ``cv2.warpPerspective`` with a constant zero border, without its 1/32-pixel quantisation)."""
    p = img_ptr + o00
    v00 = tl.load(p, mask=m00, other=0.0)
    v01 = tl.load(p + 1, mask=m01, other=0.0)
    v10 = tl.load(p + w, mask=m10, other=0.0)
    v11 = tl.load(p + w + 1, mask=m11, other=0.0)
    top = v00 * (1.0 - fx) + v01 * fx
    bottom = v10 * (1.0 - fx) + v11 * fx
    return top * (1.0 - fy) + bottom * fy


@device_function
def bilinear(img_ptr, u, v, h, w):
    """Bilinear samples of the (h, w) float32 image at ``img_ptr`` at (u, v), zero outside it."""
    o00, m00, m01, m10, m11, fx, fy = taps(u, v, h, w)
    return sample(img_ptr, o00, m00, m01, m10, m11, fx, fy, w)


@device_function
def reduce_min(x, axis: tl.constexpr):
    """``tl.min(x, axis)``: Triton's own reduction, which the interpreter runs as one NumPy call."""
    return tl.reduce(x, axis, tl.standard._elementwise_min)


@device_function
def reduce_sum(x, axis: tl.constexpr):
    """``tl.sum(x, axis)``: Triton's own reduction, which the interpreter runs as one NumPy call."""
    return tl.reduce(x, axis, tl.standard._sum_combine)
