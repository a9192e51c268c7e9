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


def _python_block():
    text = (ROOT / "README.md").read_text()
    section = text.split("\n## Python\n", 1)[1].split("\n## ", 1)[0]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_readme_python_block_runs_and_its_outputs_are_true(monkeypatch, capsys):
    """The README's Python section runs as written from the repository root; what each print
    shows is the '# -> ' comment that follows it, and its results match the twin's ground truth."""
    import numpy as np

    code = _python_block()
    expected = [line.split("# -> ", 1)[1].split("  ", 1)[0].strip() for line in code.splitlines() if "# -> " in line]
    assert len(expected) == code.count("print(") == 2
    monkeypatch.chdir(ROOT)
    namespace = {"__name__": "readme"}
    exec(compile(code, "README.md (Python)", "exec"), namespace)
    printed = capsys.readouterr().out.splitlines()
    assert printed == expected
    assert namespace["image"].shape == (1842, 2456, 3)
    assert namespace["views"].shape == (4, 705, 705, 3) and namespace["views"].dtype == np.float32
    assert namespace["book"].shape == (705, 705, 3)
    book_depth = float(np.nanmedian(namespace["depth"].depth_m[300:400, 450:550]))
    assert abs(book_depth - 0.5) < 0.01  # the scene's book is at 0.5 m
    report = namespace["report"]
    assert report.verdict == "fail"
    # part_defects: a bump of +15 mm and a dent of -15 mm (data/synthetic/manifest.json)
    assert [d.kind for d in report.defects] == ["bump", "dent"]
    np.testing.assert_allclose([d.deviation_m for d in report.defects], [0.015, -0.015], atol=0.003)
