"""Every shipped weight file has a model card whose SHA-256 is the file's, and every prior's card names the
tokenizer beside it: a retrained or refreshed file without its card (or copied from another bundle) fails here."""

from __future__ import annotations

import hashlib
import json

import pytest

from biomotion.generation.pipeline import CHECKPOINTS, TOKENIZER_FILE
from biomotion.generation.routing import FULL_BODY

FOLDERS = [CHECKPOINTS, CHECKPOINTS / FULL_BODY]


def _sha256(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.parametrize("folder", FOLDERS, ids=lambda f: f.name)
def test_cards_hold_the_shipped_files_hashes(folder):
    weights = sorted(folder.glob("*.safetensors"))
    if not weights:
        pytest.skip(f"no shipped weights in {folder}")
    tokenizer = _sha256(folder / TOKENIZER_FILE)
    for path in weights:
        card = json.loads(path.with_suffix(".json").read_text())
        assert card["sha256"] == _sha256(path), path.name
        assert path.with_suffix(".md").exists(), f"{path.name} has no Markdown card"
        if "tokenizer_sha256" in card:
            assert card["tokenizer_sha256"] == tokenizer, f"{path.name} names another tokenizer"
