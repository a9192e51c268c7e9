"""The outputs of an inspection (lfring.inspect.draw, lfring.inspect.reporting): plain-JSON
reports, the annotated image (defect boxes, the unchecked part hatched) and files written only
with overwrite."""

import json

import numpy as np
import pytest

from inspect_parts import PLANE, TOL
from lfring.errors import InvalidInputError
from lfring.inspect import annotate, inspect_frame, report, write_report


def test_report_and_annotation(parts, tmp_path):
    r, cal, views, truth, res = parts["two"]
    rep = report(res, raw="part.png")
    text = json.dumps(rep, allow_nan=False)  # plain JSON: no NaN, no NumPy types
    back = json.loads(text)
    assert back["passed"] is False and back["verdict"] == "fail" and back["num_defects"] == 2
    d0 = back["defects"][0]
    assert set(d0) == {"id", "kind", "bbox_px", "centroid_px", "area_px", "area_mm2", "max_deviation_mm", "beyond_band",
                      "mean_confidence"}
    assert set(d0["bbox_px"]) == {"x", "y", "w", "h"}
    assert abs(d0["max_deviation_mm"]) > TOL * 1e3
    assert back["settings"]["tolerance_m"] == TOL and back["input"]["raw"] == "part.png"
    img = annotate(res)
    assert img.dtype == np.uint8 and img.shape == (*views.shape[1:3], 3)
    x, y, w, h = res.defects[0].bbox_px
    colour = (255, 40, 40) if res.defects[0].kind == "bump" else (40, 140, 255)
    assert (img[y + h // 2, x] == colour).all()  # the box's left edge
    paths = write_report(res, tmp_path / "r.json", image_path=tmp_path / "r.png")
    assert [p.name for p in paths] == ["r.json", "r.png"] and (tmp_path / "r.png").read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(InvalidInputError, match="exists"):
        write_report(res, tmp_path / "r.json")
    write_report(res, tmp_path / "r.json", overwrite=True)


def test_cannot_judge_report_and_drawing(parts, tmp_path):
    r, cal, views, *_ = parts["good"]
    res = inspect_frame(np.zeros_like(views), cal, plane_m=PLANE, tolerance_m=TOL)
    back = json.loads(json.dumps(report(res), allow_nan=False))
    assert back["verdict"] == "cannot_judge" and back["passed"] is False and back["coverage"] == 0.0
    assert back["reason"].startswith("frame too dark") and back["num_defects"] == 0
    paths = write_report(res, tmp_path / "c.json", image_path=tmp_path / "c.png")
    assert [p.name for p in paths] == ["c.json", "c.png"]
    # A good part: its unchecked pixels are hatched in magenta, its checked ones never.
    good = parts["good"][4]
    img = annotate(good)
    hatch = (img == (255, 0, 255)).all(axis=-1)
    unchecked = good.part & ~good.reliable
    assert hatch[unchecked].mean() > 0.15 and hatch[good.reliable & good.part].sum() == 0
    assert json.loads(json.dumps(report(good)))["coverage"] == pytest.approx(good.coverage, abs=1e-4)


def test_a_defect_label_never_overprints_the_banner(parts):
    """A defect at the top-left corner, under the banner: its label goes below its box, and the
    banner's text stays whole (the same pixels in the banner's colour as with the defect
    elsewhere)."""
    import dataclasses

    r, cal, views, truth, res = parts["two"]
    dent = dataclasses.replace(res.defects[0], kind="dent", deviation_m=-0.019)
    top = dataclasses.replace(res, defects=(dataclasses.replace(dent, bbox_px=(12, 0, 30, 20)),))
    away = dataclasses.replace(res, defects=(dataclasses.replace(dent, bbox_px=(500, 500, 30, 20)),))
    a, b = annotate(top), annotate(away)
    banner_rgb = np.array((255, 40, 40), np.uint8)  # FAIL is red; the dent and its label are blue
    rows = slice(0, 90)
    assert ((a[rows] == banner_rgb).all(axis=-1) == (b[rows] == banner_rgb).all(axis=-1)).all()
    # The label (blue) is not drawn among the banner's three lines (below the 20 px box, down to
    # the banner's last line), but below them.
    label = (a == np.array((40, 140, 255), np.uint8)).all(axis=-1)
    assert not label[21:100, :300].any() and label[100:160, :300].any()


def test_golden_depth_judges_the_part_not_the_belt_behind_it(tmp_path):
    """What the user did: a golden part's depth map from `lfring depth`, then `lfring inspect
    --reference-depth` on a part with a bump and a dent. The belt around the part (a different
    depth, measured differently at the discs' rims) raised false defects in the frame's corners;
    only the part is judged now."""
    import subprocess
    import sys
    from pathlib import Path

    data = Path(__file__).resolve().parents[2] / "data" / "synthetic"
    run = lambda *a: subprocess.run([sys.executable, "-m", "lfring", *map(str, a)], capture_output=True, text=True,
                                    cwd=tmp_path, timeout=600)
    assert run("depth", data / "part_good.png", "--method", "local", "-o", "golden").returncode == 0
    proc = run("inspect", data / "part_defects.png", "--plane", "0.3", "--tolerance", "0.008", "--reference-depth",
               "golden/part_good_depth.tiff", "-o", "report")
    assert proc.returncode == 1, proc.stderr
    rep = json.loads((tmp_path / "report" / "part_defects_inspect.json").read_text())
    assert [d["kind"] for d in rep["defects"]] == ["bump", "dent"]
    assert all(10 < abs(d["max_deviation_mm"]) < 17 for d in rep["defects"])
    good = run("inspect", data / "part_good.png", "--plane", "0.3", "--tolerance", "0.008", "--reference-depth",
               "golden/part_good_depth.tiff", "-o", "report")
    assert good.returncode == 0, good.stdout + good.stderr
