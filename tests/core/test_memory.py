"""Fresh working arrays in anonymous memory maps."""

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from lfring.core.memory import fresh_zeros


@pytest.mark.parametrize("shape, dtype", [((3, 5), np.float32), ((2, 7, 4), np.uint16), (6, np.int64), ((0, 4), np.float32)])
def test_fresh_zeros_are_zeros_of_the_shape_and_type_and_writable(shape, dtype):
    a = fresh_zeros(shape, dtype)
    assert a.shape == ((shape,) if isinstance(shape, int) else shape)
    assert a.dtype == dtype and a.flags.c_contiguous and a.flags.writeable
    assert not a.any()
    a[...] = 7
    assert (a == 7).all()


def test_each_array_has_memory_of_its_own():
    a, b = fresh_zeros((64, 64)), fresh_zeros((64, 64))
    a += 1.5
    assert not np.shares_memory(a, b) and not b.any() and (a == 1.5).all()


def test_no_room_is_a_memory_error_that_names_the_array():
    with pytest.raises(MemoryError, match=r"shape \(33554432, 33554432\) and data type float32"):
        fresh_zeros((2**25, 2**25))


@pytest.mark.skipif(not hasattr(os, "fork"), reason="fork is POSIX's")
def test_a_forked_child_writes_its_own_copy():
    """As with any NumPy array, a child's writes do not reach the parent's array (a shared map
    would hand the parent's cached depth volumes to every child at once). In a fresh
    interpreter: numba's OpenMP refuses a fork after its threads started."""
    script = textwrap.dedent("""
        import os
        from lfring.core.memory import fresh_zeros
        a = fresh_zeros(4096)
        pid = os.fork()
        if pid == 0:
            a[:] = 5.0
            os._exit(0 if a.sum() == 5.0 * 4096 else 1)
        _, status = os.waitpid(pid, 0)
        print(os.waitstatus_to_exitcode(status), float(a.sum()))
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.split() == ["0", "0.0"]
