"""The torch backend's GPU path against the NumPy/numba CPU path, side by side in the same run.

- depth of 4 views of 1060 x 1060 (the paper's sub-aperture size; random texture, the prototype's
  optics calibration with views valid everywhere, as bench_depth.py's second table) at exactly
  64 planes, default settings ('sgm'): the GPU (NumPy views in, NumPy maps out: one upload, one
  download) against the CPU path, and the agreement of their maps;
- the twin's three-depth scene (2 x 2 binned, realistic noise), default settings;
- refocus of one 4 x 1060 x 1060 frame from NumPy (upload, kernel, download) against the NumPy
  path, and of batches of 16 frames already on the device (float32 and uint16 counts), per frame;
- the GPU memory of one depth call at 1060 x 1060 x 128 planes (torch's peak allocation).

Times are medians of a few runs after a warm-up (the GPU synchronised before each clock read).
Without a CUDA device it says so and exits 0: the GPU path cannot be judged here.

    python benchmarks/bench_gpu.py
"""

from __future__ import annotations

import sys

import numpy as np
from _common import ZMAX, ZMIN, cuda_torch, machine_line, random_views, twin_scene
from _timing import bench

from lfring.depth import estimate_depth
from lfring.focus import refocus

RUNS = 5
SIDE = 1060
BATCH = 16


def agreement(a, b) -> str:
    both = np.isfinite(a.depth_m) & np.isfinite(b.depth_m)
    rel = np.abs(b.depth_m[both] - a.depth_m[both]) / a.depth_m[both]
    conf = np.abs(b.confidence[both] - a.confidence[both]) <= 0.02
    return (f"finite maps equal on {np.mean(np.isfinite(a.depth_m) == np.isfinite(b.depth_m)) * 100:.2f} % of pixels, "
            f"depth within 0.5 % on {np.mean(rel <= 0.005) * 100:.2f} %, confidence within 0.02 on {conf.mean() * 100:.2f} %")


def main() -> int:
    torch = cuda_torch()
    if torch is None:
        return 0
    sync = torch.cuda.synchronize

    def timed(fn):
        def run():
            fn()
            sync()
        return bench(run, RUNS)

    print(machine_line())
    print(f"GPU: {torch.cuda.get_device_name()}, torch {torch.__version__}")
    print(f"median of {RUNS} runs after a warm-up, seconds")
    print("| what | CPU median | GPU median | CPU / GPU |")
    print("|---|---|---|---|")

    views, cal = random_views(SIDE)
    kw = dict(zmin_m=ZMIN, zmax_m=ZMAX, num_planes=64)
    cpu_s = bench(lambda: estimate_depth(views, cal, **kw), RUNS)[0]
    gpu_s = timed(lambda: estimate_depth(views, cal, backend="torch", **kw))[0]
    print(f"| depth 4 x {SIDE}^2 x 64 planes, defaults | {cpu_s:.3f} | {gpu_s:.4f} | {cpu_s / gpu_s:.1f} |")
    depth_note = agreement(estimate_depth(views, cal, method="sgm-reference", **kw),
                           estimate_depth(views, cal, backend="torch", **kw))

    t = twin_scene()
    tkw = dict(zmin_m=ZMIN, zmax_m=ZMAX, reference=0)
    cpu_s = bench(lambda: estimate_depth(t.views, t.cal, **tkw), RUNS)[0]
    gpu_s = timed(lambda: estimate_depth(t.views, t.cal, backend="torch", **tkw))[0]
    print(f"| twin's three-depth scene, defaults | {cpu_s:.3f} | {gpu_s:.4f} | {cpu_s / gpu_s:.1f} |")

    cpu_s = bench(lambda: refocus(views, cal, 0.5), RUNS)[0]
    gpu_s = timed(lambda: refocus(views, cal, 0.5, backend="torch"))[0]
    print(f"| refocus of one 4 x {SIDE}^2 frame from NumPy | {cpu_s:.4f} | {gpu_s:.4f} | {cpu_s / gpu_s:.1f} |")
    many = np.repeat(views[None], BATCH, axis=0)
    batch = torch.from_numpy(many).cuda()
    counts = torch.from_numpy(np.round(many * 65535).astype(np.uint16)).cuda()
    del many
    for name, frames in (("float32", batch), ("uint16 counts", counts)):
        gpu_s = timed(lambda frames=frames: refocus(frames, cal, 0.5, backend="torch"))[0]
        print(f"| refocus, a batch of {BATCH} frames on the device ({name}), per frame | {cpu_s:.4f} | "
              f"{gpu_s / BATCH:.5f} | {cpu_s * BATCH / gpu_s:.1f} |")
    del batch, counts

    torch.cuda.empty_cache()
    torch.cuda.reset_peak_memory_stats()
    before = torch.cuda.memory_allocated()
    estimate_depth(views, cal, backend="torch", zmin_m=ZMIN, zmax_m=ZMAX, num_planes=128)
    sync()
    peak = (torch.cuda.max_memory_allocated() - before) / 2**30
    print(f"\npeak GPU memory of one depth call at {SIDE}^2 x 128 planes: {peak:.2f} GiB")
    print(f"GPU against the float32 CPU reference at 64 planes: {depth_note}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
