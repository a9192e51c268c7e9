"""The fused sweep pass alone (`lfring.depth.engines.fused_volume.sweep_volume`, the default
engine's first pass) at one numba thread, in process time; with ``--against`` an older
checkout's pass on the same arguments, alternating in one process (on a noisy machine, pairs
measured a moment apart compare better than fresh processes).

    python benchmarks/bench_sweep.py                 # the twin's three-depth scene and 4 x 1060^2 x 64
    git worktree add /tmp/lfring-old 105c7ed
    python benchmarks/bench_sweep.py --against /tmp/lfring-old --runs 11

The pass's arguments are captured from one ``estimate_depth`` call (the twin: its defaults; the
random-texture views of ``_common.random_views``: 64 planes, views overlapping by about half).
The older pass must take the same arguments. Loading the same checkout twice measures the
method's own bias (0.99 on the twin when this was written).
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import time
import warnings
from pathlib import Path

import numba
from _common import ZMAX, ZMIN, machine_line, random_views, twin_scene

from lfring.depth import estimate_depth
from lfring.depth.engines import fused_volume


def captured_arguments(views, cal, **kw) -> tuple:
    captured = []
    sweep = fused_volume.sweep_volume

    def capture(*args):
        captured.append(args)
        return sweep(*args)

    fused_volume.sweep_volume = capture
    try:
        estimate_depth(views, cal, threads=1, **kw)
    finally:
        fused_volume.sweep_volume = sweep
    return captured[0]


def older_pass(checkout: Path):
    spec = importlib.util.spec_from_file_location("fused_volume_older", checkout / "lfring/depth/engines/fused_volume.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.sweep_volume


def run(name: str, args: tuple, runs: int, older) -> None:
    sweep = fused_volume.sweep_volume
    ours, theirs = [], []
    sweep(*args)
    if older is not None:
        older(*args)
    for _ in range(runs):
        t = time.process_time()
        sweep(*args)
        ours.append(time.process_time() - t)
        if older is not None:
            t = time.process_time()
            older(*args)
            theirs.append(time.process_time() - t)
    line = f"{name}: sweep pass {1e3 * statistics.median(ours):.1f} ms median, {1e3 * min(ours):.1f} min"
    if older is not None:
        ratios = [a / b for a, b in zip(ours, theirs)]
        line += (f"; older {1e3 * statistics.median(theirs):.1f} ms median; this / older per pair: median "
                 f"{statistics.median(ratios):.3f} ({min(ratios):.3f}-{max(ratios):.3f})")
    print(line)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--case", choices=("twin", "big", "all"), default="all")
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--against", type=Path, help="an older checkout whose sweep pass to time beside this one")
    a = ap.parse_args()
    numba.set_num_threads(1)
    warnings.simplefilter("ignore")
    print(machine_line())
    older = None if a.against is None else older_pass(a.against)
    if a.case in ("twin", "all"):
        t = twin_scene()
        run("twin three-depth, defaults", captured_arguments(t.views, t.cal, zmin_m=ZMIN, zmax_m=ZMAX), a.runs, older)
    if a.case in ("big", "all"):
        views, cal = random_views(1060)
        run("4 x 1060^2 x 64 planes", captured_arguments(views, cal, zmin_m=ZMIN, zmax_m=ZMAX, num_planes=64), a.runs, older)


if __name__ == "__main__":
    main()
