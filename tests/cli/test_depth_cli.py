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
    # Each float map says what it holds without its json.
    with tifffile.TiffFile(out / "scene_depth.tiff") as tif:
        words = json.loads(tif.pages[0].description)
    assert (words["quantity"], words["unit"], words["unknown"]) == ("depth", "m", "NaN")
    with tifffile.TiffFile(out / "scene_confidence.tiff") as tif:
        assert json.loads(tif.pages[0].description)["range"] == [0, 1]
    assert 0 <= conf.min() and conf.max() <= 1
    # The cup (0.3 m) fills the upper left of view 0 in the sample scene.
    assert abs(np.nanmedian(depth[200:300, 150:250]) - 0.3) < 0.005
    pts, cols = read_ply(out / "scene_points.ply")
    side = json.loads((out / "scene_depth.json").read_text())
    assert len(pts) == side["points"] > 50_000 and cols.shape == (len(pts), 3)
    assert 0.29 < np.median(pts[:, 2]) < 1.0
    assert (out / "scene_depth_preview.png").read_bytes()[:4] == b"\x89PNG"
    assert (side["cost"], side["method"], side["rim_taper"]) == ("lcn-halves", "sgm", 0.05)
    # The median confidence of the pixels with a depth (the unseen rim, confidence 0, left out).
    assert side["confidence_median"] == pytest.approx(float(np.median(conf[np.isfinite(depth)])))
    assert side["confidence_median"] > float(np.median(conf))
    # The pinhole the json gives turns the map into the points (a downstream user has no other way
    # to: the depth is from the main lens, the projection centre s in front of it).
    cam = side["points_camera"]
    assert side["min_confidence"] == 0.5 and cam["device"] == "prototype" and cam["focal_px"] == pytest.approx(1981.6, abs=0.1)
    rows, cols_ = np.nonzero(np.isfinite(depth) & (conf >= 0.5))
    z = depth[rows, cols_].astype(np.float64)
    s = cam["depth_origin_m"]
    xy = np.asarray(cam["centre_m"][:2]) + (np.stack([cols_, rows], axis=1) - cam["principal_point_px"]) * ((z - s) / cam["focal_px"])[:, None]
    np.testing.assert_allclose(pts, np.column_stack([xy, z]), atol=1e-6)
    # The same command again replaces its own files; other settings do not without --overwrite.
    assert main(["depth", str(SCENE), "--zmin", "0.3", "--zmax", "1.0", "-o", str(out), "--paths", "8"]) == 2
    assert "exists" in capsys.readouterr().err


@pytest.mark.parametrize(
    "args, text",
    # The CLI names its options (--zmax, --planes, --rim-taper, --method), not the library's
    # parameters (zmax_m, num_planes, rim_taper, method=).
    [
        (["--zmin", "1.0", "--zmax", "0.5"], "smaller than --zmax"),
        (["--zmin", "0.01", "--zmax", "0.5"], "depth origin"),
        (["--zmin", "0.3", "--zmax", "0.5", "--planes", "0"], "--planes"),
        (["--zmin", "0.3", "--zmax", "0.5", "--reference", "9"], "reference"),
        (["--zmin", "0.3", "--zmax", "0.5", "--rim-taper", "1.5"], "--rim-taper"),
        (["--zmin", "0.3", "--zmax", "0.5", "--rim-taper", "nan"], "--rim-taper"),
        (["--zmin", "0.3", "--zmax", "0.5", "--cost", "lcn-halves", "--method", "local"], "needs --method sgm"),
        (["--zmin", "0.3", "--zmax", "0.5", "--method", "local", "--paths", "8"], "belong to --method sgm"),
        (["--zmin", "0.3", "--zmax", "0.5", "--method", "local", "--consistency"], "belong to --method sgm"),
        (["--zmin", "0.3", "--zmax", "0.5", "--planes", "2"], "--planes must be an integer >= 3"),
        (["--zmin", "0.3", "--zmax", "0.35", "--planes", "3"], "give --planes >= "),
        (["--zmin", "0.3", "--zmax", "0.5", "--paths", "6"], "'6' is not one of"),
        (["--zmin", "0.3", "--zmax", "0.5", "--threads", "0"], "--threads"),
        (["--zmin", "0.3", "--zmax", "0.5", "--min-confidence", "-5"], "--min-confidence"),
        (["--zmin", "nan", "--method", "local"], "--zmin must be a distance in metres > 0 (finite), got nan"),
        # Millimetres given as metres: every method refuses a range the views do not move across.
        (["--zmin", "300", "--zmax", "1000", "--method", "local"],
         "the views move by 0.0073 px across it, too little to tell any depth in it from another; widen it; depths "
         "are in metres: were 300 and 1000 given in mm?"),
        (["--zmin", "300", "--zmax", "1000"], "were 300 and 1000 given in mm?"),
        (["--zmin", "3", "--zmax", "3.001", "--method", "local"], "too little to tell any depth"),
        # A file's name where the output folder goes (it became a folder of that name).
        (["--zmin", "0.3", "--zmax", "0.5", "-o", "out.ply"], "-o names the folder the outputs go to, got the file name 'out.ply'"),
    ],
)
def test_depth_cli_errors(tmp_path, capsys, args, text, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["depth", str(SCENE), *args, "-o", str(tmp_path / "o")][:None if "-o" not in args else -2]) == 2
    err = capsys.readouterr().err
    assert text in err and "Traceback" not in err
    assert not (tmp_path / "out.ply").exists()


def test_an_output_folder_named_like_a_file_is_taken_when_said_to_be_a_folder(tmp_path, monkeypatch):
    """-o out.ply/ (the slash says: a folder) is a folder, as is an out.ply folder that exists."""
    monkeypatch.chdir(tmp_path)
    assert main(["depth", str(SCENE), "--zmin", "0.3", "--zmax", "1.0", "--method", "local", "-o", "out.ply/"]) == 0
    assert (tmp_path / "out.ply" / "scene_depth.tiff").exists()


def test_a_point_cloud_from_no_device_and_an_empty_one_are_warned_of(tmp_path, capsys):
    """A calibration that names no device gives the point cloud the prototype's optics, which
    may not be the camera's: said as a warning (it was an info line), and the json names the
    device. A --min-confidence that leaves no pixel writes an empty cloud, and says so."""
    import dataclasses

    from lfring import RingCalibration

    cal = RingCalibration.load("twin_binned2")
    cal = dataclasses.replace(cal, device=None, provenance={k: v for k, v in cal.provenance.items() if k != "device_record"})
    path = cal.save(tmp_path / "nodev.json")
    assert main(["depth", str(SCENE), "--calib", str(path), "--zmin", "0.3", "--zmax", "1.0", "--method", "local",
                 "--min-confidence", "1.0", "-o", str(tmp_path / "o")]) == 0
    err = capsys.readouterr().err
    assert "WARNING: the calibration names no device and no --device-file was given: the point cloud's X and Y use the " \
           "prototype's optics, which may not be this camera's" in err
    assert "WARNING: no pixel has a depth at --min-confidence 1 or more: the point cloud is empty" in err
    side = json.loads((tmp_path / "o" / "scene_depth.json").read_text())
    assert side["points"] == 0 and side["points_camera"]["device"] == "prototype"


def _lfring(*args, cwd):
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-m", "lfring", *map(str, args)], capture_output=True, text=True, cwd=cwd,
                          timeout=600)


def test_depth_range_defaults_to_the_calibrations_as_refocus_does(tmp_path):
    scene = Path(__file__).resolve().parents[2] / "data" / "synthetic" / "scene.png"
    proc = _lfring("depth", scene, "--method", "local", "-o", "d", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    meta = json.loads((tmp_path / "d" / "scene_depth.json").read_text())
    assert (meta["zmin_m"], meta["zmax_m"]) == (0.3, 1.0)  # the built-in calibration's valid range


def test_depth_refuses_a_range_of_very_many_planes_and_warns_of_many(tmp_path):
    """What the user typed: --zmin 0.03 (for 0.3) swept 1541 planes for 43 s without a word."""
    scene = Path(__file__).resolve().parents[2] / "data" / "synthetic" / "scene.png"
    proc = _lfring("depth", scene, "--zmin", "0.03", "--zmax", "1.0", "-o", "d", cwd=tmp_path)
    assert proc.returncode == 2 and "depth planes" in proc.stderr and "typo" in proc.stderr and "--planes" in proc.stderr
    assert "valid range is 0.3 to 1 m" in proc.stderr and not (tmp_path / "d").exists()
    from lfring.cli.depth import MANY_PLANES, MAX_PLANES

    assert MANY_PLANES < MAX_PLANES


def test_torch_device_is_named_so_and_not_ignored(tmp_path):
    scene = Path(__file__).resolve().parents[2] / "data" / "synthetic" / "scene.png"
    proc = _lfring("depth", scene, "--method", "local", "--torch-device", "cuda", "-o", "d", cwd=tmp_path)
    assert proc.returncode == 2 and "goes with --backend torch" in proc.stderr
    old = _lfring("depth", scene, "--method", "local", "--device", "cuda", "-o", "d", cwd=tmp_path)
    assert old.returncode == 2 and "--device is now --torch-device" in old.stderr and "goes with --backend torch" in old.stderr
    assert "--torch-device" in _lfring("depth", "--help", cwd=tmp_path).stdout


def test_first_compile_is_announced_once(tmp_path, monkeypatch, caplog):
    """numba compiles the kernels on their first use, once per machine: said while a module the
    command compiles has no cached kernel, silent once every one has."""
    import logging
    import sys

    from lfring.cli._options import note_first_compile

    pkg = tmp_path / "fakepkg"
    (pkg / "__pycache__").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    for stem in ("engine", "kernels"):
        (pkg / f"{stem}.py").write_text("")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    tag = f"py{sys.version_info.major}{sys.version_info.minor}"
    modules = ("fakepkg.engine", "fakepkg.kernels")
    for cached, said in (((), True), (("kernels",), True), (("kernels", "engine"), False)):
        for stem in cached:
            (pkg / "__pycache__" / f"{stem}.run-12.{tag}.nbi").write_bytes(b"")
        caplog.clear()
        with caplog.at_level(logging.INFO, logger="lfring"):
            note_first_compile(modules)
        assert ("compiling the numerical kernels once" in caplog.text) == said, cached


def test_the_first_compile_note_names_the_modules_the_main_job_compiles(tmp_path):
    """The note's list of kernel modules is the one the default depth-aware refocus compiles
    (a module it never compiles would keep the note on at every run; one it missed would leave
    the first run's wait unexplained)."""
    import subprocess
    import sys

    from lfring.cli._options import DEPTH_KERNELS, REFOCUS_KERNELS

    script = "\n".join((
        "import sys",
        "from numba.core.dispatcher import Dispatcher",
        "from lfring.cli.main import main",
        "try:",
        f"    main(['-q', 'refocus', {str(SCENE)!r}, '--depth', '0.5', '-o', {str(tmp_path / 'r.png')!r}])",
        "except SystemExit as e:",
        "    assert not e.code, e.code",
        "print(sorted({n for n, m in list(sys.modules.items()) if n.startswith('lfring.') for v in vars(m).values()",
        "              if isinstance(v, Dispatcher) and v.signatures and v.py_func.__module__ == n}))",
    ))
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    compiled = res.stdout.strip().splitlines()[-1]
    assert compiled == str(sorted(REFOCUS_KERNELS))
    assert set(DEPTH_KERNELS) == {m for m in REFOCUS_KERNELS if m.startswith("lfring.depth.")}


def test_a_recorded_device_without_lens_positions_skips_the_point_cloud(tmp_path, capsys):
    """A calibration made with a device file that holds no lens positions (z0 given by hand)
    keeps that record; its point cloud cannot be made (the views' pinholes follow from b and c):
    the depth maps are written and the cloud is left out with a warning, as for a device that does
    not load, not refused after the whole estimate."""
    import dataclasses

    from lfring import RingCalibration
    from lfring.optics import load_device

    cal = RingCalibration.load("twin_binned2")
    dev = dataclasses.replace(load_device("prototype"), name="mine", ring_distance_m=None, sensor_distance_m=None)
    cal = dataclasses.replace(cal, device="mine", provenance={**cal.provenance, "device_record": dev.to_dict()})
    path = cal.save(tmp_path / "mine.json")
    out = tmp_path / "o"
    assert main(["depth", str(SCENE), "--calib", str(path), "--zmin", "0.3", "--zmax", "1.0", "--method", "local",
                 "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "device 'mine' has no lens positions (ring_distance_m, sensor_distance_m), which metric points need" in err
    assert "the point cloud is not written" in err
    assert (out / "scene_depth.tiff").exists() and not (out / "scene_points.ply").exists()
    assert json.loads((out / "scene_depth.json").read_text())["points_camera"] is None
