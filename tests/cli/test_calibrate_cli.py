import json

import pytest

from lfring.calibration import RingCalibration
from lfring.cli.main import main
from lfring.cli.synth import write_render
from lfring.synth import render
from lfring.synth.presets import flat_scene, target_scene


@pytest.fixture(scope="module")
def files(tmp_path_factory, prototype):
    d = tmp_path_factory.mktemp("cal")
    for z in (0.3, 1.0):
        write_render(render(prototype, target_scene(prototype, z), binning=4, noise="realistic"), d / f"t{z}.png")
    write_render(render(prototype, flat_scene(prototype), binning=4, noise="low"), d / "flat.png")
    return d


def test_calibrate_cli(files, tmp_path, capsys):
    out = tmp_path / "cal.json"
    args = ["calibrate", str(files / "t0.3.png"), str(files / "t1.0.png"), "--depths", "0.3", "1.0",
            "--flat", str(files / "flat.png"), "--device", "prototype", "-o", str(out)]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "view 3 px" in text and "alignment" in text
    cal = RingCalibration.load(out)
    assert cal.raw_size == (1228, 920) and cal.valid_depth_range_m == (0.3, 1.0)
    assert cal.depth_origin_m == pytest.approx(0.02798, abs=1e-5)
    assert json.loads(out.read_text())["provenance"]["depth_origin"].startswith("optics")
    assert main(args) == 0  # the same calibration again replaces its own file
    capsys.readouterr()
    assert main([*args, "--rank1"]) == 2  # other settings: no overwrite
    assert "exists" in capsys.readouterr().err
    # Comma-separated depths work too.
    assert main([*args[:3], "--depths", "0.3,1.0", *args[6:], "--overwrite"]) == 0


@pytest.mark.parametrize(
    "extra, match",
    [
        (["--depths", "0.3"], "2 frame\\(s\\) but 1 depth"),
        (["--depths", "0.3", "0.3"], "distinct"),
        (["--depths", "0.3", "0"], "positive"),
        (["--depths", "0.3", "1.0", "--depth-origin", "optics"], "needs --device"),
        (["--depths", "0.3", "1.0", "--depth-origin", "far"], "auto, optics or metres"),
    ],
)
def test_calibrate_cli_errors(files, tmp_path, capsys, extra, match):
    import re

    args = ["calibrate", str(files / "t0.3.png"), str(files / "t1.0.png"), *extra, "-o", str(tmp_path / "c.json")]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert re.search(match, err) and "Traceback" not in err


def test_calibrate_refuses_a_frame_that_is_not_a_target(files, tmp_path, capsys):
    """What the user did: a frame that is not a planar target (here a scene with depth) at one
    of the depths. The residuals give it away: refused, nothing written, unless --force."""
    import subprocess
    import sys
    from pathlib import Path

    data = Path(__file__).resolve().parents[2] / "data" / "synthetic"
    out = tmp_path / "cal.json"
    cmd = [sys.executable, "-m", "lfring", "calibrate", str(data / "part_good.png"), str(data / "target_1m.png"),
           "--depths", "0.3", "1.0", "--flat", str(data / "flat.png"), "--device", "prototype", "-o", str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 2 and "does not look like a planar target" in proc.stderr and "--force" in proc.stderr
    assert "part_good.png" in proc.stderr and not out.exists()
    assert "--force" in subprocess.run([*cmd[:4], "--help"], capture_output=True, text=True, timeout=120).stdout


def _calibrate_args(files, out, *extra):
    return ["calibrate", str(files / "t0.3.png"), str(files / "t1.0.png"), "--flat", str(files / "flat.png"),
            "--device", "prototype", "-o", str(out), *extra]


def test_calibrate_output_must_end_in_json(files, tmp_path, capsys):
    """What the user did: -o scene.png --overwrite. The calibration is JSON: a name that does not
    end in .json is refused before any work, and the file of that name is left as it was."""
    scene = tmp_path / "scene.png"
    scene.write_bytes(b"not a calibration")
    assert main(_calibrate_args(files, scene, "--depths", "0.3", "1.0", "--overwrite")) == 2
    err = capsys.readouterr().err
    assert "Invalid value for -o: the calibration file must end in .json, got 'scene.png'" in err
    assert scene.read_bytes() == b"not a calibration" and sorted(p.name for p in tmp_path.iterdir()) == ["scene.png"]
    # grid-calib writes a calibration too, by the same rule.
    assert main(["grid-calib", "--size", "30x20", "--disparity-scale", "2", "-o", str(tmp_path / "pair.txt")]) == 2
    assert "must end in .json, got 'pair.txt'" in capsys.readouterr().err
    assert not (tmp_path / "pair.txt").exists()


@pytest.mark.parametrize("copy", [False, True], ids=["same-path", "same-content"])
def test_calibrate_refuses_the_same_frame_for_two_depths(files, tmp_path, capsys, copy):
    """What the user did: one frame given for 0.3 m and 1.0 m. Refused as that, not as swapped
    depths, whether the same path is given twice or a copy of the file."""
    import shutil

    first = files / "t0.3.png"
    second = first
    if copy:
        second = tmp_path / "copy.png"
        shutil.copy(first, second)
        shutil.copy(files / "t0.3.png.json", tmp_path / "copy.png.json")
    out = tmp_path / "cal.json"
    args = ["calibrate", str(first), str(second), "--depths", "0.3", "1.0", "--flat", str(files / "flat.png"),
            "--device", "prototype", "-o", str(out)]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "the same frame is given for 0.3 m and 1.0 m" in err and "swapped" not in err
    assert str(second) in err and not out.exists()


def test_calibrate_refuses_millimetres_given_as_metres(files, tmp_path, capsys):
    """What the user did: --depths 300 1000 (millimetres) with --device prototype. By the
    device's optics planes at 300 m and beyond lie too far to tell from infinity (the rule lfring
    inspect refuses such a --plane by), yet the frames show them near: refused, nothing written."""
    out = tmp_path / "cal.json"
    assert main(_calibrate_args(files, out, "--depths", "300", "1000")) == 2
    err = capsys.readouterr().err
    assert "the optics of device 'prototype'" in err and "given as 300 m" in err and "not mm" in err
    assert "Traceback" not in err and not out.exists()
    # One depth in millimetres among metres cannot be told from a distant plane (a valid plane at
    # infinity): written, with a warning that says what it may be.
    assert main(_calibrate_args(files, out, "--depths", "0.3", "1000")) == 0 and out.exists()
    err = capsys.readouterr().err
    assert "the farthest plane is given as 1000 m" in err and "if 1000 was millimetres, give 1" in err


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--depths", "0.3", "1.0", "--depth-origin", "0.5"],
         "--depth-origin (0.5) must be finite and in front of the nearest plane (0.3 m)"),
        (["--depths", "0.3", "1.0", "--depth-origin", "nan"], "--depth-origin (nan) must be finite"),
        (["--depths", "0.3", "0.3"], "Invalid value for --depths: each frame needs its own depth"),
        (["--depths", "0.3", "0"],
         "Invalid value for --depths: expected a positive number of metres for each frame, got 0.3 0"),
        (["--depths", "0.3", "abc"], "Invalid value for --depths: expected a number of metres for each frame, got '0.3 abc'"),
        (["nope.png", "--depths", "0.3", "1.0", "0.5"], "Invalid value for FRAMES: no such file: nope.png"),
        (["--depths", "0.3", "1.0", "--flat", "{files}/t0.3.png"], "error: --flat {files}/t0.3.png: the frame is not a flat field"),
    ],
)
def test_calibrate_errors_name_the_options(files, tmp_path, capsys, extra, message):
    """The command's messages name its options, never the Python parameters behind them, and
    refuse before any frame is read."""
    out = tmp_path / "c.json"
    extra = [e.format(files=files) for e in extra]
    assert main(["calibrate", str(files / "t0.3.png"), str(files / "t1.0.png"), *extra, "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert message.format(files=files) in err and "depth_origin_m" not in err and "[0.3" not in err and not out.exists()


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--disparity-scale", "0"], "--disparity-scale must not be 0"),
        (["--disparity-scale", "nan"], "--disparity-scale must be a number (finite), got nan"),
        (["--disparity-scale", "2", "--disparity-offset", "inf"], "--disparity-offset must be a number (finite)"),
        (["--disparity-scale", "2", "--depth-origin", "nan"], "--depth-origin must be a number (finite)"),
        (["--disparity-scale", "2", "--size", "30"], "Invalid value for --size: expected WxH"),
        (["--disparity-scale", "2", "--positions", ""], "Invalid value for --positions: expected X,Y grid positions"),
        (["--disparity-scale", "2", "--positions", "0,0,1 1,0"], "Invalid value for --positions: expected X,Y"),
    ],
)
def test_grid_calib_errors_name_the_options(tmp_path, capsys, extra, message):
    out = tmp_path / "g.json"
    size = [] if "--size" in extra else ["--size", "30x20"]
    assert main(["grid-calib", *size, *extra, "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and not out.exists()
    python_names = ("disparity_scale_px_m", "disparity_offset_px", "depth_origin_m", "grid_positions")
    assert not any(name in err for name in python_names)


def test_calibrate_warns_of_a_depth_the_optics_contradict(files, tmp_path, capsys):
    """The frame of the plane at 1.0 m given as 0.7 m (its distance measured from the wrong
    point): two planes fit whatever their depths, but by the device's optics the views move
    less between 0.3 and 0.7 m than the frames show them moving. Written, with a warning that
    names the planes, the frames and both motions; the right depths draw no such warning (nor
    at another binning, whose layout the optics cut otherwise: the motion between two planes
    does not depend on it)."""
    import re

    from lfring.calibration.model import view_motion_px

    out = tmp_path / "cal.json"
    assert main(_calibrate_args(files, out, "--depths", "0.3", "1.0")) == 0
    assert "the views move" not in capsys.readouterr().err
    true_px = view_motion_px(RingCalibration.load(out), [0.3, 1.0], RingCalibration.load(out).layout.view_shape)
    assert main(_calibrate_args(files, out, "--depths", "0.3", "0.7", "--overwrite")) == 0 and out.exists()
    err = capsys.readouterr().err
    found = re.search(r"between the planes given as 0\.3 m and 0\.7 m \((.*?), (.*?)\) the views move ([0-9.]+) px, "
                      r"where those depths move them ([0-9.]+) px", err)
    assert found, err
    assert found.group(1).endswith("t0.3.png") and found.group(2).endswith("t1.0.png")
    seen, said = float(found.group(3)), float(found.group(4))
    assert seen == pytest.approx(true_px, abs=0.06) and seen / said > 1.15


def test_calibrate_a_camera_that_writes_its_frames_rotated(prototype, tmp_path, capsys):
    """A camera that writes its frames turned 180 degrees: calibrate had no --rotate180, and a
    --layout that records the rotation ruled out --flat. With --rotate180 the layout detected on
    the flat records it, and the planes fit as the upright camera's do."""
    for name, scene in (("t0.3", target_scene(prototype, 0.3)), ("t1.0", target_scene(prototype, 1.0)),
                        ("flat", flat_scene(prototype))):
        write_render(render(prototype, scene, binning=4, noise="low", rotate180=True), tmp_path / f"{name}.png")
    out = tmp_path / "cal.json"
    args = ["calibrate", str(tmp_path / "t0.3.png"), str(tmp_path / "t1.0.png"), "--depths", "0.3", "1.0",
            "--flat", str(tmp_path / "flat.png"), "--device", "prototype", "-o", str(out)]
    assert main([*args, "--rotate180"]) == 0, capsys.readouterr().err
    cal = RingCalibration.load(out)
    assert cal.layout.rotate180 and max(p.residual_px.max() for p in cal.planes) < 1e-9
    assert max(max(d["alignment_residual_px"]) for d in cal.provenance["planes"]) < 0.05
    assert "the views move" not in capsys.readouterr().err
    cal.layout.save(tmp_path / "layout.json")
    assert main(["calibrate", *args[1:6], "--layout", str(tmp_path / "layout.json"), "--rotate180", "-o",
                 str(tmp_path / "b.json")]) == 2
    assert "--rotate180 goes with --flat or detection" in capsys.readouterr().err


def test_two_planes_without_a_device_name_the_built_in_calibration_s(tmp_path, capsys):
    """Without --device two planes take z0 = 0; the built-in calibration of these frames names a
    device whose optics would give it, and the warning says which (with --device, no word)."""
    from pathlib import Path

    data = Path(__file__).resolve().parents[2] / "data" / "synthetic"
    args = ["calibrate", str(data / "target_0.3m.png"), str(data / "target_1m.png"), "--depths", "0.3", "1.0", "--flat",
            str(data / "flat.png")]
    assert main([*args, "-o", str(tmp_path / "plain.json")]) == 0
    err = " ".join(capsys.readouterr().err.split())
    assert "the built-in calibration 'twin_binned2' names the device 'prototype': if these frames are that camera's, " \
           "--device prototype gives z0 from its optics instead of 0" in err
    assert RingCalibration.load(tmp_path / "plain.json").depth_origin_m == 0.0
    assert main([*args, "--device", "prototype", "-o", str(tmp_path / "optics.json")]) == 0
    assert "names the device" not in capsys.readouterr().err


def test_three_planes_with_z0_fitted_print_no_leave_one_out(tmp_path, capsys):
    """Three planes and z0 fitted fit any three depths: the leave-one-out column read 0.004 px
    with a plane 1 cm off as with the right depths. It is not printed, and a line says why."""
    from pathlib import Path

    data = Path(__file__).resolve().parents[2] / "data" / "synthetic"
    out = tmp_path / "cal.json"
    args = ["calibrate", *(str(data / f"target_{z}.png") for z in ("0.3m", "0.5m", "1m")), "--depths", "0.3", "0.5",
            "1.0", "--flat", str(data / "flat.png"), "-o", str(out)]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "leave-one-out not measured: z0 fitted to three planes fits any three depths" in text
    assert "leave-one-out px" not in text
    assert all(p["leave_one_out_px"] is None for p in json.loads(out.read_text())["planes"])
