"""OpenSim 4.6 as the oracle for the body-model tests (the shared implementation lives in
`biomotion.validation.oracle`). Importing it skips without opensim."""

from __future__ import annotations

import pytest

from tests.conftest import DATA_ROOT

osim = pytest.importorskip("opensim", reason="the opensim package (validate extra) is the oracle here")

from biomotion.validation.dynamics import MODEL_GLOBS  # noqa: E402
from biomotion.validation.oracle import Oracle, random_poses, vec3  # noqa: E402

__all__ = ["Oracle", "osim", "random_poses", "vec3", "MODEL_GLOBS", "model_paths"]


def model_paths() -> list[str]:
    """Every model of MODEL_GLOBS present, relative to the data root (for test ids)."""
    found = []
    for pattern in MODEL_GLOBS:
        found += sorted(str(p.relative_to(DATA_ROOT)) for p in DATA_ROOT.glob(pattern))
    return found
