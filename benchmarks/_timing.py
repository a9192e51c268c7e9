"""Shared by the benchmark scripts: medians of repeated runs after a warm-up."""

from __future__ import annotations

import statistics
import time


def bench(fn, runs: int, *, warmup: bool = True) -> tuple[float, float, float]:
    """(median, min, max) seconds of ``runs`` calls of ``fn`` after one warm-up call (none
    when ``warmup`` is False: for work whose start-up cost is part of the figure)."""
    if warmup:
        fn()
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), min(times), max(times)


def paired(fn_a, fn_b, runs: int) -> tuple[float, float, float]:
    """(median ratio a / b, median a, median b) seconds of ``runs`` pairs of calls, ``fn_a`` then
    ``fn_b``, after one warm-up call of each. A pair's two calls run a moment apart, so a change
    of the machine's speed (another job on a shared host) falls on both: the median of the
    pairs' ratios is steadier than the ratio of two medians taken minutes apart."""
    fn_a()
    fn_b()
    ta, tb = [], []
    for _ in range(runs):
        for fn, out in ((fn_a, ta), (fn_b, tb)):
            t = time.perf_counter()
            fn()
            out.append(time.perf_counter() - t)
    return statistics.median(a / b for a, b in zip(ta, tb)), statistics.median(ta), statistics.median(tb)
