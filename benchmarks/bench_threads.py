"""Where a depth call's wall time goes as the thread count grows: the default engine's four
compiled passes (the sweep, the halves, the horizontal paths, the vertical paths with the
selection), the refinement, and the rest of the call, at 1, 2, 4, ... up to all cores.

    python benchmarks/bench_threads.py               # 4 x 1060^2 x 64 planes and the twin
    python benchmarks/bench_threads.py --runs 5 --case twin --threads 1 16
    python benchmarks/bench_threads.py --case twin --threads 1 2 --rest   # the rest's parts too

Each pass is timed by wrapping its module function (wall time, the calls in between are what
"rest" holds). Cases: the random-texture (``_common.random_views``) 4 x 1060^2 views at 64 planes, and the
twin's three-depth scene with its defaults. Medians of ``--runs`` calls after a warm-up; the
depth map of every thread count is compared with the first count's map (the engine's answer
does not depend on the thread count; the ratio column divides the first count's time by each).
"""

from __future__ import annotations

import argparse
import functools
import os
import statistics
import sys
import time
import warnings

import numpy as np
from _common import ZMAX, ZMIN, machine_line, random_views, twin_scene

from lfring.depth import estimate_depth, refine_kernels
from lfring.depth.costs import lcn
from lfring.depth.engines import fused, fused_paths, fused_volume, semiglobal

PASSES = (
    (fused_volume, "sweep_volume", "sweep"),
    (fused_volume, "sweep_halves", "halves"),
    (fused_paths, "horizontal_paths", "horizontal paths"),
    (fused_paths, "vertical_paths", "vertical paths"),
    (semiglobal, "refine_index", "refinement"),
)

# With --rest: the parts of the rest and of the refinement, named where they are looked up.
REST = (
    (fused, "guide_image", "guide image"),
    (lcn, "lcn_sources", "cost sources"),
    (fused_volume, "sample_costs", "scale sample"),
    (refine_kernels, "depth_maps", "depth maps"),
    (refine_kernels, "weighted_median", "weighted median kernel (of the refinement)"),
)


def _timed(spent: dict, parts=PASSES):
    """Wrap every pass of ``parts`` so that its wall time adds up in ``spent``."""
    for module, name, label in parts:
        fn = getattr(module, name)

        @functools.wraps(fn)
        def timed(*args, _fn=fn, _label=label, **kw):
            t = time.perf_counter()
            try:
                return _fn(*args, **kw)
            finally:
                spent[_label] = spent.get(_label, 0.0) + time.perf_counter() - t

        setattr(module, name, timed)


def _cases(which: str):
    out = {}
    if which in ("big", "all"):
        views, cal = random_views(1060)
        out["4 x 1060^2 x 64 planes"] = (views, cal, dict(zmin_m=ZMIN, zmax_m=ZMAX, num_planes=64))
    if which in ("twin", "all"):
        t = twin_scene()
        out["twin three-depth, defaults"] = (t.views, t.cal, dict(zmin_m=ZMIN, zmax_m=ZMAX))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--case", choices=("big", "twin", "all"), default="all")
    ap.add_argument("--threads", type=int, nargs="+", help="thread counts (default 1, 2, 4, ... up to all cores)")
    ap.add_argument("--rest", action="store_true", help="also time the named parts of the rest and the refinement")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    spent: dict = {}
    _timed(spent)
    parts: dict = {}
    if args.rest:
        _timed(parts, REST)
    cores = os.cpu_count() or 1
    counts = args.threads or sorted({t for t in (1, 2, 4, 8, 16, 32, 64) if t <= cores} | {cores})
    print(machine_line())
    labels = [label for _, _, label in PASSES]
    for name, (views, cal, kw) in _cases(args.case).items():
        print(f"\n{name}: wall ms, medians of {args.runs} calls after a warm-up")
        first = f"{counts[0]} thread{'s' if counts[0] > 1 else ''}"
        print("| threads | " + " | ".join(labels) + f" | rest | whole call | {first} / this | same map as {first} |")
        print("|---" * (len(labels) + 5) + "|")
        one = None
        base = None
        for t in counts:
            estimate_depth(views, cal, threads=t, **kw)
            rows = []
            part_rows = []
            for _ in range(args.runs):
                spent.clear()
                parts.clear()
                t0 = time.perf_counter()
                r = estimate_depth(views, cal, threads=t, **kw)
                rows.append(dict(spent, whole=time.perf_counter() - t0))
                part_rows.append(dict(parts))
            depth = np.nan_to_num(r.depth_m, nan=-1.0)
            base = depth if base is None else base
            med = {k: statistics.median(row.get(k, 0.0) for row in rows) for k in (*labels, "whole")}
            rest = med["whole"] - sum(med[k] for k in labels)
            one = med["whole"] if one is None else one
            cells = " | ".join(f"{med[k] * 1e3:.0f}" for k in labels)
            print(f"| {t} | {cells} | {rest * 1e3:.0f} | {med['whole'] * 1e3:.0f} | {one / med['whole']:.2f} | "
                  f"{'yes' if np.array_equal(depth, base) else 'NO'} |", flush=True)
            if args.rest:
                print("|   of which | " + ", ".join(
                    f"{label} {statistics.median(row.get(label, 0.0) for row in part_rows) * 1e3:.1f}"
                    for _, _, label in REST) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
