"""``biomotion generate``: motion for a person and an action (PG-BIG), with its forces, torques, activations,
metrics, plots and viewer (`biomotion.generation.request.generate`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from biomotion.cli._common import add_data_root, add_overwrite, command_line, fresh_folder, moved, number

#: The longest clip one request may ask for (s): the prior samples tokens autoregressively and guidance refines
#: every frame, so a request far beyond the training clips' length mostly costs time (minutes per minute of motion).
MAX_SECONDS = 60.0
MAX_SAMPLES = 64

DESCRIPTION = (
    "Generate motion of ACTION for a person (PG-BIG): the profile (a YAML/JSON file or a subject table row) and "
    "optional reference clips of the person condition an autoregressive prior over motion tokens; biomechanical "
    "guidance then refines the sample through the body model and the muscle surrogate. Writes, per sample: "
    "motion.mot (coordinates of the person's scaled model), motion.bvh, grf.mot + grf_loads.xml and torques.sto "
    "(inferred from the motion), activations.sto (surrogate), com_zmp.sto, metrics.json (with the request, the "
    "profile, the seed and the versions), plots and viewer.html; and model.osim (the generic Rajagopal 2016 model "
    "scaled to the person's height and mass; with --shape, that body's scaled model, each clip moved onto it by "
    "the HUMOS shape adapter as `biomotion adapt` does). Python: biomotion.generate."
)
EPILOG = (
    'example: biomotion generate --profile examples/runner_52_acl.yaml --action "running at 3.5 m/s" '
    "--seconds 3 --out out/runner"
)


def add_parser(verbs) -> None:
    parser = verbs.add_parser(
        "generate",
        help="generate personalised, biomechanically guided motion for a person and an action (PG-BIG)",
        description=DESCRIPTION,
        epilog=EPILOG,
    )
    person = parser.add_argument_group("who (optional: without a profile the motion is population-level)")
    person.add_argument(
        "--profile",
        type=Path,
        help="profile file (YAML/JSON: age, sex, height, mass, sport, level, experience_years, injuries)",
    )
    person.add_argument("--subject-table", type=Path, help="subject table (CSV/XLSX) holding the person")
    person.add_argument("--subject-id", help="the person's id in --subject-table")
    person.add_argument(
        "--reference",
        type=Path,
        action="append",
        help="a clip of the person (OpenSim coordinates .mot/.sto, Rajagopal-family names); "
        "repeatable. The clips condition the prior and centre the motion on the person's "
        "posture (their mean deviation from the population's for the clip's action and speed; "
        "metrics.json lists the offset)",
    )
    person.add_argument(
        "--reference-action",
        action="append",
        metavar="TEXT",
        help='what a --reference clip shows, free text like --action ("run at 2.5 m/s"); one per '
        "--reference, in order. Without it, each clip's action is the one whose population "
        "posture is nearest and its speed that action's mean",
    )
    parser.add_argument(
        "--action",
        help='(required) what to do, free text mapped to the nearest dataset label ("run at '
        '3.5 m/s", "squat", "drop jump", "walk with toes out"; without a number, the '
        'label\'s median training speed, or its lower/upper quartile for "slowly", "fast" '
        '...); the Bandai-Namco contents and styles ("wave both hands", "bow", '
        '"walk, elderly") go to the full-body bundle, with the profile\'s biodata masked '
        "(docs/generation.md). Text that matches no known action is refused with the "
        "closest ones",
    )
    parser.add_argument(
        "--seconds",
        type=number(0.5, MAX_SECONDS),
        default=3.0,
        help=f"clip length, 0.5 to {MAX_SECONDS:g} s (default: %(default)s)",
    )
    parser.add_argument(
        "--samples",
        type=number(1, MAX_SAMPLES, integer=True),
        default=1,
        help=f"clips to draw, 1 to {MAX_SAMPLES} (default: %(default)s)",
    )
    parser.add_argument(
        "--seed",
        type=number(0, 2**63 - 1, integer=True),
        default=0,
        help="random seed; the same seed gives the same files (default: %(default)s)",
    )
    parser.add_argument(
        "--generator",
        choices=("pgbig", "flexmotion"),
        default="pgbig",
        help="pgbig (default) or flexmotion: one 2.1 s window per sample with torques_generated.sto, "
        "grf_generated.mot, activations_generated.sto as generated and their agreement with inverse dynamics "
        "in metrics.json (biomotion.generation.flexmotion)",
    )
    parser.add_argument("--no-guidance", action="store_true", help="skip biomechanical guidance (ablation)")
    parser.add_argument(
        "--control",
        type=Path,
        metavar="FILE",
        help="control spec (YAML, examples/control/): targets on vertical GRF, joint angles, COM height, body "
        "paths, joint moments or muscle activations, met through guidance (biomotion.guidance.control, "
        "docs/control.md); with --generator flexmotion through FlexMotion's control module (no COM targets; "
        "metrics.json records the bounds). With PG-BIG each sample's folder then also gets control.json (per "
        "target: what it asks, what the written files achieve, met or not) and control.png + control.svg "
        "(target against achieved; not with --no-figures)",
    )
    parser.add_argument(
        "--smooth",
        type=number(0, low_open=True),
        metavar="HZ",
        help="low-pass the guided coordinates at HZ (zero-lag Butterworth, below 15 Hz at the "
        "generator's 30 Hz) before the feet are planted: 6 Hz brings jerk to the real clips' "
        "level and lowers muscle-limit violations, at a little more foot sliding "
        "(docs/results/dev_guidance_skim.md). Default: off",
    )
    parser.add_argument(
        "--refine",
        action="store_true",
        help="pass each guided sample through the PhysPT refiner (`biomotion refine`) before the files are "
        "written: steadier speed and energy, feet that stay planted (docs/results/eval_refine.md)",
    )
    parser.add_argument("--refiner", type=Path, help="refiner weights for --refine (default: the shipped ones)")
    parser.add_argument(
        "--shape",
        type=Path,
        metavar="MODEL_OR_SHAPE",
        help="write the clips on this body, what `biomotion adapt --to` takes: a scaled .osim, or a shape file "
        "(.yaml/.json: height (m) and mass (kg), optionally sex, or a Shape's fields). Each clip is moved onto it by "
        "the HUMOS shape adapter (a gait: the adapter re-times the stride for the body) and model.osim is its "
        "model, not the generic one scaled uniformly; the body wins over the profile's height and mass (a note "
        "says so where they differ), the profile still conditions the generator. PG-BIG only",
    )
    parser.add_argument(
        "--shape-height",
        type=number(0, low_open=True),
        metavar="M",
        help="standing height of the --shape body (m), needed when its model has no head or torso",
    )
    parser.add_argument(
        "--adapter",
        type=Path,
        help="shape-adapter weights for --shape (default: the shipped checkpoints/shape_adapter.safetensors)",
    )
    parser.add_argument("--no-profile", action="store_true", help="ignore the profile and references (ablation)")
    parser.add_argument("--no-figures", action="store_true", help="no plots or viewer")
    parser.add_argument(
        "--threads",
        type=number(1, 256, integer=True),
        help="torch threads for sampling and guidance (default: 2, or the machine's cores if fewer)",
    )
    add_data_root(parser, "folder with opensim-models/ (the canonical Rajagopal model)")
    parser.add_argument(
        "--checkpoints",
        type=Path,
        help="folder of trained weights (default: the shipped lab bundle, or the shipped full-body "
        "bundle checkpoints/full-body for the labels only it knows)",
    )
    parser.add_argument("--out", type=Path, help="(required) output folder (created; must be new or empty)")
    add_overwrite(parser)
    parser.add_argument(
        "--list-actions",
        action="store_true",
        help="list the actions, styles and typical speeds each shipped bundle knows, and exit",
    )
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from biomotion.errors import ConfigError

    if args.list_actions:
        from biomotion.generation.pipeline import CHECKPOINTS
        from biomotion.generation.routing import vocabulary_listing

        print(vocabulary_listing(args.checkpoints or CHECKPOINTS))
        return 0
    missing = [flag for flag, value in (("--action", args.action), ("--out", args.out)) if value is None]
    if missing:
        raise ConfigError(f"generate needs {' and '.join(missing)} (or --list-actions to see the actions)")
    if args.profile is not None and args.subject_table is not None:
        raise ConfigError("give either --profile or --subject-table/--subject-id, not both")
    if (args.subject_table is None) != (args.subject_id is None):
        raise ConfigError("--subject-table and --subject-id go together")
    if args.refiner is not None and not args.refine:
        raise ConfigError("--refiner names the weights of --refine: give --refine too")
    if args.generator == "flexmotion" and args.shape is not None:
        raise ConfigError("--shape moves PG-BIG clips onto a body: --generator flexmotion takes no --shape")
    if (args.shape_height is not None or args.adapter is not None) and args.shape is None:
        raise ConfigError("--shape-height and --adapter go with --shape")
    if args.refiner is not None and not args.refiner.is_file():
        raise ConfigError(f"{args.refiner}: --refiner is not a file")
    references = args.reference or ()
    if args.reference_action and len(args.reference_action) != len(references):
        raise ConfigError(
            f"--reference-action given {len(args.reference_action)} times for {len(references)} "
            "--reference clips: give one per clip, in the same order, or none"
        )
    for path, flag in [
        (args.profile, "--profile"),
        (args.subject_table, "--subject-table"),
        *((p, "--reference") for p in args.reference or ()),
    ]:
        if path is not None and not path.is_file():
            raise ConfigError(f"{path}: {flag} is not a file")
    from biomotion.generation.request import generate

    if args.generator == "flexmotion":
        with fresh_folder(args.out, args.overwrite) as scratch:
            result = generate(
                action=args.action, out=scratch, data_root=args.data_root, checkpoints=args.checkpoints,
                profile_file=args.profile, subject_table=args.subject_table, subject_id=args.subject_id,
                references=args.reference or (), seconds=args.seconds, seed=args.seed, samples=args.samples,
                personalised=not args.no_profile, command=command_line(), smooth_hz=args.smooth,
                refine=args.refine, generator="flexmotion", control=args.control,
            )  # fmt: skip
        print(f"generated {args.samples} FlexMotion clip(s) in {result['generate_seconds']:.2f} s -> {args.out}")
        for k, files in enumerate(result["files"]):
            for role, path in files.items():
                print(
                    f"  {f'sample_{k}/' if len(result['files']) > 1 else ''}{role:12s} {moved(path, scratch, args.out)}"
                )
        return 0
    with fresh_folder(args.out, args.overwrite) as scratch:
        result = generate(
            action=args.action,
            out=scratch,
            data_root=args.data_root,
            checkpoints=args.checkpoints,
            profile_file=args.profile,
            subject_table=args.subject_table,
            subject_id=args.subject_id,
            references=args.reference or (),
            reference_actions=args.reference_action or (),
            seconds=args.seconds,
            seed=args.seed,
            samples=args.samples,
            guidance=not args.no_guidance,
            personalised=not args.no_profile,
            figures=not args.no_figures,
            command=command_line(),
            threads=args.threads,
            smooth_hz=args.smooth,
            refine=args.refine,
            refiner=args.refiner,
            **({} if args.control is None else {"control": args.control}),
            **({} if args.shape is None else {"shape": args.shape, "shape_height": args.shape_height}),
            **({} if args.adapter is None else {"adapter": args.adapter}),
        )
    a = result["action"]
    print(f"answered by the {result['route'].describe()}")
    for note in result["notes"]:
        print(f"note: {note}")
    speed = "" if a.speed is None else f" at {a.speed:g} m/s"
    style = "" if a.style is None else f" ({a.style})"
    print(
        f"generated {args.samples} x {args.seconds:g} s of {a.action!r}{style}{speed} in "
        f"{result['generate_seconds']:.2f} s (models loaded in {result['load_seconds']:.1f} s; outputs written in "
        f"{result['write_seconds']:.1f} s) -> {args.out}"
    )
    for sample, files in result["files"].items():
        for role, path in files.items():
            print(f"  {sample + '/' if len(result['files']) > 1 else ''}{role:18s} {moved(path, scratch, args.out)}")
    return 0
