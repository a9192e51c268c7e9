"""Each command's outputs appear as a set or not at all: an interrupted command leaves nothing
(the user's SIGINT 2 s into `lfring depth`, and into a focal sweep), the rerun completes, and a
rerun with the same inputs and settings replaces the command's own files."""

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from child_processes import default_sigint, handles_sigterm

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT / "data" / "synthetic" / "scene.png"




def _interrupt(cmd, cwd, delay_s, sig):
    proc = subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=default_sigint)
    t0 = time.monotonic()
    while not handles_sigterm(proc.pid) and proc.poll() is None and time.monotonic() - t0 < 60:
        time.sleep(0.005)
    time.sleep(delay_s)
    if proc.poll() is None:
        proc.send_signal(sig)
    _, err = proc.communicate(timeout=30)
    return proc.returncode, err


def _files(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file()) if folder.exists() else []


DEPTH_SET = ["scene_confidence.tiff", "scene_depth.json", "scene_depth.lfring.json", "scene_depth.pfm", "scene_depth.tiff",
             "scene_depth_preview.png", "scene_points.ply"]


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs Linux /proc to see the command start")
def test_interrupted_depth_leaves_nothing_and_the_rerun_completes(tmp_path):
    cmd = [sys.executable, "-m", "lfring", "depth", str(SCENE), "--zmin", "0.3", "--zmax", "1.0", "--method", "local",
           "-o", "d/"]
    rng = random.Random(4)
    for i, sig in enumerate([signal.SIGINT, signal.SIGTERM]):
        shutil.rmtree(tmp_path / "d", ignore_errors=True)
        code, err = _interrupt(cmd, tmp_path, rng.uniform(0.0, 2.5) if i else 2.0, sig)
        assert "Traceback" not in err
        files = _files(tmp_path / "d")
        if code == 0:  # done before the signal came: the whole set
            assert files == DEPTH_SET
        else:  # nothing partial, no staging folder either; the whole set if the signal came at its commit
            assert code == 128 + sig, err
            assert files in ([], DEPTH_SET), f"{sig.name} left {files}"
    rerun = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert rerun.returncode == 0, rerun.stderr
    assert _files(tmp_path / "d") == DEPTH_SET
    # The same command once more replaces its own set.
    again = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    rec = json.loads((tmp_path / "d" / "scene_depth.lfring.json").read_text())
    assert rec["command"] == "lfring depth" and rec["status"] == "done" and sorted(rec["outputs"]) == [
        f for f in DEPTH_SET if f != "scene_depth.lfring.json"]
    # Other settings, or a file it did not make, need --overwrite.
    other = subprocess.run([*cmd[:-2], "--min-confidence", "0.9", "-o", "d/"], cwd=tmp_path, capture_output=True, text=True,
                           timeout=300)
    assert other.returncode == 2 and "with other settings; pass --overwrite" in other.stderr
    (tmp_path / "d" / "scene_depth.lfring.json").unlink()
    foreign = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert foreign.returncode == 2 and "exists; pass --overwrite" in foreign.stderr


@pytest.mark.parametrize("sig, code, line", [(signal.SIGINT, 130, "lfring: aborted"),
                                             (signal.SIGTERM, 143, "lfring: terminated")])
def test_a_stop_inside_the_previews_drawing_stops_the_command(tmp_path, capsys, monkeypatch, sig, code, line):
    """matplotlib converts a transformation to a matrix with its own Python code, inside C++ that
    catches every error and reports an invalid matrix: a signal that comes there still stops the
    command as itself, with nothing written."""
    import matplotlib.transforms

    from lfring.cli.main import main

    to_matrix = matplotlib.transforms.AffineBase.__array__
    came = []

    def signalled(self, *args, **kwargs):
        if not came:
            came.append(sig)
            signal.raise_signal(sig)
        return to_matrix(self, *args, **kwargs)

    monkeypatch.setattr(matplotlib.transforms.AffineBase, "__array__", signalled)
    monkeypatch.chdir(tmp_path)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        assert main(["depth", str(SCENE), "--zmin", "0.3", "--zmax", "1.0", "--method", "local", "-o", "d/"]) == code
    finally:
        signal.signal(signal.SIGINT, previous)
    assert came == [sig]
    assert capsys.readouterr().err.strip().splitlines()[-1] == line
    assert [str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*")] in ([], ["d"])  # nor a staging folder


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs Linux /proc to see the command start")
def test_interrupted_focal_sweep_leaves_nothing(tmp_path):
    cmd = [sys.executable, "-m", "lfring", "refocus", str(SCENE), "--sweep", "0.3:1.0:8", "--method", "shift-and-add",
           "-o", "stack/scene.png"]
    for delay, sig in ((1.0, signal.SIGINT), (2.0, signal.SIGTERM)):
        shutil.rmtree(tmp_path / "stack", ignore_errors=True)
        code, err = _interrupt(cmd, tmp_path, delay, sig)
        files = _files(tmp_path / "stack")
        assert "Traceback" not in err
        if code != 0:
            # Nothing, or the whole set when the signal came as it was committed (held until
            # then, it still ends the process): never a part of it, nor a staging folder.
            assert code == 128 + sig, err
            assert files == [] or (len(files) == 8 * 2 + 3 and "scene_stack.png.lfring.json" in files), files
        else:
            assert len(files) == 8 * 2 + 3
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    files = _files(tmp_path / "stack")
    assert len(files) == 8 * 2 + 3 and "scene_stack.tif" in files and "scene_stack.gif" in files
    assert "scene_stack.png.lfring.json" in files


def test_a_stop_while_the_staging_folder_is_removed_waits_for_it(tmp_path, capsys, monkeypatch):
    """Ctrl-C that comes as the staging folder is removed (the outputs already in place) is
    delivered after: the folder is gone, the outputs are whole, and the command says it stopped."""
    from lfring.cli import outputs
    from lfring.cli.main import main

    real = outputs.shutil.rmtree
    came = []

    def cut(path, *args, **kwargs):
        if not came and Path(path).name.startswith(outputs.STAGING_PREFIX):
            came.append(True)
            signal.raise_signal(signal.SIGINT)
        return real(path, *args, **kwargs)

    monkeypatch.setattr(outputs.shutil, "rmtree", cut)
    monkeypatch.chdir(tmp_path)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        code = main(["refocus", str(SCENE), "--depth", "0.5", "--method", "shift-and-add", "-o", "r.png"])
    finally:
        signal.signal(signal.SIGINT, previous)
    assert came == [True] and code == 130
    assert capsys.readouterr().err.strip().splitlines()[-1] == "lfring: aborted"
    assert sorted(os.listdir(tmp_path)) == ["r.png", "r.png.json", "r.png.lfring.json"]


def test_a_failing_command_leaves_no_staging_folder(tmp_path, capsys, monkeypatch):
    """An error while writing (here a full disk) removes what was staged and names the user's file."""
    from lfring.cli.main import main
    from lfring.io import writers

    def full(*args, **kwargs):
        raise OSError(28, "No space left on device", str(args[0]))

    monkeypatch.setattr(writers.cv2, "imwrite", full)
    monkeypatch.chdir(tmp_path)
    assert main(["refocus", str(SCENE), "--depth", "0.5", "--method", "shift-and-add"]) == 2
    err = capsys.readouterr().err
    assert "No space left on device" in err and ".lfring-stage" not in err
    assert os.listdir(tmp_path) == []


def test_a_folder_that_cannot_be_written_is_named_by_the_output(tmp_path, capsys, monkeypatch):
    """Where the staging folder cannot be made (a read-only file system), the error names the
    user's output, not the hidden folder."""
    import tempfile

    from lfring.cli.main import main

    def refused(*args, **kwargs):
        raise PermissionError(1, "Operation not permitted", str(tmp_path / ".lfring-stage-1-x"))

    monkeypatch.setattr(tempfile, "mkdtemp", refused)
    out = tmp_path / "r.png"
    assert main(["refocus", str(SCENE), "--depth", "0.5", "--method", "shift-and-add", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"cannot write there (Operation not permitted): {out}" in err and ".lfring-stage" not in err
    assert os.listdir(tmp_path) == []


def test_an_output_folder_that_cannot_be_made_is_said_so(tmp_path, capsys, monkeypatch):
    """Where the output folder cannot be made (under /proc, a read-only mount) the error says so,
    naming it (it said "No such file or directory: /proc/out" for a folder the user asked for)."""
    from lfring.cli.main import main

    real_mkdir = Path.mkdir
    out = tmp_path / "ro" / "out"

    def mkdir(self, *args, **kwargs):
        if self == out:
            raise FileNotFoundError(2, "No such file or directory", str(self))
        return real_mkdir(self, *args, **kwargs)

    monkeypatch.setattr(Path, "mkdir", mkdir)
    assert main(["split", str(SCENE), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"cannot create the output folder (No such file or directory): {out}" in err


def test_outputs_of_one_stem_and_two_formats_have_records_of_their_own(tmp_path, capsys):
    """a.png and a.tif are two output sets: each one's rerun replaces only its own files."""
    from lfring.cli.main import main

    run = ["refocus", str(SCENE), "--depth", "0.5", "--method", "shift-and-add", "-o"]
    for name in ("a.png", "a.tif", "a.png", "a.tif"):
        assert main([*run, str(tmp_path / name)]) == 0, capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "a.png", "a.png.json", "a.png.lfring.json", "a.tif", "a.tif.json", "a.tif.lfring.json"]


def test_a_set_replaced_with_overwrite_leaves_none_of_its_files_behind(tmp_path, capsys):
    """A 4-depth sweep replaced by a 2-depth one with --overwrite: the first set's files that
    the second does not make were left beside it, not in its record (a folder holding two
    stacks). They go; a file the record does not list stays."""
    from lfring.cli.main import main

    out = tmp_path / "stack"
    run = ["refocus", str(SCENE), "--method", "shift-and-add", "-o", str(out / "scene.png")]
    assert main([*run, "--sweep", "0.3:1.0:4"]) == 0, capsys.readouterr().err
    first = _files(out)
    (out / "notes.txt").write_text("mine\n")
    assert main([*run, "--sweep", "0.3:1.0:2", "--overwrite"]) == 0
    err = capsys.readouterr().err
    record = json.loads((out / "scene_stack.png.lfring.json").read_text())
    listed = set(record["outputs"].values())
    assert set(_files(out)) == listed | {"scene_stack.png.lfring.json", "notes.txt"}
    gone = sorted(set(first) - listed - {"scene_stack.png.lfring.json"})
    assert gone and all(not (out / f).exists() for f in gone)  # the first set's 0.533 and 0.767 m images
    assert f"removed {len(gone)} files of the set this run replaced" in err
    assert (out / "notes.txt").read_text() == "mine\n"


def test_only_a_set_that_is_replaced_loses_its_files_and_only_those_as_it_made_them(tmp_path, capsys):
    """The files of a set's record go only with --overwrite, when the new run shares outputs
    with that set, and only as the record found them: a stack whose record name a single image
    shares (x.png's stack and x_stack.png) lost all its frames to a run without --overwrite, and
    a frame replaced since by another command went too."""
    from lfring.cli.main import main

    sa = ["refocus", str(SCENE), "--method", "shift-and-add"]
    assert main([*sa, "--sweep", "0.4:0.8:3", "-o", str(tmp_path / "x.png")]) == 0
    stack = _files(tmp_path)
    assert main([*sa, "--depth", "0.5", "-o", str(tmp_path / "x_stack.png")]) == 0
    assert set(stack) - {"x_stack.png.lfring.json"} <= set(_files(tmp_path))  # every frame of the stack kept
    assert "removed" not in capsys.readouterr().err
    # A frame the user rewrote (or another command wrote) since the record: kept on --overwrite.
    out = tmp_path / "y"
    assert main([*sa, "--sweep", "0.4:0.8:3", "-o", str(out / "y.png")]) == 0
    mine = out / "y_001_0.6m.png"
    mine.write_bytes(b"mine")
    assert main([*sa, "--sweep", "0.4:0.8:2", "-o", str(out / "y.png"), "--overwrite"]) == 0
    assert mine.read_bytes() == b"mine" and not (out / "y_001_0.6m.png.json").exists()


def test_outputs_are_written_where_the_folder_cannot_be_locked(tmp_path, capsys, monkeypatch):
    """flock on a folder fails on NFS (EBADF) and without a lock daemon (ENOLCK): the command
    goes on with the check alone, as where the system has no such locks."""
    import errno

    fcntl = pytest.importorskip("fcntl")
    from lfring.cli.main import main

    def no_lock(fd, op):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(fcntl, "flock", no_lock)
    assert main(["refocus", str(SCENE), "--depth", "0.5", "--method", "shift-and-add", "-o", str(tmp_path / "a.png")]) == 0
    assert (tmp_path / "a.png").exists()


def test_a_command_that_finds_its_outputs_written_by_another_while_it_worked_does_not_replace_them(
        tmp_path, capsys, monkeypatch):
    """Two commands into one output with other settings: the second to finish replaced the
    first's image and record without a word (each had checked before the other wrote). The
    outputs are checked again right before they are renamed into place."""
    from lfring.cli.main import main
    from lfring.focus import shift_and_add

    out = tmp_path / "r.png"
    original = shift_and_add.Refocuser.__call__
    ran = []

    def meanwhile(self, views):  # the other command runs to its end while this one works
        if not ran:
            ran.append(subprocess.run([sys.executable, "-m", "lfring", "refocus", str(SCENE), "--depth", "0.8", "--method",
                                       "shift-and-add", "-o", str(out)], capture_output=True, text=True, timeout=300))
        return original(self, views)

    monkeypatch.setattr(shift_and_add.Refocuser, "__call__", meanwhile)
    assert main(["refocus", str(SCENE), "--depth", "0.5", "--method", "shift-and-add", "-o", str(out)]) == 2
    assert ran and ran[0].returncode == 0, ran[0].stderr
    err = capsys.readouterr().err
    assert f"{out} exists and was made by lfring refocus with other settings; pass --overwrite" in err
    assert json.loads((tmp_path / "r.png.json").read_text())["depth_m"] == 0.8
    assert json.loads((tmp_path / "r.png.lfring.json").read_text())["settings"]["depth"] == 0.8
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.png", "r.png.json", "r.png.lfring.json"]


def test_a_record_under_its_former_name_still_counts_once(tmp_path, capsys):
    """Outputs whose record an earlier lfring named after the output's stem are still this
    command's own on a rerun; the record then takes its present name."""
    from lfring.cli.main import main

    run = ["refocus", str(SCENE), "--depth", "0.5", "--method", "shift-and-add", "-o", str(tmp_path / "a.png")]
    assert main(run) == 0
    (tmp_path / "a.png.lfring.json").rename(tmp_path / "a.lfring.json")
    assert main(run) == 0, capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png", "a.png.json", "a.png.lfring.json"]
    # A former record that lists other outputs is not this set's: left alone, and no licence.
    (tmp_path / "a.png.lfring.json").unlink()
    (tmp_path / "a.lfring.json").write_text(json.dumps({"lfring_batch_record": 1, "outputs": {"x.png": "x.png"}}))
    assert main(run) == 2
    assert "a.png (and 1 more) exists; pass --overwrite" in capsys.readouterr().err
    assert (tmp_path / "a.lfring.json").exists()


def test_an_output_that_is_an_input_is_refused(tmp_path, capsys):
    """-o naming the raw frame (by any path) is refused, even with --overwrite, and the frame
    stays as it was."""
    from lfring.cli.main import main

    raw = tmp_path / "scene.png"
    shutil.copy(SCENE, raw)
    before = raw.read_bytes()
    for out in (raw, tmp_path / "." / "scene.png"):
        assert main(["refocus", str(raw), "--depth", "0.5", "--method", "shift-and-add", "-o", str(out), "--overwrite"]) == 2
        assert "is an input of this command and would be one of its outputs" in capsys.readouterr().err
    assert main(["check", str(raw), "-o", str(raw), "--overwrite"]) == 2
    assert raw.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.png"]


def test_an_output_over_an_input_s_sidecar_is_refused(tmp_path, capsys):
    """-o naming a frame's sidecar (its pattern and levels: part of the input) is refused, even
    with --overwrite, whether the sidecar is there or not; the frame reads as before."""
    from lfring.cli.main import main

    for name in ("target_0.3m.png", "target_1m.png"):
        shutil.copy(SCENE.parent / name, tmp_path / name)
    shutil.copy(SCENE.parent / "target_1m.png.json", tmp_path / "target_1m.png.json")
    before = (tmp_path / "target_1m.png.json").read_bytes()
    frames = [str(tmp_path / "target_0.3m.png"), str(tmp_path / "target_1m.png"), "--depths", "0.3", "1.0"]
    for out in ("target_1m.png.json", "target_0.3m.png.json"):
        assert main(["calibrate", *frames, "-o", str(tmp_path / out), "--overwrite"]) == 2
        err = " ".join(capsys.readouterr().err.split())
        assert f"{tmp_path / out} (the sidecar of {tmp_path / out[:-5]}) is an input of this command" in err
    assert (tmp_path / "target_1m.png.json").read_bytes() == before
    assert not (tmp_path / "target_0.3m.png.json").exists()


def test_a_rerun_from_other_input_files_says_so(tmp_path, capsys):
    """Outputs made from one file and asked again from another name both files, not a change."""
    from lfring.cli.main import main

    other = tmp_path / "copy.png"
    shutil.copy(SCENE, other)
    out = str(tmp_path / "r.png")
    assert main(["refocus", str(SCENE), "--depth", "0.5", "--method", "shift-and-add", "-o", out]) == 0
    assert main(["refocus", str(other), "--depth", "0.5", "--method", "shift-and-add", "-o", out]) == 2
    err = capsys.readouterr().err
    assert "from other input files" in err and str(SCENE) in err and str(other) in err and "changed" not in err
    os.utime(SCENE, ns=(SCENE.stat().st_atime_ns, SCENE.stat().st_mtime_ns))  # untouched: the same identity
    assert main(["refocus", str(SCENE), "--depth", "0.5", "--method", "shift-and-add", "-o", out]) == 0


def test_a_rerun_that_spells_the_same_files_otherwise_is_the_same_run(tmp_path, capsys, monkeypatch):
    """scene.png, ./scene.png and the absolute path (from another folder) name one file, and
    -o out.png and -o ./out.png one output: a rerun is a rerun, not another input."""
    from lfring.cli.main import main

    shutil.copy(SCENE, tmp_path / "scene.png")
    shutil.copy(str(SCENE) + ".json", tmp_path / "scene.png.json")
    run = ["--depth", "0.5", "--method", "shift-and-add"]
    monkeypatch.chdir(tmp_path)
    assert main(["refocus", "scene.png", *run, "-o", "out.png"]) == 0
    made = (tmp_path / "out.png").stat().st_mtime_ns
    assert main(["refocus", "./scene.png", *run, "-o", "./out.png"]) == 0, capsys.readouterr().err
    (tmp_path / "sub").mkdir()
    monkeypatch.chdir(tmp_path / "sub")
    assert main(["refocus", str(tmp_path / "scene.png"), *run, "-o", "../out.png"]) == 0, capsys.readouterr().err
    assert (tmp_path / "out.png").exists() and made > 0
    # Another file is still another input.
    shutil.copy(SCENE, tmp_path / "other.png")
    shutil.copy(str(SCENE) + ".json", tmp_path / "other.png.json")
    assert main(["refocus", str(tmp_path / "other.png"), *run, "-o", "../out.png"]) == 2
    assert "from other input files" in capsys.readouterr().err


def test_every_command_s_output_options_are_known_as_outputs():
    """The rule that tells outputs from inputs knows every command's -o and --plot parameter."""
    import click

    from lfring.cli.main import cli
    from lfring.cli.outputs import OUTPUT_OPTIONS

    seen = set()
    ctx = click.Context(cli)
    for name in cli.list_commands(ctx):
        for p in cli.get_command(ctx, name).params:
            if isinstance(p, click.Option) and {"-o", "--plot"} & set(p.opts):
                assert p.name in OUTPUT_OPTIONS, (name, p.name)
                seen.add(p.name)
    assert seen == set(OUTPUT_OPTIONS)


def test_a_file_another_command_wrote_since_is_not_replaced_by_the_record_that_made_it_first(tmp_path, capsys):
    """A stack, then a single image written over its first frame with --overwrite: the stack's
    rerun without --overwrite trusted its own record, which still listed the frame, and replaced
    the single image (whose record then described a file it no longer was). The rerun is refused
    now, naming the file, and the single image and its record stay as they were."""
    from lfring.cli.main import main

    sa = ["refocus", str(SCENE), "--method", "shift-and-add"]
    stack = [*sa, "--sweep", "0.3:1.0:3", "-o", str(tmp_path / "s.png")]
    assert main(stack) == 0, capsys.readouterr().err
    frame = tmp_path / "s_000_0.3m.png"
    assert main([*sa, "--depth", "0.3", "--interpolation", "cubic", "-o", str(frame), "--overwrite"]) == 0
    single = frame.read_bytes()
    capsys.readouterr()
    assert main(stack) == 2
    err = capsys.readouterr().err
    assert f"{frame} exists and was written since lfring refocus made it" in err and "--overwrite" in err
    assert frame.read_bytes() == single
    assert json.loads((tmp_path / "s_000_0.3m.png.lfring.json").read_text())["settings"]["interpolation"] == "cubic"
    assert main([*sa, "--depth", "0.3", "--interpolation", "cubic", "-o", str(frame)]) == 0  # its own rerun
    assert frame.read_bytes() == single
    assert main([*stack, "--overwrite"]) == 0  # asked to: the stack takes the frame back
    assert frame.read_bytes() != single


def test_a_rerun_on_a_copy_that_lost_its_times_is_the_same_run(tmp_path, capsys, monkeypatch):
    """A frame and its output whose times changed but whose contents did not are the same
    input and this command's output; a frame of the same size with another content is not."""
    from lfring.cli.main import main

    monkeypatch.chdir(tmp_path)
    shutil.copy(SCENE, tmp_path / "scene.png")
    shutil.copy(str(SCENE) + ".json", tmp_path / "scene.png.json")
    run = ["refocus", "scene.png", "--depth", "0.5", "--method", "shift-and-add", "-o", "out.png"]
    assert main(run) == 0
    for name in ("scene.png", "scene.png.json", "out.png"):
        st = (tmp_path / name).stat()
        os.utime(tmp_path / name, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    assert main(run) == 0, capsys.readouterr().err
    raw = bytearray((tmp_path / "scene.png").read_bytes())
    raw[-20] ^= 0xFF
    (tmp_path / "scene.png").write_bytes(bytes(raw))
    assert main(run) == 2
    assert "as it was before it (or its sidecar) changed" in capsys.readouterr().err


@pytest.mark.parametrize("stop", [KeyboardInterrupt, OSError])
def test_a_command_that_writes_nothing_leaves_no_folder_it_made(tmp_path, capsys, monkeypatch, stop):
    """Stopped (or failed) before its outputs were committed, a command removes the folders it
    made for them (an interrupted `lfring depth -o si/` left an empty si/); a folder that was
    there stays, and so does one that holds something else."""
    import lfring.io.writers
    from lfring.cli.main import main

    def broken(*args, **kwargs):
        raise stop(28, "No space left on device") if stop is OSError else stop()

    monkeypatch.setattr(lfring.io.writers, "write_image", broken)
    cmd = ["refocus", str(SCENE), "--depth", "0.5", "--method", "shift-and-add", "-o"]
    assert main([*cmd, str(tmp_path / "new" / "sub" / "a.png")]) in (2, 130)
    assert not (tmp_path / "new").exists()
    (tmp_path / "kept").mkdir()
    (tmp_path / "kept" / "other.txt").write_text("mine")
    assert main([*cmd, str(tmp_path / "kept" / "a.png")]) in (2, 130)
    assert _files(tmp_path / "kept") == ["other.txt"]
    capsys.readouterr()
