"""``biomotion view``: a self-contained offline HTML page that plays a motion in 3D (`biomotion.viz.viewer`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from biomotion.cli._common import writable_file

DESCRIPTION = (
    "Animated 3D view of MOTION (.mot with --model, .bvh/.bvh.gz, .trc, .c3d markers) with optional ground reaction "
    "arrows, COM/ZMP and support polygon (com_zmp.sto from `analyze`), muscle activations, and a second motion to "
    "compare (overlay or side by side). One HTML file, no network needed. Python: biomotion.view."
)


def add_parser(verbs) -> None:
    parser = verbs.add_parser(
        "view", help="write a self-contained HTML viewer of a motion (offline, any browser)", description=DESCRIPTION
    )
    parser.add_argument("motion", type=Path)
    parser.add_argument("--model", type=Path, help=".osim model for an OpenSim coordinates file")
    parser.add_argument("--grf", type=Path, help="ground reaction (.mot or .c3d)")
    parser.add_argument("--activations", type=Path, help="muscle activations (.sto)")
    parser.add_argument("--com-zmp", type=Path, help="COM/ZMP/support file (com_zmp.sto from `analyze`)")
    parser.add_argument("--compare", type=Path, help="a second motion to compare")
    parser.add_argument("--compare-mode", choices=("overlay", "side"), default="overlay")
    parser.add_argument("--geometry", type=Path, action="append", help="extra folder of .vtp meshes (repeatable)")
    parser.add_argument("--out", type=Path, default=Path("viewer.html"), help="HTML file (default: %(default)s)")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from biomotion.errors import ConfigError

    for path, flag in (
        (args.motion, "MOTION"),
        (args.model, "--model"),
        (args.grf, "--grf"),
        (args.activations, "--activations"),
        (args.com_zmp, "--com-zmp"),
        (args.compare, "--compare"),
    ):
        if path is not None and not path.is_file():
            raise ConfigError(f"{path}: {flag} is not a file")
    writable_file(args.out)
    from biomotion.viz.viewer import view_command

    path = view_command(
        args.motion,
        model=args.model,
        grf=args.grf,
        activations=args.activations,
        com_zmp=args.com_zmp,
        compare=args.compare,
        out=args.out,
        compare_mode=args.compare_mode,
        geometry=args.geometry or (),
    )
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB); open it in any browser, no network needed")
    return 0
