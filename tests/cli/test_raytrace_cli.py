"""``lfring raytrace``: a thin shell over lfring.optics.raytrace and the figure."""

from __future__ import annotations

import json
import re
import struct

import pytest

from lfring.cli.main import main
from lfring.optics import save_device

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
FAST = ["--points", "3", "--rays", "9", "--rays-per-lens", "3", "--dpi", "60"]


def _png_size(data: bytes) -> tuple[int, int]:
    assert data[:8] == PNG_MAGIC and data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def _one_error_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    assert lines[0].startswith("lfring: error: ")
    return lines[0]


def test_writes_png_and_sidecar(tmp_path, capsys):
    out = tmp_path / "rays.png"
    assert main(["raytrace", "--object-size", "0.1", "--distance", "0.3", "-o", str(out), *FAST]) == 0
    width, height = _png_size(out.read_bytes())
    # 13 x 9.5 inches at 60 dpi.
    assert (width, height) == (780, 570)
    assert out.stat().st_size > 20_000
    info = json.loads((tmp_path / "rays.json").read_text())
    assert info["ring_distance_m"] == pytest.approx(0.037369, abs=1e-6)
    assert info["sensor_distance_m"] == pytest.approx(0.0066163, abs=1e-7)
    assert info["max_spread_m"] < 1e-9 and info["max_height_error_m"] < 1e-9
    top = [r for r in info["bundles"] if r["source_height_m"] == pytest.approx(0.05) and r["lens"] == "a"]
    assert top[0]["mean_height_m"] == pytest.approx(0.0023, abs=1e-9)
    assert info["rays"]["lens_a"] + info["rays"]["lens_b"] + info["rays"]["missed_ring"] == 3 * (9 + 6)
    err = capsys.readouterr().err
    # Spreads and heights are logged in micrometres.
    assert re.search(r"source y0 = \+50\.0 mm, lens a: \d+ rays, spread 0\.000 um, mean hit \+2300\.000 um", err)
    assert "b = 37.369 mm, c = 6.616 mm" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rays.json", "rays.png", "rays.png.lfring.json"]
    # The same command again replaces its own figure and sidecar (the README can be run twice).
    assert main(["raytrace", "--object-size", "0.1", "--distance", "0.3", "-o", str(out), *FAST]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rays.json", "rays.png", "rays.png.lfring.json"]


def test_bundles_that_reach_no_sensor_are_counted_beside_the_agreement(tmp_path, capsys):
    """An object 2 cm from the lens: most bundles miss the ring or stop at the main lens. The
    spread and the error of the few that arrive are no verdict on the rest, and say so."""
    out = tmp_path / "near.png"
    assert main(["raytrace", "--object-size", "0.1", "--distance", "0.02", "-o", str(out), *FAST]) == 0
    info = json.loads((tmp_path / "near.json").read_text())
    arrived, total = info["bundles_reaching_sensor"]
    assert 0 < arrived < total
    err = " ".join(capsys.readouterr().err.split())
    assert f"{total - arrived} of {total} source-lens bundles reach no sensor pixel" in err
    assert f"(over the {arrived} of {total} source-lens bundles that reach the sensor)" in err


def test_refuses_to_overwrite(tmp_path, capsys):
    out = tmp_path / "rays.png"
    out.write_bytes(b"keep me")
    code = main(["raytrace", "--object-size", "0.1", "--distance", "0.3", "-o", str(out), *FAST])
    assert code == 2
    assert "exists; pass --overwrite" in _one_error_line(capsys.readouterr().err)
    assert out.read_bytes() == b"keep me"
    assert not (tmp_path / "rays.json").exists()
    code = main(["raytrace", "--object-size", "0.1", "--distance", "0.3", "-o", str(out), "--overwrite", *FAST])
    assert code == 0
    assert out.read_bytes()[:8] == PNG_MAGIC


def test_other_design_and_defocus_through_device_positions(tmp_path, capsys, prototype):
    # A device set for 0.1 m at 0.3 m, traced at 1.0 m: the bundles spread (SPEC 2.3).
    dev_file = tmp_path / "dev.toml"
    save_device(prototype, dev_file)
    out = tmp_path / "far.png"
    args = ["raytrace", "--object-size", "0.1", "--distance", "1.0", "-o", str(out), "--device", str(dev_file)]
    assert main([*args, "--use-device-positions", *FAST]) == 0
    info = json.loads((tmp_path / "far.json").read_text())
    assert info["positions"] == "device"
    assert info["ring_distance_m"] == pytest.approx(prototype.ring_distance_m)
    # Blur at 1.0 m is about 16 px of 1.25 um (SPEC 2.3); the filled bundle spreads by as much.
    assert info["max_spread_m"] / 1.25e-6 == pytest.approx(16, abs=1)
    # Without the flag, b and c are redesigned for 1.0 m and the bundles converge again.
    out2 = tmp_path / "redesigned.png"
    assert main(["raytrace", "--object-size", "0.1", "--distance", "1.0", "-o", str(out2), *FAST]) == 0
    info2 = json.loads((tmp_path / "redesigned.json").read_text())
    assert info2["positions"] == "fit-sensor"
    assert info2["ring_distance_m"] != pytest.approx(prototype.ring_distance_m, abs=1e-5)
    assert info2["max_spread_m"] < 1e-9


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--object-size", "0", "--distance", "0.3"], "object size must be a positive"),
        (["--object-size", "0.1", "--distance", "0.01"], "main lens focal length"),
        (["--object-size", "0.1", "--distance", "0.3", "--points", "0"], "error: --points must be an integer >= 1, got 0"),
        (["--object-size", "0.1", "--distance", "0.3", "--rays", "-1"], "error: --rays must be an integer >= 0, got -1"),
        (["--object-size", "0.1", "--distance", "0.3", "--rays-per-lens", "-2"],
         "error: --rays-per-lens must be an integer >= 0, got -2"),
        (["--object-size", "0.1", "--distance", "0.3", "--rays", "0", "--rays-per-lens", "0"],
         "error: --rays and --rays-per-lens are both 0"),
        (["--object-size", "0.1", "--distance", "0.3", "--device", "nosuchdevice"], "no built-in device named"),
        (["--object-size", "0.1", "--distance", "0.3", "--use-device-positions", "--method", "fit-sensor"],
         "give one of them"),
        (["--object-size", "0.1", "--distance", "0.3", "--dpi", "5"], "--dpi must be between 50 and 600"),
    ],
)
def test_errors_are_one_line(tmp_path, capsys, extra, message):
    out = tmp_path / "rays.png"
    assert main(["raytrace", *extra, "-o", str(out)]) == 2
    assert message in _one_error_line(capsys.readouterr().err)
    assert not out.exists()


@pytest.mark.parametrize("name", ["rays.jpg", "rt1.txt"])
def test_bad_suffix_names_the_option_before_any_work(tmp_path, capsys, name):
    out = tmp_path / name
    assert main(["raytrace", "--object-size", "0.1", "--distance", "0.3", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"Invalid value for -o: the figure file must end in .png, .pdf, .svg, got {name!r}" in err
    assert "Traceback" not in err and "lfring: INFO" not in err  # refused before the trace
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("message", "words"),
    [
        ("num_points must be an integer >= 1, got 0", "--points must be an integer >= 1, got 0"),
        ("rays_per_point and rays_per_lens are both 0: there is no ray to trace",
         "--rays and --rays-per-lens are both 0: there is no ray to trace"),
        ("rays cannot be aimed at the mini-lenses; use rays_per_lens=0 or another distance",
         "rays cannot be aimed at the mini-lenses; use --rays-per-lens 0 or another distance"),
        ("object size must be a positive length in metres, got 0", "object size must be a positive length in metres, got 0"),
    ],
)
def test_trace_messages_name_the_options(message, words):
    from lfring.cli.raytrace import _option_words

    assert _option_words(message) == words


def test_device_without_positions_is_one_line(tmp_path, capsys, prototype):
    import dataclasses

    bare = tmp_path / "bare.json"
    save_device(dataclasses.replace(prototype, ring_distance_m=None, sensor_distance_m=None), bare)
    out = tmp_path / "rays.png"
    code = main(["raytrace", "--object-size", "0.1", "--distance", "0.3", "-o", str(out), "--device", str(bare),
                 "--use-device-positions"])
    assert code == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "has no lens positions" in line and "drop --use-device-positions" in line
    # The default (design b, c) works with the same device.
    assert main(["raytrace", "--object-size", "0.1", "--distance", "0.3", "-o", str(out), "--device", str(bare),
                 *FAST]) == 0


def test_help_gives_units(capsys):
    assert main(["raytrace", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    for needle in ("Object size 2*h0 [m]", "in front of the main lens [m]", "[count, >= 1",
                   "[dots per inch", "--use-device-positions", "max-magnification"):
        assert needle in text
