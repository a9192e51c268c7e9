import matplotlib
import pytest

matplotlib.use("Agg")


@pytest.fixture(scope="session")
def prototype():
    from lfring.optics import load_device

    return load_device("prototype")
