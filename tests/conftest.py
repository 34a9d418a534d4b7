"""Fixtures shared by the whole suite."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SHARED = REPO.parent / "shared"


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """The reference folder beside the project (``../shared``), read-only."""
    if not (SHARED / "seed").is_dir():
        pytest.skip(f"reference material not found at {SHARED}")
    return SHARED


@pytest.fixture(scope="session")
def object_table(shared_dir: Path) -> Path:
    """The published object table CSV."""
    return shared_dir / "seed" / "dataset_objects_and_compliance.csv"
