"""``biomotion eval``: score motion with the metrics of the four papers (`biomotion.evaluation`): a folder or files
against references, the real data per source (``reference``), or the shipped generator on subjects it never saw
(``generation``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from biomotion.cli._common import add_data_root, command_line, number, writable_file

DESCRIPTION = (
    "`biomotion eval --pred PATH... [--ref PATH...]` scores predicted motion (OpenSim .mot files, a BVH folder, or a "
    "dataset cache) and, with --ref, compares it with reference motion (PG-BIG Table 2 / PhysPT Table 1 layout). "
    "`biomotion eval reference` scores every source of the dataset registry under --data-root per source and "
    "action: the Reference column. `biomotion eval generation` generates for every unseen subject of --data-root "
    "and tabulates PG-BIG Tables 2-3. Every mode works on any folder laid out like ../shared/data, whoever is in "
    "it. Python: biomotion.evaluate, biomotion.eval_generation."
)


def add_parser(verbs) -> None:
    parser = verbs.add_parser(
        "eval",
        help="score motion with the metrics of the four papers (JSON, Markdown table, plots)",
        description=DESCRIPTION,
    )
    parser.add_argument(
        "mode",
        nargs="?",
        choices=("reference", "generation"),
        help="reference: score the real data (reference table); generation: generate for every "
        "unseen subject of --data-root and tabulate PG-BIG Tables 2-3 (full model, w/o "
        "guidance, w/o personalization, population baseline), the identity probe and the "
        "profile-manipulation study",
    )
    parser.add_argument("--pred", nargs="+", type=Path, help="predicted motion: files or one folder")
    parser.add_argument("--ref", nargs="+", type=Path, help="reference motion: files or one folder")
    add_data_root(
        parser, "folder laid out like ../shared/data: the canonical model, and the subjects of reference and generation"
    )
    parser.add_argument("--json", type=Path, help="JSON report to write")
    parser.add_argument("--md", type=Path, help="Markdown table to write (--pred: printed when not given)")
    parser.add_argument("--plots", type=Path, help="folder for per-clip distribution plots")
    parser.add_argument("--physics", action="store_true", help="also full-body energy and ZMP-in-support (slower)")
    parser.add_argument("--no-physics", action="store_true", help="reference: skip the slower physics metrics")
    parser.add_argument("--checkpoints", type=Path, help="generation: folder of trained weights (default: shipped)")
    parser.add_argument(
        "--max-seconds",
        type=number(0.5, 600),
        default=6.0,
        help="generation: longest target clip, longer ones are cut (default: %(default)s)",
    )
    parser.add_argument(
        "--seed",
        type=number(0, 2**63 - 1, integer=True),
        default=0,
        help="generation: random seed (default: %(default)s)",
    )
    parser.add_argument(
        "--repeats",
        type=number(1, 100, integer=True),
        default=3,
        help="generation: generate and score every target this many times with different seeds "
        "and pool them (bars judged on the pooled means; per-repeat means and their 95 %% "
        "interval reported) (default: %(default)s)",
    )
    parser.add_argument(
        "--manipulation-samples",
        type=number(0, 1000, integer=True),
        default=8,
        help="generation: clips per profile in the manipulation study, 0 skips it (default: %(default)s)",
    )
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from biomotion.errors import ConfigError

    for path in (args.json, args.md):
        if path is not None:
            writable_file(path, "--json/--md")
    if args.mode == "generation":
        from biomotion.evaluation.generation import eval_generation

        if args.json is None:
            raise ConfigError("eval generation needs --json FILE")
        report = eval_generation(
            args.data_root,
            args.json,
            args.md,
            checkpoints=args.checkpoints,
            max_seconds=args.max_seconds,
            seed=args.seed,
            repeats=args.repeats,
            manipulation_samples=args.manipulation_samples,
            command=command_line(),
        )
        met = sum(bool(v) for v in report["bars"].values())
        print(
            f"evaluated {report['targets']} clips of {report['subjects']} unseen subjects; "
            f"{met}/{len(report['bars'])} bars met"
        )
        for bar, value in report["bars"].items():
            print(f"  {'–' if value is None else 'met' if value else 'NOT met':8s} {bar}")
        print(f"wrote {args.json}" + (f" and {args.md}" if args.md else ""))
        return 0
    if args.mode == "reference":
        from biomotion.evaluation.harness import reference_command

        if args.json is None or args.md is None:
            raise ConfigError("eval reference needs --json FILE and --md FILE")
        reference_command(args.data_root, args.md, args.json, physics=not args.no_physics)
        print(f"wrote {args.json} and {args.md}")
        return 0
    from biomotion.evaluation.harness import eval_command, evaluation_markdown

    if not args.pred:
        raise ConfigError("eval needs --pred PATH... (and --ref PATH... to compare), or a mode: reference, generation")
    for path in (*args.pred, *(args.ref or ())):
        if not path.exists():
            raise ConfigError(f"{path}: no such file or folder")
    single = lambda paths: paths[0] if paths and len(paths) == 1 else paths  # noqa: E731 - a folder or files
    result = eval_command(
        single(args.pred),
        single(args.ref),
        args.data_root,
        args.json,
        args.md,
        plots_dir=args.plots,
        physics=args.physics,
    )
    if args.md is None:
        print(evaluation_markdown(result))
    written = [str(path) for path in (args.json, args.md) if path is not None]
    if written:
        print(f"wrote {' and '.join(written)}")
    return 0
