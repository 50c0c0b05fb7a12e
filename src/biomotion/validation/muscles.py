"""Validation of muscle geometry and static optimization against OpenSim 4.6 (the oracle; needs ``opensim``).

`validate_muscles` returns the figures of the muscles check:

- ``moment_arm_rmse_m``: worst RMSE over all (muscle, coordinate) pairs that OpenSim reports non-zero, between
  the shipped path functions and OpenSim's ``GeometryPath.computeMomentArm`` at fresh random poses in the sampled
  box (Rajagopal2016 and the gait2392 subject01 model); per-model detail alongside.
- ``so_r2_gait2392``: mean over muscles of R^2 between our activations and those of OpenSim's
  ``StaticOptimization`` analysis run fresh on the gait2392 subject01 walk (IK motion filtered at 6 Hz, the
  subject's model plus ``gait2392_SO_Residual_Actuators.xml``, GRF from ``subject01_walk1_grf.xml``, step
  interval 1, squared activations). Torques come from OpenSim's ``InverseDynamicsTool`` on the same motion and q,
  qdot from a ``Kinematics`` analysis run with the optimization, so both solvers get the same inputs.
- ``so_speedup``: OpenSim's SO wall time over ours (geometry, muscle forces and the batched solve), same frames;
- ``so_rajagopal_*``: the same comparison on the Rajagopal walk (`rajagopal_walk_inputs`: our IK of the walk on
  the generic Rajagopal 2016 model, the walk's GRF, reserves as `LabelSettings`; OpenSim's StaticOptimization with
  its own Millard 2012 muscles vs ours with `biomotion.muscles.millard`'s curves). ``so_rajagopal_r2_all`` is the
  mean R² over all muscles, ``so_rajagopal_r2_active`` over the muscles OpenSim activates (range >
  ``ACTIVE_RANGE``). The coordinates file for OpenSim is written in radians: from a degrees file OpenSim 4.6's
  AnalyzeTool hands its optimization knee_angle_*_beta speeds in deg/s (the patella's coupled coordinate), which
  put 40 N·m of patella inertia on the hips and made the two solutions disagree (R² about 0; 0.99 in radians;
  docs/decisions/static-optimization-vs-opensim.md). ``so_rajagopal_muscle_torque_gap_rms_nm_*`` is the RMS gap
  between each solution's muscle torques (through our muscle model) and the inverse-dynamics torque; the rest is
  left to the reserves.
- ``so_r2_vs_opensim``: the lower of the two trials' mean R² over all muscles (``so_r2_gait2392``,
  ``so_rajagopal_r2_all``), so one figure holds the bar for both.
- ``surrogate_ms_per_clip``, ``surrogate_speedup_vs_opensim``: the shipped surrogate on the same walk clip (after
  model load) against OpenSim's static optimization of it, measured in the same run: the activations it reports
  (`MuscleSurrogate.predict_symmetric`, both mirror images in one batch), and one pass (what guidance runs) under
  ``surrogate_ms_per_clip_one_pass``;
- ``emg_onoff_agreement``: EMG on/off timing of the Rajagopal walk against our static optimization of the same
  trial (`biomotion.validation.emg`), and the surrogate's under ``emg_onoff_agreement_surrogate``;
  ``emg_onoff_agreement_opensim_so``: the same rule on OpenSim's own StaticOptimization of the walk's shared inputs
  above (generic model, our IK), what the check's method scores when the oracle runs it, with ours on those inputs
  beside it (``emg_onoff_agreement_same_inputs_ours``);
- ``surrogate_r2``, ``surrogate_rmse`` (`surrogate_figures`): the shipped surrogate against labels computed fresh
  (`biomotion.analysis.activation_labels.Labeler`, as `biomotion train labels`) on every clip of the lab sources
  under the data root whose subject the surrogate was not trained on, of the activations it reports
  (`MuscleSurrogate.predict_symmetric`; one pass under ``surrogate_r2_one_pass``): mean R² over the muscles whose
  labels vary (`biomotion.muscles.surrogate_scores.agreement`; how many in ``surrogate_muscles_in_mean``, each one's
  R² in ``surrogate_r2_per_muscle``, worst first), pooled R² and RMSE beside it. Not trained on: not among the
  subjects the surrogate's weights or model card list as its training set (`MuscleSurrogate.training_subjects`),
  so on a data root of new subjects every one counts; for a checkpoint that lists none, the split rule decides
  (val and test). ``surrogate_com_vel_r2`` (and ``surrogate_com_acc_r2``, RMSEs beside them): the surrogate's COM head
  against the labels' whole-body COM velocity (acceleration), R² per ground axis over all frames of those clips,
  averaged over the three axes (PG-BIG A.8). Guidance itself takes the COM terms from the body model's kinematics,
  which are exact; the head is there for users who want them at the surrogate's speed.
"""

from __future__ import annotations

import os
import tempfile
import time
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from biomotion.analysis.activation_labels import LabelSettings
from biomotion.errors import DataFormatError
from biomotion.io.xml import parse_tree
from biomotion.muscles.geometry import MusclePaths, balanced_coordinates, shipped_paths
from biomotion.muscles.properties import max_active_force, read_muscles
from biomotion.muscles.static_optimization import (
    StaticOptimizationResult,
    optimize_activations,
)
from biomotion.validation.emg import SURROGATE, emg_check

GAIT = "opensim-models/Pipelines/Gait2392_Simbody"
GAIT_MODEL = f"{GAIT}/OutputReference/subject01_simbody.osim"
RAJAGOPAL_MODEL = "opensim-models/Models/Rajagopal/Rajagopal2016.osim"
RAJAGOPAL_PIPELINE = "opensim-models/Pipelines/Rajagopal"
RESIDUALS = {
    "pelvis_tilt": 80.0,
    "pelvis_list": 80.0,
    "pelvis_rotation": 80.0,
    "pelvis_tx": 100.0,
    "pelvis_ty": 200.0,
    "pelvis_tz": 100.0,
}  # see `gait_static_optimization`


def _read_sto(path: Path) -> tuple[list[str], np.ndarray]:
    lines = path.read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if line.strip() == "endheader")
    columns = lines[start + 1].split("\t")
    return columns, np.array([[float(v) for v in line.split()] for line in lines[start + 2 :] if line.strip()])


def moment_arm_errors(
    paths: MusclePaths, model_path: str | Path, poses: int = 200, seed: int = 1, muscles: list[str] | None = None
) -> dict[tuple[str, str], float]:
    """RMSE (m) of ``paths``' moment arms against OpenSim's at ``poses`` random poses in the sampled box, for every
    (muscle, coordinate) pair whose OpenSim moment arm is non-zero (> 1e-4 m) at some pose."""
    from biomotion.muscles.opensim_paths import OpenSimPaths

    oracle = OpenSimPaths(model_path)
    rng = np.random.default_rng(seed)
    q = oracle.sample_poses(paths.ranges.numpy(), poses, rng)
    names = muscles or list(paths.muscle_names)
    spanned = paths.spanned()
    candidates = [i for i in range(paths.n_q) if i not in oracle.dependent and not torch.isnan(paths.ranges[i, 0])]
    pairs = [(oracle.muscle_names.index(m), c) for m in names for c in candidates]
    reference = oracle.moment_arms(q, pairs)  # [N, P]
    ours = paths.moment_arms(torch.from_numpy(q)).numpy()
    errors = {}
    for p, (m, c) in enumerate(pairs):
        if np.abs(reference[:, p]).max() <= 1e-4:
            continue
        row = paths.muscle_names.index(oracle.muscle_names[m])
        estimate = ours[:, row, c] if spanned[row, c] else np.zeros(len(q))
        errors[(oracle.muscle_names[m], oracle.coordinate_names[c])] = float(
            np.sqrt(((estimate - reference[:, p]) ** 2).mean())
        )
    return errors


@dataclass(frozen=True)
class OpenSimStaticOptimization:
    times: np.ndarray  # [T]
    muscle_names: tuple[str, ...]
    activations: np.ndarray  # [T, M]
    coordinate_names: tuple[str, ...]
    q: np.ndarray  # [T, n_q] rad / m, the states OpenSim's SO used
    qdot: np.ndarray  # [T, n_q]
    torques: np.ndarray  # [T, n_q] OpenSim's InverseDynamicsTool on the same coordinates
    seconds: float  # wall time of OpenSim's SO run (AnalyzeTool.run)
    actuator_controls: dict[str, np.ndarray] | None = None  # [T] per non-muscle actuator of the optimization


def opensim_static_optimization(
    model: Path,
    coordinates: Path,
    external_loads: Path,
    force_set: Path,
    start: float,
    end: float,
    workdir: str | Path | None = None,
) -> OpenSimStaticOptimization:
    """Run OpenSim's StaticOptimization (squared activations, muscle physiology, step interval 1, the model's own
    force set plus ``force_set``) and its InverseDynamicsTool (muscles excluded) on ``coordinates`` filtered at
    6 Hz with ``external_loads`` over [start, end] s, with a Kinematics analysis for the q and qdot the
    optimization saw; read back what they produced. Paths must be absolute (OpenSim resolves setup-file paths
    relative to the setup file)."""
    from biomotion.settings import opensim_oracle

    opensim = opensim_oracle()

    opensim.Logger.setLevelString("error")
    muscle_names = set(read_muscles(model).names)
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        out = Path(tmp)
        tool = opensim.AnalyzeTool()
        tool.setName("so")
        tool.setModelFilename(str(model))
        force_sets = opensim.ArrayStr()
        force_sets.append(str(force_set))
        tool.setForceSetFiles(force_sets)
        tool.setReplaceForceSet(False)
        tool.setCoordinatesFileName(str(coordinates))
        tool.setLowpassCutoffFrequency(6)
        tool.setExternalLoadsFileName(str(external_loads))
        tool.setInitialTime(start)
        tool.setFinalTime(end)
        tool.setResultsDir(str(out))
        so = opensim.StaticOptimization()
        so.setStartTime(start)
        so.setEndTime(end)
        so.setStepInterval(1)
        so.setUseModelForceSet(True)
        so.setActivationExponent(2)
        so.setUseMusclePhysiology(True)
        tool.getAnalysisSet().cloneAndAppend(so)
        kinematics = opensim.Kinematics()
        kinematics.setInDegrees(False)
        kinematics.setStepInterval(1)
        tool.getAnalysisSet().cloneAndAppend(kinematics)
        tool.printToXML(str(out / "so_setup.xml"))
        runner = opensim.AnalyzeTool(str(out / "so_setup.xml"))
        tic = time.perf_counter()
        runner.run()
        seconds = time.perf_counter() - tic

        inverse = opensim.InverseDynamicsTool()
        inverse.setName("id")
        inverse.setModelFileName(str(model))
        inverse.setCoordinatesFileName(str(coordinates))
        inverse.setLowpassCutoffFrequency(6)
        inverse.setExternalLoadsFileName(str(external_loads))
        inverse.setStartTime(start)
        inverse.setEndTime(end)
        excluded = opensim.ArrayStr()
        excluded.append("Muscles")
        inverse.setExcludedForces(excluded)
        inverse.setResultsDir(str(out))
        inverse.setOutputGenForceFileName("id.sto")
        inverse.printToXML(str(out / "id_setup.xml"))
        opensim.InverseDynamicsTool(str(out / "id_setup.xml")).run()

        columns, activations = _read_sto(out / "so_StaticOptimization_activation.sto")
        q_columns, q = _read_sto(out / "so_Kinematics_q.sto")
        u_columns, u = _read_sto(out / "so_Kinematics_u.sto")
        id_columns, torques = _read_sto(out / "id.sto")
    coordinates_out = tuple(q_columns[1:])
    muscles = tuple(n for n in columns[1:] if n in muscle_names)
    picks = [columns.index(n) for n in muscles]
    id_index = {n.rsplit("_", 1)[0]: i for i, n in enumerate(id_columns)}
    n = min(len(activations), len(q), len(torques))
    for name, table in (("Kinematics", q), ("inverse dynamics", torques)):
        if not np.allclose(table[:n, 0], activations[:n, 0], atol=1e-5):
            raise DataFormatError(
                None, f"OpenSim's {name} frames do not line up with its static optimization", field="time"
            )
    return OpenSimStaticOptimization(
        activations[:n, 0],
        muscles,
        activations[:n, picks],
        coordinates_out,
        q[:n, 1:],
        u[:n, [u_columns.index(c) for c in coordinates_out]],
        torques[:n, [id_index[c] for c in coordinates_out]],
        seconds,
        {c: activations[:n, columns.index(c)] for c in columns[1:] if c not in muscle_names},
    )


def opensim_gait_static_optimization(
    data_root: str | Path, start: float, end: float, workdir: str | Path | None = None
) -> OpenSimStaticOptimization:
    """`opensim_static_optimization` on the gait2392 subject01 walk (setup as in the module docstring)."""
    root = Path(data_root).resolve() / GAIT
    return opensim_static_optimization(
        Path(data_root).resolve() / GAIT_MODEL,
        root / "subject01_walk1_ik.mot",
        root / "subject01_walk1_grf.xml",
        root / "gait2392_SO_Residual_Actuators.xml",
        start,
        end,
        workdir,
    )


def gait_static_optimization(
    data_root: str | Path, reference: OpenSimStaticOptimization, paths: MusclePaths | None = None
) -> tuple[StaticOptimizationResult, float]:
    """Our SO on the inputs of ``reference`` (gait2392 subject01) and its wall time (s). The pelvis residuals of
    ``gait2392_SO_Residual_Actuators.xml`` (FX/FY/FZ 100/200/100 N, MX/MY/MZ 80 N·m, controls in [-1, 1]) act
    only on the six pelvis coordinates, which no muscle spans, so they are modelled as reserves there: the muscle
    problem is unchanged."""
    paths = paths or shipped_paths("gait2392_subject01")
    muscles = read_muscles(Path(data_root) / GAIT_MODEL)
    return _solve_on_reference(paths, muscles, reference, reference.coordinate_names, RESIDUALS)


#: Reserve actuators of the Rajagopal comparison, the same in both solvers: on each coordinate the muscles span,
#: the surrogate labels' reserve (`LabelSettings`: optimal force 10 N·m, control in [-100, 100], penalised like a
#: muscle, so it only takes what the muscles cannot give); on every other free coordinate (pelvis, lumbar, arms: no
#: muscle spans them, so their rows of the problem are independent of the muscles) an actuator of 1000 N·m that
#: OpenSim needs and ours leaves out.
RAJAGOPAL_RESERVE = LabelSettings().reserve_optimal_force
RAJAGOPAL_RESERVE_BOUND = LabelSettings().reserve_bound
RAJAGOPAL_OTHER_ACTUATOR = 1000.0


@dataclass(frozen=True)
class RajagopalWalkInputs:
    """The files both solvers read for the Rajagopal walk (absolute paths in a working folder)."""

    model: Path  # the generic Rajagopal 2016 model (the shipped path functions are its paths),
    # with the walk's marker set
    coordinates: Path  # our IK of the walk on that model (.mot, degrees)
    external_loads: Path  # grf_walk.mot on calcn_r / calcn_l (ExternalLoads XML)
    grf: Path  # grf_walk.mot
    force_set: Path  # the reserves above
    balanced: tuple[str, ...]  # coordinates with muscles (hips, knees, ankles)
    time_range: tuple[float, float]
    marker_rmse_m: float  # of the IK on the generic model


def generic_with_walk_markers(data_root: Path, destination: Path) -> Path:
    """Rajagopal2016.osim with its marker set replaced by the walk pipeline's ``Scale/markerset_walk_preScale.xml``
    (OpenSim 3 markers, ``<body>``, rewritten as 4.0 markers on ``/bodyset/<body>``), the markers the walk's
    TRC and IK setup name."""
    tree = parse_tree(data_root / RAJAGOPAL_MODEL)
    model = tree.getroot().find("Model")
    holder = model.find("MarkerSet")
    objects = holder.find("objects")
    for marker in list(objects):
        objects.remove(marker)
    source = parse_tree(data_root / RAJAGOPAL_PIPELINE / "Scale/markerset_walk_preScale.xml").getroot()
    for marker in source.iter("Marker"):
        body = (marker.findtext("body") or "").strip()
        location = marker.findtext("location")
        if not body or location is None:
            raise DataFormatError(
                data_root / RAJAGOPAL_PIPELINE / "Scale/markerset_walk_preScale.xml",
                f"marker {marker.get('name')!r} has no body or location",
                field="Marker",
            )
        element = ET.SubElement(objects, "Marker", name=marker.get("name"))
        ET.SubElement(element, "socket_parent_frame").text = f"/bodyset/{body}"
        ET.SubElement(element, "location").text = location.strip()
        ET.SubElement(element, "fixed").text = (marker.findtext("fixed") or "false").strip()
    tree.write(destination, encoding="UTF-8", xml_declaration=True)
    return destination


def rajagopal_walk_inputs(data_root: str | Path, folder: Path) -> RajagopalWalkInputs:
    """Write the Rajagopal walk inputs into ``folder``: `biomotion.ik.markers.solve_ik` of
    ``motion_capture_walk.trc`` on the generic Rajagopal 2016 model with ``IK/ik_setup_walk.xml``'s weights and
    time range, the GRF applied as ``ID/grf_walk.xml`` says, and the reserves. The generic model, not the
    subject's scaled one, because the shipped path functions are the generic model's paths; IK on that same model
    keeps the feet where the markers (and so the plates' centres of pressure) are, so the torques both solvers
    balance are those of a consistent, if smaller (1.70 m for the subject's 1.83 m), body."""
    from biomotion.body.model import BodyModel
    from biomotion.ik.markers import solve_ik
    from biomotion.io.mot import read_ground_reaction, write_external_loads_xml, write_motion
    from biomotion.io.setup import read_ik_setup
    from biomotion.io.trc import read_trc
    from biomotion.validation import emg

    data_root = Path(data_root).resolve()
    generic = generic_with_walk_markers(data_root, folder / "Rajagopal2016_walk_markers.osim")
    model = BodyModel.from_osim(generic)
    setup = read_ik_setup(data_root / emg.IK_SETUP)
    ik = solve_ik(
        model,
        read_trc(data_root / emg.MARKER_FILE),
        weights=setup.marker_weights,
        coordinate_tasks=setup.coordinate_tasks,
        time_range=setup.time_range,
    )
    # radians: from a degrees file, OpenSim 4.6's AnalyzeTool converts knee_angle_*_beta's values but leaves its
    # speeds in deg/s (57.3x; the coupled patella coordinate is neither rotational nor translational), and the
    # patella's inertial forces then load the femur: its optimization balanced hip torques some 40 N·m off
    coordinates = write_motion(folder / "ik_walk.mot", ik.motion, in_degrees=False)
    forces = read_ground_reaction(data_root / emg.GRF_FILE)
    forces = forces.assign(emg.external_load_bodies(data_root / emg.GRF_LOADS, forces.names))
    loads = write_external_loads_xml(folder / "grf_walk.xml", forces, str(data_root / emg.GRF_FILE))
    force_set, balanced = write_rajagopal_reserves(model, folder / "reserves.xml")
    return RajagopalWalkInputs(
        generic,
        coordinates,
        loads,
        data_root / emg.GRF_FILE,
        force_set,
        balanced,
        (float(ik.motion.times[0]), float(ik.motion.times[-1])),
        float(ik.rmse),
    )


def write_rajagopal_reserves(model, path: Path) -> tuple[Path, tuple[str, ...]]:
    """OpenSim ForceSet of the Rajagopal comparison's reserves (see `RAJAGOPAL_RESERVE`) for ``model`` (the
    generic Rajagopal 2016 `BodyModel`); returns it and the balanced coordinates (those the muscles span)."""
    balanced = balanced_coordinates(shipped_paths("rajagopal2016"), model)
    dependent = {c.dependent for c in model.couplers}
    free = [j for j in range(model.n_q) if not bool(model.locked[j]) and j not in dependent]
    actuators = []
    for j in free:
        name = model.coordinate_names[j]
        force, bound = (
            (RAJAGOPAL_RESERVE, RAJAGOPAL_RESERVE_BOUND)
            if name in balanced
            else (RAJAGOPAL_OTHER_ACTUATOR, RAJAGOPAL_RESERVE_BOUND)
        )
        actuators.append(
            f'<CoordinateActuator name="reserve_{name}"><coordinate>{name}</coordinate>'
            f"<optimal_force>{force}</optimal_force><min_control>{-bound}</min_control>"
            f"<max_control>{bound}</max_control></CoordinateActuator>"
        )
    path.write_text(
        '<?xml version="1.0" encoding="UTF-8" ?>\n<OpenSimDocument Version="40000">'
        '<ForceSet name="reserves"><objects>'
        + "".join(actuators)
        + "</objects><groups /></ForceSet></OpenSimDocument>\n"
    )
    return path, balanced


def rajagopal_static_optimization(
    inputs: RajagopalWalkInputs, reference: OpenSimStaticOptimization, paths: MusclePaths | None = None
) -> tuple[StaticOptimizationResult, float]:
    """Our SO on the inputs of ``reference`` (the Rajagopal walk, `rajagopal_walk_inputs`) and its wall time (s):
    the shipped Rajagopal path functions, the model's Millard 2012 curves, the same reserves on the balanced
    coordinates, and the torques `solver_torques` gives for the states OpenSim's optimization saw."""
    paths = paths or shipped_paths("rajagopal2016")
    muscles = read_muscles(inputs.model)
    torques, _ = solver_torques(inputs, reference)
    return _solve_on_reference(
        paths,
        muscles,
        replace(reference, torques=torques),
        inputs.balanced,
        {name: RAJAGOPAL_RESERVE for name in inputs.balanced},
        RAJAGOPAL_RESERVE_BOUND,
    )


def solver_torques(inputs: RajagopalWalkInputs, reference: OpenSimStaticOptimization) -> tuple[np.ndarray, float]:
    """([T, n_q] generalized forces in ``reference`` coordinate order, max |q - q_OpenSim| over the balanced
    coordinates): our `inverse_dynamics` (equal to OpenSim's ``InverseDynamicsSolver`` to 1e-12 N·m, tests/body)
    with the walk's GRF, on the coordinates file prepared as OpenSim's tools prepare it (6 Hz zero-lag low-pass
    after padding, quintic-spline derivatives: `biomotion.motion.Motion.smoothed`), at the optimization's frames;
    the second value checks those q against the ones OpenSim's optimization reports. With the coordinates in
    radians (`rajagopal_walk_inputs`) OpenSim's InverseDynamicsTool on the same file agrees with these torques to
    0.15 N·m RMS on every balanced coordinate (from a degrees file it reported up to 270 N·m at the swing hip, the
    patella-speed conversion fault)."""
    from biomotion.analysis.chain import _loads, loads_on_frames, model_motion
    from biomotion.body.dynamics import inverse_dynamics
    from biomotion.body.model import BodyModel
    from biomotion.io.mot import read_ground_reaction, read_motion
    from biomotion.validation import emg

    model = BodyModel.from_osim(inputs.model)
    filtered, qd, qdd = model_motion(read_motion(inputs.coordinates), model).smoothed(6.0)
    frames = [int(np.argmin(np.abs(filtered.times - t))) for t in reference.times]
    if np.abs(filtered.times[frames] - reference.times).max() > 1e-6:
        raise DataFormatError(
            inputs.coordinates, "OpenSim's optimization frames are not frames of the coordinates", field="time"
        )
    forces = read_ground_reaction(inputs.grf)
    forces = loads_on_frames(
        forces.assign(emg.external_load_bodies(inputs.external_loads, forces.names)), reference.times
    )
    as_tensor = lambda a: torch.tensor(np.ascontiguousarray(a[frames]), dtype=torch.float64)  # noqa: E731
    tau = inverse_dynamics(
        model, as_tensor(filtered.values), as_tensor(qd), as_tensor(qdd), _loads(forces, torch.float64)
    ).numpy()
    back = [list(model.coordinate_names).index(n) for n in reference.coordinate_names]
    rows = [reference.coordinate_names.index(n) for n in inputs.balanced]
    state_error = float(np.abs(filtered.values[frames][:, back][:, rows] - reference.q[:, rows]).max())
    return tau[:, back], state_error


def _solve_on_reference(
    paths: MusclePaths,
    muscles,
    reference: OpenSimStaticOptimization,
    balanced: tuple[str, ...],
    reserves: dict[str, float],
    reserve_bound: float = 1.0,
) -> tuple[StaticOptimizationResult, float]:
    """Our SO given OpenSim's q, qdot and inverse-dynamics torques (coordinates in ``reference`` order)."""
    q, qdot = _states_in_path_order(paths, reference)
    torques = torch.from_numpy(reference.torques[:, [reference.coordinate_names.index(c) for c in balanced]])
    tic = time.perf_counter()
    result = optimize_activations(paths, muscles, q, qdot, torques, balanced, reserves, reserve_bound=reserve_bound)
    return result, time.perf_counter() - tic


def _states_in_path_order(
    paths: MusclePaths, reference: OpenSimStaticOptimization
) -> tuple[torch.Tensor, torch.Tensor]:
    """OpenSim's q, qdot [T, n_q] in ``paths`` coordinate order (coordinates it does not report at 0)."""
    known = [c for c in reference.coordinate_names if c in paths.coordinate_names]
    columns = paths.select(known)
    rows = [reference.coordinate_names.index(c) for c in known]
    q = torch.zeros(len(reference.q), paths.n_q, dtype=torch.float64)
    qdot = torch.zeros_like(q)
    q[:, columns] = torch.from_numpy(reference.q[:, rows])
    qdot[:, columns] = torch.from_numpy(reference.qdot[:, rows])
    return q, qdot


def static_optimization_agreement(
    result: StaticOptimizationResult, reference: OpenSimStaticOptimization, seconds: float
) -> dict:
    """R² per muscle (mean, worst), activation RMSE, convergence and the side-by-side speed ratio."""
    ours = result.activations.numpy()[:, [result.muscle_names.index(m) for m in reference.muscle_names]]
    r2 = r_squared(ours, reference.activations)
    return {
        "r2_mean": float(r2.mean()),
        "r2_min": float(r2.min()),
        "r2_worst_muscle": reference.muscle_names[int(r2.argmin())],
        "frames": len(reference.times),
        "converged_frames": int(result.converged.sum()),
        "activation_rmse": float(np.sqrt(((ours - reference.activations) ** 2).mean())),
        "seconds_opensim": reference.seconds,
        "seconds_biomotion": seconds,
        "speedup": reference.seconds / seconds,
        "reserve_usage": result.reserve_usage(),
    }


def r_squared(estimate: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Per-column coefficient of determination of ``estimate`` against ``reference`` [T, K]."""
    total = ((reference - reference.mean(0)) ** 2).sum(0)
    return 1 - ((estimate - reference) ** 2).sum(0) / np.maximum(total, 1e-12)


def surrogate_clip_timing(
    checkpoint: Path, coordinates: Path, model_path: Path, canonical_path: Path, repeats: int = 20
) -> dict:
    """Best wall time (ms) of the shipped surrogate on the clip in ``coordinates`` (after model load; resampled
    to its rate, placed like its training clips on the model at ``model_path``; ``canonical_path``: the canonical
    body a surrogate with contact features runs its forward kinematics on, inside the timed call):
    ``ms`` of the activations it reports (`MuscleSurrogate.predict_symmetric`), ``ms_one_pass`` of one pass (what
    guidance runs); and the clip's length (s)."""
    from biomotion.body.canonical import CANONICAL_COORDINATES
    from biomotion.body.model import BodyModel
    from biomotion.data.placement import place_clip
    from biomotion.io.mot import read_motion
    from biomotion.muscles.surrogate import MuscleSurrogate

    network = MuscleSurrogate.load(checkpoint, body=BodyModel.from_osim(canonical_path))
    motion = read_motion(coordinates)
    clip = place_clip(
        motion.select(CANONICAL_COORDINATES).resample(network.config.rate),
        BodyModel.from_osim(model_path),
        height=None,
        treadmill_speed=None,
    )
    q = torch.as_tensor(clip.values, dtype=network.mean.dtype)[None]
    mask = torch.as_tensor(clip.mask)[None]
    best = {}
    with torch.no_grad():
        for name, run in (("ms", network.predict_symmetric), ("ms_one_pass", network.predict)):
            run(q, mask)
            best[name] = float("inf")
            for _ in range(repeats):
                tic = time.perf_counter()
                run(q, mask)
                best[name] = min(best[name], time.perf_counter() - tic)
    return {
        "ms": 1e3 * best["ms"],
        "ms_one_pass": 1e3 * best["ms_one_pass"],
        "clip_seconds": float(motion.times[-1] - motion.times[0]),
        "frames": clip.n_frames,
    }


def _moment_arm_figures(data_root: Path, poses: int) -> dict:
    geometry = {}
    for name, model in (("rajagopal2016", RAJAGOPAL_MODEL), ("gait2392_subject01", GAIT_MODEL)):
        if not (data_root / model).exists():
            continue
        errors = moment_arm_errors(shipped_paths(name), data_root / model, poses)
        worst = max(errors, key=errors.get)
        geometry[name] = {
            "pairs": len(errors),
            "worst_rmse_m": errors[worst],
            "worst_pair": list(worst),
            "mean_rmse_m": float(np.mean(list(errors.values()))),
            "pairs_over_2mm": sorted(f"{m}/{c}" for (m, c), e in errors.items() if e > 2e-3),
        }
    if not geometry:
        return {}
    return {"moment_arm_rmse_m": max(g["worst_rmse_m"] for g in geometry.values()), "moment_arms": geometry}


def _gait_figures(data_root: Path, start: float, end: float) -> dict:
    reference = opensim_gait_static_optimization(data_root, start, end)
    gait_static_optimization(data_root, reference)  # warm-up: first-call costs of torch
    result, seconds = gait_static_optimization(data_root, reference)
    agreement = static_optimization_agreement(result, reference, seconds)
    return {
        "so_r2_gait2392": agreement["r2_mean"],
        "so_r2_min": agreement["r2_min"],
        "so_r2_worst_muscle": agreement["r2_worst_muscle"],
        "so_frames": agreement["frames"],
        "so_converged_frames": agreement["converged_frames"],
        "so_activation_rmse": agreement["activation_rmse"],
        "so_seconds_opensim": reference.seconds,
        "so_seconds_biomotion": seconds,
        "so_speedup": agreement["speedup"],
        "reserve_usage": agreement["reserve_usage"],
    }


#: A muscle counts as active in OpenSim's solution when its activation spans more than this over the trial;
#: R² against a near-constant reference (a muscle held at its 0.01 floor) measures nothing but rounding.
ACTIVE_RANGE = 0.05


def _rajagopal_figures(data_root: Path, surrogate: Path | None) -> dict:
    with tempfile.TemporaryDirectory(prefix="biomotion-so-") as folder:
        inputs = rajagopal_walk_inputs(data_root, Path(folder))
        reference = opensim_static_optimization(
            inputs.model, inputs.coordinates, inputs.external_loads, inputs.force_set, *inputs.time_range
        )
        rajagopal_static_optimization(inputs, reference)  # warm-up
        result, seconds = rajagopal_static_optimization(inputs, reference)
        timing = (
            surrogate_clip_timing(surrogate, inputs.coordinates, inputs.model, data_root / RAJAGOPAL_MODEL)
            if surrogate is not None and Path(surrogate).exists()
            else None
        )
        torques, state_error = solver_torques(inputs, reference)
        muscles = read_muscles(inputs.model)
    agreement = static_optimization_agreement(result, reference, seconds)
    ours = result.activations.numpy()[:, [result.muscle_names.index(m) for m in reference.muscle_names]]
    r2 = r_squared(ours, reference.activations)
    active = (reference.activations.max(0) - reference.activations.min(0)) > ACTIVE_RANGE
    balanced = [reference.coordinate_names.index(c) for c in inputs.balanced]
    # the torque OpenSim's activations give with our muscle model, against the torque our solver balanced
    paths = shipped_paths("rajagopal2016")
    muscles = muscles.select(paths.muscle_names)
    q, qdot = _states_in_path_order(paths, reference)
    lengths, arms = paths.lengths_and_moment_arms(q)
    forces = max_active_force(muscles, lengths, -(arms @ qdot[..., None])[..., 0])
    theirs = torch.from_numpy(reference.activations[:, [reference.muscle_names.index(m) for m in paths.muscle_names]])
    produced = torch.einsum("tmc,tm->tc", arms[..., paths.select(inputs.balanced)], forces * theirs).numpy()
    ours_produced = torch.einsum(
        "tmc,tm->tc", arms[..., paths.select(inputs.balanced)], forces * result.activations
    ).numpy()
    figures = {
        "so_rajagopal_r2_active": float(r2[active].mean()),
        "so_rajagopal_active_muscles": int(active.sum()),
        "so_rajagopal_r2_all": float(r2.mean()),
        "so_rajagopal_activation_rmse": agreement["activation_rmse"],
        "so_rajagopal_frames": agreement["frames"],
        "so_rajagopal_converged_frames": agreement["converged_frames"],
        "so_rajagopal_seconds_opensim": reference.seconds,
        "so_rajagopal_seconds_biomotion": seconds,
        "so_rajagopal_speedup": agreement["speedup"],
        "so_rajagopal_ik_marker_rmse_m": inputs.marker_rmse_m,
        "so_rajagopal_state_max_diff": state_error,
        # RMS over frames and balanced coordinates of (muscle torque - the inverse-dynamics torque at the
        # optimization's states), both solutions through our muscle model; the rest is left to the reserves
        "so_rajagopal_muscle_torque_gap_rms_nm_opensim": float(
            np.sqrt(((produced - torques[:, balanced]) ** 2).mean())
        ),
        "so_rajagopal_muscle_torque_gap_rms_nm_ours": float(
            np.sqrt(((ours_produced - torques[:, balanced]) ** 2).mean())
        ),
        "so_rajagopal_reserve_usage": agreement["reserve_usage"],
        "so_rajagopal_r2_per_muscle": {m: float(v) for m, v in zip(reference.muscle_names, r2)},
    }
    figures.update(_emg_same_inputs(data_root, reference, ours, reference.muscle_names))
    if timing is not None:
        figures.update(
            {
                "surrogate_ms_per_clip": timing["ms"],
                "surrogate_ms_per_clip_one_pass": timing["ms_one_pass"],
                "surrogate_clip_seconds": timing["clip_seconds"],
                "surrogate_speedup_vs_opensim": 1e3 * reference.seconds / timing["ms"],
            }
        )
    return figures


def _emg_same_inputs(
    data_root: Path, reference: OpenSimStaticOptimization, ours: np.ndarray, names: Sequence[str]
) -> dict:
    """EMG on/off agreement (`biomotion.validation.emg`, its a-priori settings) of OpenSim's StaticOptimization and of
    ours on the Rajagopal walk's shared inputs: the oracle's own score under the check's method. Empty without the
    EMG recording."""
    from biomotion.validation import emg

    if not (data_root / emg.EMG_FILE).exists():
        return {}
    recording = emg.read_anc(data_root / emg.EMG_FILE)
    settings = emg.EMGSettings()
    times = reference.times
    inside = (times >= recording.times[0] - 1e-9) & (times <= recording.times[-1] + 1e-9)
    envelopes = emg.emg_envelopes(recording, times[inside], settings)
    rate = (inside.sum() - 1) / (times[inside][-1] - times[inside][0])
    scores = {
        key: emg.compare_on_off(envelopes, emg.channel_activations(a[inside], muscle_names), settings.threshold, rate)
        for key, a, muscle_names in (("opensim", reference.activations, reference.muscle_names), ("ours", ours, names))
    }
    return {
        "emg_onoff_agreement_opensim_so": round(scores["opensim"]["pooled"], 4),
        "emg_per_muscle_opensim_so": scores["opensim"]["per_muscle"],
        "emg_onoff_agreement_same_inputs_ours": round(scores["ours"]["pooled"], 4),
    }


def validate_muscles(
    data_root: str | Path, poses: int = 200, start: float = 0.5, end: float = 2.5, surrogate: Path | None = SURROGATE
) -> dict:
    """The muscles check's figures (see module docstring) computed fresh against OpenSim on whatever of their
    sources ``data_root`` holds; ``skipped`` names the parts left out and why."""
    data_root = Path(data_root)
    os.environ.setdefault("OMP_NUM_THREADS", "2")
    report: dict = {"skipped": []}
    report.update(_moment_arm_figures(data_root, poses))
    if "moment_arm_rmse_m" not in report:
        report["skipped"].append(f"moment arms: neither {RAJAGOPAL_MODEL} nor {GAIT_MODEL} under {data_root}")
    gait = [
        GAIT_MODEL,
        f"{GAIT}/subject01_walk1_ik.mot",
        f"{GAIT}/subject01_walk1_grf.xml",
        f"{GAIT}/gait2392_SO_Residual_Actuators.xml",
    ]
    absent = [n for n in gait if not (data_root / n).exists()]
    if absent:
        report["skipped"].append(f"gait2392 static optimization: {', '.join(absent)} not under {data_root}")
    else:
        report.update(_gait_figures(data_root, start, end))
    from biomotion.validation import emg

    walk = [
        RAJAGOPAL_MODEL,
        emg.MARKER_FILE,
        emg.GRF_FILE,
        emg.GRF_LOADS,
        emg.IK_SETUP,
        f"{RAJAGOPAL_PIPELINE}/Scale/markerset_walk_preScale.xml",
    ]
    absent = [n for n in walk if not (data_root / n).exists()]
    if absent:
        report["skipped"].append(f"Rajagopal walk static optimization: {', '.join(absent)} not under {data_root}")
    else:
        report.update(_rajagopal_figures(data_root, surrogate))
    trials = [report[k] for k in ("so_r2_gait2392", "so_rajagopal_r2_all") if k in report]
    if trials:
        report["so_r2_vs_opensim"] = min(trials)
    check = emg_check(data_root, surrogate=surrogate)
    report["skipped"] += check.pop("skipped", [])
    report.update(check)
    report.update(surrogate_figures(data_root, surrogate, report["skipped"]))
    return report


#: Sources of the surrogate's training cache (checkpoints/surrogate.md): the motion-capture ones, not Bandai-Namco.
SURROGATE_SOURCES = ("fukuchi", "opencap", "hamner", "schreiber")


def surrogate_figures(data_root: Path, surrogate: Path | None, skipped: list[str]) -> dict:
    """The shipped surrogate against fresh static-optimization labels of the held-out clips under ``data_root``
    (see the module docstring); appends to ``skipped`` what it could not do."""
    from biomotion.analysis.activation_labels import Labeler
    from biomotion.data.clips import build_temporary_cache
    from biomotion.data.sources import SOURCES
    from biomotion.muscles.surrogate import MuscleSurrogate
    from biomotion.muscles.surrogate_scores import COM_LABEL_COLUMNS, evaluate

    empty = {"surrogate_r2": None, "surrogate_rmse": None, "surrogate_com_vel_r2": None}
    if surrogate is None or not Path(surrogate).exists():
        skipped.append(f"surrogate agreement: no surrogate checkpoint at {surrogate}")
        return empty
    if not (data_root / RAJAGOPAL_MODEL).exists():
        skipped.append(f"surrogate agreement: {RAJAGOPAL_MODEL} not under {data_root}")
        return empty
    present = [name for name in SURROGATE_SOURCES if SOURCES[name].present(data_root)]
    if not present:
        skipped.append(f"surrogate agreement: none of {', '.join(SURROGATE_SOURCES)} under {data_root}")
        return empty
    started = time.perf_counter()
    handle, cache = build_temporary_cache(data_root, sources=present)
    with handle:
        trained = MuscleSurrogate.training_subjects(surrogate)
        held_out = [
            i
            for i, r in enumerate(cache.records)
            if (r["split"] != "train" if trained is None else f"{r['source']}/{r['subject']}" not in trained)
        ]
        if not held_out:
            skipped.append("surrogate agreement: the surrogate was trained on every subject under the data root")
            return empty
        labeler = Labeler.from_data_root(data_root)
        model = MuscleSurrogate.load(surrogate, body=labeler.model)
        clips = []
        for i in held_out:
            motion = cache.motion(i)
            labels, com = labeler.label(motion)
            clips.append(
                (
                    torch.tensor(motion.values, dtype=torch.float32)[None],
                    torch.tensor(motion.mask)[None],
                    labels.activations,
                    labels.converged,
                    com[:, COM_LABEL_COLUMNS],
                )
            )
        scores = evaluate(model, clips, symmetric=True)
        one_pass = evaluate(model, clips)
        subjects = sorted({f"{cache.records[i]['source']}/{cache.records[i]['subject']}" for i in held_out})
    return {
        **empty,
        "surrogate_r2": scores["r2_mean_per_muscle"],
        "surrogate_rmse": scores["rmse"],
        "surrogate_r2_pooled": scores["r2_pooled"],
        "surrogate_muscles_in_mean": scores["muscles_in_mean"],
        "surrogate_r2_one_pass": one_pass["r2_mean_per_muscle"],
        "surrogate_rmse_one_pass": one_pass["rmse"],
        "surrogate_r2_per_muscle": {
            name: round(value, 4) for name, value in sorted(scores["per_muscle_r2"].items(), key=lambda item: item[1])
        },  # worst first: where to work next
        "surrogate_com_vel_r2": scores["com_vel_r2"],
        "surrogate_com_vel_rmse": scores["com_vel_rmse"],
        "surrogate_com_acc_r2": scores["com_acc_r2"],
        "surrogate_com_acc_rmse": scores["com_acc_rmse"],
        "surrogate_held_out_clips": len(held_out),
        "surrogate_held_out_subjects": subjects,
        "surrogate_held_out_frames": scores["frames"],
        "surrogate_seconds": round(time.perf_counter() - started, 1),
    }
