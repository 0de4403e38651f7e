"""Count the page actions of the workbench's browser tests: a pytest plugin.

Run ``python -m pytest -p benchmarks.count_page_actions tests/workbench/test_e2e.py -k annotate
-n 0 -s``. Every user gesture a test makes through Playwright is counted once: a click (of the
mouse or of an element), a key press, a wheel step, a drag (counted at its press), a field
filled or an option chosen; mouse moves without a button (hovering for the livewire preview) are
not. At the end it prints each test's count up to and including its click on "Register" (the
annotation), and the total.
"""

from __future__ import annotations

from typing import Any

import pytest

_LOG: list[str] = []
_COUNTS: dict[str, tuple[int, int]] = {}
_GESTURES = {
    "Mouse": ("click", "dblclick", "down", "wheel"),
    "Keyboard": ("press", "type"),
    "Locator": ("click", "dblclick", "fill", "check", "select_option", "press"),
}


def _wrap(cls: Any, name: str) -> None:
    orig = getattr(cls, name)

    def counted(self: Any, *args: Any, **kwargs: Any) -> Any:
        what = f"{cls.__name__}.{name}"
        if cls.__name__ == "Locator":
            what += f" {self}"
        _LOG.append(what)
        return orig(self, *args, **kwargs)

    setattr(cls, name, counted)


def pytest_configure(config: pytest.Config) -> None:
    from playwright.sync_api import _generated as g

    for cls_name, names in _GESTURES.items():
        for name in names:
            _wrap(getattr(g, cls_name), name)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item: pytest.Item) -> Any:
    _LOG.clear()
    try:
        return (yield)
    finally:
        register = [i for i, w in enumerate(_LOG) if "register" in w and "Locator.click" in w]
        upto = register[0] + 1 if register else len(_LOG)
        _COUNTS[item.nodeid] = (upto, len(_LOG))


def pytest_terminal_summary(terminalreporter: Any) -> None:
    for nodeid, (upto, total) in _COUNTS.items():
        terminalreporter.write_line(
            f"page actions: {nodeid}: {upto} up to and including Register, {total} in all"
        )
