"""YAML/JSON files that hold one mapping (profiles, shape files, training configs), read with one-line errors.

JSON is YAML, so one safe loader reads both. Contract: returns the mapping; raises `biomotion.errors.ConfigError`
when the file cannot be read and `biomotion.errors.DataFormatError` naming the file (and the line, where the
parser gives one) when it is not valid YAML or holds something other than a mapping.
"""

from __future__ import annotations

from pathlib import Path

from biomotion.errors import ConfigError, DataFormatError


def read_mapping(path: str | Path, kind: str, expected: str) -> dict:
    """The mapping in the YAML/JSON file ``path``; ``kind`` names the file in errors ("profile file"),
    ``expected`` says what it should hold when it holds no mapping."""
    import yaml

    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{kind} not found: {path}") from None
    except OSError as error:
        raise ConfigError(f"{path}: cannot read the {kind}: {error.strerror or error}") from None
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        raise DataFormatError(
            path,
            f"not valid YAML/JSON: {getattr(error, 'problem', error)}",
            line=None if mark is None else mark.line + 1,
        ) from None
    if not isinstance(data, dict):
        raise DataFormatError(path, expected)
    return data
