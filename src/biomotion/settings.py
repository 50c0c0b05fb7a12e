"""Settings dataclasses from dictionaries (YAML configs, safetensors metadata), with unknown keys named."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields
from typing import Any, TypeVar

from biomotion.errors import ConfigError

T = TypeVar("T")


def settings_from_dict(cls: type[T], values: Mapping[str, Any], what: str) -> T:
    """``cls(**values)`` for a dataclass, or a `ConfigError` naming the unknown keys and the known ones."""
    known = {f.name for f in fields(cls)}
    unknown = set(values) - known
    if unknown:
        raise ConfigError(f"unknown {what} settings: {sorted(unknown)}; known: {sorted(known)}")
    return cls(**values)
