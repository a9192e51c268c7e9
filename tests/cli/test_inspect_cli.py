"""``lfring inspect`` on the sample parts: exit 0 for the good part, 1 for the part with a bump and
a dent, 2 for bad input (nothing written), 3 for a frame that cannot be judged (wrong plane, lens
cap, flat or unrelated frame, too little of the part checked: report written); outputs written
atomically, never overwritten without --overwrite."""

import json
from pathlib import Path

import numpy as np
import pytest

import lfring.cli.main as cli_main
from lfring.depth.io import write_pfm

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "data" / "synthetic"
GOOD, BAD = DATA / "part_good.png", DATA / "part_defects.png"


@pytest.fixture(autouse=True)
def registered(monkeypatch):
    # Until lfring.cli.main lists the command (and after: setitem is then a no-op in effect).
    monkeypatch.setitem(cli_main.COMMANDS, "inspect", "inspect")


def _run(*args):
    return cli_main.main(["inspect", *map(str, args)])


def test_good_part_passes_and_defects_fail(tmp_path, capsys):
    out = tmp_path / "report"
    assert _run(GOOD, "--plane", "0.3", "--tolerance", "0.008", "-o", out) == 0
    rep = json.loads((out / "part_good_inspect.json").read_text())
    assert rep["passed"] is True and rep["verdict"] == "pass" and rep["defects"] == [] and rep["reason"] is None
    assert 0.8 <= rep["coverage"] <= 1 and rep["settings"]["min_coverage"] == 0.8
    assert (out / "part_good_inspect.png").read_bytes()[:4] == b"\x89PNG"
    beyond = rep["stats"]["beyond_sight_fraction"]
    assert 0.1 < beyond < 0.4  # the plate runs on beyond what two views see, at the frame's corners
    assert (f"pass (checked {rep['coverage']:.0%} of the part; it may run on beyond what two views see, over "
            f"{beyond:.0%} more, unchecked)") in capsys.readouterr().out

    assert _run(BAD, "--plane", "0.3", "--tolerance", "0.008", "-o", out) == 1
    rep = json.loads((out / "part_defects_inspect.json").read_text())
    assert rep["passed"] is False and rep["num_defects"] == 2
    # The sample has a 15 mm bump and a 15 mm dent (domes: their peaks deviate most).
    assert sorted(d["kind"] for d in rep["defects"]) == ["bump", "dent"]
    for d in rep["defects"]:
        assert 10 < abs(d["max_deviation_mm"]) < 17 and (d["max_deviation_mm"] > 0) == (d["kind"] == "bump")
        assert d["area_px"] >= 150 and d["area_mm2"] > 1 and d["mean_confidence"] > 0.8
        assert {"x", "y", "w", "h"} == set(d["bbox_px"])
    s = rep["settings"]
    assert s["plane_m"] == 0.3 and s["tolerance_m"] == 0.008 and s["zmin_m"] < 0.3 < s["zmax_m"] and s["roi_px"] is None
    assert rep["input"]["calibration"] == "twin_binned2" and rep["input"]["raw"] == str(BAD)
    assert rep["verdict"] == "fail" and rep["reason"] is None and rep["coverage"] > 0.8
    assert "fail (2 defects, checked" in capsys.readouterr().out

    # The same check again replaces its own report; other settings do not without --overwrite
    # (exit 2, nothing replaced); with it, an ROI around the first defect finds only that one.
    assert _run(BAD, "--plane", "0.3", "--tolerance", "0.008", "-o", out) == 1
    capsys.readouterr()
    before = (out / "part_defects_inspect.json").read_bytes()
    assert _run(BAD, "--plane", "0.3", "--tolerance", "0.01", "-o", out) == 2
    assert "exists" in capsys.readouterr().err and (out / "part_defects_inspect.json").read_bytes() == before
    b = rep["defects"][0]["bbox_px"]
    roi = f"{b['x'] - 10},{b['y'] - 10},{b['w'] + 20},{b['h'] + 20}"
    assert _run(BAD, "--plane", "0.3", "--tolerance", "0.008", "--roi", roi, "--overwrite", "-o", out) == 1
    rep2 = json.loads((out / "part_defects_inspect.json").read_text())
    assert rep2["num_defects"] == 1 and rep2["defects"][0]["kind"] == rep["defects"][0]["kind"]


@pytest.mark.parametrize(
    "args, text",
    [
        (["--tolerance", "0"], "--tolerance must be a positive"),
        (["--tolerance", "nan"], "--tolerance must be a positive"),
        (["--tolerance", "-0.01"], "--tolerance must be a positive"),
        (["--tolerance", "0.01", "--roi", "600,600,200,200"], "roi (x=600, y=600, w=200, h=200) does not fit"),
        (["--tolerance", "0.01", "--roi", "1,2,3"], "X,Y,W,H"),
        (["--tolerance", "0.01", "--reference", "7"], "reference"),
        (["--tolerance", "0.01", "--reference-depth", "missing.pfm"], "not found"),
        (["--tolerance", "ten"], "not a valid float"),
        (["--tolerance", "0.01", "--min-coverage", "1.5"], "--min-coverage must be a number in [0, 1], got 1.5"),
        (["--tolerance", "0.01", "--min-coverage", "-0.1"], "--min-coverage must be a number in [0, 1]"),
    ],
)
def test_bad_input_exits_2(tmp_path, capsys, args, text):
    assert _run(GOOD, "--plane", "0.3", *args, "-o", tmp_path / "o") == 2
    assert text in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_reference_depth_file(tmp_path, capsys):
    small = tmp_path / "small.pfm"
    write_pfm(small, np.full((10, 12), 0.3, np.float32))
    assert _run(GOOD, "--plane", "0.3", "--tolerance", "0.01", "--reference-depth", small, "-o", tmp_path / "o") == 2
    assert "(h, w) = (705, 705), got (10, 12)" in capsys.readouterr().err
    bad = tmp_path / "depth.txt"
    bad.write_text("0.3")
    assert _run(GOOD, "--plane", "0.3", "--tolerance", "0.01", "--reference-depth", bad, "-o", tmp_path / "o") == 2
    assert ".tiff/.tif or .pfm" in capsys.readouterr().err


def test_missing_raw(tmp_path, capsys):
    assert _run(tmp_path / "nope.png", "--plane", "0.3", "--tolerance", "0.01", "-o", tmp_path / "o") == 2
    assert "nope.png" in capsys.readouterr().err


def _lens_cap(tmp_path):
    """An all-black frame (the black level and read noise) with part_good's sidecar."""
    import cv2

    rng = np.random.default_rng(3)
    raw = np.clip(64 + 2.0 * rng.standard_normal((1842, 2456)), 0, 4095).astype(np.uint16)
    path = tmp_path / "cap.png"
    cv2.imwrite(str(path), raw)
    (tmp_path / "cap.png.json").write_text((DATA / "part_good.png.json").read_text())
    return path


def _photo(tmp_path):
    """An ordinary RGB picture at the sensor's size, no ring behind it."""
    import cv2

    from lfring.synth.textures import Texture, rasterize

    rgb = rasterize(Texture("image", name="coffee"), (2456, 1842), 1.0)
    path = tmp_path / "photo.png"
    cv2.imwrite(str(path), cv2.cvtColor(np.rint(np.clip(rgb, 0, 1) ** (1 / 2.2) * 255).astype(np.uint8), cv2.COLOR_RGB2BGR))
    return path


@pytest.mark.parametrize(
    "frame, plane, reason",
    [
        (BAD, "0.5", "no surface found at the working plane"),  # the wrong plane
        ("cap", "0.3", "frame too dark"),
        (DATA / "flat.png", "0.3", "frame too flat"),
        ("photo", "0.3", "no surface found at the working plane"),
        (DATA / "scene.png", "0.3", "too few confident pixels"),  # a cup at 0.3 m, not a part
    ],
)
@pytest.mark.filterwarnings("always::lfring.errors.LfringWarning")
def test_cannot_judge_exits_3_with_the_reason(tmp_path, capsys, frame, plane, reason):
    frame = {"cap": _lens_cap, "photo": _photo}[frame](tmp_path) if isinstance(frame, str) else frame
    out = tmp_path / "report"
    assert _run(frame, "--plane", plane, "--tolerance", "0.008", "-o", out) == 3
    cap = capsys.readouterr()
    assert f"cannot judge ({reason}" in cap.out and "Traceback" not in cap.out + cap.err
    # 8 mm is 0.11 px of view motion at 0.5 m: warned of, in the options' words.
    assert ("--tolerance 0.008 m is 0.11 px of view motion at 0.5 m" in cap.err) == (plane == "0.5")
    stem = Path(frame).stem
    rep = json.loads((out / f"{stem}_inspect.json").read_text())
    assert rep["verdict"] == "cannot_judge" and rep["passed"] is False and rep["reason"].startswith(reason)
    assert rep["num_defects"] == 0 and rep["settings"]["min_coverage"] == 0.8
    # No part found: none of it checked; a part found but too little checked: below min_coverage.
    assert rep["coverage"] == 0.0 if reason != "too few confident pixels" else 0.5 < rep["coverage"] < 0.8
    assert (out / f"{stem}_inspect.png").read_bytes()[:4] == b"\x89PNG"
    # The report, its image and the record of the set (what made them from which inputs).
    assert sorted(p.name for p in out.iterdir()) == [f"{stem}_inspect.json", f"{stem}_inspect.lfring.json",
                                                     f"{stem}_inspect.png"]


def test_min_coverage_option(tmp_path, capsys):
    out = tmp_path / "report"
    assert _run(GOOD, "--plane", "0.3", "--tolerance", "0.008", "--min-coverage", "0.99", "-o", out) == 3
    said = capsys.readouterr().out
    assert "cannot judge (too few confident pixels: checked" in said
    assert "needed (--min-coverage)" in said and "(min_coverage)" not in said  # the option, as the user gave it
    rep = json.loads((out / "part_good_inspect.json").read_text())
    assert rep["verdict"] == "cannot_judge" and rep["settings"]["min_coverage"] == 0.99 and rep["coverage"] < 0.99
