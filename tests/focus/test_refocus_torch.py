"""The torch/kornia refocus against the NumPy/OpenCV reference, on the CPU."""

import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="the torch extra is not installed")

from lfring.calibration import RingCalibration  # noqa: E402
from lfring.errors import InvalidInputError  # noqa: E402
from lfring.focus import refocus  # noqa: E402
from lfring.synth import render  # noqa: E402
from lfring.synth.presets import three_depth_scene  # noqa: E402


@pytest.fixture(scope="module")
def twin(prototype):
    r = render(prototype, three_depth_scene(), binning=4)
    return r.views, RingCalibration.from_optics(r.device, layout=r.layout)


@pytest.mark.parametrize("reference", ["center", 2])
@pytest.mark.parametrize("depth", [0.3, 0.5, 1.0])
def test_parity_with_numpy(twin, reference, depth, device):
    views, cal = twin
    ref = refocus(views, cal, depth, reference=reference)
    got = refocus(views, cal, depth, reference=reference, backend="torch", device=device)
    assert got.dtype == np.float32 and got.shape == ref.shape
    assert np.abs(got - ref).max() < 1e-4


def test_batches_and_tensors(twin, device):
    views, cal = twin
    batch = np.stack([views, views[:, :, :, ::-1].copy()])
    out = refocus(batch, cal, 0.5, backend="torch", device=device)
    assert out.shape == (2, *views.shape[1:])
    np.testing.assert_allclose(out[0], refocus(views, cal, 0.5), atol=1e-4)
    t = refocus(torch.from_numpy(views), cal, 0.5, backend="torch", device=device)
    assert isinstance(t, torch.Tensor) and t.dtype == torch.float32 and t.device.type == device


def test_backend_errors(twin, device):
    views, cal = twin
    with pytest.raises(InvalidInputError, match="numpy, torch"):
        refocus(views, cal, 0.5, backend="jax")
    with pytest.raises(InvalidInputError, match="float32"):
        refocus(views.astype(np.float64), cal, 0.5, backend="torch", device=device)
    with pytest.raises(InvalidInputError, match="linear"):
        refocus(views, cal, 0.5, backend="torch", device=device, interpolation="cubic")
    counts = (views * 255).astype(np.uint8)
    with pytest.raises(InvalidInputError, match=r"the white level must be .* at most uint8's largest count\), got 1000"):
        refocus(counts, cal, 0.5, backend="torch", device=device, levels=(0, 1000))
    with pytest.raises(InvalidInputError, match=r"the device must be a torch device|device must be a torch device .*got 'tpu'"):
        refocus(views, cal, 0.5, backend="torch", device="tpu")  # torch's own RuntimeError before
    for bad in (np.nan, np.inf):  # refused as on the NumPy backend
        spoilt = views.copy()
        spoilt[1, 40, 40, 0] = bad
        with pytest.raises(InvalidInputError, match="NaN or infinite"):
            refocus(spoilt, cal, 0.5, backend="torch", device=device)
    counts = (views * 255).astype(np.float32)  # 8-bit counts as floats: refused as on the NumPy backend
    for given in (counts, torch.from_numpy(counts), counts[None]):
        with pytest.raises(InvalidInputError, match=r"views must be float in \[0, 1\].*raw counts"):
            refocus(given, cal, 0.5, backend="torch", device=device)


def test_the_refocus_kernel_matches_numpy(twin, device):
    """The Triton kernel (CUDA compiled; the CPU interpreted in a process without CUDA): a batch
    of uint8 counts with levels, normalised inside the kernel, as the NumPy refocus of the float
    views they stand for; a float32 frame as its NumPy refocus."""
    tk = pytest.importorskip("lfring.core.triton_kernels")
    if not tk.AVAILABLE or (device == "cpu" and not tk.INTERPRETED):
        pytest.skip("no Triton, or a process with CUDA (which runs no kernel on CPU tensors)")
    views, cal = twin
    levels = (16, 240)
    counts = np.stack([np.round(16 + f * 224) for f in (views, views[:, :, :, ::-1])]).astype(np.uint8)
    # Counts below black and above white, clipped as lfring.demosaic clips them (they reached 1.1
    # and -0.07 before).
    counts[:, :, 300:340, 300:340] = 255
    counts[:, :, 360:380, 300:340] = 0
    floats = np.clip((counts.astype(np.float32) - 16) / 224, 0.0, 1.0)
    with tk.interpreted_on_cpu():
        got = refocus(torch.from_numpy(counts).to(device), cal, 0.5, backend="torch", levels=levels)
        one = refocus(views, cal, 0.5, backend="torch", device=device)
    assert isinstance(got, torch.Tensor) and got.device.type == device and got.shape == (2, *views.shape[1:])
    for k in range(2):
        np.testing.assert_allclose(got[k].cpu().numpy(), refocus(floats[k], cal, 0.5), rtol=0, atol=1e-4)
    assert isinstance(one, np.ndarray) and np.abs(one - refocus(views, cal, 0.5)).max() < 1e-4
