"""A whole study in one call: every subject scaled on its static trial, every trial through the lab chain, each
written as OpenSim files, judged, and summarised in one quality report (``biomotion batch``, ``bm.batch``).

Per subject (`run_subject`): the generic model scaled to the static trial by its OpenSim ScaleTool setup
(`biomotion.ik.scaling.scale_static`: measurements, mass, marker placement), written as ``<subject>/<subject>.osim``
with its ScaleSet and static pose; the static trial is judged by `biomotion.analysis.check.static_quality`. Per
trial (`run_trial`): markers (marker map applied, low-passed over the whole capture, cut to the IK setup's or the
config's time range) → `biomotion.analysis.trial.analyze_trial` in memory: IK, inverse dynamics with the plates
assigned to the feet (or the override), or the learned / inferred ground reaction without plates, static
optimization when muscle paths fit the model, COM/ZMP → `biomotion.analysis.check.trial_quality` → files in
``<subject>/<trial>/``: ``<trial>_ik.mot``, ``coordinates_filtered.mot``, ``torques.sto``, ground reactions ``.mot``
with their ExternalLoads ``.xml``, ``com_zmp.sto``, ``activations.sto``, the model ``<subject>.osim`` (so the folder
opens in the OpenSim GUI as it is), ``summary.json``, ``outcome.json`` and ``viewer.html``.

Execution: tasks are pure functions of files (`SubjectTask`, `TrialTask` are picklable paths and settings), run in
this process (``workers=1``), on a local process pool (``executor="local"``, default one worker per core), or as Ray
tasks (``executor="ray"``, ``address`` of a running cluster or a local instance). Every worker runs torch on one
thread, so a trial's numbers do not depend on where it ran: Ray's outputs equal the pool's. A trial that fails
(bad file, too few markers matched, plates not covering the motion ...) is recorded with its error and the batch
goes on. Each task's folder appears whole or not at all (written beside it, then renamed).

Resume: a task's key is the SHA-256 of its input files, its settings and biomotion's version; with ``resume`` a
task whose folder holds an outcome with the same key is not run again (failed trials are re-run unless their
error was in their input, which would fail again).

Outputs at the top of ``out``: ``report.html`` (`biomotion.viz.report`, one self-contained file), ``record.json``
(versions, settings, input SHA-256, timings, the outcome of every task) and ``plotly.min.js`` (shared by the trial
viewers, which load it from there).
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
import shutil
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from biomotion.analysis.check import failure
from biomotion.analysis.study import (
    Study,
    StudySettings,
    SubjectSpec,
    TrialSpec,
    file_sha256,
    load_study,
    plate_bodies,
    settings_hash,
)
from biomotion.errors import BiomotionError, ConfigError

EXECUTORS = ("local", "ray")
RECORD = "record.json"
REPORT = "report.html"
OUTCOME = "outcome.json"
SCALING = "scaling.json"
PLOTLY = "plotly.min.js"
CYCLE_POINTS = 101
#: sagittal coordinates the report plots, when the model has them
PLOTTED = ("hip_flexion", "knee_angle", "ankle_angle")


def _version() -> str:
    from biomotion import __version__

    return __version__


# --- tasks ------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SubjectTask:
    """Scale one subject: its spec, the study's settings, its output folder and resume key."""

    subject: SubjectSpec
    settings: StudySettings
    out: Path
    key: str


@dataclass(frozen=True)
class TrialTask:
    """Analyse one trial on its subject's model (``model_file``, the scaled ``.osim``): output folder, resume key,
    and the ground-force estimator for learned forces (None: none given)."""

    subject: SubjectSpec
    trial: TrialSpec
    settings: StudySettings
    model_file: Path
    out: Path
    key: str
    estimator: Any = None


@dataclass
class Outcome:
    """What a task did, as JSON-able values (``outcome.json``): ``kind`` ``static`` or ``trial``, ``status``
    ``done`` or ``error`` (``error`` and ``error_kind``: ``input`` for a `BiomotionError`, ``bug`` otherwise),
    the verdict (`biomotion.analysis.check.Verdict.to_dict`), figures for the report, curves for its plots
    (cycle-normalised means), files written (relative to the output folder), seconds per step."""

    subject: str
    name: str
    kind: str
    key: str
    status: str = "done"
    error: str | None = None
    error_kind: str | None = None
    verdict: dict[str, Any] = field(default_factory=dict)
    figures: dict[str, Any] = field(default_factory=dict)
    curves: dict[str, Any] = field(default_factory=dict)
    files: dict[str, str] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)
    skipped: bool = False

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Outcome:
        known = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in data.items() if k in known})


def _setup_worker() -> None:
    """One torch thread per worker process (the batch parallelises over trials), warnings not printed."""
    import warnings

    import torch

    torch.set_num_threads(1)
    warnings.simplefilter("ignore")


def _error_outcome(subject: str, name: str, kind: str, key: str, error: BaseException, began: float) -> Outcome:
    input_error = isinstance(error, BiomotionError)
    message = str(error) if input_error else f"{type(error).__name__}: {error}"
    outcome = Outcome(
        subject, name, kind, key, status="error", error=message, error_kind="input" if input_error else "bug"
    )
    outcome.verdict = failure(message).to_dict()
    if not input_error:
        outcome.figures["traceback"] = traceback.format_exc()
    outcome.seconds["total"] = round(time.perf_counter() - began, 3)
    return outcome


class _Scratch:
    """A folder written beside ``final`` and renamed onto it when done (an earlier one is replaced)."""

    def __init__(self, final: Path) -> None:
        self.final = final
        final.parent.mkdir(parents=True, exist_ok=True)
        self.path = Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".partial", dir=final.parent))

    def commit(self) -> None:
        if self.final.exists():
            shutil.rmtree(self.final)
        os.replace(self.path, self.final)

    def discard(self) -> None:
        shutil.rmtree(self.path, ignore_errors=True)


def _write_json(path: Path, data: Any) -> None:
    from biomotion.io.atomic import atomic_write

    with atomic_write(path) as handle:
        json.dump(data, handle, indent=1, default=_json_default, allow_nan=False)


def _json_default(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON-able: {type(value).__name__}")


def _clean(value: Any) -> Any:
    """Non-finite floats to None, numpy to Python: what JSON can hold."""
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, np.ndarray):
        return _clean(value.tolist())
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def _locked(model, names: Iterable[str]):
    """``model`` with the named coordinates it has locked at 0 (welds)."""
    import torch

    index = [model.coordinate_index(n) for n in names if n in model.coordinate_names]
    if not index:
        return model
    locked, defaults = model.locked.clone(), model.defaults.clone()
    locked[torch.tensor(index)] = True
    defaults[torch.tensor(index)] = 0.0
    return dataclasses.replace(model, locked=locked, defaults=defaults)


def _read_markers(path: Path, marker_map: dict[str, str]):
    """(markers in m with gaps as NaN, plates or None) of a ``.c3d`` or ``.trc`` file, marker map applied."""
    from biomotion.io.c3d import read_c3d
    from biomotion.io.trc import read_trc

    if path.suffix.lower() == ".c3d":
        trial = read_c3d(path, zero_is_missing=True)
        markers, plates = trial.markers, trial.forces
    else:
        markers, plates = read_trc(path), None
    if marker_map:
        markers = markers.rename(marker_map)
        if len(set(markers.names)) != len(markers.names):
            raise ConfigError(f"{path}: the marker map gives two markers the same name")
    return markers, plates


# --- the subject step -----------------------------------------------------------------------------------------------


def run_subject(task: SubjectTask) -> Outcome:
    """Scale one subject (module docstring); never raises: errors become the outcome."""
    _setup_worker()
    began = time.perf_counter()
    subject = task.subject
    name = subject.static.stem if subject.static is not None else "static"
    scratch = _Scratch(task.out)
    try:
        outcome = _scale(task, scratch.path, name, began)
        _write_json(scratch.path / SCALING, _clean(outcome.as_dict()))
        scratch.commit()
        return outcome
    except Exception as error:  # noqa: BLE001 - a bad subject is reported and the batch goes on
        scratch.discard()
        outcome = _error_outcome(subject.name, name, "static", task.key, error, began)
        task.out.mkdir(parents=True, exist_ok=True)
        _write_json(task.out / SCALING, _clean(outcome.as_dict()))
        return outcome


def _scale(task: SubjectTask, folder: Path, name: str, began: float) -> Outcome:
    from biomotion.analysis.check import match_markers, static_quality
    from biomotion.body.model import BodyModel
    from biomotion.body.scaling.osim_file import write_scale_set, write_scaled_osim
    from biomotion.ik.markers import solve_ik
    from biomotion.ik.scaling import average_frames, scale_static
    from biomotion.io.mot import write_motion
    from biomotion.io.setup import read_scale_setup

    subject, settings = task.subject, task.settings
    generic = _locked(BodyModel.from_osim(subject.model), settings.locked)
    outcome = Outcome(subject.name, name, "static", task.key)
    osim = folder / f"{subject.name}.osim"
    figures: dict[str, Any] = {"generic_model": str(subject.model)}
    markers = None
    if subject.static is not None:
        markers, _ = _read_markers(subject.static, dict(settings.marker_map))
        outcome.seconds["read"] = round(time.perf_counter() - began, 3)
    if subject.scale_setup is not None:
        setup = read_scale_setup(subject.scale_setup)
        result = scale_static(generic, markers, setup, mass=subject.mass)
        scaled = result.model
        write_scaled_osim(subject.model, osim, result, name=subject.name)
        write_scale_set(folder / f"{subject.name}_scale_set.xml", result.factors)
        figures["scale_factors"] = {body: [float(v) for v in f] for body, f in result.factors.items()}
        figures["measurements"] = {k: float(v) for k, v in result.measurements.items()}
        placement = result.placement
        if placement is not None:
            write_motion(folder / f"{subject.name}_static_pose.mot", placement.pose)
            ik = placement.ik
            figures["markers_placed"] = len(placement.moved)
            landmarks = [m.name for m in generic.spec.markers if m.fixed]
            verdict = static_quality(ik.errors, ik.marker_names, landmarks)
            figures["static_marker_rms_m"] = ik.rmse
            figures["static_marker_max_m"] = float(np.nanmax(ik.errors)) if np.isfinite(ik.errors).any() else None
            outcome.verdict = verdict.to_dict()
        else:
            outcome.verdict = {"verdict": "ok", "frames": 0, "frames_flagged": 0, "reasons": []}
    else:
        scaled = generic
        shutil.copyfile(subject.model, osim)
        figures["scale_factors"] = None
        outcome.verdict = {"verdict": "ok", "frames": 0, "frames_flagged": 0, "reasons": []}
        if markers is not None:  # no scaling: the static pose's marker errors on the model as given
            match = match_markers(scaled, markers)
            if match.enough:
                ik = solve_ik(scaled, average_frames(markers))
                figures["static_marker_rms_m"] = ik.rmse
                outcome.verdict = static_quality(ik.errors, ik.marker_names, []).to_dict()
    figures["mass_kg"] = float(scaled.total_mass)
    figures["body_mass_kg"] = {b: float(m) for b, m in zip(scaled.body_names, scaled.masses.tolist())}
    figures["height_m"] = subject.height
    outcome.figures = figures
    outcome.files = {"model": osim.name}
    outcome.seconds["total"] = round(time.perf_counter() - began, 3)
    return outcome


# --- the trial step ---------------------------------------------------------------------------------------------


def run_trial(task: TrialTask) -> Outcome:
    """Analyse one trial (module docstring); never raises: errors become the outcome."""
    _setup_worker()
    began = time.perf_counter()
    scratch = _Scratch(task.out)
    try:
        outcome = _analyse(task, scratch.path, began)
        _write_json(scratch.path / OUTCOME, _clean(outcome.as_dict()))
        scratch.commit()
        return outcome
    except Exception as error:  # noqa: BLE001 - a bad trial is reported and the batch goes on
        scratch.discard()
        outcome = _error_outcome(task.subject.name, task.trial.name, "trial", task.key, error, began)
        if task.out.exists():
            shutil.rmtree(task.out)
        task.out.mkdir(parents=True)
        _write_json(task.out / OUTCOME, _clean(outcome.as_dict()))
        return outcome


def _forces_for(task: TrialTask, plates):
    """The trial's plates (read from its force file when it has one), with the plate override applied; None when
    there are none."""
    from biomotion.io.c3d import read_c3d_forces
    from biomotion.io.mot import read_ground_reaction

    trial = task.trial
    if trial.forces is not None:
        plates = (
            read_c3d_forces(trial.forces)
            if trial.forces.suffix.lower() == ".c3d"
            else read_ground_reaction(trial.forces)
        )
    if plates is None:
        return None
    overrides = plate_bodies(plates.names, task.settings.plates + trial.plates)
    if overrides:
        kept = [n for n in plates.names if overrides.get(n, "") is not None]
        if not kept:
            return None
        bodies = [overrides.get(n, b) for n, b in zip(plates.names, plates.bodies)]
        plates = plates.assign(bodies).select(kept)
    return plates


def _analyse(task: TrialTask, folder: Path, began: float) -> Outcome:
    from biomotion.analysis.activations import load_paths, write_activations
    from biomotion.analysis.chain import plate_assignment, summary, write_analysis
    from biomotion.analysis.check import match_markers, trial_quality
    from biomotion.analysis.trial import analyze_trial
    from biomotion.body.model import BodyModel
    from biomotion.ik.markers import tracked_markers
    from biomotion.io.mot import write_motion
    from biomotion.io.setup import read_ik_setup
    from biomotion.trial import Trial

    trial, settings = task.trial, task.settings
    outcome = Outcome(task.subject.name, trial.name, "trial", task.key)
    markers, plates = _read_markers(trial.markers, dict(settings.marker_map))
    plates = _forces_for(task, plates)
    setup = read_ik_setup(trial.setup) if trial.setup is not None else None
    model = _locked(BodyModel.from_osim(task.model_file), settings.locked)
    outcome.seconds["read"] = round(time.perf_counter() - began, 3)
    weights = dict(setup.marker_weights) if setup is not None else None
    match = match_markers(model, markers, weights)
    if not match.enough:
        raise ConfigError(f"{trial.markers}: {match.message()}")
    if settings.marker_filter_hz:
        markers = markers.filtered(settings.marker_filter_hz)  # over the whole capture, then cut
    window = trial.time_range or (setup.time_range if setup is not None else None)
    if window is not None:
        markers = markers.slice(*window)
        if markers.n_frames < 2:
            raise ConfigError(f"{trial.markers}: the time range {window} holds fewer than 2 frames")
    if setup is not None and setup.time_range is not None:
        setup = dataclasses.replace(setup, time_range=None)  # already cut
    forces: Any = None
    source = settings.forces
    if source == "measured" and plates is None:
        raise ConfigError(f"{trial.markers}: forces = 'measured' but the trial has no force plates")
    if source == "learned" and task.estimator is None:
        raise ConfigError("forces = 'learned' needs the learned ground-reaction model (none was given)")
    if source in ("measured", "auto") and plates is not None:
        forces = plates
    elif source in ("learned", "auto") and task.estimator is not None:
        forces = task.estimator
    paths, muscle_note = None, None
    muscles = task.subject.muscles or settings.muscles
    if muscles:
        candidate, label = load_paths(muscles)
        if tuple(candidate.coordinate_names) == tuple(model.coordinate_names):
            paths = candidate
        else:
            muscle_note = f"static optimization skipped: the muscle paths {label} are for another model's coordinates"
    else:
        muscle_note = "static optimization skipped: no muscle paths for this model (`muscles` in the config)"
    computing = time.perf_counter()

    def chain(ground: Any):
        # the plates ride along with measured or learned forces (kept for comparison), never with inferred ones
        return analyze_trial(
            Trial(markers=markers, forces=plates if ground is not None else None, source=trial.markers),
            model=model,
            forces=ground,
            setup=setup,
            marker_weights=weights,
            muscles=paths,
            muscle_model=task.model_file,
            cutoff_hz=settings.cutoff_hz,
        )

    try:
        result = chain(forces)
    except BiomotionError as error:
        if source != "auto" or forces is not task.estimator or forces is None:
            raise
        result = chain(None)  # auto: the learned model refused this motion; the inferred forces take it
        outcome.figures["learned_refused"] = str(error)
    outcome.seconds["chain"] = round(time.perf_counter() - computing, 3)
    dynamics = result.dynamics
    names = [model.marker_names[m] for m in tracked_markers(model, markers, weights)[0]]
    q = dynamics.motion.values
    assignment = {}
    if plates is not None:
        import torch

        assignment = plate_assignment(plates, model, torch.as_tensor(q, dtype=model.dtype), dynamics.motion.times)
    errors = result.fit.errors if result.fit is not None else None
    if errors is not None and errors.shape[0] != dynamics.motion.n_frames:
        errors = None
    verdict = trial_quality(
        dynamics,
        markers=markers,
        names=names,
        errors=errors,
        match=match,
        plates=plates if dynamics.measured is not None else None,
        assignment=assignment,
    )
    outcome.verdict = verdict.to_dict()
    figures = {**outcome.figures, **summary(dynamics)}
    figures["markers_tracked"] = len(names)
    figures["markers_missing"] = list(match.missing)
    figures["plates"] = assignment
    figures["torques_from"] = dynamics.torques_source
    figures["static_optimization"] = muscle_note or (
        f"{int(result.activations.converged.sum())}/{result.activations.converged.numel()} frames balanced"
        if result.activations is not None
        else None
    )
    outcome.figures = _clean(figures)
    outcome.curves = _curves(result)
    writing = time.perf_counter()
    files = write_analysis(
        dynamics,
        folder,
        extra_summary={"quality": verdict.to_dict(), "plates": _clean(assignment), "trial": trial.name},
    )
    if result.fit is not None:
        files["ik"] = write_motion(folder / f"{trial.name}_ik.mot", result.fit.motion)
    if result.activations is not None:
        files["activations"] = write_activations(folder / "activations.sto", dynamics, result.activations)
    model_copy = folder / task.model_file.name
    shutil.copyfile(task.model_file, model_copy)
    files["model"] = model_copy
    if settings.viewer:
        title = f"{task.subject.name} {trial.name}"
        files["viewer"] = _viewer(folder, files, model_copy, title, result.ground_reaction, assignment)
    outcome.files = {role: Path(path).name for role, path in files.items()}
    outcome.seconds["write"] = round(time.perf_counter() - writing, 3)
    outcome.seconds["total"] = round(time.perf_counter() - began, 3)
    outcome.figures["frames_per_s"] = round(dynamics.motion.n_frames / max(outcome.seconds["chain"], 1e-9), 1)
    return outcome


def _viewer(folder: Path, files: dict[str, Path], model: Path, title: str, loads, assignment: dict) -> Path:
    """The trial's viewer page, loading plotly.js from the batch folder (one copy for every trial). The ground
    reaction the torques used is drawn as one arrow set per foot, named with the plates it carries, so the plate
    assignment shows in the legend."""
    from biomotion.viz.viewer import read_activations, read_com_zmp, read_scene, write_viewer

    scene = read_scene(files["coordinates"], model=model)
    for side, foot in (("_r", "right foot"), ("_l", "left foot")):
        channels = [n for n, body in zip(loads.names, loads.bodies) if str(body).endswith(side)]
        if not channels:
            continue
        plates = [
            f"plate {name}" + (" (given)" if a.get("mode") == "given" else "")
            for name, a in assignment.items()
            if (a.get("mode") == "given" and str(a.get("body", "")).endswith(side))
            or (a.get("mode") == "auto" and a.get("right" if side == "_r" else "left", 0.0) > 0)
        ]
        label = f"GRF {foot}" + (f" ← {', '.join(plates)}" if plates else "")
        scene = scene.with_ground_reaction(loads.select(channels), name=label)
    if "activations" in files:
        scene = scene.with_activations(*read_activations(files["activations"]))
    scene = scene.with_balance(**read_com_zmp(files["com_zmp"]))
    return write_viewer(scene, folder / "viewer.html", title=title, plotly_src=f"../../{PLOTLY}")


def _strikes(times: np.ndarray, vertical: np.ndarray, threshold: float = 20.0, shortest: float = 0.05) -> list:
    """Right-foot cycles (strike, next strike): a strike starts a stretch of at least ``shortest`` seconds above
    ``threshold`` N (the usual stance threshold). A stretch shorter than any ground contact (sprinting's last about
    0.1 s) is plate noise or a per-frame assignment flicker on a treadmill's single plate, not a step."""
    from scipy.ndimage import label

    stretches, count = label(np.nan_to_num(vertical) > threshold)
    starts = []
    for k in range(1, count + 1):
        frames = np.flatnonzero(stretches == k)
        if times[frames[-1]] - times[frames[0]] >= shortest:
            starts.append(float(times[frames[0]]))
    return list(zip(starts[:-1], starts[1:]))


def _curves(result) -> dict[str, Any]:
    """Cycle-normalised mean curves of a trial for the report: joint angles (deg), torques (N·m/kg) and per-foot
    vertical ground reaction (BW), over right-foot cycles (strike to strike, 20 N) of the loads the torques used;
    the whole trial is one cycle when there is none."""
    from biomotion.viz.plots import normalize_cycles

    dynamics = result.dynamics
    model, motion = dynamics.model, dynamics.motion
    loads = result.ground_reaction
    vertical = {}
    for side in ("r", "l"):
        channels = [j for j, body in enumerate(loads.bodies) if str(body).endswith(f"_{side}")]
        vertical[side] = np.nan_to_num(loads.force[:, channels, 1]).sum(1) if channels else np.zeros(motion.n_frames)
    cycles = _strikes(motion.times, vertical["r"]) or None
    coordinates = [
        f"{base}_{side}"
        for side in ("r", "l")
        for base in PLOTTED
        if f"{base}_{side}" in model.coordinate_names
        and not bool(model.locked[model.coordinate_index(f"{base}_{side}")])
    ]
    if not coordinates:
        coordinates = [
            n
            for n, kind, locked in zip(model.coordinate_names, model.motion_types, model.locked.tolist())
            if kind == "rotational" and not locked
        ][:6]
    index = [model.coordinate_index(c) for c in coordinates]
    mass = float(model.total_mass)
    weight = dynamics.body_weight
    values = np.concatenate(
        [
            np.degrees(motion.values[:, index]),
            dynamics.torques[:, index] / mass,
            np.stack([vertical["r"], vertical["l"]], 1) / weight,
        ],
        1,
    )
    normalised = normalize_cycles(motion.times, values, cycles, CYCLE_POINTS).mean(0)
    k = len(coordinates)
    return {
        "cycles": len(cycles) if cycles else 0,
        "angles_deg": {c: normalised[:, j].round(3).tolist() for j, c in enumerate(coordinates)},
        "torques_nm_kg": {c: normalised[:, k + j].round(4).tolist() for j, c in enumerate(coordinates)},
        "grf_bw": {"right": normalised[:, 2 * k].round(4).tolist(), "left": normalised[:, 2 * k + 1].round(4).tolist()},
    }


# --- executors --------------------------------------------------------------------------------------------------


def _serial(fn: Callable, tasks: list) -> Iterator[tuple[Any, Any]]:
    for task in tasks:
        yield task, fn(task)


class _Pool:
    """A local process pool (spawned workers: torch is not forked)."""

    def __init__(self, workers: int) -> None:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        self.pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"))

    def map(self, fn: Callable, tasks: list) -> Iterator[tuple[Any, Any]]:
        from concurrent.futures import as_completed
        from concurrent.futures.process import BrokenProcessPool

        futures = {self.pool.submit(fn, task): task for task in tasks}
        for future in as_completed(futures):
            task = futures[future]
            try:
                yield task, future.result()
            except BrokenProcessPool as error:  # a worker died (out of memory, a crash in a C library)
                yield task, error

    def close(self) -> None:
        self.pool.shutdown(cancel_futures=True)


class _Ray:
    """Ray tasks on a running cluster (``address``) or a local instance started here (``workers`` CPUs)."""

    def __init__(self, workers: int, address: str | None) -> None:
        try:
            import ray
        except ImportError:
            raise ConfigError(
                "--executor ray needs Ray: pip install 'biomotion[distributed]' (or pip install ray)"
            ) from None
        self.ray = ray
        self.started = False
        if not ray.is_initialized():
            if address:
                ray.init(address=address, log_to_driver=False)
            else:
                ray.init(num_cpus=workers, log_to_driver=False, include_dashboard=False)
            self.started = True

    def map(self, fn: Callable, tasks: list) -> Iterator[tuple[Any, Any]]:
        remote = self.ray.remote(num_cpus=1)(fn)
        pending = {remote.remote(task): task for task in tasks}
        while pending:
            done, _ = self.ray.wait(list(pending), num_returns=1)
            task = pending.pop(done[0])
            try:
                yield task, self.ray.get(done[0])
            except Exception as error:  # noqa: BLE001 - a lost worker or node: that task fails, the rest go on
                yield task, error

    def close(self) -> None:
        if self.started:
            self.ray.shutdown()


# --- the batch --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class BatchResult:
    """What `batch` did: the study, the output folder, every outcome (statics first), the report and record
    files, and the wall time (s)."""

    study: Study
    out: Path
    outcomes: tuple[Outcome, ...]
    report: Path | None
    record: Path
    seconds: float

    def counts(self) -> dict[str, int]:
        """Trials and statics by verdict, plus ``skipped`` (resumed) and ``errors``."""
        out = {"ok": 0, "warn": 0, "fail": 0, "skipped": 0, "errors": 0}
        for outcome in self.outcomes:
            out[outcome.verdict.get("verdict", "fail")] += 1
            out["skipped"] += outcome.skipped
            out["errors"] += outcome.status == "error"
        return out


def _subject_key(subject: SubjectSpec, settings: StudySettings, hashes: dict[Path, str]) -> str:
    files = {role: file_sha256(path, hashes) for role, path in subject.files().items()}
    return settings_hash(
        "subject",
        _version(),
        files,
        subject.mass,
        subject.height,
        dict(settings.marker_map),
        list(settings.locked),
    )


def _trial_key(subject_key: str, trial: TrialSpec, task_settings: dict, hashes: dict[Path, str], estimator) -> str:
    files = {role: file_sha256(path, hashes) for role, path in trial.files().items()}
    return settings_hash(
        "trial",
        subject_key,
        files,
        trial.time_range,
        list(trial.plates),
        task_settings,
        getattr(estimator, "name", None),
    )


def _previous(path: Path, key: str, *, retry_bugs: bool) -> Outcome | None:
    """The outcome stored at ``path`` when its key is ``key`` (and it is not a bug to retry)."""
    if not path.exists():
        return None
    try:
        outcome = Outcome.from_dict(json.loads(path.read_text()))
    except (ValueError, TypeError):
        return None
    if outcome.key != key or (retry_bugs and outcome.status == "error" and outcome.error_kind != "input"):
        return None
    outcome.skipped = True
    return outcome


def _prepare_out(out: Path, resume: bool, overwrite: bool) -> None:
    if out.exists() and not out.is_dir():
        raise ConfigError(f"{out}: --out names a file; give a folder")
    if out.is_dir() and any(out.iterdir()):
        if overwrite:
            shutil.rmtree(out)
        elif not resume:
            raise ConfigError(
                f"{out}: the output folder exists and is not empty; pass --resume to continue the batch written "
                "there, --overwrite to replace it, or choose another --out"
            )
        elif not (out / RECORD).exists() and not any(out.glob(f"*/{SCALING}")):
            raise ConfigError(f"{out}: --resume continues a batch, but this folder holds none (no {RECORD})")
    out.mkdir(parents=True, exist_ok=True)


def batch(
    study: Study | str | Path,
    out: str | Path,
    *,
    workers: int | None = None,
    executor: str = "local",
    address: str | None = None,
    resume: bool = False,
    overwrite: bool = False,
    estimator: Any = None,
    progress: bool = True,
    report: bool = True,
    command: str | None = None,
) -> BatchResult:
    """Run a study (module docstring) into the folder ``out``.

    Args:
        study: a `Study`, or a folder / TOML config for `biomotion.analysis.study.load_study`.
        workers: processes (local) or CPUs (a Ray instance started here); default one per core; 1 runs every
            task in this process.
        executor: ``local`` (process pool) or ``ray`` (``address``: a running cluster's, else a local instance).
        resume: keep the tasks of an earlier run into ``out`` whose inputs and settings hash the same.
        overwrite: replace a non-empty ``out`` that is not resumed.
        estimator: the ground-force estimator used for ``forces = "learned"`` (and ``auto`` without plates),
            e.g. ``biomotion.learned_forces()``; picklable.
        report: write ``report.html`` (the record is always written).
        command: the command line, for the record.

    Returns a `BatchResult`; every task's outcome is in it, failures included (this function raises only for a
    bad study or output folder, before any work).
    """
    began = time.perf_counter()
    study = study if isinstance(study, Study) else load_study(study)
    if executor not in EXECUTORS:
        raise ConfigError(f"executor must be one of {', '.join(EXECUTORS)}, got {executor!r}")
    workers = workers or os.cpu_count() or 1
    if workers < 1:
        raise ConfigError(f"workers must be at least 1, got {workers}")
    out = Path(out)
    _prepare_out(out, resume, overwrite)
    hashes: dict[Path, str] = {}
    settings = study.settings
    task_settings = settings.as_dict()
    subject_tasks = [SubjectTask(s, settings, out / s.name, _subject_key(s, settings, hashes)) for s in study.subjects]
    from tqdm import tqdm

    bar = tqdm(total=len(subject_tasks) + study.n_trials, desc="batch", unit="task", disable=not progress)
    counts = {"ok": 0, "warn": 0, "fail": 0}

    def advance(outcome: Outcome) -> None:
        counts[outcome.verdict.get("verdict", "fail")] = counts.get(outcome.verdict.get("verdict", "fail"), 0) + 1
        bar.set_postfix(counts, refresh=False)
        bar.update()

    statics: dict[str, Outcome] = {}
    trials: list[Outcome] = []
    runner: Any = None
    try:
        if executor == "ray":
            runner = _Ray(workers, address)
            run = runner.map
        elif workers > 1:
            runner = _Pool(workers)
            run = runner.map
        else:
            run = _serial
        todo = []
        for task in subject_tasks:
            previous = _previous(task.out / SCALING, task.key, retry_bugs=True) if resume else None
            if previous is not None and previous.status == "done" and (task.out / f"{task.subject.name}.osim").exists():
                statics[task.subject.name] = previous
                advance(previous)
            else:
                todo.append(task)
        for task, outcome in run(run_subject, todo):
            if isinstance(outcome, BaseException):
                outcome = _error_outcome(task.subject.name, "static", "static", task.key, outcome, began)
            statics[task.subject.name] = outcome
            advance(outcome)
        trial_tasks, todo = [], []
        for task in subject_tasks:
            subject = task.subject
            scaled = statics[subject.name]
            for trial in subject.trials:
                folder = task.out / trial.name
                key = _trial_key(task.key, trial, task_settings, hashes, estimator)
                if scaled.status != "done":
                    outcome = Outcome(subject.name, trial.name, "trial", key, status="error", error_kind="input")
                    outcome.error = f"not analysed: scaling {subject.name} failed ({scaled.error})"
                    outcome.verdict = failure(outcome.error).to_dict()
                    trials.append(outcome)
                    advance(outcome)
                    continue
                trial_task = TrialTask(
                    subject, trial, settings, task.out / f"{subject.name}.osim", folder, key, estimator
                )
                trial_tasks.append(trial_task)
                previous = _previous(folder / OUTCOME, key, retry_bugs=True) if resume else None
                if previous is not None:
                    trials.append(previous)
                    advance(previous)
                else:
                    todo.append(trial_task)
        for task, outcome in run(run_trial, todo):
            if isinstance(outcome, BaseException):
                outcome = _error_outcome(task.subject.name, task.trial.name, "trial", task.key, outcome, began)
            trials.append(outcome)
            advance(outcome)
    finally:
        bar.close()
        if runner is not None:
            runner.close()
    order = {(s.name, t.name): k for k, (s, t) in enumerate((s, t) for s in study.subjects for t in s.trials)}
    trials.sort(key=lambda o: order.get((o.subject, o.name), 0))
    outcomes = tuple(statics[s.name] for s in study.subjects) + tuple(trials)
    report_path = None
    if report:
        from biomotion.viz.report import write_report
        from biomotion.viz.viewer import plotly_js

        (out / PLOTLY).write_text(plotly_js(), encoding="utf-8")
        report_path = write_report(
            out / REPORT,
            title=f"biomotion batch: {study.name}",
            subjects=[o.as_dict() for o in outcomes if o.kind == "static"],
            trials=[o.as_dict() for o in outcomes if o.kind == "trial"],
            settings=task_settings,
            source=str(study.source),
        )
    seconds = time.perf_counter() - began
    record = _record(study, out, outcomes, hashes, task_settings, executor, workers, seconds, command)
    _write_json(out / RECORD, _clean(record))
    return BatchResult(study, out, outcomes, report_path, out / RECORD, seconds)


def _record(
    study: Study,
    out: Path,
    outcomes: tuple[Outcome, ...],
    hashes: dict[Path, str],
    settings: dict,
    executor: str,
    workers: int,
    seconds: float,
    command: str | None,
) -> dict[str, Any]:
    """``record.json``: what ran, on what, with which inputs, and how long it took."""
    from importlib import metadata

    def version(name: str) -> str | None:
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            return None

    verdicts = {"ok": 0, "warn": 0, "fail": 0}
    for outcome in outcomes:
        if outcome.kind == "trial":
            verdicts[outcome.verdict.get("verdict", "fail")] += 1
    return {
        "biomotion": _version(),
        "command": command,
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "versions": {name: version(name) for name in ("torch", "numpy", "scipy", "ezc3d", "plotly", "ray")},
        "study": {
            "name": study.name,
            "source": str(study.source),
            "layout": study.layout,
            "subjects": len(study.subjects),
            "trials": study.n_trials,
        },
        "settings": settings,
        "executor": {"kind": executor, "workers": workers},
        "inputs_sha256": {str(path): digest for path, digest in sorted(hashes.items(), key=lambda kv: str(kv[0]))},
        "seconds": round(seconds, 2),
        "trial_verdicts": verdicts,
        "statics": [_summary_row(o) for o in outcomes if o.kind == "static"],
        "trials": [_summary_row(o) for o in outcomes if o.kind == "trial"],
    }


def _summary_row(outcome: Outcome) -> dict[str, Any]:
    return {
        "subject": outcome.subject,
        "name": outcome.name,
        "status": outcome.status,
        "verdict": outcome.verdict.get("verdict"),
        "error": outcome.error,
        "skipped": outcome.skipped,
        "key": outcome.key,
        "seconds": outcome.seconds,
        "files": outcome.files,
    }
