"""One exception family for everything biomotion rejects.

Every error names *where* the problem is (file, line, frame or field) so a user can open the file and see it.
The CLI prints a `BiomotionError` on one line and exits with status 2.
"""

from __future__ import annotations

from pathlib import Path


class BiomotionError(Exception):
    """Base of every error biomotion raises on purpose."""


class DataFormatError(BiomotionError):
    """A file or array does not follow its format: truncated, inconsistent, unknown units, empty.

    The message reads ``<file>:<line>: <what was wrong>`` (or ``frame N`` / ``field X`` where a line is
    meaningless), so editors and terminals can jump to it.
    """

    def __init__(
        self,
        path: str | Path | None,
        message: str,
        *,
        line: int | None = None,
        frame: int | None = None,
        field: str | None = None,
    ) -> None:
        self.path = None if path is None else Path(path)
        self.line = line
        self.frame = frame
        self.field = field
        where = str(self.path) if self.path is not None else "<data>"
        if line is not None:
            where += f":{line}"
        details = []
        if frame is not None:
            details.append(f"frame {frame}")
        if field is not None:
            details.append(f"field {field!r}")
        prefix = f"{where}: " + (", ".join(details) + ": " if details else "")
        super().__init__(prefix + message)


class ModelError(BiomotionError):
    """An .osim model (or a model-dependent request) that biomotion cannot use."""


class ConfigError(BiomotionError):
    """Bad options, setup files or command-line arguments."""


class SettingsError(ConfigError):
    """A setting of a configuration mapping (a training config's YAML, a model's settings) that is unknown,
    missing or of the wrong type; the caller that read the mapping from a file adds the file's name."""


class ProfileError(ConfigError, ValueError):
    """A profile field that is unknown, of the wrong type or outside its documented range; ``field`` names it.

    Also a ValueError, so code that validates a profile's values with ``except ValueError`` (and adds the file
    or table row to the message) keeps catching it.
    """

    def __init__(self, message: str, *, field: str | None = None) -> None:
        super().__init__(message)
        self.field = field


class DataSourceMissing(BiomotionError):
    """A data source the command needs is not under the data root."""


class BiomotionWarning(UserWarning):
    """Something was suspicious but usable (e.g. a `.mot` header contradicted by its values)."""
