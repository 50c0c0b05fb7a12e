"""Safetensors files (checkpoints, dataset caches, labels) read with errors that name the file.

The safetensors library raises its own ``SafetensorError`` (or an OSError, a ValueError) for a file that is missing,
cut short or not safetensors at all, without the file's name; a damaged checkpoint under ``--checkpoints`` then
surfaced as an internal error. `read_metadata` and `read_tensors` turn each of those into a
`biomotion.errors.DataFormatError` that says which file and what it should have been.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from biomotion.errors import DataFormatError


def _check(path: Path, what: str) -> None:
    if path.is_dir():
        raise DataFormatError(path, f"is a folder, not {what} (a .safetensors file)")
    if not path.exists():
        raise DataFormatError(path, f"no such file ({what})")


def _unreadable(path: Path, what: str, error: Exception) -> DataFormatError:
    return DataFormatError(path, f"cannot read the {what}: damaged or not a safetensors file ({error})")


def read_metadata(path: str | Path, what: str = "safetensors file") -> dict[str, str]:
    """The header metadata of a safetensors file (``{}`` when it has none); ``what`` names the file's role in
    errors ("generator weights", "dataset cache arrays")."""
    from safetensors import SafetensorError, safe_open

    path = Path(path)
    _check(path, what)
    try:
        with safe_open(str(path), framework="np") as handle:
            return dict(handle.metadata() or {})
    except (SafetensorError, OSError, ValueError) as error:
        raise _unreadable(path, what, error) from None


def read_tensors(path: str | Path, what: str = "safetensors file", *, numpy: bool = False, device: str = "cpu") -> Any:
    """Every tensor of a safetensors file by name: torch tensors on ``device``, or NumPy arrays with ``numpy``."""
    from safetensors import SafetensorError

    path = Path(path)
    _check(path, what)
    try:
        if numpy:
            from safetensors.numpy import load_file

            return load_file(str(path))
        from safetensors.torch import load_file

        return load_file(str(path), device=device)
    except (SafetensorError, OSError, ValueError) as error:
        raise _unreadable(path, what, error) from None
