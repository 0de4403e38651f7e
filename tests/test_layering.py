"""The import graph of the package: one-way layers, no private module of another package, a
command line that imports its commands (and the library) only when they run.

The checker parses every module with ``ast`` (nothing is imported), resolves relative imports
and checks three rules; it is itself tested on small fake trees so that it can fail.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

import biplanar_reg

PACKAGE = "biplanar_reg"
PACKAGE_DIR = Path(biplanar_reg.__file__).resolve().parent

#: Layer of each top-level module or package (README, "How data flows"): a module
#: may import its own package and lower layers only.
LAYERS: dict[str, int] = {
    "": 0,  # biplanar_reg/__init__.py: the version only (lazily, from _version)
    "_validate": 0,
    "_threads": 0,
    "_lazy": 0,
    "_content": 0,
    "_version": 0,
    "errors": 0,
    "io": 0,
    "pose": 0,  # Pose: the one rigid-transform type every layer passes (numpy only)
    "calibration": 1,
    "outline": 2,
    "mesh_cuts": 2,  # where a CT template was cropped (numpy only)
    "annotation": 3,
    "ssm": 4,
    "registration": 5,
    "simulate": 6,
    "result": 6,  # CaseResult: what the report, the batch summary and the workbench read
    "report": 7,
    "cases": 8,
    "cli": 9,
    "workbench": 9,  # the browser workbench: on top like the CLI (only the CLI imports it)
    "demo": 9,
}

#: Layer-0 modules ``biplanar_reg/cli/__init__.py`` may import at module level.
CLI_INIT_ALLOWED = {PACKAGE, f"{PACKAGE}.errors"}


@dataclass(frozen=True)
class Import:
    """One imported ``biplanar_reg`` module."""

    importer: str  # dotted module name
    target: str  # dotted module name (a package when a name of it is imported)
    line: int
    module_level: bool  # runs when the importer is imported (not inside a function)
    type_checking: bool  # inside ``if TYPE_CHECKING:``


def _module_names(root: Path) -> dict[str, Path]:
    """Dotted name -> file of every module under the package folder ``root``."""
    names = {}
    for path in sorted(root.rglob("*.py")):
        parts = list(path.relative_to(root.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        names[".".join(parts)] = path
    return names


def _resolve(importer: str, is_package: bool, node: ast.ImportFrom) -> str:
    """The absolute module of ``from <level dots><module> import ...`` in ``importer``."""
    if node.level == 0:
        return node.module or ""
    base = importer.split(".")
    base = base if is_package else base[:-1]
    if node.level > 1:
        base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _walk(
    body: list[ast.stmt], module_level: bool, type_checking: bool
) -> Iterator[tuple[ast.stmt, bool, bool]]:
    """Every statement with (runs at import time, inside ``if TYPE_CHECKING``)."""
    for stmt in body:
        yield stmt, module_level, type_checking
        if isinstance(stmt, (ast.FunctionDef, ast.AsyncFunctionDef)):
            yield from _walk(stmt.body, False, type_checking)
        elif isinstance(stmt, ast.If) and _is_type_checking(stmt.test):
            yield from _walk(stmt.body, module_level, True)
            yield from _walk(stmt.orelse, module_level, type_checking)
        else:
            for field in ("body", "orelse", "finalbody", "handlers"):
                inner = getattr(stmt, field, None)
                if isinstance(inner, list) and inner and isinstance(inner[0], ast.AST):
                    yield from _walk(inner, module_level, type_checking)  # type: ignore[arg-type]


def iter_imports(root: Path) -> Iterator[Import]:
    """Every import of a module of the package ``root`` by a module of it."""
    modules = _module_names(root)
    pkg = root.name
    for name, path in modules.items():
        is_package = path.name == "__init__.py"
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for stmt, module_level, tc in _walk(tree.body, True, False):
            targets: list[str] = []
            if isinstance(stmt, ast.Import):
                targets = [a.name for a in stmt.names]
            elif isinstance(stmt, ast.ExceptHandler):
                continue
            elif isinstance(stmt, ast.ImportFrom):
                base = _resolve(name, is_package, stmt)
                # "from pkg import sub" imports the module pkg.sub when there is one
                targets = [
                    f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base
                    for a in stmt.names
                ]
            for target in targets:
                if target == pkg or target.startswith(pkg + "."):
                    yield Import(name, target, stmt.lineno, module_level, tc)


def _top(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def layering_violations(imports: list[Import]) -> list[str]:
    """Imports of a higher layer, and modules missing from :data:`LAYERS`."""
    out = []
    for imp in imports:
        a, b = _top(imp.importer), _top(imp.target)
        missing = [m for m in (a, b) if m not in LAYERS]
        if missing:
            out.append(f"{imp.importer}:{imp.line}: {missing[0]!r} has no layer in LAYERS")
        elif a != b and LAYERS[b] > LAYERS[a]:
            out.append(
                f"{imp.importer}:{imp.line}: imports {imp.target} "
                f"(layer {LAYERS[b]} above {LAYERS[a]})"
            )
    return out


def private_module_violations(imports: list[Import]) -> list[str]:
    """Imports of a private module (``_name``) from outside the package that holds it."""
    out = []
    for imp in imports:
        parts = imp.target.split(".")
        for k, part in enumerate(parts):
            if part.startswith("_") and not part.startswith("__"):
                owner = ".".join(parts[:k])
                if not (imp.importer + ".").startswith(owner + "."):
                    out.append(f"{imp.importer}:{imp.line}: imports private {imp.target}")
                break
    return out


def cli_init_violations(imports: list[Import]) -> list[str]:
    """Module-level imports of ``biplanar_reg/cli/__init__.py`` beyond :data:`CLI_INIT_ALLOWED`
    (a command module, or the library, imported before a command is chosen)."""
    pkg = imports[0].importer.split(".")[0] if imports else PACKAGE
    allowed = {a.replace(PACKAGE, pkg, 1) for a in CLI_INIT_ALLOWED}
    return [
        f"{imp.importer}:{imp.line}: imports {imp.target} at module level"
        for imp in imports
        if imp.importer == f"{pkg}.cli"
        and imp.module_level
        and not imp.type_checking
        and imp.target not in allowed
    ]


def unplaced_modules(root: Path) -> list[str]:
    """Modules of the package whose top-level name has no layer in :data:`LAYERS`."""
    return [name for name in _module_names(root) if _top(name) not in LAYERS]


def _check(root: Path) -> dict[str, list[str]]:
    imports = list(iter_imports(root))
    return {
        "unplaced": unplaced_modules(root),
        "layers": layering_violations(imports),
        "private": private_module_violations(imports),
        "cli": cli_init_violations(imports),
    }


# -- the package ---------------------------------------------------------------------------------


def test_package_imports_follow_the_layers():
    imports = list(iter_imports(PACKAGE_DIR))
    assert len(imports) > 200  # the checker sees the package's imports
    assert unplaced_modules(PACKAGE_DIR) == []
    assert layering_violations(imports) == []


def test_no_private_module_of_another_package():
    assert private_module_violations(list(iter_imports(PACKAGE_DIR))) == []


def test_cli_init_imports_no_command_module():
    imports = list(iter_imports(PACKAGE_DIR))
    assert any(i.importer == f"{PACKAGE}.cli" for i in imports)
    assert cli_init_violations(imports) == []


@pytest.mark.parametrize("argv", [["--help"], ["calibration", "--help"], ["ssm", "--help"]])
def test_help_imports_no_numpy(argv):
    """``--help`` of the program and of a command group loads neither numpy nor the library."""
    code = (
        "import sys\n"
        "from biplanar_reg.cli import main\n"
        "try:\n"
        f"    main({argv!r})\n"
        "except SystemExit:\n"
        "    pass\n"
        "heavy = [m for m in ('numpy', 'scipy', 'cv2', 'biplanar_reg.calibration', "
        "'biplanar_reg.cases') if m in sys.modules]\n"
        "print('HEAVY', heavy)\n"
    )
    env = {**os.environ, "PYTHONPATH": str(PACKAGE_DIR.parent)}
    run = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        cwd=PACKAGE_DIR.parent,
        env=env,
        timeout=120,
    )
    assert run.returncode == 0, run.stderr
    assert "COMMAND" in run.stdout  # the help was printed
    assert "HEAVY []" in run.stdout, run.stdout[-300:]


# -- the checker on fake trees -------------------------------------------------------------------


def _tree(tmp_path: Path, files: dict[str, str]) -> Path:
    root = tmp_path / PACKAGE
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    for folder in [root, *[p for p in root.rglob("*") if p.is_dir()]]:
        (folder / "__init__.py").touch()
    return root


def test_checker_passes_a_clean_tree(tmp_path):
    root = _tree(
        tmp_path,
        {
            "errors.py": "",
            "calibration/views.py": "from .._validate import as_array\n",
            "calibration/_text.py": "",
            "calibration/io.py": "from ._text import x\nfrom ..errors import E\n",
            "cases/run.py": "from ..calibration import io\nimport biplanar_reg.report.html\n",
            "report/html.py": "from .. import __version__\n",
            "cli/__init__.py": "from ..errors import E\n\ndef main():\n    from . import cases\n",
            "cli/cases.py": "from ..cases.run import x\n",
        },
    )
    found = _check(root)
    assert found == {"unplaced": [], "layers": [], "private": [], "cli": []}, found


def test_checker_finds_each_bad_import(tmp_path):
    root = _tree(
        tmp_path,
        {
            "calibration/views.py": "from ..cases import case\n",  # 1 imports 8
            "report/html.py": "from ..cases.outputs import write\n",  # 7 imports 8
            "annotation/_fileio.py": "",
            "cases/run.py": "from ..annotation._fileio import read_json\n",  # private
            "cli/__init__.py": "from . import calibration\n",  # a command module, eagerly
            "cli/calibration.py": "",
            "gadgets.py": "",  # a module without a layer
            "cases/more.py": "from .. import gadgets\n",
        },
    )
    found = _check(root)
    assert any("calibration.views:1: imports biplanar_reg.cases" in v for v in found["layers"])
    assert any("report.html:1: imports biplanar_reg.cases.outputs" in v for v in found["layers"])
    assert any("'gadgets' has no layer" in v for v in found["layers"])
    assert found["unplaced"] == ["biplanar_reg.gadgets"]
    assert found["private"] == [
        "biplanar_reg.cases.run:1: imports private biplanar_reg.annotation._fileio"
    ]
    assert found["cli"] == [
        "biplanar_reg.cli:1: imports biplanar_reg.cli.calibration at module level"
    ]


def test_checker_resolves_relative_levels(tmp_path):
    root = _tree(
        tmp_path,
        {
            "registration/solvers/ipm.py": "from ...cases import run\nfrom . import kkt\n",
            "registration/solvers/kkt.py": "",
            "cases/run.py": "",
        },
    )
    imports = list(iter_imports(root))
    targets = {(i.importer, i.target) for i in imports}
    assert ("biplanar_reg.registration.solvers.ipm", "biplanar_reg.cases.run") in targets
    assert (
        "biplanar_reg.registration.solvers.ipm",
        "biplanar_reg.registration.solvers.kkt",
    ) in targets
    assert layering_violations(imports) == [
        "biplanar_reg.registration.solvers.ipm:1: imports biplanar_reg.cases.run (layer 8 above 5)"
    ]
