"""`lfring batch` over a folder that holds a flat field: the flat is left out with its own reason
(not reported as an ordinary photograph, not a failure), the scene is processed."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "data" / "synthetic"


def test_batch_leaves_out_a_flat_field_with_its_own_reason(tmp_path):
    inp = tmp_path / "synthetic"
    inp.mkdir()
    for name in ("flat.png", "scene.png"):
        shutil.copyfile(DATA / name, inp / name)
        shutil.copyfile(DATA / (name + ".json"), inp / (name + ".json"))
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "lfring", "batch", str(inp), "-o", str(out), "--refocus", "0.5", "--workers", "1",
           "--no-progress"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert "2 frames: 1 done, 0 skipped (already done), 0 failed" in proc.stdout
    assert "1 left out (a flat field)" in proc.stdout
    assert "flat.png: left out: a flat field" in proc.stderr
    assert "photograph" not in proc.stderr and "ERROR" not in proc.stderr
    assert sorted(p.name for p in out.iterdir()) == ["manifest.jsonl", "scene.lfring.json", "scene_refocus_0.5m.png"]
    entries = [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()]
    flat = next(e for e in entries if e["input"].endswith("flat.png"))
    assert flat["status"] == "left_out" and flat["reason"].startswith("a flat field")
    # A rerun skips the scene and leaves the flat out again.
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0 and "0 done, 1 skipped" in again.stdout and "1 left out (a flat field)" in again.stdout
    # The scene's file replaced by a flat field, rerun with --overwrite: it is left out, and the
    # outputs of the scene it was stay listed in its record (nothing replaced them), so a rerun
    # without --overwrite says the input changed instead of disowning them.
    shutil.copyfile(DATA / "flat.png", inp / "scene.png")
    shutil.copyfile(DATA / "flat.png.json", inp / "scene.png.json")
    forced = subprocess.run([*cmd, "--overwrite"], capture_output=True, text=True, timeout=600)
    assert forced.returncode == 0 and "0 done" in forced.stdout and "2 left out" in forced.stdout, forced.stderr
    record = json.loads((out / "scene.lfring.json").read_text())
    assert record["status"] == "done" and record["outputs"] == {"refocus_0.5m": "scene_refocus_0.5m.png"}
    assert (out / "scene_refocus_0.5m.png").exists()
    later = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert later.returncode == 1 and "the input changed since" in later.stderr and "not made by" not in later.stderr
