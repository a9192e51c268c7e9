"""How lfring's numba kernels are compiled and on which threads they run: the flags every kernel
module takes, and the TBB library that numba's 'tbb' threading layer needs made visible (this
module does not import numba; the kernel modules are imported on first use)."""

from __future__ import annotations

import ctypes
import importlib.metadata
import os
import sys

__all__ = ["COMPILED", "COMPILED_PARALLEL", "TBB_LIBRARY", "load_tbb"]

# Cached on disk (the depth engine's first compile takes minutes), the GIL released (threads run
# kernels side by side), IEEE arithmetic (a module that allows fast maths says which), and NumPy's
# error model: no zero-division checks, so loops vectorise.
COMPILED = dict(cache=True, nogil=True, fastmath=False, error_model="numpy")
COMPILED_PARALLEL = dict(COMPILED, parallel=True)

# The library numba's 'tbb' threading layer opens by this name (TBB 2021 and later, Linux).
TBB_LIBRARY = "libtbb.so.12"


def load_tbb() -> str | None:
    """Load the ``tbb`` package's library, if it is installed, so numba's threading layer finds it.

    numba's parallel kernels run on TBB when it can open ``libtbb.so.12`` by name, and on OpenMP
    otherwise. pip installs that library into the environment's ``lib`` folder, which is not on
    the loader's search path, so numba alone falls back to OpenMP even where the package is
    installed. A library already loaded is found by that name, so loading it here by its path
    (before numba starts its threads, on a kernel's first parallel call) makes TBB numba's layer
    on the platforms lfring installs it on (see pyproject.toml). Why TBB rather than OpenMP: GNU
    OpenMP's idle threads spin after each parallel pass and take the cores that the OpenCV steps
    between the passes need, and a process that has used GNU OpenMP cannot fork a child that uses
    it again (benchmarks/RESULTS.md). ``NUMBA_THREADING_LAYER`` still chooses, where it is set.

    Returns the path loaded, or None (another platform, the package not installed, or a library
    that does not load: numba then picks its layer as it would without lfring).
    """
    if not sys.platform.startswith("linux"):
        return None
    try:
        dist = importlib.metadata.distribution("tbb")
    except importlib.metadata.PackageNotFoundError:
        return None
    for file in dist.files or ():
        if file.name == TBB_LIBRARY:
            path = os.path.normpath(dist.locate_file(file))
            try:
                ctypes.CDLL(path)
            except OSError:
                return None
            return path
    return None


load_tbb()
