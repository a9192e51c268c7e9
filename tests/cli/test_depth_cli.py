import json
from pathlib import Path

import numpy as np
import pytest
import tifffile

from lfring.cli.main import main
from lfring.depth.io import read_pfm, read_ply

SCENE = Path(__file__).resolve().parents[2] / "data" / "synthetic" / "scene.png"


def test_depth_cli_outputs(tmp_path, capsys):
    out = tmp_path / "d"
    assert main(["depth", str(SCENE), "--zmin", "0.3", "--zmax", "1.0", "--reference", "0", "-o", str(out)]) == 0
    depth = tifffile.imread(out / "scene_depth.tiff")
    assert depth.dtype == np.float32 and depth.shape == (705, 705)
    np.testing.assert_array_equal(read_pfm(out / "scene_depth.pfm"), depth)
    conf = tifffile.imread(out / "scene_confidence.tiff")
    assert 0 <= conf.min() and conf.max() <= 1
    # The cup (0.3 m) fills the upper left of view 0 in the sample scene.
    assert abs(np.nanmedian(depth[200:300, 150:250]) - 0.3) < 0.005
    pts, cols = read_ply(out / "scene_points.ply")
    side = json.loads((out / "scene_depth.json").read_text())
    assert len(pts) == side["points"] > 50_000 and cols.shape == (len(pts), 3)
    assert 0.29 < np.median(pts[:, 2]) < 1.0
    assert (out / "scene_depth_preview.png").read_bytes()[:4] == b"\x89PNG"
    assert (side["cost"], side["method"], side["rim_taper"]) == ("lcn-halves", "sgm", 0.05)
    assert main(["depth", str(SCENE), "--zmin", "0.3", "--zmax", "1.0", "-o", str(out)]) == 2  # no overwrite
    assert "exists" in capsys.readouterr().err


@pytest.mark.parametrize(
    "args, text",
    [
        (["--zmin", "1.0", "--zmax", "0.5"], "smaller than zmax"),
        (["--zmin", "0.01", "--zmax", "0.5"], "depth origin"),
        (["--zmin", "0.3", "--zmax", "0.5", "--planes", "0"], "num_planes"),
        (["--zmin", "0.3", "--zmax", "0.5", "--reference", "9"], "reference"),
        (["--zmin", "0.3", "--zmax", "0.5", "--rim-taper", "1.5"], "rim_taper"),
        (["--zmin", "0.3", "--zmax", "0.5", "--rim-taper", "nan"], "rim_taper"),
        (["--zmin", "0.3", "--zmax", "0.5", "--cost", "lcn-halves", "--method", "local"], "needs method='sgm'"),
        (["--zmin", "0.3", "--zmax", "0.5", "--method", "local", "--paths", "8"], "belong to method='sgm'"),
        (["--zmin", "0.3", "--zmax", "0.5", "--method", "local", "--consistency"], "belong to method='sgm'"),
        (["--zmin", "0.3", "--zmax", "0.5", "--planes", "2"], "give num_planes >= 3"),
        (["--zmin", "0.3", "--zmax", "0.5", "--paths", "6"], "'6' is not one of"),
        (["--zmin", "0.3", "--zmax", "0.5", "--threads", "0"], "--threads"),
        (["--zmin", "0.3", "--zmax", "0.5", "--min-confidence", "-5"], "--min-confidence"),
    ],
)
def test_depth_cli_errors(tmp_path, capsys, args, text):
    assert main(["depth", str(SCENE), *args, "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert text in err and "Traceback" not in err
