"""Where the datasets are when a command is not told: ``$BIOMOTION_DATA_ROOT``, else ``../shared/data`` from the
working directory (the project's layout, `../shared/data/README.md`). Every command that reads them also takes
``--data-root DIR``, which wins."""

from __future__ import annotations

import os
from pathlib import Path

ENVIRONMENT_VARIABLE = "BIOMOTION_DATA_ROOT"
FALLBACK = Path("../shared/data")


def default_data_root() -> Path:
    """``$BIOMOTION_DATA_ROOT`` when set and not empty, else ``../shared/data``."""
    return Path(os.environ.get(ENVIRONMENT_VARIABLE) or FALLBACK)
