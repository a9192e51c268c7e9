"""Fixtures of the inspection tests: the twin's parts rendered and inspected once per session,
for the tests of measuring and of reporting alike."""

import pytest

from inspect_parts import PLANE, TOL, truth_defects, truth_deviation
from lfring.calibration.defaults import default_calibration
from lfring.inspect import inspect_frame
from lfring.io.demosaic import demosaic
from lfring.io.raw import RawFrame
from lfring.synth import render
from lfring.synth.presets import part_scene
from lfring.views import split_views


@pytest.fixture(scope="session")
def parts(prototype):
    """name -> (render, calibration, views, truth defects, inspection)."""
    cal = default_calibration((2456, 1842))[0]
    specs = {
        "good": dict(defect_heights_m=(), seed=21),
        "two": dict(defect_heights_m=(0.015, -0.013), defect_size_m=0.012, seed=22),
        # 12.5 mm is 0.52 px of disparity between neighbouring views at 0.3 m.
        "three": dict(defect_heights_m=(0.0125, -0.016, -0.0125), defect_size_m=0.0125, seed=23),
    }
    out = {}
    for name, kw in specs.items():
        r = render(prototype, part_scene(depth_m=PLANE, **kw), binning=2, noise="realistic", seed=kw["seed"])
        frame = RawFrame(mosaic=r.raw, pattern="RGGB", black_level=r.black_level, white_level=r.white_level, bit_depth=12)
        views = split_views(demosaic(frame), cal.layout)
        res = inspect_frame(views, cal, plane_m=PLANE, tolerance_m=TOL, device=r.device)
        out[name] = (r, cal, views, truth_defects(truth_deviation(r, cal, PLANE), TOL), res)
    return out
