import json
import re
from pathlib import Path

import pytest

from lfring.cli.main import main

SCENE = Path(__file__).resolve().parents[2] / "data" / "synthetic" / "scene.png"


def _data(path: Path) -> dict:
    text = path.read_text()
    return json.loads(re.search(r'<script id="lf-data" type="application/json">(.*?)</script>', text, re.S).group(1))


def test_view_writes_one_page_with_the_requested_stack(tmp_path, capsys):
    out = tmp_path / "v" / "scene.html"
    assert main(["view", str(SCENE), "--zmin", "0.3", "--zmax", "1.0", "--planes", "5", "--format", "webp",
                 "-o", str(out)]) == 0
    assert capsys.readouterr().out.strip() == str(out)
    d = _data(out)
    assert len(d["frames"]) == 5 and d["frames"][0].startswith("data:image/webp;base64,")
    assert d["depths_m"][0] == pytest.approx(0.3) and d["depths_m"][-1] == pytest.approx(1.0)
    # Evenly spaced in disparity 1/(Z - z0).
    inv = [1 / (z - d["depth_origin_m"]) for z in d["depths_m"]]
    assert max(inv[i] - inv[i + 1] for i in range(4)) == pytest.approx(min(inv[i] - inv[i + 1] for i in range(4)))
    assert d["metadata"]["input"] == str(SCENE) and d["metadata"]["calibration"]
    assert d["metadata"]["units"].startswith("depth in metres")
    assert d["metadata"]["calibration_model"]["depth_origin_m"] == pytest.approx(d["depth_origin_m"])
    assert main(["view", str(SCENE), "-o", str(out)]) == 2  # no overwrite
    assert "exists" in capsys.readouterr().err


@pytest.mark.parametrize(
    "args, text",
    [
        # The CLI names its options, not the library's parameters (zmax_m, num_planes, min_confidence).
        (["--zmin", "1.0", "--zmax", "0.5"], "smaller than --zmax"),
        # A stack too near to render, as refocus says it, inside the depth origin or not.
        (["--zmin", "0.01"], "the nearest depth that works with this calibration is 0.0369 m"),
        (["--zmin", "0.03"], "--zmin 0.03 m cannot be rendered"),
        (["--planes", "1"], "--planes"),
        (["--reference", "9"], "reference"),
        (["--min-confidence", "3"], "--min-confidence"),
        (["-o", "x.png"], ".html"),
    ],
)
def test_view_bad_options_are_one_line(tmp_path, capsys, args, text):
    args = args if "-o" in args else [*args, "-o", str(tmp_path / "v.html")]
    assert main(["view", str(SCENE), *args]) == 2
    err = capsys.readouterr().err
    assert text in err and "Traceback" not in err


def test_view_reads_frames_as_every_command_does(tmp_path):
    """What the README promises of every command that reads frames: --pattern, --black-level,
    --white-level and --no-check; the refusal of a photograph names --no-check, which works."""
    import subprocess
    import sys

    import cv2
    import numpy as np

    help_text = subprocess.run([sys.executable, "-m", "lfring", "view", "--help"], capture_output=True, text=True,
                               timeout=120).stdout
    for opt in ("--pattern", "--black-level", "--white-level", "--no-check"):
        assert opt in help_text
    rng = np.random.default_rng(0)
    photo = cv2.resize((rng.random((46, 61, 3)) * 255).astype(np.uint8), (2456, 1842), interpolation=cv2.INTER_CUBIC)
    cv2.imwrite(str(tmp_path / "photo.png"), photo)
    cmd = [sys.executable, "-m", "lfring", "view", str(tmp_path / "photo.png"), "--planes", "3", "-o", str(tmp_path / "p.html")]
    refused = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert refused.returncode == 2 and "--no-check" in refused.stderr and not (tmp_path / "p.html").exists()
    forced = subprocess.run([*cmd, "--no-check"], capture_output=True, text=True, timeout=300)
    assert forced.returncode == 0, forced.stderr
    assert (tmp_path / "p.html").exists()


def test_view_s_method_and_aperture_are_options_its_page_and_record_carry(tmp_path, capsys):
    """The viewer's focal stack was always depth-aware at aperture 1, and its record said
    neither: --method, --aperture and --f-number choose them, as lfring refocus's do."""
    out = tmp_path / "a.html"
    assert main(["view", str(SCENE), "--planes", "4", "--aperture", "2", "-o", str(out)]) == 0
    d = _data(out)
    assert d["metadata"]["refocus_method"] == "depth-aware" and d["metadata"]["aperture"] == 2.0
    record = json.loads((tmp_path / "a.html.lfring.json").read_text())
    assert record["settings"]["method"] == "depth-aware" and record["settings"]["aperture"] == 2.0
    assert record["made_with"] == {"method": "depth-aware", "aperture": 2.0}
    sa = tmp_path / "b.html"
    assert main(["view", str(SCENE), "--planes", "4", "--method", "shift-and-add", "-o", str(sa)]) == 0
    assert _data(sa)["metadata"]["refocus_method"] == "shift-and-add"
    record = json.loads((tmp_path / "b.html.lfring.json").read_text())
    assert record["settings"]["method"] == "shift-and-add" and record["made_with"] == {"method": "shift-and-add",
                                                                                       "aperture": None}
    # An f-number comes to an aperture through the calibration's device: the page and the record say which.
    fn = tmp_path / "d.html"
    assert main(["view", str(SCENE), "--planes", "4", "--f-number", "2.8", "-o", str(fn)]) == 0
    record = json.loads((tmp_path / "d.html.lfring.json").read_text())
    assert record["settings"]["aperture"] is None
    assert record["made_with"]["aperture"] == pytest.approx(_data(fn)["metadata"]["aperture"]) and 0 < record["made_with"]["aperture"]
    capsys.readouterr()
    assert main(["view", str(SCENE), "--method", "shift-and-add", "--f-number", "2.8", "-o", str(tmp_path / "c.html")]) == 2
    assert "--aperture and --f-number are for --method depth-aware" in capsys.readouterr().err
