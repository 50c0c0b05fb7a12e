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
    "and tabulates PG-BIG Tables 2-3. `biomotion eval ground-forces` scores the learned ground reaction on people it "
    "never saw: leave-subject-out folds over the Fukuchi runners of --data-root (each fold trained on the others), "
    "and the shipped weights on OpenCap per activity, beside m(g + a_COM) and the contact model. Every mode works "
    "on any folder laid out like ../shared/data, whoever is in "
    "it. `biomotion eval shape` puts one Fukuchi runner's motion on another's body at the same treadmill speed and "
    "compares it with the other's own (HUMOS real pairs), the shape adapter against the copy baseline on pairs of "
    "runners the adapter never saw. `biomotion eval control` samples control targets (joint paths, vertical GRF and "
    "knee-moment caps) from held-out clips, generates with PG-BIG guidance (--generator flexmotion: FlexMotion's "
    "control module; both: side by side) and recomputes what was met. "
    "Python: biomotion.evaluate, biomotion.eval_generation, "
    "biomotion.evaluation.ground_forces.eval_ground_forces, biomotion.evaluation.shape.eval_shape, "
    "biomotion.evaluation.control.eval_control."
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
        choices=("reference", "generation", "ground-forces", "refine", "shape", "control"),
        help="reference: score the real data (reference table); generation: generate for every "
        "unseen subject of --data-root and tabulate PG-BIG Tables 2-3 (full model, w/o "
        "guidance, w/o personalization, population baseline), the identity probe and the "
        "profile-manipulation study; ground-forces: the learned ground reaction, leave-subject-out on the "
        "Fukuchi runners and the shipped weights on OpenCap; refine: the PhysPT refiner on corrupted clips of "
        "the subjects it never saw (against a tuned low-pass), on PG-BIG's generated clips, and its speed; shape: "
        "real pairs of Fukuchi runners at the same speed, A's motion on B's body against B's own (HUMOS; the "
        "shape adapter against the copy baseline, on runners the adapter never saw); control: targets from "
        "held-out clips met through PG-BIG guidance, bounds recomputed by the analysis",
    )
    parser.add_argument(
        "--refiner",
        type=Path,
        help="refine: refiner weights (default: checkpoints/refiner.safetensors); --checkpoints names the generator",
    )
    parser.add_argument("--no-generated", action="store_true", help="refine: skip the generated clips (no generator)")
    parser.add_argument("--pred", nargs="+", type=Path, help="predicted motion: files or one folder")
    parser.add_argument("--ref", nargs="+", type=Path, help="reference motion: files or one folder")
    add_data_root(
        parser, "folder laid out like ../shared/data: the canonical model, and the subjects of reference and generation"
    )
    parser.add_argument("--json", type=Path, help="JSON report to write")
    parser.add_argument("--md", type=Path, help="Markdown table to write (--pred: printed when not given)")
    parser.add_argument(
        "--plots",
        type=Path,
        help="folder for per-clip distribution plots (ground-forces: a figure of example trials)",
    )
    parser.add_argument("--physics", action="store_true", help="also full-body energy and ZMP-in-support (slower)")
    parser.add_argument("--no-physics", action="store_true", help="reference: skip the slower physics metrics")
    parser.add_argument(
        "--checkpoints",
        type=Path,
        help="generation, ground-forces: folder of trained weights (default: shipped); ground-forces reads its "
        "ground_forces.safetensors",
    )
    parser.add_argument(
        "--folds",
        type=number(2, 1000, integer=True),
        default=None,
        help="generation: cross-validate by subject in this many folds, every fold's models trained without "
        "its subjects (biomotion.evaluation.generation_cv); ground-forces: leave-subject-out folds over the "
        "Fukuchi runners, at most one per runner (default: 5)",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="generation: the cross-validation's quick variant (two folds of a few subjects, models trained for "
        "a few iterations; proves the protocol runs, its figures mean nothing)",
    )
    parser.add_argument(
        "--cache-dir",
        type=Path,
        default=None,
        help="generation --folds: where the fold models are kept and found again (default: ~/.cache/biomotion)",
    )
    parser.add_argument(
        "--config",
        type=Path,
        help="ground-forces: YAML training config of the fold models (default: the one recorded in the weights)",
    )
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
    parser.add_argument(
        "--partners",
        type=number(1, 100, integer=True),
        default=None,
        help="shape: runners B paired with each runner A at each speed (default: 3)",
    )
    parser.add_argument(
        "--adapter",
        help="shape: shape-adapter weights (`biomotion train shape-adapter`; default: "
        "checkpoints/shape_adapter.safetensors when present), or 'none' for the copy baseline alone",
    )
    parser.add_argument(
        "--generator",
        choices=("pgbig", "flexmotion", "both"),
        default="pgbig",
        help="generation: pgbig, PG-BIG Tables 2-3 (default); flexmotion or both, FlexMotion beside PG-BIG on the "
        "same held-out prompts (biomotion.evaluation.flexmotion; --repeats clips per target). control: pgbig, "
        "PG-BIG's guidance path (default); flexmotion, FlexMotion's control module; both, side by side on the same "
        "targets",
    )
    parser.add_argument(
        "--cache",
        type=Path,
        default=None,
        help="generation --generator flexmotion|both: dataset cache (`biomotion data build`; default: a temporary "
        "one of --data-root)",
    )
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from biomotion.errors import ConfigError

    for path in (args.json, args.md):
        if path is not None:
            writable_file(path, "--json/--md")
    if args.mode == "generation" and args.generator != "pgbig":
        return _flexmotion(args)
    if args.mode == "generation" and (args.folds is not None or args.quick):
        return _generation_cv(args)
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
    if args.mode == "ground-forces":
        return _ground_forces(args)
    if args.mode == "refine":
        return _refine(args)
    if args.mode == "shape":
        return _shape(args)
    if args.mode == "control":
        return _control(args)
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


def _ground_forces(args: argparse.Namespace) -> int:
    import yaml

    from biomotion.errors import ConfigError, DataFormatError
    from biomotion.evaluation.ground_forces import eval_ground_forces

    if args.json is None:
        raise ConfigError("eval ground-forces needs --json FILE")
    if not args.data_root.is_dir():
        raise ConfigError(f"{args.data_root}: --data-root is not a folder")
    config = None
    if args.config is not None:
        if not args.config.is_file():
            raise ConfigError(f"{args.config}: --config is not a file")
        try:
            config = yaml.safe_load(args.config.read_text())
        except yaml.YAMLError as error:
            raise DataFormatError(args.config, f"not valid YAML: {getattr(error, 'problem', error)}") from None
    weights = args.checkpoints / "ground_forces.safetensors" if args.checkpoints is not None else None
    report = eval_ground_forces(
        args.data_root,
        args.json,
        args.md,
        folds=5 if args.folds is None else args.folds,
        checkpoint=weights,
        config=config,
        seed=args.seed,
        command=command_line(),
        plots=args.plots,
        log=print,
    )
    for key in (
        "grf_learned_vertical_rmse_bw",
        "grf_learned_vertical_rmse_bw_mean",
        "grf_learned_to_com_baseline",
        "grf_learned_vertical_rmse_bw_opencap",
    ):
        value = report.get(key)
        verdict = report["bars"].get(key)
        mark = "" if verdict is None else " (met)" if verdict else " (NOT met)"
        print(f"  {key}: {'–' if value is None else f'{value:.4f}'}{mark}")
    for line in report["skipped"]:
        print(f"  skipped {line}")
    print(f"wrote {args.json}" + (f" and {args.md}" if args.md else ""))
    return 0


def _generation_cv(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from biomotion.errors import ConfigError
    from biomotion.evaluation.generation_cv import QUICK, CVSettings, eval_generation_cv
    from biomotion.training.folds import train_fold  # the evaluation layer cannot import training: handed in

    if args.json is None:
        raise ConfigError("eval generation --folds needs --json FILE")
    settings = QUICK if args.quick else CVSettings()
    settings = replace(
        settings,
        folds=settings.folds if args.folds is None else args.folds,
        repeats=settings.repeats if args.quick else args.repeats,
        max_seconds=settings.max_seconds if args.quick else args.max_seconds,
        seed=args.seed,
    )
    report = eval_generation_cv(
        args.data_root,
        args.json,
        args.md,
        checkpoints=args.checkpoints,
        settings=settings,
        cache_dir=args.cache_dir,
        trainer=train_fold,
        command=command_line(),
    )
    print(f"cross-validated {report['subjects']} subjects in {len(report['folds'])} folds ({report['seconds']:.0f} s)")
    for key, met in report["bars"].items():
        values = ", ".join("–" if v is None else f"{v:.2f}" for v in report["per_fold"][key])
        worst = report[key]
        print(
            f"  {'–' if met is None else 'met' if met else 'NOT met':8s} {key}: worst "
            f"{'–' if worst is None else f'{worst:.2f}'} (per fold {values})"
        )
    print(f"wrote {args.json}" + (f" and {args.md}" if args.md else ""))
    return 0


def _refine(args: argparse.Namespace) -> int:
    from biomotion.evaluation.refine import eval_refine

    json_path = args.json or Path("docs/results/eval_refine.json")
    md_path = args.md or (json_path.with_suffix(".md") if args.json is None else None)
    writable_file(json_path, "--json")
    report = eval_refine(
        args.data_root,
        json_path,
        md_path,
        refiner_path=args.refiner,
        checkpoints=args.checkpoints,
        seed=args.seed,
        generated=not args.no_generated,
        command=command_line(),
    )
    for key, row in report["bars"].items():
        value = "–" if row["value"] is None else f"{row['value']:.3f}"
        print(f"  {'–' if row['met'] is None else 'met' if row['met'] else 'NOT met':8s} {key}: {value} ({row['bar']})")
    print(f"wrote {json_path}" + (f" and {md_path}" if md_path else ""))
    return 0


SHIPPED_ADAPTER = "checkpoints/shape_adapter.safetensors"


def _shape(args: argparse.Namespace) -> int:
    from biomotion.errors import ConfigError
    from biomotion.evaluation.shape import PARTNERS, eval_shape, load_adapter

    if not args.data_root.is_dir():
        raise ConfigError(f"{args.data_root}: --data-root is not a folder")
    json_path = args.json or Path("docs/results/eval_shape.json")
    md_path = args.md or (json_path.with_suffix(".md") if args.json is None else None)
    writable_file(json_path, "--json")
    adapter = args.adapter
    if adapter is None and Path(SHIPPED_ADAPTER).is_file():
        adapter = SHIPPED_ADAPTER
    adapt, trained, info = (None, (), None) if adapter in (None, "none") else load_adapter(Path(adapter))
    report = eval_shape(
        args.data_root,
        json_path,
        md_path,
        adapt=adapt,
        trained=trained,
        adapter_info=info,
        partners=PARTNERS if args.partners is None else args.partners,
        command=command_line(),
    )
    print(f"{report['pairs']} pairs of {report['subjects']} runners")
    keys = (
        "shape_copy_dtw",
        "shape_copy_stride_rel_err",
        "shape_copy_cadence_rel_err",
        "shape_copy_physics_worst_ratio_to_real",
        "shape_copy_dyn_stability_gap_points",
    )
    if adapt is not None:
        keys += (
            "shape_adapted_dtw",
            "shape_adapted_cadence_rel_err",
            "shape_dtw_gain_vs_copy",
            "shape_stride_rel_err",
            "shape_physics_worst_ratio_to_real",
            "shape_dyn_stability_gap_points",
        )
    for key in (k for k in keys if k not in report["not_measured"]):
        value = report[key]
        print(f"  {key}: {'–' if value is None else f'{value:.4f}'}")
    for key, why in report["not_measured"].items():
        print(f"  {key}: – ({why})")
    for line in report["skipped"]:
        print(f"  skipped {line}")
    print(f"wrote {json_path}" + (f" and {md_path}" if md_path else ""))
    return 0


def _control(args: argparse.Namespace) -> int:
    """``biomotion eval control``: control targets from held-out clips through PG-BIG guidance, FlexMotion's
    control module or both (--generator; `biomotion.evaluation.control`); --seed, --checkpoints, --json and --md
    as for generation."""
    from biomotion.errors import ConfigError
    from biomotion.evaluation.control import Settings, eval_control

    if not args.data_root.is_dir():
        raise ConfigError(f"{args.data_root}: --data-root is not a folder")
    json_path = args.json or Path("docs/results/eval_control.json")
    md_path = args.md or (json_path.with_suffix(".md") if args.json is None else None)
    writable_file(json_path, "--json")
    report = eval_control(
        args.data_root,
        json_path,
        md_path,
        checkpoints=args.checkpoints,
        settings=Settings(seed=args.seed),
        command=command_line(),
        generator=args.generator,
    )
    print(f"{report['targets']} control targets from {report['subjects']} held-out subjects")
    for name, column in report["columns"].items():
        print(f" {name}:")
        for key, row in column["bars"].items():
            value = "–" if row["value"] is None else f"{row['value']:.3f}"
            met = "–" if row["met"] is None else "met" if row["met"] else "NOT met"
            print(f"  {met:8s} {key}: {value} ({row['bar']})")
    print(f"wrote {json_path}" + (f" and {md_path}" if md_path else ""))
    return 0


def _flexmotion(args: argparse.Namespace) -> int:
    """``biomotion eval generation --generator flexmotion|both``: FlexMotion beside PG-BIG on the held-out prompts
    (`biomotion.evaluation.flexmotion.eval_flexmotion`; the issue's bars); --json required, --md optional."""
    import torch

    from biomotion.errors import ConfigError
    from biomotion.evaluation.flexmotion import eval_flexmotion

    if args.json is None:
        raise ConfigError("eval generation --generator flexmotion|both needs --json FILE")
    if not args.data_root.is_dir():
        raise ConfigError(f"{args.data_root}: --data-root is not a folder")
    if args.cache is not None and not args.cache.expanduser().is_dir():
        raise ConfigError(f"{args.cache}: --cache is not a folder (`biomotion data build`)")
    torch.set_num_threads(1)  # the sampling time is stated for one thread
    report = eval_flexmotion(
        args.data_root,
        args.json,
        args.md,
        cache_dir=args.cache,
        checkpoints=args.checkpoints or Path("checkpoints"),
        samples=args.repeats,
        seed=args.seed,
        command=command_line(),
    )
    print(f"FlexMotion beside PG-BIG on {report['targets']} targets of {report['subjects']} held-out subjects")
    for key, row in report["bars"].items():
        print(f"  {'met' if row['met'] else 'NOT met':8s} {key}: {row['value']:.4g} ({row['bar']})")
    print(f"wrote {args.json}" + (f" and {args.md}" if args.md else ""))
    return 0
