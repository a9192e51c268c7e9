import json

import numpy as np
import pytest

from lfring.errors import DeviceError, LfringError, LfringFileNotFoundError
from lfring.optics import RingDevice, builtin_devices, design, load_device, save_device


def test_prototype_values(prototype):
    assert "prototype" in builtin_devices()
    assert prototype.main_focal_length_m == 0.016
    assert prototype.mini_focal_length_m == 0.005
    assert prototype.sensor_width_px == 4912 and prototype.sensor_height_px == 3684
    assert prototype.sensor_height_m == pytest.approx(4.60e-3)
    assert prototype.sensor_width_m == pytest.approx(6.14e-3)
    np.testing.assert_allclose(prototype.lens_centres_m, 1.05e-3 * np.array([[-1, -1], [1, -1], [-1, 1], [1, 1]]))


def test_prototype_positions_are_the_fit_sensor_design(prototype):
    d = design(prototype, object_size_m=0.1, distance_m=0.3, method="fit-sensor")
    assert prototype.ring_distance_m == pytest.approx(d.ring_distance_m, abs=1e-12)
    assert prototype.sensor_distance_m == pytest.approx(d.sensor_distance_m, abs=1e-12)


@pytest.mark.parametrize("suffix", [".toml", ".json"])
def test_round_trip(tmp_path, prototype, suffix):
    path = save_device(prototype, tmp_path / f"dev{suffix}")
    assert load_device(path) == prototype


def test_binned(prototype):
    b = prototype.binned(2)
    assert (b.sensor_width_px, b.sensor_height_px) == (2456, 1842)
    assert b.pixel_pitch_m == pytest.approx(2.5e-6)
    assert b.sensor_height_m == prototype.sensor_height_m
    with pytest.raises(DeviceError, match="binning"):
        prototype.binned(0)


def test_a_binning_too_coarse_for_the_sensor_is_named_as_such(prototype, capsys):
    """Binning 64 left 56 rows of whole 2 x 2 blocks, 2.7 % short of the 3684-row sensor, and was
    refused as a device whose 'sensor_height_m' disagrees with its pixels: the device was
    blamed for the binning. The binning is named now, with the largest one below it that fits."""
    from lfring.cli.main import main

    assert prototype.binned(61).sensor_height_px == 60
    with pytest.raises(DeviceError) as info:
        prototype.binned(64)
    assert str(info.value).startswith("binning factor 64 is too coarse for the 4912 x 3684 px sensor of device 'prototype'")
    assert str(info.value).endswith("(the largest factor below it that fits: 61)")
    assert main(["synth", "target", "--depth", "0.5", "--binning", "64", "-o", "unused/"]) == 2
    assert "--binning 64 is too coarse" in capsys.readouterr().err


def _write(tmp_path, text, name="d.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


BASE = dict(
    name="x", main_focal_length_m=0.016, main_lens_radius_m=0.021, mini_focal_length_m=0.005,
    mini_lens_radius_m=0.001, mini_lens_offset_m=0.00105, sensor_width_px=4912, sensor_height_px=3684,
    pixel_pitch_m=1.25e-6,
)


@pytest.mark.parametrize(
    "change, match",
    [
        ({"main_focal_length_m": -0.016}, "main_focal_length_m.*> 0"),
        ({"pixel_pitch_m": float("nan")}, "pixel_pitch_m.*finite"),
        ({"sensor_width_px": 1.5}, "sensor_width_px.*integer"),
        ({"mini_lens_offset_m": 0.0005}, "overlap"),
        ({"focal": 1.0}, "unknown key.*'focal'"),
        ({"ring_distance_m": 0.03}, "given together"),
        ({"sensor_height_m": 0.006}, "disagrees"),
        ({"aperture_radius_m": 0.05}, "cannot exceed"),
        ({"main_focal_length_m": "16mm"}, "main_focal_length_m.*number"),
        # Millimetres or micrometres given as metres, and a sensor the mini-lenses image nothing on.
        ({"main_focal_length_m": 16.0}, r"'main_focal_length_m' must be a number in metres > 0 and <= 1 \(finite\) "
                                        r"\(lengths are in metres: .*were millimetres given\?\), got 16.0"),
        ({"ring_distance_m": 64.1, "sensor_distance_m": 0.007}, "'ring_distance_m' must be a number in metres > 0 and <= 1"),
        ({"pixel_pitch_m": 1.85}, r"'pixel_pitch_m' must be a number in metres >= 1e-07 and <= 0.001 \(finite\) \(a "
                                  r"sensor's pixel pitch: 1.85 um is 1.85e-06 m\), got 1.85"),
        ({"pixel_pitch_m": 1.85e-9}, "a sensor's pixel pitch"),
        ({"ring_distance_m": 0.037, "sensor_distance_m": 0.003}, r"'sensor_distance_m' \(0.003 m\) must exceed the "
                                                                 r"mini-lenses' focal length 'mini_focal_length_m' \(0.005 m\)"),
    ],
)
def test_bad_device_keys_are_named(tmp_path, change, match):
    data = {**BASE, **change}
    p = _write(tmp_path, json.dumps(data), "d.json")
    with pytest.raises(DeviceError, match=match) as info:
        load_device(p)
    assert str(p) in str(info.value)
    assert isinstance(info.value, ValueError)


def test_missing_key(tmp_path):
    data = dict(BASE)
    del data["pixel_pitch_m"]
    with pytest.raises(DeviceError, match="missing key.*pixel_pitch_m"):
        load_device(_write(tmp_path, json.dumps(data), "d.json"))


def test_malformed_files(tmp_path):
    with pytest.raises(DeviceError, match="not a valid TOML"):
        load_device(_write(tmp_path, "name = = 3"))
    with pytest.raises(LfringFileNotFoundError, match="not found"):
        load_device(tmp_path / "none.toml")
    with pytest.raises(LfringFileNotFoundError, match="built-in devices: .*prototype"):
        load_device("nonexistent")
    with pytest.raises(LfringError):
        load_device(_write(tmp_path, "[device]\nname = 'a'\n"))


def test_require_positions():
    dev = RingDevice(**BASE)
    with pytest.raises(DeviceError, match="no lens positions"):
        dev.require_positions()
    with pytest.raises(DeviceError, match="must exceed the main focal length"):
        dev.with_positions(0.01, 0.006)
