"""The GPU engine end to end (views to maps, device-resident) against the CPU engines, and the
torch backend's batches, tensors and raw counts.

Without CUDA the engine's kernels run through Triton's interpreter on CPU tensors, within
``interpreted_on_cpu`` (slow: the scene is the twin binned 16 x 16, a few planes); with CUDA the
same tests run them compiled on the GPU.
"""

import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="the torch extra is not installed")
triton_kernels = pytest.importorskip("lfring.core.triton_kernels")
if not triton_kernels.AVAILABLE:
    pytest.skip("Triton is not installed (its wheels are for Linux x86-64)", allow_module_level=True)

from lfring.calibration import RingCalibration  # noqa: E402
from lfring.core.backend import resolve_device  # noqa: E402
from lfring.depth import estimate_depth  # noqa: E402
from lfring.synth import render  # noqa: E402
from lfring.synth.presets import three_depth_scene  # noqa: E402

# The depth range and planes of the small scene: the fewest planes the 'sgm' method takes there.
KW = dict(zmin_m=0.28, zmax_m=1.1, num_planes=8, reference="center")


@pytest.fixture(scope="module")
def small_twin(prototype):
    r = render(prototype, three_depth_scene(), binning=16)
    return r.views, RingCalibration.from_optics(r.device, layout=r.layout)


@pytest.fixture
def kernel_device(device):
    """The device the engine's kernels run on: CUDA compiled, the CPU interpreted (a CPU device
    in a process with CUDA takes the torch twins instead, tested in test_depth_torch.py)."""
    if device == "cpu" and not triton_kernels.INTERPRETED:
        pytest.skip("a process with CUDA runs no kernel on CPU tensors")
    return device


def _agreement(a, b, field="depth_m"):
    """Where both maps are finite, and the shares of those pixels whose depth agrees within 0.5 %
    and whose confidence within 0.02 (the tolerances of test_depth_torch.py's parity tests)."""
    x, y = np.asarray(getattr(a, field)), np.asarray(getattr(b, field))
    both = np.isfinite(x) & np.isfinite(y)
    rel = np.abs(y[both] - x[both]) / x[both]
    dconf = np.abs(np.asarray(b.confidence)[both] - np.asarray(a.confidence)[both])
    return both, np.mean(rel <= 0.005), np.mean(dconf <= 0.02)


@pytest.mark.parametrize("views_of", ["all", "pair"])
def test_semi_global_matches_the_cpu_engines(small_twin, views_of, kernel_device):
    """The default 'sgm' settings on the GPU path (four views; a pair with its left-right check):
    depth, confidence and filled map as the float32 reference's (the same method) within the
    torch parity tests' tolerances; for four views also as the CPU default's (its 16-bit fused
    passes) within those of test_semiglobal.py; the maps defined on the same pixels. The pair at
    this size keeps about 250 pixels after its left-right check, and its filled map spreads
    them: one of them decided otherwise by the 16-bit cost moves a large part of the filled map
    (against the CPU default: 90 % within 2 %, while the GPU path equals the reference)."""
    views, cal = small_twin
    if views_of == "pair":
        views, cal = views[:2], cal.select_views([0, 1])
    reference = estimate_depth(views, cal, method="sgm-reference", **KW)
    default = estimate_depth(views, cal, **KW)
    with triton_kernels.interpreted_on_cpu():
        got = estimate_depth(views, cal, backend="torch", device=kernel_device, **KW)
    assert got.method == "sgm" and got.depth_m.dtype == np.float32 and got.depth_m.shape == views.shape[1:3]
    assert got.consistency == default.consistency == (views_of == "pair")
    for field in ("depth_m", "depth_filled_m"):
        assert np.array_equal(np.isfinite(getattr(got, field)), np.isfinite(getattr(reference, field))), field
    both, depth_ok, conf_ok = _agreement(reference, got)
    # At this size the pair's left-right check keeps few pixels; its filled map covers far more.
    assert both.mean() > (0.5 if views_of == "all" else 0.02)
    assert depth_ok >= 0.97 and conf_ok >= 0.95, (depth_ok, conf_ok)
    both, filled_ok, _ = _agreement(reference, got, "depth_filled_m")
    assert both.mean() > 0.4 and filled_ok >= 0.97, filled_ok
    assert np.mean(np.isfinite(got.depth_m) == np.isfinite(default.depth_m)) >= 0.999
    if views_of == "all":  # the pair's few kept pixels are too few for shares of them, or of a map filled from them
        both, depth_ok, conf_ok = _agreement(default, got)
        assert depth_ok >= 0.95 and conf_ok >= 0.95, (depth_ok, conf_ok)
        filled = np.isfinite(default.depth_filled_m) & np.isfinite(got.depth_filled_m)
        rel = np.abs(got.depth_filled_m[filled] - default.depth_filled_m[filled]) / default.depth_filled_m[filled]
        assert np.mean(rel <= 0.02) >= 0.97


def test_a_batch_of_raw_counts_stays_on_the_device(small_twin, kernel_device):
    """A batch (B, V, h, w, C) of uint16 counts as a tensor: estimated in one go, normalised with
    its levels on the device, its maps (B, h, w) tensors there; each frame as the CPU engine's
    estimate of its float views."""
    views, cal = small_twin
    black, white = 64, 4095
    frames = [views, np.ascontiguousarray(views[..., ::-1])]
    counts = np.stack([np.round(black + f * (white - black)) for f in frames]).astype(np.uint16)
    batch = torch.from_numpy(counts).to(kernel_device)
    with triton_kernels.interpreted_on_cpu():
        got = estimate_depth(batch, cal, backend="torch", levels=(black, white), **KW)
    for m in (got.depth_m, got.confidence, got.hypothesis_index, got.depth_filled_m):
        assert isinstance(m, torch.Tensor) and m.device.type == kernel_device and m.shape == (2, *views.shape[1:3])
    for k, f in enumerate(frames):
        want = estimate_depth(((counts[k] - black) / (white - black)).astype(np.float32), cal,
                              method="sgm-reference", **KW)
        one = type(want)(**{**want.__dict__, "depth_m": got.depth_m[k].cpu().numpy(),
                            "confidence": got.confidence[k].cpu().numpy()})
        both, depth_ok, conf_ok = _agreement(want, one)
        assert both.mean() > 0.5 and depth_ok >= 0.99 and conf_ok >= 0.99, (k, depth_ok, conf_ok)


def test_host_engines_take_batches_too(small_twin, device):
    """An engine without device kernels ('local') takes a NumPy batch of uint8 counts frame by
    frame on the host: the maps stacked, each frame's as its own estimate."""
    views, cal = small_twin
    counts = np.stack([np.round(views * 255), np.round(views[:, ::-1, ::-1] * 255)]).astype(np.uint8)
    kw = dict(KW, method="local")
    got = estimate_depth(counts, cal, backend="torch", device=device, **kw)
    assert isinstance(got.depth_m, np.ndarray) and got.depth_m.shape == (2, *views.shape[1:3])
    for k in range(2):
        one = estimate_depth(counts[k], cal, backend="torch", device=device, **kw)
        np.testing.assert_array_equal(got.depth_m[k], one.depth_m)
        np.testing.assert_array_equal(got.confidence[k], one.confidence)


def test_the_torch_backend_defaults_to_cuda():
    """``device=None`` is CUDA where present: the GPU path."""
    assert resolve_device(None).type == ("cuda" if torch.cuda.is_available() else "cpu")
