"""Shared scenes of the depth tests, rendered once per session."""


import pytest

from lfring.calibration import RingCalibration
from lfring.depth import estimate_depth
from lfring.depth.metrics import evaluation_mask
from lfring.io.demosaic import demosaic
from lfring.io.raw import RawFrame
from lfring.synth import render
from lfring.synth.presets import three_depth_scene
from lfring.views import split_views


@pytest.fixture(scope="session")
def twin(prototype):
    r = render(prototype, three_depth_scene(), binning=2, noise="realistic", seed=3)
    cal = RingCalibration.from_optics(r.device, layout=r.layout)
    frame = RawFrame(mosaic=r.raw, pattern="RGGB", black_level=r.black_level, white_level=r.white_level, bit_depth=12)
    views = split_views(demosaic(frame), r.layout)
    gt = r.depth_m[0]
    res = estimate_depth(views, cal, zmin_m=0.27, zmax_m=1.1, num_planes=41, reference=0)
    return r, cal, views, gt, evaluation_mask(gt, r.views_sharp[0]), res


@pytest.fixture(scope="session")
def hard_twin(prototype):
    """The twin's hard scene (slants, wires, a blank card, vignetting from 30 % to 96 % per view),
    4 x 4 binned with realistic noise, and its calibration."""
    from lfring.synth.presets import HARD_VIEW_FALLOFF, hard_scene

    r = render(prototype, hard_scene(), binning=4, pattern=None, view_falloff=HARD_VIEW_FALLOFF, noise="realistic", seed=3)
    return r, RingCalibration.from_optics(r.device, layout=r.layout)
