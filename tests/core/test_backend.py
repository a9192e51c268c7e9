"""The backends and the torch device."""

import logging

import pytest

from lfring.core.backend import check_backend, resolve_device
from lfring.errors import InvalidInputError


def test_backend_names():
    assert check_backend("torch") == "torch"
    with pytest.raises(InvalidInputError, match="backend must be one of numpy, torch"):
        check_backend("cuda")


def test_cuda_asked_without_cuda_falls_back_to_the_cpu_and_says_so(caplog):
    torch = pytest.importorskip("torch")
    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    with caplog.at_level(logging.WARNING, logger="lfring.core.backend"):
        assert resolve_device("cuda").type == "cpu"
    assert "CUDA is not available" in caplog.text
    assert resolve_device(None).type == "cpu"
