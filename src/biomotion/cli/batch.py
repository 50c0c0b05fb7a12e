"""``biomotion batch``: a whole lab study in one command (`biomotion.analysis.batch.batch`), with a quality report."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from biomotion.cli._common import add_overwrite, command_line, number

DESCRIPTION = (
    "Process a whole study: per subject, scale the generic model to the static trial (its OpenSim Scale setup); per "
    "trial, inverse kinematics, inverse dynamics with the plates assigned to the feet (or the learned / inferred "
    "ground reaction without plates), static optimization (when muscle paths fit the model), COM and ZMP. Each "
    "trial is written as OpenSim files (.osim, .mot, .sto, ExternalLoads .xml) with a viewer page, and judged "
    "(ok / warn / fail, with reasons) by a-priori rules from published practice. OUT gets report.html (one "
    "self-contained page: scaling per subject, a sortable table of every trial, plots) and record.json (versions, "
    "settings, input SHA-256, timings). A bad trial is reported and the rest go on; --resume skips trials whose "
    "inputs and settings hash the same. STUDY is a folder (layouts: Fukuchi c3d/<subject><trial>.c3d + subject "
    "table; OpenCap <subject>/MarkerData; Motus Kinematic_Data/<PPID>/Generated_C3D_files) or a TOML config "
    "(`biomotion.analysis.study` documents both). Python: biomotion.batch."
)
EPILOG = (
    "examples: biomotion batch ../shared/data/fukuchi-running --out out/fukuchi; one runner, one speed: biomotion "
    "batch ../shared/data/fukuchi-running --subjects RBDS001 --trials runT35 --out out/rbds001; OpenCap with the "
    "plates named: biomotion batch ../shared/data/opencap --plates 1=right,2=left,3=none --out out/opencap; on a "
    "Ray cluster (pip install 'biomotion[distributed]', study and OUT on a file system every node sees): "
    "biomotion batch STUDY --executor ray --address auto --out OUT"
)


def add_parser(verbs) -> None:
    parser = verbs.add_parser(
        "batch",
        help="a whole study: scaling, IK, ID, SO, COM/ZMP per trial, with a quality report",
        description=DESCRIPTION,
        epilog=EPILOG,
    )
    parser.add_argument("study", type=Path, help="study folder (a known layout) or TOML config")
    parser.add_argument("--out", type=Path, required=True, help="output folder (new or empty, or --resume)")
    parser.add_argument("--resume", action="store_true", help="keep the finished trials of an earlier run into OUT")
    add_overwrite(parser)
    parser.add_argument(
        "--workers",
        type=number(1, 4096, integer=True),
        help="processes (local) or CPUs of a Ray instance started here (default: one per core); 1: this process",
    )
    parser.add_argument("--executor", choices=("local", "ray"), default="local", help="(default: %(default)s)")
    parser.add_argument("--address", help="--executor ray: address of a running Ray cluster (e.g. auto, HOST:6379)")
    parser.add_argument("--subjects", help="only these subjects (comma-separated names)")
    parser.add_argument("--trials", help="only trials whose names match these shell patterns (comma-separated)")
    parser.add_argument("--model", type=Path, help="generic model for every subject (the Motus layout needs one)")
    parser.add_argument("--scale-setup", type=Path, help="OpenSim ScaleTool setup for every subject")
    parser.add_argument(
        "--marker-map",
        metavar="MAP",
        help="data marker names -> model marker names: DATA=MODEL,... or a .toml/.csv file",
    )
    parser.add_argument(
        "--plates",
        metavar="SPEC",
        help="plate override: CHANNEL=right|left|none|BODY,... (e.g. 1=right,2=left,3=none); plates not named "
        "are assigned to the feet automatically",
    )
    parser.add_argument(
        "--forces",
        choices=("auto", "measured", "inferred", "learned"),
        help="ground reaction of the torques (default: the config's, else auto: the plates when the trial has "
        "them, else the learned model when installed, else inferred)",
    )
    parser.add_argument("--forces-model", type=Path, metavar="WEIGHTS", help="weights of the learned forces model")
    parser.add_argument("--muscles", metavar="PATHS", help="muscle path functions for static optimization")
    parser.add_argument("--marker-filter", type=number(0, low_open=True), metavar="HZ", help="marker low-pass (Hz)")
    parser.add_argument("--cutoff", type=number(0, 200), help="coordinate low-pass before ID (Hz; default 6)")
    parser.add_argument("--no-viewer", action="store_true", help="skip the per-trial viewer pages")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.set_defaults(run=run)


def _estimator(args: argparse.Namespace, forces: str):
    """The learned ground-reaction model when the run may use it (None when it is not installed and not asked
    for by name)."""
    from biomotion.errors import BiomotionError, ConfigError

    if forces not in ("learned", "auto"):
        if args.forces_model is not None:
            raise ConfigError("--forces-model is the weights of --forces learned")
        return None
    try:
        from biomotion.models.ground_forces import learned_forces
    except ImportError:
        if forces == "learned":
            raise ConfigError("--forces learned: this installation has no learned ground-reaction model") from None
        return None
    try:
        return learned_forces(args.forces_model)
    except BiomotionError:
        if forces == "learned" or args.forces_model is not None:
            raise
        return None


def run(args: argparse.Namespace) -> int:
    from biomotion.analysis.batch import batch
    from biomotion.analysis.study import load_study
    from biomotion.errors import ConfigError

    overrides = {}
    for key, value in (
        ("marker_map", args.marker_map),
        ("plates", args.plates),
        ("forces", args.forces),
        ("muscles", args.muscles),
        ("marker_filter_hz", args.marker_filter),
        ("cutoff_hz", args.cutoff),
    ):
        if value is not None:
            overrides[key] = value
    if args.no_viewer:
        overrides["viewer"] = False
    if args.address and args.executor != "ray":
        raise ConfigError("--address is for --executor ray")
    study = load_study(args.study, model=args.model, scale_setup=args.scale_setup, **overrides)
    study = study.select(
        [s.strip() for s in args.subjects.split(",")] if args.subjects else None,
        [t.strip() for t in args.trials.split(",")] if args.trials else None,
    )
    estimator = _estimator(args, study.settings.forces)
    print(
        f"{study.name}: {study.layout} layout, {len(study.subjects)} subjects, {study.n_trials} trials -> {args.out}",
        file=sys.stderr,
    )
    result = batch(
        study,
        args.out,
        workers=args.workers,
        executor=args.executor,
        address=args.address,
        resume=args.resume,
        overwrite=args.overwrite,
        estimator=estimator,
        progress=not args.no_progress,
        command=command_line(),
    )
    _print(result)
    return 0


def _print(result) -> None:
    counts = result.counts()
    trials = [o for o in result.outcomes if o.kind == "trial"]
    statics = [o for o in result.outcomes if o.kind == "static"]

    def tally(outcomes) -> str:
        verdicts = [o.verdict.get("verdict", "fail") for o in outcomes]
        return ", ".join(f"{verdicts.count(v)} {v}" for v in ("ok", "warn", "fail"))

    print(
        f"{len(trials)} trials in {result.seconds / 60:.1f} min: {tally(trials)}; {len(statics)} static trials: "
        f"{tally(statics)}; {counts['skipped']} resumed, {counts['errors']} errors"
    )
    for outcome in result.outcomes:
        plates = (outcome.figures or {}).get("plates") or {}
        assigned = []
        for channel, a in plates.items():
            if a.get("mode") == "given":
                assigned.append(f"{channel}->{a['body']}")
            elif a.get("frames"):
                assigned.append(f"{channel}->" + "/".join(f"{s} {100 * a[s]:.0f}%" for s in ("right", "left") if a[s]))
        line = f"  {outcome.verdict.get('verdict', 'fail'):4s} {outcome.subject}/{outcome.name}"
        if assigned:
            line += f"  plates {', '.join(assigned)}"
        if outcome.status == "error":
            line += f"  error: {outcome.error}"
        else:
            reasons = outcome.verdict.get("reasons", [])
            worst = [r["message"] for r in reasons if r.get("verdict") in ("warn", "fail")][:2]
            if worst:
                line += "  " + " | ".join(worst)
        print(line)
    if result.report is not None:
        print(f"report: {result.report}")
    print(f"record: {result.record}")
