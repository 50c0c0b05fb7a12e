"""Validation of marker IK and static scaling against OpenSim 4.6 (the oracle; needs ``opensim``).

`validate_ik` runs, on whatever is present under a data root, our IK and OpenSim's ``InverseKinematicsTool``
(run fresh, same model, markers, weights, coordinate tasks and frames) and returns the figures of the IK check:

- ``ik_rmse_deg_same_minimum`` / ``ik_rmse_m_same_minimum``: the same over the frames where the two objectives
  agree within 1 % (both found the same minimum); ``frames_opensim_objective_1pct_higher`` and
  ``frames_our_objective_1pct_higher`` count the others (one solver in a worse local minimum);
- ``ik_rmse_deg`` / ``ik_rmse_m``: the worst per-coordinate RMSE over all frames between the two solutions,
  over rotational / translational coordinates that some tracked marker moves (a coordinate no marker depends
  on is undetermined: OpenSim leaves it wherever its optimizer drifted; those are listed, not scored);
- ``ik_marker_rmse_m`` / ``opensim_marker_rmse_m``: marker RMS error over every visible (frame, marker)
  sample of the tracked markers, both computed with the same forward kinematics;
- ``ik_speedup_vs_opensim``: OpenSim's ``run()`` wall time over ours, both reading the same TRC file and
  writing a .mot (per case also ``solve_speedup_vs_opensim``: over our solve alone);
- ``scale_factor_max_rel_err``: the worst relative difference between our ScaleTool-measurement factors from
  each Fukuchi runner's static C3D and the runner's shipped ScaleSet;
- ``fukuchi_ik_rmse_deg`` / ``fukuchi_ik_rmse_m``: the Fukuchi source's own processing chain reproduced from the
  raw C3D (`biomotion.data.fukuchi_chain`) against its shipped ``ik/T35/*_ik_simple.mot``, worst coordinate over
  the runners present;
- ``bvh_*``: every Bandai-Namco BVH clip retargeted onto Rajagopal 2016 (`biomotion.validation.bvh`).

Per case the detail holds every coordinate's RMSE and, for coordinates over the bar, how many frames OpenSim's
own objective is at least 1 % above ours there (OpenSim stopping short or in another local minimum).

OpenSim runs to ``ORACLE_ACCURACY`` rather than the setups' ``accuracy`` (1e-5 in every setup here): the check's
comparison is between two solutions of the same IK problem, and at 1e-5 OpenSim's optimizer stops before the
optimum where the objective is shallow. The speed figure times OpenSim's run at the setup's own accuracy (how it
is used), a second run beside the converged one. Measured on OpenCap Subject4 walking1 with `opensim_ik` at each
accuracy against the same `solve_ik` solution (OpenSim's
accuracy 1e-5 / 1e-7 / 1e-9): worst coordinate RMSE 7.6 / 0.17 / 0.002 deg (pronation-supination, which only the
wrist markers' small offsets pin down), OpenSim's mean objective 2.7 % / 0.03 % / 0.0003 % above ours, its run
7 / 13 / 17 s.
"""

from __future__ import annotations

import contextlib
import math
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from biomotion.body.model import BodyModel
from biomotion.body.scaling.osim_file import write_scaled_osim
from biomotion.data.fukuchi_chain import validate_fukuchi_chain
from biomotion.data.sources import OPENCAP_MODEL_FILE
from biomotion.ik.markers import IKResult, evaluate_ik, solve_ik
from biomotion.ik.scaling import body_scale_factors, scale_static
from biomotion.io.c3d import read_c3d_markers
from biomotion.io.mot import read_motion, write_motion
from biomotion.io.osim import read_scale_set
from biomotion.io.setup import CoordinateTask, read_ik_setup, read_scale_setup
from biomotion.io.trc import read_trc, write_trc
from biomotion.motion import Markers, Motion, is_translation
from biomotion.validation.bvh import BANDAI, RAJAGOPAL_MODEL, validate_bvh

GAIT = "opensim-models/Pipelines/Gait2392_Simbody"
OPENCAP = "opencap"
FUKUCHI = "fukuchi-running"
RAJAGOPAL = "opensim-models/Pipelines/Rajagopal"
OPENCAP_TRIALS = ("walking1", "DJ1", "squats1")
MARKER_FILTER_HZ = 10.0  # the Fukuchi processing chain's marker low-pass (fukuchi-running/SOURCE.md)
DEG_BAR, M_BAR = 2.0, 0.01
ORACLE_ACCURACY = 1e-8  # OpenSim's IK run to convergence (module docstring)


@dataclass(frozen=True)
class OpenSimIK:
    motion: Motion
    seconds: float


@contextlib.contextmanager
def quiet_stdout():
    """Silence what the C++ library prints on the process's stdout (OpenSim's tools print a model summary)."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 1)
            yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def opensim_ik(
    model_path: str | Path,
    markers: Markers | Path,
    *,
    weights: Mapping[str, float],
    coordinate_tasks: Sequence[CoordinateTask] = (),
    time_range: tuple[float, float] | None = None,
    accuracy: float | None = None,
) -> OpenSimIK:
    """OpenSim's InverseKinematicsTool on ``markers`` (a TRC file, or markers written to a temporary one) with
    these tasks, at ``accuracy`` (OpenSim's default 1e-5 when None), timed around ``run()``; the motion comes
    back in SI units. OpenSim converts only coordinates of
    motion type Rotational to degrees: coupled angles (``knee_angle_r_beta``) are written in radians and read
    back as such here."""
    from biomotion.settings import opensim_oracle

    opensim = opensim_oracle()

    opensim.Logger.setLevelString("error")
    model = opensim.Model(str(model_path))
    coordinates = model.getCoordinateSet()
    coupled = {
        coordinates.get(i).getName()
        for i in range(coordinates.getSize())
        if coordinates.get(i).getMotionType() == opensim.Coordinate.Coupled
    }
    with tempfile.TemporaryDirectory(prefix="biomotion-ik-") as folder:
        if isinstance(markers, Markers):
            trc, times = write_trc(Path(folder) / "markers.trc", markers), markers.times
        else:
            trc, times = Path(markers), read_trc(markers).times
        tool = opensim.InverseKinematicsTool()
        tool.setModel(model)
        tasks = tool.getIKTaskSet()
        for name, weight in weights.items():
            task = opensim.IKMarkerTask()
            task.setName(name)
            task.setWeight(float(weight))
            task.setApply(True)
            tasks.cloneAndAppend(task)
        for coordinate in coordinate_tasks:
            task = opensim.IKCoordinateTask()
            task.setName(coordinate.name)
            task.setWeight(coordinate.weight)
            task.setApply(True)
            if coordinate.value_type == "manual_value":
                task.setValueType(opensim.IKCoordinateTask.ManualValue)
                task.setValue(coordinate.value)
            elif coordinate.value_type == "default_value":
                task.setValueType(opensim.IKCoordinateTask.DefaultValue)
            else:
                raise ValueError("coordinate tasks from a file are not supported by this oracle")
            tasks.cloneAndAppend(task)
        tool.set_marker_file(str(trc))
        start, end = time_range if time_range is not None else (times[0], times[-1])
        tool.setStartTime(max(float(start) - 1e-9, float(times[0])))  # OpenSim refuses a start before the data
        tool.setEndTime(min(float(end) + 1e-9, float(times[-1])))
        tool.set_report_errors(False)
        if accuracy is not None:
            tool.set_accuracy(accuracy)
        out = Path(folder) / "ik.mot"
        tool.setOutputMotionFileName(str(out))
        tool.setResultsDir(folder)
        with quiet_stdout():
            began = time.perf_counter()
            tool.run()
            seconds = time.perf_counter() - began
        motion = read_motion(out)
    values = motion.values.copy()
    for c, name in enumerate(motion.names):
        if name in coupled and not is_translation(name):
            values[:, c] = np.rad2deg(values[:, c])  # undo the reader's degrees-to-radians conversion
    return OpenSimIK(motion.with_values(values), seconds)


def compare(
    model: BodyModel,
    markers: Markers,
    ours: IKResult,
    reference: Motion,
    *,
    weights: Mapping[str, float],
    coordinate_tasks: Sequence[CoordinateTask] = (),
) -> dict:
    """Per-coordinate RMSE between our solution and ``reference`` on our frames, marker RMSE of both."""
    theirs = evaluate_ik(
        model,
        markers.slice(ours.motion.times[0], ours.motion.times[-1]),
        reference,
        weights=weights,
        coordinate_tasks=coordinate_tasks,
    )
    ref = reference.select(model.coordinate_names)
    values = np.stack([np.interp(ours.motion.times, ref.times, ref.values[:, c]) for c in range(model.n_q)], 1)
    difference = ours.motion.values - values
    rmse = np.sqrt(np.mean(difference**2, axis=0))
    worse = theirs.cost > ours.cost * 1.01
    same = ~worse & ~(ours.cost > theirs.cost * 1.01)
    rmse_same = np.sqrt(np.mean(difference[same] ** 2, axis=0)) if same.any() else np.zeros(model.n_q)
    moved = _coordinates_moved_by(model, ours.marker_names)
    dependent = {model.coordinate_names[c.dependent] for c in model.couplers}
    per, over, unscored = {}, {}, []
    rotational_worst, translational_worst = 0.0, 0.0
    rotational_same, translational_same = 0.0, 0.0
    for c, name in enumerate(model.coordinate_names):
        translational = model.motion_types[c] == "translational"
        value = float(rmse[c]) if translational else float(np.degrees(rmse[c]))
        value_same = float(rmse_same[c]) if translational else float(np.degrees(rmse_same[c]))
        per[name] = round(value, 5)
        if bool(model.locked[c]) or name in dependent:
            continue
        if name not in moved:
            unscored.append(name)
            continue
        if translational:
            translational_worst = max(translational_worst, value)
            translational_same = max(translational_same, value_same)
        else:
            rotational_worst = max(rotational_worst, value)
            rotational_same = max(rotational_same, value_same)
        if value > (M_BAR if translational else DEG_BAR):
            over[name] = {
                "rmse": round(value, 4),
                "frames": int(difference.shape[0]),
                "frames_opensim_objective_1pct_higher": int(worse.sum()),
            }
    return {
        "frames": int(ours.motion.n_frames),
        "ik_rmse_deg": round(rotational_worst, 4),
        "ik_rmse_m": round(translational_worst, 6),
        # over the frames where both objectives agree within 1 %: the two solvers found the same minimum
        "ik_rmse_deg_same_minimum": round(rotational_same, 4),
        "ik_rmse_m_same_minimum": round(translational_same, 6),
        "frames_same_minimum": int(same.sum()),
        "frames_opensim_objective_1pct_higher": int(worse.sum()),
        "frames_our_objective_1pct_higher": int((ours.cost > theirs.cost * 1.01).sum()),
        "ik_marker_rmse_m": round(ours.rmse, 6),
        "opensim_marker_rmse_m": round(theirs.rmse, 6),
        "objective_mean": float(ours.cost.mean()),
        "opensim_objective_mean": float(theirs.cost.mean()),
        "frames_opensim_objective_lower": int((theirs.cost < ours.cost * (1 - 1e-6)).sum()),
        "coordinate_rmse": per,
        "over_bar": over,
        "no_marker_moves": unscored,
        "_squared_errors": (
            float(np.nansum(ours.errors**2)),
            float(np.nansum(theirs.errors**2)),
            int(np.isfinite(ours.errors).sum()),
        ),
    }


def _coordinates_moved_by(model: BodyModel, marker_names: Sequence[str]) -> set[str]:
    joint_of_child = {j.child: j for j in model.joints}
    moved: set[str] = set()
    for name in marker_names:
        body = int(model.marker_bodies[model.marker_index(name)])
        while body >= 0:
            joint = joint_of_child[body]
            moved.update(model.coordinate_names[c] for c in joint.coordinates)
            body = joint.parent
    for coupler in model.couplers:  # an independent coordinate moves what its dependent moves
        if model.coordinate_names[coupler.dependent] in moved:
            moved.add(model.coordinate_names[coupler.independent])
    return moved


def run_case(
    model_path: Path,
    markers: Markers,
    *,
    weights: Mapping[str, float],
    coordinate_tasks: Sequence[CoordinateTask] = (),
    time_range: tuple[float, float] | None = None,
    repeats: int = 1,
    accuracy: float = 1e-5,
) -> dict:
    """Our IK and OpenSim's on the same inputs, compared, with timings. Both sides read the same TRC file (ours
    parses the rows of the setup's window only, `read_trc`'s ``time_range``) and write a .mot; ours is the best
    of ``repeats`` runs (and, apart, its solve alone), OpenSim's ``run()`` is timed once at ``accuracy`` (the
    setup's); the agreement is with OpenSim run to ``ORACLE_ACCURACY``."""
    model = BodyModel.from_osim(model_path)
    with tempfile.TemporaryDirectory(prefix="biomotion-case-") as folder:
        trc = write_trc(Path(folder) / "markers.trc", markers)
        seconds = solve_seconds = math.inf
        for _ in range(repeats):
            # a fresh model each run, loaded outside the clock as OpenSim's is: the structures built from it (the
            # kinematic tree, cached on the model) count, as OpenSim's initSystem inside run() does
            model = BodyModel.from_osim(model_path)
            began = time.perf_counter()
            trial = read_trc(trc, time_range)
            solving = time.perf_counter()
            ours = solve_ik(model, trial, weights=weights, coordinate_tasks=coordinate_tasks, time_range=time_range)
            solve_seconds = min(solve_seconds, time.perf_counter() - solving)
            write_motion(Path(folder) / "ours.mot", ours.motion)
            seconds = min(seconds, time.perf_counter() - began)
        timed = opensim_ik(
            model_path,
            trc,
            weights=weights,
            coordinate_tasks=coordinate_tasks,
            time_range=time_range,
            accuracy=accuracy,
        )
        reference = opensim_ik(
            model_path,
            trc,
            weights=weights,
            coordinate_tasks=coordinate_tasks,
            time_range=time_range,
            accuracy=ORACLE_ACCURACY,
        )
    figures = compare(model, markers, ours, reference.motion, weights=weights, coordinate_tasks=coordinate_tasks)
    figures.update(
        coordinates=model.n_q,
        seconds=round(seconds, 3),
        solve_seconds=round(solve_seconds, 3),
        opensim_seconds=round(timed.seconds, 3),
        opensim_accuracy=accuracy,
        opensim_converged_seconds=round(reference.seconds, 3),
        ik_speedup_vs_opensim=round(timed.seconds / seconds, 1),
        solve_speedup_vs_opensim=round(timed.seconds / solve_seconds, 1),
    )
    return figures


# --- the data sets -------------------------------------------------------------------------------------------------


def gait2392_case(root: Path, repeats: int = 1) -> dict:
    """The gait2392 subject01 walk with its shipped IK setup (0.5-2.5 s, coordinate tasks)."""
    setup = read_ik_setup(root / GAIT / "subject01_Setup_IK.xml")
    return run_case(
        root / GAIT / "OutputReference" / "subject01_simbody.osim",
        read_trc(setup.file("marker_file")),
        weights=setup.marker_weights,
        coordinate_tasks=setup.coordinate_tasks,
        time_range=setup.time_range,
        repeats=repeats,
        accuracy=setup.accuracy,
    )


def opencap_subjects(root: Path) -> list[str]:
    """The OpenCap (AddBiomechanics) subjects under ``root``: folders of ``opencap/`` with markers and the scaled
    model (Subject4 here; a data root of new subjects may hold others in the same layout)."""
    return sorted(
        p.name for p in (root / OPENCAP).glob("*") if (p / "MarkerData").is_dir() and (p / OPENCAP_MODEL_FILE).is_file()
    )


def opencap_case(root: Path, trial: str, repeats: int = 1, subject: str = "Subject4") -> dict:
    """An OpenCap subject's trial, whole (its setup names no time range), on the model its IK setups name."""
    base = root / OPENCAP / subject
    setup = read_ik_setup(base / "IK" / f"{trial}_ik_setup.xml")
    return run_case(
        base / OPENCAP_MODEL_FILE,
        read_trc(base / "MarkerData" / f"{trial}.trc"),
        weights=setup.marker_weights,
        coordinate_tasks=setup.coordinate_tasks,
        time_range=setup.time_range,
        repeats=repeats,
        accuracy=setup.accuracy,
    )


def fukuchi_markers(path: Path) -> Markers:
    """A Fukuchi C3D's markers as the source's processing chain had them: zeros as gaps, 10 Hz low-pass."""
    return read_c3d_markers(path, zero_is_missing=True).filtered(MARKER_FILTER_HZ)


def fukuchi_case(root: Path, runner: str, repeats: int = 1) -> dict:
    """A runner's 3.5 m/s trial (C3D markers) with its IK setup's weights and window, on the runner's scaled
    simple model (the setup names the complex model, which is not shipped)."""
    base = root / FUKUCHI
    setup = read_ik_setup(base / runner / f"{runner}_T35_ikSetup.xml")
    return run_case(
        base / runner / f"{runner}_simple.osim",
        fukuchi_markers(base / "c3d" / f"{runner}runT35.c3d"),
        weights=setup.marker_weights,
        coordinate_tasks=setup.coordinate_tasks,
        time_range=setup.time_range,
        repeats=repeats,
        accuracy=setup.accuracy,
    )


RAJAGOPAL_SCALE_STEPS = ("scale_setup_walk_scaleOnly.xml", "scale_setup_walk.xml")


def scale_rajagopal_walk(root: Path, folder: Path) -> Path:
    """The Rajagopal pipeline's subject model, ``<folder>/Scale/subject_scaled_walk.osim``, made by OpenSim's
    ScaleTool with its two walk setups, as the pipeline's SOURCE.md runs them (their relative paths need
    ``Scale/``, ``ExpData/`` and ``generic_unscaled.osim`` side by side, so those are copied into ``folder``)."""
    from biomotion.settings import opensim_oracle

    opensim = opensim_oracle()

    opensim.Logger.setLevelString("error")
    shutil.copytree(root / RAJAGOPAL / "Scale", folder / "Scale")
    shutil.copytree(root / RAJAGOPAL / "ExpData", folder / "ExpData")
    shutil.copy(root / "opensim-models/Models/Rajagopal/Rajagopal2016.osim", folder / "generic_unscaled.osim")
    for step in RAJAGOPAL_SCALE_STEPS:
        with quiet_stdout():
            done = opensim.ScaleTool(str(folder / "Scale" / step)).run()
        if not done:
            raise RuntimeError(f"OpenSim's ScaleTool failed on {step}")
    return folder / "Scale" / "subject_scaled_walk.osim"


def rajagopal_case(root: Path, repeats: int = 1) -> dict:
    """The Rajagopal walk on the model both IKs use: the pipeline's own scaling (`scale_rajagopal_walk`)."""
    with tempfile.TemporaryDirectory(prefix="biomotion-rajagopal-") as folder:
        model = scale_rajagopal_walk(root, Path(folder))
        setup = read_ik_setup(root / RAJAGOPAL / "IK" / "ik_setup_walk.xml")
        return run_case(
            model,
            read_trc(setup.file("marker_file")),
            weights=setup.marker_weights,
            coordinate_tasks=setup.coordinate_tasks,
            time_range=setup.time_range,
            repeats=repeats,
            accuracy=setup.accuracy,
        )


def scaling_errors(root: Path, runners: Sequence[str]) -> dict:
    """Relative error of our measurement factors against each runner's shipped ScaleSet."""
    base = root / FUKUCHI
    generic = BodyModel.from_osim(base / "generic-models" / "Denton2023_LowerLimb_Fukuchi2017.osim")
    out = {}
    for runner in runners:
        setup = read_scale_setup(base / runner / f"{runner}_scaleSetup_simple.xml")
        factors, _ = body_scale_factors(generic, fukuchi_markers(base / "c3d" / f"{runner}static.c3d"), setup)
        shipped = {s.segment: s.scales for s in read_scale_set(base / runner / f"{runner}_scaleSet_simple.xml")}
        out[runner] = max(abs(factors[b][i] / shipped[b][i] - 1) for b in factors if b in shipped for i in range(3))
    return out


def scaled_model_loads(root: Path, runner: str) -> dict:
    """Scale and place markers for one runner, write the .osim and load it in OpenSim."""
    from biomotion.settings import opensim_oracle

    opensim = opensim_oracle()

    base = root / FUKUCHI
    generic_path = base / "generic-models" / "Denton2023_LowerLimb_Fukuchi2017.osim"
    setup = read_scale_setup(base / runner / f"{runner}_scaleSetup_simple.xml")
    began = time.perf_counter()
    result = scale_static(
        BodyModel.from_osim(generic_path), fukuchi_markers(base / "c3d" / f"{runner}static.c3d"), setup
    )
    seconds = time.perf_counter() - began
    with tempfile.TemporaryDirectory(prefix="biomotion-scale-") as folder:
        path = write_scaled_osim(generic_path, Path(folder) / f"{runner}_scaled.osim", result)
        model = opensim.Model(str(path))
        state = model.initSystem()
        mass = model.getTotalMass(state)
    return {
        "runner": runner,
        "loads_in_opensim": True,
        "total_mass_kg": round(mass, 6),
        "setup_mass_kg": setup.mass,
        "seconds": round(seconds, 3),
        "placement_marker_rms_m": round(result.placement.ik.rmse, 5) if result.placement else None,
    }


def validate_ik(
    data_root: str | Path,
    *,
    opencap_trials: Sequence[str] = OPENCAP_TRIALS,
    runners: int = 2,
    rajagopal: bool = True,
    bvh: bool = True,
    progress: bool = False,
) -> dict:
    """Run every IK and scaling check whose data is under ``data_root``; see the module docstring.

    ``opencap_trials`` picks the trials of each OpenCap subject (``("all",)`` for every trial with markers and an
    IK setup); ``runners`` caps the Fukuchi runners whose 3.5 m/s trial is solved (scaling is checked on every
    runner present); ``bvh`` retargets every Bandai-Namco clip present (`biomotion.validation.bvh`).
    """
    root = Path(data_root)
    cases: dict[str, dict] = {}
    skipped: list[str] = []
    if (root / GAIT / "subject01_Setup_IK.xml").exists():
        cases["gait2392_subject01_walk1"] = gait2392_case(root)
    else:
        skipped.append(f"{GAIT}: absent")
    subjects = opencap_subjects(root)
    for subject in subjects:
        folder = root / OPENCAP / subject
        available = sorted(
            p.stem for p in (folder / "MarkerData").glob("*.trc") if (folder / "IK" / f"{p.stem}_ik_setup.xml").exists()
        )
        wanted = available if tuple(opencap_trials) == ("all",) else [t for t in opencap_trials if t in available]
        skipped += [f"{OPENCAP}/{subject}/{t}: absent" for t in opencap_trials if t != "all" and t not in available]
        for trial in wanted:
            cases[f"opencap_{subject.lower()}_{trial}"] = opencap_case(root, trial, subject=subject)
    if not subjects:
        skipped.append(f"{OPENCAP}: no subject with MarkerData/ and {OPENCAP_MODEL_FILE}")
    trials = sorted((root / FUKUCHI / "c3d").glob("*runT35.c3d")) if (root / FUKUCHI / "c3d").is_dir() else []
    fukuchi_runners = [
        r
        for r in (p.name.removesuffix("runT35.c3d") for p in trials)
        if (root / FUKUCHI / r / f"{r}_simple.osim").exists() and (root / FUKUCHI / r / f"{r}_T35_ikSetup.xml").exists()
    ]
    if not fukuchi_runners:
        skipped.append(f"{FUKUCHI}: no runner with a 3.5 m/s C3D and a scaled model")
    for runner in fukuchi_runners[:runners]:
        cases[f"fukuchi_{runner}_T35"] = fukuchi_case(root, runner)
    skipped += [f"{FUKUCHI}/{r} T35 IK: over the runners cap ({runners})" for r in fukuchi_runners[runners:]]
    if rajagopal and (root / RAJAGOPAL / "IK" / "ik_setup_walk.xml").exists():
        try:
            cases["rajagopal_walk"] = rajagopal_case(root)
        except RuntimeError as error:
            skipped.append(f"{RAJAGOPAL}: {error}")
    elif rajagopal:
        skipped.append(f"{RAJAGOPAL}: absent")

    scale_runners = (
        sorted(
            p.name
            for p in (root / FUKUCHI).iterdir()
            if (p / f"{p.name}_scaleSetup_simple.xml").exists()
            and (root / FUKUCHI / "c3d" / f"{p.name}static.c3d").exists()
        )
        if (root / FUKUCHI).is_dir()
        else []
    )
    scaling = {}
    if scale_runners:
        errors = scaling_errors(root, scale_runners)
        scaling = {
            "runners": len(errors),
            "scale_factor_max_rel_err": max(errors.values()),
            "per_runner": {r: round(e, 7) for r, e in errors.items()},
            "scaled_model": scaled_model_loads(root, scale_runners[0]),
        }
    else:
        skipped.append(f"{FUKUCHI}: no runner with a static C3D and a scale setup")

    chain = validate_fukuchi_chain(root) if (root / FUKUCHI / "c3d").is_dir() else {}
    skipped += chain.pop("skipped", [])
    retargeting = validate_bvh(root, progress=progress) if bvh else {}
    if bvh and not retargeting:
        skipped.append(f"{BANDAI}: no clip (or no {RAJAGOPAL_MODEL}) under the data root")

    summary: dict = {"skipped": skipped}
    if cases:
        ours_sq = sum(c["_squared_errors"][0] for c in cases.values())
        theirs_sq = sum(c["_squared_errors"][1] for c in cases.values())
        samples = sum(c["_squared_errors"][2] for c in cases.values())
        summary.update(
            ik_rmse_deg=max(c["ik_rmse_deg"] for c in cases.values()),
            ik_rmse_m=max(c["ik_rmse_m"] for c in cases.values()),
            ik_rmse_deg_same_minimum=max(c["ik_rmse_deg_same_minimum"] for c in cases.values()),
            ik_rmse_m_same_minimum=max(c["ik_rmse_m_same_minimum"] for c in cases.values()),
            frames_opensim_objective_1pct_higher=sum(c["frames_opensim_objective_1pct_higher"] for c in cases.values()),
            frames_our_objective_1pct_higher=sum(c["frames_our_objective_1pct_higher"] for c in cases.values()),
            ik_frames=sum(c["frames"] for c in cases.values()),
            ik_marker_rmse_m=round(float(np.sqrt(ours_sq / samples)), 6),
            opensim_marker_rmse_m=round(float(np.sqrt(theirs_sq / samples)), 6),
            ik_speedup_vs_opensim=round(
                sum(c["opensim_seconds"] for c in cases.values()) / sum(c["seconds"] for c in cases.values()), 1
            ),
        )
        for case in cases.values():
            del case["_squared_errors"]
    if scaling:
        summary["scale_factor_max_rel_err"] = scaling["scale_factor_max_rel_err"]
    summary.update(retargeting)
    summary.update(chain)
    summary["cases"] = cases
    summary["scaling"] = scaling
    return summary
