"""``biomotion adapt``: a motion of one body moved onto another body the way that body would move (HUMOS shape
adapter, `biomotion.generation.adapt.adapt`), written as .mot, .osim, .bvh, a side-by-side viewer and a record."""

from __future__ import annotations

import argparse
from pathlib import Path

from biomotion.cli._common import add_data_root, add_overwrite, command_line, fresh_folder, number

DESCRIPTION = (
    "Move MOTION (OpenSim coordinates, .mot/.sto, a gait of at least two strides) from the body it was recorded on "
    "(--from) onto another body (--to) the way that body would move (HUMOS): the shipped shape-conditioned c-VAE "
    "re-decodes the hip, knee, ankle and pelvis angles for the target's build and sets the stride time the target's "
    "shape predicts; the pelvis is raised or lowered so the target's feet meet the source's floor, and the feet are "
    "planted on the ground the source ran on (a treadmill belt's speed is estimated from the source's stance feet; "
    "--no-planting keeps the decoded leg angles). A body is a "
    "scaled OpenSim model (.osim) or a shape file (YAML/JSON): 'height' (m) and 'mass' (kg), optionally 'sex' and "
    "'generic' (the generic .osim to scale, relative to the file; default --generic, else Rajagopal 2016 under "
    "--data-root), or the fields of a biomotion Shape (reference, scales, mass, masses, height, lengths, sex). A "
    "lower-limb model has no standing height: give it with --from-height/--to-height. Writes motion.mot (on the "
    "target's scaled model, degrees), model.osim (that model), motion.bvh, viewer.html (adapted and source side by "
    "side) and record.json (inputs, both shapes, the adapter's SHA-256, stride times, ground velocity, planting, "
    "versions). Python: "
    "biomotion.adapt."
)
EPILOG = (
    "example, with F=../shared/data/fukuchi-running: biomotion adapt $F/ik/T35/RBDS04_T35_ik_simple.mot --from "
    "$F/RBDS04/RBDS04_simple.osim --from-height 1.61 --to $F/RBDS012/RBDS012_simple.osim --to-height 1.81 --out "
    "out/adapted"
)


def add_parser(verbs) -> None:
    parser = verbs.add_parser(
        "adapt",
        help="move a motion onto another body the way that body would move (HUMOS shape adapter)",
        description=DESCRIPTION,
        epilog=EPILOG,
    )
    parser.add_argument("motion", type=Path, help="the motion: OpenSim coordinates (.mot/.sto) on the --from body")
    parser.add_argument(
        "--from",
        dest="source",
        type=Path,
        required=True,
        metavar="MODEL_OR_SHAPE",
        help="the body MOTION was recorded on: its scaled .osim, or a shape file (.yaml/.json)",
    )
    parser.add_argument(
        "--to",
        dest="target",
        type=Path,
        required=True,
        metavar="MODEL_OR_SHAPE",
        help="the body to move it onto: a scaled .osim, or a shape file (.yaml/.json: height and mass, or a Shape)",
    )
    parser.add_argument("--out", type=Path, required=True, help="output folder (created; must be new or empty)")
    parser.add_argument(
        "--from-height",
        type=number(0, low_open=True),
        metavar="M",
        help="standing height of the --from body (m), needed when its model has no head or torso",
    )
    parser.add_argument(
        "--to-height",
        type=number(0, low_open=True),
        metavar="M",
        help="standing height of the --to body (m), needed when its model has no head or torso",
    )
    parser.add_argument(
        "--generic",
        type=Path,
        metavar="OSIM",
        help="generic model a shape file without 'generic' is scaled from (default: Rajagopal 2016 under --data-root)",
    )
    parser.add_argument(
        "--adapter",
        type=Path,
        help="shape-adapter weights (default: the shipped checkpoints/shape_adapter.safetensors)",
    )
    parser.add_argument(
        "--no-planting",
        action="store_true",
        help="keep the adapter's leg angles: do not plant the stance feet on the source's ground (treadmill or floor)",
    )
    parser.add_argument("--no-viewer", action="store_true", help="skip viewer.html (the largest file)")
    add_data_root(parser, "folder laid out like ../shared/data, for the default generic model")
    add_overwrite(parser)
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from biomotion.errors import ConfigError

    if not args.motion.is_file():
        raise ConfigError(f"{args.motion}: MOTION is not a file (OpenSim coordinates, .mot/.sto)")
    from biomotion.generation.adapt import adapt, write_adapted
    from biomotion.io.mot import read_motion
    from biomotion.io.paths import portable

    motion = read_motion(args.motion)
    adapted = adapt(
        motion,
        args.source,
        args.target,
        adapter=args.adapter,
        source_height=args.from_height,
        target_height=args.to_height,
        generic=args.generic,
        data_root=args.data_root,
        planting=not args.no_planting,
    )
    inputs = {
        "motion": portable(args.motion),
        "from": portable(args.source),
        "to": portable(args.target),
        "from_height_m": args.from_height,
        "to_height_m": args.to_height,
        "generic": None if args.generic is None else portable(args.generic),
        "planting": not args.no_planting,
    }
    with fresh_folder(args.out, args.overwrite) as scratch:
        files = write_adapted(adapted, scratch, viewer=not args.no_viewer, inputs=inputs, command=command_line())
    source, target = adapted.source.shape, adapted.target.shape
    strides = adapted.stride_time_s
    print(
        f"adapted {args.motion.name} from {source.height:.2f} m, {source.mass:.1f} kg to {target.height:.2f} m, "
        f"{target.mass:.1f} kg ({adapted.target.model.name}): stride {strides['source']:.3f} s -> "
        f"{strides['adapted']:.3f} s"
        + ("" if adapted.floor_shift_m is None else f", pelvis_ty {100 * adapted.floor_shift_m:+.1f} cm to the floor")
    )
    if adapted.ground_velocity_m_s is not None:
        vx, vz = adapted.ground_velocity_m_s
        print(
            f"  ground under the source's stance feet: ({vx:+.2f}, {vz:+.2f}) m/s (x, z); feet "
            + ("planted on it" if adapted.planted else "not planted (--no-planting)")
        )
    if adapted.filled:
        print(f"  at the target model's defaults (not in the motion): {', '.join(adapted.filled)}")
    print(f"wrote {', '.join(sorted(p.name for p in files.values()))} -> {args.out}")
    return 0
