"""The ``lfring`` script's exit: the code it returns is the process's, whatever the interpreter
remembers of a Ctrl-C it handled."""

import signal
import subprocess
import sys
import textwrap
import types
import weakref

import click
import pytest
from child_processes import default_sigint

from lfring.cli.main import COMMANDS, Terminated, main
from lfring.errors import InvalidInputError

SCRIPT = textwrap.dedent('''
    import sys
    import types

    import click

    from lfring.cli.main import COMMANDS, main

    @click.command("interrupted")
    def command():
        # As Ctrl-C during an import that builds a dataclass: the KeyboardInterrupt escapes code
        # run from a string.
        exec("raise KeyboardInterrupt")

    sys.modules["lfring.cli.interrupted"] = types.SimpleNamespace(command=command)
    COMMANDS["interrupted"] = "interrupted"
    sys.exit(main())
''')


def test_ctrl_c_inside_code_run_from_a_string_still_exits_130(tmp_path):
    (tmp_path / "lfring_script.py").write_text(SCRIPT)
    # Run as a module, as `python -m lfring` runs: that is where CPython checks its mark.
    proc = subprocess.run([sys.executable, "-m", "lfring_script", "interrupted"], capture_output=True, text=True,
                          timeout=120, cwd=tmp_path)
    # CPython kills itself with SIGINT at exit (-2 here) when it thinks such an interrupt went
    # unhandled; main handled it.
    assert proc.returncode == 130, (proc.returncode, proc.stderr)
    assert proc.stderr.strip() == "lfring: aborted"


# A stop that comes while a file is open and not yet in a `with` (between `open` and the block,
# in our code or in pathlib's reads): the unwinding drops the file unclosed.
DROPPED = textwrap.dedent('''
    import os
    import signal
    import sys
    import types

    import click

    from lfring.cli.main import COMMANDS, main

    @click.command("dropped")
    @click.argument("sig")
    def command(sig):
        f = open(sys.executable, "rb")
        os.kill(os.getpid(), getattr(signal, sig))
        f.close()

    sys.modules["lfring.cli.dropped"] = types.SimpleNamespace(command=command)
    COMMANDS["dropped"] = "dropped"
    sys.exit(main())
''')


@pytest.mark.parametrize("sig, code, line", [("SIGTERM", 143, "lfring: terminated"), ("SIGINT", 130, "lfring: aborted")])
def test_a_file_a_stop_drops_unclosed_is_not_reported(tmp_path, sig, code, line):
    """Under warnings as errors, the script stopped while a file is open exits with its code and
    its one line, without the ResourceWarning's traceback."""
    (tmp_path / "lfring_script.py").write_text(DROPPED)
    env = {"PYTHONWARNINGS": "error", "PATH": "/usr/bin:/bin"}
    proc = subprocess.run([sys.executable, "-m", "lfring_script", "dropped", sig], capture_output=True, text=True,
                          timeout=120, cwd=tmp_path, env=env, preexec_fn=default_sigint)
    assert proc.returncode == code, (proc.returncode, proc.stderr)
    assert proc.stderr.strip() == line


# As the interpreter's loader when Ctrl-C comes while it reads a module's file: the file object
# is dropped unclosed in a frame of importlib's own module.
LEAK = textwrap.dedent('''
    import sys

    loader = {"__name__": "importlib._bootstrap_external"}
    exec("def get_data(path):\\n    f = open(path, 'rb')\\n    del f\\n", loader)
    if sys.argv[1] == "after-main":
        from lfring.cli.main import main

        own = sys.argv[2:]
        sys.argv[1:] = ["--version"]
        main()
        sys.argv[1:] = own or ["loader"]
    if sys.argv[-1] == "own":  # a file dropped by code of any other module
        f = open(sys.executable, "rb")
        del f
    else:
        loader["get_data"](sys.executable)
    print("done")
''')


def test_an_unclosed_file_of_the_interpreters_loader_is_not_reported(tmp_path):
    """Under warnings as errors, the ResourceWarning of a file the interpreter's loader dropped
    (Ctrl-C inside an import) is reported, except after the script's main has run; its own code's
    warnings stay errors."""
    (tmp_path / "leak.py").write_text(LEAK)
    env = {"PYTHONWARNINGS": "error", "PATH": "/usr/bin:/bin"}

    def run(*which):
        return subprocess.run([sys.executable, "leak.py", *which], capture_output=True, text=True, timeout=120,
                              cwd=tmp_path, env=env)

    before = run("alone")
    assert "ResourceWarning" in before.stderr  # the leak is reported without lfring's filter
    after = run("after-main")
    assert after.returncode == 0 and "done" in after.stdout
    assert "ResourceWarning" not in after.stderr and "Traceback" not in after.stderr, after.stderr
    assert "ResourceWarning" in run("after-main", "own").stderr


def test_a_single_valued_option_given_twice_is_refused(tmp_path, capsys):
    """click keeps the last of a repeated option without a word; a user who wrote two depths
    meant both. Refused before any work, naming both values; repeatable options and flags may
    repeat."""
    from lfring.cli.main import main

    from pathlib import Path

    scene = str(Path(__file__).resolve().parents[2] / "data" / "synthetic" / "scene.png")
    out = tmp_path / "b"
    assert main(["batch", scene, "-o", str(out), "--refocus", "0.5", "--refocus=0.7", "--method", "shift-and-add"]) == 2
    err = capsys.readouterr().err
    assert "--refocus is given twice (0.5 and 0.7): give it once (lfring batch --help says which options repeat)" in err
    assert not out.exists()
    assert main(["refocus", scene, "-q", "--depth", "0.5", "--method", "shift-and-add", "-o", str(tmp_path / "r.png"),
                 "-o", str(tmp_path / "s.png")]) == 2
    assert f"-o is given twice ({tmp_path / 'r.png'} and {tmp_path / 's.png'})" in capsys.readouterr().err
    assert main(["batch", scene, "-o", str(out), "--refocus", "0.5", "--method", "shift-and-add", "--exclude", "x*",
                 "--exclude", "y*", "--no-progress", "--no-progress", "-q"]) == 0


def test_a_folder_or_a_quoted_pattern_given_as_a_frame_is_named_as_such(tmp_path, capsys):
    """Every command that reads one frame says that a folder is one, and that a quoted pattern
    was not expanded; those whose work lfring batch does over many frames point there, with the
    batch option that does it. A file whose name holds a pattern's characters is read."""
    import shlex
    import shutil
    from pathlib import Path

    from lfring.cli.main import main

    data = Path(__file__).resolve().parents[2] / "data" / "synthetic"
    pattern = str(tmp_path / "*.png")
    batch = {"refocus": "--refocus Z", "depth": "--depth", "view": "--viewer"}
    for command in ("refocus", "depth", "view", "check", "split", "inspect"):
        for given, words in ((str(tmp_path), "is a folder: give one frame"),
                             (pattern, "no such file (a quoted pattern is not expanded here)")):
            assert main([command, given]) == 2
            err = capsys.readouterr().err
            assert f"{given}: {words}" in err or f"{given} {words}" in err, err
            hint = f"lfring batch {shlex.quote(given)} -o OUTDIR {batch[command]}" if command in batch else "lfring batch"
            assert (hint in err) == (command in batch), err
    # The hints name batch's own options.
    from lfring.cli._options import BATCH_COMMANDS

    assert BATCH_COMMANDS == batch
    assert main(["batch", "--help"]) == 0
    batch_help = capsys.readouterr().out
    assert all(f"{option.split()[0]} " in batch_help for option in batch.values())
    odd = tmp_path / "scene[1].png"
    shutil.copy(data / "scene.png", odd)
    shutil.copy(data / "scene.png.json", tmp_path / "scene[1].png.json")
    assert main(["check", str(odd), "-o", str(tmp_path / "check.png")]) == 0


def _command_building_a_class(stop):
    """A command stopped by ``stop`` while it builds a class, as Ctrl-C can stop an import whose
    module defines a class with a ``functools.cached_property``: the descriptor's
    ``__set_name__`` raises it (Python 3.10 and 3.11 raise a RuntimeError from it)."""

    @click.command("interrupted")
    def command():
        class Stopped:
            def __set_name__(self, owner, name):
                raise stop

        type("Built", (), {"attribute": Stopped()})

    return command


@pytest.mark.parametrize("stop, code, line", [(KeyboardInterrupt, 130, "lfring: aborted"),
                                              (Terminated, 143, "lfring: terminated")])
def test_ctrl_c_while_an_import_builds_a_class_exits_as_ctrl_c(monkeypatch, capsys, stop, code, line):
    monkeypatch.setitem(sys.modules, "lfring.cli.interrupted", types.SimpleNamespace(command=_command_building_a_class(stop)))
    monkeypatch.setitem(COMMANDS, "interrupted", "interrupted")
    assert main(["interrupted"]) == code
    assert capsys.readouterr().err.strip() == line


def test_an_error_raised_from_something_else_is_not_taken_for_ctrl_c(monkeypatch):
    monkeypatch.setitem(sys.modules, "lfring.cli.interrupted",
                        types.SimpleNamespace(command=_command_building_a_class(ValueError("a bug"))))
    monkeypatch.setitem(COMMANDS, "interrupted", "interrupted")
    with pytest.raises((RuntimeError, ValueError)) as info:
        main(["interrupted"])
    assert "a bug" in str(info.value) + str(info.value.__cause__)


def _command_losing_a_stop(stop, completed: list):
    """A command during which ``stop`` comes inside a weakref callback (as a Ctrl-C that lands in
    the callback of an import's module lock), where Python cannot raise it."""

    @click.command("interrupted")
    def command():
        class Held:
            pass

        held = Held()

        def callback(ref):
            raise stop()

        ref = weakref.ref(held, callback)  # noqa: F841 (kept alive: the callback runs at the del)
        del held
        for _ in range(1000):
            pass
        completed.append(True)

    return command


@pytest.mark.parametrize("stop, code, line", [(KeyboardInterrupt, 130, "lfring: aborted"),
                                              (Terminated, 143, "lfring: terminated")])
def test_ctrl_c_inside_a_weakref_callback_still_stops_the_command(monkeypatch, capsys, stop, code, line):
    completed = []
    monkeypatch.setitem(sys.modules, "lfring.cli.interrupted", types.SimpleNamespace(command=_command_losing_a_stop(stop, completed)))
    monkeypatch.setitem(COMMANDS, "interrupted", "interrupted")
    hook = sys.unraisablehook
    assert main(["interrupted"]) == code
    # One line, no "Exception ignored" traceback; the stop is delivered when the command is
    # over (an output set's commit would have delivered it before writing anything).
    assert capsys.readouterr().err.strip() == line
    assert completed == [True]
    assert sys.unraisablehook is hook


def test_other_exceptions_in_a_weakref_callback_are_reported_as_before(monkeypatch):
    seen = []
    monkeypatch.setattr(sys, "unraisablehook", lambda u: seen.append(u.exc_type))
    completed = []
    monkeypatch.setitem(sys.modules, "lfring.cli.interrupted",
                        types.SimpleNamespace(command=_command_losing_a_stop(ValueError, completed)))
    monkeypatch.setitem(COMMANDS, "interrupted", "interrupted")
    assert main(["interrupted"]) == 0
    assert seen == [ValueError] and completed == [True]


def test_a_lost_stop_waits_for_the_commit_point_and_is_delivered_once():
    from lfring.core.signals import deliver_lost_stops, held_signals, redelivered_stops

    class Held:
        pass

    def callback(ref):
        raise KeyboardInterrupt()

    cleaned = []
    with redelivered_stops():
        held = Held()
        ref = weakref.ref(held, callback)  # noqa: F841
        del held  # lost here: Python cannot raise from the callback
        with held_signals():  # cleanup that must not be cut (stopping workers) still runs
            cleaned.append(True)
        with pytest.raises(KeyboardInterrupt):
            deliver_lost_stops()  # where an output set or a batch frame would commit
        deliver_lost_stops()  # once
    assert cleaned == [True]


def test_an_error_raised_from_a_ctrl_c_in_a_weakref_callback_is_kept_too(monkeypatch, capsys):
    # Python 3.10 and 3.11 turn a KeyboardInterrupt inside __set_name__ into a RuntimeError
    # caused by it (lfring.core.signals.interrupt_behind): lost in a callback, it stops too.
    def raise_wrapped():
        try:
            raise KeyboardInterrupt()
        except KeyboardInterrupt as exc:
            raise RuntimeError("Error calling __set_name__") from exc

    completed = []
    monkeypatch.setitem(sys.modules, "lfring.cli.interrupted",
                        types.SimpleNamespace(command=_command_losing_a_stop(raise_wrapped, completed)))
    monkeypatch.setitem(COMMANDS, "interrupted", "interrupted")
    assert main(["interrupted"]) == 130
    assert capsys.readouterr().err.strip() == "lfring: aborted"


def _command_whose_library_forgets_a_stop(signum, error):
    """A command in which ``signum`` comes inside a library that catches every exception and
    raises ``error`` in its place, with no trace of the stop: as matplotlib's image resampling,
    cut by a Ctrl-C while it converts a matrix, reports an invalid transformation matrix."""

    @click.command("interrupted")
    def command():
        failed = False
        try:
            signal.raise_signal(signum)
        except BaseException:  # noqa: BLE001 - what the library does
            failed = True
        if failed:
            raise error

    return command


@pytest.mark.parametrize("signum, code, line", [(signal.SIGINT, 130, "lfring: aborted"),
                                                (signal.SIGTERM, 143, "lfring: terminated")])
@pytest.mark.parametrize("error", [ValueError("Invalid affine transformation matrix"), OSError("cannot write"),
                                   InvalidInputError("not a frame")], ids=["ValueError", "OSError", "LfringError"])
def test_a_stop_that_a_library_turned_into_its_own_error_still_stops(monkeypatch, capsys, signum, code, line, error):
    monkeypatch.setitem(sys.modules, "lfring.cli.interrupted",
                        types.SimpleNamespace(command=_command_whose_library_forgets_a_stop(signum, error)))
    monkeypatch.setitem(COMMANDS, "interrupted", "interrupted")
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        assert main(["interrupted"]) == code
        assert capsys.readouterr().err.strip() == line
        # The handlers are the caller's again, and the next command's errors are its own.
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL
        monkeypatch.setitem(sys.modules, "lfring.cli.interrupted",
                            types.SimpleNamespace(command=_command_building_a_class(ValueError("a bug"))))
        with pytest.raises((RuntimeError, ValueError)):
            main(["interrupted"])
    finally:
        signal.signal(signal.SIGINT, previous)


def test_a_stop_stands_behind_the_errors_of_its_own_command_only(monkeypatch, capsys):
    """A stop that came in one command is that command's: a command run inside another, or after
    it in the caller's own block, does not pass it on to the other's genuine errors; nor does it
    hide another exception that Python can only report."""
    from lfring.core.signals import raise_stop, redelivered_stops

    inner = _command_whose_library_forgets_a_stop(signal.SIGINT, ValueError("Invalid affine transformation matrix"))

    @click.command("outer")
    def outer():
        assert main(["interrupted"]) == 130  # its handlers are the outer command's
        raise ValueError("a bug of the outer command")

    monkeypatch.setitem(sys.modules, "lfring.cli.interrupted", types.SimpleNamespace(command=inner))
    monkeypatch.setitem(sys.modules, "lfring.cli.outer", types.SimpleNamespace(command=outer))
    monkeypatch.setitem(COMMANDS, "interrupted", "interrupted")
    monkeypatch.setitem(COMMANDS, "outer", "outer")
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(ValueError, match="a bug of the outer command"):
            main(["outer"])
        with redelivered_stops():  # a caller's own block around two commands
            assert main(["interrupted"]) == 130
            monkeypatch.setitem(sys.modules, "lfring.cli.interrupted",
                                types.SimpleNamespace(command=_command_building_a_class(ValueError("a bug"))))
            with pytest.raises((RuntimeError, ValueError)):
                main(["interrupted"])
            # A stop kept in this block does not take another unraisable exception for itself.
            try:
                raise_stop()
            except KeyboardInterrupt:
                pass
            seen = []
            monkeypatch.setattr(sys, "unraisablehook", lambda u: seen.append(u.exc_type))
            with redelivered_stops():
                class Held:
                    pass

                def callback(ref):
                    raise ValueError("reported")

                held = Held()
                ref = weakref.ref(held, callback)  # noqa: F841
                del held
            assert seen == [ValueError]
    finally:
        signal.signal(signal.SIGINT, previous)


def test_a_stop_that_a_library_swallowed_whole_still_stops_the_command(monkeypatch, capsys):
    """A library that clears the stop it met and goes on (no error at all): the command still
    stops, as where it would commit its work, and says so."""
    went_on = []

    @click.command("interrupted")
    def command():
        try:
            signal.raise_signal(signal.SIGINT)
        except KeyboardInterrupt:
            pass  # what such a library does
        went_on.append(True)

    monkeypatch.setitem(sys.modules, "lfring.cli.interrupted", types.SimpleNamespace(command=command))
    monkeypatch.setitem(COMMANDS, "interrupted", "interrupted")
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        assert main(["interrupted"]) == 130
        assert capsys.readouterr().err.strip() == "lfring: aborted"
        # Delivered once: the next command runs as usual.
        monkeypatch.setitem(sys.modules, "lfring.cli.interrupted",
                            types.SimpleNamespace(command=click.command("interrupted")(lambda: None)))
        assert main(["interrupted"]) == 0
    finally:
        signal.signal(signal.SIGINT, previous)
    assert went_on == [True]


def test_a_stop_kept_around_a_command_is_not_that_commands(monkeypatch, capsys):
    """A stop kept by a block around a command (the caller's, or the command that runs it) is
    neither delivered in the inner command nor used up by it: the inner command runs as usual,
    and the outer one still stops at its own commit point."""
    from lfring.core.signals import deliver_lost_stops, raise_stop, redelivered_stops

    monkeypatch.setitem(sys.modules, "lfring.cli.noop", types.SimpleNamespace(command=click.command("noop")(lambda: None)))
    monkeypatch.setitem(COMMANDS, "noop", "noop")
    with redelivered_stops():
        try:
            raise_stop()  # swallowed by the caller's own code
        except KeyboardInterrupt:
            pass
        assert main(["noop"]) == 0
        with pytest.raises(KeyboardInterrupt):
            deliver_lost_stops()  # still the caller's, at its own commit point

    @click.command("outer")
    def outer():
        try:
            signal.raise_signal(signal.SIGINT)
        except KeyboardInterrupt:
            pass  # a library that swallows the stop
        assert main(["noop"]) == 0

    monkeypatch.setitem(sys.modules, "lfring.cli.outer", types.SimpleNamespace(command=outer))
    monkeypatch.setitem(COMMANDS, "outer", "outer")
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        assert main(["outer"]) == 130
    finally:
        signal.signal(signal.SIGINT, previous)
    assert capsys.readouterr().err.strip() == "lfring: aborted"
