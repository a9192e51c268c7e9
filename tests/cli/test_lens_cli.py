"""The command line with real mini-lenses: calibrate reports the distortion, check the fit,
refocus, depth and inspect take a flat frame."""

from pathlib import Path

import pytest

from lfring.cli.main import main

DATA = Path(__file__).resolve().parents[2] / "data" / "synthetic"
CALIB = Path(__file__).resolve().parents[2] / "calib"


@pytest.fixture(scope="module")
def lens_calibration(tmp_path_factory):
    out = tmp_path_factory.mktemp("lenses") / "lenses.json"
    args = ["calibrate", str(DATA / "lenses" / "lens_target_0.3m.png"), str(DATA / "lenses" / "lens_target_1m.png"), "--depths", "0.3", "1.0",
            "--flat", str(DATA / "lenses" / "lens_flat.png"), "--device", str(CALIB / "prototype_lenses.toml"), "--carry-flat",
            "-o", str(out)]
    return args, out


def test_calibrate_models_the_lenses_and_says_so(lens_calibration, capsys):
    args, out = lens_calibration
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "distortion modelled" in text and "before" in text
    assert main(["check", str(DATA / "lenses" / "lens_target_1m.png"), "--calib", str(out), "-o", str(out.with_suffix(".png"))]) == 0
    text = capsys.readouterr().out
    assert "fit          views" in text and "lens distortion undone, flat field divided" in text


def test_calibrate_without_the_distortion_model(tmp_path, capsys):
    out = tmp_path / "plain.json"
    assert main(["calibrate", str(DATA / "lenses" / "lens_target_0.3m.png"), str(DATA / "lenses" / "lens_target_1m.png"), "--depths", "0.3",
                 "1.0", "--flat", str(DATA / "lenses" / "lens_flat.png"), "--no-distortion", "-o", str(out)]) == 0
    cap = capsys.readouterr()
    assert "distortion not estimated" in cap.out
    # These lenses distort the views by more than the residual warning allows: the warning names
    # the option that left the distortion out, not only the target.
    assert "exceeds 0.3 px" in cap.err and "or leave out --no-distortion: the lenses may distort the views" in cap.err
    assert main(["calibrate", str(DATA / "lenses" / "lens_target_0.3m.png"), str(DATA / "lenses" / "lens_target_1m.png"), "--depths", "0.3",
                 "1.0", "--carry-flat", "-o", str(tmp_path / "x.json")]) == 2


def test_refocus_takes_a_flat_frame(tmp_path):
    out = tmp_path / "scene.png"
    assert main(["refocus", str(DATA / "scene.png"), "--depth", "0.5", "--method", "shift-and-add", "--flat",
                 str(DATA / "flat.png"), "-o", str(out)]) == 0
    assert out.is_file()
    assert main(["refocus", str(DATA / "scene.png"), "--depth", "0.5", "--flat", str(DATA / "lenses" / "lens_flat.png"),
                 "-o", str(tmp_path / "bad.png")]) == 2
