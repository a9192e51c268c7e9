"""The GPU engine's Triton kernels against the NumPy/numba/OpenCV references, on small volumes.

On a machine without CUDA they run through Triton's interpreter on CPU tensors (slow: the volumes
are small); with CUDA the same tests run them compiled on the GPU.
"""

import os
import subprocess
import sys
import textwrap

import cv2
import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="the torch extra is not installed")
triton_kernels = pytest.importorskip("lfring.core.triton_kernels")
if not triton_kernels.AVAILABLE:
    pytest.skip("Triton is not installed (its wheels are for Linux x86-64)", allow_module_level=True)

from lfring.depth.aggregation import box_mean_of_finite, least_over_windows  # noqa: E402
from lfring.depth.costs.lcn_halves import take_halves  # noqa: E402
from lfring.depth.engines import gpu  # noqa: E402
from lfring.depth.refine import fill_from_farther_side, refine_index, weighted_median  # noqa: E402
from lfring.depth.sgm import cost_scale, select, sgm_aggregate  # noqa: E402


@pytest.fixture
def kernel_device(device):
    """The torch device the kernels run on here: CUDA compiled, or the CPU interpreted (a CPU
    in a process with CUDA runs no kernel)."""
    if not triton_kernels.runs_on(device) and not (device == "cpu" and triton_kernels.INTERPRETED):
        pytest.skip("compiled kernels take CUDA tensors; CPU tensors only where the process interprets them")
    return device


def _on(a, device):
    return torch.from_numpy(np.ascontiguousarray(a)).to(device)


def _volume(seed=0, shape=(12, 24, 32)):
    rng = np.random.default_rng(seed)
    cost = rng.random(shape).astype(np.float32)
    cost[3, 2, 5] = np.nan
    cost[:, 6, 0] = np.inf
    cost[5, 7, 7] = np.inf
    guide = np.clip(rng.random(shape[1:]) * 0.3 + np.where(np.arange(shape[2]) < shape[2] // 2, 0.2, 0.7), 0, 1)
    return cost, guide.astype(np.float32)


@pytest.mark.parametrize("paths, edge_scale", [(4, 0.05), (8, None)])
def test_paths_are_the_numba_aggregation(paths, edge_scale, kernel_device):
    """Every scan path, edge-aware or not, and the unknown costs filled with their pixel's mean:
    the numba kernels' sums to float32 rounding (the same operations in the same order)."""
    cost, guide = _volume(shape=(12, 24, 32) if paths == 4 else (7, 16, 20))
    want = sgm_aggregate(cost, guide=guide, p1=0.05, p2=0.3, paths=paths, edge_scale=edge_scale)
    got = gpu.aggregate_device(_on(cost, kernel_device), _on(guide, kernel_device), 0.05,
                               0.3, paths=paths, edge_scale=edge_scale)
    np.testing.assert_allclose(got.cpu().numpy(), want, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("exclude", [1, 2])
def test_selection_is_the_numba_selection(exclude, kernel_device):
    """Winner, parabola on the raw cost (its unknown points taking the pixel's mean), the
    ends' inward offsets and both distinctness measures, as ``select(raw_distinctness=True)``."""
    rng = np.random.default_rng(exclude)
    n, h, w = 9, 12, 14
    agg = rng.random((n, h, w)).astype(np.float32)
    agg[0, :3] -= 2.0  # winners at the ends
    agg[-1, 3:6] -= 2.0
    agg[4, 6, :] = agg[4, 6, :].min() - 1.0
    agg[:, 7, 1] = agg[:, 7, 0]  # ties
    raw = rng.random((n, h, w)).astype(np.float32)
    raw[3:6, 6, 2:5] = np.inf  # unknown points of the parabola
    raw[:, 8, 8] = np.inf  # no raw cost at all
    want_i, want_c = select(agg, raw=raw, exclude=exclude, raw_distinctness=True)
    got_i, got_c = gpu.select_device(_on(agg, kernel_device), _on(raw, kernel_device), exclude)
    np.testing.assert_allclose(got_i.cpu().numpy(), want_i, rtol=0, atol=1e-6)
    np.testing.assert_allclose(got_c.cpu().numpy(), want_c, rtol=0, atol=1e-6)


def test_weighted_median_is_the_numba_median(kernel_device):
    rng = np.random.default_rng(3)
    h, w = 30, 37
    values = (rng.random((h, w)) * 12).astype(np.float32)
    values[5:9, 5:30] = 3.25
    known = rng.random((h, w)) > 0.2
    guide8 = np.clip(rng.normal(120, 60, (h, w)), 0, 255).astype(np.uint8)
    want = weighted_median(values, known, guide8, 3, 25.5)
    got = gpu.weighted_median_device(_on(values, kernel_device), _on(known, kernel_device), _on(guide8, kernel_device),
                                     3, 25.5).cpu().numpy()
    assert np.array_equal(np.isnan(got), ~known)
    np.testing.assert_allclose(got[known], want[known], rtol=1e-6, atol=1e-6)


def test_fast_global_smoother_is_opencvs(kernel_device):
    """Both images of the normalised convolution, with a guide whose edges stop the smoothing:
    ximgproc's numbers."""
    rng = np.random.default_rng(1)
    h, w = 26, 31
    g8 = np.clip(rng.normal(128, 40, (h, w)), 0, 255).astype(np.uint8)
    g8[:, 15:] //= 3
    a = rng.random((h, w)).astype(np.float32)
    b = (rng.random((h, w)) > 0.5).astype(np.float32)
    fgs = cv2.ximgproc.createFastGlobalSmootherFilter(g8, 200.0, 8.0, 0.25, 3)
    images = _on(np.stack([a, b]), kernel_device)
    gpu.fgs_device(_on(g8, kernel_device), images, 200.0, 8.0)
    np.testing.assert_allclose(images[0].cpu().numpy(), fgs.filter(a), rtol=0, atol=1e-5)
    np.testing.assert_allclose(images[1].cpu().numpy(), fgs.filter(b), rtol=0, atol=1e-5)


def test_refinement_and_farther_side_fill_are_the_references(kernel_device):
    """The weighted median and the smoother's normalised convolution together (holes, NaN, a
    region cut off by the guide's edges), and the left-right check's fill along both axes."""
    rng = np.random.default_rng(4)
    h, w = 24, 30
    x = np.arange(w)[None, :].repeat(h, 0)
    index = np.where(x < 15, 8.0, 20.0).astype(np.float32) + 0.05 * rng.standard_normal((h, w)).astype(np.float32)
    guide = np.clip(np.where(x < 15, 0.3, 0.7) + 0.01 * rng.standard_normal((h, w)), 0, 1).astype(np.float32)
    confidence = np.full((h, w), 0.6, np.float32)
    confidence[4:10, 10:18] = 0.01
    index[0, 0] = np.nan
    want_r, want_f = refine_index(index, confidence, guide)
    got_r, got_f = (t.cpu().numpy() for t in gpu.refine_index_device(_on(index, kernel_device),
                                                                     _on(confidence, kernel_device),
                                                                     _on(guide, kernel_device)))
    np.testing.assert_allclose(got_r, want_r, rtol=0, atol=1e-5)
    np.testing.assert_allclose(got_f, want_f, rtol=0, atol=1e-4)
    holes = rng.random((h, w)) < 0.3
    for axis in (0, 1):
        want = fill_from_farther_side(want_r, holes, axis=axis)
        got = gpu.fill_from_farther_side_device(_on(want_r, kernel_device), _on(holes, kernel_device), axis)
        np.testing.assert_array_equal(got.cpu().numpy(), want)


def test_volume_passes_are_the_references(kernel_device):
    """The cost's scale, the halves taken, the shiftable windows (an erosion) and the wider box
    mean of the known costs, on a volume with unknown entries."""
    rng = np.random.default_rng(5)
    n, h, w = 6, 20, 23
    volume = rng.random((n, h, w)).astype(np.float32) * 3
    volume[:, :3, :4] = np.inf
    volume[2, 10, 10] = np.inf
    halves = (volume * rng.uniform(0.1, 1.5, volume.shape)).astype(np.float32)
    assert float(gpu.cost_scale_device(_on(volume, kernel_device))) == pytest.approx(cost_scale(volume), rel=1e-5)
    want = volume.copy()
    take_halves(want, halves.copy())
    got = _on(volume, kernel_device)
    gpu._take_halves(got, _on(halves, kernel_device))
    np.testing.assert_array_equal(got.cpu().numpy(), want)
    np.testing.assert_array_equal(gpu._erode(_on(want, kernel_device), 5).cpu().numpy(), least_over_windows(want, 5))
    boxed = want.copy()
    for s in boxed:
        box_mean_of_finite(s, 15)
    gpu._box_mean_of_finite(got, 15)
    np.testing.assert_allclose(got.cpu().numpy(), boxed, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("k", [1, 5, 15, 41])
def test_box_ratios_are_opencvs_box_means(k, kernel_device):
    """The sweep's box means (cv2.boxFilter, BORDER_REFLECT_101) and what each mode makes of
    them: the all-views mean where seen, a half's candidate kept where less, the mean of the
    finite costs; k = 41 reflects more than once on this 18-row volume."""
    from lfring.core.viewstack import WEIGHT_FLOOR
    from lfring.depth.engines import gpu_kernels as gk

    rng = np.random.default_rng(k)
    c, h, w = 3, 18, 45
    cost = (rng.random((c, h, w)) * 2).astype(np.float32)
    seen = (rng.random((c, h, w)) > 0.3).astype(np.float32)
    cost[seen == 0] = 0.0

    def box(x):
        return cv2.boxFilter(x, -1, (k, k), borderType=cv2.BORDER_REFLECT_101)

    cols = torch.empty((2, c, h, w), dtype=torch.float32, device=kernel_device)
    out = torch.empty((c, h, w), dtype=torch.float32, device=kernel_device)
    gpu._box_ratio(_on(cost, kernel_device), _on(seen, kernel_device), k, out, gk.BOX_MEAN, cols)
    want = np.stack([np.where(s > 0.5, box(a) / np.maximum(box(s), WEIGHT_FLOOR), np.inf) for a, s in zip(cost, seen)])
    np.testing.assert_allclose(out.cpu().numpy(), want, rtol=1e-5, atol=1e-6)
    assert np.array_equal(np.isinf(out.cpu().numpy()), seen == 0)

    least = np.where(rng.random((c, h, w)) > 0.5, np.inf, rng.random((c, h, w)) * 4).astype(np.float32)
    out = _on(least.copy(), kernel_device)  # from_numpy shares the array's memory on the CPU
    gpu._box_ratio(_on(cost, kernel_device), _on(seen, kernel_device), k, out, gk.BOX_HALF, cols, scale=1.3,
                   min_support=0.6)
    want = least.copy()
    for i in range(c):
        support = box(seen[i])
        counts = (seen[i] > 0.5) & (support >= 0.6)
        cand = 1.3 * box(cost[i]) / np.where(counts, support, 1.0)
        keep = counts & (cand < want[i])
        want[i][keep] = cand[keep]
    got = out.cpu().numpy()
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)
    assert 0 < np.mean(got != least) < 1  # some candidates taken, some not

    volume = np.where(seen > 0.5, cost, np.inf).astype(np.float32)
    part = _on(volume.copy(), kernel_device)
    gpu._box_ratio(part, part, k, part, gk.BOX_FINITE, cols)
    want = volume.copy()
    for s in want:
        box_mean_of_finite(s, k)
    np.testing.assert_allclose(part.cpu().numpy(), want, rtol=1e-5, atol=1e-6)


def test_kernels_compile_for_a_gpu():
    """Every kernel compiles to a cubin for an H100 (sm_90), without a GPU, with its blocks of
    the GPU's sizes, and spills no register: the checks the interpreter cannot make."""
    code = textwrap.dedent("""
        import os, re, subprocess, tempfile
        os.environ["TRITON_INTERPRET"] = "0"
        from triton.backends.compiler import GPUTarget
        from triton.compiler import ASTSource
        import triton
        from lfring.depth.engines import gpu_kernels as gk
        from lfring.focus import shift_and_add_kernels as fk
        P = "*fp32"
        cases = [
            (gk.lcn_kernel, dict(src_ptr=P, msk_ptr=P, hinv_ptr=P, cost_ptr=P, seen_ptr=P, nv_ptr=P, n_views="i32",
                                 members="i32", h="i32", w="i32", d0="i32", n_chunk="i32", floor="fp32"),
             dict(WRITE_NV=True, BLOCK=256), 4),
            (gk.box_columns_kernel, dict(num_ptr=P, den_ptr=P, col_num_ptr=P, col_den_ptr=P, h="i32", w="i32"),
             dict(FINITE=True, K=15, BLOCK=256), 1),
            (gk.box_ratio_kernel, dict(num_ptr=P, den_ptr=P, col_num_ptr=P, col_den_ptr=P, out_ptr=P, h="i32", w="i32",
                                       floor="fp32", scale="fp32", min_support="fp32"),
             dict(MODE=gk.BOX_HALF, K=5, BLOCK=256), 1),
            (gk.path_kernel, dict(cost_ptr=P, total_ptr=P, pen_ptr=P, p1_ptr=P, scratch_ptr=P, n="i32", h="i32",
                                  w="i32", line0="i32", n_lines="i32", n_steps="i32"),
             dict(HORIZONTAL=False, REVERSE=True, SLOPE=-1, FIRST=False, N_PAD=64, LINES=32), 8),
            (gk.select_kernel, dict(total_ptr=P, raw_ptr=P, index_ptr=P, conf_ptr=P, n="i32", hw="i32",
                                    exclude="i32"), dict(N_PAD=64, P=64), 8),
            (gk.median_kernel, dict(values_ptr=P, bins_ptr="*i32", guide_ptr="*u8", lut_ptr=P, out_ptr=P, h="i32",
                                    w="i32"), dict(RADIUS=3, WIN=64, P=32), 8),
            (gk.fgs_kernel, dict(coef_ptr=P, x_ptr=P, inter_ptr=P, n_lines="i32", n_steps="i32",
                                 stride_line="i32", stride_step="i32", image_stride="i32"),
             dict(IMAGES=2, COLUMNS=True, LINES=32), 1),
            (fk.refocus_kernel, dict(frames_ptr="*u16", msk_ptr=P, hinv_ptr=P, out_ptr=P, n_views="i32", h="i32",
                                     w="i32", channels="i32", offset="fp32", scale="fp32", floor="fp32"),
             dict(CH=4, BLOCK=256, CLIP=True), 4),
        ]
        cuobjdump = os.path.join(os.path.dirname(triton.__file__), "backends", "nvidia", "bin", "cuobjdump")
        for fn, signature, constants, warps in cases:
            signature = dict(signature, **{k: "constexpr" for k in constants})
            out = triton.compile(ASTSource(fn=fn, signature=signature, constexprs=constants),
                                 target=GPUTarget("cuda", 90, 32), options=dict(num_warps=warps, enable_fp_fusion=False))
            with tempfile.NamedTemporaryFile(suffix=".cubin", delete=False) as f:
                f.write(out.asm["cubin"])
            usage = subprocess.run([cuobjdump, "--dump-resource-usage", f.name], capture_output=True, text=True).stdout
            os.unlink(f.name)
            spilled = re.search(r"STACK:([0-9]+).*LOCAL:([0-9]+)", usage)
            assert spilled and spilled.groups() == ("0", "0"), (fn.__name__, usage)
            print(fn.__name__, "ok")
    """)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600,
                          env={**os.environ, "TRITON_DEFAULT_FP_FUSION": "0"})
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.count(" ok") == 8
