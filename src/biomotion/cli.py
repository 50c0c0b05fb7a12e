"""The ``biomotion`` command: a thin layer over the Python API.

Each verb lives in a function that parses nothing itself: `argparse` builds the interface, the API does the work.
A `BiomotionError` is printed on one line (``biomotion: error: ...``) and the command exits with status 2.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import warnings
from dataclasses import replace
from pathlib import Path

from biomotion import __version__
from biomotion.settings import DATA_ROOT_VARIABLE, default_data_root
from biomotion.errors import BiomotionError, BiomotionWarning, ConfigError



def _data_build(args: argparse.Namespace) -> int:
    from biomotion.data.registry import build_cache

    manifest = build_cache(args.data_root, args.out, rate=args.rate, sources=args.source or None,
                           progress=not args.quiet)
    counts = manifest["counts"]
    print(f"cached {counts['clips']} clips ({counts['frames']} frames at {manifest['rate_hz']:g} Hz) "
          f"from {len(counts['per_source'])} sources in {manifest['build_seconds']:.1f} s -> {args.out}")
    for source, n in counts["per_source"].items():
        print(f"  {source:10s} {n:5d} clips  {counts['subjects_per_source'][source]:3d} subjects")
    print(f"  splits: {counts['per_split']}")
    for skipped in manifest["skipped_sources"]:
        print(f"  skipped {skipped}")
    if args.report:
        import shlex

        from biomotion.data.registry import manifest_markdown
        from biomotion.io.atomic import atomic_write

        with atomic_write(args.report) as handle:
            handle.write(manifest_markdown(manifest, "biomotion " + " ".join(shlex.quote(a) for a in sys.argv[1:])))
        print(f"  counts written to {args.report}")
    return 0


def _data_augment(args: argparse.Namespace) -> int:
    from biomotion.data.augment import augmented_cache

    model = None
    if args.posture_copies > 0:
        from biomotion.data.clips import body_model

        model = body_model(args.data_root)
    manifest = augmented_cache(args.cache, args.out, args.time_warp, posture_copies=args.posture_copies,
                               model=model, seed=args.seed, split=args.split, sources=args.source or (),
                               progress=not args.quiet)
    counts = manifest["counts"]
    kinds = [f"time-warped x{', x'.join(f'{f:g}' for f in args.time_warp)}"] if args.time_warp else []
    kinds += [f"{args.posture_copies} posture offset(s) each"] if args.posture_copies > 0 else []
    print(f"wrote {counts['clips']} clips ({manifest['augmentation']['copies']} copies of the {args.split} split: "
          f"{'; '.join(kinds)}) in {manifest['build_seconds']:.1f} s -> {args.out}")
    return 0


def _data_sources(args: argparse.Namespace) -> int:
    from biomotion.data.sources import SOURCES

    for source in SOURCES.values():
        state = "present" if source.present(args.data_root) else "absent"
        print(f"{source.name:12s} {source.folder + '/':26s} {state:8s} {source.description}")
    return 0


def _convert(args: argparse.Namespace) -> int:
    from biomotion.analysis.convert import convert

    written = convert(args.input, args.output, model=args.model)
    print(f"wrote {written}")
    return 0


def _generate(args: argparse.Namespace) -> int:
    import shlex

    from biomotion.generation.command import generate_command

    if args.list_actions:
        from biomotion.generation.pipeline import CHECKPOINTS
        from biomotion.generation.routing import vocabulary_listing

        print(vocabulary_listing(args.checkpoints or CHECKPOINTS))
        return 0
    missing = [flag for flag, value in (("--action", args.action), ("--out", args.out)) if value is None]
    if missing:
        raise ConfigError(f"generate needs {' and '.join(missing)} (or --list-actions to see the actions)")

    result = generate_command(
        action=args.action, out=args.out, data_root=args.data_root, checkpoints=args.checkpoints,
        profile_file=args.profile, subject_table=args.subject_table, subject_id=args.subject_id,
        references=args.reference or (), reference_actions=args.reference_action or (), seconds=args.seconds,
        seed=args.seed, samples=args.samples,
        guidance=not args.no_guidance, personalised=not args.no_profile, figures=not args.no_figures,
        command="biomotion " + " ".join(shlex.quote(a) for a in sys.argv[1:]), threads=args.threads,
        smooth_hz=args.smooth)
    a = result["action"]
    print(f"answered by the {result['route'].describe()}")
    for note in result["notes"]:
        print(f"note: {note}")
    speed = "" if a.speed is None else f" at {a.speed:g} m/s"
    style = "" if a.style is None else f" ({a.style})"
    print(f"generated {args.samples} x {args.seconds:g} s of {a.action!r}{style}{speed} in "
          f"{result['generate_seconds']:.2f} s (models loaded in {result['load_seconds']:.1f} s; outputs written in "
          f"{result['write_seconds']:.1f} s) -> {args.out}")
    for sample, files in result["files"].items():
        for role, path in files.items():
            print(f"  {sample + '/' if len(result['files']) > 1 else ''}{role:18s} {path}")
    return 0


def _inspect(args: argparse.Namespace) -> int:
    from biomotion.io.formats import describe

    print(json.dumps(describe(args.input), indent=1))
    return 0


def _analysis_figures(args: argparse.Namespace, coordinates: Path, model: Path, result, files: dict) -> dict:
    """The viewer and the plots `analyze` writes by default (issue 8: analysis commands write them)."""
    from biomotion.analysis.chain import support_polygons
    from biomotion.viz.plots import plot_balance, plot_ground_reaction, plot_joint_angles
    from biomotion.viz.viewer import view_command

    from biomotion.viz.scene import geometry_folders

    # a model scaled here lies in a scratch folder: its meshes are where the generic model's are
    generic = geometry_folders(args.model) if Path(model) != Path(args.model) else []
    out = {"viewer": view_command(coordinates, model=model, grf=args.grf, com_zmp=files["com_zmp"],
                                  out=args.out / "viewer.html", geometry=[*(args.geometry or ()), *generic])}
    out["plot_joint_angles"] = plot_joint_angles(result.motion, args.out / "joint_angles")[0]
    reaction = result.measured if result.measured is not None else result.inferred
    out["plot_grf"] = plot_ground_reaction(reaction, args.out / "grf", body_weight=result.body_weight,
                                           inferred=result.inferred if result.measured is not None else None,
                                           label="measured" if result.measured is not None else "inferred")[0]
    out["plot_balance"] = plot_balance(result.com, result.zmp, args.out / "balance",
                                       support=support_polygons(result.contact_points, result.contact_loaded))[0]
    return out


def _check_static(args: argparse.Namespace) -> None:
    """`analyze` and `retarget`: --static needs the Scale setup whose measurements scale the model to it."""
    if args.static is not None and args.scale_setup is None:
        raise ConfigError("--static scales the model, which needs the measurements of an OpenSim Scale setup: give "
                          "--scale-setup XML too (`biomotion scale --help`)")


def _inverse_kinematics(args: argparse.Namespace, folder: Path) -> tuple[Path, Path, dict]:
    """Captured motion (markers or a skeleton) -> (coordinates file, model file, summary section): `retarget` of
    the one trial into ``folder``, as `biomotion retarget TRIAL --model MODEL [--setup] [--filter]` would write it."""
    from biomotion.body.model import BodyModel
    from biomotion.ik.retarget import is_skeleton, retarget
    from biomotion.io.setup import read_ik_setup

    setup = read_ik_setup(args.setup) if args.setup else None
    if (setup is not None or args.scale_setup is not None) and is_skeleton(args.trial):
        raise ConfigError(f"{args.trial} is a skeleton: IK and Scale setups weigh and measure markers")
    model = args.model
    if args.scale_setup is not None:
        from biomotion.ik.calibrate import calibrate

        done = calibrate(args.scale_setup, folder, model=args.model, static=args.static,
                         filter_hz=args.marker_filter)
        _print_calibration(done, files=False)
        model = done.model
    (ik,) = retarget([args.trial], BodyModel.from_osim(model), folder,
                     weights=setup.marker_weights if setup else None, filter_hz=args.marker_filter,
                     model_path=model, setup=setup, progress=False)
    if ik.error:
        raise BiomotionError(f"{args.trial}: inverse kinematics failed: {ik.error}")
    model = folder / f"{ik.trial}.osim" if is_skeleton(args.trial) else model
    kind = "joint centre" if is_skeleton(args.trial) else "marker"
    print(f"inverse kinematics: {ik.frames} frames, RMS {kind} error {100 * ik.rms_error_m:.2f} cm "
          f"(max {100 * ik.max_error_m:.2f} cm, {ik.frames_dropped} frames without a tracked point)")
    point = kind.replace(" ", "_")
    section = {"source": str(args.trial), "setup": str(args.setup) if args.setup else None,
               "filter_hz": args.marker_filter, "frames": ik.frames, f"rms_{point}_error_m": ik.rms_error_m,
               f"max_{point}_error_m": ik.max_error_m, "frames_dropped": ik.frames_dropped,
               "coordinates": f"ik/{ik.output}",
               "model": f"ik/{model.name}" if model != args.model else str(args.model)}
    if args.scale_setup is not None:
        section["scaling"] = f"ik/{done.summary_file.name}"
    return folder / ik.output, model, section


def _analyze(args: argparse.Namespace) -> int:
    import tempfile

    from biomotion.ik.retarget import MARKER_SUFFIXES, is_skeleton

    captured = args.trial.suffix.lower() in MARKER_SUFFIXES or is_skeleton(args.trial)
    if not captured and (args.setup or args.marker_filter or args.static or args.scale_setup):
        raise ConfigError(f"{args.trial}: --setup, --marker-filter, --static and --scale-setup are for captured "
                          f"motion (.trc/.c3d markers, .bvh skeletons); a coordinates file is analysed as it is")
    _check_static(args)
    if not captured:
        return _analyze_coordinates(args, args.trial, args.model, {}, None)
    with tempfile.TemporaryDirectory(prefix="biomotion-ik-") as scratch:
        coordinates, model_path, section = _inverse_kinematics(args, Path(scratch))
        return _analyze_coordinates(args, coordinates, model_path, {"inverse_kinematics": section}, Path(scratch))


def _analyze_coordinates(args: argparse.Namespace, coordinates: Path, model_path: Path, extra: dict,
                         ik_folder: Path | None) -> int:
    """`analyze` of the coordinates file ``coordinates`` on the model file ``model_path``, ``extra`` sections added
    to summary.json; ``ik_folder``: the inverse kinematics that made the coordinates, copied to OUT/ik at the end."""
    import shutil

    from biomotion.analysis.chain import analyze, summary, write_analysis
    from biomotion.body.model import BodyModel
    from biomotion.io.formats import read_any
    from biomotion.io.mot import read_motion

    motion = read_motion(coordinates)
    model = BodyModel.from_osim(model_path)
    ignored = [name for name in motion.names if name not in model.coordinate_names]
    if ignored:
        print(f"biomotion: warning: {coordinates}: {len(ignored)} column(s) name no coordinate of {model.name} and "
              f"are ignored: {', '.join(ignored)}", file=sys.stderr)
    forces = None
    if args.grf is not None:
        data = read_any(args.grf)
        forces = getattr(data, "forces", data)
        if forces is None:
            from biomotion.errors import DataFormatError

            raise DataFormatError(args.grf, "holds no force-plate data")
    paths = check = None
    if args.muscles is not None:   # before the analysis: a wrong path file fails fast and writes nothing
        from biomotion.analysis.activations import check_paths, load_paths

        paths, label = load_paths(args.muscles)
        check = check_paths(paths, label, model_path, model.coordinate_names)
        if check.warning:
            print(f"biomotion: warning: {check.warning}", file=sys.stderr)
    result = analyze(motion, model, forces, cutoff_hz=args.cutoff)
    solution = None
    if paths is not None:
        from biomotion.analysis.activations import TrialSettings, activation_summary, trial_activations

        solution = trial_activations(result, model_path, paths)
        extra["muscles"] = activation_summary(solution, check, TrialSettings())
    files = write_analysis(result, args.out, extra_summary=extra)
    if solution is not None:
        from biomotion.analysis.activations import write_activations

        files["activations"] = write_activations(args.out / "activations.sto", result, solution)
    if ik_folder is not None:   # last: the copy names the folder the analysis went to
        files["inverse_kinematics"] = Path(shutil.copytree(ik_folder, args.out / "ik", dirs_exist_ok=True))
    if not args.no_figures:
        files.update(_analysis_figures(args, coordinates, model_path, result, files))
        if solution is not None:
            from biomotion.viz.plots import plot_activations

            files["plot_activations"] = plot_activations(result.motion.times, solution.muscle_names,
                                                         solution.activations.numpy(), args.out / "activations",
                                                         title="static optimization")[0]
    figures = summary(result)
    print(f"analysed {figures['frames']} frames at {figures['rate_hz']:.0f} Hz on {model.name} "
          f"({figures['body_mass_kg']:.1f} kg); torques from {figures['torques_from']} ground reaction")
    if "inferred_vs_measured_vertical" in figures:
        ours, base = figures["inferred_vs_measured_vertical"], figures["com_baseline_vs_measured_vertical"]
        print(f"  vertical GRF from kinematics vs plates: R2 {ours['r2']:.3f}, RMSE {ours['rmse_bw']:.3f} BW "
              f"(COM baseline: R2 {base['r2']:.3f}, RMSE {base['rmse_bw']:.3f} BW)")
    if solution is not None:
        muscles = extra["muscles"]
        print(f"  muscle activations: {muscles['muscles']} muscles balance {len(muscles['balanced_coordinates'])} "
              f"coordinates on {muscles['frames_balanced']} of {muscles['frames']} frames")
    for role, path in files.items():
        print(f"  {role:20s} {path}")
    return 0


def _view(args: argparse.Namespace) -> int:
    from biomotion.viz.viewer import view_command

    path = view_command(args.motion, model=args.model, grf=args.grf, activations=args.activations,
                        com_zmp=args.com_zmp, compare=args.compare, out=args.out, compare_mode=args.compare_mode,
                        geometry=args.geometry or ())
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB); open it in any browser, no network needed")
    return 0


def _muscles_label(args: argparse.Namespace) -> int:
    from biomotion.data.registry import DatasetCache
    from biomotion.training.surrogate_labels import DEFAULT_NAME, labels_for_cache

    cache = DatasetCache(args.cache)
    out = args.out or Path(args.cache) / DEFAULT_NAME
    labels = labels_for_cache(cache, args.data_root, out, progress=not args.quiet)
    info = labels.info
    print(f"labelled {info['clips']} clips ({info['frames']} frames; {info.get('clips_resumed', 0)} resumed) with "
          f"{info['muscle_curves']} muscles: converged {100 * info['converged_share']:.1f} % of frames, reserve RMS "
          f"{info['reserve_rms_nm']:.2f} N·m -> {out}")
    return 0


def _validate(args: argparse.Namespace) -> int:
    from biomotion.validation.run import run_validation

    import shlex

    command = "biomotion " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    report = run_validation(args.what, args.data_root, args.json, progress=not args.quiet, md_path=args.md,
                            command=command)
    for key, value in report.items():
        if not isinstance(value, (dict, list)):
            print(f"  {key}: {value}")
    for skipped in report.get("skipped", []):
        print(f"  skipped {skipped}")
    print(f"report written to {args.json}")
    return 0


def _eval(args: argparse.Namespace) -> int:
    from biomotion.evaluation.harness import eval_command, reference_command

    if args.mode == "generation":
        import shlex

        from biomotion.evaluation.generation import eval_generation

        if args.json is None:
            raise ConfigError("eval generation needs --json FILE")
        report = eval_generation(args.data_root, args.json, args.md, checkpoints=args.checkpoints,
                                 max_seconds=args.max_seconds, seed=args.seed, repeats=args.repeats,
                                 manipulation_samples=args.manipulation_samples,
                                 command="biomotion " + " ".join(shlex.quote(a) for a in sys.argv[1:]))
        met = sum(bool(v) for v in report["bars"].values())
        print(f"evaluated {report['targets']} clips of {report['subjects']} unseen subjects; "
              f"{met}/{len(report['bars'])} bars met")
        for bar, value in report["bars"].items():
            print(f"  {'–' if value is None else 'met' if value else 'NOT met':8s} {bar}")
        print(f"wrote {args.json}" + (f" and {args.md}" if args.md else ""))
        return 0
    if args.mode == "reference":
        if args.json is None or args.md is None:
            raise ConfigError("eval reference needs --json FILE and --md FILE")
        reference_command(args.data_root, args.md, args.json, physics=not args.no_physics)
    else:
        from biomotion.evaluation.harness import evaluation_markdown

        if not args.pred:
            raise ConfigError("eval needs --pred PATH... (and --ref PATH... to compare), or a mode: reference, "
                              "generation")
        single = lambda paths: paths[0] if paths and len(paths) == 1 else paths  # noqa: E731 - a folder or files
        result = eval_command(single(args.pred), single(args.ref), args.data_root, args.json, args.md,
                              plots_dir=args.plots, physics=args.physics)
        if args.md is None:
            print(evaluation_markdown(result))
        written = [str(path) for path in (args.json, args.md) if path is not None]
        if written:
            print(f"wrote {' and '.join(written)}")
        return 0
    print(f"wrote {args.json} and {args.md}")
    return 0


def _scale(args: argparse.Namespace) -> int:
    from biomotion.ik.calibrate import calibrate

    by_profile = args.profile is not None or args.subject_table is not None
    if by_profile == (args.setup is not None):
        raise ConfigError("give a ScaleTool SETUP (with a static trial), or a person: --profile FILE or "
                          "--subject-table CSV --subject-id ID")
    if by_profile:
        return _scale_to_person(args)
    done = calibrate(args.setup, args.out, model=args.model, static=args.static, mass=args.mass,
                     filter_hz=args.marker_filter, name=args.name)
    _print_calibration(done)
    return 0


def _scale_to_person(args: argparse.Namespace) -> int:
    """`scale --profile|--subject-table`: no markers; stature ratio, ANSUR II segment measures where given."""
    from dataclasses import replace as replaced

    from biomotion.body.scaling.stature import write_person_model
    from biomotion.generation.command import person

    if args.model is None:
        raise ConfigError("scaling to a person needs the generic model: give --model OSIM (e.g. Rajagopal2016.osim)")
    if args.static is not None or args.marker_filter is not None:
        raise ConfigError("--static and --marker-filter belong to a ScaleTool setup; a person is scaled from "
                          "their profile")
    profile = person(args.profile, args.subject_table, args.subject_id)
    if args.mass is not None:
        profile = replaced(profile, mass=args.mass)
    model, summary_file, summary = write_person_model(args.model, profile, args.out,
                                                      args.name or profile.subject_id or "subject")
    measured = len(summary["ansur_measures_mm"])
    print(f"scaled {Path(args.model).name} to {summary['mass_kg']:.2f} kg, standing {summary['standing_height_m']:.3f}"
          f" m ({'stature ratio' if not measured else f'{measured} ANSUR II measures, stature ratio elsewhere'})")
    print(f"  {model}\n  {summary_file}")
    return 0


def _print_calibration(done, files: bool = True) -> None:
    """One line on what `biomotion.ik.calibrate.calibrate` did, then (``files``) the files it wrote."""
    summary = done.summary
    scaled = {body: f for body, f in summary["scale_factors"].items() if any(abs(v - 1) > 1e-9 for v in f)}
    print(f"scaled {Path(summary['generic_model']).name} to {summary['mass_kg']:.2f} kg: {len(scaled)} bodies "
          f"scaled by {len(summary['measurements'])} measurements"
          + (f", {summary['markers_placed']} markers placed (static pose marker RMS "
             f"{100 * summary['placement_marker_rms_m']:.2f} cm)" if summary["markers_placed"] is not None else ""))
    for path in (done.model, done.scale_set, done.pose, done.summary_file) if files else ():
        if path is not None:
            print(f"  {path}")


def _retarget(args: argparse.Namespace) -> int:
    from biomotion.body.model import BodyModel
    from biomotion.ik.retarget import motion_files, retarget
    from biomotion.io.setup import read_ik_setup
    from biomotion.ik.skeleton import JointMap

    _check_static(args)
    model_path = args.model
    if args.scale_setup is not None:
        from biomotion.ik.calibrate import calibrate
        from biomotion.ik.retarget import is_skeleton

        if args.joint_map is not None or any(is_skeleton(path) for path in motion_files(args.input)):
            raise ConfigError("--static/--scale-setup scale a model to markers; skeletons (BVH, --joint-map) are "
                              "scaled to their own joint centres: retarget them without these options")
        done = calibrate(args.scale_setup, args.out, model=args.model, static=args.static, filter_hz=args.filter)
        _print_calibration(done)
        model_path = done.model
    setup = read_ik_setup(args.setup) if args.setup else None
    if setup is not None and setup.time_range is not None and args.input.is_dir():
        print(f"note: the time range of {args.setup} belongs to one trial; the trials of {args.input} are solved "
              "whole")
        setup = replace(setup, time_range=None)
    joint_map = JointMap.from_file(args.joint_map) if args.joint_map else None
    summaries = retarget(motion_files(args.input), BodyModel.from_osim(model_path), args.out,
                         weights=setup.marker_weights if setup else None, filter_hz=args.filter,
                         joint_map=joint_map, model_path=model_path, setup=setup, progress=not args.quiet)
    failed = [s for s in summaries if s.error]
    for summary in summaries:
        state = f"FAILED: {summary.error}" if summary.error else \
            f"{summary.frames} frames, RMS error {100 * summary.rms_error_m:.2f} cm, max {100 * summary.max_error_m:.2f} cm"
        print(f"  {summary.trial}: {state}")
    print(f"{len(summaries) - len(failed)} of {len(summaries)} trials retargeted -> {args.out} (summary.csv)")
    return 2 if failed and len(failed) == len(summaries) else 0


def build_parser() -> argparse.ArgumentParser:
    data_root = default_data_root()
    parser = argparse.ArgumentParser(
        prog="biomotion",
        description="Personalized, biomechanically plausible human motion: read captured motion, analyse it on a "
                    "musculoskeletal model, build training data, generate and evaluate.",
        epilog=f"Commands that read the datasets take --data-root DIR; without it they read ${DATA_ROOT_VARIABLE} "
               f"when set, else ../shared/data from the working directory (now: {data_root}).")
    parser.add_argument("--version", action="version", version=f"biomotion {__version__}")
    verbs = parser.add_subparsers(dest="verb", metavar="VERB", required=True)

    data = verbs.add_parser("data", help="build and inspect the cached training set",
                            description="The dataset registry: every source under a data root mapped onto the "
                                        "canonical Rajagopal 2016 coordinates, one rate, subject-level splits.")
    data_verbs = data.add_subparsers(dest="data_verb", metavar="ACTION", required=True)
    build = data_verbs.add_parser(
        "build", help="build the cache (clips.safetensors + manifest.json)",
        description="Read every registered source present under --data-root, resample to --rate with an "
                    "anti-alias filter, map coordinates by name onto Rajagopal 2016 (masks for absent ones), and "
                    "write clips.safetensors and manifest.json (counts per source, subject, action; splits).")
    build.add_argument("--data-root", type=Path, default=data_root,
                       help="folder laid out like ../shared/data (default: %(default)s)")
    build.add_argument("--out", type=Path, required=True, help="cache folder to write")
    build.add_argument("--rate", type=float, default=30.0, help="common rate in Hz (default: %(default)s)")
    build.add_argument("--source", action="append", help="only this source (repeatable); default: all present")
    build.add_argument("--report", type=Path, help="also write the counts as a Markdown table (docs/results/)")
    build.add_argument("--quiet", action="store_true", help="no progress bar")
    build.set_defaults(run=_data_build)
    augment = data_verbs.add_parser(
        "augment", help="add time-warped and posture-offset copies of the training clips (for the muscle surrogate)",
        description="Copy a cache and append its training-split clips played faster or slower (--time-warp "
                    "factors; 1.25 = 25 % faster), resampled at the cache rate, and with random marker-placement "
                    "posture offsets (--posture-copies: pelvis turned, thighs and trunk kept, hip axial rotation "
                    "offset; see biomotion.data.posture). Validation and test clips are left as they are. Label the "
                    "result with `biomotion muscles label` and train the surrogate on it (see "
                    "biomotion.data.augment).")
    augment.add_argument("--cache", type=Path, required=True, help="cache folder from `biomotion data build`")
    augment.add_argument("--out", type=Path, required=True, help="new cache folder to write")
    augment.add_argument("--time-warp", type=float, nargs="*", default=[0.8, 0.9, 1.1, 1.25], metavar="F",
                         help="speed factors of the copies; none for no time-warped copies (default: %(default)s)")
    augment.add_argument("--posture-copies", type=int, default=0, metavar="N",
                         help="posture-offset copies per clip (default: %(default)s)")
    augment.add_argument("--seed", type=int, default=0, help="seed of the posture offsets (default: %(default)s)")
    augment.add_argument("--data-root", type=Path, default=data_root,
                         help="data root holding the canonical model, for posture copies (default: %(default)s)")
    augment.add_argument("--split", default="train", choices=("train", "val", "test"),
                         help="split whose clips are copied (default: %(default)s)")
    augment.add_argument("--source", action="append", metavar="NAME",
                         help="copy only the clips of this source (repeatable; default: every source); the other "
                              "sources' clips are kept without copies")
    augment.add_argument("--quiet", action="store_true", help="no progress bar")
    augment.set_defaults(run=_data_augment)
    sources = data_verbs.add_parser("sources", help="list registered sources and whether the data root has them")
    sources.add_argument("--data-root", type=Path, default=data_root)
    sources.set_defaults(run=_data_sources)

    muscles = verbs.add_parser("muscles", help="muscle activation labels for the cached training set",
                               description="Muscle work on the dataset cache (biomotion data build).")
    muscle_verbs = muscles.add_subparsers(dest="muscles_verb", metavar="ACTION", required=True)
    label = muscle_verbs.add_parser(
        "label", help="static-optimization activations (80 Rajagopal muscles) and COM terms for every cached clip",
        description="For every clip of the cache: inverse dynamics on the generic Rajagopal 2016 model with the "
                    "ground reaction inferred from the motion, batched static optimization (squared activations, "
                    "the model's Millard 2012 muscles, reserves), and the whole-body COM position, velocity and "
                    "acceleration. Writes <cache>/surrogate_labels.safetensors and bounds_muscle_activations.json. "
                    "Each finished clip is kept beside the output until all are done, so an interrupted run "
                    "resumes; labels already made from this very cache are reused.")
    label.add_argument("--cache", type=Path, required=True, help="cache folder from biomotion data build")
    label.add_argument("--data-root", type=Path, default=data_root,
                       help="folder holding opensim-models/ (the Rajagopal model; default: %(default)s)")
    label.add_argument("--out", type=Path, help="labels file (default: <cache>/surrogate_labels.safetensors)")
    label.add_argument("--quiet", action="store_true", help="no progress bar")
    label.set_defaults(run=_muscles_label)

    convert = verbs.add_parser(
        "convert", help="convert between motion/marker formats (.mot .sto .trc .c3d .bvh .csv)",
        description="Read INPUT in any supported format and write OUTPUT in the format its suffix names: "
                    "coordinates .mot/.sto/.csv, markers .trc/.c3d/.csv (from .trc, .c3d or BVH joint positions; "
                    ".c3d output holds the markers only, in mm), skeletons .bvh/.bvh.gz. With --model, INPUT "
                    "holds coordinates of that model, which become a BVH skeleton of its bodies (.bvh), its "
                    "markers by forward kinematics (.trc, .c3d) or the coordinates in model order (.mot, .sto, "
                    ".csv).")
    convert.add_argument("input", type=Path)
    convert.add_argument("output", type=Path)
    convert.add_argument("--model", type=Path, help="the .osim model whose coordinates INPUT holds")
    convert.set_defaults(run=_convert)

    generate = verbs.add_parser(
        "generate", help="generate personalised, biomechanically guided motion for a person and an action (PG-BIG)",
        description="Generate motion of ACTION for a person (PG-BIG): the profile (a YAML/JSON file or a subject "
                    "table row) and optional reference clips of the person condition an autoregressive prior over "
                    "motion tokens; biomechanical guidance then refines the sample through the body model and the "
                    "muscle surrogate. Writes, per sample: motion.mot (coordinates of the person's scaled model), "
                    "motion.bvh, grf.mot + grf_loads.xml and torques.sto (inferred from the motion), "
                    "activations.sto (surrogate), com_zmp.sto, metrics.json, plots and viewer.html; and model.osim "
                    "(the generic Rajagopal 2016 model scaled to the person's height and mass).",
        epilog="example: biomotion generate --profile examples/runner_52_acl.yaml "
               "--action \"running at 3.5 m/s\" --seconds 3 --out out/runner")
    person = generate.add_argument_group("who (optional: without a profile the motion is population-level)")
    person.add_argument("--profile", type=Path, help="profile file (YAML/JSON: age, sex, height, mass, sport, "
                                                     "level, experience_years, injuries)")
    person.add_argument("--subject-table", type=Path, help="subject table (CSV/XLSX) holding the person")
    person.add_argument("--subject-id", help="the person's id in --subject-table")
    person.add_argument("--reference", type=Path, action="append",
                        help="a clip of the person (OpenSim coordinates .mot/.sto, Rajagopal-family names); "
                             "repeatable. The clips condition the prior and centre the motion on the person's "
                             "posture (their mean deviation from the population's for the clip's action and speed; "
                             "metrics.json lists the offset)")
    person.add_argument("--reference-action", action="append", metavar="TEXT",
                        help="what a --reference clip shows, free text like --action (\"run at 2.5 m/s\"); one per "
                             "--reference, in order. Without it, each clip's action is the one whose population "
                             "posture is nearest and its speed that action's mean")
    generate.add_argument("--action",
                          help="(required) what to do, free text mapped to the nearest dataset label (\"run at "
                               "3.5 m/s\", \"squat\", \"drop jump\", \"walk with toes out\"; without a number, the "
                               "label's median training speed, or its lower/upper quartile for \"slowly\", \"fast\" "
                               "...); the Bandai-Namco contents and styles (\"wave both hands\", \"bow\", "
                               "\"walk, elderly\") go to the full-body bundle, with the profile's biodata masked "
                               "(docs/generation.md)")
    generate.add_argument("--seconds", type=float, default=3.0, help="clip length (default: %(default)s)")
    generate.add_argument("--samples", type=int, default=1, help="clips to draw (default: %(default)s)")
    generate.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")
    generate.add_argument("--no-guidance", action="store_true", help="skip biomechanical guidance (ablation)")
    generate.add_argument("--smooth", type=float, metavar="HZ",
                          help="low-pass the guided coordinates at HZ (zero-lag Butterworth, below 15 Hz at the "
                               "generator's 30 Hz) before the feet are planted: 6 Hz brings jerk to the real clips' "
                               "level and lowers muscle-limit violations, at a little more foot sliding "
                               "(docs/results/dev_guidance_skim.md). Default: off")
    generate.add_argument("--no-profile", action="store_true", help="ignore the profile and references (ablation)")
    generate.add_argument("--no-figures", action="store_true", help="no plots or viewer")
    generate.add_argument("--threads", type=int, help="torch threads for sampling and guidance (default: 2, or "
                                                      "the machine's cores if fewer)")
    generate.add_argument("--data-root", type=Path, default=data_root,
                          help="folder with opensim-models/ (the canonical Rajagopal model; default: %(default)s)")
    generate.add_argument("--checkpoints", type=Path,
                          help="folder of trained weights (default: the shipped lab bundle, or the shipped "
                               "full-body bundle checkpoints/full-body for the labels only it knows)")
    generate.add_argument("--out", type=Path, help="(required) output folder")
    generate.add_argument("--list-actions", action="store_true",
                          help="list the actions, styles and typical speeds each shipped bundle knows, and exit")
    generate.set_defaults(run=_generate)

    analyze = verbs.add_parser(
        "analyze", help="joint torques, ground forces, COM, ZMP and energy of a trial on a model",
        description="Inverse dynamics of TRIAL on MODEL: coordinates low-pass filtered (--cutoff, as OpenSim's ID "
                    "tool), ground reaction inferred from the kinematics alone (always) and, with --grf, the measured "
                    "plates assigned to the feet and used for the torques. Writes torques.sto, grf_inferred.mot "
                    "(+ ExternalLoads XML), com_zmp.sto, coordinates_filtered.mot, summary.json, viewer.html and "
                    "plots (joint angles, GRF, COM/ZMP) into --out; with --muscles also activations.sto (static "
                    "optimization of those torques). TRIAL may be captured motion too: markers (.trc, .c3d) are "
                    "first solved by inverse kinematics on MODEL (with --setup's weights, tasks and time range), a "
                    "skeleton (.bvh, .bvh.gz) is retargeted onto MODEL (the generic model, scaled to the skeleton), "
                    "exactly as `biomotion retarget` does; with --static and --scale-setup a generic MODEL is "
                    "first scaled to the subject's static trial (as `biomotion scale`). The IK result (and the "
                    "scaled model) is kept in --out/ik and summarised in summary.json, so one command runs the "
                    "whole chain from the lab's files.",
        epilog="examples, with G=../shared/data/opensim-models/Pipelines/Gait2392_Simbody: biomotion analyze "
               "$G/subject01_walk1_ik.mot --model $G/OutputReference/subject01_simbody.osim --grf "
               "$G/subject01_walk1_grf.mot --muscles gait2392_subject01 --out out/walk; from the markers: "
               "biomotion analyze $G/subject01_walk1.trc --setup $G/subject01_Setup_IK.xml --model "
               "$G/OutputReference/subject01_simbody.osim --grf $G/subject01_walk1_grf.mot --out out/walk_markers")
    analyze.add_argument("trial", type=Path,
                         help="coordinates (.mot/.sto), e.g. an IK result; or markers (.trc/.c3d) or a skeleton "
                              "(.bvh/.bvh.gz), solved by inverse kinematics first")
    analyze.add_argument("--model", type=Path, required=True,
                         help="the subject's scaled .osim model (for a skeleton: the generic model to scale)")
    analyze.add_argument("--setup", type=Path,
                         help="markers only: OpenSim IK setup XML (marker weights, coordinate tasks, time range)")
    analyze.add_argument("--static", type=Path,
                         help="markers only: a static trial; MODEL is then the generic model, scaled to it by "
                              "--scale-setup first (as `biomotion scale`; kept in --out/ik)")
    analyze.add_argument("--scale-setup", type=Path, help="OpenSim ScaleTool setup XML for --static")
    analyze.add_argument("--marker-filter", type=float, metavar="HZ",
                         help="markers: low-pass them before IK; skeletons: the coordinates (default 10 Hz, as "
                              "`biomotion retarget --filter`)")
    analyze.add_argument("--grf", type=Path, help="measured ground reaction (.mot external loads or .c3d)")
    analyze.add_argument("--cutoff", type=float, default=6.0, help="low-pass cutoff in Hz (default: %(default)s)")
    analyze.add_argument("--muscles", metavar="PATHS",
                         help="also muscle activations by static optimization (activations.sto): muscle path "
                              "functions fitted on MODEL, a file from `python -m biomotion.training.fit_paths --model "
                              "MODEL --out PATHS.safetensors` (minutes, once per model; needs opensim, the "
                              "validate extra), or a shipped name: rajagopal2016 (the generic "
                              "Rajagopal 2016 model), gait2392_subject01 (OpenSim's gait2392 subject01_simbody)")
    analyze.add_argument("--out", type=Path, required=True, help="output folder")
    analyze.add_argument("--geometry", type=Path, action="append",
                         help="extra folder of .vtp bone meshes for the viewer (repeatable)")
    analyze.add_argument("--no-figures", action="store_true", help="skip viewer.html and the PNG/SVG plots")
    analyze.set_defaults(run=_analyze)

    view = verbs.add_parser(
        "view", help="write a self-contained HTML viewer of a motion (offline, any browser)",
        description="Animated 3D view of MOTION (.mot with --model, .bvh/.bvh.gz, .trc, .c3d markers) with "
                    "optional ground reaction arrows, COM/ZMP and support polygon (com_zmp.sto from `analyze`), "
                    "muscle activations, and a second motion to compare (overlay or side by side).")
    view.add_argument("motion", type=Path)
    view.add_argument("--model", type=Path, help=".osim model for an OpenSim coordinates file")
    view.add_argument("--grf", type=Path, help="ground reaction (.mot or .c3d)")
    view.add_argument("--activations", type=Path, help="muscle activations (.sto)")
    view.add_argument("--com-zmp", type=Path, help="COM/ZMP/support file (com_zmp.sto from `analyze`)")
    view.add_argument("--compare", type=Path, help="a second motion to compare")
    view.add_argument("--compare-mode", choices=("overlay", "side"), default="overlay")
    view.add_argument("--geometry", type=Path, action="append", help="extra folder of .vtp meshes (repeatable)")
    view.add_argument("--out", type=Path, default=Path("viewer.html"), help="HTML file (default: %(default)s)")
    view.set_defaults(run=_view)

    validate = verbs.add_parser(
        "validate", help="check biomotion against OpenSim and measured data; JSON report",
        description="Run the validation checks on whatever data is under --data-root (any folder laid out like "
                    "../shared/data; absent sources are named and skipped): kinematics = forward kinematics vs "
                    "OpenSim on every model; dynamics = inverse dynamics vs OpenSim's solver and ID tool, and "
                    "ground reaction inferred from kinematics vs force plates; ik = marker IK and scaling vs "
                    "OpenSim's InverseKinematicsTool and ScaleTool; muscles = moment arms and static "
                    "optimization vs OpenSim.")
    validate.add_argument("what", choices=("kinematics", "dynamics", "ik", "muscles"))
    validate.add_argument("--data-root", type=Path, default=data_root)
    validate.add_argument("--json", type=Path, required=True, help="report file to write")
    validate.add_argument("--md", type=Path, help="also write the tables as Markdown (for docs/results/)")
    validate.add_argument("--quiet", action="store_true", help="no progress bars")
    validate.set_defaults(run=_validate)

    scale = verbs.add_parser(
        "scale", help="scale a generic model to a subject from a static trial (OpenSim ScaleTool setup) -> .osim",
        description="OpenSim's ScaleTool from its setup XML: body scale factors from the distances of the setup's "
                    "marker pairs in the static trial against the generic model (measurements; manual scales as "
                    "the setup orders them), masses scaled to the subject's mass (distribution kept when the setup "
                    "says so), then the MarkerPlacer: the static pose by IK and the non-fixed markers moved onto "
                    "the data (PG-BIG A.2). Writes NAME.osim (opens in OpenSim; use it as `retarget --model`), "
                    "NAME_scale_set.xml, NAME_static_pose.mot and NAME_scale.json into --out. Setups name their "
                    "model and static trial by paths relative to where they were written: --model and --static "
                    "override them. Without markers, a person (--profile, or a subject table row) scales --model "
                    "by stature and, where given, ANSUR II segment measures.",
        epilog="example, with F=../shared/data/fukuchi-running: biomotion scale "
               "$F/RBDS001/RBDS001_scaleSetup_simple.xml --model "
               "$F/generic-models/Denton2023_LowerLimb_Fukuchi2017.osim --static $F/c3d/RBDS001static.c3d "
               "--marker-filter 10 --out out/RBDS001")
    scale.add_argument("setup", type=Path, nargs="?", help="OpenSim ScaleTool setup XML")
    scale.add_argument("--profile", type=Path,
                       help="instead of a setup: a person (YAML/JSON profile); every body scaled by the stature "
                            "ratio, except segments whose ANSUR II measures (mm, the survey's names, e.g. "
                            "footlength) the profile gives, scaled by them (biomotion.body.scaling.segments)")
    scale.add_argument("--subject-table", type=Path, help="instead of a setup: a subject table (an ANSUR II file "
                                                          "gives every measure), with --subject-id")
    scale.add_argument("--subject-id", help="the row of --subject-table")
    scale.add_argument("--model", type=Path, help="the generic .osim (default: the setup's model_file)")
    scale.add_argument("--static", type=Path, help="the static trial, .trc or .c3d (default: the setup's marker_file)")
    scale.add_argument("--mass", type=float, help="subject mass in kg (default: the setup's mass)")
    scale.add_argument("--marker-filter", type=float, metavar="HZ",
                       help="low-pass the static markers first (zero-lag Butterworth; the Fukuchi chain used 10 Hz)")
    scale.add_argument("--name", help="name of the scaled model and its files (default: the setup's name)")
    scale.add_argument("--out", type=Path, required=True, help="output folder")
    scale.set_defaults(run=_scale)

    retarget = verbs.add_parser(
        "retarget", help="captured motion (.trc, .c3d markers; .bvh/.bvh.gz skeletons; a file or a folder) -> "
                         "model coordinates (.mot) by batched IK",
        description="Marker trials: inverse kinematics of every frame at once on MODEL, the subject's scaled model "
                    "(weighted least squares, coordinate ranges, locked and coupled coordinates, occluded markers "
                    "skipped per frame); marker weights, coordinate tasks and time range come from an OpenSim IK setup "
                    "(--setup), or every model marker found in the data weighs 1. Skeletons (BVH, or marker files of joint centres with "
                    "--joint-map): MODEL is the generic model, scaled to each skeleton's segment lengths and fitted "
                    "to its joint centres (PG-BIG A.5), coordinates filtered at 10 Hz when the frame rate is at "
                    "least 40 Hz and kept in range, feet put on y = 0; the scaled model is written as <trial>.osim. Writes <trial>.mot per trial and "
                    "summary.csv (RMS and max marker or joint-centre error, frames dropped); keeps going past a "
                    "bad trial.")
    retarget.add_argument("input", type=Path, help="a .trc/.c3d/.bvh/.bvh.gz file or a folder of them")
    retarget.add_argument("--model", type=Path, required=True,
                          help="markers: the subject's scaled .osim (with markers); skeletons: the generic .osim "
                               "(e.g. Rajagopal2016.osim)")
    retarget.add_argument("--setup", type=Path, help="OpenSim IK setup XML: its marker weights, coordinate tasks "
                                                     "and (for a single trial) time range, as OpenSim's IK tool "
                                                     "uses them")
    retarget.add_argument("--static", type=Path,
                          help="a static trial (.trc/.c3d): MODEL is then the generic model, scaled to it by "
                               "--scale-setup first (as `biomotion scale`, the static markers low-passed by --filter "
                               "too; written into --out), and the trials are solved on the scaled model")
    retarget.add_argument("--scale-setup", type=Path,
                          help="OpenSim ScaleTool setup XML for --static (its measurements, mass, marker placer)")
    retarget.add_argument("--joint-map", type=Path,
                          help='JSON {"centres": {model joint: skeleton joint}, "toes": {model toe joint: skeleton '
                               'joint}}: treat the input as joint centres (built in: the Bandai-Namco skeleton)')
    retarget.add_argument("--filter", type=float,
                          help="low-pass (Hz): markers before IK; skeletons: the coordinates (default 10, applied "
                               "when the frame rate is at least 4x the cutoff)")
    retarget.add_argument("--out", type=Path, required=True, help="output folder")
    retarget.add_argument("--quiet", action="store_true", help="no progress bar")
    retarget.set_defaults(run=_retarget)

    evaluate = verbs.add_parser(
        "eval", help="score motion with the metrics of the four papers (JSON, Markdown table, plots)",
        description="`biomotion eval --pred PATH... [--ref PATH...]` scores predicted motion (OpenSim .mot files, "
                    "a BVH folder, or a dataset cache) and, with --ref, compares it with reference motion "
                    "(PG-BIG Table 2 / PhysPT Table 1 layout). `biomotion eval reference` scores every source of "
                    "the dataset registry under --data-root per source and action: the Reference column.")
    evaluate.add_argument("mode", nargs="?", choices=("reference", "generation"),
                          help="reference: score the real data (reference table); generation: generate for every "
                               "unseen subject of --data-root and tabulate PG-BIG Tables 2-3 (full model, w/o "
                               "guidance, w/o personalization, population baseline), the identity probe and the "
                               "profile-manipulation study")
    evaluate.add_argument("--pred", nargs="+", type=Path, help="predicted motion: files or one folder")
    evaluate.add_argument("--ref", nargs="+", type=Path, help="reference motion: files or one folder")
    evaluate.add_argument("--data-root", type=Path, default=data_root,
                          help="folder laid out like ../shared/data: the canonical model, and the subjects of "
                               "reference and generation (default: %(default)s)")
    evaluate.add_argument("--json", type=Path, help="JSON report to write")
    evaluate.add_argument("--md", type=Path, help="Markdown table to write (--pred: printed when not given)")
    evaluate.add_argument("--plots", type=Path, help="folder for per-clip distribution plots")
    evaluate.add_argument("--physics", action="store_true",
                          help="also full-body energy and ZMP-in-support (slower)")
    evaluate.add_argument("--no-physics", action="store_true", help="reference: skip the slower physics metrics")
    evaluate.add_argument("--checkpoints", type=Path, help="generation: folder of trained weights (default: shipped)")
    evaluate.add_argument("--max-seconds", type=float, default=6.0,
                          help="generation: longest target clip, longer ones are cut (default: %(default)s)")
    evaluate.add_argument("--seed", type=int, default=0, help="generation: random seed (default: %(default)s)")
    evaluate.add_argument("--repeats", type=int, default=3,
                          help="generation: generate and score every target this many times with different seeds "
                               "and pool them (bars judged on the pooled means; per-repeat means and their 95 %% "
                               "interval reported) (default: %(default)s)")
    evaluate.add_argument("--manipulation-samples", type=int, default=8,
                          help="generation: clips per profile in the manipulation study, 0 skips it "
                               "(default: %(default)s)")
    evaluate.set_defaults(run=_eval)

    inspect = verbs.add_parser("inspect", help="print what a file holds (frames, rate, channels, units; for a subject "
                                                "table its schema, subjects and profile fields; for an .osim model "
                                                "its bodies, mass, coordinates, markers and muscles; for an IK or "
                                                "Scale setup .xml the files it names and its tasks)")
    inspect.add_argument("input", type=Path)
    inspect.set_defaults(run=_inspect)
    return parser


def _one_line_warnings(showwarning):
    """``warnings.showwarning`` that prints biomotion's own warnings as one line, like its errors (the default
    adds the file and line of the library code that warned, which names nothing the user gave)."""
    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, BiomotionWarning):
            print(f"biomotion: warning: {message}", file=sys.stderr if file is None else file)
        else:
            showwarning(message, category, filename, lineno, file, line)
    return show


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        from biomotion.body.kinematics import torch_threads

        # many small batched tensor ops: one intra-op thread per process is fastest (docs/results/dynamics.md)
        with torch_threads(1), warnings.catch_warnings():
            warnings.showwarning = _one_line_warnings(warnings.showwarning)
            return int(args.run(args) or 0)
    except BiomotionError as error:
        print(f"biomotion: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("biomotion: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:   # `biomotion inspect X | head`: the reader left; say nothing more
        sys.stdout = open(os.devnull, "w")
        return 141


if __name__ == "__main__":
    sys.exit(main())
