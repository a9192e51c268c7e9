"""The shared thread pool and numba's thread count."""

import threading

import numba
import pytest

from lfring.core.threads import numba_threads, run_threads


@pytest.mark.parametrize("threads", [1, 2, 5])
def test_every_task_runs_once(threads):
    done, lock = [], threading.Lock()

    def task(i):
        with lock:
            done.append(i)

    run_threads([lambda i=i: task(i) for i in range(17)], threads)
    assert sorted(done) == list(range(17))


def test_an_error_in_a_task_reaches_the_caller():
    def bad():
        raise ValueError("boom")

    with pytest.raises(ValueError, match="boom"):
        run_threads([bad, lambda: None, lambda: None], 2)


def test_numba_threads_sets_and_restores_the_count():
    before = numba.get_num_threads()
    with numba_threads(1):
        assert numba.get_num_threads() == 1
    assert numba.get_num_threads() == before
    with numba_threads(None):
        assert numba.get_num_threads() == before
