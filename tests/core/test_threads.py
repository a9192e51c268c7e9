"""The shared thread pool and numba's thread count."""

import threading

import numba
import pytest

from child_processes import default_sigint

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


def test_an_interrupt_in_the_callers_share_stops_the_pool_taking_tasks():
    """Ctrl-C in the calling thread: the pool's threads finish the task in hand and take no more
    (they went on through every task that was left: 39 of 40 here)."""
    import time

    caller = threading.current_thread()
    ran_elsewhere, lock = [], threading.Lock()

    def task(i):
        if threading.current_thread() is caller:
            raise KeyboardInterrupt
        time.sleep(0.02)
        with lock:
            ran_elsewhere.append(i)

    with pytest.raises(KeyboardInterrupt):
        run_threads([lambda i=i: task(i) for i in range(40)], 2)
    # Normally the task in hand; the margin is for a loaded machine that holds this thread back.
    assert len(ran_elsewhere) < 10, ran_elsewhere


def test_the_callers_interrupt_is_raised_rather_than_an_error_it_caused_in_the_pool():
    """Ctrl-C in the calling thread while a pool thread fails because of it (numba's loaders
    left half-way raise "generator raised StopIteration" there): the caller gets the Ctrl-C, as
    a command that stops cleanly needs, not the pool thread's error."""
    import time

    caller = threading.current_thread()

    def task():
        if threading.current_thread() is caller:
            time.sleep(0.05)  # the pool thread takes the other task meanwhile
            raise KeyboardInterrupt
        raise RuntimeError("generator raised StopIteration")

    with pytest.raises(KeyboardInterrupt):
        run_threads([task, task], 2)


def test_a_signal_during_the_callers_task_is_taken_when_the_task_ends():
    """A Ctrl-C that comes while the calling thread runs a task stops the run once that task
    is done, never inside it (inside an import, numba's loading of a kernel, the module's lock
    could stay taken and a pool thread wait for it forever); the caller takes no other task."""
    import subprocess
    import sys

    code = """
import signal, threading, time
from lfring.core.threads import run_threads
caller = threading.current_thread()
done = []
def task(i):
    time.sleep(0.01)
    if threading.current_thread() is caller:
        signal.raise_signal(signal.SIGINT)
        time.sleep(0.01)
        done.append(i)  # the task goes on to its end
try:
    run_threads([lambda i=i: task(i) for i in range(8)], 2)
except KeyboardInterrupt:
    print("interrupted after", len(done))
"""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30,
                          preexec_fn=default_sigint)
    assert proc.returncode == 0 and proc.stdout.strip() == "interrupted after 1", (proc.stdout, proc.stderr)


# A child process whose pool threads raise SIGINT as they start, between the start and the pool's
# record of the thread (run with preexec_fn=default_sigint: a parent that ignores SIGINT, a test
# runner's worker, would pass that on, and Python would not install its Ctrl-C handler).
POOL_START_INTERRUPTED = """
import signal, threading
from lfring.core.threads import run_threads
start = threading.Thread.start
def start_then_interrupt(self):
    start(self)
    if self.name.startswith("lfring"):
        signal.raise_signal(signal.SIGINT)
threading.Thread.start = start_then_interrupt
"""


def test_a_signal_while_the_pool_starts_its_threads_does_not_hang_the_exit():
    """A Ctrl-C that lands between the pool's start of a thread and its record of it (here made to
    land there) is delivered once the threads are started: the interpreter exits, instead of
    waiting at exit for a thread it was never told of."""
    import subprocess
    import sys

    code = POOL_START_INTERRUPTED + """
try:
    run_threads([lambda: None] * 4, 2)
except KeyboardInterrupt:
    print("interrupted")
"""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30,
                          preexec_fn=default_sigint)
    assert proc.returncode == 0 and proc.stdout.strip() == "interrupted", proc.stderr


def test_a_signal_held_while_the_pool_starts_stops_its_threads_too():
    """The Ctrl-C held while the pool starts its threads, delivered right after: the pool's
    threads stop as for any other interruption, and do not go on through the tasks in the
    background (counted at exit, once every thread is done)."""
    import subprocess
    import sys

    code = POOL_START_INTERRUPTED + """
import atexit, time
ran = []
atexit.register(lambda: print(len(ran)))
try:
    run_threads([lambda: (time.sleep(0.02), ran.append(1))] * 40, 2)
except KeyboardInterrupt:
    pass
"""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30,
                          preexec_fn=default_sigint)
    assert proc.returncode == 0, proc.stderr
    # Normally the task in hand; the margin is for a loaded machine.
    assert int(proc.stdout) < 10, proc.stdout
