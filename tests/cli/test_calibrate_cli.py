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
