"""Paths as records show them: relative to the working folder, or under ``~``, never a machine's absolute path.

Model cards, checkpoints' metadata and reports record the command and the folders that made them so anyone can
make them again; an absolute path names one machine (its user, its checkout) and means nothing on another.
"""

from __future__ import annotations

import os
from pathlib import Path


def portable(text: str | os.PathLike) -> str:
    """``text`` with the working folder's absolute prefix made relative and the home folder written ``~``.

    Applies to any string that contains a path (a whole command line too); other text is returned unchanged."""
    text = os.fspath(text)
    cwd = os.getcwd().rstrip(os.sep)
    home = str(Path.home()).rstrip(os.sep)
    if cwd and cwd != os.sep:
        text = text.replace(cwd + os.sep, "").replace(cwd, ".")
    if home and home != os.sep:
        text = text.replace(home + os.sep, "~" + os.sep)
    return text
