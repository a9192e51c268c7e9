"""Two checkouts of lfring side by side on the GPU: depth of 4 views of 1060 x 1060 at 64
planes (defaults, the torch backend on CUDA), timed in each, alternately, in fresh processes;
then how far the two checkouts' maps are apart.

    git worktree add /tmp/lfring-old f5de590
    python benchmarks/bench_gpu_ab.py /tmp/lfring-old .              # old, new, old, new
    python benchmarks/bench_gpu_ab.py /tmp/lfring-old . --rounds 3

Each process times 15 calls after 3 warm-ups (the GPU synchronised around each) and prints
their median. Without a CUDA device it says so and exits 0: nothing can be judged here.
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SIDE = 1060
RUNS = 15


def probe(out: str) -> None:
    """In a fresh process whose sys.path starts with one checkout: time it, save its maps."""
    import numpy as np
    import torch
    from _common import ZMAX, ZMIN, random_views

    from lfring.depth import estimate_depth

    views, cal = random_views(SIDE)
    kw = dict(zmin_m=ZMIN, zmax_m=ZMAX, num_planes=64, backend="torch", device="cuda")
    for _ in range(3):
        r = estimate_depth(views, cal, **kw)
    times = []
    for _ in range(RUNS):
        torch.cuda.synchronize()
        t = time.perf_counter()
        r = estimate_depth(views, cal, **kw)
        torch.cuda.synchronize()
        times.append(time.perf_counter() - t)
    np.save(out, np.stack([r.depth_m, r.confidence, r.depth_filled_m]))
    print(statistics.median(times))


def main(argv: list[str]) -> int:
    import argparse

    import numpy as np

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before")
    ap.add_argument("after")
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args(argv)
    from _common import cuda_torch

    if cuda_torch() is None:
        return 0
    trees = {"before": Path(args.before).resolve(), "after": Path(args.after).resolve()}
    medians = {name: [] for name in trees}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            for name, tree in trees.items():
                env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tree), os.environ.get("PYTHONPATH", "")])}
                out = subprocess.run([sys.executable, __file__, "--probe", f"{tmp}/{name}.npy"], env=env, cwd=tree,
                                     capture_output=True, text=True, check=True)
                medians[name].append(float(out.stdout.split()[-1]))
                print(f"round {r + 1}, {name} ({tree}): {medians[name][-1] * 1e3:.1f} ms")
        a, b = np.load(f"{tmp}/before.npy"), np.load(f"{tmp}/after.npy")
    print(f"medians over the rounds: before {statistics.median(medians['before']) * 1e3:.1f} ms, "
          f"after {statistics.median(medians['after']) * 1e3:.1f} ms")
    for i, name in enumerate(("depth", "confidence", "filled depth")):
        fa, fb = np.isfinite(a[i]), np.isfinite(b[i])
        both = fa & fb
        diff = np.abs(a[i][both] - b[i][both])
        print(f"{name}: finite on the same pixels {np.mean(fa == fb) * 100:.2f} %, equal on "
              f"{np.mean(diff == 0) * 100 if both.any() else 0:.1f} % of both, at most {diff.max(initial=0):.4g} apart")
    return 0


if __name__ == "__main__":
    if len(sys.argv) > 2 and sys.argv[1] == "--probe":
        probe(sys.argv[2])
    else:
        sys.exit(main(sys.argv[1:]))
