"""Every warning lfring issues is attributed to the user's own line, however deep inside lfring
it arises (lfring.errors.warn_caller): a fixed stacklevel pointed into lfring's modules from all
but one of the paths that reach a warning."""

import warnings
from pathlib import Path

import numpy as np
import pytest

import lfring
from lfring.errors import LfringWarning

DATA = Path(__file__).resolve().parents[1] / "data" / "synthetic"


@pytest.fixture(scope="module")
def scene():
    cal = lfring.RingCalibration.load("twin_binned2")
    return cal, lfring.split_views(lfring.demosaic(lfring.load_raw(DATA / "scene.png")), cal)


def _calls(cal, views):
    far = np.full(views.shape[1:3], 500.0, np.float32)  # millimetres given as metres
    return {
        "refocus beyond the range": lambda: lfring.refocus(views, cal, 2.0),
        "a depth-aware refocus of a depth map in mm": lambda: lfring.refocus(views, cal, 0.5, method="depth-aware",
                                                                            depth=far),
        "a focal stack beyond the range": lambda: lfring.focal_stack(views, cal, [0.5, 2.0]),
        "a depth range beyond the calibration's": lambda: lfring.estimate_depth(views, cal, zmin_m=0.3, zmax_m=2.0,
                                                                                method="local"),
        "an inspection tolerance below a pixel": lambda: lfring.inspect_frame(views, cal, plane_m=0.9, tolerance_m=0.0005),
    }


@pytest.mark.parametrize("what", list(_calls(None, np.zeros((4, 2, 2, 3))).keys()))
def test_warnings_name_the_caller_s_line(scene, what):
    cal, views = scene
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _calls(cal, views)[what]()
    ours = [w for w in caught if issubclass(w.category, LfringWarning)]
    assert ours, f"{what}: no warning"
    assert all(w.filename == __file__ for w in ours), [(w.filename, w.lineno, str(w.message)[:50]) for w in ours]
