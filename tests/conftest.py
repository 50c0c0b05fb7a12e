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


def _quiet_opensim() -> None:
    """Tests that use OpenSim directly get the library's logging: no ``opensim.log`` in a data folder."""
    try:
        from biomotion.settings import opensim_oracle

        opensim_oracle()
    except ImportError:
        pass


_quiet_opensim()
_STARTED = None


def pytest_sessionstart(session) -> None:
    global _STARTED
    import time

    _STARTED = time.time()


def pytest_sessionfinish(session, exitstatus) -> None:
    """The data root is read-only input: fail the run if any test wrote or touched a file under it."""
    if hasattr(session.config, "workerinput") or _STARTED is None or not DATA_ROOT.is_dir():
        return
    written = [
        path
        for path in DATA_ROOT.rglob("*")
        if path.is_file() and (path.stat().st_mtime > _STARTED or path.stat().st_ctime > _STARTED)
    ]
    if written:
        shown = ", ".join(str(p.relative_to(DATA_ROOT)) for p in written[:5])
        print(f"\nERROR: the test run wrote {len(written)} file(s) into the read-only data root {DATA_ROOT}: {shown}")
        session.exitstatus = 1
