"""Shared by the benchmark scripts: medians of repeated runs after a warm-up, and two checkouts
timed alternately."""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path


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


def alternate_checkouts(script: str, description: str, default_rounds: int) -> None:
    """The main of a benchmark that compares two checkouts (``script OLD NEW [--rounds N]``): runs
    ``script --probe`` with each checkout first on PYTHONPATH, alternately in fresh processes
    (a change of the machine's load falls on both alike), each probe printing one JSON object
    as its last line; prints every round's line, the load before and after, and each
    checkout's medians over the rounds (string values, such as digests, listed after them)."""
    import argparse

    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("old")
    parser.add_argument("new")
    parser.add_argument("--rounds", type=int, default=default_rounds)
    args = parser.parse_args()
    trees = [str(Path(p).resolve()) for p in (args.old, args.new)]
    print(f"load {os.getloadavg()[0]:.2f}")
    results = [[] for _ in trees]  # by position: the same checkout twice is a fair control
    for _ in range(args.rounds):
        for tree, rows in zip(trees, results):
            env = {**os.environ, "PYTHONPATH": tree}
            res = subprocess.run([sys.executable, script, "--probe"], env=env, capture_output=True, text=True, check=True)
            print(Path(tree).name, res.stdout.strip(), flush=True)
            rows.append(json.loads(res.stdout.strip().splitlines()[-1]))
    print(f"load {os.getloadavg()[0]:.2f}")
    for tree, rows in zip(trees, results):
        keys = [k for k, v in rows[0].items() if not isinstance(v, str)]
        strings = sorted({v for r in rows for v in r.values() if isinstance(v, str)})
        print("median over rounds", Path(tree).name,
              json.dumps({k: round(statistics.median(r[k] for r in rows), 4) for k in keys}), *strings)
