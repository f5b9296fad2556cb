"""Shared test fixtures: paths to the repository, the bundled robot and the real-data folder."""
from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
REAL = SHARED / "data" / "real"
PA10_DIR = REPO / "fixtures" / "robots" / "pa10"


@pytest.fixture(scope="session")
def real_dir() -> Path:
    if not REAL.is_dir():
        pytest.skip(f"real-data folder {REAL} is absent")
    return REAL


@pytest.fixture(scope="session")
def pa10_dir() -> Path:
    if not (PA10_DIR / "pa10.urdf").is_file():
        pytest.skip("bundled PA10 description not present yet")
    return PA10_DIR
