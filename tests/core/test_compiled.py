"""numba's threading layer: TBB where the install brings it, found without the user's help."""

import importlib.metadata
import os
import subprocess
import sys
import textwrap

from lfring.core.compiled import TBB_LIBRARY, load_tbb

# In a fresh process, numba's threads started as a depth call starts them (numba picks its layer
# then, before any kernel module is imported), then a parallel kernel, then the same kernel in a
# child forked after it: the box mean of finite values over 3 x 3, on a ramp.
_SCRIPT = textwrap.dedent(
    """
    import multiprocessing, sys
    import numba, numpy as np
    from lfring.core.threads import numba_threads
    from lfring.depth.aggregation import box_mean_of_finite

    with numba_threads(1):
        pass

    def mean(_=None):
        c = np.arange(64 * 48, dtype=np.float32).reshape(64, 48)
        return float(box_mean_of_finite(c, 3)[10, 10])

    first = mean()
    layer = numba.threading_layer()
    if layer == "tbb" and sys.platform.startswith("linux"):
        with multiprocessing.get_context("fork").Pool(1) as pool:
            child = pool.apply_async(mean, (0,)).get(timeout=120)
    else:
        child = first
    print(layer, first, child)
    """
)


def _tbb_installed():
    try:
        importlib.metadata.distribution("tbb")
    except importlib.metadata.PackageNotFoundError:
        return False
    return True


def _layer_in_a_fresh_process(env):
    """The layer _SCRIPT's process ran on, once its kernel gave the ramp's centre in the process
    and in the forked child alike."""
    out = subprocess.run([sys.executable, "-c", _SCRIPT], capture_output=True, text=True, env=env, timeout=600)
    assert out.returncode == 0, out.stderr
    layer, first, child = out.stdout.split()
    assert float(first) == float(child) == 10 * 48 + 10  # a ramp's mean over a box is its centre
    return layer


def test_parallel_kernels_run_on_tbb_where_it_is_installed():
    """pip puts TBB's library where the loader does not look; lfring loads it so numba finds it,
    and a child forked after a parallel pass runs one too (GNU OpenMP would end it)."""
    layer = _layer_in_a_fresh_process({k: v for k, v in os.environ.items() if k != "NUMBA_THREADING_LAYER"})
    if sys.platform.startswith("linux") and _tbb_installed():
        assert layer == "tbb"
        path = load_tbb()
        assert path is not None and os.path.basename(path) == TBB_LIBRARY and os.path.isfile(path)
    else:
        assert load_tbb() is None


def test_a_chosen_layer_is_kept():
    """NUMBA_THREADING_LAYER still chooses: lfring only makes TBB findable."""
    assert _layer_in_a_fresh_process(dict(os.environ, NUMBA_THREADING_LAYER="workqueue")) == "workqueue"
