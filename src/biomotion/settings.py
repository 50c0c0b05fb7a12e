"""Settings: dataclasses from dictionaries (YAML configs, safetensors metadata) with unknown keys named, and where
the datasets are by default."""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import fields
from pathlib import Path
from typing import Any, TypeVar

from biomotion.errors import SettingsError

T = TypeVar("T")


def settings_from_dict(cls: type[T], values: Mapping[str, Any], what: str) -> T:
    """``cls(**values)`` for a dataclass, or a `ConfigError` naming the unknown keys and the known ones."""
    known = {f.name for f in fields(cls)}
    unknown = set(values) - known
    if unknown:
        raise SettingsError(f"unknown {what} settings: {sorted(unknown)}; known: {sorted(known)}")
    return cls(**values)


DATA_ROOT_VARIABLE = "BIOMOTION_DATA_ROOT"
DATA_ROOT_FALLBACK = Path("../shared/data")


def default_data_root() -> Path:
    """Where the datasets are when a command is not told: ``$BIOMOTION_DATA_ROOT`` when set and not empty, else
    ``../shared/data`` from the working directory (the project's layout, `../shared/data/README.md`). Every command
    that reads them also takes ``--data-root DIR``, which wins."""
    return Path(os.environ.get(DATA_ROOT_VARIABLE) or DATA_ROOT_FALLBACK)


def opensim_oracle() -> Any:
    """The ``opensim`` module (the ``validate`` extra), with its log written to the temporary folder.

    OpenSim's tools change the working directory to their setup's folder while they run, and its logger opens
    ``opensim.log`` in the working directory at its first message: left alone, it writes into whatever data folder
    a setup lives in, which must stay read-only. Every use of OpenSim in biomotion goes through this function."""
    import tempfile

    import opensim

    opensim.Logger.removeFileSink()
    opensim.Logger.addFileSink(str(Path(tempfile.gettempdir()) / "biomotion-opensim.log"))
    return opensim
