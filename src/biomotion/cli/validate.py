"""``biomotion validate``: biomotion against OpenSim 4.6 and measured data (`biomotion.validation.run`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from biomotion.cli._common import add_data_root, command_line, writable_file

DESCRIPTION = (
    "Run the validation checks on whatever data is under --data-root (any folder laid out like ../shared/data; "
    "absent sources are named and skipped): kinematics = forward kinematics vs OpenSim on every model; dynamics = "
    "inverse dynamics vs OpenSim's solver and ID tool, and ground reaction inferred from kinematics vs force "
    "plates; ik = marker IK and scaling vs OpenSim's InverseKinematicsTool and ScaleTool; muscles = moment arms and "
    "static optimization vs OpenSim, activations vs EMG. Needs the validate extra (opensim). Python: "
    "biomotion.run_validation."
)


def add_parser(verbs) -> None:
    parser = verbs.add_parser(
        "validate", help="check biomotion against OpenSim and measured data; JSON report", description=DESCRIPTION
    )
    parser.add_argument("what", choices=("kinematics", "dynamics", "ik", "muscles"))
    add_data_root(parser)
    parser.add_argument("--json", type=Path, required=True, help="report file to write")
    parser.add_argument("--md", type=Path, help="also write the tables as Markdown (for docs/results/)")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from biomotion.errors import ConfigError

    for path in (args.json, args.md):
        if path is not None:
            writable_file(path, "--json/--md")
    if not args.data_root.is_dir():
        raise ConfigError(f"{args.data_root}: --data-root is not a folder")
    from biomotion.validation.run import run_validation

    report = run_validation(
        args.what, args.data_root, args.json, progress=not args.quiet, md_path=args.md, command=command_line()
    )
    for key, value in report.items():
        if not isinstance(value, (dict, list)):
            print(f"  {key}: {value}")
    for skipped in report.get("skipped", []):
        print(f"  skipped {skipped}")
    print(f"report written to {args.json}")
    return 0
