"""Built-in calibrations by name: RingCalibration.load('twin_binned2') reads the file shipped in
calib/ (the package lfring._calib); paths and existing files keep their meaning."""

import json
from pathlib import Path

import numpy as np
import pytest

from lfring.calibration import RingCalibration, builtin_calibrations
from lfring.errors import LfringFileNotFoundError

CALIB = Path(__file__).resolve().parents[2] / "calib"


def test_builtin_calibrations_lists_the_shipped_json_files():
    shipped = {p.stem: p for p in CALIB.glob("*.json")}
    names = builtin_calibrations()
    assert set(names) == set(shipped) and {"prototype_optics", "twin_binned2"} <= set(names)
    for name, path in shipped.items():
        data = json.loads(path.read_text())
        assert names[name] == (data["raw_width_px"], data["raw_height_px"])


@pytest.mark.parametrize("name", ["twin_binned2", "prototype_optics"])
def test_load_by_name_equals_load_by_path(name):
    by_name = RingCalibration.load(name)
    by_path = RingCalibration.load(CALIB / f"{name}.json")
    assert by_name.raw_size == by_path.raw_size == builtin_calibrations()[name]
    assert by_name.source == by_path.source
    np.testing.assert_array_equal(by_name.homographies(0.5), by_path.homographies(0.5))
    np.testing.assert_array_equal(by_name.model.A, by_path.model.A)


def test_unknown_name_lists_the_builtin_names():
    with pytest.raises(LfringFileNotFoundError, match=r"no built-in calibration of that name.*prototype_optics, twin_binned2"):
        RingCalibration.load("twin_binned3")


@pytest.mark.parametrize("path", ["twin_binned2.json", "missing/twin_binned2", "./twin_binned2"])
def test_paths_and_json_names_are_files_not_builtin_names(path, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(LfringFileNotFoundError, match="calibration file not found") as err:
        RingCalibration.load(path)
    assert "built-in" not in str(err.value)


def test_an_existing_file_wins_over_the_builtin_name(tmp_path, monkeypatch):
    other = RingCalibration.load("prototype_optics")
    monkeypatch.chdir(tmp_path)
    other.save(tmp_path / "twin_binned2")
    cal = RingCalibration.load("twin_binned2")
    assert cal.raw_size == other.raw_size == (4912, 3684)


def test_cli_calib_option_takes_a_builtin_name(tmp_path, monkeypatch, capsys):
    from lfring.cli.main import main

    scene = CALIB.parent / "data" / "synthetic" / "scene.png"
    monkeypatch.chdir(tmp_path)
    assert main(["check", str(scene), "--calib", "twin_binned2"]) == 0
    assert "calibration  twin_binned2 (2456 x 1842 px, 4 views)" in capsys.readouterr().out
    assert main(["check", str(scene), "--calib", "twin_binned9", "--overwrite"]) == 2
    assert "built-in: prototype_optics, twin_binned2" in capsys.readouterr().err
