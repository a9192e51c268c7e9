"""The fused sweep pass alone (`lfring.depth.engines.fused_volume.sweep_volume`, the default
engine's first pass) at one numba thread, in process time: for comparing two trees on a noisy
machine, run it for each in alternating fresh processes and compare the minima.

    python benchmarks/bench_sweep.py                 # the twin's three-depth scene and 4 x 1060^2 x 64
    PYTHONPATH=/tmp/lfring-old:benchmarks python benchmarks/bench_sweep.py --case twin

The pass's arguments are captured from one ``estimate_depth`` call (the twin: its defaults; the
random-texture views of ``_common.random_views``: 64 planes, views overlapping by about half),
then the pass is run ``--runs`` times.
"""

from __future__ import annotations

import argparse
import statistics
import time
import warnings

import numba
from _common import ZMAX, ZMIN, machine_line, random_views, twin_scene

from lfring.depth import estimate_depth
from lfring.depth.engines import fused_volume


def time_sweep(views, cal, runs: int, **kw) -> list[float]:
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
    args = captured[0]
    out = []
    for _ in range(runs):
        t = time.process_time()
        sweep(*args)
        out.append(time.process_time() - t)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--case", choices=("twin", "big", "all"), default="all")
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args()
    numba.set_num_threads(1)
    warnings.simplefilter("ignore")
    print(machine_line())
    if args.case in ("twin", "all"):
        t = twin_scene()
        ts = time_sweep(t.views, t.cal, args.runs, zmin_m=ZMIN, zmax_m=ZMAX)
        print(f"twin three-depth, defaults: sweep pass {1e3 * min(ts):.1f} ms min, {1e3 * statistics.median(ts):.1f} median")
    if args.case in ("big", "all"):
        views, cal = random_views(1060)
        ts = time_sweep(views, cal, args.runs, zmin_m=ZMIN, zmax_m=ZMAX, num_planes=64)
        print(f"4 x 1060^2 x 64 planes: sweep pass {1e3 * min(ts):.1f} ms min, {1e3 * statistics.median(ts):.1f} median")


if __name__ == "__main__":
    main()
