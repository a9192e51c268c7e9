import matplotlib
import pytest

matplotlib.use("Agg")


def _torch_devices() -> list[str]:
    """The torch devices of this machine: the CPU always, CUDA when present (so a machine with a
    GPU runs every torch test on it too)."""
    try:
        import torch
    except ImportError:
        return ["cpu"]
    return ["cpu", "cuda"] if torch.cuda.is_available() else ["cpu"]


@pytest.fixture(params=_torch_devices())
def device(request):
    """Each torch device present, by name (as kornia's test suite does)."""
    return request.param


@pytest.fixture(scope="session")
def prototype():
    from lfring.optics import load_device

    return load_device("prototype")
