"""Shared by the benchmark scripts: medians of repeated runs after a warm-up."""

from __future__ import annotations

import statistics
import time


def bench(fn, runs: int) -> tuple[float, float, float]:
    """(median, min, max) seconds of ``runs`` calls of ``fn`` after one warm-up call."""
    fn()
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), min(times), max(times)
