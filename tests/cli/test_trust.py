"""Issue 13: verdicts and outputs a user can trust. Each test names the finding it pins: the
command refuses or warns, with its exit code, one line and no traceback, and writes nothing
where it refuses."""

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from lfring.cli.main import main

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "data" / "synthetic"
SCENE = DATA / "scene.png"
# Where what is judged is how a frame is read or what the command says, not the refocusing method,
# shift-and-add spares a depth map of the full-size frame a call.
SAA = ("--method", "shift-and-add")


def _photo(path: Path) -> Path:
    """An ordinary RGB photograph at the sensor's size (scikit-image's astronaut, scaled)."""
    from skimage import data

    img = cv2.resize(data.astronaut(), (2456, 1842), interpolation=cv2.INTER_CUBIC)
    cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    return path


def _calibration_without_levels(folder: Path) -> Path:
    """The built-in calibration's copy that records no Bayer pattern and no levels."""
    cal = json.loads((ROOT / "calib" / "twin_binned2.json").read_text())
    for key in ("bayer_pattern", "black_level", "white_level"):
        del cal[key]
    path = folder / "cal_without_levels.json"
    path.write_text(json.dumps(cal))
    return path


def _one_error(err: str, text: str) -> None:
    assert "Traceback" not in err
    lines = [line for line in err.splitlines() if line.startswith("lfring: error:")]
    assert len(lines) == 1 and text in lines[0], err


def test_photograph_refused_not_ghosted(tmp_path, capsys):
    photo = _photo(tmp_path / "photo.png")
    out = tmp_path / "out.png"
    assert main(["refocus", str(photo), "--depth", "0.5", "-o", str(out)]) == 2
    _one_error(capsys.readouterr().err, "do not agree")
    assert not out.exists() and not Path(str(out) + ".json").exists()
    # --no-check processes it anyway (the user's call).
    assert main(["refocus", str(photo), "--depth", "0.5", "-o", str(out), "--no-check"]) == 0
    assert out.exists()


def test_photograph_refused_by_depth(tmp_path, capsys):
    photo = _photo(tmp_path / "photo.png")
    out = tmp_path / "o"
    assert main(["depth", str(photo), "--zmin", "0.3", "--zmax", "1.0", "-o", str(out)]) == 2
    _one_error(capsys.readouterr().err, "do not agree")
    assert not out.exists()


def test_photograph_cannot_be_judged_by_inspect(tmp_path, capsys):
    """For the inspection line an unrelated frame is a verdict, not a usage error: exit 3 with
    the reason, and the report written."""
    photo = _photo(tmp_path / "photo.png")
    out = tmp_path / "o"
    assert main(["inspect", str(photo), "--plane", "0.3", "--tolerance", "0.01", "-o", str(out)]) == 3
    assert "Traceback" not in capsys.readouterr().err
    report = json.loads((out / "photo_inspect.json").read_text())
    assert report["verdict"] == "cannot_judge" and report["reason"]
    assert (out / "photo_inspect.png").exists()


def test_check_command(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["check", str(SCENE)]) == 0
    text = capsys.readouterr().out
    assert "2456 x 1842 px, Bayer RGGB, 12 bits" in text and "black 64 white 4095" in text
    assert "verdict      ring frame" in text
    overlay = cv2.imread(str(tmp_path / "scene_check.png"))
    assert overlay.shape == (1842, 2456, 3)
    photo = _photo(tmp_path / "photo.png")
    assert main(["check", str(photo)]) == 1
    assert "NOT a ring frame" in capsys.readouterr().out


@pytest.mark.filterwarnings("always::lfring.errors.LfringWarning")
def test_depth_beyond_overlap_refused_with_nearest_that_works(tmp_path, capsys):
    out = tmp_path / "z.png"
    assert main(["refocus", str(SCENE), "--depth", "0.028", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    _one_error(err, "cannot be rendered")
    assert "nearest depth that works with this calibration is 0.0369 m" in err
    assert not out.exists()
    # The depth it names renders: most of the image is lit, not black.
    assert main(["refocus", str(SCENE), "--depth", "0.0369", "-o", str(out)]) == 0
    img = cv2.imread(str(out))
    assert (img.max(axis=2) > 10).mean() > 0.2


@pytest.mark.filterwarnings("always::lfring.errors.LfringWarning")
def test_depth_inf_and_stack(tmp_path, capsys):
    out = tmp_path / "inf.png"
    assert main(["refocus", str(SCENE), "--depth", "inf", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "depth inf is outside the calibrated range" in err
    assert json.loads(Path(str(out) + ".json").read_text())["depth_m"] == "inf"
    # At infinity the model is H = A: the same image as a very far depth.
    far = tmp_path / "far.png"
    assert main(["refocus", str(SCENE), "--depth", "1e6", "-o", str(far)]) == 0
    a, b = cv2.imread(str(out)).astype(int), cv2.imread(str(far)).astype(int)
    assert np.abs(a - b).max() <= 1


def test_sidecar_with_only_pattern_warns_levels_assumed(tmp_path, capsys):
    # A calibration that records no levels (the built-in one's copy without them): nothing gives them.
    frame = tmp_path / "s.png"
    shutil.copyfile(SCENE, frame)
    (tmp_path / "s.png.json").write_text(json.dumps({"pattern": "RGGB"}))
    calib = ("--calib", str(_calibration_without_levels(tmp_path)))
    assert main(["refocus", str(frame), "--depth", "0.5", *SAA, *calib, "-o", str(tmp_path / "o.png")]) == 0
    err = capsys.readouterr().err
    assert "levels assumed (black 0, white 65535)" in err and "--black-level and --white-level" in err
    assert "pass --white-level 4095" in err  # 12-bit counts in a 16-bit PNG
    # The options fix it: the same image as with the full sidecar, and no warning.
    assert main(["refocus", str(frame), "--depth", "0.5", *SAA, *calib, "-o", str(tmp_path / "p.png"), "--black-level",
                 "64", "--white-level", "4095"]) == 0
    assert "WARNING" not in capsys.readouterr().err
    assert main(["refocus", str(SCENE), "--depth", "0.5", *SAA, *calib, "-o", str(tmp_path / "q.png")]) == 0
    np.testing.assert_array_equal(cv2.imread(str(tmp_path / "p.png")), cv2.imread(str(tmp_path / "q.png")))


@pytest.mark.parametrize("sidecar", [None, {"pattern": "RGGB"}], ids=["no sidecar", "sidecar with the pattern only"])
def test_the_builtin_calibration_picked_for_a_frame_gives_its_pattern_and_levels(tmp_path, capsys, sidecar):
    # A frame without its sidecar (or with a partial one) and no --calib: the built-in calibration
    # picked by the frame's size gives what the frame lacks, as a named one does. It was picked
    # only after the frame was read, so the frame was refused for want of a pattern or read with
    # the levels 0 and 65535 (an image four times too dark, said to be "assumed" as no
    # calibration gave them).
    frame = tmp_path / "bare.png"
    shutil.copyfile(SCENE, frame)
    if sidecar is not None:
        (tmp_path / "bare.png.json").write_text(json.dumps(sidecar))
    assert main(["refocus", str(frame), "--depth", "0.5", *SAA, "-o", str(tmp_path / "a.png")]) == 0
    err = capsys.readouterr().err
    assert "using the built-in calibration 'twin_binned2'" in err
    assert "black level 64.0, white level 4095.0)" in err and "WARNING" not in err
    assert main(["refocus", str(SCENE), "--depth", "0.5", *SAA, "-o", str(tmp_path / "b.png")]) == 0
    np.testing.assert_array_equal(cv2.imread(str(tmp_path / "a.png")), cv2.imread(str(tmp_path / "b.png")))
    capsys.readouterr()
    assert main(["check", str(frame), "-o", str(tmp_path / "c.png")]) == 0
    out = capsys.readouterr().out
    assert "Bayer RGGB" in out and "black 64 white 4095 counts" in out
    # lfring split detects its layout, but takes the pattern and levels by the same rule.
    assert main(["split", str(frame), "-o", str(tmp_path / "s1")]) == 0
    assert main(["split", str(SCENE), "-o", str(tmp_path / "s2")]) == 0
    for k in range(4):
        np.testing.assert_array_equal(cv2.imread(str(tmp_path / "s1" / f"bare_view{k}.png"), cv2.IMREAD_UNCHANGED),
                                      cv2.imread(str(tmp_path / "s2" / f"scene_view{k}.png"), cv2.IMREAD_UNCHANGED))


def test_sidecarless_bayer_tiff_with_raw_options(tmp_path, capsys):
    import tifffile

    mosaic = cv2.imread(str(SCENE), cv2.IMREAD_UNCHANGED)
    tif = tmp_path / "bare.tiff"
    tifffile.imwrite(tif, mosaic)
    # Neither the frame nor the calibration (one that records no pattern) gives a pattern: refused.
    bare_cal = _calibration_without_levels(tmp_path)
    assert main(["refocus", str(tif), "--depth", "0.5", *SAA, "--calib", str(bare_cal), "-o", str(tmp_path / "a.png")]) == 2
    _one_error(capsys.readouterr().err, "no Bayer pattern")
    assert main(["refocus", str(tif), "--depth", "0.5", *SAA, "--calib", str(bare_cal), "-o", str(tmp_path / "a.png"),
                 "--pattern", "rggb", "--black-level", "64", "--white-level", "4095"]) == 0
    assert main(["refocus", str(SCENE), "--depth", "0.5", *SAA, "-o", str(tmp_path / "b.png")]) == 0
    np.testing.assert_array_equal(cv2.imread(str(tmp_path / "a.png")), cv2.imread(str(tmp_path / "b.png")))
    # The built-in calibration picked by the frame's size gives them.
    assert main(["refocus", str(tif), "--depth", "0.5", *SAA, "-o", str(tmp_path / "c.png")]) == 0
    np.testing.assert_array_equal(cv2.imread(str(tmp_path / "c.png")), cv2.imread(str(tmp_path / "b.png")))


@pytest.mark.parametrize("name", ["refocus", "depth", "inspect", "batch", "check", "split", "calibrate"])
def test_every_frame_reader_has_raw_options(name):
    import importlib

    cmd = importlib.import_module(f"lfring.cli.{name}").command
    opts = {o for p in cmd.params for o in p.opts}
    assert {"--pattern", "--black-level", "--white-level"} <= opts
    if name in ("refocus", "depth", "inspect", "batch"):
        assert "--no-check" in opts


def test_output_parent_is_a_file(tmp_path, capsys):
    blocker = tmp_path / "hostname"
    blocker.write_text("x\n")
    assert main(["refocus", str(SCENE), "--depth", "0.5", "-o", str(blocker / "out.png")]) == 2
    _one_error(capsys.readouterr().err, f"cannot write {blocker / 'out.png'}: {blocker} is a file, not a folder")
    assert blocker.read_text() == "x\n"


def test_unwritable_folder_names_the_users_path(tmp_path, capsys, monkeypatch):
    import tempfile

    def denied(*args, dir=None, **kwargs):
        raise PermissionError(13, "Permission denied", str(Path(dir) / ".out.abc.part.png"))

    monkeypatch.setattr(tempfile, "mkstemp", denied)
    out = tmp_path / "ro" / "out.png"
    assert main(["refocus", str(SCENE), "--depth", "0.5", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    _one_error(err, f"Permission denied: {out}")
    assert ".part" not in err


def test_calibrate_refuses_swapped_depths_and_remembers_device_and_levels(tmp_path, capsys):
    t03, t1 = DATA / "target_0.3m.png", DATA / "target_1m.png"
    out = tmp_path / "cal.json"
    common = ["--flat", str(DATA / "flat.png"), "--device", "prototype", "-o", str(out)]
    assert main(["calibrate", str(t03), str(t1), "--depths", "1.0", "0.3", *common]) == 2
    err = capsys.readouterr().err
    _one_error(err, "look swapped")
    assert "target_1m.png" in err and not out.exists()
    assert main(["calibrate", str(t03), str(t1), "--depths", "0.3", "1.0", *common]) == 0
    data = json.loads(out.read_text())
    assert data["device"] == "prototype" and data["bayer_pattern"] == "RGGB"
    assert data["black_level"] == 64 and data["white_level"] == 4095
    # A frame without a sidecar is read with the calibration's pattern and levels, and says so.
    bare = tmp_path / "bare.png"
    shutil.copyfile(SCENE, bare)
    capsys.readouterr()
    assert main(["refocus", str(bare), "--depth", "0.5", *SAA, "--calib", str(out), "-o", str(tmp_path / "a.png")]) == 0
    err = capsys.readouterr().err
    assert "using the calibration's (pattern RGGB, black level 64.0, white level 4095.0)" in err
    assert "WARNING" not in err
    assert main(["refocus", str(SCENE), "--depth", "0.5", *SAA, "--calib", str(out), "-o", str(tmp_path / "b.png")]) == 0
    np.testing.assert_array_equal(cv2.imread(str(tmp_path / "a.png")), cv2.imread(str(tmp_path / "b.png")))


def test_batch_over_the_sample_folder_skips_what_is_not_a_frame_and_adds_outputs(tmp_path, capsys):
    out = tmp_path / "x"
    args = ["batch", str(DATA), "-o", str(out), "--exclude", "flat*", "--workers", "1", *SAA]
    assert main([*args, "--refocus", "0.5"]) == 0
    cap = capsys.readouterr()
    frames = sum(1 for p in DATA.glob("*.png") if not p.name.startswith("flat"))  # 7 with the hard scene
    assert f"{frames} frames: {frames} done, 0 skipped (already done), 0 failed" in cap.out
    # Left out in one line: at least every frame's sidecar and ground-truth folder.
    left_out = re.search(r"(\d+) files that are not frames left out \(-v lists them\)", cap.out)
    assert left_out and int(left_out.group(1)) >= 2 * frames
    assert "Traceback" not in cap.err and "ERROR" not in cap.err
    before = {p.name: p.read_bytes() for p in out.glob("*_refocus_0.5m.png")}
    assert len(before) == frames
    # Another depth on the finished run: only the new outputs are computed.
    assert main(["-v", *args, "--refocus", "0.5,0.7"]) == 0
    cap = capsys.readouterr()
    assert f"{frames} frames: {frames} done" in cap.out and "not a frame: " in cap.err and "scene_truth" in cap.err
    lines = [json.loads(x) for x in (out / "manifest.jsonl").read_text().splitlines()]
    assert {tuple(e["outputs"]) for e in lines[-frames:]} == {(f"{p.stem}_refocus_0.7m.png",) for p in DATA.glob("*.png")
                                                         if not p.name.startswith("flat")}
    assert {p.name: p.read_bytes() for p in out.glob("*_refocus_0.5m.png")} == before
    assert main([*args, "--refocus", "0.7", "-q"]) == 0
    assert f"{frames} skipped" in capsys.readouterr().out


def test_batch_failure_printed_once(tmp_path, capsys):
    root = tmp_path / "in"
    root.mkdir()
    (root / "bad.png").write_bytes(b"not a png")
    assert main(["batch", str(root), "-o", str(tmp_path / "out"), "--refocus", "0.5", "--workers", "1"]) == 1
    cap = capsys.readouterr()
    assert cap.err.count("bad.png") == 1 and "Traceback" not in cap.err
    assert "1 failed" in cap.out


def test_quiet_after_the_subcommand(tmp_path, capsys):
    assert main(["refocus", str(SCENE), "--depth", "0.5", *SAA, "-o", str(tmp_path / "a.png"), "-q"]) == 0
    assert "INFO" not in capsys.readouterr().err
    assert main(["refocus", str(SCENE), "--depth", "0.5", *SAA, "-o", str(tmp_path / "b.png"), "-v"]) == 0
    assert "INFO" in capsys.readouterr().err


def test_python_m_lfring():
    res = subprocess.run([sys.executable, "-m", "lfring", "--version"], capture_output=True, text=True)
    assert res.returncode == 0 and "lfring, version" in res.stdout


@pytest.mark.parametrize("args, says, not_says", [
    (["view", str(SCENE), "--zmin", "1.0", "--zmax", "0.5"], "--zmin (1.0) must be smaller than --zmax (0.5)", "zmin_m"),
    # Less than a pixel of view motion: no number of planes helps.
    (["depth", str(SCENE), "--zmin", "0.49", "--zmax", "0.5", "-o", "d/"],
     "too little to tell any depth in it from another; widen it", "planes"),
    (["depth", str(SCENE), "--zmin", "0.3", "--zmax", "0.35", "--planes", "3", "-o", "d/"], "give --planes >= 4",
     "num_planes"),
    # The refocus and viewer have no --planes and no --method local: their own words.
    (["refocus", str(SCENE), "--depth", "0.3", "--zmin", "0.3", "--zmax", "0.31"],
     "--zmin 0.3 .. --zmax 0.31 m is too narrow to estimate depth over", "--method local"),
    (["view", str(SCENE), "--zmin", "0.3", "--zmax", "0.31"], "; widen the range\n", "--planes"),
    (["view", str(SCENE), "--planes", "2"], "--planes must be an integer >= 3 (", "None"),
    # --zmax alone, nearer than where the range starts: the default of --zmin said as such.
    (["refocus", str(SCENE), "--depth", "0.5", "--zmax", "0.2"],
     "--zmax (0.2 m) must be farther than the calibration's nearest valid depth (0.3 m), where the range starts when "
     "--zmin is not given", "--zmin (0.3)"),
    (["depth", str(SCENE), "--zmax", "0.2", "-o", "d/"], "where the range starts when --zmin is not given", "zmin_m"),
    # Every method refuses such planes: the remedy names no other method.
    (["depth", str(SCENE), "--zmin", "0.3", "--zmax", "0.35", "--planes", "3", "-o", "d/"],
     "or widen the depth range\n", "--method local"),
    (["inspect", str(SCENE), "--plane", "0.3", "--tolerance", "-1", "-o", "r/"], "--tolerance must be", "tolerance_m"),
    # The built-in calibration records its device now (--f-number works with it): a copy without one.
    (["refocus", str(SCENE), "--depth", "0.5", "--f-number", "4", "--calib", "no_device.json"], "or --aperture", "ring_device="),
])
def test_cli_errors_name_options_not_parameters(tmp_path, args, says, not_says):
    """What the user saw: errors that name the library's parameters. The CLI says its options."""
    import subprocess
    import sys

    twin = json.loads((DATA.parents[1] / "calib" / "twin_binned2.json").read_text())
    (tmp_path / "no_device.json").write_text(json.dumps({k: v for k, v in twin.items() if k != "device"}))
    proc = subprocess.run([sys.executable, "-m", "lfring", *args], capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert proc.returncode == 2
    assert says in proc.stderr and not_says not in proc.stderr, proc.stderr


def test_missing_pattern_is_an_error_that_names_the_option(tmp_path):
    """The README says so: a single-channel frame without a pattern is refused (a guessed
    pattern would swap colours silently), and the error names --pattern, not load_raw()."""
    import subprocess
    import sys

    import tifffile

    tifffile.imwrite(tmp_path / "grey.tif", np.zeros((1842, 2456), np.uint16))
    cal = _calibration_without_levels(tmp_path)  # the built-in calibration would give its pattern
    proc = subprocess.run([sys.executable, "-m", "lfring", "refocus", "grey.tif", "--depth", "0.5", "--calib", cal.name],
                          capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert proc.returncode == 2 and "Pass --pattern with one of RGGB" in proc.stderr and "load_raw" not in proc.stderr
    readme = (DATA.parents[1] / "README.md").read_text()
    assert "the pattern has no default" in readme


def test_depth_planes_beyond_the_free_memory_refused_in_one_line(tmp_path, capsys, monkeypatch):
    from lfring.core import memory

    monkeypatch.setattr(memory, "available_memory_bytes", lambda: 64 << 20)  # 64 MiB free
    out = tmp_path / "d"
    assert main(["depth", str(SCENE), "-o", str(out), "--planes", "60"]) == 2
    _one_error(capsys.readouterr().err, "--method sgm over 60 depth hypotheses on 705 x 705 px views (at least 114 MiB) "
                                        "needs more memory than the 64 MiB free: give fewer --planes")
    # A --planes beyond what the range can tell apart is refused before the memory is asked about.
    assert main(["depth", str(SCENE), "-o", str(out), "--planes", "1000"]) == 2
    _one_error(capsys.readouterr().err, "--planes 1000 puts the hypotheses closer than 1/8 px of view motion over 0.3..1 m")
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.parametrize("args, text", [
    (["depth", str(SCENE), "-o", "{tmp}/d", "--planes", "0"],
     "--planes must be an integer >= 3 (leave --planes out for the default spacing), got 0"),
    (["depth", str(SCENE), "-o", "{tmp}/d", "--planes", "2", "--method", "local"], "--planes must be an integer >= 3"),
    (["refocus", str(SCENE), "--sweep", "0.3:inf:3", "-o", "{tmp}/s.png"],
     "a sweep runs between two finite depths, got '0.3:inf:3'; give infinity with --depths Z1,...,inf"),
    (["batch", str(SCENE), "-o", "{tmp}/b", "--refocus", "0.5", "--executor", "local", "--scheduler", "tcp://127.0.0.1:9"],
     "--scheduler tcp://127.0.0.1:9 is a Dask scheduler: give --executor dask (or leave --executor out)"),
], ids=["planes 0", "local over 2 planes", "sweep to inf", "local executor with a scheduler"])
def test_refusals_say_what_to_give_in_the_commands_words(tmp_path, capsys, args, text):
    assert main([a.replace("{tmp}", str(tmp_path)) for a in args]) == 2
    err = capsys.readouterr().err
    assert text in err and "None" not in err and "nan" not in err and "Traceback" not in err
    assert not any(tmp_path.iterdir())


def test_check_of_a_black_frame_says_it_holds_no_light(tmp_path, capsys):
    import tifffile

    frame = tmp_path / "black.tif"
    tifffile.imwrite(frame, np.zeros((1842, 2456), np.uint16))
    assert main(["check", str(frame), "-o", str(tmp_path / "c.png")]) == 1
    captured = capsys.readouterr()
    assert "texture      none measurable (no light inside the discs)" in captured.out and "nan" not in captured.out
    assert "every count is 0: the frame holds no light" in captured.err and "1-bit" not in captured.err


@pytest.mark.filterwarnings("always::lfring.errors.LfringWarning")
def test_refocus_warns_of_an_estimation_range_outside_the_calibrated_one_as_depth_does(tmp_path, capsys):
    assert main(["refocus", str(SCENE), "--depth", "0.5", "--zmin", "0.25", "--zmax", "3", "-o", str(tmp_path / "a.png")]) == 0
    err = capsys.readouterr().err
    assert err.count("WARNING") == 1 and "depth 0.25, 3 m is outside the calibrated range (0.3 to 1 m)" in err


def test_a_refused_calibration_gets_no_verdict_on_its_distortion(tmp_path, capsys):
    # The scene given as the 1 m target: refused for its residuals, after a line that called
    # the distortion "negligible, not modelled" as if the calibration were good.
    out = tmp_path / "c.json"
    assert main(["calibrate", str(DATA / "target_0.3m.png"), str(SCENE), "--depths", "0.3", "1.0", "-o", str(out)]) == 2
    captured = capsys.readouterr()
    _one_error(captured.err, "does not look like a planar target at that depth")
    assert "distortion" not in captured.out and not out.exists()


def test_a_negative_value_read_as_an_option_is_named_as_a_value(tmp_path, capsys):
    args = ["calibrate", str(DATA / "target_0.3m.png"), str(DATA / "target_1m.png"), "--depths", "0.3", "-1",
            "-o", str(tmp_path / "c.json")]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "-1 is not an option: was it meant as a value? Depths and distances are metres in front of the lens" in err
    assert "No such option" not in err and not any(tmp_path.iterdir())
    assert main(["refocus", str(SCENE), "--dept", "0.5"]) == 2  # a misspelt option keeps click's suggestion
    assert "Did you mean" in capsys.readouterr().err


def test_output_into_a_pipe_that_closed_ends_quietly(tmp_path):
    # `lfring check frame.png | head -2` printed "lfring: error: Broken pipe".
    proc = subprocess.Popen([sys.executable, "-m", "lfring", "check", str(SCENE), "-o", str(tmp_path / "c.png")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    proc.stdout.close()  # no reader: the first line printed meets a closed pipe
    proc.stdout = None
    err = proc.communicate(timeout=300)[1]
    assert proc.returncode == 141
    assert "error" not in err and "Traceback" not in err and "Exception ignored" not in err, err


@pytest.mark.filterwarnings("always::lfring.errors.LfringWarning")
def test_a_depth_given_in_millimetres_is_named_as_such_by_refocus_and_batch(tmp_path, capsys):
    """--depth 500 (millimetres meant) refocused at 500 m, near infinity, after a warning that an
    intended far focus gets too; the warning now asks, as depth and inspect refuse with it. A far
    depth that is no millimetre reading (2 m) gets no such question."""
    assert main(["refocus", str(SCENE), "--depth", "500", "--method", "shift-and-add", "-o", str(tmp_path / "a.png")]) == 0
    assert "depth 500 m is outside the calibrated range (0.3 to 1 m); the model is extrapolated; depths are in " \
           "metres: was 500 given in mm?" in capsys.readouterr().err
    assert main(["refocus", str(SCENE), "--depth", "2", "--method", "shift-and-add", "-o", str(tmp_path / "b.png")]) == 0
    err = capsys.readouterr().err
    assert "depth 2 m is outside the calibrated range" in err and "mm?" not in err
    frames = tmp_path / "in"
    frames.mkdir()
    shutil.copy(SCENE, frames / "f.png")
    assert main(["batch", str(frames), "-o", str(tmp_path / "out"), "--refocus", "500", "--method", "shift-and-add",
                 "--workers", "1", "--no-progress"]) == 0
    assert "was 500 given in mm?" in capsys.readouterr().err
