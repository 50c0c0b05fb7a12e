"""``biomotion analyze``: the lab chain on one trial (`biomotion.analysis.trial.analyze_trial`), written as OpenSim
files, a summary, plots and a viewer page."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from biomotion.cli._common import add_overwrite, fresh_folder, moved, number

DESCRIPTION = (
    "Inverse dynamics of TRIAL on MODEL: coordinates low-pass filtered (--cutoff, as OpenSim's ID tool), ground "
    "reaction inferred from the kinematics alone (always) and, with --grf, the measured plates assigned to the feet "
    "and used for the torques. Writes torques.sto, grf_inferred.mot (+ ExternalLoads XML), com_zmp.sto, "
    "coordinates_filtered.mot, summary.json, viewer.html and plots (joint angles, GRF, COM/ZMP) into --out; with "
    "--muscles also activations.sto (static optimization of those torques). --forces learned (without plates) takes "
    "the torques from the ground reaction a network trained on force plates predicts from the kinematics "
    "(checkpoints/ground_forces.md; grf_learned.mot); summary.json's force_source says which forces the torques "
    "used (measured, inferred or learned). TRIAL may be captured motion too: "
    "markers (.trc, .c3d) are first solved by inverse kinematics on MODEL (with --setup's weights, tasks and time "
    "range), a skeleton (.bvh, .bvh.gz) is retargeted onto MODEL (the generic model, scaled to the skeleton), "
    "exactly as `biomotion retarget` does; with --static and --scale-setup a generic MODEL is first scaled to the "
    "subject's static trial (as `biomotion scale`). The IK result (and the scaled model) is kept in --out/ik and "
    "summarised in summary.json, so one command runs the whole chain from the lab's files. Python: "
    "biomotion.analyze_trial."
)
EPILOG = (
    "examples, with G=../shared/data/opensim-models/Pipelines/Gait2392_Simbody: biomotion analyze "
    "$G/subject01_walk1_ik.mot --model $G/OutputReference/subject01_simbody.osim --grf $G/subject01_walk1_grf.mot "
    "--muscles gait2392_subject01 --out out/walk; from the markers: biomotion analyze $G/subject01_walk1.trc "
    "--setup $G/subject01_Setup_IK.xml --model $G/OutputReference/subject01_simbody.osim --grf "
    "$G/subject01_walk1_grf.mot --out out/walk_markers"
)
MARKER_SUFFIXES = (".trc", ".c3d")
SKELETON_SUFFIXES = (".bvh", ".bvh.gz")


def add_parser(verbs) -> None:
    parser = verbs.add_parser(
        "analyze",
        help="joint angles, torques, ground forces, COM, ZMP, energy and (with "
        "--muscles) activations of a trial on a model",
        description=DESCRIPTION,
        epilog=EPILOG,
    )
    parser.add_argument(
        "trial",
        type=Path,
        help="coordinates (.mot/.sto), e.g. an IK result; or markers (.trc/.c3d) or a skeleton "
        "(.bvh/.bvh.gz), solved by inverse kinematics first",
    )
    parser.add_argument(
        "--model",
        type=Path,
        required=True,
        help="the subject's scaled .osim model (for a skeleton: the generic model to scale)",
    )
    parser.add_argument(
        "--setup", type=Path, help="markers only: OpenSim IK setup XML (marker weights, coordinate tasks, time range)"
    )
    parser.add_argument(
        "--static",
        type=Path,
        help="markers only: a static trial; MODEL is then the generic model, scaled to it by "
        "--scale-setup first (as `biomotion scale`; kept in --out/ik)",
    )
    parser.add_argument("--scale-setup", type=Path, help="OpenSim ScaleTool setup XML for --static")
    parser.add_argument(
        "--marker-filter",
        type=number(0, low_open=True),
        metavar="HZ",
        help="markers: low-pass them before IK; skeletons: the coordinates (default 10 Hz, as "
        "`biomotion retarget --filter`)",
    )
    parser.add_argument("--grf", type=Path, help="measured ground reaction (.mot external loads or .c3d)")
    parser.add_argument(
        "--plates",
        metavar="SPEC",
        help="which foot each --grf plate carries: CHANNEL=right|left|none|BODY,... (e.g. 1=right,2=left,3=none; a "
        "channel by number or name); plates not named are assigned to the feet automatically, per frame, and the "
        "assignment is printed and kept in summary.json",
    )
    parser.add_argument(
        "--forces",
        choices=("measured", "inferred", "learned"),
        help="ground reaction of the torques: measured (the --grf plates), inferred (the contact model, from the "
        "kinematics alone) or learned (a network trained on force plates, from the kinematics; with --grf the "
        "plates are kept for comparison) (default: measured with --grf, else inferred)",
    )
    parser.add_argument(
        "--forces-model",
        type=Path,
        metavar="WEIGHTS",
        help="--forces learned: a .safetensors file from `biomotion train ground-forces` (default: the shipped "
        "checkpoints/ground_forces.safetensors)",
    )
    parser.add_argument(
        "--forces-trim",
        action="store_true",
        help="analyse only the frames the --grf file covers when it is shorter than the motion "
        "(default: refuse a force file that does not cover the motion)",
    )
    parser.add_argument(
        "--cutoff",
        type=number(0, 200),
        default=6.0,
        help="low-pass cutoff of the coordinates in Hz, 0 for none (default: %(default)s)",
    )
    parser.add_argument(
        "--muscles",
        metavar="PATHS",
        help="also muscle activations by static optimization (activations.sto): muscle path "
        "functions fitted on MODEL, a file from `biomotion train paths --model MODEL --out "
        "PATHS.safetensors` (minutes, once per model; needs opensim, the validate extra), or "
        "a shipped name: rajagopal2016 (the generic Rajagopal 2016 model), gait2392_subject01 "
        "(OpenSim's gait2392 subject01_simbody)",
    )
    parser.add_argument("--out", type=Path, required=True, help="output folder (created; must be new or empty)")
    add_overwrite(parser)
    parser.add_argument(
        "--geometry", type=Path, action="append", help="extra folder of .vtp bone meshes for the viewer (repeatable)"
    )
    parser.add_argument("--no-figures", action="store_true", help="skip viewer.html and the PNG/SVG plots")
    parser.set_defaults(run=run)


def _check_options(args: argparse.Namespace, captured: bool) -> None:
    from biomotion.errors import ConfigError

    if not args.trial.exists():
        raise ConfigError(f"{args.trial}: no such file")
    if not args.model.is_file():
        raise ConfigError(f"{args.model}: --model is not a file")
    if not captured and (args.setup or args.marker_filter or args.static or args.scale_setup):
        raise ConfigError(
            f"{args.trial}: --setup, --marker-filter, --static and --scale-setup are for captured "
            f"motion (.trc/.c3d markers, .bvh skeletons); a coordinates file is analysed as it is"
        )
    if args.static is not None and args.scale_setup is None:
        raise ConfigError(
            "--static scales the model, which needs the measurements of an OpenSim Scale setup: give "
            "--scale-setup XML too (`biomotion scale --help`)"
        )
    if args.forces == "measured" and args.grf is None:
        raise ConfigError("--forces measured needs the plates: give --grf FILE")
    if args.forces == "inferred" and args.grf is not None:
        raise ConfigError("--forces inferred takes the torques from the kinematics alone: leave out --grf")
    if args.forces_model is not None and args.forces != "learned":
        raise ConfigError("--forces-model is the weights of --forces learned")
    skeleton = args.trial.name.lower().endswith(SKELETON_SUFFIXES)
    if skeleton and (args.setup is not None or args.scale_setup is not None):
        raise ConfigError(f"{args.trial} is a skeleton: IK and Scale setups weigh and measure markers")


def _forces(args: argparse.Namespace):
    """The measured ground reaction of --grf."""
    from biomotion.errors import DataFormatError
    from biomotion.io.formats import read_any

    if args.grf is None:
        return None
    if not args.grf.is_file():
        raise DataFormatError(args.grf, "--grf is not a file")
    data = read_any(args.grf)
    forces = getattr(data, "forces", data)
    if forces is None or not hasattr(forces, "force"):
        raise DataFormatError(args.grf, "holds no force-plate data")
    if args.plates:
        from biomotion.analysis.study import parse_plates, plate_bodies

        overrides = plate_bodies(forces.names, parse_plates(args.plates, "--plates"))
        kept = [name for name in forces.names if overrides.get(name, "") is not None]
        if not kept:
            raise DataFormatError(args.grf, "--plates leaves no plate to use")
        forces = forces.assign([overrides.get(n, b) for n, b in zip(forces.names, forces.bodies)]).select(kept)
    return forces


def run(args: argparse.Namespace) -> int:
    captured = args.trial.name.lower().endswith((*MARKER_SUFFIXES, *SKELETON_SUFFIXES))
    _check_options(args, captured)
    out = args.out
    with fresh_folder(out, args.overwrite) as scratch:
        files, figures, extra, model_name, solution = _analyze(args, captured, scratch)
    _report(figures, extra, model_name, solution, {role: moved(path, scratch, out) for role, path in files.items()})
    return 0


def _analyze(args: argparse.Namespace, captured: bool, scratch: Path):
    import numpy as np

    from biomotion.analysis.activations import (
        TrialSettings,
        activation_summary,
        check_paths,
        load_paths,
        write_activations,
    )
    from biomotion.analysis.chain import summary, write_analysis
    from biomotion.analysis.trial import analyze_trial, forces_cover
    from biomotion.body.model import BodyModel
    from biomotion.io.formats import read_trial
    from biomotion.io.setup import read_ik_setup

    model_path = args.model
    extra: dict = {}
    ik_folder = scratch / "ik"
    if args.scale_setup is not None:
        from biomotion.cli.scale import print_calibration
        from biomotion.ik.calibrate import calibrate

        done = calibrate(
            args.scale_setup, ik_folder, model=args.model, static=args.static, filter_hz=args.marker_filter
        )
        print_calibration(done, files=False)
        model_path = done.model
    setup = read_ik_setup(args.setup) if args.setup else None
    # the marker filter runs over the whole capture (its edges are not the window's): only unfiltered reads are cut
    window = setup.time_range if setup is not None and not args.marker_filter else None
    trial = read_trial(args.trial, window)
    model = BodyModel.from_osim(model_path)
    if trial.motion is not None:
        ignored = [name for name in trial.motion.names if name not in model.coordinate_names]
        if ignored:
            print(
                f"warning: {args.trial}: {len(ignored)} column(s) name no coordinate of {model.name} and are "
                f"ignored: {', '.join(ignored)}",
                file=sys.stderr,
            )
    forces = _forces(args)
    if forces is not None:
        trial = forces_cover(trial, forces, setup=setup, trim=args.forces_trim, source=args.grf)
    paths = check = None
    if args.muscles is not None:  # before the analysis: a wrong path file fails fast and writes nothing
        paths, label = load_paths(args.muscles)
        check = check_paths(paths, label, model_path, model.coordinate_names)
        if check.warning:
            print(f"warning: {check.warning}", file=sys.stderr)
    if args.forces == "learned":  # the plates, if any, stay on the trial for comparison
        from dataclasses import replace

        from biomotion.models.ground_forces import learned_forces

        trial, forces = replace(trial, forces=forces), learned_forces(args.forces_model)
    result = analyze_trial(
        trial,
        model=model,
        forces=forces,
        setup=setup,
        marker_filter_hz=args.marker_filter,
        muscles=paths,
        muscle_model=model_path,
        cutoff_hz=args.cutoff,
    )
    if forces is not None and result.dynamics.measured is not None:
        import torch

        from biomotion.analysis.chain import plate_assignment

        dynamics = result.dynamics
        q = torch.as_tensor(dynamics.motion.values, dtype=dynamics.model.dtype)
        extra["plates"] = plate_assignment(forces, dynamics.model, q, dynamics.motion.times)
    files: dict[str, Path] = {}
    coordinates, analysed_model = args.trial, model_path
    if result.fit is not None:
        coordinates, analysed_model, extra["inverse_kinematics"] = _write_fit(
            args, result, model, model_path, ik_folder
        )
        files["inverse_kinematics"] = ik_folder
    if result.activations is not None:
        extra["muscles"] = activation_summary(result.activations, check, TrialSettings())
    files = {**write_analysis(result.dynamics, scratch, extra_summary=extra), **files}
    if result.activations is not None:
        files["activations"] = write_activations(scratch / "activations.sto", result.dynamics, result.activations)
    if not args.no_figures:
        files.update(_figures(args, coordinates, analysed_model, result, files, scratch))
    if not np.isfinite(result.torques).all():
        print("warning: some torques are not finite (check the coordinates and the model)", file=sys.stderr)
    return files, summary(result.dynamics), extra, model.name, result.activations


def _write_fit(args: argparse.Namespace, result, generic, model_path: Path, folder: Path):
    """The inverse kinematics as `biomotion retarget` writes it (``<trial>.mot``, a skeleton's ``<trial>.osim``,
    summary.csv) into ``folder``; returns the coordinates file, the model file analysed and summary.json's section."""
    from biomotion.ik.retarget import SUMMARY_COLUMNS, trial_name
    from biomotion.ik.skeleton import write_scaled_model
    from biomotion.io.mot import write_motion
    from biomotion.io.tables import write_csv

    fit, name = result.fit, trial_name(args.trial)
    folder.mkdir(parents=True, exist_ok=True)
    coordinates = write_motion(folder / f"{name}.mot", fit.motion)
    model_file = model_path
    if fit.factors is not None:
        model_file = write_scaled_model(model_path, folder / f"{name}.osim", generic, fit.factors, name=name)
    row = fit.summary(name, coordinates.name)
    write_csv(folder / "summary.csv", SUMMARY_COLUMNS, [row.row()])
    kind = fit.point_kind
    print(
        f"inverse kinematics: {row.frames} frames, RMS {kind} error {100 * row.rms_error_m:.2f} cm "
        f"(max {100 * row.max_error_m:.2f} cm, {row.frames_dropped} frames without a tracked point)"
    )
    point = kind.replace(" ", "_")
    section = {
        "source": str(args.trial),
        "setup": str(args.setup) if args.setup else None,
        "filter_hz": args.marker_filter,
        "frames": row.frames,
        f"rms_{point}_error_m": row.rms_error_m,
        f"max_{point}_error_m": row.max_error_m,
        "frames_dropped": row.frames_dropped,
        "coordinates": f"ik/{coordinates.name}",
        "model": f"ik/{Path(model_file).name}" if Path(model_file) != args.model else str(args.model),
    }
    if args.scale_setup is not None:
        section["scaling"] = f"ik/{Path(model_path).stem}_scale.json"
    return coordinates, model_file, section


def _figures(args: argparse.Namespace, coordinates: Path, model: Path, result, files: dict, scratch: Path) -> dict:
    """The viewer and the plots `analyze` writes by default."""
    from biomotion.analysis.chain import support_polygons
    from biomotion.viz.plots import plot_activations, plot_balance, plot_ground_reaction, plot_joint_angles
    from biomotion.viz.scene import geometry_folders
    from biomotion.viz.viewer import view_command

    dynamics = result.dynamics
    # a model scaled here lies in the output's ik folder: its meshes are where the generic model's are
    generic = geometry_folders(args.model) if Path(model) != Path(args.model) else []
    out = {
        "viewer": view_command(
            coordinates,
            model=model,
            grf=args.grf,
            com_zmp=files["com_zmp"],
            out=scratch / "viewer.html",
            geometry=[*(args.geometry or ()), *generic],
        )
    }
    out["plot_joint_angles"] = plot_joint_angles(dynamics.motion, scratch / "joint_angles")[0]
    if dynamics.learned is not None:  # the learned forces the torques used, against the plates or the inferred
        compared = "measured" if dynamics.measured is not None else "inferred"
        reaction, label, other = dynamics.learned, "learned", getattr(dynamics, compared)
    elif dynamics.measured is not None:
        reaction, label, other, compared = dynamics.measured, "measured", dynamics.inferred, "inferred"
    else:
        reaction, label, other, compared = dynamics.inferred, "inferred", None, "inferred"
    out["plot_grf"] = plot_ground_reaction(
        reaction,
        scratch / "grf",
        body_weight=dynamics.body_weight,
        inferred=other,
        label=label,
        other_label=compared,
    )[0]
    out["plot_balance"] = plot_balance(
        dynamics.com,
        dynamics.zmp,
        scratch / "balance",
        support=support_polygons(dynamics.contact_points, dynamics.contact_loaded),
    )[0]
    if result.activations is not None:
        solution = result.activations
        out["plot_activations"] = plot_activations(
            dynamics.motion.times,
            solution.muscle_names,
            solution.activations.numpy(),
            scratch / "activations",
            title="static optimization",
        )[0]
    return out


def _report(figures: dict, extra: dict, model_name: str, solution, files: dict) -> None:
    print(
        f"analysed {figures['frames']} frames at {figures['rate_hz']:.0f} Hz on {model_name} "
        f"({figures['body_mass_kg']:.1f} kg); torques from {figures['torques_from']} ground reaction"
    )
    if "inferred_vs_measured_vertical" in figures:
        ours, base = figures["inferred_vs_measured_vertical"], figures["com_baseline_vs_measured_vertical"]
        print(
            f"  vertical GRF from kinematics vs plates: R2 {ours['r2']:.3f}, RMSE {ours['rmse_bw']:.3f} BW "
            f"(COM baseline: R2 {base['r2']:.3f}, RMSE {base['rmse_bw']:.3f} BW)"
        )
    if "learned_vs_measured_vertical" in figures:
        learned = figures["learned_vs_measured_vertical"]
        print(f"  learned vertical GRF vs plates: R2 {learned['r2']:.3f}, RMSE {learned['rmse_bw']:.3f} BW")
    if extra.get("plates"):
        parts = []
        for channel, a in extra["plates"].items():
            if a["mode"] == "given":
                parts.append(f"{channel} -> {a['body']} (given)")
            elif a["frames"]:
                shares = "/".join(f"{side} {100 * a[side]:.0f}%" for side in ("right", "left") if a[side])
                parts.append(f"{channel} -> {shares} of {a['frames']} loaded frames (auto)")
            else:
                parts.append(f"{channel}: never loaded")
        print(f"  plates: {'; '.join(parts)}")
    if solution is not None:
        muscles = extra["muscles"]
        print(
            f"  muscle activations: {muscles['muscles']} muscles balance {len(muscles['balanced_coordinates'])} "
            f"coordinates on {muscles['frames_balanced']} of {muscles['frames']} frames"
        )
    for role, path in files.items():
        print(f"  {role:20s} {path}")
