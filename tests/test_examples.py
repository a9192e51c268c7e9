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
