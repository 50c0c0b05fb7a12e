"""``biomotion retarget``: captured motion (markers or skeletons, one file or a folder) → coordinates of a model
by batched inverse kinematics (`biomotion.ik.retarget.retarget`)."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from biomotion.cli._common import add_overwrite, fresh_folder, number

DESCRIPTION = (
    "Marker trials: inverse kinematics of every frame at once on MODEL, the subject's scaled model (weighted least "
    "squares, coordinate ranges, locked and coupled coordinates, occluded markers skipped per frame); marker "
    "weights, coordinate tasks and time range come from an OpenSim IK setup (--setup), or every model marker found "
    "in the data weighs 1. Skeletons (BVH, or marker files of joint centres with --joint-map): MODEL is the generic "
    "model, scaled to each skeleton's segment lengths and fitted to its joint centres (PG-BIG A.5), coordinates "
    "filtered at 10 Hz when the frame rate is at least 40 Hz and kept in range, feet put on y = 0; the scaled model "
    "is written as <trial>.osim. Writes <trial>.mot per trial and summary.csv (RMS and max marker or joint-centre "
    "error, frames dropped); keeps going past a bad trial. Python: biomotion.retarget."
)


def add_parser(verbs) -> None:
    parser = verbs.add_parser(
        "retarget",
        help="captured motion (.trc, .c3d markers; .bvh/.bvh.gz skeletons; a file "
        "or a folder) -> model coordinates (.mot) by batched IK",
        description=DESCRIPTION,
    )
    parser.add_argument("input", type=Path, help="a .trc/.c3d/.bvh/.bvh.gz file or a folder of them")
    parser.add_argument(
        "--model",
        type=Path,
        required=True,
        help="markers: the subject's scaled .osim (with markers); skeletons: the generic .osim "
        "(e.g. Rajagopal2016.osim)",
    )
    parser.add_argument(
        "--setup",
        type=Path,
        help="OpenSim IK setup XML: its marker weights, coordinate tasks and "
        "(for a single trial) time range, as OpenSim's IK tool uses them",
    )
    parser.add_argument(
        "--static",
        type=Path,
        help="a static trial (.trc/.c3d): MODEL is then the generic model, scaled to it by "
        "--scale-setup first (as `biomotion scale`, the static markers low-passed by --filter "
        "too; written into --out), and the trials are solved on the scaled model",
    )
    parser.add_argument(
        "--scale-setup",
        type=Path,
        help="OpenSim ScaleTool setup XML for --static (its measurements, mass, marker placer)",
    )
    parser.add_argument(
        "--joint-map",
        type=Path,
        help='JSON {"centres": {model joint: skeleton joint}, "toes": {model toe joint: skeleton '
        "joint}}: treat the input as joint centres (built in: the Bandai-Namco skeleton)",
    )
    parser.add_argument(
        "--filter",
        type=number(0, low_open=True),
        metavar="HZ",
        help="low-pass (Hz): markers before IK; skeletons: the coordinates (default 10, applied "
        "when the frame rate is at least 4x the cutoff)",
    )
    parser.add_argument("--out", type=Path, required=True, help="output folder (created; must be new or empty)")
    add_overwrite(parser)
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from biomotion.errors import ConfigError
    from biomotion.ik.retarget import is_skeleton, motion_files

    if args.static is not None and args.scale_setup is None:
        raise ConfigError(
            "--static scales the model, which needs the measurements of an OpenSim Scale setup: give "
            "--scale-setup XML too (`biomotion scale --help`)"
        )
    if not args.model.is_file():
        raise ConfigError(f"{args.model}: --model is not a file")
    files = motion_files(args.input)
    if args.scale_setup is not None and (args.joint_map is not None or any(is_skeleton(p) for p in files)):
        raise ConfigError(
            "--static/--scale-setup scale a model to markers; skeletons (BVH, --joint-map) are "
            "scaled to their own joint centres: retarget them without these options"
        )
    from biomotion.errors import BiomotionError

    with fresh_folder(args.out, args.overwrite) as scratch:
        summaries = _retarget(args, files, scratch)
        if summaries and all(s.error for s in summaries):  # nothing worth keeping: --out is not made
            if len(summaries) == 1:
                raise BiomotionError(summaries[0].error)
            _print(summaries)
            raise BiomotionError(
                f"{args.input}: none of its {len(summaries)} trials could be retargeted (the first, "
                f"{summaries[0].trial}: {summaries[0].error})"
            )
    failed = [s for s in summaries if s.error]
    _print(summaries)
    print(f"{len(summaries) - len(failed)} of {len(summaries)} trials retargeted -> {args.out} (summary.csv)")
    return 0


def _print(summaries) -> None:
    for summary in summaries:
        state = (
            f"FAILED: {summary.error}"
            if summary.error
            else (
                f"{summary.frames} frames, RMS error {100 * summary.rms_error_m:.2f} cm, "
                f"max {100 * summary.max_error_m:.2f} cm"
            )
        )
        print(f"  {summary.trial}: {state}")


def _retarget(args: argparse.Namespace, files: list[Path], scratch: Path):
    from biomotion.body.model import BodyModel
    from biomotion.ik.retarget import retarget
    from biomotion.ik.skeleton import JointMap
    from biomotion.io.setup import read_ik_setup

    model_path = args.model
    if args.scale_setup is not None:
        from biomotion.cli.scale import print_calibration
        from biomotion.ik.calibrate import calibrate

        done = calibrate(args.scale_setup, scratch, model=args.model, static=args.static, filter_hz=args.filter)
        print_calibration(done, scratch=scratch, out=args.out)
        model_path = done.model
    setup = read_ik_setup(args.setup) if args.setup else None
    if setup is not None and setup.time_range is not None and args.input.is_dir():
        print(f"note: the time range of {args.setup} belongs to one trial; the trials of {args.input} are solved whole")
        setup = replace(setup, time_range=None)
    joint_map = JointMap.from_file(args.joint_map) if args.joint_map else None
    return retarget(
        files,
        BodyModel.from_osim(model_path),
        scratch,
        weights=setup.marker_weights if setup else None,
        filter_hz=args.filter,
        joint_map=joint_map,
        model_path=model_path,
        setup=setup,
        progress=not args.quiet,
    )
