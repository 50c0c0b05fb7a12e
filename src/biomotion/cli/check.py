"""``biomotion check``: a plausibility verdict for any motion (`biomotion.analysis.check.check`)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from biomotion.cli._common import add_data_root, number

DESCRIPTION = (
    "Judge MOTION — captured, refined or generated — on its model: residual force and moment at the pelvis, foot "
    "sliding, ground penetration, velocity spikes, joint-limit violations, ZMP outside the support and (with "
    "--muscles) activation saturation. Each rule flags frames by a threshold from published practice and fails "
    "when half the frames it applies to break it, warns from 5 % (biomotion.analysis.check). Prints the verdict "
    "and its reasons (--json: as JSON). Exit status 0 when the verdict is ok or warn, 1 when it is fail, 2 for "
    "bad input. Python: biomotion.check."
)


def add_parser(verbs) -> None:
    parser = verbs.add_parser(
        "check", help="plausibility verdict of a motion (exit 0 ok, 1 fail)", description=DESCRIPTION
    )
    parser.add_argument("motion", type=Path, help="coordinates (.mot/.sto) of MODEL")
    parser.add_argument(
        "--model",
        type=Path,
        help="the motion's .osim model (default: the canonical Rajagopal 2016 model under --data-root, for motions "
        "on its coordinates, as `biomotion generate` writes them)",
    )
    parser.add_argument("--forces", type=Path, help="measured ground reaction (.mot or .c3d plates)")
    parser.add_argument("--muscles", metavar="PATHS", help="muscle path functions: adds activation saturation")
    parser.add_argument("--treadmill", action="store_true", help="judge foot sliding relative to the belt")
    parser.add_argument(
        "--cutoff", type=number(0, 200), default=6.0, help="coordinate low-pass in Hz (default: %(default)s)"
    )
    parser.add_argument("--json", action="store_true", help="print the verdict as JSON")
    add_data_root(parser)
    parser.set_defaults(run=run)


def _model(args: argparse.Namespace):
    from biomotion.body.model import BodyModel
    from biomotion.errors import ConfigError

    if args.model is not None:
        if not args.model.is_file():
            raise ConfigError(f"{args.model}: --model is not a file")
        return BodyModel.from_osim(args.model), args.model
    from biomotion.data.clips import MODEL_FILE

    path = args.data_root / MODEL_FILE
    if not path.is_file():
        raise ConfigError(f"no --model given and the canonical model {path} is not there (give --model or --data-root)")
    return BodyModel.from_osim(path), path


def run(args: argparse.Namespace) -> int:
    from biomotion.analysis.check import check
    from biomotion.errors import ConfigError, DataFormatError
    from biomotion.io.formats import read_any
    from biomotion.motion import GroundReaction, Motion

    if not args.motion.is_file():
        raise ConfigError(f"{args.motion}: no such file")
    motion = read_any(args.motion)
    if not isinstance(motion, Motion):
        raise DataFormatError(args.motion, "holds no coordinates (check judges a .mot/.sto motion of a model)")
    model, model_path = _model(args)
    forces = None
    if args.forces is not None:
        if not args.forces.is_file():
            raise ConfigError(f"{args.forces}: --forces is not a file")
        data = read_any(args.forces)
        forces = getattr(data, "forces", data)
        if not isinstance(forces, GroundReaction):
            raise DataFormatError(args.forces, "holds no force-plate data")
    verdict = check(
        motion,
        model,
        forces,
        muscles=args.muscles,
        muscle_model=model_path,
        cutoff_hz=args.cutoff,
        treadmill=args.treadmill,
    )
    if args.json:
        print(json.dumps({"motion": str(args.motion), "model": str(model_path), **verdict.to_dict()}, indent=1))
    else:
        print(f"{verdict.verdict}: {args.motion} on {model.name} ({verdict.frames} frames)")
        for reason in verdict.reasons:
            print(f"  {reason.verdict:4s} {reason.rule}: {reason.message}")
    return 1 if verdict.failed else 0
