"""``biomotion convert``: a motion file into another format (`biomotion.analysis.convert.convert`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from biomotion.cli._common import writable_file

DESCRIPTION = (
    "Read INPUT in any supported format and write OUTPUT in the format its suffix names: coordinates "
    ".mot/.sto/.csv, markers .trc/.c3d/.csv (from .trc, .c3d or BVH joint positions; .c3d output holds the markers "
    "only, in mm), skeletons .bvh/.bvh.gz. With --model, INPUT holds coordinates of that model, which become a BVH "
    "skeleton of its bodies (.bvh), its markers by forward kinematics (.trc, .c3d) or the coordinates in model "
    "order (.mot, .sto, .csv). An existing OUTPUT is refused unless --overwrite. Python: biomotion.convert."
)


def add_parser(verbs) -> None:
    parser = verbs.add_parser(
        "convert", help="convert between motion/marker formats (.mot .sto .trc .c3d .bvh .csv)", description=DESCRIPTION
    )
    parser.add_argument("input", type=Path)
    parser.add_argument("output", type=Path)
    parser.add_argument("--model", type=Path, help="the .osim model whose coordinates INPUT holds")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing OUTPUT file")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from biomotion.errors import ConfigError

    if not args.input.is_file():
        raise ConfigError(
            f"{args.input}: no such file"
            if not args.input.exists()
            else f"{args.input}: INPUT is a folder; give a file"
        )
    writable_file(args.output, "OUTPUT")
    if args.output.exists() and not args.overwrite:
        raise ConfigError(f"{args.output}: exists; choose another OUTPUT or pass --overwrite to replace it")
    if args.output.absolute() == args.input.absolute():
        raise ConfigError(f"{args.output}: OUTPUT is INPUT")
    from biomotion.analysis.convert import convert

    written = convert(args.input, args.output, model=args.model)
    print(f"wrote {written}")
    return 0
