import json

import numpy as np
import pytest
import tifffile

from lfring.cli.main import main
from lfring.io.raw import load_raw
from lfring.optics import load_device
from lfring.optics.views import optical_homographies
from lfring.views import Layout


def test_synth_target_writes_raw_sidecar_and_truth(tmp_path, capsys, monkeypatch):
    args = ["synth", "target", "--depth", "0.5", "--binning", "8", "-o", str(tmp_path), "--seed", "3"]
    assert main(args) == 0
    raw = tmp_path / "target_0.5m.png"
    frame = load_raw(raw)  # pattern and levels come from the sidecar
    assert frame.pattern == "RGGB" and frame.black_level == 64 and frame.white_level == 4095
    assert frame.mosaic.shape == (460, 614)
    truth = json.loads((tmp_path / "target_0.5m_truth" / "truth.json").read_text())
    assert truth["ring_distance_m"] == pytest.approx(37.369e-3, abs=1e-6)
    assert truth["sensor_distance_m"] == pytest.approx(6.616e-3, abs=1e-6)
    depth = tifffile.imread(tmp_path / "target_0.5m_truth" / "depth_view2.tiff")
    assert depth.dtype == np.float32 and np.nanmax(np.abs(depth - 0.5)) < 1e-6
    # The stored model A + B / (Z - z0) gives the exact homographies at any depth.
    model = truth["homography_model"]["references"]["center"]
    a, b, z0 = np.array(model["A"]), np.array(model["B"]), model["depth_origin_m"]
    dev = load_device("prototype").binned(8)
    lay = Layout.from_dict(truth["layout"])
    for z in (0.31, 0.77, 3.0):
        np.testing.assert_allclose(a + b / (z - z0), optical_homographies(dev, lay, z), atol=1e-9)
    # The same run again replaces its own files with the same ones; a run with other settings
    # refuses to overwrite, names the file, and leaves it alone.
    before = raw.read_bytes()
    assert main(args) == 0 and raw.read_bytes() == before
    capsys.readouterr()
    other = [*args[:-1], "4"]  # another --seed
    import lfring.synth

    rendered = []
    render = lfring.synth.render
    monkeypatch.setattr(lfring.synth, "render", lambda *a, **k: rendered.append(1) or render(*a, **k))
    assert main(other) == 2
    assert "exists" in capsys.readouterr().err
    assert raw.read_bytes() == before
    assert rendered == []  # refused before any rendering
    assert main([*other, "--overwrite"]) == 0
    assert rendered == [1]
    assert raw.read_bytes() != before


def test_synth_part_and_scene_file(tmp_path, capsys):
    assert main(["synth", "part", "--binning", "8", "--defects", "none", "-o", str(tmp_path)]) == 0
    truth = json.loads((tmp_path / "part_good_truth" / "truth.json").read_text())
    part = [s for s in truth["scene"]["surfaces"] if s["type"] == "HeightField"][0]
    assert part["bumps"] == []
    assert main(["synth", "part", "--binning", "8", "--defects", "0.02,-0.01", "-o", str(tmp_path)]) == 0
    truth = json.loads((tmp_path / "part_defects_truth" / "truth.json").read_text())
    part = [s for s in truth["scene"]["surfaces"] if s["type"] == "HeightField"][0]
    assert sorted(b["height_m"] for b in part["bumps"]) == [-0.01, 0.02]

    scene = tmp_path / "two.toml"
    scene.write_text(
        'name = "two"\n[[plane]]\ndepth_m = 0.4\nsize_m = [0.3, 0.3]\ntexture = { kind = "image", name = "astronaut" }\n'
        '[[part]]\ndepth_m = 0.35\nsize_m = [0.02, 0.02]\ntexture = { kind = "checker", square_m = 0.005 }\n'
        '[[part.bump]]\ncenter_m = [0.01, 0.01]\nsize_m = [0.01, 0.01]\nheight_m = 0.003\n'
    )
    assert main(["synth", "file", "--scene", str(scene), "--binning", "8", "--pattern", "none", "-o", str(tmp_path)]) == 0
    frame = load_raw(tmp_path / "two.png")
    assert frame.image is not None and frame.image.shape == (460, 614, 3)
    depth = tifffile.imread(tmp_path / "two_truth" / "depth_view0.tiff")
    assert np.nanmin(depth) == pytest.approx(0.347, abs=1e-4)  # the bump top at 0.35 - 0.003


def test_synth_hard_with_conventional_images(tmp_path):
    args = ["synth", "hard", "--binning", "8", "--noise", "none", "-o", str(tmp_path),
            "--conventional-focus", "0.5", "--conventional-focus", "1", "--f-number", "4"]
    assert main(args) == 0
    truth = tmp_path / "hard_truth"
    doc = json.loads((truth / "truth.json").read_text())
    assert doc["settings"]["view_falloff"][3] == [0.9, 0.1, 0.25]
    assert {s["name"] for s in doc["scene"]["surfaces"]} >= {"diagonal wire", "curved part", "textureless card"}
    from lfring.synth import render_conventional
    from lfring.synth.presets import hard_scene

    for z in ("0.5", "1"):
        img = tifffile.imread(truth / f"conventional_{z}m_f4.tiff")
        meta = json.loads((truth / f"conventional_{z}m_f4.json").read_text())
        assert img.dtype == np.float32 and img.shape == (176, 176, 3)
        assert meta["aperture_radius_m"] == pytest.approx(0.002) and meta["reference"] == "center"
        want = render_conventional(hard_scene(), load_device("prototype"), float(z), f_number=4, binning=8,
                                   samples=meta["samples"])
        np.testing.assert_array_equal(img, want)
        assert (truth / f"conventional_{z}m_f4.png").stat().st_size > 1000
    # Without the options, nothing conventional is written; the same run again replaces its own
    # files, a run with other settings refuses to overwrite them.
    assert main(args) == 0
    assert main([*args[:-1], "2.8"]) == 2


@pytest.mark.parametrize(
    "text, match",
    [
        ("[[plane]]\ndepth_m = 0.4\nsize_m = [0.3, 0.3]\ncolour = 1\n", "unknown key.*'colour'"),
        ("[[plane]]\ndepth_m = -0.4\nsize_m = [0.3, 0.3]\n", "depth_m"),
        ("[[plane]]\ndepth_m = 0.4\n", "size_m"),
        ("[[plane]\n", "not a valid TOML"),
        ("[[plane]]\ndepth_m = 0.4\nsize_m = [0.3, 0.3]\ntexture = { kind = 'image', name = 'lena' }\n", "lena"),
    ],
)
def test_bad_scene_files(tmp_path, capsys, text, match):
    scene = tmp_path / "bad.toml"
    scene.write_text(text)
    assert main(["synth", "file", "--scene", str(scene), "--binning", "8", "-o", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    import re

    assert re.search(match, err), err


@pytest.mark.parametrize(
    "args",
    [
        ["target", "--binning", "8"],
        ["scene", "--depth", "0.5"],
        ["part", "--defects", "abc"],
        ["file"],
        ["scene", "--binning", "0"],
        ["scene", "--f-number", "4"],
        ["scene", "--conventional-focus", "0.5", "--f-number", "4", "--aperture-scale", "1"],
        ["scene", "--conventional-focus", "0.01"],
        ["scene", "--conventional-focus", "0.5", "--f-number", "-2"],
    ],
)
def test_synth_usage_errors(tmp_path, capsys, args):
    assert main(["synth", *args, "-o", str(tmp_path)]) == 2
    assert "Traceback" not in capsys.readouterr().err


@pytest.mark.parametrize(
    "args, option, words",
    [
        (["part", "--defect-size", "12"], "--defect-size", ["<= 0.0533333", "for 12 mm give --defect-size 0.012"]),
        (["part", "--defect-size", "0"], "--defect-size", ["> 0 and <= 0.0533333"]),
        (["part", "--defects", "0.2"], "--defects", ["bump height 0.2 m", "--part-depth 0.3 m"]),
        (["part", "--defects", "15,-15"], "--defects", ["for 15,-15 mm give --defects 0.015,-0.015"]),
        (["part", "--defects", "abc"], "--defects", ["comma-separated heights in metres"]),
        (["part", "--defect-size", "0.05", "--defects", "0.01,0.01,0.01,0.01"], "--defects",
         ["give fewer --defects or a smaller --defect-size"]),
        (["part", "--part-depth", "-1"], "--part-depth", ["must be a distance in metres > 0"]),
        (["scene", "--binning", "0"], "--binning", ["must be an integer >= 1, got 0"]),
        (["scene", "--exposure", "5"], "--exposure", ["must be a number > 0 and <= 4"]),
        (["scene", "--gain", "-1"], "--gain", ["must be a number > 0"]),
        (["target", "--depth", "-1"], "--depth", ["must be a distance in metres > 0"]),
        (["target", "--depth", "0.01"], "--depth", ["too close to the camera"]),
        (["scene", "--conventional-focus", "0"], "--conventional-focus", ["beyond the views' entrance pupil"]),
        (["scene", "--conventional-focus", "0.5", "--conventional-samples", "0"], "--conventional-samples",
         ["must be an integer >= 1, got 0"]),
        (["target", "--depth", "0.5", "--conventional-focus", "0.5", "--f-number", "0.1"], "--f-number",
         ["must be an f-number >= 0.5", "got 0.1"]),
        (["scene", "--conventional-focus", "0.5", "--aperture-scale", "-1"], "--aperture-scale", ["must be a number >= 0"]),
    ],
)
def test_synth_refusals_name_the_option(tmp_path, capsys, args, option, words):
    """A bad value is refused before any rendering (nothing written), as a usage error that
    names its option and says what is valid, in the command line's words, not Python's."""
    import re

    out = tmp_path / "out"
    assert main(["synth", *args, "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert re.search(rf"Invalid value for '?{option}'?: ", err), err
    for w in words:
        assert w in err, err
    for python_name in ("Traceback", "focus_m", "f_number", "aperture_scale", "depth_m", "samples must", "binning must",
                        "gain must", "exposure must", "target depth must", "defect size must"):
        assert python_name not in err, err
    assert not out.exists()


def test_a_device_without_lens_positions_is_refused_as_the_device(tmp_path, capsys):
    """A device file without b and c cannot be rendered: refused naming --device and saying how
    to get them (it was refused as "Invalid value for --depth", the first option to need them)."""
    import dataclasses

    from lfring.optics import load_device, save_device

    dev = dataclasses.replace(load_device("prototype"), name="mine", ring_distance_m=None, sensor_distance_m=None)
    path = save_device(dev, tmp_path / "mine.toml")
    out = tmp_path / "out"
    assert main(["synth", "target", "--depth", "0.5", "--device", str(path), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "Invalid value for --device: device 'mine' has no lens positions to render with: add its ring_distance_m " \
           "and sensor_distance_m" in err and "--depth" not in err
    assert not out.exists()
