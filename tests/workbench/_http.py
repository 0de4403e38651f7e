"""The workbench's API as its page calls it, through Starlette's test client: from the page's
own address (``BASE``), with the token header and JSON bodies (the server refuses state
changes without them)."""

from __future__ import annotations

from typing import Any

from starlette.testclient import TestClient

BASE = "http://127.0.0.1:8765"


def page_client(app: Any, token: str, **kwargs: Any) -> TestClient:
    """A client sending what the workbench's page sends with every request."""
    headers = {"X-Workbench-Token": token, "Content-Type": "application/json", "Origin": BASE}
    return TestClient(app, base_url=BASE, headers=headers, **kwargs)
