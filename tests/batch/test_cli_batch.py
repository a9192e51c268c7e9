"""`lfring batch`: failures named once, exit codes, usage errors."""

import pytest
from batch_frames import CORRUPT, N_FRAMES, make_folder, render_frames

from lfring.cli.main import main


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    """Two rendered 4 x 4 binned frames of the twin (1228 x 921 px) and an optics calibration."""
    return render_frames(tmp_path_factory.mktemp("render"))


@pytest.fixture
def folder(frames, tmp_path):
    """50 frames in nested folders, 3 of them corrupt."""
    d, _ = frames
    return make_folder(d, tmp_path / "in")


def test_cli_batch_names_failures_and_exits_1(frames, folder, tmp_path, capsys):
    _, cal_path = frames
    root, _ = folder
    out = tmp_path / "out"
    code = main(["batch", str(root), "-o", str(out), "--refocus", "0.5", "--calib", str(cal_path), "--workers", "1",
                 "--interpolation", "linear", "--no-progress"])
    assert code == 1
    captured = capsys.readouterr()
    # Each failure is printed once, as it happens: "lfring: ERROR: PATH: why".
    failed = [line for line in captured.err.splitlines() if line.startswith("lfring: ERROR: ")]
    assert sorted(line.split(": ")[2] for line in failed) == sorted(str(root / c) for c in CORRUPT)
    for c in CORRUPT:
        assert captured.err.count(str(root / c)) == 1
    assert f"{N_FRAMES} frames: {N_FRAMES - 3} done, 0 skipped (already done), 3 failed" in captured.out
    # Rerun: all good frames skipped, exit 1 again for the corrupt ones.
    assert main(["batch", str(root), "-o", str(out), "--refocus", "0.5", "--calib", str(cal_path), "--workers", "1",
                 "--interpolation", "linear", "--no-progress"]) == 1
    assert f"0 done, {N_FRAMES - 3} skipped" in capsys.readouterr().out


@pytest.mark.parametrize(
    "args, text",
    [
        ([], "nothing to do"),
        (["--refocus", "0.5", "--zmin", "0.3"], "go with --depth"),
        (["--depth"], "--zmin and --zmax"),
        (["--refocus", "0.5", "--workers", "0"], "workers"),
        (["--refocus", "abc"], "comma-separated"),
        (["--refocus", "0.5", "--reference", "7"], "reference"),
    ],
)
def test_cli_usage_errors_exit_2(frames, tmp_path, capsys, args, text):
    d, cal_path = frames
    assert main(["batch", str(d / "scene.png"), "-o", str(tmp_path / "o"), "--calib", str(cal_path), *args]) == 2
    err = capsys.readouterr().err
    assert text in err and "Traceback" not in err
    assert main(["batch", str(tmp_path / "nothing_here"), "-o", str(tmp_path / "o"), "--refocus", "0.5"]) == 2
    assert "no such file" in capsys.readouterr().err
