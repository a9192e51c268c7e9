"""Helpers shared by the batch tests: rendered frames of the twin copied into input folders, and
what the batch should write for them.

Each test module declares its fixtures over these (a second ``conftest.py`` beside the one in
tests/ would clash with it under ``--doctest-modules``, the test folders being no packages)."""

import hashlib
import shutil
from pathlib import Path

import numpy as np

N_FRAMES = 50
CORRUPT = ("bad_truncated.png", "sub/bad_empty.png", "sub/deeper/bad_garbage.tif")


def render_frames(d: Path) -> tuple[Path, Path]:
    """Two rendered 4 x 4 binned frames of the twin (1228 x 921 px) and an optics calibration."""
    from lfring.calibration import RingCalibration
    from lfring.cli.main import main
    from lfring.optics import load_device

    for name, seed in (("scene", 3), ("part", 4)):
        preset = ["scene"] if name == "scene" else ["part", "--defects", "0.015"]
        assert main(["-q", "synth", *preset, "--binning", "4", "--noise", "low", "--seed", str(seed), "--name", name,
                     "-o", str(d)]) == 0
    cal_path = d / "cal_binned4.json"
    RingCalibration.from_optics(load_device("prototype").binned(4)).save(cal_path)
    return d, cal_path


def make_folder(d: Path, root: Path) -> tuple[Path, list[str]]:
    """50 frames in nested folders, 3 of them corrupt."""
    good = [f"f{i:02d}.png" if i < 20 else f"sub/f{i:02d}.png" if i < 40 else f"sub/deeper/f{i:02d}.png"
            for i in range(N_FRAMES - len(CORRUPT))]
    for i, rel in enumerate(good):
        copy_frame(d / ("scene.png" if i % 2 == 0 else "part.png"), root / rel)
    data = (d / "scene.png").read_bytes()
    (root / CORRUPT[0]).write_bytes(data[: len(data) // 2])
    shutil.copyfile(d / "scene.png.json", root / (CORRUPT[0] + ".json"))
    (root / CORRUPT[1]).write_bytes(b"")
    shutil.copyfile(d / "scene.png.json", root / (CORRUPT[1] + ".json"))
    (root / CORRUPT[2]).write_bytes(b"this is not a TIFF file\n" * 10)
    return root, good


def copy_frame(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(src, dst)
    shutil.copyfile(str(src) + ".json", str(dst) + ".json")


def digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def expected_refocus(frame: Path, cal_path: Path, depth_m: float, method: str = "depth-aware") -> np.ndarray:
    """What the batch writes for ``frame`` refocused at ``depth_m`` with its default settings:
    lfring.refocus with the batch's default method (depth-aware, from a depth map estimated with
    estimate_depth's defaults over the calibration's range), 8-bit sRGB."""
    from lfring import RingCalibration, demosaic, load_raw, split_views
    from lfring.focus import refocus
    from lfring.io.writers import encode_image

    cal = RingCalibration.load(cal_path)
    views = split_views(demosaic(load_raw(frame)), cal.layout)
    from lfring.core.warping import DEFAULT_INTERPOLATION

    return encode_image(refocus(views, cal, depth_m, interpolation=DEFAULT_INTERPOLATION, method=method), 8, "srgb")


def load_calibration(p):
    from lfring import RingCalibration

    return RingCalibration.load(p)

