"""Compute backends: NumPy/OpenCV is the reference; the torch/kornia twins (imported lazily, on
first use) run the same algorithms on a GPU or the CPU."""

from __future__ import annotations

import logging

from lfring.core.validate import check_choice
from lfring.errors import InvalidInputError

__all__ = ["BACKENDS", "check_backend", "kernels_run_on", "require_torch", "resolve_device"]

BACKENDS = ("numpy", "torch")


def check_backend(backend: str) -> str:
    """``backend`` if it is one of :data:`BACKENDS`."""
    return check_choice(backend, "backend", BACKENDS)


def require_torch():
    """Import torch and kornia, or say how to install them."""
    try:
        import kornia  # noqa: F401
        import torch
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise InvalidInputError(
            f"the torch backend needs torch and kornia ({exc.name} is missing): "
            'pip install -c constraints.txt "lfring[torch]"'
        ) from None
    torch.backends.cuda.matmul.allow_tf32 = False  # same numbers as the NumPy reference
    torch.backends.cudnn.allow_tf32 = False
    return torch


def resolve_device(device):
    """'cuda' when asked and present; CPU otherwise (logged when cuda was asked but missing)."""
    torch = require_torch()
    if device is None:
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError):
        raise InvalidInputError(f"device must be a torch device ('cpu', 'cuda', 'cuda:1', a torch.device) or None, got "
                                f"{device!r}") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        logging.getLogger("lfring.core.backend").warning("device %s asked for but CUDA is not available: using the CPU",
                                                         device)
        return torch.device("cpu")
    return dev


def kernels_run_on(device) -> bool:
    """Whether lfring's Triton kernels run on tensors of ``device`` (a torch device): compiled on
    CUDA, interpreted on the CPU where :mod:`lfring.core.triton_kernels` says so; False without
    Triton, where the stages take their torch paths."""
    try:
        from lfring.core import triton_kernels
    except ImportError:  # pragma: no cover - the torch extra is not installed
        return False
    return triton_kernels.runs_on(device)
