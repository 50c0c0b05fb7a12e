"""What several verbs share: the data-root default, numeric argument types with documented ranges, the command
line as recorded in reports, output folders that appear whole or not at all, and Ctrl-C that is never lost.

Only the standard library is imported here: the parser must answer ``--help`` and argument errors before torch or
scipy load.
"""

from __future__ import annotations

import argparse
import math
import os
import shlex
import shutil
import signal
import sys
import tempfile
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

DATA_ROOT_VARIABLE = "BIOMOTION_DATA_ROOT"
_CTRL_C = threading.Event()


def default_data_root() -> Path:
    """``$BIOMOTION_DATA_ROOT`` when set and not empty, else ``../shared/data`` (as `biomotion.settings`, without
    importing the package for it)."""
    return Path(os.environ.get(DATA_ROOT_VARIABLE) or "../shared/data")


def add_data_root(parser: argparse.ArgumentParser, what: str = "folder laid out like ../shared/data") -> None:
    parser.add_argument("--data-root", type=Path, default=default_data_root(), help=f"{what} (default: %(default)s)")


def number(low: float | None = None, high: float | None = None, *, integer: bool = False, low_open: bool = False):
    """An argparse type: a finite number within [low, high] (``low_open``: low excluded); the error names the range."""

    def parse(text: str) -> float | int:
        try:
            value = int(text) if integer else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if integer else 'a number'}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"{text!r}: must be a finite number")
        if low is not None and (value < low or (low_open and value == low)):
            raise argparse.ArgumentTypeError(f"{text}: must be {'above' if low_open else 'at least'} {low:g}")
        if high is not None and value > high:
            raise argparse.ArgumentTypeError(f"{text}: must be at most {high:g}")
        return value

    return parse


def command_line(argv: list[str] | None = None) -> str:
    """The command as typed, for the records and reports that say how they were made (paths portable:
    `biomotion.io.paths.portable`)."""
    from biomotion.io.paths import portable

    def quoted(argument: str) -> str:
        argument = portable(argument)
        if argument.startswith("~/"):  # the shell expands ~ only outside quotes
            return "~/" + shlex.quote(argument[2:])
        return shlex.quote(argument)

    return "biomotion " + " ".join(quoted(a) for a in (sys.argv[1:] if argv is None else argv))


def add_overwrite(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace an existing, non-empty --out folder as a whole (default: refuse it)",
    )


@contextmanager
def fresh_folder(out: Path, overwrite: bool) -> Iterator[Path]:
    """A new empty folder beside ``out`` to write into; moved into place as ``out`` when the block succeeds, removed
    when it fails, so ``out`` never holds a half-written run or stale files of an earlier one.

    ``out`` must not be a file; an existing non-empty ``out`` is refused unless ``overwrite``, which replaces it
    whole. Raises `biomotion.errors.ConfigError` naming the folder."""
    from biomotion.errors import ConfigError

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"{out}: --out names a file; give a folder")
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise ConfigError(
            f"{out}: the output folder exists and is not empty; choose another --out or pass --overwrite to replace it"
        )
    parent = out.absolute().parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        scratch = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".partial", dir=parent))
    except OSError as error:
        raise ConfigError(f"{out}: cannot create the output folder here: {error.strerror or error}") from None
    try:
        yield scratch
        if interrupted():  # Ctrl-C that a library swallowed: the run stops all the same
            raise KeyboardInterrupt
    except BaseException:
        shutil.rmtree(scratch, ignore_errors=True)
        raise
    if out.exists():
        shutil.rmtree(out)
    os.replace(scratch, out)


def moved(path: Path | str | None, scratch: Path, out: Path) -> Path | None:
    """Where ``path``, written inside ``scratch``, lies once `fresh_folder` has moved it to ``out``."""
    if path is None:
        return None
    path = Path(path)
    try:
        return out / path.relative_to(scratch)
    except ValueError:
        return path


def writable_file(path: Path, what: str = "--out") -> Path:
    """``path`` if a file can be written there (its folder exists or can be made, it is not a folder)."""
    from biomotion.errors import ConfigError

    if path.is_dir():
        raise ConfigError(f"{path}: {what} names a folder; give a file name")
    parent = path.absolute().parent
    blocking = next((p for p in (parent, *parent.parents) if p.exists()), None)
    if blocking is not None and not blocking.is_dir():
        raise ConfigError(f"{path}: {what} cannot be written: {blocking} is a file, not a folder")
    if parent.exists() and not os.access(parent, os.W_OK):
        raise ConfigError(f"{path}: {what} is not writable (no permission on {parent})")
    return path


@contextmanager
def remembering_interrupts() -> Iterator[None]:
    """Within the block, Ctrl-C (SIGINT) raises `KeyboardInterrupt` as Python's own handler does and is also
    remembered (`interrupted`). A KeyboardInterrupt can be lost on its way up: one that lands while a C extension
    initialises comes out as ``ImportError: initialization failed``, which a library's optional import catches and
    goes on. The CLI asks `interrupted` instead, so an interrupted command still exits 130 and `fresh_folder` still
    discards its scratch folder. Outside the main thread, or where SIGINT is not Python's default handler (ignored,
    or someone else's), the handler is left as it is."""
    _CTRL_C.clear()
    if threading.current_thread() is not threading.main_thread() or (
        signal.getsignal(signal.SIGINT) is not signal.default_int_handler
    ):
        yield
        return

    def remember(signum, frame):
        _CTRL_C.set()
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGINT, remember)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def interrupted() -> bool:
    """Whether Ctrl-C came during the current `remembering_interrupts` block, whatever became of its exception."""
    return _CTRL_C.is_set()
