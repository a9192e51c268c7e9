import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from lfring.cli.main import main
from lfring.cli.synth import write_render
from lfring.synth import render
from lfring.synth.presets import flat_scene, three_depth_scene


@pytest.fixture(scope="module")
def frames(tmp_path_factory, prototype):
    d = tmp_path_factory.mktemp("frames")
    scene = render(prototype, three_depth_scene(), binning=4, noise="realistic", pattern="GBRG")
    flat = render(prototype, flat_scene(prototype), binning=4, noise="low", pattern="GBRG")
    write_render(scene, d / "scene.png")
    write_render(flat, d / "flat.png")
    return d, scene


def test_split_with_flat_and_layout(frames, tmp_path, capsys):
    d, scene = frames
    assert main(["split", str(d / "scene.png"), "--flat", str(d / "flat.png"), "-o", str(tmp_path / "a")]) == 0
    side = json.loads((tmp_path / "a" / "scene_views.json").read_text())
    assert side["views"] == [f"scene_view{k}.png" for k in range(4)] and side["pattern"] == "GBRG"
    assert side["demosaic"] == "edge-aware"
    # An RGB frame is not demosaiced: its sidecar says so, whatever --method was given.
    rgb, layout = tmp_path / "rgb.png", d / "scene_truth" / "layout.json"
    full = cv2.imread(str(d / "scene.png"), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(rgb), cv2.merge([full, full, full]))
    assert main(["split", str(rgb), "--layout", str(layout), "--method", "vng", "-o", str(tmp_path / "r")]) == 0
    assert json.loads((tmp_path / "r" / "rgb_views.json").read_text())["demosaic"] is None
    v0 = cv2.imread(str(tmp_path / "a" / "scene_view0.png"), cv2.IMREAD_UNCHANGED)
    assert v0.dtype == np.uint16 and v0.shape[2] == 3
    # With the ground-truth layout the views match the twin's views (noise and demosaicing aside).
    assert main(["split", str(d / "scene.png"), "--layout", str(d / "scene_truth" / "layout.json"),
                 "-o", str(tmp_path / "b"), "--method", "bilinear"]) == 0
    for k in range(4):
        got = cv2.cvtColor(cv2.imread(str(tmp_path / "b" / f"scene_view{k}.png"), cv2.IMREAD_UNCHANGED), cv2.COLOR_BGR2RGB)
        got = got.astype(np.float64) / 65535.0
        inner = np.s_[10:-10, 10:-10]
        psnr = 10 * np.log10(1.0 / np.mean((got[inner] - scene.views[k][inner]) ** 2))
        assert psnr > 30.0
    # No overwrite without --overwrite; nothing is changed.
    before = (tmp_path / "b" / "scene_view0.png").read_bytes()
    assert main(["split", str(d / "scene.png"), "--flat", str(d / "flat.png"), "-o", str(tmp_path / "b")]) == 2
    assert "exists" in capsys.readouterr().err
    assert (tmp_path / "b" / "scene_view0.png").read_bytes() == before
    # The same split again replaces its own views with the same ones.
    assert main(["split", str(d / "scene.png"), "--layout", str(d / "scene_truth" / "layout.json"),
                 "-o", str(tmp_path / "b"), "--method", "bilinear"]) == 0
    assert (tmp_path / "b" / "scene_view0.png").read_bytes() == before


def _err(capsys):
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return err


def test_split_bad_inputs(frames, tmp_path, capsys):
    d, _ = frames
    out = str(tmp_path / "o")
    # Truncated and corrupt files.
    data = (d / "scene.png").read_bytes()
    (tmp_path / "trunc.png").write_bytes(data[: len(data) // 2])
    (tmp_path / "trunc.png.json").write_text((d / "scene.png.json").read_text())
    assert main(["split", str(tmp_path / "trunc.png"), "-o", out]) == 2
    assert "trunc.png" in _err(capsys)
    (tmp_path / "junk.dng").write_bytes(b"\x00" * 1000)
    assert main(["split", str(tmp_path / "junk.dng"), "-o", out]) == 2
    assert "junk.dng" in _err(capsys)
    assert main(["split", str(tmp_path / "missing.png"), "-o", out]) == 2
    assert "missing.png" in _err(capsys)
    # Unknown pattern name.
    assert main(["split", str(d / "scene.png"), "--pattern", "RGBG", "-o", out]) == 2
    _err(capsys)
    # Odd size mosaic.
    cv2.imwrite(str(tmp_path / "odd.png"), np.zeros((101, 200), np.uint16))
    assert main(["split", str(tmp_path / "odd.png"), "--pattern", "RGGB", "-o", out]) == 2
    assert "odd" in _err(capsys).lower()
    # All-black frame and a flat frame with no four regions.
    cv2.imwrite(str(tmp_path / "black.png"), np.zeros((920, 1228), np.uint16))
    assert main(["split", str(tmp_path / "black.png"), "--pattern", "RGGB", "-o", out]) == 2
    assert f"error: {tmp_path / 'black.png'}: the frame is uniform" in _err(capsys)
    blob = np.zeros((920, 1228), np.uint16)
    cv2.circle(blob, (600, 460), 240, 4000, -1)
    cv2.imwrite(str(tmp_path / "blob.png"), blob)
    assert main(["split", str(d / "scene.png"), "--flat", str(tmp_path / "blob.png"), "--pattern", "GBRG", "-o", out]) == 2
    assert f"error: --flat {tmp_path / 'blob.png'}: found 1 bright region" in _err(capsys)
    # A scene given as the flat: refused as not flat (it once ended in an OpenCV assertion).
    assert main(["split", str(d / "scene.png"), "--flat", str(d / "scene.png"), "-o", out]) == 2
    err = _err(capsys)
    assert f"error: --flat {d / 'scene.png'}: the frame is not a flat field" in err and "texture" in err
    assert "detect_layout" not in err
    assert not (tmp_path / "o").exists()
    # A layout that does not fit the frame.
    lay = json.loads((d / "scene_truth" / "layout.json").read_text())
    lay["raw_width_px"], lay["raw_height_px"] = 2456, 1842
    (tmp_path / "big.json").write_text(json.dumps(lay))
    assert main(["split", str(d / "scene.png"), "--layout", str(tmp_path / "big.json"), "-o", out]) == 2
    assert "2456 x 1842" in _err(capsys)
    # Contradicting options.
    assert main(["split", str(d / "scene.png"), "--layout", "a.json", "--flat", "b.png", "-o", out]) == 2
    _err(capsys)


def test_split_flat_of_another_size_names_the_option(frames, tmp_path, capsys):
    """A --flat frame of another size than RAW is refused naming both files and their sizes."""
    d, _ = frames
    flat = Path(__file__).resolve().parents[2] / "data" / "synthetic" / "flat.png"
    assert main(["split", str(d / "scene.png"), "--flat", str(flat), "-o", str(tmp_path / "o")]) == 2
    err = _err(capsys)
    assert (f"--flat {flat} is 2456 x 1842 px but the frame {d / 'scene.png'} is 1228 x 920 px; give a flat frame "
            "of the same camera and binning") in err
    assert not (tmp_path / "o").exists()
