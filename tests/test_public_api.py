"""The public API has an edge: packages export what the docs describe; the docs' imports work.

* every name in a package's ``__all__`` is importable from it and named in ``README.md`` or a
  page of ``docs/`` other than ``docs/api.md`` (an export nobody documented fails);
* every module's ``__all__`` names that module's attributes, and each is documented too (a
  module's ``__all__`` lists what the docs describe at that module, nothing else);
* ``docs/api.md`` lists exactly the packages' ``__all__``s, one line each;
* every ``from biplanar_reg... import ...`` / ``import biplanar_reg...`` of the docs (code blocks
  and inline code) imports, and every dotted ``biplanar_reg.x.y`` name they give resolves;
* ``biplanar_reg.cases`` exports ``register_case``, ``run_case_dir`` and ``run_batch``.

The parsing helpers are tested on small inputs first, so that the checks can fail.
"""

from __future__ import annotations

import ast
import importlib
import pkgutil
import re
from pathlib import Path
from types import ModuleType

import pytest

import biplanar_reg

ROOT = Path(__file__).resolve().parents[1]
API_PAGE = ROOT / "docs" / "api.md"
DOC_FILES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

#: Dotted names the docs mention as history (what a module used to be called), not as API.
FORMER_NAMES = {"biplanar_reg.synthetic"}

_FENCE = re.compile(r"```[^\n]*\n(.*?)```", re.S)
_INLINE = re.compile(r"`([^`]+)`")
_WORD = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_DOTTED = re.compile(r"\bbiplanar_reg(?:\.[A-Za-z_][A-Za-z0-9_]*)+")
_API_LINE = re.compile(r"^- `(biplanar_reg[\w.]*)`[^:]*: (.*)$")


# ----------------------------------------------------------------------------- helpers


def code_spans(markdown: str) -> list[str]:
    """The fenced code blocks and inline code spans of a Markdown text."""
    blocks = _FENCE.findall(markdown)
    prose = _FENCE.sub("", markdown)
    return blocks + _INLINE.findall(prose)


def code_words(markdown: str) -> set[str]:
    """Every identifier that appears in code (blocks or inline) of a Markdown text."""
    return {w for span in code_spans(markdown) for w in _WORD.findall(span)}


def doc_imports(markdown: str) -> list[tuple[str, list[str]]]:
    """``(module, names)`` of each ``from biplanar_reg... import`` / ``import biplanar_reg...``.

    Read from the code spans line by line (the blocks mix Python with shell and pseudo-code);
    ``import a.b`` gives ``("a.b", [])``.
    """
    found = []
    for span in code_spans(markdown):
        lines = [line.strip() for line in span.splitlines()]
        for i, line in enumerate(lines):
            if not re.match(r"(from|import) biplanar_reg\b", line):
                continue
            if "(" in line and ")" not in line:  # a parenthesised import over several lines
                end = next(j for j in range(i, len(lines)) if ")" in lines[j])
                line = " ".join(lines[i : end + 1])
            node = ast.parse(line).body[0]
            if isinstance(node, ast.ImportFrom):
                found.append((node.module or "", [a.name for a in node.names]))
            else:
                found += [(a.name, []) for a in node.names]
    return found


def doc_dotted_names(markdown: str) -> set[str]:
    """Dotted ``biplanar_reg.x.y`` names in the code spans (``python -m`` targets included)."""
    return {m for span in code_spans(markdown) for m in _DOTTED.findall(span)}


def resolve(dotted: str) -> object:
    """The object a dotted name denotes: the longest importable module, then attributes."""
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj: object = importlib.import_module(".".join(parts[:i]))
        except ModuleNotFoundError:
            continue
        for attr in parts[i:]:
            obj = getattr(obj, attr)  # AttributeError: the name does not exist
        return obj
    raise ModuleNotFoundError(dotted)


def api_listing(markdown: str) -> dict[str, set[str]]:
    """``{module: names}`` of the ``- `module` (...): `a`, `b``` lines of ``docs/api.md``."""
    listing = {}
    for line in markdown.splitlines():
        m = _API_LINE.match(line)
        if m:
            listing[m.group(1)] = set(re.findall(r"`([^`]+)`", m.group(2)))
    return listing


def undocumented(names: list[str], words: set[str]) -> list[str]:
    """The names that no code span of the docs mentions."""
    return [n for n in names if n not in words]


def _all_modules() -> list[ModuleType]:
    """Every module of the package (``__main__`` modules excluded: importing them runs them)."""
    mods = [biplanar_reg]
    for info in pkgutil.walk_packages(biplanar_reg.__path__, "biplanar_reg."):
        if info.name.rsplit(".", 1)[-1] != "__main__":
            mods.append(importlib.import_module(info.name))
    return mods


def _is_package(module: ModuleType) -> bool:
    return hasattr(module, "__path__")


MODULES = _all_modules()
PACKAGES = [m for m in MODULES if _is_package(m)]
DOCS = {path.name: path.read_text(encoding="utf-8") for path in DOC_FILES}
#: identifiers in the code of every page except the API listing (which must not count itself)
DOC_WORDS = set().union(*(code_words(t) for name, t in DOCS.items() if name != API_PAGE.name))


# ------------------------------------------------------------------- the helpers can fail


SAMPLE = """Prose with `biplanar_reg.io.read_mesh(path)` and `from biplanar_reg.io import nope`.

```python
from biplanar_reg.io import (read_mesh)   # a comment
from biplanar_reg.io import (
    write_mesh,
)
import biplanar_reg.io.meshes
x = 1
```

```sh
biplanar-reg register CASE   # not Python
```
"""


def test_helpers_parse_code_spans():
    assert {"read_mesh", "nope", "x", "register"} <= code_words(SAMPLE)
    assert "Prose" not in code_words(SAMPLE)
    assert doc_imports(SAMPLE) == [
        ("biplanar_reg.io", ["read_mesh"]),
        ("biplanar_reg.io", ["write_mesh"]),
        ("biplanar_reg.io.meshes", []),
        ("biplanar_reg.io", ["nope"]),
    ]
    assert doc_dotted_names(SAMPLE) == {
        "biplanar_reg.io",
        "biplanar_reg.io.read_mesh",
        "biplanar_reg.io.meshes",
    }
    assert undocumented(["read_mesh", "read_volume"], code_words(SAMPLE)) == ["read_volume"]
    listing = "- `biplanar_reg.io` ([ssm](ssm.md)): `read_mesh`, `write_mesh`\n- other\n"
    assert api_listing(listing) == {"biplanar_reg.io": {"read_mesh", "write_mesh"}}


def test_resolve_fails_on_missing_names():
    assert resolve("biplanar_reg.io.read_mesh") is biplanar_reg.io.read_mesh
    with pytest.raises(AttributeError):
        resolve("biplanar_reg.io.no_such_function")
    with pytest.raises(ModuleNotFoundError):
        resolve("no_such_package.x")


# ------------------------------------------------------------------------- the checks


@pytest.mark.parametrize("package", PACKAGES, ids=lambda m: m.__name__)
def test_package_exports_are_importable_and_documented(package):
    names = list(package.__all__)
    assert len(names) == len(set(names)), f"{package.__name__}.__all__ has duplicates"
    missing = [n for n in names if not hasattr(package, n)]
    assert not missing, f"{package.__name__}.__all__ names what it does not define: {missing}"
    assert not undocumented(names, DOC_WORDS), (
        f"{package.__name__} exports names that no doc describes (README.md, docs/*.md other "
        f"than api.md): {undocumented(names, DOC_WORDS)}; document them or drop the export"
    )


def test_every_public_module_declares_its_public_names():
    # ``__all__ = []`` says "nothing public here"; only private modules (``_validate``) may omit it.
    public = [m for m in MODULES if not any(p.startswith("_") for p in m.__name__.split("."))]
    lacking = [m.__name__ for m in public if not hasattr(m, "__all__")]
    assert not lacking, f"modules without __all__: {lacking}"


@pytest.mark.parametrize(
    "module", [m for m in MODULES if hasattr(m, "__all__")], ids=lambda m: m.__name__
)
def test_module_all_names_exist_and_are_documented(module):
    names = module.__all__
    missing = [n for n in names if not hasattr(module, n)]
    assert not missing, f"{module.__name__}.__all__ names what it does not define: {missing}"
    assert not undocumented(list(names), DOC_WORDS), (
        f"{module.__name__}.__all__ lists names no doc describes: "
        f"{undocumented(list(names), DOC_WORDS)}; an internal helper stays out of __all__"
    )


def test_package_exports_are_public_in_their_modules():
    # A package re-exports a class or function from the module that defines it; that module's
    # __all__ must list it too (one public spelling, one place that documents it).
    wrong = []
    for package in PACKAGES:
        for name in package.__all__:
            obj = getattr(package, name)
            home = getattr(obj, "__module__", None)
            if home and home != package.__name__ and home.startswith("biplanar_reg"):
                if name not in getattr(importlib.import_module(home), "__all__", ()):
                    wrong.append(f"{package.__name__}.{name} (defined in {home})")
    assert not wrong, f"exported but not in the defining module's __all__: {wrong}"


def test_api_page_lists_exactly_the_package_exports():
    listing = api_listing(API_PAGE.read_text(encoding="utf-8"))
    unlisted = [p.__name__ for p in PACKAGES if p.__name__ not in listing]
    assert not unlisted, f"docs/api.md has no line for {unlisted}"
    for module, names in listing.items():
        exported = set(importlib.import_module(module).__all__)
        assert names == exported, (
            f"docs/api.md and {module}.__all__ differ: only in the page "
            f"{sorted(names - exported)}, only in __all__ {sorted(exported - names)}"
        )


@pytest.mark.parametrize("page", sorted(DOCS))
def test_doc_imports_work(page):
    failures = []
    for module, names in doc_imports(DOCS[page]):
        try:
            mod = importlib.import_module(module)
        except ImportError as exc:
            failures.append(f"import {module}: {exc}")
            continue
        for name in names:
            if name == "*" or hasattr(mod, name):
                continue
            try:  # ``from package import submodule``
                importlib.import_module(f"{module}.{name}")
            except ModuleNotFoundError:
                failures.append(f"from {module} import {name}")
    assert not failures, f"{page}: imports that fail: {failures}"


@pytest.mark.parametrize("page", sorted(DOCS))
def test_doc_dotted_names_resolve(page):
    failures = []
    for dotted in sorted(doc_dotted_names(DOCS[page]) - FORMER_NAMES):
        try:
            resolve(dotted)
        except (ImportError, AttributeError) as exc:
            failures.append(f"{dotted}: {exc}")
    assert not failures, f"{page}: names that do not exist: {failures}"


def test_cases_exports_the_runners():
    from biplanar_reg import cases
    from biplanar_reg.cases import batch, run

    assert cases.register_case is run.register_case
    assert cases.run_case_dir is run.run_case_dir
    assert cases.run_batch is batch.run_batch
    assert {"register_case", "run_case_dir", "run_batch", "RunOutcome", "BatchSummary"} <= set(
        cases.__all__
    )
