"""Case folders for the workbench tests, always copies in ``tmp_path`` (the shipped
``sample_cases/`` are never written to)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from biplanar_reg.simulate import write_synthetic_case

ROOT = Path(__file__).resolve().parents[2]
WRIST = ROOT / "sample_cases" / "wrist_radius"


@pytest.fixture(scope="session")
def _synthetic_master(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_synthetic_case(tmp_path_factory.mktemp("synthetic") / "case", seed=0)


@pytest.fixture
def synthetic_case(_synthetic_master: Path, tmp_path: Path) -> Path:
    """A fresh copy of the synthetic case (2 views of 512 x 512 px, 8 landmarks, 482 vertices)."""
    return Path(shutil.copytree(_synthetic_master, tmp_path / "case"))


@pytest.fixture
def wrist_case(tmp_path: Path) -> Path:
    """A copy of the shipped wrist case, its ``data/`` included (two 1760 x 1760 radiographs)."""
    return Path(shutil.copytree(WRIST, tmp_path / "wrist_radius"))
