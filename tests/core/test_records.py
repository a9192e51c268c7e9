"""Records holding arrays have short reprs: shapes, dtypes and the scalar fields, never the data."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from lfring.core.records import record_repr, summarize
from lfring.depth.selection import DepthResult
from lfring.inspect import Defect, InspectionResult
from lfring.io.raw import RawFrame, load_raw
from lfring.synth.result import RenderResult

DATA = Path(__file__).resolve().parents[2] / "data" / "synthetic"


def _depth(h=705, w=705):
    z = np.full((h, w), 0.5, np.float32)
    return DepthResult(z, np.ones((h, w), np.float32), np.zeros((h, w), np.float32), np.linspace(0.3, 1.0, 40),
                       step_px=0.9, reference="center", cost="lcn", aggregation="box", method="local")


def test_raw_frame_repr_shows_shape_dtype_and_levels():
    frame = load_raw(DATA / "scene.png")
    text = repr(frame)
    assert text == (
        "RawFrame(mosaic=array(shape=(1842, 2456), dtype=uint16), image=None, pattern='RGGB', black_level=64.0, "
        f"white_level=4095.0, bit_depth=12, path={frame.path!r}, file_format='png')"
    )


def test_depth_result_repr():
    assert repr(_depth()) == (
        "DepthResult(depth_m=array(shape=(705, 705), dtype=float32), confidence=array(shape=(705, 705), dtype=float32), "
        "hypothesis_index=array(shape=(705, 705), dtype=float32), depths_m=array(shape=(40,), dtype=float64), "
        "step_px=0.9, reference='center', cost='lcn', aggregation='box', method='local', depth_filled_m=None, paths=None, "
        "consistency=None)"
    )


def test_inspection_result_repr_nests_the_depth_and_defects():
    mask = np.zeros((705, 705), bool)
    dev = np.zeros((705, 705), np.float32)
    defect = Defect((1, 2, 3, 4), (2.5, 4.0), 12, None, 0.013, "bump", 0.98)
    r = InspectionResult("fail", 0.98, None, (defect,), mask, dev, dev, mask, mask, mask, _depth(),
                         np.zeros((705, 705, 3), np.float32), settings={"plane_m": 0.3}, stats={"coverage": 0.98})
    text = repr(r)
    assert text.startswith("InspectionResult(verdict='fail', coverage=0.98, reason=None, defects=(Defect(bbox_px=(1, 2, 3, 4)")
    assert "plane_mask=array(shape=(705, 705), dtype=bool)" in text
    assert "depth=DepthResult(depth_m=array(shape=(705, 705), dtype=float32)" in text
    assert "refocused=array(shape=(705, 705, 3), dtype=float32)" in text
    assert text.endswith("settings={'plane_m': 0.3}, stats={'coverage': 0.98}, beyond_sight=None)")
    assert len(text) < 1500


def test_render_result_repr(prototype):
    from lfring.synth import render
    from lfring.synth.presets import flat_scene

    r = render(prototype, flat_scene(prototype), binning=8, pattern="RGGB", defocus=False)
    text = repr(r)
    assert text.startswith("RenderResult(raw=array(shape=(460, 614), dtype=uint16), image=array(shape=(460, 614, 3), "
                           "dtype=float32), views=array(shape=(4, 176, 176, 3), dtype=float32)")
    assert "layout=Layout(raw_width_px=614" in text and "settings=RenderSettings(binning=8" in text
    assert "[[" not in text and "..." not in text


@pytest.mark.parametrize("cls", [RawFrame, DepthResult, InspectionResult, RenderResult])
def test_records_use_the_one_shared_repr(cls):
    assert cls.__repr__ is record_repr


def test_summarize_containers_and_fields_left_out_of_repr():
    assert summarize((np.zeros(2, np.int8),)) == "(array(shape=(2,), dtype=int8),)"
    assert summarize([1, np.zeros((0, 3))]) == "[1, array(shape=(0, 3), dtype=float64)]"

    @dataclasses.dataclass
    class Rec:
        a: np.ndarray
        hidden: int = dataclasses.field(default=0, repr=False)
        __repr__ = record_repr

    assert repr(Rec(np.zeros((2, 2), np.float32))) == (
        "test_summarize_containers_and_fields_left_out_of_repr.<locals>.Rec(a=array(shape=(2, 2), dtype=float32))"
    )
