"""Files given where a calibration belongs that are no calibration at all (an image, a layout,
a device description, a record of outputs, a sidecar, a JSON list): each is refused as not a
calibration and named as what it is, in words a user reads (no Python values, no codec), while a
real calibration of an unreadable file version still says the version problem."""

import json
from pathlib import Path

import pytest

from lfring.calibration.build import calibration_from_grid
from lfring.calibration.jsonio import (
    calibration_from_dict,
    calibration_to_dict,
    load_calibration,
)
from lfring.cli.main import main
from lfring.errors import FileFormatError

DATA = Path(__file__).resolve().parents[2] / "data" / "synthetic"
NOT_A_CALIBRATION = "not an lfring calibration file: "
PYTHON_WORDS = ("None", "codec", "utf-8", "lfring_calibration_version", "Traceback", "dict", "NoneType")


def _refusal(path) -> str:
    with pytest.raises(FileFormatError) as err:
        load_calibration(path)
    message = str(err.value)
    assert message.startswith(f"{path}: ")
    assert not any(w in message for w in PYTHON_WORDS), message
    return message


@pytest.mark.parametrize("content, says", [
    (b'{"a": 1}', "it holds a JSON object without a calibration's keys"),
    (b"[1, 2]", "it holds a JSON list"),
    (b"3", "it holds a JSON number"),
    (b'"twin_binned2"', "it holds a JSON string"),
    (b"null", "it holds JSON null"),
    (b"true", "it holds JSON true or false"),
    (b"", "it is empty"),
    (b'{"a": 1,\n "b": ', "it is not valid JSON (line 2, column 7)"),
    (b"\x89PNG\r\n\x1a\n" + bytes(range(256)), "it is a PNG image"),
    (b"II*\x00" + bytes(range(256)), "it is a TIFF image"),
    (b"MM\x00*" + bytes(range(256)), "it is a TIFF image"),
    (b"\xff\xd8\xff\xe0" + bytes(range(256)), "it is a JPEG image"),
    (b"\x00\x01\xfe\xff", "it is a binary file, not JSON text"),
    (b'{"lfring_batch_record": 1, "status": "done", "outputs": {}}', "it looks like the record lfring keeps"),
])
def test_a_file_that_is_no_calibration_is_named_as_what_it_is(tmp_path, content, says):
    path = tmp_path / "given.json"
    path.write_bytes(content)
    assert _refusal(path).startswith(f"{path}: {NOT_A_CALIBRATION}{says}")


def test_a_layout_and_a_device_description_are_told_by_their_keys(tmp_path, prototype):
    message = _refusal(DATA / "scene_truth" / "layout.json")
    assert f"{NOT_A_CALIBRATION}it looks like a layout file" in message
    device = prototype.to_dict()
    for i, content in enumerate((device, {"device": device})):  # a device file may hold one [device] table
        path = tmp_path / f"device{i}.json"
        path.write_text(json.dumps(content))
        assert f"{NOT_A_CALIBRATION}it looks like a device description" in _refusal(path)


def test_a_sidecar_is_told_by_the_image_beside_it(tmp_path):
    side = tmp_path / "scene.png.json"
    side.write_text((DATA / "scene.png.json").read_text())
    assert "without a calibration's keys" in _refusal(side)  # no image beside it: nothing more to say
    (tmp_path / "scene.png").write_bytes(b"\x89PNG\r\n\x1a\n")
    assert f"{NOT_A_CALIBRATION}it looks like the sidecar of the image scene.png" in _refusal(side)


def test_an_image_given_as_a_calibration_is_named_an_image():
    message = _refusal(DATA / "flat.png")
    assert message.startswith(f"{DATA / 'flat.png'}: {NOT_A_CALIBRATION}it is a PNG image; give a calibration file")


@pytest.mark.parametrize("version, says", [
    (3, "a calibration of file version 3, written by a newer lfring; this lfring reads versions 1 and 2"),
    (0, "a calibration of file version 0; this lfring reads versions 1 and 2"),
    ("2", 'its calibration file version is "2", not a version number; this lfring reads versions 1 and 2'),
    (None, "its calibration file version is null, not a version number; this lfring reads versions 1 and 2"),
])
def test_a_calibration_of_another_version_says_the_version(version, says):
    data = calibration_to_dict(calibration_from_grid((8, 8), [(0, 0), (1, 0)], disparity_scale_px_m=1.0))
    data["lfring_calibration_version"] = version
    with pytest.raises(FileFormatError) as err:
        calibration_from_dict(data, source_name="c.json")
    assert str(err.value) == f"c.json: {says}"
    assert NOT_A_CALIBRATION not in str(err.value)


def test_a_calibration_without_its_version_is_told_the_key():
    """A hand-edited calibration (its model's keys are there) that lost its file version is not
    mistaken for another kind of file: the missing key is named."""
    data = calibration_to_dict(calibration_from_grid((8, 8), [(0, 0), (1, 0)], disparity_scale_px_m=1.0))
    del data["lfring_calibration_version"]
    with pytest.raises(FileFormatError, match=r"^c\.json: missing key 'lfring_calibration_version' \(the file "
                                              r"version, 2 in the files this lfring writes\)$"):
        calibration_from_dict(data, source_name="c.json")


@pytest.mark.parametrize("given, says", [
    ("bad.json", "it holds a JSON object without a calibration's keys"),
    (str(DATA / "scene_truth" / "layout.json"), "it looks like a layout file"),
    (str(DATA / "flat.png"), "it is a PNG image"),
])
def test_calib_option_refuses_a_file_that_is_no_calibration(tmp_path, monkeypatch, capsys, given, says):
    """The command stops at the calibration, before any frame is read: exit 2, one line."""
    monkeypatch.chdir(tmp_path)
    Path("bad.json").write_text('{"a": 1}')
    assert main(["refocus", str(DATA / "scene.png"), "--depth", "0.5", "--method", "shift-and-add",
                 "--calib", given, "-o", "c1.png"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"lfring: error: {given}: {NOT_A_CALIBRATION}{says}") and err.count("\n") == 1
    assert not any(w in err for w in PYTHON_WORDS), err
    assert not Path("c1.png").exists()


def test_a_folder_given_for_a_calibration_or_layout_file_is_named_a_folder(tmp_path):
    """Saving to a folder raised Python's IsADirectoryError from the atomic writer; loading one
    said the file was not found, though the path exists."""
    from lfring.calibration import RingCalibration
    from lfring.errors import InvalidInputError, LfringFileNotFoundError

    cal = RingCalibration.load("twin_binned2")
    for save in (cal.save, cal.layout.save):
        with pytest.raises(InvalidInputError, match="it is a folder; give a file name"):
            save(tmp_path)
    with pytest.raises(LfringFileNotFoundError, match="is a folder; give the file's path"):
        RingCalibration.load(tmp_path)
    assert list(tmp_path.iterdir()) == []  # nothing written beside
