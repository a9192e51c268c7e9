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
