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
    want = encode_image(lfring.refocus(lfring.split_views(image, cal), cal, 0.3), 8, "srgb")
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


def test_live_refocus_reports_bad_frames_and_goes_on(tmp_path):
    """What the user fed the loop: a truncated frame, a JPEG, a frame of another size and an
    ordinary photograph between two good frames. One ERROR line each, no traceback, the good
    frames refocused, exit code 2."""
    good = DATA / "part_good.png"
    data = good.read_bytes()
    (tmp_path / "trunc.png").write_bytes(data[: len(data) // 3])
    (tmp_path / "trunc.png.json").write_bytes((DATA / "part_good.png.json").read_bytes())
    counts = cv2.imread(str(good), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(tmp_path / "frame.jpg"), (counts >> 4).astype(np.uint8))
    cv2.imwrite(str(tmp_path / "small.png"), counts[:900, :1200])
    (tmp_path / "small.png.json").write_bytes((DATA / "part_good.png.json").read_bytes())
    rng = np.random.default_rng(0)
    photo = cv2.resize((rng.random((46, 61, 3)) * 255).astype(np.uint8), (2456, 1842), interpolation=cv2.INTER_CUBIC)
    cv2.imwrite(str(tmp_path / "photo.png"), photo)
    names = [good, *(tmp_path / n for n in ("trunc.png", "frame.jpg", "small.png", "photo.png")), good]
    proc = subprocess.run([sys.executable, str(ROOT / "examples" / "live_refocus.py"), *map(str, names), "--depth", "0.3"],
                          check=False, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    lines = proc.stdout.strip().splitlines()
    errors = [ln for ln in lines if ln.startswith("ERROR ")]
    assert [e.split(":")[0] for e in errors] == ["ERROR trunc#0", "ERROR frame#0", "ERROR small#0", "ERROR photo#0"]
    assert "not a ring frame" in errors[3]
    assert lines[-1].startswith("2 frames at 0.3 m in ") and lines[-1].endswith("4 frames could not be used")
