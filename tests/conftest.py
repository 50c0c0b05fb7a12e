"""Shared fixtures. Real-data tests read ``../shared/data`` (or ``$BIOMOTION_DATA_ROOT``) and skip, naming the
missing source, when it is absent."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DATA_ROOT = Path(os.environ.get("BIOMOTION_DATA_ROOT", REPO.parent / "shared" / "data"))


def data_path(relative: str) -> Path:
    """Path under the data root, or skip the test saying which source is missing."""
    path = DATA_ROOT / relative
    if not path.exists():
        pytest.skip(f"real data not available: {relative} is not under {DATA_ROOT}")
    return path


@pytest.fixture(scope="session")
def data_root() -> Path:
    if not DATA_ROOT.is_dir():
        pytest.skip(f"real data not available: no data root at {DATA_ROOT}")
    return DATA_ROOT
