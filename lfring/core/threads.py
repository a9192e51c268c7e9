"""Work shared among threads: a process-wide pool (made anew in a forked child) and the numba
thread count of a block of compiled calls."""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor, wait

import lfring.core.compiled  # noqa: F401  (TBB's library loaded before numba starts its threads)
from lfring.core.signals import held_signals, signals_between

__all__ = ["STRIP_PIXELS", "numba_threads", "run_threads"]

# Pixels per strip (rows times width, with the halo): about 0.4 MiB a buffer, so a thread's dozen
# buffers stay in its L2 and L3 share; larger strips measured no faster, smaller ones slower.
STRIP_PIXELS = 1 << 17

_POOL: tuple | None = None  # (pid, executor, workers)


def _pool(workers: int) -> ThreadPoolExecutor:
    """The worker threads, made anew in a forked child (which has none of them)."""
    global _POOL
    if _POOL is None or _POOL[0] != os.getpid() or _POOL[2] < workers:
        _POOL = (os.getpid(), ThreadPoolExecutor(max_workers=workers, thread_name_prefix="lfring"), workers)
    return _POOL[1]


def run_threads(tasks, threads: int) -> None:
    """Run the callables, shared among ``threads`` threads: this one and the pool's (which take
    the next task as they free up; OpenCV and NumPy release the GIL).

    A Ctrl-C (or a SIGTERM raised as one) that comes while this thread runs a task is taken
    when the task ends. When this thread's share raises (such a stop, an error), the pool's
    threads finish the task in hand and take no other; the exception is raised once they have,
    rather than an error of theirs that the same interruption may have caused (a Ctrl-C inside
    numba's loading of a cached kernel leaves its loaders half-way for the other threads). An
    error in a pool thread's share is raised likewise, once the others have stopped.
    """
    lock = threading.Lock()
    todo = iter(tasks)
    stopped = False

    def worker() -> None:
        while True:
            with lock:
                task = None if stopped else next(todo, None)
            if task is None:
                return
            task()

    def callers_share() -> None:
        # A Ctrl-C or SIGTERM is taken between this thread's tasks, never inside one: cut inside
        # an import (numba loads a kernel's cache on its first call, in whichever thread makes
        # it), the import's module lock could stay taken, and a pool thread that then needs the
        # module would wait for it forever.
        with signals_between() as deliver:
            while True:
                deliver()
                with lock:
                    task = None if stopped else next(todo, None)
                if task is None:
                    return
                task()

    threads = max(1, min(int(threads), len(tasks)))
    if threads == 1:
        worker()
        return
    futures = []
    try:
        # The pool starts its threads in submit(); an exception that a signal raises between a
        # thread's start and the pool's record of it would leave the thread unknown to the
        # interpreter's exit, which would then wait for it forever. Signals that come meanwhile are
        # delivered after, here, where they stop the pool's threads as any other interruption.
        with held_signals():
            futures.extend(_pool(threads - 1).submit(worker) for _ in range(threads - 1))
        callers_share()
        for f in futures:
            f.result()
    except BaseException:
        with lock:
            stopped = True
        wait(futures)
        raise


class numba_threads:
    """Context: this thread's numba kernels run on ``n`` threads (None: numba's default); the old
    count comes back on exit."""

    def __init__(self, n):
        self.n = n

    def __enter__(self):
        import numba

        self.old = numba.get_num_threads()
        if self.n is not None:
            numba.set_num_threads(max(1, min(int(self.n), numba.config.NUMBA_NUM_THREADS)))

    def __exit__(self, *exc):
        import numba

        numba.set_num_threads(self.old)
        return False
