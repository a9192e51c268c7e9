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
