"""``biomotion scale``: a generic model scaled to a subject — from a static trial by an OpenSim ScaleTool setup
(`biomotion.ik.calibrate.calibrate`), or to a person's stature, mass and ANSUR II measures without markers
(`biomotion.body.scaling.stature.write_person_model`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from biomotion.cli._common import add_overwrite, fresh_folder, moved, number

DESCRIPTION = (
    "OpenSim's ScaleTool from its setup XML: body scale factors from the distances of the setup's marker pairs in "
    "the static trial against the generic model (measurements; manual scales as the setup orders them), masses "
    "scaled to the subject's mass (distribution kept when the setup says so), then the MarkerPlacer: the static "
    "pose by IK and the non-fixed markers moved onto the data (PG-BIG A.2). Writes NAME.osim (opens in OpenSim; use "
    "it as `retarget --model`), NAME_scale_set.xml, NAME_static_pose.mot and NAME_scale.json into --out. Setups "
    "name their model and static trial by paths relative to where they were written: --model and --static "
    "override them. Without markers, a person (--profile, or a subject table row) scales --model by stature and, "
    "where given, ANSUR II segment measures. Python: biomotion.calibrate."
)
EPILOG = (
    "example, with F=../shared/data/fukuchi-running: biomotion scale $F/RBDS001/RBDS001_scaleSetup_simple.xml "
    "--model $F/generic-models/Denton2023_LowerLimb_Fukuchi2017.osim --static $F/c3d/RBDS001static.c3d "
    "--marker-filter 10 --out out/RBDS001"
)


def add_parser(verbs) -> None:
    parser = verbs.add_parser(
        "scale",
        help="scale a generic model to a subject from a static trial (OpenSim "
        "ScaleTool setup) or to a person's profile -> .osim",
        description=DESCRIPTION,
        epilog=EPILOG,
    )
    parser.add_argument("setup", type=Path, nargs="?", help="OpenSim ScaleTool setup XML")
    parser.add_argument(
        "--profile",
        type=Path,
        help="instead of a setup: a person (YAML/JSON profile); every body scaled by the stature "
        "ratio, except segments whose ANSUR II measures (mm, the survey's names, e.g. "
        "footlength) the profile gives, scaled by them (biomotion.body.scaling.segments)",
    )
    parser.add_argument(
        "--subject-table",
        type=Path,
        help="instead of a setup: a subject table (an ANSUR II file gives every measure), with --subject-id",
    )
    parser.add_argument("--subject-id", help="the row of --subject-table")
    parser.add_argument("--model", type=Path, help="the generic .osim (default: the setup's model_file)")
    parser.add_argument("--static", type=Path, help="the static trial, .trc or .c3d (default: the setup's marker_file)")
    parser.add_argument("--mass", type=number(1, 500), help="subject mass in kg (default: the setup's mass)")
    parser.add_argument(
        "--marker-filter",
        type=number(0, low_open=True),
        metavar="HZ",
        help="low-pass the static markers first (zero-lag Butterworth; the Fukuchi chain used 10 Hz)",
    )
    parser.add_argument("--name", help="name of the scaled model and its files (default: the setup's name)")
    parser.add_argument("--out", type=Path, required=True, help="output folder (created; must be new or empty)")
    add_overwrite(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from biomotion.errors import ConfigError

    by_profile = args.profile is not None or args.subject_table is not None
    if by_profile == (args.setup is not None):
        raise ConfigError(
            "give a ScaleTool SETUP (with a static trial), or a person: --profile FILE or "
            "--subject-table CSV --subject-id ID"
        )
    if args.name is not None and (not args.name.strip() or any(c in args.name for c in "/\\\0")):
        raise ConfigError(f"--name {args.name!r}: a model name cannot be empty or hold a path separator")
    if by_profile:
        return _scale_to_person(args)
    from biomotion.ik.calibrate import calibrate

    with fresh_folder(args.out, args.overwrite) as scratch:
        done = calibrate(
            args.setup,
            scratch,
            model=args.model,
            static=args.static,
            mass=args.mass,
            filter_hz=args.marker_filter,
            name=args.name,
        )
    print_calibration(done, scratch=scratch, out=args.out)
    return 0


def _scale_to_person(args: argparse.Namespace) -> int:
    """`scale --profile|--subject-table`: no markers; stature ratio, ANSUR II segment measures where given."""
    from dataclasses import replace

    from biomotion.body.scaling.stature import write_person_model
    from biomotion.errors import ConfigError
    from biomotion.io.profiles import person

    if args.model is None:
        raise ConfigError("scaling to a person needs the generic model: give --model OSIM (e.g. Rajagopal2016.osim)")
    if args.static is not None or args.marker_filter is not None:
        raise ConfigError(
            "--static and --marker-filter belong to a ScaleTool setup; a person is scaled from their profile"
        )
    profile = person(args.profile, args.subject_table, args.subject_id)
    if args.mass is not None:
        profile = replace(profile, mass=args.mass)
    with fresh_folder(args.out, args.overwrite) as scratch:
        model, summary_file, summary = write_person_model(
            args.model, profile, scratch, args.name or profile.subject_id or "subject"
        )
    measured = len(summary["ansur_measures_mm"])
    print(
        f"scaled {Path(args.model).name} to {summary['mass_kg']:.2f} kg, standing {summary['standing_height_m']:.3f}"
        f" m ({'stature ratio' if not measured else f'{measured} ANSUR II measures, stature ratio elsewhere'})"
    )
    print(f"  {moved(model, scratch, args.out)}\n  {moved(summary_file, scratch, args.out)}")
    return 0


def print_calibration(done, files: bool = True, scratch: Path | None = None, out: Path | None = None) -> None:
    """One line on what `biomotion.ik.calibrate.calibrate` did, then (``files``) the files it wrote (moved from
    ``scratch`` to ``out`` when given)."""
    summary = done.summary
    scaled = {body: f for body, f in summary["scale_factors"].items() if any(abs(v - 1) > 1e-9 for v in f)}
    print(
        f"scaled {Path(summary['generic_model']).name} to {summary['mass_kg']:.2f} kg: {len(scaled)} bodies "
        f"scaled by {len(summary['measurements'])} measurements"
        + (
            f", {summary['markers_placed']} markers placed (static pose marker RMS "
            f"{100 * summary['placement_marker_rms_m']:.2f} cm)"
            if summary["markers_placed"] is not None
            else ""
        )
    )
    for path in (done.model, done.scale_set, done.pose, done.summary_file) if files else ():
        if path is not None:
            print(f"  {moved(path, scratch, out) if scratch is not None else path}")
