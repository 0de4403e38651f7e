"""The install extras: the core runs ``register`` and its report without the workbench's
server stack, ``biplanar-reg workbench`` without it is a one-line error naming the install
command, and the ``test`` extra pulls in both extras the suite uses."""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
#: Where the workbench's server stack may be imported.
SERVER_IMPORTERS = ("biplanar_reg/workbench/", "biplanar_reg/cli/workbench.py")
#: Python run first in a child process: the extras' modules cannot be imported, as on a machine
#: with the core install only.
HIDE_EXTRAS = (
    "import sys\n"
    "for name in ('starlette', 'uvicorn', 'dask', 'distributed', 'dask_jobqueue'):\n"
    "    sys.modules[name] = None\n"
)


def _names(requirements: list[str]) -> set[str]:
    """The distribution names of requirement strings (without extras and versions)."""
    return {re.match(r"[A-Za-z0-9_.-]+", r).group(0).lower() for r in requirements}


def _run(code: str, tmp_path: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", HIDE_EXTRAS + code],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=300,
    )


def test_the_core_has_no_server_or_cluster_stack():
    core = _names(PROJECT["dependencies"])
    extras = PROJECT["optional-dependencies"]
    assert _names(extras["workbench"]) == {"starlette", "uvicorn"}
    assert _names(extras["cluster"]) == {"dask", "dask-jobqueue"}
    assert not core & (_names(extras["workbench"]) | _names(extras["cluster"]))
    assert "jinja2" in core  # the report's templates


def test_the_test_extra_pulls_in_both_extras():
    test = set(PROJECT["optional-dependencies"]["test"])
    for extra in ("workbench", "cluster"):
        assert set(PROJECT["optional-dependencies"][extra]) <= test, extra


def test_only_the_workbench_imports_the_server_stack():
    found = []
    for path in sorted((ROOT / "biplanar_reg").rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        if rel.startswith(SERVER_IMPORTERS):
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            found += [f"{rel}: {n}" for n in names if n.split(".")[0] in ("starlette", "uvicorn")]
    assert found == []


def test_register_and_its_report_run_without_the_extras(tmp_path):
    case = ROOT / "sample_cases" / "synthetic_demo"
    out = tmp_path / "out"
    code = (
        "import biplanar_reg, biplanar_reg.cases, biplanar_reg.cli\n"
        "from biplanar_reg.cli import main\n"
        f"code = main(['register', {str(case)!r}, '--out', {str(out)!r}])\n"
        "print(code, 'starlette' in sys.modules and sys.modules['starlette'] is not None)\n"
    )
    run = _run(code, tmp_path)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip().splitlines()[-1] == "0 False"
    assert (out / "result.json").is_file() and (out / "report.html").is_file()


def test_the_workbench_without_its_extra_is_a_one_line_error(tmp_path):
    case = ROOT / "sample_cases" / "synthetic_demo"
    code = (
        "from biplanar_reg.cli import main\n"
        f"raise SystemExit(main(['workbench', {str(case)!r}, '--no-browser']))\n"
    )
    run = _run(code, tmp_path)
    assert run.returncode == 2, run.stderr
    err = run.stderr.strip().splitlines()
    assert err == [
        "error: biplanar-reg workbench needs starlette and uvicorn (the workbench extra): "
        "pip install 'biplanar-reg[workbench]'"
    ], run.stderr
    assert not (case / ".workbench.lock").exists()


def released_version(changelog: str) -> str | None:
    """The first version heading of a changelog (``## 0.2.0``), past an ``## Unreleased``
    section of changes not released yet."""
    heads = re.findall(r"^## (\S+)", changelog, re.MULTILINE)
    heads = heads[1:] if heads[:1] == ["Unreleased"] else heads
    return heads[0] if heads else None


def test_released_version_skips_only_a_leading_unreleased_section():
    assert released_version("# C\n\n## Unreleased\n\nx\n\n## 0.2.0\n") == "0.2.0"
    assert released_version("# C\n\n## 0.3.0\n\n## 0.2.0\n") == "0.3.0"
    assert released_version("# C\n\n## 0.2.0\n\n## Unreleased\n") == "0.2.0"
    assert released_version("# C\n") is None


def test_the_changelog_names_this_version():
    text = (ROOT / "CHANGELOG.md").read_text(encoding="utf-8")
    assert released_version(text) == PROJECT["version"]
