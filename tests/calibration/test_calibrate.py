"""lfring.calibrate end to end on the twin: targets at 0.3 and 1.0 m, held-out planes at 0.5
and 2.0 m (issue: 0.05 px noise-free, 0.15 px with realistic noise, z0 within 1 mm)."""

import numpy as np
import pytest

from lfring.calibration import calibrate
from lfring.errors import EstimationError, InvalidInputError
from lfring.core.geometry import homography_rms_px
from lfring.io.raw import RawFrame
from lfring.optics.views import optical_homographies
from lfring.synth import Plane, Scene, Texture, render
from lfring.synth.presets import flat_scene, target_scene


def _frame(r):
    return RawFrame(mosaic=r.raw, pattern=r.settings.pattern, black_level=r.black_level, white_level=r.white_level, bit_depth=12)


@pytest.fixture(scope="module", params=["none", "realistic"])
def twin(request, prototype):
    noise = request.param
    targets = {z: _frame(render(prototype, target_scene(prototype, z, seed=int(z * 10)), binning=2, noise=noise, seed=5))
               for z in (0.3, 0.5, 1.0)}
    flat = render(prototype, flat_scene(prototype), binning=2, noise="low")
    return noise, targets, _frame(flat), flat.layout, flat.device


def _held_out_error(cal, dev, layout):
    out = {}
    for z in (0.5, 2.0):
        truth = optical_homographies(dev, layout, z, reference=0)
        out[z] = float(homography_rms_px(cal.model(z), truth, layout.view_shape).max())
    return out


@pytest.fixture(scope="module")
def pair_calibration(twin):
    """The calibration from the planes at 0.3 and 1.0 m with the device's z0 (two tests judge it)."""
    noise, targets, flat, layout, dev = twin
    return calibrate({0.3: targets[0.3], 1.0: targets[1.0]}, flat=flat, layout=layout, device=dev)


def test_two_planes_predict_held_out_planes(twin, pair_calibration):
    noise, targets, flat, layout, dev = twin
    cal = pair_calibration
    assert cal.depth_origin_m == pytest.approx(dev.entrance_pupil_m)
    tol = 0.05 if noise == "none" else 0.15
    for z, err in _held_out_error(cal, dev, layout).items():
        assert err < tol, f"{z} m: {err:.4f} px"
    assert max(p.residual_px.max() for p in cal.planes) < 1e-9  # two planes: exact fit
    assert max(max(d["alignment_residual_px"]) for d in cal.provenance["planes"]) < 0.05


def test_z0_aware_fit_beats_z0_zero(twin, pair_calibration):
    noise, targets, flat, layout, dev = twin
    pair = {0.3: targets[0.3], 1.0: targets[1.0]}
    aware = _held_out_error(pair_calibration, dev, layout)
    naive = _held_out_error(calibrate(pair, flat=flat, layout=layout, depth_origin_m=0.0), dev, layout)
    for z in (0.5, 2.0):
        assert naive[z] > 0.15 and aware[z] < naive[z] / 5


def test_three_planes_recover_z0(twin, caplog):
    noise, targets, flat, layout, dev = twin
    cal = calibrate(targets, flat=flat, layout=layout, device=dev)
    assert abs(cal.depth_origin_m - dev.entrance_pupil_m) < 1e-3
    # The device by name, as to_points takes it (it raised AttributeError on a str).
    two = {z: targets[z] for z in (0.3, 1.0)}
    assert calibrate(two, flat=flat, layout=layout, device="prototype").depth_origin_m == dev.entrance_pupil_m
    with pytest.raises(InvalidInputError, match="a device is a RingDevice"):
        calibrate(two, flat=flat, layout=layout, device=2)
    assert cal.provenance["depth_origin"] == "fitted"
    assert all(p.leave_one_out_px is None for p in cal.planes)  # three planes fit any depths
    assert "z0 fitted" not in caplog.text


def test_a_mislabelled_plane_shows_as_an_impossible_z0(twin, caplog):
    """The plane at 0.5 m given as 0.45 m: three planes still fit the model to a fraction of a
    pixel, with z0 about 0.13 m where the device's optics put it at 0.028 m: a warning names
    both. A z0 fitted negative (0.5 m given as 0.6 m gives -0.49 m) is refused, device or not."""
    from lfring.calibration.fit import check_fitted_origin

    noise, targets, flat, layout, dev = twin
    cal = calibrate({0.3: targets[0.3], 0.45: targets[0.5], 1.0: targets[1.0]}, flat=flat, layout=layout, device=dev)
    assert cal.depth_origin_m > dev.entrance_pupil_m + 0.05
    assert all(p.leave_one_out_px is None for p in cal.planes)  # the fit alone cannot tell
    assert f"z0 fitted to the planes is {cal.depth_origin_m:.4f} m" in caplog.text
    assert f"from where the optics of device '{dev.name}' put it" in caplog.text
    caplog.clear()
    # 1 cm off at 0.5 m: z0 within 1 mm of the lens, 27 mm from the ring's viewpoints.
    cal = calibrate({0.3: targets[0.3], 0.51: targets[0.5], 1.0: targets[1.0]}, flat=flat, layout=layout, device=dev)
    assert abs(cal.depth_origin_m - dev.entrance_pupil_m) > 0.02
    assert f"z0 fitted to the planes is {cal.depth_origin_m:.4f} m" in caplog.text
    caplog.clear()
    for device in (None, dev):
        with pytest.raises(InvalidInputError, match=r"z0 fitted to the planes is -0.4900 m, negative.*--depth-origin"):
            check_fitted_origin(-0.49, 0.3, device)
    with pytest.raises(InvalidInputError, match="negative"):
        calibrate({0.3: targets[0.3], 0.6: targets[0.5], 1.0: targets[1.0]}, flat=flat, layout=layout)
    caplog.clear()
    check_fitted_origin(dev.entrance_pupil_m + 0.005, 0.3, dev)  # within 2 % of 0.3 m
    check_fitted_origin(0.05, 0.3, None)
    assert caplog.text == ""


def test_bad_inputs(prototype):
    targets = {z: _frame(render(prototype, target_scene(prototype, z), binning=2)) for z in (0.3, 1.0)}
    flat_r = render(prototype, flat_scene(prototype), binning=2, noise="low")
    flat, layout = _frame(flat_r), flat_r.layout
    with pytest.raises(InvalidInputError, match="two or more"):
        calibrate({0.3: targets[0.3]}, layout=layout)
    with pytest.raises(InvalidInputError, match="positive"):
        calibrate({0.3: targets[0.3], -1.0: targets[1.0]}, layout=layout)
    with pytest.raises(InvalidInputError, match="distinct"):
        calibrate({0.3: targets[0.3], 0.3 + 1e-12: targets[1.0]}, layout=layout)
    small = _frame(render(prototype, target_scene(prototype, 1.0), binning=4))
    with pytest.raises(InvalidInputError, match="same size"):
        calibrate({0.3: targets[0.3], 1.0: small}, layout=layout)
    blank = _frame(render(prototype, Scene((Plane(0.6, (1.0, 1.0), Texture("constant", colors=((0.5, 0.5, 0.5),))),)),
                          binning=2, noise="realistic"))
    with pytest.raises(EstimationError, match=r"target frame .* \(0.6 m\): .*textur"):  # which frame
        calibrate({0.3: targets[0.3], 0.6: blank}, layout=layout, flat=flat)
    bright = RawFrame(mosaic=np.full_like(flat.mosaic, flat.white_level), pattern=flat.pattern, black_level=flat.black_level,
                      white_level=flat.white_level, bit_depth=flat.bit_depth)
    with pytest.raises(InvalidInputError, match="^view 0 of the flat frame is clipped") as err:
        calibrate(targets, layout=layout, flat=bright)
    assert "flat_views" not in str(err.value) and "target frame" not in str(err.value)


def test_a_flat_of_another_setup_is_warned_of(caplog, prototype):
    """A flat taken after the ring or the zoom moved shows the discs elsewhere than the targets
    do: the calibration would cut every view off its disc, so it says so; the setup's own flat
    raises nothing, also beside a target whose texture puts its discs 4.3 px off the flat's
    (detection on a target's texture, not a move)."""
    import logging
    from pathlib import Path

    import lfring

    data = Path(__file__).resolve().parents[2] / "data" / "synthetic"
    targets = {0.3: str(data / "target_0.3m.png"), 1.0: str(data / "target_1m.png")}
    flat = lfring.load_raw(data / "flat.png")
    moved = RawFrame(mosaic=np.roll(flat.mosaic, (12, 20), axis=(0, 1)), pattern=flat.pattern, black_level=flat.black_level,
                     white_level=flat.white_level, bit_depth=flat.bit_depth)
    dev = lfring.optics.load_device("prototype")
    with caplog.at_level(logging.WARNING, logger="lfring.calibration"):
        calibrate(targets, flat=str(data / "flat.png"), device=dev)
        near = _frame(render(prototype, target_scene(prototype, 0.3, seed=2), binning=2, noise="realistic", seed=2))
        calibrate({0.3: near, 1.0: targets[1.0]}, flat=str(data / "flat.png"), device=dev)
        assert "a flat of another setup" not in caplog.text
        calibrate(targets, flat=moved, device=dev)
    assert "the flat frame shows view" in caplog.text and "a flat of another setup" in caplog.text


def test_millimetres_given_as_metres_are_refused_by_the_device_s_optics(caplog):
    """calibrate({300: ..., 1000: ...}, device=...) made a calibration in the wrong unit without a
    word (the command line refused it, the API did not look), then only warned: the views move
    some pixels between the two planes, where the device's optics move them a hundredth of one,
    and the calibration shifted the views by thousands of pixels at 0.5 m. Refused, naming both;
    the right depths raise nothing."""
    import logging
    from pathlib import Path

    data = Path(__file__).resolve().parents[2] / "data" / "synthetic"
    flat = str(data / "flat.png")
    with caplog.at_level(logging.WARNING, logger="lfring.calibration"):
        calibrate({0.3: str(data / "target_0.3m.png"), 1.0: str(data / "target_1m.png")}, flat=flat, device="prototype")
        assert "by the optics of device" not in caplog.text
        with pytest.raises(InvalidInputError, match=r"by the optics of device 'prototype', between the planes given as "
                                                    r"300 m and 1000 m .* more than 30 times off, as depths in another unit"):
            calibrate({300: str(data / "target_0.3m.png"), 1000: str(data / "target_1m.png")}, flat=flat,
                      device="prototype")


def test_a_device_file_s_optics_travel_with_the_calibration(tmp_path):
    """A calibration made with a device keeps that device's record, and later steps take its
    optics from there: a copied device file whose main lens was changed but whose name stayed
    'prototype' made a calibration naming 'prototype', whose point cloud then used the built-in
    prototype's optics (40 % off laterally) and whose --f-number the built-in focal length. A
    device that no binning fits to the frames is refused: its z0 and its checks of the depths
    were used regardless."""
    import dataclasses
    from pathlib import Path

    import lfring
    from lfring.depth.io import device_for
    from lfring.focus.depth_aware import aperture_from_f_number, resolve_aperture

    data = Path(__file__).resolve().parents[2] / "data" / "synthetic"
    targets = {0.3: str(data / "target_0.3m.png"), 1.0: str(data / "target_1m.png")}
    built_in = lfring.optics.load_device("prototype")
    custom = dataclasses.replace(built_in, main_focal_length_m=0.02)  # the same name, another lens
    cal = lfring.RingCalibration.load(calibrate(targets, flat=str(data / "flat.png"), device=custom).save(tmp_path / "c.json"))
    assert cal.device == "prototype" and cal.device_optics() == custom
    assert device_for(cal).main_focal_length_m == 0.02 and device_for(cal).sensor_width_px == 2456  # binned to the frames
    assert resolve_aperture(cal, f_number=2.8) == pytest.approx(aperture_from_f_number(2.8, custom))
    assert resolve_aperture(cal, f_number=2.8) != pytest.approx(aperture_from_f_number(2.8, built_in))
    # A calibration that names a built-in device and keeps no record (as written before) still finds it.
    old = dataclasses.replace(cal, provenance={k: v for k, v in cal.provenance.items() if k != "device_record"})
    assert old.device_optics() == built_in
    other = dataclasses.replace(built_in, sensor_width_px=4000, sensor_height_px=3000, sensor_width_m=None,
                                sensor_height_m=None)
    with pytest.raises(InvalidInputError, match=r"has a 4000 x 3000 px sensor, which no binning turns into the "
                                                r"targets' 2456 x 1842 px frames: the device is not the camera"):
        calibrate(targets, flat=str(data / "flat.png"), device=other)


def test_a_layout_that_is_not_one_is_refused_by_name():
    """calibrate(..., layout="x") ended in an AttributeError deep inside."""
    from pathlib import Path

    data = Path(__file__).resolve().parents[2] / "data" / "synthetic"
    with pytest.raises(InvalidInputError, match=r"layout must be a lfring.views.Layout \(or None: detected\), got str"):
        calibrate({0.3: str(data / "target_0.3m.png"), 1.0: str(data / "target_1m.png")}, layout="x")


def test_depths_as_strings_and_a_rank1_that_is_not_a_bool_are_refused():
    """calibrate took {"0.3": ...} (read as 0.3 here, a string everywhere else) and rank1="yes"
    (truthy), where every other entry is strict about numbers and bools."""
    from pathlib import Path

    data = Path(__file__).resolve().parents[2] / "data" / "synthetic"
    frames = {0.3: str(data / "target_0.3m.png"), 1.0: str(data / "target_1m.png")}
    with pytest.raises(InvalidInputError, match=r"target depths must be positive numbers of metres, got \['0.3', '1.0'\]"):
        calibrate({str(k): v for k, v in frames.items()})
    with pytest.raises(InvalidInputError, match=r"rank1 must be True or False, got 'yes'"):
        calibrate(frames, rank1="yes")


def test_millimetres_given_as_metres_are_refused_without_a_device(caplog):
    """Without a device, calibrate({300: ..., 1000: ...}) made a calibration valid from 300 to
    1000 m (the command line refused it, the API did not look): the built-in calibration of
    frames this size stands in for the optics, and refuses the unit; it warns of nothing smaller,
    since it may be another camera's."""
    import logging
    from pathlib import Path

    data = Path(__file__).resolve().parents[2] / "data" / "synthetic"
    flat = str(data / "flat.png")
    with pytest.raises(InvalidInputError, match=r"by the built-in calibration 'twin_binned2', between the planes given "
                                                r"as 300 m and 1000 m .* more than 30 times off"):
        calibrate({300: str(data / "target_0.3m.png"), 1000: str(data / "target_1m.png")}, flat=flat)
    # A plane given 2 m for 1 m: the device's optics warn of it, the stand-in (maybe another camera) does not.
    off = {0.3: str(data / "target_0.3m.png"), 2.0: str(data / "target_1m.png")}
    with caplog.at_level(logging.WARNING, logger="lfring.calibration"):
        cal = calibrate(off, flat=flat)
        assert cal.valid_depth_range_m == (0.3, 2.0)
        assert "by the built-in calibration" not in caplog.text
        calibrate(off, flat=flat, device="prototype")
    assert "by the optics of device 'prototype', between the planes given as 0.3 m and 2 m" in caplog.text
