"""A frame's outputs together, as users ask for them: `lfring refocus` of the bundled frame at
two depths with its all-in-focus image (depth-aware, the default), and a batch frame refocused
at one depth with its all-in-focus image, each timed inside one process (warm kernels, medians
of 5 after a first call). Two checkouts alternate in fresh processes, so that a change of the
machine's load falls on both alike.

    git worktree add /tmp/lfring-old HEAD~1
    python benchmarks/bench_outputs.py /tmp/lfring-old . --rounds 7
"""

from __future__ import annotations

import json
import shutil
import statistics
import sys
import tempfile
import time
import warnings
from pathlib import Path

SCENE = str(Path(__file__).resolve().parents[1] / "data" / "synthetic" / "scene.png")


def probe() -> None:
    from lfring.batch import BatchSettings
    from lfring.batch.pipeline import process_frame
    from lfring.cli.main import main

    warnings.simplefilter("ignore")
    out = tempfile.mkdtemp()

    def cli():
        shutil.rmtree(Path(out) / "r", ignore_errors=True)
        assert main(["-q", "refocus", SCENE, "--depths", "0.3,0.5", "--all-in-focus", "-o", f"{out}/r/scene.png"]) == 0

    settings = BatchSettings(refocus_m=(0.5,), all_in_focus=True)

    def batch():
        res = process_frame(SCENE, settings)
        assert res.ok, res.error

    times = {}
    for name, fn in (("refocus_two_depths_and_all_in_focus_ms", cli), ("batch_frame_refocus_and_all_in_focus_ms", batch)):
        fn()
        ts = []
        for _ in range(5):
            t = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t)
        times[name] = round(1e3 * statistics.median(ts), 1)
    shutil.rmtree(out, ignore_errors=True)
    print(json.dumps(times))


if __name__ == "__main__":
    if sys.argv[1:] == ["--probe"]:
        probe()
    else:
        from _timing import alternate_checkouts

        alternate_checkouts(__file__, __doc__.splitlines()[0], default_rounds=5)
