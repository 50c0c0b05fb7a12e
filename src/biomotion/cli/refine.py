"""``biomotion refine``: a noisy motion made physically consistent by the PhysPT refiner, with the ground reaction
and joint torques it infers (`biomotion.generation.refinement.refine`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from biomotion.cli._common import add_data_root, add_overwrite, fresh_folder, moved, number

DESCRIPTION = (
    "Refine MOTION (OpenSim coordinates, .mot/.sto, Rajagopal-family names with the pelvis and both legs) with the "
    "PhysPT refiner: a Transformer trained to undo the jitter, drift, foot sliding, root bounce and dropped frames of "
    "markerless capture and generated clips, with heads for joint torques and contact forces (Zhang et al. 2024). "
    "Writes refined.mot (same columns and times as MOTION, degrees), grf.mot + grf_loads.xml (the feet's ground "
    "reaction as an OpenSim ExternalLoads pair), torques.sto (generalized forces, OpenSim's column names) and "
    "before_after.png. Forces are the generic model's (75.3 kg, 1.70 m) unless --mass/--height give the person's. "
    "Python: biomotion.refine."
)


def add_parser(verbs) -> None:
    parser = verbs.add_parser(
        "refine",
        help="make noisy motion physically consistent and infer its forces (PhysPT refiner)",
        description=DESCRIPTION,
        epilog="example: biomotion refine walk_markerless.mot --out out/walk_refined",
    )
    parser.add_argument("motion", type=Path, metavar="MOTION", help="coordinates file (.mot or .sto)")
    parser.add_argument("--model", type=Path, help="refiner weights (default: checkpoints/refiner.safetensors)")
    parser.add_argument("--out", type=Path, required=True, help="output folder (created; must be new or empty)")
    add_overwrite(parser)
    parser.add_argument(
        "--height", type=number(0.5, 2.5), help="the person's height in m: places the motion at the refiner's size"
    )
    parser.add_argument("--mass", type=number(10, 300), help="the person's mass in kg: scales the forces and torques")
    parser.add_argument("--no-figures", action="store_true", help="no before/after plot")
    add_data_root(parser, "folder with opensim-models/ (the canonical Rajagopal model)")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from biomotion.errors import ConfigError

    if not args.motion.is_file():
        raise ConfigError(f"{args.motion}: MOTION is not a file")
    if args.motion.suffix.lower() not in (".mot", ".sto"):
        raise ConfigError(
            f"{args.motion}: refine reads OpenSim coordinate files (.mot/.sto); convert other formats first "
            "(`biomotion retarget` for BVH or markers)"
        )
    if args.model is not None and not args.model.is_file():
        raise ConfigError(f"{args.model}: --model is not a file")
    from biomotion.generation.refinement import refine, write_refined
    from biomotion.io.mot import read_motion

    motion = read_motion(args.motion)
    refined = refine(
        motion, args.model, data_root=args.data_root, height=args.height, mass=args.mass, source=args.motion
    )
    with fresh_folder(args.out, args.overwrite) as scratch:
        files = write_refined(scratch, refined, figures=not args.no_figures)
    print(
        f"refined {motion.n_frames} frames ({motion.duration:.2f} s at {motion.rate:.4g} Hz; the refiner runs at "
        f"{refined.rate:g} Hz) in {refined.seconds:.2f} s -> {args.out}"
    )
    for role, path in files.items():
        print(f"  {role:10s} {moved(path, scratch, args.out)}")
    return 0
