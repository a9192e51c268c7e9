"""The JSON form of a calibration: writing, reading, and refusing hand-edited files by the key
at fault."""

import dataclasses
import json

import numpy as np
import pytest

from lfring.calibration import RingCalibration
from lfring.calibration.build import (
    calibration_from_grid,
    calibration_from_plane_homographies,
)
from lfring.calibration.jsonio import (
    CALIBRATION_VERSION,
    calibration_from_dict,
    calibration_to_dict,
    load_calibration,
    save_calibration,
)
from lfring.errors import FileFormatError, LfringFileNotFoundError
from lfring.optics.views import optical_homographies, optical_layout


@pytest.fixture(scope="module")
def twin(prototype):
    dev = prototype.binned(2)
    return dev, optical_layout(dev)


def _exact(twin, depths, reference=0):
    dev, lay = twin
    return {z: optical_homographies(dev, lay, z, reference=reference) for z in depths}


def _same(a, b):
    """Assert that two calibrations hold the same record, arrays included."""
    np.testing.assert_array_equal(a.model.A, b.model.A)
    np.testing.assert_array_equal(a.model.B, b.model.B)
    assert a.model.reference == b.model.reference and a.depth_origin_m == b.depth_origin_m
    assert a.valid_depth_range_m == b.valid_depth_range_m
    # Layouts compare by identity (eq=False), so they compare here by their JSON form.
    assert a.layout.to_dict() == b.layout.to_dict()
    assert (a.source, a.device, a.pattern, a.provenance) == (b.source, b.device, b.pattern, b.provenance)
    assert (a.black_level, a.white_level) == (b.black_level, b.white_level)
    assert len(a.planes) == len(b.planes)
    for p, q in zip(a.planes, b.planes):
        assert p.depth_m == q.depth_m
        np.testing.assert_array_equal(p.residual_px, q.residual_px)
        np.testing.assert_array_equal(p.leave_one_out_px, q.leave_one_out_px)


def test_save_load_round_trip(tmp_path, twin):
    dev, lay = twin
    cal = RingCalibration.from_plane_homographies(_exact(twin, (0.3, 0.5, 1.0)), layout=lay, depth_origin_m=None, pattern="GRBG")
    back = RingCalibration.load(cal.save(tmp_path / "c.json"))
    np.testing.assert_array_equal(back.model.A, cal.model.A)
    np.testing.assert_array_equal(back.model.B, cal.model.B)
    assert back.depth_origin_m == cal.depth_origin_m and back.pattern == "GRBG"
    assert [p.depth_m for p in back.planes] == [0.3, 0.5, 1.0]
    np.testing.assert_array_equal(back.planes[1].leave_one_out_px, cal.planes[1].leave_one_out_px)


def _edit(tmp_path, cal, fn):
    data = cal.to_dict()
    fn(data)
    p = tmp_path / "edited.json"
    p.write_text(json.dumps(data))
    return p


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda d: d.update(lfring_calibration_version=99), "version"),
        (lambda d: d.pop("A"), "missing key 'A'"),
        (lambda d: d.update(B=[[1, 2], [3, 4]]), "'B' must be 4 finite 3 x 3"),
        (lambda d: d.update(depth_origin_m="zero"), "'depth_origin_m' must be a finite number"),
        (lambda d: d.update(colour="red"), "unknown key"),
        (lambda d: d.update(reference_view=7), "reference_view"),
        (lambda d: d.update(raw_width_px=100), "disagree with the layout"),
        (lambda d: d["layout"].update(rects_xywh_px=[[0, 0, 10, 10]] * 3), "4 views but the layout 3|layout"),
        (lambda d: d.update(bayer_pattern="RGBG"), "bayer_pattern"),
        (lambda d: d.update(valid_depth_range_m=[0.01, 1.0]), "valid depth range"),
        # bool("false") is True: every frame would have been turned 180 degrees.
        (lambda d: d["layout"].update(rotate180="false"), "layout rotate180 must be True or False, got 'false'"),
    ],
)
def test_hand_edited_calibration_files(tmp_path, twin, edit, match):
    cal = RingCalibration.from_optics(twin[0])
    with pytest.raises(FileFormatError, match=match):
        RingCalibration.load(_edit(tmp_path, cal, edit))


def test_corrupt_and_missing_files(tmp_path, twin):
    cal = RingCalibration.from_optics(twin[0])
    p = cal.save(tmp_path / "c.json")
    p.write_text(p.read_text()[:200])
    with pytest.raises(FileFormatError, match=r"not an lfring calibration file: it is not valid JSON \(line \d+, column \d+\)"):
        RingCalibration.load(p)
    with pytest.raises(LfringFileNotFoundError):
        RingCalibration.load(tmp_path / "none.json")


def test_dict_round_trip_through_the_functions(twin):
    dev, lay = twin
    fitted = calibration_from_plane_homographies(_exact(twin, (0.3, 0.5, 1.0)), layout=lay, depth_origin_m=None,
                                                 pattern="GRBG", provenance={"target": "checker"})
    grid = calibration_from_grid((20, 30), [(0, 0), (1, 0), (0.5, 0.25)], disparity_scale_px_m=-3.5, depth_origin_m=0.02)
    leveled = dataclasses.replace(grid, device="prototype", black_level=(64.0, 60.0, 60.0, 64.0), white_level=1023.0)
    for cal in (fitted, grid, leveled, RingCalibration.from_optics(dev)):
        data = calibration_to_dict(cal)
        assert data["lfring_calibration_version"] == CALIBRATION_VERSION
        # JSON-ready: the text form reads back to the same dict.
        assert json.loads(json.dumps(data)) == data
        _same(calibration_from_dict(json.loads(json.dumps(data))), cal)


def test_methods_delegate_to_the_functions(tmp_path, twin):
    cal = RingCalibration.from_optics(twin[0])
    assert cal.to_dict() == calibration_to_dict(cal)
    _same(RingCalibration.from_dict(cal.to_dict()), calibration_from_dict(cal.to_dict()))
    path = save_calibration(cal, tmp_path / "f.json")
    assert path == tmp_path / "f.json"
    assert cal.save(tmp_path / "m.json").read_text() == path.read_text()
    _same(load_calibration(path), cal)
    _same(RingCalibration.load(path), load_calibration(path))
    _same(load_calibration("twin_binned2"), RingCalibration.load("twin_binned2"))


@pytest.mark.parametrize("edit, match", [
    (lambda d: d.update(depth_origin_m=True), "'depth_origin_m' must be a finite number, got True"),
    (lambda d: d.update(depth_origin_m=10 ** 400), "'depth_origin_m' must be a finite number"),
    (lambda d: d.update(white_level="1023"), "'white_level' must be a finite number"),
    (lambda d: d.update(black_level=[64, 64, 64]), "four numbers"),
    (lambda d: d.update(reference_view=True), "'reference_view' must be a view index, got True"),
    (lambda d: d.update(reference_view=1.0), "'reference_view' must be a view index, got 1.0"),
    (lambda d: d.update(valid_depth_range_m=[0.3]), r"\[min, max or null\]"),
    (lambda d: d.update(planes=[{"depth_m": 0.3}]), r"'planes'\[0\] must have depth_m and residual_px"),
    (lambda d: d.update(source="camera"), "calibration source must be one of planes, optics, grid"),
    # A singular map at infinity crashed refocus and depth later with LinAlgError.
    (lambda d: d["A"].__setitem__(2, [[1, 0, 0], [1, 0, 0], [0, 0, 1]]), "A of view 2 is singular"),
    (lambda d: d["A"].__setitem__(1, [[0, 0, 0]] * 3), "A of view 1 is singular"),
])
def test_bad_values_are_refused_by_name(twin, edit, match):
    data = calibration_to_dict(RingCalibration.from_optics(twin[0]))
    edit(data)
    with pytest.raises(FileFormatError, match=match) as err:
        calibration_from_dict(data, source_name="edited.json")
    assert str(err.value).startswith("edited.json: ")
