"""Calibrations are recognised by the protocol the stages need."""

import pytest

from lfring.calibration.defaults import default_calibration
from lfring.core.protocols import Calibration, check_calibration
from lfring.errors import InvalidInputError


def test_a_ring_calibration_meets_the_protocol_and_others_do_not():
    cal, _ = default_calibration((2456, 1842))
    assert isinstance(cal, Calibration) and check_calibration(cal) is cal
    for other in (None, "twin_binned2", object(), {"homographies": None}):
        with pytest.raises(InvalidInputError, match="calibration must be a RingCalibration"):
            check_calibration(other)


def test_every_stage_that_takes_a_calibration_refuses_what_is_not_one():
    """A calibration's name, None or its layout given where a calibration goes: refocus,
    focal_stack, all_in_focus, Refocuser, depth_of_field, check_frame, inspect_frame and
    viewer_html raised TypeError ('cannot create weak reference to str') or AttributeError
    ('Layout' object has no attribute 'layout'). Each names the parameter now; a name is told
    how to load it."""
    import numpy as np

    import lfring
    from lfring.focus import depth_of_field
    from lfring.viewer import viewer_html

    cal, _ = default_calibration((2456, 1842))
    views = np.full((4, *cal.layout.view_shape, 3), 0.5, np.float32)
    calls = [lambda c: lfring.refocus(views, c, 0.5), lambda c: lfring.focal_stack(views, c, [0.4, 0.5]),
             lambda c: lfring.all_in_focus(views, c), lambda c: lfring.Refocuser(c, 0.5),
             lambda c: depth_of_field(views, c, depth=np.full(cal.layout.view_shape, 0.5, np.float32)),
             lambda c: lfring.check_frame(views, c), lambda c: lfring.inspect_frame(views, c, plane_m=0.3, tolerance_m=0.01),
             lambda c: viewer_html(views, c)]
    for call in calls:
        for bad in (None, "twin_binned2", cal.layout):
            with pytest.raises(InvalidInputError, match="calibration must be a RingCalibration, got") as info:
                call(bad)
            assert ("RingCalibration.load" in str(info.value)) == isinstance(bad, str)


def test_a_depth_that_is_not_positive_is_refused_as_such():
    """refocus at -1 m said the views no longer overlap there and offered the nearest depth that
    works: the depth is not a distance in front of the lens at all."""
    import numpy as np

    import lfring

    cal, _ = default_calibration((2456, 1842))
    views = np.full((4, *cal.layout.view_shape, 3), 0.5, np.float32)
    for z in (-1.0, 0.0, float("nan")):
        with pytest.raises(InvalidInputError, match=f"depth must be a positive distance in metres from the main lens, got {z:g}"):
            lfring.refocus(views, cal, z)
    with pytest.raises(InvalidInputError, match="must be a positive"):
        lfring.focal_stack(views, cal, [0.5, -0.2])
