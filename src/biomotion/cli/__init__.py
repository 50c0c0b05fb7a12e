"""The ``biomotion`` command: one module per verb, each a thin layer over the Python API.

A verb module has ``add_parser(verbs)`` (its arguments, help and examples) and ``run(args)`` (calls the API, prints
what it did). Only the standard library is imported before the arguments are parsed, so ``--help`` and argument
errors answer at once; the library loads inside ``run``.

Errors: a `biomotion.errors.BiomotionError` (bad input, named with its file and where in it) is printed on one line
as ``error: <file>: <what> (<where>)`` and the command exits with status 2, as argparse does for bad arguments.
Anything else is a bug in biomotion: a one-line message and exit status 1, the traceback with ``--debug``.
"""

from __future__ import annotations

import argparse
import os
import sys
from importlib import import_module

from biomotion.cli._common import DATA_ROOT_VARIABLE, default_data_root

#: Verbs in the order ``biomotion --help`` lists them, each the name of its module in this package.
VERBS = (
    "analyze",
    "batch",
    "check",
    "generate",
    "adapt",
    "refine",
    "scale",
    "retarget",
    "convert",
    "inspect",
    "view",
    "eval",
    "validate",
    "data",
    "train",
)
_MODULES = {"eval": "evaluate"}


class _Parser(argparse.ArgumentParser):
    """argparse with its errors on one line, as biomotion prints its own (``error: <what> (<where>)``); the usage
    argparse would print first is one ``--help`` away. Every verb's parser is one too (subparsers take the class
    of their parent)."""

    def error(self, message: str):
        self.exit(2, f"error: {message} (`{self.prog} --help` lists the arguments)\n")


def build_parser() -> argparse.ArgumentParser:
    """The whole command-line interface (every verb's arguments)."""
    from biomotion import __version__

    parser = _Parser(
        prog="biomotion",
        description="Personalized, biomechanically plausible human motion: read captured motion, analyse it on a "
        "musculoskeletal model, generate motion for a person and an action, evaluate and view it.",
        epilog=f"Commands that read the datasets take --data-root DIR; without it they read ${DATA_ROOT_VARIABLE} "
        f"when set, else ../shared/data from the working directory (now: {default_data_root()}). "
        "`biomotion VERB --help` explains each verb.",
    )
    parser.add_argument("--version", action="version", version=f"biomotion {__version__}")
    parser.add_argument("--debug", action="store_true", help="show the full traceback of an unexpected error")
    verbs = parser.add_subparsers(dest="verb", metavar="VERB", required=True)
    for verb in VERBS:
        import_module(f"biomotion.cli.{_MODULES.get(verb, verb)}").add_parser(verbs)
    return parser


def _one_line_warnings(showwarning):
    """``warnings.showwarning`` that prints biomotion's own warnings on one line, like its errors (the default adds
    the file and line of the library code that warned, which names nothing the user gave)."""
    from biomotion.errors import BiomotionWarning

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, BiomotionWarning):
            print(f"warning: {message}", file=sys.stderr if file is None else file)
        else:
            showwarning(message, category, filename, lineno, file, line)

    return show


def main(argv: list[str] | None = None) -> int:
    """Run ``biomotion ARGS``; returns the exit status (0 done or help shown, 1 bug, 2 bad input or arguments,
    130 interrupted)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    debug = "--debug" in argv  # accepted anywhere on the line, not only before the verb
    try:
        args = build_parser().parse_args([a for a in argv if a != "--debug"])
    except SystemExit as done:  # --help, --version (0) or an argument error (2, already printed by argparse)
        return done.code if isinstance(done.code, int) else 2
    import warnings

    from biomotion.cli._common import interrupted, remembering_interrupts

    with remembering_interrupts():
        try:
            from biomotion.body.kinematics import torch_threads

            # many small batched tensor ops: one intra-op thread per process is fastest (docs/results/dynamics.md)
            with torch_threads(1), warnings.catch_warnings():
                warnings.showwarning = _one_line_warnings(warnings.showwarning)
                status = int(args.run(args) or 0)
        except KeyboardInterrupt:
            return _interrupted()
        except Exception as error:  # noqa: BLE001 - every failure is reported on one line (see `_failed`)
            return _interrupted() if interrupted() else _failed(error, args, debug)
    return _interrupted() if interrupted() else status


def _interrupted() -> int:
    print("interrupted", file=sys.stderr)
    return 130


def _failed(error: Exception, args: argparse.Namespace, debug: bool) -> int:
    """One line on stderr for ``error`` and the exit status: 2 for bad input (`BiomotionError`) and what the file
    system refused, 141 for a closed pipe, 1 for anything else (a bug; re-raised with ``--debug``)."""
    from biomotion.errors import BiomotionError, SettingsError

    if isinstance(error, BiomotionError):
        config = getattr(args, "config", None)
        if isinstance(error, SettingsError) and config is not None:  # a setting of the --config file: name it
            error = f"{config}: {error}"
        print(f"error: {error}", file=sys.stderr)
        return 2
    if isinstance(error, BrokenPipeError):  # `biomotion inspect X | head`: the reader left; say nothing more
        sys.stdout = open(os.devnull, "w")
        return 141
    if isinstance(error, OSError):  # the file system refused: a full disk, a permission, a path that is too long
        if debug:
            raise error
        where = f"{error.filename}: " if error.filename else ""
        print(f"error: {where}{error.strerror or error}", file=sys.stderr)
        return 2
    if debug:
        raise error
    print(
        f"internal error: {type(error).__name__}: {error} (a bug in biomotion; rerun with --debug for the "
        "traceback and report it)",
        file=sys.stderr,
    )
    return 1
