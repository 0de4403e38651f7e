"""No function of the package is longer than 60 lines of code (a function should be
readable at once; lines of code exclude the docstring, comments and blank lines), and no module
longer than 800 lines.

Run as a script to list the longest functions: ``python tests/test_function_size.py [N]``.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import biplanar_reg

PACKAGE_DIR = Path(biplanar_reg.__file__).resolve().parent
MAX_LINES = 60
MAX_MODULE_LINES = 800


def code_lines(source: str, node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """Lines of code of a function in ``source``: its body without the docstring, comment-only
    lines and blank lines (the signature not counted)."""
    lines = source.splitlines()
    body = node.body
    has_doc = (
        isinstance(body[0], ast.Expr)
        and isinstance(body[0].value, ast.Constant)
        and isinstance(body[0].value.value, str)
    )
    start = body[0].end_lineno if has_doc else body[0].lineno - 1
    code = [ln for ln in lines[start : node.end_lineno] if ln.strip()]
    return sum(1 for ln in code if not ln.strip().startswith("#"))


def function_sizes(root: Path) -> list[tuple[int, str]]:
    """``(lines of code, "file:function")`` of every function under ``root``, longest first."""
    rows = []
    for path in sorted(root.rglob("*.py")):
        source = path.read_text(encoding="utf-8")
        for node in ast.walk(ast.parse(source)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                name = f"{path.relative_to(root.parent)}:{node.name}"
                rows.append((code_lines(source, node), name))
    return sorted(rows, reverse=True)


def test_code_lines_counts_code_only():
    src = 'def f(x):\n    """Doc.\n\n    More.\n    """\n    # why\n\n    y = x\n    return y\n'
    node = ast.parse(src).body[0]
    assert code_lines(src, node) == 2


def test_no_function_is_longer_than_the_limit():
    long = [f"{name} ({n} lines)" for n, name in function_sizes(PACKAGE_DIR) if n > MAX_LINES]
    assert not long, f"functions over {MAX_LINES} lines of code: {long}"


def test_no_module_is_longer_than_the_limit():
    long = []
    for path in sorted(PACKAGE_DIR.rglob("*.py")):
        n = len(path.read_text(encoding="utf-8").splitlines())
        if n > MAX_MODULE_LINES:
            long.append(f"{path.relative_to(PACKAGE_DIR.parent)} ({n} lines)")
    assert not long, f"modules over {MAX_MODULE_LINES} lines: {long}"


if __name__ == "__main__":
    for n, name in function_sizes(PACKAGE_DIR)[: int(sys.argv[1]) if len(sys.argv) > 1 else 10]:
        print(f"{n:4d}  {name}")
