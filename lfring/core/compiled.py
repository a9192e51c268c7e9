"""How lfring's numba kernels are compiled and on which threads they run: the flags every kernel
module takes, and the TBB library that numba's 'tbb' threading layer needs made visible (this
module does not import numba; the kernel modules are imported on first use)."""

from __future__ import annotations

import ctypes
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
    (before numba starts its threads: every lfring module that uses numba imports this one, or
    :mod:`lfring.core.threads`, which does) makes TBB numba's layer on the platforms lfring
    installs it on (see pyproject.toml). Why TBB rather than OpenMP: GNU OpenMP's idle threads
    spin after each parallel pass and take the cores that the OpenCV steps between the passes
    need, and a process that has used GNU OpenMP cannot fork a child that uses it again
    (benchmarks/RESULTS.md). ``NUMBA_THREADING_LAYER`` still chooses, where it is set.

    Returns the path loaded, or None (another platform, the package not installed, or a library
    that does not load: numba then picks its layer as it would without lfring).
    """
    if not sys.platform.startswith("linux"):
        return None
    path = _tbb_path()
    if path is None:
        return None
    try:
        ctypes.CDLL(path)
    except OSError:
        return None
    return path


def _tbb_path() -> str | None:
    """Where pip put TBB's library: the ``lib`` folder of the environment's or the user's data
    path (a stat each); else where the ``tbb`` package's record says (its metadata is slower to
    read, so only then)."""
    import sysconfig

    for base in (sysconfig.get_path("data"), sysconfig.get_path("data", sysconfig.get_preferred_scheme("user"))):
        path = os.path.join(base, "lib", TBB_LIBRARY)
        if os.path.isfile(path):
            return path
    import importlib.metadata

    try:
        dist = importlib.metadata.distribution("tbb")
    except importlib.metadata.PackageNotFoundError:
        return None
    for file in dist.files or ():
        if file.name == TBB_LIBRARY:
            return os.path.normpath(dist.locate_file(file))
    return None


load_tbb()
