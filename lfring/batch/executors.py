"""Where a batch's frames run: a pool of local worker processes (or this process alone, for one
worker) or a Dask cluster, each behind the same small face (``submit``, ``shutdown``,
``terminate`` and a ``wait`` that returns the finished futures).

The local workers start with Ctrl-C blocked: the terminal sends it to every process of the
group, and a worker that took it would die with a traceback of its own. The process that runs
the batch takes it and stops the workers (:meth:`LocalPool.terminate`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from concurrent.futures import FIRST_COMPLETED, FIRST_EXCEPTION, ProcessPoolExecutor, wait

from lfring.core.signals import blocked_in_children, held_signals
from lfring.errors import InvalidInputError

__all__ = ["EXECUTORS", "STOP_TIMEOUT_S", "WAIT_SLICE_S", "DaskExecutor", "InProcess", "LocalPool", "dask_client",
           "dask_wait", "held_wait", "local_executor"]

log = logging.getLogger("lfring.batch")

EXECUTORS = ("local", "dask")

STOP_TIMEOUT_S = 2.0
"""How long a stopped worker gets to exit on SIGTERM before it is killed."""

WAIT_SLICE_S = 0.2
"""The local pool's wait for finished frames runs in slices this long, Ctrl-C and SIGTERM held
within each: a stop takes effect between slices, never inside the futures' locks."""

_DASK_HINT = 'install it with: python3 -m pip install -c constraints.txt ".[dask]"  (or: pip install "dask[distributed]")'


def _init_worker(threads: int) -> None:
    """Give a worker process its share of the cores for OpenCV's threads."""
    import cv2

    cv2.setNumThreads(max(1, int(threads)))


class InProcess:
    """Runs the frames one by one here (workers=1): no process start-up, same code path."""

    def submit(self, fn, *args):
        """Run ``fn(*args)`` now; a future that holds its result or its exception."""
        from concurrent.futures import Future

        fut: Future = Future()
        try:
            fut.set_result(fn(*args))
        except Exception as exc:  # noqa: BLE001 - delivered through the future like a pool does
            fut.set_exception(exc)
        return fut

    def shutdown(self, **kwargs):
        """Nothing to stop (the pool's signature)."""

    def terminate(self):
        """Nothing to stop: an interrupted frame stops with this process."""


class LocalPool:
    """A pool of spawned worker processes that never see Ctrl-C, and can be stopped at once."""

    def __init__(self, workers: int):
        import multiprocessing as mp

        self._lost_at: float | None = None  # when a dead worker was first seen by wait
        threads = max(1, (os.cpu_count() or 1) // workers)
        # spawn, not fork: forking a process whose OpenCV thread pool is running can deadlock.
        self._pool = ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                                         initializer=_init_worker, initargs=(threads,))

    def submit(self, fn, *args):
        """Submit ``fn(*args)``; its future. Workers start here, with Ctrl-C blocked (a signal
        that comes meanwhile takes effect when the submission is complete)."""
        with held_signals(), blocked_in_children():
            return self._pool.submit(fn, *args)

    def shutdown(self, wait: bool = True, cancel_futures: bool = False):
        """Let the workers finish their frames and stop (ProcessPoolExecutor's shutdown)."""
        self._pool.shutdown(wait=wait, cancel_futures=cancel_futures)

    def wait(self, fs, return_when=FIRST_COMPLETED):
        """:func:`held_wait` for ``fs``; a worker that died and that the pool has not noticed
        after :data:`STOP_TIMEOUT_S` breaks the pool, as any lost worker does.

        A worker lost while it sends a result (killed, or crashed) leaves the message cut short:
        the pool's manager thread waits for the rest and never sees the loss, and the frames
        would never finish. The pool is stopped instead (:meth:`terminate`, which ends that
        wait), and every frame it held fails as lost."""
        return held_wait(fs, return_when, between=self._break_if_lost)

    def _break_if_lost(self) -> None:
        procs = list((getattr(self._pool, "_processes", None) or {}).values())
        if not any(p.exitcode is not None for p in procs):
            self._lost_at = None
            return
        now = time.monotonic()
        if self._lost_at is None:
            self._lost_at = now
        elif now - self._lost_at > STOP_TIMEOUT_S:
            log.warning("a worker was lost and its pool did not notice within %g s (a worker lost while it sends a "
                        "result leaves the pool waiting for the rest): stopping the pool, its frames run again",
                        STOP_TIMEOUT_S)
            self._lost_at = None
            self.terminate()

    def terminate(self):
        """Stop now: pending frames are cancelled, running ones lost, the workers ended (SIGTERM,
        then SIGKILL after :data:`STOP_TIMEOUT_S`) and waited for. A second Ctrl-C meanwhile
        takes effect once they are gone."""
        with held_signals():
            # The executor keeps its processes by pid; Python 3.14 has terminate_workers() for this.
            procs = list((getattr(self._pool, "_processes", None) or {}).values())
            # shutdown forgets the result queue and the manager thread: taken first.
            result_queue = getattr(self._pool, "_result_queue", None)
            manager = getattr(self._pool, "_executor_manager_thread", None)
            self._pool.shutdown(wait=False, cancel_futures=True)
            for p in procs:
                with contextlib.suppress(ValueError, ProcessLookupError, OSError):
                    p.terminate()
            deadline = time.monotonic() + STOP_TIMEOUT_S
            for p in procs:
                with contextlib.suppress(ValueError, OSError):
                    p.join(max(0.0, deadline - time.monotonic()))
                    if p.is_alive():
                        p.kill()
                        p.join(STOP_TIMEOUT_S)
            # A worker killed while it sent a frame's outputs leaves its message cut short, and the
            # pool's manager thread waiting for the rest. This process holds the last other end of
            # that pipe (its workers are gone and it never writes there): closed, the wait ends
            # at end-of-file and the thread stops. Left waiting, it would never end, and the
            # interpreter, which joins it at exit, would never exit.
            if result_queue is not None:
                with contextlib.suppress(OSError):
                    result_queue._writer.close()
            # The pool's manager thread notices the dead workers and closes its wake-up pipe; left
            # running, it races the interpreter's exit hook, which writes to that pipe (an
            # OSError traceback at exit when the pipe closes in between).
            if manager is not None:
                manager.join(STOP_TIMEOUT_S)


def held_wait(fs, return_when=FIRST_COMPLETED, *, between=None):
    """:func:`concurrent.futures.wait` in slices of :data:`WAIT_SLICE_S`, Ctrl-C and SIGTERM held
    within each: interrupted inside the futures' locks, a wait would leave one of them taken,
    and the pool's manager thread (which sets the results) blocked for ever. ``between``, if
    given, is called after each slice that did not end the wait."""
    while True:
        with held_signals():
            done, not_done = wait(fs, timeout=WAIT_SLICE_S, return_when=return_when)
            over = not not_done or (bool(done) and return_when == FIRST_COMPLETED) or (
                return_when == FIRST_EXCEPTION and any(not f.cancelled() and f.exception() is not None for f in done))
        if over:
            return done, not_done
        if between is not None:
            between()


def local_executor(workers: int):
    """A pool of ``workers`` spawned processes (this process alone for one) and its ``wait``."""
    if workers == 1:
        return InProcess(), wait
    pool = LocalPool(workers)
    return pool, pool.wait


def dask_client(workers: int, scheduler: str | None):
    """A Dask client of the cluster at ``scheduler``, or of a local cluster of ``workers``
    processes when none is given, and that cluster (None for a remote one)."""
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise InvalidInputError(f"--executor dask needs dask.distributed, which is not installed; {_DASK_HINT}") from None
    # The cluster's own chatter (workers starting, connections) only when lfring is verbose.
    logging.getLogger("distributed").setLevel(max(logging.WARNING, log.getEffectiveLevel()))
    if scheduler:
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise InvalidInputError(f"cannot reach the Dask scheduler at {scheduler!r}: {exc}") from None
        return client, None
    import dask

    # Dask's nannies start workers with MALLOC_TRIM_THRESHOLD_ set, which freezes glibc's mmap
    # threshold: every large NumPy temporary is then mapped and unmapped afresh, and the plane
    # sweep ran markedly slower than in a plain process. Workers of this local cluster keep
    # glibc's adaptive default.
    environ = {k: v for k, v in (dask.config.get("distributed.nanny.pre-spawn-environ") or {}).items()
               if k != "MALLOC_TRIM_THRESHOLD_"}
    with dask.config.set({"distributed.nanny.pre-spawn-environ": environ}):
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address=":0")
    client = Client(cluster)
    # As in the local pool: the cores are shared among the worker processes, not oversubscribed.
    client.run(_init_worker, max(1, (os.cpu_count() or 1) // workers))
    return client, cluster


class DaskExecutor:
    """A Dask client behind the face of a process pool (``submit``, ``shutdown``)."""

    def __init__(self, client):
        self.client = client

    def submit(self, fn, *args):
        """Submit ``fn(*args)`` to the cluster (never cached as a pure task); its future."""
        return self.client.submit(fn, *args, pure=False)

    def shutdown(self, **kwargs):
        """Nothing to stop: the caller closes the client and the cluster."""

    def terminate(self):
        """Nothing to stop here: the caller closes the client and the cluster."""


def dask_wait(futures, return_when=FIRST_COMPLETED):
    """:func:`concurrent.futures.wait` for Dask futures: (done, not done)."""
    from distributed import wait as dwait

    res = dwait(list(futures), return_when="FIRST_COMPLETED")
    return res.done, res.not_done
