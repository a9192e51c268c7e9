"""Real mini-lenses in the device description: the record, its files, what the optics makes of it."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from lfring.errors import DeviceError
from lfring.optics import MiniLens, load_device, save_device
from lfring.optics.views import ideal_discs_px, lens_distortions, optical_layout, vignetting_region

CALIB = Path(__file__).resolve().parents[2] / "calib"


def test_ideal_lenses_leave_the_device_as_it_was(prototype):
    assert prototype.lenses is None and not prototype.distorts
    assert "lenses" not in prototype.to_dict()
    same = prototype.with_lenses([MiniLens()] * 4)
    assert same.lenses is None and same == prototype
    assert lens_distortions(prototype) is None


def test_the_shipped_device_with_real_lenses():
    dev = load_device(CALIB / "prototype_lenses.toml")
    assert dev.name == "prototype_lenses" and dev.distorts and len(dev.lenses) == 4
    # Each lens its own.
    assert len({lens.k1 for lens in dev.lenses}) == 4
    base = load_device(CALIB / "prototype.toml")
    assert dev.main_focal_length_m == base.main_focal_length_m and dev.ring_distance_m == base.ring_distance_m
    # Decentred lenses move their views' centres by a few micrometres.
    moved = np.abs(dev.lens_centres_m - base.lens_centres_m).max()
    assert 1e-7 < moved < 2e-5


@pytest.mark.parametrize("suffix", [".toml", ".json"])
def test_lenses_round_trip_through_device_files(tmp_path, prototype, suffix):
    lenses = [MiniLens(k1=-0.5, p2=0.01, decentre_m=(1e-6, -2e-6), tilt_deg=(1.0, 0.0), transmission=0.9,
                       falloff=(0.3, 0.1, 0.0))] + [MiniLens(k1=-0.1 * k) for k in range(1, 4)]
    dev = prototype.with_lenses(lenses)
    back = load_device(save_device(dev, tmp_path / f"d{suffix}"))
    assert back == dev


@pytest.mark.parametrize("bad, match", [
    (dict(tilt_deg=(20.0, 0.0)), "tilt_deg"),
    (dict(transmission=1.5), "transmission"),
    (dict(falloff=(0.2, 2.0, 0.0)), "falloff"),
    (dict(decentre_m=(1e-6,)), "decentre_m"),
])
def test_bad_lenses_are_refused(bad, match):
    with pytest.raises(DeviceError, match=match):
        MiniLens(**bad)


def test_a_device_needs_four_lenses(prototype, tmp_path):
    with pytest.raises(DeviceError, match="four MiniLens"):
        dataclasses.replace(prototype, lenses=(MiniLens(k1=-0.1),) * 3)
    p = tmp_path / "three.toml"
    p.write_text((CALIB / "prototype.toml").read_text() + "\n[[lenses]]\nk1 = -0.1\n")
    with pytest.raises(DeviceError, match="four tables"):
        load_device(p)
    p.write_text((CALIB / "prototype.toml").read_text() + "\n[[lenses]]\nk7 = 1\n" * 4)
    with pytest.raises(DeviceError, match="unknown key"):
        load_device(p)


def test_the_distortion_is_centred_on_each_lens_and_moves_the_recorded_discs(prototype):
    dev = prototype.binned(2).with_lenses([MiniLens(k1=-1.0)] * 4)
    dist = lens_distortions(dev)
    centres = np.array([d.centre_px for d in dist])
    # The lens's axis lies nearer the sensor's centre than its view's disc (m_k vs m_k (1 + c/b)).
    discs = np.array(ideal_discs_px(dev))
    mid = np.array([dev.sensor_width_px, dev.sensor_height_px]) / 2 - 0.5
    assert np.all(np.hypot(*(centres - mid).T) < np.hypot(*(discs[:, :2] - mid).T))
    # Barrel distortion shrinks the recorded discs.
    recorded = optical_layout(dev).circles
    assert all(r < discs[0, 2] for _, _, r in recorded)


def test_vignetting_follows_the_bent_chief_ray_and_the_lens_transmission(prototype):
    dev = prototype.binned(4)
    rect = (220, 140, 40, 30)  # near the rim of view 0's disc
    plain = vignetting_region(dev, 0, rect)
    dim = vignetting_region(dev.with_lenses([MiniLens(transmission=0.5)] + [MiniLens()] * 3), 0, rect)
    np.testing.assert_allclose(dim, 0.5 * plain, rtol=1e-6)
    bent = vignetting_region(dev.with_lenses([MiniLens(k1=-2.0)] + [MiniLens()] * 3), 0, rect)
    assert not np.allclose(bent, plain)
