"""The ``lfring`` script's exit: the code it returns is the process's, whatever the interpreter
remembers of a Ctrl-C it handled."""

import subprocess
import sys
import textwrap

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
