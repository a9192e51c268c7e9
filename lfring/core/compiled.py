"""How lfring's numba kernels are compiled: the flags every kernel module takes (this module does
not import numba; the kernel modules are imported on first use)."""

from __future__ import annotations

__all__ = ["COMPILED", "COMPILED_PARALLEL"]

# Cached on disk (the depth engine's first compile takes minutes), the GIL released (threads run
# kernels side by side), IEEE arithmetic (a module that allows fast maths says which), and NumPy's
# error model: no zero-division checks, so loops vectorise.
COMPILED = dict(cache=True, nogil=True, fastmath=False, error_model="numpy")
COMPILED_PARALLEL = dict(COMPILED, parallel=True)
