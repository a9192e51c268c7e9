"""lfring.batch.settings: what BatchSettings refuses, and the keys of earlier versions' records."""

import pytest

from lfring.batch import BatchSettings
from lfring.errors import InvalidInputError


@pytest.mark.parametrize(
    "kwargs, text",
    [
        ({}, "nothing to do"),
        ({"refocus_m": (0.0,)}, "positive"),
        ({"refocus_m": (0.5, 0.5)}, "repeat"),
        ({"depth": True, "zmin_m": -0.3}, "zmin_m must be a positive number of metres"),
        ({"depth": True, "zmin_m": 0.8, "zmax_m": 0.4}, "smaller"),
        ({"refocus_m": (0.5,), "bit_depth": 12}, "bit_depth"),
        ({"refocus_m": (0.5,), "planes": 1}, "planes"),
        # Two planes leave the semi-global depth nothing to judge its answers against: the
        # batch's own depth map or the viewer's.
        ({"depth": True, "zmin_m": 0.3, "zmax_m": 1.0, "planes": 2}, "planes must be an integer >= 3"),
        ({"viewer": True, "planes": 2}, "planes must be an integer >= 3"),
    ],
)
def test_settings_errors(kwargs, text):
    with pytest.raises(InvalidInputError, match=text):
        BatchSettings(**kwargs)


def test_legacy_key_is_the_key_of_records_before_output_keys():
    # 6e76e9ced5695793 is what BatchSettings(refocus_m=(0.5,)).key() returned before per-output
    # keys (commit 188722c): folders made then resume instead of being refused.
    # (its default interpolation was cubic then).
    assert BatchSettings(refocus_m=(0.5,), interpolation="cubic").legacy_key() == "6e76e9ced5695793"
    assert BatchSettings(refocus_m=(0.5,), pattern="RGGB").legacy_key() is None


def test_refocusing_method_options():
    with pytest.raises(InvalidInputError, match="refocus_method must be one of"):
        BatchSettings(refocus_m=(0.5,), refocus_method="bokeh")
    with pytest.raises(InvalidInputError, match="for refocus_method='depth-aware'"):
        BatchSettings(refocus_m=(0.5,), refocus_method="shift-and-add", aperture=0.5)
    with pytest.raises(InvalidInputError, match="not both"):
        BatchSettings(refocus_m=(0.5,), aperture=0.5, f_number=2.8)
    with pytest.raises(InvalidInputError, match="aperture must be"):
        BatchSettings(refocus_m=(0.5,), aperture=-1.0)
    assert BatchSettings(refocus_m=(0.5,)).refocus_method == "depth-aware"  # as lfring refocus


def test_refocus_keys_hold_the_method_and_its_aperture():
    """A folder refocused by one method is not done for another, nor for another aperture or
    depth range; shift-and-add's keys are the ones of the folders made before refocusing had a
    method (all of them shift-and-add), so those stay done for it."""
    sa = BatchSettings(refocus_m=(0.5,), refocus_method="shift-and-add").output_keys()["refocus_0.5m"]
    assert sa == "17bef21df6197085"  # what lfring computed before methods were a setting
    keys = {BatchSettings(refocus_m=(0.5,), **kw).output_keys()["refocus_0.5m"]
            for kw in ({}, {"aperture": 0.5}, {"f_number": 2.8}, {"viewer": True, "zmin_m": 0.3, "zmax_m": 0.8})}
    assert len(keys) == 4 and sa not in keys
    viewers = {BatchSettings(viewer=True, refocus_method=m).output_keys()["viewer"] for m in ("depth-aware", "shift-and-add")}
    assert len(viewers) == 2
    d = BatchSettings(refocus_m=(0.5,), f_number=2.8).describe()
    assert d["refocus_method"] == "depth-aware" and d["f_number"] == 2.8


def test_a_calibration_without_a_depth_range_is_refused_when_a_depth_map_must_be_estimated():
    """The frames' depth maps for depth-aware refocusing and the viewer are estimated over
    lfring.focus.depth_aware.estimation_range: a grid pair's open range is refused at once,
    unless the batch is given the range or needs no depth map."""
    from lfring.calibration import RingCalibration
    from lfring.optics import load_device

    pair = RingCalibration.from_grid((64, 96), [(0, 0), (1, 0)], disparity_scale_px_m=120.0)
    for kw in ({"refocus_m": (12.0,)}, {"viewer": True}, {"refocus_m": (12.0,), "aperture": 0.5}):
        with pytest.raises(InvalidInputError, match="no upper depth bound, and none follows from it"):
            BatchSettings(calibration=pair, **kw)
    for kw in ({"refocus_m": (12.0,), "refocus_method": "shift-and-add"}, {"all_in_focus": True},
               {"refocus_m": (12.0,), "zmax_m": 30.0}, {"refocus_m": (12.0,), "zmin_m": 6.0},
               {"refocus_m": (12.0,), "viewer": True, "depth": True, "zmin_m": 6.0, "zmax_m": 30.0}):
        BatchSettings(calibration=pair, **kw)
    # A calibration from the optics gets its far end, as everywhere; a bounded one its range.
    BatchSettings(refocus_m=(0.5,), viewer=True, calibration=RingCalibration.from_optics(load_device("prototype").binned(4)))
    BatchSettings(refocus_m=(0.5,), viewer=True, calibration=RingCalibration.load("twin_binned2"))
