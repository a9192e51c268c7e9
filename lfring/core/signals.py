"""Ctrl-C and SIGTERM around work that must not be cut in two: a set of files renamed into place,
a worker process being started.

:func:`held_signals` holds SIGINT and SIGTERM for the length of a block and delivers them after
it, as if they had come then; :func:`blocked_in_children` starts processes with SIGINT blocked,
so that a Ctrl-C (which the terminal sends to every process of its group) reaches only the
process that owns them, which stops them itself; :func:`redelivered_stops` keeps a Ctrl-C that
landed where Python could only print it and go on, and :func:`deliver_lost_stops` delivers it
before a commit; :func:`raise_stop` raises a stop from a handler so that :func:`interrupt_behind`
still finds it behind the error a library turned it into.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from collections.abc import Iterator
from typing import NoReturn

__all__ = ["HELD_SIGNALS", "blocked_in_children", "deliver_lost_stops", "held_signals", "interrupt_behind",
           "raise_stop", "redelivered_stops", "signals_between", "stop_record"]

HELD_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM") if hasattr(signal, name))
"""The signals that ask a run to stop: Ctrl-C and a polite kill."""


@contextlib.contextmanager
def held_signals(signums=HELD_SIGNALS) -> Iterator[None]:
    """Hold ``signums`` while the block runs; each that came is delivered, once, when it ends.

    Only the main thread receives Python's signal handlers: elsewhere this does nothing. A
    signal that is ignored (``SIG_IGN``) stays ignored.
    """
    with signals_between(signums):
        yield


@contextlib.contextmanager
def signals_between(signums=HELD_SIGNALS) -> Iterator:
    """Hold ``signums`` while the block runs but at the points where it calls the function it
    is given: each signal that came by then is delivered there (its handler runs, and may
    raise), and the rest when the block ends. For a loop of steps that must not be cut inside
    one, at the cost of one call a step. Only the main thread receives Python's signal handlers:
    elsewhere the function does nothing.

    Examples
    --------
    >>> with signals_between() as deliver:
    ...     for step in range(3):
    ...         deliver()  # a Ctrl-C that came during the last step is raised here
    """
    if threading.current_thread() is not threading.main_thread():
        yield lambda: None
        return
    came: list[int] = []
    old = {}
    for s in signums:
        h = signal.getsignal(s)
        if h in (signal.SIG_IGN, None):
            continue
        old[s] = h

    def hold():
        for s in old:
            signal.signal(s, lambda signum, frame: came.append(signum))

    def release():
        for s, h in old.items():
            signal.signal(s, h)
        pending = list(dict.fromkeys(came))
        came.clear()
        for s in pending:
            h = old[s]
            if callable(h):
                h(s, None)
            else:  # SIG_DFL: the default action, now
                signal.raise_signal(s)

    def deliver():
        if came:
            release()  # raises, as a rule; if the handler returns, the block goes on held
            hold()

    hold()
    try:
        yield deliver
    finally:
        release()


# Stops (exception types) that came where Python could not raise them, not yet delivered; stops
# that a signal's handler raised (raise_stop). Each block's end forgets what came in it.
_LOST: list[type] = []
_RAISED: list[type] = []
# Where each open stop_record block's entries begin in _LOST and _RAISED, after the entry that
# stands for no block (0, 0).
_MARKS: list[tuple[int, int]] = [(0, 0)]


@contextlib.contextmanager
def stop_record() -> Iterator[None]:
    """The stops that come while the block runs are its own: :func:`raise_stop` keeps them for
    :func:`interrupt_behind` and :func:`deliver_lost_stops`, which see only the innermost open
    block's, and the block's end forgets them (and any that :func:`redelivered_stops` kept), so
    that they never stand behind another block's errors or commits: a command's, run after or
    inside this one, or the one around it."""
    marks = len(_LOST), len(_RAISED)
    _MARKS.append(marks)
    try:
        yield
    finally:
        _MARKS.pop()
        del _LOST[marks[0]:], _RAISED[marks[1]:]


@contextlib.contextmanager
def redelivered_stops() -> Iterator[None]:
    """While the block runs, a Ctrl-C (any KeyboardInterrupt, such as a SIGTERM raised as one, or
    an error raised from one) that lands where Python cannot raise it is kept for
    :func:`deliver_lost_stops`; the block is a :func:`stop_record`.

    A signal's handler runs wherever the main thread is. In a weakref callback or a ``__del__``
    (the import machinery's module locks have one) its exception cannot propagate: Python would
    print it as "Exception ignored", with a traceback, and the run would go on as if nothing had
    come. Instead the stop is kept; the caller delivers it where stopping is safe and before
    anything is committed (an output set's files, a batch frame's record). Other such exceptions
    are reported as before.
    """
    previous = sys.unraisablehook

    def hook(unraisable):
        stop = _stop_in_chain(unraisable.exc_value)
        if stop is not None:
            _LOST.append(type(stop))
            return
        previous(unraisable)

    sys.unraisablehook = hook
    try:
        with stop_record():
            yield
    finally:
        sys.unraisablehook = previous


def raise_stop(kind: type[KeyboardInterrupt] = KeyboardInterrupt) -> NoReturn:
    """Raise a new ``kind`` from a signal's handler, and, inside :func:`stop_record`, keep
    that it came.

    Code that catches every exception can turn the stop into an error of its own and forget it:
    matplotlib's image resampling, cut by a Ctrl-C, reports an invalid transformation matrix. Any
    error that reaches :func:`interrupt_behind` after a stop came stands for that stop.
    """
    if len(_MARKS) > 1 and threading.current_thread() is threading.main_thread():
        _RAISED.append(kind)
    raise kind()


def deliver_lost_stops() -> None:
    """Raise the stop that :func:`redelivered_stops` kept (a new exception of its type), or one
    that :func:`raise_stop` raised and that never reached its caller, once. Only the main thread
    delivers.

    lfring lets every stop through to the command's end, so one that :func:`raise_stop` raised in
    the open block, met where the command goes on to commit its work, was swallowed whole by a
    library (C code that clears the error it met)."""
    if threading.current_thread() is not threading.main_thread():
        return
    lost, raised = _MARKS[-1]  # the open block's own: an enclosing block's stops are its own
    kind = _LOST[lost] if len(_LOST) > lost else _RAISED[-1] if len(_RAISED) > raised else None
    if kind is None:
        return
    del _LOST[lost:], _RAISED[raised:]
    raise kind()


@contextlib.contextmanager
def blocked_in_children(signums=(signal.SIGINT,)) -> Iterator[None]:
    """Processes started in the block (from this thread) start with ``signums`` blocked.

    A child inherits its parent's signal mask across fork and exec; Python never unblocks it, so
    such a worker never sees a Ctrl-C meant for the run (no ``KeyboardInterrupt`` traceback of
    its own); the run stops it. Python handlers of this process still run for signals that come
    meanwhile (another thread receives them), so pair it with :func:`held_signals`.
    """
    if not hasattr(signal, "pthread_sigmask"):  # pragma: no cover - not POSIX
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, set(signums))
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def interrupt_behind(exc: BaseException) -> KeyboardInterrupt | None:
    """The Ctrl-C (or SIGTERM raised as one) that ``exc`` stands for, if any: ``exc`` itself, the
    KeyboardInterrupt it was raised from, or (inside :func:`stop_record`) a new stop of the
    kind that the last :func:`raise_stop` raised in the open :func:`stop_record` block, whatever
    ``exc`` is (in the main thread, whose handlers raise them): a stop ends the command, and an
    error that comes after it is its consequence.

    Python 3.10 and 3.11 turn an exception raised inside a class's ``__set_name__`` into a
    RuntimeError caused by it, so a Ctrl-C that comes while an import creates such a class (a
    ``functools.cached_property`` in a class body) reaches the caller as a RuntimeError; a
    handler that isolates errors must stop for it all the same.

    Examples
    --------
    >>> interrupt_behind(ValueError("bad frame")) is None
    True
    >>> stop = KeyboardInterrupt()
    >>> try:
    ...     raise RuntimeError("Error calling __set_name__") from stop
    ... except RuntimeError as exc:
    ...     interrupt_behind(exc) is stop
    True
    """
    stop = _stop_in_chain(exc)
    if stop is None and len(_RAISED) > _MARKS[-1][1] and threading.current_thread() is threading.main_thread():
        stop = _RAISED[-1]()
    return stop


def _stop_in_chain(exc: BaseException | None) -> KeyboardInterrupt | None:
    """``exc`` if it is a KeyboardInterrupt, else the first one it was raised from, if any."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__
    return None
