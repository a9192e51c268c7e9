"""The scripts in examples/ run on the bundled samples and do what they say."""

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "data" / "synthetic"


def test_live_refocus_loop(tmp_path):
    out = tmp_path / "live"
    proc = subprocess.run([sys.executable, str(ROOT / "examples" / "live_refocus.py"), str(DATA / "part_good.png"),
                           "--depth", "0.3", "--repeat", "2", "-o", str(out)], check=False, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.strip().splitlines()
    assert [ln.split(":")[0] for ln in lines[:2]] == ["part_good#0", "part_good#1"]
    assert lines[-1].startswith("2 frames at 0.3 m in ") and "frames/s" in lines[-1]
    # Each written frame is the fast path's refocus of that frame at 0.3 m.
    import lfring
    from lfring.calibration.defaults import default_calibration
    from lfring.io.writers import encode_image

    image = lfring.demosaic(lfring.load_raw(DATA / "part_good.png"))
    cal, _ = default_calibration((image.shape[1], image.shape[0]))
    want = encode_image(lfring.refocus(lfring.split_views(image, cal.layout), cal, 0.3), 8, "srgb")
    for r in (0, 1):
        got = cv2.cvtColor(cv2.imread(str(out / f"part_good_{r}_refocus.png")), cv2.COLOR_BGR2RGB)
        np.testing.assert_array_equal(got, want)


def test_live_refocus_rejects_bad_depth(tmp_path):
    proc = subprocess.run([sys.executable, str(ROOT / "examples" / "live_refocus.py"), str(DATA / "part_good.png"),
                           "--depth", "-1"], check=False, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "--depth must be positive" in proc.stderr


def test_defect_check_example(tmp_path):
    """The inspection example: one line per part, exit 1 when a part has defects, 3 when one
    cannot be judged (and none failed), 0 when all passed."""
    def run(*frames):
        return subprocess.run([sys.executable, str(ROOT / "examples" / "defect_check.py"), *map(str, frames), "--plane",
                               "0.3", "--tolerance", "0.008", "-o", str(tmp_path / "out"), "--overwrite"],
                              capture_output=True, text=True, timeout=300, cwd=ROOT)

    good, bad, flat = DATA / "part_good.png", DATA / "part_defects.png", DATA / "flat.png"
    proc = run(good, bad, flat)
    assert proc.returncode == 1, proc.stderr
    lines = proc.stdout.strip().splitlines()
    assert lines[0].startswith("PASS") and "part_good.png" in lines[0] and "of the part)" in lines[0]
    assert lines[1].startswith("FAIL") and "part_defects.png" in lines[1] and "2 defects" in lines[1]
    assert lines[2].startswith("CANNOT JUDGE") and "flat.png: frame too flat" in lines[2]
    assert lines[-1] == "1 of 3 parts failed, 1 cannot be judged, 0 could not be read"
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [
        "flat_inspect.json", "flat_inspect.png", "part_defects_inspect.json", "part_defects_inspect.png",
        "part_good_inspect.json", "part_good_inspect.png"]
    proc = run(flat)
    assert proc.returncode == 3 and proc.stdout.strip().splitlines()[-1] == "0 of 1 parts failed, 1 cannot be judged, 0 could not be read"
    proc = run(good)
    assert proc.returncode == 0 and proc.stdout.strip().splitlines()[-1] == "all 1 parts passed"
