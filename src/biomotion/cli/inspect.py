"""``biomotion inspect``: what a file holds (`biomotion.io.formats.describe`), as JSON."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def add_parser(verbs) -> None:
    parser = verbs.add_parser(
        "inspect",
        help="print what a file holds (frames, rate, channels, units; for a subject table its schema, "
        "subjects and profile fields; for an .osim model its bodies, mass, coordinates, markers and "
        "muscles; for an IK or Scale setup .xml the files it names and its tasks)",
        description="Print what INPUT holds as JSON. Python: biomotion.describe.",
    )
    parser.add_argument("input", type=Path)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from biomotion.errors import ConfigError
    from biomotion.io.formats import describe

    if not args.input.is_file():
        raise ConfigError(
            f"{args.input}: no such file" if not args.input.exists() else f"{args.input}: a folder; give a file"
        )
    print(json.dumps(describe(args.input), indent=1))
    return 0
