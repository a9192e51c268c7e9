"""The README is the front door: its two commands are what CI runs."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _quick_start_commands():
    text = (ROOT / "README.md").read_text()
    block = text.split("## Quick start", 1)[1]
    code = re.search(r"```bash\n(.*?)```", block, re.S).group(1)
    return [line for line in code.splitlines() if line.strip()]


def test_readme_has_two_commands_and_ci_runs_them():
    cmds = _quick_start_commands()
    assert len(cmds) == 2
    assert "pip install -c constraints.txt" in cmds[0]
    assert "pytest" in cmds[1]
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    for cmd in cmds:
        assert cmd in ci, f"README command not run verbatim by .ci/run: {cmd}"


def test_constraints_pin_torch():
    pins = (ROOT / "constraints.txt").read_text()
    assert re.search(r"^torch==\d+\.\d+\.\d+$", pins, re.M)


def test_packages_listed_in_pyproject_are_complete():
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib

    py = tomllib.loads((ROOT / "pyproject.toml").read_text())
    listed = set(py["tool"]["setuptools"]["packages"])
    found = {
        ".".join(p.parent.relative_to(ROOT).parts)
        for p in (ROOT / "lfring").rglob("__init__.py")
    }
    assert found - listed == set(), f"packages missing from pyproject: {found - listed}"
    assert "lfring._calib" in listed


def test_import_does_not_pull_torch():
    import subprocess
    import sys

    code = "import sys, lfring, lfring.optics, lfring.synth; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    assert out.stdout.strip() == "False"
