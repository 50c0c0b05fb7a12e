"""Model cards: the JSON and Markdown written beside shipped weights (data, command, metrics, SHA-256)."""

from __future__ import annotations

import json
import platform
from pathlib import Path

import torch

from biomotion.io.atomic import atomic_write


def environment(**extra) -> dict:
    """Python and torch versions (plus ``extra``) for a card."""
    return {"python": platform.python_version(), "torch": torch.__version__, **extra}


def write_card(weights: Path, card: dict, markdown: str) -> None:
    """``card`` as ``<weights>.json`` and ``markdown`` as ``<weights>.md``, each written atomically."""
    with atomic_write(weights.with_suffix(".json")) as handle:
        json.dump(card, handle, indent=1)
    with atomic_write(weights.with_suffix(".md")) as handle:
        handle.write(markdown)
