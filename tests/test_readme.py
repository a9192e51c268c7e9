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


def _supported_pythons():
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib

    py = tomllib.loads((ROOT / "pyproject.toml").read_text())
    versions = [c.rsplit(":: ", 1)[1] for c in py["project"]["classifiers"] if re.fullmatch(r".*:: 3\.\d+", c)]
    return py["project"]["requires-python"], sorted(versions, key=lambda v: tuple(map(int, v.split("."))))


def test_ci_runs_the_newest_and_the_oldest_supported_python():
    """CI installs as the README says on the newest Python the classifiers name and checks the
    oldest, which requires-python names."""
    requires, versions = _supported_pythons()
    assert requires == f">={versions[0]}"
    ci = (ROOT / ".ci" / "run").read_text()
    assert re.search(rf"^NEWEST={re.escape(versions[-1])}$", ci, re.M)
    assert re.search(rf"^OLDEST={re.escape(versions[0])}$", ci, re.M)
    assert 'PY_NEWEST=$(find_python "$NEWEST")\n"$PY_NEWEST" -m venv .ci-venv\n' in ci


def _newer_pythons():
    """Interpreters of Python 3.12 or newer that run on this machine (pyenv's, then PATH's)."""
    import glob
    import os
    import shutil
    import subprocess

    found = []
    root = os.environ.get("PYENV_ROOT", os.path.expanduser("~/.pyenv"))
    for minor in range(12, 20):
        candidates = [*sorted(glob.glob(os.path.join(root, "versions", f"3.{minor}.*", "bin", f"python3.{minor}"))),
                      shutil.which(f"python3.{minor}")]
        for exe in filter(None, candidates):  # a pyenv shim of a version not selected fails to run
            if subprocess.run([exe, "-c", "pass"], capture_output=True, timeout=60).returncode == 0:
                found.append(exe)
                break
    return found


def test_modules_import_without_deprecation_warnings_on_newer_pythons():
    """The test command turns warnings into errors: a module that imports a name deprecated in a
    newer Python (importlib.abc.Traversable from 3.12) fails every test there at collection.
    The stdlib-only modules are imported by every 3.12+ interpreter found here, warnings as errors."""
    import subprocess

    pythons = _newer_pythons()
    if not pythons:
        import pytest

        pytest.skip("no Python 3.12 or newer on this machine")
    code = ("import importlib.util, sys; spec = importlib.util.spec_from_file_location('lfring_resources', sys.argv[1]); "
            "m = importlib.util.module_from_spec(spec); spec.loader.exec_module(m); print(m.calib_dir())")
    for exe in pythons:
        out = subprocess.run([exe, "-W", "error", "-c", code, str(ROOT / "lfring" / "_resources.py")], capture_output=True,
                             text=True, timeout=60)
        assert out.returncode == 0, f"{exe}: {out.stderr}"


DEPRECATED_IMPORTS = {
    # module: names deprecated or removed in a Python that pyproject supports or will
    "importlib.abc": {"Traversable", "TraversableResources", "ResourceReader"},
    "datetime.datetime": {"utcnow", "utcfromtimestamp"},
    "pkg_resources": None,
    "imp": None,
    "distutils": None,
    "asyncore": None,
    "asynchat": None,
}


def test_no_module_imports_names_newer_pythons_deprecate():
    import ast

    bad = []
    for path in sorted([*(ROOT / "lfring").rglob("*.py"), *(ROOT / "tests").rglob("*.py"), *(ROOT / "examples").glob("*.py")]):
        tree = ast.parse(path.read_text(), str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module in DEPRECATED_IMPORTS:
                names = DEPRECATED_IMPORTS[node.module]
                if names is None or {a.name for a in node.names} & names:
                    bad.append(f"{path.relative_to(ROOT)}:{node.lineno}")
            elif isinstance(node, ast.Import):
                if any(a.name.split(".")[0] in DEPRECATED_IMPORTS and DEPRECATED_IMPORTS[a.name.split(".")[0]] is None
                       for a in node.names):
                    bad.append(f"{path.relative_to(ROOT)}:{node.lineno}")
            elif isinstance(node, ast.Attribute) and node.attr in {"utcnow", "utcfromtimestamp"}:
                bad.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert bad == []


def _more_commands():
    """The README's 'More commands' block: one command per entry (continuations joined,
    comments dropped)."""
    import shlex

    text = (ROOT / "README.md").read_text()
    block = re.search(r"More commands[^\n]*\n\n```bash\n(.*?)```", text, re.S).group(1)
    return [shlex.split(line, comments=True) for line in block.replace("\\\n", " ").splitlines() if line.strip()]


# The commands of the README run twice here: those whose rerun the README's readers hit (the
# main job, the third refocus line after the second, lfring check); the reruns of the others are
# in their own tests (tests/cli: output_sets for depth and the focal sweep, calibrate, design,
# raytrace, split, synth, inspect, view).
TWICE = ("refocus", "check")


def test_readme_commands_run_twice_in_a_row(tmp_path):
    """Each command of the README, run as written from a fresh folder, and then again: a rerun
    replaces what the command made a moment ago instead of refusing it."""
    import subprocess
    import sys

    (tmp_path / "data").symlink_to(ROOT / "data")
    main_job = shlex_split(_quick_start_commands()[0].split("&&", 1)[1])
    # Left out: commands that read a file another README command makes (not all of those run here).
    made = {c[c.index("-o") + 1] for c in _more_commands() if "-o" in c}
    reads_made = lambda c: any(a in made for i, a in enumerate(c) if c[i - 1] != "-o")  # noqa: E731
    commands = [main_job, *(c for c in _more_commands() if c[1] in TWICE and "--sweep" not in c and not reads_made(c))]
    assert [c[1] for c in commands[:4]] == ["refocus"] * 3 + ["check"]
    for round_ in (1, 2):
        for cmd in commands:
            assert cmd[0] == "lfring"
            proc = subprocess.run([sys.executable, "-m", "lfring", *cmd[1:]], cwd=tmp_path, capture_output=True, text=True,
                                  timeout=900)
            assert proc.returncode == 0, f"round {round_}: {' '.join(cmd)}:\n{proc.stderr}"
    assert (tmp_path / "scene_refocus_0.5m.png").exists() and (tmp_path / "scene_check.png").exists()
    assert (tmp_path / "scene_refocus_0.3m.png").exists() and (tmp_path / "scene_refocus_0.3m_shift-and-add.png").exists()


def shlex_split(text: str) -> list[str]:
    import shlex

    return shlex.split(text)
