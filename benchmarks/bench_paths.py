"""The semi-global engine's two path passes of two checkouts in one process, alternately: the
horizontal paths (with the erosion) and the vertical paths (with the winner selection), on the
inputs a real call gives them.

    git worktree add /tmp/lfring-old HEAD~1
    python benchmarks/bench_paths.py /tmp/lfring-old          # this checkout against that one
    python benchmarks/bench_paths.py /tmp/lfring-old --runs 9 --threads 1 2
    python benchmarks/bench_paths.py /tmp/lfring-old --case twin   # the twin's three-depth scene

The inputs are captured from one default call at 4 x 1060^2 x 64 planes (``_common.random_views``)
or on the twin's three-depth scene (``--case twin``, 11 hypotheses),
and each pass of each checkout (its ``lfring/depth/engines/fused_paths.py``, imported under
another name) is given copies of them: the times are of the compiled pass alone, in the same
process, alternating between the checkouts, so that the machine's load falls on both alike
(where the load changes from minute to minute, fresh processes spread more than a change does).
Each pass's outputs are compared between the checkouts: the same numbers to the bit or not.
The other checkout's module is the only part of it used: it imports this checkout's
``fused_common`` and helpers, and "this checkout" is the ``lfring`` that Python imports (run from
the checkout's root, or put it on ``PYTHONPATH``). At 64 planes the horizontal pass runs each row
alone; ``--case twin`` or ``--planes 16`` exercise the rows side by side. Both checkouts' passes
must take the same arguments and layouts: from c07dcf1 on, the paths' sums are in tiles of columns
(``fused_paths.tile_shape``) and the vertical pass has no block argument; from ab4edc4 on, the
eroded volume is in the same tiles too (the run stops with a message where the other checkout's
passes refuse the inputs). The tiles are those of the captured call, one per thread of this
process's default count: ``--threads`` changes the threads that run them, not their number.
"""

from __future__ import annotations

import argparse
import importlib.util
import shutil
import statistics
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
from _common import ZMAX, ZMIN, machine_line, random_views, twin_scene

from lfring.depth import estimate_depth
from lfring.depth.engines import fused_paths

PASSES = {"horizontal": (7, 8), "vertical": (2, 12, 13)}  # each pass's arguments that it writes


def _capture(case: str, planes: int) -> dict:
    """The arguments of both passes in one default call, copied before the pass ran."""
    got = {}

    def wrap(name):
        fn = getattr(fused_paths, name + "_paths")

        def captured(*args):
            got[name] = [np.array(a) if isinstance(a, np.ndarray) else a for a in args]
            return fn(*args)

        setattr(fused_paths, name + "_paths", captured)
        return fn

    originals = {name: wrap(name) for name in PASSES}
    try:
        if case == "big":
            views, cal = random_views(1060)
            kw = dict(num_planes=planes)
        else:
            t = twin_scene()
            views, cal, kw = t.views, t.cal, {}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            estimate_depth(views, cal, zmin_m=ZMIN, zmax_m=ZMAX, **kw)
    finally:
        for name, fn in originals.items():
            setattr(fused_paths, name + "_paths", fn)
    return got


def _load(checkout: Path, folder: Path):
    """The other checkout's module, imported from a copy in ``folder``: numba's disk cache beside
    it names the module it was compiled as, which must not be the checkout's own."""
    path = folder / "fused_paths_other.py"
    shutil.copyfile(checkout / "lfring" / "depth" / "engines" / "fused_paths.py", path)
    spec = importlib.util.spec_from_file_location("fused_paths_other", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # numba's disk cache finds a kernel's module by its name
    spec.loader.exec_module(mod)
    return mod


def _run(fn, args, written):
    a = list(args)
    for i in written:
        a[i] = args[i].copy()
    t = time.perf_counter()
    fn(*a)
    return time.perf_counter() - t, [a[i] for i in written]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("other", type=Path, help="the other checkout's root")
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--case", choices=("big", "twin"), default="big",
                    help="4 x 1060^2 views (random texture), or the twin's three-depth scene with the defaults")
    ap.add_argument("--planes", type=int, default=64, help="the hypotheses of the 1060^2 case")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        return _compare(_load(args.other, Path(folder)), args)


def _compare(other, args) -> int:
    import numba

    inputs = _capture(args.case, args.planes)
    print(machine_line())
    what = f"4 x 1060^2 x {args.planes} planes" if args.case == "big" else "the twin's three-depth scene"
    print(f"the path passes on {what}: wall ms, medians of {args.runs} calls each, alternating")
    print(f"| pass | threads | {args.other} | this checkout | this / other | same outputs |")
    print("|---|---|---|---|---|---|")
    for name, written in PASSES.items():
        fns = (getattr(other, name + "_paths"), getattr(fused_paths, name + "_paths"))
        try:
            outs = [_run(fn, inputs[name], written)[1] for fn in fns]  # compiles, and the outputs
        except Exception as exc:  # numba's typing errors for arrays of another layout, among others
            print(f"{args.other}: its {name} pass does not take this checkout's arguments ({type(exc).__name__}): "
                  "compare checkouts whose volumes are laid out alike", file=sys.stderr)
            return 2
        same = all(np.array_equal(a, b, equal_nan=True) for a, b in zip(*outs))
        for threads in args.threads:
            numba.set_num_threads(threads)
            times = ([], [])
            for _ in range(args.runs):
                for k, fn in enumerate(fns):
                    times[k].append(_run(fn, inputs[name], written)[0])
            old, new = (1e3 * statistics.median(t) for t in times)
            print(f"| {name} | {threads} | {old:.0f} | {new:.0f} | {new / old:.2f} | {'yes' if same else 'NO'} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
