"""Fresh working arrays in anonymous memory maps."""

import gc

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


def test_each_array_has_memory_of_its_own_that_outlives_the_call():
    a, b = fresh_zeros((64, 64)), fresh_zeros((64, 64))
    a += 1.5
    assert not np.shares_memory(a, b) and not b.any()
    view = a[10:20]
    del a
    gc.collect()
    assert (view == 1.5).all()  # a view keeps the map alive
