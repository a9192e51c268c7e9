"""Where a depth-aware render at a new focus spends its time: each compiled pass of the renderer
(and the layers' resizes) timed by wrapping it, on bench_refocus_quality.py's speed scene
(4 x 1060 x 1060 RGB views, the prototype's optics, a near block over a slanted plane, the
depth map given), the shift-and-add image made once. Medians of the renders after 3 warm-ups;
the passes' times are means per render. Prints only.

    python benchmarks/bench_render_passes.py [RENDERS]
"""

from __future__ import annotations

import collections
import itertools
import statistics
import sys
import time
import warnings

from _common import refocus_speed_scene

import lfring.focus.depth_aware_kernels as kernels
import lfring.focus.layers as layers
from lfring import refocus
from lfring.errors import LfringWarning
from lfring.focus.depth_aware import depth_of_field

PASSES = ("rungs", "scatter", "disc_blur", "over", "merge", "finish")


def main() -> None:
    renders = int(sys.argv[1]) if len(sys.argv) > 1 else 21
    views, cal, depth = refocus_speed_scene()
    focus = (0.45 + 1e-5 * i for i in itertools.count())
    warnings.simplefilter("ignore", LfringWarning)
    dof = depth_of_field(views, cal, depth=depth)
    sharp = refocus(views, cal, 0.45)
    spent: dict = collections.defaultdict(float)

    def timed(module, name):
        fn = getattr(module, name)

        def wrapper(*args, **kwargs):
            t = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                spent[name] += time.perf_counter() - t
        setattr(module, name, wrapper)

    for name in PASSES:
        timed(kernels, name)
    timed(layers, "_resize")
    for _ in range(3):
        dof.render(next(focus), 1.0, sharp)
    spent.clear()
    times = []
    for _ in range(renders):
        t = time.perf_counter()
        dof.render(next(focus), 1.0, sharp)
        times.append(time.perf_counter() - t)
    print(f"render at a new focus: median {1e3 * statistics.median(times):.1f} ms (min {1e3 * min(times):.1f}), "
          f"{renders} renders")
    print(", ".join(f"{name} {1e3 * spent[name] / renders:.2f}" for name in (*PASSES, "_resize")) + " ms a render")


if __name__ == "__main__":
    main()
